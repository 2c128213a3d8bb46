/* SPDX-License-Identifier: MIT */
/*
 * output_readback.h - when an output written again needs no command: the
 * read-back rule of the setpoint rows for digital outputs.
 *
 * A vendor's cyclic channel rewrites every output of its block each cycle:
 * a set_digital_output per write would flood the robot and fill the
 * command queue. So an output's level written again with the value it had
 * sends nothing when the robot reports that value (the coil's read-back
 * discrete input, regmap_readback_address), or when this output was set
 * less than OUTPUT_RESEND_MS ago and that set's result is pending or done
 * (on its way, or accepted with the report not in yet). A new value is
 * always sent; so is the old one when the robot reports otherwise and its
 * last set failed (not sent, refused, link lost) or is older (changed
 * elsewhere).
 *
 * Pure bookkeeping: the image and the time are arguments, nothing is sent.
 */
#ifndef JAKAGW_OUTPUT_READBACK_H
#define JAKAGW_OUTPUT_READBACK_H

#include <stdbool.h>
#include <stdint.h>

#include "regmap.h"

/* How long an output written again with its own value waits for the
 * robot's report of the last set before it is sent again: many status
 * periods (30 ms on jakasim, 8 ms on a controller). */
#define OUTPUT_RESEND_MS 1000

struct output_readback {
    /* Per coil address: the discrete input an output reads back at (-1
     * none), and when its last set was sent (0 never). */
    int *readback_at;
    uint64_t *sent_ms;
};

/*
 * Finds each output coil's read-back input once (a write judges it for
 * every coil of a cyclic channel's request). Returns 0 or -ENOMEM; either
 * way output_readback_free() releases what was taken.
 */
int output_readback_init(struct output_readback *o, const struct regmap *map);
void output_readback_free(struct output_readback *o);

/*
 * Does writing 'w' (a setpoint row's element, its new value already in
 * 'img') leave the output as it is, so that nothing needs sending? 'state'
 * is the result row ("gw:result.<cmdName>.state") of the command that sets
 * it (NULL: none), 'now_ms' the time now.
 */
bool output_readback_unchanged(const struct output_readback *o, const struct regmap_image *img,
                               const struct regmap_written *w, const struct regmap_row *state,
                               uint64_t now_ms);

/* Records that the set of 'w''s output went out at 'now_ms' (nothing for
 * a row with no read-back). */
void output_readback_note_sent(struct output_readback *o, const struct regmap_written *w,
                               uint64_t now_ms);

#endif
