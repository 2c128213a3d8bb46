/* SPDX-License-Identifier: MIT */
/*
 * robot.h - jakasim's robot: the controller state that the status document
 * shows and the Chapter-4 commands change.
 *
 * A command is answered the way the manual shows, quirks included, and
 * refused the way a controller refuses it (errorCode "2" and a message)
 * when the state does not allow it: enable while powered off, motion while
 * disabled, play with no program loaded, servo_j outside servo mode.
 * Requests are read as the controller's Python reads them: when a member
 * appears twice, the last one counts.
 */
#ifndef JAKASIM_ROBOT_H
#define JAKASIM_ROBOT_H

#include <stdbool.h>
#include <stddef.h>

#include "pyjson.h"
#include "ramp.h" /* SIM_JOINTS */

#define SIM_MAX_DIO 256
#define SIM_MAX_AIO 128
/* The extension IO module's pins (one Modbus TCP module). */
#define SIM_EXTIO_DI 10
#define SIM_EXTIO_DO 16
#define SIM_EXTIO_AI 8
#define SIM_EXTIO_AO 8
/* Moves a controller takes ahead of the one running. */
#define SIM_MOVE_QUEUE 8

struct sim_profile;

struct sim_robot {
    bool powered_on;
    bool enabled;
    bool emergency_stop;
    bool protective_stop;
    bool drag;
    bool servo_mode;
    bool torque_control;
    int interp_state; /* 0 idle, 1 loading, 2 paused, 3 running */
    char program[128];
    double program_time; /* seconds the loaded program has run */

    double joints[SIM_JOINTS];      /* deg */
    double joint_cmd[SIM_JOINTS];   /* commanded (joint_position) */
    double joint_target[SIM_JOINTS];
    double joint_speed;             /* deg/s of the current move */
    double joint_vel[SIM_JOINTS];   /* last tick's velocity */
    bool moving;
    /* moveL: the TCP on a straight line from lin_start to lin_target,
     * lin_done mm (or degrees, when the turn is the longer) of lin_length
     * covered so far; the joints follow by inverse kinematics. */
    bool linear;
    double lin_start[6], lin_target[6], lin_length, lin_done;
    /* Moves accepted, not started yet, in order. The manual's moves block
     * (4.7, 4.8): each starts once the one before has ended, and no sooner
     * than move_lag_ticks ticks after its own reply (a controller's
     * planner takes a few cycles). */
    struct sim_move {
        double target[SIM_JOINTS]; /* the joints at its end */
        double speed;              /* deg/s, or mm/s when linear */
        bool linear;               /* moveL: through 'pose' on a line */
        double pose[6];
        unsigned lag_left;         /* ticks before it may start */
    } queued[SIM_MOVE_QUEUE];
    unsigned queued_count;
    unsigned move_lag_ticks; /* ticks (status documents); 0: at once */
    /* Acceleration and braking: the ramp's stopping time, the running
     * move's speed, how it halts, a program's braking (ramp.h). */
    struct sim_ramp ramp;
    double tcp_speed;               /* mm/s */
    double cart[6];                 /* mm, deg: FK of joints */

    double rapid_rate;
    int tool_id, user_id;
    double tool_offsets[11][6], user_offsets[11][6];
    double payload_mass, payload_centroid[3];
    int collision_level;
    /* The last set_network_exception_handle accepted, and how many were:
     * the command port arms the connection it came on (jakasim.c). */
    int net_exception_ms, net_exception_motion;
    unsigned net_exception_count;
    bool paused_move; /* interp_state 2 holds a move, not a program */

    bool din[SIM_MAX_DIO], dout[SIM_MAX_DIO];
    double ain[SIM_MAX_AIO], aout[SIM_MAX_AIO];
    bool tio_din[8], tio_dout[8];
    double tio_ain[2];
    bool extio_do[SIM_EXTIO_DO];
    double extio_ao[SIM_EXTIO_AO];

    char errcode[16];
    char errmsg[128];
    double uptime_s;
    bool test_pattern; /* distinct values in every field, for map tests */
    /* The status document's shape, for get_data (NULL: the "full" one). */
    const struct sim_profile *profile;
    /* The errorMsg of a command failed on purpose; NULL: "call NAME failed". */
    const char *fail_message;
    /* How many times the command failed on purpose fails (0: always), and
     * how many times it has. */
    unsigned fail_times, failed;
};

void sim_robot_init(struct sim_robot *r, bool test_pattern);

/*
 * Advances motion and programs by 'dt' seconds: one tick, one status
 * document. A move outside a program (joint_move, end_move, moveL, jog)
 * starts once the move before it has ended and move_lag_ticks ticks after
 * it was accepted, ramps up to its speed (times the rapid rate) and down
 * to its target; stop_program and a protective stop end it once it has
 * slowed down to a standstill (ramp.stop_time_s from full speed, ramp.h),
 * an emergency stop, disable and power off where the arm is, each with every move
 * queued behind it; pause_program does not touch it (no program runs).
 * A program stopped or paused slows down to a standstill the same way.
 */
void sim_robot_tick(struct sim_robot *r, double dt);

/*
 * Answers one command (a JSON object's text) into 'reply'. Returns false
 * when the command must get no reply at all (the robot ignores it).
 * 'fail_cmd' (may be NULL): a cmdName to refuse with errorCode "2".
 */
bool sim_robot_command(struct sim_robot *r, const char *json, size_t size,
                       const char *fail_cmd, struct pyjson *reply,
                       char *cmd_name, size_t cmd_name_size);

/* motType of set_network_exception_handle (manual 4.75). */
enum sim_net_motion { SIM_NET_KEEP = 0, SIM_NET_PAUSE = 1, SIM_NET_STOP = 2 };

/*
 * The network-exception handler's action on whatever still runs: a program
 * (interp_state 3) or a move (a joint, Cartesian or jog motion) is kept,
 * paused (interp_state 2, "paused" true; resume_program continues it) or
 * stopped (interp_state 0, the arm holds where it is). Something already
 * paused stays paused. Writes what it did, as a phrase for the log
 * ("paused the program demo.jks", "nothing was running"), into 'done'.
 */
void sim_robot_network_lost(struct sim_robot *r, enum sim_net_motion motion, char *done,
                            size_t done_size);

/* Kinematics of a Zu-5-like arm (DH in mm, angles in degrees). */
void sim_forward_kinematics(const double joints[SIM_JOINTS], double pose[6]);
bool sim_inverse_kinematics(const double pose[6], const double seed[SIM_JOINTS],
                            double joints[SIM_JOINTS]);

#endif
