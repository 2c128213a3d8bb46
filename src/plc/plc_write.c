/* SPDX-License-Identifier: MIT */
/* plc_write.c - a PLC's write as one transaction (plc_write.h). */
#include "plc_write.h"

#include "audit.h"
#include "log.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

static const struct regmap_row *find_gw_row(const struct regmap *map, int id)
{
    for (unsigned r = 0; r < map->row_count; r++)
        if (map->rows[r].source == REGMAP_SRC_GW && map->rows[r].id == id &&
            map->rows[r].writable)
            return &map->rows[r];
    return NULL;
}

int plc_write_init(struct plc_write *pw, struct regmap_image *img,
                   struct plc_commands *commands, struct policy *policy,
                   const struct plc_write_config *cfg, const struct plc_write_hooks *hooks)
{
    memset(pw, 0, sizeof(*pw));
    pw->img = img;
    pw->commands = commands;
    pw->policy = policy;
    pw->cfg = *cfg;
    pw->hooks = *hooks;
    pw->rows.heartbeat = find_gw_row(img->map, GW_plc_heartbeat);
    pw->rows.clear_counters = find_gw_row(img->map, GW_clear_counters);
    pw->rows.fault_reset = regmap_find_path(img->map, REGMAP_SRC_PATH, "fault_reset");
    pw->rows.motion_enable = regmap_find_path(img->map, REGMAP_SRC_PATH, "motion_enable");
    if (!pw->rows.heartbeat || !pw->rows.clear_counters || !pw->rows.fault_reset ||
        !pw->rows.motion_enable)
        return -EINVAL;
    /* One element per bit at most: the largest write there is. */
    pw->elements = calloc(MODBUS_MAX_WRITE_BITS, sizeof(*pw->elements));
    return pw->elements ? 0 : -ENOMEM;
}

void plc_write_free(struct plc_write *pw)
{
    free(pw->elements);
    pw->elements = NULL;
}

/* A client of plain Modbus TCP (not TLS, whose role says what it may write,
 * nor the RTU line, whose [rtu] rights do). */
static bool is_plain_tcp(const struct mb_write *w)
{
    return w->transport && strcmp(w->transport, "modbus") == 0;
}

int plc_write_authorize(const struct plc_write *pw, const struct mb_write *w)
{
    if (pw->cfg.read_only)
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    if (pw->cfg.modbus_writes_none && is_plain_tcp(w))
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    if (pw->cfg.write_allow.count > 0 &&
        !ip_allow_contains(&pw->cfg.write_allow, &w->client_addr))
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    return policy_may_write_via(pw->policy, w->client_id, w->peer ? w->peer : w->client,
                                w->transport);
}

static bool is_command_row(const struct regmap_row *row)
{
    return row->source == REGMAP_SRC_CMD || row->source == REGMAP_SRC_PATH;
}

/* Step 2: keeps each element, decoded once. */
static int keep(void *user, const struct regmap_written *w)
{
    struct plc_write *pw = user;

    if (pw->element_count == MODBUS_MAX_WRITE_BITS)
        return MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE; /* not reached */
    pw->elements[pw->element_count++] = *w;
    return 0;
}

/* The element of the write that sets 'row', or NULL. */
static const struct regmap_written *element_of(const struct plc_write *pw,
                                               const struct regmap_row *row)
{
    for (unsigned i = 0; i < pw->element_count; i++)
        if (pw->elements[i].row == row)
            return &pw->elements[i];
    return NULL;
}

/* The fault-reset coil written 1: logged and audited when a fault was
 * latched. */
static void reset_fault(struct plc_write *pw)
{
    static const char *const names[] = {"none", "PLC heartbeat lost", "no Modbus client",
                                        "motion enable dropped"};
    enum policy_fault fault = pw->policy->fault;

    if (fault != POLICY_FAULT_NONE) {
        char what[64];
        snprintf(what, sizeof(what), "fault %d (%s)", fault,
                 (unsigned)fault < 4 ? names[fault] : "?");
        log_notice("network-exception %s reset by %s", what, pw->w->client);
        audit_fault_reset(pw->commands->cfg.audit, what);
    }
    policy_reset(pw->policy);
}

static const char *const table_names[] = {"coil", "discrete input", "input register",
                                          "holding register"};

/* The command a row belongs to: "play_program" for its trigger,
 * "joint_move" for "joint_move.jointPosition[*]"; "" for other rows. */
static void command_of(const struct regmap_row *row, char *out, size_t size)
{
    const char *path = row->source == REGMAP_SRC_CMD || row->source == REGMAP_SRC_PATH
                           ? row->path
                           : NULL;
    size_t n = path ? strcspn(path, ".[") : 0;
    snprintf(out, size, "%.*s", (int)n, path ? path : "");
}

/* The write's range, as the audit names it. */
void plc_write_name_range(struct plc_write *pw, const struct mb_write *w)
{
    if (w->count == 0)
        snprintf(pw->where, sizeof(pw->where), "a write too short to say where");
    else
        snprintf(pw->where, sizeof(pw->where), "%s %u%s%.0u", table_names[w->table % 4],
                 w->address, w->count > 1 ? "+" : "", w->count > 1 ? w->count : 0);
}

/* The element that refused the write, and its command. */
static void name_element(struct plc_write *pw, const struct regmap_written *e)
{
    char command[48];
    command_of(e->row, command, sizeof(command));
    snprintf(pw->where, sizeof(pw->where), "%s %u%s%s", table_names[e->row->table % 4],
             regmap_element_address(e->row, e->element), command[0] ? " " : "", command);
}

/* Step 1's refusal, in words. */
static void why_unauthorized(struct plc_write *pw, const struct mb_write *w)
{
    if (pw->cfg.read_only)
        snprintf(pw->why, sizeof(pw->why), "read only: [modbus] read_only = true");
    else if (pw->cfg.modbus_writes_none && is_plain_tcp(w))
        snprintf(pw->why, sizeof(pw->why),
                 "no PLC may write yet: [modbus] write_allow = none");
    else if (pw->cfg.write_allow.count > 0 && !ip_allow_contains(&pw->cfg.write_allow,
                                                                 &w->client_addr))
        snprintf(pw->why, sizeof(pw->why), "client not in [modbus] write_allow");
    else
        snprintf(pw->why, sizeof(pw->why), "not the write owner: %s feeds the heartbeat",
                 pw->policy->owner_address);
}

/* Step 5 for one element; a motion-enable drop and the reset with it were
 * taken already. */
static void act_on(struct plc_write *pw, const struct regmap_written *e, uint64_t now,
                   bool drops_enable)
{
    const struct plc_write_rows *rows = &pw->rows;

    if (e->row == rows->heartbeat) {
        policy_heartbeat(pw->policy, now, pw->w->client_id,
                         pw->w->peer ? pw->w->peer : pw->w->client, e->value);
        policy_owner_transport(pw->policy, pw->w->client_id, pw->w->transport);
    } else if (e->row == rows->fault_reset) {
        if (e->value != 0 && !drops_enable)
            reset_fault(pw);
    } else if (e->row == rows->motion_enable) {
        if (e->value != 0)
            policy_motion_enable(pw->policy, now, true,
                                 pw->hooks.robot_may_move(pw->hooks.user));
    } else if (is_command_row(e->row)) {
        plc_commands_apply(pw->commands, e);
    }
}

/* A refused write of a writer allowed to write there: its parameters count
 * as not written (plc_commands.h). */
static int refused(struct plc_write *pw, const struct mb_write *w, int ex)
{
    /* Named only when refused (no printf on a write that goes through):
     * the element that refused it, else the range written. */
    if (!pw->where[0])
        plc_write_name_range(pw, w);
    plc_commands_write_refused(pw->commands, w->table, w->address, w->count);
    return ex;
}

/*
 * Only a connection that may write there can withdraw what was written:
 * a write refused for its rights, write_allow or the owner changes
 * nothing, or any client could make the owner's next move trigger read
 * "target not written".
 */
static bool may_write(struct plc_write *pw, const struct mb_write *w)
{
    return regmap_write_allowed(pw->img->map, w->table, w->address, w->count, w->rights) == 0 &&
           plc_write_authorize(pw, w) == 0;
}

void plc_write_refused_unjudged(struct plc_write *pw, const struct mb_write *w)
{
    if (w->count > 0 && may_write(pw, w))
        plc_commands_write_refused(pw->commands, w->table, w->address, w->count);
}

int plc_write_judge(struct plc_write *pw, const struct mb_write *w)
{
    struct regmap_image *img = pw->img;
    /* First of all, the connection's rights (the role of a Modbus/TCP
     * Security client): a row outside them refuses the whole write, 01. */
    int ex = regmap_write_allowed(img->map, w->table, w->address, w->count, w->rights);

    pw->awaiting_after = false;
    pw->element_count = 0;
    pw->why[0] = '\0';
    pw->where[0] = '\0';
    if (ex) {
        snprintf(pw->why, sizeof(pw->why), "outside role \"%s\"", w->role ? w->role : "");
        plc_write_name_range(pw, w);
        return ex; /* changes nothing (may_write) */
    }
    ex = plc_write_authorize(pw, w);
    if (ex) {
        why_unauthorized(pw, w);
        plc_write_name_range(pw, w);
        return ex; /* changes nothing (may_write) */
    }
    if (w->count == 0 || w->count > MODBUS_MAX_WRITE_BITS) {
        snprintf(pw->why, sizeof(pw->why), "invalid count");
        plc_write_name_range(pw, w);
        return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    }
    pw->w = w;
    regmap_save(img, w->table, w->address, w->count, pw->saved);
    regmap_load(img, w->table, w->address, w->count, w->values);
    ex = regmap_decode_write(img, w->table, w->address, w->count, w->values, pw->saved,
                             keep, pw);
    if (ex) {
        snprintf(pw->why, sizeof(pw->why), "invalid value for the register map");
        regmap_load(img, w->table, w->address, w->count, pw->saved);
        pw->element_count = 0;
        pw->w = NULL;
        return refused(pw, w, ex);
    }
    uint64_t now = pw->hooks.now_ms(pw->hooks.user);
    /* A drop of motion enable goes first, whatever its address: nothing
     * else the write holds is judged before the policy has seen it, and
     * nothing refuses it. A reset in the same write goes just before it:
     * it acknowledges the fault latched before the write, and the drop
     * latches fault 3 if the robot runs or may run. */
    const struct regmap_written *enable = element_of(pw, pw->rows.motion_enable);
    const struct regmap_written *reset = element_of(pw, pw->rows.fault_reset);
    bool drops_enable = enable && enable->value == 0;
    const struct regmap_written *beat = element_of(pw, pw->rows.heartbeat);
    if (beat && policy_may_feed_heartbeat(pw->policy, w->client_id) != 0) {
        snprintf(pw->why, sizeof(pw->why), "only the owner's connection feeds the heartbeat");
        name_element(pw, beat);
        regmap_load(img, w->table, w->address, w->count, pw->saved);
        pw->element_count = 0;
        pw->w = NULL;
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    /* A reset while the reaction is judged or the arm moves would cancel
     * a second stop: refused, busy, with why; a drop with it still goes. */
    bool reset_refused = reset && reset->value != 0 &&
                         policy_may_reset(pw->policy, pw->why, sizeof(pw->why)) != 0;
    if (reset_refused && !drops_enable) {
        name_element(pw, reset);
        regmap_load(img, w->table, w->address, w->count, pw->saved);
        pw->element_count = 0;
        pw->w = NULL;
        return MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY;
    }
    if (drops_enable) {
        if (reset && reset->value != 0 && !reset_refused)
            reset_fault(pw);
        policy_motion_enable(pw->policy, now, false, pw->hooks.robot_may_move(pw->hooks.user));
    }
    /* Step 4: every command checked with the new values in place, against
     * the fault as it was before the write (a reset in it starts nothing). */
    plc_commands_begin(pw->commands, w->client_id, pw->elements, pw->element_count);
    for (unsigned i = 0; i < pw->element_count && ex == 0; i++)
        if (is_command_row(pw->elements[i].row)) {
            ex = plc_commands_check(pw->commands, &pw->elements[i]);
            if (ex) {
                name_element(pw, &pw->elements[i]);
                snprintf(pw->why, sizeof(pw->why), "%s", plc_commands_refusal(pw->commands));
            }
        }
    if (ex) {
        regmap_load(img, w->table, w->address, w->count, pw->saved);
        if (drops_enable)
            img->mb->tab_bits[pw->rows.motion_enable->address] = 0; /* it stays */
        plc_commands_discard(pw->commands);
        pw->element_count = 0;
        pw->w = NULL;
        return refused(pw, w, ex);
    }
    for (unsigned i = 0; i < pw->element_count; i++)
        act_on(pw, &pw->elements[i], now, drops_enable);
    plc_commands_discard(pw->commands);
    policy_check(pw->policy, now, pw->hooks.robot_may_move(pw->hooks.user));
    /* 'w' is the server's and lives only for this call. */
    pw->w = NULL;
    pw->table = w->table;
    pw->address = w->address;
    pw->count = w->count;
    pw->awaiting_after = true;
    return 0;
}

void plc_write_after(struct plc_write *pw)
{
    if (!pw->awaiting_after)
        return;
    pw->awaiting_after = false;
    for (unsigned a = pw->address; a < pw->address + pw->count; a++)
        if (regmap_write_skips(pw->img->map, pw->table, a, pw->address, pw->count))
            pw->img->mb->tab_registers[a] = 0;
    for (unsigned i = 0; i < pw->element_count; i++) {
        const struct regmap_written *e = &pw->elements[i];
        /* Command coils: done once written, they read 0. */
        if (e->row == pw->rows.fault_reset) {
            pw->img->mb->tab_bits[e->row->address] = 0;
        } else if (e->row == pw->rows.clear_counters) {
            if (e->value != 0 && pw->hooks.clear_counters)
                pw->hooks.clear_counters(pw->hooks.user);
            pw->img->mb->tab_bits[e->row->address] = 0;
        }
    }
    pw->element_count = 0;
}
