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

/* Sends 'action', or keeps it owed when it cannot go out now. */
static void act(struct policy *p, enum policy_action action)
{
    if (action == POLICY_KEEP || !p->sink.send_action)
        return;
    if (p->sink.send_action(p->sink.user, action, p->fault))
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
    act(p, action);
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
        act(p, POLICY_PAUSE);
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
            act(p, p->owed);
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
