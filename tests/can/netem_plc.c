/* SPDX-License-Identifier: MIT */
/*
 * A PLC for the netem VM test (tests/can/test_netem_vm.py), where there is
 * no Python: a libmodbus master that feeds the heartbeat (holding register
 * 0) from its own thread on the connection that owns the write side, as a
 * PLC's cyclic task does, while the main thread runs the test's schedule.
 *
 *   netem_plc trials PORTS N TRIAL_MS SETTLE_MS ON OFF
 *       N trials: the shell command ON (netem on), TRIAL_MS of heartbeats,
 *       OFF (netem off), SETTLE_MS; then per port the faults the gateway
 *       latched during the trial (input register 63's change) and whether
 *       the program ran at the trial's start and end, and a latched fault
 *       reset (coil 130); every trial starts with the program running
 *       (resumed, coil 109, if it is paused).
 *   netem_plc commands PORT N FIRST
 *       N commands through the exactly-once mailbox, one after the other:
 *       rapid_rate (code 20) with rate_value (FIRST + k) / 1000, each waited
 *       for (done_seq), its state and time printed.
 *
 * PORTS is a comma-separated list of Modbus ports on 127.0.0.1. Output
 * lines start with "@@" so that the test finds them on the console.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <modbus.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define MAX_PORTS 4
#define HEARTBEAT_PERIOD_MS 50
#define REG_HEARTBEAT 0
#define REG_MAILBOX 400
#define COIL_FAULT_RESET 130
#define COIL_RESUME 109
#define IR_FAULT 60
#define IR_FAULTS 63
#define IR_INTERP_STATE 102 /* 3 running */
#define INTERP_RUNNING 3
#define IR_MAILBOX_DONE 4601
#define IR_MAILBOX_STATE 4602
#define MAILBOX_RAPID_RATE 20

struct plc {
    int port;
    modbus_t *owner;   /* heartbeat and writes, under lock */
    modbus_t *monitor; /* reads */
    pthread_mutex_t lock;
    pthread_t thread;
    atomic_bool stop;
    atomic_uint writes;
    atomic_uint failures;
    atomic_uint max_gap_ms; /* longest time between two completed heartbeats */
};

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1000.0 + ts.tv_nsec / 1e6;
}

static void sleep_ms(double ms)
{
    if (ms <= 0)
        return;
    struct timespec ts = {(time_t)(ms / 1000), (long)((ms - (time_t)(ms / 1000) * 1000) * 1e6)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR) {
    }
}

static modbus_t *connect_to(int port)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    if (ctx == NULL)
        return NULL;
    modbus_set_response_timeout(ctx, 5, 0);
    modbus_set_slave(ctx, 1);
    for (int i = 0; i < 100; i++) {
        if (modbus_connect(ctx) == 0)
            return ctx;
        sleep_ms(100);
    }
    fprintf(stderr, "@@error connect %d: %s\n", port, modbus_strerror(errno));
    modbus_free(ctx);
    return NULL;
}

/* A failed request closes the connection as a PLC would and opens another. */
static void reconnect(modbus_t *ctx)
{
    modbus_close(ctx);
    sleep_ms(100);
    modbus_connect(ctx);
}

static void *heartbeat(void *arg)
{
    struct plc *p = arg;
    uint16_t value = 0;
    double last = now_ms();
    while (!atomic_load(&p->stop)) {
        double start = now_ms();
        pthread_mutex_lock(&p->lock);
        int rc = modbus_write_register(p->owner, REG_HEARTBEAT, ++value);
        if (rc != 1)
            reconnect(p->owner);
        pthread_mutex_unlock(&p->lock);
        double done = now_ms();
        if (rc == 1) {
            atomic_fetch_add(&p->writes, 1);
            unsigned gap = (unsigned)(done - last);
            if (gap > atomic_load(&p->max_gap_ms))
                atomic_store(&p->max_gap_ms, gap);
            last = done;
        } else {
            atomic_fetch_add(&p->failures, 1);
        }
        sleep_ms(HEARTBEAT_PERIOD_MS - (now_ms() - start));
    }
    return NULL;
}

static int read_ir(modbus_t *ctx, int address)
{
    uint16_t v;
    if (modbus_read_input_registers(ctx, address, 1, &v) != 1) {
        reconnect(ctx);
        if (modbus_read_input_registers(ctx, address, 1, &v) != 1)
            return -1;
    }
    return v;
}

/* Pulses a coil 0 -> 1 on the owner's connection. */
static int pulse(struct plc *p, int coil)
{
    pthread_mutex_lock(&p->lock);
    int rc = modbus_write_bit(p->owner, coil, 0) == 1 && modbus_write_bit(p->owner, coil, 1) == 1;
    pthread_mutex_unlock(&p->lock);
    return rc ? 0 : -1;
}

/* A latched fault reset and the program the gateway paused resumed. */
static void unlatch(struct plc *p)
{
    if (read_ir(p->monitor, IR_FAULT) == 0)
        return;
    pthread_mutex_lock(&p->lock);
    modbus_write_bit(p->owner, COIL_FAULT_RESET, 1);
    pthread_mutex_unlock(&p->lock);
    pulse(p, COIL_RESUME);
}

/* The program running (resumed if it is paused, by the gateway's policy or
 * by the robot's own network-exception handler): a trial measures the
 * policy only while the robot runs a program. */
static int ensure_running(struct plc *p)
{
    /* 6 s: a TCG guest on a busy host took more than 3 s once. */
    for (int i = 0; i < 60; i++) {
        if (read_ir(p->monitor, IR_INTERP_STATE) == INTERP_RUNNING)
            return 1;
        if (i % 10 == 0)
            pulse(p, COIL_RESUME);
        sleep_ms(100);
    }
    return 0;
}

static int start(struct plc *p, int port)
{
    memset(p, 0, sizeof(*p));
    p->port = port;
    pthread_mutex_init(&p->lock, NULL);
    p->owner = connect_to(port);
    p->monitor = connect_to(port);
    if (p->owner == NULL || p->monitor == NULL)
        return -1;
    return pthread_create(&p->thread, NULL, heartbeat, p) == 0 ? 0 : -1;
}

static void finish(struct plc *p)
{
    atomic_store(&p->stop, true);
    pthread_join(p->thread, NULL);
    modbus_close(p->owner);
    modbus_free(p->owner);
    modbus_close(p->monitor);
    modbus_free(p->monitor);
}

static int run_trials(struct plc *plcs, int n_plcs, int trials, int trial_ms, int settle_ms,
                      const char *on, const char *off)
{
    /* A heartbeat longer than any limit, then every trial starts unlatched. */
    sleep_ms(1500);
    int faults[MAX_PORTS];
    for (int k = 0; k < n_plcs; k++) {
        unlatch(&plcs[k]);
        sleep_ms(200);
        faults[k] = read_ir(plcs[k].monitor, IR_FAULTS);
    }
    for (int i = 0; i < trials; i++) {
        int running[MAX_PORTS];
        for (int k = 0; k < n_plcs; k++) {
            running[k] = ensure_running(&plcs[k]);
            faults[k] = read_ir(plcs[k].monitor, IR_FAULTS);
            atomic_store(&plcs[k].max_gap_ms, 0);
        }
        if (system(on) != 0)
            printf("@@error tc: %s\n", on);
        sleep_ms(trial_ms);
        if (system(off) != 0)
            printf("@@error tc: %s\n", off);
        sleep_ms(settle_ms);
        for (int k = 0; k < n_plcs; k++) {
            int now = read_ir(plcs[k].monitor, IR_FAULTS);
            int running_end = read_ir(plcs[k].monitor, IR_INTERP_STATE) == INTERP_RUNNING;
            printf("@@trial %d port %d trips %d max_heartbeat_gap_ms %u writes %u failures %u "
                   "running %d %d\n",
                   i, plcs[k].port, (now - faults[k]) & 0xFFFF,
                   atomic_load(&plcs[k].max_gap_ms), atomic_load(&plcs[k].writes),
                   atomic_load(&plcs[k].failures), running[k], running_end);
            unlatch(&plcs[k]);
        }
        fflush(stdout);
    }
    return 0;
}

static int run_commands(struct plc *p, int n, int first)
{
    sleep_ms(1500);
    unlatch(p);
    int seq = read_ir(p->monitor, IR_MAILBOX_DONE);
    if (seq < 0)
        return 1;
    for (int k = 0; k < n; k++) {
        uint16_t regs[26] = {0};
        float value = (float)(first + k) / 1000.0f;
        uint32_t bits;
        memcpy(&bits, &value, sizeof(bits));
        seq = (seq + 1) & 0xFFFF;
        regs[0] = MAILBOX_RAPID_RATE;
        regs[1] = (uint16_t)(bits >> 16);
        regs[2] = (uint16_t)bits;
        regs[25] = (uint16_t)seq;
        double t0 = now_ms();
        pthread_mutex_lock(&p->lock);
        int rc = modbus_write_registers(p->owner, REG_MAILBOX, 26, regs);
        pthread_mutex_unlock(&p->lock);
        if (rc != 26) {
            printf("@@cmd %d seq %d value %.3f write-failed %s\n", k, seq, value,
                   modbus_strerror(errno));
            continue;
        }
        int state = -1;
        while (now_ms() - t0 < 20000) {
            if (read_ir(p->monitor, IR_MAILBOX_DONE) == seq) {
                state = read_ir(p->monitor, IR_MAILBOX_STATE);
                break;
            }
            sleep_ms(20);
        }
        printf("@@cmd %d seq %d value %.3f state %d ms %.0f\n", k, seq, value, state,
               now_ms() - t0);
        fflush(stdout);
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 8 && strcmp(argv[1], "trials") == 0) {
        struct plc plcs[MAX_PORTS];
        int n = 0;
        char *ports = argv[2];
        for (char *tok = strtok(ports, ","); tok && n < MAX_PORTS; tok = strtok(NULL, ","))
            if (start(&plcs[n++], atoi(tok)) != 0)
                return 1;
        run_trials(plcs, n, atoi(argv[3]), atoi(argv[4]), atoi(argv[5]), argv[6], argv[7]);
        for (int k = 0; k < n; k++)
            finish(&plcs[k]);
        return 0;
    }
    if (argc == 5 && strcmp(argv[1], "commands") == 0) {
        struct plc p;
        if (start(&p, atoi(argv[2])) != 0)
            return 1;
        int rc = run_commands(&p, atoi(argv[3]), atoi(argv[4]));
        finish(&p);
        return rc;
    }
    fprintf(stderr, "usage: netem_plc trials PORTS N TRIAL_MS SETTLE_MS ON OFF\n"
                    "       netem_plc commands PORT N FIRST\n");
    return 2;
}
