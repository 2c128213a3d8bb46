/* SPDX-License-Identifier: MIT */
/*
 * cmd_json.h - a command's JSON, written as bytes from the values.
 *
 * The bytes are exactly what cJSON_PrintUnformatted printed for the tree
 * the gateway used to build (tests/test_cmd_json.c compares the two for
 * every command and generated values): "cmdName" first, members in the
 * order they were first set, setting a member again moves it to the end,
 * "name[i]" sets element i of an array member (grown with nulls), no
 * white space, strings escaped as cJSON escapes them, numbers as cJSON
 * prints them (an integer within int's range as an integer, any other
 * number with 15 significant digits, or 17 when 15 do not read back).
 *
 * The values are kept as text when set and printed once by
 * cmd_json_finish(): no tree, no allocation until then, and a number is
 * written from its digits rather than printed and read back, except a
 * number with no short decimal form (none that a register yields).
 */
#ifndef JAKAGW_CMD_JSON_H
#define JAKAGW_CMD_JSON_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define CMD_JSON_MEMBERS 16 /* members besides cmdName */
#define CMD_JSON_ITEMS 16   /* elements of one array member */
#define CMD_JSON_TEXT 2048  /* bytes of keys and values */

struct cmd_json_member {
    uint16_t key;   /* offset in text */
    uint16_t key_size;
    bool array;
    uint8_t count;  /* array: elements set or filled */
    /* The value (or each element): offset and size in text; size 0 is null. */
    uint16_t at[CMD_JSON_ITEMS];
    uint16_t size[CMD_JSON_ITEMS];
};

struct cmd_json {
    char name[64];
    struct cmd_json_member members[CMD_JSON_MEMBERS];
    unsigned member_count;
    char text[CMD_JSON_TEXT];
    size_t text_used;
    bool overflow; /* more than fits: cmd_json_finish() fails */
    bool non_finite; /* a number set was not finite (cJSON would print null) */
};

/* Starts the command 'name'. */
void cmd_json_begin(struct cmd_json *j, const char *name);

/*
 * Sets member 'key' ("name" or "name[i]") to a number. 'from_float': the
 * value came from a 32-bit float register and is sent at its precision
 * (7 significant digits), as the gateway always has. A value that is not
 * finite is written as cJSON writes it (null) and marks the command
 * 'non_finite', for the caller to refuse.
 */
void cmd_json_set_number(struct cmd_json *j, const char *key, double value, bool from_float);

/* Sets member 'key' to the text 'value' (escaped when written). */
void cmd_json_set_string(struct cmd_json *j, const char *key, const char *value);

/*
 * Sets the members of 'fixed', a register row's fixed members in the
 * form '"key": integer, "key": integer'. Returns 0, or -EINVAL when it is
 * not of that form (nothing is set then).
 */
int cmd_json_set_fixed(struct cmd_json *j, const char *fixed);

/*
 * The JSON text, NUL-terminated, in memory the caller frees (free()).
 * NULL when it did not fit (the limits above) or memory ran out.
 */
char *cmd_json_finish(const struct cmd_json *j);

/*
 * Writes 'value' as cJSON prints a number into 'out' (at least 32 bytes);
 * returns the length. With 'from_float', the value rounded to 7
 * significant digits first, as read from a float register.
 */
size_t cmd_json_number(char *out, double value, bool from_float);

#endif
