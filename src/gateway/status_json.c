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

#define NEVER_MS 4294967295.0

static const char *const link_states[] = {"disconnected", "connecting", "connected", "silent"};
static const char *const fault_names[] = {"none", "PLC heartbeat lost", "no Modbus client",
                                          "motion enable dropped"};
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

static void add_commands(cJSON *root, const struct audit *a)
{
    cJSON *array = cJSON_AddArrayToObject(root, "commands");
    for (unsigned i = 0; array && i < audit_count(a); i++) {
        const struct audit_record *r = audit_get(a, i);
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
    cJSON_AddStringToObject(o, "fault_name", (unsigned)p->fault < 4 ? fault_names[p->fault] : "?");
    cJSON_AddNumberToObject(o, "fault_age_ms",
                            (double)policy_fault_age_ms(p, uv_now(gw->loop)));
    cJSON_AddNumberToObject(o, "faults", (double)p->faults);
    cJSON_AddStringToObject(o, "handler", handler < 4 ? handler_names[handler] : "?");
    cJSON_AddStringToObject(o, "write_owner", p->owner_address);
    cJSON_AddBoolToObject(o, "motion_enabled", p->motion_enabled);
    cJSON_AddNumberToObject(o, "time_limit_ms", p->cfg.time_limit_ms);
}

/* Every element of the map: [table, address, name, value, unit]. */
static void add_registers(cJSON *root, const struct gateway *gw)
{
    cJSON *array = cJSON_AddArrayToObject(root, "registers");
    const struct regmap *map = &gw->map;

    for (unsigned r = 0; array && r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        for (unsigned i = 0; i < row->elements; i++) {
            char name[96], text[300];
            cJSON *e = cJSON_CreateArray();
            if (!e || !cJSON_AddItemToArray(array, e)) {
                cJSON_Delete(e);
                return;
            }
            regmap_expand(name, sizeof(name), row->name, row->index + i, i + 1);
            cJSON_AddItemToArray(e, cJSON_CreateNumber(row->table));
            cJSON_AddItemToArray(e, cJSON_CreateNumber(regmap_element_address(row, i)));
            cJSON_AddItemToArray(e, cJSON_CreateString(name));
            if (row->type == REGMAP_STR) {
                regmap_get_text(&gw->image, row, i, text, sizeof(text));
                cJSON_AddItemToArray(e, cJSON_CreateString(text));
            } else {
                double v = regmap_get_number(&gw->image, row, i);
                cJSON_AddItemToArray(e, isfinite(v) ? cJSON_CreateNumber(v) : cJSON_CreateNull());
            }
            cJSON_AddItemToArray(e, cJSON_CreateString(row->unit ? row->unit : ""));
        }
    }
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
    cJSON *links = cJSON_AddObjectToObject(root, "links");
    add_link(links, "status", v[GW_status_link_state], v[GW_status_link_up],
             v[GW_status_reconnects]);
    add_link(links, "command", v[GW_command_link_state], v[GW_command_link_up],
             v[GW_command_reconnects]);
    cJSON_AddBoolToObject(root, "status_fresh", v[GW_status_fresh] != 0);
    add_age(root, "status_age_ms", v[GW_status_age_ms]);
    cJSON *robot = cJSON_AddObjectToObject(root, "robot");
    add_text_row(robot, "controller_version", gw, REGMAP_SRC_PATH, "info.controller_version");
    add_text_row(robot, "loaded_program", gw, REGMAP_SRC_PATH, "info.loaded_program");
    const struct regmap_row *errmsg = NULL;
    for (unsigned r = 0; r < gw->map.row_count && !errmsg; r++)
        if (gw->map.rows[r].source == REGMAP_SRC_STATUS && gw->map.rows[r].type == REGMAP_STR &&
            strcmp(gw->map.rows[r].name, "errmsg") == 0)
            errmsg = &gw->map.rows[r];
    char text[300] = "";
    if (errmsg)
        regmap_get_text(&gw->image, errmsg, 0, text, sizeof(text));
    cJSON_AddStringToObject(robot, "errmsg", text);
    struct clients_ctx ctx = {gw, cJSON_AddArrayToObject(root, "clients")};
    if (ctx.array)
        mb_server_foreach_client(&gw->modbus, add_client, &ctx);
    add_policy(root, gw);
    add_commands(root, &gw->audit);
    cJSON *counters = cJSON_AddObjectToObject(root, "counters");
    for (unsigned i = 0; counters && i < GW_VALUE_COUNT; i++)
        cJSON_AddNumberToObject(counters, gw_value_names[i], v[i]);
    if (registers)
        add_registers(root, gw);
    char *printed = cJSON_PrintUnformatted(root);
    cJSON_Delete(root);
    if (!printed)
        return NULL;
    char *out = harden(printed, size);
    cJSON_free(printed);
    return out;
}
