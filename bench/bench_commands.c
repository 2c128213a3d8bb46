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
#include "bench_proc.h"

#include <pthread.h>

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
    modbus_tcp_send(p->fd, p->tid++, fc, address, value);
    modbus_tcp_answer(p->fd, fc, rsp, rsp_size, "the gateway");
}

/* Sends a write without waiting for its answer. */
static void modbus_send_write(struct plc *p, uint8_t fc, uint16_t address, uint16_t value)
{
    modbus_tcp_send(p->fd, p->tid++, fc, address, value);
}

static void modbus_write_answer(struct plc *p, uint8_t fc)
{
    uint8_t rsp[12];
    modbus_tcp_answer(p->fd, fc, rsp, sizeof(rsp), "the gateway");
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
    die("the command never completed");
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
        if (t1 < 0)
            die("no command from the gateway");
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
        if (t1 < 0)
            die("no command from the gateway");
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
    *rx = accept_within(l, 1, "the reference's socket");
    close(l);
}

static const struct regmap_row *find_row(const struct regmap *map, enum regmap_source src,
                                         const char *path)
{
    const struct regmap_row *row = regmap_find_path(map, src, path);
    if (!row)
        die("the register map has no row %s", path);
    return row;
}

int main(void)
{
    static struct gateway_thread g;
    static struct bench b;
    struct regmap map;
    char why[256];
    uint16_t status_port, command_port, modbus_port;

    bench_begin("bench_commands");
    log_set_level(LOG_LEVEL_ERR);
    if (regmap_init(&map))
        die("regmap_init");
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
    if (rc)
        die("configuration: %s", why);
    g.cfg.modbus_listen_fd = modbus_listener;
    pthread_mutex_init(&g.lock, NULL);
    pthread_cond_init(&g.started_cond, NULL);
    if ((rc = pthread_create(&g.thread, NULL, run_gateway, &g)) != 0)
        die("pthread_create: %s", strerror(rc));
    pthread_mutex_lock(&g.lock);
    while (!g.started)
        pthread_cond_wait(&g.started_cond, &g.lock);
    pthread_mutex_unlock(&g.lock);
    if (g.start_rc)
        die("gateway_start: %s", strerror(-g.start_rc));

    int status_fd = accept_within(status_listener, 5, "the gateway's status link");
    b.robot = accept_within(command_listener, 5, "the gateway's command link");
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
    bench_end();
    return 0;
}
