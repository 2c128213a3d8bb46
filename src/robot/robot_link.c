/* SPDX-License-Identifier: MIT */
/* robot_link.c - see robot_link.h. */
#include "robot_link.h"

#include "log.h"

#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>

static void start_connect(struct robot_link *link);
static void on_connect_timeout(uv_timer_t *t);
static void on_check(uv_check_t *c);

static void set_state(struct robot_link *link, enum robot_link_state state)
{
    if (link->state == state)
        return;
    link->state = state;
    if (link->cb.on_state)
        link->cb.on_state(link, state);
}

/* Hands an object to the owner; the silence watchdog counts from after it. */
static void deliver(struct robot_link *link, const char *data, size_t size)
{
    link->cb.on_object(link, data, size);
    /* Handling the object may have taken long (a large document): the
     * silence watchdog must count from now, not from the loop time
     * cached before it, or it would take the work for silence. */
    uv_update_time(link->loop);
    link->last_object_ms = uv_now(link->loop);
}

/*
 * newest_only: keeps 'data' as the object to hand over in the check phase.
 * One held before is superseded: handed over now only if the owner says
 * it carries a change, else dropped.
 */
static void hold(struct robot_link *link, const char *data, size_t size)
{
    if (link->holding) {
        link->holding = false;
        if (link->cb.on_superseded && link->cb.on_superseded(link, link->held, link->held_size))
            deliver(link, link->held, link->held_size);
        else
            link->superseded++;
        if (link->state != ROBOT_LINK_CONNECTED)
            return; /* the owner restarted the link: nothing more is held */
    }
    memcpy(link->held, data, size);
    link->held_size = size;
    link->holding = true;
    link->held_turns = 0;
    uv_check_start(&link->check, on_check);
}

static void on_framer_event(void *user, enum framer_event event,
                            const char *data, size_t size)
{
    struct robot_link *link = user;

    if (event == FRAMER_EVENT_OBJECT) {
        /* The robot speaks: a later failure starts the backoff afresh. */
        link->backoff_ms = 0;
        link->last_error = 0;
        link->objects_on_connection++;
        if (link->unstable) {
            log_notice("%s link: the robot is sending again (%llu reconnects while "
                       "it was not)", link->cfg.name,
                       (unsigned long long)link->quiet_reconnects);
            link->unstable = false;
            link->quiet_reconnects = 0;
        }
        if (link->cfg.newest_only) {
            link->last_object_ms = uv_now(link->loop);
            hold(link, data, size);
            return;
        }
        deliver(link, data, size);
        return;
    }
    if (link->cb.on_framing_error)
        link->cb.on_framing_error(link, event, size);
}

int robot_link_init(uv_loop_t *loop, struct robot_link *link,
                    const struct robot_link_config *cfg,
                    const struct robot_link_callbacks *cb, void *user)
{
    int rc;

    if (!loop || !link || !cfg || !cb || !cb->on_object || !cfg->host ||
        strlen(cfg->host) >= sizeof(link->host) || cfg->port == 0 ||
        cfg->reconnect_min_ms == 0 || cfg->reconnect_min_ms > cfg->reconnect_max_ms)
        return -EINVAL;
    memset(link, 0, sizeof(*link));
    link->loop = loop;
    link->cfg = *cfg;
    snprintf(link->host, sizeof(link->host), "%s", cfg->host);
    link->cfg.host = link->host;
    link->cb = *cb;
    link->user = user;
    rc = framer_init(&link->framer, cfg->max_object, on_framer_event, link);
    if (rc)
        return rc;
    if (cfg->newest_only) {
        link->held = malloc(cfg->max_object);
        if (!link->held) {
            framer_free(&link->framer);
            return -ENOMEM;
        }
    }
    if (cfg->tls)
        tls_context_ref(cfg->tls);
    uv_timer_init(loop, &link->timer);
    uv_timer_init(loop, &link->watchdog);
    link->timer.data = link;
    link->watchdog.data = link;
    /* A robot that drops connections while sending: one line per 5 s. */
    link->loss_log.interval_ms = 5000;
    link->open_handles = 2;
    uv_check_init(loop, &link->check);
    link->check.data = link;
    link->open_handles++;
    return 0;
}

/* A failed handshake's cause, as last_error: apart from libuv's errors. */
#define TLS_ERROR_BASE (-100000)

void robot_link_set_tls(struct robot_link *link, struct tls_context *ctx)
{
    if (ctx)
        tls_context_ref(ctx);
    tls_context_unref(link->cfg.tls);
    link->cfg.tls = ctx;
}

/* Logs a failure once per change of its cause. */
static void log_failure(struct robot_link *link, int err, const char *what)
{
    if (err == link->last_error)
        return;
    link->last_error = err;
    log_warn("%s link: %s %s:%u: %s; retrying every %u ms at most "
             "(logged again when the cause changes)",
             link->cfg.name, what, link->host, link->cfg.port, uv_strerror(err),
             link->cfg.reconnect_max_ms);
}

/*
 * A handshake that failed: the controller is not the one configured (or
 * does not speak TLS). Logged like a refused connect, once per cause, with
 * OpenSSL's reason; the PLC reads the cause in tls_failure.
 */
static void log_tls_failure(struct robot_link *link, enum tls_failure f, const char *why)
{
    int err = TLS_ERROR_BASE - (int)f;

    link->tls_failure = f;
    if (err == link->last_error)
        return;
    link->last_error = err;
    log_warn("%s link: TLS handshake with %s:%u failed: %s (%s); retrying every %u ms "
             "at most (logged again when the cause changes)",
             link->cfg.name, link->host, link->cfg.port, tls_failure_name(f), why,
             link->cfg.reconnect_max_ms);
}

static void on_retry_timer(uv_timer_t *t)
{
    start_connect(t->data);
}

static void schedule_retry(struct robot_link *link)
{
    if (link->stopping)
        return;
    if (link->backoff_ms == 0)
        link->backoff_ms = link->cfg.reconnect_min_ms;
    else if (link->backoff_ms < link->cfg.reconnect_max_ms / 2)
        link->backoff_ms *= 2;
    else
        link->backoff_ms = link->cfg.reconnect_max_ms;
    uv_timer_stop(&link->timer);
    uv_timer_start(&link->timer, on_retry_timer, link->backoff_ms, 0);
}

static void on_tcp_closed(uv_handle_t *h)
{
    struct robot_link *link = h->data;

    link->tcp_open = false;
    link->open_handles--;
    if (link->stopping) {
        if (link->open_handles == 0 && link->close_cb)
            link->close_cb(link);
        return;
    }
    schedule_retry(link);
}

/*
 * Closes the socket abortively (RST): whatever is still in the kernel's
 * send queue is discarded instead of being delivered later. A command
 * the gateway has given up on (and told the PLC so) must never reach the
 * robot when a pulled cable comes back; a graceful close would keep
 * retransmitting it. Falls back to a plain close when the socket has no
 * descriptor yet.
 */
static void close_abortively(struct robot_link *link)
{
    if (uv_tcp_close_reset(&link->tcp, on_tcp_closed) != 0)
        uv_close((uv_handle_t *)&link->tcp, on_tcp_closed);
}

/*
 * Kernel-level bounds on a connection the gateway may not be watching:
 * keepalive probes after KEEPALIVE_IDLE_S idle, then every
 * KEEPALIVE_INTERVAL_S, and TCP_USER_TIMEOUT, after which data (or
 * probes) unacknowledged that long make the kernel abort the connection
 * (a read error here). With TCP_USER_TIMEOUT set, Linux gives up on
 * keepalive once that long has passed with a probe out, instead of
 * counting KEEPALIVE_COUNT probes. These cost the controller nothing (its
 * kernel answers); the command link check (command_port.h) also catches a
 * command server that hangs while its TCP stack lives.
 */
static void tune_socket(struct robot_link *link)
{
    int on = 1, idle = ROBOT_LINK_KEEPALIVE_IDLE_S, interval = ROBOT_LINK_KEEPALIVE_INTERVAL_S,
        count = ROBOT_LINK_KEEPALIVE_COUNT;
    unsigned int user_timeout = link->cfg.user_timeout_ms;
    uv_os_fd_t fd;
    int rc = uv_fileno((uv_handle_t *)&link->tcp, &fd);

    if (rc == 0 &&
        (setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &on, sizeof(on)) != 0 ||
         setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle, sizeof(idle)) != 0 ||
         setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &interval, sizeof(interval)) != 0 ||
         setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &count, sizeof(count)) != 0 ||
         (user_timeout &&
          setsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &user_timeout, sizeof(user_timeout)) != 0)))
        rc = -errno;
    if (rc != 0 && !link->tune_failure_logged) {
        link->tune_failure_logged = true;
        log_warn("%s link: cannot set keepalive and TCP_USER_TIMEOUT: %s; a silent peer "
                 "is found by the gateway's own checks only", link->cfg.name, strerror(-rc));
    }
}

/* Closes the socket; the retry is scheduled once it is closed. */
static void drop_connection(struct robot_link *link)
{
    uv_timer_stop(&link->timer);
    uv_timer_stop(&link->watchdog);
    framer_reset(&link->framer);
    /* What the lost connection held is not handed over after it. */
    link->holding = false;
    link->read_paused = false;
    uv_check_stop(&link->check);
    /* No close_notify: closing the handle would cancel its write anyway,
     * and the controller learns of the end from the TCP close. */
    tls_conn_free(link->tls_conn);
    link->tls_conn = NULL;
    link->tls_ready = false;
    set_state(link, ROBOT_LINK_DISCONNECTED);
    if (link->tcp_open && !uv_is_closing((uv_handle_t *)&link->tcp))
        close_abortively(link);
    else if (!link->tcp_open)
        schedule_retry(link);
}

/*
 * A connection ends. The first loss is a warning; while the link keeps
 * losing connections on which nothing arrived, the rest are debug lines.
 */
static void log_loss(struct robot_link *link, const char *what, const char *why)
{
    if (link->state != ROBOT_LINK_CONNECTED)
        return;
    uint64_t suppressed = 0;
    /* Becoming unstable is always said; losses of working connections are
     * rate-limited. */
    bool becomes_unstable = !link->unstable && link->objects_on_connection == 0;
    if (link->unstable ||
        (!becomes_unstable &&
         !log_ratelimit_pass(&link->loss_log, uv_now(link->loop), &suppressed)))
        log_debug("%s link: %s %s:%u: %s", link->cfg.name, what, link->host,
                  link->cfg.port, why);
    else
        log_warn("%s link: %s %s:%u: %s%s (%llu more losses since the last such line)",
                 link->cfg.name, what, link->host, link->cfg.port, why,
                 link->objects_on_connection ? ""
                                             : " (nothing arrived on it; while this "
                                               "goes on, reconnects are not logged)",
                 (unsigned long long)suppressed);
    if (link->objects_on_connection == 0)
        link->unstable = true;
}

void robot_link_restart(struct robot_link *link, const char *why)
{
    log_loss(link, "closing connection to", why);
    link->last_error = 0;
    drop_connection(link);
}

static void on_watchdog(uv_timer_t *t)
{
    struct robot_link *link = t->data;
    uint64_t silent = uv_now(link->loop) - link->last_object_ms;
    char why[96];

    if (silent < link->cfg.silence_timeout_ms) {
        link->watchdog_waited = false;
        uv_timer_start(&link->watchdog, on_watchdog,
                       link->cfg.silence_timeout_ms - silent, 0);
        return;
    }
    /* Bytes waiting in the socket: the loop itself may have stood still
     * (libuv runs its timers before it reads), not the robot. Read them
     * first and judge again in a moment, once: a peer streaming bytes
     * that make no document is still dropped. Without this, every stall
     * of the gateway longer than the timeout dropped a healthy link. */
    int fd = -1, waiting = 0;
    if (!link->watchdog_waited && uv_fileno((uv_handle_t *)&link->tcp, &fd) == 0 &&
        ioctl(fd, FIONREAD, &waiting) == 0 && waiting > 0) {
        link->watchdog_waited = true;
        uv_timer_start(&link->watchdog, on_watchdog, 10, 0);
        return;
    }
    link->watchdog_waited = false;
    snprintf(why, sizeof(why), "no complete document for %llu ms",
             (unsigned long long)silent);
    robot_link_restart(link, why);
}

static void on_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf)
{
    struct robot_link *link = h->data;
    (void)suggested;
    *buf = uv_buf_init(link->read_buf, sizeof(link->read_buf));
}

static void link_established(struct robot_link *link);
static int write_raw(struct robot_link *link, const void *data, size_t size);

/* Sends what the TLS engine has for the socket. 0 or a negative error. */
static int flush_tls(struct robot_link *link)
{
    /* Not plain_buf: a send from inside the framer's callback comes here
     * while the framer still reads that buffer. */
    char cipher[16384];
    size_t n;
    int rc = 0;

    while (rc == 0 && (n = tls_conn_take(link->tls_conn, cipher, sizeof(cipher))) > 0)
        rc = write_raw(link, cipher, n);
    return rc;
}

/* Advances the handshake; false when the connection was dropped. */
static bool continue_handshake(struct robot_link *link)
{
    char why[200];
    int rc = tls_conn_handshake(link->tls_conn);
    int sent = flush_tls(link);

    if (rc == TLS_AGAIN && sent == 0)
        return true;
    if (rc == TLS_OK && sent == 0) {
        link->tls_ready = true;
        link->tls_failure = TLS_FAIL_NONE;
        uv_timer_stop(&link->timer);
        link_established(link);
        return true;
    }
    if (rc == TLS_ERROR) {
        enum tls_failure f = tls_conn_failure(link->tls_conn, why, sizeof(why));
        log_tls_failure(link, f, why);
    } else {
        log_failure(link, sent, "cannot write to");
    }
    drop_connection(link);
    return false;
}

/* Decrypts what arrived for the framer; false when the connection ended. */
static bool read_tls(struct robot_link *link, const char *data, size_t size)
{
    char why[200];
    int n;

    if (tls_conn_feed(link->tls_conn, data, size) != 0) {
        log_loss(link, "lost the connection to", "out of memory for TLS input");
        drop_connection(link);
        return false;
    }
    if (!link->tls_ready && !continue_handshake(link))
        return false;
    while (link->tls_ready) {
        n = tls_conn_read(link->tls_conn, link->plain_buf, sizeof(link->plain_buf));
        if (n > 0) {
            framer_feed(&link->framer, link->plain_buf, (size_t)n);
            /* The framer's callback may have restarted the link. */
            if (!link->tls_conn)
                return false;
            continue;
        }
        if (n == TLS_AGAIN)
            break;
        if (n == TLS_CLOSED) {
            log_loss(link, "lost the connection to", "closed by the robot (TLS close_notify)");
        } else {
            tls_conn_failure(link->tls_conn, why, sizeof(why));
            log_loss(link, "lost the connection to", why);
        }
        drop_connection(link);
        return false;
    }
    /* TLS 1.3 may answer what arrived (a key update). */
    if (link->tls_conn && flush_tls(link) != 0) {
        drop_connection(link);
        return false;
    }
    return true;
}

static void on_read(uv_stream_t *s, ssize_t nread, const uv_buf_t *buf)
{
    struct robot_link *link = s->data;

    if (nread > 0) {
        if (link->tls_conn)
            read_tls(link, buf->base, (size_t)nread);
        else
            framer_feed(&link->framer, buf->base, (size_t)nread);
        /* A full buffer: more bytes wait. Let the loop serve the other
         * sockets (a PLC's command) before taking more, and decide the
         * held object first. */
        if (link->holding && (size_t)nread == sizeof(link->read_buf) &&
            link->state == ROBOT_LINK_CONNECTED && uv_read_stop(s) == 0)
            link->read_paused = true;
        return;
    }
    if (nread == 0)
        return;
    log_loss(link, "lost the connection to",
             nread == UV_EOF ? "closed by the robot" : uv_strerror((int)nread));
    link->last_error = (int)nread;
    drop_connection(link);
}

/* Bytes waiting in the socket, 0 when unknown. */
static size_t bytes_waiting(struct robot_link *link)
{
    int fd = -1, waiting = 0;
    if (uv_fileno((uv_handle_t *)&link->tcp, &fd) != 0 || ioctl(fd, FIONREAD, &waiting) != 0)
        return 0;
    return waiting > 0 ? (size_t)waiting : 0;
}

/*
 * The loop's check phase, after it served every socket ready this turn:
 * the held object is handed over, unless reading paused with a newer whole
 * object possibly waiting (then it waits for that one, a bounded number of
 * turns, so that a stream faster than the parse still gets parsed).
 */
static void on_check(uv_check_t *c)
{
    struct robot_link *link = c->data;
    bool resume = link->read_paused;

    link->read_paused = false;
    if (link->holding && resume && link->held_turns < ROBOT_LINK_HOLD_TURNS &&
        bytes_waiting(link) >= link->held_size) {
        link->held_turns++;
    } else if (link->holding) {
        link->holding = false;
        uv_check_stop(c);
        deliver(link, link->held, link->held_size);
    } else {
        uv_check_stop(c);
    }
    if (resume && link->state == ROBOT_LINK_CONNECTED && link->tcp_open &&
        !uv_is_closing((uv_handle_t *)&link->tcp) &&
        uv_read_start((uv_stream_t *)&link->tcp, on_alloc, on_read) != 0)
        robot_link_restart(link, "cannot read again after a pause");
}

static void on_connected(uv_connect_t *req, int status)
{
    struct robot_link *link = req->data;
    int rc;

    uv_timer_stop(&link->timer);
    if (status == UV_ECANCELED)
        return; /* closed under us: on_tcp_closed takes over */
    if (status < 0) {
        log_failure(link, status, "cannot connect to");
        drop_connection(link);
        return;
    }
    rc = uv_read_start((uv_stream_t *)&link->tcp, on_alloc, on_read);
    if (rc < 0) {
        log_failure(link, rc, "cannot read from");
        drop_connection(link);
        return;
    }
    uv_tcp_nodelay(&link->tcp, 1);
    tune_socket(link);
    if (!link->cfg.tls) {
        link_established(link);
        return;
    }
    /* The handshake gets its own connect_timeout_ms. */
    link->tls_conn = tls_conn_new(link->cfg.tls, link->host);
    if (!link->tls_conn) {
        log_failure(link, UV_ENOMEM, "cannot start TLS with");
        drop_connection(link);
        return;
    }
    uv_timer_start(&link->timer, on_connect_timeout, link->cfg.connect_timeout_ms, 0);
    continue_handshake(link);
}

/* Connected (and, with TLS, the controller authenticated): ready to use. */
static void link_established(struct robot_link *link)
{
    link->connections++;
    link->last_error = 0;
    link->last_object_ms = uv_now(link->loop);
    link->watchdog_waited = false;
    link->objects_on_connection = 0;
    if (link->unstable) {
        link->quiet_reconnects++;
        log_debug("%s link: connected to %s:%u", link->cfg.name, link->host,
                  link->cfg.port);
    } else {
        log_notice("%s link: connected to %s:%u", link->cfg.name, link->host,
                   link->cfg.port);
    }
    set_state(link, ROBOT_LINK_CONNECTED);
    if (link->cfg.silence_timeout_ms)
        uv_timer_start(&link->watchdog, on_watchdog, link->cfg.silence_timeout_ms,
                       0);
}

static void on_connect_timeout(uv_timer_t *t)
{
    struct robot_link *link = t->data;
    if (link->tls_conn)
        log_tls_failure(link, TLS_FAIL_TIMEOUT, "no complete handshake within "
                                                "connect_timeout_ms");
    else
        log_failure(link, UV_ETIMEDOUT, "cannot connect to");
    /* Closing the handle cancels the pending connect. */
    drop_connection(link);
}

static void on_resolved(uv_getaddrinfo_t *req, int status, struct addrinfo *res)
{
    struct robot_link *link = req->data;
    int rc;

    link->resolving = false;
    if (link->stopping) {
        uv_freeaddrinfo(res);
        link->open_handles--;
        if (link->open_handles == 0 && link->close_cb)
            link->close_cb(link);
        return;
    }
    link->open_handles--;
    if (status < 0) {
        log_failure(link, status, "cannot resolve");
        uv_freeaddrinfo(res);
        schedule_retry(link);
        return;
    }
    uv_tcp_init(link->loop, &link->tcp);
    link->tcp.data = link;
    link->tcp_open = true;
    link->open_handles++;
    link->connect_req.data = link;
    rc = uv_tcp_connect(&link->connect_req, &link->tcp, res->ai_addr, on_connected);
    uv_freeaddrinfo(res);
    if (rc < 0) {
        log_failure(link, rc, "cannot connect to");
        drop_connection(link);
        return;
    }
    uv_timer_start(&link->timer, on_connect_timeout, link->cfg.connect_timeout_ms, 0);
}

static void start_connect(struct robot_link *link)
{
    struct addrinfo hints;
    char port[8];
    int rc;

    if (link->stopping || link->tcp_open || link->resolving)
        return;
    set_state(link, ROBOT_LINK_CONNECTING);
    memset(&hints, 0, sizeof(hints));
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    snprintf(port, sizeof(port), "%u", link->cfg.port);
    link->resolver.data = link;
    rc = uv_getaddrinfo(link->loop, &link->resolver, on_resolved, link->host, port,
                        &hints);
    if (rc < 0) {
        log_failure(link, rc, "cannot resolve");
        set_state(link, ROBOT_LINK_DISCONNECTED);
        schedule_retry(link);
        return;
    }
    link->resolving = true;
    link->open_handles++;
}

int robot_link_start(struct robot_link *link)
{
    log_info("%s link: connecting to %s:%u", link->cfg.name, link->host,
             link->cfg.port);
    start_connect(link);
    return 0;
}

struct send_req {
    uv_write_t req;
    char data[];
};

static void on_written(uv_write_t *req, int status)
{
    (void)status; /* a failed write shows up as a read error too */
    free(req);
}

/*
 * Sends bytes as they go on the wire (ciphertext with TLS): written at
 * once when nothing waits before them, as nearly always (no copy, and no
 * write request whose completion costs libuv an epoll_ctl); the rest, or
 * all of it after an error, queued in a copy.
 */
static int write_raw(struct robot_link *link, const void *data, size_t size)
{
    struct send_req *sr;
    uv_buf_t buf = uv_buf_init((char *)data, (unsigned)size);
    int rc = uv_try_write((uv_stream_t *)&link->tcp, &buf, 1);

    if (rc > 0) {
        if ((size_t)rc == size)
            return 0;
        data = (const char *)data + rc;
        size -= (size_t)rc;
    }
    sr = malloc(sizeof(*sr) + size);
    if (!sr)
        return -ENOMEM;
    memcpy(sr->data, data, size);
    buf = uv_buf_init(sr->data, (unsigned)size);
    rc = uv_write(&sr->req, (uv_stream_t *)&link->tcp, &buf, 1, on_written);
    if (rc < 0)
        free(sr);
    return rc;
}

int robot_link_send(struct robot_link *link, const char *data, size_t size)
{
    if (link->state != ROBOT_LINK_CONNECTED)
        return -ENOTCONN;
    /* A robot that does not read must not make the gateway queue without
     * bound: past the limit, sending fails and the caller says so. */
    if (uv_stream_get_write_queue_size((uv_stream_t *)&link->tcp) > ROBOT_LINK_MAX_QUEUED)
        return -ENOBUFS;
    if (!link->tls_conn)
        return write_raw(link, data, size);
    if (tls_conn_write(link->tls_conn, data, size) != 0)
        return -EPROTO;
    return flush_tls(link);
}

static void on_timer_closed(uv_handle_t *h)
{
    struct robot_link *link = h->data;
    link->open_handles--;
    if (link->open_handles == 0 && link->close_cb)
        link->close_cb(link);
}

/* The held copy goes last: a callback that closed the link may still
 * read the object it was handed. */
static void on_check_closed(uv_handle_t *h)
{
    struct robot_link *link = h->data;
    free(link->held);
    link->held = NULL;
    on_timer_closed(h);
}

void robot_link_close(struct robot_link *link,
                      void (*cb)(struct robot_link *link))
{
    link->stopping = true;
    link->close_cb = cb;
    set_state(link, ROBOT_LINK_DISCONNECTED);
    framer_free(&link->framer);
    tls_conn_free(link->tls_conn);
    link->tls_conn = NULL;
    link->tls_ready = false;
    tls_context_unref(link->cfg.tls);
    link->cfg.tls = NULL;
    uv_close((uv_handle_t *)&link->timer, on_timer_closed);
    uv_close((uv_handle_t *)&link->watchdog, on_timer_closed);
    link->holding = false;
    uv_close((uv_handle_t *)&link->check, on_check_closed);
    if (link->tcp_open && !uv_is_closing((uv_handle_t *)&link->tcp))
        uv_close((uv_handle_t *)&link->tcp, on_tcp_closed);
    if (link->resolving)
        uv_cancel((uv_req_t *)&link->resolver);
}
