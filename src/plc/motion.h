/* SPDX-License-Identifier: MIT */
/*
 * motion.h - the motion tracker: what became of the last move the gateway
 * sent, as a PLC can trust it (gw:motion.state, gw:motion.count), and what
 * the status shows the arm doing (for the network-exception policy).
 *
 * The moves followed are joint_move, end_move and moveL, from a trigger,
 * the exactly-once mailbox or the JSON mailbox. Each one sent counts once
 * (motion_sent) and reads MOTION_MOVING from then on: before the PLC's
 * write is answered. The robot queues moves (manual 4.7, 4.8: each starts
 * once the one before has ended), so the tracker holds every move the
 * robot may hold, in the order sent, each matched to its own reply by
 * whose it is (the 'tag': the PLC slot that sent it, so one slot's
 * refusal is never taken for another's move of the same name). It reads:
 * - MOTION_ARRIVED only when the last move held has reached its target
 *   after each move before it reached its own, in order: a move before
 *   the last reaches its target when a status document received after its
 *   reply (or after its reply was lost) shows the target; the last one
 *   when such a document shows the arm in position, no program running,
 *   its joints the same as in the document before, and the target:
 *   every joint within MOTION_JOINT_TOL_DEG of jointPosition (joint_move),
 *   or the TCP (actual_position) within MOTION_TCP_TOL_MM of the target's
 *   position and MOTION_TCP_TOL_DEG of its orientation (end_move, moveL).
 *   A relative move's target is the position the last document showed
 *   when it was sent, plus the offset (joints, or the TCP's six numbers);
 *   a move whose reply was lost (a timeout, the link lost) may still
 *   arrive;
 * - MOTION_STOPPED when they end before: a stop the robot accepted
 *   (motion_stop_sent, then motion_stop_answered) once a document after
 *   its reply shows the arm still (a refused or unanswered stop ends
 *   nothing); the robot's refusal of every move held; an emergency or
 *   protective stop, the robot disabled or powered off, once the arm
 *   stands still;
 * - MOTION_TIMED_OUT when a move held has not reached its target within
 *   its bound (motion_bound_ms): its travel at its speed times the rapid
 *   rate the status shows now, times MOTION_BOUND_FACTOR, plus
 *   MOTION_BOUND_MARGIN_MS, counted from when it was written to the robot
 *   (not when it was queued, nor when its reply came), or from the
 *   arrival of the move before it if later. Never while the status shows the arm
 *   moving; and a late arrival still turns it into MOTION_ARRIVED.
 * A move sent after the last one ended starts a new list. Other motion
 * commands (jog, movc, servo_j, the compliance settings) are not followed:
 * state and count stay.
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

/* The moves the robot may hold: more than a controller queues (jakasim
 * 8), so none it holds is forgotten. */
#define MOTION_HELD_MAX 16

/* One move held, as sent. */
struct motion_move {
    const void *tag;     /* whose: the PLC slot that sent it */
    enum motion_target kind;
    bool target_known;
    double target[6];
    double travel;       /* deg (joints) or mm / deg (TCP), for the bound */
    double speed;        /* deg/s or mm/s, at rapid rate 1 */
    enum motion_reply { MOTION_REPLY_AWAITED, MOTION_REPLY_ACCEPTED, MOTION_REPLY_LOST } reply;
    uint64_t sent_ms;    /* handed to the command queue */
    uint64_t written_ms; /* written to the robot (known with its reply) */
    uint64_t answered_ms;
    bool reached;        /* its target shown, after the move before it */
    uint64_t reached_ms;
};

struct motion {
    enum motion_state state;
    uint16_t count;
    /* The last two documents. */
    struct motion_view last, previous;
    bool have_last, have_previous;
    uint64_t last_document_ms;
    /* The moves held, in the order sent. */
    struct motion_move held[MOTION_HELD_MAX];
    unsigned held_count;
    /* The last move sent, as the log and the page name it. */
    char name[16];
    enum motion_target kind;
    bool target_known;
    double target[6];
    uint64_t bound_ms;   /* its bound at the rapid rate when sent */
    /* A stop sent while they run: it ends them only once the robot
     * accepted it and the arm stands still. */
    bool stop_sent, stop_accepted;
    uint64_t stop_answered_ms;
    char stop_why[64];
    char why[64];        /* why it ended, as the log says it */
};

void motion_init(struct motion *m);

/*
 * A command sent for a PLC, as its JSON text; 'tag' says whose (its
 * reply comes to motion_answered with the same tag). Returns true when it
 * is a move this module follows (then counted, and MOTION_MOVING).
 */
bool motion_sent(struct motion *m, uint64_t now_ms, const char *json, const void *tag);

/*
 * The reply to the command of 'tag': 'accepted' (errorCode 0), or its
 * outcome unknown ('unknown': a timeout, the link lost; the move may run
 * and may still arrive), or refused or never sent (the move is not held:
 * when no move is left, MOTION_STOPPED). The oldest move of 'tag' awaiting
 * its reply is the one answered; another command's reply changes nothing.
 * 'written_ms' is when the command was written to the robot (0 or later
 * than 'now_ms': taken as 'now_ms'): the robot starts a move on receipt,
 * so its time bound begins then.
 */
void motion_answered(struct motion *m, uint64_t now_ms, const void *tag, uint64_t written_ms,
                     bool accepted, bool unknown);

/* A stop went out (stop_program, for the PLC or the policy; 'why' says
 * whose): the moves held end when it is accepted and the arm is still. */
void motion_stop_sent(struct motion *m, uint64_t now_ms, const char *why);

/* The stop's reply: accepted, or refused or lost (the moves go on). */
void motion_stop_answered(struct motion *m, uint64_t now_ms, bool accepted);

/* The command link was lost with moves held: what the robot does with
 * them is unknown now (its handler may pause or stop them). They end as
 * MOTION_TIMED_OUT with 'why' at once, so a PLC learns it within the link
 * bound, not the moves' bound; a later arrival still reads 2. */
void motion_link_lost(struct motion *m, uint64_t now_ms, const char *why);

/* A status document received at 'now_ms'. */
void motion_document(struct motion *m, uint64_t now_ms, const struct motion_view *v);

/* Time passes: a move past its bound, the arm not moving, reads
 * MOTION_TIMED_OUT. Returns true when the state changed. */
bool motion_check(struct motion *m, uint64_t now_ms);

/* The move's bound, ms from its write: travel / speed * factor + margin. */
uint64_t motion_bound_ms(double travel, double speed);

/* The largest joint change between the last two documents, in degrees
 * (the policy's step(): braking shows as a falling step); -1 unknown. */
double motion_step_deg(const struct motion *m);

/* What the arm does, from the last two documents ('fresh': the status is). */
enum policy_robot motion_robot(const struct motion *m, bool fresh);

/* The angle between two orientations given as rx, ry, rz (fixed XYZ, deg). */
double motion_orientation_error_deg(const double a[3], const double b[3]);

#endif
