/* SPDX-License-Identifier: MIT */
/*
 * test_param_rows.c - the commands' parameter rows (param_rows.h) on the
 * real register map and command table: each command's span, and which
 * elements count as written. What a motion trigger does with them is
 * tested in test_plc_commands.c.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "command.h"
#include "param_rows.h"
#include "regmap.h"

static struct regmap map;
static struct param_rows params;

/* Every parameter row of a command lies in its span, and only those. */
static void each_span_holds_its_commands_rows(void **state)
{
    (void)state;
    unsigned with_rows = 0;
    for (unsigned c = 0; c < cmd_table_count; c++) {
        const struct cmd_def *def = &cmd_table[c];
        unsigned first, end, inside = 0, all = 0;
        param_rows_span(&params, def, &first, &end);
        for (unsigned r = 0; r < map.row_count; r++) {
            if (!param_rows_is_param_of(&map.rows[r], def->name))
                continue;
            all++;
            inside += r >= first && r < end;
            assert_ptr_equal(param_rows_command_of(map.rows[r].path), def);
        }
        assert_int_equal(inside, all);
        if (all == 0)
            assert_int_equal(end, 0);
        else
            with_rows++;
    }
    assert_true(with_rows >= 5); /* joint_move, moveL, ... have their rows */
}

/* Written elements count until a refused write covers them; the write
 * being judged counts as written. */
static void written_until_withdrawn(void **state)
{
    (void)state;
    const struct cmd_def *def = cmd_find("joint_move");
    assert_non_null(def);
    assert_false(param_rows_all_written(&params, def, NULL, 0));
    unsigned first, end;
    param_rows_span(&params, def, &first, &end);
    const struct regmap_row *last = NULL;
    for (unsigned r = first; r < end; r++) {
        const struct regmap_row *row = &map.rows[r];
        if (!param_rows_is_param_of(row, def->name))
            continue;
        for (unsigned i = 0; i < row->elements; i++)
            param_rows_note_written(&params, row, i);
        if (!last || row->elements > last->elements)
            last = row; /* the widest: jointPosition */
    }
    assert_true(last && last->elements > 1);
    assert_true(param_rows_all_written(&params, def, NULL, 0));

    /* A refused write over the last element of that row withdraws it alone. */
    unsigned width = regmap_element_width(last);
    unsigned stride = last->stride ? last->stride : width;
    unsigned at = last->address + (last->elements - 1) * stride;
    param_rows_withdraw(&params, last->table, at, width);
    assert_false(param_rows_all_written(&params, def, NULL, 0));
    struct regmap_written now = {.row = last, .element = last->elements - 1};
    assert_true(param_rows_all_written(&params, def, &now, 1));
    now.element = 0;
    assert_false(param_rows_all_written(&params, def, &now, 1));
    param_rows_note_written(&params, last, last->elements - 1);
    assert_true(param_rows_all_written(&params, def, NULL, 0));
}

static int setup(void **state)
{
    (void)state;
    if (regmap_init(&map) != 0)
        return -1;
    return param_rows_init(&params, &map);
}

static int teardown(void **state)
{
    (void)state;
    param_rows_free(&params);
    regmap_free(&map);
    return 0;
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(each_span_holds_its_commands_rows),
        cmocka_unit_test(written_until_withdrawn),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
