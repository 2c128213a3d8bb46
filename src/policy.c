/* SPDX-License-Identifier: MIT */
/* policy.c - the network-exception policy's state machine (policy.h). */
#include "policy.h"

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

static bool heartbeat_expired(const struct policy *p, uint64_t now_ms)
{
    return p->heartbeat_armed && now_ms - p->heartbeat_ms >= p->cfg.time_limit_ms;
}

static void clear_owner(struct policy *p)
{
    p->owner = 0;
    p->owner_address[0] = '\0';
}

int policy_may_write(const struct policy *p, uint64_t client)
{
    if (!p->cfg.single_owner || p->owner == 0 || p->owner == client)
        return 0;
    return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
}

void policy_heartbeat(struct policy *p, uint64_t now_ms, uint64_t client,
                      const char *address, double value)
{
    /* Only a change counts: a PLC stuck writing the same value is silent. */
    if (!p->heartbeat_armed || value != p->heartbeat_value) {
        p->heartbeat_ms = now_ms;
        p->heartbeat_armed = true;
    }
    p->heartbeat_value = value;
    if (p->cfg.single_owner && p->owner == 0) {
        p->owner = client;
        snprintf(p->owner_address, sizeof(p->owner_address), "%s", address);
    }
}

void policy_client_opened(struct policy *p, uint64_t now_ms, unsigned clients)
{
    (void)now_ms;
    p->clients = clients;
    p->connection_armed = true;
}

void policy_client_closed(struct policy *p, uint64_t now_ms, uint64_t client,
                          unsigned clients)
{
    p->clients = clients;
    if (clients == 0)
        p->no_client_since_ms = now_ms;
    if (client == p->owner)
        clear_owner(p);
}

/* Sends 'action' for 'reason', or keeps it owed when it cannot go out now. */
static void act(struct policy *p, enum policy_action action, enum policy_fault reason)
{
    if (action == POLICY_KEEP || !p->sink.send_action)
        return;
    if (p->sink.send_action(p->sink.user, action, reason))
        p->owed = POLICY_KEEP;
    else if (action > p->owed)
        p->owed = action; /* stop outranks pause */
}

static void latch(struct policy *p, uint64_t now_ms, enum policy_fault reason,
                  enum policy_action action)
{
    p->fault = reason;
    p->fault_since_ms = now_ms;
    p->faults++;
    act(p, action, reason);
}

void policy_motion_enable(struct policy *p, uint64_t now_ms, bool value,
                          bool robot_moving)
{
    bool dropped = p->motion_enabled && !value;

    p->motion_enabled = value;
    /* Idle, nothing to pause: the coil at 0 already keeps programs and
     * motion from starting (policy_blocks_commands). Moving, it pauses at
     * once, whatever fault is latched already. */
    if (!p->cfg.motion_enable || !dropped || !robot_moving)
        return;
    if (p->fault == POLICY_FAULT_NONE)
        latch(p, now_ms, POLICY_FAULT_MOTION_ENABLE, POLICY_PAUSE);
    else
        act(p, POLICY_PAUSE, POLICY_FAULT_MOTION_ENABLE); /* its own reason, not the old one's */
}

void policy_reset(struct policy *p)
{
    p->fault = POLICY_FAULT_NONE;
    p->fault_since_ms = 0;
    p->owed = POLICY_KEEP;
}

/* Which watched signal is lost now, if any. */
static enum policy_fault lost_signal(const struct policy *p, uint64_t now_ms)
{
    if ((p->cfg.watch & POLICY_WATCH_HEARTBEAT) && heartbeat_expired(p, now_ms))
        return POLICY_FAULT_HEARTBEAT;
    if ((p->cfg.watch & POLICY_WATCH_CONNECTION) && p->connection_armed &&
        p->clients == 0 && now_ms - p->no_client_since_ms >= p->cfg.time_limit_ms)
        return POLICY_FAULT_NO_CLIENT;
    return POLICY_FAULT_NONE;
}

void policy_check(struct policy *p, uint64_t now_ms, bool robot_moving)
{
    /* An owner whose heartbeat expired gives the write side up. */
    if (p->owner && heartbeat_expired(p, now_ms))
        clear_owner(p);
    if (p->fault != POLICY_FAULT_NONE) {
        /* Latched: the action went out once and is never repeated; one
         * that could not go out is tried again while the robot may move. */
        if (p->owed != POLICY_KEEP && robot_moving)
            act(p, p->owed, p->fault);
        return;
    }
    enum policy_fault lost = lost_signal(p, now_ms);
    if (lost != POLICY_FAULT_NONE && robot_moving)
        latch(p, now_ms, lost, p->cfg.action);
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

int policy_gate_command(const struct policy *p, const struct cmd_def *def, char *why,
                        size_t size)
{
    /* Unknown to the table: judged as motion. */
    unsigned flags = def ? def->flags : CMD_MOTION;

    if (def && strcmp(def->name, "stop_program") == 0)
        return 0; /* stopping is never refused */
    if (p->fault != POLICY_FAULT_NONE) {
        snprintf(why, size, "network-exception fault %d latched: reset it first", p->fault);
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    if ((flags & (CMD_MOTION | CMD_STARTS_MOTION)) && policy_blocks_commands(p)) {
        snprintf(why, size, "motion enable is 0");
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    return 0;
}
