/* SPDX-License-Identifier: MIT */
/*
 * fuzz_rtu.c - libFuzzer target: an arbitrary run of bytes from a serial
 * line, with the silences the reader saw inside it, cut by rtu_split() as
 * the RTU transport cuts what arrived between two silences of t3.5.
 * Input: one byte, the number of silences (mod 17), two bytes per silence
 * (its offset, taken mod the run's length), then the run (at most 1024
 * bytes, the receive buffer). Rules:
 * - every byte is accounted for once, in order: frames and dropped runs
 *   tile the chunk exactly, and cutting ends;
 * - every frame handed on has a good CRC, 4..256 bytes, and no silence
 *   strictly inside it;
 * - a frame dropped for a silence had a good CRC too.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "rtu_frame.h"

struct walk {
    const uint8_t *chunk;
    size_t size, at;
    const uint16_t *gaps;
    size_t gap_count;
};

static bool gap_inside(const struct walk *w, size_t from, size_t size)
{
    for (size_t i = 0; i < w->gap_count; i++)
        if (!(w->gaps[i] & RTU_GAP_WAITED) && w->gaps[i] > from && w->gaps[i] < from + size)
            return true;
    return false;
}

static void on_frame(void *user, const uint8_t *frame, size_t size)
{
    struct walk *w = user;
    if (frame != w->chunk + w->at || size < RTU_MIN_ADU || size > RTU_MAX_ADU ||
        w->at + size > w->size || !rtu_crc_ok(frame, size) || gap_inside(w, w->at, size))
        abort();
    w->at += size;
}

static void on_dropped(void *user, enum rtu_drop why, size_t size)
{
    struct walk *w = user;
    if (size == 0 || w->at + size > w->size)
        abort();
    if (why == RTU_DROP_GAP && !rtu_crc_ok(w->chunk + w->at, size))
        abort();
    w->at += size;
}

static int cmp_u16(const void *a, const void *b)
{
    return (int)(*(const uint16_t *)a & ~RTU_GAP_WAITED) -
           (int)(*(const uint16_t *)b & ~RTU_GAP_WAITED);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint16_t gaps[16];
    size_t n = 0;

    if (size < 1)
        return 0;
    size_t count = data[0] % 17;
    if (size < 1 + 2 * count)
        return 0;
    const uint8_t *chunk = data + 1 + 2 * count;
    size_t chunk_size = size - 1 - 2 * count;
    if (chunk_size == 0 || chunk_size > 1024)
        return 0;
    for (size_t i = 0; i < count && n < 16; i++) {
        unsigned raw = (unsigned)data[1 + 2 * i] << 8 | data[2 + 2 * i];
        uint16_t g = (uint16_t)(raw % chunk_size);
        if (g > 0) /* the top bit: a silence waited past, not a pause */
            gaps[n++] = (uint16_t)(g | (raw & 0x8000 ? RTU_GAP_WAITED : 0));
    }
    qsort(gaps, n, sizeof(gaps[0]), cmp_u16);
    size_t unique = 0;
    for (size_t i = 0; i < n; i++)
        if (unique == 0 || (gaps[unique - 1] & ~RTU_GAP_WAITED) != (gaps[i] & ~RTU_GAP_WAITED))
            gaps[unique++] = gaps[i];

    struct walk w = {.chunk = chunk, .size = chunk_size, .gaps = gaps, .gap_count = unique};
    struct rtu_split_hooks hooks = {.frame = on_frame, .dropped = on_dropped, .user = &w};
    rtu_split(chunk, chunk_size, gaps, unique, &hooks);
    if (w.at != chunk_size)
        abort();
    /* What a tail lacks is at most a whole frame: the wait it sets is
     * bounded. */
    if (rtu_missing_bytes(chunk, chunk_size, gaps, unique) >= RTU_MAX_ADU)
        abort();
    return 0;
}
