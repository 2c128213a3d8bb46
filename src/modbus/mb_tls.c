/* SPDX-License-Identifier: MIT */
/* mb_tls.c - see mb_tls.h. */
#include "mb_tls.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct mb_tls_conn {
    struct tls_conn *tls;
    struct mb_client *client;
    bool admitted;
    bool heard;                /* bytes came for its handshake */
    bool queued;               /* waits for its handshake step */
    struct mb_tls_conn *next;  /* in the step queue */
    /* Pending handshakes, oldest first: who makes room at max_handshakes. */
    struct mb_tls_conn *older, *newer;
};

/*
 * Ciphertext a pending handshake may hold before its step: a ClientHello
 * with a certificate chain fits. Reading stops while a connection waits for
 * its step, so one read (16 KiB) and the rest of a record is what it holds;
 * the cap is the bound that does not depend on that.
 */
#define HANDSHAKE_INPUT_MAX (64 * 1024)

/* Per-session lines: at most this many per window, the rest counted. */
#define SESSION_LINES_PER_WINDOW 10
#define SESSION_LINE_WINDOW_MS 10000

/*
 * Handshake work is rationed: one handshake step (a key exchange, a
 * signature, a certificate check: about 2 ms here, ten times that on a
 * small ARM core) per turn of the loop. A connection whose handshake has
 * new input joins a queue; an idle handle keeps the loop turning without
 * waiting in poll while the queue is not empty, so between two steps
 * every established client, on either port, is read and answered. A flood
 * of handshakes then delays other handshakes, not the polling PLCs.
 *
 * The queue is allocated with its handle and freed by the handle's close
 * callback, so it may outlive the struct mb_tls that started closing it.
 */
struct mb_tls_steps {
    uv_idle_t idle;
    struct mb_tls *t;
    struct mb_tls_conn *head, *tail;
};

static struct mb_tls_conn *conn_of(struct mb_client *c)
{
    return *mb_client_data(c);
}

int mb_tls_init(struct mb_tls *t, struct tls_context *ctx, const struct mb_tls_config *cfg)
{
    if (!ctx || !cfg || !cfg->rights_for_role || cfg->max_handshakes == 0)
        return -EINVAL;
    memset(t, 0, sizeof(*t));
    t->ctx = ctx;
    t->cfg = *cfg;
    t->fail_log.interval_ms = 1000;
    t->limit_log.interval_ms = 1000;
    t->close_log.interval_ms = 1000;
    return 0;
}

void mb_tls_set_context(struct mb_tls *t, struct tls_context *ctx)
{
    tls_context_unref(t->ctx);
    t->ctx = ctx;
}

static void on_steps_closed(uv_handle_t *h)
{
    free(h->data);
}

void mb_tls_free(struct mb_tls *t)
{
    tls_context_unref(t->ctx);
    t->ctx = NULL;
    if (t->steps) {
        /* Every connection has gone: the queue is empty. */
        uv_close((uv_handle_t *)&t->steps->idle, on_steps_closed);
        t->steps = NULL;
    }
}

uint64_t mb_tls_failed_total(const struct mb_tls_stats *s)
{
    uint64_t total = 0;
    for (int i = 1; i < TLS_FAIL_COUNT; i++)
        total += s->failed[i];
    return total;
}

/* Counts a failed handshake and says why, at most once a second. */
static void handshake_failed(struct mb_tls *t, struct mb_client *c, enum tls_failure f,
                             const char *why, struct log_ratelimit *limit)
{
    uint64_t suppressed;

    t->stats.failed[f]++;
    if (!log_ratelimit_pass(limit, uv_now(mb_client_loop(c)), &suppressed))
        return;
    log_warn("mbaps: client %s: handshake failed: %s (%s); %llu more failed handshakes "
             "since the last such line",
             mb_client_peer(c), tls_failure_name(f), why, (unsigned long long)suppressed);
}

/* A session ends on an error of its own (a bad record): rate-limited. */
static void client_closed_log(struct mb_tls *t, struct mb_client *c, const char *why)
{
    uint64_t suppressed;

    if (!log_ratelimit_pass(&t->close_log, uv_now(mb_client_loop(c)), &suppressed))
        return;
    log_warn("mbaps: client %s: closing connection: %s; %llu more such lines suppressed",
             mb_client_peer(c), why, (unsigned long long)suppressed);
}

/*
 * Writes what the engine has for the socket: also while the connection
 * flushes its last replies, so that a close_notify goes out.
 */
static void flush(struct mb_client *c, struct mb_tls_conn *conn)
{
    uint8_t buf[16384];
    size_t n;

    while (mb_client_can_send(c) && (n = tls_conn_take(conn->tls, buf, sizeof(buf))) > 0)
        mb_client_send_raw(c, buf, n);
}

static void unlink_pending(struct mb_tls *t, struct mb_tls_conn *conn)
{
    if (conn->older)
        conn->older->newer = conn->newer;
    else if (t->pending_oldest == conn)
        t->pending_oldest = conn->newer;
    if (conn->newer)
        conn->newer->older = conn->older;
    else if (t->pending_newest == conn)
        t->pending_newest = conn->older;
    conn->older = conn->newer = NULL;
}

/*
 * The pending handshake to close for a newcomer, by the plain port's rule
 * (mb_server.h): the oldest that has sent nothing (not a byte read, none
 * waiting in the kernel), else the oldest. Silent sockets, however fast
 * they come back, only displace one another; a client that sends its
 * ClientHello at once is not among them.
 */
static struct mb_tls_conn *handshake_victim(struct mb_tls *t)
{
    for (struct mb_tls_conn *p = t->pending_oldest; p; p = p->newer)
        if (!p->heard && !mb_client_has_input(p->client))
            return p;
    return t->pending_oldest;
}

static void make_room(struct mb_tls *t, struct mb_client *newcomer)
{
    struct mb_tls_conn *victim = handshake_victim(t);
    uint64_t age;
    char why[160];

    if (!victim)
        return;
    age = uv_now(mb_client_loop(newcomer)) - mb_client_accepted_ms(victim->client);
    snprintf(why, sizeof(why), "closed after %llu ms %s, to admit %s (max_handshakes %u)",
             (unsigned long long)age,
             victim->heard ? "as the oldest pending handshake" : "without a byte sent",
             mb_client_peer(newcomer), t->cfg.max_handshakes);
    handshake_failed(t, victim->client, TLS_FAIL_OVER_LIMIT, why, &t->limit_log);
    mb_client_close(victim->client, NULL);
}

static int tls_open(void *state, struct mb_client *c)
{
    struct mb_tls *t = state;
    struct mb_tls_conn *conn;

    if (t->stats.handshakes >= t->cfg.max_handshakes)
        make_room(t, c);
    if (t->stats.handshakes >= t->cfg.max_handshakes) {
        char why[64];
        snprintf(why, sizeof(why), "max_handshakes %u running; closed at once",
                 t->cfg.max_handshakes);
        handshake_failed(t, c, TLS_FAIL_OVER_LIMIT, why, &t->limit_log);
        return -EBUSY;
    }
    conn = calloc(1, sizeof(*conn));
    if (conn)
        conn->tls = tls_conn_new(t->ctx, NULL);
    if (!conn || !conn->tls) {
        free(conn);
        log_err("mbaps: out of memory for a new connection from %s: closed", mb_client_peer(c));
        return -ENOMEM;
    }
    conn->client = c;
    conn->older = t->pending_newest;
    if (t->pending_newest)
        t->pending_newest->newer = conn;
    else
        t->pending_oldest = conn;
    t->pending_newest = conn;
    *mb_client_data(c) = conn;
    t->stats.handshakes++;
    mb_client_set_deadline(c, t->cfg.handshake_timeout_ms);
    return MB_TRANSPORT_PENDING;
}

static void tls_alloc(void *state, struct mb_client *c, uv_buf_t *buf)
{
    struct mb_tls *t = state;
    (void)c;
    *buf = uv_buf_init((char *)t->read_buf, sizeof(t->read_buf));
}

/*
 * A session line may be printed: at most SESSION_LINES_PER_WINDOW per
 * SESSION_LINE_WINDOW_MS, so that a handshake loop cannot fill the journal
 * while the first sessions of every PLC still get theirs. *suppressed: the
 * lines held back since the last one printed.
 */
static bool session_line_passes(struct mb_tls *t, uint64_t now, uint64_t *suppressed)
{
    if (now - t->session_window_ms >= SESSION_LINE_WINDOW_MS || !t->session_lines) {
        t->session_window_ms = now;
        t->session_lines = 0;
    }
    if (t->session_lines >= SESSION_LINES_PER_WINDOW) {
        t->sessions_unlogged++;
        return false;
    }
    t->session_lines++;
    *suppressed = t->sessions_unlogged;
    t->sessions_unlogged = 0;
    return true;
}

/* The handshake is done: a line (rate-limited), the rights of the role, a client. */
static void admit(struct mb_tls *t, struct mb_client *c, struct mb_tls_conn *conn)
{
    bool valid, listed = false;
    const char *role = tls_conn_role(conn->tls, &valid);
    uint32_t rights = t->cfg.rights_for_role(t->cfg.user, role, valid, &listed);
    uint64_t suppressed;
    char shown[160], role_text[TLS_ROLE_MAX + 80], more[80] = "";

    t->stats.handshakes--;
    t->stats.handshakes_ok++;
    conn->admitted = true;
    unlink_pending(t, conn);
    t->stats.clients++;
    if (session_line_passes(t, uv_now(mb_client_loop(c)), &suppressed)) {
        regmap_format_rights(rights, shown, sizeof(shown));
        if (!valid)
            snprintf(role_text, sizeof(role_text), "(not taken: %s)",
                     tls_conn_role_problem(conn->tls));
        else if (role[0])
            snprintf(role_text, sizeof(role_text), "\"%s\"", role);
        else
            snprintf(role_text, sizeof(role_text), "(none)");
        if (suppressed)
            snprintf(more, sizeof(more), "; %llu more sessions since the last such line",
                     (unsigned long long)suppressed);
        log_notice("mbaps: client %s: certificate \"%s\", role %s: may write %s (%s, %s, %s)%s",
                   mb_client_peer(c), tls_conn_subject(conn->tls), role_text, shown,
                   listed ? "[roles]" : "default_rights", tls_conn_version(conn->tls),
                   tls_conn_resumed(conn->tls) ? "session resumed" : "new session", more);
    }
    mb_client_set_identity(c, tls_conn_subject(conn->tls), valid ? role : "");
    mb_client_admit(c, rights);
}

/* Hands every whole piece of plaintext to the server's framing. */
static void read_plaintext(struct mb_tls *t, struct mb_client *c, struct mb_tls_conn *conn)
{
    char why[200];

    while (mb_client_is_open(c)) {
        size_t room;
        uint8_t *space = mb_client_space(c, &room);
        if (room == 0)
            return;
        int n = tls_conn_read(conn->tls, space, room);
        if (n > 0) {
            mb_client_received(c, (size_t)n);
            continue;
        }
        flush(c, conn); /* an alert or a ticket */
        if (n == TLS_AGAIN || !mb_client_is_open(c))
            return;
        if (n == TLS_CLOSED) {
            mb_client_release(c, NULL);
            return;
        }
        enum tls_failure f = tls_conn_failure(conn->tls, why, sizeof(why));
        if (tls_conn_renegotiation_refused(conn->tls)) {
            /* A handshake that failed: counted as one (protocol). */
            handshake_failed(t, c, f, why, &t->fail_log);
            mb_client_close(c, NULL);
            return;
        }
        client_closed_log(t, c, why);
        mb_client_close(c, NULL);
        return;
    }
}

/* Advances one connection's handshake with what it was fed. */
static void step_handshake(struct mb_tls *t, struct mb_client *c, struct mb_tls_conn *conn)
{
    char why[200];
    int rc = tls_conn_handshake(conn->tls);

    flush(c, conn); /* our flight, or the alert that says no */
    if (!mb_client_is_open(c))
        return;
    if (rc == TLS_AGAIN) {
        mb_client_resume_reading(c); /* its turn is over: the next flight */
        return;
    }
    if (rc == TLS_ERROR) {
        enum tls_failure f = tls_conn_failure(conn->tls, why, sizeof(why));
        handshake_failed(t, c, f, why, &t->fail_log);
        mb_client_close(c, NULL);
        return;
    }
    admit(t, c, conn);
    if (mb_client_resume_reading(c) == 0)
        read_plaintext(t, c, conn); /* a request sent with the client's Finished */
}

static void unqueue(struct mb_tls_steps *q, struct mb_tls_conn *conn)
{
    struct mb_tls_conn *prev = NULL;

    for (struct mb_tls_conn *p = q->head; p; prev = p, p = p->next) {
        if (p != conn)
            continue;
        if (prev)
            prev->next = p->next;
        else
            q->head = p->next;
        if (q->tail == p)
            q->tail = prev;
        break;
    }
    conn->next = NULL;
    conn->queued = false;
}

/* One turn of the loop: one handshake step. */
static void on_step_turn(uv_idle_t *idle)
{
    struct mb_tls_steps *q = idle->data;
    struct mb_tls_conn *conn = q->head;

    if (conn) {
        unqueue(q, conn);
        step_handshake(q->t, conn->client, conn);
    }
    if (!q->head)
        uv_idle_stop(&q->idle);
}

/* Queues a handshake step; 0, or -ENOMEM when the queue cannot be made. */
static int queue_step(struct mb_tls *t, struct mb_client *c, struct mb_tls_conn *conn)
{
    struct mb_tls_steps *q = t->steps;

    if (conn->queued)
        return 0;
    if (!q) {
        q = calloc(1, sizeof(*q));
        if (!q)
            return -ENOMEM;
        uv_idle_init(mb_client_loop(c), &q->idle);
        q->idle.data = q;
        q->t = t;
        t->steps = q;
    }
    conn->queued = true;
    conn->next = NULL;
    if (q->tail)
        q->tail->next = conn;
    else
        q->head = conn;
    q->tail = conn;
    uv_idle_start(&q->idle, on_step_turn);
    return 0;
}

static void tls_input(void *state, struct mb_client *c, const uint8_t *data, size_t size)
{
    struct mb_tls *t = state;
    struct mb_tls_conn *conn = conn_of(c);

    if (!conn->admitted) {
        conn->heard = true;
        if (tls_conn_buffered(conn->tls) + size > HANDSHAKE_INPUT_MAX) {
            char why[80];
            snprintf(why, sizeof(why), "more than %u bytes sent before its handshake step",
                     HANDSHAKE_INPUT_MAX);
            handshake_failed(t, c, TLS_FAIL_PROTOCOL, why, &t->fail_log);
            mb_client_close(c, NULL);
            return;
        }
    }
    if (tls_conn_feed(conn->tls, data, size) < 0) {
        mb_client_close(c, "out of memory for TLS input");
        return;
    }
    if (conn->admitted) {
        read_plaintext(t, c, conn);
        return;
    }
    /* Nothing more is read until its step has taken this. */
    mb_client_pause_reading(c);
    if (queue_step(t, c, conn) < 0)
        mb_client_close(c, "out of memory for the handshake queue");
}

static void tls_output(void *state, struct mb_client *c, const uint8_t *data, size_t size)
{
    struct mb_tls_conn *conn = conn_of(c);
    (void)state;

    if (tls_conn_write(conn->tls, data, size) != 0) {
        mb_client_close(c, "TLS encryption failed");
        return;
    }
    flush(c, conn);
}

static void tls_finish(void *state, struct mb_client *c)
{
    struct mb_tls_conn *conn = conn_of(c);
    (void)state;

    tls_conn_close_notify(conn->tls);
    flush(c, conn);
}

static void tls_expired(void *state, struct mb_client *c)
{
    struct mb_tls *t = state;
    char why[64];

    snprintf(why, sizeof(why), "not finished within handshake_timeout_ms %u",
             t->cfg.handshake_timeout_ms);
    handshake_failed(t, c, TLS_FAIL_TIMEOUT, why, &t->fail_log);
}

static void tls_closed(void *state, struct mb_client *c, bool was_pending)
{
    struct mb_tls *t = state;
    struct mb_tls_conn *conn = conn_of(c);

    (void)was_pending; /* the connection knows better: admitted or not */
    if (!conn)
        return; /* refused at open */
    if (conn->queued)
        unqueue(t->steps, conn);
    if (conn->admitted) {
        t->stats.clients--;
    } else {
        t->stats.handshakes--;
        unlink_pending(t, conn);
    }
}

static void tls_free(void *state, struct mb_client *c)
{
    struct mb_tls_conn *conn = conn_of(c);
    (void)state;

    if (!conn)
        return;
    tls_conn_free(conn->tls);
    free(conn);
    *mb_client_data(c) = NULL;
}

const struct mb_transport mb_transport_tls = {
    .name = "mbaps",
    .stats_slot = 1,
    .open = tls_open,
    .alloc = tls_alloc,
    .input = tls_input,
    .output = tls_output,
    .finish = tls_finish,
    .expired = tls_expired,
    .closed = tls_closed,
    .free = tls_free,
};
