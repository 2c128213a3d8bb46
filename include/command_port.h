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

struct command_port {
    uv_loop_t *loop;
    struct robot_link link;
    struct cmd_queue queue;
    uv_timer_t timer; /* the reply timeout of the command in flight */
    struct log_ratelimit unsolicited_log;
    /* The link came up or went down (after the queue has been told). */
    void (*on_state)(struct command_port *cp, enum robot_link_state state);
    void *user;
    int open_parts;
    void (*close_cb)(struct command_port *cp);
};

/* Returns 0 or a negative errno. */
int command_port_init(uv_loop_t *loop, struct command_port *cp,
                      const struct robot_link_config *link_cfg,
                      uint32_t reply_timeout_ms,
                      void (*on_state)(struct command_port *cp,
                                       enum robot_link_state state),
                      void *user);

int command_port_start(struct command_port *cp);

/* Fails whatever is queued, closes; 'cb' runs when all is closed. */
void command_port_close(struct command_port *cp, void (*cb)(struct command_port *cp));

#endif
