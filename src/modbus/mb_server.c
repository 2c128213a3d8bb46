/* SPDX-License-Identifier: MIT */
/* mb_server.c - see mb_server.h. */
#include "mb_server.h"

#include "ip_allow.h"

#include "log.h"
#include "mb_request.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <netinet/tcp.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#define MBAP_SIZE 7
#define MAX_PDU 253
#define MAX_ADU (MBAP_SIZE + MAX_PDU)
#define MAX_QUEUED_REPLY_BYTES (64 * 1024)
/* Reads per drain, so a client that never stops sending cannot hold us. */
#define MAX_DRAIN_READS 16
/* A stop answers everything that has arrived: up to this many reads (about
 * 130 KB) per client, against one that never stops sending. */
#define MAX_SHUTDOWN_READS 256

enum client_state {
    CLIENT_PENDING,  /* held by its transport (a handshake); not counted */
    CLIENT_OPEN,     /* reading requests; counts toward max_clients */
    CLIENT_FLUSHING, /* no more reading; replies still going out */
    CLIENT_CLOSING,  /* uv_close() called */
};

struct mb_client {
    uv_tcp_t tcp;
    /* The one deadline in force: the partial frame's, the idle timeout's,
     * or (flushing) the bound on delivering the last replies. */
    uv_timer_t timer;
    uv_shutdown_t shutdown;
    struct mb_server *srv;
    struct mb_client *prev, *next;
    uint8_t buf[2 * MAX_ADU];
    size_t used;
    uint64_t accepted_ms;
    uint64_t last_activity_ms; /* when bytes last came: the idle timeout */
    uint64_t frame_start_ms;   /* when the first byte of a partial frame came */
    uint64_t last_request_ms;  /* when the last complete request came */
    /* srv->sequence at accept and at the last complete request: the
     * eviction order, exact where milliseconds tie. */
    uint64_t accept_seq;
    uint64_t request_seq;      /* 0: no request completed yet */
    char peer[64];
    char host[48]; /* the peer's address alone */
    struct in6_addr addr; /* the same, for comparing (ip_allow.h) */
    enum client_state state;
    int open_handles;          /* tcp and timer */
    const struct mb_transport *transport;
    void *transport_state;
    void *transport_data;      /* the transport's, per connection */
    uint32_t rights;           /* mb_write.rights */
    bool reading_paused;       /* mb_client_pause_reading */
    uint32_t idle_timeout_ms;  /* 0: never */
    /* No socket (mb_server_attach): bytes come and go through the
     * transport alone, and only 'timer' is a handle. */
    bool no_socket;
    uint64_t requests, exceptions; /* this connection's */
    char subject[128], role[64];   /* mb_client_set_identity */
};

const double mb_stats_service_bounds_s[MB_STATS_SERVICE_BUCKETS] = {
    0.00005, 0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.1};

/* The breakdown's transport index of a connection. */
static unsigned transport_index(const struct mb_client *c)
{
    return c->transport->stats_slot < MB_STATS_TRANSPORTS ? c->transport->stats_slot : 0;
}

static void count_exception(struct mb_client *c, int code)
{
    c->srv->stats.exceptions++;
    c->srv->stats.by.exceptions[transport_index(c)][(unsigned)code & 15]++;
    c->exceptions++;
}

struct reply {
    uv_write_t req;
    size_t size;
    uint8_t data[];
};

/* Logs a client event, rate-limited per kind of event ('limit'). */
static void client_log(struct mb_server *srv, struct log_ratelimit *limit,
                       const char *peer, const char *fmt, const char *why)
{
    uint64_t suppressed;
    if (!log_ratelimit_pass(limit, uv_now(srv->loop), &suppressed))
        return;
    if (suppressed)
        log_warn("modbus: client %s: %s: %s (%llu similar lines suppressed)", peer,
                 fmt, why, (unsigned long long)suppressed);
    else
        log_warn("modbus: client %s: %s: %s", peer, fmt, why);
}

static void maybe_finish_close(struct mb_server *srv)
{
    if (srv->closing && srv->open_handles == 0 && srv->close_cb)
        srv->close_cb(srv);
}

static void on_client_handle_closed(uv_handle_t *h)
{
    struct mb_client *c = h->data;
    struct mb_server *srv = c->srv;

    if (--c->open_handles > 0)
        return;
    if (c->transport->free)
        c->transport->free(c->transport_state, c);
    free(c);
    srv->open_handles--;
    maybe_finish_close(srv);
}

/* Closes at once; replies not yet written are dropped. */
static void client_gone(struct mb_client *c);

static void close_client(struct mb_client *c, const char *why)
{
    struct mb_server *srv = c->srv;

    if (c->state == CLIENT_CLOSING)
        return;
    if (why)
        client_log(srv, &srv->close_log_limit, c->peer, "closing connection", why);
    if (c->prev)
        c->prev->next = c->next;
    else
        srv->clients = c->next;
    if (c->next)
        c->next->prev = c->prev;
    if (c->state == CLIENT_OPEN)
        client_gone(c);
    if (c->transport->closed)
        c->transport->closed(c->transport_state, c, c->state == CLIENT_PENDING);
    c->state = CLIENT_CLOSING;
    if (!c->no_socket)
        uv_close((uv_handle_t *)&c->tcp, on_client_handle_closed);
    uv_close((uv_handle_t *)&c->timer, on_client_handle_closed);
}

/* A client stops counting: it no longer reads requests. */
static void client_gone(struct mb_client *c)
{
    struct mb_server *srv = c->srv;
    srv->stats.clients--;
    if (c->no_socket)
        srv->line_clients--;
    if (srv->hooks.on_client)
        srv->hooks.on_client(srv->hooks.user, c->accept_seq, false, srv->stats.clients);
}

static void on_client_shutdown(uv_shutdown_t *req, int status)
{
    (void)status; /* UV_ECANCELED when closed meanwhile: close_client knows */
    close_client(req->data, NULL);
}

static void on_client_timer(uv_timer_t *t);

/*
 * Stops serving 'c' but delivers the replies already built: the client
 * stops counting toward max_clients at once, reading stops, and the
 * connection closes when its write queue is empty (at most
 * MB_SERVER_FLUSH_MS later). Used for every close but those caused by
 * the write side (a client that does not read, a failed write).
 */
static void release_client(struct mb_client *c, const char *why)
{
    struct mb_server *srv = c->srv;

    if (c->state != CLIENT_OPEN)
        return;
    if (why)
        client_log(srv, &srv->close_log_limit, c->peer, "closing connection", why);
    client_gone(c);
    c->state = CLIENT_FLUSHING;
    c->used = 0;
    if (!c->no_socket)
        uv_read_stop((uv_stream_t *)&c->tcp);
    if (c->transport->finish)
        c->transport->finish(c->transport_state, c);
    if (c->state != CLIENT_FLUSHING)
        return; /* the last words failed: closed */
    if (c->no_socket) {
        close_client(c, NULL); /* its replies went out through the transport */
        return;
    }
    if (uv_stream_get_write_queue_size((uv_stream_t *)&c->tcp) == 0 ||
        uv_shutdown(&c->shutdown, (uv_stream_t *)&c->tcp, on_client_shutdown) < 0) {
        close_client(c, NULL);
        return;
    }
    uv_timer_start(&c->timer, on_client_timer, MB_SERVER_FLUSH_MS, 0);
}

static void on_reply_written(uv_write_t *req, int status)
{
    (void)status; /* a broken connection also fails its next read */
    free(req);
}

/* Queues what the socket did not take at once, in a copy freed when written. */
static void queue_bytes(struct mb_client *c, const uint8_t *data, size_t size)
{
    struct reply *r;
    uv_buf_t buf;

    if (uv_stream_get_write_queue_size((uv_stream_t *)&c->tcp) >
        MAX_QUEUED_REPLY_BYTES) {
        close_client(c, "does not read its replies");
        return;
    }
    r = malloc(sizeof(*r) + size);
    if (!r) {
        close_client(c, "out of memory for a reply");
        return;
    }
    memcpy(r->data, data, size);
    r->size = size;
    buf = uv_buf_init((char *)r->data, (unsigned)size);
    if (uv_write(&r->req, (uv_stream_t *)&c->tcp, &buf, 1, on_reply_written) < 0) {
        free(r);
        close_client(c, "write failed");
    }
}

/*
 * Writes a reply at once when nothing is queued before it, as nearly every
 * reply is: no copy, no allocation, no write callback. The rest (a client
 * slow to read, or an error, which the queued write reports as before) goes
 * through the queue, behind what is already there.
 */
static void send_bytes(struct mb_client *c, const uint8_t *data, size_t size)
{
    uv_buf_t buf = uv_buf_init((char *)data, (unsigned)size);
    int n = uv_try_write((uv_stream_t *)&c->tcp, &buf, 1);

    if (n > 0) {
        data += n;
        size -= (size_t)n;
        if (size == 0)
            return;
    }
    queue_bytes(c, data, size);
}

/* A reply goes out through the connection's transport. */
static void send_reply(struct mb_client *c, const uint8_t *data, size_t size)
{
    c->transport->output(c->transport_state, c, data, size);
}

static void put16(uint8_t *p, unsigned v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)v;
}

/* Sends a PDU we built ourselves, under the request's MBAP header. */
static void send_pdu(struct mb_client *c, const uint8_t *req, const uint8_t *pdu,
                     size_t pdu_size)
{
    uint8_t adu[MAX_ADU];

    memcpy(adu, req, 4); /* transaction and protocol id */
    put16(adu + 4, (unsigned)(pdu_size + 1));
    adu[6] = req[6];
    memcpy(adu + MBAP_SIZE, pdu, pdu_size);
    send_reply(c, adu, MBAP_SIZE + pdu_size);
}

/*
 * Moves the reply libmodbus just wrote into the socketpair to the client.
 * Should libmodbus have produced none, the client still gets an answer:
 * exception 04, built here.
 */
static void forward_libmodbus_reply(struct mb_client *c, const uint8_t *req)
{
    uint8_t rsp[MAX_ADU + 16];
    ssize_t n = recv(c->srv->pair[1], rsp, sizeof(rsp), MSG_DONTWAIT);

    if (n > 0) {
        send_reply(c, rsp, (size_t)n);
        return;
    }
    log_err("modbus: libmodbus produced no reply to function %u (%s); "
            "answering exception 04",
            req[MBAP_SIZE], n < 0 ? strerror(errno) : "empty");
    uint8_t pdu[2] = {(uint8_t)(req[MBAP_SIZE] | 0x80),
                      MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE};
    count_exception(c, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
    send_pdu(c, req, pdu, sizeof(pdu));
}

/*
 * Answers a checked read (functions 1-4) straight from the image. Reads are
 * nearly every request a PLC sends; building them here saves the trip
 * through libmodbus and the socketpair, which cost more than the answer.
 * Returns false for any other function.
 */
static bool answer_read(struct mb_client *c, const uint8_t *req, const uint8_t *pdu)
{
    const modbus_mapping_t *mb = c->srv->img->mb;
    uint8_t rsp[2 + MAX_PDU];
    unsigned address = (unsigned)pdu[1] << 8 | pdu[2];
    unsigned count = (unsigned)pdu[3] << 8 | pdu[4];
    const uint8_t *bits = NULL;
    const uint16_t *regs = NULL;

    switch (pdu[0]) {
    case MODBUS_FC_READ_COILS:
        bits = mb->tab_bits;
        break;
    case MODBUS_FC_READ_DISCRETE_INPUTS:
        bits = mb->tab_input_bits;
        break;
    case MODBUS_FC_READ_HOLDING_REGISTERS:
        regs = mb->tab_registers;
        break;
    case MODBUS_FC_READ_INPUT_REGISTERS:
        regs = mb->tab_input_registers;
        break;
    default:
        return false;
    }
    rsp[0] = pdu[0];
    if (bits) {
        unsigned bytes = (count + 7) / 8;
        rsp[1] = (uint8_t)bytes;
        memset(rsp + 2, 0, bytes);
        for (unsigned i = 0; i < count; i++)
            if (bits[address + i])
                rsp[2 + i / 8] |= (uint8_t)(1u << (i % 8));
        send_pdu(c, req, rsp, 2 + bytes);
    } else {
        rsp[1] = (uint8_t)(2 * count);
        for (unsigned i = 0; i < count; i++)
            put16(rsp + 2 + 2 * i, regs[address + i]);
        send_pdu(c, req, rsp, 2 + 2 * count);
    }
    return true;
}

static const char *exception_name(int code)
{
    switch (code) {
    case MODBUS_EXCEPTION_ILLEGAL_FUNCTION: return "illegal function";
    case MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS: return "illegal data address";
    case MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE: return "illegal data value";
    case MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE: return "server failure";
    case MB_EXCEPTION_GATEWAY_PATH: return "no such unit id";
    case MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY: return "busy: the previous command is pending";
    case MODBUS_EXCEPTION_GATEWAY_TARGET: return "the robot's command link is down";
    default: return "exception";
    }
}

/* Says what a refused request asked for, and why it was refused. */
static void log_refused(struct mb_client *c, const uint8_t *req, size_t size, int code)
{
    char what[160];
    const uint8_t *pdu = req + MBAP_SIZE;
    size_t pdu_size = size - MBAP_SIZE;

    if (pdu_size >= 5)
        snprintf(what, sizeof(what),
                 "unit %u function %u address %u quantity/value %u: exception %02X (%s)",
                 req[6], pdu[0], (unsigned)pdu[1] << 8 | pdu[2],
                 (unsigned)pdu[3] << 8 | pdu[4], (unsigned)code, exception_name(code));
    else
        snprintf(what, sizeof(what), "unit %u function %u, %zu-byte PDU: exception %02X (%s)",
                 req[6], pdu_size ? pdu[0] : 0, pdu_size, (unsigned)code,
                 exception_name(code));
    client_log(c->srv, &c->srv->refuse_log_limit, c->peer, "request refused", what);
}

static void reply_exception(struct mb_client *c, const uint8_t *req, int code)
{
    count_exception(c, code);
    if (modbus_reply_exception(c->srv->ctx, req, (unsigned)code) < 0) {
        /* Build it here rather than leave the client without an answer. */
        uint8_t pdu[2] = {(uint8_t)(req[MBAP_SIZE] | 0x80), (uint8_t)code};
        log_err("modbus: libmodbus cannot build exception %02X: %s", (unsigned)code,
                modbus_strerror(errno));
        send_pdu(c, req, pdu, sizeof(pdu));
        return;
    }
    forward_libmodbus_reply(c, req);
}

static void reply_server_id(struct mb_client *c, const uint8_t *req)
{
    struct mb_server *srv = c->srv;
    uint8_t pdu[3 + sizeof(srv->device_info)];
    size_t len = strlen(srv->device_info);
    bool running = srv->hooks.is_running && srv->hooks.is_running(srv->hooks.user);

    pdu[0] = MODBUS_FC_REPORT_SLAVE_ID;
    pdu[1] = (uint8_t)(len + 2);
    pdu[2] = req[6];                 /* server id: the unit id asked for */
    pdu[3] = running ? 0xFF : 0x00;  /* run indicator: robot data is live */
    memcpy(pdu + 4, srv->device_info, len);
    send_pdu(c, req, pdu, 4 + len);
}

/* Device identification objects (43/14): basic 0-2, regular 3-6, 0x80+. */
static int device_object(const struct mb_server *srv, unsigned id, char *out,
                         size_t size)
{
    switch (id) {
    case 0x00: return snprintf(out, size, "jakagw");
    case 0x01: return snprintf(out, size, "jakagw-modbus");
    case 0x02: return snprintf(out, size, "%s", JAKAGW_VERSION);
    case 0x04: return snprintf(out, size, "JAKA robot Modbus TCP gateway");
    case 0x05: return snprintf(out, size, "jakagw");
    case 0x80:
        return snprintf(out, size, "map %d crc %08X", REGMAP_VERSION,
                        srv->img->map->crc);
    default: return -1;
    }
}

static void reply_device_id(struct mb_client *c, const uint8_t *req)
{
    /* The objects we have, in order; code 1 streams up to 0x02 (basic),
     * code 2 up to 0x7F (regular), code 3 everything (extended). */
    static const uint8_t objects[] = {0x00, 0x01, 0x02, 0x04, 0x05, 0x80};
    static const unsigned stream_last[4] = {0, 0x02, 0x7F, 0xFF};
    const uint8_t *pdu = req + MBAP_SIZE;
    unsigned code = pdu[2], object = pdu[3];
    uint8_t rsp[253];
    size_t n = 7;
    unsigned count = 0;
    char text[64];

    if (code == 4) {
        int len = device_object(c->srv, object, text, sizeof(text));
        if (len < 0) {
            reply_exception(c, req, MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
            return;
        }
        rsp[n++] = (uint8_t)object;
        rsp[n++] = (uint8_t)len;
        memcpy(rsp + n, text, (size_t)len);
        n += (size_t)len;
        count = 1;
    } else {
        /* An unknown start object restarts the stream at object 0. */
        if (object > stream_last[code] ||
            device_object(c->srv, object, text, sizeof(text)) < 0)
            object = 0;
        for (size_t i = 0; i < sizeof(objects); i++) {
            if (objects[i] < object || objects[i] > stream_last[code])
                continue;
            int len = device_object(c->srv, objects[i], text, sizeof(text));
            rsp[n++] = objects[i];
            rsp[n++] = (uint8_t)len;
            memcpy(rsp + n, text, (size_t)len);
            n += (size_t)len;
            count++;
        }
    }
    rsp[0] = MB_FC_READ_DEVICE_ID;
    rsp[1] = MB_MEI_READ_DEVICE_ID;
    rsp[2] = (uint8_t)code;
    rsp[3] = 0x83; /* conformity: extended, stream and individual access */
    rsp[4] = 0x00; /* no more follows: every object fits in one reply */
    rsp[5] = 0x00;
    rsp[6] = (uint8_t)count;
    send_pdu(c, req, rsp, n);
}

/* Tells the owner what a write that was answered changed. */
static void after_write(struct mb_client *c, const uint8_t *pdu, size_t pdu_size)
{
    struct mb_server *srv = c->srv;
    enum regmap_table table;
    unsigned address, count;

    if (mb_request_is_write(pdu[0]) && srv->hooks.after_write &&
        mb_request_write_range(pdu, pdu_size, &table, &address, &count) == 0)
        srv->hooks.after_write(srv->hooks.user, table, address, count);
}

/*
 * Answers a checked and accepted write of one coil or one register (5 and
 * 6), a PLC's command, without libmodbus: the value goes into the image as
 * modbus_reply would put it, and the reply is the request itself (Modbus
 * Application Protocol 1.1b3, 6.5 and 6.6: "the normal response is an echo
 * of the request"). Saves a send and a receive on the socketpair per
 * command. Returns false for any other function.
 */
static bool answer_single_write(struct mb_client *c, const uint8_t *req, size_t size,
                                const struct mb_write *w)
{
    const uint8_t *pdu = req + MBAP_SIZE;

    if ((pdu[0] != MODBUS_FC_WRITE_SINGLE_COIL && pdu[0] != MODBUS_FC_WRITE_SINGLE_REGISTER) ||
        size != MBAP_SIZE + 5 || w->count != 1)
        return false;
    regmap_load(c->srv->img, w->table, w->address, 1, w->values);
    send_reply(c, req, size);
    after_write(c, pdu, size - MBAP_SIZE);
    return true;
}

static void answer_request(struct mb_client *c, const uint8_t *req, size_t size)
{
    struct mb_server *srv = c->srv;
    const uint8_t *pdu = req + MBAP_SIZE;
    size_t pdu_size = size - MBAP_SIZE;
    int ex;

    if (srv->hooks.before_request)
        srv->hooks.before_request(srv->hooks.user);
    ex = mb_request_check(srv->img, pdu, pdu_size);
    if (ex == MB_REQUEST_NOT_A_REQUEST) {
        /* Whatever the unit id: no exception reply to it exists. */
        char why[80];
        snprintf(why, sizeof(why), "function code %u is reserved for exception responses",
                 pdu[0]);
        srv->stats.bad_frames++;
        release_client(c, why);
        return;
    }
    srv->stats.requests++;
    srv->stats.by.requests[transport_index(c)][pdu[0] & 127]++;
    c->requests++;
    if (srv->cfg.unit_id >= 0 && req[6] != srv->cfg.unit_id) {
        /* Nothing stands behind this gateway at that unit id. */
        log_refused(c, req, size, MB_EXCEPTION_GATEWAY_PATH);
        reply_exception(c, req, MB_EXCEPTION_GATEWAY_PATH);
        return;
    }
    if (ex) {
        log_refused(c, req, size, ex);
        if (mb_request_is_write(pdu[0]) && srv->hooks.on_write_refused) {
            struct mb_write w = {.client = c->host, .peer = c->peer, .client_addr = c->addr,
                                 .client_id = c->accept_seq, .rights = c->rights,
                                 .transport = c->transport->name, .subject = c->subject,
                                 .role = c->role};
            if (mb_request_write_range(pdu, pdu_size, &w.table, &w.address, &w.count) != 0)
                w.count = 0;
            srv->hooks.on_write_refused(srv->hooks.user, &w, ex);
        }
        reply_exception(c, req, ex);
        return;
    }
    if (pdu[0] == MODBUS_FC_REPORT_SLAVE_ID) {
        reply_server_id(c, req);
        return;
    }
    if (pdu[0] == MB_FC_READ_DEVICE_ID) {
        reply_device_id(c, req);
        return;
    }
    if (srv->closing && mb_request_is_write(pdu[0])) {
        /* Stopping (mb_server_shutdown): nothing may be started on the way
         * out, so a write is refused rather than acted on. */
        client_log(srv, &srv->refuse_log_limit, c->peer, "write refused",
                   "the gateway is stopping (exception 06)");
        reply_exception(c, req, MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
        return;
    }
    if (mb_request_is_write(pdu[0]) && srv->hooks.on_write) {
        /* Act before answering, so that a write can be refused. */
        static uint16_t values[MODBUS_MAX_WRITE_BITS];
        struct mb_write w = {.client = c->host, .peer = c->peer, .client_addr = c->addr,
                             .client_id = c->accept_seq, .values = values,
                             .rights = c->rights, .transport = c->transport->name,
                             .subject = c->subject, .role = c->role};
        int n = mb_request_written_values(srv->img, pdu, pdu_size, &w.table,
                                          &w.address, values);
        w.count = n > 0 ? (unsigned)n : 0;
        /* A checked write always has values; if none came out, libmodbus
         * must not apply it unjudged: 04. */
        ex = n > 0 ? srv->hooks.on_write(srv->hooks.user, &w)
                   : MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE;
        if (ex) {
            log_refused(c, req, size, ex);
            reply_exception(c, req, ex);
            return;
        }
        if (answer_single_write(c, req, size, &w))
            return;
    }
    if (answer_read(c, req, pdu)) /* checked: answered from the image */
        return;
    if (modbus_reply(srv->ctx, req, (int)size, srv->img->mb) < 0) {
        log_err("modbus: libmodbus could not answer function %u: %s", pdu[0],
                modbus_strerror(errno));
        reply_exception(c, req, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
        return;
    }
    forward_libmodbus_reply(c, req);
    after_write(c, pdu, pdu_size);
}

/* Answers one request, its service time into the histogram if counted. */
static void answer(struct mb_client *c, const uint8_t *req, size_t size)
{
    struct mb_server_breakdown *by = &c->srv->stats.by;
    uint64_t requests = c->srv->stats.requests;
    uint64_t start_ns = uv_hrtime();
    unsigned b = 0;

    answer_request(c, req, size);
    if (c->srv->stats.requests == requests)
        return; /* not a request: the connection was closed */
    double seconds = (double)(uv_hrtime() - start_ns) / 1e9;
    while (b < MB_STATS_SERVICE_BUCKETS && seconds > mb_stats_service_bounds_s[b])
        b++;
    by->service_buckets[b]++;
    by->service_seconds += seconds;
}

/*
 * Answers every complete request in the buffer, in order. Returns the bytes
 * consumed.
 */
static size_t process_frames(struct mb_client *c)
{
    size_t off = 0;

    while (c->state == CLIENT_OPEN && c->used - off >= MBAP_SIZE) {
        const uint8_t *h = c->buf + off;
        unsigned protocol = (unsigned)h[2] << 8 | h[3];
        unsigned length = (unsigned)h[4] << 8 | h[5];
        char why[96];

        if (protocol != 0 || length < 2 || length > 254) {
            snprintf(why, sizeof(why),
                     "bad MBAP header (protocol id %u, length %u)", protocol,
                     length);
            c->srv->stats.bad_frames++;
            release_client(c, why);
            return off;
        }
        size_t frame = MBAP_SIZE - 1 + length;
        if (c->used - off < frame)
            break;
        c->request_seq = ++c->srv->sequence;
        c->last_request_ms = uv_now(c->srv->loop);
        answer(c, h, frame);
        off += frame;
    }
    if (c->state != CLIENT_OPEN)
        return off;
    if (off) {
        memmove(c->buf, c->buf + off, c->used - off);
        c->used -= off;
    }
    return off;
}

static void on_client_alloc(uv_handle_t *h, size_t suggested, uv_buf_t *buf)
{
    struct mb_client *c = h->data;
    (void)suggested;
    c->transport->alloc(c->transport_state, c, buf);
}

/*
 * Arms the client's timer for its earliest deadline: the partial frame's
 * (frame_timeout_ms after its first byte) or the idle timeout's. One
 * timer per connection, so each deadline holds to the millisecond.
 */
static void arm_deadline(struct mb_client *c)
{
    struct mb_server *srv = c->srv;
    uint64_t now = uv_now(srv->loop), deadline = UINT64_MAX;

    if (c->used)
        deadline = c->frame_start_ms + srv->cfg.frame_timeout_ms;
    if (c->idle_timeout_ms && c->last_activity_ms + c->idle_timeout_ms < deadline)
        deadline = c->last_activity_ms + c->idle_timeout_ms;
    if (deadline == UINT64_MAX)
        uv_timer_stop(&c->timer);
    else
        uv_timer_start(&c->timer, on_client_timer, deadline > now ? deadline - now : 0, 0);
}

/* Takes 'n' new bytes at c->buf + c->used: answers, then re-arms. */
static void client_received(struct mb_client *c, size_t n)
{
    bool had_partial = c->used > 0;

    c->used += n;
    c->last_activity_ms = uv_now(c->srv->loop);
    size_t consumed = process_frames(c);
    if (c->state != CLIENT_OPEN)
        return;
    /* A partial frame keeps the deadline of its first byte. */
    if (c->used == 0)
        c->frame_start_ms = 0;
    else if (consumed > 0 || !had_partial)
        c->frame_start_ms = c->last_activity_ms;
    arm_deadline(c);
}

/*
 * Reads, without waiting, whatever the kernel already holds for 'c', as
 * the read callback would have a moment later: requests are answered, an
 * end of stream releases the client. Every judgement of a connection
 * (deadline, idle timeout, eviction) comes after this, so a request that
 * has arrived is answered, and a peer that has closed does not count.
 * libuv reads the same socket with read(2) and keeps no data of its own,
 * so reading it here loses nothing.
 */
static void drain_client_reads(struct mb_client *c, int max_reads)
{
    uv_os_fd_t fd;

    if (c->state != CLIENT_OPEN || c->no_socket ||
        uv_fileno((uv_handle_t *)&c->tcp, &fd) != 0)
        return;
    for (int i = 0; i < max_reads && c->state == CLIENT_OPEN; i++) {
        uv_buf_t into;
        c->transport->alloc(c->transport_state, c, &into);
        ssize_t n = recv(fd, into.base, into.len, MSG_DONTWAIT);
        if (n > 0) {
            c->transport->input(c->transport_state, c, (const uint8_t *)into.base,
                                (size_t)n);
        } else if (n == 0) {
            release_client(c, NULL);
        } else if (errno != EINTR) {
            if (errno != EAGAIN && errno != EWOULDBLOCK)
                close_client(c, strerror(errno));
            return;
        }
    }
}

static void drain_client(struct mb_client *c)
{
    drain_client_reads(c, MAX_DRAIN_READS);
}

static void on_client_read(uv_stream_t *s, ssize_t nread, const uv_buf_t *buf)
{
    struct mb_client *c = s->data;

    if (nread == 0)
        return;
    if (nread == UV_EOF) {
        /* Replies to what it sent before closing its side still go out. */
        if (c->state == CLIENT_PENDING)
            close_client(c, NULL);
        else
            release_client(c, NULL);
        return;
    }
    if (nread < 0) {
        close_client(c, uv_strerror((int)nread));
        return;
    }
    c->transport->input(c->transport_state, c, (const uint8_t *)buf->base, (size_t)nread);
}

static void on_client_timer(uv_timer_t *t)
{
    struct mb_client *c = t->data;
    struct mb_server *srv = c->srv;
    char why[96];

    if (c->state == CLIENT_FLUSHING) {
        close_client(c, "replies not taken after the client closed its side");
        return;
    }
    if (c->state == CLIENT_PENDING) {
        if (c->transport->expired)
            c->transport->expired(c->transport_state, c);
        close_client(c, NULL);
        return;
    }
    drain_client(c); /* bytes that have arrived count */
    if (c->state != CLIENT_OPEN)
        return;
    uint64_t now = uv_now(srv->loop);
    if (c->used && now - c->frame_start_ms >= srv->cfg.frame_timeout_ms) {
        snprintf(why, sizeof(why), "request incomplete after %llu ms (%zu bytes)",
                 (unsigned long long)(now - c->frame_start_ms), c->used);
        srv->stats.bad_frames++;
        release_client(c, why);
    } else if (c->idle_timeout_ms && now - c->last_activity_ms >= c->idle_timeout_ms) {
        snprintf(why, sizeof(why), "idle for %llu ms",
                 (unsigned long long)(now - c->last_activity_ms));
        /* A line (no socket) whose master pauses is no news: it counts
         * again with its next request. */
        if (c->no_socket)
            log_debug("modbus: client %s no longer counted: %s", c->peer, why);
        release_client(c, c->no_socket ? NULL : why);
    } else {
        arm_deadline(c);
    }
}

/*
 * The client to evict for a newcomer. First the connections that never
 * completed a request, oldest first: a burst of silent connects only
 * displaces itself. Then the client whose last complete request is the
 * oldest: a PLC reconnecting after a cable pull displaces its own
 * half-dead connection, and an actively polling client goes last.
 */
static struct mb_client *eviction_victim(struct mb_server *srv)
{
    struct mb_client *best = NULL;

    for (struct mb_client *c = srv->clients; c; c = c->next) {
        /* A line with no socket (RTU) is not a connection a PLC can
         * make again: never evicted. */
        if (c->state != CLIENT_OPEN || c->no_socket)
            continue;
        if (!best) {
            best = c;
        } else if ((c->request_seq == 0) != (best->request_seq == 0)) {
            if (c->request_seq == 0)
                best = c;
        } else if (c->request_seq == 0 ? c->accept_seq < best->accept_seq
                                       : c->request_seq < best->request_seq) {
            best = c;
        }
    }
    return best;
}

static void evict_for(struct mb_server *srv, const char *newcomer)
{
    struct mb_client *victim = eviction_victim(srv);
    uint64_t now = uv_now(srv->loop);
    char why[160];

    if (!victim)
        return;
    if (victim->request_seq == 0)
        snprintf(why, sizeof(why),
                 "evicted, no request in the %llu ms since it connected, to admit %s "
                 "(max_clients %u)",
                 (unsigned long long)(now - victim->accepted_ms), newcomer,
                 srv->cfg.max_clients);
    else
        snprintf(why, sizeof(why),
                 "evicted after %llu ms without a request to admit %s (max_clients %u)",
                 (unsigned long long)(now - victim->last_request_ms), newcomer,
                 srv->cfg.max_clients);
    srv->stats.evictions++;
    release_client(victim, why);
}

static void describe_peer(struct mb_client *c)
{
    struct sockaddr_storage sa;
    int len = sizeof(sa);
    char host[48] = "?";
    unsigned port = 0;

    if (uv_tcp_getpeername(&c->tcp, (struct sockaddr *)&sa, &len) == 0) {
        ip_addr_from_sockaddr((struct sockaddr *)&sa, &c->addr);
        if (sa.ss_family == AF_INET) {
            uv_ip4_name((struct sockaddr_in *)&sa, host, sizeof(host));
            port = ntohs(((struct sockaddr_in *)&sa)->sin_port);
        } else if (sa.ss_family == AF_INET6) {
            uv_ip6_name((struct sockaddr_in6 *)&sa, host, sizeof(host));
            port = ntohs(((struct sockaddr_in6 *)&sa)->sin6_port);
        }
    }
    snprintf(c->peer, sizeof(c->peer), "%s:%u", host, port);
    snprintf(c->host, sizeof(c->host), "%s", host);
}

static void on_connection(uv_stream_t *listener, int status);
static void admit_client(struct mb_client *c);

static void on_refused_closed(uv_handle_t *h)
{
    struct mb_server *srv = h->data;

    srv->refusing = false;
    srv->open_handles--;
    if (srv->closing) {
        maybe_finish_close(srv);
        return;
    }
    /* Other connections waited while this one closed: libuv polls a
     * listener again only once its connection is accepted. Every waiting
     * listener is taken up; one that has to refuse again while another
     * refusal is under way waits again, for that one's close. */
    for (int i = 0; i < MB_LISTENER_COUNT; i++) {
        struct mb_listener *l = &srv->listeners[i];
        if (!l->refuse_waiting)
            continue;
        l->refuse_waiting = false;
        on_connection((uv_stream_t *)&l->handle, 0);
    }
}

/*
 * No memory for a new client: accept the connection and close it at once.
 * Returning without uv_accept() would stop libuv from polling the listener
 * for good, and no PLC could connect again.
 */
static void refuse_connection(struct mb_server *srv, struct mb_listener *l)
{
    uint64_t suppressed;

    if (srv->refusing) {
        /* Accepted when the previous one is closed. */
        l->refuse_waiting = true;
        return;
    }
    srv->stats.refused_no_memory++;
    if (log_ratelimit_pass(&srv->refuse_log_limit, uv_now(srv->loop), &suppressed))
        log_err("modbus: out of memory for a new client: connection closed "
                "(%llu more since the last such line)", (unsigned long long)suppressed);
    srv->refusing = true;
    srv->open_handles++;
    uv_tcp_init(srv->loop, &srv->refused);
    srv->refused.data = srv;
    if (uv_accept((uv_stream_t *)&l->handle, (uv_stream_t *)&srv->refused) < 0)
        log_err("modbus: cannot accept a connection to close it");
    uv_close((uv_handle_t *)&srv->refused, on_refused_closed);
}

/*
 * TCP keepalive and TCP_USER_TIMEOUT (mb_server.h): a peer gone without a
 * word is let go in about 5 s (libuv's own keepalive, 10 s and then 10
 * probes a second apart, took 20 s; the kernel's defaults, over two hours).
 */
static void tune_keepalive(struct mb_client *c)
{
    static const struct { int level, name, value; const char *what; } opts[] = {
        {IPPROTO_TCP, TCP_KEEPINTVL, MB_SERVER_KEEPALIVE_INTERVAL_S, "TCP_KEEPINTVL"},
        {IPPROTO_TCP, TCP_KEEPCNT, MB_SERVER_KEEPALIVE_COUNT, "TCP_KEEPCNT"},
        {IPPROTO_TCP, TCP_USER_TIMEOUT, MB_SERVER_USER_TIMEOUT_MS, "TCP_USER_TIMEOUT"},
    };
    uv_os_fd_t fd;
    int rc = uv_tcp_keepalive(&c->tcp, 1, MB_SERVER_KEEPALIVE_IDLE_S);

    if (rc < 0 || uv_fileno((uv_handle_t *)&c->tcp, &fd) != 0) {
        log_debug("modbus: client %s: keepalive not set: %s", c->peer,
                  uv_strerror(rc < 0 ? rc : UV_EBADF));
        return;
    }
    for (size_t i = 0; i < sizeof(opts) / sizeof(opts[0]); i++)
        if (setsockopt(fd, opts[i].level, opts[i].name, &opts[i].value,
                       sizeof(opts[i].value)) < 0)
            log_debug("modbus: client %s: %s not set: %s", c->peer, opts[i].what,
                      strerror(errno));
}

static void on_connection(uv_stream_t *listener, int status)
{
    struct mb_listener *l = listener->data;
    struct mb_server *srv = l->srv;
    struct mb_client *c;

    if (status < 0) {
        log_warn("modbus: accept failed: %s", uv_strerror(status));
        return;
    }
    c = srv->calloc_client(1, sizeof(*c));
    if (!c) {
        refuse_connection(srv, l);
        return;
    }
    c->srv = srv;
    c->rights = REGMAP_RIGHTS_ALL;
    c->idle_timeout_ms = srv->cfg.idle_timeout_ms;
    c->transport = l->transport;
    c->transport_state = l->state;
    uv_tcp_init(srv->loop, &c->tcp);
    uv_timer_init(srv->loop, &c->timer);
    c->tcp.data = c;
    c->timer.data = c;
    c->shutdown.data = c;
    c->open_handles = 2;
    srv->open_handles++;
    if (uv_accept(listener, (uv_stream_t *)&c->tcp) < 0) {
        c->state = CLIENT_CLOSING;
        uv_close((uv_handle_t *)&c->tcp, on_client_handle_closed);
        uv_close((uv_handle_t *)&c->timer, on_client_handle_closed);
        return;
    }
    describe_peer(c);
    c->accepted_ms = c->last_activity_ms = uv_now(srv->loop);
    uv_tcp_nodelay(&c->tcp, 1);
    tune_keepalive(c);
    /* In the list, so that a close of the server closes it, but pending:
     * not a client, neither counted nor heard of, until admitted. */
    c->state = CLIENT_PENDING;
    c->next = srv->clients;
    if (srv->clients)
        srv->clients->prev = c;
    srv->clients = c;
    int rc = c->transport->open(c->transport_state, c);
    if (rc < 0) {
        close_client(c, NULL);
        return;
    }
    if (uv_read_start((uv_stream_t *)&c->tcp, on_client_alloc, on_client_read) < 0) {
        close_client(c, "cannot read");
        return;
    }
    if (rc != MB_TRANSPORT_PENDING)
        admit_client(c);
}

/* A connection becomes a client: counted, heard of, served. */
static void admit_client(struct mb_client *c)
{
    struct mb_server *srv = c->srv;

    /* A line with no socket (RTU) is not a connection: it takes no slot
     * and evicts no one, however often it comes back after idle_timeout. */
    if (!c->no_socket && srv->stats.clients - srv->line_clients >= srv->cfg.max_clients) {
        /* Judge on what has arrived: answer the requests the kernel holds
         * and let go of the peers that have closed. A burst of connects is
         * accepted in one go, before any of these would be read. */
        struct mb_client *next;
        for (struct mb_client *o = srv->clients; o; o = next) {
            next = o->next;
            drain_client(o);
        }
        if (srv->stats.clients - srv->line_clients >= srv->cfg.max_clients)
            evict_for(srv, c->peer);
    }
    if (c->state != CLIENT_PENDING)
        return; /* closed meanwhile */
    c->last_activity_ms = uv_now(srv->loop);
    c->accept_seq = ++srv->sequence;
    c->state = CLIENT_OPEN;
    srv->stats.clients++;
    if (c->no_socket)
        srv->line_clients++;
    if (srv->hooks.on_client)
        srv->hooks.on_client(srv->hooks.user, c->accept_seq, true, srv->stats.clients);
    log_debug("modbus: client %s connected (%u now)", c->peer, srv->stats.clients);
    arm_deadline(c);
}

static int open_reply_pair(struct mb_server *srv)
{
    if (socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_NONBLOCK | SOCK_CLOEXEC, 0,
                   srv->pair) < 0)
        return -errno;
    srv->ctx = modbus_new_tcp(NULL, 0);
    if (!srv->ctx)
        return -ENOMEM;
    modbus_set_socket(srv->ctx, srv->pair[0]);
    /* modbus_reply never needs to wait; keep any wait it might do minimal. */
    modbus_set_response_timeout(srv->ctx, 0, 1);
    return 0;
}

/*
 * Serves a socket that is already bound and listening (systemd's socket
 * activation): the bind address and port of the configuration do not
 * apply, and no privilege is needed for port 502.
 */
static int adopt_listener(struct mb_server *srv, int fd)
{
    struct sockaddr_storage sa;
    int len = sizeof(sa);
    char host[48] = "?";
    int rc;

    uv_tcp_t *listener = &srv->listeners[MB_LISTENER_PLAIN].handle;

    rc = uv_tcp_open(listener, fd);
    if (rc == 0)
        rc = uv_listen((uv_stream_t *)listener, 64, on_connection);
    if (rc < 0) {
        log_err("modbus: cannot listen on the socket passed as fd %d: %s", fd,
                uv_strerror(rc));
        return rc;
    }
    if (uv_tcp_getsockname(listener, (struct sockaddr *)&sa, &len) == 0) {
        if (sa.ss_family == AF_INET6)
            uv_ip6_name((struct sockaddr_in6 *)&sa, host, sizeof(host));
        else
            uv_ip4_name((struct sockaddr_in *)&sa, host, sizeof(host));
    }
    log_notice("modbus: listening on %s port %d, the socket passed by systemd "
               "([modbus] bind and port do not apply; max %u clients)",
               host, mb_server_port(srv), srv->cfg.max_clients);
    return 0;
}

static void init_listener(struct mb_server *srv, struct mb_listener *l,
                          const struct mb_transport *transport, void *state)
{
    uv_tcp_init(srv->loop, &l->handle);
    l->handle.data = l;
    l->srv = srv;
    l->transport = transport;
    l->state = state;
    srv->open_handles++;
}

int mb_server_start(uv_loop_t *loop, struct mb_server *srv,
                    const struct mb_server_config *cfg, struct regmap_image *img,
                    const struct mb_server_hooks *hooks)
{
    struct sockaddr_storage addr;
    int rc;

    memset(srv, 0, sizeof(*srv));
    srv->pair[0] = srv->pair[1] = -1;
    if (!cfg || !img || !cfg->bind || cfg->max_clients == 0 ||
        strlen(cfg->bind) >= sizeof(srv->bind))
        return -EINVAL;
    srv->loop = loop;
    srv->cfg = *cfg;
    snprintf(srv->bind, sizeof(srv->bind), "%s", cfg->bind);
    srv->cfg.bind = srv->bind;
    srv->hooks = *hooks;
    srv->img = img;
    srv->calloc_client = calloc;
    srv->close_log_limit.interval_ms = 1000;
    srv->refuse_log_limit.interval_ms = 1000;
    snprintf(srv->device_info, sizeof(srv->device_info), "jakagw %s map %d",
             JAKAGW_VERSION, REGMAP_VERSION);

    if (uv_ip4_addr(cfg->bind, cfg->port, (struct sockaddr_in *)&addr) != 0 &&
        uv_ip6_addr(cfg->bind, cfg->port, (struct sockaddr_in6 *)&addr) != 0) {
        log_err("modbus: bind address '%s' is not an IPv4 or IPv6 address", cfg->bind);
        return -EINVAL;
    }
    rc = open_reply_pair(srv);
    if (rc < 0) {
        log_err("modbus: cannot prepare libmodbus: %s", strerror(-rc));
        return rc;
    }
    struct mb_listener *plain = &srv->listeners[MB_LISTENER_PLAIN];
    init_listener(srv, plain, &mb_transport_plain, NULL);
    if (cfg->no_plain) {
        log_notice("modbus: no plain Modbus TCP listener ([modbus] enabled = false)");
        return 0;
    }
    plain->listening = true;
    if (cfg->listen_fd > 0)
        return adopt_listener(srv, cfg->listen_fd);
    rc = uv_tcp_bind(&plain->handle, (const struct sockaddr *)&addr, 0);
    if (rc == 0)
        rc = uv_listen((uv_stream_t *)&plain->handle, 64, on_connection);
    if (rc < 0) {
        log_err("modbus: cannot listen on %s port %u: %s", cfg->bind, cfg->port,
                uv_strerror(rc));
        return rc;
    }
    log_notice("modbus: listening on %s port %d (max %u clients)", cfg->bind,
               mb_server_port(srv), cfg->max_clients);
    return 0;
}

static int port_of(const uv_tcp_t *listener)
{
    struct sockaddr_storage sa;
    int len = sizeof(sa);

    if (uv_tcp_getsockname(listener, (struct sockaddr *)&sa, &len) != 0)
        return -1;
    if (sa.ss_family == AF_INET6)
        return ntohs(((struct sockaddr_in6 *)&sa)->sin6_port);
    return ntohs(((struct sockaddr_in *)&sa)->sin_port);
}

int mb_server_listen_port(const struct mb_server *srv)
{
    const struct mb_listener *l = &srv->listeners[MB_LISTENER_EXTRA];
    return l->listening ? port_of(&l->handle) : -1;
}

int mb_server_listen(struct mb_server *srv, const char *bind, uint16_t port, int listen_fd,
                     const struct mb_transport *transport, void *state)
{
    struct sockaddr_storage addr;
    const char *name = transport->name;
    int rc;

    struct mb_listener *l = &srv->listeners[MB_LISTENER_EXTRA];

    if (l->transport || srv->closing)
        return -EBUSY;
    if (listen_fd <= 0 && uv_ip4_addr(bind, port, (struct sockaddr_in *)&addr) != 0 &&
        uv_ip6_addr(bind, port, (struct sockaddr_in6 *)&addr) != 0) {
        log_err("%s: bind address '%s' is not an IPv4 or IPv6 address", name, bind);
        return -EINVAL;
    }
    init_listener(srv, l, transport, state);
    if (listen_fd > 0)
        rc = uv_tcp_open(&l->handle, listen_fd);
    else
        rc = uv_tcp_bind(&l->handle, (const struct sockaddr *)&addr, 0);
    if (rc == 0)
        rc = uv_listen((uv_stream_t *)&l->handle, 64, on_connection);
    if (rc < 0) {
        if (listen_fd > 0)
            log_err("%s: cannot listen on the socket passed as fd %d: %s", name, listen_fd,
                    uv_strerror(rc));
        else
            log_err("%s: cannot listen on %s port %u: %s", name, bind, port,
                    uv_strerror(rc));
        return rc;
    }
    l->listening = true;
    if (listen_fd > 0)
        log_notice("%s: listening on port %d, the socket passed by systemd", name,
                   mb_server_listen_port(srv));
    else
        log_notice("%s: listening on %s port %d", name, bind, mb_server_listen_port(srv));
    return 0;
}

int mb_server_port(const struct mb_server *srv)
{
    const struct mb_listener *l = &srv->listeners[MB_LISTENER_PLAIN];
    return l->listening ? port_of(&l->handle) : -1;
}

static void on_server_handle_closed(uv_handle_t *h)
{
    struct mb_listener *l = h->data;
    struct mb_server *srv = l->srv;
    srv->open_handles--;
    maybe_finish_close(srv);
}

static void close_server(struct mb_server *srv, void (*cb)(struct mb_server *srv),
                         bool graceful)
{
    struct mb_client *c, *next;

    srv->closing = true;
    srv->close_cb = cb;
    for (c = srv->clients; c; c = next) {
        /* Neither call frees a client: 'next' stays valid. */
        next = c->next;
        if (c->state == CLIENT_PENDING) {
            close_client(c, NULL); /* never served: nothing owed */
        } else if (graceful) {
            /* Answered with the image as it is now, before anything closes. */
            drain_client_reads(c, MAX_SHUTDOWN_READS);
            release_client(c, NULL);
        } else {
            close_client(c, NULL);
        }
    }
    if (srv->ctx) {
        /* libmodbus would close the socket it was given; we own it. */
        modbus_set_socket(srv->ctx, -1);
        modbus_free(srv->ctx);
        srv->ctx = NULL;
    }
    for (int i = 0; i < 2; i++) {
        if (srv->pair[i] >= 0)
            close(srv->pair[i]);
        srv->pair[i] = -1;
    }
    if (srv->open_handles == 0) {
        maybe_finish_close(srv);
        return;
    }
    for (int i = 0; i < MB_LISTENER_COUNT; i++)
        if (srv->listeners[i].transport)
            uv_close((uv_handle_t *)&srv->listeners[i].handle, on_server_handle_closed);
}

void mb_server_close(struct mb_server *srv, void (*cb)(struct mb_server *srv))
{
    close_server(srv, cb, false);
}

void mb_server_shutdown(struct mb_server *srv, void (*cb)(struct mb_server *srv))
{
    close_server(srv, cb, true);
}

/* ---- the plain transport, and what transports may call ---- */

static int plain_open(void *state, struct mb_client *c)
{
    (void)state, (void)c;
    return 0;
}

static void plain_alloc(void *state, struct mb_client *c, uv_buf_t *buf)
{
    (void)state;
    /* Straight into the framing buffer: no copy. */
    *buf = uv_buf_init((char *)c->buf + c->used, (unsigned)(sizeof(c->buf) - c->used));
}

static void plain_input(void *state, struct mb_client *c, const uint8_t *data, size_t size)
{
    (void)state, (void)data;
    client_received(c, size);
}

static void plain_output(void *state, struct mb_client *c, const uint8_t *data, size_t size)
{
    (void)state;
    send_bytes(c, data, size);
}

const struct mb_transport mb_transport_plain = {
    .name = "modbus",
    .stats_slot = 0,
    .open = plain_open,
    .alloc = plain_alloc,
    .input = plain_input,
    .output = plain_output,
};

void **mb_client_data(struct mb_client *c)
{
    return &c->transport_data;
}

const char *mb_client_peer(const struct mb_client *c)
{
    return c->peer;
}

uv_loop_t *mb_client_loop(const struct mb_client *c)
{
    return c->srv->loop;
}

bool mb_client_is_open(const struct mb_client *c)
{
    return c->state == CLIENT_PENDING || c->state == CLIENT_OPEN;
}

bool mb_client_can_send(const struct mb_client *c)
{
    return c->state != CLIENT_CLOSING;
}

bool mb_client_has_input(const struct mb_client *c)
{
    uv_os_fd_t fd;
    int n = 0;

    return uv_fileno((const uv_handle_t *)&c->tcp, &fd) == 0 && ioctl(fd, FIONREAD, &n) == 0 &&
           n > 0;
}

void mb_client_pause_reading(struct mb_client *c)
{
    if (!mb_client_is_open(c) || c->reading_paused)
        return;
    uv_read_stop((uv_stream_t *)&c->tcp);
    c->reading_paused = true;
}

int mb_client_resume_reading(struct mb_client *c)
{
    int rc;

    if (!mb_client_is_open(c) || !c->reading_paused)
        return 0;
    c->reading_paused = false;
    rc = uv_read_start((uv_stream_t *)&c->tcp, on_client_alloc, on_client_read);
    if (rc < 0)
        close_client(c, "cannot read");
    return rc;
}

uint64_t mb_client_accepted_ms(const struct mb_client *c)
{
    return c->accepted_ms;
}

uint8_t *mb_client_space(struct mb_client *c, size_t *room)
{
    *room = c->state == CLIENT_OPEN ? sizeof(c->buf) - c->used : 0;
    return c->buf + c->used;
}

void mb_client_received(struct mb_client *c, size_t n)
{
    if (c->state == CLIENT_OPEN && n > 0 && n <= sizeof(c->buf) - c->used)
        client_received(c, n);
}

void mb_client_send_raw(struct mb_client *c, const uint8_t *data, size_t size)
{
    if (c->state != CLIENT_CLOSING && !c->no_socket && size > 0)
        send_bytes(c, data, size);
}

void mb_client_set_deadline(struct mb_client *c, uint64_t ms)
{
    if (c->state == CLIENT_PENDING)
        uv_timer_start(&c->timer, on_client_timer, ms, 0);
}

void mb_client_set_identity(struct mb_client *c, const char *subject, const char *role)
{
    snprintf(c->subject, sizeof(c->subject), "%s", subject ? subject : "");
    snprintf(c->role, sizeof(c->role), "%s", role ? role : "");
}

void mb_server_foreach_client(const struct mb_server *srv,
                              void (*cb)(void *user, const struct mb_client_info *info),
                              void *user)
{
    for (const struct mb_client *c = srv->clients; c; c = c->next) {
        if (c->state != CLIENT_OPEN)
            continue;
        struct mb_client_info info = {
            .id = c->accept_seq, .peer = c->peer, .host = c->host, .transport = c->transport->name,
            .subject = c->subject, .role = c->role, .rights = c->rights,
            .requests = c->requests, .exceptions = c->exceptions,
            .accepted_ms = c->accepted_ms,
            .last_request_ms = c->request_seq ? c->last_request_ms : 0,
        };
        cb(user, &info);
    }
}

void mb_client_admit(struct mb_client *c, uint32_t rights)
{
    if (c->state != CLIENT_PENDING)
        return;
    c->rights = rights;
    uv_timer_stop(&c->timer);
    admit_client(c);
}

void mb_client_close(struct mb_client *c, const char *why)
{
    close_client(c, why);
}

void mb_client_release(struct mb_client *c, const char *why)
{
    if (c->state == CLIENT_PENDING)
        close_client(c, why);
    else
        release_client(c, why);
}

int mb_server_attach(struct mb_server *srv, const char *peer,
                     const struct mb_transport *transport, void *state, uint32_t rights,
                     uint32_t idle_timeout_ms, struct mb_client **out)
{
    struct mb_client *c;

    *out = NULL;
    if (srv->closing)
        return -ESHUTDOWN;
    c = srv->calloc_client(1, sizeof(*c));
    if (!c)
        return -ENOMEM;
    c->srv = srv;
    c->no_socket = true;
    c->transport = transport;
    c->transport_state = state;
    c->idle_timeout_ms = idle_timeout_ms;
    snprintf(c->peer, sizeof(c->peer), "%s", peer);
    snprintf(c->host, sizeof(c->host), "%s", peer);
    uv_timer_init(srv->loop, &c->timer);
    c->timer.data = c;
    c->open_handles = 1;
    srv->open_handles++;
    c->accepted_ms = c->last_activity_ms = uv_now(srv->loop);
    c->state = CLIENT_PENDING;
    c->next = srv->clients;
    if (srv->clients)
        srv->clients->prev = c;
    srv->clients = c;
    mb_client_admit(c, rights);
    if (c->state != CLIENT_OPEN)
        return -ECONNABORTED; /* closed meanwhile: its transport heard why */
    *out = c;
    return 0;
}
