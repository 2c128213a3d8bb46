/* SPDX-License-Identifier: MIT */
/* policy.c - the network-exception policy's state machine (policy.h). */
#include "policy.h"

#include <errno.h>

#include <modbus.h>
#include <stdio.h>
#include <string.h>

void policy_init(struct policy *p, const struct policy_config *cfg,
                 const struct policy_sink *sink)
{
    memset(p, 0, sizeof(*p));
    p->cfg = *cfg;
    p->sink = *sink;
}

const char *policy_fault_name(enum policy_fault reason)
{
    static const char *const names[] = {"none", "PLC heartbeat lost", "no Modbus client",
                                        "motion enable dropped", "gateway loop stalled"};
    return (unsigned)reason < sizeof(names) / sizeof(names[0]) ? names[reason] : "unknown";
}

const char *policy_reaction_name(enum policy_reaction reaction)
{
    static const char *const names[] = {
        "nothing due",     "flag only (action keep)", "action sent, awaiting the status",
        "paused",          "stopped",                 "still moving: stop sent",
        "still moving after the stop"};
    return (unsigned)reaction < sizeof(names) / sizeof(names[0]) ? names[reaction] : "unknown";
}

/*
 * Every entry point that is given the time passes it here first: a gap
 * since the last longer than time_limit_ms is the gateway's stall. The
 * PLC's clocks move on by the gap, so that what the PLC could not be heard
 * saying meanwhile is not held against it.
 */
static void see_time(struct policy *p, uint64_t now_ms)
{
    uint64_t gap = p->last_seen_ms && now_ms > p->last_seen_ms ? now_ms - p->last_seen_ms : 0;

    if (now_ms > p->last_seen_ms)
        p->last_seen_ms = now_ms;
    if (gap <= p->cfg.time_limit_ms) {
        /* A late turn, no stall: libuv runs its timers before it polls,
         * so the heartbeat sent meanwhile is still in the socket. The
         * timed verdicts wait for a later call (limit_passed). */
        if (p->cfg.check_period_ms && gap > 2 * (uint64_t)p->cfg.check_period_ms) {
            p->late_turn_ms = now_ms;
            p->late_turn_from_ms = now_ms - gap;
        }
        return;
    }
    /* A stall is a late turn too: the status documents that say whether
     * the robot ran are in their socket, and the status looks stale until
     * they are read, so the stall is judged by a later call (lost_signals):
     * an idle robot is then seen idle, not assumed to move. */
    if (p->cfg.check_period_ms) {
        p->late_turn_ms = now_ms;
        p->late_turn_from_ms = now_ms - gap;
    }
    p->heartbeat_ms += gap;
    p->no_client_since_ms += gap;
    p->start_answered_ms += gap;
    p->stalls++;
    p->last_stall_ms = gap;
    p->stall_pending = true;
    if (p->sink.on_stall)
        p->sink.on_stall(p->sink.user, gap);
}

/*
 * Has the loop read its input since its last late turn (or stall)? Its
 * timers run first; the next check period's tick comes after a poll. The
 * calls in between (a write read in that poll) may come before the input
 * that matters (another client's heartbeat, the status documents).
 */
static bool heard_since_late_turn(const struct policy *p, uint64_t now_ms)
{
    return p->late_turn_ms == 0 || now_ms >= p->late_turn_ms + p->cfg.check_period_ms;
}

/*
 * Has the time limit passed since 'since_ms' (the heartbeat's last change,
 * the last client's close)? In a late turn's own calls, only if it had
 * passed already when the late gap began: what the PLC sent meanwhile is
 * still in a socket, read after the turn's timers. A loop late on every
 * turn is thus judged one turn late, never not at all.
 */
static bool limit_passed(const struct policy *p, uint64_t now_ms, uint64_t since_ms)
{
    if (now_ms - since_ms < p->cfg.time_limit_ms)
        return false;
    if (heard_since_late_turn(p, now_ms))
        return true;
    return p->late_turn_from_ms >= since_ms &&
           p->late_turn_from_ms - since_ms >= p->cfg.time_limit_ms;
}

static bool heartbeat_expired(const struct policy *p, uint64_t now_ms)
{
    return p->heartbeat_armed && limit_passed(p, now_ms, p->heartbeat_ms);
}

static void clear_owner(struct policy *p)
{
    p->owner = 0;
    p->owner_address[0] = '\0';
    p->owner_host[0] = '\0';
    p->owner_transport[0] = '\0';
}

/* The address alone of "address:port" (the port after the last colon;
 * an RTU line's name has none, and is kept whole). */
static void host_of(const char *peer, char *out, size_t size)
{
    const char *colon = strrchr(peer, ':');
    snprintf(out, size, "%.*s", colon ? (int)(colon - peer) : (int)strlen(peer), peer);
}

int policy_may_write_via(const struct policy *p, uint64_t client, const char *peer,
                         const char *transport)
{
    if (!p->cfg.single_owner || p->owner == 0 || p->owner == client)
        return 0;
    /* A plain connection never shares a TLS owner's rights (nor the
     * reverse): the same address is not the same PLC across transports. */
    bool same_transport = !transport || !p->owner_transport[0] ||
                          strcmp(transport, p->owner_transport) == 0;
    if (!p->cfg.owner_by_connection && peer && p->owner_host[0] && same_transport) {
        char host[64];
        host_of(peer, host, sizeof(host));
        if (strcmp(host, p->owner_host) == 0)
            return 0; /* the owner PLC's other connection */
    }
    return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
}

int policy_may_write_from(const struct policy *p, uint64_t client, const char *peer)
{
    return policy_may_write_via(p, client, peer, NULL);
}

int policy_may_feed_heartbeat(const struct policy *p, uint64_t client)
{
    if (!p->cfg.single_owner || p->owner == 0 || p->owner == client)
        return 0;
    return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
}

void policy_owner_transport(struct policy *p, uint64_t client, const char *transport)
{
    if (p->owner != 0 && p->owner == client && transport)
        snprintf(p->owner_transport, sizeof(p->owner_transport), "%s", transport);
}

int policy_may_write(const struct policy *p, uint64_t client)
{
    return policy_may_write_from(p, client, NULL);
}

void policy_heartbeat(struct policy *p, uint64_t now_ms, uint64_t client,
                      const char *address, double value)
{
    see_time(p, now_ms);
    /* Only a change counts: a PLC stuck writing the same value is silent.
     * The register reads 0 at start: a first 0 is no change. */
    if (value != p->heartbeat_value)
        p->heartbeat_changed = true;
    if (!p->heartbeat_armed || value != p->heartbeat_value) {
        p->heartbeat_ms = now_ms;
        p->heartbeat_armed = true;
    }
    p->heartbeat_value = value;
    if (p->cfg.single_owner && p->owner == 0) {
        p->owner = client;
        snprintf(p->owner_address, sizeof(p->owner_address), "%s", address);
        host_of(address, p->owner_host, sizeof(p->owner_host));
    }
}

enum policy_heartbeat_state policy_heartbeat_state(const struct policy *p, uint64_t now_ms)
{
    if (!p->heartbeat_changed)
        return POLICY_HEARTBEAT_NEVER;
    return now_ms - p->heartbeat_ms >= p->cfg.time_limit_ms ? POLICY_HEARTBEAT_LOST
                                                            : POLICY_HEARTBEAT_RUNNING;
}

void policy_client_opened(struct policy *p, uint64_t now_ms, unsigned clients)
{
    see_time(p, now_ms);
    p->clients = clients;
    p->connection_armed = true;
}

void policy_client_closed(struct policy *p, uint64_t now_ms, uint64_t client,
                          unsigned clients)
{
    see_time(p, now_ms);
    p->clients = clients;
    if (clients == 0)
        p->no_client_since_ms = now_ms;
    if (client == p->owner)
        clear_owner(p);
}

static enum policy_robot robot_seen(const struct policy *p)
{
    return p->sink.robot ? p->sink.robot(p->sink.user) : POLICY_ROBOT_UNKNOWN;
}

static void set_reaction(struct policy *p, uint64_t now_ms, enum policy_reaction reaction)
{
    if (reaction == p->reaction)
        return;
    p->reaction = reaction;
    if (p->sink.on_reaction)
        p->sink.on_reaction(p->sink.user, reaction, p->reaction_action,
                            p->reaction_answered ? now_ms - p->reaction_answered_ms : 0);
}

/*
 * Sends 'action' for 'reason', or keeps it owed when it cannot go out now.
 * Either way its check starts again: the status after its reply decides.
 */
static void act(struct policy *p, uint64_t now_ms, enum policy_action action,
                enum policy_fault reason)
{
    if (action == POLICY_KEEP || !p->sink.send_action)
        return;
    p->reaction_action = action;
    p->reaction_answered = false;
    p->reaction_min_step = -1;
    if (p->reaction != POLICY_REACTION_ESCALATED)
        set_reaction(p, now_ms, POLICY_REACTION_SENT);
    p->reaction_lost = false;
    if (p->sink.send_action(p->sink.user, action, reason)) {
        p->owed = POLICY_KEEP;
    } else {
        p->reaction_lost = true; /* nothing in flight to judge */
        if (action > p->owed)
            p->owed = action; /* stop outranks pause */
    }
}

/*
 * The action for 'configured' now: a pause becomes a stop whenever the arm
 * may run a move outside a program, which pause_program leaves running.
 */
static enum policy_action choose_action(const struct policy *p, uint64_t now_ms,
                                        enum policy_action configured)
{
    if (configured != POLICY_PAUSE)
        return configured;
    switch (robot_seen(p)) {
    case POLICY_ROBOT_MOVING:
        return POLICY_STOP; /* moving, no program: a move */
    case POLICY_ROBOT_PROGRAM:
        return POLICY_PAUSE;
    case POLICY_ROBOT_UNKNOWN:
        /* Blind: what the gateway itself started last decides. */
        return p->last_start_move ? POLICY_STOP : POLICY_PAUSE;
    default:
        /* Still as far as the status shows: a move just sent may not
         * show yet. */
        return p->last_start_move && policy_start_unshown(p, now_ms) ? POLICY_STOP
                                                                       : POLICY_PAUSE;
    }
}

static void latch(struct policy *p, uint64_t now_ms, enum policy_fault reason,
                  enum policy_action action)
{
    p->fault = reason;
    p->fault_since_ms = now_ms;
    p->faults++;
    if (action == POLICY_KEEP) {
        set_reaction(p, now_ms, POLICY_REACTION_FLAG_ONLY);
        return;
    }
    act(p, now_ms, choose_action(p, now_ms, action), reason);
}

void policy_action_answered(struct policy *p, uint64_t now_ms, bool accepted)
{
    if (p->reaction != POLICY_REACTION_SENT && p->reaction != POLICY_REACTION_ESCALATED)
        return;
    p->reaction_answered = true;
    p->reaction_answered_ms = now_ms;
    p->reaction_min_step = -1;
    p->reaction_refused = !accepted;
}

uint64_t policy_status_period_ms(const struct policy *p)
{
    return p->status_period_ms;
}

/*
 * Is the arm stopping? Within the stopping time, an arm that moves no
 * faster than it has since the action's reply is braking; unknown steps
 * (no joints in the status) leave it to the stopping time. The smallest
 * step seen is kept: speeding up is measured from it, with a tenth and
 * 0.005 deg of room for the documents' rounding.
 */
static bool arm_slowing(struct policy *p)
{
    double step = p->sink.step ? p->sink.step(p->sink.user) : -1;

    if (!(step >= 0) || p->last_document_ms <= p->reaction_answered_ms)
        return true;
    if (p->reaction_min_step < 0 || step < p->reaction_min_step)
        p->reaction_min_step = step;
    return step <= p->reaction_min_step * 1.1 + 0.005;
}

/*
 * The action's check, at every check period: once its reply came, a
 * status document received after the reply showing the arm still ends it
 * (paused, or stopped); an arm braking within the stopping time is left
 * to stop; otherwise none by one status period after the reply sends
 * stop_program once more, and a second miss is final.
 */
static void judge_reaction(struct policy *p, uint64_t now_ms)
{
    if ((p->reaction != POLICY_REACTION_SENT && p->reaction != POLICY_REACTION_ESCALATED) ||
        !p->reaction_answered)
        return;
    enum policy_robot robot = robot_seen(p);
    if ((robot == POLICY_ROBOT_STILL || robot == POLICY_ROBOT_PAUSED) &&
        p->last_document_ms > p->reaction_answered_ms) {
        set_reaction(p, now_ms,
                     robot == POLICY_ROBOT_PAUSED ? POLICY_REACTION_PAUSED
                                                  : POLICY_REACTION_STOPPED);
        return;
    }
    /* Before two documents, the check period stands for the period. */
    uint64_t period = p->status_period_ms > p->cfg.check_period_ms ? p->status_period_ms
                                                                   : p->cfg.check_period_ms;
    bool slowing = arm_slowing(p);
    if (now_ms < p->reaction_answered_ms + period)
        return;
    /* Braking is stopping (after a stop the robot accepted: a refused one
     * stops nothing); the document showing the arm at rest comes up to one
     * period after it stopped. */
    if (slowing && !p->reaction_refused && p->cfg.stop_time_ms > 0 &&
        now_ms < p->reaction_answered_ms + p->cfg.stop_time_ms + period)
        return;
    if (p->reaction == POLICY_REACTION_ESCALATED) {
        set_reaction(p, now_ms, POLICY_REACTION_STILL_MOVING);
        return;
    }
    set_reaction(p, now_ms, POLICY_REACTION_ESCALATED);
    act(p, now_ms, POLICY_STOP, p->fault);
}

int policy_may_reset(const struct policy *p, char *why, size_t why_size)
{
    if (p->fault == POLICY_FAULT_NONE)
        return 0;
    /* An action lost with its link (owed again while the robot may move)
     * has no reply to judge it by: the arm's stillness decides below. */
    if ((p->reaction == POLICY_REACTION_SENT || p->reaction == POLICY_REACTION_ESCALATED) &&
        !p->reaction_lost) {
        snprintf(why, why_size, "reaction still judged: wait");
        return -EBUSY;
    }
    /* With nothing sent (action keep, or the robot idle at the fault)
     * there is no stop to cancel. */
    if (p->reaction == POLICY_REACTION_NONE || p->reaction == POLICY_REACTION_FLAG_ONLY)
        return 0;
    if (robot_seen(p) == POLICY_ROBOT_MOVING) {
        snprintf(why, why_size, "arm still moving: wait");
        return -EBUSY;
    }
    return 0;
}

void policy_action_unknown(struct policy *p, enum policy_action action)
{
    if (p->fault == POLICY_FAULT_NONE || action == POLICY_KEEP)
        return;
    p->reaction_lost = true; /* no reply will come to judge it by */
    if (action > p->owed)
        p->owed = action; /* stop outranks pause */
}

void policy_reset(struct policy *p)
{
    p->fault = POLICY_FAULT_NONE;
    p->fault_since_ms = 0;
    p->owed = POLICY_KEEP;
    p->reaction = POLICY_REACTION_NONE;
    p->reaction_answered = false;
}

#define START_UNSHOWN_MAX_MS_DEFAULT 10000

void policy_start_sent(struct policy *p, uint64_t now_ms)
{
    see_time(p, now_ms);
    p->starts_unanswered++;
}

void policy_start_kind(struct policy *p, bool move)
{
    p->last_start_move = move;
}

void policy_start_answered(struct policy *p, uint64_t now_ms)
{
    see_time(p, now_ms);
    if (p->starts_unanswered > 0)
        p->starts_unanswered--;
    if (p->starts_unanswered == 0) {
        p->start_unshown = true;
        p->start_answered_ms = now_ms;
    }
}

/* The longest interval of the last documents, decaying by an eighth a
 * document: one late push is allowed for a while. A gap of more than four
 * periods is an outage (the status stale meanwhile), not the period. */
static void measure_status_period(struct policy *p, uint64_t now_ms)
{
    if (p->last_document_ms && now_ms > p->last_document_ms) {
        uint64_t interval = now_ms - p->last_document_ms;
        if (p->status_period_ms == 0 || interval <= 4 * p->status_period_ms)
            p->status_period_ms = interval >= p->status_period_ms
                                      ? interval
                                      : (p->status_period_ms * 7 + interval) / 8;
    }
    p->last_document_ms = now_ms;
}

void policy_status_document(struct policy *p, uint64_t now_ms)
{
    see_time(p, now_ms);
    measure_status_period(p, now_ms);
    /* Only a document received well after the reply can show the start: a
     * controller answers before its next status push reflects the new
     * program state, and jakasim's 8 ms push is no promise for a real
     * one, so the first documents after the reply prove nothing. */
    if (p->starts_unanswered == 0 && p->start_unshown &&
        now_ms >= p->start_answered_ms + POLICY_START_SETTLE_MS)
        p->start_unshown = false;
}

bool policy_start_unshown(const struct policy *p, uint64_t now_ms)
{
    uint32_t max = p->cfg.start_unshown_max_ms ? p->cfg.start_unshown_max_ms
                                               : START_UNSHOWN_MAX_MS_DEFAULT;
    /* Unanswered, it may start any moment: the command queue bounds that
     * (a reply, a reply timeout or the link's loss answers every one). */
    if (p->starts_unanswered > 0)
        return true;
    return p->start_unshown && now_ms - p->start_answered_ms < max;
}

/* Does the robot run, or may it run: what the status shows, or a start
 * sent that it cannot show yet. */
static bool may_run(const struct policy *p, uint64_t now_ms, bool robot_moving)
{
    return robot_moving || policy_start_unshown(p, now_ms);
}

#define LOST(reason) (1u << (reason))

/*
 * The one rule for every watched signal: which are lost now, as a set of
 * LOST(reason). A signal counts only once armed (a first heartbeat change,
 * a first client, a first 1 on the motion-enable coil), and is judged as a
 * level, never as an edge.
 */
static unsigned lost_signals(const struct policy *p, uint64_t now_ms, bool stall_now)
{
    unsigned lost = 0;

    if ((p->cfg.watch & POLICY_WATCH_HEARTBEAT) && heartbeat_expired(p, now_ms))
        lost |= LOST(POLICY_FAULT_HEARTBEAT);
    if ((p->cfg.watch & POLICY_WATCH_CONNECTION) && p->connection_armed &&
        p->clients == 0 && limit_passed(p, now_ms, p->no_client_since_ms))
        lost |= LOST(POLICY_FAULT_NO_CLIENT);
    if (p->cfg.motion_enable && p->motion_enable_armed && !p->motion_enabled)
        lost |= LOST(POLICY_FAULT_MOTION_ENABLE);
    if (p->stall_pending && (stall_now || heard_since_late_turn(p, now_ms)))
        lost |= LOST(POLICY_FAULT_GATEWAY_STALL);
    return lost;
}

/* Motion enable's own action is always pause; the others' is configured. */
static enum policy_action action_for(const struct policy *p, enum policy_fault reason)
{
    return reason == POLICY_FAULT_MOTION_ENABLE ? POLICY_PAUSE : p->cfg.action;
}

/*
 * Applies the rule: signals lost while the robot runs or may run latch the
 * first of them (in the order of enum policy_fault) and send the strongest
 * of their actions. Under a latched fault nothing is repeated, except
 * motion enable's pause, once per drop.
 */
static void apply_rule(struct policy *p, uint64_t now_ms, bool running, bool stall_now)
{
    unsigned lost = lost_signals(p, now_ms, stall_now);

    /* A stall is an event, judged once: by the first rule that sees it. */
    if (lost & LOST(POLICY_FAULT_GATEWAY_STALL))
        p->stall_pending = false;
    if (lost == 0 || !running)
        return;
    if (p->fault == POLICY_FAULT_NONE) {
        enum policy_fault first = POLICY_FAULT_NONE;
        enum policy_action action = POLICY_KEEP;
        for (enum policy_fault r = POLICY_FAULT_HEARTBEAT; r <= POLICY_FAULT_GATEWAY_STALL;
             r++) {
            if (!(lost & LOST(r)))
                continue;
            if (first == POLICY_FAULT_NONE)
                first = r;
            if (action_for(p, r) > action)
                action = action_for(p, r); /* stop outranks pause */
        }
        if (lost & LOST(POLICY_FAULT_MOTION_ENABLE))
            p->motion_enable_paused = true;
        latch(p, now_ms, first, action);
        return;
    }
    if ((lost & LOST(POLICY_FAULT_MOTION_ENABLE)) && !p->motion_enable_paused) {
        /* Its own reason, not the latched one's: the log says why. */
        p->motion_enable_paused = true;
        act(p, now_ms, choose_action(p, now_ms, POLICY_PAUSE), POLICY_FAULT_MOTION_ENABLE);
    }
}

void policy_motion_enable(struct policy *p, uint64_t now_ms, bool value,
                          bool robot_moving)
{
    see_time(p, now_ms);
    p->motion_enabled = value;
    if (value) {
        p->motion_enable_armed = true;
        p->motion_enable_paused = false; /* the next drop pauses again */
        return;
    }
    /* Idle, nothing to pause: the coil at 0 already keeps programs and
     * motion from starting (policy_gate_command). Running or about to,
     * it pauses at once, whatever fault is latched already. */
    apply_rule(p, now_ms, may_run(p, now_ms, robot_moving), false);
}

void policy_check(struct policy *p, uint64_t now_ms, bool robot_moving)
{
    see_time(p, now_ms);
    bool running = may_run(p, now_ms, robot_moving);

    /* An owner whose heartbeat expired gives the write side up. */
    if (p->owner && heartbeat_expired(p, now_ms))
        clear_owner(p);
    /* Latched: an action that could not go out is tried again while the
     * robot may move. */
    if (p->fault != POLICY_FAULT_NONE && p->owed != POLICY_KEEP && running)
        act(p, now_ms, p->owed, p->fault);
    apply_rule(p, now_ms, running, false);
    judge_reaction(p, now_ms);
}

bool policy_blocks_commands(const struct policy *p)
{
    return p->fault != POLICY_FAULT_NONE ||
           (p->cfg.motion_enable && !p->motion_enabled);
}

uint64_t policy_fault_age_ms(const struct policy *p, uint64_t now_ms)
{
    return p->fault == POLICY_FAULT_NONE ? 0 : now_ms - p->fault_since_ms;
}

bool policy_robot_may_move(bool status_fresh, const struct jaka_status *status)
{
    if (!status_fresh || !status)
        return true; /* blind: assume the worst */
    const struct status_num *inpos = status_num_at(status, STATUS_F_inpos, 0);
    const struct status_num *interp = status_num_at(status, STATUS_F_interp_state, 0);
    /* interp_state 1 loading, 3 running: a program may move the arm. */
    bool running = interp->present && (interp->value == 1 || interp->value == 3);
    return running || (inpos->present && inpos->value == 0);
}

bool policy_command_starts_motion(const struct cmd_def *def)
{
    /* Unknown to the table: judged as motion. */
    return !def || (def->flags & (CMD_MOTION | CMD_STARTS_MOTION));
}

int policy_gate_command(struct policy *p, uint64_t now_ms, const struct cmd_def *def,
                        char *why, size_t size)
{
    see_time(p, now_ms);
    if (def && strcmp(def->name, "stop_program") == 0)
        return 0; /* stopping is never refused */
    if (p->fault != POLICY_FAULT_NONE) {
        /* Every reason fits a result's 40 bytes (20 registers) whole. */
        snprintf(why, size, "fault %d latched: reset it first", p->fault);
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    if (!policy_command_starts_motion(def))
        return 0;
    /* A PLC that never fed the heartbeat would run the robot unwatched. */
    if (p->cfg.require_heartbeat && !p->heartbeat_changed) {
        snprintf(why, size, "heartbeat not started");
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    /* A start right after a stall is judged with it at once: the PLC
     * asks the robot to run before the gateway knows what it did. */
    unsigned lost = lost_signals(p, now_ms, true);
    if (lost) {
        /* The PLC asks the robot to run without the signal: the rule as
         * if the start had gone out, so the outcome does not depend on
         * whether the start came before or after the loss. */
        apply_rule(p, now_ms, true, true);
        snprintf(why, size, "%s: fault %d latched", policy_fault_name(p->fault), p->fault);
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    if (policy_blocks_commands(p)) {
        snprintf(why, size, "motion enable is 0");
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    return 0;
}
