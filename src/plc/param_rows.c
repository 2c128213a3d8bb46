/* SPDX-License-Identifier: MIT */
/* param_rows.c - commands' parameter rows in the register map (param_rows.h). */
#include "param_rows.h"

#include "log.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const struct cmd_def *param_rows_command_of(const char *path)
{
    char name[64];
    size_t n = strcspn(path, ".");
    if (n >= sizeof(name))
        return NULL;
    memcpy(name, path, n);
    name[n] = '\0';
    return cmd_find(name);
}

bool param_rows_is_param(const struct regmap_row *row)
{
    return row->source == REGMAP_SRC_CMD && !row->fixed && strchr(row->path, '.');
}

bool param_rows_is_param_of(const struct regmap_row *row, const char *name)
{
    size_t n = strlen(name);
    return row->source == REGMAP_SRC_CMD && !row->fixed &&
           strncmp(row->path, name, n) == 0 && row->path[n] == '.';
}

/*
 * Finds 'member' among a command's mailbox arguments ("name[N]" takes N,
 * a '#' or '$' suffix marks the kind). Returns how many values it takes,
 * or 0 when it is not one of them.
 */
static unsigned mailbox_arg_count(const struct cmd_def *def, const char *member)
{
    char args[128];

    snprintf(args, sizeof(args), "%s", def->mailbox_args);
    for (char *save = NULL, *tok = strtok_r(args, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        size_t n = strcspn(tok, "[#$");
        if (strlen(member) == n && strncmp(tok, member, n) == 0)
            return tok[n] == '[' ? (unsigned)atoi(tok + n + 1) : 1;
    }
    return 0;
}

/* Does a parameter row of 'def' give mailbox argument 'arg'? */
static bool has_param_row(const struct regmap *map, const struct cmd_def *def,
                          const char *arg, size_t arg_len)
{
    size_t n = strlen(def->name);
    for (unsigned r = 0; r < map->row_count; r++) {
        const char *path = map->rows[r].path;
        if (map->rows[r].source == REGMAP_SRC_CMD && !map->rows[r].fixed &&
            strncmp(path, def->name, n) == 0 && path[n] == '.' &&
            strncmp(path + n + 1, arg, arg_len) == 0 &&
            (path[n + 1 + arg_len] == '\0' || path[n + 1 + arg_len] == '['))
            return true;
    }
    return false;
}

/* Does every parameter and setpoint row ("<cmdName>.<member>") match an
 * argument of its command in the command table? 0 or -EINVAL, logged. */
static int check_rows_against_table(const struct regmap *map)
{
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        const char *dot = row->source == REGMAP_SRC_CMD ? strchr(row->path, '.') : NULL;
        if (!dot)
            continue;
        const struct cmd_def *def = param_rows_command_of(row->path);
        if (!def) {
            log_err("register map: row %s belongs to no command of the command table",
                    row->name);
            return -EINVAL;
        }
        if (!def->code)
            continue; /* not in the mailbox: nothing to compare with */
        char member[64];
        snprintf(member, sizeof(member), "%.*s", (int)strcspn(dot + 1, "["), dot + 1);
        unsigned count = mailbox_arg_count(def, member);
        /* A parameter row gives the whole argument; a setpoint row one
         * element of it, the others fixed by the row. */
        if (count == 0 || (!row->fixed && count != row->elements)) {
            log_err("register map: row %s (%s, %u values) does not match %s's arguments "
                    "in the command table (%s)",
                    row->name, row->path, row->elements, def->name, def->mailbox_args);
            return -EINVAL;
        }
    }
    return 0;
}

/* The other way: has a triggered command's every argument its row? 0 or
 * -EINVAL, logged. */
static int check_table_against_rows(const struct regmap *map)
{
    for (unsigned i = 0; i < cmd_table_count; i++) {
        const struct cmd_def *def = &cmd_table[i];
        char args[128];
        bool triggered = false;
        for (unsigned r = 0; r < map->row_count && !triggered; r++)
            triggered = param_rows_is_param_of(&map->rows[r], def->name);
        if (!triggered || !def->code)
            continue;
        snprintf(args, sizeof(args), "%s", def->mailbox_args);
        for (char *save = NULL, *tok = strtok_r(args, ",", &save); tok;
             tok = strtok_r(NULL, ",", &save)) {
            size_t n = strcspn(tok, "[#$");
            if (!has_param_row(map, def, tok, n)) {
                log_err("register map: %s's argument %.*s has no parameter row", def->name,
                        (int)n, tok);
                return -EINVAL;
            }
        }
    }
    return 0;
}

/* A row's written elements are a bit each: at most 32. 0 or -EINVAL. */
static int check_row_widths(const struct regmap *map)
{
    for (unsigned r = 0; r < map->row_count; r++)
        if (param_rows_is_param(&map->rows[r]) && map->rows[r].elements > 32) {
            log_err("register map: parameter row %s has more than 32 elements",
                    map->rows[r].name);
            return -EINVAL;
        }
    return 0;
}

/* Where each command's parameter rows lie in the map (none: 0, 0). */
static void find_spans(struct param_rows *p)
{
    const struct regmap *map = p->map;

    for (unsigned i = 0; i < cmd_table_count; i++) {
        p->first[i] = p->end[i] = 0;
        for (unsigned r = 0; r < map->row_count; r++) {
            if (!param_rows_is_param_of(&map->rows[r], cmd_table[i].name))
                continue;
            if (p->end[i] == 0)
                p->first[i] = (uint16_t)r;
            p->end[i] = (uint16_t)(r + 1);
        }
    }
}

int param_rows_init(struct param_rows *p, const struct regmap *map)
{
    memset(p, 0, sizeof(*p));
    p->map = map;
    if (check_rows_against_table(map) != 0 || check_table_against_rows(map) != 0 ||
        check_row_widths(map) != 0)
        return -EINVAL;
    p->written = calloc(map->row_count, sizeof(*p->written));
    p->first = calloc(cmd_table_count ? cmd_table_count : 1, sizeof(*p->first));
    p->end = calloc(cmd_table_count ? cmd_table_count : 1, sizeof(*p->end));
    if (!p->written || !p->first || !p->end)
        return -ENOMEM;
    find_spans(p);
    return 0;
}

void param_rows_free(struct param_rows *p)
{
    free(p->written);
    p->written = NULL;
    free(p->first);
    p->first = NULL;
    free(p->end);
    p->end = NULL;
}

void param_rows_span(const struct param_rows *p, const struct cmd_def *def, unsigned *first,
                     unsigned *end)
{
    unsigned c = (unsigned)(def - cmd_table);

    *first = p->first[c];
    *end = p->end[c];
}

void param_rows_note_written(struct param_rows *p, const struct regmap_row *row,
                             unsigned element)
{
    p->written[row - p->map->rows] |= 1u << element;
}

void param_rows_withdraw(struct param_rows *p, enum regmap_table table, unsigned address,
                         unsigned count)
{
    for (unsigned a = address; a < address + count; a++) {
        const struct regmap_row *row = regmap_find(p->map, table, a);
        if (!row || !param_rows_is_param(row))
            continue;
        unsigned width = regmap_element_width(row);
        unsigned stride = row->stride ? row->stride : width;
        unsigned i = (a - row->address) / stride;
        if (i < row->elements)
            p->written[row - p->map->rows] &= ~(1u << i);
    }
}

/* Does one of the 'count' elements 'writing' sets set element 'i' of 'row'? */
static bool writes_element(const struct regmap_written *writing, unsigned count,
                           const struct regmap_row *row, unsigned i)
{
    for (unsigned e = 0; e < count; e++)
        if (writing[e].row == row && writing[e].element == i)
            return true;
    return false;
}

bool param_rows_all_written(const struct param_rows *p, const struct cmd_def *def,
                            const struct regmap_written *writing, unsigned count)
{
    const struct regmap *map = p->map;

    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        if (!param_rows_is_param_of(row, def->name))
            continue;
        for (unsigned i = 0; i < row->elements; i++)
            if (!(p->written[r] & (1u << i)) && !writes_element(writing, count, row, i))
                return false;
    }
    return true;
}
