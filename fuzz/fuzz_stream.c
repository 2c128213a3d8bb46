/* SPDX-License-Identifier: MIT */
/*
 * fuzz_stream.c - libFuzzer target: arbitrary bytes from the robot's status
 * port, cut into reads at arbitrary points, through the framer, the status
 * parser and the register encoder, as the gateway does.
 *
 * The first two bytes choose the framer's buffer size (from the minimum,
 * 256 bytes, up to 16 KiB) and the read size, so that short inputs reach
 * every size limit: a full buffer, a header cut at the buffer's end, the
 * discard cap. The same bytes are then framed again in one single read,
 * and both runs must report the same objects: how TCP splits the stream
 * must never change what the gateway sees.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "framer.h"
#include "regmap.h"
#include "status.h"

static struct regmap map;
static struct regmap_image img;
static struct jaka_status st;

/* What a run reported: a running hash of the objects, and a count. */
struct trace {
    size_t max_object;
    uint64_t hash;
    uint64_t objects;
    bool parse;
};

static uint64_t mix(uint64_t h, const char *data, size_t size)
{
    for (size_t i = 0; i < size; i++)
        h = (h ^ (uint8_t)data[i]) * 1099511628211ULL;
    return (h ^ size) * 1099511628211ULL;
}

static void on_event(void *user, enum framer_event ev, const char *data, size_t size)
{
    struct trace *t = user;

    if (ev != FRAMER_EVENT_OBJECT)
        return;
    /* An object starts with '{', fits the buffer and ends with a closing
     * bracket (the brace scanner does not pair '[' with ']'; the parser
     * judges the content). */
    if (size > t->max_object || size < 2 || data[0] != '{' ||
        (data[size - 1] != '}' && data[size - 1] != ']'))
        abort();
    t->hash = mix(t->hash, data, size);
    t->objects++;
    if (t->parse && status_parse(&st, data, size) == STATUS_PARSE_OK)
        regmap_encode_status(&img, &st);
}

static void run(struct trace *t, const uint8_t *data, size_t size, size_t chunk)
{
    struct framer f;

    if (framer_init(&f, t->max_object, on_event, t))
        abort();
    for (size_t off = 0; off < size; off += chunk) {
        framer_feed(&f, (const char *)data + off, size - off < chunk ? size - off : chunk);
        if (f.used >= f.max_object)
            abort(); /* every feed must leave room, or the next one spins */
    }
    framer_free(&f);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;

    if (!ready) {
        if (regmap_init(&map) || regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST))
            abort();
        ready = 1;
    }
    if (size < 2)
        return 0;
    size_t max_object = FRAMER_MIN_OBJECT + (size_t)data[0] * 64;
    size_t chunk = (size_t)data[1] + 1;
    data += 2;
    size -= 2;

    struct trace split = {max_object, 14695981039346656037ULL, 0, true};
    struct trace whole = {max_object, 14695981039346656037ULL, 0, false};
    run(&split, data, size, chunk);
    run(&whole, data, size, size ? size : 1);
    if (split.objects != whole.objects || split.hash != whole.hash)
        abort(); /* the objects depend on how the stream was split */
    return 0;
}
