/* SPDX-License-Identifier: MIT */
/*
 * robot_link.h - one TCP connection to the robot controller, kept open.
 *
 * A robot link resolves the host, connects (with a timeout), frames what it
 * reads into JSON objects (framer.h) and hands each to a callback. When the
 * connection fails, closes, or stays silent longer than 'silence_timeout_ms'
 * (0: never), it closes and tries again after a delay that doubles from
 * 'reconnect_min_ms' up to 'reconnect_max_ms'; the delay resets once the
 * robot has sent a complete object. Each change of state is logged once:
 * a controller that stays unreachable does not flood the journal.
 *
 * With a TLS context (cfg.tls, tls.h), the link speaks TLS: after the TCP
 * connect it runs the handshake, through the engine's memory BIOs on the
 * same loop, and is CONNECTED only once the controller's certificate has
 * been verified (against the CA, or by its pinned fingerprint). The
 * connect timeout covers connect and handshake together. A handshake that
 * fails is a link fault like a refused connect: logged once per cause with
 * its reason (robot_link.tls_failure holds it for the PLC), retried with
 * the same backoff. What the robot sends is decrypted before the framer
 * sees it, and what the link sends is encrypted: nothing above changes.
 *
 * A connection closed for a fault (an error, silence, a failed handshake,
 * robot_link_restart) is closed abortively, with an RST: nothing still
 * queued in the kernel is delivered after the gateway gave up on it. Both
 * sockets have tuned keepalive and TCP_USER_TIMEOUT (cfg.user_timeout_ms).
 * robot_link_close, a clean stop, closes normally.
 *
 * With cfg.newest_only (the status port: each document is a whole
 * snapshot), a complete object is held, not handed over at once, and
 * handed over from a uv_check handle, after the loop has served every
 * other socket that was ready in the same turn; when a newer object is
 * complete first, the held one is superseded: on_superseded decides
 * whether it must still be handled (it carries a change that the newer
 * one would hide), else it is dropped unhandled. A read that fills the
 * whole buffer (more bytes are waiting) pauses reading until the held
 * object is decided, so a backlog is taken one buffer per loop turn, and
 * a held object is not handed over while a newer whole one may already be
 * waiting in the socket, at most ROBOT_LINK_HOLD_TURNS turns in a row.
 *
 * Life cycle, as libuv handles: robot_link_init(), robot_link_start(),
 * robot_link_close(cb); the memory is the caller's until cb runs.
 * Nothing here blocks: resolving runs on libuv's thread pool.
 */
#ifndef JAKAGW_ROBOT_LINK_H
#define JAKAGW_ROBOT_LINK_H

#include <stdbool.h>
#include <stdint.h>
#include <uv.h>

#include "framer.h"
#include "log.h"
#include "tls.h"

/* TCP keepalive on both robot sockets (see robot_link.c, tune_socket). */
#define ROBOT_LINK_KEEPALIVE_IDLE_S 2
#define ROBOT_LINK_KEEPALIVE_INTERVAL_S 1
#define ROBOT_LINK_KEEPALIVE_COUNT 3

/* Bytes queued to a robot that does not read, before sends fail. */
#define ROBOT_LINK_MAX_QUEUED (64 * 1024)

/* Turns a held object waits for a newer one already in the socket. */
#define ROBOT_LINK_HOLD_TURNS 8

enum robot_link_state {
    ROBOT_LINK_DISCONNECTED = 0,
    ROBOT_LINK_CONNECTING = 1,
    ROBOT_LINK_CONNECTED = 2,
};

struct robot_link;

struct robot_link_callbacks {
    /* One complete JSON object from the robot. */
    void (*on_object)(struct robot_link *link, const char *json, size_t size);
    /* A framing problem (garbage, oversize, cut-short or len mismatch). */
    void (*on_framing_error)(struct robot_link *link, enum framer_event event,
                             size_t size);
    /* The state changed. */
    void (*on_state)(struct robot_link *link, enum robot_link_state state);
    /* cfg.newest_only: a held object a newer one replaced; return true to
     * have it handed to on_object all the same (at once). NULL: dropped. */
    bool (*on_superseded)(struct robot_link *link, const char *json, size_t size);
};

struct robot_link_config {
    const char *name; /* for log lines: "status", "command" */
    const char *host;
    uint16_t port;
    uint32_t connect_timeout_ms;
    uint32_t reconnect_min_ms;
    uint32_t reconnect_max_ms;
    uint32_t silence_timeout_ms;
    /* TCP_USER_TIMEOUT: how long sent data (or a keepalive probe) may stay
     * unacknowledged before the kernel aborts the connection; 0: the
     * kernel's default (about 15 minutes of retransmissions). */
    uint32_t user_timeout_ms;
    size_t max_object;
    /* NULL: plain TCP. Else TLS with this client context, of which the
     * link keeps its own reference (robot_link_set_tls to change it). */
    struct tls_context *tls;
    /* Objects are snapshots: only the newest of several waiting is handed
     * over (see above). */
    bool newest_only;
};

struct robot_link {
    uv_loop_t *loop;
    struct robot_link_config cfg;
    char host[256];
    struct robot_link_callbacks cb;
    void *user;

    enum robot_link_state state;
    uv_tcp_t tcp;
    bool tcp_open;
    uv_timer_t timer;    /* connect timeout, or the wait before retrying */
    uv_timer_t watchdog; /* silence while connected */
    uv_getaddrinfo_t resolver;
    bool resolving;
    uv_connect_t connect_req;
    struct framer framer;
    char read_buf[16384];

    /* TLS (cfg.tls): the connection's engine, and whether its handshake is
     * done; the reason the last handshake failed (TLS_FAIL_NONE once one
     * succeeds), for the PLC. */
    struct tls_conn *tls_conn;
    bool tls_ready;
    enum tls_failure tls_failure;
    char plain_buf[16384];

    uint32_t backoff_ms;
    int last_error; /* the failure last logged, to log each change once */
    bool tune_failure_logged; /* keepalive or TCP_USER_TIMEOUT refused */
    bool stopping;
    int open_handles;
    void (*close_cb)(struct robot_link *link);

    /*
     * Connections that end before the robot sent anything on them make the
     * link unstable: after the first such loss is logged, reconnects and
     * losses are logged at debug level only, until an object arrives.
     */
    bool unstable;
    uint64_t objects_on_connection;
    uint64_t quiet_reconnects; /* while unstable */
    struct log_ratelimit loss_log;
    uint64_t connections; /* successful connects, ever */
    uint64_t last_object_ms;
    bool watchdog_waited; /* gave bytes waiting in the socket one more look */

    /* cfg.newest_only: the object held until the loop's check phase, and
     * whether reading waits for it to be decided. */
    uv_check_t check;
    char *held;
    size_t held_size;
    bool holding;
    bool read_paused;
    unsigned held_turns;
    uint64_t superseded; /* objects dropped unhandled for a newer one */
};

/* Returns 0, or a negative errno (-EINVAL for a bad config, -ENOMEM). */
int robot_link_init(uv_loop_t *loop, struct robot_link *link,
                    const struct robot_link_config *cfg,
                    const struct robot_link_callbacks *cb, void *user);

/* Starts connecting. Returns 0 or a negative errno. */
int robot_link_start(struct robot_link *link);

/*
 * Queues 'size' bytes to the robot. Returns 0, -ENOTCONN when not
 * connected (nothing is queued: the caller decides what that means),
 * -ENOBUFS when more than ROBOT_LINK_MAX_QUEUED bytes wait because the
 * robot does not read, or a negative libuv error.
 */
int robot_link_send(struct robot_link *link, const char *data, size_t size);

/*
 * Connections made from now on use 'ctx' (a reference is taken; NULL: plain
 * TCP); the one open keeps what it has. On reload.
 */
void robot_link_set_tls(struct robot_link *link, struct tls_context *ctx);

/* Closes the connection now, abortively, and reconnects after the backoff
 * delay. */
void robot_link_restart(struct robot_link *link, const char *why);

/* Stops for good; 'cb' runs when every handle is closed. */
void robot_link_close(struct robot_link *link,
                      void (*cb)(struct robot_link *link));

#endif
