/* SPDX-License-Identifier: MIT */
/*
 * plc_scan.c - the PLC library run as a PLC: matiec's C of plc/jaka.st and
 * tests/plc/cell.st, called once per 10 ms scan, its register image kept
 * in step with jakagw by a libmodbus master, the way a PLC's Modbus
 * client maps it.
 *
 *   plc_scan unit                          the blocks against a simulated image
 *   plc_scan case NAME PORT [SIM_PID]      one end-to-end case against jakagw
 *   plc_scan case NAME PORT SIM_PID split  with reads and writes on two connections
 *
 * Each scan (10 ms, on a monotonic clock):
 * 1. reads: input registers 0-14 (self-description, status sequence, start id), 16-19 (links, status
 *    age), 48-49 (heartbeat age), 60-89 (fault, owner), 100-115 (robot
 *    state, override), 200-235 (positions), 4000-4503 (every result
 *    block, in reads of 120), 4600-4676 (mailboxes), 5600-5603 (motion);
 *    discrete inputs 0-23 (links, flags) and 512-535 (outputs read back):
 *    15 requests (FC04, FC02);
 * 2. the program (matiec's C), once;
 * 3. writes, only what the program changed: each holding-register block
 *    whose registers changed, whole, in one FC16 (a block of one register,
 *    with FC06), the blocks being HR 0, 100, 200-231, 300-316, 320-335,
 *    340-359, 400-425; then each changed coil with FC05, in address order
 *    (parameters before their trigger).
 * A refused write (a Modbus exception) is logged and not repeated: the
 * block reads the outcome from the result registers, as the contract
 * says. A failed read or write closes the connection; the next scan
 * connects again (the image keeps its last values meanwhile).
 *
 * Prints "PASS name (figures)" or "FAIL name: why" per case.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <modbus.h>

#include "iec_std_lib.h"
#include "POUS.h"
#include "Cell.h"

#include <stdbool.h> /* after matiec's headers, which take the name bool */
#include <unistd.h>

#include "vendor_client.h"

TIME __CURRENT_TIME;
extern JAKACELL RES__MAIN;
extern JAKAEXAMPLE RES__EXAMPLE;
extern JAKAPICKPLACE RES__PICKPLACE;
#define P RES__MAIN
#define EX RES__EXAMPLE
void config_init__(void);
void config_run__(unsigned long tick);

/* A constant of plc/jaka_map.st, as the generated configuration holds it. */
#define K(name) (*__GET_GLOBAL_##name())

#define N_CO 240
#define N_DI 1648
#define N_IR 5604
#define N_HR 620
#define SCAN_MS 10
/* The task's period: 10 ms, or a vendor case's. */
static int scan_ms = SCAN_MS;
/* The image kept in step by a vendor's client model (vendor_client.c). */
static bool vendor_mode;

/* ---- time ---- */

static long long now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1000000LL + ts.tv_nsec / 1000;
}

/* The unit tests' clock is driven, not read: each scan is 10 ms. */
static bool simulated;
static long long sim_us;

static long long clock_us(void)
{
    return simulated ? sim_us : now_us();
}

/* ---- the Modbus client ---- */

struct range {
    int first, count;
};

struct client {
    const char *host;
    int port;
    bool split;         /* reads and writes on connections of their own */
    modbus_t *rd, *wr;
    long long down_until_us;
    uint16_t hr_sent[N_HR];
    uint8_t co_sent[N_CO];
    long writes, refused, reads, failures;
};

static struct client cl;

/* The image the client keeps in step: the cell's (tests/plc/cell.st), or
 * the example program's (plc/examples/jaka_cell.st) in case "example". */
static struct {
    uint8_t *co, *di;
    uint16_t *ir, *hr;
} img;
static unsigned long tick;
static long scans;
static double scan_work_max_ms, scan_work_sum_ms;
static long overruns; /* scans whose work took longer than the period */

static modbus_t *connect_one(void)
{
    modbus_t *ctx = modbus_new_tcp(cl.host, cl.port);
    if (!ctx)
        return NULL;
    modbus_set_response_timeout(ctx, 0, 500000);
    if (modbus_connect(ctx) != 0) {
        modbus_free(ctx);
        return NULL;
    }
    return ctx;
}

static void disconnect(void)
{
    if (cl.wr && cl.wr != cl.rd) {
        modbus_close(cl.wr);
        modbus_free(cl.wr);
    }
    if (cl.rd) {
        modbus_close(cl.rd);
        modbus_free(cl.rd);
    }
    cl.rd = cl.wr = NULL;
}

static bool connected(void)
{
    if (cl.rd)
        return true;
    if (now_us() < cl.down_until_us)
        return false;
    cl.rd = connect_one();
    if (!cl.rd)
        return false;
    cl.wr = cl.split ? connect_one() : cl.rd;
    if (!cl.wr) {
        disconnect();
        return false;
    }
    return true;
}

/* What the program reads: the map's self-description and diagnostics, the
 * fault, the robot's flags and positions, every result block, the
 * mailboxes' results, the motion state. */
static const struct range ir_reads[] = {
    {0, 15}, {16, 4}, {48, 2}, {60, 30}, {100, 16}, {200, 36},
    {4000, 120}, {4120, 120}, {4240, 120}, {4360, 120}, {4480, 24},
    {4600, 77}, {5600, 4},
};
static const struct range di_reads[] = {{0, 24}, {512, 24}};

static void lose_link(const char *what)
{
    cl.failures++;
    fprintf(stderr, "plc_scan: %s: %s: the connection is closed\n", what, modbus_strerror(errno));
    disconnect();
}

static void read_inputs(void)
{
    uint16_t regs[125];
    uint8_t bits[64];

    if (!connected())
        return;
    for (size_t i = 0; i < sizeof(ir_reads) / sizeof(ir_reads[0]); i++) {
        const struct range *r = &ir_reads[i];
        if (modbus_read_input_registers(cl.rd, r->first, r->count, regs) != r->count) {
            lose_link("read input registers");
            return;
        }
        for (int k = 0; k < r->count; k++)
            img.ir[r->first + k] = regs[k];
        cl.reads++;
    }
    for (size_t i = 0; i < sizeof(di_reads) / sizeof(di_reads[0]); i++) {
        const struct range *r = &di_reads[i];
        if (modbus_read_input_bits(cl.rd, r->first, r->count, bits) != r->count) {
            lose_link("read discrete inputs");
            return;
        }
        for (int k = 0; k < r->count; k++)
            img.di[r->first + k] = bits[k];
        cl.reads++;
    }
}

/* A refused write is an answer: logged, counted, not repeated. */
static bool write_answered(int rc, const char *what, int address)
{
    if (rc >= 0) {
        cl.writes++;
        return true;
    }
    if (errno >= MODBUS_ENOBASE && errno < MODBUS_ENOBASE + 20) {
        cl.refused++;
        fprintf(stderr, "plc_scan: %s %d refused: %s\n", what, address, modbus_strerror(errno));
        return true;
    }
    lose_link(what);
    return false;
}

static void write_outputs(void)
{
    /* The holding-register blocks a PLC's client would configure, one
     * request each: the heartbeat, the speed override, the program name,
     * each move's parameters, the mailbox. */
    const struct range writes[] = {
        {K(JAKA_HR_PLC_HEARTBEAT), 1},
        {K(JAKA_HR_RAPID_RATE), 1},
        {K(JAKA_HR_LOAD_PROGRAM_NAME), 32},
        {K(JAKA_HR_JOINT_MOVE_JOINT_1), K(JAKA_HR_JOINT_MOVE_RELATIVE) - K(JAKA_HR_JOINT_MOVE_JOINT_1) + 1},
        {K(JAKA_HR_END_MOVE_POSE_1), K(JAKA_HR_END_MOVE_ACCEL) + 2 - K(JAKA_HR_END_MOVE_POSE_1)},
        {K(JAKA_HR_MOVEL_POSE_1), K(JAKA_HR_MOVEL_TOL) + 2 - K(JAKA_HR_MOVEL_POSE_1)},
        {K(JAKA_HR_MAILBOX_CODE), K(JAKA_HR_MAILBOX_SEQ) - K(JAKA_HR_MAILBOX_CODE) + 1},
    };
    const uint16_t *hr = img.hr;
    const uint8_t *co = img.co;

    if (!connected())
        return;
    for (size_t i = 0; i < sizeof(writes) / sizeof(writes[0]); i++) {
        const struct range *w = &writes[i];
        if (memcmp(hr + w->first, cl.hr_sent + w->first, w->count * sizeof(uint16_t)) == 0)
            continue;
        int rc = w->count == 1 ? modbus_write_register(cl.wr, w->first, hr[w->first])
                               : modbus_write_registers(cl.wr, w->first, w->count, hr + w->first);
        if (!write_answered(rc, "write holding registers", w->first))
            return;
        memcpy(cl.hr_sent + w->first, hr + w->first, w->count * sizeof(uint16_t));
    }
    for (int a = 0; a < N_CO; a++) {
        if (!co[a] == !cl.co_sent[a])
            continue;
        if (!write_answered(modbus_write_bit(cl.wr, a, co[a] ? 1 : 0), "write coil", a))
            return;
        cl.co_sent[a] = co[a] ? 1 : 0;
    }
}

/* ---- the scan ---- */

static void set_time(void)
{
    long long us = clock_us();
    __CURRENT_TIME.tv_sec = us / 1000000;
    __CURRENT_TIME.tv_nsec = (us % 1000000) * 1000;
}

/* One scan: inputs, program, outputs; then the rest of the 10 ms. */
static void scan(void)
{
    long long start = now_us();
    if (vendor_mode)
        vc_publish_inputs();
    else if (!simulated)
        read_inputs();
    set_time();
    config_run__(tick++);
    if (vendor_mode)
        vc_run_requests(now_us());
    else if (!simulated)
        write_outputs();
    double work = (now_us() - start) / 1000.0;
    scans++;
    scan_work_sum_ms += work;
    if (work > scan_work_max_ms)
        scan_work_max_ms = work;
    if (work > scan_ms)
        overruns++;
    if (simulated) {
        sim_us += SCAN_MS * 1000;
        return;
    }
    long long next = start + scan_ms * 1000LL;
    long long left = next - now_us();
    if (left > 0) {
        struct timespec ts = {left / 1000000, (left % 1000000) * 1000};
        nanosleep(&ts, NULL);
    }
}

/* ---- checks ---- */

static char why[512];
static bool failed;

static void fail(const char *fmt, ...)
{
    va_list ap;
    if (failed)
        return;
    failed = true;
    va_start(ap, fmt);
    vsnprintf(why, sizeof(why), fmt, ap);
    va_end(ap);
}

/* Scans until 'cond' holds or 'ms' pass; fails naming 'what'. Returns the
 * time it took, in ms. */
#define SCAN_UNTIL(cond, ms, what)                                                  \
    ({                                                                              \
        long long t0_ = clock_us();                                                 \
        while (!failed && !(cond)) {                                                \
            if (clock_us() - t0_ > (long long)(ms) * 1000) {                        \
                fail("%s: not within %d ms (%s)", what, (int)(ms), #cond);          \
                break;                                                              \
            }                                                                       \
            scan();                                                                 \
        }                                                                           \
        (clock_us() - t0_) / 1000.0;                                                \
    })

#define IR(a) (P.INREGS.value.table[a])
#define HR(a) (P.HOLDREGS.value.table[a])
#define CO(a) (P.COILS.value.table[a])
#define DI(a) (P.INPUTS.value.table[a])

static float ir_f32(int address)
{
    bool low_first = IR(K(JAKA_IR_WORD_ORDER)) == 1;
    uint32_t hi = IR(address + (low_first ? 1 : 0)), lo = IR(address + (low_first ? 0 : 1));
    uint32_t bits = hi << 16 | lo;
    float f;
    memcpy(&f, &bits, sizeof(f));
    return f;
}

static float hr_f32(int address)
{
    bool low_first = IR(K(JAKA_IR_WORD_ORDER)) == 1;
    uint32_t hi = HR(address + (low_first ? 1 : 0)), lo = HR(address + (low_first ? 0 : 1));
    uint32_t bits = hi << 16 | lo;
    float f;
    memcpy(&f, &bits, sizeof(f));
    return f;
}

/* ---- unit tests: the blocks against a simulated image ---- */

static int unit_passed, unit_failed;

static void reset_program(void)
{
    config_init__();
    tick = 0;
    failed = false;
    why[0] = '\0';
}

static void report(const char *name, const char *figures)
{
    if (failed) {
        unit_failed++;
        printf("FAIL %s: %s\n", name, why);
    } else {
        unit_passed++;
        printf("PASS %s%s%s%s\n", name, figures[0] ? " (" : "", figures, figures[0] ? ")" : "");
    }
    fflush(stdout);
}

/* The gateway's side of one trigger: the count moves on, the state is s,
 * the text (a reason) at the result's error_msg. */
static void gateway_answers(int result, int state, const char *text)
{
    IR(result + 23)++;
    IR(result) = state;
    for (int i = 0; i < 20; i++) {
        int c0 = text && (int)strlen(text) > 2 * i ? text[2 * i] : 0;
        int c1 = text && (int)strlen(text) > 2 * i + 1 ? text[2 * i + 1] : 0;
        IR(result + 3 + i) = (c0 & 0xFF) << 8 | (c1 & 0xFF);
    }
}

static void fill_map_header(void)
{
    IR(K(JAKA_IR_MAP_MAGIC)) = K(JAKA_MAP_MAGIC_VALUE);
    IR(K(JAKA_IR_MAP_VERSION)) = K(JAKA_MAP_VERSION_VALUE);
    IR(K(JAKA_IR_PROBE_U32)) = K(JAKA_PROBE_U32_VALUE) >> 16;
    IR(K(JAKA_IR_PROBE_U32) + 1) = K(JAKA_PROBE_U32_VALUE) & 0xFFFF;
    IR(K(JAKA_IR_MAP_CRC)) = K(JAKA_MAP_CRC_VALUE) >> 16;
    IR(K(JAKA_IR_MAP_CRC) + 1) = K(JAKA_MAP_CRC_VALUE) & 0xFFFF;
    DI(K(JAKA_DI_STATUS_FRESH)) = 1;
}

static void unit_real_bits(void)
{
    /* -0.0 reads as 0.0: ST cannot tell them apart without the bits. */
    const float values[] = {0.0f, 1.0f, -1234.5f, 0.1f, 3.4e38f, 1e-40f, 123456.789f};
    char figures[64];
    reset_program();
    for (size_t i = 0; i < sizeof(values) / sizeof(values[0]); i++) {
        uint32_t want;
        memcpy(&want, &values[i], sizeof(want));
        P.REALPROBE.value = values[i];
        scan();
        if (P.REALPROBEBITS.value != want)
            fail("JAKA_RealBits(%g) = 0x%08X, expected 0x%08X", values[i], P.REALPROBEBITS.value, want);
    }
    snprintf(figures, sizeof(figures), "%zu values bit-exact", sizeof(values) / sizeof(values[0]));
    report("unit_real_bits", figures);
}

/* The client brings a new status document: status_sequence moves on. */
static void refresh(void)
{
    IR(K(JAKA_IR_STATUS_SEQUENCE))++;
    scan();
}

static void unit_link(void)
{
    char figures[160];
    reset_program();
    fill_map_header();
    scan();
    uint16_t hb = HR(K(JAKA_HR_PLC_HEARTBEAT));
    refresh();
    if (HR(K(JAKA_HR_PLC_HEARTBEAT)) == hb)
        fail("the heartbeat did not change from one scan to the next");
    if (P.LINK.VALID.value)
        fail("Valid after one refresh: a client reading its ranges in turn may not have read them all");
    refresh();
    if (!P.LINK.VALID.value || !P.LINK.MAPCHECKED.value || !P.LINK.MAPEXACT.value)
        fail("not Valid (or not MapExact) with the map's magic, version, probe and CRC in place");
    /* A client refreshing every 600 ms keeps it Valid (60 s of it). */
    bool dropped = false;
    for (int i = 0; i < 100 && !failed; i++) {
        for (int k = 0; k < 60; k++) {
            scan();
            dropped = dropped || !P.LINK.VALID.value;
        }
        IR(K(JAKA_IR_STATUS_SEQUENCE))++;
    }
    if (dropped)
        fail("Valid dropped with the image refreshed every 600 ms");
    /* The image stops changing: stale after StaleTime (3 s). */
    double t = SCAN_UNTIL(!P.LINK.VALID.value, 4000, "Valid falls on a frozen image");
    if (!failed && (t < 2900 || P.LINK.ERRORID.value != 5))
        fail("stale after %.0f ms with ErrorID %u (expected ~3000 ms, 5)", t, P.LINK.ERRORID.value);
    refresh();
    refresh();
    if (!P.LINK.VALID.value)
        fail("not Valid again when the image moves again");
    snprintf(figures, sizeof(figures), "heartbeat each scan, Valid after two refreshes, 60 s at a 600 ms "
             "refresh, stale at %.0f ms, CRC, version, word order, no map", t);
    /* Another CRC (a gateway with rows added): Valid, not MapExact. */
    reset_program();
    fill_map_header();
    IR(K(JAKA_IR_MAP_CRC))++;
    refresh();
    refresh();
    if (!P.LINK.VALID.value || P.LINK.MAPEXACT.value)
        fail("another map CRC: Valid %d MapExact %d", P.LINK.VALID.value, P.LINK.MAPEXACT.value);
    /* A wrong version: ErrorID 4, checked once at start. */
    reset_program();
    fill_map_header();
    IR(K(JAKA_IR_MAP_VERSION)) = K(JAKA_MAP_VERSION_VALUE) + 1;
    scan();
    if (!P.LINK.ERROR.value || P.LINK.ERRORID.value != 4 || P.LINK.VALID.value)
        fail("another map version: Error %d ErrorID %u", P.LINK.ERROR.value, P.LINK.ERRORID.value);
    /* Low word first announced but the probe reads high word first. */
    reset_program();
    fill_map_header();
    IR(K(JAKA_IR_WORD_ORDER)) = 1;
    scan();
    if (P.LINK.ERRORID.value != 4)
        fail("word order 1 with a high-first probe: ErrorID %u, expected 4", P.LINK.ERRORID.value);
    /* No map within CheckTime (3 s). */
    reset_program();
    SCAN_UNTIL(P.LINK.ERROR.value, 3500, "no map: Error");
    report("unit_link", figures);
}

/* JAKA_Stop holds the stop while Execute stays TRUE: its trigger stays 1
 * (nothing more is sent), a move is refused (16#0007) with its trigger
 * untouched; Execute falls, the trigger goes to 0 and moves run again. */
static void unit_stop_holds(void)
{
    int coil = K(JAKA_CO_CMD_STOP_PROGRAM), res = K(JAKA_IR_RESULT_STOP_PROGRAM_STATE);
    reset_program();
    fill_map_header();
    DI(K(JAKA_DI_INPOS)) = 1;
    P.HALT.EXECUTE.value = 1;
    scan();
    gateway_answers(res, 2, NULL);
    scan();
    scan();
    if (!P.HALT.DONE.value || !CO(coil))
        fail("stop: Done %d, trigger %d (held at 1 while Execute)", P.HALT.DONE.value, CO(coil));
    P.MOVEJ.EXECUTE.value = 1;
    scan();
    if (!P.MOVEJ.ERROR.value || P.MOVEJ.ERRORID.value != 0x0007 || CO(K(JAKA_CO_CMD_JOINT_MOVE)))
        fail("a move while the stop holds: Error %d ErrorID 0x%04X trigger %d", P.MOVEJ.ERROR.value,
             P.MOVEJ.ERRORID.value, CO(K(JAKA_CO_CMD_JOINT_MOVE)));
    P.MOVEJ.EXECUTE.value = 0;
    P.HALT.EXECUTE.value = 0;
    scan();
    if (CO(coil))
        fail("the stop's trigger still 1 after Execute fell");
    P.MOVEJ.EXECUTE.value = 1;
    scan();
    if (!CO(K(JAKA_CO_CMD_JOINT_MOVE)) || P.MOVEJ.ERROR.value)
        fail("a move after the stop released: trigger %d Error %d", CO(K(JAKA_CO_CMD_JOINT_MOVE)),
             P.MOVEJ.ERROR.value);
    report("unit_stop_holds", "trigger held while Execute, a move refused 16#0007, released on the fall");
}

/* A trigger block: an edge starts exactly one request (the trigger coil
 * set once), Done only after the count moved, the coil back to 0, the
 * outputs held while Execute and one scan after. */
static void unit_trigger_handshake(void)
{
    int coil = K(JAKA_CO_CMD_STOP_PROGRAM), res = K(JAKA_IR_RESULT_STOP_PROGRAM_STATE);
    reset_program();
    fill_map_header();
    IR(res) = 2; /* a stale "done" from before: must not pass */
    P.PROG.COMMAND.value = 5; /* stop_program */
    P.PROG.EXECUTE.value = 1;
    scan();
    if (!CO(coil) || !P.PROG.BUSY.value)
        fail("Execute: trigger coil %d, Busy %d", CO(coil), P.PROG.BUSY.value);
    for (int i = 0; i < 20; i++)
        scan();
    if (P.PROG.DONE.value)
        fail("Done on a stale result, before the count changed");
    gateway_answers(res, 1, NULL); /* pending */
    scan();
    if (P.PROG.DONE.value || !CO(coil))
        fail("Done while pending");
    IR(res) = 2;
    scan();
    scan();
    if (!P.PROG.DONE.value || P.PROG.BUSY.value || CO(coil))
        fail("after done: Done %d Busy %d coil %d", P.PROG.DONE.value, P.PROG.BUSY.value, CO(coil));
    for (int i = 0; i < 10; i++)
        scan();
    if (!P.PROG.DONE.value)
        fail("Done not held while Execute is TRUE");
    P.PROG.EXECUTE.value = 0;
    scan();
    if (P.PROG.DONE.value)
        fail("Done held after Execute fell");
    /* Execute held TRUE does not start a second request. */
    uint16_t count = IR(res + 23);
    P.PROG.EXECUTE.value = 1;
    scan();
    gateway_answers(res, 2, NULL);
    scan();
    scan();
    P.PROG.EXECUTE.value = 1;
    for (int i = 0; i < 10; i++)
        scan();
    if (CO(coil))
        fail("a held Execute set the trigger again");
    if (IR(res + 23) != (uint16_t)(count + 1))
        fail("count moved %d times", IR(res + 23) - count);
    /* Execute falls while busy: Done shows for exactly one scan. */
    P.PROG.EXECUTE.value = 0;
    scan();
    P.PROG.EXECUTE.value = 1;
    scan();
    P.PROG.EXECUTE.value = 0;
    scan();
    gateway_answers(res, 2, NULL);
    int shown = 0;
    for (int i = 0; i < 10; i++) {
        scan();
        shown += P.PROG.DONE.value;
    }
    if (shown != 1)
        fail("Execute fell while busy: Done shown %d scans, expected 1", shown);
    report("unit_trigger_handshake", "one request per edge, stale result ignored, Done held, one scan after a fall");
}

static void unit_timeouts(void)
{
    int res = K(JAKA_IR_RESULT_STOP_PROGRAM_STATE);
    char figures[96];
    reset_program();
    fill_map_header();
    P.PROG.COMMAND.value = 5;
    P.PROG.TIMEOUT.value = (TIME){1, 0};
    P.PROG.EXECUTE.value = 1;
    double t = SCAN_UNTIL(P.PROG.ERROR.value, 2000, "no count change: Error");
    if (P.PROG.ERRORID.value != 1 || CO(K(JAKA_CO_CMD_STOP_PROGRAM)))
        fail("no count change: ErrorID %u coil %d", P.PROG.ERRORID.value, CO(K(JAKA_CO_CMD_STOP_PROGRAM)));
    P.PROG.EXECUTE.value = 0;
    scan();
    P.PROG.EXECUTE.value = 1;
    scan();
    gateway_answers(res, 1, NULL);
    double t2 = SCAN_UNTIL(P.PROG.ERROR.value, 2000, "pending for ever: Error");
    if (P.PROG.ERRORID.value != 2)
        fail("pending: ErrorID %u, expected 2", P.PROG.ERRORID.value);
    snprintf(figures, sizeof(figures), "no result: ErrorID 1 after %.0f ms; pending: 2 after %.0f ms", t, t2);
    report("unit_timeouts", figures);
}

/* Every refusal the gateway gives, as its result state and reason. */
static void unit_refusals(void)
{
    static const struct {
        int state;
        const char *reason;
        unsigned id;
    } cases[] = {
        {7, "heartbeat not started", 0x0201},
        {7, "trigger still 1: write 0 first", 0x0202},
        {7, "target not written", 0x0203},
        {7, "fault 1 latched: reset it first", 0x0204},
        {7, "PLC heartbeat lost: fault 1 latched", 0x0204},
        {7, "no Modbus client: fault 2 latched", 0x0204},
        {7, "motion enable dropped: fault 3 latched", 0x0204},
        {7, "gateway loop stalled: fault 4 latched", 0x0204},
        {7, "motion enable is 0", 0x0205},
        {7, "motion is off: [commands] motion = true enables it", 0x0206},
        {7, "not the write owner: 127.0.0.1:40122", 0x0207},
        {7, "busy: the previous one is pending", 0x0208},
        {7, "write code, args and seq in one write", 0x0209},
        {7, "something new", 0x0107},
        {3, "robot says no", 0x0103},
        {4, "reply timeout", 0x0104},
        {5, "link lost", 0x0104},
        {6, "invalid parameters", 0x0106},
        {8, "not sent: the command link is down", 0x0108},
    };
    int res = K(JAKA_IR_RESULT_JOINT_MOVE_STATE);
    reset_program();
    fill_map_header();
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]) && !failed; i++) {
        P.MOVEJ.EXECUTE.value = 1;
        scan();
        gateway_answers(res, cases[i].state, cases[i].reason);
        scan();
        scan();
        if (!P.MOVEJ.ERROR.value || P.MOVEJ.ERRORID.value != cases[i].id || P.MOVEJ.DONE.value)
            fail("state %d \"%s\": Error %d ErrorID 0x%04X, expected 0x%04X", cases[i].state,
                 cases[i].reason, P.MOVEJ.ERROR.value, P.MOVEJ.ERRORID.value, cases[i].id);
        P.MOVEJ.EXECUTE.value = 0;
        scan();
        if (P.MOVEJ.ERROR.value)
            fail("Error held after Execute fell");
    }
    /* The mailbox's own refusal. */
    P.MAILBOX.EXECUTE.value = 1;
    scan();
    IR(K(JAKA_IR_MAILBOX_COUNT))++;
    IR(K(JAKA_IR_MAILBOX_STATE)) = 7;
    const char *r = "write code, args and seq in one write";
    for (int i = 0; i < 20; i++)
        IR(K(JAKA_IR_MAILBOX_ERROR_MSG) + i) = (i * 2 < (int)strlen(r) ? r[2 * i] << 8 : 0) |
                                                (i * 2 + 1 < (int)strlen(r) ? r[2 * i + 1] : 0);
    scan();
    if (P.MAILBOX.ERRORID.value != 0x0209)
        fail("mailbox refusal: ErrorID 0x%04X", P.MAILBOX.ERRORID.value);
    report("unit_refusals", "19 result states and reasons, each its ErrorID");
}

/* A move: parameters in the image before the trigger, in the gateway's
 * word order; Done only on arrival of this move (motion count moved). */
/* JAKA_MoveJoint started, accepted (its result at IR 'res'), and its move
 * at once in motion state 'state', one scan later. */
static void move_ends_in(int res, int state)
{
    P.MOVEJ.EXECUTE.value = 1;
    scan();
    gateway_answers(res, 2, NULL);
    scan();
    IR(K(JAKA_IR_MOTION_COUNT))++;
    IR(K(JAKA_IR_MOTION_STATE)) = state;
    scan();
}

static void unit_move(void)
{
    int res = K(JAKA_IR_RESULT_JOINT_MOVE_STATE);
    reset_program();
    fill_map_header();
    IR(K(JAKA_IR_MOTION_STATE)) = 2; /* the previous move arrived */
    for (int lw = 0; lw < 2 && !failed; lw++) {
        IR(K(JAKA_IR_WORD_ORDER)) = lw;
        for (int i = 0; i < 6; i++)
            P.MOVEJ.POSITION.value.table[i] = 10.5f * (i + 1);
        P.MOVEJ.SPEED.value = 12.5f;
        P.MOVEJ.RELATIVE.value = 1;
        P.MOVEJ.EXECUTE.value = 1;
        scan();
        for (int i = 0; i < 6; i++)
            if (hr_f32(K(JAKA_HR_JOINT_MOVE_JOINT_1) + 2 * i) != 10.5f * (i + 1))
                fail("word order %d: joint %d reads %g", lw, i + 1, hr_f32(K(JAKA_HR_JOINT_MOVE_JOINT_1) + 2 * i));
        if (hr_f32(K(JAKA_HR_JOINT_MOVE_SPEED)) != 12.5f || HR(K(JAKA_HR_JOINT_MOVE_RELATIVE)) != 1)
            fail("speed or relative flag not in the image");
        if (!CO(K(JAKA_CO_CMD_JOINT_MOVE)))
            fail("trigger not set with the parameters");
        gateway_answers(res, 2, NULL); /* accepted */
        for (int i = 0; i < 5; i++)
            scan();
        if (P.MOVEJ.DONE.value)
            fail("Done on the previous move's arrival (motion count unchanged)");
        IR(K(JAKA_IR_MOTION_COUNT))++;
        IR(K(JAKA_IR_MOTION_STATE)) = 1;
        scan();
        if (P.MOVEJ.DONE.value || !P.MOVEJ.BUSY.value)
            fail("Done while moving");
        IR(K(JAKA_IR_MOTION_STATE)) = 2;
        scan();
        if (!P.MOVEJ.DONE.value)
            fail("not Done on arrival");
        P.MOVEJ.EXECUTE.value = 0;
        scan();
    }
    /* Stopped before arriving: CommandAborted, not Error. */
    move_ends_in(res, 3);
    scan();
    if (!P.MOVEJ.COMMANDABORTED.value || P.MOVEJ.ERROR.value || P.MOVEJ.DONE.value)
        fail("stopped: CommandAborted %d Error %d", P.MOVEJ.COMMANDABORTED.value, P.MOVEJ.ERROR.value);
    P.MOVEJ.EXECUTE.value = 0;
    scan();
    /* Not arrived in time (4): Error 0x0302. */
    move_ends_in(res, 4);
    if (!P.MOVEJ.ERROR.value || P.MOVEJ.ERRORID.value != 0x0302)
        fail("motion state 4: ErrorID 0x%04X", P.MOVEJ.ERRORID.value);
    P.MOVEJ.EXECUTE.value = 0;
    scan();
    /* A new edge while the move runs: the old one ends (CommandAborted
     * that call), stop_program, the arm stops, then the new move's
     * trigger with the new target; Done on the new move's arrival. */
    int stop = K(JAKA_IR_RESULT_STOP_PROGRAM_STATE);
    P.MOVEJ.POSITION.value.table[0] = 10.0f;
    P.MOVEJ.EXECUTE.value = 1;
    scan();
    gateway_answers(res, 2, NULL);
    scan();
    IR(K(JAKA_IR_MOTION_COUNT))++;
    IR(K(JAKA_IR_MOTION_STATE)) = 1;
    scan();
    if (!P.MOVEJ.ACTIVE.value || !P.MOVEJ.BUSY.value)
        fail("moving: Active %d Busy %d", P.MOVEJ.ACTIVE.value, P.MOVEJ.BUSY.value);
    P.MOVEJ.EXECUTE.value = 0;
    scan();
    P.MOVEJ.POSITION.value.table[0] = 20.0f;
    P.MOVEJ.EXECUTE.value = 1;
    scan();
    if (!P.MOVEJ.COMMANDABORTED.value || !P.MOVEJ.BUSY.value || !CO(K(JAKA_CO_CMD_STOP_PROGRAM)))
        fail("re-triggered: CommandAborted %d Busy %d stop trigger %d", P.MOVEJ.COMMANDABORTED.value,
             P.MOVEJ.BUSY.value, CO(K(JAKA_CO_CMD_STOP_PROGRAM)));
    if (hr_f32(K(JAKA_HR_JOINT_MOVE_JOINT_1)) != 20.0f)
        fail("re-triggered: the new target not in the image");
    scan();
    if (P.MOVEJ.COMMANDABORTED.value)
        fail("CommandAborted of the replaced move held past its call");
    gateway_answers(stop, 2, NULL);
    scan();
    scan();
    if (CO(K(JAKA_CO_CMD_JOINT_MOVE)))
        fail("the new move triggered while the arm still moves");
    IR(K(JAKA_IR_MOTION_STATE)) = 3; /* stopped */
    scan();
    scan();
    scan();
    if (!CO(K(JAKA_CO_CMD_JOINT_MOVE)) || P.MOVEJ.DONE.value || P.MOVEJ.COMMANDABORTED.value)
        fail("after the stop: trigger %d Done %d CommandAborted %d", CO(K(JAKA_CO_CMD_JOINT_MOVE)),
             P.MOVEJ.DONE.value, P.MOVEJ.COMMANDABORTED.value);
    gateway_answers(res, 2, NULL);
    scan();
    scan();
    IR(K(JAKA_IR_MOTION_COUNT))++;
    IR(K(JAKA_IR_MOTION_STATE)) = 2;
    scan();
    if (!P.MOVEJ.DONE.value || P.MOVEJ.ACTIVE.value)
        fail("the new move arrived: Done %d Active %d", P.MOVEJ.DONE.value, P.MOVEJ.ACTIVE.value);
    P.MOVEJ.EXECUTE.value = 0;
    scan();
    report("unit_move", "both word orders, Done only on this move's arrival, aborted, not arrived, "
           "Active, a new edge replaces the running move");
}

static void unit_other_blocks(void)
{
    reset_program();
    fill_map_header();
    /* Power: power_on, then enable_robot, then the status. */
    P.POWER.EXECUTE.value = 1;
    scan();
    if (!CO(K(JAKA_CO_CMD_POWER_ON)) || CO(K(JAKA_CO_CMD_ENABLE_ROBOT)))
        fail("power: power_on first");
    gateway_answers(K(JAKA_IR_RESULT_POWER_ON_STATE), 2, NULL);
    scan();
    scan();
    if (!CO(K(JAKA_CO_CMD_ENABLE_ROBOT)) || CO(K(JAKA_CO_CMD_POWER_ON)))
        fail("power: enable_robot second, power_on's coil back to 0");
    gateway_answers(K(JAKA_IR_RESULT_ENABLE_ROBOT_STATE), 2, NULL);
    scan();
    scan();
    if (P.POWER.DONE.value)
        fail("power: Done before the status shows it");
    DI(K(JAKA_DI_POWERED_ON)) = 1;
    DI(K(JAKA_DI_ENABLED)) = 1;
    scan();
    if (!P.POWER.DONE.value)
        fail("power: not Done");
    /* Program: the name's text, two bytes a register; a bad command. */
    memcpy(P.PROG.PROGRAMNAME.value.body, "Demo_1", 6);
    P.PROG.PROGRAMNAME.value.len = 6;
    P.PROG.COMMAND.value = 1;
    P.PROG.EXECUTE.value = 1;
    scan();
    int n = K(JAKA_HR_LOAD_PROGRAM_NAME);
    if (HR(n) != ('D' << 8 | 'e') || HR(n + 1) != ('m' << 8 | 'o') || HR(n + 2) != ('_' << 8 | '1') || HR(n + 3))
        fail("program name registers %04X %04X %04X %04X", HR(n), HR(n + 1), HR(n + 2), HR(n + 3));
    P.PROG.EXECUTE.value = 0;
    gateway_answers(K(JAKA_IR_RESULT_LOAD_PROGRAM_STATE), 2, NULL);
    scan();
    scan();
    P.PROG.COMMAND.value = 9;
    P.PROG.EXECUTE.value = 1;
    scan();
    if (!P.PROG.ERROR.value || P.PROG.ERRORID.value != 6)
        fail("program command 9: ErrorID %u", P.PROG.ERRORID.value);
    /* Speed override: per mille; Done on the status's read-back, not on
     * a stale result; an error state after the request is its error. */
    IR(K(JAKA_IR_RESULT_RAPID_RATE_STATE)) = 2;
    P.OVERRIDE.FACTOR.value = 0.5f;
    P.OVERRIDE.EXECUTE.value = 1;
    scan();
    if (HR(K(JAKA_HR_RAPID_RATE)) != 500)
        fail("override: HR reads %u", HR(K(JAKA_HR_RAPID_RATE)));
    scan();
    scan();
    if (P.OVERRIDE.DONE.value)
        fail("override: Done before the status shows it");
    IR(K(JAKA_IR_RAPIDRATE_PERMILLE)) = 500;
    scan();
    if (!P.OVERRIDE.DONE.value)
        fail("override: not Done on the read-back");
    P.OVERRIDE.EXECUTE.value = 0;
    scan();
    P.OVERRIDE.FACTOR.value = 0.2f;
    P.OVERRIDE.EXECUTE.value = 1;
    scan();
    gateway_answers(K(JAKA_IR_RESULT_RAPID_RATE_STATE), 7, "not the write owner: 10.0.0.9:502");
    scan();
    if (!P.OVERRIDE.ERROR.value || P.OVERRIDE.ERRORID.value != 0x0207)
        fail("override refused: Error %d ErrorID 0x%04X", P.OVERRIDE.ERROR.value, P.OVERRIDE.ERRORID.value);
    P.OVERRIDE.EXECUTE.value = 0;
    P.OVERRIDE.FACTOR.value = 1.5f;
    scan();
    P.OVERRIDE.EXECUTE.value = 1;
    scan();
    if (P.OVERRIDE.ERRORID.value != 6)
        fail("override 1.5: ErrorID %u", P.OVERRIDE.ERRORID.value);
    /* Output: the coil, then Done on the read-back. */
    P.DIGOUT.INDEX.value = 3;
    P.DIGOUT.VALUE.value = 1;
    P.DIGOUT.EXECUTE.value = 1;
    scan();
    if (!CO(K(JAKA_CO_CABINET_DO_1) + 2))
        fail("output 3: coil not set");
    scan();
    scan();
    if (P.DIGOUT.DONE.value)
        fail("output: Done before the read-back");
    DI(K(JAKA_DI_DOUT_1) + 2) = 1;
    scan();
    if (!P.DIGOUT.DONE.value)
        fail("output: not Done on the read-back");
    P.DIGOUT.EXECUTE.value = 0;
    P.DIGOUT.INDEX.value = 17;
    scan();
    P.DIGOUT.EXECUTE.value = 1;
    scan();
    if (P.DIGOUT.ERRORID.value != 6)
        fail("output 17: ErrorID %u", P.DIGOUT.ERRORID.value);
    /* Reset: motion enable held, fault_reset 1 then 0, Done at fault 0. */
    IR(K(JAKA_IR_FAULT)) = 1;
    P.RESET.MOTIONENABLE.value = 1;
    P.RESET.EXECUTE.value = 1;
    scan();
    if (!CO(K(JAKA_CO_MOTION_ENABLE)) || !CO(K(JAKA_CO_FAULT_RESET)))
        fail("reset: coils");
    double held = SCAN_UNTIL(!CO(K(JAKA_CO_FAULT_RESET)), 1000, "reset: fault_reset back to 0");
    if (!failed && held < 290)
        fail("reset: fault_reset held %.0f ms, expected PulseTime (300 ms): a client writing every "
             "100 ms could miss it", held);
    IR(K(JAKA_IR_FAULT)) = 0;
    scan();
    if (!P.RESET.DONE.value)
        fail("reset: not Done at fault 0");
    /* Mailbox: code, arguments, sequence in the image together. */
    IR(K(JAKA_IR_MAILBOX_ACK_SEQ)) = 41;
    P.MAILBOX.CODE.value = 20;
    P.MAILBOX.ARGS.value.table[0] = 0.25f;
    P.MAILBOX.EXECUTE.value = 1;
    scan();
    if (HR(K(JAKA_HR_MAILBOX_CODE)) != 20 || hr_f32(K(JAKA_HR_MAILBOX_ARG_1)) != 0.25f ||
        HR(K(JAKA_HR_MAILBOX_SEQ)) != 42)
        fail("mailbox: code %u arg %g seq %u", HR(K(JAKA_HR_MAILBOX_CODE)),
             hr_f32(K(JAKA_HR_MAILBOX_ARG_1)), HR(K(JAKA_HR_MAILBOX_SEQ)));
    IR(K(JAKA_IR_MAILBOX_COUNT))++;
    IR(K(JAKA_IR_MAILBOX_STATE)) = 2;
    IR(K(JAKA_IR_MAILBOX_DONE_SEQ)) = 41; /* an older one: not ours */
    scan();
    if (P.MAILBOX.DONE.value)
        fail("mailbox: Done on another sequence");
    IR(K(JAKA_IR_MAILBOX_DONE_SEQ)) = 42;
    scan();
    if (!P.MAILBOX.DONE.value)
        fail("mailbox: not Done");
    P.MAILBOX.EXECUTE.value = 0;
    scan();
    /* A mailbox move (joint_move, code 30): Done on arrival, not when done. */
    IR(K(JAKA_IR_MAILBOX_ACK_SEQ)) = 42;
    P.MAILBOX.CODE.value = 30;
    P.MAILBOX.EXECUTE.value = 1;
    scan();
    IR(K(JAKA_IR_MAILBOX_COUNT))++;
    IR(K(JAKA_IR_MAILBOX_STATE)) = 2;
    IR(K(JAKA_IR_MAILBOX_DONE_SEQ)) = 43;
    for (int i = 0; i < 5; i++)
        scan();
    if (P.MAILBOX.DONE.value || !P.MAILBOX.BUSY.value)
        fail("mailbox move: Done %d Busy %d before it arrived", P.MAILBOX.DONE.value, P.MAILBOX.BUSY.value);
    IR(K(JAKA_IR_MOTION_COUNT))++;
    IR(K(JAKA_IR_MOTION_STATE)) = 2;
    scan();
    if (!P.MAILBOX.DONE.value)
        fail("mailbox move: not Done on arrival");
    P.MAILBOX.EXECUTE.value = 0;
    scan();
    /* An output the image holds while the robot reports otherwise (an
     * HMI set it): the other level for PulseTime, then the value. */
    P.DIGOUT.EXECUTE.value = 0;
    scan();
    P.DIGOUT.INDEX.value = 3;
    P.DIGOUT.VALUE.value = 1;
    DI(K(JAKA_DI_DOUT_1) + 2) = 0;
    P.DIGOUT.EXECUTE.value = 1;
    scan();
    if (CO(K(JAKA_CO_CABINET_DO_1) + 2) || !P.DIGOUT.BUSY.value)
        fail("output set elsewhere: coil %d (expected the other level first)", CO(K(JAKA_CO_CABINET_DO_1) + 2));
    double nudge = SCAN_UNTIL(CO(K(JAKA_CO_CABINET_DO_1) + 2), 1000, "output: the value after the pulse");
    DI(K(JAKA_DI_DOUT_1) + 2) = 1;
    scan();
    if (!P.DIGOUT.DONE.value)
        fail("output set elsewhere: not Done on the read-back");
    P.DIGOUT.EXECUTE.value = 0;
    scan();
    /* The override likewise, one per mille off first. */
    P.OVERRIDE.EXECUTE.value = 0;
    scan();
    P.OVERRIDE.FACTOR.value = 0.5f;
    P.OVERRIDE.EXECUTE.value = 1;
    scan();
    P.OVERRIDE.EXECUTE.value = 0;
    IR(K(JAKA_IR_RAPIDRATE_PERMILLE)) = 500;
    scan();
    scan();
    IR(K(JAKA_IR_RAPIDRATE_PERMILLE)) = 700; /* an HMI changed it */
    P.OVERRIDE.EXECUTE.value = 1;
    scan();
    if (HR(K(JAKA_HR_RAPID_RATE)) != 499)
        fail("override changed elsewhere: HR %u first, expected 499", HR(K(JAKA_HR_RAPID_RATE)));
    SCAN_UNTIL(HR(K(JAKA_HR_RAPID_RATE)) == 500, 1000, "override: the value after the pulse");
    IR(K(JAKA_IR_RAPIDRATE_PERMILLE)) = 500;
    scan();
    if (!P.OVERRIDE.DONE.value)
        fail("override changed elsewhere: not Done on the read-back");
    char figures[160];
    snprintf(figures, sizeof(figures), "power, program name and command, override, output, reset, "
             "mailbox, a mailbox move Done on arrival, output and override set elsewhere (pulse %.0f ms)",
             nudge);
    report("unit_other_blocks", figures);
}

static int run_unit(void)
{
    simulated = true;
    sim_us = 1000000;
    unit_real_bits();
    unit_link();
    unit_trigger_handshake();
    unit_stop_holds();
    unit_timeouts();
    unit_refusals();
    unit_move();
    unit_other_blocks();
    printf("%d passed, %d failed\n", unit_passed, unit_failed);
    return unit_failed ? 1 : 0;
}

/* ---- end-to-end cases against jakagw and jakasim ---- */

static pid_t sim_pid;
static char figures[400];

static void fig(const char *fmt, ...)
{
    va_list ap;
    size_t n = strlen(figures);
    va_start(ap, fmt);
    vsnprintf(figures + n, sizeof(figures) - n, fmt, ap);
    va_end(ap);
}

/* Execute one block until Done (or fails); returns ms from Execute. */
#define RUN_BLOCK(blk, ms, what)                                                         \
    ({                                                                                   \
        P.blk.EXECUTE.value = 1;                                                         \
        double t_ = SCAN_UNTIL(P.blk.DONE.value || P.blk.ERROR.value, ms, what);         \
        if (!failed && P.blk.ERROR.value)                                                \
            fail("%s: Error, ErrorID 0x%04X", what, P.blk.ERRORID.value);                \
        P.blk.EXECUTE.value = 0;                                                         \
        scan();                                                                          \
        t_;                                                                              \
    })

static void link_up(void)
{
    double t = SCAN_UNTIL(P.LINK.VALID.value, 5000, "JAKA_Link Valid");
    if (!failed && !P.LINK.MAPEXACT.value)
        fail("JAKA_Link: the gateway's map CRC is not plc/jaka_map.st's");
    fig("%sValid after %.0f ms", figures[0] ? ", " : "", t);
}

static void start_up(void)
{
    link_up();
    P.RESET.MOTIONENABLE.value = 1;
    double t = RUN_BLOCK(RESET, 3000, "JAKA_Reset");
    fig(", reset %.0f ms", t);
    P.POWER.SWITCHON.value = 1;
    t = RUN_BLOCK(POWER, 10000, "JAKA_Power on");
    fig(", power %.0f ms", t);
}

/* A move and its figures: Done only with motion state 2 and the arm in
 * position, never before; the time from Execute to Done. */
static void move_and_check(const char *name, int which)
{
    long long t0 = clock_us();
    bool done_seen_early = false;
    switch (which) {
    case 0: P.MOVEJ.EXECUTE.value = 1; break;
    case 1: P.MOVEL.EXECUTE.value = 1; break;
    default: P.MOVET.EXECUTE.value = 1; break;
    }
    for (;;) {
        scan();
        bool done = which == 0 ? P.MOVEJ.DONE.value : which == 1 ? P.MOVEL.DONE.value : P.MOVET.DONE.value;
        bool err = which == 0 ? P.MOVEJ.ERROR.value || P.MOVEJ.COMMANDABORTED.value
                 : which == 1 ? P.MOVEL.ERROR.value || P.MOVEL.COMMANDABORTED.value
                              : P.MOVET.ERROR.value || P.MOVET.COMMANDABORTED.value;
        if (done) {
            if (IR(K(JAKA_IR_MOTION_STATE)) != 2 || !DI(K(JAKA_DI_INPOS)))
                done_seen_early = true;
            break;
        }
        if (err) {
            fail("%s: Error, ErrorID 0x%04X", name,
                 which == 0 ? P.MOVEJ.ERRORID.value : which == 1 ? P.MOVEL.ERRORID.value : P.MOVET.ERRORID.value);
            return;
        }
        if (clock_us() - t0 > 30000000) {
            fail("%s: not Done within 30 s", name);
            return;
        }
    }
    if (done_seen_early)
        fail("%s: Done with motion state %u, in position %d", name, IR(K(JAKA_IR_MOTION_STATE)),
             DI(K(JAKA_DI_INPOS)));
    fig(", %s Done %.0f ms after Execute", name, (clock_us() - t0) / 1000.0);
    P.MOVEJ.EXECUTE.value = P.MOVEL.EXECUTE.value = P.MOVET.EXECUTE.value = 0;
    scan();
}

static void case_startup(void)
{
    start_up();
    P.OVERRIDE.FACTOR.value = 0.8f;
    double t = RUN_BLOCK(OVERRIDE, 5000, "JAKA_SpeedOverride");
    fig(", override %.0f ms", t);
    memcpy(P.PROG.PROGRAMNAME.value.body, "plc_demo", 8);
    P.PROG.PROGRAMNAME.value.len = 8;
    P.PROG.COMMAND.value = 1;
    t = RUN_BLOCK(PROG, 5000, "JAKA_Program load");
    P.PROG.COMMAND.value = 2;
    t += RUN_BLOCK(PROG, 5000, "JAKA_Program play");
    fig(", load+play %.0f ms", t);
    SCAN_UNTIL(P.LINK.PROGRAMSTATE.value == 3, 3000, "program running (interp_state 3)");
    P.DIGOUT.INDEX.value = 1;
    P.DIGOUT.VALUE.value = 1;
    t = RUN_BLOCK(DIGOUT, 5000, "JAKA_Output 1");
    fig(", output %.0f ms", t);
    t = RUN_BLOCK(HALT, 5000, "JAKA_Stop");
    fig(", stop %.0f ms", t);
}

/* The arm at Done is where the move was to take it. */
static void check_arrived(const char *name, int address, float want, float tolerance)
{
    float at = ir_f32(address);
    if (!failed && fabsf(at - want) > tolerance)
        fail("%s: Done at %.3f, the target is %.3f", name, at, want);
}

static void case_moves(void)
{
    start_up();
    int j1 = K(JAKA_IR_JOINT_ACTUAL_POSITION_1), x = K(JAKA_IR_ACTUAL_POSITION_0);
    float from = ir_f32(j1);
    P.MOVEJ.POSITION.value.table[0] = 10.0f;
    P.MOVEJ.RELATIVE.value = 1;
    P.MOVEJ.SPEED.value = 30.0f;
    move_and_check("joint", 0);
    check_arrived("joint", j1, from + 10.0f, 0.1f);
    for (int i = 0; i < 6; i++)
        P.MOVEL.POSE.value.table[i] = 0;
    from = ir_f32(x + 4);
    P.MOVEL.POSE.value.table[2] = 20.0f;
    P.MOVEL.RELATIVE.value = 1;
    P.MOVEL.SPEED.value = 100.0f;
    if (!failed)
        move_and_check("linear", 1);
    check_arrived("linear (z)", x + 4, from + 20.0f, 1.0f);
    for (int i = 0; i < 6; i++)
        P.MOVET.POSE.value.table[i] = ir_f32(x + 2 * i);
    P.MOVET.POSE.value.table[0] += 15.0f;
    P.MOVET.SPEED.value = 30.0f;
    if (!failed)
        move_and_check("tcp", 2);
    check_arrived("tcp (x)", x, P.MOVET.POSE.value.table[0], 1.0f);
}

/* A long joint move, interrupted by 'interrupt'; CommandAborted expected. */
static void interrupted_move(const char *what, void (*interrupt)(void))
{
    start_up();
    P.MOVEJ.POSITION.value.table[0] = 90.0f;
    P.MOVEJ.RELATIVE.value = 1;
    P.MOVEJ.SPEED.value = 20.0f;
    P.MOVEJ.EXECUTE.value = 1;
    SCAN_UNTIL(IR(K(JAKA_IR_MOTION_STATE)) == 1 && !DI(K(JAKA_DI_INPOS)), 5000, "the arm moving");
    for (int i = 0; i < 50; i++)
        scan();
    if (failed)
        return;
    float j1 = ir_f32(K(JAKA_IR_JOINT_ACTUAL_POSITION_1));
    long long t0 = clock_us();
    interrupt();
    double t = SCAN_UNTIL(P.MOVEJ.COMMANDABORTED.value || P.MOVEJ.ERROR.value || P.MOVEJ.DONE.value,
                          8000, "the move's end");
    if (!failed && !P.MOVEJ.COMMANDABORTED.value)
        fail("%s: CommandAborted %d Error %d (0x%04X) Done %d", what, P.MOVEJ.COMMANDABORTED.value,
             P.MOVEJ.ERROR.value, P.MOVEJ.ERRORID.value, P.MOVEJ.DONE.value);
    double stopped = SCAN_UNTIL(DI(K(JAKA_DI_INPOS)), 8000, "the arm in position (stopped)");
    float j1_end = ir_f32(K(JAKA_IR_JOINT_ACTUAL_POSITION_1));
    fig(", %s: CommandAborted %.0f ms after, arm stopped %.0f ms after, joint 1 travelled %.1f deg after it",
        what, t, (clock_us() - t0) / 1000.0, fabsf(j1_end - j1));
    (void)stopped;
    P.MOVEJ.EXECUTE.value = 0;
    scan();
}

static void stop_heartbeat(void) { P.LINK.FEED.value = 0; }

/* What JAKA_Link reports after the interruption: 'fault' latched (or the
 * e-stop flag when fault is 0). */
static void check_reported(const char *what, unsigned fault)
{
    if (failed)
        return;
    if (fault == 0) {
        SCAN_UNTIL(P.LINK.EMERGENCYSTOP.value, 2000, "JAKA_Link EmergencyStop");
        fig(", JAKA_Link EmergencyStop");
        return;
    }
    SCAN_UNTIL(IR(K(JAKA_IR_FAULT)) == fault, 3000, "the fault latched");
    scan();
    if (P.LINK.FAULT.value != fault)
        fail("%s: JAKA_Link.Fault %u, expected %u", what, P.LINK.FAULT.value, fault);
    fig(", fault %u, reaction %u", fault, IR(K(JAKA_IR_FAULT_REACTION)));
}
static void drop_motion_enable(void) { P.RESET.MOTIONENABLE.value = 0; }
static void press_estop(void)
{
    if (sim_pid > 0)
        kill(sim_pid, SIGRTMIN);
    else
        fail("no jakasim pid for the e-stop");
}

static void case_heartbeat_loss(void)
{
    interrupted_move("heartbeat stopped", stop_heartbeat);
    check_reported("heartbeat stopped", 1);
}

static void case_motion_enable(void)
{
    interrupted_move("motion enable dropped", drop_motion_enable);
    check_reported("motion enable dropped", 3);
}

static void case_estop(void)
{
    interrupted_move("e-stop", press_estop);
    check_reported("e-stop", 0);
}

static void case_fault_reset(void)
{
    interrupted_move("motion enable dropped", drop_motion_enable);
    if (failed)
        return;
    SCAN_UNTIL(P.LINK.FAULT.value != 0, 3000, "a fault latched");
    /* A move before the reset: the gateway refuses it, the block says why. */
    P.RESET.MOTIONENABLE.value = 1;
    P.MOVEJ.POSITION.value.table[0] = 1.0f;
    P.MOVEJ.EXECUTE.value = 1;
    SCAN_UNTIL(P.MOVEJ.ERROR.value || P.MOVEJ.DONE.value, 3000, "a move under a latched fault");
    if (!failed && P.MOVEJ.ERRORID.value != 0x0204)
        fail("a move under a latched fault: Done %d ErrorID 0x%04X, expected 0x0204",
             P.MOVEJ.DONE.value, P.MOVEJ.ERRORID.value);
    fig(", a move before the reset refused (16#0204)");
    P.MOVEJ.EXECUTE.value = 0;
    scan();
    double t = RUN_BLOCK(RESET, 3000, "JAKA_Reset after the fault");
    if (!failed && P.LINK.FAULT.value != 0)
        fail("fault %u after the reset", P.LINK.FAULT.value);
    fig(", reset Done %.0f ms", t);
    P.MOVEJ.POSITION.value.table[0] = -5.0f;
    P.MOVEJ.SPEED.value = 30.0f;
    if (!failed)
        move_and_check("joint after reset", 0);
}

/* The PLC restarts while its trigger coil is 1 at the gateway: the new
 * program (all zero) on a new connection; its first request meets the
 * coil left at 1 and is refused (ErrorID 16#0202), nothing sent; the
 * retry runs. */
static void case_restart(void)
{
    start_up();
    P.PROG.COMMAND.value = 5; /* stop_program: harmless, always answered */
    P.PROG.EXECUTE.value = 1;
    scan(); /* the trigger is written with this scan */
    if (!cl.co_sent[K(JAKA_CO_CMD_STOP_PROGRAM)])
        fail("the trigger was not written");
    disconnect();
    config_init__(); /* the PLC restarts: every variable at its initial value */
    memset(cl.hr_sent, 0, sizeof(cl.hr_sent));
    memset(cl.co_sent, 0, sizeof(cl.co_sent));
    link_up();
    P.PROG.COMMAND.value = 5;
    P.PROG.EXECUTE.value = 1;
    SCAN_UNTIL(P.PROG.DONE.value || P.PROG.ERROR.value, 5000, "the first request after the restart");
    if (!failed && (!P.PROG.ERROR.value || P.PROG.ERRORID.value != 0x0202))
        fail("after a restart with the trigger left at 1: Done %d ErrorID 0x%04X, expected 0x0202",
             P.PROG.DONE.value, P.PROG.ERRORID.value);
    P.PROG.EXECUTE.value = 0;
    scan();
    double t = RUN_BLOCK(PROG, 5000, "the retry");
    fig(", refused with 16#0202 then Done %.0f ms", t);
}

/* Refusals from the real gateway, as ErrorIDs: a move before the first
 * heartbeat (16#0201). */
static void case_refusals(void)
{
    P.LINK.FEED.value = 0;
    start_up();
    P.MOVEJ.POSITION.value.table[0] = 1.0f;
    P.MOVEJ.RELATIVE.value = 1;
    P.MOVEJ.EXECUTE.value = 1;
    SCAN_UNTIL(P.MOVEJ.ERROR.value || P.MOVEJ.DONE.value, 3000, "a move before the heartbeat");
    if (!failed && P.MOVEJ.ERRORID.value != 0x0201)
        fail("a move before the heartbeat: Done %d ErrorID 0x%04X, expected 0x0201",
             P.MOVEJ.DONE.value, P.MOVEJ.ERRORID.value);
    P.MOVEJ.EXECUTE.value = 0;
    P.LINK.FEED.value = 1;
    scan();
    SCAN_UNTIL(P.LINK.HEARTBEATSTATE.value == 1, 3000, "the heartbeat seen running");
    P.MOVEJ.EXECUTE.value = 1;
    SCAN_UNTIL(P.MOVEJ.DONE.value || P.MOVEJ.ERROR.value, 5000, "the move with the heartbeat");
    if (!failed && !P.MOVEJ.DONE.value)
        fail("the move with the heartbeat: ErrorID 0x%04X", P.MOVEJ.ERRORID.value);
    fig(", a move before the heartbeat refused (16#0201), Done once it runs");
}

/* A new Execute edge while a long move runs: the old one ends with
 * CommandAborted, the arm stops (stop_program) and goes to the new target;
 * Done there, and only there. */
static void case_retrigger(void)
{
    start_up();
    int j1 = K(JAKA_IR_JOINT_ACTUAL_POSITION_1);
    float from = ir_f32(j1);
    for (int i = 0; i < 6; i++)
        P.MOVEJ.POSITION.value.table[i] = ir_f32(j1 + 2 * i);
    P.MOVEJ.RELATIVE.value = 0;
    P.MOVEJ.SPEED.value = 20.0f;
    P.MOVEJ.POSITION.value.table[0] = from + 60.0f;
    P.MOVEJ.EXECUTE.value = 1;
    SCAN_UNTIL(P.MOVEJ.ACTIVE.value && IR(K(JAKA_IR_MOTION_STATE)) == 1, 5000, "the first move under way");
    for (int i = 0; i < 30; i++)
        scan();
    float at = ir_f32(j1);
    P.MOVEJ.EXECUTE.value = 0;
    scan();
    float target = from - 10.0f;
    P.MOVEJ.POSITION.value.table[0] = target;
    P.MOVEJ.SPEED.value = 40.0f;
    P.MOVEJ.EXECUTE.value = 1;
    scan();
    if (!failed && !P.MOVEJ.COMMANDABORTED.value)
        fail("the new edge: no CommandAborted for the old move");
    long long t0 = clock_us();
    scan(); /* CommandAborted was the old move's, for the call of the edge */
    if (!failed && P.MOVEJ.COMMANDABORTED.value)
        fail("CommandAborted held past the call of the new edge");
    double t = SCAN_UNTIL(P.MOVEJ.DONE.value || P.MOVEJ.ERROR.value || P.MOVEJ.COMMANDABORTED.value,
                          15000, "the new move's end");
    if (!failed && !P.MOVEJ.DONE.value)
        fail("the new move: Error %d (0x%04X) CommandAborted %d", P.MOVEJ.ERROR.value,
             P.MOVEJ.ERRORID.value, P.MOVEJ.COMMANDABORTED.value);
    check_arrived("the new move", j1, target, 0.1f);
    fig(", joint 1 at %.1f of %.1f when re-triggered, Done at %.2f (target %.2f) %.0f ms later", at - from,
        60.0, ir_f32(j1) - from, target - from, (clock_us() - t0) / 1000.0);
    (void)t;
    P.MOVEJ.EXECUTE.value = 0;
    scan();
}

/* JAKA_Command with a move (joint_move, code 30): Done only on arrival. */
static void case_mailbox_move(void)
{
    start_up();
    int j1 = K(JAKA_IR_JOINT_ACTUAL_POSITION_1);
    float from = ir_f32(j1);
    P.MAILBOX.CODE.value = 30;
    memset(P.MAILBOX.ARGS.value.table, 0, sizeof(P.MAILBOX.ARGS.value.table));
    P.MAILBOX.ARGS.value.table[0] = 20.0f; /* joint 1 +20 deg */
    P.MAILBOX.ARGS.value.table[6] = 40.0f; /* speed */
    P.MAILBOX.ARGS.value.table[7] = 100.0f; /* accel */
    P.MAILBOX.ARGS.value.table[8] = 1.0f; /* relative */
    P.MAILBOX.EXECUTE.value = 1;
    long long t0 = clock_us();
    bool early = false;
    while (!failed && !P.MAILBOX.DONE.value && !P.MAILBOX.ERROR.value) {
        if (clock_us() - t0 > 10000000) {
            fail("the mailbox move: not Done within 10 s");
            break;
        }
        scan();
        if (P.MAILBOX.DONE.value && (IR(K(JAKA_IR_MOTION_STATE)) != 2 || fabsf(ir_f32(j1) - from - 20.0f) > 0.1f))
            early = true;
    }
    if (!failed && P.MAILBOX.ERROR.value)
        fail("the mailbox move: ErrorID 0x%04X", P.MAILBOX.ERRORID.value);
    if (!failed && early)
        fail("the mailbox move Done at joint 1 %+.2f deg, motion state %u: before it arrived",
             ir_f32(j1) - from, IR(K(JAKA_IR_MOTION_STATE)));
    fig(", the mailbox's joint_move Done %.0f ms after Execute, on arrival (joint 1 %+.2f deg)",
        (clock_us() - t0) / 1000.0, ir_f32(j1) - from);
    P.MAILBOX.EXECUTE.value = 0;
    scan();
}

static void case_link_lost(void)
{
    link_up();
    disconnect();
    cl.down_until_us = now_us() + 4000000;
    double t = SCAN_UNTIL(!P.LINK.VALID.value, 4000, "Valid falls with the link");
    if (!failed && P.LINK.ERRORID.value != 5)
        fail("link lost: ErrorID %u, expected 5 (stale)", P.LINK.ERRORID.value);
    double back = SCAN_UNTIL(P.LINK.VALID.value, 5000, "Valid again");
    fig(", not Valid %.0f ms after the link was cut, Valid %.0f ms after that", t, back);
}

static void case_mailbox(void)
{
    start_up();
    P.MAILBOX.CODE.value = 20; /* rapid_rate */
    P.MAILBOX.ARGS.value.table[0] = 0.37f;
    double t = RUN_BLOCK(MAILBOX, 5000, "JAKA_Command rapid_rate");
    for (int i = 0; i < 30; i++)
        scan();
    fig(", mailbox Done %.0f ms (sequence %u)", t, P.MAILBOX.SEQUENCE.value);
}

/* The example program as it ships: the operator's start, then its whole
 * sequence (power, override, load, play, output, stop, a move) with no
 * alarm; jakasim's log is checked by the driver. */
static void case_example(void)
{
    img.co = EX.COILS.value.table;
    img.di = EX.INPUTS.value.table;
    img.ir = EX.INREGS.value.table;
    img.hr = EX.HOLDREGS.value.table;
    double t = SCAN_UNTIL(EX.LINK.VALID.value, 5000, "the example's JAKA_Link Valid");
    fig("Valid after %.0f ms", t);
    EX.STARTBUTTON.value = 1;
    SCAN_UNTIL(EX.SEQUENCE.value != 0, 1000, "the sequence started");
    EX.STARTBUTTON.value = 0;
    t = SCAN_UNTIL(EX.SEQUENCE.value == 0 || EX.ALARM.value, 20000, "the sequence's end");
    if (!failed && EX.ALARM.value)
        fail("the example's alarm, ErrorID 0x%04X, at step %d", EX.ALARMID.value, EX.SEQUENCE.value);
    fig(", the whole sequence in %.0f ms", t);
}

static int run_case(const char *name, const char *port, const char *pid, bool split)
{
    static const struct {
        const char *name;
        void (*run)(void);
    } cases[] = {
        {"startup", case_startup},           {"moves", case_moves},
        {"heartbeat_loss", case_heartbeat_loss}, {"motion_enable", case_motion_enable},
        {"fault_reset", case_fault_reset},   {"restart", case_restart},
        {"link_lost", case_link_lost},       {"estop", case_estop},
        {"mailbox", case_mailbox},           {"two_connections", case_startup},
        {"refusals", case_refusals},         {"example", case_example},
        {"retrigger", case_retrigger},       {"mailbox_move", case_mailbox_move},
    };
    cl.host = "127.0.0.1";
    cl.port = atoi(port);
    cl.split = split;
    sim_pid = pid ? atoi(pid) : 0;
    config_init__();
    img.co = P.COILS.value.table;
    img.di = P.INPUTS.value.table;
    img.ir = P.INREGS.value.table;
    img.hr = P.HOLDREGS.value.table;
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        if (strcmp(cases[i].name, name) != 0)
            continue;
        cases[i].run();
        /* Let the last writes (trigger back to 0) go out. */
        for (int k = 0; k < 5; k++)
            scan();
        disconnect();
        if (failed)
            printf("FAIL %s: %s\n", name, why);
        else
            printf("PASS %s (%s; scan work mean %.2f ms, max %.2f ms, %ld overruns in %ld scans of "
                   "%d ms; %ld reads, %ld writes, %ld refused)\n",
                   name, figures[0] == ',' ? figures + 2 : figures, scan_work_sum_ms / scans,
                   scan_work_max_ms, overruns, scans, SCAN_MS, cl.reads, cl.writes, cl.refused);
        return failed ? 1 : 0;
    }
    fprintf(stderr, "plc_scan: no case %s\n", name);
    return 2;
}

/* ---- a cell in a vendor's client model ---- */

#define PP RES__PICKPLACE

static void bind_image(uint8_t *co, uint8_t *di, uint16_t *ir, uint16_t *hr)
{
    struct vc_image image = {.co = co, .di = di, .ir = ir, .hr = hr};
    vc_bind(&image);
}

/* The shipped example's whole sequence, from its start button. */
static void vendor_example(void)
{
    bind_image(EX.COILS.value.table, EX.INPUTS.value.table, EX.INREGS.value.table,
               EX.HOLDREGS.value.table);
    double t = SCAN_UNTIL(EX.LINK.VALID.value, 20000, "the example's JAKA_Link Valid");
    fig("example Valid after %.0f ms", t);
    EX.STARTBUTTON.value = 1;
    SCAN_UNTIL(EX.SEQUENCE.value != 0, 2000, "the example's sequence started");
    EX.STARTBUTTON.value = 0;
    t = SCAN_UNTIL(EX.SEQUENCE.value == 0 || EX.ALARM.value, 40000, "the example's sequence's end");
    if (!failed && EX.ALARM.value)
        fail("the example's alarm, ErrorID 0x%04X", EX.ALARMID.value);
    fig(", its sequence in %.0f ms", t);
}

/* Pick and place until 'cycles' loops are done, or an alarm. */
static double vendor_cycles(int cycles, int limit_ms)
{
    PP.PAUSEAT.value = cycles; /* the cell stops there, no move begun after */
    PP.START.value = 1;
    double t = SCAN_UNTIL((PP.CYCLES.value >= cycles && PP.SEQUENCE.value == 0) || PP.ALARM.value,
                          limit_ms, "the pick-and-place cycles");
    PP.START.value = 0;
    scan();
    if (!failed && PP.ALARM.value)
        fail("pick-and-place alarm after %d cycles: ErrorID 0x%04X at step %d", PP.CYCLES.value,
             PP.ALARMID.value, PP.ALARMSTEP.value);
    return t;
}

/* The operator's reset, when a fault is latched (a restarted gateway). */
static void vendor_reset(void)
{
    PP.RESETBUTTON.value = 1;
    SCAN_UNTIL(PP.RESET.DONE.value || PP.RESET.ERROR.value, 5000, "the operator's reset");
    PP.RESETBUTTON.value = 0;
    scan();
}

/* ---- an HMI beside the PLC ---- */

/* An operator panel on the PLC's host: a Modbus client of its own (its own
 * connection), writing between the PLC's scans, as a panel writes whenever
 * its operator touches it. The gateway runs with owner = host for it. */
static modbus_t *hmi;

static bool hmi_connect(int port)
{
    hmi = modbus_new_tcp("127.0.0.1", port);
    if (!hmi)
        return false;
    modbus_set_response_timeout(hmi, 1, 0);
    if (modbus_connect(hmi) != 0) {
        modbus_free(hmi);
        hmi = NULL;
        return false;
    }
    return true;
}

static void hmi_close(void)
{
    if (!hmi)
        return;
    modbus_close(hmi);
    modbus_free(hmi);
    hmi = NULL;
}

/* The HMI writes output 'index' (1-16); the PLC scans until its image
 * shows the robot reporting it. */
static void hmi_sets_output(int index, int value)
{
    if (failed)
        return;
    if (modbus_write_bit(hmi, K(JAKA_CO_CABINET_DO_1) + index - 1, value) != 1) {
        fail("the HMI's write of output %d: %s", index, modbus_strerror(errno));
        return;
    }
    SCAN_UNTIL(DI(K(JAKA_DI_DOUT_1) + index - 1) == value, 5000, "the HMI's output level at the robot");
}

static void hmi_sets_override(int permille)
{
    if (failed)
        return;
    if (modbus_write_register(hmi, K(JAKA_HR_RAPID_RATE), permille) != 1) {
        fail("the HMI's write of the override: %s", modbus_strerror(errno));
        return;
    }
    SCAN_UNTIL(IR(K(JAKA_IR_RAPIDRATE_PERMILLE)) == permille, 5000, "the HMI's override at the robot");
}

/* What the HMI reads back on its own connection: not the PLC's image. */
static int hmi_reads_output(int index)
{
    uint8_t bit = 2;
    if (modbus_read_input_bits(hmi, K(JAKA_DI_DOUT_1) + index - 1, 1, &bit) != 1)
        return -1;
    return bit;
}

static int hmi_reads_override(void)
{
    uint16_t v;
    if (modbus_read_input_registers(hmi, K(JAKA_IR_RAPIDRATE_PERMILLE), 1, &v) != 1)
        return -1;
    return v;
}

/* The PLC sets output 1 and the override; the HMI changes both; the PLC
 * asks again for the value its image already holds: written, Done, and
 * the robot has it. Two rounds, output 1 then 0, override 50 % then 30 %. */
static void vendor_hmi(int port)
{
    static const struct {
        int level, permille;
    } rounds[] = {{1, 500}, {0, 300}};
    double worst_out = 0, worst_rate = 0;

    bind_image(P.COILS.value.table, P.INPUTS.value.table, P.INREGS.value.table, P.HOLDREGS.value.table);
    if (!hmi_connect(port)) {
        fail("the HMI cannot connect: %s", modbus_strerror(errno));
        return;
    }
    start_up();
    for (size_t i = 0; i < sizeof(rounds) / sizeof(rounds[0]) && !failed; i++) {
        int level = rounds[i].level, permille = rounds[i].permille;
        P.DIGOUT.INDEX.value = 1;
        P.DIGOUT.VALUE.value = level;
        RUN_BLOCK(DIGOUT, 8000, "the PLC's output 1");
        hmi_sets_output(1, !level);
        double t = RUN_BLOCK(DIGOUT, 8000, "the PLC's output 1 again, after the HMI's change");
        if (!failed && hmi_reads_output(1) != level)
            fail("output 1 Done for %d, the robot reports %d", level, hmi_reads_output(1));
        worst_out = t > worst_out ? t : worst_out;
        P.OVERRIDE.FACTOR.value = permille / 1000.0f;
        RUN_BLOCK(OVERRIDE, 8000, "the PLC's override");
        hmi_sets_override(700);
        t = RUN_BLOCK(OVERRIDE, 8000, "the PLC's override again, after the HMI's change");
        if (!failed && hmi_reads_override() != permille)
            fail("override Done for %d per mille, the robot reports %d", permille, hmi_reads_override());
        worst_rate = t > worst_rate ? t : worst_rate;
    }
    hmi_close();
    fig(", after each HMI change the PLC's same value Done: output within %.0f ms, override "
        "within %.0f ms (2 rounds)", worst_out, worst_rate);
}

/* ---- a PLC restarted mid-handshake ---- */

static void set_program_name(const char *name)
{
    size_t n = strlen(name);
    memcpy(P.PROG.PROGRAMNAME.value.body, name, n);
    P.PROG.PROGRAMNAME.value.len = n;
}

/* The cell's JAKA_Program loads "prog_A": its client writes the trigger,
 * and the PLC restarts before it has read the result (the trigger stays
 * 1 at the gateway): its connections closed, every variable at its
 * initial value, the client taking what it wrote as 0 (vendor_client.c).
 * Once JAKA_Link is Valid the new program loads "prog_B": the gateway
 * refuses it (trigger still 1) and the block ends Error 16#0202, never
 * Done (the robot has prog_A); it writes the trigger 0, and the retry
 * loads prog_B. What the robot received is checked by the driver. */
static void vendor_plc_restart(void)
{
    int trigger = K(JAKA_CO_CMD_LOAD_PROGRAM);

    bind_image(P.COILS.value.table, P.INPUTS.value.table, P.INREGS.value.table, P.HOLDREGS.value.table);
    start_up();
    set_program_name("prog_A");
    P.PROG.COMMAND.value = 1;
    P.PROG.EXECUTE.value = 1;
    SCAN_UNTIL(vc_coil_written(trigger) == 1, 3000, "prog_A's load: the trigger written");
    if (failed)
        return;
    vc_close();
    config_init__();
    bind_image(P.COILS.value.table, P.INPUTS.value.table, P.INREGS.value.table, P.HOLDREGS.value.table);
    double valid = SCAN_UNTIL(P.LINK.VALID.value, 20000, "JAKA_Link Valid after the PLC's restart");
    set_program_name("prog_B");
    P.PROG.COMMAND.value = 1;
    P.PROG.EXECUTE.value = 1;
    long long t0 = clock_us();
    while (!failed && !P.PROG.ERROR.value) {
        if (P.PROG.DONE.value) {
            fail("prog_B's load with the trigger left at 1: Done %.0f ms after Execute (the "
                 "gateway refuses it: trigger still 1)", (clock_us() - t0) / 1000.0);
            break;
        }
        if (clock_us() - t0 > 8000000) {
            fail("prog_B's load with the trigger left at 1: neither Done nor Error within 8 s");
            break;
        }
        scan();
    }
    double refused = (clock_us() - t0) / 1000.0;
    if (!failed && P.PROG.ERRORID.value != 0x0202)
        fail("prog_B's load with the trigger left at 1: ErrorID 0x%04X, expected 0x0202 (trigger "
             "still 1)", P.PROG.ERRORID.value);
    P.PROG.EXECUTE.value = 0;
    scan();
    double again = RUN_BLOCK(PROG, 8000, "prog_B's load again");
    fig(", the PLC restarted with prog_A's trigger at 1; Valid %.0f ms later; prog_B's load Error "
        "16#0202 after %.0f ms, its retry Done in %.0f ms", valid, refused, again);
}

/*
 * plc_scan vendor REQUESTS PORT SIM_PID PERIOD_MS WHAT SECONDS [GO_FILE]
 * WHAT: "cell" (the example's sequence, then 3 pick-and-place cycles),
 * "link" (JAKA_Link Valid all the time for SECONDS), "restart" (a cycle,
 * "PAUSED" on stdout, wait for GO_FILE (the gateway restarted meanwhile),
 * then 3 cycles more without a PLC restart), "hmi" (the cell's output and
 * override, changed by an HMI between the PLC's requests: vendor_hmi),
 * "plc_restart" (the PLC restarted mid-handshake: vendor_plc_restart).
 */
static int run_vendor(char **argv, int argc)
{
    const char *what = argv[6];
    int seconds = atoi(argv[7]);
    if (vc_load(argv[2], "127.0.0.1", atoi(argv[3])) != 0)
        return 2;
    sim_pid = atoi(argv[4]);
    scan_ms = atoi(argv[5]);
    vendor_mode = true;
    config_init__();
    long long t0 = now_us();
    if (strcmp(what, "hmi") == 0) {
        vendor_hmi(atoi(argv[3]));
    } else if (strcmp(what, "plc_restart") == 0) {
        vendor_plc_restart();
    } else if (strcmp(what, "link") == 0) {
        bind_image(PP.COILS.value.table, PP.INPUTS.value.table, PP.INREGS.value.table,
                   PP.HOLDREGS.value.table);
        double t = SCAN_UNTIL(PP.LINK.VALID.value, 20000, "JAKA_Link Valid");
        long drops = 0;
        bool was = true;
        long long end = now_us() + seconds * 1000000LL;
        while (!failed && now_us() < end) {
            scan();
            if (was && !PP.LINK.VALID.value)
                drops++;
            was = PP.LINK.VALID.value;
        }
        if (!failed && drops)
            fail("JAKA_Link Valid dropped %ld times in %d s (ErrorID 0x%04X)", drops, seconds,
                 PP.LINK.ERRORID.value);
        fig("Valid after %.0f ms, kept %d s", t, seconds);
    } else {
        if (strcmp(what, "cell") == 0)
            vendor_example();
        if (!failed)
            bind_image(PP.COILS.value.table, PP.INPUTS.value.table, PP.INREGS.value.table,
                       PP.HOLDREGS.value.table);
        if (!failed)
            SCAN_UNTIL(PP.LINK.VALID.value, 20000, "the pick-and-place JAKA_Link Valid");
        /* Its link had no image until now (ErrorID 4 after CheckTime): an
         * alarm the operator resets. */
        if (!failed && PP.ALARM.value)
            vendor_reset();
        if (strcmp(what, "restart") == 0 && !failed) {
            vendor_cycles(1, seconds * 1000);
            SCAN_UNTIL(PP.SEQUENCE.value == 0, 5000, "the cell paused");
            printf("PAUSED\n");
            fflush(stdout);
            const char *go = argc > 8 ? argv[8] : "";
            SCAN_UNTIL(access(go, F_OK) == 0, 30000, "the gateway restarted");
            SCAN_UNTIL(PP.LINK.RESTARTS.value > 0, 10000, "JAKA_Link sees the restart (start_id)");
            SCAN_UNTIL(PP.LINK.VALID.value, 20000, "JAKA_Link Valid after the restart");
            /* The robot's own network-exception handler pauses the arm
             * timeLimit (1 s) after its command connection was lost,
             * whatever connects meanwhile (jakasim, after the manual): the
             * operator starts the cell again once that has passed. */
            long long restarted = now_us();
            SCAN_UNTIL(now_us() - restarted > 1500000, 3000, "the robot's handler acted");
            if (PP.LINK.FAULT.value != 0 || PP.ALARM.value)
                vendor_reset();
            fig("a cycle, the gateway restarted (a new start_id seen)");
        }
        if (!failed) {
            double t = vendor_cycles(PP.CYCLES.value + 3, seconds * 1000);
            fig("%s3 pick-and-place cycles in %.0f ms", figures[0] ? ", " : "", t);
        }
    }
    const struct vc_stats *st = vc_stats();
    double s_total = (now_us() - t0) / 1e6;
    vc_close();
    if (failed)
        printf("FAIL %s %d ms %s: %s (in %.1f s: ", vc_vendor(), scan_ms, what, why, s_total);
    else
        printf("PASS %s %d ms %s (%s; ", vc_vendor(), scan_ms, what, figures);
    printf("%.1f requests/s: %ld reads, %ld writes (heartbeat %ld, other "
           "registers %ld, coils %ld), %ld refused, %ld reconnects; scan work mean %.2f ms, "
           "max %.2f ms, %ld overruns in %ld scans)\n",
           st->requests / s_total, st->reads, st->writes,
           st->heartbeat_writes, st->other_writes, st->coil_writes, st->refused, st->failures,
           scan_work_sum_ms / scans, scan_work_max_ms, overruns, scans);
    return failed ? 1 : 0;
}

int main(int argc, char **argv)
{
    signal(SIGPIPE, SIG_IGN);
    if (argc == 2 && strcmp(argv[1], "unit") == 0)
        return run_unit();
    if (argc >= 8 && strcmp(argv[1], "vendor") == 0)
        return run_vendor(argv, argc);
    if (argc >= 4 && strcmp(argv[1], "case") == 0)
        return run_case(argv[2], argv[3], argc > 4 ? argv[4] : NULL,
                        argc > 5 && strcmp(argv[5], "split") == 0);
    fprintf(stderr, "usage: plc_scan unit | plc_scan case NAME PORT [SIM_PID [split]] | "
                    "plc_scan vendor REQUESTS PORT SIM_PID PERIOD_MS cell|link|restart|hmi|plc_restart SECONDS [GO_FILE]\n");
    return 2;
}
