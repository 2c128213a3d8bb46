/* SPDX-License-Identifier: MIT */
/*
 * command_port.h - everything about the robot's command port (10001): the
 * connection (robot_link.h), the command queue on it (command.h), and the
 * timer that enforces the reply timeout.
 *
 * The gateway is the only client of port 10001, as JAKA requires. Replies
 * are framed like the status stream, so a reply larger than one read (such
 * as get_data's whole status) arrives whole.
 *
 * The link check: a command link idle for link_check_ms (no command queued
 * or in flight, nothing received) is checked with a harmless query the
 * controller answers, COMMAND_PORT_CHECK_QUERY. It goes through the queue
 * as an entry of the gateway's own, so its reply is matched by order and
 * never taken for a PLC command's; a PLC command submitted while it is in
 * flight is written at once behind it. Its reply must come within
 * min(reply_timeout_ms, link_check_ms) (with a command written behind it,
 * within that command's reply timeout from its send), or the link is
 * restarted (abortively) and reads down. With the defaults (1000, 2000) a silently
 * dead idle link reads down within link_check_ms + 1000 ms = 2 s.
 *
 * While a move of ours runs (hooks.move_running says so), the idle link is
 * checked COMMAND_PORT_MOVING_CHECKS times as often, so that a link gone
 * silent under a moving arm is found within link_check_ms /
 * COMMAND_PORT_MOVING_CHECKS + min(reply_timeout_ms, link_check_ms): 1.25 s
 * with the defaults, where the moves' own time bounds run to many seconds.
 * The reply's bound stays as it is: a loaded controller is not taken for a
 * dead one any sooner. The period is chosen each time an idle period
 * starts (after each reply), so it follows the move without a call.
 *
 * The link reads "answering" (command_port_answering) once a reply has
 * come on the connection: a controller that accepts connections while its
 * command server hangs never reads as up.
 *
 * Life cycle, as libuv handles: command_port_init(), command_port_start(),
 * command_port_close(cb); the memory is the caller's until cb runs.
 */
#ifndef JAKAGW_COMMAND_PORT_H
#define JAKAGW_COMMAND_PORT_H

#include <stdbool.h>
#include <uv.h>

#include "command.h"
#include "log.h"
#include "robot_link.h"

#define COMMAND_PORT_CHECK_QUERY "get_robot_state"
/* How many times as often the idle link is checked while a move runs. */
#define COMMAND_PORT_MOVING_CHECKS 4

struct command_port;

struct command_port_hooks {
    /* The link came up or went down (after the queue has been told). */
    void (*on_state)(struct command_port *cp, enum robot_link_state state);
    /* command_port_answering() changed (may be NULL). */
    void (*on_answering)(struct command_port *cp, bool answering);
    /* A link check was answered: 'r' holds the reply (may be NULL). */
    void (*on_check_reply)(struct command_port *cp, const char *query,
                           const struct cmd_result *r);
    /* Whether a move the gateway sent may be running now (may be NULL:
     * never). Asked whenever an idle period starts. */
    bool (*move_running)(struct command_port *cp);
    void *user;
};

struct command_port {
    uv_loop_t *loop;
    struct robot_link link;
    struct cmd_queue queue;
    uv_timer_t timer;       /* the reply timeout of the command in flight */
    uv_timer_t check_timer; /* link_check_ms of idleness */
    uint32_t link_check_ms; /* 0: no link check */
    bool answering;         /* a reply came on this connection */
    struct log_ratelimit unsolicited_log;
    struct command_port_hooks hooks;
    void *user;
    int open_parts;
    void (*close_cb)(struct command_port *cp);
};

/*
 * link_check_ms: 0, or how long the link may be idle before it is checked
 * (it may be changed later, from the next idle period). Returns 0 or a
 * negative errno.
 */
int command_port_init(uv_loop_t *loop, struct command_port *cp,
                      const struct robot_link_config *link_cfg,
                      uint32_t reply_timeout_ms, uint32_t link_check_ms,
                      const struct command_port_hooks *hooks);

/*
 * A new link_check_ms (on reload; 0: no check): an idle period under way
 * starts again at the new value, from now.
 */
void command_port_set_link_check(struct command_port *cp, uint32_t link_check_ms);

/* Connected, and the controller has answered on this connection. */
bool command_port_answering(const struct command_port *cp);

/* The command link's state as PLCs read it: 0 disconnected, 1 connecting,
 * 2 connected and answering, 3 connected, no reply yet. */
unsigned command_port_state(const struct command_port *cp);

int command_port_start(struct command_port *cp);

/* Fails whatever is queued, closes; 'cb' runs when all is closed. */
void command_port_close(struct command_port *cp, void (*cb)(struct command_port *cp));

#endif
