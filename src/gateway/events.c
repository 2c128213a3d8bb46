/* SPDX-License-Identifier: MIT */
/* events.c - the event log (events.h). */
#include "events.h"

#include "policy.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

static const char *const link_names[] = {"disconnected", "connecting", "connected",
                                         "connected, but silent (status stale)"};
static const char *const command_link_names[] = {"disconnected", "connecting", "connected",
                                                 "connected, no reply yet"};
static const char *const handler_names[] = {"not sent", "pending", "accepted",
                                            "refused or unanswered"};
static const char *const program_names[] = {"idle", "loading", "paused", "running"};

static int flag(const struct jaka_status *s, enum status_field f)
{
    const struct status_num *n = status_num_at(s, f, 0);
    return n->present ? n->value != 0 : -1;
}

static int number(const struct jaka_status *s, enum status_field f)
{
    const struct status_num *n = status_num_at(s, f, 0);
    return n->present ? (int)n->value : -1;
}

void robot_view_of(const struct jaka_status *s, bool fresh, struct robot_view *v)
{
    v->known = s && fresh;
    if (!v->known) {
        v->powered_on = v->enabled = v->program = v->emergency_stop = v->protective_stop =
            v->mode = -1;
        v->speed_override = NAN;
        return;
    }
    v->powered_on = flag(s, STATUS_F_powered_on);
    v->enabled = flag(s, STATUS_F_enabled);
    v->program = number(s, STATUS_F_interp_state);
    if (v->program > 3)
        v->program = -1;
    v->emergency_stop = flag(s, STATUS_F_emergency_stop);
    v->protective_stop = flag(s, STATUS_F_protective_stop);
    v->mode = number(s, STATUS_F_task_mode);
    const struct status_num *rate = status_num_at(s, STATUS_F_rapidrate, 0);
    v->speed_override = rate->present ? rate->value : NAN;
}

static uint64_t wall_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000 + (uint64_t)ts.tv_nsec / 1000000;
}

static void add(struct events *e, const char *kind, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void add(struct events *e, const char *kind, const char *fmt, ...)
{
    struct gw_event *ev = &e->ring[e->next];
    va_list ap;

    memset(ev, 0, sizeof(*ev));
    ev->seq = ++e->seq;
    ev->wall_ms = wall_ms();
    snprintf(ev->kind, sizeof(ev->kind), "%s", kind);
    va_start(ap, fmt);
    vsnprintf(ev->text, sizeof(ev->text), fmt, ap);
    va_end(ap);
    e->next = (e->next + 1) % EVENTS_KEPT;
    if (e->count < EVENTS_KEPT)
        e->count++;
}

static const char *name_of(const char *const *names, unsigned count, int i)
{
    return i >= 0 && (unsigned)i < count ? names[i] : "?";
}

#define NAME(names, i) name_of(names, sizeof(names) / sizeof(names[0]), i)

/* A robot flag that became known, or changed. */
static void robot_flag(struct events *e, const char *what, int was, int now, const char *on,
                       const char *off)
{
    if (was != now && now >= 0)
        add(e, "robot", "%s: %s", what, now ? on : off);
}

void events_update(struct events *e, const struct events_state *state)
{
    struct events_state now = *state;

    if (!e->started) {
        /* The state at start is no change: only what follows is. */
        e->last = now;
        e->last.status_link = e->last.command_link = -1;
        e->last.robot = (struct robot_view){.powered_on = -1, .enabled = -1, .program = -1,
                                            .emergency_stop = -1, .protective_stop = -1,
                                            .mode = -1};
        e->started = true;
    }
    const struct events_state *was = &e->last;
    if (!now.robot.known) {
        /* Unknown is said once; the values before it stay the reference,
         * so that a reconnect logs only what changed meanwhile. */
        int program = was->robot.program;
        now.robot = was->robot;
        now.robot.known = false;
        now.robot.program = program;
    }
    if (now.status_link != was->status_link)
        add(e, "link", "status link: %s", NAME(link_names, now.status_link));
    if (now.command_link != was->command_link)
        add(e, "link", "command link: %s", NAME(command_link_names, now.command_link));
    if (now.fault != was->fault) {
        if (now.fault)
            add(e, "fault", "fault %d latched: %s", now.fault, policy_fault_name(now.fault));
        else
            add(e, "fault", "fault %d (%s) reset by the PLC", was->fault,
                policy_fault_name(was->fault));
    }
    if (now.handler != was->handler)
        add(e, "policy", "robot's network-exception handler: %s",
            NAME(handler_names, now.handler));
    if (now.motion_enabled != was->motion_enabled)
        add(e, "policy", "motion enable: %s", now.motion_enabled ? "on" : "off");
    if (strcmp(now.owner, was->owner) != 0)
        add(e, "policy", "write owner: %s", now.owner[0] ? now.owner : "none");
    if (now.robot.known != was->robot.known && !now.robot.known && e->seq)
        add(e, "robot", "robot state unknown (no fresh status)");
    const struct robot_view *r = &now.robot, *p = &was->robot;
    robot_flag(e, "power", p->powered_on, r->powered_on, "on", "off");
    robot_flag(e, "robot", p->enabled, r->enabled, "enabled", "disabled");
    if (r->program != p->program && r->program >= 0)
        add(e, "robot", "program: %s", NAME(program_names, r->program));
    robot_flag(e, "emergency stop", p->emergency_stop, r->emergency_stop, "triggered",
               "released");
    robot_flag(e, "protective stop", p->protective_stop, r->protective_stop, "triggered",
               "released");
    e->last = now;
}

unsigned events_count(const struct events *e)
{
    return e->count;
}

const struct gw_event *events_get(const struct events *e, unsigned i)
{
    unsigned oldest = (e->next + EVENTS_KEPT - e->count) % EVENTS_KEPT;
    return i < e->count ? &e->ring[(oldest + i) % EVENTS_KEPT] : NULL;
}
