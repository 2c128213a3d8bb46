/* SPDX-License-Identifier: MIT */
/*
 * policy.h - the network-exception policy for the PLC side, enforced by the
 * gateway: when the PLC goes silent, the robot is paused or stopped as
 * configured, never left moving blind.
 *
 * The robot protects itself against losing the gateway
 * (set_network_exception_handle, sent by plc_commands.h on every connect);
 * it cannot see the PLC, whose loss leaves the robot's own link healthy.
 * This state machine watches the PLC:
 * - the heartbeat: the PLC changes holding register plc_heartbeat at least
 *   every time_limit_ms. The watch arms on the first change;
 * - the connection: at least one Modbus client connected (armed once one
 *   has connected);
 * - the motion-enable coil, when required: the PLC holds it at 1 for the
 *   robot to run (armed once it has been written 1); at 0 the program is
 *   paused at once.
 * Every signal is judged by one rule (lost_signals() in policy.c), as a
 * level, at every check period, at every write that changes one, and at
 * every command that would start motion: when a watched signal is lost
 * while the robot runs or may run, the action (keep: flag only; pause:
 * pause_program; stop: stop_program; always pause for motion enable) is
 * sent once and a fault is latched, visible on Modbus with its reason and
 * age. "May run" is what the status shows (moving, a program loading or
 * running, or a stale status: blind, the worst is assumed), and also a
 * start the gateway sent that the status cannot show yet
 * (policy_start_sent): until a status document received at least
 * POLICY_START_SETTLE_MS after its reply (the controller's status may lag
 * its reply by a few pushes), or start_unshown_max_ms after the reply at
 * most. A command that would start motion while
 * a signal is lost is refused, and counts as the robot about to run: the
 * fault is latched and the action sent, so a PLC that starts and drops
 * motion enable ends the same way in either order.
 * What the action is: the configured one (keep, pause, stop; motion
 * enable: pause) for a program. A move outside a program is not stopped
 * by pause_program (the manual, 4.23 (b): "stop_program can be used to
 * stop other robot move commands, such as joint_move/moveL"): whenever the
 * arm may be running one (the status shows it moving with no program
 * running, or the last start the gateway sent was a move and the status
 * cannot show it yet, or is stale), a pause becomes stop_program
 * (choose_action() in policy.c). Keep stays keep.
 * Then the action is checked, not assumed (struct policy's reaction): once
 * its reply came, a status document received after it must show the arm
 * still (in position, no program running, positions unchanged: the
 * sink's robot()) within one status period (the interval of the last
 * documents) after the reply. A real arm brakes: within stop_time_ms of
 * the reply (the robot's stopping time) and the one status period its
 * document of rest takes to come, an arm that moves no faster than
 * it did since the reply (the sink's step(): its largest joint change
 * from one document to the next) is stopping, and gets no second command;
 * one that speeds up, or still moves after stop_time_ms, gets stop_program
 * once more (POLICY_REACTION_ESCALATED), checked the same way: still
 * moving then is POLICY_REACTION_STILL_MOVING, latched until the reset.
 * A pause is never turned into a stop while its arm brakes. The reset is
 * refused while the reaction is still judged or the arm still moves
 * (policy_may_reset), so it can never cancel an escalation.
 * While a fault is latched, commands are refused, except stop and the
 * reset; the action is never repeated, except motion enable's pause, sent
 * once for each drop, and an action whose outcome is unknown (its
 * connection lost before its reply: policy_action_unknown). Only an explicit reset by the PLC clears it. A loss
 * while the robot is idle sends nothing and latches nothing.
 *
 * The gateway's own stall: the policy sees time only when the gateway's
 * loop turns (the check period, every input). A gap between two calls
 * longer than time_limit_ms means the gateway itself stood still (its
 * process stopped, starved of CPU, a blocking call; not a suspended host:
 * the monotonic clock stands still with it, and the robot's own handler
 * covers that): the PLC's signals
 * could not be read meanwhile, so the gap is not counted against them (the
 * heartbeat's and the connection's clocks move on by the gap) and the
 * stall is its own fault, POLICY_FAULT_GATEWAY_STALL, judged by the same
 * rule: while the robot runs or may run the action goes out and the fault
 * latches; idle, it is only reported (sink.on_stall, once per stall, with
 * its length). With check_period_ms set, it is judged at the next tick of
 * the check period, after the loop has read what waited in its sockets
 * (the status documents saying whether the robot ran; until then the
 * status looks stale), and a start command before then at once. A turn
 * late by less than the limit (more than two check periods) likewise
 * defers the heartbeat's and the connection's verdicts to that tick, for
 * the heartbeat waiting in a socket, once: a loss already due when the
 * late gap began is judged at once.
 *
 * Write ownership, when configured: the client that feeds the heartbeat
 * owns the write side; other clients' writes are refused (exception 01).
 * owner = connection (the default) keeps it to that one connection;
 * owner = host lets every connection from the owner's address and of its
 * transport write too, as a PLC that reads on one connection and writes
 * on another does, but only the owner's connection feeds the heartbeat
 * (policy_may_feed_heartbeat). Ownership passes only when the owner's
 * connection closes or its heartbeat expires.
 *
 * No motion without a heartbeat (require_heartbeat): until the heartbeat
 * has been seen changing, commands that start motion are refused, so a
 * PLC that never feeds it cannot run the robot unwatched.
 *
 * Pure logic: time comes in as arguments and the action goes out through
 * 'struct policy_sink', so every transition is unit-tested without a loop.
 */
#ifndef JAKAGW_POLICY_H
#define JAKAGW_POLICY_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "command.h"
#include "status.h"

/* How long after a start's reply a status document must arrive to show
 * whether the start ran. */
#define POLICY_START_SETTLE_MS 200

enum policy_action { POLICY_KEEP = 0, POLICY_PAUSE = 1, POLICY_STOP = 2 };

/* What the status shows the arm doing, as the policy's sink reads it. */
enum policy_robot {
    POLICY_ROBOT_UNKNOWN = 0, /* no fresh status: blind */
    POLICY_ROBOT_STILL = 1,   /* in position, no program running, positions unchanged */
    POLICY_ROBOT_PAUSED = 2,  /* a program paused, the arm still */
    POLICY_ROBOT_PROGRAM = 3, /* a program loading or running */
    POLICY_ROBOT_MOVING = 4,  /* the arm moving (not in position) with no program running */
};

/* What the robot did about the latched fault, as the PLC reads it (IR
 * network_exception.reaction). */
enum policy_reaction {
    POLICY_REACTION_NONE = 0,       /* no fault, or nothing was running */
    POLICY_REACTION_FLAG_ONLY = 1,  /* action keep: nothing sent */
    POLICY_REACTION_SENT = 2,       /* sent, its reply or the status awaited */
    POLICY_REACTION_PAUSED = 3,     /* a status after the reply shows a program paused */
    POLICY_REACTION_STOPPED = 4,    /* ... shows the arm still */
    POLICY_REACTION_ESCALATED = 5,  /* still moving: stop_program sent once more */
    POLICY_REACTION_STILL_MOVING = 6, /* still moving after that stop too */
};

/* The reaction's words, as the log and the page say them. */
const char *policy_reaction_name(enum policy_reaction reaction);

enum policy_watch {
    POLICY_WATCH_HEARTBEAT = 1,
    POLICY_WATCH_CONNECTION = 2,
    POLICY_WATCH_BOTH = 3,
};

/* The latched fault's reason, as the PLC reads it. */
enum policy_fault {
    POLICY_FAULT_NONE = 0,
    POLICY_FAULT_HEARTBEAT = 1,     /* the heartbeat stopped */
    POLICY_FAULT_NO_CLIENT = 2,     /* no Modbus client connected */
    POLICY_FAULT_MOTION_ENABLE = 3, /* the motion-enable coil dropped */
    POLICY_FAULT_GATEWAY_STALL = 4, /* the gateway's own loop stalled */
};

/* The reason's name, as the log, the page and the PLC guide say it. */
const char *policy_fault_name(enum policy_fault reason);

struct policy_config {
    uint32_t time_limit_ms;
    enum policy_action action;
    enum policy_watch watch;
    bool motion_enable;  /* the motion-enable coil is required */
    bool single_owner;   /* one write owner at a time */
    bool owner_by_connection; /* the owner is its connection, not its host */
    bool require_heartbeat;   /* no start before the heartbeat changed */
    /*
     * How long after its reply a start the gateway sent counts as "may
     * run" at most when no status document comes (0: 10 s). The gateway
     * sets status_timeout_ms: by then the status is judged stale, and
     * blind, the worst is assumed anyway.
     */
    uint32_t start_unshown_max_ms;
    /*
     * The caller's check period (0: none, every gap up to the limit
     * counts). A turn later than twice this, but within the limit, is a
     * late turn: the heartbeat and connection verdicts wait for a call at
     * a later time, after the turn's input has been read (see see_time).
     */
    uint32_t check_period_ms;
    /* The robot's stopping time: how long an arm slowing down after the
     * action's reply counts as stopping (0: one status period). */
    uint32_t stop_time_ms;
};

struct policy_sink {
    /*
     * Sends pause_program or stop_program; never called for KEEP. Returns
     * false when it could not be sent (the command link is down): the
     * action stays owed and is tried again every check while the robot
     * may move.
     */
    bool (*send_action)(void *user, enum policy_action action,
                        enum policy_fault reason);
    /* A stall of 'gap_ms' seen (optional): once per stall, before it is
     * judged. */
    void (*on_stall)(void *user, uint64_t gap_ms);
    /* What the status shows the arm doing now, from the last documents
     * (optional: NULL reads as POLICY_ROBOT_UNKNOWN). */
    enum policy_robot (*robot)(void *user);
    /* The arm's largest joint change between the last two documents, in
     * degrees; negative when unknown (optional: NULL, always unknown). */
    double (*step)(void *user);
    /* The reaction changed (optional): 'after_ms' since the action's reply. */
    void (*on_reaction)(void *user, enum policy_reaction reaction, enum policy_action sent,
                        uint64_t after_ms);
    void *user;
};

struct policy {
    struct policy_config cfg;
    struct policy_sink sink;
    /* The heartbeat. */
    bool heartbeat_armed;
    uint64_t heartbeat_ms; /* when it last changed */
    double heartbeat_value;
    bool heartbeat_changed; /* seen changing once (from the register's 0) */
    /* The connection. */
    unsigned clients;
    bool connection_armed;
    uint64_t no_client_since_ms;
    /* The motion-enable coil. */
    bool motion_enabled;
    bool motion_enable_armed;  /* written 1 once: from then on 0 is a loss */
    bool motion_enable_paused; /* this drop's pause went out (or is owed) */
    /* Starts the gateway sent that the status may not show yet. */
    unsigned starts_unanswered; /* sent or queued, no reply yet */
    bool start_unshown;         /* answered, no status document since */
    uint64_t start_answered_ms; /* the last reply */
    /* The gateway's own loop: when the policy last saw the time. */
    uint64_t last_seen_ms; /* 0: not yet */
    bool stall_pending;    /* a stall seen, not judged yet */
    uint64_t stalls;       /* seen, ever */
    uint64_t last_stall_ms; /* the last one's length */
    uint64_t late_turn_ms;  /* the last late turn (check_period_ms); 0: none */
    uint64_t late_turn_from_ms; /* the call before it: when its gap began */
    bool last_start_move; /* the last start sent was a move, not a program */
    /* The status stream's period: a decaying peak of its intervals. */
    uint64_t last_document_ms;
    uint64_t status_period_ms;
    /* The check of the last action sent (see the top). */
    enum policy_reaction reaction;
    enum policy_action reaction_action; /* the last action sent */
    bool reaction_answered;             /* its reply came */
    uint64_t reaction_answered_ms;
    double reaction_min_step; /* the smallest step() since the reply; < 0 none */
    bool reaction_refused;    /* the robot refused the action */
    bool reaction_lost;       /* not sent, or lost with its link: no reply comes */
    /* The latched fault. */
    enum policy_fault fault;
    uint64_t fault_since_ms;
    enum policy_action owed; /* an action not sent yet; KEEP: none */
    uint64_t faults; /* latched, ever */
    /* The write owner: 0 none. Its address and port as the PLC reads
     * them (IR 66), and its address alone (owner = host). */
    uint64_t owner;
    char owner_address[64];
    char owner_host[64];
    char owner_transport[16]; /* "modbus", "tls", "rtu": its transport */
};

/* The PLC heartbeat as the PLC reads it (IR 5603). */
enum policy_heartbeat_state {
    POLICY_HEARTBEAT_NEVER = 0,   /* never seen changing */
    POLICY_HEARTBEAT_RUNNING = 1,
    POLICY_HEARTBEAT_LOST = 2,    /* no change within time_limit_ms */
};

void policy_init(struct policy *p, const struct policy_config *cfg,
                 const struct policy_sink *sink);

/*
 * May connection 'client', at 'peer' ("address:port", NULL unknown), write?
 * 0, or exception 01 when another PLC owns the write side: with owner =
 * host any connection from the owner's address may. Call before every
 * write. policy_may_write() is the same with the peer unknown (only the
 * owner's own connection may).
 */
int policy_may_write_from(const struct policy *p, uint64_t client, const char *peer);
int policy_may_write(const struct policy *p, uint64_t client);

/*
 * policy_may_write_from() for a connection of 'transport' (the server's
 * name for it: "modbus", "tls"; NULL unknown): with owner = host, only a
 * connection of the owner's own transport shares its rights, so a plain
 * client on the address of a TLS owner never does.
 */
int policy_may_write_via(const struct policy *p, uint64_t client, const char *peer,
                         const char *transport);

/*
 * May connection 'client' write the heartbeat? Only the owner's connection
 * feeds it (0, or exception 01): with owner = host another program on the
 * PLC's host could otherwise keep it alive while the PLC is halted.
 */
int policy_may_feed_heartbeat(const struct policy *p, uint64_t client);

/* The owner's transport, recorded when connection 'client' fed the
 * heartbeat and owns the write side. */
void policy_owner_transport(struct policy *p, uint64_t client, const char *transport);

/* A write to plc_heartbeat by connection 'client', at 'address'
 * ("address:port", as the write owner is shown). */
void policy_heartbeat(struct policy *p, uint64_t now_ms, uint64_t client,
                      const char *address, double value);

/* The heartbeat: never seen changing, running, or lost. */
enum policy_heartbeat_state policy_heartbeat_state(const struct policy *p, uint64_t now_ms);

/* Modbus clients: one connected, or one gone ('clients' counts the rest). */
void policy_client_opened(struct policy *p, uint64_t now_ms, unsigned clients);
void policy_client_closed(struct policy *p, uint64_t now_ms, uint64_t client,
                          unsigned clients);

/*
 * A write to the motion-enable coil. The first 1 arms it. At 0 (armed)
 * while the robot runs or may run: pause at once, even with another fault
 * latched (which it then keeps); the pause goes out once per drop.
 */
void policy_motion_enable(struct policy *p, uint64_t now_ms, bool value,
                          bool robot_moving);

/*
 * A command that starts motion (CMD_STARTS_MOTION, CMD_MOTION, or a name
 * the table does not know) was sent or queued for a PLC; and its reply
 * came, or it failed (any outcome: a timeout or a dropped link leaves its
 * fate unknown). From the first until a status document received after
 * the last reply (policy_status_document), the robot may run whatever the
 * status says: while one is unanswered (the command queue answers every
 * one in bounded time), then start_unshown_max_ms after the reply at most.
 */
void policy_start_sent(struct policy *p, uint64_t now_ms);
/*
 * What the start sent last is: a move outside a program (true: any motion
 * command) or a program's start (play_program, resume_program). Call with
 * policy_start_sent.
 */
void policy_start_kind(struct policy *p, bool move);
void policy_start_answered(struct policy *p, uint64_t now_ms);
void policy_status_document(struct policy *p, uint64_t now_ms);
/* Is a start sent that the status cannot show yet? */
bool policy_start_unshown(const struct policy *p, uint64_t now_ms);

/*
 * The action sent for the latched fault ended with its outcome unknown (no
 * reply in time, or the command link lost before it): reset with its
 * connection, the robot may never have had it. It is owed again, and goes
 * out at the next check while the robot runs or may run (a pause sent twice
 * is harmless; a robot left running with its PLC gone is not). Nothing
 * without a latched fault.
 */
void policy_action_unknown(struct policy *p, enum policy_action action);

/*
 * The action the policy sent got its reply (any outcome but unknown, which
 * is policy_action_unknown): the status is judged from now on (see the
 * top). 'accepted': errorCode 0; a refused action brakes nothing, so it
 * gets no stopping time.
 */
void policy_action_answered(struct policy *p, uint64_t now_ms, bool accepted);

/* The status period the reaction's check allows (ms; 0 before two
 * documents). */
uint64_t policy_status_period_ms(const struct policy *p);

/*
 * May the PLC reset the latched fault now? 0, or -EBUSY with the reason in
 * 'why' (a result's 40 bytes) while the action's reaction is still judged
 * (sent, or escalated, no status yet showing the arm still) or, an action
 * having been sent, the status shows the arm moving: a reset then would
 * cancel the check, and with it a second stop the arm may still need.
 */
int policy_may_reset(const struct policy *p, char *why, size_t why_size);

/* The PLC's reset: clears the latched fault. */
void policy_reset(struct policy *p);

/*
 * Re-evaluates: call every check period and after any input. 'robot_moving'
 * is true while the robot moves or a program runs, or while the status is
 * stale and the gateway cannot tell (policy_robot_may_move); a start not
 * shown yet (policy_start_unshown) is added here.
 */
void policy_check(struct policy *p, uint64_t now_ms, bool robot_moving);

/*
 * Are commands that start motion refused now: a latched fault, or the
 * motion-enable coil required and at 0? (Other commands are refused only
 * by a latched fault, and stop_program never.)
 */
bool policy_blocks_commands(const struct policy *p);

/*
 * Does the robot move or run a program, as far as the gateway can tell?
 * True while a program loads or runs (interp_state 1 or 3), while the arm
 * reports it is not in position (inpos 0), and whenever the status is
 * stale ('status_fresh' false) or absent: blind, the worst is assumed.
 */
bool policy_robot_may_move(bool status_fresh, const struct jaka_status *status);

/*
 * The policy's say on a command about to be sent for a PLC: 0, or
 * exception 01 with the reason in 'why'. stop_program always passes; a
 * latched fault refuses everything else; with require_heartbeat, a start
 * before the heartbeat was seen changing ("heartbeat not started"); with
 * the motion-enable coil
 * required and at 0, motion and program starts are refused. A start while
 * a watched signal is lost (the heartbeat expired, motion enable dropped
 * after it was armed) is refused and latches that fault, sending its
 * action: the PLC asked the robot to run without the signal. 'def' NULL (a
 * name the command table does not know) is judged as motion.
 */
int policy_gate_command(struct policy *p, uint64_t now_ms, const struct cmd_def *def,
                        char *why, size_t size);

/* Does 'def' start motion (NULL, unknown: judged as motion)? */
bool policy_command_starts_motion(const struct cmd_def *def);

/* Milliseconds since the fault latched; 0 when none. */
uint64_t policy_fault_age_ms(const struct policy *p, uint64_t now_ms);

#endif
