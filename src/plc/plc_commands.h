/* SPDX-License-Identifier: MIT */
/*
 * plc_commands.h - what PLC writes do to the robot: the command rows of the
 * register map, bound to the command queue (command.h).
 *
 * Three ways for a PLC to command the robot, all rows of the register map:
 * - a trigger coil per command ("cmd:<cmdName>"): a 0 -> 1 write sends the
 *   command with the parameters in its holding registers
 *   ("cmd:<cmdName>.<param>"). A write of 1 onto a trigger that reads 1
 *   is, from the connection that set it, a retransmission (answered, nothing
 *   sent); from any other connection (a restarted PLC, a reconnect) it is
 *   refused, 01 "trigger still 1: write 0 first": nothing is ever sent
 *   twice because a connection dropped and came back, and nothing is
 *   answered OK with nothing to show for it. A motion trigger whose
 *   parameters were not all written since start (or whose last write was
 *   refused) is refused, 03 "target not written". Setpoint rows (rapid
 *   rate, digital and analog outputs, tool and user frame, collision
 *   level) send their command each time they are written, but for an
 *   output written again with its level (output_readback.h). Each command's
 *   result is readable: "gw:result.<cmdName>.state", ".error_code",
 *   ".error_msg", and ".count", which changes with every trigger handled
 *   whatever its outcome: a PLC reads it before its trigger and waits for
 *   it to change, so it never takes an older result for its own;
 * - the exactly-once mailbox ("gw:mailbox.*"): the PLC writes code,
 *   arguments and sequence number last in one write; a new sequence number
 *   runs the command once, its echo in ack_seq at once and in done_seq
 *   with the result; the same number again does nothing. A new sequence
 *   number without the code and the arguments in the same write is
 *   refused, 03 "write code, args and seq in one write" (they could be
 *   another command's). mailbox.count changes with every new number;
 * - the JSON mailbox ("gw:json.*"): any Chapter-4 command as text; its
 *   trigger follows the trigger coils' rule, json.count counts them, and a
 *   refusal clears the previous reply.
 * Writes are checked before anything is sent, and refused with a Modbus
 * exception (the reason, at most 40 bytes, in the result's error_msg): 01
 * not permitted by the configuration (motion, shutdown,
 * read-only, client not allowed to write), 03 an invalid value or command,
 * 06 the same command (or mailbox) is still pending, 0B the command link
 * is down. Nothing refused is ever sent or queued.
 *
 * The module also keeps the robot information the status stream lacks
 * ("gw:info.*"): fetched on every connect and after commands that change it.
 */
#ifndef JAKAGW_PLC_COMMANDS_H
#define JAKAGW_PLC_COMMANDS_H

#include <stdbool.h>
#include <stdint.h>

#include "audit.h"
#include "command.h"
#include "log.h"
#include "output_readback.h"
#include "param_rows.h"
#include "regmap.h"

#define PLC_MAX_COMMANDS 96

struct plc_commands_config {
    bool motion;         /* motion commands allowed */
    bool allow_shutdown; /* the shutdown command allowed */
    /* The robot's own network-exception handler, set on every connect. */
    bool robot_handle;          /* send set_network_exception_handle */
    uint32_t robot_time_limit_ms;
    unsigned robot_mot_type;    /* 0 keep, 1 pause, 2 stop */
    bool require_robot_handle;  /* commands refused until it is accepted */
    /*
     * Another say on every command (the network-exception policy): 0, or
     * the exception that refuses it, with the reason in 'why'. 'def' is
     * NULL for a JSON mailbox command the table does not know (let through
     * only with motion on), which must be judged as motion.
     */
    int (*gate)(void *user, const struct cmd_def *def, char *why, size_t size);
    void *gate_user;
    /*
     * A command that starts motion (policy_command_starts_motion) was
     * sent or queued for a PLC; its result came (any outcome). Called
     * with 'gate_user'; either may be NULL.
     */
    void (*start_sent)(void *user);
    void (*start_answered)(void *user);
    /*
     * A command sent by plc_commands_send_now ended with its outcome
     * unknown (CMD_TIMEOUT, CMD_LINK_DOWN: written, no reply; the robot
     * may never have had it). Called with 'gate_user'; may be NULL.
     */
    void (*own_unknown)(void *user, const struct cmd_def *def);
    /*
     * Every command sent for a PLC, as its JSON text ('def' NULL: a name
     * the table does not know); every result of a command or mailbox
     * (any outcome); every result of a command plc_commands_send_now sent.
     * For the motion tracker and the policy's check of its own action.
     * 'tag' says whose: the same for a command's send and its result, and
     * never shared by two commands pending at once. Called with
     * 'gate_user'; each may be NULL.
     */
    void (*sent)(void *user, const struct cmd_def *def, const char *json, const void *tag);
    void (*answered)(void *user, const struct cmd_def *def, const void *tag,
                     const struct cmd_result *r);
    void (*own_answered)(void *user, const struct cmd_def *def, const struct cmd_result *r);
    /* The audit trail: every command sent and its result (NULL: none). */
    struct audit *audit;
};

/* The robot's network-exception handler, as the PLC reads it. */
enum plc_handle_state {
    PLC_HANDLE_NOT_SENT = 0, /* no command link yet, or not configured */
    PLC_HANDLE_PENDING = 1,
    PLC_HANDLE_ACCEPTED = 2,
    PLC_HANDLE_FAILED = 3, /* refused or unanswered: a fault, shown until
                              the robot accepts it on a later connection */
};

enum plc_slot_kind {
    PLC_SLOT_COMMAND,
    PLC_SLOT_MAILBOX,
    PLC_SLOT_JSON,
    PLC_SLOT_INFO,
    PLC_SLOT_HANDLE,
};

/* Where the results of one command (or mailbox) show. */
struct plc_slot {
    struct plc_commands *pc;
    enum plc_slot_kind kind;
    const struct cmd_def *def; /* PLC_SLOT_COMMAND, PLC_SLOT_INFO */
    const struct regmap_row *state, *error_code, *error_msg, *count;
    uint64_t trigger_by;       /* the connection that set its trigger to 1 */
    unsigned pending;
    unsigned starts_pending;   /* of them, commands that start motion */
    /* Of them, those whose result a later request's refusal replaced: a
     * PLC reads the result of the request that moved the count. */
    unsigned superseded;
    bool failed;               /* a failure among the pending ones */
    struct cmd_result failure; /* the first of them */
};

#define PLC_INFO_COMMANDS 8

struct plc_commands {
    struct regmap_image *img;
    struct cmd_queue *queue;
    struct plc_commands_config cfg;
    struct plc_slot slots[PLC_MAX_COMMANDS]; /* by cmd_table index */
    struct plc_slot mailbox;
    struct plc_slot json;
    struct plc_slot info[PLC_INFO_COMMANDS];
    struct plc_slot handle;
    enum plc_handle_state handle_state;
    const struct regmap_row *handle_row;
    /* The commands the write being judged would send, built by the check
     * and sent, in order, by the apply: each is built once. */
    struct plc_staged {
        char *json;
        const struct cmd_def *def;
    } staged_cmds[CMD_QUEUE_CAPACITY];
    unsigned staged, applied;
    /* The write being judged: who writes, and all it sets. */
    uint64_t writer;
    const struct regmap_written *write_elements;
    unsigned write_element_count;
    /* The commands' parameter rows: their spans, and the elements written
     * since start and not refused since. */
    struct param_rows params;
    /* Per row of the map: the command a command row ("<cmdName>" or
     * "<cmdName>.<param>") belongs to, found once at init; NULL for others. */
    const struct cmd_def **row_cmd;
    /* The outputs' read-back: when writing a level again sends nothing. */
    struct output_readback outputs;
    bool sending_frequent; /* the command being sent is a setpoint's */
    struct log_ratelimit refuse_log_limit;
    char refusal[96]; /* why the last plc_commands_check refused */
    const struct regmap_row *mailbox_ack, *mailbox_done, *mailbox_code,
        *mailbox_arg;
    const struct regmap_row *json_request, *json_reply, *json_truncated,
        *json_length;
    const struct regmap_row *json_trigger;
    const struct regmap_row *info_age;
    uint64_t info_updated_ms; /* 0: never */
    uint64_t (*now_ms)(void *clock);
    void *clock;
};

/*
 * Finds the rows and prepares the slots. Returns 0, -EINVAL when the
 * register map lacks a row this module needs (a programming error), or
 * -ENOMEM.
 */
int plc_commands_init(struct plc_commands *pc, struct regmap_image *img,
                      struct cmd_queue *queue, const struct plc_commands_config *cfg,
                      uint64_t (*now_ms)(void *clock), void *clock);
void plc_commands_free(struct plc_commands *pc);

/*
 * Starts checking a new write (phase 1 below) by connection 'writer' (the
 * Modbus server's client id), which sets 'elements' (all of them, decoded;
 * they stay valid until plc_commands_discard).
 */
void plc_commands_begin(struct plc_commands *pc, uint64_t writer,
                        const struct regmap_written *elements, unsigned count);

/*
 * A write to 'count' registers of 'table' from 'address' was refused
 * (whatever refused it): the parameters it held count as not written, so
 * a motion trigger cannot send the values the PLC meant to replace.
 */
void plc_commands_write_refused(struct plc_commands *pc, enum regmap_table table,
                                unsigned address, unsigned count);

/*
 * Phase 1 of a write, for each element it sets, with the new values already
 * in the image: returns 0 or the exception code that refuses the write (04
 * when memory ran out: nothing is sent then either). The command is built
 * here, once, and kept for phase 2.
 */
int plc_commands_check(struct plc_commands *pc, const struct regmap_written *w);
/* Why the last plc_commands_check() refused, in the words its result
 * registers show ("" none said). */
const char *plc_commands_refusal(const struct plc_commands *pc);
/* Phase 2, once every element passed, for the same elements in the same
 * order: sends what phase 1 built. */
void plc_commands_apply(struct plc_commands *pc, const struct regmap_written *w);
/* Ends a write: frees what phase 1 built and phase 2 did not send (all of
 * it when the write was refused). */
void plc_commands_discard(struct plc_commands *pc);

/*
 * The command link came up: set the robot's network-exception handler
 * first, then fetch the robot information. Or it went down.
 */
void plc_commands_link_up(struct plc_commands *pc);
void plc_commands_link_down(struct plc_commands *pc);

/*
 * Sends 'name' (pause_program or stop_program) for the gateway itself,
 * past every gate; its result shows as the command's, and an outcome
 * unknown is also told to cfg.own_unknown. Returns 0 or a negative errno
 * (-ENOTCONN: the command link is down).
 */
int plc_commands_send_now(struct plc_commands *pc, const char *name);

/*
 * The link check's reply (command_port.h): what it says about the robot
 * (get_robot_state: enabled, powered on) is shown in the information rows.
 * 'name' is the query's cmdName. The information's age is not changed: the
 * check refreshes only these rows.
 */
void plc_commands_link_check_reply(struct plc_commands *pc, const char *name,
                                   const struct cmd_result *r);

/* Refreshes the values that change with time (the information's age). */
void plc_commands_refresh(struct plc_commands *pc);

#endif
