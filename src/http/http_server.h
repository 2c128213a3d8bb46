/* SPDX-License-Identifier: MIT */
/*
 * http_server.h - a small read-only HTTP server on the gateway's libuv loop.
 *
 * The HTTP protocol is libmicrohttpd's (Debian's libmicrohttpd12): no
 * internal thread, its epoll descriptor watched by a uv_poll_t and its
 * timeouts by a uv_timer_t, MHD_run() after each event. MHD_run() never
 * blocks, so a request is served in the same turn of the loop as a Modbus
 * request and never delays one by more than the time to build the answer.
 *
 * What any client may do is bounded here, whatever the handler does:
 * - GET and HEAD only; any other method gets 405 with "Allow: GET, HEAD";
 *   a request body (Content-Length other than 0, or Transfer-Encoding)
 *   gets 413 and the connection closed, never read;
 * - the request line and headers at most HTTP_MAX_HEAD_BYTES (431 past it;
 *   libmicrohttpd answers 431 itself once its buffer is full, or 414 when
 *   the request line alone fills it);
 * - at most HTTP_MAX_CONNECTIONS at once: at the limit, a new connection
 *   takes the place of the one that has waited longest for a request head
 *   if that is HTTP_EVICT_IDLE_MS or more, else it is closed at once;
 * - a connection silent for HTTP_IDLE_TIMEOUT_S is closed, and so is one
 *   that has not sent a whole request head within HTTP_HEAD_DEADLINE_MS of
 *   connecting or of its last response (slowloris), or that has not read
 *   its response within HTTP_RESPONSE_DEADLINE_MS (a slow reader);
 * - a bind address that is not loopback logs one warning at start; on
 *   loopback, a Host header that is neither an address nor localhost gets
 *   403 (a page that rebound its name to 127.0.0.1, in a browser on the
 *   gateway's host, reads nothing).
 *
 * Life cycle as libuv handles: http_server_start(), http_server_close(cb);
 * the struct is the caller's until cb runs.
 */
#ifndef JAKAGW_HTTP_SERVER_H
#define JAKAGW_HTTP_SERVER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <uv.h>

#include "log.h"

#define HTTP_MAX_HEAD_BYTES 8192
#define HTTP_MAX_CONNECTIONS 32
#define HTTP_EVICT_IDLE_MS 100
#define HTTP_IDLE_TIMEOUT_S 10
#define HTTP_HEAD_DEADLINE_MS 10000
#define HTTP_RESPONSE_DEADLINE_MS 30000
/* The most of the loop's time HTTP takes when clients ask back to back
 * (http_server.c, rest_after). */
#define HTTP_LOOP_PERCENT 20
#define HTTP_REST_AFTER_US 500

struct http_request {
    const char *path;  /* without the query */
    void *connection;  /* for http_request_arg */
};

/* The value of query argument 'name' ("?name=value"), or NULL. */
const char *http_request_arg(const struct http_request *req, const char *name);

struct http_response {
    unsigned status;          /* 200, 404... */
    const char *content_type; /* a static string */
    char *body;               /* malloc()ed, taken by the server; may be NULL */
    size_t size;
    /* A Content-Security-Policy header, or NULL. */
    const char *security_policy;
};

/*
 * Answers a GET or HEAD of 'req' (the method is checked already). Fills
 * 'resp'; returning with resp->status 0, or a body that could not be
 * allocated, answers 500.
 */
typedef void (*http_handler)(void *user, const struct http_request *req,
                             struct http_response *resp);

struct http_conn;

/*
 * Answers built in one turn of the server (one MHD_run: every connection
 * that is ready, once; nothing else runs on the loop meanwhile), kept for
 * the other requests of that turn: thirty clients pipelining
 * /status.json?registers=1 cost one rendering a turn, not thirty, so a
 * turn stays short whatever the clients do.
 */
#define HTTP_TURN_KEPT 4

struct http_turn_entry {
    const char *key; /* a static string */
    char *body;
    size_t size;
    unsigned status;
    const char *content_type;
    const char *security_policy;
};

struct http_server {
    uv_loop_t *loop;
    struct MHD_Daemon *daemon;
    int listen_fd;
    uv_poll_t listener; /* accepts: over the limit, closed at once */
    uv_poll_t poll;   /* libmicrohttpd's epoll descriptor */
    bool poll_open;
    bool listener_open;
    uv_timer_t timer; /* its next timeout */
    uv_timer_t sweep; /* the head and response deadlines */
    http_handler handler;
    void *user;
    struct http_conn *conns; /* every open connection */
    unsigned conn_count;
    unsigned evicting;       /* of them, shut down to make room, not closed yet */
    uint64_t requests;       /* answered, any status */
    uint64_t closed_slow;    /* closed by a deadline */
    uint64_t refused;        /* closed over the connection limit: new, or idlest */
    uint64_t rests;          /* turns long enough to rest after (HTTP_LOOP_PERCENT) */
    bool resting;
    struct http_turn_entry turn[HTTP_TURN_KEPT];
    unsigned turn_count;
    struct log_ratelimit log_limit;
    int open_handles;
    bool running;
    bool loopback; /* bound to loopback: Host names checked (DNS rebinding) */
    void (*close_cb)(struct http_server *srv);
};

/*
 * Listens on bind:port (a literal IPv4 or IPv6 address). Returns 0, or a
 * negative errno having logged why; call http_server_close() either way.
 */
int http_server_start(uv_loop_t *loop, struct http_server *srv, const char *bind,
                      uint16_t port, http_handler handler, void *user);

/*
 * The answer kept as 'key' in this turn, copied into 'resp' (true), or
 * false. A handler whose answer depends only on the gateway's state (not
 * on the request beyond its path and 'key') looks here first and keeps
 * what it built with http_turn_keep().
 */
bool http_turn_cached(struct http_server *srv, const char *key, struct http_response *resp);
void http_turn_keep(struct http_server *srv, const char *key, const struct http_response *resp);

/* Closes the listener and every connection; 'cb' runs when all are closed. */
void http_server_close(struct http_server *srv, void (*cb)(struct http_server *srv));

#endif
