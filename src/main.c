/*
 * main.c - jakagw: the service. Flags and configuration, signals as loop
 * events, systemd readiness, status and watchdog; everything else is in
 * gateway.c.
 */
#include "can_map.h"
#include "config.h"
#include "gateway.h"
#include "log.h"
#include "regmap.h"

#include <errno.h>
#include <getopt.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <systemd/sd-daemon.h>
#include <uv.h>

#define EXIT_CONFIG 2

struct service {
    uv_loop_t *loop;
    struct gateway gw;
    uv_signal_t sigint, sigterm;
    uv_timer_t watchdog;
    bool watchdog_on;
    bool stopping;
    int exit_code;
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
            "      --print-map FORMAT   print the register map as csv or md, exit\n"
            "      --print-dbc          print the DBC of the CAN frames as configured, exit\n"
            "      --version            print the version, exit\n"
            "  -h, --help               print this help, exit\n\n"
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
    else {
        fprintf(stderr, "jakagw: --print-map: '%s' must be csv or md\n", format);
        return EXIT_CONFIG;
    }
    rc = regmap_init(&map);
    if (rc) {
        fprintf(stderr, "jakagw: the built-in register map is invalid\n");
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
        fprintf(stderr, "jakagw: the built-in CAN frame map is invalid\n");
        return 1;
    }
    if (can_map_print_dbc(&opt, stdout) != 0 || fflush(stdout) != 0)
        return 1;
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
    uv_close((uv_handle_t *)&svc->watchdog, on_handle_closed);
    gateway_close(&svc->gw, on_gateway_closed);
}

static void on_signal(uv_signal_t *s, int signum)
{
    struct service *svc = s->data;
    log_notice("received %s: stopping", strsignal(signum));
    stop_service(svc, 0);
}

static void on_gateway_change(struct gateway *gw)
{
    char status[160];
    gateway_describe(gw, status, sizeof(status));
    sd_notifyf(0, "STATUS=%s", status);
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
        fprintf(stderr, "jakagw: %s needs a value; see jakagw --help\n",
                is_long ? word : shown);
    else if (is_long && optopt != 0)
        fprintf(stderr, "jakagw: '%s': %.*s takes no value; see jakagw --help\n", word,
                (int)strcspn(word, "="), word);
    else if (matches > 1)
        fprintf(stderr, "jakagw: '%s' is ambiguous; see jakagw --help\n", word);
    else
        fprintf(stderr, "jakagw: unknown flag '%s'; see jakagw --help\n",
                is_long || optopt == 0 ? word : shown);
}

static int parse_flags(int argc, char **argv, struct gw_config *cfg,
                       bool *check_only, const char **print_format, bool *file_read,
                       bool *print_dbc_only)
{
    enum { OPT_ROBOT_HOST = 256, OPT_STATUS_PORT, OPT_COMMAND_PORT,
           OPT_MODBUS_BIND, OPT_MODBUS_PORT, OPT_LOG_LEVEL, OPT_CHECK,
           OPT_PRINT_MAP, OPT_VERSION, OPT_PRINT_DBC };
    static const struct option options[] = {
        {"config", required_argument, NULL, 'c'},
        {"robot-host", required_argument, NULL, OPT_ROBOT_HOST},
        {"status-port", required_argument, NULL, OPT_STATUS_PORT},
        {"command-port", required_argument, NULL, OPT_COMMAND_PORT},
        {"modbus-bind", required_argument, NULL, OPT_MODBUS_BIND},
        {"modbus-port", required_argument, NULL, OPT_MODBUS_PORT},
        {"log-level", required_argument, NULL, OPT_LOG_LEVEL},
        {"check-config", no_argument, NULL, OPT_CHECK},
        {"print-map", required_argument, NULL, OPT_PRINT_MAP},
        {"print-dbc", no_argument, NULL, OPT_PRINT_DBC},
        {"version", no_argument, NULL, OPT_VERSION},
        {"help", no_argument, NULL, 'h'},
        {NULL, 0, NULL, 0},
    };
    /* Flags override the file, so they are applied after it is read. */
    struct { const char *section, *key, *flag, *value; } overrides[8];
    const char *config_path = NULL;
    unsigned n_overrides = 0;
    char why[512];
    int opt;

    opterr = 0;
    while ((opt = getopt_long(argc, argv, ":c:h", options, NULL)) != -1) {
        const char *section = NULL, *key = NULL;
        switch (opt) {
        case 'c': config_path = optarg; continue;
        case 'h': usage(stdout); exit(0);
        case OPT_VERSION: printf("jakagw %s (register map %d)\n", JAKAGW_VERSION,
                                 REGMAP_VERSION); exit(0);
        case OPT_CHECK: *check_only = true; continue;
        case OPT_PRINT_MAP: *print_format = optarg; continue;
        case OPT_PRINT_DBC: *print_dbc_only = true; continue;
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
        overrides[n_overrides].section = section;
        overrides[n_overrides].key = key;
        overrides[n_overrides].flag = options[0].name;
        for (const struct option *o = options; o->name; o++)
            if (o->val == opt)
                overrides[n_overrides].flag = o->name;
        overrides[n_overrides++].value = optarg;
        if (n_overrides == sizeof(overrides) / sizeof(overrides[0])) {
            fprintf(stderr, "jakagw: too many flags\n");
            return -EINVAL;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "jakagw: unexpected argument '%s'; see jakagw --help\n",
                argv[optind]);
        return -EINVAL;
    }
    config_defaults(cfg);
    if (*print_format)
        return 0;
    int rc = config_load(cfg, config_path ? config_path : CONFIG_DEFAULT_PATH, why,
                         sizeof(why));
    *file_read = rc == 0;
    /* No file at the default place: defaults and flags only. A file that is
     * there but cannot be read is an error, like one given with -c. */
    if (rc == -ENOENT && !config_path)
        rc = 0;
    if (rc) {
        fprintf(stderr, "jakagw: configuration error: %s\n", why);
        return -EINVAL;
    }
    for (unsigned i = 0; i < n_overrides; i++) {
        if (config_set(cfg, overrides[i].section, overrides[i].key,
                       overrides[i].value, why, sizeof(why))) {
            fprintf(stderr, "jakagw: --%s: %s\n", overrides[i].flag, why);
            return -EINVAL;
        }
    }
    if (config_validate(cfg, why, sizeof(why))) {
        fprintf(stderr, "jakagw: configuration error: %s\n", why);
        return -EINVAL;
    }
    return 0;
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
    char status[160];

    if (parse_flags(argc, argv, &cfg, &check_only, &print_format, &file_read,
                    &print_dbc_only))
        return EXIT_CONFIG;
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
    /* A robot or PLC closing mid-write must not kill the gateway. */
    signal(SIGPIPE, SIG_IGN);

    memset(&svc, 0, sizeof(svc));
    svc.loop = uv_default_loop();
    uv_signal_init(svc.loop, &svc.sigint);
    uv_signal_init(svc.loop, &svc.sigterm);
    svc.sigint.data = svc.sigterm.data = &svc;
    uv_signal_start(&svc.sigint, on_signal, SIGINT);
    uv_signal_start(&svc.sigterm, on_signal, SIGTERM);
    uv_timer_init(svc.loop, &svc.watchdog);
    svc.watchdog.data = &svc;

    log_notice("jakagw %s starting: robot %s (status %u, command %u), Modbus %s:%u",
               JAKAGW_VERSION, cfg.robot_host, cfg.status_port, cfg.command_port,
               cfg.modbus_bind, cfg.modbus_port);
    svc.gw.on_change = NULL;
    if (gateway_start(svc.loop, &svc.gw, &cfg) != 0) {
        log_err("cannot start; see the lines above");
        stop_service(&svc, 1);
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
