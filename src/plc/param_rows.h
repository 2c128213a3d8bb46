/* SPDX-License-Identifier: MIT */
/*
 * param_rows.h - a command's parameter rows in the register map: where they
 * lie, that they agree with the command table, and which of their elements
 * a PLC has written.
 *
 * A parameter row ("<cmdName>.<param>", a holding register row of source
 * REGMAP_SRC_CMD that is not a setpoint's fixed row) holds one argument of
 * a triggered command. The command table (cmd_def.mailbox_args) describes
 * the same arguments again, for the mailbox: the two are checked against
 * each other at start, so that they cannot drift apart. Each command's
 * parameter rows are found once (its span), so building a triggered
 * command looks only there.
 *
 * A motion trigger may only send values the PLC wrote: every element of
 * its parameter rows written since start, and not withdrawn by a refused
 * write since (a move to a target nobody wrote, zeros at speed 0, or what a
 * refused write meant to replace, must not go). A row has at most 32
 * elements: a bit each.
 */
#ifndef JAKAGW_PARAM_ROWS_H
#define JAKAGW_PARAM_ROWS_H

#include <stdbool.h>
#include <stdint.h>

#include "command.h"
#include "regmap.h"

struct param_rows {
    const struct regmap *map;
    /* Per row of the map: the elements written since start and not
     * refused since, a bit per element. */
    uint32_t *written;
    /* By cmd_table index: its parameter rows lie in rows [first, end) of
     * the map (none: 0, 0). */
    uint16_t *first, *end;
};

/*
 * Checks the map's parameter and setpoint rows against the command table,
 * and finds each command's span. Returns 0, -EINVAL having logged the
 * difference (a programming error), or -ENOMEM; either way
 * param_rows_free() releases what was taken.
 */
int param_rows_init(struct param_rows *p, const struct regmap *map);
void param_rows_free(struct param_rows *p);

/* The command a command row ("<cmdName>" or "<cmdName>.<member>") belongs
 * to; NULL when the command table has none of that name. */
const struct cmd_def *param_rows_command_of(const char *path);

/* Is 'row' a command's parameter row? One of command 'name''s? */
bool param_rows_is_param(const struct regmap_row *row);
bool param_rows_is_param_of(const struct regmap_row *row, const char *name);

/* The span of rows [*first, *end) that holds 'def''s parameter rows. */
void param_rows_span(const struct param_rows *p, const struct cmd_def *def, unsigned *first,
                     unsigned *end);

/* Element 'element' of parameter row 'row' was written and acted on. */
void param_rows_note_written(struct param_rows *p, const struct regmap_row *row,
                             unsigned element);

/*
 * A write to 'count' registers of 'table' from 'address' was refused: the
 * parameter elements it held count as not written.
 */
void param_rows_withdraw(struct param_rows *p, enum regmap_table table, unsigned address,
                         unsigned count);

/*
 * Were all of 'def''s parameters written since start (and not withdrawn
 * since), or are they among the 'count' elements 'writing' sets now?
 */
bool param_rows_all_written(const struct param_rows *p, const struct cmd_def *def,
                            const struct regmap_written *writing, unsigned count);

#endif
