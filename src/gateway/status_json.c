/* SPDX-License-Identifier: MIT */
/* status_json.c - the state as JSON (status_json.h). */
#include "status_json.h"

#include "log.h"
#include "strbuf.h"

#include <cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define NEVER_MS 4294967295.0

static uint64_t wall_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000 + (uint64_t)ts.tv_nsec / 1000000;
}

static const char *const link_states[] = {"disconnected", "connecting", "connected", "silent"};
static const char *const handler_names[] = {"not sent", "pending", "accepted", "failed"};

/* A text row of the map, by path ("info.loaded_program"), into 'obj'. */
static void add_text_row(cJSON *obj, const char *name, const struct gateway *gw,
                         enum regmap_source source, const char *path)
{
    char text[300] = "";
    const struct regmap_row *row = regmap_find_path(&gw->map, source, path);
    if (row)
        regmap_get_text(&gw->image, row, 0, text, sizeof(text));
    cJSON_AddStringToObject(obj, name, text);
}

static void add_age(cJSON *obj, const char *name, double ms)
{
    if (ms >= NEVER_MS - 1)
        cJSON_AddNullToObject(obj, name);
    else
        cJSON_AddNumberToObject(obj, name, ms);
}

static void add_link(cJSON *links, const char *name, double state, double up, double reconnects)
{
    cJSON *l = cJSON_AddObjectToObject(links, name);
    unsigned s = (unsigned)state;
    cJSON_AddBoolToObject(l, "up", up != 0);
    cJSON_AddStringToObject(l, "state", s < 4 ? link_states[s] : "?");
    cJSON_AddNumberToObject(l, "reconnects", reconnects);
}

struct clients_ctx {
    struct gateway *gw;
    cJSON *array;
};

static void add_client(void *user, const struct mb_client_info *info)
{
    struct clients_ctx *ctx = user;
    const struct policy *p = &ctx->gw->policy;
    uint64_t now = uv_now(ctx->gw->loop);
    cJSON *c = cJSON_CreateObject();

    if (!c || !cJSON_AddItemToArray(ctx->array, c)) {
        cJSON_Delete(c);
        return;
    }
    cJSON_AddStringToObject(c, "address", info->host);
    cJSON_AddStringToObject(c, "peer", info->peer);
    cJSON_AddStringToObject(c, "transport", info->transport);
    cJSON_AddStringToObject(c, "subject", info->subject);
    cJSON_AddStringToObject(c, "role", info->role);
    char rights[160];
    regmap_format_rights(info->rights, rights, sizeof(rights));
    cJSON_AddStringToObject(c, "may_write", rights);
    cJSON_AddBoolToObject(c, "owner", p->owner != 0 && p->owner == info->id);
    cJSON_AddNumberToObject(c, "requests", (double)info->requests);
    cJSON_AddNumberToObject(c, "exceptions", (double)info->exceptions);
    add_age(c, "last_request_age_ms",
            info->last_request_ms ? (double)(now - info->last_request_ms) : NEVER_MS);
    cJSON_AddNumberToObject(c, "connected_ms", (double)(now - info->accepted_ms));
}

/* Audit records (PLCs' or the gateway's own), oldest first, as 'name'. */
static void add_commands(cJSON *root, const char *name, const struct audit *a, bool own)
{
    cJSON *array = cJSON_AddArrayToObject(root, name);
    unsigned count = own ? audit_own_count(a) : audit_count(a);
    for (unsigned i = 0; array && i < count; i++) {
        const struct audit_record *r = own ? audit_own_get(a, i) : audit_get(a, i);
        cJSON *c = cJSON_CreateObject();
        if (!c || !cJSON_AddItemToArray(array, c)) {
            cJSON_Delete(c);
            return;
        }
        cJSON_AddNumberToObject(c, "seq", (double)r->seq);
        cJSON_AddNumberToObject(c, "time_ms", (double)r->wall_ms);
        cJSON_AddStringToObject(c, "transport", r->who.transport);
        cJSON_AddStringToObject(c, "client", r->who.client);
        cJSON_AddStringToObject(c, "subject", r->who.subject);
        cJSON_AddStringToObject(c, "role", r->who.role);
        cJSON_AddStringToObject(c, "command", r->command);
        cJSON_AddStringToObject(c, "what", r->what);
        cJSON_AddStringToObject(c, "result", r->result);
        cJSON_AddStringToObject(c, "reason", r->reason);
        cJSON_AddNumberToObject(c, "error_code", (double)r->error_code);
        cJSON_AddStringToObject(c, "error_msg", r->error_msg);
        cJSON_AddNumberToObject(c, "count", r->count);
    }
}

static void add_policy(cJSON *root, const struct gateway *gw)
{
    const struct policy *p = &gw->policy;
    cJSON *o = cJSON_AddObjectToObject(root, "policy");
    unsigned handler = (unsigned)gw->commands.handle_state;

    add_age(o, "heartbeat_age_ms", gw->gw_values[GW_plc_heartbeat_age_ms]);
    cJSON_AddNumberToObject(o, "fault", p->fault);
    cJSON_AddStringToObject(o, "fault_name", policy_fault_name(p->fault));
    uint64_t fault_age = policy_fault_age_ms(p, uv_now(gw->loop));
    cJSON_AddNumberToObject(o, "fault_age_ms", (double)fault_age);
    /* When it latched, as wall time, and how the PLC resets it. */
    if (p->fault != POLICY_FAULT_NONE)
        cJSON_AddNumberToObject(o, "fault_time_ms", (double)(wall_now_ms() - fault_age));
    else
        cJSON_AddNullToObject(o, "fault_time_ms");
    cJSON_AddStringToObject(o, "action",
                            p->cfg.action == POLICY_STOP    ? "stop_program"
                            : p->cfg.action == POLICY_PAUSE ? "pause_program"
                                                            : "none");
    const struct regmap_row *reset = regmap_find_path(&gw->map, REGMAP_SRC_PATH, "fault_reset");
    if (reset)
        cJSON_AddNumberToObject(o, "fault_reset_coil", reset->address);
    const struct regmap_row *enable =
        regmap_find_path(&gw->map, REGMAP_SRC_PATH, "motion_enable");
    if (enable)
        cJSON_AddNumberToObject(o, "motion_enable_coil", enable->address);
    const struct regmap_row *beat = NULL;
    for (unsigned r = 0; r < gw->map.row_count && !beat; r++)
        if (gw->map.rows[r].source == REGMAP_SRC_GW && gw->map.rows[r].id == GW_plc_heartbeat &&
            gw->map.rows[r].writable)
            beat = &gw->map.rows[r];
    if (beat)
        cJSON_AddNumberToObject(o, "heartbeat_register", beat->address);
    cJSON_AddNumberToObject(o, "faults", (double)p->faults);
    cJSON_AddStringToObject(o, "handler", handler < 4 ? handler_names[handler] : "?");
    cJSON_AddStringToObject(o, "write_owner", p->owner_address);
    /* "never" until the PLC heartbeat was seen changing: motion is
     * refused then (require_heartbeat), and the page says why. */
    static const char *const beat_states[] = {"never", "running", "lost"};
    cJSON_AddStringToObject(o, "plc_heartbeat_state",
                            beat_states[policy_heartbeat_state(p, uv_now(gw->loop))]);
    cJSON_AddBoolToObject(o, "motion_enabled", p->motion_enabled);
    cJSON_AddNumberToObject(o, "time_limit_ms", p->cfg.time_limit_ms);
    /* What the robot did, not only what was sent (IR 5602). */
    cJSON_AddNumberToObject(o, "reaction", p->reaction);
    cJSON_AddStringToObject(o, "reaction_name", policy_reaction_name(p->reaction));
    if (p->reaction >= POLICY_REACTION_SENT)
        cJSON_AddStringToObject(o, "action_sent", p->reaction_action == POLICY_STOP
                                                      ? "stop_program"
                                                      : "pause_program");
    else
        cJSON_AddNullToObject(o, "action_sent");
}

/* The last move the gateway sent and what became of it (IR 5600-5601). */
static void add_motion(cJSON *root, const struct gateway *gw)
{
    const struct motion *m = &gw->motion;
    cJSON *o = cJSON_AddObjectToObject(root, "motion");

    cJSON_AddNumberToObject(o, "state", m->state);
    cJSON_AddStringToObject(o, "state_name", motion_state_name(m->state));
    cJSON_AddNumberToObject(o, "count", m->count);
    cJSON_AddStringToObject(o, "command", m->name);
    cJSON_AddStringToObject(o, "why", m->why);
}

static const char *const program_states[] = {"idle", "loading", "paused", "running"};
static const char *const task_modes[] = {"?", "manual", "automatic", "reserved", "drag"};

static void add_flag(cJSON *obj, const char *name, int v)
{
    if (v < 0)
        cJSON_AddNullToObject(obj, name);
    else
        cJSON_AddBoolToObject(obj, name, v != 0);
}

static void add_text_or_null(cJSON *obj, const char *name, const char *text, bool known)
{
    if (known)
        cJSON_AddStringToObject(obj, name, text);
    else
        cJSON_AddNullToObject(obj, name);
}

/*
 * The robot as the status link shows it. Every value that comes from the
 * link is null ("unknown") while it is down or stale: an old program or
 * "no error" during an outage would be a claim the gateway cannot make.
 */
static void add_robot(cJSON *root, const struct gateway *gw)
{
    struct robot_view v;
    char text[300] = "";
    cJSON *robot = cJSON_AddObjectToObject(root, "robot");

    robot_view_of(gw->status, gateway_status_fresh(gw), &v);
    cJSON_AddBoolToObject(robot, "known", v.known);
    add_flag(robot, "powered_on", v.powered_on);
    add_flag(robot, "enabled", v.enabled);
    add_text_or_null(robot, "program_state", v.program >= 0 ? program_states[v.program] : "",
                     v.program >= 0);
    const struct regmap_row *row =
        regmap_find_path(&gw->map, REGMAP_SRC_PATH, "info.loaded_program");
    if (row)
        regmap_get_text(&gw->image, row, 0, text, sizeof(text));
    add_text_or_null(robot, "loaded_program", text, v.known);
    add_flag(robot, "emergency_stop", v.emergency_stop);
    add_flag(robot, "protective_stop", v.protective_stop);
    if (isfinite(v.speed_override))
        cJSON_AddNumberToObject(robot, "speed_override", v.speed_override);
    else
        cJSON_AddNullToObject(robot, "speed_override");
    add_text_or_null(robot, "mode", v.mode >= 1 && v.mode <= 4 ? task_modes[v.mode] : "",
                     v.mode >= 1 && v.mode <= 4);
    const struct status_num *code =
        gw->status ? status_num_at(gw->status, STATUS_F_errcode, 0) : NULL;
    if (v.known && code && code->present)
        cJSON_AddNumberToObject(robot, "errcode", code->value);
    else
        cJSON_AddNullToObject(robot, "errcode");
    text[0] = '\0';
    for (unsigned r = 0; r < gw->map.row_count; r++)
        if (gw->map.rows[r].source == REGMAP_SRC_STATUS && gw->map.rows[r].type == REGMAP_STR &&
            strcmp(gw->map.rows[r].name, "errmsg") == 0) {
            regmap_get_text(&gw->image, &gw->map.rows[r], 0, text, sizeof(text));
            break;
        }
    add_text_or_null(robot, "errmsg", text, v.known);
    /* From the command link's queries: not the status link's to void. */
    add_text_row(robot, "controller_version", gw, REGMAP_SRC_PATH, "info.controller_version");
}

/* The event log, oldest first. */
static void add_events(cJSON *root, const struct events *e)
{
    cJSON *array = cJSON_AddArrayToObject(root, "events");
    for (unsigned i = 0; array && i < events_count(e); i++) {
        const struct gw_event *ev = events_get(e, i);
        cJSON *o = cJSON_CreateObject();
        if (!o || !cJSON_AddItemToArray(array, o)) {
            cJSON_Delete(o);
            return;
        }
        cJSON_AddNumberToObject(o, "seq", (double)ev->seq);
        cJSON_AddNumberToObject(o, "time_ms", (double)ev->wall_ms);
        cJSON_AddStringToObject(o, "kind", ev->kind);
        cJSON_AddStringToObject(o, "text", ev->text);
    }
}

/*
 * The "registers" member: every element of the map as [table, address,
 * name, value, unit]. About 2,300 elements and 90 KB, too much to build
 * with cJSON for every request (5-7 ms of the loop each, and any local
 * process may ask back to back): the parts that never change (table,
 * address, name, unit) are printed once, and the member is rebuilt from
 * them and the image's values at most once per status document, or once
 * REGISTERS_MAX_AGE_MS old when documents come slower (the gateway's own
 * values, a PLC's writes). Every request in between is served the same
 * text.
 */
#define REGISTERS_MAX_AGE_MS 100

struct reg_element {
    const struct regmap_row *row;
    unsigned i;
    uint32_t head, head_len; /* in 'fixed': '[table,address,"name",' */
    uint32_t tail, tail_len; /* ',"unit"]' */
};

static struct registers_cache {
    const struct regmap *map; /* what 'fixed' was printed from */
    struct reg_element *elements;
    unsigned count;
    char *fixed;
    char *text; /* the member's value, hardened; NULL: none yet */
    size_t size;
    uint64_t documents; /* documents_parsed when built */
    uint64_t built_ms;
} cache;

static char *harden(const char *json, size_t *size);

/* 'text' as a JSON string, hardened as the rest of the document. */
static void json_string(struct strbuf *b, const char *text)
{
    cJSON *s = cJSON_CreateString(text);
    char *printed = s ? cJSON_PrintUnformatted(s) : NULL;
    size_t n = 0;
    char *hard = printed ? harden(printed, &n) : NULL;
    if (hard)
        strbuf_append(b, hard, n - 1); /* without harden's newline */
    else
        strbuf_append(b, "\"\"", 2);
    free(hard);
    cJSON_free(printed);
    cJSON_Delete(s);
}

/* Prints the parts that never change, once per map. */
static bool registers_prepare(const struct regmap *map)
{
    struct strbuf b;
    unsigned count = 0;

    if (cache.map == map && cache.elements)
        return true;
    for (unsigned r = 0; r < map->row_count; r++)
        count += map->rows[r].elements;
    struct reg_element *elements = calloc(count ? count : 1, sizeof(*elements));
    if (!elements)
        return false;
    strbuf_init(&b, (size_t)count * 48);
    unsigned k = 0;
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        for (unsigned i = 0; i < row->elements; i++, k++) {
            char name[96];
            struct reg_element *e = &elements[k];
            e->row = row;
            e->i = i;
            regmap_expand(name, sizeof(name), row->name, row->index + i, i + 1);
            e->head = (uint32_t)b.len;
            strbuf_printf(&b, "[%u,%u,", (unsigned)row->table, regmap_element_address(row, i));
            json_string(&b, name);
            strbuf_append(&b, ",", 1);
            e->head_len = (uint32_t)(b.len - e->head);
            e->tail = (uint32_t)b.len;
            strbuf_append(&b, ",", 1);
            json_string(&b, row->unit ? row->unit : "");
            strbuf_append(&b, "]", 1);
            e->tail_len = (uint32_t)(b.len - e->tail);
        }
    }
    char *fixed = strbuf_take(&b, NULL);
    if (!fixed) {
        free(elements);
        return false;
    }
    free(cache.elements);
    free(cache.fixed);
    free(cache.text);
    cache = (struct registers_cache){.map = map, .elements = elements, .count = count,
                                     .fixed = fixed};
    return true;
}

/* A number as JSON: integers as such, others with as few digits as give
 * the same double back; not finite: null. */
static void json_number(struct strbuf *b, double v)
{
    char text[32];
    int n;

    if (!isfinite(v)) {
        strbuf_append(b, "null", 4);
        return;
    }
    if (v == floor(v) && fabs(v) < 1e15) {
        n = snprintf(text, sizeof(text), "%.0f", v);
    } else {
        n = snprintf(text, sizeof(text), "%.15g", v);
        if (strtod(text, NULL) != v)
            n = snprintf(text, sizeof(text), "%.17g", v);
    }
    strbuf_append(b, text, (size_t)n);
}

/* The member's value, rebuilt when out of date; NULL when out of memory. */
static const char *registers_text(struct gateway *gw, size_t *size)
{
    uint64_t now = uv_now(gw->loop);

    if (!registers_prepare(&gw->map))
        return NULL;
    if (cache.text && cache.documents == gw->counters.documents_parsed &&
        now - cache.built_ms < REGISTERS_MAX_AGE_MS) {
        *size = cache.size;
        return cache.text;
    }
    struct strbuf b;
    strbuf_init(&b, cache.size ? cache.size + 4096 : 131072);
    strbuf_append(&b, "[", 1);
    for (unsigned k = 0; k < cache.count; k++) {
        const struct reg_element *e = &cache.elements[k];
        if (k)
            strbuf_append(&b, ",", 1);
        strbuf_append(&b, cache.fixed + e->head, e->head_len);
        if (e->row->type == REGMAP_STR) {
            char text[300];
            regmap_get_text(&gw->image, e->row, e->i, text, sizeof(text));
            json_string(&b, text);
        } else {
            json_number(&b, regmap_get_number(&gw->image, e->row, e->i));
        }
        strbuf_append(&b, cache.fixed + e->tail, e->tail_len);
    }
    strbuf_append(&b, "]", 1);
    size_t n;
    char *text = strbuf_take(&b, &n);
    if (!text)
        return NULL;
    free(cache.text);
    cache.text = text;
    cache.size = n;
    cache.documents = gw->counters.documents_parsed;
    cache.built_ms = now;
    *size = n;
    return text;
}

/*
 * Writes the printed JSON with <, > and & as \u escapes (only in strings:
 * JSON has them nowhere else), U+2028 and U+2029 as \u escapes too (line
 * ends to older JavaScript), and every byte that is not part of
 * well-formed UTF-8 as U+FFFD: outside text (a robot's errorMsg, a program
 * name) is any bytes, and JSON is UTF-8 or a strict reader refuses all of it.
 */
static char *harden(const char *json, size_t *size)
{
    struct strbuf b;
    size_t len = strlen(json);
    strbuf_init(&b, len + 256);
    const unsigned char *p = (const unsigned char *)json;
    size_t run = 0;
    for (size_t i = 0; i <= len;) {
        const char *esc = NULL;
        size_t n = 1;
        if (p[i] == '<')
            esc = "\\u003c";
        else if (p[i] == '>')
            esc = "\\u003e";
        else if (p[i] == '&')
            esc = "\\u0026";
        else if (p[i] >= 0x80) {
            n = utf8_sequence(p + i, len - i);
            if (n == 0) {
                esc = "\xef\xbf\xbd"; /* U+FFFD for this byte */
                n = 1;
            } else if (n == 3 && p[i] == 0xE2 && p[i + 1] == 0x80 &&
                       (p[i + 2] == 0xA8 || p[i + 2] == 0xA9)) {
                esc = p[i + 2] == 0xA8 ? "\\u2028" : "\\u2029";
            }
        }
        if (!esc && p[i]) {
            i += n;
            continue;
        }
        strbuf_append(&b, json + run, i - run);
        if (!p[i])
            break;
        strbuf_append(&b, esc, strlen(esc));
        i += n;
        run = i;
    }
    strbuf_append(&b, "\n", 1);
    return strbuf_take(&b, size);
}

char *status_json_render(struct gateway *gw, bool registers, size_t *size)
{
    const double *v = gw->gw_values;
    cJSON *root = cJSON_CreateObject();
    if (!root)
        return NULL;

    cJSON *g = cJSON_AddObjectToObject(root, "gateway");
    cJSON_AddStringToObject(g, "version", JAKAGW_VERSION);
    cJSON_AddNumberToObject(g, "uptime_s", v[GW_uptime_s]);
    char crc[16];
    snprintf(crc, sizeof(crc), "%08X", (unsigned)v[GW_map_crc]);
    cJSON_AddStringToObject(g, "map_crc", crc);
    cJSON_AddStringToObject(g, "robot", gw->cfg.robot_host);
    char writes[160];
    config_describe_writes(&gw->cfg, writes, sizeof(writes));
    cJSON_AddStringToObject(g, "modbus_writes", writes);
    cJSON *links = cJSON_AddObjectToObject(root, "links");
    add_link(links, "status", v[GW_status_link_state], v[GW_status_link_up],
             v[GW_status_reconnects]);
    add_link(links, "command", v[GW_command_link_state], v[GW_command_link_up],
             v[GW_command_reconnects]);
    cJSON_AddBoolToObject(root, "status_fresh", v[GW_status_fresh] != 0);
    add_age(root, "status_age_ms", v[GW_status_age_ms]);
    add_robot(root, gw);
    struct clients_ctx ctx = {gw, cJSON_AddArrayToObject(root, "clients")};
    if (ctx.array)
        mb_server_foreach_client(&gw->modbus, add_client, &ctx);
    add_policy(root, gw);
    add_motion(root, gw);
    add_commands(root, "commands", &gw->audit, false);
    add_commands(root, "gateway_commands", &gw->audit, true);
    add_events(root, &gw->events);
    cJSON *counters = cJSON_AddObjectToObject(root, "counters");
    for (unsigned i = 0; counters && i < GW_VALUE_COUNT; i++)
        cJSON_AddNumberToObject(counters, gw_value_names[i], v[i]);
    char *printed = cJSON_PrintUnformatted(root);
    cJSON_Delete(root);
    if (!printed)
        return NULL;
    char *out = harden(printed, size);
    cJSON_free(printed);
    if (!out || !registers)
        return out;
    /* The registers member spliced in before the closing brace (and the
     * newline harden() ends with). */
    size_t reg_size;
    const char *reg = registers_text(gw, &reg_size);
    if (!reg) {
        free(out);
        return NULL;
    }
    struct strbuf b;
    strbuf_init(&b, *size + reg_size + 32);
    strbuf_append(&b, out, *size - 2);
    strbuf_append(&b, ",\"registers\":", 13);
    strbuf_append(&b, reg, reg_size);
    strbuf_append(&b, "}\n", 2);
    free(out);
    return strbuf_take(&b, size);
}
