/* SPDX-License-Identifier: MIT */
/*
 * test_plc_commands.c - PLC writes that command the robot (plc_commands.h),
 * against the real register map and image and a real command queue whose
 * link records what is sent. Writes go through the same two phases as
 * gateway.c's on_write: every element checked with the new values in
 * place, then applied; one refusal restores the image and sends nothing.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cJSON.h>

#include "audit.h"
#include "command.h"
#include "log.h"
#include "plc_commands.h"
#include "plc_write.h"
#include "policy.h"
#include "regmap.h"

#define MAX_SENT 128
#define EX_NONE 0
#define EX_NOT_PERMITTED MODBUS_EXCEPTION_ILLEGAL_FUNCTION         /* 01 */
#define EX_INVALID MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE             /* 03 */
#define EX_BUSY MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY              /* 06 */
#define EX_LINK_DOWN MODBUS_EXCEPTION_GATEWAY_TARGET               /* 0B */

struct fake_robot {
    char sent[MAX_SENT][600];
    unsigned sent_count;
    int fail_sends;
    uint64_t now;
};

#define EX_FAILURE MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE

static struct regmap map;
static struct regmap_image img;
static struct cmd_queue queue;
static struct plc_commands pc;
static struct fake_robot robot;
static struct plc_commands_config cfg;
static const char *client = "192.0.2.10";
/* The connection writes come from (the server's client id). */
static uint64_t connection = 1;
/* The write transaction the server uses, with a policy that watches nothing. */
static struct policy policy;
static struct plc_write writes;
static struct plc_write_config write_cfg; /* for the next start(), then cleared */

static int fake_send(void *io, const char *data, size_t size)
{
    struct fake_robot *r = io;
    if (r->fail_sends > 0) {
        r->fail_sends--;
        return -EPIPE;
    }
    assert_true(r->sent_count < MAX_SENT);
    assert_true(size < sizeof(r->sent[0]));
    memcpy(r->sent[r->sent_count], data, size);
    r->sent[r->sent_count][size] = '\0';
    r->sent_count++;
    return 0;
}

static uint64_t fake_now(void *io)
{
    return ((struct fake_robot *)io)->now;
}

static void fake_restart(void *io, const char *why)
{
    (void)io;
    (void)why;
    cmd_queue_set_connected(&queue, false);
}

static bool never_moves(void *user)
{
    (void)user;
    return false;
}

/* (Re)creates the module with 'config' (and write_cfg); the map and queue stay. */
static void start(const struct plc_commands_config *config)
{
    struct policy_config quiet = {.time_limit_ms = 1000};
    struct policy_sink no_sink = {0};
    struct plc_write_hooks hooks = {.now_ms = fake_now, .robot_may_move = never_moves,
                                    .user = &robot};

    cfg = *config;
    plc_commands_free(&pc);
    assert_int_equal(plc_commands_init(&pc, &img, &queue, &cfg, fake_now, &robot), 0);
    policy_init(&policy, &quiet, &no_sink);
    plc_write_free(&writes);
    assert_int_equal(plc_write_init(&writes, &img, &pc, &policy, &write_cfg, &hooks), 0);
    memset(&write_cfg, 0, sizeof(write_cfg));
}

static int setup(void **state)
{
    (void)state;
    struct cmd_ops ops = {.send = fake_send, .now_ms = fake_now,
                          .restart_link = fake_restart, .io = &robot};
    struct plc_commands_config none = {0};

    log_set_level(LOG_LEVEL_WARNING);
    memset(&robot, 0, sizeof(robot));
    connection = 1;
    robot.now = 50000;
    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    cmd_queue_init(&queue, &ops, 1000);
    cmd_queue_set_connected(&queue, true);
    start(&none);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    cmd_queue_free(&queue);
    plc_write_free(&writes);
    plc_commands_free(&pc);
    regmap_image_free(&img);
    regmap_free(&map);
    return 0;
}

/* ---- rows ---- */

static const struct regmap_row *cmd_row(const char *path)
{
    const struct regmap_row *row = regmap_find_path(&map, REGMAP_SRC_CMD, path);
    if (!row)
        fail_msg("no row cmd:%s", path);
    return row;
}

static const struct regmap_row *gw_row(const char *path)
{
    const struct regmap_row *row = regmap_find_path(&map, REGMAP_SRC_PATH, path);
    if (!row)
        fail_msg("no row gw:%s", path);
    return row;
}

static double gw_number(const char *path)
{
    return regmap_get_number(&img, gw_row(path), 0);
}

static double gw_number_at(const char *path, unsigned i)
{
    return regmap_get_number(&img, gw_row(path), i);
}

static const char *gw_text(const char *path)
{
    static char text[600];
    regmap_get_text(&img, gw_row(path), 0, text, sizeof(text));
    return text;
}

/* ---- writes, through the transaction the Modbus server uses ---- */

static int write_from(const char *who, enum regmap_table table, unsigned address,
                      unsigned count, const uint16_t *values)
{
    struct mb_write w = {.table = table, .address = address, .count = count,
                         .values = values, .client = who, .client_id = connection,
                         .rights = REGMAP_RIGHTS_ALL};

    assert_int_equal(ip_addr_parse(who, &w.client_addr), 0);
    int ex = plc_write_judge(&writes, &w);
    if (ex == 0) {
        regmap_load(&img, table, address, count, values); /* as libmodbus does */
        plc_write_after(&writes);
    }
    return ex;
}

static int write_raw(enum regmap_table table, unsigned address, unsigned count,
                     const uint16_t *values)
{
    return write_from(client, table, address, count, values);
}

static int write_bit(const struct regmap_row *row, unsigned element, int value)
{
    uint16_t v = (uint16_t)value;
    return write_raw(row->table, regmap_element_address(row, element), 1, &v);
}

static int trigger(const char *cmd)
{
    return write_bit(cmd_row(cmd), 0, 1);
}

static int rearm(const char *cmd)
{
    return write_bit(cmd_row(cmd), 0, 0);
}

static int write_u16(const struct regmap_row *row, unsigned element, uint16_t value)
{
    return write_raw(row->table, regmap_element_address(row, element), 1, &value);
}

static void put_f32(uint16_t *regs, double v)
{
    regmap_encode_value(regs, REGMAP_F32, v, true, 1, img.word_order);
}

static int write_f32(const struct regmap_row *row, unsigned element, double v)
{
    uint16_t regs[2];
    put_f32(regs, v);
    return write_raw(row->table, regmap_element_address(row, element), 2, regs);
}

static int write_text(const struct regmap_row *row, const char *text)
{
    uint16_t regs[256];
    assert_true(row->str_regs <= 256);
    regmap_encode_string(regs, row->str_regs, text);
    return write_raw(row->table, row->address, row->str_regs, regs);
}

/* The whole exactly-once mailbox in one write: code, arguments, seq last. */
static int mailbox(unsigned code, const double *args, unsigned nargs, uint16_t seq)
{
    const struct regmap_row *code_row = gw_row("mailbox.code");
    const struct regmap_row *arg_row = gw_row("mailbox.arg[*]");
    const struct regmap_row *seq_row = gw_row("mailbox.seq");
    uint16_t regs[64] = {0};
    unsigned count = seq_row->address - code_row->address + 1;

    assert_true(count <= 64);
    assert_true(nargs <= arg_row->elements);
    regs[0] = (uint16_t)code;
    for (unsigned i = 0; i < arg_row->elements; i++)
        put_f32(&regs[regmap_element_address(arg_row, i) - code_row->address],
                i < nargs ? args[i] : 0);
    regs[count - 1] = seq;
    return write_raw(REGMAP_HOLDING_REGISTER, code_row->address, count, regs);
}

static int json_mailbox(const char *text)
{
    int ex = write_text(gw_row("json.request"), text);
    if (ex)
        return ex;
    ex = write_bit(gw_row("json.trigger"), 0, 0);
    if (ex)
        return ex;
    return write_bit(gw_row("json.trigger"), 0, 1);
}

/* ---- the robot side ---- */

static void reply(const char *json)
{
    cmd_queue_on_reply(&queue, json, strlen(json));
}

static void reply_ok(void)
{
    reply("{\"errorCode\":\"0\",\"errorMsg\":\"\"}");
}

/* Macros, so that a failure names the line of the test. */
#define expect_sent(index, json)                                               \
    do {                                                                       \
        unsigned i_ = (index);                                                 \
        if (i_ >= robot.sent_count)                                            \
            fail_msg("expected %s as command %u; only %u sent", (json), i_,    \
                     robot.sent_count);                                        \
        assert_string_equal(robot.sent[i_], (json));                           \
    } while (0)

#define expect_last_sent(json)                                                 \
    do {                                                                       \
        assert_true(robot.sent_count > 0);                                     \
        expect_sent(robot.sent_count - 1, (json));                             \
    } while (0)

static double result_state(const char *cmd)
{
    char path[96];
    snprintf(path, sizeof(path), "result.%s.state", cmd);
    return gw_number(path);
}

/* The error text a PLC reads for 'cmd' (the first 40 bytes). */
static const char *result_text(const char *cmd)
{
    char path[96];
    snprintf(path, sizeof(path), "result.%s.error_msg", cmd);
    return gw_text(path);
}

/* ---- triggers ---- */

static void trigger_sends_on_rising_edge_only(void **state)
{
    (void)state;
    assert_int_equal(result_state("power_on"), CMD_IDLE);
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    expect_sent(0, "{\"cmdName\":\"power_on\"}");
    assert_int_equal(result_state("power_on"), CMD_PENDING);
    reply_ok();
    assert_int_equal(result_state("power_on"), CMD_DONE);
    assert_int_equal(gw_number("result.power_on.error_code"), 0);
    /* A retransmitted 1 is no new command; 0 re-arms and sends nothing. */
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(rearm("power_on"), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(robot.sent_count, 2);
    reply("{\"cmdName\":\"power_on\",\"errorCode\":\"2\",\"errorMsg\":\"call power_on failed\"}");
    assert_int_equal(result_state("power_on"), CMD_ROBOT_ERROR);
    assert_int_equal(gw_number("result.power_on.error_code"), 2);
    assert_string_equal(gw_text("result.power_on.error_msg"), "call power_on failed");
    /* A negative errorCode reads back negative. cmocka compares as
     * uintmax_t: a negative double must become a signed integer first (its
     * conversion to an unsigned type is undefined; ARM makes it 0). */
    rearm("power_on");
    trigger("power_on");
    reply("{\"errorCode\":\"-1\",\"errorMsg\":\"no\"}");
    assert_int_equal((long)gw_number("result.power_on.error_code"), -1);
    /* stop_program's reply comes as pause_program: it still answers stop. */
    trigger("stop_program");
    expect_last_sent("{\"cmdName\":\"stop_program\"}");
    reply("{\"cmdName\":\"pause_program\",\"errorCode\":\"0\",\"errorMsg\":\"\"}");
    assert_int_equal(result_state("stop_program"), CMD_DONE);
    assert_int_equal(result_state("pause_program"), CMD_IDLE);
}

static void trigger_sends_its_parameters(void **state)
{
    (void)state;
    assert_int_equal(write_text(cmd_row("load_program.programName"), "track/test.jks"),
                     EX_NONE);
    assert_int_equal(robot.sent_count, 0); /* a parameter sends nothing */
    assert_int_equal(trigger("load_program"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"load_program\",\"programName\":\"track/test.jks\"}");
    reply_ok();
    /* Its refresh follows. */
    expect_last_sent("{\"cmdName\":\"get_loaded_program\"}");
    reply("{\"cmdName\":\"get_loaded_program\",\"errorCode\":\"0\",\"programName\":\"track/test.jks\"}");
    assert_string_equal(gw_text("info.loaded_program"), "track/test.jks");

    /* Floats go as the PLC wrote them, not as their binary expansion. */
    const struct regmap_row *centroid = cmd_row("set_payload.centroid[*]");
    write_f32(cmd_row("set_payload.mass"), 0, 2.5);
    write_f32(centroid, 0, 0.1);
    write_f32(centroid, 1, -20);
    write_f32(centroid, 2, 30.25);
    assert_int_equal(trigger("set_payload"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"set_payload\",\"mass\":2.5,\"centroid\":[0.1,-20,30.25]}");
}

static void motion_trigger_with_every_parameter(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    const struct regmap_row *pos = cmd_row("joint_move.jointPosition[*]");
    for (unsigned i = 0; i < 6; i++)
        write_f32(pos, i, 10.5 * (i + 1) - 30);
    write_f32(cmd_row("joint_move.speed"), 0, 20);
    write_f32(cmd_row("joint_move.accel"), 0, 100);
    write_u16(cmd_row("joint_move.relFlag"), 0, 1);
    assert_int_equal(trigger("joint_move"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"joint_move\",\"jointPosition\":[-19.5,-9,1.5,12,22.5,33],"
                     "\"speed\":20,\"accel\":100,\"relFlag\":1}");
    reply_ok();

    const struct regmap_row *cart = cmd_row("moveL.cartPosition[*]");
    for (unsigned i = 0; i < 6; i++)
        write_f32(cart, i, i == 2 ? 300.125 : 0);
    write_f32(cmd_row("moveL.speed"), 0, 50);
    write_f32(cmd_row("moveL.accel"), 0, 500);
    write_f32(cmd_row("moveL.tol"), 0, 0.5);
    write_u16(cmd_row("moveL.relFlag"), 0, 0);
    assert_int_equal(trigger("moveL"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"moveL\",\"cartPosition\":[0,0,300.125,0,0,0],"
                     "\"speed\":50,\"accel\":500,\"relFlag\":0,\"tol\":0.5}");
}

/* ---- setpoints ---- */

static void setpoints_send_each_write(void **state)
{
    (void)state;
    const struct regmap_row *rate = cmd_row("rapid_rate.rate_value");
    assert_int_equal(write_u16(rate, 0, 500), EX_NONE);
    expect_last_sent("{\"cmdName\":\"rapid_rate\",\"rate_value\":0.5}");
    reply_ok();
    assert_int_equal(result_state("rapid_rate"), CMD_DONE);
    /* The same value again is sent again: a setpoint is a command. */
    assert_int_equal(write_u16(rate, 0, 500), EX_NONE);
    assert_int_equal(robot.sent_count, 2);
    reply_ok();
    assert_int_equal(write_u16(rate, 0, 1000), EX_NONE);
    expect_last_sent("{\"cmdName\":\"rapid_rate\",\"rate_value\":1}");
    reply_ok();
    assert_int_equal(write_u16(rate, 0, 1001), EX_INVALID); /* past max */
    assert_int_equal(robot.sent_count, 3);

    /* Digital outputs: a coil each, with its type and index. */
    const struct regmap_row *cab = NULL, *tool = NULL, *ext = NULL;
    for (unsigned r = 0; r < map.row_count; r++) {
        const struct regmap_row *row = &map.rows[r];
        if (row->source != REGMAP_SRC_CMD || !row->fixed ||
            strcmp(row->path, "set_digital_output.value") != 0)
            continue;
        if (strstr(row->fixed, "\"type\": 0"))
            cab = row;
        else if (strstr(row->fixed, "\"type\": 1"))
            tool = row;
        else if (strstr(row->fixed, "\"type\": 2"))
            ext = row;
    }
    assert_non_null(cab);
    assert_non_null(tool);
    assert_non_null(ext);
    char expected[160];
    assert_int_equal(write_bit(cab, 0, 1), EX_NONE);
    snprintf(expected, sizeof(expected),
             "{\"cmdName\":\"set_digital_output\",\"type\":0,\"index\":%u,\"value\":1}",
             cab->index);
    expect_last_sent(expected);
    reply_ok();
    assert_int_equal(write_bit(cab, 0, 0), EX_NONE);
    snprintf(expected, sizeof(expected),
             "{\"cmdName\":\"set_digital_output\",\"type\":0,\"index\":%u,\"value\":0}",
             cab->index);
    expect_last_sent(expected);
    reply_ok();
    assert_int_equal(write_bit(tool, 1, 1), EX_NONE);
    snprintf(expected, sizeof(expected),
             "{\"cmdName\":\"set_digital_output\",\"type\":1,\"index\":%u,\"value\":1}",
             tool->index + 1);
    expect_last_sent(expected);
    reply_ok();
    assert_int_equal(write_bit(ext, 15, 1), EX_NONE);
    snprintf(expected, sizeof(expected),
             "{\"cmdName\":\"set_digital_output\",\"type\":2,\"index\":%u,\"value\":1}",
             ext->index + 15);
    expect_last_sent(expected);
    reply_ok();

    /* Analog output, tool and user frame, collision level. */
    const struct regmap_row *ao = NULL;
    for (unsigned r = 0; r < map.row_count && !ao; r++)
        if (map.rows[r].source == REGMAP_SRC_CMD && map.rows[r].fixed &&
            strcmp(map.rows[r].path, "set_analog_output.value") == 0)
            ao = &map.rows[r];
    assert_non_null(ao);
    assert_int_equal(write_f32(ao, 2, 1.5), EX_NONE);
    snprintf(expected, sizeof(expected),
             "{\"cmdName\":\"set_analog_output\",\"type\":0,\"index\":%u,\"value\":1.5}",
             ao->index + 2);
    expect_last_sent(expected);
    reply_ok();
    assert_int_equal(write_u16(cmd_row("set_tool_id.tool_id"), 0, 3), EX_NONE);
    expect_last_sent("{\"cmdName\":\"set_tool_id\",\"tool_id\":3}");
    reply_ok();
    assert_int_equal(write_u16(cmd_row("set_user_id.user_frame_id"), 0, 2), EX_NONE);
    expect_last_sent("{\"cmdName\":\"set_user_id\",\"user_frame_id\":2}");
    reply_ok();
    assert_int_equal(write_u16(cmd_row("set_clsn_sensitivity.sensitivityVal"), 0, 4),
                     EX_NONE);
    expect_last_sent("{\"cmdName\":\"set_clsn_sensitivity\",\"sensitivityVal\":4}");
    reply_ok();
    expect_last_sent("{\"cmdName\":\"get_clsn_sensitivity\"}");
    reply("{\"errorCode\":\"0\",\"sensitivityLevel\":4}");
    assert_int_equal(gw_number("info.collision_level"), 4);
}

/* One write of several outputs: one command each, in address order; an
 * output written 0 again while the robot reports 0 sends nothing. */
static void multiple_coils_queue_in_order(void **state)
{
    (void)state;
    const struct regmap_row *cab = cmd_row("set_digital_output.value");
    uint16_t bits[4] = {1, 0, 1, 1};
    char expected[160];

    assert_int_equal(write_raw(cab->table, cab->address, 4, bits), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    assert_int_equal(cmd_queue_pending(&queue), 3);
    for (unsigned i = 0, k = 0; i < 4; i++) {
        if (!bits[i])
            continue;
        snprintf(expected, sizeof(expected),
                 "{\"cmdName\":\"set_digital_output\",\"type\":0,\"index\":%u,\"value\":%u}",
                 cab->index + i, bits[i]);
        expect_sent(k++, expected);
        reply_ok();
    }
    assert_int_equal(robot.sent_count, 3);
    assert_int_equal(result_state("set_digital_output"), CMD_DONE);
}

/* A cyclic channel rewrites each output's level every cycle: the same
 * value again sends nothing while the robot reports it, nor within
 * OUTPUT_RESEND_MS of its last set while that one is pending or done;
 * after that, or when it failed, a value the robot reports otherwise is
 * set again, once. */
static void outputs_written_again_send_once(void **state)
{
    (void)state;
    const struct regmap_row *cab = cmd_row("set_digital_output.value");
    int back = regmap_readback_address(&map, cab, 0);
    uint16_t on = 1;

    assert_true(back >= 0);
    assert_int_equal(write_raw(cab->table, cab->address, 1, &on), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    reply_ok();
    for (int i = 0; i < 50; i++) { /* every 10 ms, the report not yet in */
        robot.now += 10;
        assert_int_equal(write_raw(cab->table, cab->address, 1, &on), EX_NONE);
    }
    assert_int_equal(robot.sent_count, 1);
    img.mb->tab_input_bits[back] = 1; /* the robot reports it */
    for (int i = 0; i < 150; i++) {
        robot.now += 10;
        assert_int_equal(write_raw(cab->table, cab->address, 1, &on), EX_NONE);
    }
    assert_int_equal(robot.sent_count, 1);
    img.mb->tab_input_bits[back] = 0; /* set to 0 elsewhere (a pendant) */
    assert_int_equal(write_raw(cab->table, cab->address, 1, &on), EX_NONE);
    assert_int_equal(robot.sent_count, 2);
    reply("{\"errorCode\":\"1\",\"errorMsg\":\"io busy\"}"); /* that set failed */
    robot.now += 10;
    assert_int_equal(write_raw(cab->table, cab->address, 1, &on), EX_NONE);
    assert_int_equal(robot.sent_count, 3); /* a failed set is no reason to wait */
    reply_ok();
    robot.now += 10;
    assert_int_equal(write_raw(cab->table, cab->address, 1, &on), EX_NONE);
    assert_int_equal(robot.sent_count, 3);
}

/* ---- the exactly-once mailbox ---- */

static void mailbox_runs_each_sequence_number_once(void **state)
{
    (void)state;
    const double dout[] = {0, 5, 1};
    assert_int_equal(mailbox(21, dout, 3, 1), EX_NONE);
    expect_last_sent("{\"cmdName\":\"set_digital_output\",\"type\":0,\"index\":5,\"value\":1}");
    assert_int_equal(gw_number("mailbox.ack_seq"), 1);
    assert_int_equal(gw_number("mailbox.done_seq"), 0);
    assert_int_equal(gw_number("mailbox.state"), CMD_PENDING);
    reply_ok();
    assert_int_equal(gw_number("mailbox.done_seq"), 1);
    assert_int_equal(gw_number("mailbox.state"), CMD_DONE);

    /* The same number again, whatever else: nothing is sent. */
    assert_int_equal(mailbox(21, dout, 3, 1), EX_NONE);
    assert_int_equal(mailbox(1, NULL, 0, 1), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    assert_int_equal(gw_number("mailbox.ack_seq"), 1);

    const double rate[] = {0.25};
    assert_int_equal(mailbox(20, rate, 1, 2), EX_NONE);
    expect_last_sent("{\"cmdName\":\"rapid_rate\",\"rate_value\":0.25}");
    reply("{\"errorCode\":\"2\",\"errorMsg\":\"refused\"}");
    assert_int_equal(gw_number("mailbox.done_seq"), 2);
    assert_int_equal(gw_number("mailbox.state"), CMD_ROBOT_ERROR);
    assert_int_equal(gw_number("mailbox.error_code"), 2);
    assert_string_equal(gw_text("mailbox.error_msg"), "refused");

    const double payload[] = {1.5, 0.1, -2, 3};
    assert_int_equal(mailbox(25, payload, 4, 3), EX_NONE);
    expect_last_sent("{\"cmdName\":\"set_payload\",\"mass\":1.5,\"centroid\":[0.1,-2,3]}");
    reply_ok();
    while (cmd_queue_pending(&queue))
        reply_ok(); /* information fetched again, if any */

    /* A text argument comes from the command's own text registers. */
    write_text(cmd_row("load_program.programName"), "welding/seam 2.jks");
    assert_int_equal(mailbox(10, NULL, 0, 4), EX_NONE);
    expect_last_sent("{\"cmdName\":\"load_program\",\"programName\":\"welding/seam 2.jks\"}");
    reply_ok();
    while (cmd_queue_pending(&queue))
        reply_ok();

    assert_int_equal(mailbox(1, NULL, 0, 5), EX_NONE);
    expect_last_sent("{\"cmdName\":\"power_on\"}");
    reply_ok();
    /* Wrapping the number is a new number too. */
    assert_int_equal(mailbox(2, NULL, 0, 0), EX_NONE);
    expect_last_sent("{\"cmdName\":\"power_off\"}");
    reply_ok();
    assert_int_equal(gw_number("mailbox.done_seq"), 0);
    assert_int_equal(queue.stats.unsolicited, 0);
}

static void mailbox_motion_with_motion_on(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    const double args[] = {1, 2, 3, 4, 5, 6, 10, 20, 0};
    assert_int_equal(mailbox(30, args, 9, 7), EX_NONE);
    expect_last_sent("{\"cmdName\":\"joint_move\",\"jointPosition\":[1,2,3,4,5,6],"
                     "\"speed\":10,\"accel\":20,\"relFlag\":0}");
    /* relFlag must be whole. */
    reply_ok();
    const double half[] = {1, 2, 3, 4, 5, 6, 10, 20, 0.5};
    assert_int_equal(mailbox(30, half, 9, 8), EX_INVALID);
    assert_int_equal(robot.sent_count, 1);
}

static void mailbox_refusals(void **state)
{
    (void)state;
    const struct regmap_row *seq = gw_row("mailbox.seq");

    assert_int_equal(mailbox(99, NULL, 0, 1), EX_INVALID);
    assert_int_equal(gw_number("mailbox.state"), CMD_INVALID);
    assert_string_equal(gw_text("mailbox.error_msg"), "unknown command code");
    assert_int_equal(regmap_get_number(&img, seq, 0), 0); /* the write was undone */
    assert_int_equal(gw_number("mailbox.ack_seq"), 0);
    assert_int_equal(mailbox(0, NULL, 0, 1), EX_INVALID);
    /* Codes of commands not offered in the mailbox. */
    assert_int_equal(mailbox(cmd_find("get_version")->code, NULL, 0, 1), EX_INVALID);
    /* A whole number expected: index 1.5. */
    const double half[] = {0, 1.5, 1};
    assert_int_equal(mailbox(21, half, 3, 1), EX_INVALID);
    /* An empty program name. */
    assert_int_equal(mailbox(10, NULL, 0, 1), EX_INVALID);
    /* Not permitted by the configuration. */
    const double args[] = {1, 2, 3, 4, 5, 6, 10, 20, 0};
    assert_int_equal(mailbox(30, args, 9, 1), EX_NOT_PERMITTED);
    assert_int_equal(gw_number("mailbox.state"), CMD_REFUSED);
    assert_int_equal(mailbox(6, NULL, 0, 1), EX_NOT_PERMITTED);
    assert_int_equal(robot.sent_count, 0);
    assert_int_equal(gw_number("mailbox.ack_seq"), 0);

    /* Busy while the last one is pending; nothing of the refused write stays. */
    assert_int_equal(mailbox(1, NULL, 0, 1), EX_NONE);
    assert_int_equal(mailbox(2, NULL, 0, 2), EX_BUSY);
    assert_int_equal(regmap_get_number(&img, seq, 0), 1);
    assert_int_equal(regmap_get_number(&img, gw_row("mailbox.code"), 0), 1);
    /* The count moved: the result is the refused request's, until the
     * pending one ends (done_seq then says whose it is). */
    assert_int_equal(gw_number("mailbox.state"), CMD_REFUSED);
    assert_int_equal(robot.sent_count, 1);
    reply_ok();
    assert_int_equal(gw_number("mailbox.state"), CMD_DONE);
    assert_int_equal(gw_number("mailbox.done_seq"), 1);
    assert_int_equal(mailbox(2, NULL, 0, 2), EX_NONE);
    expect_last_sent("{\"cmdName\":\"power_off\"}");
    reply_ok();
    assert_int_equal(gw_number("mailbox.done_seq"), 2);

    /* Link down. */
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(mailbox(1, NULL, 0, 3), EX_LINK_DOWN);
    assert_int_equal(gw_number("mailbox.state"), CMD_NOT_SENT);
    assert_int_equal(gw_number("mailbox.ack_seq"), 2);
    assert_int_equal(robot.sent_count, 2);
}

/*
 * A mailbox command that was accepted but could not be sent still ends:
 * the PLC waits for done_seq to echo its number, and must see it with
 * the result, or it waits forever.
 */
static void mailbox_send_failure_still_completes(void **state)
{
    (void)state;
    robot.fail_sends = 1;
    assert_int_equal(mailbox(1, NULL, 0, 1), EX_NONE);
    assert_int_equal(robot.sent_count, 0);
    assert_int_equal(gw_number("mailbox.ack_seq"), 1);
    assert_true(gw_number("mailbox.state") != CMD_PENDING);
    assert_true(gw_number("mailbox.state") != CMD_DONE);
    assert_int_equal(gw_number("mailbox.done_seq"), 1);
}

/*
 * Information is fetched again after the commands that change it, however
 * they came: a trigger, the exactly-once mailbox or the JSON mailbox.
 */
static void mailbox_commands_refresh_information(void **state)
{
    (void)state;
    write_text(cmd_row("load_program.programName"), "b.jks");
    assert_int_equal(mailbox(10, NULL, 0, 1), EX_NONE);
    expect_last_sent("{\"cmdName\":\"load_program\",\"programName\":\"b.jks\"}");
    reply_ok();
    expect_last_sent("{\"cmdName\":\"get_loaded_program\"}");
    reply("{\"errorCode\":\"0\",\"programName\":\"b.jks\"}");
    assert_string_equal(gw_text("info.loaded_program"), "b.jks");

    const double payload[] = {1.5, 0.1, -2, 3};
    assert_int_equal(mailbox(25, payload, 4, 2), EX_NONE);
    reply_ok();
    expect_last_sent("{\"cmdName\":\"get_payload\"}");
    reply("{\"errorCode\":\"0\",\"mass\":1.5,\"centroid\":[0.1,-2,3]}");
    assert_float_equal(gw_number("info.payload_mass"), 1.5, 1e-6);

    assert_int_equal(json_mailbox("{\"cmdName\":\"play_program\"}"), EX_NONE);
    reply_ok();
    expect_last_sent("{\"cmdName\":\"get_program_state\"}");
    reply("{\"errorCode\":\"0\",\"programState\":\"running\"}");
    assert_int_equal(gw_number("info.program_state"), 1);
}

/* ---- the JSON mailbox ---- */

static void json_mailbox_sends_the_text(void **state)
{
    (void)state;
    const char *text = "{\"cmdName\": \"get_data\", \"note\": \"as written\"}";
    assert_int_equal(json_mailbox(text), EX_NONE);
    expect_last_sent(text);
    assert_int_equal(gw_number("json.state"), CMD_PENDING);
    const char *answer = "{\"cmdName\":\"get_data\",\"errorCode\":\"0\",\"errorMsg\":\"\","
                         "\"data\":{\"x\":\"\xc3\xa9\"}}";
    reply(answer);
    assert_int_equal(gw_number("json.state"), CMD_DONE);
    assert_string_equal(gw_text("json.reply"), answer);
    assert_int_equal(gw_number("json.reply_truncated"), 0);
    assert_int_equal(gw_number("json.reply_length"), strlen(answer));
    /* Writing 1 again sends nothing; the trigger sends on 0 -> 1 only. */
    assert_int_equal(write_bit(gw_row("json.trigger"), 0, 1), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    /* A robot error shows its code. */
    assert_int_equal(json_mailbox("{\"cmdName\":\"power_on\"}"), EX_NONE);
    reply("{\"errorCode\":\"3\",\"errorMsg\":\"nope\"}");
    assert_int_equal(gw_number("json.state"), CMD_ROBOT_ERROR);
    assert_int_equal(gw_number("json.error_code"), 3);
}

/* The reply's registers as bytes (not up to the first NUL). */
static size_t json_reply_bytes(char *out, size_t size)
{
    const struct regmap_row *row = gw_row("json.reply");
    const uint16_t *regs = &img.mb->tab_input_registers[row->address];
    size_t n = 0;
    assert_true(size >= (size_t)row->str_regs * 2 + 1);
    for (unsigned r = 0; r < row->str_regs; r++) {
        out[n++] = (char)(regs[r] >> 8);
        out[n++] = (char)(regs[r] & 0xFF);
    }
    out[n] = '\0';
    return strlen(out);
}

/* A long reply is cut to the block, never inside a UTF-8 sequence. */
static void json_reply_truncated_on_a_character_boundary(void **state)
{
    (void)state;
    static const char *const chars[] = {"\xc3\xa9", "\xe2\x82\xac", "\xf0\x9f\x98\x80"};
    const size_t block = (size_t)gw_row("json.reply")->str_regs * 2;
    char answer[2048], got[2048];

    for (unsigned c = 0; c < 3; c++) {
        size_t clen = strlen(chars[c]);
        for (size_t shift = 0; shift < clen; shift++) {
            /* The multi-byte character starts 'shift' bytes before the end
             * of the block (0: exactly at its end). */
            const char *head = "{\"errorCode\":\"0\",\"errorMsg\":\"";
            size_t before = block - strlen(head) - shift;
            size_t n = (size_t)snprintf(answer, sizeof(answer), "%s", head);
            memset(answer + n, 'a', before);
            n += before;
            n += (size_t)snprintf(answer + n, sizeof(answer) - n, "%s%s\"}", chars[c],
                                  "tail \xc3\xa9");
            assert_int_equal(json_mailbox("{\"cmdName\":\"get_data\"}"), EX_NONE);
            reply(answer);
            size_t kept = json_reply_bytes(got, sizeof(got));
            size_t start = block - shift; /* where the character begins */
            size_t expect = shift == 0 ? block : start;
            if (kept != expect)
                fail_msg("character of %zu bytes %zu before the end: kept %zu, expected %zu",
                         clen, shift, kept, expect);
            assert_memory_equal(got, answer, kept);
            assert_int_equal(gw_number("json.reply_truncated"), 1);
            assert_int_equal(gw_number("json.reply_length"), strlen(answer));
        }
    }
    /* Exactly the block's size: whole, not truncated. */
    memset(answer, 0, sizeof(answer));
    int n = snprintf(answer, sizeof(answer), "{\"errorCode\":\"0\",\"errorMsg\":\"");
    memset(answer + n, 'b', block - (size_t)n - 2);
    memcpy(answer + block - 2, "\"}", 3);
    assert_int_equal(strlen(answer), block);
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_data\"}"), EX_NONE);
    reply(answer);
    assert_int_equal(json_reply_bytes(got, sizeof(got)), block);
    assert_string_equal(got, answer);
    assert_int_equal(gw_number("json.reply_truncated"), 0);
    assert_int_equal(gw_number("json.reply_length"), block);
    /* A short reply after a long one leaves nothing of the long one. */
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_data\"}"), EX_NONE);
    reply("{\"errorCode\":\"0\"}");
    json_reply_bytes(got, sizeof(got));
    assert_string_equal(got, "{\"errorCode\":\"0\"}");
    /* No reply at all (link down): an empty reply of length 0. */
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_data\"}"), EX_NONE);
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(gw_number("json.state"), CMD_LINK_DOWN);
    json_reply_bytes(got, sizeof(got));
    assert_string_equal(got, "");
    assert_int_equal(gw_number("json.reply_length"), 0);
    assert_int_equal(gw_number("json.reply_truncated"), 0);
}

static void json_mailbox_refusals(void **state)
{
    (void)state;
    assert_int_equal(json_mailbox("{\"cmdName\":"), EX_INVALID);
    assert_int_equal(gw_number("json.state"), CMD_INVALID);
    assert_int_equal(json_mailbox("not json"), EX_INVALID);
    assert_int_equal(json_mailbox("[\"power_on\"]"), EX_INVALID);
    assert_int_equal(json_mailbox("{\"errorCode\":\"0\"}"), EX_INVALID);
    assert_int_equal(json_mailbox("{\"cmdName\":\"\"}"), EX_INVALID);
    assert_int_equal(json_mailbox("{\"cmdName\":5}"), EX_INVALID);
    assert_int_equal(json_mailbox(""), EX_INVALID);
    /* Motion and shutdown stay off through the JSON mailbox too. */
    assert_int_equal(json_mailbox("{\"cmdName\":\"joint_move\",\"jointPosition\":[0,0,0,0,0,0],"
                                  "\"speed\":1,\"accel\":1,\"relFlag\":1}"),
                     EX_NOT_PERMITTED);
    assert_int_equal(gw_number("json.state"), CMD_REFUSED);
    assert_int_equal(json_mailbox("{\"cmdName\":\"servo_j\"}"), EX_NOT_PERMITTED);
    assert_int_equal(json_mailbox("{\"cmdName\":\"shutdown\"}"), EX_NOT_PERMITTED);
    assert_int_equal(robot.sent_count, 0);
    /* The refused trigger reads 0 again: the next 0 -> 1 is a new one. */
    assert_int_equal(regmap_get_number(&img, gw_row("json.trigger"), 0), 0);
    /* Busy. */
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_version\"}"), EX_NONE);
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_version\"}"), EX_BUSY);
    assert_int_equal(robot.sent_count, 1);
}

/* ---- refusals of triggers and setpoints ---- */

static void not_permitted(void **state)
{
    (void)state;
    assert_int_equal(trigger("joint_move"), EX_NOT_PERMITTED);
    assert_int_equal(result_state("joint_move"), CMD_REFUSED);
    assert_int_equal(regmap_get_number(&img, cmd_row("joint_move"), 0), 0);
    assert_int_equal(trigger("end_move"), EX_NOT_PERMITTED);
    assert_int_equal(trigger("moveL"), EX_NOT_PERMITTED);
    assert_int_equal(trigger("shutdown"), EX_NOT_PERMITTED);
    assert_int_equal(result_state("shutdown"), CMD_REFUSED);
    /* One refused element refuses the whole write: power_on, in the same
     * write of coils before joint_move, is not sent either. */
    const struct regmap_row *first = cmd_row("power_on"), *last = cmd_row("joint_move");
    uint16_t ones[64];
    for (unsigned i = 0; i < 64; i++)
        ones[i] = 0;
    ones[0] = 1;
    ones[last->address - first->address] = 1;
    assert_int_equal(write_raw(REGMAP_COIL, first->address,
                               last->address - first->address + 1, ones),
                     EX_NOT_PERMITTED);
    assert_int_equal(regmap_get_number(&img, first, 0), 0);
    assert_int_equal(robot.sent_count, 0);

    /* Read-only: nothing at all may be written. */
    struct plc_commands_config ro = {.motion = true};
    write_cfg.read_only = true;
    start(&ro);
    assert_int_equal(trigger("power_on"), EX_NOT_PERMITTED);
    assert_int_equal(write_u16(cmd_row("rapid_rate.rate_value"), 0, 300), EX_NOT_PERMITTED);
    assert_int_equal(regmap_get_number(&img, cmd_row("rapid_rate.rate_value"), 0), 0);

    /* write_allow: only the clients named. */
    struct plc_commands_config allow = {0};
    char why[96];
    assert_int_equal(ip_allow_parse("192.0.2.7, 2001:db8::7", &write_cfg.write_allow, why,
                                    sizeof(why)), 0);
    start(&allow);
    uint16_t one = 1;
    assert_int_equal(write_from("192.0.2.70", REGMAP_COIL, first->address, 1, &one),
                     EX_NOT_PERMITTED);
    assert_int_equal(write_from("192.0.2.10", REGMAP_COIL, first->address, 1, &one),
                     EX_NOT_PERMITTED);
    assert_int_equal(robot.sent_count, 0);
    assert_int_equal(write_from("2001:db8::7", REGMAP_COIL, first->address, 1, &one),
                     EX_NONE);
    expect_last_sent("{\"cmdName\":\"power_on\"}");
    reply_ok();
    /* Compared as addresses: an IPv4 client of a dual-stack listener, and
     * another spelling of the IPv6 address, are the same clients. */
    assert_int_equal(write_from("::ffff:192.0.2.7", REGMAP_COIL, first->address, 1, &one),
                     EX_NONE); /* 1 -> 1: no command, but allowed */
    assert_int_equal(write_from("2001:0db8:0:0::0:7", REGMAP_COIL, first->address, 1, &one),
                     EX_NONE);
    assert_int_equal(write_from("::ffff:192.0.2.70", REGMAP_COIL, first->address, 1, &one),
                     EX_NOT_PERMITTED);
    /* Shutdown when allowed. */
    struct plc_commands_config down = {.allow_shutdown = true};
    start(&down);
    assert_int_equal(trigger("shutdown"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"shutdown\"}");
}

static void invalid_values(void **state)
{
    (void)state;
    /* load_program without a program name. */
    assert_int_equal(trigger("load_program"), EX_INVALID);
    assert_int_equal(result_state("load_program"), CMD_INVALID);
    assert_int_equal(regmap_get_number(&img, cmd_row("load_program"), 0), 0);
    /* A name, then erased. */
    write_text(cmd_row("load_program.programName"), "x.jks");
    write_text(cmd_row("load_program.programName"), "");
    assert_int_equal(trigger("load_program"), EX_INVALID);
    /* Out of range and not finite: the map refuses them. */
    assert_int_equal(write_u16(cmd_row("set_tool_id.tool_id"), 0, 11), EX_INVALID);
    assert_int_equal(write_f32(cmd_row("set_payload.mass"), 0, NAN), EX_INVALID);
    assert_int_equal(write_f32(cmd_row("set_payload.mass"), 0, -1), EX_INVALID);
    assert_int_equal(robot.sent_count, 0);
}

static void busy(void **state)
{
    (void)state;
    assert_int_equal(trigger("power_on"), EX_NONE);
    rearm("power_on");
    /* The same command again while it is pending: refused, and the result
     * the PLC reads with the count moved is this request's, even after
     * the pending one's reply. */
    assert_int_equal(trigger("power_on"), EX_BUSY);
    assert_int_equal(result_state("power_on"), CMD_REFUSED);
    assert_string_equal(result_text("power_on"), "busy: the previous one is pending");
    assert_int_equal(regmap_get_number(&img, cmd_row("power_on"), 0), 0);
    /* Another command queues behind it. */
    assert_int_equal(trigger("enable_robot"), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    reply_ok();
    assert_int_equal(result_state("power_on"), CMD_REFUSED);
    expect_last_sent("{\"cmdName\":\"enable_robot\"}");
    reply_ok();

    /* A full queue refuses the whole write. */
    const struct regmap_row *rate = cmd_row("rapid_rate.rate_value");
    for (unsigned i = 0; i < CMD_QUEUE_CAPACITY; i++)
        assert_int_equal(write_u16(rate, 0, (uint16_t)i), EX_NONE);
    assert_int_equal(cmd_queue_pending(&queue), CMD_QUEUE_CAPACITY);
    assert_int_equal(write_u16(rate, 0, 999), EX_BUSY);
    assert_int_equal(img.mb->tab_registers[rate->address], CMD_QUEUE_CAPACITY - 1);
    /* A trigger refused for a full queue: its count and its result. */
    double before = gw_number("result.power_off.count");
    assert_int_equal(trigger("power_off"), EX_BUSY);
    assert_int_equal(gw_number("result.power_off.count"), before + 1);
    assert_int_equal(result_state("power_off"), CMD_REFUSED);
    assert_string_equal(result_text("power_off"), "busy: the command queue is full");
    rearm("power_off");
    reply_ok();
    /* One place, but a write of two outputs needs two. */
    const struct regmap_row *cab = cmd_row("set_digital_output.value");
    uint16_t bits[2] = {1, 1};
    assert_int_equal(write_raw(cab->table, cab->address, 2, bits), EX_BUSY);
    assert_int_equal(write_raw(cab->table, cab->address, 1, bits), EX_NONE);
    assert_int_equal(cmd_queue_pending(&queue), CMD_QUEUE_CAPACITY);
    unsigned sent = robot.sent_count;
    while (cmd_queue_pending(&queue))
        reply_ok();
    assert_int_equal(robot.sent_count, sent + CMD_QUEUE_CAPACITY - 1);
}

/* Writes joint_move's whole target block, so its trigger may send. */
static void write_joint_target(double joint1)
{
    const struct regmap_row *pos = cmd_row("joint_move.jointPosition[*]");
    for (unsigned i = 0; i < 6; i++)
        assert_int_equal(write_f32(pos, i, i == 0 ? joint1 : 90), EX_NONE);
    assert_int_equal(write_f32(cmd_row("joint_move.speed"), 0, 20), EX_NONE);
    assert_int_equal(write_f32(cmd_row("joint_move.accel"), 0, 100), EX_NONE);
    assert_int_equal(write_u16(cmd_row("joint_move.relFlag"), 0, 0), EX_NONE);
}

static void halts_own_the_queue(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    /* power_on in flight; behind it a joint_move and an output wait. */
    assert_int_equal(trigger("power_on"), EX_NONE);
    write_joint_target(30);
    assert_int_equal(trigger("joint_move"), EX_NONE);
    assert_int_equal(trigger("play_program"), EX_NONE);
    assert_int_equal(write_bit(cmd_row("set_digital_output.value"), 0, 1), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    /* The PLC's stop goes out at once; what would move the arm is out of
     * the queue with its own result, the output still waits. */
    assert_int_equal(trigger("stop_program"), EX_NONE);
    assert_int_equal(robot.sent_count, 2);
    expect_last_sent("{\"cmdName\":\"stop_program\"}");
    assert_int_equal(result_state("joint_move"), CMD_NOT_SENT);
    assert_string_equal(result_text("joint_move"), "not sent: a safety action took its place");
    assert_int_equal(result_state("play_program"), CMD_NOT_SENT);
    assert_int_equal(cmd_queue_pending(&queue), 3);
    while (cmd_queue_pending(&queue))
        reply_ok();
    for (unsigned i = 0; i < robot.sent_count; i++) {
        assert_null(strstr(robot.sent[i], "joint_move"));
        assert_null(strstr(robot.sent[i], "play_program"));
    }
    assert_non_null(strstr(robot.sent[2], "set_digital_output"));
    /* A full queue never refuses a stop or a pause, nor one pending. */
    const struct regmap_row *rate = cmd_row("rapid_rate.rate_value");
    for (unsigned i = 0; i < CMD_QUEUE_CAPACITY; i++)
        assert_int_equal(write_u16(rate, 0, (uint16_t)i), EX_NONE);
    assert_int_equal(cmd_queue_pending(&queue), CMD_QUEUE_CAPACITY);
    rearm("stop_program");
    assert_int_equal(trigger("pause_program"), EX_NONE);
    assert_int_equal(trigger("stop_program"), EX_NONE);
    rearm("stop_program");
    assert_int_equal(trigger("stop_program"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"stop_program\"}");
    assert_int_equal(result_state("stop_program"), CMD_PENDING);
    while (cmd_queue_pending(&queue))
        reply_ok();
    assert_int_equal(result_state("stop_program"), CMD_DONE);
    /* The mailbox keeps one command pending, a stop too: its done_seq
     * and its result are one command's (the stop trigger is the way). */
    assert_int_equal(mailbox(1, NULL, 0, 7), EX_NONE);
    assert_int_equal(mailbox(cmd_find("stop_program")->code, NULL, 0, 8), EX_BUSY);
    reply_ok();
    assert_int_equal(gw_number("mailbox.done_seq"), 7);
}

/* A number that is not finite never goes out: 1e999 reads as infinity. */
static void json_mailbox_refuses_non_finite_numbers(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    assert_int_equal(json_mailbox("{\"cmdName\":\"joint_move\",\"jointPosition\":"
                                  "[1e999,90,90,0,90,0],\"speed\":20}"),
                     EX_INVALID);
    assert_int_equal(gw_number("json.state"), CMD_INVALID);
    assert_int_equal(json_mailbox("{\"cmdName\":\"moveL\",\"cartPosition\":"
                                  "[0,0,1,0,0,0],\"speed\":-1e999}"),
                     EX_INVALID);
    assert_int_equal(robot.sent_count, 0);
    assert_int_equal(json_mailbox("{\"cmdName\":\"joint_move\",\"jointPosition\":"
                                  "[1e300,90,90,0,90,0],\"speed\":20}"),
                     EX_NONE);
    assert_int_equal(robot.sent_count, 1);
}

static void link_down(void **state)
{
    (void)state;
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(trigger("power_on"), EX_LINK_DOWN);
    assert_int_equal(result_state("power_on"), CMD_NOT_SENT);
    assert_string_equal(result_text("power_on"), "not sent: the command link is down");
    assert_int_equal(regmap_get_number(&img, cmd_row("power_on"), 0), 0);
    /* A write of several setpoints: none sent, none kept. */
    const struct regmap_row *rate = cmd_row("rapid_rate.rate_value");
    uint16_t regs[4] = {500, 1, 2, 3};
    assert_int_equal(write_raw(rate->table, rate->address, 4, regs), EX_LINK_DOWN);
    assert_int_equal(regmap_get_number(&img, rate, 0), 0);
    assert_int_equal(regmap_get_number(&img, cmd_row("set_tool_id.tool_id"), 0), 0);
    assert_int_equal(robot.sent_count, 0);
    /* Parameters alone are no command: they may be written while down. */
    assert_int_equal(write_text(cmd_row("load_program.programName"), "a.jks"), EX_NONE);
    /* A command pending when the link goes down shows it: written, its
     * outcome is unknown; queued behind it, it was never sent. */
    cmd_queue_set_connected(&queue, true);
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(trigger("enable_robot"), EX_NONE);
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(result_state("power_on"), CMD_LINK_DOWN);
    assert_string_equal(result_text("power_on"), "outcome unknown: the link went down");
    assert_int_equal(result_state("enable_robot"), CMD_NOT_SENT);
    assert_string_equal(result_text("enable_robot"), "not sent: the link went down");
    /* The reply timeout shows too. */
    cmd_queue_set_connected(&queue, true);
    rearm("power_on");
    assert_int_equal(trigger("power_on"), EX_NONE);
    robot.now += 1000;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(result_state("power_on"), CMD_TIMEOUT);
    /* The PLC reads the first 40 bytes: they say what matters. */
    assert_true(strncmp(result_text("power_on"), "outcome unknown: no reply in", 28) == 0);
    assert_false(queue.connected);
}

/* ---- robot information ---- */

/* The link check's reply shows what it says about the robot, in either
 * spelling of the manual and of real controllers; a failed one changes
 * nothing. */
static void link_check_reply_shows_the_robot_state(void **state)
{
    (void)state;
    const char *reply1 = "{\"cmdName\":\"get_robot_state\",\"errorCode\":\"0\","
                         "\"enable\":\"robot_enabled\",\"power\":\"powered on\"}";
    struct cmd_result r;

    assert_int_equal(gw_number("info.robot_enabled"), 0);
    cmd_parse_reply(reply1, strlen(reply1), &r);
    plc_commands_link_check_reply(&pc, "get_robot_state", &r);
    assert_int_equal(gw_number("info.robot_enabled"), 1);
    assert_int_equal(gw_number("info.robot_powered_on"), 1);
    const char *reply2 = "{\"errorCode\":\"0\",\"enable\":\"robot_disabled\","
                         "\"power\":\"powered_off\"}";
    cmd_parse_reply(reply2, strlen(reply2), &r);
    plc_commands_link_check_reply(&pc, "get_robot_state", &r);
    assert_int_equal(gw_number("info.robot_enabled"), 0);
    assert_int_equal(gw_number("info.robot_powered_on"), 0);
    const char *reply3 = "{\"errorCode\":\"1\",\"enable\":\"robot_enabled\"}";
    cmd_parse_reply(reply3, strlen(reply3), &r);
    plc_commands_link_check_reply(&pc, "get_robot_state", &r);
    assert_int_equal(gw_number("info.robot_enabled"), 0);
    /* An unknown word reads as absent (0), not as the last value. */
    cmd_parse_reply(reply1, strlen(reply1), &r);
    plc_commands_link_check_reply(&pc, "get_robot_state", &r);
    assert_int_equal(gw_number("info.robot_enabled"), 1);
    const char *reply4 = "{\"errorCode\":\"0\",\"enable\":\"maybe\"}";
    cmd_parse_reply(reply4, strlen(reply4), &r);
    plc_commands_link_check_reply(&pc, "get_robot_state", &r);
    assert_int_equal(gw_number("info.robot_enabled"), 0);
}

static void information_after_replies(void **state)
{
    (void)state;
    plc_commands_refresh(&pc);
    assert_int_equal(gw_number("info.age_ms"), 4294967295.0);

    plc_commands_link_up(&pc);
    expect_last_sent("{\"cmdName\":\"get_version\"}");
    reply("{\"cmdName\":\"get_version\",\"errorCode\":\"0\",\"errorMsg\":\"\","
          "\"version\":\"1.7.2.16\"}");
    expect_last_sent("{\"cmdName\":\"get_loaded_program\"}");
    reply("{\"cmdName\":\"get_loaded_program\",\"errorCode\":\"0\",\"errorMsg\":\"\","
          "\"programName\":\"track/\xc3\xa9t\xc3\xa9.jks\"}");
    expect_last_sent("{\"cmdName\":\"get_program_state\"}");
    reply("{\"cmdName\":\"get_program_state\",\"errorCode\":\"0\",\"errorMsg\":\"\","
          "\"programState\":\"running\"}");
    expect_last_sent("{\"cmdName\":\"get_payload\"}");
    reply("{\"cmdName\":\"get_payload\",\"errorCode\":\"0\",\"errorMsg\":\"\","
          "\"mass\":2.5,\"centroid\":[10,-20.5,30]}");
    expect_last_sent("{\"cmdName\":\"get_clsn_sensitivity\"}");
    robot.now = 60000;
    reply("{\"cmdName\":\"get_clsn_sensitivity\",\"errorCode\":\"0\",\"errorMsg\":\"\","
          "\"sensitivityLevel\":3}");
    /* Frames as the manual spells them ("tool offsets", one array per frame). */
    expect_last_sent("{\"cmdName\":\"get_tool_offsets\"}");
    reply("{\"errorCode\":\"0\",\"tool offsets\":[[0,0,0,0,0,0],[1,2,3,4,5,6]]}");
    expect_last_sent("{\"cmdName\":\"get_user_offsets\"}");
    reply("{\"errorCode\":\"0\",\"user_offsets\":[[9,8,7,6,5,4]]}");
    expect_last_sent("{\"cmdName\":\"get_dh_param\"}");
    reply("{\"errorCode\":\"0\",\"alpha\":[0,1.5708,0,0,1.5708,-1.5708],"
          "\"a\":[0,0,430,368.5,0,0],\"d\":[120.15,0,0,114.5,113.5,107],"
          "\"joint_homeoff\":[0,0,0,0,0,0]}");
    assert_int_equal(robot.sent_count, 8);
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_float_equal(gw_number_at("info.tool_offsets[*]", 6), 1, 1e-6);
    assert_float_equal(gw_number_at("info.tool_offsets[*]", 11), 6, 1e-6);
    assert_float_equal(gw_number_at("info.user_offsets[*]", 0), 9, 1e-6);
    assert_true(isnan(gw_number_at("info.user_offsets[*]", 6))); /* not sent */
    assert_float_equal(gw_number_at("info.dh_a[*]", 2), 430, 1e-4);
    assert_float_equal(gw_number_at("info.dh_d[*]", 0), 120.15, 1e-4);

    assert_string_equal(gw_text("info.controller_version"), "1.7.2.16");
    assert_string_equal(gw_text("info.loaded_program"), "track/\xc3\xa9t\xc3\xa9.jks");
    assert_int_equal(gw_number("info.program_state"), 1);
    assert_float_equal(gw_number("info.payload_mass"), 2.5, 1e-6);
    assert_float_equal(gw_number_at("info.payload_centroid[*]", 0), 10, 1e-6);
    assert_float_equal(gw_number_at("info.payload_centroid[*]", 1), -20.5, 1e-6);
    assert_float_equal(gw_number_at("info.payload_centroid[*]", 2), 30, 1e-6);
    assert_int_equal(gw_number("info.collision_level"), 3);
    robot.now = 60250;
    plc_commands_refresh(&pc);
    assert_int_equal(gw_number("info.age_ms"), 250);
    /* Information fetches never show in a command's result registers. */
    assert_int_equal(result_state("set_payload"), CMD_IDLE);

    /* The collision level as a string; program states by name or number. */
    plc_commands_link_up(&pc);
    reply_ok();
    reply_ok();
    reply("{\"errorCode\":\"0\",\"programState\":\"paused\"}");
    assert_int_equal(gw_number("info.program_state"), 2);
    reply_ok();
    reply("{\"errorCode\":\"0\",\"sensitivityLevel\":\"4\"}");
    assert_int_equal(gw_number("info.collision_level"), 4);
    reply_ok();
    reply_ok();
    reply_ok();
    /* A reply without the member leaves the value as it was. */
    assert_string_equal(gw_text("info.loaded_program"), "track/\xc3\xa9t\xc3\xa9.jks");

    trigger("stop_program");
    reply_ok();
    expect_last_sent("{\"cmdName\":\"get_program_state\"}");
    reply("{\"errorCode\":\"0\",\"programState\":\"idle\"}");
    assert_int_equal(gw_number("info.program_state"), 0);
    rearm("stop_program");
    trigger("stop_program");
    reply_ok();
    reply("{\"errorCode\":\"0\",\"programState\":2}");
    assert_int_equal(gw_number("info.program_state"), 2);
    /* A refused command fetches nothing. */
    trigger("play_program");
    unsigned sent = robot.sent_count;
    reply("{\"errorCode\":\"1\"}");
    assert_int_equal(robot.sent_count, sent);
    /* A failed fetch keeps the last values. */
    plc_commands_link_up(&pc);
    reply("{\"errorCode\":\"1\",\"version\":\"9\"}");
    assert_string_equal(gw_text("info.controller_version"), "1.7.2.16");
}

/* Connecting twice while the fetches are pending fetches each once. */
static void information_fetched_once_at_a_time(void **state)
{
    (void)state;
    plc_commands_link_up(&pc);
    plc_commands_link_up(&pc);
    assert_int_equal(cmd_queue_pending(&queue), PLC_INFO_COMMANDS);
    cmd_queue_set_connected(&queue, false);
    cmd_queue_set_connected(&queue, true);
    plc_commands_link_up(&pc);
    assert_int_equal(cmd_queue_pending(&queue), PLC_INFO_COMMANDS);
}

/*
 * A command accepted while another is in flight is the next sent, even
 * when the reply to the one in flight asks for information again: the
 * refresh of load_program queues behind play_program, and each reply
 * answers its own command.
 */
static void refresh_queues_behind_accepted_commands(void **state)
{
    (void)state;
    write_text(cmd_row("load_program.programName"), "a.jks");
    assert_int_equal(trigger("load_program"), EX_NONE);
    assert_int_equal(trigger("play_program"), EX_NONE);
    reply("{\"cmdName\":\"load_program\",\"errorCode\":\"0\"}");
    assert_int_equal(result_state("load_program"), CMD_DONE);
    expect_sent(1, "{\"cmdName\":\"play_program\"}");
    reply("{\"cmdName\":\"play_program\",\"errorCode\":\"0\"}");
    assert_int_equal(result_state("play_program"), CMD_DONE);
    expect_sent(2, "{\"cmdName\":\"get_loaded_program\"}");
    reply("{\"cmdName\":\"get_loaded_program\",\"errorCode\":\"0\",\"programName\":\"a.jks\"}");
    expect_sent(3, "{\"cmdName\":\"get_program_state\"}");
    reply("{\"cmdName\":\"get_program_state\",\"errorCode\":\"0\",\"programState\":\"running\"}");
    assert_int_equal(robot.sent_count, 4);
    assert_string_equal(gw_text("info.loaded_program"), "a.jks");
    assert_int_equal(gw_number("info.program_state"), 1);
    assert_int_equal(cmd_queue_pending(&queue), 0);
}

/* ---- the robot's network-exception handler, the gate, send_now ---- */

static void robot_handler_first_on_every_connect(void **state)
{
    (void)state;
    struct plc_commands_config c = {.robot_handle = true, .robot_time_limit_ms = 500,
                                    .robot_mot_type = 1, .require_robot_handle = true};
    start(&c);
    assert_int_equal(gw_number("network_exception.robot_handle"), PLC_HANDLE_NOT_SENT);
    /* Before the robot accepts it, commands are refused. */
    assert_int_equal(trigger("power_on"), EX_NOT_PERMITTED);
    assert_int_equal(result_state("power_on"), CMD_REFUSED);
    assert_int_equal(robot.sent_count, 0);
    plc_commands_link_up(&pc);
    expect_sent(0, "{\"cmdName\":\"set_network_exception_handle\",\"timeLimit\":500,"
                   "\"motType\":1}");
    assert_int_equal(gw_number("network_exception.robot_handle"), PLC_HANDLE_PENDING);
    assert_int_equal(trigger("power_on"), EX_NOT_PERMITTED);
    reply_ok();
    assert_int_equal(gw_number("network_exception.robot_handle"), PLC_HANDLE_ACCEPTED);
    expect_last_sent("{\"cmdName\":\"get_version\"}");
    while (cmd_queue_pending(&queue))
        reply_ok();
    assert_int_equal(trigger("power_on"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"power_on\"}");
    reply_ok();

    /* A new connection sets it again; refused, commands stay refused. */
    cmd_queue_set_connected(&queue, false);
    plc_commands_link_down(&pc);
    assert_int_equal(gw_number("network_exception.robot_handle"), PLC_HANDLE_NOT_SENT);
    cmd_queue_set_connected(&queue, true);
    plc_commands_link_up(&pc);
    reply("{\"errorCode\":\"1\",\"errorMsg\":\"unsupported\"}");
    assert_int_equal(gw_number("network_exception.robot_handle"), PLC_HANDLE_FAILED);
    while (cmd_queue_pending(&queue))
        reply_ok();
    rearm("power_on");
    unsigned sent = robot.sent_count;
    assert_int_equal(trigger("power_on"), EX_NOT_PERMITTED);
    assert_int_equal(robot.sent_count, sent);
    /* Not required: sent, but its failure refuses nothing. */
    c.require_robot_handle = false;
    start(&c);
    assert_int_equal(trigger("power_on"), EX_NONE);
}

static char gate_seen[64];

static int gate_all_but_stop(void *user, const struct cmd_def *def, char *why, size_t size)
{
    (void)user;
    snprintf(gate_seen, sizeof(gate_seen), "%s", def ? def->name : "(none)");
    if (def && strcmp(def->name, "stop_program") == 0)
        return 0;
    snprintf(why, size, "fault latched");
    return EX_NOT_PERMITTED;
}

static void gate_has_a_say_on_every_command(void **state)
{
    (void)state;
    struct plc_commands_config c = {.gate = gate_all_but_stop};
    start(&c);
    assert_int_equal(trigger("play_program"), EX_NOT_PERMITTED);
    assert_string_equal(gate_seen, "play_program");
    assert_int_equal(result_state("play_program"), CMD_REFUSED);
    assert_string_equal(gw_text("result.play_program.error_msg"), "fault latched");
    assert_int_equal(write_u16(cmd_row("rapid_rate.rate_value"), 0, 100), EX_NOT_PERMITTED);
    assert_int_equal(mailbox(1, NULL, 0, 1), EX_NOT_PERMITTED);
    assert_int_equal(gw_number("mailbox.ack_seq"), 0);
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_data\"}"), EX_NOT_PERMITTED);
    assert_string_equal(gate_seen, "get_data");
    assert_int_equal(robot.sent_count, 0);
    /* Writes that send nothing are not the gate's business. */
    gate_seen[0] = '\0';
    assert_int_equal(write_text(cmd_row("load_program.programName"), "a.jks"), EX_NONE);
    assert_string_equal(gate_seen, "");
    assert_int_equal(trigger("stop_program"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"stop_program\"}");
}

/*
 * A name the command table does not know went to the robot unchecked:
 * "Joint_Move" reached the controller with motion off while joint_move was
 * refused. Now it is refused (01) unless motion is on, and with motion on
 * the gates judge it as motion.
 */
static void json_mailbox_refuses_names_outside_the_table(void **state)
{
    (void)state;
    static const char *const smuggled[] = {
        "{\"cmdName\":\"Joint_Move\",\"jointPosition\":[20,0,0,0,0,0],\"speed\":10,"
        "\"accel\":10,\"relFlag\":1}",
        "{\"cmdName\":\"JOINT_MOVE\"}",
        "{\"cmdName\":\"joint_move \"}",
        "{\"cmdName\":\"a_motion_command_from_a_newer_controller\"}",
    };
    for (unsigned i = 0; i < sizeof(smuggled) / sizeof(smuggled[0]); i++) {
        assert_int_equal(json_mailbox(smuggled[i]), EX_NOT_PERMITTED);
        assert_int_equal(robot.sent_count, 0);
        assert_int_equal(gw_number("json.state"), CMD_REFUSED);
    }
    /* Chapter 4's queries stay reachable with motion off. */
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_joint_pos\"}"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"get_joint_pos\"}");
    reply_ok();
    /* Motion on: the gate sees it, as motion (def NULL), and may refuse it. */
    struct plc_commands_config gated = {.motion = true, .gate = gate_all_but_stop};
    start(&gated);
    unsigned sent = robot.sent_count;
    gate_seen[0] = '\0';
    assert_int_equal(json_mailbox(smuggled[0]), EX_NOT_PERMITTED);
    assert_string_equal(gate_seen, "(none)");
    assert_int_equal(robot.sent_count, sent);
    /* Motion on and nothing against it: it goes out as written. */
    struct plc_commands_config open = {.motion = true};
    start(&open);
    assert_int_equal(json_mailbox(smuggled[0]), EX_NONE);
    expect_last_sent(smuggled[0]);
}

/* A malloc for cJSON that fails once 'alloc_budget' allocations are spent. */
static long alloc_budget = -1;
static unsigned failed_allocs;

static void *budget_malloc(size_t size)
{
    if (alloc_budget == 0) {
        failed_allocs++;
        return NULL;
    }
    if (alloc_budget > 0)
        alloc_budget--;
    return malloc(size);
}

/*
 * A command from the registers is written as bytes (cmd_json.h), with no
 * cJSON tree: with every cJSON allocation failing it still goes out, the
 * same bytes as with memory to spare. (Building it with cJSON, an
 * unchecked cJSON_CreateNull() while growing an array once spun the event
 * loop for ever.)
 */
static void table_commands_need_no_cjson_allocation(void **state)
{
    (void)state;
    cJSON_Hooks hooks = {.malloc_fn = budget_malloc, .free_fn = free};
    struct plc_commands_config motion = {.motion = true};
    const double args[] = {10, 20, 30, 40, 50, 60, 5, 5, 0};
    char first[600];

    start(&motion);
    alarm(20); /* a hang fails the test instead of stalling the suite */
    for (long budget = -1; budget < 3; budget++) {
        unsigned sent = robot.sent_count;
        cJSON_InitHooks(&hooks);
        alloc_budget = budget;
        int ex = mailbox(30, args, 9, (uint16_t)(budget + 2)); /* joint_move */
        alloc_budget = -1;
        cJSON_InitHooks(NULL);
        assert_int_equal(ex, EX_NONE);
        assert_int_equal(robot.sent_count, sent + 1);
        if (budget < 0)
            snprintf(first, sizeof(first), "%s", robot.sent[sent]);
        else
            assert_string_equal(robot.sent[sent], first);
        while (cmd_queue_pending(&queue))
            reply_ok();
    }
    alarm(0);
    assert_string_equal(first, "{\"cmdName\":\"joint_move\",\"jointPosition\":[10,20,30,40,50,60],"
                               "\"speed\":5,\"accel\":5,\"relFlag\":0}");
}

/* What the audit trail records of each command's members. */
static struct audit_record audited[8];
static unsigned audited_count;

static void audit_to_list(void *user, const struct audit_record *r)
{
    (void)user;
    if (audited_count < 8)
        audited[audited_count++] = *r;
}

/*
 * The audit trail records a command's members as sent, without cmdName:
 * from the bytes already built for a table's command (no parse), from the
 * PLC's own text for the JSON mailbox; the same records as when both were
 * parsed and printed again.
 */
static void audit_records_the_members_as_sent(void **state)
{
    (void)state;
    static struct audit audit;
    struct audit_sink sink = {.emit = audit_to_list};
    struct plc_commands_config with_audit = {.audit = &audit, .motion = true};

    struct audit_clock clock = {.now_ms = fake_now, .user = &robot};

    audit_init(&audit, &clock, &sink);
    audited_count = 0;
    start(&with_audit);
    const struct regmap_row *centroid = cmd_row("set_payload.centroid[*]");
    write_f32(cmd_row("set_payload.mass"), 0, 2.5);
    write_f32(centroid, 0, 0.1);
    write_f32(centroid, 1, -20);
    write_f32(centroid, 2, 30.25);
    assert_int_equal(trigger("set_payload"), EX_NONE);
    reply_ok();
    while (cmd_queue_pending(&queue))
        reply_ok();
    assert_int_equal(write_u16(cmd_row("rapid_rate.rate_value"), 0, 500), EX_NONE);
    reply_ok();
    assert_int_equal(trigger("power_on"), EX_NONE);
    reply_ok();
    assert_int_equal(json_mailbox("{ \"cmdName\": \"get_joint_pos\", \"b\" : [1, 2.50] }"),
                     EX_NONE);
    reply_ok();
    audit_flush(&audit);
    const char *expected[][2] = {
        {"set_payload", "{\"mass\":2.5,\"centroid\":[0.1,-20,30.25]}"},
        {"rapid_rate", "{\"rate_value\":0.5}"},
        {"power_on", ""},
        {"get_joint_pos", "{\"b\":[1,2.5]}"},
    };
    unsigned found = 0;
    for (unsigned i = 0; i < audited_count; i++)
        for (unsigned e = 0; e < 4; e++)
            if (strcmp(audited[i].command, expected[e][0]) == 0) {
                assert_string_equal(audited[i].what, expected[e][1]);
                found |= 1u << e;
            }
    assert_int_equal(found, 15);
    start(&(struct plc_commands_config){0});
    audit_finish(&audit);
}

/* The parameter rows and the command table cannot drift apart: a row the
 * table does not know, or of another length, stops the start. */
static void parameter_rows_are_checked_against_the_command_table(void **state)
{
    (void)state;
    struct regmap doctored = map;
    struct regmap_image doctored_img = img;
    struct regmap_row *rows = malloc(map.row_count * sizeof(*rows));
    struct plc_commands other;
    struct plc_commands_config none = {0};

    assert_non_null(rows);
    doctored.rows = rows;
    doctored_img.map = &doctored;
    for (int change = 0; change < 3; change++) {
        memcpy(rows, map.rows, map.row_count * sizeof(*rows));
        struct regmap_row *speed =
            (struct regmap_row *)&rows[cmd_row("joint_move.speed") - map.rows];
        struct regmap_row *joints =
            (struct regmap_row *)&rows[cmd_row("joint_move.jointPosition[*]") - map.rows];
        if (change == 0)
            speed->path = "joint_move.sped";   /* not an argument of joint_move */
        else if (change == 1)
            joints->elements = 5;              /* jointPosition[6] in the table */
        else
            speed->path = "jog_move.speed";    /* no such command */
        assert_int_equal(plc_commands_init(&other, &doctored_img, &queue, &none, fake_now,
                                           &robot), -EINVAL);
    }
    free(rows);
}

static void send_now_passes_every_gate(void **state)
{
    (void)state;
    struct plc_commands_config c = {.gate = gate_all_but_stop};
    write_cfg.read_only = true;
    start(&c);
    assert_int_equal(plc_commands_send_now(&pc, "pause_program"), 0);
    expect_last_sent("{\"cmdName\":\"pause_program\"}");
    assert_int_equal(result_state("pause_program"), CMD_PENDING);
    reply_ok();
    assert_int_equal(result_state("pause_program"), CMD_DONE);
    expect_last_sent("{\"cmdName\":\"get_program_state\"}");
    reply_ok();
    /* (Sent while pause_program is pending, stop_program meets the
     * ordering fault refresh_queues_behind_accepted_commands shows.) */
    assert_int_equal(plc_commands_send_now(&pc, "stop_program"), 0);
    expect_last_sent("{\"cmdName\":\"stop_program\"}");
    reply_ok();
    assert_int_equal(result_state("stop_program"), CMD_DONE);
    assert_int_equal(plc_commands_send_now(&pc, "no_such_command"), -EINVAL);
    while (cmd_queue_pending(&queue))
        reply_ok();
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(plc_commands_send_now(&pc, "stop_program"), -ENOTCONN);
}

static unsigned own_unknown_calls;
static const char *own_unknown_name;

static void record_own_unknown(void *user, const struct cmd_def *def)
{
    (void)user;
    own_unknown_calls++;
    own_unknown_name = def->name;
}

/*
 * The gateway's own pause whose connection is lost before its reply: its
 * outcome is unknown, and the owner of the action (the policy) is told, so
 * that it can send it again. Not for a reply (done or refused), not for
 * the PLC's own pause_program, not for a command never written.
 */
static void own_command_with_outcome_unknown_is_told(void **state)
{
    (void)state;
    struct plc_commands_config c = {.own_unknown = record_own_unknown};
    start(&c);
    own_unknown_calls = 0;
    assert_int_equal(plc_commands_send_now(&pc, "pause_program"), 0);
    reply("{\"errorCode\":\"1\",\"errorMsg\":\"no program running\"}");
    assert_int_equal(result_state("pause_program"), CMD_ROBOT_ERROR);
    assert_int_equal(own_unknown_calls, 0);
    /* The PLC's own pause, lost with the link: its result shows it. */
    assert_int_equal(trigger("pause_program"), 0);
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(result_state("pause_program"), CMD_LINK_DOWN);
    assert_int_equal(own_unknown_calls, 0);
    /* The gateway's: lost with the link after it was written. */
    cmd_queue_set_connected(&queue, true);
    assert_int_equal(plc_commands_send_now(&pc, "stop_program"), 0);
    expect_last_sent("{\"cmdName\":\"stop_program\"}");
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(result_state("stop_program"), CMD_LINK_DOWN);
    assert_int_equal(own_unknown_calls, 1);
    assert_string_equal(own_unknown_name, "stop_program");
    /* Unanswered in time: the same. */
    cmd_queue_set_connected(&queue, true);
    assert_int_equal(plc_commands_send_now(&pc, "pause_program"), 0);
    robot.now += 1000;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(result_state("pause_program"), CMD_TIMEOUT);
    assert_int_equal(own_unknown_calls, 2);
    assert_string_equal(own_unknown_name, "pause_program");
}


/* ---- the PLC contract: counts, triggers left at 1, targets, reasons ---- */

static double count_of(const char *path)
{
    return gw_number(path);
}

/* A refusal as the PLC reads it: the exception, the result's reason whole
 * (at most 40 bytes: 20 registers), and the count moved on. */
#define expect_refused(ex_got, ex, cmd, why)                                   \
    do {                                                                       \
        assert_int_equal((ex_got), (ex));                                      \
        assert_true(strlen(why) <= 40);                                        \
        assert_string_equal(result_text(cmd), (why));                          \
    } while (0)

static void count_changes_with_every_trigger(void **state)
{
    (void)state;
    assert_int_equal(count_of("result.power_on.count"), 0);
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(count_of("result.power_on.count"), 1);
    reply_ok();
    /* The same connection's 1 again: a retransmission, nothing sent and
     * nothing counted (the count changed with the first). */
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(count_of("result.power_on.count"), 1);
    assert_int_equal(robot.sent_count, 1);
    /* Another connection (a PLC restarted mid-handshake) writes 1 onto the
     * trigger left at 1: refused, the count changes, the old result (done)
     * is no longer there to be taken for its own. */
    connection = 2;
    expect_refused(trigger("power_on"), EX_NOT_PERMITTED, "power_on",
                   "trigger still 1: write 0 first");
    assert_int_equal(count_of("result.power_on.count"), 2);
    assert_int_equal(result_state("power_on"), CMD_REFUSED);
    assert_int_equal(robot.sent_count, 1);
    assert_int_equal(regmap_get_number(&img, cmd_row("power_on"), 0), 1);
    /* 0 then 1, as the guide says: sent, counted. */
    assert_int_equal(rearm("power_on"), EX_NONE);
    assert_int_equal(count_of("result.power_on.count"), 2); /* a 0 is no trigger */
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(count_of("result.power_on.count"), 3);
    assert_int_equal(robot.sent_count, 2);
    reply_ok();
    /* A refused trigger counts too (motion is off). */
    expect_refused(trigger("joint_move"), EX_NOT_PERMITTED, "joint_move",
                   "motion off: [commands] motion");
    assert_int_equal(count_of("result.joint_move.count"), 1);
    /* The mailboxes count the same way. */
    assert_int_equal(mailbox(1, NULL, 0, 7), EX_NONE);
    reply_ok();
    assert_int_equal(count_of("mailbox.count"), 1);
    assert_int_equal(mailbox(1, NULL, 0, 7), EX_NONE); /* the same number: done */
    assert_int_equal(count_of("mailbox.count"), 1);
    assert_int_equal(mailbox(99, NULL, 0, 8), EX_INVALID);
    assert_int_equal(count_of("mailbox.count"), 2);
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_version\"}"), EX_NONE);
    reply_ok();
    assert_int_equal(json_mailbox("nonsense"), EX_INVALID);
    assert_int_equal(count_of("json.count"), 2);
    assert_int_equal(robot.sent_count, 4);
}

static void count_wraps(void **state)
{
    (void)state;
    regmap_set_number(&img, gw_row("result.power_on.count"), 0, 65535, true);
    assert_int_equal(trigger("power_on"), EX_NONE);
    assert_int_equal(count_of("result.power_on.count"), 0);
}

/* Every motion parameter of joint_move, relative. */
static void write_relative_joint_move(void)
{
    const struct regmap_row *pos = cmd_row("joint_move.jointPosition[*]");
    for (unsigned i = 0; i < 6; i++)
        assert_int_equal(write_f32(pos, i, i == 0 ? 10 : 0), EX_NONE);
    assert_int_equal(write_f32(cmd_row("joint_move.speed"), 0, 20), EX_NONE);
    assert_int_equal(write_f32(cmd_row("joint_move.accel"), 0, 100), EX_NONE);
    assert_int_equal(write_u16(cmd_row("joint_move.relFlag"), 0, 1), EX_NONE);
}

static void relative_move_never_sent_twice_across_a_reconnect(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    write_relative_joint_move();
    assert_int_equal(trigger("joint_move"), EX_NONE);
    assert_int_equal(robot.sent_count, 1);
    reply_ok();
    /* The connection drops; the PLC reconnects and repeats its last
     * request: refused, never a second relative move. */
    connection = 3;
    expect_refused(trigger("joint_move"), EX_NOT_PERMITTED, "joint_move",
                   "trigger still 1: write 0 first");
    assert_int_equal(robot.sent_count, 1);
    assert_int_equal(count_of("result.joint_move.count"), 2);
}

static void motion_trigger_refused_until_its_target_is_written(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    /* A fresh gateway: nothing written, nothing sent. */
    expect_refused(trigger("moveL"), EX_INVALID, "moveL", "target not written");
    assert_int_equal(result_state("moveL"), CMD_INVALID);
    assert_int_equal(count_of("result.moveL.count"), 1);
    /* All but one parameter: still refused. */
    const struct regmap_row *pos = cmd_row("joint_move.jointPosition[*]");
    for (unsigned i = 0; i < 5; i++)
        write_f32(pos, i, 1);
    write_f32(cmd_row("joint_move.speed"), 0, 20);
    write_f32(cmd_row("joint_move.accel"), 0, 100);
    write_u16(cmd_row("joint_move.relFlag"), 0, 0);
    expect_refused(trigger("joint_move"), EX_INVALID, "joint_move", "target not written");
    write_f32(pos, 5, 1);
    assert_int_equal(trigger("joint_move"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"joint_move\",\"jointPosition\":[1,1,1,1,1,1],"
                     "\"speed\":20,\"accel\":100,\"relFlag\":0}");
    reply_ok();
    rearm("joint_move");
    /* A refused write to the target (not finite): the old target is not
     * what the PLC meant, so it is not sent either. */
    uint16_t nan_regs[2];
    put_f32(nan_regs, NAN);
    assert_int_equal(write_raw(REGMAP_HOLDING_REGISTER, regmap_element_address(pos, 2), 2,
                               nan_regs),
                     EX_INVALID);
    expect_refused(trigger("joint_move"), EX_INVALID, "joint_move", "target not written");
    assert_int_equal(robot.sent_count, 1);
    write_f32(pos, 2, 3);
    assert_int_equal(trigger("joint_move"), EX_NONE);
    assert_int_equal(robot.sent_count, 2);
}

static void parameter_block_in_one_write_across_its_gap(void **state)
{
    (void)state;
    struct plc_commands_config on = {.motion = true};
    start(&on);
    const struct regmap_row *cart = cmd_row("moveL.cartPosition[*]");
    const struct regmap_row *tol = cmd_row("moveL.tol");
    unsigned first = cart->address, count = tol->address + 2 - first;
    uint16_t regs[32] = {0};
    assert_true(count <= 32);
    for (unsigned i = 0; i < 6; i++)
        put_f32(&regs[regmap_element_address(cart, i) - first], 100 + i);
    put_f32(&regs[cmd_row("moveL.speed")->address - first], 50);
    put_f32(&regs[cmd_row("moveL.accel")->address - first], 500);
    regs[cmd_row("moveL.relFlag")->address - first] = 1;
    put_f32(&regs[tol->address - first], 0.5);
    /* The unassigned register inside the block (HR 357): ignored. */
    unsigned gap = cmd_row("moveL.relFlag")->address + 1;
    assert_null(regmap_find(&map, REGMAP_HOLDING_REGISTER, gap));
    regs[gap - first] = 0x1234;
    assert_int_equal(write_raw(REGMAP_HOLDING_REGISTER, first, count, regs), EX_NONE);
    assert_int_equal(img.mb->tab_registers[gap], 0);
    assert_int_equal(trigger("moveL"), EX_NONE);
    expect_last_sent("{\"cmdName\":\"moveL\",\"cartPosition\":[100,101,102,103,104,105],"
                     "\"speed\":50,\"accel\":500,\"relFlag\":1,\"tol\":0.5}");
    /* Alone, or at an end of a write, it is no parameter: 02. */
    uint16_t one = 1;
    assert_int_equal(write_raw(REGMAP_HOLDING_REGISTER, gap, 1, &one),
                     MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    uint16_t zeros[2] = {0, 0};
    assert_int_equal(write_raw(REGMAP_HOLDING_REGISTER, gap - 1, 2, zeros),
                     MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    assert_false(regmap_write_skips(&map, REGMAP_HOLDING_REGISTER, gap, gap, 3));
    assert_true(regmap_write_skips(&map, REGMAP_HOLDING_REGISTER, gap, gap - 1, 3));
}

static void mailbox_sequence_alone_is_refused(void **state)
{
    (void)state;
    /* rapid_rate 0.8 through the mailbox, whole. */
    const double rate[] = {0.8};
    unsigned code = cmd_find("rapid_rate")->code;
    assert_int_equal(mailbox(code, rate, 1, 1), EX_NONE);
    expect_last_sent("{\"cmdName\":\"rapid_rate\",\"rate_value\":0.8}");
    reply_ok();
    /* The code written on its own, then the sequence on its own: the
     * arguments would be whatever an older command left. */
    uint16_t v = (uint16_t)code;
    assert_int_equal(write_u16(gw_row("mailbox.code"), 0, v), EX_NONE);
    assert_int_equal(write_u16(gw_row("mailbox.seq"), 0, 2), EX_INVALID);
    assert_string_equal(gw_text("mailbox.error_msg"), "write code, args and seq in one write");
    assert_true(strlen(gw_text("mailbox.error_msg")) <= 40);
    assert_int_equal(gw_number("mailbox.state"), CMD_INVALID);
    assert_int_equal(gw_number("mailbox.ack_seq"), 1);
    assert_int_equal(count_of("mailbox.count"), 2);
    assert_int_equal(robot.sent_count, 1);
    /* Code and sequence without the argument it takes: refused too. */
    const struct regmap_row *code_row = gw_row("mailbox.code");
    const struct regmap_row *seq_row = gw_row("mailbox.seq");
    uint16_t regs[2] = {v, 3};
    assert_int_equal(seq_row->address, code_row->address + 25);
    assert_int_equal(write_raw(REGMAP_HOLDING_REGISTER, code_row->address, 1, regs), EX_NONE);
    assert_int_equal(write_raw(REGMAP_HOLDING_REGISTER, seq_row->address, 1, regs + 1),
                     EX_INVALID);
    assert_int_equal(robot.sent_count, 1);
}

static void json_refusal_clears_the_reply(void **state)
{
    (void)state;
    assert_int_equal(json_mailbox("{\"cmdName\":\"get_version\"}"), EX_NONE);
    reply("{\"cmdName\":\"get_version\",\"errorCode\":\"0\",\"version\":\"1.7.2\"}");
    assert_non_null(strstr(gw_text("json.reply"), "1.7.2"));
    assert_true(gw_number("json.reply_length") > 0);
    assert_int_equal(json_mailbox("{\"cmdName\":\"shutdown\"}"), EX_NOT_PERMITTED);
    assert_string_equal(gw_text("json.reply"), "");
    assert_int_equal(gw_number("json.reply_length"), 0);
    assert_string_equal(gw_text("json.error_msg"), "shutdown off: [commands] allow_shutdown");
}

/* Every reason the gateway gives in a result fits its 40 bytes whole. */
static void every_reason_fits_its_registers(void **state)
{
    (void)state;
    const struct regmap_row *msg = gw_row("result.power_on.error_msg");
    assert_int_equal(msg->str_regs * 2, 40);
    expect_refused(trigger("joint_move"), EX_NOT_PERMITTED, "joint_move",
                   "motion off: [commands] motion");
    expect_refused(trigger("shutdown"), EX_NOT_PERMITTED, "shutdown",
                   "shutdown off: [commands] allow_shutdown");
    write_text(cmd_row("load_program.programName"), "");
    expect_refused(trigger("load_program"), EX_INVALID, "load_program", "invalid parameters");
    cmd_queue_set_connected(&queue, false);
    expect_refused(trigger("power_on"), EX_LINK_DOWN, "power_on",
                   "not sent: the command link is down");
    cmd_queue_set_connected(&queue, true);
    struct plc_commands_config handler = {.robot_handle = true, .require_robot_handle = true,
                                          .robot_time_limit_ms = 1000};
    start(&handler);
    expect_refused(trigger("power_off"), EX_NOT_PERMITTED, "power_off",
                   "robot has not accepted its handler");
    start(&(struct plc_commands_config){.motion = true});
    expect_refused(trigger("end_move"), EX_INVALID, "end_move", "target not written");
    /* A trigger left at 1 by another connection, a mailbox in pieces:
     * count_changes_with_every_trigger and mailbox_sequence_alone_is_refused;
     * the policy's reasons: test_policy.c. */
}

int main(void)
{
#define T(name) cmocka_unit_test_setup_teardown(name, setup, teardown)
    const struct CMUnitTest tests[] = {
        T(trigger_sends_on_rising_edge_only),
        T(trigger_sends_its_parameters),
        T(motion_trigger_with_every_parameter),
        T(setpoints_send_each_write),
        T(multiple_coils_queue_in_order),
        T(outputs_written_again_send_once),
        T(mailbox_runs_each_sequence_number_once),
        T(mailbox_motion_with_motion_on),
        T(mailbox_refusals),
        T(mailbox_send_failure_still_completes),
        T(mailbox_commands_refresh_information),
        T(json_mailbox_sends_the_text),
        T(json_reply_truncated_on_a_character_boundary),
        T(json_mailbox_refusals),
        T(not_permitted),
        T(invalid_values),
        T(busy),
        T(halts_own_the_queue),
        T(json_mailbox_refuses_non_finite_numbers),
        T(link_down),
        T(link_check_reply_shows_the_robot_state),
        T(information_after_replies),
        T(information_fetched_once_at_a_time),
        T(refresh_queues_behind_accepted_commands),
        T(robot_handler_first_on_every_connect),
        T(gate_has_a_say_on_every_command),
        T(send_now_passes_every_gate),
        T(own_command_with_outcome_unknown_is_told),
        T(json_mailbox_refuses_names_outside_the_table),
        T(parameter_rows_are_checked_against_the_command_table),
        T(table_commands_need_no_cjson_allocation),
        T(audit_records_the_members_as_sent),
        T(count_changes_with_every_trigger),
        T(count_wraps),
        T(relative_move_never_sent_twice_across_a_reconnect),
        T(motion_trigger_refused_until_its_target_is_written),
        T(parameter_block_in_one_write_across_its_gap),
        T(mailbox_sequence_alone_is_refused),
        T(json_refusal_clears_the_reply),
        T(every_reason_fits_its_registers),
    };
#undef T
    return cmocka_run_group_tests(tests, NULL, NULL);
}
