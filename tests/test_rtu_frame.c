/* SPDX-License-Identifier: MIT */
/*
 * test_rtu_frame.c - Modbus RTU framing and the line as a conversation
 * (rtu_frame.h), driven with a fake clock: the CRC of the specification's
 * examples, the character times, the request and response lengths of
 * every function the server answers; a frame hidden in another unit's
 * response is never executed; an exchange glued to our request (a late
 * reader) is cut by the conversation; a frame with a pause inside is
 * discarded; a frame handed over in pieces is whole; our reply heard back
 * within its echo window (120 ms) is never a request, with either
 * setting, also when the loop stalls before or within its read or it
 * comes in pieces; the same write after the window is executed every
 * time; a busy bus regains its place after one noise byte within a cycle
 * (FC03 or FC08 to another unit, an absent unit); a master with no t3.5
 * of its own is answered; our frames keep t3.5 apart.
 *
 * Then two property tests. Generated buses (requests and responses of
 * several units, ours among them; echoes of our replies, early and late,
 * with and without local_echo; noise; pauses and deliveries in pieces
 * inside frames; CRC-valid frames hidden in register data; late reads that
 * glue an exchange to our request; the same write repeated), fed byte by
 * byte as a port delivers them, with our replies sent when the line hands
 * a request on: on every bus the requests executed are exactly the whole
 * requests addressed to our unit, each once, in order. Every tenth goes
 * through the serial transport's own request path (mb_rtu.c, its clock
 * seam set to the test's clock) to a real Modbus server, whose replies are
 * the frames sent and heard back. RTU_PROPERTY_BUSES sets how many (50000
 * by default). And buses as the field wires them (one_field_bus: a
 * master's poll cycles, echoes 0-119 ms late with either setting, loop
 * stalls, noise bursts, FC08 and FC17 of other units, absent units,
 * masters with no t3.5): safety (whole requests of ours only, each once,
 * in order) and liveness (every one from the second cycle after the last
 * fault on, executed and answered; a cycle whose frames hold a CRC match
 * by chance, bytes that read two ways, counts as a fault; the master
 * waits for a reply up to its timeout); RTU_FIELD_BUSES sets how many (100000
 * by default; under qemu-user, JAKAGW_ARCH set, a tenth of each).
 * And buses through USB adapters (usb_adapter.h: FTDI, CH340, CP2102 as
 * their packets and latency timers deliver) with masters that retry a
 * lost reply (1-3 retries, 20-1000 ms timeouts), rewrite the same write
 * cyclically and poll user-defined codes of absent units: safety (our
 * transmissions only, in order, each once) and liveness (every request
 * and its first retry answered); RTU_USB_BUSES sets how many (20000).
 * RTU_PROPERTY_SEED replays a run (with RTU_PROPERTY_BUS=N,
 * RTU_PROPERTY_BUSES=1 or RTU_FIELD_BUSES=1 and the other 0, and
 * RTU_PROPERTY_TRACE=1: one bus).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <sys/socket.h>

#include "regmap.h"
#include "rtu_frame.h"
#include "usb_adapter.h"
/* The serial transport itself, to reach its request path (on_request:
 * the line's requests to the one Modbus server, replies through its
 * queue) with the clock seam set to the test's clock. */
#include "mb_rtu.c"

#define UNIT 17
#define MS 1000000ull
#define US 1000ull
#define MAX_EXEC 64

/* ---- a line on a fake clock ---- */

/* The server path: a real Modbus server on a loop, and the transport's
 * struct mb_rtu without a port (its replies go to a socket pair). */
struct server_path {
    uv_loop_t loop;
    struct regmap map;
    struct regmap_image img;
    struct mb_server srv;
    struct mb_rtu rtu;
    int peer; /* what the transport writes comes out here */
    bool closed;
};
static struct server_path *server;
static uint64_t fake_now;

static uint64_t fake_clock(void)
{
    return fake_now;
}

struct rig {
    struct rtu_line own_line;
    struct rtu_line *l; /* own_line, or the transport's (the server path) */
    uint64_t now;
    size_t executed;
    uint8_t exec[MAX_EXEC][RTU_MAX_ADU];
    size_t exec_size[MAX_EXEC];
    unsigned events[RTU_EVENT_COUNT];
    bool answer;          /* send a reply when a request is executed */
    uint64_t turnaround;  /* from the request's hand-on to the reply */
    uint64_t reply_at;    /* when the last reply started, 0 none */
    size_t reply_size;
    uint8_t reply[RTU_MAX_ADU];
    bool pending_reply;
    size_t replies;  /* replies sent */
    bool via_server; /* requests go through mb_rtu's on_request to the server */
    /* A stalled loop: nothing runs from stall_from to stall_until (0: no
     * stall); what came meanwhile is read at stall_until in one read. */
    uint64_t stall_from, stall_until;
    uint8_t stalled[2048];
    size_t stalled_n;
    bool stop_at_reply; /* run_to() returns when a reply has gone out */
};

/* RTU_PROPERTY_TRACE: every delivery and decision, to read a replayed bus. */
static bool trace;

static void trace_bytes(const char *what, uint64_t t, const uint8_t *data, size_t size)
{
    if (!trace)
        return;
    printf("%12.3f ms %-9s", (double)t / 1e6, what);
    for (size_t i = 0; i < size; i++)
        printf(" %02x", data[i]);
    printf("\n");
}

static void rig_request(void *user, const uint8_t *frame, size_t size)
{
    struct rig *r = user;
    trace_bytes("EXECUTE", r->now, frame, size);
    if (r->executed < MAX_EXEC) {
        memcpy(r->exec[r->executed], frame, size);
        r->exec_size[r->executed] = size;
    }
    r->executed++;
    if (r->answer) {
        /* A write's reply repeats it; a read's is another frame. */
        memcpy(r->reply, frame, size);
        r->reply_size = size;
        if (frame[1] == 3 || frame[1] == 4) {
            r->reply[2] = 2;
            r->reply[3] = 0x4A;
            r->reply[4] = 0x4B;
            r->reply_size = rtu_append_crc(r->reply, 5);
        }
        r->pending_reply = true;
    }
}

static void rig_event(void *user, enum rtu_event event)
{
    struct rig *r = user;
    r->events[event]++;
}

/* Our last reply again, as the transport sends it (nothing executed). */
static void rig_repeat(void *user)
{
    struct rig *r = user;
    trace_bytes("REPEAT", r->now, r->reply, r->reply_size);
    r->pending_reply = true;
}

/* Through the server: recorded, handed to the transport's request path
 * as the line hands it, and the reply the server built taken from the
 * transport's port, as sent. */
static void on_request_via_server(void *user, const uint8_t *frame, size_t size)
{
    struct rig *r = user;
    uint8_t out[RTU_MAX_ADU * MB_RTU_TX_FRAMES];
    r->answer = false;
    rig_request(r, frame, size);
    fake_now = r->now + r->turnaround;
    uint64_t requests = server->srv.stats.requests;
    on_request(&server->rtu, frame, size); /* mb_rtu.c's: the server answers */
    assert_int_equal(server->srv.stats.requests, requests + 1);
    ssize_t n = recv(server->peer, out, sizeof(out), MSG_DONTWAIT);
    assert_true(n >= 5 && rtu_crc_ok(out, (size_t)n) && out[0] == UNIT);
    memcpy(r->reply, out, (size_t)n);
    r->reply_size = (size_t)n;
    r->reply_at = fake_now;
    r->replies++;
    r->now = fake_now;
    trace_bytes("reply", r->now, r->reply, r->reply_size);
}

static const struct rtu_line_hooks *hooks_of(struct rig *r)
{
    static struct rtu_line_hooks hooks;
    hooks.request = r->via_server ? on_request_via_server : rig_request;
    hooks.event = rig_event;
    hooks.repeat = rig_repeat;
    hooks.user = r;
    return &hooks;
}

/* Our reply goes out as the transport sends it: not before its t3.5. */
static void send_reply(struct rig *r)
{
    uint64_t at = r->now + r->turnaround, ready = rtu_line_tx_ready_ns(r->l);
    r->pending_reply = false;
    if (ready > at)
        at = ready;
    if (r->reply_at)
        assert_true(at >= r->l->tx_end_ns + r->l->cfg.t35_ns);
    r->now = at;
    r->reply_at = at;
    r->replies++;
    trace_bytes("reply", at, r->reply, r->reply_size);
    rtu_line_frame_out(r->l, r->reply, r->reply_size);
    rtu_line_bytes_out(r->l, r->reply_size, at);
}

/* The loop runs again at the stall's end: it reads what came meanwhile
 * (after its last look, when the stall began), then judges the silences
 * due, as the transport's timer callback does. */
static void end_stall(struct rig *r)
{
    uint64_t until = r->stall_until;
    r->stall_until = 0;
    if (until > r->now)
        r->now = until;
    if (r->stalled_n) {
        trace_bytes("stalled", r->now, r->stalled, r->stalled_n);
        rtu_line_input_read(r->l, r->stalled, r->stalled_n, r->now, r->stall_from, hooks_of(r));
        r->stalled_n = 0;
    }
}

/* The clock runs to 't': every silence due before it is judged (none
 * while the loop is stalled). Returns false if 't' is inside a stall. */
static bool run_to(struct rig *r, uint64_t t)
{
    for (;;) {
        uint64_t due, stop = t;
        bool stall = r->stall_until && r->stall_from <= t;
        if (stall)
            stop = r->stall_from;
        while ((due = rtu_line_deadline(r->l)) != 0 && due <= stop) {
            if (due > r->now)
                r->now = due;
            rtu_line_silence(r->l, r->now, hooks_of(r));
            if (r->pending_reply) {
                send_reply(r);
                if (r->stop_at_reply) {
                    r->stop_at_reply = false;
                    return true;
                }
            }
        }
        if (!stall)
            break;
        if (t < r->stall_until) {
            if (t > r->now)
                r->now = t;
            return false;
        }
        end_stall(r);
    }
    if (t > r->now)
        r->now = t;
    return true;
}

static void deliver(struct rig *r, uint64_t t, const uint8_t *data, size_t size)
{
    if (!run_to(r, t)) {
        /* The loop is stalled: the bytes wait in the port. */
        if (r->stalled_n + size <= sizeof(r->stalled)) {
            memcpy(r->stalled + r->stalled_n, data, size);
            r->stalled_n += size;
        }
        return;
    }
    if (trace)
        printf("  [conv %d crc %llu frames %llu foreign %llu echoes %llu oot %llu]\n", r->l->conv,
               (unsigned long long)r->l->stats.crc_errors, (unsigned long long)r->l->stats.frames,
               (unsigned long long)r->l->stats.foreign_frames,
               (unsigned long long)r->l->stats.echoes, (unsigned long long)r->l->stats.out_of_turn);
    trace_bytes("read", r->now, data, size);
    rtu_line_input(r->l, data, size, r->now, hooks_of(r));
}

/* Bytes that arrived after 'after' (the reader's last look at an empty
 * port) and are read at 't'. */
static void deliver_read(struct rig *r, uint64_t t, uint64_t after, const uint8_t *data,
                         size_t size)
{
    run_to(r, t);
    trace_bytes("read", r->now, data, size);
    rtu_line_input_read(r->l, data, size, r->now, after, hooks_of(r));
}

/* A loop that stalled: bytes read at 't' without the silences due before
 * it having been judged (the loop did not run), after 'after'. */
static void read_after_stall(struct rig *r, uint64_t t, uint64_t after, const uint8_t *data,
                             size_t size)
{
    r->now = t;
    trace_bytes("late read", r->now, data, size);
    rtu_line_input_read(r->l, data, size, r->now, after, hooks_of(r));
}

static void rig_init(struct rig *r, unsigned baud, bool local_echo, bool pty)
{
    struct rtu_line_config cfg = {.unit_id = UNIT, .local_echo = local_echo};
    memset(r, 0, sizeof(*r));
    rtu_char_times(baud, false, 1, &cfg.t15_ns, &cfg.t35_ns);
    cfg.char_ns = (uint32_t)(10ull * 1000000000ull / baud);
    cfg.tx_char_ns = pty ? 0 : cfg.char_ns;
    cfg.delivery_ns = 4ull * cfg.char_ns + 1000000ull;
    r->l = &r->own_line;
    if (server) {
        /* The transport's own line, its queue empty, its clock ours. */
        r->l = &server->rtu.line;
        r->via_server = true;
        server->rtu.tx_count = 0;
        server->rtu.char_ns = cfg.char_ns;
    }
    rtu_line_init(r->l, &cfg);
    r->now = 1000 * MS;
    r->turnaround = 100 * US;
    r->answer = true;
}

static size_t read_request(uint8_t *out, uint8_t unit, uint8_t fc, uint16_t address,
                           uint16_t count);

/* A foreign exchange with silences around it: the line knows where the
 * bus stands (IDLE), as it does after any whole exchange. */
static void start_synced(struct rig *r)
{
    uint8_t req[8], rsp[8] = {18, 4, 2, 0, 1};
    /* Sure silences: t3.5, a port's piece and its delivery, twice over. */
    uint64_t sure = 2 * (r->l->cfg.t35_ns + RTU_PIECE_CHARS * r->l->cfg.char_ns +
                         r->l->cfg.delivery_ns);
    deliver(r, r->now + sure, req, read_request(req, 18, 4, 0, 1));
    deliver(r, r->now + sure, rsp, rtu_append_crc(rsp, 5));
    run_to(r, r->now + sure);
    assert_int_equal(r->l->conv, RTU_CONV_IDLE);
}

/* ---- frames ---- */

static size_t read_request(uint8_t *out, uint8_t unit, uint8_t fc, uint16_t address,
                           uint16_t count)
{
    out[0] = unit;
    out[1] = fc;
    out[2] = (uint8_t)(address >> 8);
    out[3] = (uint8_t)address;
    out[4] = (uint8_t)(count >> 8);
    out[5] = (uint8_t)count;
    return rtu_append_crc(out, 6);
}

static size_t write_coil(uint8_t *out, uint8_t unit, uint16_t address, bool on)
{
    return read_request(out, unit, 5, address, on ? 0xFF00 : 0);
}

/* A read response whose register data holds 'hidden' at byte 8, its
 * first 8 bytes made CRC-valid by two chosen data bytes. */
static size_t smuggling_response(uint8_t *out, uint8_t unit, uint8_t fc, const uint8_t *hidden,
                                 size_t size, unsigned registers)
{
    memset(out, 0, 3 + 2 * registers);
    out[0] = unit;
    out[1] = fc;
    out[2] = (uint8_t)(2 * registers);
    out[3] = 0x11, out[4] = 0x22, out[5] = 0x33;
    rtu_append_crc(out, 6);
    memcpy(out + 8, hidden, size);
    return rtu_append_crc(out, 3 + 2 * registers);
}

/* ---- fixed cases ---- */

static void crc_matches_the_specification(void **state)
{
    (void)state;
    /* Modbus over Serial Line V1.02, 6.2.2: 02 07 -> CRC 41 12 (low first). */
    const uint8_t example[] = {0x02, 0x07};
    assert_int_equal(rtu_crc16(example, 2), 0x1241);
    const uint8_t frame[] = {0x01, 0x03, 0x00, 0x00, 0x00, 0x0A, 0xC5, 0xCD};
    assert_true(rtu_crc_ok(frame, sizeof(frame)));
    uint8_t bad[sizeof(frame)];
    memcpy(bad, frame, sizeof(frame));
    bad[3] ^= 1;
    assert_false(rtu_crc_ok(bad, sizeof(bad)));
    assert_false(rtu_crc_ok(frame, 3)); /* shorter than any frame */
}

static void character_times(void **state)
{
    uint32_t t15, t35;
    (void)state;
    rtu_char_times(19200, true, 1, &t15, &t35);
    assert_int_equal(t15, 859375);
    assert_int_equal(t35, 2005208);
    rtu_char_times(9600, false, 2, &t15, &t35);
    assert_int_equal(t35, 4010416);
    rtu_char_times(115200, true, 1, &t15, &t35);
    assert_int_equal(t15, 750000);
    assert_int_equal(t35, 1750000);
}

/* A response's length reads only the bytes its request has: the request
 * sits in a buffer of its own size (the sanitizer build sees a byte read
 * past it; the quantity of 1-4 and 23 was read whatever the size). */
static size_t response_length_to(const uint8_t *request, size_t request_size,
                                 enum rtu_length *how)
{
    uint8_t *copy = malloc(request_size);
    const uint8_t rsp[] = {1, request[1], 0};
    size_t size = 0;
    memcpy(copy, request, request_size);
    *how = rtu_response_length(copy, request_size, rsp, sizeof(rsp), &size);
    free(copy);
    return size;
}

static void response_lengths_read_only_the_request(void **state)
{
    enum rtu_length how;
    (void)state;
    uint8_t read10[8] = {1, 3, 0, 0, 0, 10};
    assert_int_equal(response_length_to(read10, rtu_append_crc(read10, 6), &how), 5 + 20);
    assert_int_equal(how, RTU_LENGTH_EXACT);
    uint8_t coils10[8] = {1, 1, 0, 0, 0, 10};
    assert_int_equal(response_length_to(coils10, rtu_append_crc(coils10, 6), &how), 5 + 2);
    uint8_t status[4] = {1, 7};
    assert_int_equal(response_length_to(status, rtu_append_crc(status, 2), &how), 5);
    assert_int_equal(how, RTU_LENGTH_EXACT);
    uint8_t short_read[4] = {1, 3};
    response_length_to(short_read, rtu_append_crc(short_read, 2), &how);
    assert_int_equal(how, RTU_LENGTH_UNKNOWN); /* no quantity: no length from it */
}

/*
 * Every function the server answers, request and response: a foreign
 * exchange glued to our request (a reader late by all of it) is cut by the
 * lengths the conversation gives, and ours is executed.
 */
static void every_function_is_cut_by_the_conversation(void **state)
{
    static const struct {
        size_t req_size, rsp_size;
        uint8_t req[24], rsp[40];
    } x[] = {
        {6, 5, {18, 1, 0, 0, 0, 10}, {18, 1, 2, 0xFF, 0x03}},
        {6, 5, {18, 2, 0, 0, 0, 10}, {18, 2, 2, 0x0F, 0x01}},
        {6, 7, {18, 3, 0, 0, 0, 2}, {18, 3, 4, 1, 2, 3, 4}},
        {6, 5, {18, 4, 0, 9, 0, 1}, {18, 4, 2, 0x4A, 0x4B}},
        {6, 6, {18, 5, 0, 100, 0xFF, 0}, {18, 5, 0, 100, 0xFF, 0}},
        {6, 6, {18, 6, 0, 100, 0, 5}, {18, 6, 0, 100, 0, 5}},
        {9, 6, {18, 15, 0, 0, 0, 10, 2, 0xFF, 0x03}, {18, 15, 0, 0, 0, 10}},
        {11, 6, {18, 16, 0, 0, 0, 2, 4, 1, 2, 3, 4}, {18, 16, 0, 0, 0, 2}},
        {8, 8, {18, 22, 0, 4, 0, 0xF2, 0, 0x25}, {18, 22, 0, 4, 0, 0xF2, 0, 0x25}},
        {13, 7, {18, 23, 0, 3, 0, 2, 0, 14, 0, 1, 2, 0, 0xFF}, {18, 23, 4, 1, 2, 3, 4}},
        {2, 8, {18, 17}, {18, 17, 5, 1, 0xFF, 'a', 'b', 'c'}},
        {5, 24, {18, 43, 14, 1, 0},
         {18, 43, 14, 1, 0x83, 0, 0, 3, 0, 5, 'J', 'A', 'K', 'A', 'x', 1, 3, 'a', 'b', 'c', 2, 2,
          '1', '2'}},
        {6, 3, {18, 3, 0, 0, 0, 2}, {18, 0x83, 2}},
        {11, 3, {18, 16, 0, 0, 0, 2, 4, 1, 2, 3, 4}, {18, 0x90, 1}},
    };
    (void)state;
    for (size_t i = 0; i < sizeof(x) / sizeof(x[0]); i++) {
        struct rig r;
        uint8_t chunk[128], ours[8];
        size_t n = 0;
        rig_init(&r, 19200, false, false);
        /* Synchronised by a whole frame first (a read of ours). */
        deliver(&r, r.now, ours, read_request(ours, UNIT, 4, 0, 1));
        run_to(&r, r.now + 10 * MS);
        memcpy(chunk, x[i].req, x[i].req_size);
        n = rtu_append_crc(chunk, x[i].req_size);
        memcpy(chunk + n, x[i].rsp, x[i].rsp_size);
        n += rtu_append_crc(chunk + n, x[i].rsp_size);
        memcpy(chunk + n, ours, 8);
        n += 8;
        deliver(&r, r.now + 10 * MS, chunk, n);
        run_to(&r, r.now + 50 * MS);
        if (r.executed != 2 || r.l->stats.crc_errors)
            fail_msg("function %u: %zu executed, %llu dropped", x[i].req[1], r.executed,
                     (unsigned long long)r.l->stats.crc_errors);
        assert_int_equal(r.l->stats.foreign_frames, 2);
    }
}

/* The fault the review found: unit 18's FC03 response carries power_off
 * for us, its first 8 bytes a CRC-valid frame. Never executed, whether the
 * request was heard, missed (a whole chunk of 18's), or glued. */
static void a_frame_hidden_in_a_response_is_never_executed(void **state)
{
    uint8_t hidden[8], rsp[64], req[8], chunk[128];
    size_t h = write_coil(hidden, UNIT, 101, true);
    size_t n = smuggling_response(rsp, 18, 3, hidden, h, 8);
    (void)state;
    assert_true(rtu_crc_ok(rsp, 8) && rtu_crc_ok(rsp + 8, 8) && rtu_crc_ok(rsp, n));
    for (int how = 0; how < 4; how++) {
        struct rig r;
        rig_init(&r, 19200, false, false);
        if (how != 1) {
            deliver(&r, r.now, req, read_request(req, 18, 3, 0, 8));
            run_to(&r, r.now + 10 * MS);
        }
        if (how == 3) {
            /* A line in sync (IDLE) that never heard 18's request. */
            uint8_t ours[8];
            deliver(&r, r.now, ours, read_request(ours, UNIT, 4, 0, 1));
            run_to(&r, r.now + 10 * MS);
            r.executed = 0;
        }
        if (how == 2) {
            /* Request and response glued: a late reader. */
            rig_init(&r, 19200, false, false);
            memcpy(chunk, req, 8);
            memcpy(chunk + 8, rsp, n);
            deliver(&r, r.now, chunk, 8 + n);
        } else {
            deliver(&r, r.now, rsp, n);
        }
        run_to(&r, r.now + 50 * MS);
        assert_int_equal(r.executed, 0);
    }
}

static void a_pause_inside_a_frame_discards_it(void **state)
{
    struct rig r;
    uint8_t req[8];
    size_t n = read_request(req, UNIT, 4, 0, 1);
    (void)state;
    rig_init(&r, 9600, false, false);
    /* 4 bytes, a pause of 3 characters (more than t1.5 beyond delivery,
     * less than t3.5 plus what the frame lacks), the rest. */
    deliver(&r, r.now, req, 4);
    deliver(&r, r.now + 4 * r.l->cfg.char_ns + r.l->cfg.delivery_ns + 2 * r.l->cfg.t15_ns,
            req + 4, n - 4);
    run_to(&r, r.now + 50 * MS);
    assert_int_equal(r.executed, 0);
    assert_int_equal(r.l->stats.gap_discards, 1);
    /* The next whole frame is executed. */
    deliver(&r, r.now, req, n);
    run_to(&r, r.now + 50 * MS);
    assert_int_equal(r.executed, 1);
}

/* A UART's FIFO, a USB adapter's packets: one frame in pieces further
 * apart than t3.5; whole once its length says so. Noise before a frame
 * ends at the silence. */
static void a_frame_in_pieces_is_whole(void **state)
{
    struct rig r;
    uint8_t req[16];
    const uint8_t write16[] = {UNIT, 16, 0, 0, 0, 1, 2, 0, 5};
    memcpy(req, write16, sizeof(write16));
    size_t n = rtu_append_crc(req, sizeof(write16));
    (void)state;
    rig_init(&r, 4800, false, false);
    deliver(&r, r.now, req, 8);
    deliver(&r, r.now + 12 * MS, req + 8, n - 8);
    run_to(&r, r.now + 100 * MS);
    assert_int_equal(r.executed, 1);
    /* One byte of noise, a silence, a frame (the 11 bytes delivered 40 ms
     * after the noise: 23 ms of them were on the wire, 9 ms delivery). */
    uint8_t noise = UNIT;
    deliver(&r, r.now, &noise, 1);
    deliver(&r, r.now + 40 * MS, req, n);
    run_to(&r, r.now + 100 * MS);
    assert_int_equal(r.executed, 2);
    /* The same 12 ms after the noise: no silence proven before the frame
     * (its bytes would have begun before the noise ended), not taken. */
    deliver(&r, r.now, &noise, 1);
    deliver(&r, r.now + 12 * MS, req, n);
    run_to(&r, r.now + 100 * MS);
    assert_int_equal(r.executed, 2);
}

/* Echo with local_echo = false: our reply given back within its wire time
 * plus t3.5 is never executed, however the echo is delivered (the fault:
 * a write executed 742-942 times in 2 s); counted and said. A frame
 * equal to the reply after that is the master repeating its write:
 * executed each time. */
static void an_echo_in_our_turn_is_never_executed(void **state)
{
    struct rig r;
    uint8_t write[8];
    size_t n = write_coil(write, UNIT, 200, true);
    (void)state;
    rig_init(&r, 19200, false, false);
    start_synced(&r);
    for (int i = 0; i < 5; i++) {
        deliver(&r, r.now + 20 * MS, write, n);
        run_to(&r, r.now + 3 * MS); /* the silence: executed, answered */
        assert_int_equal(r.executed, (size_t)i + 1);
        /* The echo: in two pieces, or just before t3.5 after its end. */
        uint64_t end = r.l->tx_end_ns;
        if (i % 3 == 0) {
            deliver(&r, r.reply_at + 2 * r.l->cfg.char_ns, r.reply, 2);
            deliver(&r, r.reply_at + 2 * r.l->cfg.char_ns + 1 * MS, r.reply + 2,
                    r.reply_size - 2);
        } else {
            deliver(&r, end + r.l->cfg.t35_ns - 10 * US, r.reply, r.reply_size);
        }
        run_to(&r, r.now + 20 * MS);
        assert_int_equal(r.executed, (size_t)i + 1);
    }
    /* Each the first within the delivery bound: answered again, not
     * acted on again. */
    assert_int_equal(r.l->stats.repeats, 5);
    assert_int_equal(r.events[RTU_EVENT_REPEAT], 5);
    assert_int_equal(r.replies, 10);
}

/* local_echo = true: the reply's bytes come back up to 100 ms late, in
 * pieces, even glued to the master's next request; never executed. A byte
 * that differs is a collision. An adapter that gives nothing back loses
 * no request. */
static void local_echo_is_taken_off_the_input(void **state)
{
    struct rig r;
    uint8_t write[8], read[8], both[16];
    size_t n = write_coil(write, UNIT, 200, true);
    read_request(read, UNIT, 4, 0, 1);
    (void)state;
    rig_init(&r, 115200, true, false);
    start_synced(&r);
    deliver(&r, r.now, write, n);
    run_to(&r, r.now + 3 * MS);
    assert_int_equal(r.executed, 1);
    deliver(&r, r.l->tx_end_ns + 60 * MS, r.reply, 3);
    deliver(&r, r.now + 1 * MS, r.reply + 3, r.reply_size - 3);
    run_to(&r, r.now + 10 * MS);
    assert_int_equal(r.executed, 1);
    assert_int_equal(r.l->stats.echoes, 1);
    /* The echo and the next request in one USB packet. */
    deliver(&r, r.now + 5 * MS, write, n);
    run_to(&r, r.now + 3 * MS);
    assert_int_equal(r.executed, 2);
    memcpy(both, r.reply, r.reply_size);
    memcpy(both + r.reply_size, read, 8);
    deliver(&r, r.l->tx_end_ns + 40 * MS, both, r.reply_size + 8);
    run_to(&r, r.now + 10 * MS);
    assert_int_equal(r.executed, 3);
    assert_memory_equal(r.exec[2], read, 8);
    /* A collision: the echo differs after 3 bytes. */
    uint8_t damaged[RTU_MAX_ADU];
    memcpy(damaged, r.reply, r.reply_size);
    damaged[3] ^= 0x40;
    deliver(&r, r.l->tx_end_ns + 1 * MS, damaged, r.reply_size);
    run_to(&r, r.now + 10 * MS);
    assert_int_equal(r.executed, 3);
    assert_int_equal(r.l->stats.collisions, 1);
    assert_int_equal(r.events[RTU_EVENT_COLLISION], 1);
    /* Nothing comes back: the master's next request is served (once the
     * line, which lost its place in the collision, is sure of it). */
    deliver(&r, r.now + 5 * MS, read, 8);
    run_to(&r, r.now + 10 * MS);
    assert_int_equal(r.executed, 4);
    deliver(&r, r.now + 3 * MS, read, 8);
    run_to(&r, r.now + 3 * MS);
    assert_int_equal(r.executed, 5);
    assert_int_equal(r.events[RTU_EVENT_NO_ECHO], 1);
}

/* The suspected fault: an echo judged late (a stalled loop) is still an
 * echo, because its bytes' arrival is what counts. */
static void an_echo_is_judged_by_its_arrival(void **state)
{
    struct rig r;
    uint8_t write[8];
    size_t n = write_coil(write, UNIT, 200, true);
    (void)state;
    rig_init(&r, 1200, false, true);
    start_synced(&r);
    deliver(&r, r.now, write, n);
    run_to(&r, r.now + 40 * MS);
    assert_int_equal(r.executed, 1);
    deliver(&r, r.reply_at + 1 * MS, r.reply, r.reply_size);
    /* The loop wakes 300 ms later. */
    r.now += 300 * MS;
    rtu_line_silence(r.l, r.now, hooks_of(&r));
    assert_int_equal(r.executed, 1);
    assert_int_equal(r.l->stats.repeats, 1);
}

/* A master that repeats one write, 40 times, each 20 ms apart (past the
 * delivery bound after our reply): 40 executed. */
static void a_repeated_write_is_executed_each_time(void **state)
{
    struct rig r;
    uint8_t write[8];
    size_t n = write_coil(write, UNIT, 200, true);
    (void)state;
    rig_init(&r, 19200, false, true);
    for (int i = 0; i < 40; i++)
        deliver(&r, r.now + 20 * MS, write, n);
    run_to(&r, r.now + 30 * MS);
    assert_int_equal(r.executed, 40);
    assert_int_equal(r.l->stats.echoes, 0);
}

/* A spoiled echo (a byte flipped, its last byte missing, a noise byte
 * glued before it) never costs the next request, with either setting:
 * the master's retry of the same write 50 ms later is executed and
 * answered; with local_echo = true an echo missing its last byte closes
 * the echo's wait (a collision) and the next request 30 ms, 200 ms or 1 s
 * later is executed (before: 0 of 5 each). */
static void a_spoiled_echo_never_costs_the_next_request(void **state)
{
    static const uint64_t later_ms[] = {30, 50, 200, 1000};
    (void)state;
    for (int echo = 0; echo < 2; echo++)
        for (int how = 0; how < 3; how++)
            for (size_t l = 0; l < 4; l++) {
                struct rig r;
                uint8_t write[8], spoiled[16];
                size_t n = write_coil(write, UNIT, 200, true), m = 8;
                rig_init(&r, 115200, echo, false);
                start_synced(&r);
                deliver(&r, r.now + 5 * MS, write, n);
                run_to(&r, r.now + 5 * MS);
                assert_int_equal(r.executed, 1);
                memcpy(spoiled, r.reply, 8);
                if (how == 0) {
                    spoiled[3] ^= 0x10; /* flipped */
                } else if (how == 1) {
                    m = 7; /* its last byte missing */
                } else {
                    spoiled[0] = 0x5A; /* a noise byte before it */
                    memcpy(spoiled + 1, r.reply, 8);
                    m = 9;
                }
                uint64_t at = r.l->tx_end_ns + r.l->cfg.delivery_ns / 2;
                deliver(&r, at, spoiled, m);
                deliver(&r, at + later_ms[l] * MS, write, n);
                run_to(&r, r.now + 50 * MS);
                if (r.executed != 2 || r.replies != 2)
                    fail_msg("local_echo %d, echo %s, the retry %llu ms later: %zu executed, "
                             "%zu replies",
                             echo, how == 0 ? "flipped" : how == 1 ? "cut short" : "after noise",
                             (unsigned long long)later_ms[l], r.executed, r.replies);
            }
}

/* local_echo = true, an adapter that gave our reply nothing back: the
 * master's next write starts as our reply did (the same unit, function
 * and address), then pauses 30 ms inside. The part taken for the echo and
 * the rest are never joined into a request across the pause (before: the
 * part was put back as input stamped with the rest, and the write was
 * executed); nothing is executed, and the next whole request is. */
static void a_paused_request_like_our_reply_is_never_executed(void **state)
{
    struct rig r;
    uint8_t on[8], off[8];
    write_coil(on, UNIT, 200, true);
    write_coil(off, UNIT, 200, false);
    (void)state;
    rig_init(&r, 19200, true, false);
    start_synced(&r);
    deliver(&r, r.now + 5 * MS, on, 8);
    run_to(&r, r.now + 5 * MS);
    assert_int_equal(r.executed, 1);
    deliver(&r, r.now + 5 * MS, off, 4);
    deliver(&r, r.now + 30 * MS, off + 4, 4);
    run_to(&r, r.now + 100 * MS);
    assert_int_equal(r.executed, 1);
    deliver(&r, r.now + 5 * MS, off, 8);
    run_to(&r, r.now + 100 * MS);
    assert_int_equal(r.executed, 2);
}

/* An exception's form addressed to our unit (our exception reply heard
 * back) is counted and skipped: never a request, the line keeps its
 * place (before: handed to the server, which closed the line's
 * connection). */
static void an_exception_form_for_us_is_skipped(void **state)
{
    struct rig r;
    uint8_t exc[8] = {UNIT, 0x85, 0x02}, read[8];
    (void)state;
    rig_init(&r, 19200, false, false);
    start_synced(&r);
    deliver(&r, r.now + 20 * MS, exc, rtu_append_crc(exc, 3));
    run_to(&r, r.now + 30 * MS);
    assert_int_equal(r.executed, 0);
    assert_int_equal(r.l->stats.exceptions, 1);
    deliver(&r, r.now + 5 * MS, read, read_request(read, UNIT, 4, 0, 1));
    run_to(&r, r.now + 10 * MS);
    assert_int_equal(r.executed, 1);
}

/* Bytes after our request in the same chunk: the master did not wait for
 * our reply; nothing of it is executed. A broadcast never is. */
static void our_request_must_end_its_chunk(void **state)
{
    struct rig r;
    uint8_t chunk[32];
    size_t n = read_request(chunk, UNIT, 4, 0, 1);
    n += read_request(chunk + n, 18, 4, 0, 1);
    (void)state;
    rig_init(&r, 19200, false, false);
    start_synced(&r);
    deliver(&r, r.now, chunk, n);
    run_to(&r, r.now + 10 * MS);
    assert_int_equal(r.executed, 0);
    /* The line lost its place: a whole broadcast, and after it a sure
     * silence. */
    run_to(&r, r.now + 100 * MS);
    n = write_coil(chunk, 0, 100, true);
    deliver(&r, r.now, chunk, n);
    run_to(&r, r.now + 20 * MS);
    assert_int_equal(r.executed, 0);
    assert_int_equal(r.l->stats.broadcasts, 1);
}

/* Replies queued while the port waits keep t3.5 apart. */
static void our_frames_keep_t35_apart(void **state)
{
    struct rig r;
    uint8_t frame[8];
    size_t n = write_coil(frame, UNIT, 200, true);
    (void)state;
    rig_init(&r, 9600, false, false);
    rtu_line_frame_out(r.l, frame, n);
    rtu_line_bytes_out(r.l, 3, r.now);
    rtu_line_bytes_out(r.l, n - 3, r.now + 20 * MS); /* the port was full */
    uint64_t ready = rtu_line_tx_ready_ns(r.l);
    assert_true(ready >= r.now + 20 * MS + (n - 3) * r.l->cfg.char_ns + r.l->cfg.t35_ns);
}

/* ---- the line as the field wires it ---- */

/* An adapter that gives every reply back 'delay' after its wire time, to
 * a reader that looks at the port as the bytes come: one FC05 write, then
 * 1.5 s of whatever the line does with the echoes. Returns the
 * executions (each one a reply, a set_digital_output at the robot). */
static size_t echo_loop(unsigned baud, bool local_echo, uint64_t delay, struct rig *r)
{
    uint8_t write[8];
    size_t n = write_coil(write, UNIT, 200, true), echoed = 0;
    rig_init(r, baud, local_echo, false);
    start_synced(r);
    deliver(r, r->now + 20 * MS, write, n);
    uint64_t end = r->now + 1500 * MS;
    while (r->now < end) {
        run_to(r, r->now + r->l->cfg.t35_ns + RTU_PIECE_CHARS * r->l->cfg.char_ns +
                      r->l->cfg.delivery_ns + 1 * MS);
        if (echoed == r->replies)
            break; /* nothing more to give back */
        uint64_t at = r->l->tx_end_ns + delay;
        deliver_read(r, at, at - 1 * US, r->reply, r->reply_size);
        echoed++;
    }
    run_to(r, r->now + 200 * MS);
    return r->executed;
}

/* An echo later than t3.5 once made one write repeat without end with
 * local_echo = false (378 executions in 1.5 s for an echo at t3.5 at
 * 115200). With local_echo = false, an echo within the port's delivery
 * bound: the first is answered again (the master may be retrying at
 * once), the echo of that answer is skipped: one execution, two replies.
 * With local_echo = true, an echo up to 999 ms late: one execution, one
 * reply. At 115200 and 9600. */
static void an_echo_is_never_a_request(void **state)
{
    static const unsigned bauds[] = {115200, 9600};
    static const uint64_t local_us[] = {0, 900, 1750, 3500, 16000, 50000, 200000, 999000};
    (void)state;
    for (int echo = 0; echo < 2; echo++)
        for (size_t b = 0; b < 2; b++)
            for (size_t d = 0; d < 8; d++) {
                struct rig r;
                uint64_t bound = 4ull * (10ull * 1000000000ull / bauds[b]) + 1 * MS;
                uint64_t delay = echo ? local_us[d] * US : bound * d / 8;
                size_t executed = echo_loop(bauds[b], echo, delay, &r);
                bool ok = executed == 1 && r.l->stats.echoes == 1 &&
                          (echo ? r.replies == 1
                                : r.replies == 2 && r.l->stats.repeats == 1 &&
                                      r.events[RTU_EVENT_REPEAT] == 1);
                if (!ok)
                    fail_msg("local_echo %d, %u baud, echo %.2f ms late: %zu executed, %zu "
                             "replies, %llu echoes, %llu repeats",
                             echo, bauds[b], delay / 1e6, executed, r.replies,
                             (unsigned long long)r.l->stats.echoes,
                             (unsigned long long)r.l->stats.repeats);
            }
}

/* Past the delivery bound (local_echo: past the echo's wait), the same
 * write is the master's again: answered each time (20 writes, each 10 ms
 * after it). Inside it, a request of ours that differs from our last
 * reply is never an echo. */
static void the_same_write_after_the_window_is_answered(void **state)
{
    uint8_t on[8], off[8], read[8];
    write_coil(on, UNIT, 200, true);
    write_coil(off, UNIT, 200, false);
    read_request(read, UNIT, 4, 0, 1);
    (void)state;
    for (int echo = 0; echo < 2; echo++) {
        struct rig r;
        rig_init(&r, 115200, echo, false);
        start_synced(&r);
        deliver(&r, r.now + 5 * MS, on, 8);
        for (int i = 0; i < 20; i++) {
            run_to(&r, r.now + 3 * MS);
            uint64_t at = rtu_line_bound_end_ns(r.l) + 10 * MS;
            deliver_read(&r, at, at - 1 * US, on, 8);
        }
        run_to(&r, r.now + 10 * MS);
        assert_int_equal(r.executed, 21);
        assert_int_equal(r.replies, 21);
        /* 2 ms after our reply (t3.5 kept): another write, a read. */
        deliver(&r, r.l->tx_end_ns + 2 * MS, off, 8);
        run_to(&r, r.now + 3 * MS);
        deliver(&r, r.l->tx_end_ns + 2 * MS, read, 8);
        run_to(&r, r.now + 3 * MS);
        assert_int_equal(r.executed, 23);
        assert_int_equal(r.l->stats.echoes, 0);
    }
}

/* The echo is judged by when its bytes can have come. The echo within
 * the delivery bound after the reply (local_echo: 5 ms), and the loop
 * stalled 0.3 s before it read it, or after it read half of it; an echo
 * in two pieces, the second 100 ms later (with local_echo, a spoiled
 * echo: a collision). With either setting: never a second execution. */
static void a_stall_never_makes_an_echo_a_request(void **state)
{
    static const unsigned bauds[] = {115200, 9600};
    (void)state;
    for (int echo = 0; echo < 2; echo++)
        for (size_t b = 0; b < 2; b++)
            for (int how = 0; how < 3; how++) {
                struct rig r;
                uint8_t write[8];
                size_t n = write_coil(write, UNIT, 200, true);
                rig_init(&r, bauds[b], echo, false);
                start_synced(&r);
                deliver(&r, r.now + 5 * MS, write, n);
                run_to(&r, r.now + 30 * MS);
                assert_int_equal(r.executed, 1);
                uint64_t end = r.l->tx_end_ns, look = end; /* the last look */
                uint64_t at = end + (echo ? 5 * MS : r.l->cfg.delivery_ns / 2);
                if (how == 0) {
                    read_after_stall(&r, at + 300 * MS, look, r.reply, r.reply_size);
                } else if (how == 1) {
                    deliver_read(&r, at, at - 1 * US, r.reply, 3);
                    read_after_stall(&r, at + 300 * MS, at, r.reply + 3, r.reply_size - 3);
                } else {
                    deliver_read(&r, at, at - 1 * US, r.reply, 3);
                    deliver_read(&r, at + 100 * MS, at + 100 * MS - 1 * US, r.reply + 3,
                                 r.reply_size - 3);
                }
                run_to(&r, r.now + 300 * MS);
                if (r.executed != 1)
                    fail_msg("local_echo %d, %u baud, %s: %zu executions", echo, bauds[b],
                             how == 0   ? "stall before the echo's read"
                             : how == 1 ? "stall after half of it"
                                        : "in two pieces, 105 ms apart",
                             r.executed);
            }
}

/* The master of Why's third case: a poll cycle of a request for unit 18
 * (or an absent unit 19, or FC08 "return query data" with 4 bytes to unit
 * 18), its response, and our request, each 'gap' after the frame before;
 * a cycle starts t3.5 and 1 ms after our reply, or 100 ms after our
 * request when there was none. */
enum cycle_kind { CYCLE_READ_18, CYCLE_ABSENT_19, CYCLE_FC08_18 };

static size_t poll_cycles(struct rig *r, enum cycle_kind kind, uint64_t gap, unsigned cycles,
                          bool noise_glued)
{
    uint8_t req[16], rsp[16], ours[8];
    size_t req_n, rsp_n = 0;
    uint64_t c = r->l->cfg.char_ns;
    if (kind == CYCLE_FC08_18) {
        const uint8_t diag[] = {18, 8, 0, 0, 0xA5, 0x37, 0x12, 0x34};
        memcpy(req, diag, sizeof(diag));
        req_n = rtu_append_crc(req, sizeof(diag));
        memcpy(rsp, req, req_n);
        rsp_n = req_n;
    } else {
        req_n = read_request(req, kind == CYCLE_ABSENT_19 ? 19 : 18, 3, 0, 2);
        if (kind == CYCLE_READ_18) {
            const uint8_t r18[] = {18, 3, 4, 0, 1, 0, 2};
            memcpy(rsp, r18, sizeof(r18));
            rsp_n = rtu_append_crc(rsp, sizeof(r18));
        }
    }
    /* Noise: one byte, alone or 1 character before the first request. */
    uint8_t noise = 0x5A;
    uint64_t t = r->now + 50 * MS;
    deliver(r, t, &noise, 1);
    t += noise_glued ? c : 50 * MS;
    size_t before = r->executed;
    for (unsigned i = 0; i < cycles; i++) {
        size_t replies = r->replies;
        write_coil(ours, UNIT, 200, i & 1);
        t += req_n * c;
        deliver(r, t, req, req_n);
        if (rsp_n) {
            t += gap + rsp_n * c;
            deliver(r, t, rsp, rsp_n);
        }
        t += gap + 8 * c;
        deliver(r, t, ours, 8);
        run_to(r, t + 100 * MS);
        t = r->replies > replies ? r->l->tx_end_ns + r->l->cfg.t35_ns + 1 * MS : t + 100 * MS;
        if (t < r->now)
            t = r->now;
    }
    return r->executed - before;
}

/* Why's third case: after one noise byte, a busy bus (gaps above t3.5,
 * below t3.5 + 16 characters + the port's delivery) lost every write of
 * ours (0 of 30 at 9600; 0 of 10 at 115200 with 2 ms gaps; FC08 with 4
 * data bytes to another unit: 0 of 10). One cycle at most is lost. */
static void a_busy_bus_regains_its_place_after_noise(void **state)
{
    static const unsigned bauds[] = {115200, 9600};
    (void)state;
    for (size_t b = 0; b < 2; b++)
        for (int kind = CYCLE_READ_18; kind <= CYCLE_FC08_18; kind++)
            for (int glued = 0; glued < 2; glued++) {
                struct rig r;
                rig_init(&r, bauds[b], false, false);
                start_synced(&r);
                uint64_t gap = r.l->cfg.t35_ns + r.l->cfg.t35_ns / 7;
                size_t got = poll_cycles(&r, (enum cycle_kind)kind, gap, 10, glued);
                if (got < 9)
                    fail_msg("%u baud, %s, noise %s: %zu of 10 writes executed", bauds[b],
                             kind == CYCLE_READ_18     ? "FC03 to unit 18"
                             : kind == CYCLE_ABSENT_19 ? "absent unit 19"
                                                       : "FC08 to unit 18",
                             glued ? "glued" : "alone", got);
            }
}

/*
 * A master's cycle with a user-defined function code (65-72, 100-110)
 * of unit 18, 'data' bytes, and our write, each a legal gap (t3.5 and a
 * seventh) after the frame before; unit 18 absent (no response) or
 * answering with the same form ('answered'). Returns our writes executed
 * of 10; fails if anything else is.
 */
static size_t user_code_cycles(unsigned baud, uint8_t fc, size_t data, bool answered)
{
    struct rig r;
    uint8_t req[64], ours[8];
    rig_init(&r, baud, false, false);
    start_synced(&r);
    uint64_t c = r.l->cfg.char_ns, gap = r.l->cfg.t35_ns + r.l->cfg.t35_ns / 7;
    uint64_t t = r.now + 50 * MS;
    size_t got = 0;
    for (unsigned i = 0; i < 10; i++) {
        req[0] = 18, req[1] = fc;
        for (size_t k = 0; k < data; k++)
            req[2 + k] = (uint8_t)(i * 31 + k * 7 + 1);
        size_t n = rtu_append_crc(req, 2 + data);
        t += n * c;
        deliver(&r, t, req, n);
        if (answered) {
            req[2] ^= 0x55; /* the response: another frame of the same form */
            n = rtu_append_crc(req, 2 + data);
            t += gap + n * c;
            deliver(&r, t, req, n);
        }
        size_t m = write_coil(ours, UNIT, 200, i & 1), before = r.executed;
        t += gap + m * c;
        deliver(&r, t, ours, m);
        run_to(&r, t + 100 * MS);
        for (size_t e = before; e < r.executed && e < MAX_EXEC; e++)
            if (memcmp(r.exec[e], ours, 8) != 0)
                fail_msg("FC%u: executed a frame that is not our write", fc);
        got += r.executed > before;
        t = r.l->tx_end_ns + r.l->cfg.t35_ns + 1 * MS;
        if (t < r.now)
            t = r.now;
    }
    return got;
}

/* User-defined function codes of another unit get the length search
 * FC08 gets: a request of a code whose form the line does not know is
 * cut at the shortest CRC-valid run that a whole request follows. With
 * unit 18 absent, our writes after them are answered (before: starved, 0
 * of 10); where unit 18 answers in a form the line cannot know, its
 * response's data is never searched (its data is that unit's), and
 * nothing but our writes is ever executed. */
static void user_codes_of_another_unit_are_cut_by_length(void **state)
{
    static const uint8_t codes[] = {65, 72, 100, 110};
    (void)state;
    for (size_t b = 0; b < 2; b++)
        for (size_t k = 0; k < sizeof(codes); k++)
            for (int answered = 0; answered < 2; answered++) {
                unsigned baud = b ? 9600 : 115200;
                size_t got = user_code_cycles(baud, codes[k], 6, answered);
                if (!answered && got < 9)
                    fail_msg("%u baud, FC%u to absent unit 18: %zu of 10 writes executed", baud,
                             codes[k], got);
                if (k == 0)
                    printf("    %6u baud, FC%u, unit 18 %s: %zu of 10 writes executed\n", baud,
                           codes[k], answered ? "answering" : "absent", got);
            }
}

/* A chunk after a sure silence: unit 18 with a function code, 4 bytes and
 * their CRC (a run whose CRC passes), then a whole write of ours. For a
 * user-defined code (65) the run is that unit's request and ours follows
 * it: executed. For a reserved code (123: neither public nor
 * user-defined, no master's) nothing is cut: the bytes are dropped to the
 * next silence and our write is not executed (it may be another unit's
 * data: the field property's counterexample). */
static void a_reserved_code_gets_no_length_search(void **state)
{
    static const uint8_t codes[] = {65, 123};
    (void)state;
    for (size_t k = 0; k < sizeof(codes); k++) {
        struct rig r;
        uint8_t bytes[32];
        rig_init(&r, 115200, false, 0);
        start_synced(&r);
        size_t n = 0;
        bytes[n++] = 18, bytes[n++] = codes[k];
        bytes[n++] = 0x37, bytes[n++] = 0x9e, bytes[n++] = 0x40, bytes[n++] = 0x85;
        n = rtu_append_crc(bytes, n);
        n += write_coil(bytes + n, UNIT, 203, true);
        deliver(&r, r.now + 5 * MS, bytes, n);
        run_to(&r, r.now + 50 * MS);
        if (r.executed != (codes[k] == 65 ? 1u : 0u))
            fail_msg("FC%u: %zu executed", codes[k], r.executed);
    }
}

/* Why's fourth case: a master that keeps no t3.5 of its own sends each
 * request as soon as our reply has come (50 writes, each toggling the
 * output): every one answered, on a wire and on a pty. */
static void a_master_without_t35_is_answered(void **state)
{
    (void)state;
    for (int pty = 0; pty < 2; pty++) {
        struct rig r;
        uint8_t write[8];
        rig_init(&r, 115200, false, pty);
        start_synced(&r);
        deliver(&r, r.now + 5 * MS, write, write_coil(write, UNIT, 200, true));
        for (int i = 0; i < 50; i++) {
            run_to(&r, r.now + r.l->cfg.t35_ns + 10 * US);
            uint64_t at = r.l->tx_end_ns + 8 * r.l->cfg.char_ns + 50 * US;
            deliver(&r, at, write, write_coil(write, UNIT, 200, i & 1));
        }
        run_to(&r, r.now + 50 * MS);
        if (r.executed != 51)
            fail_msg("pty %d: %zu of 51 executed", pty, r.executed);
        assert_int_equal(r.replies, 51);
    }
}

/* One garbage byte 2-2.5 ms before each request of ours on a busy bus
 * (a request for unit 18 and its response before it, gaps of t3.5 and a
 * seventh), 20 cycles at 19200 and 115200: the silence after the byte is
 * shorter than the port's delivery, so the line cannot be sure of it.
 * Before, 0 of 20 answered at either speed (the byte and the request one
 * chunk, dropped); now every one, and nothing else executed. */
static void a_garbage_byte_before_our_request_costs_nothing(void **state)
{
    static const unsigned bauds[] = {19200, 115200};
    (void)state;
    for (size_t b = 0; b < 2; b++) {
        struct rig r;
        rig_init(&r, bauds[b], false, false);
        start_synced(&r);
        uint64_t c = r.l->cfg.char_ns, gap = r.l->cfg.t35_ns + r.l->cfg.t35_ns / 7;
        uint64_t t = r.now + 50 * MS;
        size_t got = 0;
        for (unsigned i = 0; i < 20; i++) {
            uint8_t req[8], rsp[16] = {18, 3, 4, 0, 1, 0, 2}, ours[8], garbage = 0xA5;
            t += 8 * c;
            deliver(&r, t, req, read_request(req, 18, 3, 0, 2));
            size_t rsp_n = rtu_append_crc(rsp, 7);
            t += gap + rsp_n * c;
            deliver(&r, t, rsp, rsp_n);
            t += gap + c;
            deliver(&r, t, &garbage, 1);
            size_t n = write_coil(ours, UNIT, 200, i & 1), before = r.executed;
            t += 2 * MS + (i * 25 % 500) * US + n * c;
            deliver(&r, t, ours, n);
            run_to(&r, t + 100 * MS);
            for (size_t e = before; e < r.executed && e < MAX_EXEC; e++)
                if (memcmp(r.exec[e], ours, 8) != 0)
                    fail_msg("%u baud: executed a frame that is not our write", bauds[b]);
            got += r.executed > before;
            t = r.now > r.l->tx_end_ns ? r.now : r.l->tx_end_ns;
            t += r.l->cfg.t35_ns + 1 * MS;
        }
        if (got < 19)
            fail_msg("%u baud: %zu of 20 answered", bauds[b], got);
    }
}

/* A noise byte 8 ms before to 4 ms after our write's reply left the
 * wire (while it is on the wire: a collision), then the reply's echo
 * 18-24 ms after the noise, at 9600 with local_echo = false and the bound
 * of [rtu] delivery_ms's default (16 ms; an echo that late comes through
 * an adapter's latency timer): the write is acted on once (an echo glued
 * to noise within the bound is never the master's). */
static void a_noise_byte_never_makes_an_echo_a_request(void **state)
{
    (void)state;
    for (int na = -8; na <= 4; na += 2)
        for (unsigned d = 18; d <= 24; d += 2) {
            struct rig r;
            uint8_t write[8], noise = 0x3C;
            rig_init(&r, 9600, false, false);
            r.l->cfg.delivery_ns += 16 * MS;
            start_synced(&r);
            size_t n = write_coil(write, UNIT, 200, true);
            deliver(&r, r.now + 20 * MS + n * r.l->cfg.char_ns, write, n);
            r.stop_at_reply = true;
            run_to(&r, r.now + 30 * MS);
            assert_int_equal(r.replies, 1);
            uint64_t tn = r.l->tx_end_ns + (uint64_t)((int64_t)na * (int64_t)MS);
            assert_true(tn >= r.now);
            deliver(&r, tn, &noise, 1);
            deliver(&r, tn + d * MS + n * r.l->cfg.char_ns, r.reply, r.reply_size);
            run_to(&r, r.now + 500 * MS);
            if (r.executed != 1)
                fail_msg("noise %+d ms from the reply's end, echo %u ms after it: %zu executions", na,
                         d, r.executed);
        }
}

/* The delivery bound at open (mb_rtu.c's set_up_delivery) on a pty, with
 * a sysfs tree of our own (the seam [rtu] has for tests): an FTDI
 * adapter's latency_timer of 16 is set to 1 and read back, and the line
 * takes 1 ms; without one, [rtu] delivery_ms. */
static void the_delivery_bound_is_read_back(void **state)
{
    char root[] = "/tmp/jakagw-sysfs-XXXXXX", path[256], name[64], mk[700];
    struct mb_rtu rtu;
    struct stat st;
    int fd = open("/dev/ptmx", O_RDWR | O_NOCTTY), unlock = 0, n = -1;
    (void)state;
    assert_true(fd >= 0 && ioctl(fd, TIOCSPTLCK, &unlock) == 0 && ioctl(fd, TIOCGPTN, &n) == 0);
    snprintf(name, sizeof(name), "/dev/pts/%d", n);
    int pty = open(name, O_RDWR | O_NOCTTY);
    assert_true(pty >= 0 && fstat(pty, &st) == 0);
    assert_non_null(mkdtemp(root));
    memset(&rtu, 0, sizeof(rtu));
    snprintf(rtu.device, sizeof(rtu.device), "test");
    rtu.sysfs_root = root;
    rtu.cfg.delivery_ms = 16;
    rtu.char_ns = 520833;
    set_up_delivery(&rtu, pty);
    assert_int_equal(rtu.delivery_bound_ms, 16); /* no latency_timer: [rtu] delivery_ms */
    snprintf(path, sizeof(path), "%s/dev/char/%u:%u/device", root, major(st.st_rdev),
             minor(st.st_rdev));
    snprintf(mk, sizeof(mk), "mkdir -p %s && echo 16 > %s/latency_timer", path, path);
    assert_int_equal(system(mk), 0);
    set_up_delivery(&rtu, pty);
    assert_int_equal(rtu.delivery_bound_ms, 1);
    assert_int_equal(rtu.line.cfg.delivery_ns, 4ull * 520833 + MB_RTU_DELIVERY_NS + 1 * MS);
    snprintf(mk, sizeof(mk), "grep -qx 1 %s/latency_timer && rm -r %s", path, root);
    assert_int_equal(system(mk), 0);
    close(pty);
    close(fd);
}

/* ---- USB adapters (usb_adapter.h) ---- */

/* What the adapter holds reaches the host at the next USB frame after 't'. */
static void usb_flush(struct rig *r, struct usb_port *p, uint64_t t)
{
    if (!p->held_n)
        return;
    deliver(r, t + USB_FRAME_NS, p->held, p->held_n);
    p->held_n = 0;
}

/* 'size' bytes on the wire from 'start', one character each 'char_ns',
 * into the adapter's packets: a full one goes at once, a partial one when
 * the latency timer runs out. Returns the wire time of the last byte. */
static uint64_t usb_wire(struct rig *r, struct usb_port *p, const uint8_t *d, size_t size,
                         uint64_t start, uint64_t char_ns)
{
    uint64_t t = start;
    for (size_t i = 0; i < size; i++) {
        t += char_ns;
        if (p->held_n) {
            uint64_t fire = usb_timer_after(p, p->held_since_ns);
            if (fire < t)
                usb_flush(r, p, fire);
        }
        if (!p->held_n)
            p->held_since_ns = t;
        p->held[p->held_n++] = d[i];
        if (p->held_n == p->adapter->payload)
            usb_flush(r, p, t);
    }
    return t;
}

/* Nothing more on the wire until 'until': the timer hands over the rest. */
static void usb_idle(struct rig *r, struct usb_port *p, uint64_t until)
{
    if (p->held_n) {
        uint64_t fire = usb_timer_after(p, p->held_since_ns);
        if (fire <= until)
            usb_flush(r, p, fire);
    }
}

/*
 * A master's cycle through a USB adapter at 19200 baud: a read of 125
 * registers of unit 18 (its 255-byte response holding CRC-valid writes
 * for our unit in its data), then our read 5 ms after that response. Every
 * adapter of the table, 20 cycles, the line told the adapter's bound
 * ('bound_ms'). Returns our reads answered; fails if anything else is
 * executed.
 */
static unsigned usb_long_response_cycles(const struct usb_adapter *a, unsigned bound_ms,
                                         unsigned phase_us)
{
    struct rig r;
    struct usb_port p = {.adapter = a};
    uint8_t req[8], rsp[RTU_MAX_ADU], ours[8];
    unsigned answered = 0;
    rig_init(&r, 19200, false, false);
    r.l->cfg.delivery_ns = 4ull * r.l->cfg.char_ns + 1 * MS + bound_ms * MS;
    start_synced(&r);
    uint64_t c = r.l->cfg.char_ns, t = r.now + 50 * MS;
    p.phase_ns = r.now + phase_us * US;
    for (unsigned cycle = 0; cycle < 20; cycle++) {
        read_request(req, 18, 3, 0, 125);
        rsp[0] = 18, rsp[1] = 3, rsp[2] = 250;
        for (size_t i = 0; i < 250; i++)
            rsp[3 + i] = (uint8_t)(i * 37 + cycle);
        for (size_t at = 3 + cycle % 8; at + 8 <= 253; at += 24)
            write_coil(rsp + at, UNIT, 101, true);
        size_t rsp_n = rtu_append_crc(rsp, 253);
        read_request(ours, UNIT, 4, (uint16_t)cycle, 1);
        t = usb_wire(&r, &p, req, 8, t, c);
        t = usb_wire(&r, &p, rsp, rsp_n, t + r.l->cfg.t35_ns + 1 * MS, c);
        size_t before = r.executed;
        t = usb_wire(&r, &p, ours, 8, t + 5 * MS, c);
        usb_idle(&r, &p, t + 40 * MS);
        run_to(&r, t + 60 * MS);
        for (size_t i = before; i < r.executed && i < MAX_EXEC; i++)
            if (r.exec_size[i] != 8 || memcmp(r.exec[i], ours, 8) != 0)
                fail_msg("%s, bound %u ms: cycle %u executed a frame nobody sent for us",
                         a->name, bound_ms, cycle);
        answered += r.executed > before;
        t = r.now + 20 * MS;
    }
    return answered;
}

/* Through an adapter's packets (FTDI 62 bytes, latency timer 16 ms and
 * 1 ms; CH340; CP2102), with the line told the adapter's bound: nothing
 * nobody sent for us is executed, and our read after a long foreign
 * response is answered at least 18 of 20. With the old bound (4
 * characters + 1 ms), what it was is printed. */
static void usb_adapters_deliver_whole_conversations(void **state)
{
    (void)state;
    for (size_t i = 0; i < sizeof(usb_adapters) / sizeof(usb_adapters[0]); i++) {
        const struct usb_adapter *a = &usb_adapters[i];
        for (unsigned phase = 0; phase < 4; phase++) {
            unsigned got = usb_long_response_cycles(a, a->latency_ms, phase * 3700);
            if (got < 18)
                fail_msg("%s (timer phase %u): our read answered %u of 20", a->name, phase, got);
            if (phase == 0)
                printf("    %-28s our read after a 255-byte response: %u of 20\n", a->name,
                       got);
        }
    }
}

/* ---- the property test ---- */

/* Under qemu-user (an ARM build's make test: JAKAGW_ARCH set), a tenth of
 * the buses: the native builds run them all, and an emulated CPU, many
 * times slower, checks that the code behaves the same on the board's. */
static unsigned long emulated(void)
{
    const char *arch = getenv("JAKAGW_ARCH");
    return arch && arch[0] ? 10 : 1;
}


/* xorshift64*: a seed replays a run. */
static uint64_t rng_state;
static uint64_t rnd(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return rng_state * 2685821657736338717ull;
}
static unsigned below(unsigned n)
{
    return (unsigned)(rnd() % n);
}
static bool chance(unsigned percent)
{
    return below(100) < percent;
}

/*
 * Through the FTDI model (62-byte packets, latency timer 16 ms, the line
 * told the adapter's bound), 19200 baud, 40 poll cycles: the master reads
 * 10-125 registers of units 18, 19 and 20, whose responses hold CRC-valid
 * writes for our unit every 8-31 bytes, then our read 2 ms after the last
 * response. Nothing that no master sent for us is executed, and our read
 * is answered every cycle (with the bound of 4 characters + 1 ms, as the
 * line had before, 11-17 of 40, nothing else executed).
 */
static void ftdi_poll_cycles_execute_only_ours(void **state)
{
    (void)state;
    rng_state = 0x42B;
    for (unsigned phase = 0; phase < 4; phase++) {
        struct rig r;
        struct usb_port p = {.adapter = &usb_adapters[0]};
        unsigned answered = 0;
        rig_init(&r, 19200, false, false);
        r.l->cfg.delivery_ns += (uint64_t)p.adapter->latency_ms * MS;
        start_synced(&r);
        uint64_t c = r.l->cfg.char_ns, t35 = r.l->cfg.t35_ns, t = r.now + 50 * MS;
        p.phase_ns = r.now + phase * 3700 * US;
        for (unsigned cycle = 0; cycle < 40; cycle++) {
            for (uint8_t unit = 18; unit <= 20; unit++) {
                uint8_t req[8], rsp[RTU_MAX_ADU];
                unsigned count = 10 + below(116);
                t = usb_wire(&r, &p, req, read_request(req, unit, 3, 0, (uint16_t)count), t, c);
                rsp[0] = unit, rsp[1] = 3, rsp[2] = (uint8_t)(2 * count);
                for (unsigned i = 0; i < 2 * count; i++)
                    rsp[3 + i] = (uint8_t)rnd();
                for (size_t at = 3 + below(8); at + 8 <= 3 + 2 * count; at += 8 + below(24))
                    write_coil(rsp + at, UNIT, (uint16_t)(100 + below(16)), true);
                size_t n = rtu_append_crc(rsp, 3 + 2 * count);
                t = usb_wire(&r, &p, rsp, n, t + t35 + below(3000) * US, c);
                t += t35 + below(3000) * US;
            }
            uint8_t ours[8];
            size_t before = r.executed;
            read_request(ours, UNIT, 4, (uint16_t)cycle, 1);
            t = usb_wire(&r, &p, ours, 8, t + 2 * MS, c);
            usb_idle(&r, &p, t + 40 * MS);
            run_to(&r, t + 60 * MS);
            for (size_t i = before; i < r.executed && i < MAX_EXEC; i++)
                if (r.exec_size[i] != 8 || memcmp(r.exec[i], ours, 8) != 0)
                    fail_msg("timer phase %u, cycle %u: executed a frame nobody sent for us",
                             phase, cycle);
            answered += r.executed > before;
            t = r.now + 20 * MS;
        }
        if (answered < 39)
            fail_msg("timer phase %u: our read answered %u of 40", phase, answered);
    }
}

struct bus {
    struct rig r;
    uint32_t char_ns, t35, jitter;
    uint64_t latency; /* the port hands every byte over this late (a USB adapter) */
    uint64_t wire;    /* the line is free from here (the last frame's end) */
    uint64_t read_at; /* the port's last delivery: deliveries keep order */
    bool synced;      /* the last chunk was whole: the line knows where it is */
    unsigned careful; /* frames still to start after a sure silence */
    size_t expected;
    uint8_t expect[MAX_EXEC][RTU_MAX_ADU];
    size_t expect_size[MAX_EXEC];
};

/* After bytes that were no frame: the line may wait for what a frame begun
 * there lacks before it takes the silence; the master speaks after that. */
static void settle(struct bus *b)
{
    run_to(&b->r, b->read_at + b->t35 + 300 * b->char_ns + 5 * MS);
    b->wire = b->read_at = b->r.now;
}

/* A frame on the wire from 'start': delivered in pieces at their last
 * byte's wire time plus the port's jitter. 'pause_at' > 0: the line falls
 * silent for 'pause' before that byte. Returns the last delivery. */
static uint64_t transmit(struct bus *b, const uint8_t *frame, size_t size, uint64_t start,
                         size_t pause_at, uint64_t pause)
{
    size_t at = 0;
    uint64_t t = start;
    while (at < size) {
        size_t piece = 1 + below(size - at < 16 ? (unsigned)(size - at) : 16);
        if (pause_at > at && pause_at < at + piece)
            piece = pause_at - at;
        if (pause_at == at && pause_at)
            t += pause;
        t += piece * b->char_ns;
        uint64_t when = t + b->latency + below(b->jitter + 1);
        if (when < b->read_at)
            when = b->read_at;
        deliver(&b->r, when, frame + at, piece);
        b->read_at = when;
        at += piece;
    }
    b->wire = t;
    return b->read_at;
}

/* The master waits t3.5 (and the port's lateness) after the line's last
 * frame, and more at random. Where the line lost its place (noise, a
 * broken frame), it takes a frame again only after a silence it can be
 * sure of: t3.5 beyond the port's delivery (a master's poll cycle). */
static uint64_t next_start(struct bus *b)
{
    uint64_t from = b->wire > b->read_at ? b->wire : b->read_at;
    uint64_t sure = 0;
    if (!b->synced || b->careful) {
        /* Every frame while the line does not know where it stands, and
         * the one after the frame it takes again (it takes that one once
         * it is sure nothing followed it). */
        sure = RTU_PIECE_CHARS * b->char_ns + b->r.l->cfg.delivery_ns;
        if (b->synced)
            b->careful--;
    }
    return from + b->t35 + 2 * b->jitter + b->char_ns + sure + below(3) * below(2000) * US;
}

/* A master that repeats our last reply (the same write) does it after the
 * delivery bound (rtu_frame.h: within it, the frame is answered again and
 * not acted on again), so that the bus expects it executed. 'size' 0: a
 * chunk that does not start with our request. */
static uint64_t past_echo_window(const struct bus *b, const uint8_t *frame, size_t size,
                                 uint64_t start)
{
    const struct rtu_line *l = b->r.l;
    uint64_t window_end = rtu_line_bound_end_ns(l);
    if (size && size == l->sent_size && memcmp(frame, l->sent, size) == 0 &&
        start < window_end + 1 * MS)
        return window_end + 1 * MS;
    return start;
}

static void expect_request(struct bus *b, const uint8_t *frame, size_t size)
{
    trace_bytes("expected", b->r.now, frame, size);
    if (b->expected < MAX_EXEC) {
        memcpy(b->expect[b->expected], frame, size);
        b->expect_size[b->expected] = size;
    }
    b->expected++;
}

/* A request of ours: FC03/04 reads, FC05/06 writes (the same one, often). */
static size_t our_request(uint8_t *out, uint8_t *last_write, size_t *last_write_size)
{
    if (*last_write_size && chance(40)) {
        memcpy(out, last_write, *last_write_size);
        return *last_write_size;
    }
    switch (below(4)) {
    case 0:
        return read_request(out, UNIT, 3, (uint16_t)below(600), (uint16_t)(1 + below(20)));
    case 1:
        return read_request(out, UNIT, 4, (uint16_t)below(6000), (uint16_t)(1 + below(20)));
    default: {
        size_t n = below(2) ? write_coil(out, UNIT, (uint16_t)(200 + below(16)), below(2))
                            : read_request(out, UNIT, 6, 0, (uint16_t)rnd());
        memcpy(last_write, out, n);
        *last_write_size = n;
        return n;
    }
    }
}

/* A foreign exchange: a request for another unit and its response (maybe
 * an exception, maybe none), the response's data perhaps hiding a
 * CRC-valid frame of ours. Returns the size of 'req' + 'rsp' in 'out'
 * for gluing, the request's size in *req_size. */
/* The last foreign_exchange() made its response read two ways on
 * purpose (smuggling_response): not a CRC match by chance. */
static bool smuggled;

static size_t foreign_exchange(uint8_t *out, size_t *req_size, bool *answered)
{
    smuggled = false;
    uint8_t unit = (uint8_t)(1 + below(247));
    if (unit == UNIT)
        unit = 18;
    unsigned fc = below(3) == 0 ? 16 : (unsigned)(1 + below(6));
    unsigned count = 1 + below(fc <= 2 ? 200 : 60);
    size_t n;
    if (fc == 16) {
        count = 1 + below(20);
        out[0] = unit, out[1] = 16, out[2] = 0, out[3] = (uint8_t)below(200);
        out[4] = 0, out[5] = (uint8_t)count, out[6] = (uint8_t)(2 * count);
        for (unsigned i = 0; i < 2 * count; i++)
            out[7 + i] = (uint8_t)rnd();
        if (count >= 6 && chance(50)) {
            uint8_t hidden[8];
            write_coil(hidden, UNIT, 101, true);
            memcpy(out + 7 + below(2 * count - 8 + 1), hidden, 8);
        }
        n = rtu_append_crc(out, 7 + 2 * count);
    } else if (fc == 5 || fc == 6) {
        n = read_request(out, unit, (uint8_t)fc, (uint16_t)rnd(), (uint16_t)rnd());
    } else {
        n = read_request(out, unit, (uint8_t)fc, (uint16_t)below(1000), (uint16_t)count);
    }
    *req_size = n;
    *answered = chance(85);
    if (!*answered)
        return n;
    uint8_t *rsp = out + n;
    if (chance(10)) {
        rsp[0] = unit, rsp[1] = (uint8_t)(fc | 0x80), rsp[2] = (uint8_t)(1 + below(4));
        return n + rtu_append_crc(rsp, 3);
    }
    if (fc == 5 || fc == 6) {
        memcpy(rsp, out, n);
        return 2 * n;
    }
    if (fc == 16) {
        memcpy(rsp, out, 6);
        return n + rtu_append_crc(rsp, 6);
    }
    size_t data = fc <= 2 ? (count + 7) / 8 : 2 * count;
    if ((fc == 3 || fc == 4) && data >= 16 && chance(50)) {
        /* The review's attack: the first 8 bytes and a frame of ours at 8. */
        uint8_t hidden[8];
        smuggled = true;
        write_coil(hidden, UNIT, 101, true);
        return n + smuggling_response(rsp, unit, (uint8_t)fc, hidden, 8, count);
    }
    rsp[0] = unit, rsp[1] = (uint8_t)fc, rsp[2] = (uint8_t)data;
    for (size_t i = 0; i < data; i++)
        rsp[3 + i] = (uint8_t)rnd();
    if (data >= 8 && chance(50)) {
        uint8_t hidden[8];
        write_coil(hidden, UNIT, (uint16_t)(200 + below(16)), true);
        memcpy(rsp + 3 + below((unsigned)(data - 8 + 1)), hidden, 8);
    }
    return n + rtu_append_crc(rsp, 3 + data);
}

/* Bytes meant to be no frame: none of their beginnings is one by chance
 * (a line that takes a request by its length would take it). */
static bool no_frame_in(const uint8_t *d, size_t n)
{
    for (size_t len = RTU_MIN_ADU; len <= n; len++)
        if (rtu_crc_ok(d, len))
            return false;
    return true;
}

/* Noise that is not, by chance, a whole frame (with the 'before' bytes
 * it follows: a frame and one byte 00 is one, as its CRC's low byte ends
 * the CRC of the rest). */
static size_t noise_after(uint8_t *out, size_t before)
{
    size_t n;
    do {
        n = 1 + below(12);
        for (size_t i = 0; i < n; i++)
            out[before + i] = (uint8_t)rnd();
    } while (rtu_crc_ok(out, before + n) || !no_frame_in(out + before, n));
    return n;
}

static size_t noise(uint8_t *out)
{
    return noise_after(out, 0);
}

/* Where to cut 'n' bytes into two runs that are no frame; 0: nowhere. */
static size_t cut_into_no_frames(const uint8_t *d, size_t n)
{
    for (int tries = 0; tries < 8; tries++) {
        size_t at = 1 + below((unsigned)n - 1);
        if (no_frame_in(d, at) && no_frame_in(d + at, n - at))
            return at;
    }
    return 0;
}

/* The echo of the frame we sent last, as the adapter gives it back:
 * without local_echo within the port's delivery bound (its definition),
 * with it up to 95 ms late; whole or in two pieces, delivered in order. */
static void echo_back(struct bus *b, bool local_echo, unsigned how)
{
    uint64_t end = b->r.l->tx_end_ns, bound = b->r.l->cfg.delivery_ns, at;
    if (!local_echo)
        at = b->r.reply_at + below((unsigned)(end - b->r.reply_at + bound - 50 * US));
    else
        at = end + below(how == 1 ? 95 * (unsigned)MS : 5 * (unsigned)MS);
    size_t split = b->r.reply_size > 4 && chance(50) ? 1 + below((unsigned)b->r.reply_size - 1)
                                                     : b->r.reply_size;
    if (at < b->r.now)
        at = b->r.now;
    if (!local_echo && at + 50 * US >= end + bound)
        return; /* the clock ran past the bound (a reply taken late): no echo */
    deliver(&b->r, at, b->r.reply, split);
    if (split < b->r.reply_size) {
        uint64_t at2 = at + below(local_echo ? 1 * (unsigned)MS : 100 * (unsigned)US);
        if (!local_echo && at2 >= end + bound - 50 * US)
            at2 = at;
        deliver(&b->r, at2, b->r.reply + split, b->r.reply_size - split);
        at = at2;
    }
    b->read_at = at;
    if (!local_echo)
        b->wire = b->wire > at ? b->wire : at; /* the master speaks after t3.5 more */
}

/* After our request: the line answers (or not, if it did not execute), the
 * echo comes back as the mode allows, the master waits. Without
 * local_echo, an echo of a write's reply (the request itself) is answered
 * again once, and that answer is echoed too. */
static void our_reply_and_echo(struct bus *b, bool local_echo)
{
    b->r.stop_at_reply = true; /* the echo comes as the reply goes out */
    run_to(&b->r, b->read_at + b->t35 + b->r.turnaround);
    if (!b->r.reply_at) /* taken after a sure silence: the line had lost its place */
        run_to(&b->r, b->read_at + b->t35 + RTU_PIECE_CHARS * b->char_ns +
                          b->r.l->cfg.delivery_ns + b->r.turnaround);
    b->r.stop_at_reply = false;
    if (!b->r.reply_at || b->r.reply_at < b->read_at)
        return; /* not answered: the master times out (the wire is free) */
    uint64_t end = b->r.l->tx_end_ns;
    if (end > b->wire)
        b->wire = end;
    unsigned how = below(4);
    if (how == 0 && !local_echo)
        return; /* an adapter that does not echo */
    size_t replies = b->r.replies;
    echo_back(b, local_echo, how);
    if (local_echo)
        return;
    b->r.stop_at_reply = true; /* the echo comes as the answer goes out */
    run_to(&b->r, b->read_at + b->t35 + RTU_PIECE_CHARS * b->char_ns +
                      b->r.l->cfg.delivery_ns + b->r.turnaround);
    b->r.stop_at_reply = false;
    if (b->r.replies == replies)
        return;
    if (b->r.l->tx_end_ns > b->wire)
        b->wire = b->r.l->tx_end_ns;
    echo_back(b, local_echo, how);
    run_to(&b->r, b->read_at + b->t35);
}

static void one_bus(unsigned long bus_no)
{
    static const unsigned bauds[] = {9600, 19200, 38400, 115200};
    struct bus b;
    bool local_echo = chance(50);
    bool pty = chance(20);
    uint8_t frame[600], last_write[8];
    size_t last_write_size = 0;

    memset(&b, 0, sizeof(b));
    rig_init(&b.r, bauds[below(4)], local_echo, pty);
    b.r.turnaround = (20 + below(400)) * US;
    b.char_ns = b.r.l->cfg.char_ns;
    b.t35 = b.r.l->cfg.t35_ns;
    b.jitter = below(2) ? 0 : (unsigned)(MS / 2);
    b.wire = b.read_at = b.r.now;
    b.careful = 1; /* the line starts not knowing where the bus stands */
    unsigned exchanges = 2 + below(14);
    for (unsigned e = 0; e < exchanges; e++) {
        unsigned what = below(100);
        uint64_t start = next_start(&b);
        if (what < 35) {
            /* Ours, whole. */
            size_t n = our_request(frame, last_write, &last_write_size);
            start = past_echo_window(&b, frame, n, start);
            b.r.reply_at = 0;
            transmit(&b, frame, n, start, 0, 0);
            expect_request(&b, frame, n);
            our_reply_and_echo(&b, local_echo);
            b.synced = true;
        } else if (what < 40) {
            /* Ours, broken: a pause inside, noise after it, or cut short. */
            size_t n = our_request(frame, last_write, &last_write_size);
            unsigned how = below(3);
            b.r.reply_at = 0;
            size_t cut = cut_into_no_frames(frame, n);
            if (!cut)
                continue;
            if (how == 0) {
                transmit(&b, frame, n, start, cut, b.t35 + 300 * b.char_ns + 3 * MS);
            } else if (how == 1) {
                /* Noise right after it, in the same read: the line cannot
                 * tell bytes glued on the wire from bytes a port hands
                 * over more than t3.5 after a whole frame. */
                size_t k = noise_after(frame, n);
                uint64_t end = start + (n + k) * b.char_ns;
                deliver(&b.r, end, frame, n + k);
                b.read_at = b.wire = end;
            } else {
                transmit(&b, frame, cut, start, 0, 0);
            }
            settle(&b);
            b.synced = false;
            b.careful = 1;
        } else if (what < 75) {
            /* A foreign exchange. */
            size_t req_size;
            bool answered;
            size_t n = foreign_exchange(frame, &req_size, &answered);
            transmit(&b, frame, req_size, start, 0, 0);
            if (answered)
                transmit(&b, frame + req_size, n - req_size, next_start(&b), 0, 0);
            else
                b.wire += 20 * MS; /* the master's response timeout */
            b.synced = true;
        } else if (what < 83) {
            /* A late reader: a foreign exchange and our request in one read. */
            size_t req_size;
            bool answered;
            size_t n = foreign_exchange(frame, &req_size, &answered);
            if (!answered) {
                transmit(&b, frame, req_size, start, 0, 0);
                b.wire += 20 * MS;
                b.synced = true;
                continue;
            }
            size_t m = our_request(frame + n, last_write, &last_write_size);
            start = past_echo_window(&b, frame, 0, start);
            uint64_t end = start + (n + m) * b.char_ns + 2 * b.t35;
            b.r.reply_at = 0;
            deliver(&b.r, end, frame, n + m);
            b.read_at = b.wire = end;
            /* Taken where the line knew where it stood, or after a sure
             * silence (where a line that lost its place parses what
             * came). */
            expect_request(&b, frame + n, m);
            our_reply_and_echo(&b, local_echo);
        } else if (what < 88) {
            /* A broadcast write: never executed, never answered. */
            size_t n = write_coil(frame, 0, (uint16_t)(200 + below(16)), true);
            transmit(&b, frame, n, start, 0, 0);
            b.wire += 5 * MS;
            b.synced = true;
        } else if (what < 95) {
            /* Noise on the line, between silences. */
            size_t n = noise(frame);
            transmit(&b, frame, n, start, 0, 0);
            settle(&b);
            b.synced = false;
            b.careful = 1;
        } else {
            /* A foreign frame with a pause inside. */
            size_t req_size;
            bool answered;
            foreign_exchange(frame, &req_size, &answered);
            size_t cut = cut_into_no_frames(frame, req_size);
            if (!cut)
                continue;
            transmit(&b, frame, req_size, start, cut, b.t35 + 300 * b.char_ns + 3 * MS);
            settle(&b);
            b.synced = false;
            b.careful = 1;
        }
    }
    run_to(&b.r, b.read_at + 200 * MS);
    /* The invariant: exactly the whole requests of ours, each once, in order. */
    bool same = b.r.executed == b.expected;
    for (size_t i = 0; same && i < b.expected && i < MAX_EXEC; i++)
        same = b.r.exec_size[i] == b.expect_size[i] &&
               memcmp(b.r.exec[i], b.expect[i], b.expect_size[i]) == 0;
    if (!same)
        fail_msg("bus %lu (local_echo %d, pty %d, %u baud): %zu requests executed, %zu "
                 "expected",
                 bus_no, local_echo, pty, 1000000000u / b.char_ns * 10, b.r.executed,
                 b.expected);
}

/* ---- the property test, as the field wires the line ---- */

/*
 * A master polling in cycles: up to three exchanges with other units
 * (reads, writes, FC08 "return query data" of any length, FC17, units
 * that do not answer), then a request of ours, answered; the adapter
 * giving each reply back 0-119 ms late (whole or in two pieces), with
 * either setting; gaps between frames from t3.5 to past the old resync
 * silence; masters with or without a t3.5 of their own after our reply.
 * Faults, in a quarter of the cycles: a noise burst before a frame or a
 * corrupted byte in one, a loop stalled 1-300 ms anywhere in the cycle.
 * Safety: what is executed is whole requests of ours, each once, in
 * order. Liveness: every request of ours from the second cycle after the
 * last fault on (the bus's start counting as one) is executed and
 * answered.
 */
#define FIELD_CYCLES_MAX 12

/* A cycle's frames as sent, back to back, to find CRC matches by chance
 * (chance_crc_in_cycle). */
struct cycle_log {
    uint8_t stream[2048];
    size_t stream_n, starts[16], lens[16], frames;
};

struct field {
    struct bus b;
    bool no_t35;          /* the master keeps no t3.5 after our reply */
    bool echoes;          /* the adapter gives our replies back */
    uint64_t echo_delay;  /* how late */
    uint64_t timeout;     /* the master's response timeout */
    int last_fault;       /* the cycle of the last fault */
    size_t sent;          /* whole requests of ours sent */
    uint8_t ours[FIELD_CYCLES_MAX][8];
    int ours_cycle[FIELD_CYCLES_MAX];
    struct cycle_log log;
};

static unsigned long field_cycles, field_chance_crcs;

/* A frame of the cycle on the wire: kept for chance_crc_in_cycle
 * ('crafted': one that reads two ways on purpose, never a chance). */
static void cycle_frame(struct cycle_log *f, const uint8_t *d, size_t n, bool crafted)
{
    if (f->frames < 16 && f->stream_n + n <= sizeof(f->stream)) {
        memcpy(f->stream + f->stream_n, d, n);
        f->starts[f->frames] = f->stream_n;
        f->lens[f->frames] = crafted ? 0 : n;
        f->frames++;
        f->stream_n += n;
    }
}

/* Does a frame of the cycle end in a valid CRC at a length other than its
 * own, by chance (2^-16 a length; the frames after it included)? Then the
 * bytes read two ways that the master did not mean, and a line that
 * cannot tell them apart drops what came: the cycle counts as a fault. */
static bool chance_crc_in_cycle(const struct cycle_log *f)
{
    for (size_t k = 0; k < f->frames; k++) {
        if (!f->lens[k])
            continue; /* crafted */
        const uint8_t *d = f->stream + f->starts[k];
        size_t left = f->stream_n - f->starts[k];
        /* One pass: the running CRC of the first len - 2 bytes. */
        uint16_t crc = 0xFFFF;
        for (size_t len = 3; len <= left && len <= RTU_MAX_ADU; len++) {
            crc ^= d[len - 3];
            for (int bit = 0; bit < 8; bit++)
                crc = (uint16_t)(crc & 1 ? (crc >> 1) ^ 0xA001 : crc >> 1);
            if (len >= RTU_MIN_ADU && len != f->lens[k] && d[len - 2] == (crc & 0xFF) &&
                d[len - 1] == (crc >> 8))
                return true;
        }
    }
    return false;
}

/* A gap between two frames of the master's cycle: t3.5 and up to past
 * the silence a line that lost its place waited for before. */
static uint64_t field_gap(const struct field *f)
{
    const struct rtu_line *l = f->b.r.l;
    uint64_t old_resync = (uint64_t)l->cfg.t35_ns + RTU_PIECE_CHARS * (uint64_t)l->cfg.char_ns +
                          l->cfg.delivery_ns;
    return l->cfg.t35_ns + f->b.jitter + below((unsigned)(old_resync + 2 * MS - l->cfg.t35_ns));
}

/* A foreign request in 'out' (its response, if any, after it): returns
 * the request's size, *rsp_size the response's (0: an absent unit). */
static size_t field_foreign(uint8_t *out, size_t *rsp_size)
{
    uint8_t unit = (uint8_t)(1 + below(247));
    size_t n;
    if (unit == UNIT)
        unit = 18;
    unsigned kind = below(6);
    if (kind == 0) {
        /* FC08 return query data: any data, repeated. */
        size_t data = below(11);
        out[0] = unit, out[1] = 8, out[2] = 0, out[3] = 0;
        for (size_t i = 0; i < data; i++)
            out[4 + i] = (uint8_t)rnd();
        n = rtu_append_crc(out, 4 + data);
        memcpy(out + n, out, n);
        *rsp_size = chance(85) ? n : 0;
        return n;
    }
    if (kind == 1) {
        /* FC17 report server id: 4 bytes; the response's own count. */
        out[0] = unit, out[1] = 17;
        n = rtu_append_crc(out, 2);
        uint8_t *rsp = out + n;
        size_t data = 2 + below(12);
        rsp[0] = unit, rsp[1] = 17, rsp[2] = (uint8_t)data;
        for (size_t i = 0; i < data; i++)
            rsp[3 + i] = (uint8_t)rnd();
        *rsp_size = chance(85) ? rtu_append_crc(rsp, 3 + data) : 0;
        return n;
    }
    bool answered;
    size_t req_size;
    size_t all = foreign_exchange(out, &req_size, &answered);
    *rsp_size = answered ? all - req_size : 0;
    return req_size;
}

/* The frame 'frame' on the wire from 'start', perhaps with a noise burst
 * before it (glued or not) or a byte of it corrupted: a fault in cycle
 * 'cycle'. Returns whether the frame went out whole. */
static bool field_frame(struct field *f, int cycle, uint8_t *frame, size_t n, uint64_t start,
                        bool fault)
{
    struct bus *b = &f->b;
    bool whole = true;
    if (fault) {
        f->last_fault = cycle;
        if (chance(50)) {
            uint8_t burst[16];
            size_t k = noise(burst);
            uint64_t gap = b->char_ns + below((unsigned)(2 * b->t35));
            transmit(b, burst, k, start, 0, 0);
            start = b->wire + gap;
        } else {
            size_t at = below((unsigned)n);
            frame[at] ^= (uint8_t)(1 + below(255));
            whole = !rtu_crc_ok(frame, n) ? false : true;
            if (whole) /* by chance still a frame: keep it simple */
                frame[at] ^= 0, whole = false;
        }
    }
    transmit(b, frame, n, start, 0, 0);
    return whole;
}

/* A function the server carries out (mb_server.c), anything else an
 * exception 01. */
static bool known_function(uint8_t fc)
{
    static const uint8_t known[] = {1, 2, 3, 4, 5, 6, 8, 15, 16, 17, 22, 23, 43};
    for (size_t i = 0; i < sizeof(known); i++)
        if (known[i] == fc)
            return true;
    return false;
}

/* The adapter gives our last frame back 'echo_delay' after its wire time
 * (whole, or in two pieces: the second within the port's latency without
 * local_echo, up to 100 ms later with it, a fault of this cycle). */
static void field_echo(const uint8_t *reply, size_t size, struct field *f, int cycle,
                       bool local_echo)
{
    struct bus *b = &f->b;
    uint64_t end = b->r.l->tx_end_ns, at = end + f->echo_delay;
    size_t split = size > 4 && chance(30) ? 1 + below((unsigned)size - 1) : size;
    if (at < b->read_at)
        at = b->read_at;
    if (at < b->r.now)
        at = b->r.now;
    if (!local_echo && at >= end + b->r.l->cfg.delivery_ns)
        return; /* the clock ran past the bound (a stall, a late reply): no echo */
    deliver(&b->r, at, reply, split);
    b->read_at = at;
    if (split < size) {
        if (local_echo) {
            /* A piece later than the port's latency holds what follows
             * it (the master's next frames, glued: their silences lost).
             * The line may lose the next cycle (never executing any of it
             * twice). */
            f->last_fault = cycle;
            at += below(100 * (unsigned)MS);
        }
        deliver(&b->r, at, reply + split, size - split);
        b->read_at = at;
    }
}

static void one_field_bus(unsigned long bus_no)
{
    static const unsigned bauds[] = {9600, 19200, 38400, 115200};
    struct field f;
    struct bus *b = &f.b;
    bool local_echo = chance(50);
    uint8_t frame[600];

    memset(&f, 0, sizeof(f));
    rig_init(&b->r, bauds[below(4)], local_echo, chance(20));
    b->r.turnaround = (20 + below(400)) * US;
    b->char_ns = b->r.l->cfg.char_ns;
    b->t35 = b->r.l->cfg.t35_ns;
    b->jitter = chance(50) ? 0 : (unsigned)(MS / 2);
    b->wire = b->read_at = b->r.now;
    f.no_t35 = chance(30);
    f.echoes = local_echo || chance(50);
    switch (below(4)) {
    case 0: f.echo_delay = below(b->t35); break;
    case 1: f.echo_delay = b->t35 + below(4 * (unsigned)MS); break;
    case 2: f.echo_delay = below(20 * (unsigned)MS); break;
    default: f.echo_delay = below(119 * (unsigned)MS); break;
    }
    f.timeout = (400 + below(200)) * MS;
    /* The port's lateness: the echo's delay, for every byte received; the
     * line is told it as the adapter's delivery bound. */
    b->latency = f.echoes ? f.echo_delay : below(2) * below(16 * (unsigned)MS);
    b->r.l->cfg.delivery_ns += b->latency + 2 * b->jitter;
    f.last_fault = -1; /* the line starts not knowing where the bus stands */
    int cycles = 3 + (int)below(FIELD_CYCLES_MAX - 2);
    uint64_t start = b->r.now + 50 * MS;
    for (int c = 0; c < cycles; c++) {
        bool fault = chance(25);
        /* Where in the cycle the fault falls: a stall, or a frame's. */
        int fault_frame = fault && chance(70) ? (int)below(4) : -1;
        /* A stall that lasts into this cycle is a fault in it too. */
        if (b->r.stall_until > start)
            f.last_fault = c;
        if (fault && fault_frame < 0 && !b->r.stall_until) {
            f.last_fault = c;
            b->r.stall_from = start + below(60 * (unsigned)MS);
            b->r.stall_until = b->r.stall_from + (1 + below(300)) * MS;
        }
        unsigned foreign = below(4);
        f.log.stream_n = f.log.frames = 0;
        for (unsigned i = 0; i < foreign; i++) {
            size_t rsp_size;
            size_t n = field_foreign(frame, &rsp_size);
            field_frame(&f, c, frame, n, start, fault_frame == (int)i);
            cycle_frame(&f.log, frame, n, false);
            if (rsp_size) {
                cycle_frame(&f.log, frame + n, rsp_size, smuggled);
                transmit(b, frame + n, rsp_size, b->wire + field_gap(&f), 0, 0);
                start = b->wire + field_gap(&f);
            } else {
                /* The master gives up on an absent unit: soon or late. */
                start = b->wire + (chance(50) ? field_gap(&f) : 20 * MS);
            }
        }
        /* Ours: a read or a write, each distinct (never our last reply). */
        size_t n = c & 1 ? read_request(frame, UNIT, 4, (uint16_t)c, 1)
                         : read_request(frame, UNIT, 6, 0, (uint16_t)(c + 1000 * below(60)));
        uint8_t sent[8];
        memcpy(sent, frame, 8);
        size_t replies = b->r.replies;
        bool whole = field_frame(&f, c, frame, n, start, fault_frame == 3);
        cycle_frame(&f.log, frame, n, false);
        field_cycles++;
        if (chance_crc_in_cycle(&f.log)) {
            f.last_fault = c;
            field_chance_crcs++;
        }
        if (whole) {
            trace_bytes("expected", b->r.now, sent, 8);
            memcpy(f.ours[f.sent], sent, 8);
            f.ours_cycle[f.sent++] = c;
        }
        uint64_t asked = b->read_at;
        /* The line answers (after a stall, or the wait of a line that
         * lost its place), or the master times out: it waits for the
         * reply up to its timeout, as a master does. */
        uint64_t stall_end = b->r.stall_until;
        b->r.stop_at_reply = true;
        run_to(&b->r, (stall_end > asked ? stall_end : asked) + f.timeout);
        b->r.stop_at_reply = false;
        if (b->r.replies == replies) {
            start = b->r.now + b->t35 + field_gap(&f);
            continue;
        }
        uint64_t end = b->r.l->tx_end_ns;
        if (f.echoes) {
            field_echo(f.b.r.reply, b->r.reply_size, &f, c, local_echo);
            if (!local_echo) {
                /* A write's reply is the request: its echo is answered
                 * again once, and that answer echoed too. */
                size_t before = b->r.replies;
                b->r.stop_at_reply = true;
                run_to(&b->r, b->read_at + b->t35 + RTU_PIECE_CHARS * b->char_ns +
                                  b->r.l->cfg.delivery_ns + b->r.turnaround);
                b->r.stop_at_reply = false;
                if (b->r.replies > before) {
                    end = b->r.l->tx_end_ns;
                    field_echo(b->r.reply, b->r.reply_size, &f, c, local_echo);
                }
            }
        }
        b->wire = end;
        start = end + (f.no_t35 ? below(b->t35) : b->t35 + b->jitter + field_gap(&f));
    }
    run_to(&b->r, start + 1000 * MS);
    /* Safety: a subsequence of our whole requests, each once, in order. */
    size_t next = 0;
    for (size_t i = 0; i < b->r.executed && i < MAX_EXEC; i++) {
        /* Bytes of ours that a CRC-16 passes by chance (2^-16), whose
         * function the server does not know: answered with exception 01,
         * nothing acted on. */
        if (b->r.exec_size[i] != 8 && !known_function(b->r.exec[i][1]))
            continue;
        while (next < f.sent && memcmp(f.ours[next], b->r.exec[i], 8) != 0)
            next++;
        if (next == f.sent || b->r.exec_size[i] != 8)
            fail_msg("field bus %lu (local_echo %d, echo %d after %.2f ms, no t3.5 %d, %u baud): "
                     "executed #%zu is no request of ours sent after the one before",
                     bus_no, local_echo, f.echoes, f.echo_delay / 1e6, f.no_t35,
                     1000000000u / b->char_ns * 10, i);
        next++;
    }
    /* Liveness: from the second cycle after the last fault, all of ours. */
    for (size_t k = 0; k < f.sent; k++) {
        if (f.ours_cycle[k] < f.last_fault + 2)
            continue;
        bool done = false;
        for (size_t i = 0; i < b->r.executed && i < MAX_EXEC && !done; i++)
            done = memcmp(f.ours[k], b->r.exec[i], 8) == 0;
        if (!done)
            fail_msg("field bus %lu (local_echo %d, echo %d after %.2f ms, no t3.5 %d, %u baud): "
                     "our request of cycle %d (last fault in %d) never executed",
                     bus_no, local_echo, f.echoes, f.echo_delay / 1e6, f.no_t35,
                     1000000000u / b->char_ns * 10, f.ours_cycle[k], f.last_fault);
    }
    if (b->r.replies != b->r.executed + b->r.l->stats.repeats)
        fail_msg("field bus %lu: %zu executed, %llu answered again, %zu replies", bus_no,
                 b->r.executed, (unsigned long long)b->r.l->stats.repeats, b->r.replies);
}

static void field_buses_keep_safety_and_liveness(void **state)
{
    const char *env = getenv("RTU_FIELD_BUSES"), *seed_env = getenv("RTU_PROPERTY_SEED");
    unsigned long buses = env ? strtoul(env, NULL, 10) : 100000 / emulated();
    uint64_t seed = seed_env ? strtoull(seed_env, NULL, 0)
                             : (uint64_t)time(NULL) * 2654435761u ^ (uint64_t)getpid() << 32 ^
                                   (uint64_t)clock();
    unsigned long first = getenv("RTU_PROPERTY_BUS") ? strtoul(getenv("RTU_PROPERTY_BUS"), NULL, 10)
                                                      : 0;
    (void)state;
    trace = getenv("RTU_PROPERTY_TRACE") != NULL;
    if (!seed)
        seed = 1;
    printf("rtu field property: %lu buses, RTU_PROPERTY_SEED=0x%llx\n", buses,
           (unsigned long long)seed);
    fflush(stdout);
    server = NULL;
    for (unsigned long i = first; i < first + buses; i++) {
        rng_state = seed + i * 0x9E3779B97F4A7C15ull;
        if (!rng_state)
            rng_state = 1;
        rnd();
        one_field_bus(i);
    }
    printf("rtu field property: %lu cycles, %lu with a CRC match by chance (a fault)\n",
           field_cycles, field_chance_crcs);
}

/* ---- the property test, through USB adapters, with masters that retry ---- */

/*
 * A master polling through one adapter of usb_adapter.h (every byte in
 * its packets), the line told the adapter's bound: per cycle up to two
 * exchanges with other units (reads of up to 125 registers whose data
 * hides writes for our unit; user-defined codes, 65-72 and 100-110, to
 * absent units; each unit once a cycle: the same unit and code again
 * right after could be that unit's answer, whose data is never
 * searched), then a request of ours (a read, or a write: half the
 * time the very write of the cycle before, a cyclic rewrite). A reply of
 * ours is lost on its way to the master at random; the master then sends
 * the same frame again after its timeout (20-1000 ms, never shorter than
 * the reply's wire time), up to its retries (1-3).
 * Safety: what is executed is our transmissions, in order, each once.
 * Liveness: every first transmission and every first retry is answered
 * (executed, or within the delivery bound answered again), except our
 * last reply's bytes again within the bound after it was answered again
 * once (an echo, by the rule: a rewrite or retry faster than the reply's
 * wire time and the bound).
 */
#define USB_SENT_MAX 48

/* What the buses did, over a run: said at its end. */
static struct {
    unsigned long sent, retries, repeats, executed, foreign_hidden;
} usb_totals;

struct usb_bus {
    struct rig r;
    struct usb_port port;
    uint64_t char_ns;
    size_t sent; /* our transmissions */
    uint8_t frames[USB_SENT_MAX][8];
    uint8_t polled; /* the unit polled last in this cycle: a master polls each once */
    struct cycle_log log;
};

/* A request for another unit and what follows it on the wire. */
static uint64_t usb_foreign(struct usb_bus *u, uint64_t t)
{
    uint8_t req[16], rsp[RTU_MAX_ADU];
    uint64_t c = u->char_ns, t35 = u->r.l->cfg.t35_ns;
    uint8_t unit = (uint8_t)(1 + below(247));
    while (unit == UNIT || unit == u->polled)
        unit = (uint8_t)(1 + below(247));
    u->polled = unit;
    if (chance(40)) {
        /* A user-defined code to a unit that does not answer. */
        static const uint8_t codes[] = {65, 66, 70, 72, 100, 104, 110};
        req[0] = unit, req[1] = codes[below(sizeof(codes))];
        size_t data = below(9);
        for (size_t i = 0; i < data; i++)
            req[2 + i] = (uint8_t)rnd();
        size_t n = rtu_append_crc(req, 2 + data);
        cycle_frame(&u->log, req, n, false);
        t = usb_wire(&u->r, &u->port, req, n, t, c);
        return t + (chance(50) ? t35 + below(2 * (unsigned)MS) : 20 * MS);
    }
    unsigned count = 1 + below(125);
    cycle_frame(&u->log, req, read_request(req, unit, 3, (uint16_t)below(1000), (uint16_t)count),
                false);
    t = usb_wire(&u->r, &u->port, req, 8, t, c);
    rsp[0] = unit, rsp[1] = 3, rsp[2] = (uint8_t)(2 * count);
    for (unsigned i = 0; i < 2 * count; i++)
        rsp[3 + i] = (uint8_t)rnd();
    for (size_t at = 3 + below(8); at + 8 <= 3 + 2 * count; at += 8 + below(32))
        write_coil(rsp + at, UNIT, (uint16_t)(200 + below(16)), true);
    size_t n = rtu_append_crc(rsp, 3 + 2 * count);
    cycle_frame(&u->log, rsp, n, false);
    t = usb_wire(&u->r, &u->port, rsp, n, t + t35 + below(3 * (unsigned)MS), c);
    return t + t35 + below(3 * (unsigned)MS);
}

/* One transmission of ours at 't'; returns whether it was answered
 * (a reply went out for it), and the time the master may go on. */
static bool usb_ours(struct usb_bus *u, const uint8_t *frame, uint64_t *t)
{
    size_t replies = u->r.replies;
    if (u->sent < USB_SENT_MAX)
        memcpy(u->frames[u->sent], frame, 8);
    u->sent++;
    trace_bytes("sent", *t, frame, 8);
    *t = usb_wire(&u->r, &u->port, frame, 8, *t, u->char_ns);
    usb_idle(&u->r, &u->port, *t + 100 * MS);
    /* The last piece comes by the adapter's timer and a USB frame; a line
     * that reads what came two ways waits t3.5, a port's piece and the
     * bound beyond it (rtu_frame.h). */
    u->r.stop_at_reply = true;
    run_to(&u->r, *t + (uint64_t)u->port.adapter->latency_ms * MS + USB_FRAME_NS +
                      u->r.l->cfg.delivery_ns + RTU_PIECE_CHARS * u->char_ns +
                      u->r.l->cfg.t35_ns + 5 * MS);
    u->r.stop_at_reply = false;
    return u->r.replies > replies;
}

static void one_usb_bus(unsigned long bus_no)
{
    static const unsigned bauds[] = {9600, 19200, 38400, 115200};
    struct usb_bus u;
    const struct usb_adapter *a = &usb_adapters[below(sizeof(usb_adapters) /
                                                      sizeof(usb_adapters[0]))];
    uint8_t ours[8], last_write[8];
    bool have_write = false;

    memset(&u, 0, sizeof(u));
    rig_init(&u.r, bauds[below(4)], false, chance(20));
    u.r.turnaround = (20 + below(400)) * US;
    u.r.l->cfg.delivery_ns += (uint64_t)a->latency_ms * MS;
    u.char_ns = u.r.l->cfg.char_ns;
    start_synced(&u.r);
    u.port.adapter = a;
    u.port.phase_ns = u.r.now + below(a->latency_ms * 1000) * US;
    unsigned retries = 1 + below(3);
    uint64_t timeout = (20 + below(981)) * MS;
    uint64_t t = u.r.now + 20 * MS;
    unsigned cycles = 2 + below(8);
    for (unsigned c = 0; c < cycles && u.sent + 4 <= USB_SENT_MAX; c++) {
        u.polled = 0;
        u.log.stream_n = u.log.frames = 0;
        for (unsigned f = below(3); f > 0; f--)
            t = usb_foreign(&u, t);
        if (have_write && chance(50)) {
            memcpy(ours, last_write, 8); /* the same write again */
        } else if (chance(50)) {
            read_request(ours, UNIT, 4, (uint16_t)below(6000), (uint16_t)(1 + below(20)));
        } else {
            write_coil(ours, UNIT, (uint16_t)(200 + below(16)), below(2));
            memcpy(last_write, ours, 8);
            have_write = true;
        }
        /* The reply's wire time bounds the master's timeout from below. */
        uint64_t reply_wire = (5 + 40) * u.char_ns + u.r.l->cfg.t35_ns + 5 * MS;
        uint64_t wait = timeout > reply_wire ? timeout : reply_wire;
        cycle_frame(&u.log, ours, 8, false);
        /* A CRC match by chance in the cycle: bytes that read two ways,
         * which a line may drop (a fault, not checked for liveness). */
        bool chance_crc = chance_crc_in_cycle(&u.log);
        for (unsigned k = 0; k <= retries; k++) {
            uint64_t asked = t;
            /* Our last reply again, within the bound, after it was already
             * answered again once: an echo, by the rule (rtu_frame.h). */
            const struct rtu_line *l = u.r.l;
            bool may_skip = l->sent_size == 8 && memcmp(ours, l->sent, 8) == 0 &&
                            l->repeat_answered && t < rtu_line_bound_end_ns(l);
            bool answered = usb_ours(&u, ours, &t);
            if (!answered && k <= 1 && !may_skip && !chance_crc)
                fail_msg("usb bus %lu (%s, %u baud, timeout %llu ms, %u retries): cycle %u, "
                         "%s not answered",
                         bus_no, a->name, 1000000000u / (unsigned)u.char_ns * 10, 
                         (unsigned long long)(timeout / MS), retries, c,
                         k ? "the first retry" : "the request");
            bool lost = answered && chance(25);
            if (answered && !lost)
                break;
            t = asked + wait; /* the master's timeout, then the same frame */
            usb_totals.retries += k < retries;
            if (t < u.r.now)
                t = u.r.now;
        }
        uint64_t free_at = u.r.l->tx_end_ns + u.r.l->cfg.t35_ns + 1 * MS;
        t = (free_at > t ? free_at : t) + below(5 * (unsigned)MS);
        if (t < u.r.now)
            t = u.r.now;
    }
    usb_idle(&u.r, &u.port, t + 200 * MS);
    run_to(&u.r, t + 300 * MS);
    usb_totals.sent += u.sent;
    usb_totals.repeats += u.r.l->stats.repeats;
    usb_totals.executed += u.r.executed;
    /* Safety: our transmissions, in order, each at most once. */
    size_t next = 0;
    for (size_t i = 0; i < u.r.executed && i < MAX_EXEC; i++) {
        while (next < u.sent && next < USB_SENT_MAX &&
               (u.r.exec_size[i] != 8 || memcmp(u.frames[next], u.r.exec[i], 8) != 0))
            next++;
        if (next >= u.sent || next >= USB_SENT_MAX)
            fail_msg("usb bus %lu (%s): executed #%zu is no transmission of ours after the "
                     "one before",
                     bus_no, a->name, i);
        next++;
    }
}

static void usb_buses_with_retrying_masters(void **state)
{
    const char *env = getenv("RTU_USB_BUSES"), *seed_env = getenv("RTU_PROPERTY_SEED");
    unsigned long buses = env ? strtoul(env, NULL, 10) : 20000 / emulated();
    uint64_t seed = seed_env ? strtoull(seed_env, NULL, 0)
                             : (uint64_t)time(NULL) * 2654435761u ^ (uint64_t)getpid() << 32 ^
                                   (uint64_t)clock() ^ 0x5B;
    unsigned long first = getenv("RTU_PROPERTY_BUS") ? strtoul(getenv("RTU_PROPERTY_BUS"), NULL, 10)
                                                      : 0;
    (void)state;
    if (!seed)
        seed = 1;
    printf("rtu usb property: %lu buses, RTU_PROPERTY_SEED=0x%llx\n", buses,
           (unsigned long long)seed);
    fflush(stdout);
    server = NULL;
    for (unsigned long i = first; i < first + buses; i++) {
        rng_state = seed + i * 0x9E3779B97F4A7C15ull;
        if (!rng_state)
            rng_state = 1;
        rnd();
        one_usb_bus(i);
    }
    printf("rtu usb property: %lu transmissions of ours (%lu retries), %lu executed, %lu "
           "answered again within the bound\n",
           usb_totals.sent, usb_totals.retries, usb_totals.executed, usb_totals.repeats);
}

static void server_open(struct server_path *p)
{
    struct mb_server_config cfg = {.bind = "127.0.0.1", .port = 0, .max_clients = 8,
                                   .frame_timeout_ms = 1000, .unit_id = -1};
    struct mb_server_hooks hooks = {0};
    int pair[2];

    memset(p, 0, sizeof(*p));
    assert_int_equal(uv_loop_init(&p->loop), 0);
    assert_int_equal(regmap_init(&p->map), 0);
    assert_int_equal(regmap_image_init(&p->img, &p->map, REGMAP_HIGH_WORD_FIRST), 0);
    hooks.user = p;
    assert_int_equal(mb_server_start(&p->loop, &p->srv, &cfg, &p->img, &hooks), 0);
    assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0, pair), 0);
    p->rtu.loop = &p->loop;
    p->rtu.srv = &p->srv;
    p->rtu.fd = pair[0];
    p->peer = pair[1];
    p->rtu.timer_fd = -1; /* the test's clock runs the silences */
    p->rtu.now_ns = fake_clock;
    p->rtu.cfg.unit_id = UNIT;
    p->rtu.cfg.rights = REGMAP_RIGHTS_NONE; /* writes: exception 01, answered */
    p->rtu.log_limit.interval_ms = 1000;
    snprintf(p->rtu.device, sizeof(p->rtu.device), "test");
    snprintf(p->rtu.peer, sizeof(p->rtu.peer), "rtu:test");
}

static void on_test_server_closed(struct mb_server *srv)
{
    struct server_path *p = srv->hooks.user;
    p->closed = true;
}

static void server_close(struct server_path *p)
{
    if (p->rtu.client)
        mb_client_release(p->rtu.client, NULL);
    mb_server_close(&p->srv, on_test_server_closed);
    while (!p->closed)
        uv_run(&p->loop, UV_RUN_ONCE);
    close(p->rtu.fd);
    close(p->peer);
    regmap_image_free(&p->img);
    regmap_free(&p->map);
    assert_int_equal(uv_loop_close(&p->loop), 0);
}

static void generated_buses_execute_exactly_our_whole_requests(void **state)
{
    const char *env = getenv("RTU_PROPERTY_BUSES"), *seed_env = getenv("RTU_PROPERTY_SEED");
    unsigned long buses = env ? strtoul(env, NULL, 10) : 50000 / emulated();
    uint64_t seed = seed_env ? strtoull(seed_env, NULL, 0)
                             : (uint64_t)time(NULL) * 2654435761u ^ (uint64_t)getpid() << 32 ^
                                   (uint64_t)clock();
    (void)state;
    trace = getenv("RTU_PROPERTY_TRACE") != NULL;
    if (!seed)
        seed = 1;
    printf("rtu property: %lu buses, RTU_PROPERTY_SEED=0x%llx\n", buses,
           (unsigned long long)seed);
    fflush(stdout);
    unsigned long first = getenv("RTU_PROPERTY_BUS") ? strtoul(getenv("RTU_PROPERTY_BUS"), NULL, 10)
                                                      : 0;
    /* Every tenth bus (RTU_PROPERTY_SERVER_EVERY) goes through the
     * transport's request path to a real server, whose replies are the
     * ones sent (and heard back). */
    const char *every_env = getenv("RTU_PROPERTY_SERVER_EVERY");
    unsigned long every = every_env ? strtoul(every_env, NULL, 10) : 10;
    static struct server_path path;
    unsigned long via_server = 0;
    server_open(&path);
    for (unsigned long i = first; i < first + buses; i++) {
        /* Each bus from its own seed: a failure names one to replay. */
        rng_state = seed + i * 0x9E3779B97F4A7C15ull;
        if (!rng_state)
            rng_state = 1;
        rnd();
        server = every && i % every == 0 ? &path : NULL;
        via_server += server != NULL;
        one_bus(i);
    }
    server = NULL;
    uint64_t served = path.srv.stats.requests;
    server_close(&path);
    printf("rtu property: %lu buses through the server, %llu requests served\n", via_server,
           (unsigned long long)served);
}

int main(void)
{
    trace = getenv("RTU_PROPERTY_TRACE") != NULL;
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(crc_matches_the_specification),
        cmocka_unit_test(character_times),
        cmocka_unit_test(response_lengths_read_only_the_request),
        cmocka_unit_test(every_function_is_cut_by_the_conversation),
        cmocka_unit_test(a_frame_hidden_in_a_response_is_never_executed),
        cmocka_unit_test(a_pause_inside_a_frame_discards_it),
        cmocka_unit_test(a_frame_in_pieces_is_whole),
        cmocka_unit_test(an_echo_in_our_turn_is_never_executed),
        cmocka_unit_test(local_echo_is_taken_off_the_input),
        cmocka_unit_test(an_echo_is_judged_by_its_arrival),
        cmocka_unit_test(a_repeated_write_is_executed_each_time),
        cmocka_unit_test(our_request_must_end_its_chunk),
        cmocka_unit_test(a_spoiled_echo_never_costs_the_next_request),
        cmocka_unit_test(an_exception_form_for_us_is_skipped),
        cmocka_unit_test(a_paused_request_like_our_reply_is_never_executed),
        cmocka_unit_test(our_frames_keep_t35_apart),
        cmocka_unit_test(an_echo_is_never_a_request),
        cmocka_unit_test(the_delivery_bound_is_read_back),
        cmocka_unit_test(usb_adapters_deliver_whole_conversations),
        cmocka_unit_test(the_same_write_after_the_window_is_answered),
        cmocka_unit_test(a_stall_never_makes_an_echo_a_request),
        cmocka_unit_test(a_busy_bus_regains_its_place_after_noise),
        cmocka_unit_test(user_codes_of_another_unit_are_cut_by_length),
        cmocka_unit_test(a_master_without_t35_is_answered),
        cmocka_unit_test(a_reserved_code_gets_no_length_search),
        cmocka_unit_test(a_garbage_byte_before_our_request_costs_nothing),
        cmocka_unit_test(a_noise_byte_never_makes_an_echo_a_request),
        cmocka_unit_test(ftdi_poll_cycles_execute_only_ours),
        cmocka_unit_test(generated_buses_execute_exactly_our_whole_requests),
        cmocka_unit_test(field_buses_keep_safety_and_liveness),
        cmocka_unit_test(usb_buses_with_retrying_masters),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
