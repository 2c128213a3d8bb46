/* SPDX-License-Identifier: MIT */
/*
 * command.h - commands to the robot's command port (10001).
 *
 * The command table names every command the gateway sends on a PLC's
 * behalf, with what it needs (motion permission, the shutdown switch) and
 * its code in the exactly-once mailbox.
 *
 * The queue sends commands one at a time, in the order accepted, and
 * matches each reply to the command in flight by order, never by name:
 * real controllers answer some commands without a cmdName, and the manual
 * answers stop_program as "pause_program". A reply means "accepted", not
 * "finished". Rules that keep a command from running twice or being
 * answered by the wrong reply:
 * - nothing is ever resent: a command whose reply does not come within
 *   the timeout fails, and the connection is restarted (through
 *   ops.restart_link), so its late reply can never be taken for the next
 *   command's;
 * - when the link goes down, every command fails: one already written
 *   with its outcome unknown (CMD_TIMEOUT, CMD_LINK_DOWN: the robot may
 *   have acted on it), one never written as not sent (CMD_NOT_SENT: the
 *   robot never received it); nothing is sent after a reconnect that was
 *   accepted before it;
 * - while the link is down, nothing is accepted (-ENOTCONN).
 *
 * The link check (cmd_queue_submit_check) is an entry of the queue like
 * any other, so its reply is matched by order and never taken for a PLC
 * command's; it is accepted only into an empty queue (never while a
 * command is in flight), and a command submitted while it is in flight is
 * written at once behind it (pipelined), so a check never delays one; the
 * check's short bound then grows to that command's reply timeout, from
 * the command's send, so a check never cuts one short either.
 *
 * Time and I/O reach the queue through 'struct cmd_ops', so its rules are
 * unit-tested with a fake clock and a fake link.
 */
#ifndef JAKAGW_COMMAND_H
#define JAKAGW_COMMAND_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

enum cmd_flags {
    CMD_MOTION = 1,   /* moves the robot: only with [commands] motion = true */
    CMD_SHUTDOWN = 2, /* only with [commands] allow_shutdown = true */
    CMD_STARTS_MOTION = 4, /* starts a program: the robot may move */
    CMD_HALTS = 8, /* pauses or stops the robot: written at once, ahead of
                      queued commands, and allowed before the robot has
                      accepted its network-exception handler */
};

struct cmd_def {
    const char *name; /* cmdName */
    unsigned flags;
    uint16_t code; /* in the exactly-once mailbox; 0: not offered there */
    /* Information to fetch again once it has been accepted ("" none). */
    const char *refresh;
    /*
     * The exactly-once mailbox's arguments, in order: JSON member names;
     * "name[N]" takes N arguments into an array; a '#' suffix marks a
     * whole number; a '$' suffix a text taken from the command's own text
     * registers ("cmd:<cmdName>.<name>") instead of an argument.
     */
    const char *mailbox_args;
};

extern const struct cmd_def cmd_table[];
extern const unsigned cmd_table_count;

/* The command named 'name' (a space may stand for an underscore), or NULL. */
const struct cmd_def *cmd_find(const char *name);
/* The command with mailbox code 'code', or NULL. */
const struct cmd_def *cmd_find_code(unsigned code);

/* What became of a command; the values PLCs read in the state registers. */
enum cmd_outcome {
    CMD_IDLE = 0,        /* never sent */
    CMD_PENDING = 1,     /* sent or queued, no reply yet */
    CMD_DONE = 2,        /* the robot accepted it (errorCode 0) */
    CMD_ROBOT_ERROR = 3, /* the robot refused it: see error_code, error_msg */
    CMD_TIMEOUT = 4,     /* written, no reply within the timeout: outcome unknown */
    CMD_LINK_DOWN = 5,   /* written, the link went down before its reply:
                            outcome unknown */
    CMD_INVALID = 6,     /* refused by validation, nothing sent */
    CMD_REFUSED = 7,     /* not allowed now (configuration, state), nothing sent */
    CMD_NOT_SENT = 8,    /* accepted but never written (the link was down or
                            went down, a fault dropped the queue, a safety
                            action took its place): the robot never got it */
};

const char *cmd_outcome_name(enum cmd_outcome outcome);

/* A command's result, as the done callback sees it. */
struct cmd_result {
    enum cmd_outcome outcome;
    long error_code;     /* the robot's errorCode (CMD_DONE, CMD_ROBOT_ERROR) */
    char error_msg[128]; /* the robot's errorMsg, or the gateway's reason */
    const char *reply;   /* the whole reply (valid during the callback), or NULL */
    size_t reply_size;
    /* When it was written to the robot (ops.now_ms), 0: never written. A
     * command the robot starts on receipt (a move) began then, not when
     * its reply came nor when it was queued. */
    uint64_t sent_at_ms;
};

typedef void (*cmd_done_cb)(void *user, const struct cmd_result *result);

/* Parses a reply: errorCode as text ("0", "-1") or number, errorMsg. */
void cmd_parse_reply(const char *json, size_t size, struct cmd_result *result);

struct cmd_ops {
    /* Queues bytes to the robot; 0 or a negative errno. */
    int (*send)(void *io, const char *data, size_t size);
    /* Milliseconds from any fixed point. */
    uint64_t (*now_ms)(void *io);
    /* Drops the connection abortively (it reconnects by itself). */
    void (*restart_link)(void *io, const char *why);
    /* A command went out: its reply's deadline starts (may be NULL). */
    void (*sent)(void *io);
    void *io;
};

#define CMD_QUEUE_CAPACITY 64

struct cmd_entry {
    char *json;
    size_t size;
    cmd_done_cb done;
    void *user;
    bool sent;           /* written already (the head, or an urgent one) */
    bool check;          /* the gateway's link check (cmd_queue_submit_check) */
    bool moves;          /* can start or continue motion (cmd_queue_submit_urgent) */
    uint32_t timeout_ms; /* its reply's deadline; 0: the queue's */
    uint64_t sent_at_ms;
};

struct cmd_queue_stats {
    uint64_t sent;
    uint64_t replies;
    uint64_t robot_errors;
    uint64_t timeouts;
    uint64_t failed_link_down; /* written, then the link went down */
    uint64_t not_sent;         /* accepted, never written */
    uint64_t unsolicited;
    uint64_t checks;        /* link checks written */
    uint64_t checks_failed; /* link checks unanswered within their bound */
};

struct cmd_queue {
    struct cmd_ops ops;
    uint32_t timeout_ms;
    bool connected;
    struct cmd_entry entries[CMD_QUEUE_CAPACITY]; /* [head] is in flight */
    unsigned head, count;
    bool in_flight;
    uint64_t sent_at_ms;
    uint32_t flight_timeout_ms; /* the deadline of the one in flight */
    struct cmd_queue_stats stats;
};

void cmd_queue_init(struct cmd_queue *q, const struct cmd_ops *ops,
                    uint32_t timeout_ms);

/* Fails whatever is queued (CMD_LINK_DOWN if written, else CMD_NOT_SENT)
 * and frees it. */
void cmd_queue_free(struct cmd_queue *q);

/*
 * Accepts a complete JSON command. 'done' runs exactly once, with the
 * result, and never from inside this call. Returns 0, -ENOTCONN while the
 * link is down, -EBUSY when the queue is full, -ENOMEM.
 */
int cmd_queue_submit(struct cmd_queue *q, const char *json, size_t size,
                     cmd_done_cb done, void *user);

/* The same for a command built from the table entry 'def' (its cmdName is
 * def->name): whether it moves is read from def, not from the text. */
int cmd_queue_submit_def(struct cmd_queue *q, const struct cmd_def *def, const char *json,
                         size_t size, cmd_done_cb done, void *user);

/*
 * Accepts a safety action (pause_program, stop_program) and writes it at
 * once, even while another command waits for its reply: it goes right
 * behind the commands already written, and its reply is matched in that
 * order (the controller answers in order). It owns the queue: every
 * command not written yet that can start or continue motion (CMD_MOTION,
 * CMD_STARTS_MOTION, or a name the table does not know) is taken out and
 * fails CMD_NOT_SENT, "not sent: a safety action took its place", so
 * nothing that moves the arm reaches the robot after the action; the
 * rest stays queued behind it. At capacity, the last queued command that
 * is not written yet fails (CMD_NOT_SENT) to make room. Those callbacks
 * run once the action is written, never when it fails. Returns 0,
 * -ENOTCONN, -EBUSY when every queued command is written already, -ENOMEM,
 * or the send's error (then nothing changed).
 */
int cmd_queue_submit_urgent(struct cmd_queue *q, const char *json, size_t size,
                            cmd_done_cb done, void *user);

/*
 * The link check: writes 'json' (a harmless query) at once, if the queue is
 * empty; its reply must come within 'timeout_ms' (0: the queue's), or it
 * fails as CMD_TIMEOUT and the link is restarted like after any reply
 * timeout. Commands submitted while it is in flight are written at once
 * behind it, and its deadline becomes the latest of theirs (each command's
 * send plus the queue's timeout) if that is later. Returns 0, -ENOTCONN, -EBUSY when anything is queued or in
 * flight (the link is in use: no check needed), -ENOMEM, or the send's
 * error (then nothing changed).
 */
int cmd_queue_submit_check(struct cmd_queue *q, const char *json, size_t size,
                           uint32_t timeout_ms, cmd_done_cb done, void *user);

/* The command link came up or went down. */
void cmd_queue_set_connected(struct cmd_queue *q, bool connected);

/* One complete JSON object from the command port. */
void cmd_queue_on_reply(struct cmd_queue *q, const char *json, size_t size);

/* Fails the command in flight if its reply is late. Call on a timer. */
void cmd_queue_check_timeout(struct cmd_queue *q);

/* Milliseconds until the command in flight times out; UINT64_MAX if none. */
uint64_t cmd_queue_next_deadline_ms(const struct cmd_queue *q);

/* Commands accepted and not finished (in flight and queued). */
unsigned cmd_queue_pending(const struct cmd_queue *q);

#endif
