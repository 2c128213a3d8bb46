/* SPDX-License-Identifier: MIT */
/*
 * test_plc_write.c - the write transaction's own rows and rules: the
 * heartbeat and the write owner, the fault reset and clear-counters coils
 * (acted on, then reading 0), motion enable, read-only and write_allow
 * compared as addresses. Command rows are tested in test_plc_commands.c
 * through the same transaction; here, only how they meet the policy: a
 * start and a motion-enable drop, a start and a reset, in one write or in
 * two, either order.
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

static unsigned sent_commands;
static char last_sent[128];

static int no_send(void *io, const char *data, size_t size)
{
    (void)io;
    sent_commands++;
    snprintf(last_sent, sizeof(last_sent), "%.*s", (int)size, data);
    return 0;
}

/* The policy's hooks into the command rows, as gateway.c binds them. */
static int policy_gate(void *user, const struct cmd_def *def, char *why, size_t size)
{
    return policy_gate_command(user, now, def, why, size);
}

static void policy_sent(void *user)
{
    policy_start_sent(user, now);
}

static void policy_answered(void *user)
{
    policy_start_answered(user, now);
}

/* What the status shows the arm doing, for the policy's reaction check. */
static enum policy_robot robot_view;

static enum policy_robot fake_robot(void *user)
{
    (void)user;
    return robot_view;
}

/* The action's reply came and a status document shows the arm still: the
 * reaction is judged, and a reset may clear the fault. */
static void action_done_arm_still(void)
{
    policy_action_answered(&policy, now, true);
    robot_view = POLICY_ROBOT_STILL;
    now += 10;
    policy_status_document(&policy, now);
    policy_check(&policy, now, false);
    moving = false;
}

static void start(const struct plc_write_config *wc, bool single_owner, bool motion_enable)
{
    struct cmd_ops ops = {.send = no_send, .now_ms = fake_now};
    struct plc_commands_config cc = {0};
    struct policy_config pcfg = {.time_limit_ms = 1000, .action = POLICY_PAUSE,
                                 .watch = POLICY_WATCH_HEARTBEAT,
                                 .single_owner = single_owner,
                                 .motion_enable = motion_enable};
    struct policy_sink sink = {.send_action = count_action, .robot = fake_robot};
    struct plc_write_hooks hooks = {.now_ms = fake_now, .robot_may_move = fake_moving,
                                    .clear_counters = count_clear};

    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    cmd_queue_init(&queue, &ops, 1000);
    assert_int_equal(plc_commands_init(&pc, &img, &queue, &cc, fake_now, NULL), 0);
    policy_init(&policy, &pcfg, &sink);
    assert_int_equal(plc_write_init(&pw, &img, &pc, &policy, wc, &hooks), 0);
    cleared = actions = 0;
    sent_commands = 0;
    moving = false;
    robot_view = POLICY_ROBOT_UNKNOWN;
}

/* start() with the policy bound to the command rows and the link up. */
static void start_bound(void)
{
    struct plc_write_config wc = {0};
    start(&wc, false, true);
    pc.cfg.gate = policy_gate;
    pc.cfg.start_sent = policy_sent;
    pc.cfg.start_answered = policy_answered;
    pc.cfg.gate_user = &policy;
    cmd_queue_set_connected(&queue, true);
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
    /* Not while the reaction is judged: the reset would cancel a second
     * stop. Nor while the status shows the arm moving. */
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.fault_reset, 1), 6);
    assert_string_equal(pw.why, "reaction still judged: wait");
    assert_int_equal(policy.fault, POLICY_FAULT_HEARTBEAT);
    action_done_arm_still();
    assert_int_equal(policy.reaction, POLICY_REACTION_STOPPED);
    robot_view = POLICY_ROBOT_MOVING;
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.fault_reset, 1), 6);
    assert_string_equal(pw.why, "arm still moving: wait");
    robot_view = POLICY_ROBOT_STILL;
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

/* Several coils in one FC15, as the server makes it. */
static int write_coils(const struct regmap_row *first, const uint16_t *values, unsigned count)
{
    struct mb_write w = {.table = first->table, .address = first->address, .count = count,
                         .values = values, .client = "192.0.2.1", .client_id = 1,
                         .rights = REGMAP_RIGHTS_ALL};
    assert_int_equal(ip_addr_parse(w.client, &w.client_addr), 0);
    int ex = plc_write_judge(&pw, &w);
    if (ex == 0) {
        regmap_load(&img, first->table, first->address, count, values);
        plc_write_after(&pw);
    }
    return ex;
}

static const struct regmap_row *coil_row(const char *command)
{
    char path[64];
    snprintf(path, sizeof(path), "%s", command);
    const struct regmap_row *row = regmap_find_path(&map, REGMAP_SRC_CMD, path);
    assert_non_null(row);
    return row;
}

/*
 * issue 23: play_program, then motion enable dropped before the status
 * shows the program running (the robot still reads idle): the start the
 * gateway sent counts as running, so the drop pauses and latches fault 3.
 * The old transaction judged the drop on the status alone and sent nothing.
 */
static void drop_right_after_a_start_pauses(void **state)
{
    (void)state;
    start_bound();
    const struct regmap_row *play = coil_row("play_program");
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    assert_int_equal(write_one("192.0.2.1", 1, play, 1), 0);
    assert_int_equal(sent_commands, 1);
    assert_string_equal(last_sent, "{\"cmdName\":\"play_program\"}");
    now += 10;
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 0), 0);
    assert_int_equal(actions, 1);
    assert_int_equal(policy.fault, POLICY_FAULT_MOTION_ENABLE);
    /* Answered, still no status after it: it may run, the fault stays one. */
    static const char ok[] = "{\"errorCode\":\"0\"}";
    cmd_queue_on_reply(&queue, ok, sizeof(ok) - 1);
    assert_int_equal(policy.starts_unanswered, 0);
    assert_true(policy_start_unshown(&policy, now));
    policy_check(&policy, now, moving);
    assert_int_equal(actions, 1);
}

/* The other order: motion enable dropped first (idle: nothing to pause),
 * then play_program. Refused, never sent, and the same end as the first
 * order: fault 3 latched, pause sent. */
static void start_after_a_drop_is_refused_and_latches(void **state)
{
    (void)state;
    start_bound();
    const struct regmap_row *play = coil_row("play_program");
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 0), 0);
    assert_int_equal(actions, 0);
    assert_int_equal(policy.fault, POLICY_FAULT_NONE);
    assert_int_equal(write_one("192.0.2.1", 1, play, 1), 1);
    assert_int_equal(sent_commands, 0);
    assert_int_equal(actions, 1);
    assert_int_equal(policy.fault, POLICY_FAULT_MOTION_ENABLE);
    assert_int_equal(img.mb->tab_bits[play->address], 0); /* refused: as before */
    /* A command that starts nothing still passes the lost signal (it is
     * refused only by the latched fault now, until the reset). */
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    action_done_arm_still();
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.fault_reset, 1), 0);
    assert_int_equal(write_one("192.0.2.1", 1, coil_row("power_on"), 1), 0);
    assert_int_equal(sent_commands, 1);
}

/* The trigger block 100-131 in one FC15, as a vendor's client channel
 * writes it (its unassigned coils 0): a start with motion enable dropped in
 * the same write is judged after the drop, refused and never sent (fault 3
 * latched, as for a start after a drop); the same block with motion enable
 * held at 1 sends the start. */
static void trigger_block_with_a_drop_refuses_the_start(void **state)
{
    (void)state;
    start_bound();
    const struct regmap_row *play = coil_row("play_program");
    const struct regmap_row *first = coil_row("power_on");
    unsigned count = pw.rows.motion_enable->address - first->address + 1;
    uint16_t block[64] = {0};
    assert_true(count <= 64);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    block[play->address - first->address] = 1;
    block[pw.rows.motion_enable->address - first->address] = 0;
    assert_int_equal(write_coils(first, block, count), 1);
    assert_int_equal(sent_commands, 0);
    assert_int_equal(img.mb->tab_bits[play->address], 0);
    assert_int_equal(img.mb->tab_bits[pw.rows.motion_enable->address], 0);
    /* The refused start latched fault 3 (as a start after a drop does):
     * motion enable back, the reaction judged (the arm still), the fault
     * reset, then the block again. */
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    action_done_arm_still();
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.fault_reset, 1), 0);
    block[pw.rows.motion_enable->address - first->address] = 1;
    assert_int_equal(write_coils(first, block, count), 0);
    assert_int_equal(sent_commands, 1);
    assert_string_equal(last_sent, "{\"cmdName\":\"play_program\"}");
}

/* Never armed (no 1 written yet): motion enable at 0 refuses starts and
 * latches nothing, as before. */
static void start_before_motion_enable_is_armed_is_only_refused(void **state)
{
    (void)state;
    start_bound();
    assert_int_equal(write_one("192.0.2.1", 1, coil_row("play_program"), 1), 1);
    assert_int_equal(actions, 0);
    assert_int_equal(policy.fault, POLICY_FAULT_NONE);
}

/*
 * One FC15 over the fault-reset and motion-enable coils (130, 131): the
 * reset acknowledges the fault latched before the write, then the drop is
 * judged; the robot running, fault 3 is latched and one pause sent, not
 * cleared by the reset that came with it.
 */
static void reset_and_drop_in_one_write(void **state)
{
    (void)state;
    start_bound();
    assert_int_equal(pw.rows.motion_enable->address, pw.rows.fault_reset->address + 1);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 1), 0);
    moving = true;
    now += 1000;
    policy_check(&policy, now, moving);
    assert_int_equal(policy.fault, POLICY_FAULT_HEARTBEAT);
    assert_int_equal(actions, 1);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 2), 0);
    action_done_arm_still();
    moving = true; /* a program runs again: the drop's pause goes out */
    const uint16_t reset_and_drop[] = {1, 0};
    assert_int_equal(write_coils(pw.rows.fault_reset, reset_and_drop, 2), 0);
    assert_int_equal(policy.fault, POLICY_FAULT_MOTION_ENABLE);
    assert_int_equal(actions, 2);
    assert_int_equal(img.mb->tab_bits[pw.rows.fault_reset->address], 0);
    assert_int_equal(img.mb->tab_bits[pw.rows.motion_enable->address], 0);
    /* Reset and raise in one write: the fault clears, the robot may run. */
    action_done_arm_still();
    const uint16_t reset_and_raise[] = {1, 1};
    assert_int_equal(write_coils(pw.rows.fault_reset, reset_and_raise, 2), 0);
    assert_int_equal(policy.fault, POLICY_FAULT_NONE);
    assert_int_equal(actions, 2);
}

/* A reset and a start: the start is judged against the fault as it was
 * before the reset (a reset never starts anything). Taken one after the
 * other, the start after the reset passes, the one before is refused. */
static void reset_then_start_and_start_then_reset(void **state)
{
    (void)state;
    start_bound();
    const struct regmap_row *play = coil_row("play_program");
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.motion_enable, 1), 0);
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 1), 0);
    moving = true;
    now += 1000;
    policy_check(&policy, now, moving);
    assert_int_equal(policy.fault, POLICY_FAULT_HEARTBEAT);
    moving = false;
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.heartbeat, 2), 0);
    assert_int_equal(write_one("192.0.2.1", 1, play, 1), 1); /* latched */
    assert_int_equal(sent_commands, 0);
    action_done_arm_still();
    assert_int_equal(write_one("192.0.2.1", 1, pw.rows.fault_reset, 1), 0);
    assert_int_equal(write_one("192.0.2.1", 1, play, 1), 0);
    assert_int_equal(sent_commands, 1);
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

/* One write over 'transport' ("modbus", "mbaps", "rtu"). */
static int write_over(const char *transport, uint64_t client_id, const struct regmap_row *row,
                      uint16_t value)
{
    struct mb_write w = {.table = row->table, .address = row->address, .count = 1,
                         .values = &value, .client = "127.0.0.1", .client_id = client_id,
                         .rights = REGMAP_RIGHTS_ALL, .transport = transport};
    assert_int_equal(ip_addr_parse("127.0.0.1", &w.client_addr), 0);
    int ex = plc_write_judge(&pw, &w);
    if (ex == 0) {
        regmap_load(&img, row->table, row->address, 1, &value);
        plc_write_after(&pw);
    }
    return ex;
}

/* write_allow = none: no plain Modbus TCP client writes, with the reason
 * the PLC's result registers give; a TLS client and the RTU line write as
 * their rights allow. */
static void write_allow_none_refuses_plain_tcp_only(void **state)
{
    (void)state;
    struct plc_write_config wc = {.modbus_writes_none = true};
    start(&wc, false, false);
    assert_int_equal(write_over("modbus", 1, pw.rows.heartbeat, 1), 1);
    assert_non_null(strstr(pw.why, "write_allow = none"));
    assert_false(policy.heartbeat_armed);
    assert_int_equal(write_over("mbaps", 2, pw.rows.heartbeat, 1), 0);
    assert_int_equal(write_over("rtu", 2, pw.rows.heartbeat, 2), 0);
}

/*
 * A write refused for who sent it (write_allow, the owner) changes nothing:
 * the owner's parameters stay written, judged or refused by the server.
 */
static void refused_writer_changes_nothing(void **state)
{
    (void)state;
    char why[96];
    struct plc_write_config wc = {0};
    assert_int_equal(ip_allow_parse("127.0.0.1 127.0.0.2", &wc.write_allow, why, sizeof(why)),
                     0);
    start(&wc, true, false);
    const struct regmap_row *rel = regmap_find_path(&map, REGMAP_SRC_CMD, "joint_move.relFlag");
    unsigned bit = (unsigned)(rel - map.rows);
    assert_int_equal(write_one("127.0.0.1", 1, pw.rows.heartbeat, 1), 0);
    assert_int_equal(write_one("127.0.0.1", 1, rel, 0), 0);
    assert_true(pc.params.written[bit] & 1);
    /* Not in write_allow: judged and refused, or refused by the server. */
    assert_int_equal(write_one("192.0.2.7", 2, rel, 1), 1);
    assert_true(pc.params.written[bit] & 1);
    uint16_t one = 1;
    struct mb_write w = {.table = rel->table, .address = rel->address, .count = 1,
                         .values = &one, .client = "192.0.2.7", .client_id = 2,
                         .rights = REGMAP_RIGHTS_ALL};
    assert_int_equal(ip_addr_parse("192.0.2.7", &w.client_addr), 0);
    plc_write_refused_unjudged(&pw, &w);
    assert_true(pc.params.written[bit] & 1);
    /* Allowed, but not the owner: the same. */
    assert_int_equal(write_one("127.0.0.2", 3, rel, 1), 1);
    assert_true(pc.params.written[bit] & 1);
    w.client = "127.0.0.2";
    w.client_id = 3;
    assert_int_equal(ip_addr_parse("127.0.0.2", &w.client_addr), 0);
    plc_write_refused_unjudged(&pw, &w);
    assert_true(pc.params.written[bit] & 1);
    /* The owner's own refused write withdraws what it meant to replace. */
    w.client = "127.0.0.1";
    w.client_id = 1;
    assert_int_equal(ip_addr_parse("127.0.0.1", &w.client_addr), 0);
    plc_write_refused_unjudged(&pw, &w);
    assert_false(pc.params.written[bit] & 1);
}


/* One write from connection 'client_id' at 'peer' ("address:port"). */
static int write_from_peer(const char *peer, uint64_t client_id, const struct regmap_row *row,
                           uint16_t value)
{
    char host[64];
    snprintf(host, sizeof(host), "%.*s", (int)(strrchr(peer, ':') - peer), peer);
    struct mb_write w = {.table = row->table, .address = row->address, .count = 1,
                         .values = &value, .client = host, .peer = peer,
                         .client_id = client_id, .rights = REGMAP_RIGHTS_ALL};
    assert_int_equal(ip_addr_parse(host, &w.client_addr), 0);
    int ex = plc_write_judge(&pw, &w);
    if (ex == 0) {
        regmap_load(&img, row->table, row->address, 1, &value);
        plc_write_after(&pw);
    }
    return ex;
}

static void owner_is_the_plc_and_named_with_its_port(void **state)
{
    (void)state;
    struct plc_write_config wc = {0};
    start(&wc, true, false);
    assert_int_equal(write_from_peer("192.0.2.1:40122", 1, pw.rows.heartbeat, 7), 0);
    assert_string_equal(policy.owner_address, "192.0.2.1:40122");
    /* The same PLC's other connection writes; another host does not, and
     * is told who owns the write side. */
    assert_int_equal(write_from_peer("192.0.2.1:40200", 2, pw.rows.clear_counters, 1), 0);
    assert_int_equal(cleared, 1);
    assert_int_equal(write_from_peer("192.0.2.2:40122", 3, pw.rows.clear_counters, 1), 1);
    assert_string_equal(pw.why, "not the write owner: 192.0.2.1:40122 feeds the heartbeat");
    assert_int_equal(cleared, 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_teardown(heartbeat_owner_and_command_coils, teardown),
        cmocka_unit_test_teardown(owner_is_the_plc_and_named_with_its_port, teardown),
        cmocka_unit_test_teardown(motion_enable_drop_pauses_through_the_transaction, teardown),
        cmocka_unit_test_teardown(read_only_and_write_allow, teardown),
        cmocka_unit_test_teardown(write_allow_none_refuses_plain_tcp_only, teardown),
        cmocka_unit_test_teardown(refused_writer_changes_nothing, teardown),
        cmocka_unit_test_teardown(drop_right_after_a_start_pauses, teardown),
        cmocka_unit_test_teardown(start_after_a_drop_is_refused_and_latches, teardown),
        cmocka_unit_test_teardown(trigger_block_with_a_drop_refuses_the_start, teardown),
        cmocka_unit_test_teardown(start_before_motion_enable_is_armed_is_only_refused, teardown),
        cmocka_unit_test_teardown(reset_and_drop_in_one_write, teardown),
        cmocka_unit_test_teardown(reset_then_start_and_start_then_reset, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
