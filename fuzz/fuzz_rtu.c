/* SPDX-License-Identifier: MIT */
/*
 * fuzz_rtu.c - libFuzzer target: the serial line's conversation model
 * (struct rtu_line, rtu_frame.h) fed an arbitrary bus, checked against the
 * invariant of the property test in tests/test_rtu_frame.c: the requests
 * executed are exactly the whole requests addressed to our unit, each once,
 * in order.
 *
 * Input: one byte of setup (baud, local_echo, pty), then events of a bus,
 * each a tag byte and its bytes, every frame between silences the line can
 * be sure of, delivered in pieces as a port hands them over:
 *   tag % 8 == 0: a request of ours (function 1..6, 8 bytes, CRC made
 *      good): it must be executed, once; our reply goes out;
 *   1: one byte of noise (the line loses its place), then 'len' arbitrary
 *      bytes: executed only if the run, whole, is a request of ours;
 *   2: our last reply given back ((tag >> 3) & 15 sixteenths of the
 *      port's delivery bound late; with local_echo, that many times
 *      3.75 ms), read at once or (tag & 0x80) by a loop stalled 300 ms:
 *      never executed (without local_echo, a write's reply, which is the
 *      request, is answered again once, not executed);
 *   3: a read of 'len' / 2 registers of another unit and its response,
 *      the arbitrary bytes its register data: nothing executed;
 *   4: a write of those bytes to another unit's registers (16) and its
 *      response: nothing executed;
 *   5: a busy poll cycle: a read of another unit, its response (the
 *      arbitrary bytes its data; or none: an absent unit), a request of
 *      ours, gaps between t3.5 and t3.5 + 16 characters + the port's
 *      delivery: safety as everywhere, and liveness: ours executed in
 *      every such cycle after one that was (a line that lost its place
 *      regains it within a cycle);
 *   6, 7: a silence of (tag >> 3) milliseconds.
 * Invariants: safety (exactly the whole requests of ours that the input
 * made, each once, in order: abort otherwise) and liveness (the requests
 * of tag 0, and of tag 5 after a cycle that was served, executed).
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "rtu_frame.h"

#define UNIT 17
#define MS 1000000ull

struct bus {
    struct rtu_line line;
    uint64_t now;
    size_t executed, expected;
    uint8_t last[RTU_MAX_ADU];
    size_t last_size;
    uint8_t want[RTU_MAX_ADU];
    size_t want_size;
    bool want_one;
    uint8_t reply[RTU_MAX_ADU];
    size_t reply_size;
    bool reply_due;
    bool echoed;          /* our last reply was given back */
    unsigned served_cycles; /* busy cycles served in a row */
};

static void on_request(void *user, const uint8_t *frame, size_t size)
{
    struct bus *b = user;
    /* Only what the input made a whole request of ours, once. */
    if (!b->want_one || size != b->want_size || memcmp(frame, b->want, size) != 0)
        abort();
    b->want_one = false;
    b->executed++;
    memcpy(b->reply, frame, size);
    b->reply_size = size;
    b->reply_due = true;
}

/* Our last reply again (rtu_frame.h): nothing executed. */
static void on_repeat(void *user)
{
    struct bus *b = user;
    b->reply_due = true;
}

static const struct rtu_line_hooks hooks = {.request = on_request, .repeat = on_repeat};

static void run_to(struct bus *b, uint64_t t)
{
    uint64_t due;
    while ((due = rtu_line_deadline(&b->line)) != 0 && due <= t) {
        if (due > b->now)
            b->now = due;
        struct rtu_line_hooks h = hooks;
        h.user = b;
        rtu_line_silence(&b->line, b->now, &h);
        if (b->reply_due) {
            b->reply_due = false;
            uint64_t at = b->now + 100000, ready = rtu_line_tx_ready_ns(&b->line);
            if (ready > at)
                at = ready;
            b->now = at;
            rtu_line_frame_out(&b->line, b->reply, b->reply_size);
            rtu_line_bytes_out(&b->line, b->reply_size, at);
            b->echoed = false;
        }
    }
    if (t > b->now)
        b->now = t;
}

/* A silence the line can be sure of, before or after any run. */
static uint64_t sure(const struct bus *b)
{
    return 2 * ((uint64_t)b->line.cfg.t35_ns + RTU_PIECE_CHARS * (uint64_t)b->line.cfg.char_ns +
                b->line.cfg.delivery_ns) +
           (b->line.cfg.local_echo ? RTU_LOCAL_ECHO_WINDOW_NS : b->line.cfg.delivery_ns);
}

static void deliver(struct bus *b, uint64_t t, const uint8_t *data, size_t size)
{
    struct rtu_line_hooks h = hooks;
    h.user = b;
    run_to(b, t);
    rtu_line_input(&b->line, data, size, b->now, &h);
}

/* Is this run, whole, a request of ours? */
static bool ours(const uint8_t *d, size_t n)
{
    size_t len;
    enum rtu_length how;
    if (n < RTU_MIN_ADU || n > RTU_MAX_ADU || d[0] != UNIT || !rtu_crc_ok(d, n))
        return false;
    how = rtu_request_length(d, n, &len);
    return how == RTU_LENGTH_UNKNOWN || (how == RTU_LENGTH_EXACT && len == n);
}

static void expect(struct bus *b, const uint8_t *frame, size_t size)
{
    memcpy(b->want, frame, size);
    b->want_size = size;
    b->want_one = true;
    b->expected++;
}

/* The next byte says how many bytes follow (at most 'max'). */
static size_t take(const uint8_t *data, size_t size, size_t *at, size_t max)
{
    if (*at >= size)
        return 0;
    size_t n = data[(*at)++];
    if (n > max)
        n = max;
    if (n > size - *at)
        n = size - *at;
    return n;
}

/* A frame (or run) on the wire after a sure silence, in pieces of up to 16
 * bytes their wire time apart (the piece sizes from 'sizes', if given),
 * and a sure silence after it. */
static void send(struct bus *b, const uint8_t *frame, size_t size, const uint8_t *sizes,
                 size_t sizes_n)
{
    uint64_t t = b->now + sure(b);
    for (size_t off = 0, i = 0; off < size; i++) {
        size_t piece = sizes && sizes_n ? 1 + (sizes[i % sizes_n] & 15) : 8;
        if (piece > size - off)
            piece = size - off;
        t += piece * b->line.cfg.char_ns;
        deliver(b, t, frame + off, piece);
        off += piece;
    }
    run_to(b, b->now + sure(b));
}

/* 'frame' on the wire from 't', in one piece (a pty) or two (a port),
 * delivered at its last byte's wire time; returns that time. */
static uint64_t put(struct bus *b, const uint8_t *frame, size_t n, uint64_t t)
{
    t += n * b->line.cfg.char_ns;
    deliver(b, t, frame, n);
    return t;
}

static void busy_cycle(struct bus *b, const uint8_t *data, size_t size, size_t *at, uint8_t tag)
{
    uint8_t req[8], rsp[RTU_MAX_ADU], ours[8] = {UNIT, 4, 0, 0, 0, 1};
    size_t n = take(data, size, at, 16) & ~(size_t)1;
    uint8_t unit = (uint8_t)(tag >> 3);
    const struct rtu_line_config *c = &b->line.cfg;
    uint64_t span = (uint64_t)RTU_PIECE_CHARS * c->char_ns + c->delivery_ns;
    uint64_t gap = c->t35_ns + 50000 + (n ? data[*at] : 0) * span / 256;
    bool absent = n == 0;

    if (unit == UNIT || unit == RTU_BROADCAST)
        unit = 18;
    req[0] = unit, req[1] = 3, req[2] = 0, req[3] = 0, req[4] = 0, req[5] = (uint8_t)(n / 2);
    rtu_append_crc(req, 6);
    rsp[0] = unit, rsp[1] = 3, rsp[2] = (uint8_t)n;
    memcpy(rsp + 3, data + *at, n);
    size_t rsp_n = rtu_append_crc(rsp, 3 + n);
    *at += n;
    ours[3] = (uint8_t)b->expected; /* each request of ours its own */
    rtu_append_crc(ours, 6);

    uint64_t t = b->now + sure(b);
    t = put(b, req, 8, t) + gap;
    if (!absent)
        t = put(b, rsp, rsp_n, t) + gap;
    expect(b, ours, 8);
    put(b, ours, 8, t);
    run_to(b, b->now + sure(b));
    if (b->want_one && b->served_cycles)
        abort(); /* liveness: a line that was served lost ours */
    b->served_cycles = b->want_one ? 0 : b->served_cycles + 1;
    if (b->want_one) {
        b->want_one = false; /* not executed: the master times out */
        b->expected--;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const unsigned bauds[] = {9600, 19200, 38400, 115200};
    struct bus *b = calloc(1, sizeof(*b));
    struct rtu_line_config cfg = {.unit_id = UNIT};
    size_t at = 1;

    if (!b)
        return 0;
    if (size < 1) {
        free(b);
        return 0;
    }
    unsigned baud = bauds[data[0] & 3];
    cfg.local_echo = data[0] & 4;
    rtu_char_times(baud, false, 1, &cfg.t15_ns, &cfg.t35_ns);
    cfg.char_ns = (uint32_t)(10ull * 1000000000ull / baud);
    cfg.tx_char_ns = data[0] & 8 ? 0 : cfg.char_ns;
    cfg.delivery_ns = 4ull * cfg.char_ns + MS;
    rtu_line_init(&b->line, &cfg);
    b->now = 1000 * MS;

    while (at < size) {
        uint8_t tag = data[at++];
        switch (tag & 7) {
        case 0: {
            uint8_t req[8] = {UNIT, 3, 0, 0, 0, 1};
            for (int i = 1; i < 6 && at < size; i++)
                req[i] = data[at++];
            req[1] = (uint8_t)(1 + req[1] % 6); /* 1..6: 8-byte requests */
            rtu_append_crc(req, 6);
            expect(b, req, 8);
            send(b, req, 8, NULL, 0);
            if (b->want_one) /* a whole request of ours, not executed */
                abort();
            break;
        }
        case 1: {
            size_t n = take(data, size, &at, 255);
            uint8_t noise = tag;
            send(b, &noise, 1, NULL, 0);
            if (n == 0)
                break;
            if (ours(data + at, n))
                expect(b, data + at, n);
            send(b, data + at, n, data + at, n);
            at += n;
            if (b->want_one)
                abort();
            break;
        }
        case 2:
            if (b->reply_size && b->line.tx_end_ns && !b->echoed) {
                uint64_t step = b->line.cfg.local_echo ? 3750000ull : b->line.cfg.delivery_ns / 16;
                uint64_t t = b->line.tx_end_ns + (uint64_t)((tag >> 3) & 15) * step;
                if (t < b->now)
                    break; /* too late to be an echo in its window */
                b->echoed = true;
                if (tag & 0x80) {
                    /* Arrived at t; the loop, stalled, reads it later. */
                    struct rtu_line_hooks h = hooks;
                    h.user = b;
                    run_to(b, t - 1);
                    b->now = t + 300 * MS;
                    rtu_line_input_read(&b->line, b->reply, b->reply_size, b->now, t - 1, &h);
                } else {
                    deliver(b, t, b->reply, b->reply_size);
                }
                run_to(b, b->now + sure(b));
            }
            break;
        case 5:
            busy_cycle(b, data, size, &at, tag);
            break;
        case 3:
        case 4: {
            size_t n = take(data, size, &at, 240) & ~(size_t)1;
            uint8_t unit = (uint8_t)(tag >> 3), frame[RTU_MAX_ADU];
            if (unit == UNIT || unit == RTU_BROADCAST)
                unit = 18;
            if (n == 0)
                break;
            if ((tag & 7) == 3) {
                size_t len = 0;
                frame[0] = unit, frame[1] = 3, frame[2] = 0, frame[3] = 0;
                frame[4] = 0, frame[5] = (uint8_t)(n / 2);
                send(b, frame, rtu_append_crc(frame, 6), NULL, 0);
                frame[2] = (uint8_t)n;
                memcpy(frame + 3, data + at, n);
                len = rtu_append_crc(frame, 3 + n);
                send(b, frame, len, data + at, n);
            } else {
                frame[0] = unit, frame[1] = 16, frame[2] = 0, frame[3] = 0;
                frame[4] = 0, frame[5] = (uint8_t)(n / 2), frame[6] = (uint8_t)n;
                memcpy(frame + 7, data + at, n);
                send(b, frame, rtu_append_crc(frame, 7 + n), data + at, n);
                send(b, frame, rtu_append_crc(frame, 6), NULL, 0);
            }
            at += n;
            break;
        }
        default:
            run_to(b, b->now + (uint64_t)(tag >> 3) * MS);
            break;
        }
        if ((tag & 7) == 1)
            b->served_cycles = 0; /* the line may have lost its place */
    }
    run_to(b, b->now + sure(b));
    if (b->executed != b->expected)
        abort();
    free(b);
    return 0;
}
