/* SPDX-License-Identifier: MIT */
/*
 * main.c - jakagw: the service. Flags and configuration, signals as loop
 * events, systemd readiness, status and watchdog; everything else is in
 * gateway.c.
 */
#include "can_map.h"
#include "config.h"
#include "config_reload.h"
#include "gateway.h"
#include "gw_http.h"
#include "gw_tls.h"
#include "log.h"
#include "regmap.h"
#include "unit_exec.h"

#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <signal.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <systemd/sd-daemon.h>
#include <uv.h>

#define EXIT_CONFIG 2
/* --check-start's answers, as systemd's ExecCondition= reads them: 1-254
 * skip the start (the unit is not failed), 255 fails the unit. */
#define EXIT_CHECK_NO_ROBOT 1
#define EXIT_CHECK_CANNOT_START 255

struct service {
    uv_loop_t *loop;
    struct gateway gw;
    uv_signal_t sigint, sigterm, sighup;
    uv_timer_t watchdog;
    bool watchdog_on;
    bool stopping;
    int exit_code;
    /* Keys the last reload found changed that wait for a restart: shown in
     * the status line until then (config_reload.h). */
    char restart_keys[CONFIG_RELOAD_KEYS_TEXT];
};

static void usage(FILE *out)
{
    fprintf(out,
            "Usage: jakagw [options]\n"
            "Presents a JAKA robot controller as a Modbus TCP slave.\n\n"
            "  -c, --config FILE        configuration file (default %s if it exists)\n"
            "      --robot-host HOST    robot controller address\n"
            "      --status-port N      robot status port (default 10000)\n"
            "      --command-port N     robot command port (default 10001)\n"
            "      --modbus-bind ADDR   Modbus TCP listen address (default 0.0.0.0)\n"
            "      --modbus-port N      Modbus TCP port (default 502)\n"
            "      --log-level LEVEL    error, warning, notice, info or debug\n"
            "      --check-config       check the configuration, print it, exit\n"
            "      --check-start        with the flags the service runs with: exit 0 if\n"
            "                           it would start, 1 if no robot is named, 255 if\n"
            "                           it cannot start (the reason on stderr)\n"
            "      --start-condition UNIT  then COMMAND...: the units' start condition,\n"
            "                           --check-start with the command line systemd runs\n"
            "                           UNIT with (COMMAND if systemd does not say): exit\n"
            "                           1 if no robot is named, else 0\n"
            "      --print-map FORMAT   print the register map as csv, md or st, exit\n"
            "      --print-config-keys  print every configuration key, its default and\n"
            "                           whether a reload (SIGHUP) applies it, exit\n"
            "      --print-dbc          print the DBC of the CAN frames as configured, exit\n"
            "      --version            print the version, exit\n"
            "  -h, --help               print this help, exit\n\n"
            "Signals: SIGHUP reads the configuration again; SIGTERM or SIGINT stops.\n"
            "Exit status: 0 stopped cleanly, 1 runtime failure, 2 bad flag or "
            "configuration.\n",
            CONFIG_DEFAULT_PATH);
}

static int print_map(const char *format)
{
    struct regmap map;
    enum regmap_format f;
    int rc;

    if (strcmp(format, "csv") == 0)
        f = REGMAP_FORMAT_CSV;
    else if (strcmp(format, "md") == 0)
        f = REGMAP_FORMAT_MD;
    else if (strcmp(format, "st") == 0)
        f = REGMAP_FORMAT_ST;
    else {
        log_plain("jakagw: --print-map: '%s' must be csv, md or st", format);
        return EXIT_CONFIG;
    }
    rc = regmap_init(&map);
    if (rc) {
        log_plain("jakagw: the built-in register map is invalid");
        return 1;
    }
    rc = regmap_print(&map, f, stdout);
    regmap_free(&map);
    if (fflush(stdout) != 0 || rc != 0)
        return 1;
    return 0;
}

/* The DBC for the configured identifiers, period and frame groups. */
static int print_dbc(const struct gw_config *cfg)
{
    struct can_dbc_options opt = {
        .base_id = cfg->can_base_id,
        .extended_ids = cfg->can_extended_ids,
        .period_ms = cfg->can_period_ms,
        .groups = cfg->can_groups,
    };

    if (can_map_check() != 0) {
        log_plain("jakagw: the built-in CAN frame map is invalid");
        return 1;
    }
    if (can_map_print_dbc(&opt, stdout) != 0 || fflush(stdout) != 0)
        return 1;
    return 0;
}

/* The flags that set keys, kept to read the configuration again on SIGHUP. */
static struct {
    const char *config_path; /* -c FILE; NULL: CONFIG_DEFAULT_PATH if it exists */
    struct { const char *section, *key, *flag, *value; } overrides[8];
    unsigned n_overrides;
} flags;

/*
 * Reads the configuration file over the defaults and the flags over it, and
 * checks the whole: at start, and again on every reload. Returns 0, or
 * -EINVAL with the reason written to 'why'.
 */
static int load_config(struct gw_config *cfg, bool *file_read, char *why, size_t why_size)
{
    char reason[512];
    int rc;

    config_defaults(cfg);
    rc = config_load(cfg, flags.config_path ? flags.config_path : CONFIG_DEFAULT_PATH,
                     reason, sizeof(reason));
    *file_read = rc == 0;
    /* No file at the default place: defaults and flags only. A file that is
     * there but cannot be read is an error, like one given with -c. */
    if (rc == -ENOENT && !flags.config_path)
        rc = 0;
    if (rc) {
        snprintf(why, why_size, "configuration error: %s", reason);
        return -EINVAL;
    }
    for (unsigned i = 0; i < flags.n_overrides; i++) {
        if (config_set(cfg, flags.overrides[i].section, flags.overrides[i].key,
                       flags.overrides[i].value, reason, sizeof(reason))) {
            snprintf(why, why_size, "--%s: %s", flags.overrides[i].flag, reason);
            return -EINVAL;
        }
    }
    if (config_validate(cfg, reason, sizeof(reason))) {
        snprintf(why, why_size, "configuration error: %s", reason);
        return -EINVAL;
    }
    /* Every certificate, key, CA and CRL loads, and the key matches. */
    if (gw_tls_check(cfg, reason, sizeof(reason))) {
        snprintf(why, why_size, "configuration error: %s", reason);
        return -EINVAL;
    }
    return 0;
}

static void on_gateway_closed(struct gateway *gw)
{
    (void)gw;
}

static void on_handle_closed(uv_handle_t *h)
{
    (void)h;
}

static void stop_service(struct service *svc, int exit_code)
{
    if (svc->stopping)
        return;
    svc->stopping = true;
    svc->exit_code = exit_code;
    sd_notify(0, "STOPPING=1");
    uv_close((uv_handle_t *)&svc->sigint, on_handle_closed);
    uv_close((uv_handle_t *)&svc->sigterm, on_handle_closed);
    uv_close((uv_handle_t *)&svc->sighup, on_handle_closed);
    uv_close((uv_handle_t *)&svc->watchdog, on_handle_closed);
    gateway_close(&svc->gw, on_gateway_closed);
}

/*
 * SIGTERM, SIGINT: no new connection is accepted, the Modbus requests that
 * have arrived are answered, and the robot connections are closed. Nothing
 * is sent to the robot on the way out: it goes on as its own handling of a
 * lost network connection says.
 */
static void on_signal(uv_signal_t *s, int signum)
{
    struct service *svc = s->data;
    log_notice("received %s: stopping: answering the requests that have arrived, "
               "closing the robot connections (no command is sent)",
               strsignal(signum));
    stop_service(svc, 0);
}

static void on_gateway_change(struct gateway *gw)
{
    const struct service *svc =
        (const struct service *)((const char *)gw - offsetof(struct service, gw));
    char status[160];

    gateway_describe(gw, status, sizeof(status));
    if (svc->restart_keys[0])
        sd_notifyf(0, "STATUS=%s; restart needed for %s", status, svc->restart_keys);
    else
        sd_notifyf(0, "STATUS=%s", status);
}

/*
 * SIGHUP: the configuration file and the flags are read again and checked
 * in full. A file with any error changes nothing; otherwise the keys that
 * can change live do, and the others keep their value until a restart,
 * each with a line saying so (config_reload.h).
 */
static void on_reload(uv_signal_t *s, int signum)
{
    struct service *svc = s->data;
    const char *path = flags.config_path ? flags.config_path : CONFIG_DEFAULT_PATH;
    struct config_reload_result result;
    struct gw_config next;
    bool file_read;
    char why[600];

    (void)signum;
    sd_notify(0, "RELOADING=1");
    log_notice("received SIGHUP: reading the configuration again");
    if (load_config(&next, &file_read, why, sizeof(why)) != 0) {
        log_err("reload refused, the running configuration stays in force: %s", why);
    } else {
        next.modbus_listen_fd = svc->gw.cfg.modbus_listen_fd;
        next.tls_listen_fd = svc->gw.cfg.tls_listen_fd;
        if (config_reload_apply(&svc->gw, &next, &result) != 0) {
            log_err("reload: out of memory; the running configuration stays in force");
        } else {
            log_notice("reload: %s%s: %u changes applied, %u need a restart%s%s%s",
                       file_read ? "" : "no file at ", path, result.applied, result.restart,
                       result.restart ? " (" : "", result.restart_keys,
                       result.restart ? "): systemctl restart" : "");
            memcpy(svc->restart_keys, result.restart_keys, sizeof(svc->restart_keys));
        }
    }
    on_gateway_change(&svc->gw);
    sd_notify(0, "READY=1");
}

/*
 * Socket activation: the listening sockets passed by systemd are served
 * instead of binding [modbus] bind and port ([tls] bind and port). The one
 * named "mbaps" (FileDescriptorName= in jakagw-mbaps.socket) is the
 * Modbus/TCP Security listener; the other (jakagw.socket) is plain Modbus
 * TCP. Returns 0 with cfg->modbus_listen_fd and cfg->tls_listen_fd set for
 * those passed, -EINVAL (logged) when what was passed is not at most one
 * listening TCP socket of each kind.
 */
static int adopt_passed_socket(struct gw_config *cfg)
{
    char **names = NULL;
    int n = sd_listen_fds_with_names(1, &names);
    int rc = 0;

    if (n == 0)
        return 0;
    if (n < 0) {
        log_err("cannot read the sockets passed by systemd: %s", strerror(-n));
        return -EINVAL;
    }
    for (int i = 0; i < n; i++) {
        int fd = SD_LISTEN_FDS_START + i;
        bool tls = names && names[i] && strcmp(names[i], "mbaps") == 0;
        int *slot = tls ? &cfg->tls_listen_fd : &cfg->modbus_listen_fd;
        if (rc == 0 && (*slot || sd_is_socket(fd, AF_UNSPEC, SOCK_STREAM, 1) <= 0)) {
            log_err("systemd passed %d file descriptors; jakagw serves one listening TCP "
                    "socket for Modbus TCP (jakagw.socket) and one named mbaps "
                    "(jakagw-mbaps.socket) at most",
                    n);
            rc = -EINVAL;
        }
        *slot = fd;
    }
    if (rc == 0 && cfg->tls_listen_fd && !cfg->tls_enabled) {
        /* jakagw-socket.service wants jakagw-mbaps.socket (Sockets=): it
         * is passed whether or not the configuration serves it. */
        log_notice("systemd passed the mbaps socket (port 802), but [tls] enabled is "
                   "false: it is not served");
        close(cfg->tls_listen_fd);
        cfg->tls_listen_fd = 0;
    }
    if (rc == 0 && cfg->modbus_listen_fd && !cfg->modbus_enabled) {
        log_err("systemd passed a Modbus TCP socket, but [modbus] enabled is false");
        rc = -EINVAL;
    }
    for (int i = 0; names && i < n; i++)
        free(names[i]);
    free(names);
    return rc;
}

/*
 * The systemd watchdog is fed from a loop timer: if the loop stalls, the
 * pings stop and systemd restarts the service. Freshness is refreshed here
 * too, so STATUS= tells when the robot falls silent.
 */
static void on_watchdog(uv_timer_t *t)
{
    struct service *svc = t->data;
    if (svc->watchdog_on)
        sd_notify(0, "WATCHDOG=1");
    on_gateway_change(&svc->gw);
}

/*
 * getopt_long's own messages are off (a leading ':' in the option string and
 * opterr = 0), so a bad flag gets this one line instead of two.
 */
static void report_bad_flag(int opt, char **argv, const struct option *options)
{
    /* getopt_long has stepped past the offending word. */
    const char *word = argv[optind - 1];
    char shown[3] = {'-', (char)optopt, '\0'};
    bool is_long = strncmp(word, "--", 2) == 0;
    size_t name_len = strcspn(word + 2, "=");
    unsigned matches = 0;

    for (const struct option *o = options; is_long && o->name; o++)
        matches += strncmp(o->name, word + 2, name_len) == 0;
    if (opt == ':')
        log_plain("jakagw: %s needs a value; see jakagw --help",
                is_long ? word : shown);
    else if (is_long && optopt != 0)
        log_plain("jakagw: '%s': %.*s takes no value; see jakagw --help", word,
                (int)strcspn(word, "="), word);
    else if (matches > 1)
        log_plain("jakagw: '%s' is ambiguous; see jakagw --help", word);
    else
        log_plain("jakagw: unknown flag '%s'; see jakagw --help",
                is_long || optopt == 0 ? word : shown);
}

static int parse_flags(int argc, char **argv, struct gw_config *cfg,
                       bool *check_only, const char **print_format, bool *file_read,
                       bool *print_dbc_only, bool *print_keys)
{
    enum { OPT_ROBOT_HOST = 256, OPT_STATUS_PORT, OPT_COMMAND_PORT,
           OPT_MODBUS_BIND, OPT_MODBUS_PORT, OPT_LOG_LEVEL, OPT_CHECK,
           OPT_PRINT_MAP, OPT_VERSION, OPT_PRINT_DBC, OPT_PRINT_KEYS,
           OPT_CHECK_START };
    static const struct option options[] = {
        {"config", required_argument, NULL, 'c'},
        {"robot-host", required_argument, NULL, OPT_ROBOT_HOST},
        {"status-port", required_argument, NULL, OPT_STATUS_PORT},
        {"command-port", required_argument, NULL, OPT_COMMAND_PORT},
        {"modbus-bind", required_argument, NULL, OPT_MODBUS_BIND},
        {"modbus-port", required_argument, NULL, OPT_MODBUS_PORT},
        {"log-level", required_argument, NULL, OPT_LOG_LEVEL},
        {"check-config", no_argument, NULL, OPT_CHECK},
        {"check-start", no_argument, NULL, OPT_CHECK_START},
        {"print-map", required_argument, NULL, OPT_PRINT_MAP},
        {"print-dbc", no_argument, NULL, OPT_PRINT_DBC},
        {"print-config-keys", no_argument, NULL, OPT_PRINT_KEYS},
        {"version", no_argument, NULL, OPT_VERSION},
        {"help", no_argument, NULL, 'h'},
        {NULL, 0, NULL, 0},
    };
    /* Flags override the file, so they are applied after it is read. */
    char why[600];
    int opt;

    opterr = 0;
    while ((opt = getopt_long(argc, argv, ":c:h", options, NULL)) != -1) {
        const char *section = NULL, *key = NULL;
        switch (opt) {
        case 'c': flags.config_path = optarg; continue;
        case 'h': usage(stdout); exit(0);
        case OPT_VERSION: printf("jakagw %s (register map %d)\n", JAKAGW_VERSION,
                                 REGMAP_VERSION); exit(0);
        case OPT_CHECK: *check_only = true; continue;
        case OPT_CHECK_START: continue; /* found by wants_check_start() */
        case OPT_PRINT_MAP: *print_format = optarg; continue;
        case OPT_PRINT_DBC: *print_dbc_only = true; continue;
        case OPT_PRINT_KEYS: *print_keys = true; continue;
        case OPT_ROBOT_HOST: section = "robot"; key = "host"; break;
        case OPT_STATUS_PORT: section = "robot"; key = "status_port"; break;
        case OPT_COMMAND_PORT: section = "robot"; key = "command_port"; break;
        case OPT_MODBUS_BIND: section = "modbus"; key = "bind"; break;
        case OPT_MODBUS_PORT: section = "modbus"; key = "port"; break;
        case OPT_LOG_LEVEL: section = "log"; key = "level"; break;
        default:
            report_bad_flag(opt, argv, options);
            return -EINVAL;
        }
        flags.overrides[flags.n_overrides].section = section;
        flags.overrides[flags.n_overrides].key = key;
        flags.overrides[flags.n_overrides].flag = options[0].name;
        for (const struct option *o = options; o->name; o++)
            if (o->val == opt)
                flags.overrides[flags.n_overrides].flag = o->name;
        flags.overrides[flags.n_overrides++].value = optarg;
        if (flags.n_overrides == sizeof(flags.overrides) / sizeof(flags.overrides[0])) {
            log_plain("jakagw: too many flags");
            return -EINVAL;
        }
    }
    if (optind < argc) {
        log_plain("jakagw: unexpected argument '%s'; see jakagw --help",
                argv[optind]);
        return -EINVAL;
    }
    config_defaults(cfg);
    if (*print_format || *print_keys)
        return 0;
    if (load_config(cfg, file_read, why, sizeof(why))) {
        log_plain("jakagw: %s", why);
        return -EINVAL;
    }
    return 0;
}

/* --check-start, wherever it is: a bad flag before it is still its
 * answer (255), not the service's exit status 2. */
static bool wants_check_start(int argc, char **argv)
{
    for (int i = 1; i < argc && strcmp(argv[i], "--") != 0; i++)
        if (strcmp(argv[i], "--check-start") == 0)
            return true;
    return false;
}

/*
 * Would the service start with these flags and this file? The units ask
 * before each start (ExecCondition=), with the command line the service
 * runs with, drop-ins' flags included, in the service's own sandbox: so
 * the gateway's parser decides, never a guess at the file's text. A file
 * that names no robot is a skip, any reason not to start a failure.
 */
static int check_start(const struct gw_config *cfg, bool file_read)
{
    const char *path = flags.config_path ? flags.config_path : CONFIG_DEFAULT_PATH;

    if (!cfg->robot_named) {
        log_plain("jakagw: %s%s names no robot ([robot] host is commented out or missing, "
                  "and no --robot-host flag): not started; name the robot, then restart the "
                  "service",
                  file_read ? "" : "no configuration file: ", path);
        return EXIT_CHECK_NO_ROBOT;
    }
    printf("jakagw: %s: robot %s: the service starts\n", path, cfg->robot_host);
    return 0;
}

/* Whether 'path' is this very program (the same file, by any name). */
static bool is_this_program(const char *path)
{
    struct stat a, b;
    return stat(path, &a) == 0 && stat("/proc/self/exe", &b) == 0 && a.st_dev == b.st_dev &&
           a.st_ino == b.st_ino;
}

/* The check of --check-start on 'argv' in this process, its output
 * discarded: 0 it would start, 1 no robot named, 255 it cannot start. */
static int check_quietly(int argc, char **argv, struct gw_config *cfg, bool *file_read)
{
    bool check_only = false, print_dbc_only = false, print_keys = false;
    const char *print_format = NULL;
    int out = dup(STDOUT_FILENO), err = dup(STDERR_FILENO);
    int null = open("/dev/null", O_WRONLY | O_CLOEXEC);
    int rc;

    if (out < 0 || err < 0 || null < 0 || dup2(null, STDOUT_FILENO) < 0 ||
        dup2(null, STDERR_FILENO) < 0) {
        rc = 0; /* nothing checked: the start goes on, ExecStart= decides */
    } else {
        rc = parse_flags(argc, argv, cfg, &check_only, &print_format, file_read,
                         &print_dbc_only, &print_keys)
                 ? EXIT_CHECK_CANNOT_START
                 : cfg->robot_named ? 0 : EXIT_CHECK_NO_ROBOT;
        fflush(stdout);
        fflush(stderr);
    }
    if (out >= 0) {
        dup2(out, STDOUT_FILENO);
        close(out);
    }
    if (err >= 0) {
        dup2(err, STDERR_FILENO);
        close(err);
    }
    if (null >= 0)
        close(null);
    return rc;
}

/*
 * --start-condition UNIT COMMAND...: the units' ExecCondition= (through
 * jakagw-condition, as root). The command line checked is the one systemd
 * runs UNIT with (unit_exec.h: the first ExecStart=, drop-ins included,
 * word for word), or COMMAND (the package's own ExecStart=) when systemd
 * does not say; with the gateway's own parser, in this process. The
 * answer, as ExecCondition= reads it: 1 (a skip, the reason on stderr,
 * which the journal keeps) when no robot is named; else 0, also where the
 * service cannot start (a bad value, a missing file, a bad flag):
 * ExecStart= then fails with the same reason and exit status 2, which the
 * units never restart, and the unit shows in 'systemctl --failed' (a
 * condition's own failure would be restarted every RestartSec= by
 * Restart=always, never 'failed'). A unit that runs another program is
 * not checked: it starts as configured.
 */
static int start_condition(int argc, char **argv)
{
    const char *unit = argc > 2 ? argv[2] : "";
    char **words = NULL, **command = argv + 3, why[300];
    int count = argc > 3 ? argc - 3 : 0, rc = 0;

    if (unit_exec_start(unit, &words, why, sizeof(why)) == 0) {
        command = words;
        for (count = 0; words[count]; count++)
            ;
    } else {
        log_plain("jakagw-condition: systemd did not say how %s runs (%s): checked with the "
                  "package's command line", unit, why);
    }
    if (count == 0 || !is_this_program(command[0])) {
        log_plain("jakagw-condition: %s runs '%s', not this jakagw: the check cannot apply its "
                  "flags; it starts as configured", unit, count ? command[0] : "");
    } else {
        char **check = calloc((size_t)count + 2, sizeof(*check));
        struct gw_config cfg;
        bool file_read = false;
        if (!check) {
            log_plain("jakagw-condition: out of memory: the start goes on unchecked");
        } else {
            memcpy(check, command, (size_t)count * sizeof(*check));
            check[count] = "--check-start";
            rc = check_quietly(count + 1, check, &cfg, &file_read);
            if (rc == EXIT_CHECK_NO_ROBOT)
                check_start(&cfg, file_read); /* says why, on stderr */
            else
                rc = 0;
            free(check);
        }
    }
    unit_exec_free(words);
    return rc;
}

int main(int argc, char **argv)
{
    struct service svc;
    struct gw_config cfg;
    bool check_only = false;
    const char *print_format = NULL;
    uint64_t watchdog_usec = 0;
    bool file_read = false;
    bool print_dbc_only = false;
    bool print_keys = false;
    char status[160];

    if (argc >= 2 && strcmp(argv[1], "--start-condition") == 0)
        return start_condition(argc, argv);
    if (parse_flags(argc, argv, &cfg, &check_only, &print_format, &file_read,
                    &print_dbc_only, &print_keys)) {
        if (wants_check_start(argc, argv)) {
            log_plain("jakagw: the service cannot start (the line above says why)");
            return EXIT_CHECK_CANNOT_START;
        }
        return EXIT_CONFIG;
    }
    if (wants_check_start(argc, argv))
        return check_start(&cfg, file_read);
    if (print_keys)
        return config_reload_print_keys(stdout) == 0 && fflush(stdout) == 0 ? 0 : 1;
    if (print_dbc_only)
        return print_dbc(&cfg);
    if (print_format)
        return print_map(print_format);
    if (check_only) {
        if (!file_read)
            printf("; no configuration file was read (%s does not exist): defaults and "
                   "flags in force\n",
                   CONFIG_DEFAULT_PATH);
        config_print(&cfg, stdout);
        return 0;
    }
    log_set_level((enum log_level)cfg.log_level);
    if (!file_read)
        log_notice("no configuration file was read (%s does not exist): defaults and flags "
                   "in force",
                   CONFIG_DEFAULT_PATH);
    if (adopt_passed_socket(&cfg) != 0)
        return EXIT_CONFIG;
    /* A robot or PLC closing mid-write must not kill the gateway. */
    signal(SIGPIPE, SIG_IGN);

    memset(&svc, 0, sizeof(svc));
    svc.loop = uv_default_loop();
    uv_signal_init(svc.loop, &svc.sigint);
    uv_signal_init(svc.loop, &svc.sigterm);
    uv_signal_init(svc.loop, &svc.sighup);
    svc.sigint.data = svc.sigterm.data = svc.sighup.data = &svc;
    uv_signal_start(&svc.sigint, on_signal, SIGINT);
    uv_signal_start(&svc.sigterm, on_signal, SIGTERM);
    uv_signal_start(&svc.sighup, on_reload, SIGHUP);
    uv_timer_init(svc.loop, &svc.watchdog);
    svc.watchdog.data = &svc;

    if (cfg.modbus_listen_fd > 0)
        log_notice("jakagw %s starting: robot %s (status %u, command %u), Modbus on the "
                   "socket passed by systemd",
                   JAKAGW_VERSION, cfg.robot_host, cfg.status_port, cfg.command_port);
    else
        log_notice("jakagw %s starting: robot %s (status %u, command %u), Modbus %s:%u",
                   JAKAGW_VERSION, cfg.robot_host, cfg.status_port, cfg.command_port,
                   cfg.modbus_bind, cfg.modbus_port);
    svc.gw.on_change = NULL;
    if (gateway_start(svc.loop, &svc.gw, &cfg) != 0 || gw_http_start(&svc.gw) != 0) {
        log_err("cannot start; see the lines above");
        stop_service(&svc, svc.gw.config_error ? EXIT_CONFIG : 1);
    } else {
        svc.gw.on_change = on_gateway_change;
        svc.watchdog_on = sd_watchdog_enabled(0, &watchdog_usec) > 0;
        uint64_t period_ms = svc.watchdog_on ? watchdog_usec / 2000 : 1000;
        if (period_ms == 0 || period_ms > 1000)
            period_ms = 1000;
        uv_timer_start(&svc.watchdog, on_watchdog, period_ms, period_ms);
        gateway_describe(&svc.gw, status, sizeof(status));
        sd_notifyf(0, "READY=1\nSTATUS=%s", status);
    }
    uv_run(svc.loop, UV_RUN_DEFAULT);
    if (uv_loop_close(svc.loop) != 0)
        log_err("internal error: handles left open at exit");
    log_notice("stopped");
    return svc.exit_code;
}
