/* SPDX-License-Identifier: MIT */
/* command_port.c - see command_port.h. */
#include "command_port.h"

#include "log.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

static int send_bytes(void *io, const char *data, size_t size)
{
    struct command_port *cp = io;
    return robot_link_send(&cp->link, data, size);
}

static uint64_t now_ms(void *io)
{
    struct command_port *cp = io;
    uv_update_time(cp->loop);
    return uv_now(cp->loop);
}

static void restart_link(void *io, const char *why)
{
    struct command_port *cp = io;
    robot_link_restart(&cp->link, why);
}

static void on_timer(uv_timer_t *t);

/* Arms the timer for the command in flight, if any. */
static void arm_timer(struct command_port *cp)
{
    uint64_t left = cmd_queue_next_deadline_ms(&cp->queue);
    if (left == UINT64_MAX)
        uv_timer_stop(&cp->timer);
    else
        uv_timer_start(&cp->timer, on_timer, left, 0);
}

static void on_timer(uv_timer_t *t)
{
    struct command_port *cp = t->data;
    cmd_queue_check_timeout(&cp->queue);
    arm_timer(cp);
}

static void on_sent(void *io)
{
    arm_timer(io);
}

static void on_check_timer(uv_timer_t *t);

/* How long the link may be idle before it is checked: shorter while a
 * move runs, so that a cut under a moving arm is found within the link's
 * bound, not the move's. */
static uint32_t idle_period_ms(struct command_port *cp)
{
    if (cp->hooks.move_running && cp->hooks.move_running(cp)) {
        uint32_t period = cp->link_check_ms / COMMAND_PORT_MOVING_CHECKS;
        return period > 0 ? period : 1;
    }
    return cp->link_check_ms;
}

/* Idle from now: the link is checked after the idle period unless
 * something arrives or is sent before. */
static void arm_check(struct command_port *cp)
{
    if (cp->link_check_ms == 0 || !cp->queue.connected)
        uv_timer_stop(&cp->check_timer);
    else
        uv_timer_start(&cp->check_timer, on_check_timer, idle_period_ms(cp), 0);
}

void command_port_set_link_check(struct command_port *cp, uint32_t link_check_ms)
{
    cp->link_check_ms = link_check_ms;
    /* Waiting out an idle period at the old value: it starts again at the
     * new one, so a shorter value bounds detection from now, not after an
     * old period of up to a minute. A check in flight or a command keeps
     * its own deadline; the new value applies from the next idle period. */
    if (uv_is_active((uv_handle_t *)&cp->check_timer) || link_check_ms == 0)
        arm_check(cp);
}

static void on_check_done(void *user, const struct cmd_result *r)
{
    struct command_port *cp = user;

    /* A robot error still proves that the command server answers. An
     * unanswered check has restarted the link already (command.c). */
    if ((r->outcome == CMD_DONE || r->outcome == CMD_ROBOT_ERROR) && cp->hooks.on_check_reply)
        cp->hooks.on_check_reply(cp, COMMAND_PORT_CHECK_QUERY, r);
}

static void on_check_timer(uv_timer_t *t)
{
    struct command_port *cp = t->data;
    static const char query[] = "{\"cmdName\":\"" COMMAND_PORT_CHECK_QUERY "\"}";

    /* Commands queued or in flight: their replies (or their timeout)
     * watch the link; the idle period starts again after them. */
    if (cmd_queue_pending(&cp->queue) > 0) {
        arm_check(cp);
        return;
    }
    uint32_t bound = cp->queue.timeout_ms < cp->link_check_ms ? cp->queue.timeout_ms
                                                              : cp->link_check_ms;
    int rc = cmd_queue_submit_check(&cp->queue, query, sizeof(query) - 1, bound,
                                    on_check_done, cp);
    if (rc == -ENOMEM) {
        arm_check(cp); /* the gateway's trouble, not the link's: later */
        return;
    }
    if (rc < 0 && rc != -ENOTCONN) {
        /* Could not be written (the robot does not read what was sent
         * before, a write error): a command link that cannot take a
         * 30-byte request is not usable. */
        char why[96];
        snprintf(why, sizeof(why), "link check not sent: %s", strerror(-rc));
        robot_link_restart(&cp->link, why);
        return;
    }
    arm_timer(cp);
}

static void set_answering(struct command_port *cp, bool answering)
{
    if (cp->answering == answering)
        return;
    cp->answering = answering;
    if (cp->hooks.on_answering)
        cp->hooks.on_answering(cp, answering);
}

static void on_reply(struct robot_link *link, const char *json, size_t size)
{
    struct command_port *cp = link->user;
    uint64_t unsolicited = cp->queue.stats.unsolicited;

    uint64_t suppressed;

    cmd_queue_on_reply(&cp->queue, json, size);
    if (cp->queue.stats.unsolicited != unsolicited &&
        log_ratelimit_pass(&cp->unsolicited_log, uv_now(cp->loop), &suppressed))
        log_warn("command link: a %zu-byte message came with no command in flight; "
                 "dropped (%llu more since the last such line): %.*s",
                 size, (unsigned long long)suppressed, (int)(size > 120 ? 120 : size), json);
    arm_timer(cp);
    if (cmd_queue_pending(&cp->queue) == 0)
        arm_check(cp);
    /* The callbacks above may have restarted the link. */
    if (cp->link.state == ROBOT_LINK_CONNECTED)
        set_answering(cp, true);
}

static void on_link_state(struct robot_link *link, enum robot_link_state state)
{
    struct command_port *cp = link->user;

    set_answering(cp, false);
    cmd_queue_set_connected(&cp->queue, state == ROBOT_LINK_CONNECTED);
    arm_timer(cp);
    arm_check(cp);
    if (cp->hooks.on_state)
        cp->hooks.on_state(cp, state);
}

bool command_port_answering(const struct command_port *cp)
{
    return cp->link.state == ROBOT_LINK_CONNECTED && cp->answering;
}

unsigned command_port_state(const struct command_port *cp)
{
    if (cp->link.state != ROBOT_LINK_CONNECTED)
        return cp->link.state;
    return cp->answering ? 2 : 3;
}

int command_port_init(uv_loop_t *loop, struct command_port *cp,
                      const struct robot_link_config *link_cfg,
                      uint32_t reply_timeout_ms, uint32_t link_check_ms,
                      const struct command_port_hooks *hooks)
{
    struct robot_link_callbacks cb = {.on_object = on_reply, .on_state = on_link_state};
    struct cmd_ops ops = {.send = send_bytes, .now_ms = now_ms,
                          .restart_link = restart_link, .sent = on_sent, .io = cp};

    memset(cp, 0, sizeof(*cp));
    cp->loop = loop;
    cp->hooks = *hooks;
    cp->user = hooks->user;
    cp->link_check_ms = link_check_ms;
    cp->unsolicited_log.interval_ms = 5000;
    cmd_queue_init(&cp->queue, &ops, reply_timeout_ms);
    int rc = robot_link_init(loop, &cp->link, link_cfg, &cb, cp);
    if (rc)
        return rc;
    uv_timer_init(loop, &cp->timer);
    uv_timer_init(loop, &cp->check_timer);
    cp->timer.data = cp;
    cp->check_timer.data = cp;
    cp->open_parts = 3;
    return 0;
}

int command_port_start(struct command_port *cp)
{
    return robot_link_start(&cp->link);
}

static void part_closed(struct command_port *cp)
{
    if (--cp->open_parts == 0 && cp->close_cb)
        cp->close_cb(cp);
}

static void on_timer_closed(uv_handle_t *h)
{
    part_closed(h->data);
}

static void on_link_closed(struct robot_link *link)
{
    part_closed(link->user);
}

void command_port_close(struct command_port *cp, void (*cb)(struct command_port *cp))
{
    cp->close_cb = cb;
    /* Nothing is left to be sent later: every queued command fails now. */
    cmd_queue_free(&cp->queue);
    uv_close((uv_handle_t *)&cp->timer, on_timer_closed);
    uv_close((uv_handle_t *)&cp->check_timer, on_timer_closed);
    robot_link_close(&cp->link, on_link_closed);
}
