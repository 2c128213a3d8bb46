/* SPDX-License-Identifier: MIT */
/*
 * fuzz_command.c - libFuzzer target: the command port's reply parser
 * (cmd_parse_reply) and the command queue (command.c), fed replies in any
 * order.
 *
 * Every input is first parsed whole as a reply. Rules: the outcome is done
 * (errorCode 0) or a robot error with a non-zero code; errorMsg is a
 * terminated string; nothing is read outside the input (it carries no NUL).
 *
 * Then the input is a program of steps for a queue on a fake link:
 * submitting up to 80 commands at once (past the 64-command capacity),
 * safety actions (cmd_queue_submit_urgent), commands whose done callback
 * submits another (plain or urgent) or drops the link; the robot answering
 * with canned or raw bytes; stray replies with nothing in flight; time
 * passing past the reply timeout; the link going down and up; a send
 * failing. Rules:
 * - a command is written at most once; an ordinary one only when nothing
 *   written is unanswered and everything accepted before it has finished;
 *   a safety action at once, inside its submit call;
 * - the robot answers in order: a reply finishes the oldest unanswered
 *   command, with the parser's outcome; a stray reply finishes nothing;
 * - a late reply fails the command in flight (timeout), and everything
 *   queued behind it, and restarts the link;
 * - submitting returns -ENOTCONN while down, -EBUSY when 64 are queued; a
 *   done callback never runs inside cmd_queue_submit, and inside
 *   cmd_queue_submit_urgent only for the queued command it displaces and
 *   the unwritten moves it takes out (not sent); after a safety action no
 *   move never written is left in the queue; a command written finishes answered or with its outcome
 *   unknown (timeout, link down), one never written as not sent; every accepted command's done callback runs exactly once,
 *   at the latest when the queue is freed, and the queue never holds more
 *   than its capacity.
 */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "command.h"
#include "fuzz_util.h"


#define MAX_JOBS 1024
#define MAX_STEPS 128
#define TIMEOUT_MS 2000

enum { CHILD_NONE, CHILD_SUBMIT, CHILD_URGENT, CHILD_DROP_LINK };

struct job {
    unsigned id;
    bool accepted;
    bool urgent;
    bool moves; /* a command that can start motion (joint_move) */
    unsigned done_calls;
    unsigned sends;
    enum cmd_outcome outcome;
    int child; /* what its done callback does */
};

static struct job jobs[MAX_JOBS];
static unsigned job_count;
static struct cmd_queue queue;
static bool connected;
/* Written and not yet answered, oldest first: the robot answers in order. */
static unsigned wire[MAX_JOBS];
static unsigned wire_count;
static uint64_t now_ms;
static int fail_next_send;
static int in_submit;     /* 1: cmd_queue_submit, 2: cmd_queue_submit_urgent */
static unsigned displaced; /* done callbacks inside the current urgent submit */
static unsigned taken_out; /* of them, motion the safety action took out */
static bool dropped_inside; /* a done callback dropped the link inside it */
static int submitting = -1; /* the job inside its submit call, not queued yet */
/* While the robot's reply is being handed over: the job it must finish. */
static int expect_reply_for = -1;
static enum cmd_outcome expect_outcome;
static bool reply_finished;

static int submit(int child, bool urgent);

static int fake_send(void *io, const char *data, size_t size)
{
    unsigned id;
    char text[96];
    (void)io;
    FUZZ_REQUIRE(connected, "sent while the link is down");
    if (fail_next_send) {
        int rc = fail_next_send;
        fail_next_send = 0;
        return rc;
    }
    FUZZ_REQUIRE(size < sizeof(text), "sent %zu bytes, never submitted", size);
    memcpy(text, data, size);
    text[size] = '\0';
    const char *job = strstr(text, ",\"job\":");
    FUZZ_REQUIRE(job && sscanf(job, ",\"job\":%u}", &id) == 1 && id < job_count,
            "sent bytes that were never submitted: %s", text);
    struct job *j = &jobs[id];
    FUZZ_REQUIRE(j->accepted && j->done_calls == 0, "job %u sent after it finished", id);
    FUZZ_REQUIRE(j->sends == 0, "job %u sent twice", id);
    if (!j->urgent) {
        FUZZ_REQUIRE(wire_count == 0, "job %u sent while job %u is unanswered", id, wire[0]);
        for (unsigned k = 0; k < id; k++)
            FUZZ_REQUIRE(!jobs[k].accepted || jobs[k].done_calls, "job %u sent while job %u waits",
                    id, k);
    } else {
        FUZZ_REQUIRE(in_submit == 2, "safety action %u written after its submit", id);
    }
    j->sends++;
    wire[wire_count++] = id;
    return 0;
}

static uint64_t fake_now(void *io)
{
    (void)io;
    return now_ms;
}

static void link_down(void)
{
    if (!connected)
        return;
    connected = false;
    if (in_submit)
        dropped_inside = true;
    cmd_queue_set_connected(&queue, false);
    FUZZ_REQUIRE(wire_count == 0, "job %u still unanswered after the link went down", wire[0]);
    for (unsigned k = 0; k < job_count; k++)
        FUZZ_REQUIRE(!jobs[k].accepted || jobs[k].done_calls || (int)k == submitting ||
                         /* taken out by the safety action being submitted:
                          * told right after this callback */
                         (in_submit == 2 && jobs[k].moves && !jobs[k].sends),
                "job %u still waits after the link went down", k);
}

static void fake_restart(void *io, const char *why)
{
    (void)io;
    (void)why;
    link_down(); /* robot_link_restart() drops the connection at once */
}

static void on_done(void *user, const struct cmd_result *r)
{
    struct job *j = user;

    FUZZ_REQUIRE(in_submit != 1, "done callback of job %u from inside cmd_queue_submit", j->id);
    FUZZ_REQUIRE(j->accepted, "done callback of job %u, never accepted", j->id);
    FUZZ_REQUIRE(++j->done_calls == 1, "done callback of job %u ran twice", j->id);
    FUZZ_REQUIRE(r->outcome > CMD_PENDING && r->outcome <= CMD_NOT_SENT,
            "job %u finished with outcome %d", j->id, r->outcome);
    /* Written: answered, or its outcome unknown. Never written: not sent. */
    FUZZ_REQUIRE(j->sends ? r->outcome == CMD_DONE || r->outcome == CMD_ROBOT_ERROR ||
                                r->outcome == CMD_TIMEOUT || r->outcome == CMD_LINK_DOWN
                          : r->outcome == CMD_NOT_SENT,
            "job %u, written %u times, finished with outcome %d", j->id, j->sends, r->outcome);
    FUZZ_REQUIRE(memchr(r->error_msg, '\0', sizeof(r->error_msg)), "errorMsg not terminated");
    bool took_place = strcmp(r->error_msg, "not sent: a safety action took its place") == 0;
    if (in_submit == 2 && r->outcome == CMD_NOT_SENT && j->sends == 0 && !dropped_inside &&
        took_place) {
        /* Motion never follows a safety action. */
        FUZZ_REQUIRE(j->moves, "job %u, no motion, taken out by a safety action", j->id);
        taken_out++;
    } else if (in_submit == 2 && r->outcome == CMD_NOT_SENT && j->sends == 0 && !dropped_inside)
        displaced++; /* made room for the safety action */
    else if (in_submit == 2)
        FUZZ_REQUIRE(dropped_inside && (r->outcome == CMD_LINK_DOWN || r->outcome == CMD_NOT_SENT),
                "job %u finished (%d) inside a safety action's submit", j->id, r->outcome);
    j->outcome = r->outcome;
    if (j->sends) {
        /* Written: its outcome comes in the order the robot answers. */
        FUZZ_REQUIRE(wire_count && wire[0] == j->id,
                "job %u finished before job %u, written earlier", j->id, wire[0]);
        memmove(wire, wire + 1, --wire_count * sizeof(*wire));
    }
    if (expect_reply_for >= 0 && !reply_finished) {
        FUZZ_REQUIRE((unsigned)expect_reply_for == j->id,
                "the reply to job %d finished job %u", expect_reply_for, j->id);
        FUZZ_REQUIRE(r->outcome == expect_outcome, "job %u: outcome %d, the reply says %d", j->id,
                r->outcome, expect_outcome);
        reply_finished = true;
    }
    if (j->child == CHILD_SUBMIT)
        submit(CHILD_NONE, false);
    else if (j->child == CHILD_URGENT)
        submit(CHILD_NONE, true);
    else if (j->child == CHILD_DROP_LINK)
        link_down();
}

static int submit(int child, bool urgent)
{
    char json[64];
    if (job_count == MAX_JOBS)
        return -ENOSPC;
    struct job *j = &jobs[job_count];
    /* Every other one a move: what a safety action must take out. */
    bool moves = !urgent && job_count % 2 == 1;
    *j = (struct job){.id = job_count, .child = child, .urgent = urgent, .moves = moves};
    int n = snprintf(json, sizeof(json), "{\"cmdName\":\"%s\",\"job\":%u}",
                     urgent ? "stop_program" : moves ? "joint_move" : "set_digital_output",
                     job_count);
    unsigned before = cmd_queue_pending(&queue);
    bool was_connected = connected;
    int outer = in_submit;
    unsigned outer_displaced = displaced, outer_taken = taken_out;
    bool outer_dropped = dropped_inside;
    int outer_submitting = submitting;
    job_count++;
    j->accepted = true; /* provisionally: it is written inside */
    in_submit = urgent ? 2 : 1;
    displaced = taken_out = 0;
    dropped_inside = false;
    submitting = (int)j->id;
    int rc = urgent ? cmd_queue_submit_urgent(&queue, json, (size_t)n, on_done, j)
                    : cmd_queue_submit(&queue, json, (size_t)n, on_done, j);
    in_submit = outer;
    submitting = outer_submitting;
    j->accepted = rc == 0;
    FUZZ_REQUIRE(cmd_queue_pending(&queue) <= CMD_QUEUE_CAPACITY, "%u commands in a queue of %d",
            cmd_queue_pending(&queue), CMD_QUEUE_CAPACITY);
    if (!was_connected)
        FUZZ_REQUIRE(rc == -ENOTCONN, "submit while down returned %d", rc);
    else if (!urgent && before >= CMD_QUEUE_CAPACITY)
        FUZZ_REQUIRE(rc == -EBUSY, "submit to a full queue returned %d", rc);
    else if (urgent && rc == -EBUSY)
        /* Only when every queued command is written and unanswered (the
         * robot sits on 63 safety actions): none can give way. */
        FUZZ_REQUIRE(wire_count >= CMD_QUEUE_CAPACITY, "urgent submit returned -EBUSY with %u "
                "queued, %u of them written", before, wire_count);
    else
        FUZZ_REQUIRE(rc == 0 || (rc < 0 && rc != -EBUSY && j->sends == 0),
                "%s returned %d with %u queued", urgent ? "urgent submit" : "submit", rc,
                before);
    if (urgent && rc == 0)
        FUZZ_REQUIRE(j->sends == 1, "safety action %u not written at once", j->id);
    if (urgent && was_connected)
        FUZZ_REQUIRE(displaced <= 1 && (displaced == 0 || before - taken_out >= CMD_QUEUE_CAPACITY),
                "a safety action displaced %u commands with %u queued, %u taken out", displaced,
                before, taken_out);
    /* Not when nested in another's callbacks: the moves that one took out
     * are told one after another, some still untold now. */
    if (urgent && rc == 0 && !dropped_inside && outer == 0)
        for (unsigned i = 0; i < j->id; i++) /* later ones came after it */
            FUZZ_REQUIRE(!(jobs[i].accepted && jobs[i].moves && !jobs[i].sends &&
                           !jobs[i].done_calls),
                    "job %u, a move never written, still queued after a safety action", i);
    /* Unless a done callback inside the call dropped the link (fails all). */
    FUZZ_REQUIRE(j->done_calls == 0 || dropped_inside, "job %u finished inside its submit", j->id);
    displaced = outer_displaced;
    taken_out = outer_taken;
    dropped_inside = outer_dropped || dropped_inside;
    return rc;
}

static void check_parse(const char *data, size_t size, struct cmd_result *r)
{
    cmd_parse_reply(data, size, r);
    FUZZ_REQUIRE(r->reply == data && r->reply_size == size, "reply not kept");
    FUZZ_REQUIRE(r->outcome == CMD_DONE || r->outcome == CMD_ROBOT_ERROR, "parse outcome %d",
            r->outcome);
    FUZZ_REQUIRE((r->outcome == CMD_DONE) == (r->error_code == 0),
            "outcome %d with errorCode %ld", r->outcome, r->error_code);
    FUZZ_REQUIRE(memchr(r->error_msg, '\0', sizeof(r->error_msg)), "errorMsg not terminated");
}

/* The robot answers: the job in flight must finish, with this outcome. */
static void reply(const char *data, size_t size)
{
    struct cmd_result r;
    uint64_t unsolicited = queue.stats.unsolicited;

    if (!connected)
        return; /* nothing arrives on a link that is down */
    check_parse(data, size, &r);
    expect_reply_for = wire_count ? (int)wire[0] : -1;
    expect_outcome = r.outcome;
    reply_finished = false;
    unsigned done_before = 0;
    for (unsigned k = 0; k < job_count; k++)
        done_before += jobs[k].done_calls;
    cmd_queue_on_reply(&queue, data, size);
    unsigned done_after = 0;
    for (unsigned k = 0; k < job_count; k++)
        done_after += jobs[k].done_calls;
    if (expect_reply_for >= 0)
        FUZZ_REQUIRE(reply_finished, "the reply did not finish job %d", expect_reply_for);
    else
        FUZZ_REQUIRE(done_after == done_before && queue.stats.unsolicited == unsolicited + 1,
                "a stray reply finished a command");
    expect_reply_for = -1;
}

static const char *const canned[] = {
    "{\"errorCode\":\"0\",\"errorMsg\":\"\"}",
    "{\"errorCode\":0}",
    "{\"errorCode\":\"2\",\"errorMsg\":\"call power_on first\"}",
    "{\"errorCode\":1e300}",
    "{\"errorCode\":-2147483649}",
    "{\"errorCode\":\"99999999999999999999999\"}",
    "{\"errorCode\":\"\"}",
    "{\"errorMsg\":\"no code\"}",
    "{\"errorCode\":\"0\",\"errorCode\":\"1\"}",
    "{}",
    "[1]",
    "",
};

static void step(struct cursor *c)
{
    uint8_t op = next(c), arg = next(c);

    switch (op % 9) {
    case 0: /* a burst of commands, 1..80 */
        for (unsigned i = 0, n = 1 + arg % 80; i < n; i++)
            submit(CHILD_NONE, false);
        break;
    case 1: /* one command whose done callback submits again or drops the link */
        submit(CHILD_SUBMIT + arg % 3, arg & 4);
        break;
    case 2: { /* a canned reply */
        const char *r = canned[arg % (sizeof(canned) / sizeof(*canned))];
        reply(r, strlen(r));
        break;
    }
    case 3: { /* a raw reply, from the input */
        size_t take = arg < c->left ? arg : c->left;
        /* A copy of exactly its size: any read past it is caught. */
        char *copy = malloc(take ? take : 1);
        if (!copy)
            abort();
        memcpy(copy, c->p, take);
        reply(copy, take);
        free(copy);
        c->p += take;
        c->left -= take;
        break;
    }
    case 4: { /* time passes */
        bool late = queue.in_flight && now_ms + (uint64_t)arg * 16 - queue.sent_at_ms >= TIMEOUT_MS;
        int head = wire_count ? (int)wire[0] : -1;
        now_ms += (uint64_t)arg * 16;
        cmd_queue_check_timeout(&queue);
        if (late) {
            FUZZ_REQUIRE(head >= 0 && jobs[head].outcome == CMD_TIMEOUT,
                    "job %d in flight past the timeout ended %d", head,
                    head >= 0 ? (int)jobs[head].outcome : -1);
            FUZZ_REQUIRE(!connected, "a reply timeout did not restart the link");
        } else if (head >= 0) {
            FUZZ_REQUIRE(jobs[head].done_calls == 0, "job %d timed out early", head);
        }
        break;
    }
    case 5: /* the link goes down */
        link_down();
        break;
    case 6: /* the link comes up */
        if (!connected) {
            connected = true;
            cmd_queue_set_connected(&queue, true);
        }
        break;
    case 7: /* the next send fails */
        fail_next_send = arg & 1 ? -ENOBUFS : -EPIPE;
        break;
    case 8: /* safety actions, 1..4 at once */
        for (unsigned i = 0, n = 1 + arg % 4; i < n; i++)
            submit(CHILD_NONE, true);
        break;
    }
    FUZZ_REQUIRE(queue.in_flight == (wire_count != 0), "the queue thinks %s in flight, the link %s",
            queue.in_flight ? "one is" : "none is", wire_count ? "has one" : "has none");
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct cmd_ops ops = {.send = fake_send, .now_ms = fake_now, .restart_link = fake_restart};
    struct cmd_result r;
    struct cursor c = {data, size};

    /* The whole input as one reply: a copy of exactly its size. */
    char *copy = malloc(size ? size : 1);
    if (!copy)
        abort();
    memcpy(copy, data, size);
    check_parse(copy, size, &r);
    free(copy);

    job_count = 0;
    wire_count = 0;
    now_ms = 5000;
    fail_next_send = 0;
    connected = true;
    cmd_queue_init(&queue, &ops, TIMEOUT_MS);
    cmd_queue_set_connected(&queue, true);
    for (unsigned i = 0; i < MAX_STEPS && c.left; i++)
        step(&c);
    cmd_queue_free(&queue);
    for (unsigned k = 0; k < job_count; k++)
        FUZZ_REQUIRE(!jobs[k].accepted || jobs[k].done_calls == 1,
                "job %u: %u done callbacks", k, jobs[k].done_calls);
    return 0;
}
