/* SPDX-License-Identifier: MIT */
/*
 * test_plc_write.c - the write transaction's own rows and rules: the
 * heartbeat and the write owner, the fault reset and clear-counters coils
 * (acted on, then reading 0), motion enable, read-only and write_allow
 * compared as addresses. Command rows are tested in test_plc_commands.c
 * through the same transaction.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <string.h>

#include "plc_write.h"

static struct regmap map;
static struct regmap_image img;
static struct cmd_queue queue;
static struct plc_commands pc;
static struct policy policy;
static struct plc_write pw;
static uint64_t now = 100000;
static bool moving;
static unsigned cleared, actions;

static uint64_t fake_now(void *user)
{
    (void)user;
    return now;
}

static bool fake_moving(void *user)
{
    (void)user;
    return moving;
}

static void count_clear(void *user)
{
    (void)user;
    cleared++;
}

static bool count_action(void *user, enum policy_action action, enum policy_fault reason)
{
    (void)user, (void)action, (void)reason;
    actions++;
    return true;
}

static int no_send(void *io, const char *data, size_t size)
{
    (void)io, (void)data, (void)size;
    return 0;
}

static void start(const struct plc_write_config *wc, bool single_owner, bool motion_enable)
{
    struct cmd_ops ops = {.send = no_send, .now_ms = fake_now};
    struct plc_commands_config cc = {0};
    struct policy_config pcfg = {.time_limit_ms = 1000, .action = POLICY_PAUSE,
                                 .watch = POLICY_WATCH_HEARTBEAT,
                                 .single_owner = single_owner,
                                 .motion_enable = motion_enable};
    struct policy_sink sink = {.send_action = count_action};
    struct plc_write_hooks hooks = {.now_ms = fake_now, .robot_may_move = fake_moving,
                                    .clear_counters = count_clear};

    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    cmd_queue_init(&queue, &ops, 1000);
    assert_int_equal(plc_commands_init(&pc, &img, &queue, &cc, fake_now, NULL), 0);
    policy_init(&policy, &pcfg, &sink);
    assert_int_equal(plc_write_init(&pw, &img, &pc, &policy, wc, &hooks), 0);
    cleared = actions = 0;
    moving = false;
}

static int teardown(void **state)
{
    (void)state;
    plc_write_free(&pw);
    plc_commands_free(&pc);
    cmd_queue_free(&queue);
    regmap_image_free(&img);
    regmap_free(&map);
    return 0;
}

/* One write as the server makes it: judged, then applied and finished. */
static int write_one(const char *from, uint64_t client_id, const struct regmap_row *row,
                     uint16_t value)
{
    struct mb_write w = {.table = row->table, .address = row->address, .count = 1,
                         .values = &value, .client = from, .client_id = client_id,
                         .rights = REGMAP_RIGHTS_ALL};
    assert_int_equal(ip_addr_parse(from, &w.client_addr), 0);
    int ex = plc_write_judge(&pw, &w);
    if (ex == 0) {
        regmap_load(&img, row->table, row->address, 1, &value);
        plc_write_after(&pw);
    }
    return ex;
}

static void heartbeat_owner_and_command_coils(void **state)
{
    (void)state;
    struct plc_write_config wc = {0};
    start(&wc, true, false);

    /* The heartbeat writer becomes the owner; others may not write. */
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 7), 0);
    assert_true(policy.heartbeat_armed);
    assert_int_equal(policy.owner, 1);
    assert_int_equal(write_one("192.0.2.2", 2, pw.rows.heartbeat, 8), 1);
    /* Clear counters: acted on once, and the coil reads 0 again. */
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.clear_counters, 1), 0);
    assert_int_equal(cleared, 1);
    assert_int_equal(img.mb->tab_bits[pw.rows.clear_counters->address], 0);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.clear_counters, 0), 0);
    assert_int_equal(cleared, 1);
    /* A heartbeat loss while moving latches; the reset coil clears it and
     * reads 0 again. */
    moving = true;
    now += 1000;
    policy_check(&policy, now, moving);
    assert_int_equal(policy.fault, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(actions, 1);
    /* The heartbeat back first: a reset while it is still lost would latch again. */
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 9), 0);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.fault_reset, 1), 0);
    assert_int_equal(policy.fault, POLICY_FAULT_NONE);
    assert_int_equal(img.mb->tab_bits[pw.rows.fault_reset->address], 0);
}

static void motion_enable_drop_pauses_through_the_transaction(void **state)
{
    (void)state;
    struct plc_write_config wc = {0};
    start(&wc, false, true);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    assert_true(policy.motion_enabled);
    moving = true;
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 0), 0);
    assert_int_equal(actions, 1);
    assert_int_equal(policy.fault, POLICY_FAULT_MOTION_ENABLE);
}

static void read_only_and_write_allow(void **state)
{
    (void)state;
    char why[96];
    struct plc_write_config wc = {.read_only = true};
    start(&wc, false, false);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 1), 1);
    assert_false(policy.heartbeat_armed);
    teardown(NULL);

    memset(&wc, 0, sizeof(wc));
    assert_int_equal(ip_allow_parse("127.0.0.1 ::1", &wc.write_allow, why, sizeof(why)), 0);
    start(&wc, false, false);
    /* A dual-stack listener (bind = ::) sees IPv4 clients mapped. */
    assert_int_equal(write_one("::ffff:127.0.0.1", 1, pw.rows.heartbeat, 1), 0);
    assert_int_equal(write_one("127.0.0.1", 1, pw.rows.heartbeat, 2), 0);
    assert_int_equal(write_one("0:0:0:0:0:0:0:1", 1, pw.rows.heartbeat, 3), 0);
    assert_int_equal(write_one("127.0.0.2", 1, pw.rows.heartbeat, 4), 1);
    assert_int_equal(write_one("::ffff:127.0.0.2", 1, pw.rows.heartbeat, 4), 1);
    assert_int_equal(write_one("::2", 1, pw.rows.heartbeat, 4), 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_teardown(heartbeat_owner_and_command_coils, teardown),
        cmocka_unit_test_teardown(motion_enable_drop_pauses_through_the_transaction, teardown),
        cmocka_unit_test_teardown(read_only_and_write_allow, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
