/* SPDX-License-Identifier: MIT */
/*
 * motion.h - the motion tracker: what became of the last move the gateway
 * sent, as a PLC can trust it (gw:motion.state, gw:motion.count), and what
 * the status shows the arm doing (for the network-exception policy).
 *
 * The moves followed are joint_move, end_move and moveL, from a trigger,
 * the exactly-once mailbox or the JSON mailbox. Each one sent counts once
 * (motion_sent) and reads MOTION_MOVING from then on: before the PLC's
 * write is answered. It reads:
 * - MOTION_ARRIVED only when a status document received after the move's
 *   reply shows the arm in position, no program running, its joints the
 *   same as in the document before, and the target reached: every joint
 *   within MOTION_JOINT_TOL_DEG of jointPosition (joint_move), or the TCP
 *   (actual_position) within MOTION_TCP_TOL_MM of the target's position
 *   and MOTION_TCP_TOL_DEG of its orientation (end_move, moveL). A
 *   relative move's target is the position the last document showed when
 *   it was sent, plus the offset (joints, or the TCP's six numbers);
 * - MOTION_STOPPED when it ends before: a stop_program sent (by the PLC
 *   or by the policy), the robot's refusal of the move, an emergency or
 *   protective stop, the robot disabled or powered off;
 * - MOTION_TIMED_OUT when it has not arrived within its bound
 *   (motion_bound_ms): the travel at the move's speed times the rapid
 *   rate, times MOTION_BOUND_FACTOR, plus MOTION_BOUND_MARGIN_MS, counted
 *   from the reply. A move whose reply was lost (a timeout, the link
 *   lost) stays MOTION_MOVING until it arrives or its bound passes.
 * A new move replaces the one followed. Other motion commands (jog, movc,
 * servo_j, the compliance settings) are not followed: state and count stay.
 *
 * Pure logic: the time and the status come in as arguments (struct
 * motion_view, made from a parsed document by motion_view_of), so every
 * rule is unit-tested without a loop.
 */
#ifndef JAKAGW_MOTION_H
#define JAKAGW_MOTION_H

#include <stdbool.h>
#include <stdint.h>

#include "policy.h"
#include "status.h"

/* The tolerances of "arrived" and the terms of the time bound. */
#define MOTION_JOINT_TOL_DEG 0.1
#define MOTION_TCP_TOL_MM 1.0
#define MOTION_TCP_TOL_DEG 0.5
/* Joints unchanged between two documents: "no longer moving". */
#define MOTION_STILL_DEG 0.01
#define MOTION_BOUND_FACTOR 1.5
#define MOTION_BOUND_MARGIN_MS 1000
/* end_move's joint travel is the controller's inverse solution, which the
 * gateway does not compute: its bound assumes the largest joint turns this
 * far. */
#define MOTION_END_MOVE_TRAVEL_DEG 180.0
#define MOTION_BOUND_MAX_MS 3600000

enum motion_state {
    MOTION_IDLE = 0,      /* no move sent yet */
    MOTION_MOVING = 1,    /* sent: from the PLC's reply on */
    MOTION_ARRIVED = 2,   /* a status after its reply shows it at its target */
    MOTION_STOPPED = 3,   /* ended before arriving */
    MOTION_TIMED_OUT = 4, /* not arrived within its bound */
};

/* The state's words, for the log and /status.json. */
const char *motion_state_name(enum motion_state state);

/* What one status document says about the arm; -1 or false: not carried. */
struct motion_view {
    int inpos;        /* 1 in position, 0 moving, -1 not carried */
    int interp_state; /* 0 idle, 1 loading, 2 paused, 3 running, -1 */
    int enabled, powered_on, emergency_stop, protective_stop; /* 0, 1, -1 */
    bool have_joints, have_tcp;
    double joints[6]; /* joint_actual_position, deg */
    double tcp[6];    /* actual_position: mm, and rx, ry, rz in deg */
    double rapid_rate; /* rapidrate; <= 0: not carried */
};

/* The view of a parsed document. */
void motion_view_of(const struct jaka_status *s, struct motion_view *v);

enum motion_target { MOTION_TARGET_JOINTS, MOTION_TARGET_TCP };

struct motion {
    enum motion_state state;
    uint16_t count;
    /* The last two documents. */
    struct motion_view last, previous;
    bool have_last, have_previous;
    uint64_t last_document_ms;
    /* The move followed. */
    char name[16];
    enum motion_target kind;
    bool target_known;
    double target[6];
    double travel;       /* deg (joints) or mm / deg (TCP), for the bound */
    double speed;        /* deg/s or mm/s, times the rapid rate */
    bool answered;       /* its reply came, accepted */
    uint64_t sent_ms, answered_ms;
    uint64_t bound_ms;   /* from the reply (or the send) */
    char why[64];        /* why it ended, as the log says it */
};

void motion_init(struct motion *m);

/*
 * A command sent for a PLC, as its JSON text. Returns true when it is a
 * move this module follows (then counted, and MOTION_MOVING).
 */
bool motion_sent(struct motion *m, uint64_t now_ms, const char *json);

/*
 * The reply to command 'name': 'accepted' (errorCode 0), or refused by the
 * robot ('unknown' false: MOTION_STOPPED), or its outcome unknown (a
 * timeout, the link lost, 'unknown' true: the move may run).
 */
void motion_answered(struct motion *m, uint64_t now_ms, const char *name, bool accepted,
                     bool unknown);

/* A stop went out (stop_program, for the PLC or the policy): a move not
 * arrived yet ends here. 'why' says whose. */
void motion_stopped(struct motion *m, uint64_t now_ms, const char *why);

/* A status document received at 'now_ms'. */
void motion_document(struct motion *m, uint64_t now_ms, const struct motion_view *v);

/* Time passes: a move past its bound reads MOTION_TIMED_OUT. Returns true
 * when the state changed. */
bool motion_check(struct motion *m, uint64_t now_ms);

/* The move's bound, ms from its reply: travel / speed * factor + margin. */
uint64_t motion_bound_ms(double travel, double speed);

/* The largest joint change between the last two documents, in degrees
 * (the policy's step(): braking shows as a falling step); -1 unknown. */
double motion_step_deg(const struct motion *m);

/* What the arm does, from the last two documents ('fresh': the status is). */
enum policy_robot motion_robot(const struct motion *m, bool fresh);

/* The angle between two orientations given as rx, ry, rz (fixed XYZ, deg). */
double motion_orientation_error_deg(const double a[3], const double b[3]);

#endif
