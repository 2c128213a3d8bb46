/* SPDX-License-Identifier: MIT */
/* command_port.c - see command_port.h. */
#include "command_port.h"

#include "log.h"

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
}

static void on_link_state(struct robot_link *link, enum robot_link_state state)
{
    struct command_port *cp = link->user;

    cmd_queue_set_connected(&cp->queue, state == ROBOT_LINK_CONNECTED);
    arm_timer(cp);
    if (cp->on_state)
        cp->on_state(cp, state);
}

int command_port_init(uv_loop_t *loop, struct command_port *cp,
                      const struct robot_link_config *link_cfg,
                      uint32_t reply_timeout_ms,
                      void (*on_state)(struct command_port *cp,
                                       enum robot_link_state state),
                      void *user)
{
    struct robot_link_callbacks cb = {.on_object = on_reply, .on_state = on_link_state};
    struct cmd_ops ops = {.send = send_bytes, .now_ms = now_ms,
                          .restart_link = restart_link, .sent = on_sent, .io = cp};

    memset(cp, 0, sizeof(*cp));
    cp->loop = loop;
    cp->on_state = on_state;
    cp->user = user;
    cp->unsolicited_log.interval_ms = 5000;
    cmd_queue_init(&cp->queue, &ops, reply_timeout_ms);
    int rc = robot_link_init(loop, &cp->link, link_cfg, &cb, cp);
    if (rc)
        return rc;
    uv_timer_init(loop, &cp->timer);
    cp->timer.data = cp;
    cp->open_parts = 2;
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
    robot_link_close(&cp->link, on_link_closed);
}
