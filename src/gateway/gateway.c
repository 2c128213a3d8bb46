/* SPDX-License-Identifier: MIT */
/* gateway.c - see gateway.h. */
#include "gateway.h"

#include "gw_tls.h"
#include "log.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define NEVER_MS GATEWAY_NEVER_MS

static struct gateway *gateway_of_link(struct robot_link *link)
{
    return link->user;
}

/* The state the event log follows (events.h): each change one event. */
static void events_check(struct gateway *gw)
{
    bool fresh = gateway_status_fresh(gw);
    struct events_state s = {
        .status_link = gw->status_link.state == ROBOT_LINK_CONNECTED && !fresh
                           ? 3
                           : (int)gw->status_link.state,
        .command_link = (int)command_port_state(&gw->command),
        .fault = gw->policy.fault,
        .handler = gw->commands.handle_state,
        .motion_enabled = gw->policy.motion_enabled,
    };
    /* A copy, not snprintf: this runs on every write a PLC makes. */
    size_t owner_len = strnlen(gw->policy.owner_address, sizeof(s.owner) - 1);
    memcpy(s.owner, gw->policy.owner_address, owner_len);
    s.owner[owner_len] = '\0';
    robot_view_of(gw->status, fresh, &s.robot);
    events_update(&gw->events, &s);
}

static void notify_change(struct gateway *gw)
{
    events_check(gw);
    if (gw->on_change)
        gw->on_change(gw);
}

/*
 * The stale streak, updated whenever the freshness is looked at (every
 * check period, every refresh, every document). It starts when the status
 * goes stale and ends only once it has been fresh, with no gap, for twice
 * status_timeout_ms: a controller that hangs after one push per connection
 * keeps it running through every reconnect, as a flapping status_fresh
 * (or link_up) cannot.
 */
static void track_status_streak(struct gateway *gw, bool fresh)
{
    uint64_t now = uv_now(gw->loop);
    uint64_t timeout = gw->cfg.status_timeout_ms;

    if (!fresh) {
        gw->status_fresh_since_ms = 0;
        if (gw->status_stale_since_ms == 0) {
            /* Stale from when the last document got too old, if that is
             * what happened; else (the link lost) from now. */
            uint64_t since = now;
            if (gw->last_document_ms && gw->last_document_ms + timeout < now)
                since = gw->last_document_ms + timeout;
            gw->status_stale_since_ms = since ? since : 1;
        }
        return;
    }
    if (gw->status_fresh_since_ms == 0)
        gw->status_fresh_since_ms = now;
    if (gw->status_stale_since_ms && now - gw->status_fresh_since_ms >= 2 * timeout)
        gw->status_stale_since_ms = 0;
}

uint64_t gateway_status_stale_ms(struct gateway *gw)
{
    track_status_streak(gw, gateway_status_fresh(gw));
    return gw->status_stale_since_ms ? uv_now(gw->loop) - gw->status_stale_since_ms : 0;
}

static void on_status_document(struct robot_link *link, const char *json,
                               size_t size)
{
    struct gateway *gw = gateway_of_link(link);
    bool was_fresh = gateway_status_fresh(gw);
    status_marks_of(json, size, &gw->last_marks);
    /* Parse aside: a bad document must not wipe the last good status. */
    int rc = status_parse(gw->scratch, json, size);

    if (rc != STATUS_PARSE_OK) {
        uint64_t suppressed;
        gw->counters.parse_errors++;
        if (log_ratelimit_pass(&gw->parse_log_limit, uv_now(gw->loop), &suppressed))
            log_warn("status link: dropped a %zu-byte document: %s "
                     "(%llu more since the last such line)",
                     size, rc == STATUS_PARSE_BAD_JSON ? "not valid JSON"
                                                       : "not a JSON object",
                     (unsigned long long)suppressed);
        return;
    }
    struct jaka_status *previous = gw->status;
    gw->status = gw->scratch;
    gw->scratch = previous;
    gw->counters.documents_parsed++;
    gw->status_sequence++;
    /* A fresh clock: the parse may have taken a while, and the age that
     * PLCs read must count from when the data became available. */
    uv_update_time(gw->loop);
    /* A gap before this document belongs to the streak, even one no
     * check saw (a reconnect between two check periods). */
    if (!was_fresh)
        track_status_streak(gw, false);
    gw->last_document_ms = uv_now(gw->loop);
    gw->last_document_bytes = size;
    track_status_streak(gw, true);
    struct motion_view view;
    motion_view_of(gw->status, &view);
    motion_document(&gw->motion, gw->last_document_ms, &view);
    policy_status_document(&gw->policy, gw->last_document_ms);
    regmap_encode_status(&gw->image, gw->status);
    if (!was_fresh)
        notify_change(gw);
    else
        events_check(gw); /* the robot's state may have changed */
}

/*
 * A document a newer one replaced before it was parsed (the gateway fell
 * behind the stream). The status is a snapshot, so the newer one says all
 * a PLC can read; but a document that changes what the events log and the
 * motion tracker follow (status.h, STATUS_MARK_MEMBERS) is parsed all the
 * same, so that no transition is lost, however short.
 */
static bool on_status_superseded(struct robot_link *link, const char *json, size_t size)
{
    struct gateway *gw = gateway_of_link(link);
    struct status_marks marks;

    status_marks_of(json, size, &marks);
    bool changes = status_marks_differ(&marks, &gw->last_marks);
    gw->last_marks = marks;
    return changes;
}

static void on_status_framing(struct robot_link *link, enum framer_event event,
                              size_t size)
{
    struct gateway *gw = gateway_of_link(link);
    uint64_t suppressed;
    const char *what = "";

    switch (event) {
    case FRAMER_EVENT_GARBAGE:
        gw->counters.framing_errors++;
        gw->counters.garbage_bytes += size;
        what = "skipped bytes that belong to no document";
        break;
    case FRAMER_EVENT_OVERSIZE:
        gw->counters.framing_errors++;
        gw->counters.oversize_documents++;
        what = "dropped a document larger than max_document_bytes";
        break;
    case FRAMER_EVENT_TRUNCATED:
        gw->counters.framing_errors++;
        what = "dropped a document cut short by the next one";
        break;
    case FRAMER_EVENT_LEN_MISMATCH:
        gw->counters.len_mismatches++;
        what = "a document's \"len\" disagreed with its real end";
        break;
    case FRAMER_EVENT_OBJECT:
        return;
    }
    if (log_ratelimit_pass(&gw->parse_log_limit, uv_now(gw->loop), &suppressed))
        log_warn("status link: %s (%zu bytes; %llu more such events since the "
                 "last line)",
                 what, size, (unsigned long long)suppressed);
}

static void on_link_state(struct robot_link *link, enum robot_link_state state)
{
    struct gateway *gw = gateway_of_link(link);

    if (state == ROBOT_LINK_CONNECTED && link->connections > 1)
        gw->counters.status_reconnects++;
    notify_change(gw);
}

static void check_policy(struct gateway *gw);

static void on_command_state(struct command_port *cp, enum robot_link_state state)
{
    struct gateway *gw = cp->user;

    if (state == ROBOT_LINK_CONNECTED) {
        if (cp->link.connections > 1)
            gw->counters.command_reconnects++;
        plc_commands_link_up(&gw->commands);
        /* An action still owed goes out at once, ahead of the rest. */
        if (gw->parts & GATEWAY_PART_POLICY)
            check_policy(gw);
    } else {
        plc_commands_link_down(&gw->commands);
        /* What the robot does with the moves it holds is unknown now (its
         * handler pauses or stops them): the PLC learns it at once. */
        motion_link_lost(&gw->motion, uv_now(gw->loop), "the command link was lost");
    }
    notify_change(gw);
}

static void on_command_answering(struct command_port *cp, bool answering)
{
    (void)answering;
    notify_change(cp->user);
}

/* A link check's reply: what it says about the robot shows in the map. */
static void on_link_check_reply(struct command_port *cp, const char *query,
                                const struct cmd_result *r)
{
    struct gateway *gw = cp->user;
    plc_commands_link_check_reply(&gw->commands, query, r);
}

/* A move of ours may be running: the command link is checked more often
 * meanwhile (command_port.h). */
static bool move_running(struct command_port *cp)
{
    const struct gateway *gw = cp->user;
    return gw->motion.state == MOTION_MOVING;
}

bool gateway_status_fresh(const struct gateway *gw)
{
    return gw->last_document_ms != 0 &&
           gw->status_link.state == ROBOT_LINK_CONNECTED &&
           uv_now(gw->loop) - gw->last_document_ms < gw->cfg.status_timeout_ms;
}

static double age_ms(const struct gateway *gw, uint64_t since)
{
    if (since == 0)
        return NEVER_MS;
    uint64_t age = uv_now(gw->loop) - since;
    return age > NEVER_MS - 1 ? NEVER_MS - 1 : (double)age;
}

/* The policy's state, as PLCs read it. */
static void show_policy(struct gateway *gw)
{
    struct regmap_image *img = &gw->image;
    const struct policy *p = &gw->policy;
    const struct gateway_policy_rows *rows = &gw->policy_rows;

    regmap_set_number(img, rows->fault, 0, p->fault, true);
    regmap_set_number(img, rows->fault_age_ms, 0,
                      (double)policy_fault_age_ms(p, uv_now(gw->loop)), true);
    regmap_set_number(img, rows->faults, 0, (double)(p->faults & 0xFFFF), true);
    regmap_set_number(img, rows->motion_enabled, 0, p->motion_enabled, true);
    regmap_set_text(img, rows->write_owner, 0, p->owner_address);
    regmap_set_number(img, rows->heartbeat_state, 0,
                      policy_heartbeat_state(p, uv_now(gw->loop)), true);
    regmap_set_number(img, rows->reaction, 0, p->reaction, true);
}

/* The last move's state: its time bound judged now, an end logged once. */
static void show_motion(struct gateway *gw)
{
    struct motion *m = &gw->motion;
    const struct gateway_policy_rows *rows = &gw->policy_rows;

    motion_check(m, uv_now(gw->loop));
    if (m->state != gw->motion_logged) {
        if (m->state == MOTION_STOPPED || m->state == MOTION_TIMED_OUT)
            log_notice("motion: %s (move %u) %s: %s", m->name, (unsigned)m->count,
                       motion_state_name(m->state), m->why);
        gw->motion_logged = m->state;
    }
    if (!rows->motion_state)
        return;
    regmap_set_number(&gw->image, rows->motion_state, 0, m->state, true);
    regmap_set_number(&gw->image, rows->motion_count, 0, m->count, true);
}

/* The serial line's state and counters. */
static void refresh_rtu_values(struct gateway *gw, double *v)
{
    static const struct mb_rtu_stats none;
    bool on = gw->parts & GATEWAY_PART_RTU;
    const struct mb_rtu_stats *s = on ? &gw->rtu.stats : &none;

    v[GW_rtu_line_state] = on ? mb_rtu_state(&gw->rtu) : MB_RTU_OFF;
    v[GW_rtu_frames] = (double)s->frames;
    v[GW_rtu_crc_errors] = (double)s->crc_errors;
    v[GW_rtu_foreign_frames] = (double)s->foreign_frames;
    v[GW_rtu_broadcasts] = (double)s->broadcasts;
    v[GW_rtu_overruns] = (double)s->overruns;
    v[GW_rtu_gap_discards] = (double)s->gap_discards;
    v[GW_rtu_turnaround_us] = s->turnaround_us;
    v[GW_rtu_turnaround_max_us] = s->turnaround_max_us;
    v[GW_rtu_echoes] = (double)s->echoes;
    v[GW_rtu_collisions] = (double)s->collisions;
    v[GW_rtu_out_of_turn] = (double)s->out_of_turn;
    v[GW_rtu_repeats] = (double)s->repeats;
    v[GW_rtu_exceptions] = (double)s->exceptions;
    v[GW_rtu_delivery_ms] = on ? gw->rtu.delivery_bound_ms : 0;
}

static void refresh_tls_values(struct gateway *gw, double *v)
{
    static const struct mb_tls_stats none;
    const struct mb_tls_stats *s = gw->mbaps ? &gw->mbaps->stats : &none;

    v[GW_tls_clients] = s->clients;
    v[GW_tls_handshakes_running] = s->handshakes;
    v[GW_tls_handshakes_ok] = (double)s->handshakes_ok;
    v[GW_tls_failed_total] = (double)mb_tls_failed_total(s);
    v[GW_tls_failed_no_certificate] = (double)s->failed[TLS_FAIL_NO_CERTIFICATE];
    v[GW_tls_failed_untrusted] = (double)s->failed[TLS_FAIL_UNTRUSTED];
    v[GW_tls_failed_expired] = (double)s->failed[TLS_FAIL_EXPIRED];
    v[GW_tls_failed_revoked] = (double)s->failed[TLS_FAIL_REVOKED];
    v[GW_tls_failed_protocol] = (double)s->failed[TLS_FAIL_PROTOCOL];
    v[GW_tls_failed_timeout] = (double)s->failed[TLS_FAIL_TIMEOUT];
    v[GW_tls_failed_over_limit] = (double)s->failed[TLS_FAIL_OVER_LIMIT];
    v[GW_status_link_tls_failure] = gw->status_link.tls_failure;
    v[GW_command_link_tls_failure] = gw->command.link.tls_failure;
}

static void clear_tls_counters(struct gateway *gw)
{
    if (!gw->mbaps)
        return;
    gw->mbaps->stats.handshakes_ok = 0;
    memset(gw->mbaps->stats.failed, 0, sizeof(gw->mbaps->stats.failed));
}

void gateway_refresh_values(struct gateway *gw)
{
    double *v = gw->gw_values;
    const struct mb_server_stats *mb = &gw->modbus.stats;
    const struct gateway_counters *c = &gw->counters;
    bool fresh = gateway_status_fresh(gw);

    /* The constant values are set once, in set_constant_values(). */
    v[GW_status_link_up] = gw->status_link.state == ROBOT_LINK_CONNECTED;
    v[GW_command_link_up] = command_port_answering(&gw->command);
    v[GW_status_fresh] = fresh;
    v[GW_status_link_state] =
        gw->status_link.state == ROBOT_LINK_CONNECTED && !fresh ? 3
                                                                : gw->status_link.state;
    v[GW_command_link_state] = command_port_state(&gw->command);
    v[GW_link_checks] = (double)gw->command.queue.stats.checks;
    v[GW_link_checks_failed] = (double)gw->command.queue.stats.checks_failed;
    v[GW_status_age_ms] = age_ms(gw, gw->last_document_ms);
    v[GW_documents_parsed] = (double)c->documents_parsed;
    v[GW_status_sequence] = gw->status_sequence;
    v[GW_parse_errors] = (double)c->parse_errors;
    v[GW_framing_errors] = (double)c->framing_errors;
    v[GW_oversize_documents] = (double)c->oversize_documents;
    v[GW_garbage_bytes] = (double)c->garbage_bytes;
    v[GW_len_mismatches] = (double)c->len_mismatches;
    v[GW_status_reconnects] = (double)c->status_reconnects;
    v[GW_command_reconnects] = (double)c->command_reconnects;
    v[GW_modbus_requests] = (double)mb->requests;
    v[GW_modbus_exceptions] = (double)mb->exceptions;
    v[GW_modbus_clients] = mb->clients;
    v[GW_modbus_evictions] = (double)mb->evictions;
    v[GW_uptime_s] = (double)((uv_now(gw->loop) - gw->started_ms) / 1000);
    v[GW_last_document_bytes] = (double)gw->last_document_bytes;
    v[GW_plc_heartbeat_age_ms] =
        age_ms(gw, gw->policy.heartbeat_armed ? gw->policy.heartbeat_ms : 0);
    /* The value the PLC last wrote, as holding register plc_heartbeat
     * shows it: without it, /status.json's counters said 0 forever. */
    v[GW_plc_heartbeat] = gw->policy.heartbeat_value;
    uint64_t stale = gateway_status_stale_ms(gw);
    v[GW_status_stale_ms] = stale > NEVER_MS - 1 ? NEVER_MS - 1 : (double)stale;
    v[GW_loop_stalls] = (double)gw->policy.stalls;
    v[GW_loop_stall_last_ms] =
        gw->policy.last_stall_ms > NEVER_MS - 1 ? NEVER_MS - 1 : (double)gw->policy.last_stall_ms;
    v[GW_can_state] = gw->can.state;
    v[GW_can_frames_sent] = (double)gw->can.stats.frames_sent;
    v[GW_can_frames_dropped] = (double)gw->can.stats.frames_dropped;
    v[GW_can_errors] = (double)can_mirror_errors(&gw->can.stats);
    refresh_tls_values(gw, v);
    refresh_rtu_values(gw, v);
    regmap_encode_gw(&gw->image, v);
    plc_commands_refresh(&gw->commands);
    show_motion(gw);
    if (gw->parts & GATEWAY_PART_POLICY)
        show_policy(gw);
}

static void clear_counters(void *user)
{
    struct gateway *gw = user;

    memset(&gw->counters, 0, sizeof(gw->counters));
    gw->command.queue.stats.checks = 0;
    gw->command.queue.stats.checks_failed = 0;
    gw->modbus.stats.requests = 0;
    gw->modbus.stats.exceptions = 0;
    gw->modbus.stats.evictions = 0;
    gw->modbus.stats.bad_frames = 0;
    memset(&gw->modbus.stats.by, 0, sizeof(gw->modbus.stats.by));
    can_mirror_clear_stats(&gw->can);
    clear_tls_counters(gw);
    if (gw->parts & GATEWAY_PART_RTU)
        mb_rtu_clear_stats(&gw->rtu);
    log_notice("counters cleared by a Modbus client");
}

static void before_request(void *user)
{
    gateway_refresh_values(user);
}

static void after_write(void *user, enum regmap_table table, unsigned address,
                        unsigned count)
{
    struct gateway *gw = user;
    (void)table, (void)address, (void)count; /* the transaction knows them */
    plc_write_after(&gw->writes);
}

static bool robot_may_move(void *user)
{
    struct gateway *gw = user;
    return policy_robot_may_move(gateway_status_fresh(gw), gw->status);
}

static void check_policy(struct gateway *gw)
{
    policy_check(&gw->policy, uv_now(gw->loop), robot_may_move(gw));
}

static void on_policy_timer(uv_timer_t *t)
{
    struct gateway *gw = t->data;
    show_motion(gw);
    check_policy(gw);
    track_status_streak(gw, gateway_status_fresh(gw));
    audit_flush(&gw->audit);
    events_check(gw); /* a fault latched, the status gone stale */
}

/* Why the action is what it is, for its log line. */
static const char *action_because(const struct gateway *gw, enum policy_action action,
                                  enum policy_fault reason)
{
    enum policy_action configured =
        reason == POLICY_FAULT_MOTION_ENABLE ? POLICY_PAUSE : (enum policy_action)gw->cfg.ne_action;
    if (gw->policy.reaction == POLICY_REACTION_ESCALATED)
        return " once more: the arm was still moving after the first action";
    if (action == POLICY_STOP && configured == POLICY_PAUSE)
        return " (the arm may run a move outside a program, which pause_program does not stop)";
    return "";
}

/* The policy's action goes out as pause_program or stop_program. */
static bool send_policy_action(void *user, enum policy_action action,
                               enum policy_fault reason)
{
    struct gateway *gw = user;
    const char *name = action == POLICY_STOP ? "stop_program" : "pause_program";
    int rc = plc_commands_send_now(&gw->commands, name);
    if (rc == 0 && action == POLICY_STOP)
        motion_stop_sent(&gw->motion, uv_now(gw->loop), "stopped by the network-exception policy");
    if (rc == 0)
        log_warn("network exception: %s while the robot may move: sent %s%s; "
                 "commands are refused until the PLC resets the fault",
                 policy_fault_name(reason), name, action_because(gw, action, reason));
    else if (!gw->policy.owed)
        log_err("network exception: %s while the robot may move: cannot send %s "
                "(%s); trying again on every check until it goes out",
                policy_fault_name(reason), name, strerror(-rc));
    return rc == 0;
}

/* What the status shows the arm doing, for the policy. */
static enum policy_robot robot_seen(void *user)
{
    struct gateway *gw = user;
    return motion_robot(&gw->motion, gateway_status_fresh(gw));
}

static double arm_step(void *user)
{
    struct gateway *gw = user;
    return gateway_status_fresh(gw) ? motion_step_deg(&gw->motion) : -1;
}

/* What the robot did about the action: one log line per change. */
static void on_reaction(void *user, enum policy_reaction reaction, enum policy_action sent,
                        uint64_t after_ms)
{
    struct gateway *gw = user;
    const char *name = sent == POLICY_STOP ? "stop_program" : "pause_program";

    switch (reaction) {
    case POLICY_REACTION_PAUSED:
    case POLICY_REACTION_STOPPED:
        log_notice("network exception: the status shows the robot %s, %llu ms after %s's "
                   "reply", policy_reaction_name(reaction), (unsigned long long)after_ms, name);
        break;
    case POLICY_REACTION_ESCALATED:
        log_err("network exception: the arm is still moving %llu ms after %s's reply "
                "(status period %llu ms): sending stop_program once more",
                (unsigned long long)after_ms, name,
                (unsigned long long)policy_status_period_ms(&gw->policy));
        break;
    case POLICY_REACTION_STILL_MOVING:
        log_err("network exception: the arm is still moving %llu ms after the second "
                 "stop_program's reply: the robot does not stop; check it now",
                 (unsigned long long)after_ms);
        break;
    default:
        break;
    }
}

/* The policy's own action was answered: its check starts. */
static void on_own_answered(void *user, const struct cmd_def *def, const struct cmd_result *r)
{
    struct gateway *gw = user;
    (void)def;
    if (gw->parts & GATEWAY_PART_POLICY)
        policy_action_answered(&gw->policy, uv_now(gw->loop), r->outcome == CMD_DONE);
}

/* Every command sent for a PLC: a move followed, a stop, a start's kind. */
static void on_command_sent(void *user, const struct cmd_def *def, const char *json,
                            const void *tag)
{
    struct gateway *gw = user;
    uint64_t now = uv_now(gw->loop);

    if (def && strcmp(def->name, "stop_program") == 0)
        motion_stop_sent(&gw->motion, now, "stop_program from a PLC");
    if (policy_command_starts_motion(def))
        policy_start_kind(&gw->policy, !def || (def->flags & CMD_MOTION));
    /* Only a move has a target to follow: the table says which commands
     * are moves, so the others are not parsed again (the tracker ignores
     * them anyway). */
    if (def && (def->flags & CMD_MOTION))
        motion_sent(&gw->motion, now, json, tag);
}

static void on_command_answered(void *user, const struct cmd_def *def, const void *tag,
                                const struct cmd_result *r)
{
    struct gateway *gw = user;
    uint64_t now = uv_now(gw->loop);
    /* A stop ends the moves only once the robot accepted it. */
    if (def && strcmp(def->name, "stop_program") == 0)
        motion_stop_answered(&gw->motion, now, r->outcome == CMD_DONE);
    motion_answered(&gw->motion, now, tag, r->sent_at_ms, r->outcome == CMD_DONE,
                    r->outcome == CMD_TIMEOUT || r->outcome == CMD_LINK_DOWN);
}

/* The policy saw the loop stand still: logged once per stall, as the
 * gateway's own fault, never the PLC's. */
static void on_loop_stall(void *user, uint64_t gap_ms)
{
    struct gateway *gw = user;

    log_warn("gateway loop stalled for %llu ms (longer than time_limit_ms %u): the "
             "process was stopped or blocked; the PLC is not blamed (its heartbeat "
             "clock moves on by the stall); network-exception fault 4 if the robot "
             "may move",
             (unsigned long long)gap_ms, (unsigned)gw->cfg.ne_time_limit_ms);
}

/* The policy's action went out, and its outcome is unknown: owed again. */
static void on_own_unknown(void *user, const struct cmd_def *def)
{
    struct gateway *gw = user;

    /* Stopping: every command fails with the link; nothing is sent again. */
    if (!(gw->parts & GATEWAY_PART_POLICY) || gw->close_cb)
        return;
    enum policy_action action = strcmp(def->name, "stop_program") == 0    ? POLICY_STOP
                                : strcmp(def->name, "pause_program") == 0 ? POLICY_PAUSE
                                                                          : POLICY_KEEP;
    /* A controller that hangs would lose one on every reconnect. */
    static struct log_ratelimit limit = {.interval_ms = 10000};
    uint64_t suppressed;
    if (action != POLICY_KEEP && gw->policy.fault != POLICY_FAULT_NONE &&
        log_ratelimit_pass(&limit, uv_now(gw->loop), &suppressed))
        log_warn("network exception: %s's outcome is unknown (its connection was lost "
                 "before the reply); sent again once the command link is back, while "
                 "the robot may move (%llu more such lines suppressed)", def->name,
                 (unsigned long long)suppressed);
    policy_action_unknown(&gw->policy, action);
}

/* The policy's say on every command the PLC side sends. */
static int gate_command(void *user, const struct cmd_def *def, char *why, size_t size)
{
    struct gateway *gw = user;
    return policy_gate_command(&gw->policy, uv_now(gw->loop), def, why, size);
}

/* Starts the PLC side sent: the robot may run before its status shows it. */
static void on_start_sent(void *user)
{
    struct gateway *gw = user;
    policy_start_sent(&gw->policy, uv_now(gw->loop));
}

static void on_start_answered(void *user)
{
    struct gateway *gw = user;
    policy_start_answered(&gw->policy, uv_now(gw->loop));
}

/* A refused write into the audit trail: who, where, the exception, why. */
static void audit_refusal(struct gateway *gw, const struct mb_write *w, int ex, bool judged)
{
    /* Refused before it was judged: the server's own checks. */
    static const char *const unjudged[] = {"", "function not allowed on this table",
                                           "no such address in the register map",
                                           "invalid count or value"};
    const char *why = judged ? gw->writes.why : ex >= 1 && ex <= 3 ? unjudged[ex] : "";

    if (!judged)
        plc_write_name_range(&gw->writes, w);
    audit_write_refused(&gw->audit, w->transport, w->peer ? w->peer : w->client, w->subject,
                        w->role, gw->writes.where, ex, why);
}

/* Every write judged; the commands it sends, and a refusal, audited. */
static int on_write(void *user, const struct mb_write *w)
{
    struct gateway *gw = user;

    audit_set_writer(&gw->audit, w->transport, w->peer ? w->peer : w->client, w->subject,
                     w->role);
    int ex = plc_write_judge(&gw->writes, w);
    audit_clear_writer(&gw->audit);
    if (ex)
        audit_refusal(gw, w, ex, true);
    else
        events_check(gw); /* a fault reset, a new write owner */
    return ex;
}

/* A write the map refused before it could be judged: audited the same. */
static void on_write_refused(void *user, const struct mb_write *w, int ex)
{
    struct gateway *gw = user;
    plc_write_refused_unjudged(&gw->writes, w);
    audit_refusal(gw, w, ex, false);
}

static void on_client(void *user, uint64_t client, bool open, unsigned clients)
{
    struct gateway *gw = user;
    if (open)
        policy_client_opened(&gw->policy, uv_now(gw->loop), clients);
    else
        policy_client_closed(&gw->policy, uv_now(gw->loop), client, clients);
}

static bool is_running(void *user)
{
    return gateway_status_fresh(user);
}

void gateway_describe(const struct gateway *gw, char *buf, size_t size)
{
    static const char *const names[] = {"disconnected", "connecting", "connected"};
    snprintf(buf, size, "status link %s%s, command link %s%s, %u Modbus clients",
             names[gw->status_link.state],
             gw->status_link.state == ROBOT_LINK_CONNECTED &&
                     !gateway_status_fresh(gw)
                 ? " (silent)"
                 : "",
             names[gw->command.link.state],
             command_port_state(&gw->command) == 3 ? " (not answering yet)" : "",
             gw->modbus.stats.clients);
    size_t used = strlen(buf);
    if ((gw->parts & GATEWAY_PART_RTU) && gw->rtu.fd >= 0 && used < size)
        snprintf(buf + used, size - used, ", serial line delivery %u ms",
                 gw->rtu.delivery_bound_ms);
}

static int start_links(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    struct tls_context *tls;
    int rc = gw_tls_robot_links(&gw->cfg, &tls, "robot links");
    if (rc)
        return rc;
    struct robot_link_config lc = {
        .name = "status",
        .host = cfg->robot_host,
        .port = (uint16_t)cfg->status_port,
        .connect_timeout_ms = cfg->connect_timeout_ms,
        .reconnect_min_ms = cfg->reconnect_min_ms,
        .reconnect_max_ms = cfg->reconnect_max_ms,
        .silence_timeout_ms = cfg->status_timeout_ms,
        /* The kernel's bounds come a second after the gateway's own, so
         * that what the PLC reads is the gateway's decision. */
        .user_timeout_ms = cfg->status_timeout_ms + 1000,
        .max_object = cfg->max_document_bytes,
        .tls = tls,
        /* A document is the robot's whole state: a command must not wait
         * behind documents that a newer one makes stale. */
        .newest_only = true,
    };
    struct robot_link_callbacks status_cb = {
        .on_object = on_status_document,
        .on_framing_error = on_status_framing,
        .on_superseded = on_status_superseded,
        .on_state = on_link_state,
    };
    rc = robot_link_init(gw->loop, &gw->status_link, &lc, &status_cb, gw);
    if (rc) {
        tls_context_unref(tls);
        return rc;
    }
    gw->parts |= GATEWAY_PART_STATUS_LINK;
    lc.name = "command";
    lc.newest_only = false; /* every reply counts */
    lc.port = (uint16_t)cfg->command_port;
    /* Replies come only when asked; silence is normal there, and the link
     * check (link_check_ms) asks when it lasts. */
    lc.silence_timeout_ms = 0;
    lc.user_timeout_ms = cfg->reply_timeout_ms + 1000;
    struct command_port_hooks hooks = {
        .on_state = on_command_state,
        .on_answering = on_command_answering,
        .on_check_reply = on_link_check_reply,
        .move_running = move_running,
        .user = gw,
    };
    rc = command_port_init(gw->loop, &gw->command, &lc, cfg->reply_timeout_ms,
                           cfg->link_check_ms, &hooks);
    tls_context_unref(tls); /* each link holds its own reference */
    if (rc)
        return rc;
    gw->parts |= GATEWAY_PART_COMMAND_LINK;
    robot_link_start(&gw->status_link);
    command_port_start(&gw->command);
    return 0;
}

/* The CAN mirror's view each period: the model and values Modbus reads. */
static void can_snapshot(void *user, struct can_inputs *in)
{
    struct gateway *gw = user;

    gateway_refresh_values(gw);
    in->status = gw->status;
    in->gw = gw->gw_values;
}

static int start_can(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    struct can_mirror_config cc = {
        .base_id = cfg->can_base_id,
        .extended_ids = cfg->can_extended_ids,
        .period_ms = cfg->can_period_ms,
        .groups = cfg->can_groups,
    };
    int rc;

    if (!cfg->can_enabled)
        return 0;
    snprintf(cc.interface, sizeof(cc.interface), "%s", cfg->can_interface);
    rc = can_mirror_init(&gw->can, &cc, NULL, can_snapshot, gw);
    if (rc) {
        log_err("CAN mirror: the [can] settings do not fit the frame map");
        return rc;
    }
    rc = can_mirror_start(gw->loop, &gw->can);
    if (rc == 0)
        gw->parts |= GATEWAY_PART_CAN;
    return rc;
}

static uint64_t loop_now_ms(void *clock)
{
    return uv_now(clock);
}

static uint64_t loop_now_ms_of_gateway(void *user)
{
    return uv_now(((struct gateway *)user)->loop);
}

/* Binds the command rows to the command port's queue. */
static int start_commands(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    motion_init(&gw->motion);
    gw->policy_rows.motion_state = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "motion.state");
    gw->policy_rows.motion_count = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "motion.count");
    if (!gw->policy_rows.motion_state || !gw->policy_rows.motion_count)
        return -EINVAL;
    struct plc_commands_config pcc = {
        .motion = cfg->motion,
        .allow_shutdown = cfg->allow_shutdown,
        .robot_handle = cfg->ne_robot_time_limit_ms > 0,
        .robot_time_limit_ms = cfg->ne_robot_time_limit_ms,
        .robot_mot_type = cfg->ne_robot_action,
        .require_robot_handle = cfg->ne_require_robot_handle,
        .gate = gate_command,
        .gate_user = gw,
        .start_sent = on_start_sent,
        .start_answered = on_start_answered,
        .own_unknown = on_own_unknown,
        .sent = on_command_sent,
        .answered = on_command_answered,
        .own_answered = on_own_answered,
        .audit = &gw->audit,
    };
    return plc_commands_init(&gw->commands, &gw->image, &gw->command.queue, &pcc,
                             loop_now_ms, gw->loop);
}

/* The network-exception policy: its rows, its state machine, its timer. */
static int start_policy(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    struct gateway_policy_rows *rows = &gw->policy_rows;
    struct policy_config pc = {
        .time_limit_ms = cfg->ne_time_limit_ms,
        .action = (enum policy_action)cfg->ne_action,
        .watch = (enum policy_watch)(cfg->ne_watch + 1),
        .motion_enable = cfg->ne_motion_enable,
        .single_owner = cfg->ne_single_owner,
        .owner_by_connection = cfg->ne_owner == 1,
        .require_heartbeat = cfg->ne_require_heartbeat,
        .start_unshown_max_ms = cfg->status_timeout_ms,
        .stop_time_ms = cfg->ne_stop_time_ms,
    };
    struct policy_sink sink = {.send_action = send_policy_action,
                               .on_stall = on_loop_stall,
                               .robot = robot_seen,
                               .step = arm_step,
                               .on_reaction = on_reaction,
                               .user = gw};

    rows->fault = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "fault");
    rows->fault_age_ms = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "fault_age_ms");
    rows->faults = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "faults");
    rows->write_owner = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "write_owner");
    rows->motion_enabled = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "motion_enabled");
    rows->heartbeat_state =
        regmap_find_path(&gw->map, REGMAP_SRC_PATH, "plc_heartbeat_state");
    rows->reaction =
        regmap_find_path(&gw->map, REGMAP_SRC_PATH, "network_exception.reaction");
    if (!rows->fault || !rows->fault_age_ms || !rows->faults || !rows->write_owner ||
        !rows->motion_enabled || !rows->heartbeat_state || !rows->reaction)
        return -EINVAL;
    /* A tenth of the limit, 10..100 ms: reactions within limit + period. */
    uint64_t period = cfg->ne_time_limit_ms / 10;
    period = period < 10 ? 10 : period > 100 ? 100 : period;
    pc.check_period_ms = (uint32_t)period;
    policy_init(&gw->policy, &pc, &sink);
    uv_timer_init(gw->loop, &gw->policy_timer);
    gw->policy_timer.data = gw;
    gw->parts |= GATEWAY_PART_POLICY;
    uv_timer_start(&gw->policy_timer, on_policy_timer, period, period);
    return 0;
}


/* The write transaction: every Modbus write, judged before it is answered. */
static int start_writes(struct gateway *gw)
{
    struct plc_write_config wc = {
        .read_only = gw->cfg.read_only,
        .write_allow = gw->cfg.write_allow_addrs,
        .modbus_writes_none = config_writes_from_nobody(&gw->cfg),
    };
    char writes[160];

    /* Who may write, once at start: a gateway that takes writes from any
     * client says so as a warning (the packaged file takes none). */
    config_describe_writes(&gw->cfg, writes, sizeof(writes));
    if (!gw->cfg.read_only && gw->cfg.write_allow_addrs.count == 0 &&
        !config_writes_from_nobody(&gw->cfg))
        log_warn("Modbus writes %s", writes);
    else
        log_notice("Modbus writes %s", writes);
    struct plc_write_hooks hooks = {
        .now_ms = loop_now_ms_of_gateway,
        .robot_may_move = robot_may_move,
        .clear_counters = clear_counters,
        .user = gw,
    };
    int rc = plc_write_init(&gw->writes, &gw->image, &gw->commands, &gw->policy, &wc, &hooks);
    if (rc == 0)
        gw->parts |= GATEWAY_PART_WRITES;
    return rc;
}

/* A number for this start of the gateway (start_id): a PLC that reads
 * another one knows the gateway restarted and lost what it was written.
 * Drawn from the clock and the pid: two starts agree once in 65536. The
 * mix is 64 bits wide on every target (a 32-bit long would lose the
 * seconds' high half, and shifting it by 32 is undefined). */
static unsigned draw_start_id(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    uint64_t mix = (uint64_t)ts.tv_sec * 1000003u ^ (uint64_t)ts.tv_nsec ^
                   (uint64_t)getpid() * 2654435761u;
    return (unsigned)((mix ^ mix >> 16 ^ mix >> 32) & 0xFFFF);
}

/* The self-description values, which never change while running. */
static void set_constant_values(struct gateway *gw)
{
    double *v = gw->gw_values;
    unsigned major = 0, minor = 0, patch = 0;

    sscanf(JAKAGW_VERSION, "%u.%u.%u", &major, &minor, &patch);
    v[GW_map_magic] = REGMAP_MAGIC;
    v[GW_start_id] = draw_start_id();
    v[GW_map_version] = REGMAP_VERSION;
    v[GW_map_crc] = gw->map.crc;
    v[GW_word_order] = gw->image.word_order;
    v[GW_address_base] = 0;
    v[GW_probe_f32] = REGMAP_PROBE_F32;
    v[GW_probe_u32] = REGMAP_PROBE_U32;
    v[GW_version_major] = major;
    v[GW_version_minor] = minor;
    v[GW_version_patch] = patch;
}

/* [rtu] enabled: the serial line, one more client of the Modbus server. */
static int start_rtu(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    int rc;

    if (!cfg->rtu_enabled)
        return 0;
    struct mb_rtu_config rc_cfg = {
        .device = cfg->rtu_device,
        .baud = cfg->rtu_baud,
        .parity = (enum mb_rtu_parity)cfg->rtu_parity,
        .stop_bits = cfg->rtu_stop_bits,
        .unit_id = cfg->rtu_unit_id,
        .rs485 = cfg->rtu_rs485,
        .local_echo = cfg->rtu_local_echo,
        .delivery_ms = cfg->rtu_delivery_ms,
        .rights = cfg->rtu_rights_mask,
        .active_ms = cfg->ne_time_limit_ms,
    };
    gw->parts |= GATEWAY_PART_RTU;
    rc = mb_rtu_start(gw->loop, &gw->rtu, &gw->modbus, &rc_cfg);
    if (rc == -ENOTTY)
        gw->config_error = true;
    return rc;
}

static uint32_t rights_for_role(void *user, const char *role, bool valid, bool *listed)
{
    struct gateway *gw = user;
    return config_role_rights(&gw->cfg, role, valid, listed);
}

/* The Modbus/TCP Security listener, when [tls] enabled. */
static int start_mbaps(struct gateway *gw)
{
    const struct gw_config *cfg = &gw->cfg;
    struct tls_context *ctx;
    char why[600];
    int rc;

    if (!cfg->tls_enabled)
        return 0;
    rc = gw_tls_server_context(cfg, &ctx, why, sizeof(why));
    if (rc) {
        log_err("mbaps: %s", why);
        return rc;
    }
    struct mb_tls_config tc = {
        .handshake_timeout_ms = cfg->tls_handshake_timeout_ms,
        .max_handshakes = cfg->tls_max_handshakes,
        .rights_for_role = rights_for_role,
        .user = gw,
    };
    gw->mbaps = calloc(1, sizeof(*gw->mbaps));
    if (!gw->mbaps) {
        tls_context_unref(ctx);
        return -ENOMEM;
    }
    rc = mb_tls_init(gw->mbaps, ctx, &tc);
    if (rc) {
        tls_context_unref(ctx);
        return rc;
    }
    log_notice("mbaps: certificate \"%s\"; TLS %s and later; clients must chain to %s%s%s",
               tls_context_subject(ctx), cfg->tls_min_version ? "1.3" : "1.2",
               cfg->tls_client_ca, cfg->tls_crl[0] ? ", CRL " : "", cfg->tls_crl);
    return mb_server_listen(&gw->modbus, cfg->tls_bind[0] ? cfg->tls_bind : cfg->modbus_bind,
                            (uint16_t)cfg->tls_port, cfg->tls_listen_fd, &mb_transport_tls,
                            gw->mbaps);
}

int gateway_start(uv_loop_t *loop, struct gateway *gw, const struct gw_config *cfg)
{
    int rc;

    memset(gw, 0, sizeof(*gw));
    gw->loop = loop;
    gw->cfg = *cfg;
    gw->started_ms = uv_now(loop);
    /* No status yet: stale from the start, so that a robot never reached
     * is an outage like any other. */
    gw->status_stale_since_ms = gw->started_ms ? gw->started_ms : 1;
    gw->parse_log_limit.interval_ms = 5000;
    gw->command_log_limit.interval_ms = 5000;
    rc = regmap_init(&gw->map);
    if (rc)
        return rc;
    rc = regmap_image_init(&gw->image, &gw->map, (enum regmap_word_order)cfg->word_order);
    if (rc)
        return rc;
    struct audit_clock clock = {.now_ms = loop_now_ms, .user = loop};
    audit_init(&gw->audit, &clock, NULL);
    gw->status = &gw->status_buffers[0];
    gw->scratch = &gw->status_buffers[1];
    /* Nothing received yet: every value reads as absent. */
    regmap_encode_status(&gw->image, gw->status);
    set_constant_values(gw);
    rc = start_commands(gw);
    if (rc)
        return rc;
    rc = start_policy(gw);
    if (rc)
        return rc;
    rc = start_writes(gw);
    if (rc)
        return rc;
    gateway_refresh_values(gw);

    struct mb_server_config mc = {
        .bind = cfg->modbus_bind,
        .port = (uint16_t)cfg->modbus_port,
        .max_clients = cfg->max_clients,
        .idle_timeout_ms = cfg->idle_timeout_ms,
        .frame_timeout_ms = cfg->frame_timeout_ms,
        .unit_id = cfg->unit_id,
        .listen_fd = cfg->modbus_listen_fd,
        .no_plain = !cfg->modbus_enabled,
    };
    struct mb_server_hooks hooks = {
        .before_request = before_request,
        .on_write = on_write,
        .on_write_refused = on_write_refused,
        .on_client = on_client,
        .after_write = after_write,
        .is_running = is_running,
        .user = gw,
    };
    gw->parts |= GATEWAY_PART_MODBUS;
    rc = mb_server_start(loop, &gw->modbus, &mc, &gw->image, &hooks);
    if (rc)
        return rc;
    rc = start_mbaps(gw);
    if (rc)
        return rc;
    rc = start_rtu(gw);
    if (rc)
        return rc;
    rc = start_links(gw);
    if (rc)
        return rc;
    rc = start_can(gw);
    if (rc)
        return rc;
    return 0;
}

static void part_closed(struct gateway *gw)
{
    if (--gw->closing_parts > 0)
        return;
    /* The commands failed by the links' close are in: the last counts. */
    audit_finish(&gw->audit);
    if (gw->parts & GATEWAY_PART_WRITES)
        plc_write_free(&gw->writes);
    if (gw->mbaps) {
        mb_tls_free(gw->mbaps);
        free(gw->mbaps);
        gw->mbaps = NULL;
    }
    plc_commands_free(&gw->commands);
    regmap_image_free(&gw->image);
    regmap_free(&gw->map);
    if (gw->close_cb)
        gw->close_cb(gw);
}

static void on_link_closed(struct robot_link *link)
{
    part_closed(link->user);
}

static void on_policy_timer_closed(uv_handle_t *h)
{
    part_closed(h->data);
}

static void on_command_port_closed(struct command_port *cp)
{
    part_closed(cp->user);
}

static void on_server_closed(struct mb_server *srv)
{
    part_closed(srv->hooks.user);
}

static void on_can_closed(struct can_mirror *m)
{
    part_closed(m->user);
}

static void on_rtu_closed(struct mb_rtu *rtu)
{
    part_closed(rtu->user);
}

static void on_http_closed(struct http_server *srv)
{
    part_closed(srv->user);
}

void gateway_close(struct gateway *gw, void (*cb)(struct gateway *gw))
{
    gw->close_cb = cb;
    /* Held until every close is issued: a part may finish synchronously. */
    gw->closing_parts = 1;
    if (gw->parts & GATEWAY_PART_MODBUS) {
        gw->closing_parts++;
        /* Requests that have arrived are answered before the clients go. */
        mb_server_shutdown(&gw->modbus, on_server_closed);
    }
    if (gw->parts & GATEWAY_PART_STATUS_LINK) {
        gw->closing_parts++;
        robot_link_close(&gw->status_link, on_link_closed);
    }
    if (gw->parts & GATEWAY_PART_COMMAND_LINK) {
        gw->closing_parts++;
        command_port_close(&gw->command, on_command_port_closed);
    }
    if (gw->parts & GATEWAY_PART_POLICY) {
        gw->closing_parts++;
        uv_close((uv_handle_t *)&gw->policy_timer, on_policy_timer_closed);
    }
    if (gw->parts & GATEWAY_PART_CAN) {
        gw->closing_parts++;
        can_mirror_close(&gw->can, on_can_closed);
    }
    if (gw->parts & GATEWAY_PART_RTU) {
        /* After the server's shutdown began: the line's client has had
         * its answers. */
        gw->closing_parts++;
        gw->rtu.user = gw;
        mb_rtu_close(&gw->rtu, on_rtu_closed);
    }
    if (gw->parts & GATEWAY_PART_HTTP) {
        gw->closing_parts++;
        http_server_close(&gw->http, on_http_closed);
    }
    part_closed(gw);
}
