/* SPDX-License-Identifier: MIT */
/*
 * plc_write.h - a PLC's Modbus write as one transaction: authorized,
 * decoded once, judged whole, acted on, and only then answered.
 *
 * The Modbus server (mb_server.h) calls plc_write_judge() before it answers
 * a write, and plc_write_after() once libmodbus has applied it. In order:
 * 0. the connection's rights (regmap_write_allowed): a Modbus/TCP
 *    Security client writes only rows of the write classes its role has;
 *    exception 01, nothing changes;
 * 1. authorization, before anything is looked at: [modbus] read_only,
 *    write_allow (the client's address, compared as an address), and the
 *    policy's write owner: exception 01, nothing changes;
 * 2. the new values go into the image and are decoded once, element by
 *    element (regmap_decode_write): 02 for an address no writable row owns
 *    or a split value, 03 for a value out of range;
 * 3. a drop of the motion-enable coil is taken now, whatever its address
 *    (with the fault reset just before it, if the write holds one): the
 *    policy sees it before anything else in the write is judged, and
 *    nothing refuses it: the coil stays 0 even if step 4 refuses the rest;
 * 4. every element is checked with the new values in place (a command
 *    sees the parameters written with it): the command rows by
 *    plc_commands_check(), which builds each command once; the policy's
 *    gates apply through it, against the fault as it was before the write
 *    (a reset starts nothing). One refusal refuses the whole write: the
 *    image is restored (but for a motion-enable drop) and nothing is sent;
 * 5. every element is acted on, in address order: the heartbeat and the
 *    fault reset and motion-enable coils go to the policy, command rows
 *    send what step 4 built; then the policy is re-evaluated;
 * 6. after libmodbus applied the write: command coils (fault reset, clear
 *    counters) read 0 again, and clear counters clears them; a register
 *    inside a command's parameters that no row owns (regmap_write_skips)
 *    reads 0 again: what was written there is ignored.
 *
 * Time, the robot's motion and the counters reach the transaction through
 * 'struct plc_write_hooks', so its decisions are unit-tested and fuzzed
 * without a loop (tests/test_plc_write.c, fuzz/fuzz_robot.h).
 */
#ifndef JAKAGW_PLC_WRITE_H
#define JAKAGW_PLC_WRITE_H

#include <stdbool.h>
#include <stdint.h>

#include "ip_allow.h"
#include "mb_server.h"
#include "plc_commands.h"
#include "policy.h"
#include "regmap.h"

struct plc_write_config {
    bool read_only;              /* no write at all */
    struct ip_allow write_allow; /* count 0: any client may write */
    bool modbus_writes_none;     /* no plain Modbus TCP client may write */
};

struct plc_write_hooks {
    /* Milliseconds from any fixed point. */
    uint64_t (*now_ms)(void *user);
    /* Does the robot move or run a program (policy_robot_may_move)? */
    bool (*robot_may_move)(void *user);
    /* A PLC asked for the diagnostic counters to be cleared. */
    void (*clear_counters)(void *user);
    void *user;
};

/* The rows with a meaning of their own, found by name at init. */
struct plc_write_rows {
    const struct regmap_row *heartbeat;      /* gw:plc_heartbeat */
    const struct regmap_row *clear_counters; /* gw:clear_counters */
    const struct regmap_row *fault_reset;    /* network_exception.fault_reset */
    const struct regmap_row *motion_enable;  /* network_exception.motion_enable */
};

struct plc_write {
    struct regmap_image *img;
    struct plc_commands *commands;
    struct policy *policy;
    struct plc_write_config cfg;
    struct plc_write_hooks hooks;
    struct plc_write_rows rows;
    /* The write being judged, then awaiting plc_write_after(). */
    const struct mb_write *w;
    uint16_t saved[MODBUS_MAX_WRITE_BITS]; /* its range, before it */
    struct regmap_written *elements;       /* decoded once */
    unsigned element_count;
    bool awaiting_after;
    /* Its range, for step 6 (registers regmap_write_skips() passed over
     * read 0 again). */
    enum regmap_table table;
    unsigned address, count;
    /* The last refusal: where ("coil 107 play_program", or the write's
     * range) and why, as the PLC's result registers say it. */
    char where[96];
    char why[128];
};

/*
 * Finds the rows and allocates room for the largest write's elements.
 * Returns 0, -EINVAL when the map lacks a row (a programming error), or
 * -ENOMEM.
 */
int plc_write_init(struct plc_write *pw, struct regmap_image *img,
                   struct plc_commands *commands, struct policy *policy,
                   const struct plc_write_config *cfg, const struct plc_write_hooks *hooks);
void plc_write_free(struct plc_write *pw);

/*
 * May this client write at all (step 1)? 0, or exception 01.
 */
int plc_write_authorize(const struct plc_write *pw, const struct mb_write *w);

/*
 * Steps 1-5 for write 'w'. Returns 0 (acted on: libmodbus applies and
 * answers it), or the Modbus exception that refuses it (the image is as
 * before, but for a motion-enable drop, and nothing was sent).
 */
int plc_write_judge(struct plc_write *pw, const struct mb_write *w);

/* Names the range of 'w' as the audit does ("holding register 100+2")
 * in pw->where, for a write refused before it was judged. */
void plc_write_name_range(struct plc_write *pw, const struct mb_write *w);

/* A write the server refused before it could be judged (an address or a
 * value outside the map): the parameters it held count as not written. */
void plc_write_refused_unjudged(struct plc_write *pw, const struct mb_write *w);

/* Step 6, after a write plc_write_judge() accepted was applied. */
void plc_write_after(struct plc_write *pw);

#endif
