/* SPDX-License-Identifier: MIT */
/* mb_rtu.c - see mb_rtu.h. */
#include "mb_rtu.h"

#include <errno.h>
#include <fcntl.h>
#include <linux/serial.h>
#include <stdio.h>
#include <string.h>
#include <sys/file.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/timerfd.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define MBAP_SIZE 7
#define RETRY_MS 1000

static uint64_t monotonic_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

static speed_t speed_of(unsigned baud)
{
    switch (baud) {
    case 1200: return B1200;
    case 2400: return B2400;
    case 4800: return B4800;
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    case 460800: return B460800;
    case 921600: return B921600;
    default: return B0;
    }
}

/* Unix98 pty slaves: majors 136-143. */
static bool is_pseudo_terminal(int fd)
{
    struct stat st;
    return fstat(fd, &st) == 0 && S_ISCHR(st.st_mode) && major(st.st_rdev) >= 136 &&
           major(st.st_rdev) <= 143;
}

/* After termios: the kernel's RS-485 mode, and no stale input. */
static int finish_setup(struct mb_rtu *rtu, int fd, char *why, size_t why_size)
{
    if (rtu->cfg.rs485) {
        struct serial_rs485 rs;
        memset(&rs, 0, sizeof(rs));
        rs.flags = SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND;
        if (ioctl(fd, TIOCSRS485, &rs) < 0) {
            snprintf(why, why_size,
                     "rs485 = true, but the driver refuses RS-485 mode (TIOCSRS485: %s)",
                     strerror(errno));
            return -ENOTTY;
        }
    }
    tcflush(fd, TCIOFLUSH); /* nothing from before we listened */
    return 0;
}

/*
 * Sets the port raw at the configured speed and framing. Returns 0,
 * -ENOTTY for a setting the device refuses (a configuration error, with
 * 'why'), or another negative errno.
 */
static int configure_port(struct mb_rtu *rtu, int fd, char *why, size_t why_size)
{
    struct termios tio;
    speed_t speed = speed_of(rtu->cfg.baud);

    if (tcgetattr(fd, &tio) < 0) {
        snprintf(why, why_size, "not a serial port: %s", strerror(errno));
        return -ENOTTY;
    }
    cfmakeraw(&tio);
    tio.c_cflag |= CLOCAL | CREAD;
    tio.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | PARODD | CSTOPB | CRTSCTS);
    tio.c_cflag |= CS8;
    if (rtu->cfg.parity != MB_RTU_PARITY_NONE)
        tio.c_cflag |= PARENB;
    if (rtu->cfg.parity == MB_RTU_PARITY_ODD)
        tio.c_cflag |= PARODD;
    if (rtu->cfg.stop_bits == 2)
        tio.c_cflag |= CSTOPB;
    tio.c_iflag &= ~(tcflag_t)(IXON | IXOFF | IXANY);
    /* VMIN 1: with O_NONBLOCK a read with nothing to give fails with
     * EAGAIN, and 0 means end of file (a hangup); VMIN 0 would return 0. */
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    if (speed == B0 || cfsetispeed(&tio, speed) < 0 || cfsetospeed(&tio, speed) < 0) {
        snprintf(why, why_size, "baud %u is not supported", rtu->cfg.baud);
        return -ENOTTY;
    }
    int rc = tcsetattr(fd, TCSANOW, &tio);
    if (rc < 0 && errno == EINVAL && (tio.c_cflag & PARENB) && is_pseudo_terminal(fd)) {
        /* Some kernels refuse a parity bit on a pty, which has no wire for
         * it to be on: the same line without it. */
        tio.c_cflag &= ~(tcflag_t)(PARENB | PARODD);
        rc = tcsetattr(fd, TCSANOW, &tio);
    }
    if (rc < 0) {
        snprintf(why, why_size, "cannot set baud %u: %s", rtu->cfg.baud, strerror(errno));
        return -ENOTTY;
    }
    return finish_setup(rtu, fd, why, why_size);
}

/* The USB serial adapter's latency timer (ms) in sysfs, for the tty 'st'
 * names: the FTDI driver's (ftdi_sio) on the usb-serial port, which is the
 * tty's "device". 'value' NULL: reads it; else writes it first. Returns the
 * value read, or -1 where there is none (another driver, a pty, a UART). */
static int latency_timer(const struct mb_rtu *rtu, const struct stat *st, const char *value)
{
    char path[160], text[16];
    int fd, ms = -1;

    snprintf(path, sizeof(path), "%s/dev/char/%u:%u/device/latency_timer", rtu->sysfs_root,
             major(st->st_rdev), minor(st->st_rdev));
    /* O_TRUNC as a shell's "echo 1 >" does: sysfs takes it. */
    if (value && (fd = open(path, O_WRONLY | O_TRUNC | O_CLOEXEC)) >= 0) {
        /* Refused without the right to write it: what is read back holds. */
        if (write(fd, value, strlen(value)) < 0)
            log_info("rtu: %s: cannot set the adapter's latency timer to %s ms: %s",
                     rtu->device, value, strerror(errno));
        close(fd);
    }
    if ((fd = open(path, O_RDONLY | O_CLOEXEC)) < 0)
        return -1;
    ssize_t n = read(fd, text, sizeof(text) - 1);
    close(fd);
    if (n > 0) {
        text[n] = 0;
        if (sscanf(text, "%d", &ms) != 1 || ms < 0 || ms > 255)
            ms = -1;
    }
    return ms;
}

/*
 * A USB adapter hands over what it received in packets, a partial one
 * only when its latency timer runs out (FTDI: 16 ms by default): a gap
 * the host sees may be that timer, not a silence on the wire. Asks for low
 * latency where the driver allows (ASYNC_LOW_LATENCY, which ftdi_sio
 * turns into a 1 ms timer; its sysfs latency_timer set to 1), reads the
 * bound back from sysfs where it exists, else takes [rtu] delivery_ms, and
 * gives the line that bound beyond a FIFO's 4-character timeout and the
 * host's own delivery (MB_RTU_DELIVERY_NS).
 */
static void set_up_delivery(struct mb_rtu *rtu, int fd)
{
    struct serial_struct ss;
    struct stat st;
    int ms = -1;

    memset(&ss, 0, sizeof(ss));
    if (ioctl(fd, TIOCGSERIAL, &ss) == 0 && !(ss.flags & ASYNC_LOW_LATENCY)) {
        ss.flags |= ASYNC_LOW_LATENCY;
        (void)ioctl(fd, TIOCSSERIAL, &ss); /* a refusal: the bound read back holds */
    }
    if (fstat(fd, &st) == 0 && S_ISCHR(st.st_mode)) {
        ms = latency_timer(rtu, &st, NULL);
        if (ms > 1)
            ms = latency_timer(rtu, &st, "1");
    }
    rtu->delivery_source = ms >= 0 ? "the adapter's latency timer" : "[rtu] delivery_ms";
    rtu->delivery_bound_ms = ms >= 0 ? (uint32_t)ms : rtu->cfg.delivery_ms;
    rtu->line.cfg.delivery_ns =
        4ull * rtu->char_ns + MB_RTU_DELIVERY_NS + rtu->delivery_bound_ms * 1000000ull;
}

static void on_serial(uv_poll_t *p, int status, int events);

/*
 * A serial port has one owner: two masters' frames on one line split it
 * (each gets some of the replies) and two robots' commands mix. The lock is
 * the one pyserial's exclusive=True and other Linux serial programs take,
 * flock() on the device, held while it is open; TIOCEXCL then refuses any
 * later open(2) of the tty by a program that does not lock (but root's).
 * -ENOTTY with 'why' when another program has it: a configuration error,
 * never a line fault retried in silence.
 */
static int own_port(int fd, char *why, size_t why_size)
{
    if (flock(fd, LOCK_EX | LOCK_NB) < 0) {
        if (errno == EWOULDBLOCK) {
            snprintf(why, why_size, "the port is taken: another program (another gateway "
                                    "whose [rtu] device is this port?) holds its lock");
            return -ENOTTY;
        }
        snprintf(why, why_size, "cannot lock the port: %s", strerror(errno));
        return -errno;
    }
    if (ioctl(fd, TIOCEXCL) < 0 && errno != ENOTTY) {
        snprintf(why, why_size, "cannot make the port exclusive (TIOCEXCL): %s",
                 strerror(errno));
        return -ENOTTY;
    }
    return 0;
}

/* Opens and sets up the device. 0, -ENOTTY (why set) or -errno (why set). */
static int open_line(struct mb_rtu *rtu, char *why, size_t why_size)
{
    int fd = open(rtu->device, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    int rc;

    if (fd < 0 && errno == EBUSY) {
        /* TIOCEXCL of the program that has it. */
        snprintf(why, why_size, "the port is taken: another program has it open "
                                "exclusively (TIOCEXCL)");
        return -ENOTTY;
    }
    if (fd < 0) {
        rc = -errno;
        snprintf(why, why_size, "%s", strerror(errno));
        return rc;
    }
    rc = own_port(fd, why, why_size);
    if (rc == 0)
        rc = configure_port(rtu, fd, why, why_size);
    if (rc == 0) {
        rc = uv_poll_init(rtu->loop, &rtu->serial, fd);
        if (rc < 0)
            snprintf(why, why_size, "cannot watch it: %s", uv_strerror(rc));
    }
    if (rc < 0) {
        close(fd);
        return rc;
    }
    rtu->fd = fd;
    rtu->serial.data = rtu;
    rtu->serial_handle = true;
    rtu->open_handles++;
    rtu->tx_count = 0;
    rtu->tx_waiting = false;
    /* Perhaps another adapter: nothing of the old conversation holds. A
     * pty has no wire: what is written is delivered at once. */
    rtu->line.cfg.tx_char_ns = is_pseudo_terminal(fd) ? 0 : rtu->char_ns;
    set_up_delivery(rtu, fd);
    rtu_line_reset(&rtu->line);
    /* Flushed just now: what is read later came after this. */
    rtu->seen_empty_ns = rtu->now_ns();
    uv_poll_start(&rtu->serial, UV_READABLE, on_serial);
    return 0;
}

static void maybe_finish_close(struct mb_rtu *rtu)
{
    if (rtu->closing && rtu->open_handles == 0 && rtu->close_cb)
        rtu->close_cb(rtu);
}

static void on_handle_closed(uv_handle_t *h)
{
    struct mb_rtu *rtu = h->data;

    if (h == (uv_handle_t *)&rtu->serial)
        rtu->serial_closing = false;
    rtu->open_handles--;
    maybe_finish_close(rtu);
}

static void set_silence_timer(struct mb_rtu *rtu, uint64_t at_ns)
{
    struct itimerspec its;

    memset(&its, 0, sizeof(its));
    if (at_ns) {
        its.it_value.tv_sec = (time_t)(at_ns / 1000000000ull);
        its.it_value.tv_nsec = (long)(at_ns % 1000000000ull);
    }
    timerfd_settime(rtu->timer_fd, at_ns ? TFD_TIMER_ABSTIME : 0, &its, NULL);
}

/* Stops serving the port and closes it; the server's client goes too. */
static void close_line(struct mb_rtu *rtu)
{
    if (rtu->client)
        mb_client_release(rtu->client, NULL); /* 'closed' clears rtu->client */
    if (rtu->fd < 0)
        return;
    uv_poll_stop(&rtu->serial);
    rtu->serial_handle = false;
    rtu->serial_closing = true;
    uv_close((uv_handle_t *)&rtu->serial, on_handle_closed);
    close(rtu->fd);
    rtu->fd = -1;
    rtu_line_reset(&rtu->line);
    rtu->tx_count = 0;
    set_silence_timer(rtu, 0);
}

static void on_retry(uv_timer_t *t)
{
    struct mb_rtu *rtu = t->data;
    char why[200];

    if (rtu->closing || rtu->fd >= 0 || rtu->serial_closing)
        return; /* the previous handle is still closing: next second */
    int rc = open_line(rtu, why, sizeof(why));
    if (rc == -ENOTTY && rtu->retry_error != rc)
        /* The device is back but refuses the settings (another adapter,
         * one without RS-485 mode): not the absence said when it failed. */
        log_err("rtu: device %s: %s; trying again every second", rtu->device, why);
    rtu->retry_error = rc;
    if (rc != 0)
        return; /* said once when it failed */
    uv_timer_stop(&rtu->retry);
    log_notice("rtu: %s: line up again (%u baud, unit %u)", rtu->device, rtu->cfg.baud,
               rtu->cfg.unit_id);
}

static void start_retry(struct mb_rtu *rtu)
{
    uv_timer_start(&rtu->retry, on_retry, RETRY_MS, RETRY_MS);
}

/* The device failed: one line, the state, a new open every second. */
static void line_fault(struct mb_rtu *rtu, const char *why)
{
    if (rtu->fd < 0 || rtu->closing)
        return;
    log_warn("rtu: %s: %s: line down; opening it again every second", rtu->device, why);
    close_line(rtu);
    start_retry(rtu);
}

static void sync_stats(struct mb_rtu *rtu)
{
    const struct rtu_line_stats *l = &rtu->line.stats;
    rtu->stats.frames = l->frames;
    rtu->stats.crc_errors = l->crc_errors;
    rtu->stats.foreign_frames = l->foreign_frames;
    rtu->stats.broadcasts = l->broadcasts;
    rtu->stats.gap_discards = l->gap_discards;
    rtu->stats.echoes = l->echoes;
    rtu->stats.collisions = l->collisions;
    rtu->stats.out_of_turn = l->out_of_turn;
    rtu->stats.repeats = l->repeats;
    rtu->stats.exceptions = l->exceptions;
    /* overruns: the line's receive overruns and the replies not taken */
}

/* The timerfd fires at the line's next deadline: the silence that ends
 * the chunk being received, or the time a queued reply may start. */
static void arm_timer(struct mb_rtu *rtu)
{
    uint64_t at = rtu_line_deadline(&rtu->line);
    /* Looks at the port when our turn ends (our reply's end plus t3.5)
     * and when the delivery bound after it ends: found empty then, what
     * comes later surely came after it, and a frame equal to our reply is
     * the master's request; bytes found there may be our reply heard back.
     * And, with local_echo, when the rest of an echo that came in part is
     * late: found empty then, the echo was spoiled. */
    const uint64_t looks[] = {rtu_line_tx_ready_ns(&rtu->line),
                              rtu_line_bound_end_ns(&rtu->line),
                              rtu_line_echo_look_ns(&rtu->line)};

    for (size_t i = 0; i < sizeof(looks) / sizeof(looks[0]); i++)
        if (looks[i] && rtu->seen_empty_ns < looks[i] && (!at || looks[i] < at))
            at = looks[i];

    if (rtu->tx_count && !rtu->tx_waiting) {
        uint64_t ready = rtu_line_tx_ready_ns(&rtu->line);
        if (ready && (!at || ready < at))
            at = ready;
    }
    set_silence_timer(rtu, at);
}

/*
 * Writes the queued replies: each starts only t3.5 after the one before
 * left the wire, and only once the one before went to the port whole; the
 * rest waits for the port to be writable or for the timer.
 */
static void flush_tx(struct mb_rtu *rtu)
{
    bool was_waiting = rtu->tx_waiting;

    rtu->tx_waiting = false;
    while (rtu->tx_count && rtu->fd >= 0) {
        struct mb_rtu_tx_frame *f = &rtu->tx[0];
        uint64_t now = rtu->now_ns();
        if (f->sent == 0) {
            uint64_t ready = rtu_line_tx_ready_ns(&rtu->line);
            if (ready && now < ready)
                break; /* the timer starts it */
        }
        ssize_t n = write(rtu->fd, f->data + f->sent, f->size - f->sent);
        if (n > 0) {
            if (f->sent == 0) {
                rtu_line_frame_out(&rtu->line, f->data, f->size);
                uint64_t us = now > rtu->request_end_ns ? (now - rtu->request_end_ns) / 1000 : 0;
                rtu->stats.turnaround_us = us > UINT32_MAX ? UINT32_MAX : (uint32_t)us;
                if (rtu->stats.turnaround_us > rtu->stats.turnaround_max_us)
                    rtu->stats.turnaround_max_us = rtu->stats.turnaround_us;
            }
            rtu_line_bytes_out(&rtu->line, (size_t)n, now);
            f->sent += (size_t)n;
            if (f->sent == f->size) {
                rtu->tx_count--;
                memmove(&rtu->tx[0], &rtu->tx[1], rtu->tx_count * sizeof(rtu->tx[0]));
            }
            continue;
        }
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            rtu->tx_waiting = true;
            break;
        }
        line_fault(rtu, n < 0 ? strerror(errno) : "write failed");
        return;
    }
    /* The poll changes only when a reply waits for the port, or waited:
     * nearly every reply goes out whole and costs no epoll_ctl. */
    if (rtu->fd >= 0 && rtu->tx_waiting != was_waiting)
        uv_poll_start(&rtu->serial, rtu->tx_waiting ? UV_READABLE | UV_WRITABLE : UV_READABLE,
                      on_serial);
    if (rtu->fd >= 0)
        arm_timer(rtu);
}

/* The server's reply (an MBAP frame) goes out as an RTU frame. */
static void rtu_output(void *state, struct mb_client *c, const uint8_t *data, size_t size)
{
    struct mb_rtu *rtu = state;
    size_t pdu_size = size - MBAP_SIZE;
    uint64_t suppressed;

    (void)c;
    if (rtu->fd < 0 || size <= MBAP_SIZE || pdu_size > RTU_MAX_ADU - 3)
        return;
    if (rtu->tx_count == MB_RTU_TX_FRAMES) {
        rtu->stats.overruns++;
        if (log_ratelimit_pass(&rtu->log_limit, uv_now(rtu->loop), &suppressed))
            log_warn("rtu: %s: the port does not take replies: one dropped", rtu->device);
        return;
    }
    uint8_t *frame = rtu->tx[rtu->tx_count].data;
    frame[0] = (uint8_t)rtu->cfg.unit_id;
    memcpy(frame + 1, data + MBAP_SIZE, pdu_size);
    /* Report server id names the unit asked for: the line's. */
    if (frame[1] == 17 && pdu_size >= 3)
        frame[3] = (uint8_t)rtu->cfg.unit_id;
    rtu->tx[rtu->tx_count].size = rtu_append_crc(frame, 1 + pdu_size);
    rtu->tx[rtu->tx_count].sent = 0;
    rtu->tx_count++;
    rtu->stats.replies++;
    if (!rtu->tx_waiting)
        flush_tx(rtu);
}

static void rtu_closed(void *state, struct mb_client *c, bool was_pending)
{
    struct mb_rtu *rtu = state;
    (void)was_pending;
    if (rtu->client == c)
        rtu->client = NULL;
}

const struct mb_transport mb_transport_rtu = {
    .name = "rtu",
    .stats_slot = 2,
    .output = rtu_output,
    .closed = rtu_closed,
};

/* A request for this unit that the conversation made certain: to the
 * server, as a TCP client's. */
static void on_request(void *user, const uint8_t *frame, size_t size)
{
    struct mb_rtu *rtu = user;
    unsigned unit = frame[0];
    size_t pdu_size = size - 3, room;
    uint64_t suppressed;
    uint8_t *into;

    if (rtu->fd < 0)
        return; /* the line failed meanwhile */
    rtu->request_end_ns = rtu->line.last_rx_ns;
    if (!rtu->client) {
        int rc = mb_server_attach(rtu->srv, rtu->peer, &mb_transport_rtu, rtu, rtu->cfg.rights,
                                  rtu->cfg.active_ms, &rtu->client);
        if (rc < 0) {
            if (rc != -ESHUTDOWN &&
                log_ratelimit_pass(&rtu->log_limit, uv_now(rtu->loop), &suppressed))
                log_err("rtu: %s: cannot serve a request: %s", rtu->device, strerror(-rc));
            return;
        }
    }
    into = mb_client_space(rtu->client, &room);
    if (room < MBAP_SIZE + pdu_size)
        return; /* not reached: the server consumes every whole request */
    rtu->transaction++;
    into[0] = (uint8_t)(rtu->transaction >> 8);
    into[1] = (uint8_t)rtu->transaction;
    into[2] = into[3] = 0;
    into[4] = (uint8_t)((pdu_size + 1) >> 8);
    into[5] = (uint8_t)(pdu_size + 1);
    /* The server judges the unit id of [modbus] unit_id; the line has
     * already judged its own. */
    into[6] = rtu->srv->cfg.unit_id >= 0 ? (uint8_t)rtu->srv->cfg.unit_id : (uint8_t)unit;
    memcpy(into + MBAP_SIZE, frame + 1, pdu_size);
    mb_client_received(rtu->client, MBAP_SIZE + pdu_size);
}

/* What the line noticed about our own transmissions, said once each. */
static const char *const event_text[RTU_EVENT_COUNT] = {
    [RTU_EVENT_ECHO] = "a reply came back as it was sent (the adapter echoes): skipped; "
                       "set [rtu] local_echo = true for this adapter",
    [RTU_EVENT_REPEAT] = "a frame equal to the last reply came within the adapter's delivery "
                         "bound: answered again, not acted on again (a master retrying at "
                         "once, or the adapter echoing: then set [rtu] local_echo = true)",
    [RTU_EVENT_COLLISION] = "a reply came back different from what was sent: another "
                            "transmitter on the line at the same time (collision); counted",
    [RTU_EVENT_NO_ECHO] = "local_echo = true, but a reply did not come back: does this "
                          "adapter echo?",
};

static void on_event(void *user, enum rtu_event event)
{
    struct mb_rtu *rtu = user;

    /* With local_echo the echo is expected: nothing to say. */
    if (event >= RTU_EVENT_COUNT || rtu->event_logged[event] ||
        (event == RTU_EVENT_ECHO && rtu->cfg.local_echo))
        return;
    rtu->event_logged[event] = true;
    log_warn("rtu: %s: %s", rtu->device, event_text[event]);
}

/* The master sent our last reply's bytes again within the delivery bound
 * (rtu_frame.h): the same reply again, nothing acted on. */
static void on_repeat(void *user)
{
    struct mb_rtu *rtu = user;
    uint64_t suppressed;

    if (rtu->fd < 0 || !rtu->line.sent_size)
        return;
    if (rtu->tx_count == MB_RTU_TX_FRAMES) {
        rtu->stats.overruns++;
        if (log_ratelimit_pass(&rtu->log_limit, uv_now(rtu->loop), &suppressed))
            log_warn("rtu: %s: the port does not take replies: one dropped", rtu->device);
        return;
    }
    struct mb_rtu_tx_frame *f = &rtu->tx[rtu->tx_count++];
    memcpy(f->data, rtu->line.sent, rtu->line.sent_size);
    f->size = rtu->line.sent_size;
    f->sent = 0;
    rtu->request_end_ns = rtu->line.last_rx_ns;
    rtu->stats.replies++;
    if (!rtu->tx_waiting)
        flush_tx(rtu);
}

static struct rtu_line_hooks line_hooks_of(struct mb_rtu *rtu)
{
    struct rtu_line_hooks hooks = {
        .request = on_request, .event = on_event, .repeat = on_repeat, .user = rtu};
    return hooks;
}

/* Reads what the port holds. Returns the bytes read, or -1 on a fault. */
static ssize_t read_line(struct mb_rtu *rtu)
{
    uint8_t buf[512];
    ssize_t total = 0;
    struct rtu_line_hooks hooks = line_hooks_of(rtu);

    while (rtu->fd >= 0) {
        uint64_t before = rtu->now_ns();
        ssize_t n = read(rtu->fd, buf, sizeof(buf));
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            rtu->seen_empty_ns = before; /* what comes next came after this */
            break;
        }
        if (n <= 0) {
            line_fault(rtu, n < 0 ? strerror(errno) : "hung up");
            return -1;
        }
        uint64_t overruns = rtu->line.stats.overruns;
        rtu_line_input_read(&rtu->line, buf, (size_t)n, rtu->now_ns(), rtu->seen_empty_ns,
                            &hooks);
        rtu->stats.overruns += rtu->line.stats.overruns - overruns;
        total += n;
        /* A terminal gives all it holds, up to the size asked: less means
         * nothing is left, and the poll says when more comes. */
        if ((size_t)n < sizeof(buf))
            break;
    }
    sync_stats(rtu);
    if (total > 0 && rtu->fd >= 0)
        arm_timer(rtu);
    return total;
}

static void on_serial(uv_poll_t *p, int status, int events)
{
    struct mb_rtu *rtu = p->data;

    if (status < 0) {
        /* libuv says EBADF for any POLLERR: a read tells what happened (EIO
         * when the other end of a pty went, or a USB adapter was pulled). */
        if (read_line(rtu) >= 0)
            line_fault(rtu, "the device reports an error");
        return;
    }
    if (events & UV_WRITABLE)
        flush_tx(rtu);
    if (rtu->fd >= 0 && (events & (UV_READABLE | UV_DISCONNECT)))
        read_line(rtu);
}

static void on_silence(uv_poll_t *p, int status, int events)
{
    struct mb_rtu *rtu = p->data;
    uint64_t expirations;
    struct rtu_line_hooks hooks = line_hooks_of(rtu);

    (void)status, (void)events;
    if (read(rtu->timer_fd, &expirations, sizeof(expirations)) < 0 && errno == EAGAIN)
        return;
    if (rtu->fd < 0 || rtu->closing)
        return;
    /* Bytes that have arrived count before the silence is judged. */
    if (read_line(rtu) < 0)
        return;
    rtu_line_silence(&rtu->line, rtu->now_ns(), &hooks);
    sync_stats(rtu);
    if (rtu->fd < 0)
        return;
    if (rtu->tx_count && !rtu->tx_waiting)
        flush_tx(rtu); /* also arms the timer */
    else
        arm_timer(rtu);
}

int mb_rtu_start(uv_loop_t *loop, struct mb_rtu *rtu, struct mb_server *srv,
                 const struct mb_rtu_config *cfg)
{
    char why[200];
    int rc;

    memset(rtu, 0, sizeof(*rtu));
    rtu->loop = loop;
    rtu->srv = srv;
    rtu->fd = -1;
    rtu->timer_fd = -1;
    if (!cfg->device || !cfg->device[0] || strlen(cfg->device) >= sizeof(rtu->device) ||
        cfg->unit_id < 1 || cfg->unit_id > 247)
        return -EINVAL;
    rtu->cfg = *cfg;
    snprintf(rtu->device, sizeof(rtu->device), "%s", cfg->device);
    rtu->cfg.device = rtu->device;
    snprintf(rtu->peer, sizeof(rtu->peer), "rtu:%s", cfg->device);
    rtu->log_limit.interval_ms = 1000;
    rtu->now_ns = monotonic_ns;
    rtu->sysfs_root = cfg->sysfs_root ? cfg->sysfs_root : "/sys";
    rtu->delivery_bound_ms = cfg->delivery_ms;
    rtu->delivery_source = "[rtu] delivery_ms";
    rtu->char_ns = (uint32_t)((1 + 8 + (cfg->parity != MB_RTU_PARITY_NONE) + cfg->stop_bits) *
                              1000000000ull / (cfg->baud ? cfg->baud : 19200));
    struct rtu_line_config line_cfg = {
        .unit_id = cfg->unit_id,
        .char_ns = rtu->char_ns,
        .tx_char_ns = rtu->char_ns,
        .delivery_ns = 4ull * rtu->char_ns + MB_RTU_DELIVERY_NS + cfg->delivery_ms * 1000000ull,
        .local_echo = cfg->local_echo,
    };
    rtu_char_times(cfg->baud, cfg->parity != MB_RTU_PARITY_NONE, cfg->stop_bits, &line_cfg.t15_ns,
                   &line_cfg.t35_ns);
    rtu_line_init(&rtu->line, &line_cfg);

    uv_timer_init(loop, &rtu->retry);
    rtu->retry.data = rtu;
    rtu->open_handles++;
    rtu->timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    if (rtu->timer_fd < 0) {
        rc = -errno;
        log_err("rtu: cannot make a timer: %s", strerror(errno));
        return rc;
    }
    rc = uv_poll_init(loop, &rtu->silence, rtu->timer_fd);
    if (rc < 0) {
        log_err("rtu: cannot watch the timer: %s", uv_strerror(rc));
        close(rtu->timer_fd);
        rtu->timer_fd = -1;
        return rc;
    }
    rtu->silence.data = rtu;
    rtu->open_handles++;
    uv_poll_start(&rtu->silence, UV_READABLE, on_silence);

    rc = open_line(rtu, why, sizeof(why));
    if (rc == -ENOTTY) {
        log_err("rtu: device %s: %s", rtu->device, why);
        return rc;
    }
    if (rc < 0) {
        log_warn("rtu: %s: %s: line down; opening it again every second", rtu->device, why);
        start_retry(rtu);
        return 0;
    }
    log_notice("rtu: %s: %u baud, parity %s, %u stop bit%s, unit %u%s%s; t1.5 %u us, "
               "t3.5 %u us; delivery bound %u ms (%s)",
               rtu->device, cfg->baud,
               cfg->parity == MB_RTU_PARITY_NONE   ? "none"
               : cfg->parity == MB_RTU_PARITY_EVEN ? "even"
                                                   : "odd",
               cfg->stop_bits, cfg->stop_bits == 1 ? "" : "s", cfg->unit_id,
               cfg->rs485 ? ", RS-485 mode" : "", cfg->local_echo ? ", local echo" : "",
               rtu->line.cfg.t15_ns / 1000, rtu->line.cfg.t35_ns / 1000,
               rtu->delivery_bound_ms, rtu->delivery_source);
    return 0;
}

enum mb_rtu_state mb_rtu_state(const struct mb_rtu *rtu)
{
    if (rtu->fd < 0)
        return MB_RTU_FAULT;
    return rtu->client ? MB_RTU_POLLED : MB_RTU_IDLE;
}

void mb_rtu_clear_stats(struct mb_rtu *rtu)
{
    memset(&rtu->stats, 0, sizeof(rtu->stats));
    memset(&rtu->line.stats, 0, sizeof(rtu->line.stats));
}

void mb_rtu_close(struct mb_rtu *rtu, void (*cb)(struct mb_rtu *rtu))
{
    rtu->closing = true;
    rtu->close_cb = cb;
    close_line(rtu);
    if (rtu->open_handles == 0) {
        maybe_finish_close(rtu);
        return;
    }
    if (rtu->timer_fd >= 0) {
        uv_close((uv_handle_t *)&rtu->silence, on_handle_closed);
        close(rtu->timer_fd);
        rtu->timer_fd = -1;
    }
    uv_close((uv_handle_t *)&rtu->retry, on_handle_closed);
}
