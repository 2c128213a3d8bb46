/* SPDX-License-Identifier: MIT */
/*
 * fuzz_mailbox.c - libFuzzer target: the PLC command rows (plc_commands.c)
 * driven by arbitrary writes and robot replies, with a recording fake robot
 * (fuzz_robot.h).
 *
 * The input is a configuration byte (motion, allow_shutdown, the robot's
 * network-exception handler) and then a program of steps: writes to the
 * exactly-once mailbox (holding registers 400-425 and around them), whole
 * or partial texts into the JSON mailbox (500-619), trigger and setpoint
 * writes, replies from the robot (canned, raw, or long enough to pass the
 * JSON mailbox's 512-byte reply block), time passing (reply timeouts), the
 * link going down and up, and the policy's safety actions
 * (plc_commands_send_now, written ahead of the queue). Steps that build a whole mailbox command or
 * a long reply from two bytes let short inputs reach every limit: the
 * 240-byte request text, the 512-byte reply cut (also inside a UTF-8
 * sequence), the 64-command queue.
 *
 * Rules, besides the fake robot's (one JSON object per command, no motion
 * or shutdown when off, one command at a time): a refused write leaves the
 * image unchanged; the mailbox's done_seq only ever takes the value of
 * ack_seq; the JSON reply's length register says how long the reply was.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_robot.h"
#include "log.h"

#define MAILBOX_CODE 400
#define MAILBOX_SEQ 425
#define JSON_REQUEST 500
#define JSON_REQUEST_REGS 120
#define JSON_TRIGGER_COIL 120
#define MAX_STEPS 96

static struct regmap map;
static struct regmap_image img;
static struct cmd_queue queue;
static struct fake_robot robot;
static struct plc_commands pc;
static struct fuzz_gateway gw;
static const struct regmap_row *ack_row, *done_row, *json_length_row;

static const char *const canned[] = {
    "{\"errorCode\":\"0\",\"errorMsg\":\"\"}",
    "{\"errorCode\":0}",
    "{\"errorCode\":\"2\",\"errorMsg\":\"robot is not powered on\"}",
    "{\"errorCode\":\"-1\"}",
    "{\"cmdName\":\"get_payload\",\"errorCode\":\"0\",\"mass\":1.5,\"centroid\":[1,2,3]}",
    "{\"errorCode\":\"0\",\"programName\":\"track/demo.jks\"}",
    "{\"errorCode\":\"0\",\"programState\":\"running\"}",
    "{\"errorCode\":\"0\",\"version\":\"1.7.1_12\"}",
    "{\"errorCode\":\"0\",\"sensitivityLevel\":3}",
    "{\"errorCode\":\"x\"}",
    "not json",
    "[]",
};

/* Commands for the JSON mailbox that a PLC might write, good and bad. */
static const char *const json_commands[] = {
    "{\"cmdName\":\"power_on\"}",
    "{\"cmdName\":\"get_version\"}",
    "{\"cmdName\":\"joint_move\",\"jointPosition\":[0,0,0,0,0,0],\"speed\":1,\"accel\":1,\"relFlag\":1}",
    "{\"cmdName\":\"shutdown\"}",
    "{\"cmdName\":\"power_on\",\"cmdName\":\"joint_move\"}",
    "{\"cmdName\":\"power_on\"} {\"cmdName\":\"joint_move\"}",
    "{\"cmdName\":\"rapid_rate\",\"rate_value\":0.5}",
    "{\"cmdName\":\"\"}",
};

static void write_registers(unsigned address, unsigned count, const uint16_t *values)
{
    uint16_t done_before = (uint16_t)regmap_get_number(&img, done_row, 0);
    fuzz_write(&gw, REGMAP_HOLDING_REGISTER, address, count, values, true);
    uint16_t done_after = (uint16_t)regmap_get_number(&img, done_row, 0);
    FUZZ_REQUIRE(done_after == done_before ||
                     done_after == (uint16_t)regmap_get_number(&img, ack_row, 0),
                 "done_seq became %u, not the acknowledged number", done_after);
}

static void write_text(const uint8_t *text, size_t len, unsigned regs)
{
    uint16_t values[JSON_REQUEST_REGS] = {0};
    for (size_t i = 0; i < len && i < 2 * (size_t)regs; i++)
        values[i / 2] |= (uint16_t)(i % 2 ? text[i] : text[i] << 8);
    write_registers(JSON_REQUEST, regs, values);
}

static void write_coil(unsigned address, bool on)
{
    uint16_t v = on;
    fuzz_write(&gw, REGMAP_COIL, address, 1, &v, true);
}

static void reply(const char *json, size_t size)
{
    uint16_t done_before = (uint16_t)regmap_get_number(&img, done_row, 0);
    bool json_pending = pc.json.pending > 0;
    if (!fake_reply(&robot, json, size))
        return;
    uint16_t done_after = (uint16_t)regmap_get_number(&img, done_row, 0);
    FUZZ_REQUIRE(done_after == done_before ||
                     done_after == (uint16_t)regmap_get_number(&img, ack_row, 0),
                 "done_seq %u is not the acknowledged number", done_after);
    if (json_pending && pc.json.pending == 0)
        FUZZ_REQUIRE(regmap_get_number(&img, json_length_row, 0) == (double)size ||
                         regmap_get_number(&img, json_length_row, 0) == 0,
                     "the JSON reply's length shows %g, the reply had %zu bytes",
                     regmap_get_number(&img, json_length_row, 0), size);
}

/* A reply of 'len' bytes: errorCode 0 and a long errorMsg of 'fill'. */
static void long_reply(size_t len, const char *fill)
{
    static char buf[4096];
    size_t n = (size_t)snprintf(buf, sizeof(buf), "{\"errorCode\":\"0\",\"errorMsg\":\"");
    size_t fl = strlen(fill);
    while (n + fl + 2 < len && n + fl + 2 < sizeof(buf)) {
        memcpy(buf + n, fill, fl);
        n += fl;
    }
    buf[n++] = '"';
    buf[n++] = '}';
    reply(buf, n);
}

static void step(struct cursor *c)
{
    uint8_t op = next(c);
    uint16_t values[MODBUS_MAX_WRITE_REGISTERS];

    switch (op % 13) {
    case 0: { /* any write in and around the exactly-once mailbox */
        unsigned start = MAILBOX_CODE - 2 + next(c) % 32;
        unsigned count = 1 + next(c) % 30;
        for (unsigned i = 0; i < count; i++)
            values[i] = next16(c);
        write_registers(start, count, values);
        break;
    }
    case 1: { /* a whole mailbox command: code, arguments as f32, a sequence number */
        unsigned k = next(c);
        const struct cmd_def *def = &cmd_table[k % cmd_table_count];
        values[0] = k & 0x80 ? (uint16_t)(k & 0x7F) : def->code;
        for (unsigned i = 0; i < 12; i++) {
            float f = (float)(int8_t)next(c) / 4;
            uint32_t bits;
            memcpy(&bits, &f, sizeof(bits));
            values[1 + 2 * i] = (uint16_t)(bits >> 16);
            values[2 + 2 * i] = (uint16_t)bits;
        }
        values[25] = next16(c);
        write_registers(MAILBOX_CODE, 26, values);
        break;
    }
    case 2: { /* raw text into the JSON mailbox: whole block, or a part of it */
        unsigned len = next(c);
        unsigned regs = next(c);
        regs = regs & 0x80 ? 1 + regs % JSON_REQUEST_REGS : JSON_REQUEST_REGS;
        size_t take = len < c->left ? len : c->left;
        write_text(c->p, take, regs);
        c->p += take;
        c->left -= take;
        break;
    }
    case 3: { /* a known JSON command, or one padded to the block's 240 bytes */
        uint8_t k = next(c);
        const char *cmd = json_commands[k % (sizeof(json_commands) / sizeof(*json_commands))];
        uint8_t text[2 * JSON_REQUEST_REGS];
        size_t len = strlen(cmd);
        memcpy(text, cmd, len);
        if (k & 0x80) /* spaces after it, up to the last byte of the block */
            for (; len < sizeof(text); len++)
                text[len] = ' ';
        write_text(text, len, JSON_REQUEST_REGS);
        break;
    }
    case 4: /* the JSON mailbox's trigger */
        write_coil(JSON_TRIGGER_COIL, next(c) & 1);
        break;
    case 5: { /* a trigger coil or a digital output */
        uint8_t k = next(c);
        write_coil(k & 0x80 ? 200 + k % 40 : 100 + k % 32, next(c) & 1);
        break;
    }
    case 6: { /* a setpoint or parameter register */
        unsigned start = 98 + next(c) % 64;
        unsigned count = 1 + next(c) % 8;
        for (unsigned i = 0; i < count; i++)
            values[i] = next16(c);
        write_registers(start, count, values);
        break;
    }
    case 7: { /* the robot answers with a canned reply */
        const char *r = canned[next(c) % (sizeof(canned) / sizeof(*canned))];
        reply(r, strlen(r));
        break;
    }
    case 8: { /* the robot answers with raw bytes */
        unsigned len = next(c);
        size_t take = len < c->left ? len : c->left;
        reply((const char *)c->p, take);
        c->p += take;
        c->left -= take;
        break;
    }
    case 9: { /* a long reply, 8..2048 bytes, ASCII or 2- and 3-byte UTF-8 */
        static const char *const fills[] = {"x", "\xc3\xa9", "\xe2\x82\xac", "ab\xc3\xa9"};
        uint8_t k = next(c);
        long_reply(8 + (size_t)next(c) * 8, fills[k % 4]);
        break;
    }
    case 10: /* time passes: a reply may be late */
        robot.now_ms += (uint64_t)next(c) * 32;
        cmd_queue_check_timeout(&queue);
        break;
    case 11: /* the link goes down, or comes back, or a send fails */
        switch (next(c) % 3) {
        case 0: fake_link_down(&robot); break;
        case 1: fake_link_up(&robot); break;
        default: robot.fail_next_send = -ENOBUFS; break;
        }
        break;
    case 12: /* the network-exception policy's safety action, ahead of the queue */
        plc_commands_send_now(&pc, next(c) & 1 ? "stop_program" : "pause_program");
        break;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    struct cursor c = {data, size};

    if (!ready) {
        log_set_level((enum log_level)0);
        if (regmap_init(&map))
            abort();
        ready = 1;
    }
    if (size < 1)
        return 0;
    /* A fresh gateway for every input, so that a crash reproduces alone. */
    if (regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST))
        abort();
    uint8_t conf = next(&c);
    struct plc_commands_config cfg = {
        .motion = conf & 1,
        .allow_shutdown = conf & 2,
        .robot_handle = conf & 4,
        .robot_time_limit_ms = 500,
        .robot_mot_type = 1,
        .require_robot_handle = conf & 8,
    };
    fake_robot_init(&robot, &queue, NULL, 2000);
    robot.motion = cfg.motion;
    robot.allow_shutdown = cfg.allow_shutdown;
    if (plc_commands_init(&pc, &img, &queue, &cfg, fake_now, &robot))
        abort();
    robot.pc = &pc;
    fuzz_gateway_init(&gw, &img, &pc, &robot, conf & 32);
    ack_row = pc.mailbox_ack;
    done_row = pc.mailbox_done;
    json_length_row = pc.json_length;
    if (!(conf & 16))
        fake_link_up(&robot);
    for (unsigned i = 0; i < MAX_STEPS && c.left; i++)
        step(&c);
    /* Whatever is left fails once, through the done callbacks. */
    cmd_queue_free(&queue);
    fuzz_gateway_free(&gw);
    plc_commands_free(&pc);
    regmap_image_free(&img);
    return 0;
}
