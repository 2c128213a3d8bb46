/* SPDX-License-Identifier: MIT */
/*
 * test_rtu_frame.c - Modbus RTU framing: the CRC of the specification's
 * examples, the character times, and the cut of a run of bytes into frames
 * by length, CRC and silences: glued frames of several units are all found,
 * a frame with a silence inside it is discarded, and after bytes that are
 * no frame the next frame after a silence is found again.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <string.h>

#include "rtu_frame.h"

#define MAX_SEEN 16

struct seen {
    size_t frames, dropped_crc, dropped_gap;
    uint8_t unit[MAX_SEEN];
    size_t size[MAX_SEEN];
    size_t dropped_bytes;
};

static void on_frame(void *user, const uint8_t *frame, size_t size)
{
    struct seen *s = user;
    assert_true(rtu_crc_ok(frame, size));
    if (s->frames < MAX_SEEN) {
        s->unit[s->frames] = frame[0];
        s->size[s->frames] = size;
    }
    s->frames++;
}

static void on_dropped(void *user, enum rtu_drop why, size_t size)
{
    struct seen *s = user;
    if (why == RTU_DROP_GAP)
        s->dropped_gap++;
    else
        s->dropped_crc++;
    s->dropped_bytes += size;
}

static struct seen split(const uint8_t *chunk, size_t size, const uint16_t *gaps, size_t n)
{
    struct seen s;
    memset(&s, 0, sizeof(s));
    struct rtu_split_hooks hooks = {.frame = on_frame, .dropped = on_dropped, .user = &s};
    rtu_split(chunk, size, gaps, n, &hooks);
    return s;
}

/* unit, function 4, address, count, CRC */
static size_t read_request(uint8_t *out, uint8_t unit, uint16_t address, uint16_t count)
{
    out[0] = unit;
    out[1] = 4;
    out[2] = (uint8_t)(address >> 8);
    out[3] = (uint8_t)address;
    out[4] = (uint8_t)(count >> 8);
    out[5] = (uint8_t)count;
    return rtu_append_crc(out, 6);
}

/* unit, function 4, byte count, registers, CRC */
static size_t read_response(uint8_t *out, uint8_t unit, unsigned count)
{
    out[0] = unit;
    out[1] = 4;
    out[2] = (uint8_t)(2 * count);
    for (unsigned i = 0; i < 2 * count; i++)
        out[3 + i] = (uint8_t)(0x30 + i);
    return rtu_append_crc(out, 3 + 2 * count);
}

static void crc_matches_the_specification(void **state)
{
    (void)state;
    /* Modbus over Serial Line V1.02, 6.2.2: 02 07 -> CRC 41 12 (low first). */
    const uint8_t example[] = {0x02, 0x07};
    assert_int_equal(rtu_crc16(example, 2), 0x1241);
    /* A read of holding registers as every Modbus tool prints it. */
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
    /* 19200 baud, 11 bits a character: 573 us each. */
    rtu_char_times(19200, true, 1, &t15, &t35);
    assert_int_equal(t15, 859375);
    assert_int_equal(t35, 2005208);
    /* 9600, no parity, 2 stop bits: 11 bits as well. */
    rtu_char_times(9600, false, 2, &t15, &t35);
    assert_int_equal(t35, 4010416);
    /* Above 19200: fixed. */
    rtu_char_times(115200, true, 1, &t15, &t35);
    assert_int_equal(t15, 750000);
    assert_int_equal(t35, 1750000);
}

static void one_frame_per_chunk(void **state)
{
    uint8_t buf[RTU_MAX_ADU];
    (void)state;
    size_t n = read_request(buf, 17, 0, 13);
    struct seen s = split(buf, n, NULL, 0);
    assert_int_equal(s.frames, 1);
    assert_int_equal(s.size[0], 8);
    assert_int_equal(s.dropped_crc + s.dropped_gap, 0);
}

static void glued_frames_of_several_units_are_all_found(void **state)
{
    /* Foreign request, foreign response, ours, an exception, ours: glued as
     * a late reader sees them, no silence recorded. */
    uint8_t chunk[200];
    size_t n = 0;
    (void)state;
    n += read_request(chunk + n, 18, 100, 2);
    n += read_response(chunk + n, 18, 2);
    n += read_request(chunk + n, 17, 0, 1);
    chunk[n] = 19;
    chunk[n + 1] = 0x84;
    chunk[n + 2] = 0x02;
    n += rtu_append_crc(chunk + n, 3);
    n += read_request(chunk + n, 17, 5540, 1);
    struct seen s = split(chunk, n, NULL, 0);
    assert_int_equal(s.frames, 5);
    assert_int_equal(s.unit[0], 18);
    assert_int_equal(s.size[1], 9);
    assert_int_equal(s.unit[2], 17);
    assert_int_equal(s.size[3], 5);
    assert_int_equal(s.unit[4], 17);
    assert_int_equal(s.dropped_crc + s.dropped_gap, 0);
}

static void a_silence_inside_a_frame_discards_it(void **state)
{
    uint8_t chunk[64];
    (void)state;
    size_t n = read_request(chunk, 17, 0, 1);
    n += read_request(chunk + n, 17, 1, 1);
    /* A gap after 4 bytes of the first frame; one at the second's start. */
    const uint16_t gaps[] = {4, 8};
    struct seen s = split(chunk, n, gaps, 2);
    assert_int_equal(s.dropped_gap, 1);
    assert_int_equal(s.frames, 1);
    assert_int_equal(s.size[0], 8);
}

static void after_noise_the_next_frame_after_a_silence_is_found(void **state)
{
    uint8_t chunk[64];
    (void)state;
    /* Half a frame (its end lost), a silence, then a whole frame. */
    size_t n = read_request(chunk, 17, 0, 1);
    n = 5;
    n += read_request(chunk + n, 17, 2, 1);
    const uint16_t gaps[] = {5};
    struct seen s = split(chunk, n, gaps, 1);
    assert_int_equal(s.dropped_crc, 1);
    assert_int_equal(s.dropped_bytes, 5);
    assert_int_equal(s.frames, 1);
    /* No silence to resynchronise at: the run is dropped as a whole. */
    s = split(chunk, n, NULL, 0);
    assert_int_equal(s.frames, 0);
    assert_int_equal(s.dropped_crc, 1);
    assert_int_equal(s.dropped_bytes, n);
}

static void a_bad_crc_is_dropped(void **state)
{
    uint8_t chunk[16];
    (void)state;
    size_t n = read_request(chunk, 17, 0, 1);
    chunk[n - 1] ^= 0xFF;
    struct seen s = split(chunk, n, NULL, 0);
    assert_int_equal(s.frames, 0);
    assert_int_equal(s.dropped_crc, 1);
    /* Fewer bytes than the smallest frame. */
    s = split(chunk, 3, NULL, 0);
    assert_int_equal(s.frames, 0);
    assert_int_equal(s.dropped_bytes, 3);
}

static void write_multiple_and_unknown_functions(void **state)
{
    uint8_t chunk[300];
    size_t n;
    (void)state;
    /* 16: unit, fc, address, count 3, byte count 6, values, CRC. */
    const uint8_t write16[] = {17, 16, 0, 200, 0, 3, 6, 1, 2, 3, 4, 5, 6};
    memcpy(chunk, write16, sizeof(write16));
    n = rtu_append_crc(chunk, sizeof(write16));
    /* A function whose length is not known: the rest of the chunk. */
    const uint8_t odd[] = {17, 100, 1, 2, 3};
    memcpy(chunk + n, odd, sizeof(odd));
    size_t m = rtu_append_crc(chunk + n, sizeof(odd));
    struct seen s = split(chunk, n + m, NULL, 0);
    assert_int_equal(s.frames, 2);
    assert_int_equal(s.size[0], 15);
    assert_int_equal(s.size[1], 7);
}

/*
 * Every function the server answers, in its request and its response form,
 * and exception responses: a foreign unit's frame glued to ours (a late
 * reader) is cut by its length, and ours after it is found.
 */
static void every_served_function_is_cut_by_its_length(void **state)
{
    static const struct {
        size_t size;
        uint8_t bytes[40];
    } foreign[] = {
        {6, {18, 1, 0, 0, 0, 10}},          {5, {18, 1, 2, 0xFF, 0x03}},
        {6, {18, 2, 0, 0, 0, 10}},          {5, {18, 2, 2, 0x0F, 0x01}},
        {6, {18, 3, 0, 0, 0, 2}},           {7, {18, 3, 4, 1, 2, 3, 4}},
        {6, {18, 4, 0, 9, 0, 1}},           {5, {18, 4, 2, 0x4A, 0x4B}},
        {6, {18, 5, 0, 100, 0xFF, 0}},      {6, {18, 6, 0, 100, 0, 5}},
        {9, {18, 15, 0, 0, 0, 10, 2, 0xFF, 0x03}},
        {6, {18, 15, 0, 0, 0, 10}},
        {11, {18, 16, 0, 0, 0, 2, 4, 1, 2, 3, 4}},
        {6, {18, 16, 0, 0, 0, 2}},
        {8, {18, 22, 0, 4, 0, 0xF2, 0, 0x25}},
        {17, {18, 23, 0, 3, 0, 6, 0, 14, 0, 3, 6, 0, 0xFF, 0, 0xFF, 0, 0xFF}},
        {15, {18, 23, 12, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5, 0, 6}},
        {2, {18, 17}},
        {8, {18, 17, 5, 1, 0xFF, 'a', 'b', 'c'}},
        {5, {18, 43, 14, 1, 0}},
        {24, {18, 43, 14, 1, 0x83, 0, 0, 3, 0, 5, 'J', 'A', 'K', 'A', 'x', 1, 3, 'a', 'b',
              'c', 2, 2, '1', '2'}},
        {3, {18, 0x83, 2}},                 {3, {18, 0x97, 1}},
        {3, {18, 0xAB, 1}},
    };
    uint8_t chunk[64];
    (void)state;
    for (size_t i = 0; i < sizeof(foreign) / sizeof(foreign[0]); i++) {
        memcpy(chunk, foreign[i].bytes, foreign[i].size);
        size_t n = rtu_append_crc(chunk, foreign[i].size);
        n += read_request(chunk + n, 17, 0, 1);
        struct seen s = split(chunk, n, NULL, 0);
        if (s.frames != 2 || s.size[0] != foreign[i].size + 2 || s.unit[1] != 17)
            fail_msg("function %u, %zu bytes: %zu frames, %zu dropped", foreign[i].bytes[1],
                     foreign[i].size + 2, s.frames, s.dropped_bytes);
    }
}

/* A frame handed over in pieces: what its tail lacks, piece by piece. */
static void missing_bytes_of_a_frame_begun(void **state)
{
    uint8_t chunk[64];
    (void)state;
    /* 16: unit, fc, address, count 1, byte count 2, value, CRC: 11 bytes. */
    const uint8_t write16[] = {17, 16, 0, 0, 0, 1, 2, 0, 5};
    memcpy(chunk, write16, sizeof(write16));
    size_t n = rtu_append_crc(chunk, sizeof(write16));
    assert_int_equal(n, 11);
    assert_int_equal(rtu_missing_bytes(chunk, 1, NULL, 0), 3);
    assert_int_equal(rtu_missing_bytes(chunk, 3, NULL, 0), 5); /* 8 at least */
    assert_int_equal(rtu_missing_bytes(chunk, 7, NULL, 0), 1); /* 8: the response form */
    assert_int_equal(rtu_missing_bytes(chunk, 8, NULL, 0), 3); /* 11 by its byte count */
    assert_int_equal(rtu_missing_bytes(chunk, 11, NULL, 0), 0);
    /* Whole frames, then one begun: what that one lacks. */
    size_t m = read_request(chunk + n, 18, 0, 1);
    assert_int_equal(rtu_missing_bytes(chunk, n + m, NULL, 0), 0);
    assert_int_equal(rtu_missing_bytes(chunk, n + 5, NULL, 0), 3);
    /* Bytes no frame length explains: nothing to wait for. */
    chunk[n + m - 1] ^= 0xFF;
    assert_int_equal(rtu_missing_bytes(chunk, n + m, NULL, 0), 0);
    /* After noise, the frame begun after the silence. */
    const uint16_t gaps[] = {3};
    memmove(chunk + 3, chunk, n);
    assert_int_equal(rtu_missing_bytes(chunk, 3 + 8, gaps, 1), 3);
}

/* A silence waited past (a frame not yet whole): a frame across it is
 * whole; bytes before it that were no frame end there, and the frame after
 * it is found. */
static void a_waited_silence_is_a_place_to_resynchronise_only(void **state)
{
    uint8_t chunk[64];
    (void)state;
    size_t n = read_request(chunk, 17, 0, 1);
    const uint16_t across[] = {5 | RTU_GAP_WAITED};
    struct seen s = split(chunk, n, across, 1);
    assert_int_equal(s.frames, 1);
    assert_int_equal(s.dropped_gap, 0);
    /* One byte of noise (it began a frame), the silence, a frame. */
    chunk[0] = 17;
    n = 1 + read_request(chunk + 1, 17, 0, 1);
    const uint16_t after_noise[] = {1 | RTU_GAP_WAITED};
    s = split(chunk, n, after_noise, 1);
    assert_int_equal(s.frames, 1);
    assert_int_equal(s.dropped_bytes, 1);
    assert_int_equal(rtu_missing_bytes(chunk, n, after_noise, 1), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(crc_matches_the_specification),
        cmocka_unit_test(character_times),
        cmocka_unit_test(one_frame_per_chunk),
        cmocka_unit_test(glued_frames_of_several_units_are_all_found),
        cmocka_unit_test(a_silence_inside_a_frame_discards_it),
        cmocka_unit_test(after_noise_the_next_frame_after_a_silence_is_found),
        cmocka_unit_test(a_bad_crc_is_dropped),
        cmocka_unit_test(write_multiple_and_unknown_functions),
        cmocka_unit_test(every_served_function_is_cut_by_its_length),
        cmocka_unit_test(missing_bytes_of_a_frame_begun),
        cmocka_unit_test(a_waited_silence_is_a_place_to_resynchronise_only),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
