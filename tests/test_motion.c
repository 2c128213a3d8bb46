/* SPDX-License-Identifier: MIT */
/*
 * test_motion.c - the motion tracker (motion.h) with time and status
 * documents given as arguments: what is followed and counted, "moving"
 * from the send, "arrived" only from a document received after the reply
 * that shows the arm in position, still, at its target (absolute and
 * relative, joints and TCP, at the tolerances), the ends before arrival
 * (a stop, the robot's refusal, an emergency or protective stop, the
 * robot disabled), the time bound, what the arm does for the policy, and
 * a property test over generated moves and documents
 * (MOTION_PROPERTY_SEED replays a run).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "motion.h"
#include "property.h"

#define T0 500000

static struct motion m;

/* A document of an enabled robot, idle, in position at 'joints', TCP 'tcp'. */
static struct motion_view doc_at(const double joints[6], const double tcp[6])
{
    struct motion_view v = {.inpos = 1, .interp_state = 0, .enabled = 1, .powered_on = 1,
                            .emergency_stop = 0, .protective_stop = 0, .have_joints = true,
                            .have_tcp = true, .rapid_rate = 1.0};
    memcpy(v.joints, joints, sizeof(v.joints));
    memcpy(v.tcp, tcp, sizeof(v.tcp));
    return v;
}

static const double HOME[6] = {0, 90, 90, 0, 90, 0};
/* Whose a move is (the PLC slot that sent it), and another's. */
static const int slot_a, slot_b;
#define SLOT ((const void *)&slot_a)
#define OTHER ((const void *)&slot_b)
static const double HOME_TCP[6] = {400, 0, 300, 180, 0, 90};

static void start_at_home(void)
{
    motion_init(&m);
    struct motion_view v = doc_at(HOME, HOME_TCP);
    motion_document(&m, T0 - 20, &v);
    motion_document(&m, T0, &v);
}

static void feed(uint64_t t, const double joints[6], const double tcp[6], int inpos)
{
    struct motion_view v = doc_at(joints, tcp);
    v.inpos = inpos;
    motion_document(&m, t, &v);
}

static void only_the_three_moves_count(void **state)
{
    (void)state;
    start_at_home();
    assert_int_equal(m.state, MOTION_IDLE);
    assert_false(motion_sent(&m, T0, "{\"cmdName\":\"power_on\"}", SLOT));
    assert_false(motion_sent(&m, T0, "{\"cmdName\":\"jog\",\"jog_mode\":3}", SLOT));
    assert_false(motion_sent(&m, T0, "not json", SLOT));
    assert_int_equal(m.count, 0);
    assert_true(motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":"
                                    "[10,90,90,0,90,0],\"speed\":20,\"relFlag\":0}", SLOT));
    assert_true(motion_sent(&m, T0, "{\"cmdName\":\"end_move\",\"endPosition\":"
                                    "[400,0,300,180,0,90],\"speed\":20}", SLOT));
    assert_true(motion_sent(&m, T0, "{\"cmdName\":\"moveL\",\"cartPosition\":"
                                    "[0,0,10,0,0,0],\"speed\":20,\"relFlag\":1}", SLOT));
    assert_int_equal(m.count, 3);
    assert_int_equal(m.state, MOTION_MOVING);
    /* A member given twice counts with its last value, as the robot reads
     * it: the target is the far one, never the arm's own position. */
    motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":[0,90,90,0,90,0],"
                        "\"jointPosition\":[45,90,90,0,90,0],\"speed\":20}", SLOT);
    assert_true(m.target_known && m.target[0] == 45);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    feed(T0 + 20, HOME, HOME_TCP, 1);
    feed(T0 + 40, HOME, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING);
    /* It wraps as a u16 register does. */
    m.count = 65535;
    motion_sent(&m, T0, "{\"cmdName\":\"moveL\",\"cartPosition\":[0,0,1,0,0,0],\"speed\":1}", SLOT);
    assert_int_equal(m.count, 0);
}

static void arrived_only_after_the_status_shows_it(void **state)
{
    (void)state;
    const double target[6] = {30, 90, 90, 0, 90, 0};
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":[30,90,90,0,90,0],"
                        "\"speed\":20,\"relFlag\":0}", SLOT);
    assert_int_equal(m.state, MOTION_MOVING);
    /* Before its reply, even a document at the target proves nothing. */
    feed(T0 + 1, target, HOME_TCP, 1);
    feed(T0 + 2, target, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING);
    motion_answered(&m, T0 + 3, SLOT, T0 + 3, true, false);
    /* The controller's lag: in position where it was. */
    feed(T0 + 20, HOME, HOME_TCP, 1);
    feed(T0 + 40, HOME, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING);
    double q[6];
    memcpy(q, HOME, sizeof(q));
    for (int k = 1; k <= 75; k++) {
        q[0] = k * 0.4;
        feed(T0 + 40 + 20 * k, q, HOME_TCP, k < 75 ? 0 : 1);
        assert_int_equal(m.state, MOTION_MOVING); /* never in passing */
    }
    /* At the target and in position, but still changing since the last. */
    assert_int_equal(m.state, MOTION_MOVING);
    feed(T0 + 1600, target, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
}

static void arrives_within_the_joint_tolerance_only(void **state)
{
    (void)state;
    double near[6] = {10 + 0.09, 90 - 0.09, 90, 0, 90, 0};
    double off[6] = {10 + 0.11, 90, 90, 0, 90, 0};
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":[10,90,90,0,90,0],"
                        "\"speed\":20}", SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    feed(T0 + 20, off, HOME_TCP, 1);
    feed(T0 + 40, off, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING);
    feed(T0 + 60, near, HOME_TCP, 1);
    feed(T0 + 80, near, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
}

static void relative_moves_aim_from_the_position_at_the_trigger(void **state)
{
    (void)state;
    double q[6] = {5, 85, 90, 0, 90, 0};
    double tcp[6] = {400, 0, 300, 180, 0, 90};
    double there[6] = {400, 0, 350, 180, 0, 90};
    start_at_home();
    feed(T0 + 1, q, HOME_TCP, 1);
    motion_sent(&m, T0 + 2, "{\"cmdName\":\"joint_move\",\"jointPosition\":[1,2,0,0,0,0],"
                            "\"speed\":20,\"relFlag\":1}", SLOT);
    assert_true(m.target_known);
    assert_true(fabs(m.target[0] - 6) < 1e-9 && fabs(m.target[1] - 87) < 1e-9);
    motion_answered(&m, T0 + 2, SLOT, T0 + 2, false, false); /* refused: none held */
    assert_int_equal(m.state, MOTION_STOPPED);
    /* moveL relative: the TCP at the trigger plus the offset. */
    feed(T0 + 3, q, tcp, 1);
    motion_sent(&m, T0 + 4, "{\"cmdName\":\"moveL\",\"cartPosition\":[0,0,50,0,0,0],"
                            "\"speed\":100,\"relFlag\":1}", OTHER);
    motion_answered(&m, T0 + 5, OTHER, T0 + 5, true, false);
    feed(T0 + 20, q, tcp, 1);
    feed(T0 + 40, q, tcp, 1);
    assert_int_equal(m.state, MOTION_MOVING); /* still where it was: not there */
    there[2] = 349.2; /* 0.8 mm short: within 1 mm */
    feed(T0 + 600, q, there, 1);
    feed(T0 + 620, q, there, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
}

static void tcp_tolerances_and_equivalent_angles(void **state)
{
    (void)state;
    double q[6] = {1, 2, 3, 4, 5, 6};
    /* The same orientation written two ways (roll and yaw by 180, pitch
     * mirrored): 0 deg apart. */
    const double a[3] = {180, 0, 90}, b[3] = {0, 180, -90};
    assert_true(motion_orientation_error_deg(a, b) < 1e-6);
    const double c[3] = {180, 0.4, 90}, d[3] = {180, 0.6, 90};
    assert_true(fabs(motion_orientation_error_deg(a, c) - 0.4) < 1e-6);
    assert_true(fabs(motion_orientation_error_deg(a, d) - 0.6) < 1e-6);
    /* end_move: 1.1 mm away is not there, 0.6 deg turned is not there. */
    double far[6] = {400, 1.1, 300, 180, 0, 90}, turned[6] = {400, 0, 300, 180, 0.6, 90};
    double flipped[6] = {400, 0, 300, 0, 180, -90};
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"end_move\",\"endPosition\":[400,0,300,180,0,90],"
                        "\"speed\":20}", SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    feed(T0 + 20, q, far, 1);
    feed(T0 + 40, q, far, 1);
    feed(T0 + 60, q, turned, 1);
    feed(T0 + 80, q, turned, 1);
    assert_int_equal(m.state, MOTION_MOVING);
    feed(T0 + 100, q, flipped, 1);
    feed(T0 + 120, q, flipped, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
}

/* A document at 'joints' showing one of the robot's own stops: 0 an
 * emergency stop, 1 a protective stop, 2 disabled, 3 powered off. */
static struct motion_view doc_with_stop(int kind, const double joints[6])
{
    struct motion_view v = doc_at(joints, HOME_TCP);
    if (kind == 0)
        v.emergency_stop = 1;
    else if (kind == 1)
        v.protective_stop = 1;
    else if (kind == 2)
        v.enabled = 0;
    else
        v.powered_on = 0;
    return v;
}

static void ends_before_arriving(void **state)
{
    (void)state;
    static const char *const move =
        "{\"cmdName\":\"joint_move\",\"jointPosition\":[30,90,90,0,90,0],\"speed\":20}";
    double q[6] = {3, 90, 90, 0, 90, 0};
    /* A stop. */
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    motion_stop_sent(&m, T0 + 50, "stop_program from a PLC");
    assert_int_equal(m.state, MOTION_MOVING); /* not before the robot took it */
    motion_stop_answered(&m, T0 + 51, true);
    feed(T0 + 52, q, HOME_TCP, 0);
    assert_int_equal(m.state, MOTION_MOVING); /* braking: not still yet */
    feed(T0 + 54, q, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_STOPPED);
    assert_string_equal(m.why, "stop_program from a PLC");
    /* Nothing after it changes it: not even the arm at the target. */
    const double target[6] = {30, 90, 90, 0, 90, 0};
    feed(T0 + 60, target, HOME_TCP, 1);
    feed(T0 + 80, target, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_STOPPED);
    /* The robot's refusal; an unknown outcome is not one. */
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, false, true);
    assert_int_equal(m.state, MOTION_MOVING);
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, OTHER, T0 + 1, false, false); /* another command's */
    assert_int_equal(m.state, MOTION_MOVING);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, false, false);
    assert_int_equal(m.state, MOTION_STOPPED);
    /* The robot's own stops, as the status shows them. */
    for (int kind = 0; kind < 4; kind++) {
        start_at_home();
        motion_sent(&m, T0, move, SLOT);
        motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
        struct motion_view v = doc_with_stop(kind, q);
        v.inpos = 0;
        motion_document(&m, T0 + 20, &v);
        /* Unpowered it cannot move; stopped, it is 3 once it stands still. */
        assert_int_equal(m.state, kind < 2 ? MOTION_MOVING : MOTION_STOPPED);
        motion_document(&m, T0 + 40, &v);
        assert_int_equal(m.state, MOTION_STOPPED);
    }
    /* A stop a command ahead of the move was about to end (clear_error
     * after a protective stop, enable_robot): the documents before the
     * move's reply still show it, the arm still; they end nothing. After
     * the reply the robot has it: the move goes on. */
    for (int kind = 0; kind < 4; kind++) {
        start_at_home();
        motion_sent(&m, T0, move, SLOT);
        struct motion_view v = doc_with_stop(kind, HOME);
        motion_document(&m, T0 + 20, &v);
        motion_document(&m, T0 + 40, &v);
        assert_int_equal(m.state, MOTION_MOVING);
        motion_answered(&m, T0 + 40, SLOT, T0 + 1, true, false);
        motion_document(&m, T0 + 40, &v); /* the same loop turn as the reply */
        assert_int_equal(m.state, MOTION_MOVING);
        feed(T0 + 60, q, HOME_TCP, 0);
        assert_int_equal(m.state, MOTION_MOVING);
    }
}

static void not_arrived_within_the_bound(void **state)
{
    (void)state;
    /* 30 deg at 20 deg/s and the rapid rate at 0.5: 3 s, times 1.5, plus
     * 1 s: 5.5 s from the reply. */
    start_at_home();
    struct motion_view v = doc_at(HOME, HOME_TCP);
    v.rapid_rate = 0.5;
    motion_document(&m, T0, &v);
    motion_sent(&m, T0 + 1, "{\"cmdName\":\"joint_move\",\"jointPosition\":"
                            "[30,90,90,0,90,0],\"speed\":20}", SLOT);
    assert_int_equal(m.bound_ms, 5500);
    motion_answered(&m, T0 + 10, SLOT, T0 + 10, true, false);
    assert_false(motion_check(&m, T0 + 10 + 5499));
    assert_int_equal(m.state, MOTION_MOVING);
    assert_true(motion_check(&m, T0 + 10 + 5500));
    assert_int_equal(m.state, MOTION_TIMED_OUT);
    assert_false(motion_check(&m, T0 + 10 + 9999));
    /* moveL: 50 mm at 100 mm/s: 0.5 s * 1.5 + 1 s; end_move: 180 deg. */
    assert_int_equal(motion_bound_ms(50, 100), 1750);
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"end_move\",\"endPosition\":[400,0,300,180,0,90],"
                        "\"speed\":30}", SLOT);
    assert_int_equal(m.bound_ms, 10000);
    assert_int_equal(motion_bound_ms(180, 0), MOTION_BOUND_MAX_MS); /* no speed: capped */
}

/* The bound begins when the move was written to the robot, which starts it
 * on receipt: not when it was queued (it waited 400 ms behind a slow
 * command in the gateway's queue), not when its reply came (600 ms after
 * the write). */
static void the_bound_begins_when_written(void **state)
{
    (void)state;
    static const char *const move =
        "{\"cmdName\":\"joint_move\",\"jointPosition\":[30,90,90,0,90,0],\"speed\":20}";
    const uint64_t queued = T0, written = T0 + 400, replied = T0 + 1000;
    const double short_of[6] = {29, 90, 90, 0, 90, 0};
    start_at_home();
    assert_true(motion_sent(&m, queued, move, SLOT));
    assert_int_equal(m.bound_ms, 3250); /* 1.5 s * 1.5 + 1 s */
    assert_false(motion_check(&m, written + 3250)); /* no reply yet: its timeout decides */
    motion_answered(&m, replied, SLOT, written, true, false);
    /* The arm stopped 1 deg short, still. */
    feed(replied + 20, short_of, HOME_TCP, 1);
    feed(replied + 40, short_of, HOME_TCP, 1);
    assert_false(motion_check(&m, queued + 3250 + 399));
    assert_false(motion_check(&m, written + 3250 - 1));
    assert_int_equal(m.state, MOTION_MOVING);
    assert_true(motion_check(&m, written + 3250)); /* from the reply: 600 ms later */
    assert_int_equal(m.state, MOTION_TIMED_OUT);
    assert_string_equal(m.why, "not arrived within 3250 ms");
    /* Written time unknown (0) or after the reply (another clock): the
     * reply's time. */
    start_at_home();
    motion_sent(&m, queued, move, SLOT);
    motion_answered(&m, replied, SLOT, 0, true, false);
    feed(replied + 20, short_of, HOME_TCP, 1);
    feed(replied + 40, short_of, HOME_TCP, 1);
    assert_false(motion_check(&m, replied + 3250 - 1));
    assert_true(motion_check(&m, replied + 3250));
    start_at_home();
    motion_sent(&m, queued, move, SLOT);
    motion_answered(&m, replied, SLOT, replied + 5000, true, false);
    feed(replied + 20, short_of, HOME_TCP, 1);
    feed(replied + 40, short_of, HOME_TCP, 1);
    assert_false(motion_check(&m, replied + 3250 - 1));
    assert_true(motion_check(&m, replied + 3250));
    /* A queued move behind one that arrived: from that arrival when the
     * write came before it. */
    start_at_home();
    motion_sent(&m, queued, "{\"cmdName\":\"joint_move\",\"jointPosition\":"
                            "[10,90,90,0,90,0],\"speed\":20}", SLOT);
    motion_sent(&m, queued + 1, move, OTHER);
    motion_answered(&m, queued + 2, SLOT, queued + 1, true, false);
    motion_answered(&m, queued + 3, OTHER, queued + 2, true, false);
    const double first[6] = {10, 90, 90, 0, 90, 0};
    feed(T0 + 900, first, HOME_TCP, 0); /* passing the first target at 900 ms */
    feed(T0 + 920, short_of, HOME_TCP, 1);
    feed(T0 + 940, short_of, HOME_TCP, 1);
    /* The second: 20 deg from the first's target, 1 s * 1.5 + 1 s. */
    assert_false(motion_check(&m, T0 + 900 + 2500 - 1));
    assert_true(motion_check(&m, T0 + 900 + 2500));
}

static void a_new_move_replaces_the_last(void **state)
{
    (void)state;
    const double first[6] = {10, 90, 90, 0, 90, 0};
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":[10,90,90,0,90,0],"
                        "\"speed\":20}", SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    motion_sent(&m, T0 + 5, "{\"cmdName\":\"joint_move\",\"jointPosition\":[20,90,90,0,90,0],"
                            "\"speed\":20}", SLOT);
    motion_answered(&m, T0 + 6, SLOT, T0 + 6, true, false);
    feed(T0 + 600, first, HOME_TCP, 1);
    feed(T0 + 620, first, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING); /* the first's target is not the second's */
    assert_int_equal(m.count, 2);
}

static void what_the_arm_does(void **state)
{
    (void)state;
    double q[6] = {1, 90, 90, 0, 90, 0};
    motion_init(&m);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_UNKNOWN);
    start_at_home();
    assert_int_equal(motion_robot(&m, false), POLICY_ROBOT_UNKNOWN);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_STILL);
    feed(T0 + 20, q, HOME_TCP, 1); /* in position, but it moved */
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_MOVING);
    feed(T0 + 40, q, HOME_TCP, 0);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_MOVING);
    struct motion_view v = doc_at(q, HOME_TCP);
    v.interp_state = 3;
    motion_document(&m, T0 + 60, &v);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_PROGRAM);
    v.interp_state = 2;
    motion_document(&m, T0 + 80, &v);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_PAUSED);
    v.inpos = 0; /* a move paused by the robot's handler: not in position, held */
    motion_document(&m, T0 + 90, &v);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_PAUSED);
    v.joints[0] += 1;
    motion_document(&m, T0 + 95, &v);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_MOVING);
    v.inpos = 1;
    v.interp_state = 0;
    motion_document(&m, T0 + 100, &v);
    assert_int_equal(motion_robot(&m, true), POLICY_ROBOT_STILL);
}

/*
 * The property: over generated moves (absolute or relative, any command
 * of the three) and generated documents (the lag, positions on the way,
 * at the target or just off it, in position or not, faults), the state is
 * ARRIVED only if the last document was received after the accepted
 * reply, shows the arm in position, no program, the same joints as the
 * one before, and the target within tolerance; it is never ARRIVED while
 * the reply is awaited; the count grows by one per move.
 */

#define EPS 1e-5 /* the targets go out with six decimals */

static double jitter(double scale)
{
    return ((double)property_next(2001) - 1000) / 1000 * scale;
}

static void generated_moves_arrive_only_when_shown(void **state)
{
    (void)state;
    unsigned runs = 5000, arrived = 0;
    property_seed("motion property", "MOTION_PROPERTY_SEED", runs);
    for (unsigned run = 0; run < runs; run++) {
        start_at_home();
        unsigned which = property_next(3);
        bool relative = which != 1 && property_next(2);
        double given[6], target[6];
        const double *from = which == 0 ? HOME : HOME_TCP;
        for (int i = 0; i < 6; i++) {
            given[i] = relative ? jitter(20) : from[i] + jitter(20);
            target[i] = relative ? from[i] + given[i] : given[i];
        }
        char json[512];
        snprintf(json, sizeof(json),
                 "{\"cmdName\":\"%s\",\"%s\":[%.6f,%.6f,%.6f,%.6f,%.6f,%.6f],\"speed\":%u,"
                 "\"relFlag\":%d}",
                 which == 0 ? "joint_move" : which == 1 ? "end_move" : "moveL",
                 which == 0 ? "jointPosition" : which == 1 ? "endPosition" : "cartPosition",
                 given[0], given[1], given[2], given[3], given[4], given[5],
                 1 + property_next(100), relative);
        uint16_t before = m.count;
        assert_true(motion_sent(&m, T0 + 1, json, SLOT));
        assert_int_equal((uint16_t)(before + 1), m.count);
        uint64_t t = T0 + 1, reply_at = 0;
        bool accepted = false;
        unsigned docs = 5 + property_next(40);
        for (unsigned k = 0; k < docs && m.state == MOTION_MOVING; k++) {
            t += 1 + property_next(30);
            if (!reply_at && property_next(4) == 0) {
                accepted = property_next(8) != 0;
                reply_at = t;
                motion_answered(&m, t, SLOT, t, accepted, false);
                continue;
            }
            /* A document: at the target (exactly, within or outside the
             * tolerance), on the way, or where it was. */
            struct motion_view v = doc_at(HOME, HOME_TCP);
            double *pos = which == 0 ? v.joints : v.tcp;
            unsigned where = property_next(4);
            double scale = which == 0 ? MOTION_JOINT_TOL_DEG : MOTION_TCP_TOL_MM / 2;
            for (int i = 0; i < 6; i++)
                pos[i] = where == 0   ? target[i]
                         : where == 1 ? target[i] + jitter(scale)
                         : where == 2 ? target[i] + jitter(5 * scale)
                                      : from[i];
            if (which == 0 && property_next(2))
                memcpy(v.joints, m.last.joints, sizeof(v.joints)); /* still */
            if (which != 0)
                memcpy(v.joints, m.have_last && property_next(2) ? m.last.joints : HOME,
                       sizeof(v.joints));
            v.inpos = property_next(3) != 0;
            v.interp_state = property_next(10) == 0 ? 3 : 0;
            if (property_next(50) == 0)
                v.protective_stop = 1;
            struct motion_view prev = m.last;
            motion_document(&m, t, &v);
            if (m.state != MOTION_ARRIVED)
                continue;
            arrived++;
            /* Arrived: then everything the rule asks held (to within
             * the JSON's six decimals of the target sent). */
            assert_true(reply_at && accepted && t > reply_at);
            assert_int_equal(v.inpos, 1);
            assert_int_not_equal(v.interp_state, 3);
            for (int i = 0; i < 6; i++)
                assert_true(fabs(v.joints[i] - prev.joints[i]) <= MOTION_STILL_DEG);
            if (which == 0) {
                for (int i = 0; i < 6; i++)
                    assert_true(fabs(v.joints[i] - target[i]) <= MOTION_JOINT_TOL_DEG + EPS);
            } else {
                double mm = 0;
                for (int i = 0; i < 3; i++)
                    mm += (v.tcp[i] - target[i]) * (v.tcp[i] - target[i]);
                assert_true(sqrt(mm) <= MOTION_TCP_TOL_MM + EPS);
                assert_true(motion_orientation_error_deg(v.tcp + 3, target + 3) <=
                            MOTION_TCP_TOL_DEG + EPS);
            }
        }
    }
    /* The generator reaches arrivals, not only refusals. */
    assert_true(arrived > runs / 20);
}

/* A joint target with joint 1 at 'j1', the rest at home. */
static void at_j1(double j1, double q[6])
{
    memcpy(q, HOME, sizeof(double) * 6);
    q[0] = j1;
}

/* Out 60 deg and back, the second queued behind the first (the robot
 * holds both, manual 4.7): never 2 before the arm went out and came back. */
static void queued_moves_arrive_in_order(void **state)
{
    (void)state;
    double q[6];
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":[60,90,90,0,90,0],"
                        "\"speed\":60}", SLOT);
    motion_sent(&m, T0 + 1, "{\"cmdName\":\"joint_move\",\"jointPosition\":[0,90,90,0,90,0],"
                            "\"speed\":60}", OTHER);
    motion_answered(&m, T0 + 2, SLOT, T0 + 2, true, false);
    motion_answered(&m, T0 + 3, OTHER, T0 + 3, true, false);
    /* The arm has not left: it is at the second's target, still. */
    feed(T0 + 20, HOME, HOME_TCP, 1);
    feed(T0 + 40, HOME, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING);
    uint64_t t = T0 + 40;
    for (int k = 1; k <= 60; k++) {
        at_j1(k, q);
        feed(t += 20, q, HOME_TCP, 0);
        assert_int_equal(m.state, MOTION_MOVING);
    }
    for (int k = 59; k >= 1; k--) {
        at_j1(k, q);
        feed(t += 20, q, HOME_TCP, 0);
        assert_int_equal(m.state, MOTION_MOVING);
    }
    feed(t += 20, HOME, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_MOVING); /* changed since the last */
    feed(t += 20, HOME, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
    /* One slot's refusal is never taken for another's move. */
    start_at_home();
    motion_sent(&m, T0, "{\"cmdName\":\"joint_move\",\"jointPosition\":[5,90,90,0,90,0],"
                        "\"speed\":60}", SLOT);
    motion_sent(&m, T0 + 1, "{\"cmdName\":\"joint_move\",\"jointPosition\":[9,90,90,0,90,0],"
                            "\"speed\":60}", OTHER);
    motion_answered(&m, T0 + 2, OTHER, T0 + 2, false, false);
    assert_int_equal(m.state, MOTION_MOVING);
    motion_answered(&m, T0 + 3, SLOT, T0 + 3, true, false);
    at_j1(5, q);
    feed(T0 + 20, q, HOME_TCP, 1);
    feed(T0 + 40, q, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
}

/* A refused or unanswered stop ends nothing; a lost reply can arrive; the
 * bound follows the override and never ends a move the arm still makes;
 * a late arrival turns 4 into 2; a lost command link says so at once. */
static void ends_in_the_state_the_arm_is_in(void **state)
{
    (void)state;
    static const char *const move =
        "{\"cmdName\":\"joint_move\",\"jointPosition\":[30,90,90,0,90,0],\"speed\":20}";
    double q[6];
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    motion_stop_sent(&m, T0 + 10, "stop_program from a PLC");
    motion_stop_answered(&m, T0 + 11, false);
    at_j1(10, q);
    feed(T0 + 20, q, HOME_TCP, 1);
    feed(T0 + 40, q, HOME_TCP, 1); /* still, but the stop was refused */
    assert_int_equal(m.state, MOTION_MOVING);
    at_j1(30, q);
    feed(T0 + 60, q, HOME_TCP, 1);
    feed(T0 + 80, q, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
    /* The reply lost: it may still arrive. */
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, false, true);
    feed(T0 + 20, q, HOME_TCP, 1);
    feed(T0 + 40, q, HOME_TCP, 1);
    assert_int_equal(m.state, MOTION_ARRIVED);
    /* The override lowered to 10 % after the send: 30 deg at 2 deg/s. */
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, true, false);
    assert_int_equal(m.bound_ms, 3250);
    struct motion_view v = doc_at(HOME, HOME_TCP);
    v.rapid_rate = 0.1;
    v.inpos = 0;
    uint64_t t = T0 + 1;
    for (int k = 1; k <= 200; k++) { /* 2 deg/s, 20 ms a document: 8 s */
        v.joints[0] = k * 0.04;
        motion_document(&m, t += 20, &v);
        motion_check(&m, t);
        assert_int_equal(m.state, MOTION_MOVING); /* moving: never terminal */
    }
    /* Standing off the target past the bound at 10 %: 4. */
    v.inpos = 1;
    motion_document(&m, t += 20, &v);
    assert_false(motion_check(&m, T0 + 1 + 23500 - 1));
    assert_true(motion_check(&m, T0 + 1 + 23500));
    assert_int_equal(m.state, MOTION_TIMED_OUT);
    /* Then on to the target after all: 2. */
    v.joints[0] = 30;
    motion_document(&m, T0 + 30000, &v);
    motion_document(&m, T0 + 30020, &v);
    assert_int_equal(m.state, MOTION_ARRIVED);
    /* The command link lost: 4 at once, with why. */
    start_at_home();
    motion_sent(&m, T0, move, SLOT);
    motion_answered(&m, T0 + 1, SLOT, T0 + 1, false, true);
    motion_link_lost(&m, T0 + 2, "the command link was lost");
    assert_int_equal(m.state, MOTION_TIMED_OUT);
    assert_string_equal(m.why, "the command link was lost");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(only_the_three_moves_count),
        cmocka_unit_test(arrived_only_after_the_status_shows_it),
        cmocka_unit_test(arrives_within_the_joint_tolerance_only),
        cmocka_unit_test(relative_moves_aim_from_the_position_at_the_trigger),
        cmocka_unit_test(tcp_tolerances_and_equivalent_angles),
        cmocka_unit_test(ends_before_arriving),
        cmocka_unit_test(not_arrived_within_the_bound),
        cmocka_unit_test(the_bound_begins_when_written),
        cmocka_unit_test(a_new_move_replaces_the_last),
        cmocka_unit_test(what_the_arm_does),
        cmocka_unit_test(generated_moves_arrive_only_when_shown),
        cmocka_unit_test(queued_moves_arrive_in_order),
        cmocka_unit_test(ends_in_the_state_the_arm_is_in),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
