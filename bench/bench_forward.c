/* SPDX-License-Identifier: MIT */
/*
 * bench_forward.c - how long a PLC's command takes through jakagw, against
 * a floor forwarder (bench/floor_forwarder.c) measured side by side in
 * the same run.
 *
 * Both servers run as processes with their robot ports on sockets of this
 * program, which plays the robot (status and command ports) and the PLC
 * (a Modbus TCP client with blocking I/O). One sample: the trigger
 * power_on re-armed (FC05 OFF), then FC05 ON sent, and the time until the
 * command's last byte arrives at the robot's command socket; the robot
 * then replies, and for jakagw the client polls the result register until
 * the reply has been taken, so every command finds the queue empty.
 * Samples alternate between the servers, one by one, so a burst of load
 * on the shared machine hits both.
 *
 *   idle       no status stream
 *   1 kHz      the status document (the 8979-byte real one) written to
 *              both status ports every millisecond by a thread
 *   backlog    the server stopped (SIGSTOP), 50 documents (--backlog) written to its
 *              status port, then the FC05 sent; timed from SIGCONT
 *   paced      as idle, but a pair of samples every millisecond
 *   scraped    paced, and jakagw's /metrics fetched every 100 ms by a
 *              thread (about 100 scrapes fall among the samples; paced
 *              without it, and the floor, which has no HTTP, are the
 *              controls: a sleep between samples costs both servers a
 *              wake-up)
 *
 * and, the other way, how old the status a PLC reads is: one document
 * written to the status port (two variants in turn, their "len" one
 * apart), then FC04 polled until it shows it (jakagw: status_sequence,
 * one more per document parsed; the floor: the newest document's "len"),
 * timed from the document's last byte sent to the answer that shows it.
 *
 * Where valgrind and strace are installed, also: the instructions each
 * server runs per forwarded command (callgrind, user space, toggled on
 * in the functions that handle a Modbus request and the robot's reply:
 * a cycle with the command, less a cycle of the same requests without
 * it) and the system calls per forwarded command (strace -c attached over
 * the same two kinds of cycles).
 *
 *   bench_forward [--samples N] [--rounds N] [--backlog DOCUMENTS] [--no-counts]
 *
 * (BUILD/bench/bench_forward: BUILD/jakagw, BUILD/bench/floor_forwarder.)
 */
#include "bench_proc.h"

#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>

#include "regmap.h"

#define BACKLOG_DOCUMENTS 50
static unsigned backlog_documents = BACKLOG_DOCUMENTS; /* --backlog N */
#define BACKLOG_SAMPLES 7
#define COUNT_CYCLES 200

enum server { JAKAGW, FLOOR, SERVERS };
static const char *const server_names[SERVERS] = {"jakagw", "floor"};

static char document[16384];
static size_t document_size;
/* The document again, one byte longer ("len" + 1, a space more), so that
 * each of two documents in turn changes what the floor serves. */
static char document_alt[16384 + 8];
static size_t document_alt_size;

struct server_io {
    pid_t pid;
    int status; /* robot side of the server's status connection */
    int robot;  /* robot side of its command connection */
    int plc;
    uint16_t tid;
    uint16_t modbus_port;
    uint16_t http_port; /* jakagw's /metrics, 0: none */
    bool alt_next;      /* the status kind: which document goes next */
};

static uint16_t trigger_address, trigger_state;
static struct server_io servers[SERVERS];

static const char ok_reply[] = "{\"cmdName\":\"power_on\",\"errorCode\":\"0\",\"errorMsg\":\"\"}";

/* Answers what a server sends on connect until it has been quiet a while. */
static void answer_until_quiet(int fd, int quiet_ms)
{
    struct object_reader r;
    double end = now_s() + 10; /* the link check asks again and again */
    while (now_s() < end && read_object(fd, &r, quiet_ms) >= 0)
        send_all(fd, ok_reply, sizeof(ok_reply) - 1);
}

/* Answers what jakagw asks the robot while no command is under way (its
 * link check, after a while without a command: unanswered within a
 * second, it closes the link). */
static void answer_link_checks(int fd)
{
    struct object_reader r;
    struct pollfd p = {.fd = fd, .events = POLLIN};
    while (poll(&p, 1, 0) == 1 && read_object(fd, &r, 0) >= 0)
        send_all(fd, ok_reply, sizeof(ok_reply) - 1);
}

/* The command power_on at the robot: the time its last byte arrived.
 * Anything else jakagw asks meanwhile (its link check) is answered. */
static double read_command(int fd)
{
    struct object_reader r;
    for (;;) {
        double t = read_object(fd, &r, 10000);
        if (t < 0 || strstr(r.buf, "\"power_on\""))
            return t;
        send_all(fd, ok_reply, sizeof(ok_reply) - 1);
    }
}

static void modbus_send(struct server_io *s, uint8_t fc, uint16_t address, uint16_t value)
{
    modbus_tcp_send(s->plc, s->tid++, fc, address, value);
}

static void modbus_answer(struct server_io *s, uint8_t fc, uint8_t *rsp, size_t size)
{
    modbus_tcp_answer(s->plc, fc, rsp, size, server_names[s - servers]);
}

static void write_coil(struct server_io *s, bool on)
{
    uint8_t rsp[12];
    modbus_send(s, 5, trigger_address, on ? 0xFF00 : 0);
    modbus_answer(s, 5, rsp, sizeof(rsp));
}

static uint16_t read_input(struct server_io *s, uint16_t address)
{
    uint8_t rsp[11];
    modbus_send(s, 4, address, 1);
    modbus_answer(s, 4, rsp, sizeof(rsp));
    return (uint16_t)(rsp[9] << 8 | rsp[10]);
}

/* jakagw: until the result register shows the robot's reply taken. */
static unsigned wait_done(struct server_io *s, enum server which)
{
    unsigned polls = 0;
    if (which != JAKAGW) {
        read_input(s, trigger_state); /* the same request, for the same cycle */
        return 1;
    }
    for (double deadline = now_s() + 10; now_s() < deadline;) {
        polls++;
        if (read_input(s, trigger_state) == 2 /* CMD_DONE */)
            return polls;
    }
    die("jakagw: the command never completed");
    return 0;
}

/* ---- the 1 kHz status stream, a thread writing to both servers ---- */

static atomic_bool streaming;
static atomic_bool stream_stop;
static pthread_t stream_thread;

/* Sleeps until 'next' + 'period_ns' (a thread's fixed rate), 'next' moved on. */
static void sleep_period(struct timespec *next, long period_ns)
{
    next->tv_nsec += period_ns;
    while (next->tv_nsec >= 1000000000) {
        next->tv_nsec -= 1000000000;
        next->tv_sec++;
    }
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, next, NULL) == EINTR)
        ;
}

static void *stream_main(void *arg)
{
    (void)arg;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    while (!atomic_load(&stream_stop)) {
        if (atomic_load(&streaming))
            for (int s = 0; s < SERVERS; s++)
                send_all(servers[s].status, document, document_size);
        sleep_period(&next, 1000000);
    }
    return NULL;
}

/* ---- /metrics at 10 Hz, a thread scraping jakagw ---- */

static atomic_bool scraping;
static atomic_bool scrape_stop;
static atomic_uint scrapes;
static pthread_t scrape_thread;

/* One GET /metrics on a new connection; the whole answer read. */
static void scrape_once(uint16_t port)
{
    static const char request[] = "GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                                  "Connection: close\r\n\r\n";
    char buf[16384];
    size_t got = 0;
    int fd = connect_loopback(port);
    send_all(fd, request, sizeof(request) - 1);
    for (;;) {
        ssize_t n = recv(fd, buf, sizeof(buf), 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            die("/metrics: %s", strerror(errno));
        if (n == 0)
            break;
        if (got == 0 && strncmp(buf, "HTTP/1.1 200", 12) != 0)
            die("/metrics answered %.12s", buf);
        got += (size_t)n;
    }
    close(fd);
    if (got == 0)
        die("/metrics: no answer");
    atomic_fetch_add(&scrapes, 1);
}

static void *scrape_main(void *arg)
{
    (void)arg;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    while (!atomic_load(&scrape_stop)) {
        if (atomic_load(&scraping))
            scrape_once(servers[JAKAGW].http_port);
        sleep_period(&next, 100000000);
    }
    return NULL;
}

/* In the order they run: the last one sends commands, so that jakagw's
 * command link is busy when the counts begin (no link check due). */
enum kind { K_IDLE, K_PACED, K_SCRAPE, K_STATUS, K_STREAM, K_BACKLOG, K_COUNT };
static const char *const kind_names[K_COUNT] = {
    "idle", "paced 1 ms", "paced, /metrics 10 Hz", "status -> FC04", "1 kHz status", "backlog"};

/* Counting (instructions, system calls): the reply is given time to be
 * taken before the result is polled, so that every cycle polls once, and
 * a cycle without a command waits as long. */
static bool counting;
static double count_wait_s = 0.002; /* longer under valgrind */

/* One command through one server; microseconds to the robot. */
static double sample(enum server which, bool backlog)
{
    struct server_io *s = &servers[which];
    double t0, t1;
    uint8_t rsp[12];
    int st;

    write_coil(s, false);
    if (backlog) {
        kill(s->pid, SIGSTOP);
        if (waitpid(s->pid, &st, WUNTRACED) != s->pid || !WIFSTOPPED(st))
            die("%s did not stop", server_names[which]);
        for (unsigned i = 0; i < backlog_documents; i++)
            send_all(s->status, document, document_size);
        modbus_send(s, 5, trigger_address, 0xFF00);
        t0 = now_us();
        kill(s->pid, SIGCONT);
    } else {
        t0 = now_us();
        modbus_send(s, 5, trigger_address, 0xFF00);
    }
    t1 = read_command(s->robot);
    if (t1 < 0)
        die("%s sent no command", server_names[which]);
    modbus_answer(s, 5, rsp, sizeof(rsp));
    send_all(s->robot, ok_reply, sizeof(ok_reply) - 1);
    if (counting)
        sleep_s(count_wait_s);
    wait_done(s, which);
    return t1 - t0;
}

/* One status document written, FC04 polled until it shows it:
 * microseconds from its last byte sent to the answer that shows it. */
static double status_sample(enum server which)
{
    struct server_io *s = &servers[which];
    /* jakagw: status_sequence (input register 13); the floor serves the
     * newest document's "len" at any address. */
    uint16_t address = 13;
    answer_link_checks(s->robot);
    uint16_t before = read_input(s, address);
    s->alt_next = !s->alt_next;
    send_all(s->status, s->alt_next ? document_alt : document,
             s->alt_next ? document_alt_size : document_size);
    double t0 = now_us();
    for (double deadline = now_s() + 10; now_s() < deadline;) {
        uint16_t now = read_input(s, address);
        double t1 = now_us();
        if (now != before)
            return t1 - t0;
    }
    die("%s never showed a new document", server_names[which]);
    return -1;
}

/* A cycle of the same requests without a command: the trigger stays 0. */
static void idle_cycle(enum server which)
{
    write_coil(&servers[which], false);
    sleep_s(count_wait_s);
    read_input(&servers[which], trigger_state);
}

/* ---- starting the servers ---- */

/* The server's connection to one of the robot's ports. */
static int accept_server(int listener, double seconds, const char *what)
{
    int fd = accept_within(listener, seconds, what);
    /* Room for a backlog of documents while the server is stopped. */
    int size = 4 << 20;
    setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &size, sizeof(size));
    return fd;
}

struct paths {
    const char *jakagw, *floor;
    char conf[PATH_MAX + 16];
    uint16_t http_port; /* 0: no HTTP */
};

/* Starts 'which' (with 'wrapper' in front, e.g. valgrind; NULL: none). */
static void start_server(enum server which, const struct paths *p, char *const *wrapper)
{
    struct server_io *s = &servers[which];
    uint16_t status_port, command_port;
    int status_listener = listen_loopback(&status_port);
    int command_listener = listen_loopback(&command_port);
    char sp[8], cp[8], mp[8];
    char *argv[32];
    unsigned n = 0;

    s->modbus_port = free_port();
    snprintf(sp, sizeof(sp), "%u", status_port);
    snprintf(cp, sizeof(cp), "%u", command_port);
    snprintf(mp, sizeof(mp), "%u", s->modbus_port);
    for (; wrapper && wrapper[n]; n++)
        argv[n] = wrapper[n];
    if (which == JAKAGW) {
        char *rest[] = {(char *)p->jakagw, "-c", (char *)p->conf, "--robot-host", "127.0.0.1",
                        "--status-port", sp, "--command-port", cp, "--modbus-bind",
                        "127.0.0.1", "--modbus-port", mp, NULL};
        memcpy(argv + n, rest, sizeof(rest));
    } else {
        char *rest[] = {(char *)p->floor, sp, cp, mp, NULL};
        memcpy(argv + n, rest, sizeof(rest));
    }
    s->pid = spawn(server_names[which], argv, -1);
    double wait = wrapper ? 60 : 10;
    s->status = accept_server(status_listener, wait, server_names[which]);
    s->robot = accept_server(command_listener, wait, server_names[which]);
    close(status_listener);
    close(command_listener);
    if (which == JAKAGW)
        answer_until_quiet(s->robot, wrapper ? 1000 : 300);
    wait_listening(s->modbus_port, s->pid, server_names[which]);
    s->plc = connect_loopback(s->modbus_port);
    s->tid = 1;
    s->http_port = which == JAKAGW ? p->http_port : 0;
}

static void stop_server(enum server which)
{
    struct server_io *s = &servers[which];
    close(s->plc);
    stop_child(s->pid);
    close(s->status);
    close(s->robot);
}

/* ---- instructions (callgrind) and system calls (strace) ---- */

static bool have_program(const char *name)
{
    char cmd[128];
    snprintf(cmd, sizeof(cmd), "command -v %s >/dev/null 2>&1", name);
    return system(cmd) == 0;
}

/* The total of a callgrind output file's "summary:" / "totals:" line. */
static double callgrind_total(const char *path)
{
    char line[512];
    double total = -1;
    FILE *f = fopen(path, "r");
    if (!f)
        die("%s: %s", path, strerror(errno));
    while (fgets(line, sizeof(line), f))
        if (strncmp(line, "totals:", 7) == 0 || strncmp(line, "summary:", 8) == 0)
            total = strtod(strchr(line, ':') + 1, NULL);
    fclose(f);
    if (total < 0)
        die("%s: no totals", path);
    return total;
}

/* The functions where each server handles a Modbus request and the
 * robot's reply; everything they call counts. */
#define COUNTED_FUNCTIONS 2
static const char *const counted_functions[SERVERS][COUNTED_FUNCTIONS] = {
    [JAKAGW] = {"on_client_read", "on_reply"},
    [FLOOR] = {"serve", "drop_reply"},
};

/* Whether callgrind's output names 'function' as a function or a callee
 * ("fn=(id) name" or "cfn=(id) name" where the name first appears,
 * "fn=name" uncompressed): --toggle-collect matches a symbol's name
 * exactly, so a function inlined or cloned under another name
 * ("serve.constprop.0") is never counted, and says nothing. */
static bool callgrind_saw(const char *path, const char *function)
{
    char line[512];
    bool seen = false;
    size_t len = strlen(function);
    FILE *f = fopen(path, "r");
    if (!f)
        die("%s: %s", path, strerror(errno));
    while (!seen && fgets(line, sizeof(line), f)) {
        const char *fn = line[0] == 'c' ? line + 1 : line;
        if (strncmp(fn, "fn=", 3) != 0)
            continue;
        const char *name = fn + 3;
        if (*name == '(') {
            name = strchr(name, ')');
            if (!name)
                continue;
            name += name[1] == ' ' ? 2 : 1;
        }
        seen = strncmp(name, function, len) == 0 && (name[len] == '\n' || name[len] == '\0');
    }
    fclose(f);
    return seen;
}

/* Instructions per cycle of one kind: with_command or not. */
static double count_instructions(enum server which, const struct paths *p, bool with_command)
{
    char out[PATH_MAX + 32], arg[PATH_MAX + 64];
    char toggles[COUNTED_FUNCTIONS][96];
    snprintf(out, sizeof(out), "%s/callgrind.%s.%d", bench_tmp_dir, server_names[which],
             with_command);
    snprintf(arg, sizeof(arg), "--callgrind-out-file=%s", out);
    char *wrapper[5 + COUNTED_FUNCTIONS] = {"/usr/bin/valgrind", "--tool=callgrind", arg,
                                            "--collect-atstart=no"};
    for (int i = 0; i < COUNTED_FUNCTIONS; i++) {
        snprintf(toggles[i], sizeof(toggles[i]), "--toggle-collect=%s",
                 counted_functions[which][i]);
        wrapper[4 + i] = toggles[i];
    }
    start_server(which, p, wrapper);
    for (int i = 0; i < COUNT_CYCLES; i++) {
        if (with_command)
            sample(which, false);
        else
            idle_cycle(which);
    }
    stop_server(which);
    /* A cycle with the command runs each of them (one without, no reply). */
    for (int i = 0; with_command && i < COUNTED_FUNCTIONS; i++)
        if (!callgrind_saw(out, counted_functions[which][i]))
            die("%s: callgrind never counted in %s() (inlined, or cloned under another "
                "name?): its figure would be wrong", server_names[which],
                counted_functions[which][i]);
    return callgrind_total(out) / COUNT_CYCLES;
}

static pid_t tracer_of(pid_t pid)
{
    char path[64], line[256];
    long tracer = 0;
    snprintf(path, sizeof(path), "/proc/%d/status", (int)pid);
    FILE *f = fopen(path, "r");
    if (!f)
        return 0;
    while (fgets(line, sizeof(line), f))
        if (strncmp(line, "TracerPid:", 10) == 0)
            tracer = strtol(line + 10, NULL, 10);
    fclose(f);
    return (pid_t)tracer;
}

/* System calls per cycle, strace -c attached to the running server. */
static double count_syscalls(enum server which, bool with_command)
{
    char out[PATH_MAX + 32], pid[16], line[512];
    snprintf(out, sizeof(out), "%s/strace.%s.%d", bench_tmp_dir, server_names[which],
             with_command);
    snprintf(pid, sizeof(pid), "%d", (int)servers[which].pid);
    char *argv[] = {"/usr/bin/strace", "-c", "-f", "-o", out, "-p", pid, NULL};
    pid_t tracer = spawn("strace", argv, -1);
    for (double deadline = now_s() + 10; tracer_of(servers[which].pid) != tracer;) {
        if (now_s() > deadline)
            die("strace did not attach");
        sleep_s(0.01);
    }
    for (int i = 0; i < COUNT_CYCLES; i++) {
        if (with_command)
            sample(which, false);
        else
            idle_cycle(which);
    }
    kill(tracer, SIGINT);
    int st;
    waitpid(tracer, &st, 0);
    long calls = -1;
    FILE *f = fopen(out, "r");
    if (!f)
        die("%s: %s", out, strerror(errno));
    while (fgets(line, sizeof(line), f))
        if (strstr(line, " total"))
            sscanf(line, "%*f %*f %*d %ld", &calls);
    fclose(f);
    if (calls < 0)
        die("%s: no total", out);
    return (double)calls / COUNT_CYCLES;
}

static void load_document(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f)
        die("%s: %s", path, strerror(errno));
    document_size = fread(document, 1, sizeof(document), f);
    fclose(f);
    while (document_size && (document[document_size - 1] == '\n'))
        document_size--;
    document[document_size] = '\0';
    /* '{"len": N,' then the rest: the same with N + 1 and a space more. */
    const char *comma = strchr(document, ',');
    unsigned len;
    if (sscanf(document, "{\"len\": %u,", &len) != 1 || !comma || len != document_size)
        die("%s: not a status document that starts with its len", path);
    int n = snprintf(document_alt, sizeof(document_alt), "{\"len\": %u, %s", len + 1,
                     comma + 1);
    if (n < 0 || (size_t)n != document_size + 1)
        die("%s: the document's variant is %d bytes", path, n);
    document_alt_size = (size_t)n;
}

int main(int argc, char **argv)
{
    unsigned samples = 1700, rounds = 6;
    struct paths p = {.jakagw = sibling(argv[0], "../jakagw"),
                      .floor = sibling(argv[0], "floor_forwarder")};
    const char *doc_path = "tests/data/status-controller-a.json";
    bool counts = true;

    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--samples") == 0 && i + 1 < argc)
            samples = (unsigned)atoi(argv[++i]);
        else if (strcmp(argv[i], "--rounds") == 0 && i + 1 < argc)
            rounds = (unsigned)atoi(argv[++i]);
        else if (strcmp(argv[i], "--document") == 0 && i + 1 < argc)
            doc_path = argv[++i];
        else if (strcmp(argv[i], "--backlog") == 0 && i + 1 < argc)
            backlog_documents = (unsigned)atoi(argv[++i]);
        else if (strcmp(argv[i], "--no-counts") == 0)
            counts = false;
        else
            die("usage: bench_forward [--samples N] [--rounds N] [--document PATH] "
                "[--backlog DOCUMENTS] [--no-counts]");
    }
    bench_begin("bench_forward");
    load_document(doc_path);
    struct regmap map;
    if (regmap_init(&map))
        die("regmap_init");
    trigger_address = regmap_find_path(&map, REGMAP_SRC_CMD, "power_on")->address;
    trigger_state = regmap_find_path(&map, REGMAP_SRC_PATH, "result.power_on.state")->address;
    regmap_free(&map);
    /* HTTP on for the latency runs (scraped in one kind), off for the
     * counts. */
    char http[64];
    p.http_port = free_port();
    snprintf(http, sizeof(http), "[http]\nenabled = true\nport = %u\n", p.http_port);
    write_jakagw_config(p.conf, sizeof(p.conf), 4, http);

    for (int s = 0; s < SERVERS; s++)
        start_server((enum server)s, &p, NULL);
    for (int i = 0; i < 50; i++)
        for (int s = 0; s < SERVERS; s++)
            sample((enum server)s, false);

    pthread_create(&stream_thread, NULL, stream_main, NULL);
    pthread_create(&scrape_thread, NULL, scrape_main, NULL);
    double *t[SERVERS];
    for (int s = 0; s < SERVERS; s++)
        t[s] = calloc(samples, sizeof(double));
    double p50[K_COUNT][SERVERS][16], p99[K_COUNT][SERVERS][16], max[K_COUNT][SERVERS][16];
    if (rounds > 16)
        rounds = 16;
    for (int k = 0; k < K_COUNT; k++) {
        unsigned n = k == K_BACKLOG ? BACKLOG_SAMPLES : samples;
        atomic_store(&streaming, k == K_STREAM);
        atomic_store(&scraping, k == K_SCRAPE);
        for (unsigned r = 0; r < (k == K_BACKLOG ? 1 : rounds); r++) {
            for (unsigned i = 0; i < n; i++) {
                for (int s = 0; s < SERVERS; s++)
                    t[s][i] = k == K_STATUS ? status_sample((enum server)s)
                                            : sample((enum server)s, k == K_BACKLOG);
                if (k == K_PACED || k == K_SCRAPE)
                    sleep_s(0.001);
            }
            for (int s = 0; s < SERVERS; s++) {
                p50[k][s][r] = percentile(t[s], n, 0.5);
                p99[k][s][r] = percentile(t[s], n, 0.99);
                max[k][s][r] = t[s][n - 1];
            }
        }
    }
    atomic_store(&streaming, false);
    atomic_store(&stream_stop, true);
    pthread_join(stream_thread, NULL);
    atomic_store(&scraping, false);
    atomic_store(&scrape_stop, true);
    pthread_join(scrape_thread, NULL);

    printf("Command latency, FC05 sent -> the command's last byte at the robot (loopback), "
           "jakagw beside a floor forwarder, samples interleaved\n");
    for (int i = 0; i < K_COUNT; i++) {
        /* The commands' kinds first, then the status's. */
        int k = i < K_STATUS ? i : i == K_COUNT - 1 ? K_STATUS : i + 1;
        unsigned r = k == K_BACKLOG ? 1 : rounds;
        double a50 = median(p50[k][JAKAGW], r), f50 = median(p50[k][FLOOR], r);
        if (k == K_STATUS)
            printf("Status, a document's last byte sent to the status port -> the first FC04 "
                   "answer that shows it (polled back to back), at idle\n");
        if (k == K_BACKLOG) {
            printf("  %-7s of %3u median of %u: jakagw %8.1f us  floor %7.1f us  ratio %5.2f "
                   "(timed from SIGCONT)\n",
                   kind_names[k], backlog_documents, BACKLOG_SAMPLES, a50, f50, a50 / f50);
            continue;
        }
        printf("  %-21s p50 jakagw %7.1f us floor %6.1f us (%4.2fx)  p99 jakagw %8.1f us "
               "floor %7.1f us  max %8.1f / %7.1f us  (%u rounds of %u)\n",
               kind_names[k], a50, f50, a50 / f50, median(p99[k][JAKAGW], r),
               median(p99[k][FLOOR], r), median(max[k][JAKAGW], r), median(max[k][FLOOR], r),
               r, samples);
    }
    printf("  (/metrics scraped %u times, jakagw only)\n", atomic_load(&scrapes));
    fflush(stdout);
    counting = true;
    if (counts && have_program("strace")) {
        double c[SERVERS][2];
        for (int s = 0; s < SERVERS; s++)
            for (int w = 0; w < 2; w++)
                c[s][w] = count_syscalls((enum server)s, w);
        printf("System calls per forwarded FC05 (strace -c, a cycle with the command less "
               "one without): jakagw %.2f, floor %.2f\n",
               c[JAKAGW][1] - c[JAKAGW][0], c[FLOOR][1] - c[FLOOR][0]);
        fflush(stdout);
    }
    for (int s = 0; s < SERVERS; s++)
        stop_server((enum server)s);
    write_jakagw_config(p.conf, sizeof(p.conf), 4, "");
    p.http_port = 0;
    count_wait_s = 0.03;
    if (counts && have_program("valgrind")) {
        double c[SERVERS][2];
        for (int s = 0; s < SERVERS; s++)
            for (int w = 0; w < 2; w++)
                c[s][w] = count_instructions((enum server)s, &p, w);
        printf("Instructions per forwarded FC05 (callgrind, in the request and reply "
               "handlers, a cycle with the command less one without): jakagw %.0f, "
               "floor %.0f (%.1fx)\n",
               c[JAKAGW][1] - c[JAKAGW][0], c[FLOOR][1] - c[FLOOR][0],
               (c[JAKAGW][1] - c[JAKAGW][0]) / (c[FLOOR][1] - c[FLOOR][0]));
    }
    bench_end();
    return 0;
}
