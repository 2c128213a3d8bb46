/* SPDX-License-Identifier: MIT */
/*
 * jakasim.c - a JAKA robot controller simulator: the status port pushes the
 * status document every period; the command port answers Chapter-4
 * commands; faults are injected on request, for the gateway's tests. With
 * --tls-cert and --tls-key both ports speak TLS, as some controllers do
 * (no client certificate is asked for), through the gateway's own engine.
 *
 * set_network_exception_handle (manual 4.75) arms the command connection it
 * comes on: when that connection is lost, whatever still runs is kept,
 * paused or stopped per motType, timeLimit ms after the loss was seen. The
 * manual does not say how a controller sees the loss; jakasim takes a
 * connection closed (FIN), reset (RST) or failed (a read, write or TLS
 * error) at once, and, with --link-check-ms N, one silent for N ms (a link
 * check missed) as lost then. The handler belongs to the connection that
 * set it: a client that never set one loses nothing by leaving.
 *
 * Two signals make faults a test can start and end at a moment it chooses
 * (the alert tests time both): SIGUSR1 toggles a silent status stream
 * (connections stay open, nothing is pushed, as --silent-after-ms), SIGUSR2
 * toggles the robot's protective stop, SIGRTMIN its emergency stop (the
 * button pressed: the robot disabled, a running program stopped; released,
 * the robot stays disabled until enable_robot).
 */
#include "framer.h"
#include "log.h"
#include "pyjson.h"
#include "robot.h"
#include "status_doc.h"
#include "tls.h"

#include <cJSON.h>
#include <errno.h>
#include <getopt.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#define MAX_QUEUED_STATUS (1024 * 1024)
/* Commands --reply-delay may name. */
#define SIM_REPLY_DELAYS 8

struct sim_options {
    const char *bind;
    int status_port, command_port;
    unsigned period_ms;
    const char *profile;
    bool test_pattern;
    const char *replay;
    bool print_status;
    bool auto_run;
    /* faults */
    unsigned drop_every_ms;
    unsigned silent_after_ms;
    bool split;
    unsigned merge;
    unsigned garbage_every;
    unsigned truncate_every;
    unsigned oversize_every;
    unsigned corrupt_every;
    const char *fail_command;
    const char *fail_message; /* its errorMsg; NULL: "call NAME failed" */
    const char *ignore_command;
    unsigned reply_delay_ms;
    const char *delay_command; /* delay only this command's reply */
    /* --reply-delay CMD:MS: this command's reply, MS ms late. */
    struct reply_delay {
        char name[64];
        unsigned ms;
    } delays[SIM_REPLY_DELAYS];
    unsigned delay_count;
    unsigned stop_time_ms; /* --stop-time-ms: a stop from full speed */
    bool log_commands;
    const char *tls_cert, *tls_key; /* both ports over TLS */
    /* A live command client sends something at least this often (0: a
     * silent connection is never taken as lost). */
    unsigned link_check_ms;
    unsigned move_lag;   /* status documents before an accepted move starts */
    unsigned fail_times; /* --fail-command fails this many times (0: always) */
};

struct peer {
    uv_tcp_t tcp;
    struct sim *sim;
    uint64_t id; /* unique for the simulator's life: memory is reused */
    bool status; /* a status-port client, else a command-port client */
    bool synced; /* has seen a document start: a client joining while a
                    document is sent in pieces waits for the next one */
    struct framer framer;
    bool framer_ready;
    bool closing;
    struct tls_conn *tls; /* with --tls-cert */
    bool ready;           /* plain TCP, or the TLS handshake done */
    /* set_network_exception_handle, as accepted on this connection. */
    bool handler_set;
    unsigned handler_ms;
    enum sim_net_motion handler_motion;
    /* Since when the client has had nothing to wait for and has sent
     * nothing: the later of its last bytes and our last reply. */
    uint64_t quiet_since_ms;
    unsigned replies_owed; /* held by --reply-delay-ms */
    /* The last held reply's time: a controller answers in order, so a
     * reply due sooner waits behind it. */
    uint64_t held_until_ms;
    uv_timer_t silence;    /* command clients: --link-check-ms + timeLimit */
    int open_handles;      /* the peer is freed when the last one closes */
    struct peer *next;
};

struct sim {
    uv_loop_t *loop;
    struct sim_options opt;
    const struct sim_profile *profile;
    struct sim_robot robot;
    uv_tcp_t status_server, command_server;
    uv_timer_t tick, drop, split_timer;
    uv_signal_t sigint, sigterm, sigusr1, sigusr2, sigestop;
    bool silenced; /* SIGUSR1 */
    struct peer *peers;
    struct pyjson doc;
    char *replay_doc;
    size_t replay_size;
    uint64_t documents;
    uint64_t started_ms;
    char *merged;       /* documents held for --merge */
    size_t merged_size;
    unsigned merged_count;
    char *pieces;       /* the rest of a document sent in pieces (--split) */
    size_t piece_size, piece_sent;
    uint64_t next_peer_id;
    struct delayed_reply *delayed; /* replies waiting for --reply-delay-ms */
    struct link_loss *losses;      /* handlers waiting out their timeLimit */
    struct log_ratelimit handler_log; /* a client may open and drop many */
    struct tls_context *tls;
};

struct write_req {
    uv_write_t req;
    char data[];
};

static void on_written(uv_write_t *req, int status)
{
    (void)status;
    free(req);
}

static void peer_closed(uv_handle_t *h)
{
    struct peer *p = h->data;
    if (--p->open_handles > 0)
        return;
    if (p->framer_ready)
        framer_free(&p->framer);
    tls_conn_free(p->tls);
    free(p);
}

/* Closes a connection; 'reset': with an RST, nothing queued delivered. */
static void close_peer_how(struct peer *p, bool reset)
{
    struct sim *sim = p->sim;
    if (p->closing)
        return;
    p->closing = true;
    for (struct peer **pp = &sim->peers; *pp; pp = &(*pp)->next) {
        if (*pp == p) {
            *pp = p->next;
            break;
        }
    }
    if (!p->status)
        uv_close((uv_handle_t *)&p->silence, peer_closed);
    if (!reset || uv_tcp_close_reset(&p->tcp, peer_closed) != 0)
        uv_close((uv_handle_t *)&p->tcp, peer_closed);
}

static void close_peer(struct peer *p)
{
    close_peer_how(p, false);
}

/* ---- the network-exception handler ---- */

/* A lost connection's handler, waiting out its timeLimit. */
struct link_loss {
    uv_timer_t timer;
    struct sim *sim;
    uint64_t peer_id;
    enum sim_net_motion motion;
    unsigned time_limit_ms;
    uint64_t seen_ms; /* when the loss was seen */
    char why[128];
    struct link_loss *next;
};

static void loss_closed(uv_handle_t *h)
{
    free(h->data);
}

static void drop_loss(struct link_loss *l)
{
    for (struct link_loss **pp = &l->sim->losses; *pp; pp = &(*pp)->next) {
        if (*pp == l) {
            *pp = l->next;
            break;
        }
    }
    uv_close((uv_handle_t *)&l->timer, loss_closed);
}

/* The rate limiter's count, as the end of the line that passes. */
static const char *held_back(uint64_t suppressed)
{
    static char text[64];
    text[0] = '\0';
    if (suppressed)
        snprintf(text, sizeof(text), " (%llu handler lines held back)",
                 (unsigned long long)suppressed);
    return text;
}

static const char *motion_name(enum sim_net_motion m)
{
    return m == SIM_NET_PAUSE ? "pause" : m == SIM_NET_STOP ? "stop" : "keep";
}

/* The handler acts on the robot, and says in one line what, why and after
 * how long. */
static void handler_act(struct sim *sim, uint64_t peer_id, enum sim_net_motion motion,
                        unsigned time_limit_ms, const char *why, uint64_t waited_ms)
{
    char done[192];
    uint64_t suppressed;

    sim_robot_network_lost(&sim->robot, motion, done, sizeof(done));
    if (log_ratelimit_pass(&sim->handler_log, uv_now(sim->loop), &suppressed))
        log_notice("jakasim: network exception on command connection %llu: %s; waited %llu "
                   "ms (timeLimit %u ms); motType %d (%s): %s%s",
                   (unsigned long long)peer_id, why, (unsigned long long)waited_ms,
                   time_limit_ms, (int)motion, motion_name(motion), done,
                   held_back(suppressed));
}

static void on_loss_timer(uv_timer_t *t)
{
    struct link_loss *l = t->data;
    handler_act(l->sim, l->peer_id, l->motion, l->time_limit_ms, l->why,
                uv_now(l->sim->loop) - l->seen_ms);
    drop_loss(l);
}

/*
 * Connection 'p' is lost from the client's side ('why'): with a handler
 * set, its action runs timeLimit ms from now (the manual's "how many ms
 * delay will it trigger upon network anomaly"), whatever connects
 * meanwhile. Then the connection is closed.
 */
static void lose_peer(struct peer *p, const char *why)
{
    struct sim *sim = p->sim;

    if (p->closing)
        return;
    if (!p->status && p->handler_set) {
        struct link_loss *l = calloc(1, sizeof(*l));
        if (l) {
            l->sim = sim;
            l->peer_id = p->id;
            l->motion = p->handler_motion;
            l->time_limit_ms = p->handler_ms;
            l->seen_ms = uv_now(sim->loop);
            snprintf(l->why, sizeof(l->why), "%s", why);
            uv_timer_init(sim->loop, &l->timer);
            l->timer.data = l;
            l->next = sim->losses;
            sim->losses = l;
            uv_timer_start(&l->timer, on_loss_timer, p->handler_ms, 0);
        } else {
            handler_act(sim, p->id, p->handler_motion, p->handler_ms, why, 0);
        }
    }
    close_peer(p);
}

/*
 * Nothing from a client with a handler set for --link-check-ms plus
 * timeLimit, while it waited for no reply: a link check did not come, and
 * timeLimit has passed since. The handler acts now, and the connection is
 * reset: a client whose link comes back finds it gone instead of a robot
 * that no longer watches it.
 */
static void on_silence(uv_timer_t *t)
{
    struct peer *p = t->data;
    struct sim *sim = p->sim;
    uint64_t silent_ms = uv_now(sim->loop) - p->quiet_since_ms;
    uint64_t check_ms = sim->opt.link_check_ms;
    char why[128];

    snprintf(why, sizeof(why), "silent for %llu ms, a link check expected every %llu ms",
             (unsigned long long)silent_ms, (unsigned long long)check_ms);
    handler_act(sim, p->id, p->handler_motion, p->handler_ms, why,
                silent_ms > check_ms ? silent_ms - check_ms : 0);
    close_peer_how(p, true);
}

/*
 * Bytes arrived, or a reply left: the silence starts again. A client
 * waiting for a delayed reply sends no link check (the gateway never
 * checks a link with a command in flight), so its silence is not counted
 * until the reply has gone.
 */
static void peer_alive(struct peer *p)
{
    p->quiet_since_ms = uv_now(p->sim->loop);
    if (p->handler_set && p->sim->opt.link_check_ms && p->replies_owed == 0)
        uv_timer_start(&p->silence, on_silence,
                       (uint64_t)p->sim->opt.link_check_ms + p->handler_ms, 0);
    else
        uv_timer_stop(&p->silence);
}

/* Bytes as they go on the wire. */
static void write_raw(struct peer *p, const char *data, size_t size)
{
    struct write_req *w;
    uv_buf_t buf;

    if (uv_stream_get_write_queue_size((uv_stream_t *)&p->tcp) > MAX_QUEUED_STATUS) {
        log_warn("jakasim: dropping a client that does not read");
        lose_peer(p, "it does not read: over 1 MiB queued");
        return;
    }
    w = malloc(sizeof(*w) + size);
    if (!w)
        return;
    memcpy(w->data, data, size);
    buf = uv_buf_init(w->data, (unsigned)size);
    int rc = uv_write(&w->req, (uv_stream_t *)&p->tcp, &buf, 1, on_written);
    if (rc < 0) {
        char why[96];
        free(w);
        snprintf(why, sizeof(why), "write failed: %s", uv_strerror(rc));
        lose_peer(p, why);
    }
}

/* What the TLS engine has for the socket. */
static void flush_tls(struct peer *p)
{
    char cipher[16384];
    size_t n;

    while (!p->closing && (n = tls_conn_take(p->tls, cipher, sizeof(cipher))) > 0)
        write_raw(p, cipher, n);
}

static void send_to(struct peer *p, const char *data, size_t size)
{
    if (p->closing || !p->ready || size == 0)
        return;
    if (!p->tls) {
        write_raw(p, data, size);
        return;
    }
    if (tls_conn_write(p->tls, data, size) != 0) {
        log_warn("jakasim: TLS write failed; closing the client");
        lose_peer(p, "TLS write failed");
        return;
    }
    flush_tls(p);
}

static void broadcast_status(struct sim *sim, const char *data, size_t size)
{
    struct peer *next;
    for (struct peer *p = sim->peers; p; p = next) {
        next = p->next;
        if (p->status && p->synced && p->ready)
            send_to(p, data, size);
    }
}

/* A document starts: every status client may receive it from here on. */
static void start_document(struct sim *sim)
{
    for (struct peer *p = sim->peers; p; p = p->next)
        p->synced = true;
}

static void on_split_timer(uv_timer_t *t)
{
    struct sim *sim = t->data;
    size_t left = sim->piece_size - sim->piece_sent;
    size_t n = left > sim->piece_size / 3 + 1 ? sim->piece_size / 3 + 1 : left;

    broadcast_status(sim, sim->pieces + sim->piece_sent, n);
    sim->piece_sent += n;
    if (sim->piece_sent >= sim->piece_size)
        uv_timer_stop(t);
}

static void send_document(struct sim *sim, const char *doc, size_t size);

/* Sends one document, as the fault options shape it. */
static void emit_document(struct sim *sim, const char *doc, size_t size)
{
    const struct sim_options *o = &sim->opt;
    uint64_t n = ++sim->documents;
    char *corrupt = NULL;

    if (o->corrupt_every && n % o->corrupt_every == 0) {
        /* Same length, braces intact: framed fine, but not JSON. */
        corrupt = malloc(size);
        if (corrupt) {
            memcpy(corrupt, doc, size);
            char *sep = strstr(corrupt + size / 2, ", \"");
            if (sep)
                *sep = '#';
            doc = corrupt;
        }
    }
    send_document(sim, doc, size);
    free(corrupt);
}

static void send_document(struct sim *sim, const char *doc, size_t size)
{
    const struct sim_options *o = &sim->opt;
    uint64_t n = sim->documents;

    /* Finish a document still being sent in pieces before the next. */
    if (sim->piece_sent < sim->piece_size) {
        broadcast_status(sim, sim->pieces + sim->piece_sent,
                         sim->piece_size - sim->piece_sent);
        sim->piece_sent = sim->piece_size;
        uv_timer_stop(&sim->split_timer);
    }
    start_document(sim);
    if (o->garbage_every && n % o->garbage_every == 0) {
        static const char garbage[] = "\x01\x02GARBAGE\xff\xfe not json ]] 123 ";
        broadcast_status(sim, garbage, sizeof(garbage) - 1);
    }
    if (o->truncate_every && n % o->truncate_every == 0)
        broadcast_status(sim, doc, size / 2); /* a document cut short */
    if (o->merge > 1) {
        char *m = realloc(sim->merged, sim->merged_size + size);
        if (!m)
            return;
        sim->merged = m;
        memcpy(sim->merged + sim->merged_size, doc, size);
        sim->merged_size += size;
        if (++sim->merged_count >= o->merge) {
            broadcast_status(sim, sim->merged, sim->merged_size);
            sim->merged_size = 0;
            sim->merged_count = 0;
        }
        return;
    }
    if (o->split && size > 3) {
        /* First third now, the rest in two more writes 2 ms apart. */
        char *copy = realloc(sim->pieces, size);
        if (!copy)
            return;
        sim->pieces = copy;
        memcpy(sim->pieces, doc, size);
        sim->piece_size = size;
        sim->piece_sent = 0;
        on_split_timer(&sim->split_timer);
        uv_timer_start(&sim->split_timer, on_split_timer, 2, 2);
        return;
    }
    broadcast_status(sim, doc, size);
}

static void on_tick(uv_timer_t *t)
{
    struct sim *sim = t->data;
    const struct sim_options *o = &sim->opt;

    sim_robot_tick(&sim->robot, o->period_ms / 1000.0);
    if (sim->silenced || (o->silent_after_ms &&
                          uv_now(sim->loop) - sim->started_ms >= o->silent_after_ms))
        return; /* stop pushing, keep the connections open */
    if (sim->replay_doc) {
        emit_document(sim, sim->replay_doc, sim->replay_size);
        return;
    }
    size_t pad = 0;
    if (o->oversize_every && (sim->documents + 1) % o->oversize_every == 0)
        pad = 70 * 1024;
    sim_status_document(&sim->doc, &sim->robot, sim->profile, pad);
    if (!sim->doc.failed)
        emit_document(sim, sim->doc.buf, sim->doc.len);
}

static void on_drop_timer(uv_timer_t *t)
{
    struct sim *sim = t->data;
    log_notice("jakasim: dropping every connection (--drop-every-ms)");
    while (sim->peers)
        close_peer(sim->peers);
}

struct delayed_reply {
    uv_timer_t timer;
    struct sim *sim;
    /* The connection the command came on, by id, not by address: a
     * connection made since may occupy the freed peer's memory, and must
     * never receive a reply meant for a closed one. */
    uint64_t peer_id;
    char name[64]; /* the command's cmdName */
    struct delayed_reply *next;
    size_t size;
    char data[];
};

static void delayed_closed(uv_handle_t *h)
{
    free(h->data);
}

static void drop_delayed(struct delayed_reply *d)
{
    for (struct delayed_reply **pp = &d->sim->delayed; *pp; pp = &(*pp)->next) {
        if (*pp == d) {
            *pp = d->next;
            break;
        }
    }
    uv_close((uv_handle_t *)&d->timer, delayed_closed);
}

static void on_delayed_reply(uv_timer_t *t)
{
    struct delayed_reply *d = t->data;
    bool sent = false;
    for (struct peer *p = d->sim->peers; p && !sent; p = p->next)
        if (p->id == d->peer_id && !p->closing) {
            p->replies_owed--;
            send_to(p, d->data, d->size);
            sent = true;
            peer_alive(p);
        }
    if (d->sim->opt.log_commands)
        log_info("jakasim: delayed reply to %s %s", d->name,
                 sent ? "sent" : "dropped: its client has gone");
    drop_delayed(d);
}

/* set_network_exception_handle was accepted on command connection 'p'. */
static void arm_handler(struct peer *p)
{
    const struct sim_robot *r = &p->sim->robot;
    uint64_t suppressed;

    p->handler_set = true;
    p->handler_ms = (unsigned)r->net_exception_ms;
    p->handler_motion = (enum sim_net_motion)r->net_exception_motion;
    peer_alive(p);
    if (log_ratelimit_pass(&p->sim->handler_log, uv_now(p->sim->loop), &suppressed))
        log_info("jakasim: command connection %llu: network exception handler set: "
                 "timeLimit %u ms, motType %d (%s)%s", (unsigned long long)p->id,
                 p->handler_ms, (int)p->handler_motion, motion_name(p->handler_motion),
                 held_back(suppressed));
}

/* How late command 'name''s reply goes: --reply-delay's entry for it, else
 * --reply-delay-ms (for every command, or --delay-command's only). */
static unsigned reply_delay_of(const struct sim_options *o, const char *name)
{
    for (unsigned i = 0; i < o->delay_count; i++)
        if (strcmp(o->delays[i].name, name) == 0)
            return o->delays[i].ms;
    if (o->reply_delay_ms && (!o->delay_command || strcmp(o->delay_command, name) == 0))
        return o->reply_delay_ms;
    return 0;
}

/* Holds a reply until 'due_ms' (loop time). */
static void hold_reply(struct peer *p, const char *name, const char *data, size_t size,
                       uint64_t due_ms)
{
    struct sim *sim = p->sim;
    struct delayed_reply *d = malloc(sizeof(*d) + size);

    if (!d) {
        log_warn("jakasim: out of memory holding a reply; closing the client");
        lose_peer(p, "out of memory");
        return;
    }
    d->sim = sim;
    d->peer_id = p->id;
    snprintf(d->name, sizeof(d->name), "%s", name);
    d->next = sim->delayed;
    sim->delayed = d;
    d->size = size;
    memcpy(d->data, data, size);
    uv_timer_init(sim->loop, &d->timer);
    d->timer.data = d;
    /* Timers due at the same time run in the order started: in order. */
    uv_timer_start(&d->timer, on_delayed_reply, due_ms - uv_now(sim->loop), 0);
    p->held_until_ms = due_ms;
    p->replies_owed++;
    peer_alive(p);
}

static void on_command_object(void *user, enum framer_event ev, const char *data,
                              size_t size)
{
    struct peer *p = user;
    struct sim *sim = p->sim;
    struct pyjson reply;
    char name[64];

    if (ev != FRAMER_EVENT_OBJECT)
        return;
    pyjson_init(&reply);
    unsigned handlers = sim->robot.net_exception_count;
    bool answer = sim_robot_command(&sim->robot, data, size, sim->opt.fail_command,
                                    &reply, name, sizeof(name));
    if (sim->robot.net_exception_count != handlers)
        arm_handler(p);
    const char *ignore = sim->opt.ignore_command;
    if (ignore && (strcmp(ignore, "all") == 0 || strcmp(ignore, name) == 0))
        answer = false;
    if (sim->opt.log_commands) {
        /* A log line holds about 1000 bytes: a longer reply is cut, and
         * its whole length given. */
        if (answer && reply.len > 600)
            log_info("jakasim: command %.*s -> %.300s... (%zu bytes)", (int)size, data,
                     reply.buf, reply.len);
        else
            log_info("jakasim: command %.*s -> %s", (int)size, data,
                     answer ? reply.buf : "(no reply)");
    }
    if (!answer) {
        /* The client waits for a reply that never comes, sending nothing:
         * only its reply timeout, a close, can end that. */
        p->replies_owed++;
        peer_alive(p);
    }
    if (answer && !reply.failed) {
        uint64_t now = uv_now(sim->loop);
        uint64_t due = now + reply_delay_of(&sim->opt, name);
        if (due < p->held_until_ms)
            due = p->held_until_ms; /* in order, behind a held reply */
        if (due > now)
            hold_reply(p, name, reply.buf, reply.len, due);
        else {
            send_to(p, reply.buf, reply.len);
            peer_alive(p);
        }
    }
    pyjson_free(&reply);
}

static void on_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf)
{
    (void)h;
    buf->base = malloc(suggested);
    buf->len = buf->base ? suggested : 0;
}

/* Runs the handshake; false when it failed and the client is closed. */
static bool continue_handshake(struct peer *p)
{
    char why[200];
    int rc = tls_conn_handshake(p->tls);

    flush_tls(p); /* an alert too */
    if (rc == TLS_OK) {
        p->ready = true;
        p->synced = false; /* from the next document's start */
        log_info("jakasim: %s client: TLS %s", p->status ? "status" : "command",
                 tls_conn_version(p->tls));
    } else if (rc == TLS_ERROR) {
        tls_conn_failure(p->tls, why, sizeof(why));
        log_warn("jakasim: %s client: TLS handshake failed: %s",
                 p->status ? "status" : "command", why);
        close_peer(p);
        return false;
    }
    return true;
}

/* Decrypts what arrived and hands a command client's text to its framer. */
static void read_tls(struct peer *p, const char *data, size_t size)
{
    char plain[16384];
    int n;

    if (tls_conn_feed(p->tls, data, size) != 0 || (!p->ready && !continue_handshake(p))) {
        lose_peer(p, "TLS error");
        return;
    }
    while (p->ready && !p->closing) {
        n = tls_conn_read(p->tls, plain, sizeof(plain));
        if (n == TLS_AGAIN)
            break;
        if (n < 0) {
            lose_peer(p, "TLS error or close");
            return;
        }
        if (!p->status)
            framer_feed(&p->framer, plain, (size_t)n);
    }
    flush_tls(p);
}

static void on_read(uv_stream_t *s, ssize_t nread, const uv_buf_t *buf)
{
    struct peer *p = s->data;
    char why[96];

    if (nread > 0 && !p->status)
        peer_alive(p);
    if (nread > 0 && p->tls) {
        read_tls(p, buf->base, (size_t)nread);
    } else if (nread > 0 && !p->status) {
        framer_feed(&p->framer, buf->base, (size_t)nread);
    } else if (nread < 0) {
        if (nread == UV_EOF)
            snprintf(why, sizeof(why), "closed by the client (FIN)");
        else if (nread == UV_ECONNRESET)
            snprintf(why, sizeof(why), "reset by the client (RST)");
        else
            snprintf(why, sizeof(why), "read failed: %s", uv_strerror((int)nread));
        lose_peer(p, why);
    }
    free(buf->base);
}

static void accept_peer(uv_stream_t *server, bool status)
{
    struct sim *sim = server->data;
    struct peer *p = calloc(1, sizeof(*p));

    if (!p)
        return;
    p->sim = sim;
    p->id = ++sim->next_peer_id;
    p->status = status;
    uv_tcp_init(sim->loop, &p->tcp);
    p->tcp.data = p;
    p->open_handles = 1;
    if (uv_accept(server, (uv_stream_t *)&p->tcp) < 0) {
        p->closing = true;
        uv_close((uv_handle_t *)&p->tcp, peer_closed);
        return;
    }
    p->quiet_since_ms = uv_now(sim->loop);
    if (!status) {
        uv_timer_init(sim->loop, &p->silence);
        p->silence.data = p;
        p->open_handles++;
        if (framer_init(&p->framer, 65536, on_command_object, p) < 0) {
            close_peer(p);
            return;
        }
        p->framer_ready = true;
    }
    if (sim->tls) {
        p->tls = tls_conn_new(sim->tls, NULL);
        if (!p->tls) {
            close_peer(p);
            return;
        }
    } else {
        p->ready = true;
    }
    p->next = sim->peers;
    sim->peers = p;
    uv_tcp_nodelay(&p->tcp, 1);
    uv_read_start((uv_stream_t *)&p->tcp, on_alloc, on_read);
    log_info("jakasim: %s client connected (connection %llu)", status ? "status" : "command",
             (unsigned long long)p->id);
}

static void on_status_connection(uv_stream_t *s, int status)
{
    if (status == 0)
        accept_peer(s, true);
}

static void on_command_connection(uv_stream_t *s, int status)
{
    if (status == 0)
        accept_peer(s, false);
}

static int listen_on(struct sim *sim, uv_tcp_t *server, int port, uv_connection_cb cb)
{
    struct sockaddr_storage addr;
    int rc;

    if (uv_ip4_addr(sim->opt.bind, port, (struct sockaddr_in *)&addr) != 0 &&
        uv_ip6_addr(sim->opt.bind, port, (struct sockaddr_in6 *)&addr) != 0) {
        log_plain("jakasim: --bind: '%s' is not an IP address", sim->opt.bind);
        return -EINVAL;
    }
    uv_tcp_init(sim->loop, server);
    server->data = sim;
    rc = uv_tcp_bind(server, (struct sockaddr *)&addr, 0);
    if (rc == 0)
        rc = uv_listen((uv_stream_t *)server, 16, cb);
    if (rc < 0)
        log_plain("jakasim: cannot listen on %s port %d: %s", sim->opt.bind,
                port, uv_strerror(rc));
    return rc;
}

static void on_close_quiet(uv_handle_t *h)
{
    (void)h;
}

static void on_signal(uv_signal_t *s, int signum)
{
    struct sim *sim = s->data;
    (void)signum;
    while (sim->peers)
        close_peer(sim->peers);
    while (sim->delayed)
        drop_delayed(sim->delayed);
    while (sim->losses)
        drop_loss(sim->losses);
    uv_close((uv_handle_t *)&sim->status_server, on_close_quiet);
    uv_close((uv_handle_t *)&sim->command_server, on_close_quiet);
    uv_close((uv_handle_t *)&sim->tick, on_close_quiet);
    uv_close((uv_handle_t *)&sim->drop, on_close_quiet);
    uv_close((uv_handle_t *)&sim->split_timer, on_close_quiet);
    uv_close((uv_handle_t *)&sim->sigint, on_close_quiet);
    uv_close((uv_handle_t *)&sim->sigterm, on_close_quiet);
    uv_close((uv_handle_t *)&sim->sigusr1, on_close_quiet);
    uv_close((uv_handle_t *)&sim->sigusr2, on_close_quiet);
    uv_close((uv_handle_t *)&sim->sigestop, on_close_quiet);
}

/* SIGUSR1, SIGUSR2 and SIGRTMIN: a fault toggled on or off (see the top). */
static void on_fault_signal(uv_signal_t *s, int signum)
{
    struct sim *sim = s->data;

    if (signum == SIGUSR1) {
        sim->silenced = !sim->silenced;
        log_notice("jakasim: status stream %s (SIGUSR1)",
                   sim->silenced ? "silent, connections kept" : "pushing again");
    } else if (signum != SIGUSR2) {
        sim->robot.emergency_stop = !sim->robot.emergency_stop;
        if (sim->robot.emergency_stop)
            sim->robot.enabled = false; /* the next tick stops a program */
        log_notice("jakasim: emergency stop %s (SIGRTMIN)",
                   sim->robot.emergency_stop ? "pressed" : "released");
    } else {
        sim->robot.protective_stop = !sim->robot.protective_stop;
        log_notice("jakasim: protective stop %s (SIGUSR2)",
                   sim->robot.protective_stop ? "triggered" : "cleared");
    }
}

static int load_replay(struct sim *sim, const char *path)
{
    FILE *f = fopen(path, "rb");
    long size;

    if (!f) {
        log_plain("jakasim: --replay: cannot open %s: %s", path, strerror(errno));
        return -1;
    }
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    fseek(f, 0, SEEK_SET);
    sim->replay_doc = malloc((size_t)size + 1);
    if (!sim->replay_doc || fread(sim->replay_doc, 1, (size_t)size, f) != (size_t)size) {
        fclose(f);
        log_plain("jakasim: --replay: cannot read %s", path);
        return -1;
    }
    fclose(f);
    /* Recorded files may end with a newline the wire never had. */
    while (size > 0 && (sim->replay_doc[size - 1] == '\n' || sim->replay_doc[size - 1] == '\r'))
        size--;
    sim->replay_size = (size_t)size;
    cJSON *check = cJSON_ParseWithLength(sim->replay_doc, sim->replay_size);
    bool ok = cJSON_IsObject(check);
    cJSON_Delete(check);
    if (!ok) {
        log_plain("jakasim: --replay: %s is not one JSON object", path);
        return -1;
    }
    return 0;
}

static void usage(FILE *out)
{
    fprintf(out,
        "Usage: jakasim [options]\n"
        "Simulates a JAKA robot controller: status port and command port.\n\n"
        "  --bind ADDR            listen address (default 127.0.0.1)\n"
        "  --status-port N        status port (default 10000)\n"
        "  --command-port N       command port (default 10001)\n"
        "  --period-ms N          status push period (default 30)\n"
        "  --profile NAME         controller version: manual, zu5s, full (default full)\n"
        "  --test-pattern         distinct values in every field (for map tests)\n"
        "  --replay FILE          push this recorded document instead\n"
        "  --auto-run             power on, enable and play a program at start\n"
        "  --print-status         print one status document and exit\n"
        "  --log-commands         log every command and its reply\n"
        "  --tls-cert FILE        serve both ports over TLS with this certificate (PEM)\n"
        "  --tls-key FILE         and this private key (PEM, mode 0600)\n"
        "  --link-check-ms N      a command client sends a request at least every N ms\n"
        "                         (jakagw: [robot] link_check_ms); with a network\n"
        "                         exception handler set, N ms of silence is a lost link\n"
        "                         (default 0: only a closed or reset connection is)\n"
        "Faults:\n"
        "  --drop-every-ms N      close every connection every N ms\n"
        "  --silent-after-ms N    stop pushing status after N ms, keep connections\n"
        "  --split                write each document in three pieces 2 ms apart\n"
        "  --merge N              write N documents in one write\n"
        "  --garbage-every N      send garbage bytes before every Nth document\n"
        "  --truncate-every N     send half of every Nth document first\n"
        "  --oversize-every N     make every Nth document larger than 64 KiB\n"
        "  --corrupt-every N      break the JSON of every Nth document, keeping its length\n"
        "  --fail-command NAME    answer command NAME with errorCode \"2\"\n"
        "  --fail-message TEXT    the errorMsg of --fail-command's answer (any bytes)\n"
        "  --fail-times N         fail --fail-command's first N calls only (0: all)\n"
        "  --move-lag N           a move starts N status documents after its reply\n"
        "                         (default 3)\n"
        "  --ignore-command NAME  never answer NAME (\"all\": any command)\n"
        "  --reply-delay-ms N     answer commands after N ms\n"
        "  --delay-command NAME   delay only NAME's replies (with --reply-delay-ms)\n"
        "  --reply-delay CMD:MS   answer command CMD after MS ms (repeatable, up to 8);\n"
        "                         replies still leave in the order the commands came\n"
        "Motion:\n"
        "  --stop-time-ms N       a stop from a move's full speed takes N ms; moves ramp\n"
        "                         up and down at that rate (default 0: at once)\n"
        "\nSignals: SIGUSR1 toggles a silent status stream (connections kept),\n"
        "SIGUSR2 toggles a protective stop, SIGRTMIN an emergency stop.\n");
}

static int parse_uint(const char *flag, const char *text, unsigned max, unsigned *out)
{
    char *end;
    unsigned long v = strtoul(text, &end, 10);
    if (*text < '0' || *text > '9' || *end || v > max) {
        log_plain("jakasim: --%s: '%s' must be a whole number 0..%u", flag,
                text, max);
        return -1;
    }
    *out = (unsigned)v;
    return 0;
}

/* --reply-delay CMD:MS */
static int parse_reply_delay(const char *text, struct sim_options *o)
{
    const char *colon = strrchr(text, ':');

    if (!colon || colon == text || (size_t)(colon - text) >= sizeof(o->delays[0].name)) {
        log_plain("jakasim: --reply-delay: '%s' must be CMD:MS", text);
        return -1;
    }
    if (o->delay_count == SIM_REPLY_DELAYS) {
        log_plain("jakasim: --reply-delay: at most %d commands", SIM_REPLY_DELAYS);
        return -1;
    }
    struct reply_delay *d = &o->delays[o->delay_count];
    if (parse_uint("reply-delay", colon + 1, 600000, &d->ms))
        return -1;
    snprintf(d->name, sizeof(d->name), "%.*s", (int)(colon - text), text);
    o->delay_count++;
    return 0;
}

static int parse_options(int argc, char **argv, struct sim_options *o)
{
    static const struct option options[] = {
        {"bind", required_argument, NULL, 'b'},
        {"status-port", required_argument, NULL, 's'},
        {"command-port", required_argument, NULL, 'c'},
        {"period-ms", required_argument, NULL, 'p'},
        {"profile", required_argument, NULL, 'P'},
        {"test-pattern", no_argument, NULL, 't'},
        {"replay", required_argument, NULL, 'r'},
        {"print-status", no_argument, NULL, 'o'},
        {"auto-run", no_argument, NULL, 'a'},
        {"log-commands", no_argument, NULL, 'l'},
        {"drop-every-ms", required_argument, NULL, 'D'},
        {"silent-after-ms", required_argument, NULL, 'S'},
        {"split", no_argument, NULL, 'x'},
        {"merge", required_argument, NULL, 'm'},
        {"garbage-every", required_argument, NULL, 'g'},
        {"truncate-every", required_argument, NULL, 'T'},
        {"oversize-every", required_argument, NULL, 'O'},
        {"corrupt-every", required_argument, NULL, 'C'},
        {"fail-command", required_argument, NULL, 'f'},
        {"fail-message", required_argument, NULL, 'F'},
        {"ignore-command", required_argument, NULL, 'i'},
        {"reply-delay-ms", required_argument, NULL, 'd'},
        {"delay-command", required_argument, NULL, 'e'},
        {"tls-cert", required_argument, NULL, 'K'},
        {"tls-key", required_argument, NULL, 'k'},
        {"link-check-ms", required_argument, NULL, 'L'},
        {"move-lag", required_argument, NULL, 'M'},
        {"fail-times", required_argument, NULL, 'n'},
        {"reply-delay", required_argument, NULL, 'R'},
        {"stop-time-ms", required_argument, NULL, 'B'},
        {"help", no_argument, NULL, 'h'},
        {NULL, 0, NULL, 0},
    };
    unsigned v;
    int opt;

    /* getopt's own message would print the flag raw: this one escapes it. */
    opterr = 0;
    while ((opt = getopt_long(argc, argv, ":h", options, NULL)) != -1) {
        switch (opt) {
        case 'b': o->bind = optarg; break;
        case 's': if (parse_uint("status-port", optarg, 65535, &v)) return -1;
                  o->status_port = (int)v; break;
        case 'c': if (parse_uint("command-port", optarg, 65535, &v)) return -1;
                  o->command_port = (int)v; break;
        case 'p':
            if (parse_uint("period-ms", optarg, 60000, &o->period_ms))
                return -1;
            if (o->period_ms == 0)
                o->period_ms = 1;
            break;
        case 'P': o->profile = optarg; break;
        case 't': o->test_pattern = true; break;
        case 'r': o->replay = optarg; break;
        case 'o': o->print_status = true; break;
        case 'a': o->auto_run = true; break;
        case 'l': o->log_commands = true; break;
        case 'D': if (parse_uint("drop-every-ms", optarg, 3600000, &o->drop_every_ms)) return -1; break;
        case 'S': if (parse_uint("silent-after-ms", optarg, 3600000, &o->silent_after_ms)) return -1; break;
        case 'x': o->split = true; break;
        case 'm': if (parse_uint("merge", optarg, 100, &o->merge)) return -1; break;
        case 'g': if (parse_uint("garbage-every", optarg, 1000000, &o->garbage_every)) return -1; break;
        case 'T': if (parse_uint("truncate-every", optarg, 1000000, &o->truncate_every)) return -1; break;
        case 'O': if (parse_uint("oversize-every", optarg, 1000000, &o->oversize_every)) return -1; break;
        case 'C': if (parse_uint("corrupt-every", optarg, 1000000, &o->corrupt_every)) return -1; break;
        case 'f': o->fail_command = optarg; break;
        case 'F': o->fail_message = optarg; break;
        case 'i': o->ignore_command = optarg; break;
        case 'd': if (parse_uint("reply-delay-ms", optarg, 600000, &o->reply_delay_ms)) return -1; break;
        case 'e': o->delay_command = optarg; break;
        case 'K': o->tls_cert = optarg; break;
        case 'k': o->tls_key = optarg; break;
        case 'L': if (parse_uint("link-check-ms", optarg, 600000, &o->link_check_ms)) return -1; break;
        case 'M': if (parse_uint("move-lag", optarg, 1000, &o->move_lag)) return -1; break;
        case 'n': if (parse_uint("fail-times", optarg, 1000000, &o->fail_times)) return -1; break;
        case 'R': if (parse_reply_delay(optarg, o)) return -1; break;
        case 'B': if (parse_uint("stop-time-ms", optarg, 60000, &o->stop_time_ms)) return -1; break;
        case 'h': usage(stdout); exit(0);
        case ':':
            log_plain("jakasim: %s needs a value; see jakasim --help", argv[optind - 1]);
            return -1;
        default:
            log_plain("jakasim: unknown flag '%s'; see jakasim --help", argv[optind - 1]);
            return -1;
        }
    }
    if (optind < argc) {
        log_plain("jakasim: unexpected argument '%s'", argv[optind]);
        return -1;
    }
    if (!o->tls_cert != !o->tls_key) {
        log_plain("jakasim: --tls-cert and --tls-key go together");
        return -1;
    }
    return 0;
}

/* --tls-cert, --tls-key: the context every connection uses. */
static int load_tls(struct sim *sim)
{
    char why[600];
    struct tls_settings s = {
        .server = true,
        .anonymous_clients = true,
        .certificate = sim->opt.tls_cert,
        .private_key = sim->opt.tls_key,
        .min_version = 12,
        .certificate_key = "--tls-cert",
        .private_key_key = "--tls-key",
        .ca_key = "",
        .crl_key = "",
        .fingerprint_key = "",
    };

    if (!sim->opt.tls_cert)
        return 0;
    if (tls_context_new(&s, &sim->tls, why, sizeof(why)) != 0) {
        log_plain("jakasim: %s", why);
        return -1;
    }
    return 0;
}

int main(int argc, char **argv)
{
    struct sim sim;

    memset(&sim, 0, sizeof(sim));
    sim.opt = (struct sim_options){.bind = "127.0.0.1", .status_port = 10000,
                                   .command_port = 10001, .period_ms = 30, .move_lag = 3,
                                   .profile = "full"};
    if (parse_options(argc, argv, &sim.opt))
        return 2;
    sim.profile = sim_profile_find(sim.opt.profile);
    if (!sim.profile) {
        log_plain("jakasim: --profile: '%s' must be manual, zu5s or full",
                sim.opt.profile);
        return 2;
    }
    sim_robot_init(&sim.robot, sim.opt.test_pattern);
    sim.handler_log.interval_ms = 100;
    sim.robot.profile = sim.profile;
    sim.robot.fail_message = sim.opt.fail_message;
    sim.robot.fail_times = sim.opt.fail_times;
    sim.robot.move_lag_ticks = sim.opt.move_lag;
    sim.robot.ramp.stop_time_s = sim.opt.stop_time_ms / 1000.0;
    if (sim.opt.auto_run) {
        sim.robot.powered_on = sim.robot.enabled = true;
        snprintf(sim.robot.program, sizeof(sim.robot.program), "demo.jks");
        sim.robot.interp_state = 3;
    }
    if (sim.opt.replay && load_replay(&sim, sim.opt.replay))
        return 2;
    pyjson_init(&sim.doc);
    if (sim.opt.print_status) {
        if (sim.replay_doc)
            fwrite(sim.replay_doc, 1, sim.replay_size, stdout);
        else {
            sim_status_document(&sim.doc, &sim.robot, sim.profile, 0);
            fwrite(sim.doc.buf, 1, sim.doc.len, stdout);
        }
        pyjson_free(&sim.doc);
        free(sim.replay_doc);
        return 0;
    }
    if (load_tls(&sim))
        return 2;
    signal(SIGPIPE, SIG_IGN);
    sim.loop = uv_default_loop();
    if (listen_on(&sim, &sim.status_server, sim.opt.status_port, on_status_connection) ||
        listen_on(&sim, &sim.command_server, sim.opt.command_port, on_command_connection))
        return 1;
    uv_timer_init(sim.loop, &sim.tick);
    uv_timer_init(sim.loop, &sim.drop);
    uv_timer_init(sim.loop, &sim.split_timer);
    sim.tick.data = sim.drop.data = sim.split_timer.data = &sim;
    uv_timer_start(&sim.tick, on_tick, sim.opt.period_ms, sim.opt.period_ms);
    if (sim.opt.drop_every_ms)
        uv_timer_start(&sim.drop, on_drop_timer, sim.opt.drop_every_ms,
                       sim.opt.drop_every_ms);
    uv_signal_init(sim.loop, &sim.sigint);
    uv_signal_init(sim.loop, &sim.sigterm);
    sim.sigint.data = sim.sigterm.data = &sim;
    uv_signal_start(&sim.sigint, on_signal, SIGINT);
    uv_signal_start(&sim.sigterm, on_signal, SIGTERM);
    uv_signal_init(sim.loop, &sim.sigusr1);
    uv_signal_init(sim.loop, &sim.sigusr2);
    uv_signal_init(sim.loop, &sim.sigestop);
    sim.sigusr1.data = sim.sigusr2.data = sim.sigestop.data = &sim;
    uv_signal_start(&sim.sigusr1, on_fault_signal, SIGUSR1);
    uv_signal_start(&sim.sigusr2, on_fault_signal, SIGUSR2);
    uv_signal_start(&sim.sigestop, on_fault_signal, SIGRTMIN);
    sim.started_ms = uv_now(sim.loop);
    log_notice("jakasim: status port %s:%d, command port %s:%d, every %u ms, "
               "profile %s%s%s%s", sim.opt.bind, sim.opt.status_port, sim.opt.bind,
               sim.opt.command_port, sim.opt.period_ms, sim.profile->name,
               sim.replay_doc ? ", replaying a recorded document" : "",
               sim.tls ? ", TLS with certificate " : "",
               sim.tls ? tls_context_subject(sim.tls) : "");
    uv_run(sim.loop, UV_RUN_DEFAULT);
    uv_loop_close(sim.loop);
    pyjson_free(&sim.doc);
    tls_context_unref(sim.tls);
    free(sim.replay_doc);
    free(sim.merged);
    free(sim.pieces);
    return 0;
}
