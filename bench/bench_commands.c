/* SPDX-License-Identifier: MIT */
/*
 * bench_commands.c - command latency through the whole gateway: from a
 * Modbus client sending a write to the last byte of the command it causes
 * arriving at a socket that stands for the robot's command port, as a
 * ratio to writing the same command bytes straight to a socket.
 *
 * The gateway runs as jakagw runs it (gateway_start, its own libuv loop, in
 * a thread of this process), on loopback TCP: the Modbus listener, the
 * status port (accepted and kept silent) and the command port are sockets
 * of this program, which plays the PLC and the robot with blocking I/O.
 * After each command the robot replies and the client polls the result
 * registers until the gateway has taken the reply, so every command finds
 * the queue empty and goes out at once. Each timed write follows an
 * untimed request (a poll, or the trigger's re-arm), as in a PLC's cycle.
 *
 * Samples of every kind are interleaved one by one, so a burst of load on
 * a shared machine hits them all; each round yields p50 and p99 per kind,
 * and the figures printed are the medians over the rounds (ratios: the
 * median of the per-round ratios to the reference).
 */
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <uv.h>

#include "config.h"
#include "gateway.h"
#include "log.h"
#include "regmap.h"

#define ROUNDS 9
#define SAMPLES 500 /* per kind and round */
#define WARMUP 50

enum kind { K_DIRECT, K_SETPOINT, K_TRIGGER, K_COUNT };

static const char *const kind_names[K_COUNT][2] = {
    {"reference", "the same bytes written straight to a socket"},
    {"setpoint", "FC06 rapid_rate -> rapid_rate"},
    {"trigger", "FC05 power_on -> power_on"},
};

static double now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double percentile(double *v, unsigned n, double p)
{
    qsort(v, n, sizeof(v[0]), cmp_double);
    unsigned i = (unsigned)(p * (n - 1) + 0.5);
    return v[i];
}

static double median(double *v, unsigned n)
{
    return percentile(v, n, 0.5);
}

static void die(const char *what)
{
    fprintf(stderr, "bench_commands: %s: %s\n", what, strerror(errno));
    exit(1);
}

static void no_delay(int fd)
{
    int one = 1;
    if (setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one)) < 0)
        die("TCP_NODELAY");
}

/* A loopback listener on a free port. */
static int listen_loopback(uint16_t *port)
{
    struct sockaddr_in sa = {.sin_family = AF_INET,
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof(sa);
    int fd = socket(AF_INET, SOCK_STREAM, 0);

    if (fd < 0 || bind(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0 || listen(fd, 8) < 0 ||
        getsockname(fd, (struct sockaddr *)&sa, &len) < 0)
        die("listen");
    *port = ntohs(sa.sin_port);
    return fd;
}

static int connect_loopback(uint16_t port)
{
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons(port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0 || connect(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0)
        die("connect");
    no_delay(fd);
    return fd;
}

static int accept_within(int listener, int timeout_ms)
{
    struct pollfd p = {.fd = listener, .events = POLLIN};
    if (poll(&p, 1, timeout_ms) != 1) {
        fprintf(stderr, "bench_commands: the gateway did not connect\n");
        exit(1);
    }
    int fd = accept(listener, NULL, NULL);
    if (fd < 0)
        die("accept");
    no_delay(fd);
    return fd;
}

static void send_all(int fd, const void *data, size_t size)
{
    const char *p = data;
    while (size > 0) {
        ssize_t n = send(fd, p, size, MSG_NOSIGNAL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            die("send");
        p += n;
        size -= (size_t)n;
    }
}

static void recv_exact(int fd, void *data, size_t size)
{
    char *p = data;
    while (size > 0) {
        ssize_t n = recv(fd, p, size, 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            if (n == 0)
                errno = ECONNRESET;
            die("recv");
        }
        p += n;
        size -= (size_t)n;
    }
}

/*
 * Reads one JSON object (whole reads: the peer writes objects one at a
 * time and waits for the answer) and returns when its last byte arrived.
 */
struct object_reader {
    char buf[4096];
    size_t size;
};

static double read_object(int fd, struct object_reader *r, int timeout_ms)
{
    int depth = 0;
    bool in_string = false, escaped = false, started = false;

    r->size = 0;
    for (;;) {
        if (timeout_ms >= 0) {
            struct pollfd p = {.fd = fd, .events = POLLIN};
            if (poll(&p, 1, timeout_ms) != 1)
                return -1;
        }
        ssize_t n = recv(fd, r->buf + r->size, sizeof(r->buf) - 1 - r->size, 0);
        double t = now_us();
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            if (n == 0)
                errno = ECONNRESET;
            die("recv (robot side)");
        }
        for (size_t i = r->size; i < r->size + (size_t)n; i++) {
            char c = r->buf[i];
            if (in_string) {
                if (escaped)
                    escaped = false;
                else if (c == '\\')
                    escaped = true;
                else if (c == '"')
                    in_string = false;
            } else if (c == '"') {
                in_string = true;
            } else if (c == '{') {
                depth++;
                started = true;
            } else if (c == '}') {
                depth--;
            }
        }
        r->size += (size_t)n;
        r->buf[r->size] = '\0';
        if (started && depth == 0)
            return t;
        if (r->size >= sizeof(r->buf) - 1) {
            fprintf(stderr, "bench_commands: object too large\n");
            exit(1);
        }
    }
}

static const char ok_reply[] = "{\"cmdName\":\"\",\"errorCode\":\"0\",\"errorMsg\":\"\"}";

/* Answers whatever the gateway sends until it has been quiet a while. */
static unsigned answer_until_quiet(int fd, int quiet_ms)
{
    struct object_reader r;
    unsigned n = 0;
    while (read_object(fd, &r, quiet_ms) >= 0) {
        send_all(fd, ok_reply, sizeof(ok_reply) - 1);
        n++;
    }
    return n;
}

/* ---- the gateway, in its own thread ---- */

struct gateway_thread {
    pthread_t thread;
    uv_loop_t loop;
    uv_async_t stop;
    struct gateway gw;
    struct gw_config cfg;
    int start_rc;
    pthread_mutex_t lock;
    pthread_cond_t started_cond;
    bool started;
};

static void on_gateway_closed(struct gateway *gw)
{
    (void)gw;
}

static void on_stop(uv_async_t *a)
{
    struct gateway_thread *g = a->data;
    gateway_close(&g->gw, on_gateway_closed);
    uv_close((uv_handle_t *)a, NULL);
}

static void *run_gateway(void *arg)
{
    struct gateway_thread *g = arg;

    uv_loop_init(&g->loop);
    uv_async_init(&g->loop, &g->stop, on_stop);
    g->stop.data = g;
    int rc = gateway_start(&g->loop, &g->gw, &g->cfg);
    pthread_mutex_lock(&g->lock);
    g->start_rc = rc;
    g->started = true;
    pthread_cond_signal(&g->started_cond);
    pthread_mutex_unlock(&g->lock);
    uv_run(&g->loop, UV_RUN_DEFAULT);
    uv_loop_close(&g->loop);
    return NULL;
}

/* ---- Modbus, as a PLC writes ---- */

struct plc {
    int fd;
    uint16_t tid;
};

static void modbus_request(struct plc *p, uint8_t fc, uint16_t address, uint16_t value,
                           uint8_t *rsp, size_t rsp_size)
{
    uint8_t req[12] = {(uint8_t)(p->tid >> 8), (uint8_t)p->tid, 0, 0, 0, 6, 1, fc,
                       (uint8_t)(address >> 8), (uint8_t)address, (uint8_t)(value >> 8),
                       (uint8_t)value};
    p->tid++;
    send_all(p->fd, req, sizeof(req));
    recv_exact(p->fd, rsp, 9);
    if (rsp[7] != fc) {
        fprintf(stderr, "bench_commands: function %u at %u answered with exception %u\n",
                fc, address, rsp[8]);
        exit(1);
    }
    recv_exact(p->fd, rsp + 9, rsp_size - 9);
}

/* Sends a write without waiting for its answer. */
static void modbus_send_write(struct plc *p, uint8_t fc, uint16_t address, uint16_t value)
{
    uint8_t req[12] = {(uint8_t)(p->tid >> 8), (uint8_t)p->tid, 0, 0, 0, 6, 1, fc,
                       (uint8_t)(address >> 8), (uint8_t)address, (uint8_t)(value >> 8),
                       (uint8_t)value};
    p->tid++;
    send_all(p->fd, req, sizeof(req));
}

static void modbus_write_answer(struct plc *p, uint8_t fc)
{
    uint8_t rsp[12];
    recv_exact(p->fd, rsp, 9);
    if (rsp[7] != fc) {
        fprintf(stderr, "bench_commands: write answered with exception %u\n", rsp[8]);
        exit(1);
    }
    recv_exact(p->fd, rsp + 9, 3);
}

static uint16_t read_input_register(struct plc *p, uint16_t address)
{
    uint8_t rsp[11];
    modbus_request(p, 4, address, 1, rsp, sizeof(rsp));
    return (uint16_t)(rsp[9] << 8 | rsp[10]);
}

/* Waits until the gateway has taken the robot's reply. */
static void wait_done(struct plc *p, uint16_t state_address)
{
    for (int i = 0; i < 100000; i++)
        if (read_input_register(p, state_address) == CMD_DONE)
            return;
    fprintf(stderr, "bench_commands: the command never completed\n");
    exit(1);
}

struct bench {
    struct plc plc;
    int robot; /* the gateway's command connection, robot side */
    int direct_tx, direct_rx;
    uint16_t rate_address, rate_state, trigger_address, trigger_state;
    char command[K_COUNT][512]; /* what each kind delivered last */
    uint16_t rate_value;
};

static double sample(struct bench *b, enum kind k)
{
    struct object_reader r;
    double t0, t1;

    switch (k) {
    case K_DIRECT: {
        const char *cmd = b->command[K_SETPOINT];
        t0 = now_us();
        send_all(b->direct_tx, cmd, strlen(cmd));
        t1 = read_object(b->direct_rx, &r, -1);
        break;
    }
    case K_SETPOINT:
        b->rate_value = b->rate_value == 500 ? 600 : 500;
        /* A poll first, as before the trigger's re-arm: the gateway is in
         * the same state for both kinds of write. */
        read_input_register(&b->plc, b->rate_state);
        t0 = now_us();
        modbus_send_write(&b->plc, 6, b->rate_address, b->rate_value);
        t1 = read_object(b->robot, &r, 5000);
        if (t1 < 0) {
            fprintf(stderr, "bench_commands: no command from the gateway\n");
            exit(1);
        }
        modbus_write_answer(&b->plc, 6);
        send_all(b->robot, ok_reply, sizeof(ok_reply) - 1);
        wait_done(&b->plc, b->rate_state);
        break;
    case K_TRIGGER: {
        uint8_t rsp[12];
        modbus_request(&b->plc, 5, b->trigger_address, 0x0000, rsp, sizeof(rsp)); /* re-arm */
        t0 = now_us();
        modbus_send_write(&b->plc, 5, b->trigger_address, 0xFF00);
        t1 = read_object(b->robot, &r, 5000);
        if (t1 < 0) {
            fprintf(stderr, "bench_commands: no command from the gateway\n");
            exit(1);
        }
        modbus_write_answer(&b->plc, 5);
        send_all(b->robot, ok_reply, sizeof(ok_reply) - 1);
        wait_done(&b->plc, b->trigger_state);
        break;
    }
    default:
        abort();
    }
    snprintf(b->command[k], sizeof(b->command[k]), "%.511s", r.buf);
    return t1 - t0;
}

static void socket_pair_tcp(int *tx, int *rx)
{
    uint16_t port;
    int l = listen_loopback(&port);
    *tx = connect_loopback(port);
    *rx = accept_within(l, 1000);
    close(l);
}

static const struct regmap_row *find_row(const struct regmap *map, enum regmap_source src,
                                         const char *path)
{
    const struct regmap_row *row = regmap_find_path(map, src, path);
    if (!row) {
        fprintf(stderr, "bench_commands: the register map has no row %s\n", path);
        exit(1);
    }
    return row;
}

int main(void)
{
    static struct gateway_thread g;
    static struct bench b;
    struct regmap map;
    char why[256];
    uint16_t status_port, command_port, modbus_port;

    log_set_level(LOG_LEVEL_ERR);
    if (regmap_init(&map))
        return 1;
    b.rate_address = find_row(&map, REGMAP_SRC_CMD, "rapid_rate.rate_value")->address;
    b.rate_state = find_row(&map, REGMAP_SRC_PATH, "result.rapid_rate.state")->address;
    b.trigger_address = find_row(&map, REGMAP_SRC_CMD, "power_on")->address;
    b.trigger_state = find_row(&map, REGMAP_SRC_PATH, "result.power_on.state")->address;
    regmap_free(&map);

    int status_listener = listen_loopback(&status_port);
    int command_listener = listen_loopback(&command_port);
    int modbus_listener = listen_loopback(&modbus_port);
    char text[16];
    config_defaults(&g.cfg);
    snprintf(text, sizeof(text), "%u", status_port);
    int rc = config_set(&g.cfg, "robot", "status_port", text, why, sizeof(why));
    snprintf(text, sizeof(text), "%u", command_port);
    rc = rc ? rc : config_set(&g.cfg, "robot", "command_port", text, why, sizeof(why));
    rc = rc ? rc : config_set(&g.cfg, "robot", "host", "127.0.0.1", why, sizeof(why));
    /* The status port stays silent: do not count that as a fault. */
    rc = rc ? rc : config_set(&g.cfg, "robot", "status_timeout_ms", "600000", why, sizeof(why));
    rc = rc ? rc : config_set(&g.cfg, "modbus", "idle_timeout_ms", "0", why, sizeof(why));
    if (rc) {
        fprintf(stderr, "bench_commands: configuration: %s\n", why);
        return 1;
    }
    g.cfg.modbus_listen_fd = modbus_listener;
    pthread_mutex_init(&g.lock, NULL);
    pthread_cond_init(&g.started_cond, NULL);
    if (pthread_create(&g.thread, NULL, run_gateway, &g))
        die("pthread_create");
    pthread_mutex_lock(&g.lock);
    while (!g.started)
        pthread_cond_wait(&g.started_cond, &g.lock);
    pthread_mutex_unlock(&g.lock);
    if (g.start_rc) {
        fprintf(stderr, "bench_commands: gateway_start: %s\n", strerror(-g.start_rc));
        return 1;
    }

    int status_fd = accept_within(status_listener, 5000);
    b.robot = accept_within(command_listener, 5000);
    /* What the gateway sends on connect: its handler, the information. */
    unsigned greeting = answer_until_quiet(b.robot, 300);
    b.plc.fd = connect_loopback(modbus_port);
    b.plc.tid = 1;
    socket_pair_tcp(&b.direct_tx, &b.direct_rx);

    /* Warm up every path; the first setpoint also gives the bytes the
     * reference sends. */
    for (int i = 0; i < WARMUP; i++)
        for (int k = K_COUNT - 1; k >= 0; k--)
            sample(&b, (enum kind)k);

    static double t[K_COUNT][SAMPLES];
    double p50[K_COUNT][ROUNDS], p99[K_COUNT][ROUNDS];
    double r50[K_COUNT][ROUNDS], r99[K_COUNT][ROUNDS];
    for (int round = 0; round < ROUNDS; round++) {
        for (int i = 0; i < SAMPLES; i++)
            for (int k = 0; k < K_COUNT; k++)
                t[k][i] = sample(&b, (enum kind)k);
        for (int k = 0; k < K_COUNT; k++) {
            p50[k][round] = percentile(t[k], SAMPLES, 0.50);
            p99[k][round] = percentile(t[k], SAMPLES, 0.99);
        }
        for (int k = 0; k < K_COUNT; k++) {
            r50[k][round] = p50[k][round] / p50[K_DIRECT][round];
            r99[k][round] = p99[k][round] / p99[K_DIRECT][round];
        }
    }

    printf("Command latency: a Modbus write sent by the client to the command's last byte "
           "at the robot's socket (loopback TCP), p50/p99 of %d per round, medians of %d "
           "rounds\n",
           SAMPLES, ROUNDS);
    for (int k = 0; k < K_COUNT; k++) {
        char label[96];
        snprintf(label, sizeof(label), "%-10s %s", kind_names[k][0], kind_names[k][1]);
        printf("  %-60s p50 %6.1f us  %5.2f   p99 %6.1f us  %5.2f\n", label,
               median(p50[k], ROUNDS), median(r50[k], ROUNDS), median(p99[k], ROUNDS),
               median(r99[k], ROUNDS));
    }
    printf("  (%zu-byte command %s; the gateway sent %u commands on connect, all answered)\n",
           strlen(b.command[K_SETPOINT]), b.command[K_SETPOINT], greeting);

    uv_async_send(&g.stop);
    pthread_join(g.thread, NULL);
    close(b.direct_tx);
    close(b.direct_rx);
    close(b.plc.fd);
    close(b.robot);
    close(status_fd);
    close(status_listener);
    close(command_listener);
    return 0;
}
