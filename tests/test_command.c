/* SPDX-License-Identifier: MIT */
/*
 * test_command.c - the command queue (command.h) with a fake link and a
 * fake clock: one command at a time, replies matched by order, the reply
 * timeout, the link going down, and done callbacks that run exactly once.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cJSON.h>

#include "command.h"

#define MAX_SENT 256
#define MAX_JOBS 160

/* The robot side: what was sent, the clock, restarts. */
struct fake_link {
    struct cmd_queue *q;
    char sent[MAX_SENT][128];
    unsigned sent_count;
    int fail_sends;   /* the next this many sends fail with send_error */
    int send_error;
    uint64_t now;
    unsigned restarts;
    char restart_why[128];
    bool restart_disconnects; /* restart_link drops the link, as robot_link does */
    bool in_submit;           /* inside cmd_queue_submit (test_submit) */
};

/* One command as its owner sees it. */
struct job {
    const char *json;
    unsigned calls;
    struct cmd_result result; /* reply pointer cleared: it dies with the call */
    char reply[256];
    unsigned order; /* position among all done callbacks, from 1 */
    /* A command to submit from inside this job's done callback. */
    struct job *submit_from_done;
    int submit_from_done_rc;
};

static struct fake_link link;
static struct cmd_queue queue;
static unsigned done_calls;
/* Set by the teardown: a test that failed half-way leaves commands whose
 * jobs lived on its stack; their callbacks must not touch them. */
static bool tearing_down;

static int fake_send(void *io, const char *data, size_t size)
{
    struct fake_link *l = io;
    if (l->fail_sends > 0) {
        l->fail_sends--;
        return l->send_error;
    }
    assert_true(l->sent_count < MAX_SENT);
    assert_true(size < sizeof(l->sent[0]));
    memcpy(l->sent[l->sent_count], data, size);
    l->sent[l->sent_count][size] = '\0';
    l->sent_count++;
    return 0;
}

static uint64_t fake_now(void *io)
{
    return ((struct fake_link *)io)->now;
}

static void fake_restart(void *io, const char *why)
{
    struct fake_link *l = io;
    l->restarts++;
    snprintf(l->restart_why, sizeof(l->restart_why), "%s", why);
    if (l->restart_disconnects)
        cmd_queue_set_connected(l->q, false);
}

static int test_submit(struct job *j);

static void on_done(void *user, const struct cmd_result *r)
{
    struct job *j = user;

    if (tearing_down)
        return;
    /* Never from inside cmd_queue_submit, never twice. */
    assert_false(link.in_submit);
    assert_int_equal(j->calls, 0);
    j->calls++;
    j->order = ++done_calls;
    j->result = *r;
    j->result.reply = NULL;
    j->reply[0] = '\0';
    if (r->reply) {
        assert_true(r->reply_size < sizeof(j->reply));
        memcpy(j->reply, r->reply, r->reply_size);
        j->reply[r->reply_size] = '\0';
    }
    if (j->submit_from_done)
        j->submit_from_done_rc = test_submit(j->submit_from_done);
}

static int test_submit(struct job *j)
{
    bool outer = link.in_submit;
    link.in_submit = true;
    int rc = cmd_queue_submit(&queue, j->json, strlen(j->json), on_done, j);
    link.in_submit = outer;
    return rc;
}

static void reply(const char *json)
{
    cmd_queue_on_reply(&queue, json, strlen(json));
}

static const char *last_sent(void)
{
    return link.sent_count ? link.sent[link.sent_count - 1] : "";
}

static int setup(void **state)
{
    (void)state;
    struct cmd_ops ops = {.send = fake_send, .now_ms = fake_now,
                          .restart_link = fake_restart, .io = &link};
    memset(&link, 0, sizeof(link));
    link.q = &queue;
    link.now = 1000;
    link.send_error = -EPIPE;
    done_calls = 0;
    tearing_down = false;
    cmd_queue_init(&queue, &ops, 500);
    cmd_queue_set_connected(&queue, true);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    tearing_down = true;
    cmd_queue_free(&queue);
    assert_int_equal(cmd_queue_pending(&queue), 0);
    return 0;
}

static void table_lookups(void **state)
{
    (void)state;
    assert_non_null(cmd_find("power_on"));
    assert_int_equal(cmd_find("power_on")->code, 1);
    assert_null(cmd_find("power"));
    assert_null(cmd_find(""));
    assert_string_equal(cmd_find_code(14)->name, "stop_program");
    assert_null(cmd_find_code(0)); /* commands without a code are not offered */
    assert_null(cmd_find_code(999));
    assert_true(cmd_find("joint_move")->flags & CMD_MOTION);
    assert_true(cmd_find("shutdown")->flags & CMD_SHUTDOWN);
    /* Mailbox codes are unique. */
    for (unsigned i = 0; i < cmd_table_count; i++)
        if (cmd_table[i].code)
            assert_ptr_equal(cmd_find_code(cmd_table[i].code), &cmd_table[i]);
    assert_string_equal(cmd_outcome_name(CMD_DONE), "done");
    assert_string_equal(cmd_outcome_name(CMD_LINK_DOWN), "link down");
    assert_string_equal(cmd_outcome_name(CMD_NOT_SENT), "not sent");
    assert_string_equal(cmd_outcome_name((enum cmd_outcome)99), "?");
}

/* Each result says when its command was written (a move's time bound
 * begins then): not when it was queued, not when its reply came; a
 * command never written says 0. */
static void results_say_when_written(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"rapid_rate\",\"rate_value\":0.5}"};
    struct job b = {.json = "{\"cmdName\":\"joint_move\",\"jointPosition\":[1,2,3,4,5,6]}"};
    struct job c = {.json = "{\"cmdName\":\"power_on\"}"};

    assert_int_equal(test_submit(&a), 0); /* written at 1000 */
    link.now = 1010;
    assert_int_equal(test_submit(&b), 0); /* queued at 1010, behind a */
    link.now = 1400;
    reply("{\"errorCode\":\"0\"}"); /* a's reply: b written at 1400 */
    assert_int_equal(a.result.sent_at_ms, 1000);
    link.now = 2000;
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(b.result.outcome, CMD_DONE);
    assert_int_equal(b.result.sent_at_ms, 1400);
    /* Never written: the link down before its turn. The one written
     * before it, with no reply, says when. */
    struct job d = {.json = "{\"cmdName\":\"enable_robot\"}"};
    assert_int_equal(test_submit(&d), 0);
    assert_int_equal(test_submit(&c), 0);
    link.now = 2100;
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(d.result.outcome, CMD_LINK_DOWN);
    assert_int_equal(d.result.sent_at_ms, 2000);
    assert_int_equal(c.result.outcome, CMD_NOT_SENT);
    assert_int_equal(c.result.sent_at_ms, 0);
}

static void one_at_a_time_in_order(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"enable_robot\"}"};
    struct job c = {.json = "{\"cmdName\":\"play_program\"}"};

    assert_int_equal(cmd_queue_next_deadline_ms(&queue), UINT64_MAX);
    assert_int_equal(test_submit(&a), 0);
    assert_int_equal(test_submit(&b), 0);
    assert_int_equal(test_submit(&c), 0);
    /* Only the first goes out; the others wait for its reply. */
    assert_int_equal(link.sent_count, 1);
    assert_string_equal(link.sent[0], a.json);
    assert_int_equal(cmd_queue_pending(&queue), 3);
    assert_int_equal(done_calls, 0);

    reply("{\"cmdName\":\"power_on\",\"errorCode\":\"0\",\"errorMsg\":\"\"}");
    assert_int_equal(a.calls, 1);
    assert_int_equal(a.result.outcome, CMD_DONE);
    assert_int_equal(link.sent_count, 2);
    assert_string_equal(link.sent[1], b.json);
    assert_int_equal(b.calls, 0);

    reply("{\"cmdName\":\"enable_robot\",\"errorCode\":\"0\"}");
    assert_int_equal(link.sent_count, 3);
    assert_string_equal(link.sent[2], c.json);
    reply("{\"cmdName\":\"play_program\",\"errorCode\":\"0\"}");
    assert_int_equal(link.sent_count, 3);
    assert_int_equal(a.order, 1);
    assert_int_equal(b.order, 2);
    assert_int_equal(c.order, 3);
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_int_equal(queue.stats.sent, 3);
    assert_int_equal(queue.stats.replies, 3);
    assert_int_equal(queue.stats.robot_errors, 0);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), UINT64_MAX);
}

/* Whatever cmdName a reply carries, it answers the command in flight. */
static void replies_matched_by_order_not_name(void **state)
{
    (void)state;
    struct job stop = {.json = "{\"cmdName\":\"stop_program\"}"};
    struct job estop = {.json = "{\"cmdName\":\"emergency_stop_status\"}"};
    struct job other = {.json = "{\"cmdName\":\"get_version\"}"};
    struct job after = {.json = "{\"cmdName\":\"power_off\"}"};

    test_submit(&stop);
    test_submit(&estop);
    test_submit(&other);
    test_submit(&after);
    /* The manual answers stop_program as pause_program. */
    reply("{\"cmdName\":\"pause_program\",\"errorCode\":\"0\",\"errorMsg\":\"\"}");
    assert_int_equal(stop.calls, 1);
    assert_int_equal(stop.result.outcome, CMD_DONE);
    assert_string_equal(stop.reply,
                        "{\"cmdName\":\"pause_program\",\"errorCode\":\"0\",\"errorMsg\":\"\"}");
    /* Real controllers answer some commands without a cmdName. */
    reply("{\"errorCode\": \"1\", \"errorMsg\": \"Exception:function call failed\"}");
    assert_int_equal(estop.calls, 1);
    assert_int_equal(estop.result.outcome, CMD_ROBOT_ERROR);
    assert_int_equal(estop.result.error_code, 1);
    assert_string_equal(estop.result.error_msg, "Exception:function call failed");
    /* Even another command's name answers the one in flight. */
    reply("{\"cmdName\":\"power_off\",\"errorCode\":\"0\",\"version\":\"1.7\"}");
    assert_int_equal(other.calls, 1);
    assert_int_equal(other.result.outcome, CMD_DONE);
    assert_int_equal(after.calls, 0);
    assert_string_equal(last_sent(), after.json);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(after.calls, 1);
    assert_int_equal(queue.stats.unsolicited, 0);
}

struct reply_case {
    const char *reply;
    enum cmd_outcome outcome;
    long error_code;
    const char *error_msg; /* NULL: not checked */
};

static void error_codes(void **state)
{
    (void)state;
    static const struct reply_case cases[] = {
        {"{\"errorCode\":\"0\",\"errorMsg\":\"\"}", CMD_DONE, 0, ""},
        {"{\"errorCode\":\"1\",\"errorMsg\":\"Exception:function call failed\"}",
         CMD_ROBOT_ERROR, 1, "Exception:function call failed"},
        {"{\"errorCode\":\"2\",\"errorMsg\":\"call joint_move failed\"}", CMD_ROBOT_ERROR,
         2, "call joint_move failed"},
        {"{\"errorCode\":\"-1\",\"errorMsg\":\"servoj command can only be excuted\"}",
         CMD_ROBOT_ERROR, -1, "servoj command can only be excuted"},
        {"{\"errorCode\":\"3\"}", CMD_ROBOT_ERROR, 3, ""},
        /* Some controllers send a number. */
        {"{\"errorCode\":0}", CMD_DONE, 0, ""},
        {"{\"errorCode\":7,\"errorMsg\":\"seven\"}", CMD_ROBOT_ERROR, 7, "seven"},
        {"{\"errorCode\":-1}", CMD_ROBOT_ERROR, -1, ""},
        /* No errorCode, or one that is no number: never taken as success. */
        {"{\"cmdName\":\"power_on\"}", CMD_ROBOT_ERROR, -1, "reply has no errorCode"},
        {"{\"errorCode\":\"\"}", CMD_ROBOT_ERROR, -1, "reply has no errorCode"},
        {"{\"errorCode\":null}", CMD_ROBOT_ERROR, -1, "reply has no errorCode"},
        {"{\"errorCode\":true}", CMD_ROBOT_ERROR, -1, "reply has no errorCode"},
        {"{\"errorCode\":\"ok\"}", CMD_ROBOT_ERROR, -1, "errorCode 'ok' is not a number"},
        {"{\"errorCode\":\"0x\"}", CMD_ROBOT_ERROR, -1, NULL},
        {"{\"errorCode\":\"0 \"}", CMD_ROBOT_ERROR, -1, NULL},
        /* Garbage and other JSON values. */
        {"[0]", CMD_ROBOT_ERROR, -1, "reply is not a JSON object"},
        {"{\"errorCode\":\"0\"", CMD_ROBOT_ERROR, -1, "reply is not a JSON object"},
        {"\"0\"", CMD_ROBOT_ERROR, -1, "reply is not a JSON object"},
        {"}{", CMD_ROBOT_ERROR, -1, "reply is not a JSON object"},
    };
    const unsigned n = sizeof(cases) / sizeof(cases[0]);
    static struct job jobs[sizeof(cases) / sizeof(cases[0])];

    for (unsigned i = 0; i < n; i++) {
        jobs[i] = (struct job){.json = "{\"cmdName\":\"clear_error\"}"};
        assert_int_equal(test_submit(&jobs[i]), 0);
    }
    for (unsigned i = 0; i < n; i++) {
        reply(cases[i].reply);
        assert_int_equal(jobs[i].calls, 1);
        if (jobs[i].result.outcome != cases[i].outcome ||
            jobs[i].result.error_code != cases[i].error_code)
            fail_msg("reply %s: outcome %d code %ld, expected %d %ld", cases[i].reply,
                     jobs[i].result.outcome, jobs[i].result.error_code, cases[i].outcome,
                     cases[i].error_code);
        if (cases[i].error_msg)
            assert_string_equal(jobs[i].result.error_msg, cases[i].error_msg);
        else
            assert_true(jobs[i].result.error_msg[0] != '\0');
        assert_string_equal(jobs[i].reply, cases[i].reply);
    }
    assert_int_equal(queue.stats.replies, n);
    assert_int_equal(queue.stats.robot_errors, n - 2);
}

/* The replies real controllers sent, from tests/data. */
/*
 * The reply as cJSON reads it, the way cmd_parse_reply() read every reply
 * before flat replies were read without a tree: the reference the fast
 * path must agree with.
 */
static void parse_reply_with_cjson(const char *json, size_t size, struct cmd_result *r)
{
    cJSON *doc = cJSON_ParseWithLength(json, size);
    const cJSON *code = cJSON_GetObjectItemCaseSensitive(doc, "errorCode");
    const cJSON *msg = cJSON_GetObjectItemCaseSensitive(doc, "errorMsg");

    memset(r, 0, sizeof(*r));
    if (!cJSON_IsObject(doc)) {
        r->outcome = CMD_ROBOT_ERROR;
        r->error_code = -1;
        snprintf(r->error_msg, sizeof(r->error_msg), "reply is not a JSON object");
    } else if (cJSON_IsNumber(code) || (cJSON_IsString(code) && code->valuestring[0])) {
        char *end = NULL;
        bool huge = cJSON_IsNumber(code) &&
                    !(code->valuedouble > -2147483648.0 && code->valuedouble < 2147483648.0);
        r->error_code = cJSON_IsNumber(code) ? (huge ? -1 : (long)code->valuedouble)
                                             : strtol(code->valuestring, &end, 10);
        if (huge) {
            r->outcome = CMD_ROBOT_ERROR;
            snprintf(r->error_msg, sizeof(r->error_msg), "errorCode %g is out of range",
                     code->valuedouble);
        } else if (cJSON_IsString(code) && *end != '\0') {
            r->outcome = CMD_ROBOT_ERROR;
            r->error_code = -1;
            snprintf(r->error_msg, sizeof(r->error_msg), "errorCode '%.60s' is not a number",
                     code->valuestring);
        } else {
            r->outcome = r->error_code == 0 ? CMD_DONE : CMD_ROBOT_ERROR;
        }
    } else {
        r->outcome = CMD_ROBOT_ERROR;
        r->error_code = -1;
        snprintf(r->error_msg, sizeof(r->error_msg), "reply has no errorCode");
    }
    if (cJSON_IsString(msg) && r->error_msg[0] == '\0')
        snprintf(r->error_msg, sizeof(r->error_msg), "%s", msg->valuestring);
    cJSON_Delete(doc);
}

/* Pieces replies are made of: members, values, spacing, the odd byte. */
static const char *const reply_keys[] = {"errorCode", "errorMsg", "cmdName", "errorcode",
                                         "error\\u0043ode", "x"};
static const char *const reply_values[] = {
    "\"0\"", "\"1\"", "\"-1\"", "\"2\"", "\"\"", "\"ok\"", "\"0x\"", "\" 3\"", "\"0 \"",
    "0", "7", "-1", "0.5", "1e3", "-0", "01", "1.", "3000000000", "-2147483649", "1E+2",
    "\"call joint_move failed\"", "\"a\\\"b\"", "\"\\u00e9t\\u00e9\"", "\"\xc3\xa9t\xc3\xa9\"",
    "\"tab\there\"", "null", "true", "false", "[0]", "{\"errorCode\":\"0\"}",
    "\"Exception:function call failed, a message long enough to be cut where the "
    "result's text ends: 128 bytes are all a result keeps, and the rest goes\"",
};
static const char *const reply_spaces[] = {"", "", "", " ", "\n", "\t \r\n", "\v", "\f"};

static const char *pick(const char *const *list, size_t n)
{
    return list[(size_t)rand() % n];
}
#define PICK(list) pick(list, sizeof(list) / sizeof(list[0]))

/* A generated reply: mostly flat objects, some broken on purpose. */
static size_t generate_reply(char *out, size_t cap)
{
    size_t n = 0;
    unsigned members = (unsigned)rand() % 5;

    n += (size_t)snprintf(out + n, cap - n, "%s{%s", PICK(reply_spaces), PICK(reply_spaces));
    for (unsigned i = 0; i < members && n < cap; i++)
        n += (size_t)snprintf(out + n, cap - n, "%s\"%s\"%s:%s%s%s", i ? "," : "",
                              PICK(reply_keys), PICK(reply_spaces), PICK(reply_spaces),
                              PICK(reply_values), PICK(reply_spaces));
    if (n < cap)
        n += (size_t)snprintf(out + n, cap - n, "}%s", PICK(reply_spaces));
    if (n >= cap)
        n = cap - 1;
    switch (rand() % 8) {
    case 0: /* cut short */
        n = n ? (size_t)rand() % n : 0;
        break;
    case 1: /* one byte changed */
        if (n)
            out[(size_t)rand() % n] = "{}[],:\"\\ 0a\x01\x80"[rand() % 14];
        break;
    case 2: /* something after the object */
        n += (size_t)snprintf(out + n, cap - n, "%s", rand() % 2 ? "x" : "{}");
        break;
    default:
        break;
    }
    out[n] = '\0';
    return n;
}

static void replies_read_as_cjson_reads_them(void **state)
{
    (void)state;
    unsigned rounds = 20000;
    const char *arch = getenv("JAKAGW_ARCH");
    if (arch && arch[0])
        rounds /= 10;
    srand(44);
    for (unsigned i = 0; i < rounds; i++) {
        char text[1024];
        size_t n = generate_reply(text, sizeof(text));
        struct cmd_result got, want;
        cmd_parse_reply(text, n, &got);
        parse_reply_with_cjson(text, n, &want);
        if (got.outcome != want.outcome || got.error_code != want.error_code ||
            strcmp(got.error_msg, want.error_msg) != 0)
            fail_msg("reply '%s': %d %ld '%s', cJSON reads %d %ld '%s'", text, got.outcome,
                     got.error_code, got.error_msg, want.outcome, want.error_code,
                     want.error_msg);
        assert_ptr_equal(got.reply, text);
        assert_int_equal(got.reply_size, n);
    }
}

static void recorded_replies(void **state)
{
    (void)state;
    static const struct {
        const char *file;
        long code;
        const char *msg;
    } cases[] = {
        {"reply-emergency_stop_status_nocmdname_errorCode1.json", 1,
         "Exception:function call failed"},
        {"reply-end_move_errorCode2.json", 2, "call end_move failed"},
        {"reply-joint_move_errorCode2.json", 2, "call joint_move failed"},
        {"reply-moveL_errorCode2.json", 2, "call moveL failed"},
        {"reply-servo_j_errorCode-1.json", -1,
         "servoj command can only be excuted in servo move mode"},
    };
    for (unsigned i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        char path[512], text[1024];
        snprintf(path, sizeof(path), "%s/%s", SAMPLES_DIR, cases[i].file);
        FILE *f = fopen(path, "rb");
        assert_non_null(f);
        size_t n = fread(text, 1, sizeof(text), f);
        fclose(f);
        struct job j = {.json = "{\"cmdName\":\"joint_move\"}"};
        assert_int_equal(test_submit(&j), 0);
        cmd_queue_on_reply(&queue, text, n);
        assert_int_equal(j.calls, 1);
        assert_int_equal(j.result.outcome, CMD_ROBOT_ERROR);
        assert_int_equal(j.result.error_code, cases[i].code);
        assert_string_equal(j.result.error_msg, cases[i].msg);
    }
}

static void timeout_at_the_limit_restarts_and_fails_the_rest(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"play_program\"}"};
    struct job b = {.json = "{\"cmdName\":\"pause_program\"}"};
    struct job c = {.json = "{\"cmdName\":\"stop_program\"}"};

    link.now = 2000;
    test_submit(&a);
    link.now = 2100;
    test_submit(&b);
    test_submit(&c);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 400);
    /* One millisecond before the limit: nothing happens. */
    link.now = 2499;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(done_calls, 0);
    assert_int_equal(link.restarts, 0);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 1);
    /* At the limit: the command fails, and so does everything behind it. */
    link.now = 2500;
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 0);
    cmd_queue_check_timeout(&queue);
    assert_int_equal(a.calls, 1);
    assert_int_equal(a.result.outcome, CMD_TIMEOUT);
    assert_null(strstr(a.result.error_msg, "errorCode"));
    assert_non_null(strstr(a.result.error_msg, "500 ms"));
    /* Written and unanswered: the robot may have acted on it. */
    assert_true(strncmp(a.result.error_msg, "outcome unknown", 15) == 0);
    /* Queued behind it, never written: the robot never got them. */
    assert_int_equal(b.calls, 1);
    assert_int_equal(b.result.outcome, CMD_NOT_SENT);
    assert_true(strncmp(b.result.error_msg, "not sent", 8) == 0);
    assert_int_equal(c.calls, 1);
    assert_int_equal(c.result.outcome, CMD_NOT_SENT);
    assert_true(a.order < b.order && b.order < c.order);
    assert_int_equal(link.restarts, 1);
    assert_non_null(strstr(link.restart_why, "no reply within 500 ms"));
    /* Nothing resent, nothing sent in its place. */
    assert_int_equal(link.sent_count, 1);
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), UINT64_MAX);
    assert_int_equal(queue.stats.timeouts, 1);
    assert_int_equal(queue.stats.failed_link_down, 0);
    assert_int_equal(queue.stats.not_sent, 2);

    /* The late reply answers nothing. */
    reply("{\"cmdName\":\"play_program\",\"errorCode\":\"0\"}");
    assert_int_equal(queue.stats.unsolicited, 1);
    assert_int_equal(queue.stats.replies, 0);
    assert_int_equal(done_calls, 3);
    /* Later checks find nothing to time out. */
    link.now = 100000;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
}

/*
 * With the link restart as robot_link does it (the link goes down at
 * once): a late reply is unsolicited, and after the reconnect a new
 * command is answered by its own reply.
 */
static void late_reply_after_restart_never_matches(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"power_off\"}"};
    struct job d = {.json = "{\"cmdName\":\"enable_robot\"}"};

    link.restart_disconnects = true;
    test_submit(&a);
    test_submit(&b);
    link.now += 500;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(a.result.outcome, CMD_TIMEOUT);
    assert_int_equal(b.result.outcome, CMD_NOT_SENT);
    assert_false(queue.connected);
    assert_int_equal(test_submit(&d), -ENOTCONN);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(queue.stats.unsolicited, 1);
    cmd_queue_set_connected(&queue, true);
    assert_int_equal(link.sent_count, 1);
    assert_int_equal(test_submit(&d), 0);
    assert_string_equal(last_sent(), d.json);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(d.calls, 1);
    assert_int_equal(d.result.outcome, CMD_DONE);
    assert_int_equal(a.calls + b.calls, 2);
}

static void link_down_fails_in_flight_and_queued(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"enable_robot\"}"};
    struct job c = {.json = "{\"cmdName\":\"play_program\"}"};
    struct job d = {.json = "{\"cmdName\":\"clear_error\"}"};

    test_submit(&a);
    test_submit(&b);
    test_submit(&c);
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(a.calls, 1);
    assert_int_equal(b.calls, 1);
    assert_int_equal(c.calls, 1);
    /* a was written: unknown; b and c never left the gateway. */
    assert_int_equal(a.result.outcome, CMD_LINK_DOWN);
    assert_true(strncmp(a.result.error_msg, "outcome unknown", 15) == 0);
    assert_int_equal(b.result.outcome, CMD_NOT_SENT);
    assert_true(strncmp(b.result.error_msg, "not sent", 8) == 0);
    assert_int_equal(c.result.outcome, CMD_NOT_SENT);
    assert_true(a.order < b.order && b.order < c.order);
    assert_int_equal(queue.stats.failed_link_down, 1);
    assert_int_equal(queue.stats.not_sent, 2);
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), UINT64_MAX);

    /* While down, nothing is accepted; the done callback never runs. */
    assert_int_equal(test_submit(&d), -ENOTCONN);
    assert_int_equal(d.calls, 0);
    /* Down twice is down once. */
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(done_calls, 3);

    /* After the reconnect, nothing that was accepted before it is sent. */
    cmd_queue_set_connected(&queue, true);
    assert_int_equal(link.sent_count, 1);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(queue.stats.unsolicited, 1);
    assert_int_equal(done_calls, 3);
    assert_int_equal(test_submit(&d), 0);
    assert_int_equal(link.sent_count, 2);
    assert_string_equal(last_sent(), d.json);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(d.calls, 1);
}

static void not_connected_before_the_first_connect(void **state)
{
    (void)state;
    struct cmd_queue q;
    struct cmd_ops ops = {.send = fake_send, .now_ms = fake_now,
                          .restart_link = fake_restart, .io = &link};
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};

    cmd_queue_init(&q, &ops, 100);
    assert_int_equal(cmd_queue_submit(&q, a.json, strlen(a.json), on_done, &a), -ENOTCONN);
    assert_int_equal(cmd_queue_pending(&q), 0);
    assert_int_equal(link.sent_count, 0);
    cmd_queue_free(&q);
    assert_int_equal(a.calls, 0);
}

static void busy_at_capacity(void **state)
{
    (void)state;
    static struct job jobs[CMD_QUEUE_CAPACITY + 1];

    for (unsigned i = 0; i < CMD_QUEUE_CAPACITY; i++) {
        jobs[i] = (struct job){.json = "{\"cmdName\":\"rapid_rate\",\"rate_value\":0.5}"};
        assert_int_equal(test_submit(&jobs[i]), 0);
    }
    jobs[CMD_QUEUE_CAPACITY] = (struct job){.json = "{\"cmdName\":\"power_off\"}"};
    assert_int_equal(test_submit(&jobs[CMD_QUEUE_CAPACITY]), -EBUSY);
    assert_int_equal(cmd_queue_pending(&queue), CMD_QUEUE_CAPACITY);
    /* One reply frees one place. */
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(test_submit(&jobs[CMD_QUEUE_CAPACITY]), 0);
    assert_int_equal(test_submit(&jobs[CMD_QUEUE_CAPACITY]), -EBUSY);
    for (unsigned i = 1; i <= CMD_QUEUE_CAPACITY; i++)
        reply("{\"errorCode\":\"0\"}");
    for (unsigned i = 0; i <= CMD_QUEUE_CAPACITY; i++) {
        assert_int_equal(jobs[i].calls, 1);
        assert_int_equal(jobs[i].order, i + 1);
    }
    assert_int_equal(link.sent_count, CMD_QUEUE_CAPACITY + 1);
    assert_string_equal(last_sent(), "{\"cmdName\":\"power_off\"}");
}

/* The ring wraps many times over; order and matching hold throughout. */
static void ring_wraps(void **state)
{
    (void)state;
    static struct job jobs[MAX_JOBS];
    static char names[MAX_JOBS][48];
    unsigned submitted = 0, answered = 0;

    while (answered < MAX_JOBS) {
        while (submitted < MAX_JOBS && cmd_queue_pending(&queue) < 5) {
            snprintf(names[submitted], sizeof(names[0]), "{\"cmdName\":\"n%u\"}", submitted);
            jobs[submitted] = (struct job){.json = names[submitted]};
            assert_int_equal(test_submit(&jobs[submitted]), 0);
            submitted++;
        }
        assert_string_equal(last_sent(), names[answered]);
        char r[64];
        snprintf(r, sizeof(r), "{\"errorCode\":\"%u\"}", answered);
        reply(r);
        assert_int_equal(jobs[answered].calls, 1);
        assert_int_equal(jobs[answered].result.error_code, (long)answered);
        answered++;
    }
    assert_int_equal(link.sent_count, MAX_JOBS);
}

/* A send that fails when nothing is in flight is the caller's to report. */
static void send_failure_on_submit(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"power_off\"}"};

    link.fail_sends = 1;
    assert_int_equal(test_submit(&a), -EPIPE);
    assert_int_equal(a.calls, 0);
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_int_equal(queue.stats.sent, 0);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), UINT64_MAX);
    /* The queue is usable afterwards. */
    assert_int_equal(test_submit(&b), 0);
    assert_string_equal(last_sent(), b.json);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(b.calls, 1);
    assert_int_equal(b.result.outcome, CMD_DONE);
}

/* A queued command whose send fails is failed, and the next one goes. */
static void send_failure_of_a_queued_command(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"enable_robot\"}"};
    struct job c = {.json = "{\"cmdName\":\"play_program\"}"};

    test_submit(&a);
    test_submit(&b);
    test_submit(&c);
    link.fail_sends = 1;
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(a.result.outcome, CMD_DONE);
    assert_int_equal(b.calls, 1);
    assert_int_equal(b.result.outcome, CMD_NOT_SENT);
    assert_non_null(strstr(b.result.error_msg, "not sent: Broken pipe"));
    assert_int_equal(c.calls, 0);
    assert_int_equal(link.sent_count, 2);
    assert_string_equal(last_sent(), c.json);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(c.calls, 1);
    assert_int_equal(c.result.outcome, CMD_DONE);
    /* Every send failing: everything queued fails, each once. */
    struct job d = {.json = "{\"cmdName\":\"a\"}"}, e = {.json = "{\"cmdName\":\"b\"}"},
               f = {.json = "{\"cmdName\":\"c\"}"};
    test_submit(&d);
    test_submit(&e);
    test_submit(&f);
    link.fail_sends = 2;
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(e.result.outcome, CMD_NOT_SENT);
    assert_int_equal(f.result.outcome, CMD_NOT_SENT);
    assert_int_equal(d.calls + e.calls + f.calls, 3);
    assert_int_equal(cmd_queue_pending(&queue), 0);
}

/*
 * A done callback may submit (plc_commands fetches information again after
 * load_program and the program commands). What it submits queues behind
 * the commands accepted before it: the next command sent is the next in
 * line, and every reply answers the command it was sent for.
 */
static void submit_from_done_queues_behind(void **state)
{
    (void)state;
    struct job refresh = {.json = "{\"cmdName\":\"get_loaded_program\"}"};
    struct job load = {.json = "{\"cmdName\":\"load_program\",\"programName\":\"a.jks\"}",
                       .submit_from_done = &refresh};
    struct job play = {.json = "{\"cmdName\":\"play_program\"}"};

    test_submit(&load);
    test_submit(&play);
    reply("{\"cmdName\":\"load_program\",\"errorCode\":\"0\"}");
    assert_int_equal(load.submit_from_done_rc, 0);
    assert_int_equal(link.sent_count, 2);
    assert_string_equal(link.sent[1], play.json);
    reply("{\"cmdName\":\"play_program\",\"errorCode\":\"0\"}");
    assert_int_equal(play.calls, 1);
    assert_string_equal(play.reply, "{\"cmdName\":\"play_program\",\"errorCode\":\"0\"}");
    assert_int_equal(link.sent_count, 3);
    assert_string_equal(link.sent[2], refresh.json);
    reply("{\"cmdName\":\"get_loaded_program\",\"errorCode\":\"0\"}");
    assert_int_equal(refresh.calls, 1);
    assert_int_equal(link.sent_count, 3);
    assert_int_equal(cmd_queue_pending(&queue), 0);
}

/* With nothing queued, what a done callback submits goes out at once. */
static void submit_from_done_on_an_empty_queue(void **state)
{
    (void)state;
    struct job refresh = {.json = "{\"cmdName\":\"get_program_state\"}"};
    struct job play = {.json = "{\"cmdName\":\"play_program\"}", .submit_from_done = &refresh};

    test_submit(&play);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(play.calls, 1);
    assert_int_equal(play.submit_from_done_rc, 0);
    assert_int_equal(link.sent_count, 2);
    assert_string_equal(last_sent(), refresh.json);
    reply("{\"errorCode\":\"0\",\"programState\":\"running\"}");
    assert_int_equal(refresh.calls, 1);
    assert_int_equal(queue.stats.unsolicited, 0);
}

/* A done callback that runs on link down cannot queue anything. */
static void submit_from_done_while_down(void **state)
{
    (void)state;
    struct job again = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job a = {.json = "{\"cmdName\":\"power_on\"}", .submit_from_done = &again};

    test_submit(&a);
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(a.calls, 1);
    assert_int_equal(a.submit_from_done_rc, -ENOTCONN);
    assert_int_equal(again.calls, 0);
    assert_int_equal(cmd_queue_pending(&queue), 0);
}

static void unsolicited_when_idle(void **state)
{
    (void)state;
    reply("{\"errorCode\":\"0\"}");
    reply("garbage");
    assert_int_equal(queue.stats.unsolicited, 2);
    assert_int_equal(queue.stats.replies, 0);
    assert_int_equal(done_calls, 0);
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 0);
}

static void free_fails_everything_once(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"power_off\"}"};

    test_submit(&a);
    test_submit(&b);
    cmd_queue_free(&queue);
    assert_int_equal(a.calls, 1);
    assert_int_equal(b.calls, 1);
    assert_int_equal(a.result.outcome, CMD_LINK_DOWN);
    assert_int_equal(b.result.outcome, CMD_NOT_SENT);
    assert_non_null(strstr(a.result.error_msg, "stopped"));
    assert_non_null(strstr(b.result.error_msg, "stopping"));
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_int_equal(link.sent_count, 1);
    /* Freeing again (the teardown does) changes nothing. */
    cmd_queue_free(&queue);
    assert_int_equal(done_calls, 2);
}


/*
 * A safety action is written at once, even while a command waits for its
 * reply, ahead of the queued ones; replies still match in order.
 */
static void urgent_action_goes_out_at_once(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"joint_move\"}"};
    struct job b = {.json = "{\"cmdName\":\"power_off\"}"};
    struct job u = {.json = "{\"cmdName\":\"pause_program\"}"};
    struct job v = {.json = "{\"cmdName\":\"stop_program\"}"};

    assert_int_equal(test_submit(&a), 0);
    assert_int_equal(test_submit(&b), 0);
    assert_int_equal(link.sent_count, 1); /* b waits for a's reply */
    link.now += 100;
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u), 0);
    assert_string_equal(last_sent(), u.json); /* not waiting for a */
    assert_int_equal(cmd_queue_submit_urgent(&queue, v.json, strlen(v.json), on_done, &v), 0);
    assert_string_equal(last_sent(), v.json);
    assert_int_equal(link.sent_count, 3);
    reply("{\"errorCode\": \"0\", \"cmdName\": \"joint_move\"}");
    assert_int_equal(a.calls, 1);
    assert_int_equal(link.sent_count, 3); /* u is in flight now, already written */
    reply("{\"errorCode\": \"0\", \"cmdName\": \"pause_program\"}");
    assert_int_equal(u.calls, 1);
    assert_string_equal(u.reply, "{\"errorCode\": \"0\", \"cmdName\": \"pause_program\"}");
    reply("{\"errorCode\": \"0\", \"cmdName\": \"pause_program\"}"); /* stop's, as the manual answers */
    assert_int_equal(v.calls, 1);
    assert_int_equal(link.sent_count, 4);
    assert_string_equal(last_sent(), b.json); /* b only now */
    reply("{\"errorCode\": \"0\"}");
    assert_int_equal(b.calls, 1);
    assert_true(a.order < u.order && u.order < v.order && v.order < b.order);
    /* With nothing in flight it is an ordinary send. */
    struct job w = {.json = "{\"cmdName\":\"pause_program\"}"};
    assert_int_equal(cmd_queue_submit_urgent(&queue, w.json, strlen(w.json), on_done, &w), 0);
    assert_int_equal(link.sent_count, 5);
    /* The in-flight one's deadline runs from its own send. */
    link.now += 499;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 0);
    link.now += 1;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
}

/*
 * A safety action owns the queue: every unwritten command that can start
 * or continue motion (a move, a program start or resume, a name the table
 * does not know) is taken out and fails "not sent: a safety action took
 * its place"; the rest waits behind the action. When the action cannot be
 * written, the queue stays exactly as it was.
 */
static void urgent_action_takes_out_what_moves(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"get_version\"}"};
    struct job b = {.json = "{\"cmdName\":\"joint_move\"}"};
    struct job c = {.json = "{\"cmdName\":\"set_digital_output\"}"};
    struct job d = {.json = "{\"cmdName\":\"resume_program\"}"};
    struct job e = {.json = "{\"cmdName\":\"Joint_Move\"}"};
    struct job f = {.json = "{\"cmdName\":\"power_off\"}"};
    struct job u = {.json = "{\"cmdName\":\"stop_program\"}"};
    struct job *queued[] = {&a, &b, &c, &d, &e, &f};

    for (unsigned i = 0; i < 6; i++)
        assert_int_equal(test_submit(queued[i]), 0);
    assert_int_equal(link.sent_count, 1);
    /* Refused by the link: nothing changes, nobody is told. */
    link.fail_sends = 1;
    link.send_error = -EPIPE;
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u),
                     -EPIPE);
    assert_int_equal(cmd_queue_pending(&queue), 6);
    assert_int_equal(b.calls + d.calls + e.calls, 0);
    /* Written: the three that move are out, in order, before any reply. */
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u), 0);
    assert_string_equal(last_sent(), u.json);
    for (unsigned i = 0; i < 3; i++) {
        struct job *j = (struct job *[]){&b, &d, &e}[i];
        assert_int_equal(j->calls, 1);
        assert_int_equal(j->result.outcome, CMD_NOT_SENT);
        assert_string_equal(j->result.error_msg, "not sent: a safety action took its place");
    }
    assert_true(b.order < d.order && d.order < e.order);
    assert_int_equal(cmd_queue_pending(&queue), 4);
    reply("{\"errorCode\": \"0\"}");
    reply("{\"errorCode\": \"0\", \"cmdName\": \"pause_program\"}");
    assert_int_equal(u.result.outcome, CMD_DONE);
    assert_string_equal(last_sent(), c.json);
    reply("{\"errorCode\": \"0\"}");
    assert_string_equal(last_sent(), f.json);
    reply("{\"errorCode\": \"0\"}");
    assert_int_equal(link.sent_count, 4);
    assert_int_equal(queue.stats.not_sent, 3);
}

/* ---- the link check (cmd_queue_submit_check) ---- */

#define CHECK_JSON "{\"cmdName\":\"get_robot_state\"}"

static int submit_check(struct job *j, uint32_t bound_ms)
{
    return cmd_queue_submit_check(&queue, j->json, strlen(j->json), bound_ms, on_done, j);
}

/*
 * A PLC command submitted while a check is in flight goes out at once,
 * behind it; the first reply is the check's and the second the command's,
 * whatever they say: the check's reply never answers the PLC's command.
 */
static void check_reply_never_answers_a_command(void **state)
{
    (void)state;
    struct job chk = {.json = CHECK_JSON};
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};

    assert_int_equal(submit_check(&chk, 300), 0);
    assert_int_equal(link.sent_count, 1);
    assert_string_equal(last_sent(), chk.json);
    assert_int_equal(queue.stats.checks, 1);
    /* Written at once, not after the check's reply. */
    assert_int_equal(test_submit(&a), 0);
    assert_int_equal(link.sent_count, 2);
    assert_string_equal(last_sent(), a.json);
    /* The check's reply, even one that names power_on, is the check's. */
    reply("{\"cmdName\":\"power_on\",\"errorCode\":\"0\",\"enable\":\"robot_disabled\"}");
    assert_int_equal(chk.calls, 1);
    assert_int_equal(chk.result.outcome, CMD_DONE);
    assert_non_null(strstr(chk.reply, "robot_disabled"));
    assert_int_equal(a.calls, 0);
    /* power_on is in flight now, and its own reply answers it. */
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 500);
    reply("{\"cmdName\":\"power_on\",\"errorCode\":\"2\",\"errorMsg\":\"estop\"}");
    assert_int_equal(a.calls, 1);
    assert_int_equal(a.result.outcome, CMD_ROBOT_ERROR);
    assert_string_equal(a.result.error_msg, "estop");
    assert_true(chk.order < a.order);
    assert_int_equal(queue.stats.unsolicited, 0);
    assert_int_equal(link.sent_count, 2);
}

/* No check while a command is queued or in flight (or the link is down);
 * once the queue is empty again, it is accepted. */
static void check_never_while_a_command_is_in_flight(void **state)
{
    (void)state;
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"enable_robot\"}"};
    struct job chk = {.json = CHECK_JSON};

    assert_int_equal(test_submit(&a), 0);
    assert_int_equal(test_submit(&b), 0);
    assert_int_equal(submit_check(&chk, 300), -EBUSY);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(submit_check(&chk, 300), -EBUSY); /* b in flight */
    assert_int_equal(link.sent_count, 2);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(cmd_queue_pending(&queue), 0);
    assert_int_equal(submit_check(&chk, 300), 0);
    assert_int_equal(link.sent_count, 3);
    /* One at a time: a second check waits for the first. */
    struct job chk2 = {.json = CHECK_JSON};
    assert_int_equal(submit_check(&chk2, 300), -EBUSY);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(chk.calls, 1);
    assert_int_equal(queue.stats.checks, 1);
    assert_int_equal(chk2.calls, 0);
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(submit_check(&chk2, 300), -ENOTCONN);
    assert_int_equal(link.sent_count, 3);
}

/*
 * Commands during a check: the first goes out at once and its deadline
 * runs from its own send; a second waits for the first's reply, as
 * always (one PLC command at a time).
 */
static void commands_during_a_check_are_not_delayed(void **state)
{
    (void)state;
    struct job chk = {.json = CHECK_JSON};
    struct job a = {.json = "{\"cmdName\":\"power_on\"}"};
    struct job b = {.json = "{\"cmdName\":\"enable_robot\"}"};

    link.now = 5000;
    assert_int_equal(submit_check(&chk, 300), 0);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 300);
    link.now = 5100;
    assert_int_equal(test_submit(&a), 0);
    assert_string_equal(last_sent(), a.json);
    assert_int_equal(test_submit(&b), 0);
    assert_int_equal(link.sent_count, 2); /* b waits for a, not for the check */
    link.now = 5150;
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(chk.calls, 1);
    assert_int_equal(link.sent_count, 2); /* a was written already */
    /* a's reply timeout counts from 5100, when it went out. */
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 450);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(a.calls, 1);
    assert_string_equal(last_sent(), b.json);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(b.calls, 1);
    assert_true(chk.order < a.order && a.order < b.order);
    /* A safety action during a check is written at once too. */
    struct job chk2 = {.json = CHECK_JSON};
    struct job u = {.json = "{\"cmdName\":\"pause_program\"}"};
    assert_int_equal(submit_check(&chk2, 300), 0);
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u), 0);
    assert_string_equal(last_sent(), u.json);
    reply("{\"errorCode\":\"0\"}");
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(chk2.calls, 1);
    assert_int_equal(u.calls, 1);
    assert_int_equal(u.result.outcome, CMD_DONE);
}

/*
 * An unanswered check restarts the link at its own bound when nothing
 * waits behind it; with a command written behind it, at that command's
 * own reply timeout (counted from its send). The command then reads
 * outcome unknown, one still queued not sent.
 */
static void unanswered_check_restarts_the_link(void **state)
{
    (void)state;
    struct job chk = {.json = CHECK_JSON};
    struct job a = {.json = "{\"cmdName\":\"play_program\"}"};
    struct job b = {.json = "{\"cmdName\":\"power_off\"}"};

    link.restart_disconnects = true;
    link.now = 1000;
    assert_int_equal(submit_check(&chk, 200), 0);
    link.now = 1199;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 0);
    link.now = 1200; /* the check's bound, not the queue's 500 ms */
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
    assert_non_null(strstr(link.restart_why, "link check unanswered within 200 ms"));
    assert_int_equal(chk.result.outcome, CMD_TIMEOUT);
    assert_int_equal(queue.stats.checks_failed, 1);

    /* Again, with commands behind the check. */
    cmd_queue_set_connected(&queue, true);
    chk = (struct job){.json = CHECK_JSON};
    link.now = 2000;
    assert_int_equal(submit_check(&chk, 200), 0);
    link.now = 2050;
    test_submit(&a);
    test_submit(&b);
    link.now = 2200; /* a went out at 2050: it has its 500 ms */
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 350);
    link.now = 2549;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
    link.now = 2550;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 2);
    assert_non_null(strstr(link.restart_why, "link check unanswered within 550 ms"));
    assert_int_equal(chk.result.outcome, CMD_TIMEOUT);
    assert_int_equal(queue.stats.checks_failed, 2);
    assert_int_equal(a.result.outcome, CMD_LINK_DOWN);
    assert_true(strncmp(a.result.error_msg, "outcome unknown", 15) == 0);
    assert_int_equal(b.result.outcome, CMD_NOT_SENT);
    assert_true(strncmp(b.result.error_msg, "not sent", 8) == 0);
    assert_int_equal(link.sent_count, 3); /* two checks and a; b never */
    /* The check's late reply answers nothing after the reconnect. */
    cmd_queue_set_connected(&queue, true);
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(queue.stats.unsolicited, 1);
}

/*
 * A safety action written just before the bound of a check in flight:
 * the check's reply comes late (past its own bound) but within the
 * action's reply timeout. The link is not cut under the action: the
 * check and the action are both answered, in order, and nothing is lost.
 * (It used to be cut at the check's bound, 10 ms after the pause went
 * out: the pause read "outcome unknown" and, reset with the link, may
 * never have reached the robot.)
 */
static void action_behind_a_check_gets_its_own_timeout(void **state)
{
    (void)state;
    struct job chk = {.json = CHECK_JSON};
    struct job u = {.json = "{\"cmdName\":\"pause_program\"}"};

    link.restart_disconnects = true;
    link.now = 1000;
    assert_int_equal(submit_check(&chk, 200), 0);
    link.now = 1190;
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u), 0);
    assert_string_equal(last_sent(), u.json);
    link.now = 1200;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 0);
    link.now = 1350;
    reply("{\"errorCode\":\"0\"}");
    assert_int_equal(chk.calls, 1);
    assert_int_equal(chk.result.outcome, CMD_DONE);
    /* The pause's own deadline: 500 ms from 1190. */
    assert_int_equal(cmd_queue_next_deadline_ms(&queue), 340);
    link.now = 1400;
    reply("{\"errorCode\":\"0\",\"cmdName\":\"pause_program\"}");
    assert_int_equal(u.calls, 1);
    assert_int_equal(u.result.outcome, CMD_DONE);
    assert_int_equal(queue.stats.checks_failed, 0);
    assert_int_equal(link.restarts, 0);
    /* Unanswered, the pair is cut at the pause's deadline, the pause
     * outcome unknown. */
    chk = (struct job){.json = CHECK_JSON};
    u = (struct job){.json = "{\"cmdName\":\"pause_program\"}"};
    link.now = 2000;
    assert_int_equal(submit_check(&chk, 200), 0);
    link.now = 2100;
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u), 0);
    link.now = 2599;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 0);
    link.now = 2600;
    cmd_queue_check_timeout(&queue);
    assert_int_equal(link.restarts, 1);
    assert_int_equal(chk.result.outcome, CMD_TIMEOUT);
    assert_int_equal(u.result.outcome, CMD_LINK_DOWN);
    assert_true(strncmp(u.result.error_msg, "outcome unknown", 15) == 0);
}

/*
 * Not sent against outcome unknown on every path: a safety action
 * displacing the newest queued command at capacity (never written: not
 * sent), a command whose write fails (not sent), the link going down
 * with written safety actions and unwritten commands.
 */
static void not_sent_and_unknown_on_every_path(void **state)
{
    (void)state;
    static struct job jobs[CMD_QUEUE_CAPACITY];
    struct job u = {.json = "{\"cmdName\":\"stop_program\"}"};

    for (unsigned i = 0; i < CMD_QUEUE_CAPACITY; i++) {
        jobs[i] = (struct job){.json = "{\"cmdName\":\"rapid_rate\",\"rate_value\":0.5}"};
        assert_int_equal(test_submit(&jobs[i]), 0);
    }
    assert_int_equal(cmd_queue_submit_urgent(&queue, u.json, strlen(u.json), on_done, &u), 0);
    struct job *last = &jobs[CMD_QUEUE_CAPACITY - 1];
    assert_int_equal(last->calls, 1);
    assert_int_equal(last->result.outcome, CMD_NOT_SENT);
    assert_string_equal(last->result.error_msg, "not sent: displaced by a safety action");
    assert_int_equal(link.sent_count, 2); /* jobs[0] and the action */
    cmd_queue_set_connected(&queue, false);
    assert_int_equal(jobs[0].result.outcome, CMD_LINK_DOWN);
    assert_int_equal(u.result.outcome, CMD_LINK_DOWN);
    for (unsigned i = 1; i < CMD_QUEUE_CAPACITY - 1; i++)
        assert_int_equal(jobs[i].result.outcome, CMD_NOT_SENT);
    assert_int_equal(queue.stats.failed_link_down, 2);
    assert_int_equal(queue.stats.not_sent, CMD_QUEUE_CAPACITY - 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(table_lookups),
        cmocka_unit_test_setup_teardown(one_at_a_time_in_order, setup, teardown),
        cmocka_unit_test_setup_teardown(results_say_when_written, setup, teardown),
        cmocka_unit_test_setup_teardown(urgent_action_goes_out_at_once, setup, teardown),
        cmocka_unit_test_setup_teardown(urgent_action_takes_out_what_moves, setup, teardown),
        cmocka_unit_test_setup_teardown(replies_matched_by_order_not_name, setup, teardown),
        cmocka_unit_test_setup_teardown(error_codes, setup, teardown),
        cmocka_unit_test_setup_teardown(recorded_replies, setup, teardown),
        cmocka_unit_test(replies_read_as_cjson_reads_them),
        cmocka_unit_test_setup_teardown(timeout_at_the_limit_restarts_and_fails_the_rest,
                                        setup, teardown),
        cmocka_unit_test_setup_teardown(late_reply_after_restart_never_matches, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(link_down_fails_in_flight_and_queued, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(not_connected_before_the_first_connect, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(busy_at_capacity, setup, teardown),
        cmocka_unit_test_setup_teardown(ring_wraps, setup, teardown),
        cmocka_unit_test_setup_teardown(send_failure_on_submit, setup, teardown),
        cmocka_unit_test_setup_teardown(send_failure_of_a_queued_command, setup, teardown),
        cmocka_unit_test_setup_teardown(submit_from_done_queues_behind, setup, teardown),
        cmocka_unit_test_setup_teardown(submit_from_done_on_an_empty_queue, setup, teardown),
        cmocka_unit_test_setup_teardown(submit_from_done_while_down, setup, teardown),
        cmocka_unit_test_setup_teardown(unsolicited_when_idle, setup, teardown),
        cmocka_unit_test_setup_teardown(free_fails_everything_once, setup, teardown),
        cmocka_unit_test_setup_teardown(check_reply_never_answers_a_command, setup, teardown),
        cmocka_unit_test_setup_teardown(check_never_while_a_command_is_in_flight, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(commands_during_a_check_are_not_delayed, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(unanswered_check_restarts_the_link, setup, teardown),
        cmocka_unit_test_setup_teardown(action_behind_a_check_gets_its_own_timeout, setup,
                                        teardown),
        cmocka_unit_test_setup_teardown(not_sent_and_unknown_on_every_path, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
