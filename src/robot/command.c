/* SPDX-License-Identifier: MIT */
/* command.c - the command table and the command queue (command.h). */
#include "command.h"

#include "json_arena.h"

#include <cJSON.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/*
 * Mailbox codes are part of the PLC interface: never renumber one; add new
 * commands with new codes. 'refresh' names the information the gateway
 * fetches again after the command was accepted.
 */
const struct cmd_def cmd_table[] = {
    {"power_on", 0, 1, "", ""},
    {"power_off", 0, 2, "", ""},
    {"enable_robot", 0, 3, "", ""},
    {"disable_robot", 0, 4, "", ""},
    {"clear_error", 0, 5, "", ""},
    {"shutdown", CMD_SHUTDOWN, 6, "", ""},
    {"load_program", 0, 10, "get_loaded_program", "programName$"},
    {"play_program", CMD_STARTS_MOTION, 11, "get_program_state", ""},
    {"pause_program", CMD_HALTS, 12, "get_program_state", ""},
    {"resume_program", CMD_STARTS_MOTION, 13, "get_program_state", ""},
    {"stop_program", CMD_HALTS, 14, "get_program_state", ""},
    {"rapid_rate", 0, 20, "", "rate_value"},
    {"set_digital_output", 0, 21, "", "type#,index#,value#"},
    {"set_analog_output", 0, 22, "", "type#,index#,value"},
    {"set_tool_id", 0, 23, "", "tool_id#"},
    {"set_user_id", 0, 24, "", "user_frame_id#"},
    {"set_payload", 0, 25, "get_payload", "mass,centroid[3]"},
    {"set_clsn_sensitivity", 0, 26, "get_clsn_sensitivity", "sensitivityVal#"},
    {"joint_move", CMD_MOTION, 30, "", "jointPosition[6],speed,accel,relFlag#"},
    {"end_move", CMD_MOTION, 31, "", "endPosition[6],speed,accel"},
    {"moveL", CMD_MOTION, 32, "", "cartPosition[6],speed,accel,relFlag#,tol"},
    /* Sent by the gateway itself, or through the JSON mailbox only. */
    {"get_loaded_program", 0, 0, "", ""},
    {"get_program_state", 0, 0, "", ""},
    {"get_version", 0, 0, "", ""},
    {"get_payload", 0, 0, "", ""},
    {"get_clsn_sensitivity", 0, 0, "", ""},
    {"set_network_exception_handle", 0, 0, "", ""},
    {"get_tool_offsets", 0, 0, "", ""},
    {"get_user_offsets", 0, 0, "", ""},
    {"get_dh_param", 0, 0, "", ""},
    /* Through the JSON mailbox: what they change is fetched again. */
    {"set_tool_offsets", 0, 0, "get_tool_offsets", ""},
    {"set_user_offsets", 0, 0, "get_user_offsets", ""},
    /* Chapter 4's queries, through the JSON mailbox: none moves the arm. */
    {"get_data", 0, 0, "", ""},
    {"get_joint_pos", 0, 0, "", ""},
    {"get_tcp_pos", 0, 0, "", ""},
    {"get_robot_state", 0, 0, "", ""},
    {"kine_forward", 0, 0, "", ""},
    {"kine_inverse", 0, 0, "", ""},
    {"get_digital_input_status", 0, 0, "", ""},
    {"get_funcdi_status", 0, 0, "", ""},
    {"get_extio_status", 0, 0, "", ""},
    {"get_tio_vout_param", 0, 0, "", ""},
    {"get_tool_payload", 0, 0, "", ""},
    {"get_compliant_type", 0, 0, "", ""},
    {"get_admit_ctrl_config", 0, 0, "", ""},
    {"get_torque_sensor_comm", 0, 0, "", ""},
    {"get_torsenosr_brand", 0, 0, "", ""},
    {"get_torq_sensor_identify_staus", 0, 0, "", ""},
    {"get_torq_sensor_payload_identify_result", 0, 0, "", ""},
    {"get_traj_config", 0, 0, "", ""},
    {"get_traj_sample_status", 0, 0, "", ""},
    {"get_exist_traj_file_name", 0, 0, "", ""},
    {"is_in_servomove", 0, 0, "", ""},
    {"drag_status", 0, 0, "", ""},
    {"protective_stop_status", 0, 0, "", ""},
    {"emergency_stop_status", 0, 0, "", ""},
    {"query_user_defined_variable", 0, 0, "", ""},
    {"wait_complete", 0, 0, "", ""},
    /* Settings that move nothing by themselves. */
    {"set_tool_payload", 0, 0, "", ""},
    {"set_tio_vout_param", 0, 0, "", ""},
    {"set_torque_sensor_comm", 0, 0, "", ""},
    {"set_torsenosr_brand", 0, 0, "", ""},
    {"set_traj_config", 0, 0, "", ""},
    {"set_servo_move_filter", 0, 0, "", ""},
    {"modify_user_defined_variable", 0, 0, "", ""},
    {"generate_traj_exe_file", 0, 0, "", ""},
    {"remove_traj_file", 0, 0, "", ""},
    {"rename_traj_file_name", 0, 0, "", ""},
    {"disable_force_control", 0, 0, "", ""},
    /* Motion of any kind, recognised in the JSON mailbox. */
    {"jog", CMD_MOTION, 0, "", ""},
    {"movc", CMD_MOTION, 0, "", ""},
    {"servo_move", CMD_MOTION, 0, "", ""},
    {"servo_j", CMD_MOTION, 0, "", ""},
    {"servo_p", CMD_MOTION, 0, "", ""},
    {"torque_control_enable", CMD_MOTION, 0, "", ""},
    /* These move the arm, or let forces move it. */
    {"start_torq_sensor_payload_identify", CMD_MOTION, 0, "", ""},
    {"enable_admittance_ctrl", CMD_MOTION, 0, "", ""},
    {"set_compliant_type", CMD_MOTION, 0, "", ""},
    {"set_traj_sample_mode", CMD_MOTION, 0, "", ""},
    {"set_admit_ctrl_config", CMD_MOTION, 0, "", ""},
    {"set_compliance_condition", CMD_MOTION, 0, "", ""},
    {"set_vel_compliant_ctrl", CMD_MOTION, 0, "", ""},
    {"set_torque_sensor_mode", CMD_MOTION, 0, "", ""},
};
const unsigned cmd_table_count = sizeof(cmd_table) / sizeof(cmd_table[0]);

/* Equal names, where a space matches an underscore: the manual writes
 * "joint move" for joint_move, and some controllers may accept either. */
static bool same_name(const char *table_name, const char *name)
{
    for (; *table_name && *name; table_name++, name++)
        if (*table_name != *name && !(*table_name == '_' && *name == ' '))
            return false;
    return *table_name == *name;
}

const struct cmd_def *cmd_find(const char *name)
{
    for (unsigned i = 0; i < cmd_table_count; i++)
        if (same_name(cmd_table[i].name, name))
            return &cmd_table[i];
    return NULL;
}

const struct cmd_def *cmd_find_code(unsigned code)
{
    for (unsigned i = 0; code && i < cmd_table_count; i++)
        if (cmd_table[i].code == code)
            return &cmd_table[i];
    return NULL;
}

const char *cmd_outcome_name(enum cmd_outcome outcome)
{
    static const char *const names[] = {
        [CMD_IDLE] = "idle",         [CMD_PENDING] = "pending",
        [CMD_DONE] = "done",         [CMD_ROBOT_ERROR] = "robot error",
        [CMD_TIMEOUT] = "timeout",   [CMD_LINK_DOWN] = "link down",
        [CMD_INVALID] = "invalid",   [CMD_REFUSED] = "refused",
        [CMD_NOT_SENT] = "not sent",
    };
    return (unsigned)outcome < sizeof(names) / sizeof(names[0]) ? names[outcome] : "?";
}

/*
 * The trees of a command read for its name and of a reply: their nodes come
 * from this arena (json_arena.h), not a malloc and a free each (for a
 * reply of a few members, half of what reading it cost). Nothing of a tree
 * outlives the function that parsed it.
 */
static struct json_arena arena;

/*
 * The members of a flat object, read without a tree: a command as the
 * gateway builds it and a reply as the controller sends it
 * ({"cmdName":"power_on","errorCode":"0","errorMsg":""}) are one level of
 * string keys and plain values. scan_flat_object() takes only strict JSON
 * that cJSON reads the same way (strings of printable ASCII without
 * escapes, numbers of JSON's own grammar, the object alone up to the
 * end); anything else (nesting, escapes, literals, other bytes) returns
 * false and is parsed with cJSON, so what it finds is what cJSON's lookup
 * would (the first member of a name).
 */
enum flat_kind { FLAT_ABSENT, FLAT_STRING, FLAT_NUMBER };

/* A member to look for, named by a string literal. */
#define FLAT_KEY(name) {.key = (name), .key_len = sizeof(name) - 1}

struct flat_member {
    const char *key;
    size_t key_len;
    enum flat_kind kind;
    const char *text; /* a string's bytes, without quotes */
    size_t len;
};

static bool is_json_space(char c)
{
    return c == ' ' || c == '\t' || c == '\n' || c == '\r';
}

static const char *skip_space(const char *p, const char *end)
{
    while (p < end && is_json_space(*p))
        p++;
    return p;
}

/* A string at 'p' (its opening quote); the byte after its closing quote,
 * or NULL when it is not one the scan takes. */
static const char *scan_string(const char *p, const char *end)
{
    if (p >= end || *p != '"')
        return NULL;
    for (p++; p < end; p++) {
        unsigned char c = (unsigned char)*p;
        if (c == '"')
            return p + 1;
        if (c < 0x20 || c > 0x7E || c == '\\')
            return NULL;
    }
    return NULL;
}

static bool is_digit(char c)
{
    return c >= '0' && c <= '9';
}

/* A number of JSON's grammar at 'p'; the byte after it, or NULL. */
static const char *scan_number(const char *p, const char *end)
{
    if (p < end && *p == '-')
        p++;
    if (p >= end || !is_digit(*p))
        return NULL;
    if (*p == '0')
        p++;
    else
        while (p < end && is_digit(*p))
            p++;
    if (p < end && *p == '.') {
        if (++p >= end || !is_digit(*p))
            return NULL;
        while (p < end && is_digit(*p))
            p++;
    }
    if (p < end && (*p == 'e' || *p == 'E')) {
        if (++p < end && (*p == '+' || *p == '-'))
            p++;
        if (p >= end || !is_digit(*p))
            return NULL;
        while (p < end && is_digit(*p))
            p++;
    }
    return p;
}

/* Notes a member for the first of the keys 'm' it is. */
static void note_member(struct flat_member *m, unsigned n, const char *key, size_t key_len,
                        enum flat_kind kind, const char *text, size_t len)
{
    for (unsigned i = 0; i < n; i++)
        if (m[i].kind == FLAT_ABSENT && m[i].key_len == key_len &&
            memcmp(m[i].key, key, key_len) == 0) {
            m[i].kind = kind;
            m[i].text = text;
            m[i].len = len;
            return;
        }
}

static bool scan_flat_object(const char *json, size_t size, struct flat_member *m, unsigned n)
{
    const char *p = json, *end = json + size;

    for (unsigned i = 0; i < n; i++)
        m[i].kind = FLAT_ABSENT;
    p = skip_space(p, end);
    if (p >= end || *p++ != '{')
        return false;
    p = skip_space(p, end);
    if (p < end && *p == '}')
        return skip_space(p + 1, end) == end;
    for (;;) {
        const char *key = p;
        if (!(p = scan_string(p, end)))
            return false;
        size_t key_len = (size_t)(p - key) - 2;
        p = skip_space(p, end);
        if (p >= end || *p++ != ':')
            return false;
        p = skip_space(p, end);
        const char *value = p;
        enum flat_kind kind = p < end && *p == '"' ? FLAT_STRING : FLAT_NUMBER;
        if (!(p = kind == FLAT_STRING ? scan_string(p, end) : scan_number(p, end)))
            return false;
        if (kind == FLAT_STRING)
            note_member(m, n, key + 1, key_len, kind, value + 1, (size_t)(p - value) - 2);
        else
            note_member(m, n, key + 1, key_len, kind, value, (size_t)(p - value));
        p = skip_space(p, end);
        if (p < end && *p == ',') {
            p = skip_space(p + 1, end);
            continue;
        }
        if (p < end && *p == '}')
            return skip_space(p + 1, end) == end;
        return false;
    }
}

/* The outcome an errorCode given as text says (as strtol reads it). */
static void judge_code_text(struct cmd_result *r, const char *code)
{
    char *end = NULL;

    r->error_code = strtol(code, &end, 10);
    if (*end != '\0') {
        r->outcome = CMD_ROBOT_ERROR;
        r->error_code = -1;
        snprintf(r->error_msg, sizeof(r->error_msg), "errorCode '%.60s' is not a number", code);
    } else {
        r->outcome = r->error_code == 0 ? CMD_DONE : CMD_ROBOT_ERROR;
    }
}

/* A flat reply whose errorCode, if any, is text: read without cJSON. False
 * when the reply is not one (cJSON reads it then). */
static bool parse_flat_reply(const char *json, size_t size, struct cmd_result *r)
{
    struct flat_member m[2] = {FLAT_KEY("errorCode"), FLAT_KEY("errorMsg")};
    char code[64];

    if (!scan_flat_object(json, size, m, 2) || m[0].kind == FLAT_NUMBER ||
        m[0].len >= sizeof(code))
        return false;
    memset(r, 0, sizeof(*r));
    r->reply = json;
    r->reply_size = size;
    if (m[0].kind == FLAT_STRING && m[0].len > 0) {
        memcpy(code, m[0].text, m[0].len);
        code[m[0].len] = '\0';
        judge_code_text(r, code);
    } else {
        r->outcome = CMD_ROBOT_ERROR;
        r->error_code = -1;
        snprintf(r->error_msg, sizeof(r->error_msg), "reply has no errorCode");
    }
    if (m[1].kind == FLAT_STRING && r->error_msg[0] == '\0') {
        size_t len = m[1].len < sizeof(r->error_msg) - 1 ? m[1].len : sizeof(r->error_msg) - 1;
        memcpy(r->error_msg, m[1].text, len);
        r->error_msg[len] = '\0';
    }
    return true;
}

void cmd_parse_reply(const char *json, size_t size, struct cmd_result *r)
{
    if (parse_flat_reply(json, size, r))
        return;
    const cJSON *doc = json_arena_parse(&arena, json, size);
    const cJSON *code = cJSON_GetObjectItemCaseSensitive(doc, "errorCode");
    const cJSON *msg = cJSON_GetObjectItemCaseSensitive(doc, "errorMsg");

    memset(r, 0, sizeof(*r));
    r->reply = json;
    r->reply_size = size;
    if (!cJSON_IsObject(doc)) {
        r->outcome = CMD_ROBOT_ERROR;
        r->error_code = -1;
        snprintf(r->error_msg, sizeof(r->error_msg), "reply is not a JSON object");
    } else if (cJSON_IsNumber(code) || (cJSON_IsString(code) && code->valuestring[0])) {
        /* Real controllers send "0", "1", "2", "-1", "3"; some a number. */
        /* A number outside long's range would be undefined to convert. */
        bool huge = cJSON_IsNumber(code) &&
                    !(code->valuedouble > -2147483648.0 && code->valuedouble < 2147483648.0);
        if (cJSON_IsString(code)) {
            judge_code_text(r, code->valuestring);
        } else if (huge) {
            r->error_code = -1;
            r->outcome = CMD_ROBOT_ERROR;
            snprintf(r->error_msg, sizeof(r->error_msg), "errorCode %g is out of range",
                     code->valuedouble);
        } else {
            r->error_code = (long)code->valuedouble;
            r->outcome = r->error_code == 0 ? CMD_DONE : CMD_ROBOT_ERROR;
        }
    } else {
        r->outcome = CMD_ROBOT_ERROR;
        r->error_code = -1;
        snprintf(r->error_msg, sizeof(r->error_msg), "reply has no errorCode");
    }
    if (cJSON_IsString(msg) && r->error_msg[0] == '\0')
        snprintf(r->error_msg, sizeof(r->error_msg), "%s", msg->valuestring);
    json_arena_reset(&arena);
}

void cmd_queue_init(struct cmd_queue *q, const struct cmd_ops *ops,
                    uint32_t timeout_ms)
{
    memset(q, 0, sizeof(*q));
    q->ops = *ops;
    q->timeout_ms = timeout_ms;
}

static struct cmd_entry *entry_at(struct cmd_queue *q, unsigned i)
{
    return &q->entries[(q->head + i) % CMD_QUEUE_CAPACITY];
}

/* Removes the head entry and reports 'r' to its owner, with when it was
 * written. */
static void finish_head(struct cmd_queue *q, const struct cmd_result *r)
{
    struct cmd_entry e = *entry_at(q, 0);
    struct cmd_result told = *r;

    told.sent_at_ms = e.sent ? e.sent_at_ms : 0;
    q->head = (q->head + 1) % CMD_QUEUE_CAPACITY;
    q->count--;
    q->in_flight = false;
    free(e.json);
    e.done(e.user, &told);
}

static void fail_head(struct cmd_queue *q, enum cmd_outcome outcome, const char *why)
{
    struct cmd_result r = {.outcome = outcome};
    snprintf(r.error_msg, sizeof(r.error_msg), "%s", why);
    finish_head(q, &r);
}

/*
 * A command lost with its connection. Written, the robot may have acted on
 * it: its outcome is unknown. Never written, the robot never got it. The
 * texts lead with that, since a PLC reads their first 40 bytes.
 */
static void fail_head_lost(struct cmd_queue *q, const char *why_sent,
                           const char *why_not_sent)
{
    if (entry_at(q, 0)->sent) {
        q->stats.failed_link_down++;
        fail_head(q, CMD_LINK_DOWN, why_sent);
    } else {
        q->stats.not_sent++;
        fail_head(q, CMD_NOT_SENT, why_not_sent);
    }
}

/*
 * Can the command 'json' start or continue motion? Its cmdName in the
 * table with CMD_MOTION or CMD_STARTS_MOTION; a name the table does not
 * know, or no name, could be anything (the JSON mailbox passes such text
 * only with motion allowed): counted as motion.
 */
static bool command_moves(const char *json, size_t size)
{
    struct flat_member m = FLAT_KEY("cmdName");
    char text[64];

    if (scan_flat_object(json, size, &m, 1) && (m.kind != FLAT_STRING || m.len < sizeof(text))) {
        if (m.kind != FLAT_STRING)
            return true;
        memcpy(text, m.text, m.len);
        text[m.len] = '\0';
        const struct cmd_def *found = cmd_find(text);
        return !found || (found->flags & (CMD_MOTION | CMD_STARTS_MOTION));
    }
    const cJSON *doc = json_arena_parse(&arena, json, size);
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(doc, "cmdName");
    const struct cmd_def *def = cJSON_IsString(name) ? cmd_find(name->valuestring) : NULL;
    bool moves = !def || (def->flags & (CMD_MOTION | CMD_STARTS_MOTION));

    json_arena_reset(&arena);
    return moves;
}

/* Writes an entry; 0 or the send's error. */
static int write_entry(struct cmd_queue *q, struct cmd_entry *e)
{
    int rc = q->ops.send(q->ops.io, e->json, e->size);
    if (rc < 0)
        return rc;
    e->sent = true;
    e->sent_at_ms = q->ops.now_ms(q->ops.io);
    q->stats.sent++;
    return 0;
}

/* The head is in flight: its reply's deadline runs from when it went out. */
static void start_flight(struct cmd_queue *q)
{
    const struct cmd_entry *head = entry_at(q, 0);

    q->in_flight = true;
    q->sent_at_ms = head->sent_at_ms;
    q->flight_timeout_ms = head->timeout_ms ? head->timeout_ms : q->timeout_ms;
    if (q->ops.sent)
        q->ops.sent(q->ops.io);
}

/* Puts the head in flight, writing it unless it went out already. */
static void send_next(struct cmd_queue *q)
{
    while (q->count > 0 && !q->in_flight && q->connected) {
        struct cmd_entry *e = entry_at(q, 0);
        int rc = e->sent ? 0 : write_entry(q, e);
        if (rc < 0) {
            char why[96];
            /* Whole in a result's 40 bytes: a long message by its number. */
            if (strlen(strerror(-rc)) <= 30)
                snprintf(why, sizeof(why), "not sent: %s", strerror(-rc));
            else
                snprintf(why, sizeof(why), "not sent: write error %d", -rc);
            q->stats.not_sent++;
            fail_head(q, CMD_NOT_SENT, why);
            continue;
        }
        start_flight(q);
    }
}

/*
 * Entry 'e' (a command, not a check) was just written behind the link
 * check in flight. The check's own bound is short (it is there to find a
 * dead idle link), but the command's reply now comes only after the
 * check's: the connection is given the command's whole reply timeout,
 * counted from its own send, before it is cut. Else a command, a safety
 * action above all, written just before the check's bound would be cut
 * with the link after a few milliseconds and read "outcome unknown"
 * (possibly never delivered) where it would have had reply_timeout_ms.
 */
static void extend_check_for(struct cmd_queue *q, const struct cmd_entry *e)
{
    if (!q->in_flight || !entry_at(q, 0)->check || e->check)
        return;
    uint64_t need = e->sent_at_ms - q->sent_at_ms + q->timeout_ms;
    if (need > q->flight_timeout_ms)
        q->flight_timeout_ms = need > UINT32_MAX ? UINT32_MAX : (uint32_t)need;
}

/* Is every entry before 'n' a link check written already? Then nothing
 * waits: the entry at 'n' may be written at once, behind them. */
static bool only_checks_before(struct cmd_queue *q, unsigned n)
{
    for (unsigned i = 0; i < n; i++) {
        const struct cmd_entry *e = entry_at(q, i);
        if (!e->check || !e->sent)
            return false;
    }
    return true;
}

static int submit_entry(struct cmd_queue *q, const char *json, size_t size, bool moves,
                        cmd_done_cb done, void *user);

int cmd_queue_submit(struct cmd_queue *q, const char *json, size_t size,
                     cmd_done_cb done, void *user)
{
    return submit_entry(q, json, size, command_moves(json, size), done, user);
}

int cmd_queue_submit_def(struct cmd_queue *q, const struct cmd_def *def, const char *json,
                         size_t size, cmd_done_cb done, void *user)
{
    return submit_entry(q, json, size, def->flags & (CMD_MOTION | CMD_STARTS_MOTION), done,
                        user);
}

static int submit_entry(struct cmd_queue *q, const char *json, size_t size, bool moves,
                        cmd_done_cb done, void *user)
{
    if (!q->connected)
        return -ENOTCONN;
    if (q->count == CMD_QUEUE_CAPACITY)
        return -EBUSY;
    char *copy = malloc(size);
    if (!copy)
        return -ENOMEM;
    memcpy(copy, json, size);
    struct cmd_entry *e = entry_at(q, q->count);
    *e = (struct cmd_entry){.json = copy, .size = size, .done = done, .user = user,
                            .moves = moves};
    q->count++;
    /* Only an empty queue sends at once: a command submitted from a done
     * callback, while others wait, must not jump ahead of them. Behind a
     * link check nothing waits: the command goes out at once, pipelined,
     * and its reply is matched after the check's. */
    bool empty = !q->in_flight && q->count == 1;
    if (empty || only_checks_before(q, q->count - 1)) {
        /* Sent now: a failure here is the caller's to report. */
        int rc = write_entry(q, e);
        if (rc < 0) {
            q->count--;
            free(copy);
            return rc;
        }
        if (empty)
            start_flight(q);
        else
            extend_check_for(q, e);
    }
    return 0;
}

int cmd_queue_submit_check(struct cmd_queue *q, const char *json, size_t size,
                           uint32_t timeout_ms, cmd_done_cb done, void *user)
{
    if (!q->connected)
        return -ENOTCONN;
    /* A command in flight or queued: the link is in use, and its own
     * reply timeout watches it. */
    if (q->in_flight || q->count > 0)
        return -EBUSY;
    char *copy = malloc(size);
    if (!copy)
        return -ENOMEM;
    memcpy(copy, json, size);
    struct cmd_entry *e = entry_at(q, 0);
    *e = (struct cmd_entry){.json = copy, .size = size, .done = done, .user = user,
                            .check = true, .timeout_ms = timeout_ms};
    q->count = 1;
    int rc = write_entry(q, e);
    if (rc < 0) {
        q->count = 0;
        free(copy);
        return rc;
    }
    q->stats.checks++;
    start_flight(q);
    return 0;
}

/*
 * Takes every unwritten command that can start or continue motion out of
 * the queue, in order, into 'out' (their owners are told later, once the
 * queue is whole again: a callback may submit or drop the link). Returns
 * how many.
 */
static unsigned take_out_motion(struct cmd_queue *q, struct cmd_entry *out)
{
    unsigned kept = 0, taken = 0;

    for (unsigned i = 0; i < q->count; i++) {
        struct cmd_entry *e = entry_at(q, i);
        if (!e->sent && e->moves)
            out[taken++] = *e;
        else
            *entry_at(q, kept++) = *e;
    }
    q->count = kept;
    return taken;
}

/* The owners of commands a safety action took out learn it: not sent. */
static void fail_taken_out(struct cmd_queue *q, struct cmd_entry *taken, unsigned n,
                           const char *why)
{
    for (unsigned i = 0; i < n; i++) {
        struct cmd_result r = {.outcome = CMD_NOT_SENT};
        snprintf(r.error_msg, sizeof(r.error_msg), "%s", why);
        q->stats.not_sent++;
        free(taken[i].json);
        taken[i].done(taken[i].user, &r);
    }
}

int cmd_queue_submit_urgent(struct cmd_queue *q, const char *json, size_t size,
                            cmd_done_cb done, void *user)
{
    /* On the stack (2 x 64 entries, 7 KiB): a done callback told below may
     * submit another safety action, which needs its own. */
    struct cmd_entry saved[CMD_QUEUE_CAPACITY], taken[CMD_QUEUE_CAPACITY];
    struct cmd_entry displaced = {0};
    unsigned saved_count = q->count, taken_count;

    if (!q->connected)
        return -ENOTCONN;
    if (!q->in_flight && q->count == 0)
        return cmd_queue_submit(q, json, size, done, user);
    char *copy = malloc(size);
    if (!copy)
        return -ENOMEM;
    memcpy(copy, json, size);
    /* The queue as it was, in case the action cannot be written. */
    for (unsigned i = 0; i < saved_count; i++)
        saved[i] = *entry_at(q, i);
    /* Nothing that could move the arm may follow the action. */
    taken_count = take_out_motion(q, taken);
    if (q->count == CMD_QUEUE_CAPACITY) {
        /* Room for safety first: the newest unwritten command gives way. */
        if (entry_at(q, q->count - 1)->sent) {
            free(copy);
            return -EBUSY; /* every entry written already */
        }
        displaced = *entry_at(q, q->count - 1);
        q->count--;
    }
    /* Behind what is written already, ahead of what is not. */
    unsigned at = 0;
    while (at < q->count && entry_at(q, at)->sent)
        at++;
    for (unsigned i = q->count; i > at; i--)
        *entry_at(q, i) = *entry_at(q, i - 1);
    struct cmd_entry *e = entry_at(q, at);
    *e = (struct cmd_entry){.json = copy, .size = size, .done = done, .user = user};
    q->count++;
    int rc = write_entry(q, e);
    if (rc < 0) {
        /* Not sent after all: the queue is as it was. */
        for (unsigned i = 0; i < saved_count; i++)
            *entry_at(q, i) = saved[i];
        q->count = saved_count;
        free(copy);
        return rc;
    }
    if (at > 0)
        extend_check_for(q, e);
    if (displaced.json)
        fail_taken_out(q, &displaced, 1, "not sent: displaced by a safety action");
    fail_taken_out(q, taken, taken_count, "not sent: a safety action took its place");
    if (!q->in_flight)
        send_next(q); /* at == 0: it is the head now */
    return 0;
}

static void fail_all(struct cmd_queue *q, const char *why_sent, const char *why_not_sent)
{
    while (q->count > 0)
        fail_head_lost(q, why_sent, why_not_sent);
}

void cmd_queue_set_connected(struct cmd_queue *q, bool connected)
{
    q->connected = connected;
    /* Also when already marked down (after a reply timeout): whatever is
     * still queued then must not wait for a connection that is gone. */
    if (!connected)
        fail_all(q, "outcome unknown: the link went down",
                 "not sent: the link went down");
}

void cmd_queue_on_reply(struct cmd_queue *q, const char *json, size_t size)
{
    struct cmd_result r;

    if (!q->in_flight) {
        q->stats.unsolicited++;
        return;
    }
    cmd_parse_reply(json, size, &r);
    q->stats.replies++;
    if (r.outcome == CMD_ROBOT_ERROR)
        q->stats.robot_errors++;
    finish_head(q, &r);
    send_next(q);
}

void cmd_queue_check_timeout(struct cmd_queue *q)
{
    if (!q->in_flight ||
        q->ops.now_ms(q->ops.io) - q->sent_at_ms < q->flight_timeout_ms)
        return;
    char why[96], msg[64];
    bool check = entry_at(q, 0)->check;
    unsigned limit = (unsigned)q->flight_timeout_ms;
    if (check)
        snprintf(why, sizeof(why), "link check unanswered within %u ms", limit);
    else
        snprintf(why, sizeof(why), "no reply within %u ms; the outcome is unknown", limit);
    snprintf(msg, sizeof(msg), "outcome unknown: no reply in %u ms", limit);
    q->stats.timeouts++;
    if (check)
        q->stats.checks_failed++;
    /* The connection is condemned from here: nothing a callback submits
     * may be written to it. */
    q->connected = false;
    fail_head(q, CMD_TIMEOUT, msg);
    /* The late reply must never answer the next command: drop the
     * connection it would come on, and what was queued behind it. */
    fail_all(q, "outcome unknown: link restarted", "not sent: link restarted");
    q->ops.restart_link(q->ops.io, why);
}

uint64_t cmd_queue_next_deadline_ms(const struct cmd_queue *q)
{
    if (!q->in_flight)
        return UINT64_MAX;
    uint64_t elapsed = q->ops.now_ms(q->ops.io) - q->sent_at_ms;
    return elapsed >= q->flight_timeout_ms ? 0 : q->flight_timeout_ms - elapsed;
}

unsigned cmd_queue_pending(const struct cmd_queue *q)
{
    return q->count;
}

void cmd_queue_free(struct cmd_queue *q)
{
    fail_all(q, "outcome unknown: the gateway stopped", "not sent: the gateway is stopping");
    json_arena_free(&arena);
}
