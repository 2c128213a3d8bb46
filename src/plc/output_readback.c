/* SPDX-License-Identifier: MIT */
/* output_readback.c - the read-back rule of output writes (output_readback.h). */
#include "output_readback.h"

#include "command.h"

#include <errno.h>
#include <stdlib.h>

int output_readback_init(struct output_readback *o, const struct regmap *map)
{
    unsigned coils = map->size[REGMAP_COIL];

    o->readback_at = malloc(coils * sizeof(*o->readback_at));
    o->sent_ms = calloc(coils, sizeof(*o->sent_ms));
    if (!o->readback_at || !o->sent_ms)
        return -ENOMEM;
    for (unsigned a = 0; a < coils; a++) {
        const struct regmap_row *row = regmap_find(map, REGMAP_COIL, a);
        o->readback_at[a] = row ? regmap_readback_address(map, row, a - row->address) : -1;
    }
    return 0;
}

void output_readback_free(struct output_readback *o)
{
    free(o->readback_at);
    o->readback_at = NULL;
    free(o->sent_ms);
    o->sent_ms = NULL;
}

bool output_readback_unchanged(const struct output_readback *o, const struct regmap_image *img,
                               const struct regmap_written *w, const struct regmap_row *state,
                               uint64_t now_ms)
{
    unsigned coil = regmap_element_address(w->row, w->element);
    int at = w->row->table == REGMAP_COIL ? o->readback_at[coil] : -1;

    if (at < 0 || w->value != w->previous)
        return false;
    if ((img->mb->tab_input_bits[at] != 0) == (w->value != 0))
        return true;
    uint64_t sent = o->sent_ms[coil];
    if (sent == 0 || now_ms - sent >= OUTPUT_RESEND_MS || !state)
        return false;
    double set_state = regmap_get_number(img, state, 0);
    return set_state == CMD_PENDING || set_state == CMD_DONE;
}

void output_readback_note_sent(struct output_readback *o, const struct regmap_written *w,
                               uint64_t now_ms)
{
    if (w->row->table != REGMAP_COIL || !w->row->readback)
        return;
    /* 0 means never sent: a clock that starts at 0 counts from 1. */
    o->sent_ms[regmap_element_address(w->row, w->element)] = now_ms ? now_ms : 1;
}
