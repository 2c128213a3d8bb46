/* SPDX-License-Identifier: MIT */
/*
 * fuzz_motion.c - libFuzzer target: the motion tracker (motion.c) and the
 * policy's judge of its own action (policy.c), fed moves, replies, stops,
 * status documents and time in any order, with any numbers: JSON moves
 * whose members are huge, negative, 1e999 (infinity) or missing, and
 * documents whose joints, TCP and rapid rate are NaN, infinite or huge.
 *
 * The input is a program of steps. Rules:
 * - the tracker: its state is one of the five; it holds at most
 *   MOTION_HELD_MAX moves; its count moves by one for each move it
 *   follows (motion_sent true) and for nothing else; MOTION_ARRIVED only
 *   from a document (never from a reply, a stop or time); no terminal
 *   state from motion_check while the last document shows the arm moving;
 *   motion_bound_ms never exceeds MOTION_BOUND_MAX_MS, whatever it is given;
 * - the policy: it sends at most two actions for one fault (the action and
 *   one escalation), the reaction stays one of the seven, and a reset is
 *   allowed (policy_may_reset) only once the reaction is no longer judged.
 * The sanitizers (with float-cast-overflow, which UBSan's "undefined" group
 * leaves out) catch every conversion of a number out of range.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "fuzz_util.h"
#include "log.h"
#include "motion.h"
#include "policy.h"

#define MAX_STEPS 160

static struct motion m;
static struct policy p;
static unsigned actions;
static enum policy_robot robot_now;
static double step_now;
static const int tags[3];

/* A number for a JSON member or a document: ordinary, or an edge. */
static double number_of(struct cursor *c)
{
    static const double edges[] = {0, -0.0, 1e300, -1e300, 1e-300, 4294967296.0, -1,
                                   180, 360, 1e18, 1e19};
    uint8_t b = next(c);
    if (b < 200)
        return (double)(int16_t)next16(c) / 8.0;
    if (b < 240)
        return edges[b % (sizeof(edges) / sizeof(edges[0]))];
    if (b < 248)
        return b % 2 ? INFINITY : -INFINITY;
    return NAN;
}

/* A number as the JSON text of a move: 1e999 for infinity (cJSON reads
 * it so), "null" for NaN (no JSON number is NaN). */
static void json_number(char *out, size_t size, double v)
{
    if (isnan(v))
        snprintf(out, size, "null");
    else if (isinf(v))
        snprintf(out, size, "%s1e999", v < 0 ? "-" : "");
    else
        snprintf(out, size, "%.17g", v);
}

static void send_move(struct cursor *c, uint64_t now)
{
    static const char *const names[] = {"joint_move", "end_move", "moveL", "jog"};
    static const char *const members[] = {"jointPosition", "endPosition", "cartPosition",
                                          "jointPosition"};
    unsigned k = next(c) % 4;
    char json[1024], num[40];
    int n = snprintf(json, sizeof(json), "{\"cmdName\":\"%s\",\"%s\":[", names[k], members[k]);
    for (int i = 0; i < 6; i++) {
        json_number(num, sizeof(num), number_of(c));
        n += snprintf(json + n, sizeof(json) - (size_t)n, "%s%s", i ? "," : "", num);
    }
    json_number(num, sizeof(num), number_of(c));
    n += snprintf(json + n, sizeof(json) - (size_t)n, "],\"speed\":%s,\"relFlag\":%d}", num,
                  next(c) % 2);
    uint16_t before = m.count;
    bool followed = motion_sent(&m, now, json, &tags[next(c) % 3]);
    FUZZ_REQUIRE(followed == (k < 3), "%s followed: %d", names[k], followed);
    FUZZ_REQUIRE((uint16_t)(before + followed) == m.count, "count %u -> %u", before, m.count);
    FUZZ_REQUIRE(!followed || m.bound_ms <= MOTION_BOUND_MAX_MS, "bound %llu",
                 (unsigned long long)m.bound_ms);
}

static void document(struct cursor *c, uint64_t now, struct motion_view *v)
{
    uint8_t what = next(c);
    if (what & 1)
        for (int i = 0; i < 6; i++)
            v->joints[i] = number_of(c);
    if (what & 2)
        for (int i = 0; i < 6; i++)
            v->tcp[i] = number_of(c);
    if (what & 4)
        v->rapid_rate = number_of(c);
    v->inpos = (int)(next(c) % 3) - 1;
    v->interp_state = (int)(next(c) % 5) - 1;
    uint8_t flags = next(c);
    v->emergency_stop = flags & 1;
    v->protective_stop = (flags >> 1) & 1;
    v->enabled = (flags >> 2) & 1 ? 0 : 1;
    v->powered_on = (flags >> 3) & 1 ? 0 : 1;
    v->have_joints = !((flags >> 4) & 1);
    v->have_tcp = !((flags >> 5) & 1);
    enum motion_state before = m.state;
    motion_document(&m, now, v);
    FUZZ_REQUIRE(m.state != MOTION_ARRIVED || before == MOTION_ARRIVED || v->inpos == 1,
                 "arrived from a document not in position");
    robot_now = motion_robot(&m, (flags >> 6) & 1 ? false : true);
    step_now = motion_step_deg(&m);
    policy_status_document(&p, now);
}

static bool send_action(void *user, enum policy_action action, enum policy_fault reason)
{
    (void)user, (void)action, (void)reason;
    actions++;
    return true;
}

static enum policy_robot robot_seen(void *user)
{
    (void)user;
    return robot_now;
}

static double step_seen(void *user)
{
    (void)user;
    return step_now;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct cursor c = {data, size};
    struct policy_config cfg = {.time_limit_ms = 500, .action = POLICY_PAUSE,
                                .watch = POLICY_WATCH_HEARTBEAT, .check_period_ms = 50,
                                .stop_time_ms = 20u * next(&c)};
    struct policy_sink sink = {.send_action = send_action, .robot = robot_seen,
                               .step = step_seen};
    struct motion_view v;
    uint64_t now = 1000000;
    char why[64];

    log_set_level(LOG_LEVEL_ERR);
    motion_init(&m);
    policy_init(&p, &cfg, &sink);
    memset(&v, 0, sizeof(v));
    actions = 0;
    robot_now = POLICY_ROBOT_MOVING;
    step_now = -1;
    policy_heartbeat(&p, now, 1, "192.0.2.1:1", 1);
    for (unsigned s = 0; s < MAX_STEPS && c.left; s++) {
        switch (next(&c) % 10) {
        case 0:
        case 1:
            send_move(&c, now);
            break;
        case 2:
            motion_answered(&m, now, &tags[next(&c) % 3], now - 10u * next(&c), next(&c) % 2,
                            next(&c) % 2);
            break;
        case 3:
            motion_stop_sent(&m, now, "fuzz");
            break;
        case 4:
            motion_stop_answered(&m, now, next(&c) % 2);
            break;
        case 5:
        case 6:
            document(&c, now, &v);
            break;
        case 7: {
            bool moving = m.have_last && (m.last.inpos == 0 || robot_now == POLICY_ROBOT_MOVING);
            enum motion_state before = m.state;
            now += next16(&c);
            motion_check(&m, now);
            FUZZ_REQUIRE(!(before == MOTION_MOVING && m.state == MOTION_TIMED_OUT && moving &&
                           m.last.inpos == 0),
                         "timed out while the status shows the arm moving");
            policy_check(&p, now, robot_now != POLICY_ROBOT_STILL);
            break;
        }
        case 8:
            policy_action_answered(&p, now, next(&c) % 2);
            break;
        case 9: {
            double travel = number_of(&c), speed = number_of(&c);
            FUZZ_REQUIRE(motion_bound_ms(travel, speed) <= MOTION_BOUND_MAX_MS,
                         "bound of %g at %g", travel, speed);
            if (next(&c) % 8 == 0)
                motion_link_lost(&m, now, "fuzz");
            break;
        }
        }
        FUZZ_REQUIRE(m.state <= MOTION_TIMED_OUT, "motion state %d", m.state);
        FUZZ_REQUIRE(m.held_count <= MOTION_HELD_MAX, "%u moves held", m.held_count);
        FUZZ_REQUIRE(p.reaction <= POLICY_REACTION_STILL_MOVING, "reaction %d", p.reaction);
        FUZZ_REQUIRE(actions <= 2, "%u actions for one fault", actions);
        if ((p.reaction == POLICY_REACTION_SENT || p.reaction == POLICY_REACTION_ESCALATED) &&
            p.fault != POLICY_FAULT_NONE && !p.reaction_lost)
            FUZZ_REQUIRE(policy_may_reset(&p, why, sizeof(why)) != 0,
                         "a reset allowed while the reaction is judged");
    }
    return 0;
}
