/* SPDX-License-Identifier: MIT */
/*
 * mb_server.h - the Modbus TCP slave.
 *
 * libuv owns every socket. Each connection has its own MBAP framer, so a
 * client that sends half a request and stalls delays nobody else; several
 * requests in one segment are answered one by one, in order. A request is
 * checked completely (mb_request.h) before libmodbus builds the reply with
 * modbus_reply() or modbus_reply_exception(); libmodbus writes that reply
 * into a private socketpair that is drained at once, so libmodbus never
 * touches a client socket and never blocks. modbus_receive() is never used.
 *
 * Connection rules:
 * - a bad MBAP header (protocol id not 0, length outside 2..254) closes the
 *   connection: the stream can no longer be trusted to be framed;
 * - a function code of 128-255 closes the connection: the Modbus
 *   specification reserves those codes for exception responses, so no
 *   exception reply to them exists (see MB_REQUEST_NOT_A_REQUEST); function
 *   code 0 is answered with exception 01 (80 01);
 * - a request must complete within frame_timeout_ms of its first byte; each
 *   connection has its own timer, so the deadline holds to the millisecond;
 * - a connection silent for idle_timeout_ms (0: never) is closed;
 * - at max_clients, a new connection is always admitted and evicts, first,
 *   the oldest connection that has not completed a request, then the
 *   client whose last complete request is the oldest. A burst of silent
 *   connects only displaces itself, never a polling PLC; a PLC reconnecting
 *   after a cable pull displaces its own half-dead previous connection.
 *   Before judging, the server reads what the kernel already holds for
 *   every client: requests that have arrived are answered, and peers that
 *   have closed are let go and do not count;
 * - a client that closes its side (or is closed by these rules) still gets
 *   the replies already built, for up to MB_SERVER_FLUSH_MS; one that does
 *   not read its replies (more than 64 KiB queued) is closed at once;
 * - TCP keepalive probes a connection silent for MB_SERVER_KEEPALIVE_IDLE_S,
 *   every MB_SERVER_KEEPALIVE_INTERVAL_S, MB_SERVER_KEEPALIVE_COUNT times,
 *   and data unacknowledged for MB_SERVER_USER_TIMEOUT_MS ends it: a PLC
 *   pulled off the network without a word frees its connection (and, as
 *   any closed client, what it owned) within about 5 s.
 * Function codes 17 (report server id) and 43/14 (device identification)
 * are answered here, because libmodbus 3.1.6 reports its own name for 17
 * and does not know 43.
 *
 * One server, several transports. How a connection's bytes arrive and
 * leave is a small table of functions (struct mb_transport), as libmodbus
 * keeps its backends: plain TCP (the listener of mb_server_start) and
 * Modbus/TCP Security (mb_tls.h, on a second listener of the same server),
 * and Modbus RTU on a serial line (mb_rtu.h, a client with no socket).
 * Framing, limits, deadlines, eviction, the clients counted and the write
 * checks are the server's, the same for every transport. A transport may
 * hold a new connection back (a TLS handshake): it is then pending, does
 * not count toward max_clients, is never a client the hooks hear of, and
 * is admitted (mb_client_admit) or closed by its transport.
 */
#ifndef JAKAGW_MB_SERVER_H
#define JAKAGW_MB_SERVER_H

#include <stdbool.h>
#include <netinet/in.h>
#include <stdint.h>
#include <uv.h>

#include <modbus.h>

#include "log.h"
#include "regmap.h"

/* How long replies may take to leave once a connection is being closed. */
#define MB_SERVER_FLUSH_MS 5000

/* A silent peer: probed after 2 s, then every second, dropped after 3
 * unanswered probes (5 s); unacknowledged data: dropped after 5 s. */
#define MB_SERVER_KEEPALIVE_IDLE_S 2
#define MB_SERVER_KEEPALIVE_INTERVAL_S 1
#define MB_SERVER_KEEPALIVE_COUNT 3
#define MB_SERVER_USER_TIMEOUT_MS 5000

struct mb_server_config {
    const char *bind;
    uint16_t port;
    unsigned max_clients;
    uint32_t idle_timeout_ms;  /* 0: never */
    uint32_t frame_timeout_ms;
    int unit_id;               /* -1: answer any */
    /*
     * A listening TCP socket to serve instead of binding bind:port, such as
     * the one systemd passes (fd 3 and up); 0: bind and listen here.
     */
    int listen_fd;
    /* No plain Modbus TCP listener ([modbus] enabled = false): only the
     * listeners added with mb_server_listen(). */
    bool no_plain;
};

/* A write request, checked, before anything is applied. */
struct mb_write {
    enum regmap_table table;
    unsigned address;
    unsigned count;
    const uint16_t *values; /* one per bit (0 or 1) or register */
    const char *client;     /* the client's IP address, as text (for logs) */
    const char *peer;       /* address:port, or the line (the audit's client) */
    struct in6_addr client_addr; /* the same, IPv4 mapped (ip_allow.h) */
    uint64_t client_id;     /* unique for each connection */
    /* What the connection may write: a bit per enum regmap_write_class
     * (regmap_write_allowed); REGMAP_RIGHTS_ALL on plain Modbus TCP. */
    uint32_t rights;
    /* Who writes, for the audit trail: the transport's name ("modbus",
     * "mbaps"), and on mbaps the certificate's subject and role ("" none). */
    const char *transport;
    const char *subject;
    const char *role;
};

struct mb_server_hooks {
    /* Before a request is answered: refresh the live gateway values. */
    void (*before_request)(void *user);
    /*
     * Before a write is applied and answered: act on it, and return 0 to
     * let it be applied, or a Modbus exception code to refuse it (nothing
     * of it is applied then).
     */
    int (*on_write)(void *user, const struct mb_write *w);
    /*
     * A write refused before on_write judged it (the map's check: an
     * address or value outside it), with exception 'ex'; w->values is
     * NULL, and w->count 0 when the request is too short to say where.
     */
    void (*on_write_refused)(void *user, const struct mb_write *w, int ex);
    /* After a write was applied to the image. */
    void (*after_write)(void *user, enum regmap_table table, unsigned address,
                        unsigned count);
    /* A client connected (open) or stopped counting; 'clients' now open. */
    void (*on_client)(void *user, uint64_t client_id, bool open, unsigned clients);
    /* Run indicator for function 17: is the robot data live? */
    bool (*is_running)(void *user);
    void *user;
};

/*
 * The requests and exceptions above, broken down: by transport (its
 * stats_slot: 0 plain Modbus TCP, 1 Modbus/TCP Security, 2 the RTU line),
 * function code and
 * exception code. Their sums are the totals; they are cleared with them.
 * The service time of each request counted (from its last byte to its
 * reply queued) goes into a histogram with the upper bounds below.
 */
#define MB_STATS_TRANSPORTS 3
#define MB_STATS_SERVICE_BUCKETS 9
extern const double mb_stats_service_bounds_s[MB_STATS_SERVICE_BUCKETS];

struct mb_server_breakdown {
    uint64_t requests[MB_STATS_TRANSPORTS][128]; /* by function code */
    uint64_t exceptions[MB_STATS_TRANSPORTS][16]; /* by exception code */
    uint64_t service_buckets[MB_STATS_SERVICE_BUCKETS + 1]; /* the last: +Inf */
    double service_seconds; /* their sum */
};

struct mb_server_stats {
    uint64_t requests;
    uint64_t exceptions;
    uint64_t evictions;
    uint64_t bad_frames;
    uint64_t refused_no_memory; /* connections closed for want of memory */
    unsigned clients;
    struct mb_server_breakdown by;
};

struct mb_client;

/*
 * A transport. Every function gets the transport's own state (the 'state'
 * given to mb_server_listen) and the connection. The server calls them
 * from its loop callbacks; a transport calls back into the server only
 * through the mb_client_* functions below. It feeds a connection no more
 * input once mb_client_is_open() says false, and writes to it no more once
 * mb_client_can_send() does (a flushing connection still takes its last
 * words, a TLS close_notify).
 */
struct mb_transport {
    const char *name; /* "modbus", "mbaps", "rtu": for logs and metrics */
    /* Its row in mb_server_breakdown (< MB_STATS_TRANSPORTS). */
    unsigned stats_slot;
    /*
     * A connection was accepted. Returns 0 to have it served at once,
     * MB_TRANSPORT_PENDING to hold it until the transport calls
     * mb_client_admit() (the server closes it when
     * mb_client_set_deadline()'s time passes, calling 'expired' first),
     * or < 0 to close it now (the transport has said why).
     */
    int (*open)(void *state, struct mb_client *c);
    /* Where the next read from the socket goes (libuv's alloc_cb). */
    void (*alloc)(void *state, struct mb_client *c, uv_buf_t *buf);
    /* 'size' bytes arrived at 'data', the buffer 'alloc' gave. */
    void (*input)(void *state, struct mb_client *c, const uint8_t *data, size_t size);
    /* A reply to send. */
    void (*output)(void *state, struct mb_client *c, const uint8_t *data, size_t size);
    /* The server stops reading the connection and flushes it: last words
     * (TLS close_notify) go out through mb_client_send_raw(). */
    void (*finish)(void *state, struct mb_client *c);
    /* A pending connection's deadline passed; it is closed after this. */
    void (*expired)(void *state, struct mb_client *c);
    /* The connection is being closed (it was pending or not). */
    void (*closed)(void *state, struct mb_client *c, bool was_pending);
    /* Its memory goes: free what 'open' made (mb_client_data). */
    void (*free)(void *state, struct mb_client *c);
};

#define MB_TRANSPORT_PENDING 1

/* A listening socket and what its connections go through. */
enum { MB_LISTENER_PLAIN, MB_LISTENER_EXTRA, MB_LISTENER_COUNT };

struct mb_listener {
    uv_tcp_t handle;
    struct mb_server *srv;
    const struct mb_transport *transport; /* NULL: this listener was never made */
    void *state;                          /* the transport's */
    bool listening;
    /* A connection waits on it, unaccepted, for the refusal before it to
     * close (see mb_server.refused). */
    bool refuse_waiting;
};

/* Plain Modbus TCP: the bytes as they are. */
extern const struct mb_transport mb_transport_plain;

struct mb_server {
    uv_loop_t *loop;
    struct mb_server_config cfg;
    char bind[64];
    struct mb_server_hooks hooks;
    struct regmap_image *img;
    /* [MB_LISTENER_PLAIN]: mb_server_start's; [MB_LISTENER_EXTRA]:
     * mb_server_listen's. Both take connections by one path. */
    struct mb_listener listeners[MB_LISTENER_COUNT];
    modbus_t *ctx;
    int pair[2]; /* [0] libmodbus writes replies, [1] we read them */
    /* Doubly linked, newest first: the clients still open or flushing. */
    struct mb_client *clients;
    uint64_t sequence; /* orders accepts and requests, for eviction */
    struct mb_server_stats stats;
    char device_info[64];
    /* Lines a client can trigger, at most one per second per kind. */
    struct log_ratelimit close_log_limit;
    struct log_ratelimit refuse_log_limit;
    bool closing;
    int open_handles;
    void (*close_cb)(struct mb_server *srv);
    /*
     * A connection there is no memory for is accepted on this handle and
     * closed: libuv stops polling a listener whose connection is left
     * unaccepted. One at a time; each listener's 'refuse_waiting' marks
     * that it holds the next.
     */
    uv_tcp_t refused;
    bool refusing;
    /* Allocates a client: calloc, which a test may make fail. */
    void *(*calloc_client)(size_t count, size_t size);
};

/*
 * Starts listening. Returns 0 or a negative errno / libuv error (for
 * example UV_EADDRINUSE), having logged what failed.
 */
int mb_server_start(uv_loop_t *loop, struct mb_server *srv,
                    const struct mb_server_config *cfg, struct regmap_image *img,
                    const struct mb_server_hooks *hooks);

/* The port actually bound (useful with port 0); -1 without a plain listener. */
int mb_server_port(const struct mb_server *srv);

/*
 * Adds a listener whose connections go through 'transport' (with its
 * 'state'): bind:port, or 'listen_fd' (> 0) already listening. One at
 * most. Returns 0 or a negative errno / libuv error, having logged it.
 */
int mb_server_listen(struct mb_server *srv, const char *bind, uint16_t port, int listen_fd,
                     const struct mb_transport *transport, void *state);
/* The port of that listener; -1 if none. */
int mb_server_listen_port(const struct mb_server *srv);

/*
 * Adds a client that has no socket and no listener: a serial line (mb_rtu.h).
 * Its transport puts complete requests in with mb_client_space() and
 * mb_client_received() and gets every reply through its 'output', before
 * mb_client_received() returns. It is admitted at once with 'rights' and
 * is a client like any other (counted, heard of by on_client, answered by
 * the same rules), but never evicted; the server releases it after
 * 'idle_timeout_ms' without a request (0: never), and its transport hears
 * of every close through 'closed'. Returns 0 with *out set, -ESHUTDOWN
 * while the server stops, -ENOMEM, or -ECONNABORTED if it was closed while
 * being admitted.
 */
int mb_server_attach(struct mb_server *srv, const char *peer,
                     const struct mb_transport *transport, void *state, uint32_t rights,
                     uint32_t idle_timeout_ms, struct mb_client **out);

/* For transports: their connection. */
void **mb_client_data(struct mb_client *c);
const char *mb_client_peer(const struct mb_client *c);
uv_loop_t *mb_client_loop(const struct mb_client *c);
bool mb_client_is_open(const struct mb_client *c); /* pending or served */
/*
 * Bytes may still be written to the socket: open, pending, or flushing
 * its last replies (a TLS close_notify goes out then). False once closing.
 */
bool mb_client_can_send(const struct mb_client *c);
/* Bytes have arrived that were not read yet (the kernel holds them). */
bool mb_client_has_input(const struct mb_client *c);
/*
 * A pending connection's reading stops (its transport has enough to work
 * on) and starts again; neither does anything once it is not pending or
 * served. 0, or a negative libuv error (the connection is then closed).
 */
void mb_client_pause_reading(struct mb_client *c);
int mb_client_resume_reading(struct mb_client *c);
/* When the connection was accepted (uv_now). */
uint64_t mb_client_accepted_ms(const struct mb_client *c);
/* Where plaintext goes, and how much room is left there. */
uint8_t *mb_client_space(struct mb_client *c, size_t *room);
/* 'n' bytes of plaintext were put there: frame and answer them. */
void mb_client_received(struct mb_client *c, size_t n);
/* Writes bytes to the socket as they are (queued when it is full). */
void mb_client_send_raw(struct mb_client *c, const uint8_t *data, size_t size);
/* A pending connection is closed this many ms from now unless admitted. */
void mb_client_set_deadline(struct mb_client *c, uint64_t ms);
/* Who the peer is, as its certificate says: subject and role (the audit
 * trail, the status page). Copied; NULL is "". */
void mb_client_set_identity(struct mb_client *c, const char *subject, const char *role);
/* A pending connection becomes a client, with what it may write. */
void mb_client_admit(struct mb_client *c, uint32_t rights);
/* Closes at once ('why' logged, rate-limited; NULL: not logged). */
void mb_client_close(struct mb_client *c, const char *why);
/* The peer has finished (end of stream): replies already built still go. */
void mb_client_release(struct mb_client *c, const char *why);

/* One client being served, as mb_server_foreach_client shows it. */
struct mb_client_info {
    uint64_t id;           /* mb_write.client_id */
    const char *peer;      /* address:port */
    const char *host;      /* address */
    const char *transport; /* "modbus", "mbaps" */
    const char *subject;   /* the certificate's subject; "" none */
    const char *role;      /* its role; "" none */
    uint32_t rights;
    uint64_t requests, exceptions;
    uint64_t accepted_ms;
    uint64_t last_request_ms; /* 0: none yet */
};

/* Calls 'cb' for every client served (not pending, not closing), newest
 * first. 'cb' must not open or close connections. */
void mb_server_foreach_client(const struct mb_server *srv,
                              void (*cb)(void *user, const struct mb_client_info *info),
                              void *user);

/* Closes the listener and every client; 'cb' runs when all are closed. */
void mb_server_close(struct mb_server *srv, void (*cb)(struct mb_server *srv));

/*
 * Stops serving gracefully, for a clean stop: the listener closes (no new
 * connection is accepted), every complete request that has arrived is
 * answered, and each client is closed once its replies are written (at
 * most MB_SERVER_FLUSH_MS later). Reads are answered from the image; writes
 * get exception 06 (server busy) and are not acted on, so that nothing is
 * started on the way out. A request that has not arrived whole is dropped.
 * 'cb' runs when all are closed.
 */
void mb_server_shutdown(struct mb_server *srv, void (*cb)(struct mb_server *srv));

#endif
