/* SPDX-License-Identifier: MIT */
/*
 * test_output_readback.c - the outputs' read-back rule (output_readback.h)
 * on the real register map: when an output written again with its level
 * needs no command, at the edges of the rule (the robot's report, the 1 s
 * window, the state of the last set). What plc_commands sends for it is
 * tested in test_plc_commands.c.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "command.h"
#include "output_readback.h"
#include "regmap.h"

static struct regmap map;
static struct regmap_image img;
static struct output_readback outputs;
static const struct regmap_row *output, *state;
static int back; /* the first output's read-back discrete input */

/* The first output written with 'value', the image holding 'previous'. */
static struct regmap_written write_of(double value, double previous)
{
    return (struct regmap_written){.row = output, .element = 0, .value = value,
                                   .previous = previous};
}

static bool unchanged(double value, double previous, uint64_t now)
{
    struct regmap_written w = write_of(value, previous);
    return output_readback_unchanged(&outputs, &img, &w, state, now);
}

static void set_sent_at(uint64_t now)
{
    struct regmap_written w = write_of(1, 1);
    output_readback_note_sent(&outputs, &w, now);
}

/* A new level is always sent; the same one not while the robot reports it. */
static void the_robot_report_decides_first(void **state_)
{
    (void)state_;
    img.mb->tab_input_bits[back] = 0;
    assert_false(unchanged(1, 0, 5000)); /* a new level */
    assert_false(unchanged(0, 1, 5000));
    assert_true(unchanged(0, 0, 5000)); /* reported as written */
    img.mb->tab_input_bits[back] = 1;
    assert_true(unchanged(1, 1, 5000));
    assert_false(unchanged(1, 0, 5000));
    assert_false(unchanged(0, 0, 5000)); /* reported otherwise, never set */
}

/* Reported otherwise: held back only within OUTPUT_RESEND_MS of the last
 * set, and only while that set is pending or done. */
static void a_recent_set_holds_it_back_for_one_second(void **state_)
{
    (void)state_;
    img.mb->tab_input_bits[back] = 0; /* the robot still reports 0 */
    set_sent_at(10000);
    regmap_set_number(&img, state, 0, CMD_PENDING, true);
    assert_true(unchanged(1, 1, 10000));
    assert_true(unchanged(1, 1, 10000 + OUTPUT_RESEND_MS - 1));
    assert_false(unchanged(1, 1, 10000 + OUTPUT_RESEND_MS));
    regmap_set_number(&img, state, 0, CMD_DONE, true);
    assert_true(unchanged(1, 1, 10500)); /* accepted, the report not in yet */
    static const enum cmd_outcome failed[] = {CMD_ROBOT_ERROR, CMD_TIMEOUT, CMD_NOT_SENT,
                                              CMD_LINK_DOWN};
    for (unsigned i = 0; i < sizeof(failed) / sizeof(failed[0]); i++) {
        regmap_set_number(&img, state, 0, failed[i], true);
        assert_false(unchanged(1, 1, 10500)); /* a failed set is no reason to wait */
    }
    regmap_set_number(&img, state, 0, CMD_PENDING, true);
    assert_false(output_readback_unchanged(&outputs, &img, &(struct regmap_written){
                                               .row = output, .value = 1, .previous = 1},
                                           NULL, 10500)); /* no result row: sent */
}

/* A clock that reads 0 still records the set (0 means never sent). */
static void a_set_at_time_zero_counts(void **state_)
{
    (void)state_;
    img.mb->tab_input_bits[back] = 0;
    regmap_set_number(&img, state, 0, CMD_PENDING, true);
    set_sent_at(0); /* kept as 1 */
    assert_true(unchanged(1, 1, 1));
    assert_true(unchanged(1, 1, OUTPUT_RESEND_MS));
    assert_false(unchanged(1, 1, OUTPUT_RESEND_MS + 1));
}

static int setup(void **state_)
{
    (void)state_;
    if (regmap_init(&map) != 0 || regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST) != 0 ||
        output_readback_init(&outputs, &map) != 0)
        return -1;
    output = regmap_find_path(&map, REGMAP_SRC_CMD, "set_digital_output.value");
    state = regmap_find_path(&map, REGMAP_SRC_PATH, "result.set_digital_output.state");
    if (!output || !state || output->table != REGMAP_COIL)
        return -1;
    back = regmap_readback_address(&map, output, 0);
    return back >= 0 ? 0 : -1;
}

static int teardown(void **state_)
{
    (void)state_;
    output_readback_free(&outputs);
    regmap_image_free(&img);
    regmap_free(&map);
    return 0;
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(the_robot_report_decides_first),
        cmocka_unit_test(a_recent_set_holds_it_back_for_one_second),
        cmocka_unit_test(a_set_at_time_zero_counts),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
