/* SPDX-License-Identifier: MIT */
/*
 * ramp.h - jakasim's acceleration and braking profile: how fast the arm
 * speeds up into a move, slows down to its target, and comes to rest when
 * a move or a program is stopped or paused.
 *
 * The manual gives joint_move an "accel" (4.7) and a controller ramps every
 * move up and down; a stop_program or pause_program (4.19, 4.20) brings a
 * program's motion to rest, not to a dead halt. The model: stop_time_s is
 * the time a stop takes from a move's full speed (its speed at rapid rate
 * 1), so the ramp's rate is that speed / stop_time_s; 0 means instant, no
 * ramp. A move runs along its path (joint space, or the TCP's line) at
 * path_speed, which changes by at most that rate per second, never faster
 * than it can still come to rest before its end; a program brought to a
 * halt slows every joint linearly from its last speed to 0 over
 * stop_time_s. The gateway's policy judges "still braking" against this
 * stopping time, so the profile is a behaviour a PLC sees.
 *
 * Pure arithmetic on joint arrays and time: the robot's state, its
 * kinematics and its status stay in robot.c.
 */
#ifndef JAKASIM_RAMP_H
#define JAKASIM_RAMP_H

#include <stdbool.h>

/* The arm's joints (a JAKA Zu: six). */
#define SIM_JOINTS 6

/* How a move slowing down to 0 ends once at rest. */
enum sim_halt {
    SIM_HALT_NONE,  /* it is not halting: it runs to its target */
    SIM_HALT_STOP,  /* stopped where it comes to rest */
    SIM_HALT_PAUSE, /* paused there, to go on when resumed */
};

struct sim_ramp {
    double stop_time_s; /* from full speed to rest; 0: no ramp */
    /* The running move's speed now (deg/s or mm/s); a move ends early only
     * once it has come down to 0: 'halting' says how it ends then. */
    double path_speed;
    enum sim_halt halting;
    /* A program brought to a halt (stop or pause): every joint slows down
     * from brake_vel to 0 over brake_total_s, brake_left_s still to go. */
    bool braking;
    double brake_vel[SIM_JOINTS], brake_total_s, brake_left_s;
};

/*
 * The running move's speed for the next 'dt' seconds: up towards
 * 'full_speed' times 'rate' (the rapid rate; down to 0 while halting),
 * never faster than it can still come to rest within 'remaining' (deg or
 * mm), changing by at most full_speed / stop_time_s per second.
 */
double sim_ramp_speed(const struct sim_ramp *m, double full_speed, double rate,
                      double remaining, double dt);

/*
 * A joint move for 'dt' seconds: every joint on its way to 'target' at
 * once, all arriving together (a straight line in joint space), the
 * largest turn at the ramped speed (path_speed is updated). Returns true
 * once 'joints' are at 'target'.
 */
bool sim_ramp_move_joints(struct sim_ramp *m, double joints[SIM_JOINTS],
                          const double target[SIM_JOINTS], double full_speed, double rate,
                          double dt);

/*
 * A program stopped or paused: every joint slows down from 'joint_vel'
 * (its speed of the last tick) to 0 within the stopping time. Nothing to
 * do with no stopping time (the arm stands at once).
 */
void sim_ramp_brake(struct sim_ramp *m, const double joint_vel[SIM_JOINTS]);

/*
 * One tick of that braking, 'dt' seconds: v(t) = v0 (1 - t / T),
 * integrated over the tick. Returns true when the arm came to rest in it
 * (braking is over).
 */
bool sim_ramp_brake_tick(struct sim_ramp *m, double joints[SIM_JOINTS], double dt);

#endif
