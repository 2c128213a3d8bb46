/* SPDX-License-Identifier: MIT */
/* http_server.c - see http_server.h. */
#define _GNU_SOURCE /* accept4 */
#include "http_server.h"

#include "log.h"

#include <arpa/inet.h>
#include <errno.h>
#include <microhttpd.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <unistd.h>

#ifndef MHD_HTTP_CONTENT_TOO_LARGE
#define MHD_HTTP_CONTENT_TOO_LARGE 413
#endif

/* One connection, from libmicrohttpd's connect notice to its close notice. */
struct http_conn {
    struct http_conn *prev, *next;
    int fd;
    uint64_t waiting_since_ms; /* for a head: connect or last response */
    uint64_t answering_since_ms; /* 0: no response under way */
    bool cut;                  /* shut down by a deadline already */
    bool evicted;              /* shut down to make room (make_room) */
};

/* Each request's own state (libmicrohttpd's per-request pointer). */
static char request_accepted, request_refused;

static void schedule(struct http_server *srv);

/* Forgets the bodies kept for the turn that is over. */
static void turn_clear(struct http_server *srv)
{
    for (unsigned i = 0; i < srv->turn_count; i++)
        free(srv->turn[i].body);
    srv->turn_count = 0;
}

static void on_rest_over(uv_timer_t *t);

/*
 * After a turn that took 'spent_ns', HTTP rests: nothing of it runs for
 * (100 - HTTP_LOOP_PERCENT) / HTTP_LOOP_PERCENT times as long, so that
 * however many clients ask back to back, HTTP has at most that share of
 * the loop and Modbus requests wait for one short turn at most. A turn
 * shorter than HTTP_REST_AFTER_US (one request, even the registers
 * document) rests not at all: a lone client is never slowed.
 */
static void rest_after(struct http_server *srv, uint64_t spent_ns)
{
    uint64_t rest_ms = spent_ns * (100 - HTTP_LOOP_PERCENT) / HTTP_LOOP_PERCENT / 1000000;

    if (spent_ns < HTTP_REST_AFTER_US * 1000 || rest_ms == 0 || !srv->running)
        return;
    srv->resting = true;
    srv->rests++;
    uv_poll_stop(&srv->poll);
    uv_poll_stop(&srv->listener);
    uv_timer_start(&srv->timer, on_rest_over, rest_ms, 0);
}

/* One turn of libmicrohttpd: every connection ready, once. */
static void run(struct http_server *srv)
{
    uint64_t t0 = uv_hrtime();
    MHD_run(srv->daemon);
    turn_clear(srv);
    rest_after(srv, uv_hrtime() - t0);
}

bool http_turn_cached(struct http_server *srv, const char *key, struct http_response *resp)
{
    for (unsigned i = 0; i < srv->turn_count; i++) {
        const struct http_turn_entry *e = &srv->turn[i];
        if (strcmp(e->key, key) != 0)
            continue;
        resp->status = e->status;
        resp->content_type = e->content_type;
        resp->security_policy = e->security_policy;
        resp->size = e->size;
        resp->body = malloc(e->size ? e->size : 1);
        if (resp->body)
            memcpy(resp->body, e->body, e->size);
        return true;
    }
    return false;
}

void http_turn_keep(struct http_server *srv, const char *key, const struct http_response *resp)
{
    if (!resp->body || resp->status == 0 || srv->turn_count == HTTP_TURN_KEPT)
        return;
    struct http_turn_entry *e = &srv->turn[srv->turn_count];
    e->body = malloc(resp->size ? resp->size : 1);
    if (!e->body)
        return;
    memcpy(e->body, resp->body, resp->size);
    e->key = key;
    e->size = resp->size;
    e->status = resp->status;
    e->content_type = resp->content_type;
    e->security_policy = resp->security_policy;
    srv->turn_count++;
}

static void on_mhd_log(void *cls, const char *fmt, va_list ap)
{
    struct http_server *srv = cls;
    char line[256];
    uint64_t suppressed;

    vsnprintf(line, sizeof(line), fmt, ap);
    line[strcspn(line, "\n")] = '\0';
    if (log_ratelimit_pass(&srv->log_limit, uv_now(srv->loop), &suppressed))
        log_info("http: %s (%llu more such lines since the last)", line,
                 (unsigned long long)suppressed);
}

static struct http_conn *conn_of(struct MHD_Connection *connection)
{
    const union MHD_ConnectionInfo *info =
        MHD_get_connection_info(connection, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    return info ? info->socket_context : NULL;
}

static void on_connection(void *cls, struct MHD_Connection *connection, void **socket_context,
                          enum MHD_ConnectionNotificationCode code)
{
    struct http_server *srv = cls;
    struct http_conn *c = *socket_context;

    if (code == MHD_CONNECTION_NOTIFY_STARTED) {
        c = calloc(1, sizeof(*c));
        if (!c)
            return; /* served, without the deadlines */
        const union MHD_ConnectionInfo *info =
            MHD_get_connection_info(connection, MHD_CONNECTION_INFO_CONNECTION_FD);
        c->fd = info ? info->connect_fd : -1;
        c->waiting_since_ms = uv_now(srv->loop);
        c->next = srv->conns;
        if (c->next)
            c->next->prev = c;
        srv->conns = c;
        srv->conn_count++;
        *socket_context = c; /* its sweep starts after this MHD_run */
        return;
    }
    if (!c)
        return;
    if (c->prev)
        c->prev->next = c->next;
    else
        srv->conns = c->next;
    if (c->next)
        c->next->prev = c->prev;
    srv->conn_count--;
    if (c->evicted)
        srv->evicting--;
    free(c);
    *socket_context = NULL;
}

static void on_completed(void *cls, struct MHD_Connection *connection, void **con_cls,
                         enum MHD_RequestTerminationCode toe)
{
    struct http_server *srv = cls;
    struct http_conn *c = conn_of(connection);

    (void)toe;
    *con_cls = NULL;
    if (c) {
        c->answering_since_ms = 0;
        c->waiting_since_ms = uv_now(srv->loop);
    }
}

/*
 * The deadlines libmicrohttpd does not keep: a whole head within
 * HTTP_HEAD_DEADLINE_MS, a response read within HTTP_RESPONSE_DEADLINE_MS.
 * A connection past one is shut down, not closed: the descriptor stays
 * libmicrohttpd's, which sees the end of the stream and closes it itself.
 */
static void on_sweep(uv_timer_t *t)
{
    struct http_server *srv = t->data;
    uint64_t now = uv_now(srv->loop);
    bool cut = false;

    for (struct http_conn *c = srv->conns; c; c = c->next) {
        bool late = c->answering_since_ms
                        ? now - c->answering_since_ms >= HTTP_RESPONSE_DEADLINE_MS
                        : now - c->waiting_since_ms >= HTTP_HEAD_DEADLINE_MS;
        if (!late || c->cut || c->fd < 0)
            continue;
        shutdown(c->fd, SHUT_RDWR);
        c->cut = true;
        cut = true;
        srv->closed_slow++;
    }
    if (cut) {
        uint64_t suppressed;
        if (log_ratelimit_pass(&srv->log_limit, now, &suppressed))
            log_info("http: closed connections too slow to send a request or read a "
                     "response (%llu closed so, in all)",
                     (unsigned long long)srv->closed_slow);
        run(srv);
        schedule(srv);
    }
    if (!srv->conns)
        uv_timer_stop(&srv->sweep);
}

struct head_size {
    size_t bytes;
};

/*
 * Is 'host' (a Host header) an address, or localhost, with or without a
 * port? Only such names reach a server bound to loopback honestly (a
 * browser on the same host, an SSH tunnel, a reverse proxy passing the
 * upstream's address); any other is a page that rebound its own name to
 * 127.0.0.1 to read the answers from a browser on the gateway's host.
 */
static bool host_is_local(const char *host)
{
    char name[64];
    const char *port = NULL;
    size_t n;
    struct in6_addr a6;
    struct in_addr a4;

    if (host[0] == '[') {
        const char *end = strchr(host, ']');
        if (!end || (size_t)(end - host - 1) >= sizeof(name))
            return false;
        n = (size_t)(end - host - 1);
        memcpy(name, host + 1, n);
        name[n] = '\0';
        if (end[1] == ':')
            port = end + 2;
        else if (end[1] != '\0')
            return false;
        if (inet_pton(AF_INET6, name, &a6) != 1)
            return false;
    } else {
        const char *colon = strchr(host, ':');
        n = colon ? (size_t)(colon - host) : strlen(host);
        if (n == 0 || n >= sizeof(name))
            return false;
        memcpy(name, host, n);
        name[n] = '\0';
        port = colon ? colon + 1 : NULL;
        if (inet_pton(AF_INET, name, &a4) != 1 && strcasecmp(name, "localhost") != 0)
            return false;
    }
    if (port) {
        if (!*port || strlen(port) > 5)
            return false;
        for (const char *p = port; *p; p++)
            if (*p < '0' || *p > '9')
                return false;
    }
    return true;
}

static enum MHD_Result add_header(void *cls, enum MHD_ValueKind kind, const char *key,
                                  const char *value)
{
    struct head_size *h = cls;
    (void)kind;
    h->bytes += strlen(key) + 2 + (value ? strlen(value) : 0) + 2;
    return MHD_YES;
}

static enum MHD_Result queue(struct MHD_Connection *connection, unsigned status,
                             const char *content_type, char *body, size_t size,
                             const char *security_policy, const char *allow)
{
    struct MHD_Response *r =
        MHD_create_response_from_buffer(size, body ? body : (char *)"",
                                        body ? MHD_RESPMEM_MUST_FREE : MHD_RESPMEM_PERSISTENT);
    if (!r) {
        free(body);
        return MHD_NO;
    }
    MHD_add_response_header(r, "Content-Type", content_type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
    MHD_add_response_header(r, "Referrer-Policy", "no-referrer");
    MHD_add_response_header(r, "X-Frame-Options", "DENY");
    if (security_policy)
        MHD_add_response_header(r, "Content-Security-Policy", security_policy);
    if (allow)
        MHD_add_response_header(r, "Allow", allow);
    enum MHD_Result ret = MHD_queue_response(connection, status, r);
    MHD_destroy_response(r);
    return ret;
}

static enum MHD_Result queue_text(struct MHD_Connection *connection, unsigned status,
                                  const char *text, const char *allow)
{
    char *body = strdup(text);
    return queue(connection, status, "text/plain; charset=utf-8", body, body ? strlen(body) : 0,
                 NULL, allow);
}

const char *http_request_arg(const struct http_request *req, const char *name)
{
    return MHD_lookup_connection_value(req->connection, MHD_GET_ARGUMENT_KIND, name);
}

/*
 * libmicrohttpd calls this once the head has arrived, then for each piece
 * of a body, then once more with none. A refusal is queued at once (the
 * connection then closes); an answer is queued on the last call: queued
 * earlier, libmicrohttpd cannot know the request is over and closes the
 * connection after it, which would cost every scrape a new connection.
 */
static enum MHD_Result on_request(void *cls, struct MHD_Connection *connection,
                                  const char *url, const char *method, const char *version,
                                  const char *upload_data, size_t *upload_data_size,
                                  void **con_cls)
{
    struct http_server *srv = cls;

    (void)upload_data;
    if (*con_cls == NULL) {
        struct http_conn *c = conn_of(connection);
        struct head_size head = {strlen(method) + 1 + strlen(url) + 1 + strlen(version) + 2};
        if (c)
            c->answering_since_ms = uv_now(srv->loop);
        srv->requests++;
        *con_cls = &request_refused;
        MHD_get_connection_values(connection, MHD_HEADER_KIND, add_header, &head);
        if (head.bytes > HTTP_MAX_HEAD_BYTES)
            return queue_text(connection, MHD_HTTP_REQUEST_HEADER_FIELDS_TOO_LARGE,
                              "request line and headers larger than 8 KiB\n", NULL);
        if (strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0)
            return queue_text(connection, MHD_HTTP_METHOD_NOT_ALLOWED,
                              "read-only: GET and HEAD only\n", "GET, HEAD");
        const char *host = MHD_lookup_connection_value(connection, MHD_HEADER_KIND, "Host");
        if (srv->loopback && host && !host_is_local(host))
            return queue_text(connection, MHD_HTTP_FORBIDDEN,
                              "bound to loopback: Host must be an address or localhost\n",
                              NULL);
        /* A body would be read, and dropped, for as long as it is sent:
         * refused, the connection closed. */
        const char *length =
            MHD_lookup_connection_value(connection, MHD_HEADER_KIND, "Content-Length");
        if ((length && strcmp(length, "0") != 0) ||
            MHD_lookup_connection_value(connection, MHD_HEADER_KIND, "Transfer-Encoding"))
            return queue_text(connection, MHD_HTTP_CONTENT_TOO_LARGE,
                              "a request body is not accepted\n", NULL);
        *con_cls = &request_accepted;
        return MHD_YES;
    }
    if (*upload_data_size != 0 || *con_cls == &request_refused) {
        *upload_data_size = 0; /* a body is never read: dropped */
        return MHD_YES;
    }
    struct http_request req = {.path = url, .connection = connection};
    struct http_response resp = {0};
    srv->handler(srv->user, &req, &resp);
    if (resp.status == 0 || (resp.size > 0 && !resp.body)) {
        free(resp.body);
        return queue_text(connection, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory\n", NULL);
    }
    return queue(connection, resp.status, resp.content_type, resp.body, resp.size,
                 resp.security_policy, NULL);
}

static void on_timer(uv_timer_t *t)
{
    struct http_server *srv = t->data;
    run(srv);
    schedule(srv);
}

static void on_poll(uv_poll_t *p, int status, int events);
static void on_listener(uv_poll_t *p, int status, int events);

/*
 * The rest is over: the polls watch again, and what waited runs, new
 * connections first. Accepted here, not left to the listener's poll: a
 * turn long enough to rest again stops that poll before the loop ever
 * polls it, and with clients asking back to back every turn is, so a
 * scraper's new connection waited in the backlog for seconds.
 */
static void on_rest_over(uv_timer_t *t)
{
    struct http_server *srv = t->data;

    srv->resting = false;
    if (!srv->running)
        return;
    uv_poll_start(&srv->poll, UV_READABLE, on_poll);
    uv_poll_start(&srv->listener, UV_READABLE, on_listener);
    on_listener(&srv->listener, 0, UV_READABLE); /* accepts, then runs a turn */
}

/* libmicrohttpd's next timeout, as the timer's; none: stopped. */
static void schedule(struct http_server *srv)
{
    MHD_UNSIGNED_LONG_LONG ms;

    if (!srv->running || srv->resting)
        return; /* the rest's timer runs the next turn */
    /* Never 0: libuv before 1.45 runs a timer started at 0 from its own
     * callback again in the same pass over the timers, without polling in
     * between, and libmicrohttpd says 0 for as long as a connection has
     * work left (pipelined requests, a long answer): HTTP clients kept the
     * loop in that pass, and Modbus unanswered, for as long as they sent.
     * 1 ms lets every other handle have its turn first. */
    if (MHD_get_timeout(srv->daemon, &ms) == MHD_YES)
        uv_timer_start(&srv->timer, on_timer, ms ? ms : 1, 0);
    else
        uv_timer_stop(&srv->timer);
    if (srv->conns && !uv_is_active((uv_handle_t *)&srv->sweep))
        uv_timer_start(&srv->sweep, on_sweep, 1000, 1000);
}

static void on_poll(uv_poll_t *p, int status, int events)
{
    struct http_server *srv = p->data;
    (void)status, (void)events;
    run(srv);
    schedule(srv);
}

/*
 * New connections: accepted here, not by libmicrohttpd, so that one over
 * the limit is closed at once instead of waiting in the kernel's backlog
 * (where a flood of idle connections would hold the page's visitors for
 * as long as it lasts). At most 64 per turn of the loop.
 */
/*
 * At the limit, a new connection takes the place of the one that has
 * waited longest for a request head, if it has waited HTTP_EVICT_IDLE_MS:
 * otherwise a local process holding the limit's worth of idle connections
 * (and re-opening each one the head deadline closes) locked every scraper
 * out, and Prometheus counted a healthy gateway down. A scraper's own
 * connection sends its request at once and is read in the turn that
 * accepts it, so it is never the idlest for that long. The one closed is
 * counted as refused. True when there is room (once it is closed).
 */
static bool make_room(struct http_server *srv)
{
    uint64_t now = uv_now(srv->loop);
    struct http_conn *idlest = NULL;

    for (struct http_conn *c = srv->conns; c; c = c->next)
        if (!c->cut && c->fd >= 0 && !c->answering_since_ms &&
            now - c->waiting_since_ms >= HTTP_EVICT_IDLE_MS &&
            (!idlest || c->waiting_since_ms < idlest->waiting_since_ms))
            idlest = c;
    if (!idlest)
        return false;
    /* libmicrohttpd closes it (and on_connection counts it out) in its
     * next run, at the end of this accept (its own limit leaves room). */
    shutdown(idlest->fd, SHUT_RDWR);
    idlest->cut = true;
    idlest->evicted = true;
    srv->evicting++;
    srv->refused++;
    return true;
}

static void on_listener(uv_poll_t *p, int status, int events)
{
    struct http_server *srv = p->data;
    (void)status, (void)events;

    for (int i = 0; i < 64; i++) {
        struct sockaddr_storage peer;
        socklen_t len = sizeof(peer);
        int fd = accept4(srv->listen_fd, (struct sockaddr *)&peer, &len,
                         SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0)
            break; /* EAGAIN, or an error the next accept reports again */
        if (srv->conn_count - srv->evicting >= HTTP_MAX_CONNECTIONS && !make_room(srv)) {
            close(fd);
            srv->refused++;
            continue;
        }
        /* Closes the descriptor itself when it cannot take it. */
        MHD_add_connection(srv->daemon, fd, (struct sockaddr *)&peer, len);
    }
    run(srv);
    schedule(srv);
}

static int listen_on(struct http_server *srv, const struct sockaddr *addr, socklen_t len)
{
    int one = 1;
    int fd = socket(addr->sa_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -errno;
    if (setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) != 0 ||
        (addr->sa_family == AF_INET6 &&
         setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &one, sizeof(one)) != 0) ||
        bind(fd, addr, len) != 0 || listen(fd, 64) != 0) {
        int rc = -errno;
        close(fd);
        return rc;
    }
    srv->listen_fd = fd;
    return 0;
}

static bool is_loopback(const struct sockaddr *sa)
{
    if (sa->sa_family == AF_INET)
        return (ntohl(((const struct sockaddr_in *)sa)->sin_addr.s_addr) >> 24) == 127;
    const struct in6_addr *a = &((const struct sockaddr_in6 *)sa)->sin6_addr;
    return IN6_IS_ADDR_LOOPBACK(a) ||
           (IN6_IS_ADDR_V4MAPPED(a) && a->s6_addr[12] == 127);
}

int http_server_start(uv_loop_t *loop, struct http_server *srv, const char *bind,
                      uint16_t port, http_handler handler, void *user)
{
    struct sockaddr_storage addr;
    unsigned flags = MHD_USE_EPOLL | MHD_USE_ERROR_LOG | MHD_USE_NO_LISTEN_SOCKET;
    bool v6 = false;
    int rc;

    memset(srv, 0, sizeof(*srv));
    srv->loop = loop;
    srv->handler = handler;
    srv->user = user;
    srv->log_limit.interval_ms = 5000;
    srv->listen_fd = -1;
    if (uv_ip4_addr(bind, port, (struct sockaddr_in *)&addr) != 0) {
        if (uv_ip6_addr(bind, port, (struct sockaddr_in6 *)&addr) != 0) {
            log_err("http: bind %s is not an IP address", bind);
            return -EINVAL;
        }
        v6 = true;
    }
    uv_timer_init(loop, &srv->timer);
    uv_timer_init(loop, &srv->sweep);
    srv->timer.data = srv->sweep.data = srv;
    srv->open_handles = 2;
    srv->daemon = MHD_start_daemon(
        flags, 0, NULL, NULL, on_request, srv,
        MHD_OPTION_EXTERNAL_LOGGER, on_mhd_log, srv,
        /* Room for the ones make_room() shut down until they close. */
        MHD_OPTION_CONNECTION_LIMIT, (unsigned)(2 * HTTP_MAX_CONNECTIONS),
        MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)HTTP_IDLE_TIMEOUT_S,
        /* The head and the response's own headers: a head past 8 KiB is
         * refused by the handler; one past the pool, by libmicrohttpd. */
        MHD_OPTION_CONNECTION_MEMORY_LIMIT, (size_t)(2 * HTTP_MAX_HEAD_BYTES + 4096),
        MHD_OPTION_NOTIFY_CONNECTION, on_connection, srv,
        MHD_OPTION_NOTIFY_COMPLETED, on_completed, srv,
        MHD_OPTION_END);
    if (!srv->daemon) {
        log_err("http: libmicrohttpd cannot start");
        return -ENOMEM;
    }
    rc = listen_on(srv, (struct sockaddr *)&addr,
                   v6 ? sizeof(struct sockaddr_in6) : sizeof(struct sockaddr_in));
    if (rc) {
        log_err("http: cannot listen on %s port %u: %s", bind, port, strerror(-rc));
        return rc;
    }
    if (uv_poll_init(loop, &srv->listener, srv->listen_fd) != 0) {
        log_err("http: cannot watch the listening socket");
        return -EIO;
    }
    srv->listener.data = srv;
    srv->listener_open = true;
    srv->open_handles++;
    uv_poll_start(&srv->listener, UV_READABLE, on_listener);
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(srv->daemon, MHD_DAEMON_INFO_EPOLL_FD);
    if (!info || uv_poll_init(loop, &srv->poll, info->epoll_fd) != 0) {
        log_err("http: cannot watch libmicrohttpd's epoll descriptor");
        return -EIO;
    }
    srv->poll.data = srv;
    srv->poll_open = true;
    srv->open_handles++;
    srv->running = true;
    uv_poll_start(&srv->poll, UV_READABLE, on_poll);
    schedule(srv);
    srv->loopback = is_loopback((struct sockaddr *)&addr);
    if (!srv->loopback)
        log_warn("http: listening on %s port %u, not only loopback: the status page and the "
                 "metrics are readable by anyone who can reach it (docs/metrics.md: an SSH "
                 "tunnel or a reverse proxy with TLS)",
                 bind, port);
    else
        log_notice("http: metrics and status page on http://%s%s%s:%u/", v6 ? "[" : "", bind,
                   v6 ? "]" : "", port);
    return 0;
}

static void on_handle_closed(uv_handle_t *h)
{
    struct http_server *srv = h->data;
    if (--srv->open_handles == 0 && srv->close_cb)
        srv->close_cb(srv);
}

void http_server_close(struct http_server *srv, void (*cb)(struct http_server *srv))
{
    srv->close_cb = cb;
    srv->running = false;
    if (srv->open_handles == 0) {
        if (cb)
            cb(srv);
        return;
    }
    /* The polls stop before their descriptors are closed. */
    if (srv->poll_open) {
        uv_poll_stop(&srv->poll);
        uv_close((uv_handle_t *)&srv->poll, on_handle_closed);
    }
    if (srv->listener_open) {
        uv_poll_stop(&srv->listener);
        uv_close((uv_handle_t *)&srv->listener, on_handle_closed);
    }
    if (srv->daemon) {
        MHD_stop_daemon(srv->daemon); /* closes every connection now */
        srv->daemon = NULL;
    }
    turn_clear(srv);
    uv_close((uv_handle_t *)&srv->timer, on_handle_closed);
    uv_close((uv_handle_t *)&srv->sweep, on_handle_closed);
    if (srv->listen_fd >= 0) {
        close(srv->listen_fd);
        srv->listen_fd = -1;
    }
}
