/* SPDX-License-Identifier: MIT */
/*
 * mb_rtu.h - Modbus RTU on a serial line (RS-485 or RS-232), one more
 * transport under the one Modbus server (mb_server.h).
 *
 * The line is a client of the server with no socket (mb_server_attach):
 * its requests go through the same request checks, register map, write
 * judgement, rights, single_owner and heartbeat policy, counters and
 * shutdown as a TCP or TLS client's. This module only frames: it owns the
 * serial port (termios, the kernel's RS-485 mode), cuts the bytes into
 * frames (rtu_frame.h), hands the ones addressed to its unit id to the
 * server as requests and sends the replies back with their CRC.
 *
 * Timing. The serial fd is watched by a uv_poll; each read is stamped with
 * the clock (CLOCK_MONOTONIC; a seam, 'now_ns', for tests) and handed to
 * the line's conversation model (struct rtu_line, rtu_frame.h), which
 * says which frames are requests for this unit, and when. The end of a
 * frame (3.5 character times of silence, 1.75 ms above 19200 baud) is
 * finer than libuv's millisecond timers, so a timerfd under a second
 * uv_poll fires at the line's next deadline: the silence after the last
 * byte, or the time our next reply may start; the loop never blocks. The
 * times are those of the reads, not of the bytes on the wire: a UART
 * hands over its FIFO every 8 characters, a USB adapter its packets, and
 * a host may be late to read; the model allows for the port's delivery.
 *
 * What is answered: a request for unit_id that the conversation makes
 * certain (rtu_frame.h): a whole frame between two silences, or one whose
 * boundaries the exchange before it in the same chunk gives. A frame for
 * another unit is counted and skipped, and so is its response, by the
 * length its request gives: a frame hidden in its data is never seen. A
 * broadcast (unit 0) is counted and never acted on, because no reply
 * could tell the master whether a command was carried out.
 *
 * Delivery and echo. At open, set_up_delivery() asks for low latency
 * (ASYNC_LOW_LATENCY; an FTDI adapter's sysfs latency_timer set to 1) and
 * reads the adapter's delivery bound back from sysfs, else takes [rtu]
 * delivery_ms: a gap shorter than it is never a silence (rtu_frame.h). A
 * frame equal to our last reply (FC05, FC06: the request itself) later
 * than the bound is the master's, acted on and answered; within it, it is
 * answered again once and not acted on again (on_repeat); a second one is
 * an echo, skipped. local_echo = true takes each reply's one echo off the
 * input within 1 s; a spoiled echo is a collision, counted and logged
 * once. Two frames we send are at least t3.5 apart, however the port's
 * writability goes (replies wait in a small queue).
 *
 * Limits. The line is a client of the server with no socket: it never
 * takes one of [modbus] max_clients' slots and never causes an eviction.
 * For [network_exception] watch = connection, it counts as a connected
 * client while a valid request addressed to this unit arrived within
 * 'active_ms'.
 *
 * A device that is absent at start or goes away (a USB adapter unplugged,
 * a read or write that fails) is a link fault: one log line, the state in
 * the diagnostics, and a new open every second, TCP unaffected. A device
 * that is not a terminal, or that refuses TIOCSRS485 with rs485 = true, is
 * a configuration error at start (mb_rtu_start returns -ENOTTY).
 *
 * Life cycle as libuv handles: mb_rtu_start(), mb_rtu_close(cb); the
 * struct is the caller's until cb runs. A frame still waiting for its
 * t3.5 silence at the close is dropped: neither acted on nor answered
 * (its reply could not go out before the silence), so a master sees a
 * timeout, never a write carried out without a reply.
 */
#ifndef JAKAGW_MB_RTU_H
#define JAKAGW_MB_RTU_H

#include <stdbool.h>
#include <stdint.h>
#include <uv.h>

#include "log.h"
#include "mb_server.h"
#include "rtu_frame.h"

enum mb_rtu_parity { MB_RTU_PARITY_NONE = 0, MB_RTU_PARITY_EVEN = 1, MB_RTU_PARITY_ODD = 2 };

struct mb_rtu_config {
    const char *device;
    unsigned baud;
    enum mb_rtu_parity parity;
    unsigned stop_bits; /* 1 or 2 */
    unsigned unit_id;   /* 1..247 */
    bool rs485;         /* TIOCSRS485: the kernel drives RTS while sending */
    bool local_echo;    /* the adapter gives back what it sends */
    uint32_t delivery_ms; /* the adapter's delivery bound where sysfs tells none */
    const char *sysfs_root; /* NULL: "/sys" (a seam for tests) */
    uint32_t rights;    /* what the line may write (regmap_parse_rights) */
    uint32_t active_ms; /* counted as a client this long after a request */
};

/* The line's state, as the diagnostics show it. */
enum mb_rtu_state {
    MB_RTU_OFF = 0,    /* [rtu] enabled = false */
    MB_RTU_IDLE = 1,   /* open; no request for this unit within active_ms */
    MB_RTU_POLLED = 2, /* open; a master polls this unit */
    MB_RTU_FAULT = 3,  /* the device is absent or failed: retried every second */
};

struct mb_rtu_stats {
    uint64_t frames;         /* frames the conversation explained, every unit */
    uint64_t crc_errors;     /* chunks (or their rest) that were not what was expected */
    uint64_t foreign_frames; /* requests and responses of other units, skipped */
    uint64_t broadcasts;     /* good frames for unit 0, not acted on */
    uint64_t overruns;       /* chunks longer than the receive buffer, replies not taken */
    uint64_t gap_discards;   /* good frames with a pause inside them */
    uint64_t echoes;         /* our own replies read back, skipped */
    uint64_t collisions;     /* local_echo: a reply came back different */
    uint64_t out_of_turn;    /* frames begun before our reply's end + t3.5 (served) */
    uint64_t repeats;        /* our last reply again within the delivery bound: answered again */
    uint64_t exceptions;     /* exception-form frames addressed to us, skipped */
    uint64_t replies;
    uint32_t turnaround_us;     /* the last reply: request's last byte to write */
    uint32_t turnaround_max_us;
};

/* How late a port may hand over bytes it received, beyond a FIFO's 4
 * character receive timeout: the interrupt, the driver, a USB frame. */
#define MB_RTU_DELIVERY_NS 1000000ull

/* Replies waiting for the port or for their t3.5 (normally none). */
#define MB_RTU_TX_FRAMES 4

struct mb_rtu {
    uv_loop_t *loop;
    struct mb_server *srv;
    struct mb_rtu_config cfg;
    char device[256];
    char peer[48];
    int fd;                  /* the serial port, -1: not open */
    uv_poll_t serial;        /* watches fd */
    bool serial_handle;      /* 'serial' initialised and not yet closed */
    bool serial_closing;     /* its close callback is due */
    int timer_fd;            /* the line's next deadline (timerfd) */
    uv_poll_t silence;
    uv_timer_t retry;        /* reopens a failed device every second */
    int retry_error;         /* what the last reopen returned */
    struct mb_client *client; /* the server's client for this line, or NULL */
    struct rtu_line line;    /* the conversation (rtu_frame.h) */
    uint64_t (*now_ns)(void); /* the clock: CLOCK_MONOTONIC, a seam for tests */
    uint64_t request_end_ns; /* the request being answered: its last read */
    uint64_t seen_empty_ns;  /* the last read that found the port empty */
    uint32_t char_ns;        /* one character on the wire */
    /* The adapter's delivery bound (ms): its latency timer read back from
     * sysfs, else cfg.delivery_ms; 'delivery_source' says which. */
    uint32_t delivery_bound_ms;
    const char *delivery_source;
    const char *sysfs_root;
    struct mb_rtu_tx_frame {
        uint8_t data[RTU_MAX_ADU];
        size_t size, sent;
    } tx[MB_RTU_TX_FRAMES];  /* tx[0] goes first */
    size_t tx_count;
    bool tx_waiting;         /* polling for writable */
    bool event_logged[RTU_EVENT_COUNT]; /* each said once */
    uint16_t transaction;
    struct mb_rtu_stats stats;
    struct log_ratelimit log_limit;
    bool closing;
    int open_handles;
    void (*close_cb)(struct mb_rtu *rtu);
    void *user;
};

/*
 * Opens the line and starts serving it through 'srv'. Returns 0 (an absent
 * device is a link fault, retried), -ENOTTY when the device is not a
 * terminal or refuses rs485 (logged, naming the device: a configuration
 * error), or another negative errno. Call mb_rtu_close() in every case.
 */
int mb_rtu_start(uv_loop_t *loop, struct mb_rtu *rtu, struct mb_server *srv,
                 const struct mb_rtu_config *cfg);

enum mb_rtu_state mb_rtu_state(const struct mb_rtu *rtu);

void mb_rtu_clear_stats(struct mb_rtu *rtu);

/* Closes the port and its handles; 'cb' runs when all are closed. */
void mb_rtu_close(struct mb_rtu *rtu, void (*cb)(struct mb_rtu *rtu));

/* The line as a transport of the one Modbus server (mb_server.h). */
extern const struct mb_transport mb_transport_rtu;

#endif
