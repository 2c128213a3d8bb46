/* SPDX-License-Identifier: MIT */
/*
 * events.h - the event log of the status page and /status.json: the last
 * EVENTS_KEPT changes of the links, the status data's freshness, the
 * network-exception policy (fault latched or reset, write owner, motion
 * enable, the robot's handler) and the robot's state (power, enabled,
 * program, emergency and protective stop), each with its wall time.
 *
 * The gateway calls events_update() with its state wherever it may have
 * changed (a link's state, a status document, a write, the policy's check
 * timer): the state is compared with the one last seen and every
 * difference is one event, so no change needs a hook of its own and none
 * is logged twice. Pure: the gateway gathers the state (gateway.c).
 */
#ifndef JAKAGW_EVENTS_H
#define JAKAGW_EVENTS_H

#include <stdbool.h>
#include <stdint.h>

#include "status.h"

#define EVENTS_KEPT 100

/* The robot as the status link shows it; every value -1 when the link is
 * down or stale ("unknown"), else 0 or 1 (program: 0 idle, 1 loading,
 * 2 paused, 3 running; mode: task_mode). */
struct robot_view {
    bool known;
    int powered_on, enabled, program, emergency_stop, protective_stop, mode;
    double speed_override; /* 0 to 1; NAN unknown */
};

/* The robot as 'status' shows it; all unknown unless 'fresh'. */
void robot_view_of(const struct jaka_status *status, bool fresh, struct robot_view *v);

struct gw_event {
    uint64_t seq;     /* from 1 */
    uint64_t wall_ms; /* ms since the Unix epoch */
    char kind[8];     /* "link", "policy", "fault", "robot" */
    char text[120];
};

/* What events_check() compares. */
struct events_state {
    int status_link, command_link; /* robot_link_state; status 3: stale */
    int fault;
    int handler;
    int motion_enabled;
    char owner[64];
    struct robot_view robot;
};

struct events {
    struct gw_event ring[EVENTS_KEPT]; /* [next] the oldest once full */
    unsigned next, count;
    uint64_t seq;
    struct events_state last;
    bool started;
};

/* Compares 'now' with the state last seen; each change is an event. */
void events_update(struct events *e, const struct events_state *now);

/* The kept events, oldest first: 'i' from 0 to events_count() - 1. */
unsigned events_count(const struct events *e);
const struct gw_event *events_get(const struct events *e, unsigned i);

#endif
