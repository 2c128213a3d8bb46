/*
 * fuzz_stream.c - libFuzzer target: arbitrary bytes from the robot's status
 * port, cut into reads at arbitrary points, through the framer, the status
 * parser and the register encoder, as the gateway does.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "framer.h"
#include "regmap.h"
#include "status.h"

#define MAX_OBJECT (64 * 1024)

static struct regmap map;
static struct regmap_image img;
static struct jaka_status st;

static void on_event(void *user, enum framer_event ev, const char *data, size_t size)
{
    (void)user;
    if (ev == FRAMER_EVENT_OBJECT && size > MAX_OBJECT)
        abort(); /* never an object larger than the framer's buffer */
    if (ev == FRAMER_EVENT_OBJECT && status_parse(&st, data, size) == STATUS_PARSE_OK)
        regmap_encode_status(&img, &st);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    struct framer f;

    if (!ready) {
        if (regmap_init(&map) || regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST))
            abort();
        ready = 1;
    }
    if (size < 1)
        return 0;
    /* The first byte chooses the read size, so splits land anywhere. */
    size_t chunk = (size_t)data[0] + 1;
    data++;
    size--;
    if (framer_init(&f, MAX_OBJECT, on_event, NULL))
        abort();
    for (size_t off = 0; off < size; off += chunk)
        framer_feed(&f, (const char *)data + off, size - off < chunk ? size - off : chunk);
    if (f.used > f.max_object)
        abort();
    framer_free(&f);
    return 0;
}
