/* SPDX-License-Identifier: MIT */
/*
 * fuzz_robot.h - what the fuzz targets share: the robot's end of the
 * command port, and the gateway's write path.
 *
 * The fake robot records what the command queue sends and judges each
 * command as a robot reads it: one JSON object and nothing else, its
 * cmdName the last member of that name (as Python's json module, and so
 * the controller, reads a repeated key). A motion or shutdown command that
 * reaches the robot while the configuration forbids it, a command sent
 * before the ones already sent were answered (only the safety actions,
 * pause_program and stop_program, may go out at once), or bytes that are
 * not one JSON object abort the run: the gateway must never put them on
 * the wire. The robot answers in order.
 *
 * fuzz_write() runs a write through plc_write_judge(), the transaction the
 * Modbus server calls, with a real network-exception policy behind it,
 * and checks what it left.
 */
#ifndef JAKAGW_FUZZ_ROBOT_H
#define JAKAGW_FUZZ_ROBOT_H

#include <cJSON.h>
#include <errno.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "command.h"
#include "fuzz_util.h"
#include "ip_allow.h"
#include "plc_commands.h"
#include "plc_write.h"
#include "policy.h"
#include "regmap.h"


struct fake_robot {
    struct cmd_queue *queue;
    struct plc_commands *pc; /* told of link changes, or NULL */
    bool motion;             /* what the gateway's configuration allows */
    bool allow_shutdown;
    bool connected;
    unsigned outstanding;    /* sent and not yet answered on this connection */
    uint64_t now_ms;
    int fail_next_send;      /* a negative errno for the next send, 0: none */
    unsigned sends, restarts;
    char last_name[64];      /* cmdName of the last command, as the robot reads it */
};

/* The robot's reading of one command: 0, or a reason it is not a command. */
static inline const char *robot_read_command(const char *data, size_t size, char *name,
                                      size_t name_size)
{
    char *text = malloc(size + 1);
    const char *end = NULL;
    const cJSON *m, *last = NULL;

    if (!text)
        abort();
    memcpy(text, data, size);
    text[size] = '\0';
    if (strlen(text) != size) {
        free(text);
        return "a NUL byte inside the command";
    }
    cJSON *doc = cJSON_ParseWithOpts(text, &end, 1);
    free(text);
    if (!cJSON_IsObject(doc)) {
        cJSON_Delete(doc);
        return "not exactly one JSON object (or something follows it)";
    }
    for (m = doc->child; m; m = m->next)
        if (m->string && strcmp(m->string, "cmdName") == 0)
            last = m;
    if (!cJSON_IsString(last)) {
        cJSON_Delete(doc);
        return "no cmdName text";
    }
    snprintf(name, name_size, "%s", last->valuestring);
    cJSON_Delete(doc);
    return NULL;
}

static inline int fake_send(void *io, const char *data, size_t size)
{
    struct fake_robot *r = io;
    char name[64];
    const char *bad;

    FUZZ_REQUIRE(r->connected, "a command was sent while the link is down");
    if (r->fail_next_send) {
        int rc = r->fail_next_send;
        r->fail_next_send = 0;
        return rc;
    }
    bad = robot_read_command(data, size, name, sizeof(name));
    FUZZ_REQUIRE(!bad, "sent to the robot: %s: %.*s", bad, (int)(size > 300 ? 300 : size),
                 data);
    FUZZ_REQUIRE(r->outstanding == 0 || strcmp(name, "pause_program") == 0 ||
                     strcmp(name, "stop_program") == 0,
                 "a command was sent before the robot answered the one before: %.*s",
                 (int)(size > 200 ? 200 : size), data);
    const struct cmd_def *def = cmd_find(name);
    FUZZ_REQUIRE(!def || !(def->flags & CMD_MOTION) || r->motion,
                 "motion command '%s' reached the robot with motion off: %.*s", name,
                 (int)(size > 300 ? 300 : size), data);
    FUZZ_REQUIRE(!def || !(def->flags & CMD_SHUTDOWN) || r->allow_shutdown,
                 "'%s' reached the robot with allow_shutdown off: %.*s", name,
                 (int)(size > 300 ? 300 : size), data);
    snprintf(r->last_name, sizeof(r->last_name), "%s", name);
    r->outstanding++;
    r->sends++;
    return 0;
}

static inline uint64_t fake_now(void *io)
{
    return ((struct fake_robot *)io)->now_ms;
}

static inline void fake_link_down(struct fake_robot *r)
{
    if (!r->connected)
        return;
    r->connected = false;
    r->outstanding = 0;
    /* As command_port.c: the queue first, then the PLC side. */
    cmd_queue_set_connected(r->queue, false);
    if (r->pc)
        plc_commands_link_down(r->pc);
}

static inline void fake_link_up(struct fake_robot *r)
{
    if (r->connected)
        return;
    r->connected = true;
    cmd_queue_set_connected(r->queue, true);
    if (r->pc)
        plc_commands_link_up(r->pc);
}

/* robot_link_restart() drops the connection at once (set_state). */
static inline void fake_restart(void *io, const char *why)
{
    struct fake_robot *r = io;
    (void)why;
    r->restarts++;
    fake_link_down(r);
}

static inline void fake_robot_init(struct fake_robot *r, struct cmd_queue *q,
                            struct plc_commands *pc, uint32_t timeout_ms)
{
    struct cmd_ops ops = {.send = fake_send, .now_ms = fake_now,
                          .restart_link = fake_restart, .io = r};
    memset(r, 0, sizeof(*r));
    r->queue = q;
    r->pc = pc;
    r->now_ms = 1000;
    cmd_queue_init(q, &ops, timeout_ms);
}

/* The robot answers the command in flight, if there is one. */
static inline bool fake_reply(struct fake_robot *r, const char *json, size_t size)
{
    if (!r->connected || r->outstanding == 0)
        return false;
    r->outstanding--;
    cmd_queue_on_reply(r->queue, json, size);
    return true;
}

/* Answers until nothing is in flight: every command accepted. */
static inline void fake_drain(struct fake_robot *r)
{
    static const char ok[] = "{\"errorCode\":\"0\",\"errorMsg\":\"\"}";
    for (unsigned i = 0; i < 4 * CMD_QUEUE_CAPACITY && fake_reply(r, ok, sizeof(ok) - 1); i++)
        ;
    FUZZ_REQUIRE(r->outstanding == 0, "the queue never empties");
}

/* ---- the gateway's write transaction (plc_write.h), as the server calls it -- */

/* The write side of a gateway: the transaction with a real policy. */
struct fuzz_gateway {
    struct policy policy;
    struct plc_write writes;
    struct plc_commands *pc;
    struct fake_robot *robot;
    bool moving; /* what the robot's status would say */
};

static inline uint64_t fuzz_gateway_now(void *user)
{
    return ((struct fuzz_gateway *)user)->robot->now_ms;
}

static inline bool fuzz_gateway_moving(void *user)
{
    return ((struct fuzz_gateway *)user)->moving;
}

/* The policy's action goes out as the gateway sends it. */
static inline bool fuzz_gateway_send_action(void *user, enum policy_action action,
                                            enum policy_fault reason)
{
    struct fuzz_gateway *g = user;
    (void)reason;
    return plc_commands_send_now(g->pc, action == POLICY_STOP ? "stop_program"
                                                               : "pause_program") == 0;
}

static inline int fuzz_gateway_gate(void *user, const struct cmd_def *def, char *why,
                                    size_t size)
{
    struct fuzz_gateway *g = user;
    return policy_gate_command(&g->policy, g->robot->now_ms, def, why, size);
}

static inline void fuzz_gateway_init(struct fuzz_gateway *g, struct regmap_image *img,
                                     struct plc_commands *pc, struct fake_robot *robot,
                                     bool motion_enable)
{
    struct policy_config pcfg = {.time_limit_ms = 300, .action = POLICY_PAUSE,
                                 .watch = POLICY_WATCH_HEARTBEAT,
                                 .motion_enable = motion_enable};
    struct policy_sink sink = {.send_action = fuzz_gateway_send_action, .user = g};
    struct plc_write_config wcfg = {0};
    struct plc_write_hooks hooks = {.now_ms = fuzz_gateway_now,
                                    .robot_may_move = fuzz_gateway_moving, .user = g};

    g->pc = pc;
    g->robot = robot;
    g->moving = false;
    policy_init(&g->policy, &pcfg, &sink);
    FUZZ_REQUIRE(plc_write_init(&g->writes, img, pc, &g->policy, &wcfg, &hooks) == 0,
                 "plc_write_init");
    /* The command gate is the policy's, as in the gateway. */
    pc->cfg.gate = fuzz_gateway_gate;
    pc->cfg.gate_user = g;
}

static inline void fuzz_gateway_free(struct fuzz_gateway *g)
{
    plc_write_free(&g->writes);
}

/*
 * Judges write 'count' bits or registers at 'address' through the same
 * transaction as the server (plc_write_judge), then checks what it left:
 * a refused write leaves the image as it was; an accepted one was decoded
 * into elements, in address order, that cover it exactly. With 'apply',
 * the values are applied as libmodbus would and the after-write step runs;
 * otherwise the caller does both (plc_write_after) around modbus_reply.
 * Returns 0 or the exception that refused it.
 */
static inline int fuzz_write(struct fuzz_gateway *g, enum regmap_table table,
                             unsigned address, unsigned count, const uint16_t *values,
                             bool apply)
{
    static uint16_t saved[MODBUS_MAX_WRITE_BITS], after[MODBUS_MAX_WRITE_BITS];
    struct regmap_image *img = g->writes.img;
    struct mb_write w = {.table = table, .address = address, .count = count,
                         .values = values, .client = "192.0.2.1", .client_id = 1,
                         .rights = REGMAP_RIGHTS_ALL};
    int ex;

    FUZZ_REQUIRE(count >= 1 && count <= MODBUS_MAX_WRITE_BITS, "write count %u", count);
    ip_addr_parse(w.client, &w.client_addr);
    regmap_save(img, table, address, count, saved);
    ex = plc_write_judge(&g->writes, &w);
    if (ex) {
        regmap_save(img, table, address, count, after);
        /* Except a drop of motion enable, which nothing refuses (plc_write.h). */
        const struct regmap_row *enable = g->writes.rows.motion_enable;
        if (table == enable->table && enable->address >= address &&
            enable->address < address + count && values[enable->address - address] == 0)
            saved[enable->address - address] = 0;
        FUZZ_REQUIRE(memcmp(saved, after, count * sizeof(*saved)) == 0,
                     "a refused write left the image changed");
        return ex;
    }
    unsigned next = address;
    for (unsigned k = 0; k < g->writes.element_count; k++) {
        const struct regmap_written *e = &g->writes.elements[k];
        const struct regmap_row *row = e->row;
        FUZZ_REQUIRE(row && row->writable && row->table == table,
                     "decode reported a row that is not writable in the table written");
        FUZZ_REQUIRE(e->element < row->elements, "element %u of a %u-element row",
                     e->element, row->elements);
        unsigned a = regmap_element_address(row, e->element);
        unsigned width = regmap_element_width(row);
        /* Unassigned registers inside a command's parameters, passed over. */
        while (next < a && regmap_write_skips(img->map, table, next, address, count))
            next++;
        FUZZ_REQUIRE(a == next && a + width <= address + count,
                     "element at %u (width %u) outside the write %u+%u or out of order", a,
                     width, address, count);
        FUZZ_REQUIRE(e->source_index == row->index + e->element, "source index");
        next = a + width;
    }
    FUZZ_REQUIRE(g->writes.element_count > 0 && next == address + count,
                 "an accepted write of %u+%u decoded into elements up to %u only", address,
                 count, next);
    if (apply) {
        regmap_load(img, table, address, count, values);
        plc_write_after(&g->writes);
    }
    return 0;
}

#endif
