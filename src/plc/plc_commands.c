/* SPDX-License-Identifier: MIT */
/* plc_commands.c - PLC writes that command the robot (plc_commands.h). */
#include "plc_commands.h"

#include "cmd_json.h"
#include "log.h"
#include "policy.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define EX_NOT_PERMITTED MODBUS_EXCEPTION_ILLEGAL_FUNCTION
#define EX_INVALID MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE
#define EX_BUSY MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY
#define EX_LINK_DOWN MODBUS_EXCEPTION_GATEWAY_TARGET
#define EX_FAILURE MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE

/* A reply's word and the number its row shows for it. */
struct info_word {
    const char *text;
    double value;
};

static const struct info_word program_states[] = {
    {"idle", 0}, {"running", 1}, {"paused", 2}, {NULL, 0}};
/* get_robot_state (4.12): the manual writes "powered on", jakasim and some
 * controllers "powered_on". */
static const struct info_word enable_states[] = {
    {"robot_disabled", 0}, {"robot_enabled", 1}, {NULL, 0}};
static const struct info_word power_states[] = {
    {"powered_off", 0}, {"powered off", 0}, {"powered_on", 1}, {"powered on", 1}, {NULL, 0}};

/* Robot information the status stream lacks: command, reply member, row,
 * and the words a text value may take (NULL: a number). */
static const struct info_item {
    const char *cmd;
    const char *key;
    const char *row;
    const struct info_word *words;
} info_items[] = {
    {"get_version", "version", "info.controller_version", NULL},
    {"get_loaded_program", "programName", "info.loaded_program", NULL},
    {"get_program_state", "programState", "info.program_state", program_states},
    /* The link check's query (command_port.h). */
    {"get_robot_state", "enable", "info.robot_enabled", enable_states},
    {"get_robot_state", "power", "info.robot_powered_on", power_states},
    {"get_payload", "mass", "info.payload_mass", NULL},
    {"get_payload", "centroid", "info.payload_centroid[*]", NULL},
    {"get_clsn_sensitivity", "sensitivityLevel", "info.collision_level", NULL},
    /* The manual spells the reply member "tool offsets"; some send "_". */
    {"get_tool_offsets", "tool_offsets", "info.tool_offsets[*]", NULL},
    {"get_tool_offsets", "tool offsets", "info.tool_offsets[*]", NULL},
    {"get_user_offsets", "user_offsets", "info.user_offsets[*]", NULL},
    {"get_user_offsets", "user offsets", "info.user_offsets[*]", NULL},
    {"get_dh_param", "alpha", "info.dh_alpha[*]", NULL},
    {"get_dh_param", "a", "info.dh_a[*]", NULL},
    {"get_dh_param", "d", "info.dh_d[*]", NULL},
    {"get_dh_param", "joint_homeoff", "info.dh_joint_homeoff[*]", NULL},
};
static const char *const info_commands[PLC_INFO_COMMANDS] = {
    "get_version",          "get_loaded_program", "get_program_state",
    "get_payload",          "get_clsn_sensitivity", "get_tool_offsets",
    "get_user_offsets",     "get_dh_param"};

/* The gateway row "<prefix>.<member>". */
static const struct regmap_row *path_row(const struct plc_commands *pc,
                                         const char *prefix, const char *member)
{
    char path[96];
    snprintf(path, sizeof(path), "%s.%s", prefix, member);
    return regmap_find_path(pc->img->map, REGMAP_SRC_PATH, path);
}

static int bind_slot(struct plc_commands *pc, struct plc_slot *slot,
                     enum plc_slot_kind kind, const char *prefix)
{
    slot->pc = pc;
    slot->kind = kind;
    slot->state = path_row(pc, prefix, "state");
    slot->error_code = path_row(pc, prefix, "error_code");
    slot->error_msg = path_row(pc, prefix, "error_msg");
    slot->count = path_row(pc, prefix, "count");
    if (!slot->state || !slot->error_code || !slot->error_msg || !slot->count) {
        log_err("register map: no result rows for %s", prefix);
        return -EINVAL;
    }
    return 0;
}

int plc_commands_init(struct plc_commands *pc, struct regmap_image *img,
                      struct cmd_queue *queue, const struct plc_commands_config *cfg,
                      uint64_t (*now_ms)(void *clock), void *clock)
{
    char prefix[64];

    memset(pc, 0, sizeof(*pc));
    pc->img = img;
    pc->queue = queue;
    pc->cfg = *cfg;
    pc->now_ms = now_ms;
    pc->clock = clock;
    pc->refuse_log_limit.interval_ms = 5000;
    if (cmd_table_count > PLC_MAX_COMMANDS)
        return -EINVAL;
    int err = param_rows_init(&pc->params, img->map);
    if (err != 0)
        return err;
    pc->row_cmd = calloc(img->map->row_count, sizeof(*pc->row_cmd));
    if (!pc->row_cmd || output_readback_init(&pc->outputs, img->map) != 0)
        return -ENOMEM;
    for (unsigned r = 0; r < img->map->row_count; r++)
        if (img->map->rows[r].source == REGMAP_SRC_CMD)
            pc->row_cmd[r] = param_rows_command_of(img->map->rows[r].path);
    for (unsigned i = 0; i < cmd_table_count; i++) {
        struct plc_slot *slot = &pc->slots[i];
        slot->pc = pc;
        slot->def = &cmd_table[i];
        if (!cmd_table[i].code)
            continue; /* not offered to PLCs on its own */
        snprintf(prefix, sizeof(prefix), "result.%s", cmd_table[i].name);
        if (bind_slot(pc, slot, PLC_SLOT_COMMAND, prefix))
            return -EINVAL;
    }
    if (bind_slot(pc, &pc->mailbox, PLC_SLOT_MAILBOX, "mailbox") ||
        bind_slot(pc, &pc->json, PLC_SLOT_JSON, "json"))
        return -EINVAL;
    for (unsigned i = 0; i < PLC_INFO_COMMANDS; i++) {
        pc->info[i] = (struct plc_slot){.pc = pc, .kind = PLC_SLOT_INFO,
                                        .def = cmd_find(info_commands[i])};
        if (!pc->info[i].def)
            return -EINVAL;
    }
    pc->mailbox_ack = path_row(pc, "mailbox", "ack_seq");
    pc->mailbox_done = path_row(pc, "mailbox", "done_seq");
    pc->mailbox_code = path_row(pc, "mailbox", "code");
    pc->mailbox_arg = path_row(pc, "mailbox", "arg[*]");
    pc->json_request = path_row(pc, "json", "request");
    pc->json_trigger = path_row(pc, "json", "trigger");
    pc->json_reply = path_row(pc, "json", "reply");
    pc->json_truncated = path_row(pc, "json", "reply_truncated");
    pc->json_length = path_row(pc, "json", "reply_length");
    pc->info_age = path_row(pc, "info", "age_ms");
    pc->handle_row = path_row(pc, "network_exception", "robot_handle");
    pc->handle = (struct plc_slot){.pc = pc, .kind = PLC_SLOT_HANDLE,
                                   .def = cmd_find("set_network_exception_handle")};
    if (!pc->mailbox_ack || !pc->mailbox_done || !pc->mailbox_code ||
        !pc->mailbox_arg || !pc->json_request || !pc->json_trigger ||
        !pc->json_reply || !pc->json_truncated || !pc->json_length || !pc->info_age ||
        !pc->handle_row || !pc->handle.def) {
        log_err("register map: mailbox rows missing");
        return -EINVAL;
    }
    return 0;
}

void plc_commands_free(struct plc_commands *pc)
{
    /* Only a write's staged commands; queued ones belong to the queue. */
    plc_commands_discard(pc);
    param_rows_free(&pc->params);
    free(pc->row_cmd);
    pc->row_cmd = NULL;
    output_readback_free(&pc->outputs);
}

static void set_result(struct plc_slot *slot, enum cmd_outcome outcome, long code,
                       const char *msg)
{
    struct regmap_image *img = slot->pc->img;
    if (!slot->state)
        return;
    regmap_set_number(img, slot->state, 0, outcome, true);
    regmap_set_number(img, slot->error_code, 0, (double)code, true);
    regmap_set_text(img, slot->error_msg, 0, msg);
}

/* Why a command could not be built from what the PLC wrote. */
enum build_result {
    BUILT = 0,
    BUILD_INVALID,   /* the PLC's values do not make a command: 03 */
    BUILD_NO_MEMORY, /* the command does not fit, or no memory: 04, nothing sent */
};

/* Sets element 'i' of a parameter row under its JSON path. */
static enum build_result add_param(const struct plc_commands *pc, struct cmd_json *cmd,
                                   const struct regmap_row *row, unsigned i)
{
    char path[96];
    regmap_expand(path, sizeof(path), row->path, row->index + i, i);
    const char *key = strchr(path, '.') + 1;

    if (row->type == REGMAP_STR) {
        char text[256];
        regmap_get_text(pc->img, row, i, text, sizeof(text));
        if (!text[0])
            return BUILD_INVALID; /* a text parameter must be given */
        cmd_json_set_string(cmd, key, text);
    } else {
        /* Floats from f32 registers at their precision. */
        cmd_json_set_number(cmd, key, regmap_get_number(pc->img, row, i),
                            row->type == REGMAP_F32);
    }
    return cmd->overflow ? BUILD_NO_MEMORY : BUILT;
}

/* The command 'def' with the parameters in its holding registers. */
static enum build_result build_triggered(const struct plc_commands *pc,
                                         const struct cmd_def *def, struct cmd_json *cmd)
{
    unsigned first, end;

    param_rows_span(&pc->params, def, &first, &end);
    cmd_json_begin(cmd, def->name);
    for (unsigned r = first; r < end; r++) {
        const struct regmap_row *row = &pc->img->map->rows[r];
        if (!param_rows_is_param_of(row, def->name))
            continue;
        for (unsigned i = 0; i < row->elements; i++) {
            enum build_result result = add_param(pc, cmd, row, i);
            if (result != BUILT)
                return result;
        }
    }
    return BUILT;
}

/* A setpoint row's command: its fixed members and the value written. */
static enum build_result build_setpoint(const struct regmap_written *w,
                                        const struct cmd_def *def, struct cmd_json *cmd)
{
    const struct regmap_row *row = w->row;
    char fixed[160], path[96];

    cmd_json_begin(cmd, def->name);
    regmap_expand(fixed, sizeof(fixed), row->fixed, w->source_index, w->element);
    /* The members come from the register table (test_regmap checks their
     * form), so only a row written wrongly can fail here. */
    if (cmd_json_set_fixed(cmd, fixed) != 0)
        return BUILD_NO_MEMORY;
    regmap_expand(path, sizeof(path), row->path, w->source_index, w->element);
    cmd_json_set_number(cmd, strchr(path, '.') + 1, w->value, row->type == REGMAP_F32);
    return cmd->overflow ? BUILD_NO_MEMORY : BUILT;
}

/* The mailbox's command, from its code and arguments (cmd_def.mailbox_args). */
static enum build_result build_mailbox(const struct plc_commands *pc,
                                       const struct cmd_def *def, struct cmd_json *cmd)
{
    char args[128], name[64];
    unsigned next = 0;

    cmd_json_begin(cmd, def->name);
    snprintf(args, sizeof(args), "%s", def->mailbox_args);
    for (char *save = NULL, *tok = strtok_r(args, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        size_t n = strlen(tok);
        char mark = n && (tok[n - 1] == '#' || tok[n - 1] == '$') ? tok[--n] : 0;
        tok[n] = '\0';
        if (mark == '$') {
            char path[96];
            snprintf(path, sizeof(path), "%s.%s", def->name, tok);
            const struct regmap_row *row =
                regmap_find_path(pc->img->map, REGMAP_SRC_CMD, path);
            enum build_result result = row ? add_param(pc, cmd, row, 0) : BUILD_INVALID;
            if (result != BUILT)
                return result;
            continue;
        }
        unsigned count = 1;
        char *bracket = strchr(tok, '[');
        if (bracket) {
            count = (unsigned)atoi(bracket + 1);
            *bracket = '\0';
        }
        for (unsigned k = 0; k < count; k++) {
            if (next >= pc->mailbox_arg->elements)
                return BUILD_INVALID;
            double v = regmap_get_number(pc->img, pc->mailbox_arg, next++);
            if (mark == '#' && v != nearbyint(v))
                return BUILD_INVALID; /* a whole number was expected */
            if (bracket)
                snprintf(name, sizeof(name), "%s[%u]", tok, k);
            else
                snprintf(name, sizeof(name), "%s", tok);
            cmd_json_set_number(cmd, name, v, mark != '#');
        }
    }
    return cmd->overflow ? BUILD_NO_MEMORY : BUILT;
}

/*
 * Does any member name appear twice? cJSON finds the first, a controller
 * may act on the last: a second "cmdName" could smuggle motion past the
 * checks made on the first.
 */
static bool has_repeated_member(const cJSON *obj)
{
    for (const cJSON *a = obj->child; a; a = a->next)
        for (const cJSON *b = a->next; b; b = b->next)
            if (a->string && b->string && strcmp(a->string, b->string) == 0)
                return true;
    return false;
}

/* The JSON mailbox's command: the PLC's text, if it is a command. */
/* Does 'item' hold a number that is not finite (1e999 reads as infinity),
 * at any depth? The robot's reading of it, and every bound computed from
 * it, would be undefined. */
static bool has_non_finite(const cJSON *item)
{
    if (cJSON_IsNumber(item))
        return !isfinite(item->valuedouble);
    for (const cJSON *c = item ? item->child : NULL; c; c = c->next)
        if (has_non_finite(c))
            return true;
    return false;
}

static cJSON *parse_json_request(const struct plc_commands *pc, const struct cmd_def **def,
                                 enum build_result *result)
{
    char text[512];
    const char *end = NULL;
    regmap_get_text(pc->img, pc->json_request, 0, text, sizeof(text));
    /* One object and nothing after it: the robot must act on exactly what
     * is judged here. */
    cJSON *obj = cJSON_ParseWithOpts(text, &end, true);
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(obj, "cmdName");
    if (!cJSON_IsObject(obj) || !cJSON_IsString(name) || !name->valuestring[0] ||
        has_repeated_member(obj)) {
        cJSON_Delete(obj);
        *result = BUILD_INVALID;
        return NULL;
    }
    *def = cmd_find(name->valuestring);
    *result = BUILT;
    return obj;
}

/* ACT_STALE: a 1 written onto a trigger another connection left at 1. */
enum action { ACT_NONE, ACT_TRIGGER, ACT_STALE, ACT_SETPOINT, ACT_MAILBOX, ACT_JSON };

/*
 * A trigger written 1: 0 -> 1 triggers; 1 again is the same connection's
 * retransmission (nothing to do), or another connection's write onto a
 * trigger left at 1 (a PLC restarted mid-handshake, a reconnect): refused,
 * since sending again could move the arm twice and answering OK would let
 * the PLC take the old result for its own.
 */
static enum action trigger_action(const struct plc_commands *pc, const struct plc_slot *slot,
                                  const struct regmap_written *w, enum action act)
{
    if (w->value == 0)
        return ACT_NONE;
    if (w->previous == 0)
        return act;
    return slot->trigger_by == pc->writer ? ACT_NONE : ACT_STALE;
}

/* What writing 'w' asks for; sets *def and *slot. */
static enum action action_of(struct plc_commands *pc, const struct regmap_written *w,
                             const struct cmd_def **def, struct plc_slot **slot)
{
    const struct regmap_row *row = w->row;

    *def = NULL;
    *slot = NULL;
    if (row->source == REGMAP_SRC_CMD) {
        *def = pc->row_cmd[row - pc->img->map->rows];
        if (!*def)
            return ACT_NONE;
        *slot = &pc->slots[*def - cmd_table];
        if (row->fixed)
            return output_readback_unchanged(&pc->outputs, pc->img, w, (*slot)->state,
                                             pc->now_ms(pc->clock))
                       ? ACT_NONE
                       : ACT_SETPOINT;
        if (!strchr(row->path, '.'))
            return trigger_action(pc, *slot, w, ACT_TRIGGER);
        return ACT_NONE;
    }
    if (row == pc->json_trigger) {
        *slot = &pc->json;
        return trigger_action(pc, *slot, w, ACT_JSON);
    }
    if (row->source == REGMAP_SRC_PATH && strcmp(row->path, "mailbox.seq") == 0) {
        *slot = &pc->mailbox;
        /* The same sequence number again is the same command: done already. */
        if (w->value == w->previous)
            return ACT_NONE;
        *def = cmd_find_code((unsigned)regmap_get_number(pc->img, pc->mailbox_code, 0));
        return ACT_MAILBOX;
    }
    return ACT_NONE;
}

/*
 * Builds what writing 'w' asks for: a table command as bytes in 'cmd', or
 * the JSON mailbox's request parsed into '*request' (judged as the robot
 * reads it, and sent as the PLC wrote it).
 */
static enum build_result build(struct plc_commands *pc, enum action act,
                               const struct regmap_written *w, const struct cmd_def **def,
                               struct cmd_json *cmd, cJSON **request)
{
    enum build_result result = BUILD_INVALID;

    *request = NULL;
    switch (act) {
    case ACT_TRIGGER:
        return build_triggered(pc, *def, cmd);
    case ACT_SETPOINT:
        return build_setpoint(w, *def, cmd);
    case ACT_MAILBOX:
        return *def ? build_mailbox(pc, *def, cmd) : BUILD_INVALID;
    case ACT_JSON:
        *request = parse_json_request(pc, def, &result);
        return result;
    case ACT_STALE:
    case ACT_NONE:
        break;
    }
    return result;
}

void plc_commands_begin(struct plc_commands *pc, uint64_t writer,
                        const struct regmap_written *elements, unsigned count)
{
    plc_commands_discard(pc);
    pc->writer = writer;
    pc->write_elements = elements;
    pc->write_element_count = count;
}

void plc_commands_discard(struct plc_commands *pc)
{
    for (unsigned i = pc->applied; i < pc->staged; i++)
        free(pc->staged_cmds[i].json);
    pc->staged = 0;
    pc->applied = 0;
    pc->write_elements = NULL;
    pc->write_element_count = 0;
}

/* Does the write being judged set element 'i' of 'row'? */
static bool write_sets(const struct plc_commands *pc, const struct regmap_row *row, unsigned i)
{
    for (unsigned e = 0; e < pc->write_element_count; e++)
        if (pc->write_elements[e].row == row && pc->write_elements[e].element == i)
            return true;
    return false;
}

/* How many of the mailbox's argument registers 'def' takes. */
static unsigned mailbox_args_taken(const struct cmd_def *def)
{
    char args[128];
    unsigned n = 0;

    snprintf(args, sizeof(args), "%s", def->mailbox_args);
    for (char *save = NULL, *tok = strtok_r(args, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        size_t len = strlen(tok);
        if (len && tok[len - 1] == '$')
            continue; /* from a parameter row, not the mailbox */
        const char *bracket = strchr(tok, '[');
        n += bracket ? (unsigned)atoi(bracket + 1) : 1;
    }
    return n;
}

/*
 * Does the write that sets a new sequence number carry the code and the
 * arguments of its command too? Written apart, they could be another
 * command's (a rapid_rate 0 sent with a previous command's arguments).
 */
static bool mailbox_whole(const struct plc_commands *pc, const struct cmd_def *def)
{
    if (!write_sets(pc, pc->mailbox_code, 0))
        return false;
    unsigned taken = def ? mailbox_args_taken(def) : 0;
    for (unsigned k = 0; k < taken && k < pc->mailbox_arg->elements; k++)
        if (!write_sets(pc, pc->mailbox_arg, k))
            return false;
    return true;
}

void plc_commands_write_refused(struct plc_commands *pc, enum regmap_table table,
                                unsigned address, unsigned count)
{
    param_rows_withdraw(&pc->params, table, address, count);
}

/* A trigger or mailbox write handled, whatever comes of it. */
static void count_handled(struct plc_commands *pc, const struct plc_slot *slot)
{
    if (!slot->count)
        return;
    double n = regmap_get_number(pc->img, slot->count, 0);
    regmap_set_number(pc->img, slot->count, 0, n >= 65535 ? 0 : n + 1, true);
}

/* Refuses with 'ex', showing why in the slot's result registers. */
static int refuse(struct plc_commands *pc, struct plc_slot *slot, int ex,
                  enum cmd_outcome outcome, const char *why)
{
    /* The same words for the audit trail (plc_commands_refusal). */
    snprintf(pc->refusal, sizeof(pc->refusal), "%s", why);
    if (slot && slot->state) {
        /* The count moved for this request: the result is its own. The
         * commands still pending no longer write theirs when they end,
         * except the mailbox's: done_seq says whose result it shows. */
        if (slot->kind != PLC_SLOT_MAILBOX)
            slot->superseded = slot->pending;
        set_result(slot, outcome, 0, why);
        /* The previous command's reply is no answer to this one. */
        if (slot == &pc->json) {
            regmap_set_text(pc->img, pc->json_reply, 0, "");
            regmap_set_number(pc->img, pc->json_truncated, 0, 0, true);
            regmap_set_number(pc->img, pc->json_length, 0, 0, true);
        }
    }
    return ex;
}

/*
 * A name the command table does not know could be anything, motion
 * included (a controller may read "Joint_Move" as joint_move): only with
 * motion allowed may it go out, and then it is judged as motion.
 */
static int refuse_unknown_json_command(struct plc_commands *pc, const cJSON *cmd)
{
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(cmd, "cmdName");
    uint64_t suppressed;

    if (log_ratelimit_pass(&pc->refuse_log_limit, pc->now_ms(pc->clock), &suppressed))
        log_notice("JSON mailbox: refused cmdName \"%s\": not in the command table, and "
                   "only [commands] motion = true lets other commands through "
                   "(%llu more refusals since the last such line)",
                   cJSON_IsString(name) ? name->valuestring : "", (unsigned long long)suppressed);
    return refuse(pc, &pc->json, EX_NOT_PERMITTED, CMD_REFUSED,
                  "not in the command table: motion is off");
}

/* The gates, in order, for a command that passed validation. */
static int gate(struct plc_commands *pc, enum action act, const struct cmd_def *def,
                struct plc_slot *slot)
{
    /* Unknown (JSON mailbox only, with motion on): judged as motion. */
    unsigned flags = def ? def->flags : CMD_MOTION;

    /* Every reason fits a result's error_msg (40 bytes) whole. */
    if ((flags & CMD_MOTION) && !pc->cfg.motion)
        return refuse(pc, slot, EX_NOT_PERMITTED, CMD_REFUSED, "motion off: [commands] motion");
    if ((flags & CMD_SHUTDOWN) && !pc->cfg.allow_shutdown)
        return refuse(pc, slot, EX_NOT_PERMITTED, CMD_REFUSED,
                      "shutdown off: [commands] allow_shutdown");
    if (act == ACT_TRIGGER && (flags & CMD_MOTION) &&
        !param_rows_all_written(&pc->params, def, pc->write_elements, pc->write_element_count))
        return refuse(pc, slot, EX_INVALID, CMD_INVALID, "target not written");
    if (!pc->queue->connected)
        return refuse(pc, slot, EX_LINK_DOWN, CMD_NOT_SENT, "not sent: the command link is down");
    /* Pausing and stopping are never held back for want of the handler. */
    bool halts = flags & CMD_HALTS;
    if (pc->cfg.require_robot_handle && pc->cfg.robot_handle && !halts &&
        pc->handle_state != PLC_HANDLE_ACCEPTED)
        return refuse(pc, slot, EX_NOT_PERMITTED, CMD_REFUSED,
                      "robot has not accepted its handler");
    if (pc->cfg.gate) {
        char why[96] = "";
        int ex = pc->cfg.gate(pc->cfg.gate_user, def, why, sizeof(why));
        if (ex)
            return refuse(pc, slot, ex, CMD_REFUSED, why);
    }
    /* A setpoint may queue behind itself; a command or mailbox may not,
     * except a pause or stop trigger: the mailboxes keep one pending (their
     * done_seq and reply are one command's). */
    if (act != ACT_SETPOINT && slot->pending && !(halts && act == ACT_TRIGGER))
        return refuse(pc, slot, EX_BUSY, CMD_REFUSED, "busy: the previous one is pending");
    /* A pause or stop never waits for room: it goes ahead of the queue and
     * takes out what would move the arm (cmd_queue_submit_urgent). (One
     * write stages at most a few: the bound is never reached.) */
    if (halts && pc->staged < CMD_QUEUE_CAPACITY)
        return 0;
    if (cmd_queue_pending(pc->queue) + pc->staged >= CMD_QUEUE_CAPACITY)
        return refuse(pc, slot, EX_BUSY, CMD_REFUSED, "busy: the command queue is full");
    return 0;
}

const char *plc_commands_refusal(const struct plc_commands *pc)
{
    return pc->refusal;
}

int plc_commands_check(struct plc_commands *pc, const struct regmap_written *w)
{
    const struct cmd_def *def;
    struct plc_slot *slot;
    enum action act = action_of(pc, w, &def, &slot);
    enum build_result built;
    int ex;

    if (act == ACT_NONE)
        return 0;
    pc->refusal[0] = '\0';
    if (act != ACT_SETPOINT)
        count_handled(pc, slot);
    if (act == ACT_STALE)
        return refuse(pc, slot, EX_NOT_PERMITTED, CMD_REFUSED, "trigger still 1: write 0 first");
    if (act == ACT_MAILBOX && !mailbox_whole(pc, def))
        return refuse(pc, slot, EX_INVALID, CMD_INVALID, "write code, args and seq in one write");
    struct cmd_json cmd;
    cJSON *request;
    built = build(pc, act, w, &def, &cmd, &request);
    if (built != BUILT)
        return built == BUILD_NO_MEMORY
                   ? refuse(pc, slot, EX_FAILURE, CMD_REFUSED, "out of memory: nothing sent")
                   : refuse(pc, slot, EX_INVALID, CMD_INVALID,
                            act == ACT_MAILBOX && !def ? "unknown command code"
                            : act == ACT_JSON          ? "not a JSON command with a cmdName"
                                                       : "invalid parameters");
    if (request ? has_non_finite(request) : cmd.non_finite) {
        cJSON_Delete(request);
        return refuse(pc, slot, EX_INVALID, CMD_INVALID, "a number is not finite");
    }
    if (act == ACT_JSON && !def && !pc->cfg.motion)
        ex = refuse_unknown_json_command(pc, request);
    else
        ex = gate(pc, act, def, slot);
    cJSON_Delete(request);
    if (ex)
        return ex;
    /* Built once, here: applying sends exactly what was judged. */
    char *json;
    if (act == ACT_JSON) {
        /* Exactly the PLC's text goes to the robot. */
        char text[512];
        regmap_get_text(pc->img, pc->json_request, 0, text, sizeof(text));
        json = strdup(text);
    } else {
        json = cmd_json_finish(&cmd);
    }
    if (!json)
        return refuse(pc, slot, EX_FAILURE, CMD_REFUSED, "out of memory: nothing sent");
    pc->staged_cmds[pc->staged].json = json;
    pc->staged_cmds[pc->staged].def = def;
    pc->staged++;
    return 0;
}

static void on_done(void *user, const struct cmd_result *r);
static void set_handle_state(struct plc_commands *pc, enum plc_handle_state state);

/*
 * What a command carries, for the audit trail: its members after cmdName,
 * as an object ({"rate_value":0.5}), or "" when it has none. A command
 * built from the table starts '{"cmdName":"<its name>"' as cmd_json
 * writes it, so its members are the bytes after that: taken as they are,
 * which is what printing it again without cmdName gave.
 */
static void members_of_built(const char *json, const char *name, char *what, size_t size)
{
    size_t name_len = strlen(name);
    size_t head = strlen("{\"cmdName\":\"") + name_len + 1;

    what[0] = '\0';
    if (strncmp(json, "{\"cmdName\":\"", 12) != 0 || strncmp(json + 12, name, name_len) != 0 ||
        strlen(json) <= head || json[head] != ',')
        return; /* no members */
    /* "{" and the rest, cut to fit as snprintf would: a copy, on every
     * command. */
    size_t n = strnlen(json + head + 1, size - 2);
    what[0] = '{';
    memcpy(what + 1, json + head + 1, n);
    what[n + 1] = '\0';
}

/* The same for the JSON mailbox's request, the PLC's own text. */
static void members_of_request(const char *json, char *name, size_t name_size, char *what,
                               size_t size)
{
    cJSON *doc = cJSON_Parse(json);
    const cJSON *n = cJSON_GetObjectItemCaseSensitive(doc, "cmdName");

    snprintf(name, name_size, "%s", cJSON_IsString(n) ? n->valuestring : "?");
    cJSON_DeleteItemFromObjectCaseSensitive(doc, "cmdName");
    char *params = doc && cJSON_GetArraySize(doc) > 0 ? cJSON_PrintUnformatted(doc) : NULL;
    snprintf(what, size, "%s", params ? params : "");
    cJSON_free(params);
    cJSON_Delete(doc);
}

/* The command's name and members for the audit trail: the table's and the
 * bytes already built, or, for the PLC's own JSON, read from its text. */
static void audit_sent(struct plc_commands *pc, struct plc_slot *slot, const char *json,
                       const struct cmd_def *def, bool own)
{
    char name[48] = "";
    char what[256] = "";

    if (!pc->cfg.audit)
        return;
    if (slot != &pc->json && def) {
        size_t n = strnlen(def->name, sizeof(name) - 1);
        memcpy(name, def->name, n);
        name[n] = '\0';
        members_of_built(json, def->name, what, sizeof(what));
    } else {
        members_of_request(json, name, sizeof(name), what, sizeof(what));
        if (def)
            snprintf(name, sizeof(name), "%s", def->name);
    }
    audit_command_sent_what(pc->cfg.audit, slot, name, what, own, pc->sending_frequent);
}

static void submit(struct plc_commands *pc, struct plc_slot *slot, const char *json,
                   const struct cmd_def *def)
{
    /* Pause and stop go out at once, ahead of whatever waits. */
    /* A command built from its table entry moves as the entry says; the
     * JSON mailbox's text is read for its name. */
    bool built = slot != &pc->json && def;
    int rc = def && (def->flags & CMD_HALTS)
                 ? cmd_queue_submit_urgent(pc->queue, json, strlen(json), on_done, slot)
             : built ? cmd_queue_submit_def(pc->queue, def, json, strlen(json), on_done, slot)
                     : cmd_queue_submit(pc->queue, json, strlen(json), on_done, slot);
    audit_sent(pc, slot, json, def, false);
    if (rc < 0) {
        char why[48];
        snprintf(why, sizeof(why), "not sent: %s",
                 rc == -ENOTCONN ? "the command link is down"
                 : rc == -EBUSY  ? "the command queue is full"
                 : rc == -ENOMEM ? "out of memory"
                                 : "error");
        /* The write was accepted: whatever kept the command from going
         * out, the robot never got it. */
        struct cmd_result r = {.outcome = CMD_NOT_SENT};
        snprintf(r.error_msg, sizeof(r.error_msg), "%s", why);
        audit_command_done(pc->cfg.audit, slot, &r);
        set_result(slot, CMD_NOT_SENT, 0, why);
        /* The mailbox's sequence number is finished too: a PLC waiting on
         * done_seq must not wait for ever. */
        if (slot->kind == PLC_SLOT_MAILBOX)
            regmap_set_number(pc->img, pc->mailbox_done, 0,
                              regmap_get_number(pc->img, pc->mailbox_ack, 0), true);
        return;
    }
    slot->pending++;
    if (slot->state)
        set_result(slot, CMD_PENDING, 0, "");
    if (pc->cfg.sent)
        pc->cfg.sent(pc->cfg.gate_user, def, json, slot);
    /* The policy counts the robot as running from now on, until the
     * status can show it. */
    if (policy_command_starts_motion(def)) {
        slot->starts_pending++;
        if (pc->cfg.start_sent)
            pc->cfg.start_sent(pc->cfg.gate_user);
    }
}

void plc_commands_apply(struct plc_commands *pc, const struct regmap_written *w)
{
    const struct cmd_def *def;
    struct plc_slot *slot;
    enum action act = action_of(pc, w, &def, &slot);

    if (param_rows_is_param(w->row))
        param_rows_note_written(&pc->params, w->row, w->element);
    if (act == ACT_TRIGGER || act == ACT_JSON)
        slot->trigger_by = pc->writer; /* its 1 again is a retransmission */
    if (act == ACT_NONE || pc->applied == pc->staged)
        return; /* the second: not checked, so not staged (not reached) */
    struct plc_staged *st = &pc->staged_cmds[pc->applied++];
    def = st->def;
    if (act == ACT_MAILBOX || act == ACT_JSON)
        slot->def = def; /* one pending at a time: its refresh, its log line */
    if (act == ACT_MAILBOX)
        regmap_set_number(pc->img, pc->mailbox_ack, 0, w->value, true);
    if (act == ACT_SETPOINT)
        output_readback_note_sent(&pc->outputs, w, pc->now_ms(pc->clock));
    pc->sending_frequent = act == ACT_SETPOINT;
    submit(pc, slot, st->json, def);
    pc->sending_frequent = false;
    free(st->json);
    st->json = NULL;
}

/* Maps a reply member onto an info row. */
static void store_info(struct plc_commands *pc, const struct info_item *item,
                       const cJSON *value)
{
    const struct regmap_row *row =
        regmap_find_path(pc->img->map, REGMAP_SRC_PATH, item->row);
    if (!row || !value)
        return;
    if (row->type == REGMAP_STR) {
        if (cJSON_IsString(value))
            regmap_set_text(pc->img, row, 0, value->valuestring);
        return;
    }
    if (cJSON_IsArray(value)) {
        /* Nested arrays (one per frame) are read row after row. */
        unsigned i = 0;
        const cJSON *e;
        cJSON_ArrayForEach(e, value) {
            if (cJSON_IsArray(e)) {
                const cJSON *x;
                cJSON_ArrayForEach(x, e) {
                    if (i < row->elements)
                        regmap_set_number(pc->img, row, i, cJSON_IsNumber(x) ? x->valuedouble : 0,
                                          cJSON_IsNumber(x));
                    i++;
                }
            } else {
                if (i < row->elements)
                    regmap_set_number(pc->img, row, i, cJSON_IsNumber(e) ? e->valuedouble : 0,
                                      cJSON_IsNumber(e));
                i++;
            }
        }
        for (; i < row->elements; i++)
            regmap_set_number(pc->img, row, i, 0, false);
        return;
    }
    double v = 0;
    bool ok = true;
    if (cJSON_IsNumber(value)) {
        v = value->valuedouble;
    } else if (cJSON_IsString(value)) {
        char *end;
        v = strtod(value->valuestring, &end);
        ok = end != value->valuestring && *end == '\0';
        for (const struct info_word *w = item->words; !ok && w && w->text; w++)
            if (strcmp(value->valuestring, w->text) == 0) {
                v = w->value;
                ok = true;
            }
    } else {
        ok = false;
    }
    regmap_set_number(pc->img, row, 0, v, ok);
}

static void fetch_info(struct plc_commands *pc, const char *name)
{
    for (unsigned i = 0; i < PLC_INFO_COMMANDS; i++) {
        struct plc_slot *slot = &pc->info[i];
        if (strcmp(slot->def->name, name) != 0 || slot->pending)
            continue;
        char json[96];
        snprintf(json, sizeof(json), "{\"cmdName\":\"%s\"}", name);
        if (cmd_queue_submit(pc->queue, json, strlen(json), on_done, slot) == 0)
            slot->pending++;
    }
}

/* Maps the members of an accepted reply to 'name' onto their rows. */
static void store_reply(struct plc_commands *pc, const char *name, const struct cmd_result *r)
{
    cJSON *doc = cJSON_ParseWithLength(r->reply, r->reply_size);
    for (unsigned i = 0; i < sizeof(info_items) / sizeof(info_items[0]); i++)
        if (strcmp(info_items[i].cmd, name) == 0)
            store_info(pc, &info_items[i],
                       cJSON_GetObjectItemCaseSensitive(doc, info_items[i].key));
    cJSON_Delete(doc);
}

static void record_info(struct plc_commands *pc, const struct plc_slot *slot,
                        const struct cmd_result *r)
{
    if (r->outcome != CMD_DONE)
        return;
    store_reply(pc, slot->def->name, r);
    pc->info_updated_ms = pc->now_ms(pc->clock);
}

void plc_commands_link_check_reply(struct plc_commands *pc, const char *name,
                                   const struct cmd_result *r)
{
    if (r->outcome == CMD_DONE && r->reply)
        store_reply(pc, name, r);
}

/* The JSON mailbox shows the reply itself, cut to its block if longer. */
static void record_json_reply(struct plc_commands *pc, const struct cmd_result *r)
{
    char text[1024];
    size_t cap = (size_t)pc->json_reply->str_regs * 2;
    size_t n = r->reply ? r->reply_size : 0;

    if (cap > sizeof(text) - 1)
        cap = sizeof(text) - 1;
    if (n > cap) {
        n = cap;
        /* Never cut a UTF-8 sequence in two. */
        while (n > 0 && ((unsigned char)r->reply[n] & 0xC0) == 0x80)
            n--;
    }
    if (n)
        memcpy(text, r->reply, n);
    text[n] = '\0';
    regmap_set_text(pc->img, pc->json_reply, 0, text);
    regmap_set_number(pc->img, pc->json_truncated, 0, r->reply && r->reply_size > n, true);
    regmap_set_number(pc->img, pc->json_length, 0, r->reply ? (double)r->reply_size : 0, true);
}

static void on_done(void *user, const struct cmd_result *r)
{
    struct plc_slot *slot = user;
    struct plc_commands *pc = slot->pc;

    if (slot->kind != PLC_SLOT_INFO)
        audit_command_done(pc->cfg.audit, slot, r);
    if (pc->cfg.answered && slot->kind != PLC_SLOT_INFO && slot->kind != PLC_SLOT_HANDLE)
        pc->cfg.answered(pc->cfg.gate_user, slot->def, slot, r);
    slot->pending--;
    /* A later request's refusal wrote the result registers: they are its. */
    bool superseded = slot->superseded > 0;
    if (superseded)
        slot->superseded--;
    if (slot->starts_pending > 0) {
        /* One pending at a time for these slots: this is the start. */
        slot->starts_pending--;
        if (pc->cfg.start_answered)
            pc->cfg.start_answered(pc->cfg.gate_user);
    }
    /* Several commands of one setpoint (an FC15 of outputs): the result
     * stays pending until the last is answered, and the first failure
     * among them is what it shows then. */
    if (r->outcome != CMD_DONE && !slot->failed) {
        slot->failed = true;
        slot->failure = *r;
        slot->failure.reply = NULL;
    }
    if (slot->pending > 0 && slot->kind == PLC_SLOT_COMMAND)
        return;
    if (slot->failed && slot->kind == PLC_SLOT_COMMAND && r->outcome == CMD_DONE)
        r = &slot->failure;
    slot->failed = false;
    if (slot->kind == PLC_SLOT_INFO) {
        record_info(pc, slot, r);
        return;
    }
    if (slot->kind == PLC_SLOT_HANDLE) {
        set_handle_state(pc, r->outcome == CMD_DONE ? PLC_HANDLE_ACCEPTED : PLC_HANDLE_FAILED);
        if (r->outcome == CMD_DONE)
            log_notice("robot accepted its network-exception handler");
        else
            log_err("robot did not accept set_network_exception_handle: %s (%ld) %s; "
                    "commands are refused until it does",
                    cmd_outcome_name(r->outcome), r->error_code, r->error_msg);
        return;
    }
    if (!superseded)
        set_result(slot, r->outcome, r->error_code, r->error_msg);
    if (slot->kind == PLC_SLOT_MAILBOX)
        regmap_set_number(pc->img, pc->mailbox_done, 0,
                          regmap_get_number(pc->img, pc->mailbox_ack, 0), true);
    if (slot->kind == PLC_SLOT_JSON && !superseded)
        record_json_reply(pc, r);
    if (r->outcome != CMD_DONE)
        log_notice("command %s: %s (%ld) %s",
                   slot->def ? slot->def->name : slot->kind == PLC_SLOT_JSON ? "from the JSON mailbox" : "from the mailbox",
                   cmd_outcome_name(r->outcome), r->error_code, r->error_msg);
    if (r->outcome == CMD_DONE && slot->def && slot->def->refresh[0])
        fetch_info(pc, slot->def->refresh);
}

/* A command the gateway sent for itself (plc_commands_send_now). */
static void on_own_done(void *user, const struct cmd_result *r)
{
    struct plc_slot *slot = user;
    struct plc_commands *pc = slot->pc;
    const struct cmd_def *def = slot->def;
    bool unknown = r->outcome == CMD_TIMEOUT || r->outcome == CMD_LINK_DOWN;

    on_done(slot, r);
    if (!unknown && pc->cfg.own_answered)
        pc->cfg.own_answered(pc->cfg.gate_user, def, r);
    if (unknown && pc->cfg.own_unknown)
        pc->cfg.own_unknown(pc->cfg.gate_user, def);
}

static void set_handle_state(struct plc_commands *pc, enum plc_handle_state state)
{
    pc->handle_state = state;
    regmap_set_number(pc->img, pc->handle_row, 0, state, true);
}

void plc_commands_link_up(struct plc_commands *pc)
{
    if (pc->cfg.robot_handle) {
        char json[128];
        /* First on every connection: queued before any PLC command. */
        snprintf(json, sizeof(json),
                 "{\"cmdName\":\"set_network_exception_handle\",\"timeLimit\":%u,"
                 "\"motType\":%u}",
                 (unsigned)pc->cfg.robot_time_limit_ms, pc->cfg.robot_mot_type);
        int rc = cmd_queue_submit(pc->queue, json, strlen(json), on_done, &pc->handle);
        if (rc == 0) {
            audit_sent(pc, &pc->handle, json, pc->handle.def, true);
            pc->handle.pending++;
            if (pc->handle_state != PLC_HANDLE_FAILED)
                set_handle_state(pc, PLC_HANDLE_PENDING);
        } else {
            set_handle_state(pc, PLC_HANDLE_FAILED);
        }
    }
    for (unsigned i = 0; i < PLC_INFO_COMMANDS; i++)
        fetch_info(pc, info_commands[i]);
}

void plc_commands_link_down(struct plc_commands *pc)
{
    /* A new connection must set it again; a failure stays visible until
     * the robot accepts it. */
    if (pc->handle_state != PLC_HANDLE_FAILED)
        set_handle_state(pc, PLC_HANDLE_NOT_SENT);
}

int plc_commands_send_now(struct plc_commands *pc, const char *name)
{
    const struct cmd_def *def = cmd_find(name);
    if (!def)
        return -EINVAL;
    struct plc_slot *slot = &pc->slots[def - cmd_table];
    char json[96];
    snprintf(json, sizeof(json), "{\"cmdName\":\"%s\"}", name);
    /* Written now, ahead of whatever the PLC queued. */
    int rc = cmd_queue_submit_urgent(pc->queue, json, strlen(json), on_own_done, slot);
    if (rc == 0) {
        audit_sent(pc, slot, json, def, true);
        slot->pending++;
        if (slot->state)
            set_result(slot, CMD_PENDING, 0, "");
    }
    return rc;
}

void plc_commands_refresh(struct plc_commands *pc)
{
    double age = pc->info_updated_ms ? (double)(pc->now_ms(pc->clock) - pc->info_updated_ms)
                                     : 4294967295.0;
    regmap_set_number(pc->img, pc->info_age, 0, age, true);
}
