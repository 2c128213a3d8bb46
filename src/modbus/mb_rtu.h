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
 * CLOCK_MONOTONIC. The end of a frame (3.5 character times of silence,
 * 1.75 ms above 19200 baud) is finer than libuv's millisecond timers, so a
 * timerfd under a second uv_poll fires at the last byte's time plus t3.5;
 * the loop never blocks. The times are those of the reads, not of the
 * bytes on the wire: a UART hands over its FIFO every 8 characters (the
 * rest 4 characters after the last), a USB adapter its packets, and a
 * host may be late to read. So a read marks a gap (a frame with a gap
 * inside it is discarded) only when it comes more than t1.5 after the
 * previous one once its own bytes' wire time and the port's delivery (4
 * characters and 1 ms) are taken off; a silence of t3.5 after a frame
 * begun but not whole by its length (rtu_missing_bytes) waits as long
 * again as its missing bytes and the delivery take; and frames are also
 * cut by their length and CRC (rtu_split), so a late reader keeps its
 * sync.
 *
 * What is answered: a frame with a good CRC addressed to unit_id. A frame
 * for another unit is counted and skipped; a broadcast (unit 0) is counted
 * and never acted on, because no reply could tell the master whether a
 * command was carried out. An RS-485 adapter that hears its own
 * transmitter gives each reply back: the frame equal to the last reply,
 * arriving within its wire time and 100 ms, is skipped, not taken for a
 * request (which would be answered, and heard again); but where the line
 * has shown that it does not echo, the same write (05, 06) repeated by a
 * master within that time, equal to its reply, is served. For
 * [network_exception] watch = connection, the line counts as a connected
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
    uint64_t frames;         /* frames with a good CRC, every unit */
    uint64_t crc_errors;     /* runs of bytes that were no frame */
    uint64_t foreign_frames; /* good frames for another unit, skipped */
    uint64_t broadcasts;     /* good frames for unit 0, not acted on */
    uint64_t overruns;       /* chunks longer than the receive buffer */
    uint64_t gap_discards;   /* good frames with a silence inside them */
    uint64_t echoes;         /* our own replies read back, skipped */
    uint64_t replies;
    uint32_t turnaround_us;     /* the last reply: request's last byte to write */
    uint32_t turnaround_max_us;
};

/* How late a port may hand over bytes it received, beyond a FIFO's 4
 * character receive timeout: the interrupt, the driver, a USB frame. */
#define MB_RTU_DELIVERY_NS 1000000ull

/* Bytes kept between two silences: several frames glued together. */
#define MB_RTU_RX_SIZE 1024
#define MB_RTU_MAX_GAPS 64
#define MB_RTU_TX_SIZE 1024

struct mb_rtu {
    uv_loop_t *loop;
    struct mb_server *srv;
    struct mb_rtu_config cfg;
    char device[256];
    char peer[48];
    uint32_t t15_ns, t35_ns;
    int fd;                  /* the serial port, -1: not open */
    uv_poll_t serial;        /* watches fd */
    bool serial_handle;      /* 'serial' initialised and not yet closed */
    bool serial_closing;     /* its close callback is due */
    int timer_fd;            /* the silence timer (timerfd) */
    uv_poll_t silence;
    uv_timer_t retry;        /* reopens a failed device every second */
    int retry_error;         /* what the last reopen returned */
    struct mb_client *client; /* the server's client for this line, or NULL */
    /* The chunk being received: bytes since the last silence of t3.5. */
    uint8_t rx[MB_RTU_RX_SIZE];
    size_t rx_used;
    bool rx_overrun;
    uint16_t gaps[MB_RTU_MAX_GAPS]; /* offsets of bytes after a gap > t1.5 */
    size_t gap_count;
    uint64_t last_rx_ns;     /* when the last bytes were read */
    uint64_t request_end_ns; /* the frame being answered: its last read */
    /* The last reply, as an adapter that hears its own transmitter gives
     * it back: skipped when it comes back whole before echo_until_ns. */
    uint8_t echo[RTU_MAX_ADU];
    size_t echo_size;
    uint64_t echo_until_ns;
    /* Does the adapter give replies back? An echo is the next frame after
     * a reply, before any master's; a reply unlike its request (a read, an
     * exception) heard back says yes, three replies in a row followed by
     * another frame say no. A write's reply (05, 06) equals its request,
     * so a master repeating that write is told from the echo only on a
     * line known not to echo. */
    enum { MB_RTU_ECHO_UNKNOWN, MB_RTU_ECHO_YES, MB_RTU_ECHO_NO } line_echo;
    unsigned no_echo_proofs;   /* replies not given back, in a row */
    bool echo_probe;           /* the next frame tells whether the line echoes */
    bool echo_is_request;      /* the last reply equals its request */
    const uint8_t *request;    /* the frame being answered (in rx) */
    size_t request_size;
    uint32_t char_ns;        /* one character on the wire */
    uint64_t delivery_ns;    /* how late the port may hand bytes over */
    uint8_t tx[MB_RTU_TX_SIZE]; /* what the port did not take at once */
    size_t tx_used;
    bool tx_waiting;         /* polling for writable: tx_used was > 0 */
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
