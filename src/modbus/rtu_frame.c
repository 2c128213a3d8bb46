/* SPDX-License-Identifier: MIT */
/* rtu_frame.c - see rtu_frame.h. */
#include "rtu_frame.h"

#include <string.h>

/* The CRC of every byte value, so that a byte costs one lookup and a shift
 * instead of eight shifts (the approach of libmodbus and of the Modbus
 * serial line specification's appendix, here as one 16-bit table). */
static const uint16_t crc_table[256] = {
    0x0000, 0xC0C1, 0xC181, 0x0140, 0xC301, 0x03C0, 0x0280, 0xC241,
    0xC601, 0x06C0, 0x0780, 0xC741, 0x0500, 0xC5C1, 0xC481, 0x0440,
    0xCC01, 0x0CC0, 0x0D80, 0xCD41, 0x0F00, 0xCFC1, 0xCE81, 0x0E40,
    0x0A00, 0xCAC1, 0xCB81, 0x0B40, 0xC901, 0x09C0, 0x0880, 0xC841,
    0xD801, 0x18C0, 0x1980, 0xD941, 0x1B00, 0xDBC1, 0xDA81, 0x1A40,
    0x1E00, 0xDEC1, 0xDF81, 0x1F40, 0xDD01, 0x1DC0, 0x1C80, 0xDC41,
    0x1400, 0xD4C1, 0xD581, 0x1540, 0xD701, 0x17C0, 0x1680, 0xD641,
    0xD201, 0x12C0, 0x1380, 0xD341, 0x1100, 0xD1C1, 0xD081, 0x1040,
    0xF001, 0x30C0, 0x3180, 0xF141, 0x3300, 0xF3C1, 0xF281, 0x3240,
    0x3600, 0xF6C1, 0xF781, 0x3740, 0xF501, 0x35C0, 0x3480, 0xF441,
    0x3C00, 0xFCC1, 0xFD81, 0x3D40, 0xFF01, 0x3FC0, 0x3E80, 0xFE41,
    0xFA01, 0x3AC0, 0x3B80, 0xFB41, 0x3900, 0xF9C1, 0xF881, 0x3840,
    0x2800, 0xE8C1, 0xE981, 0x2940, 0xEB01, 0x2BC0, 0x2A80, 0xEA41,
    0xEE01, 0x2EC0, 0x2F80, 0xEF41, 0x2D00, 0xEDC1, 0xEC81, 0x2C40,
    0xE401, 0x24C0, 0x2580, 0xE541, 0x2700, 0xE7C1, 0xE681, 0x2640,
    0x2200, 0xE2C1, 0xE381, 0x2340, 0xE101, 0x21C0, 0x2080, 0xE041,
    0xA001, 0x60C0, 0x6180, 0xA141, 0x6300, 0xA3C1, 0xA281, 0x6240,
    0x6600, 0xA6C1, 0xA781, 0x6740, 0xA501, 0x65C0, 0x6480, 0xA441,
    0x6C00, 0xACC1, 0xAD81, 0x6D40, 0xAF01, 0x6FC0, 0x6E80, 0xAE41,
    0xAA01, 0x6AC0, 0x6B80, 0xAB41, 0x6900, 0xA9C1, 0xA881, 0x6840,
    0x7800, 0xB8C1, 0xB981, 0x7940, 0xBB01, 0x7BC0, 0x7A80, 0xBA41,
    0xBE01, 0x7EC0, 0x7F80, 0xBF41, 0x7D00, 0xBDC1, 0xBC81, 0x7C40,
    0xB401, 0x74C0, 0x7580, 0xB541, 0x7700, 0xB7C1, 0xB681, 0x7640,
    0x7200, 0xB2C1, 0xB381, 0x7340, 0xB101, 0x71C0, 0x7080, 0xB041,
    0x5000, 0x90C1, 0x9181, 0x5140, 0x9301, 0x53C0, 0x5280, 0x9241,
    0x9601, 0x56C0, 0x5780, 0x9741, 0x5500, 0x95C1, 0x9481, 0x5440,
    0x9C01, 0x5CC0, 0x5D80, 0x9D41, 0x5F00, 0x9FC1, 0x9E81, 0x5E40,
    0x5A00, 0x9AC1, 0x9B81, 0x5B40, 0x9901, 0x59C0, 0x5880, 0x9841,
    0x8801, 0x48C0, 0x4980, 0x8941, 0x4B00, 0x8BC1, 0x8A81, 0x4A40,
    0x4E00, 0x8EC1, 0x8F81, 0x4F40, 0x8D01, 0x4DC0, 0x4C80, 0x8C41,
    0x4400, 0x84C1, 0x8581, 0x4540, 0x8701, 0x47C0, 0x4680, 0x8641,
    0x8201, 0x42C0, 0x4380, 0x8341, 0x4100, 0x81C1, 0x8081, 0x4040,
};

uint16_t rtu_crc16(const uint8_t *data, size_t size)
{
    uint16_t crc = 0xFFFF;

    /* (uint8_t) rather than & 0xFF: the same index, one WP can bound. */
    /*@ loop invariant 0 <= i <= size;
        loop assigns i, crc;
        loop variant size - i;
    */
    for (size_t i = 0; i < size; i++)
        crc = (uint16_t)((crc >> 8) ^ crc_table[(uint8_t)(crc ^ data[i])]);
    return crc;
}

bool rtu_crc_ok(const uint8_t *frame, size_t size)
{
    if (size < RTU_MIN_ADU)
        return false;
    uint16_t crc = rtu_crc16(frame, size - 2);
    return frame[size - 2] == (crc & 0xFF) && frame[size - 1] == (crc >> 8);
}

size_t rtu_append_crc(uint8_t *frame, size_t size)
{
    uint16_t crc = rtu_crc16(frame, size);

    frame[size] = (uint8_t)(crc & 0xFF);
    frame[size + 1] = (uint8_t)(crc >> 8);
    return size + 2;
}

void rtu_char_times(unsigned baud, bool parity, unsigned stop_bits, uint32_t *t15_ns,
                    uint32_t *t35_ns)
{
    uint64_t bits = 1 + 8 + (parity ? 1 : 0) + stop_bits;

    if (baud == 0 || baud > 19200) {
        *t15_ns = 750000;
        *t35_ns = 1750000;
        return;
    }
    *t15_ns = (uint32_t)(bits * 1500000000ull / baud);
    *t35_ns = (uint32_t)(bits * 3500000000ull / baud);
}

enum rtu_length rtu_request_length(const uint8_t *d, size_t avail, size_t *size)
{
    /* Where the length depends on a byte count: the offset of that count
     * and the bytes around it. */
    size_t count_at = 0, fixed = 0;

    if (avail < 2) {
        *size = RTU_MIN_ADU;
        return RTU_LENGTH_MORE;
    }
    switch (d[1]) {
    case 1: case 2: case 3: case 4: case 5: case 6:
        *size = 8;
        return RTU_LENGTH_EXACT;
    case 8:
        if (avail < 4) {
            *size = 8;
            return RTU_LENGTH_MORE;
        }
        if (d[2] == 0 && d[3] == 0)
            return RTU_LENGTH_UNKNOWN; /* return query data: any data */
        *size = 8;
        return RTU_LENGTH_EXACT;
    case 7: case 11: case 12: case 17:
        *size = 4;
        return RTU_LENGTH_EXACT;
    case 22:
        *size = 10;
        return RTU_LENGTH_EXACT;
    case 24:
        *size = 6;
        return RTU_LENGTH_EXACT;
    case 15: case 16:
        count_at = 6, fixed = 9;
        break;
    case 20: case 21:
        count_at = 2, fixed = 5;
        break;
    case 23:
        count_at = 10, fixed = 13;
        break;
    case 43:
        if (avail < 3) {
            *size = 7;
            return RTU_LENGTH_MORE;
        }
        if (d[2] != 14)
            return RTU_LENGTH_UNKNOWN; /* 13, CANopen: not a form we know */
        *size = 7;
        return RTU_LENGTH_EXACT;
    default:
        return RTU_LENGTH_UNKNOWN;
    }
    if (avail <= count_at) {
        *size = fixed;
        return RTU_LENGTH_MORE;
    }
    *size = fixed + d[count_at];
    return RTU_LENGTH_EXACT;
}

/* Read device identification's response: MEI type, code, conformity, more
 * follows, next object, the number of objects, then each object's id,
 * length and value. */
/*@ requires rtu_bytes(d, avail) && \valid(size);
    assigns *size;
    ensures rtu_length_told(\result, *size, avail) && \result != RTU_LENGTH_UNKNOWN;
*/
static enum rtu_length device_id_length(const uint8_t *d, size_t avail, size_t *size)
{
    size_t end = 8;

    if (avail < 8) {
        *size = 8 + 2;
        return RTU_LENGTH_MORE;
    }
    /*@ loop invariant 0 <= i <= d[7];
        loop invariant 8 <= end <= 8 + 257 * i;
        loop assigns i, end;
        loop variant d[7] - i;
    */
    for (unsigned i = 0; i < d[7]; i++) {
        if (end + 2 > avail) {
            *size = end + 2 + 2;
            return RTU_LENGTH_MORE;
        }
        end += 2 + (size_t)d[end + 1];
    }
    *size = end + 2;
    return RTU_LENGTH_EXACT;
}

/*
 * The length of a response to function 'fc' that neither the request nor
 * the line's history changes: a fixed size, or its own byte count.
 * RTU_LENGTH_UNKNOWN for the others (each caller knows those its own way).
 */
/*@ requires rtu_bytes(d, avail) && \valid(size);
    assigns *size;
    ensures rtu_length_told(\result, *size, avail);
*/
static enum rtu_length own_length(uint8_t fc, const uint8_t *d, size_t avail, size_t *size)
{
    switch (fc) {
    case 5: case 6: case 11: case 15: case 16:
        *size = 8;
        return RTU_LENGTH_EXACT;
    case 7:
        *size = 5;
        return RTU_LENGTH_EXACT;
    case 22:
        *size = 10;
        return RTU_LENGTH_EXACT;
    case 12: case 17: case 20:
        if (avail < 3) {
            *size = 5;
            return RTU_LENGTH_MORE;
        }
        *size = 5 + (size_t)d[2];
        return RTU_LENGTH_EXACT;
    case 24:
        if (avail < 4) {
            *size = 6;
            return RTU_LENGTH_MORE;
        }
        *size = 6 + ((size_t)d[2] << 8 | d[3]);
        return RTU_LENGTH_EXACT;
    default:
        return RTU_LENGTH_UNKNOWN;
    }
}

enum rtu_length rtu_response_length(const uint8_t *request, size_t request_size,
                                    const uint8_t *d, size_t avail, size_t *size)
{
    /* The quantity a read asks for (23: its read's), where the request
     * holds it: theirs are 8 bytes and more. */
    unsigned count = request_size >= 8 ? request[4] * 256u + request[5] : 0;

    if (avail < 2) {
        *size = 5;
        return RTU_LENGTH_MORE;
    }
    if (d[1] & 0x80) {
        *size = 5; /* an exception */
        return RTU_LENGTH_EXACT;
    }
    switch (request[1]) {
    case 1: case 2:
        if (request_size < 8)
            return RTU_LENGTH_UNKNOWN; /* no quantity: not a request of these */
        *size = 5 + (count + 7) / 8;
        return RTU_LENGTH_EXACT;
    case 3: case 4: case 23: /* 23: the read's count, as for 3 */
        if (request_size < 8)
            return RTU_LENGTH_UNKNOWN;
        *size = 5 + 2 * (size_t)count;
        return RTU_LENGTH_EXACT;
    case 8: /* return query data repeats the request; the others, 8 bytes */
        *size = request[2] == 0 && request[3] == 0 ? request_size : 8;
        return RTU_LENGTH_EXACT;
    case 21:
        *size = request_size; /* the request, repeated */
        return RTU_LENGTH_EXACT;
    case 43:
        return device_id_length(d, avail, size);
    default:
        break; /* after the switch: WP proves its call's assigns there */
    }
    return own_length(request[1], d, avail, size);
}

/*
 * The length of a response at 'd' whose request the line did not hear,
 * from the response's own fields (a byte count, an exception's fixed
 * size); RTU_LENGTH_UNKNOWN where only the request tells (21, FC08's
 * return query data).
 */
/*@ requires rtu_bytes(d, avail) && \valid(size);
    assigns *size;
    ensures rtu_length_told(\result, *size, avail);
*/
static enum rtu_length response_form_length(const uint8_t *d, size_t avail, size_t *size)
{
    if (avail < 3) {
        *size = 5;
        return RTU_LENGTH_MORE;
    }
    if (d[1] & 0x80) {
        *size = 5;
        return RTU_LENGTH_EXACT;
    }
    switch (d[1]) {
    case 1: case 2: case 3: case 4: case 23:
        *size = 5 + (size_t)d[2];
        return RTU_LENGTH_EXACT;
    case 8:
        if (avail < 4) {
            *size = 8;
            return RTU_LENGTH_MORE;
        }
        if (d[2] == 0 && d[3] == 0)
            return RTU_LENGTH_UNKNOWN;
        *size = 8;
        return RTU_LENGTH_EXACT;
    case 43:
        if (d[2] != 14)
            return RTU_LENGTH_UNKNOWN;
        return device_id_length(d, avail, size);
    default:
        break; /* after the switch: WP proves its call's assigns there */
    }
    return own_length(d[1], d, avail, size);
}

/* ---- the line as a conversation ---- */

void rtu_line_init(struct rtu_line *line, const struct rtu_line_config *cfg)
{
    memset(line, 0, sizeof(*line));
    line->cfg = *cfg;
    line->conv = RTU_CONV_UNSYNCED;
}

static void clear_chunk(struct rtu_line *line)
{
    line->rx_used = 0;
    line->gap_count = 0;
    line->chunk_open = false;
    line->rx_overrun = false;
    line->echo_broken = false;
    line->waited = false;
    line->judge_at_ns = 0;
    line->chunk_after_ns = 0;
}

void rtu_line_reset(struct rtu_line *line)
{
    clear_chunk(line);
    line->conv = RTU_CONV_UNSYNCED;
    line->echo_pending = false;
}

static void emit(const struct rtu_line_hooks *hooks, enum rtu_event event)
{
    if (hooks && hooks->event)
        hooks->event(hooks->user, event);
}

#define GAP_AT(g) ((size_t)((g) & ~RTU_GAP_WAITED))

/* Is the chunk's last boundary at its end (before the bytes to come)? */
static bool gap_at_end(const struct rtu_line *line)
{
    return line->gap_count && GAP_AT(line->gaps[line->gap_count - 1]) == line->rx_used;
}

static void add_gap_at_end(struct rtu_line *line, uint16_t flags)
{
    if (line->gap_count < RTU_LINE_MAX_GAPS && line->rx_used < RTU_GAP_WAITED && !gap_at_end(line))
        line->gaps[line->gap_count++] = (uint16_t)(line->rx_used | flags);
}

/* Bytes that are the line's input (not our echo), read at 'now_ns',
 * arrived after 'after_ns'. */
static void append(struct rtu_line *line, const uint8_t *data, size_t size, uint64_t now_ns,
                   uint64_t after_ns)
{
    if (size == 0)
        return;
    /* The silence the line surely had before these bytes: the time since
     * the last read once their own wire time and the port's delivery are
     * taken off (a UART hands over its FIFO every 8 characters, further
     * apart than t3.5 at 19200 baud, with no pause on the wire). */
    uint64_t since = now_ns - line->last_rx_ns,
             own = (uint64_t)size * line->cfg.char_ns + line->cfg.delivery_ns;
    uint64_t silence = !line->last_rx_ns ? UINT64_MAX : since > own ? since - own : 0;
    /* A reader late for the chunk's silence (a stalled loop: the bytes may
     * have come right after the last ones, long before this read) proves
     * no silence before them. */
    if (line->chunk_open && now_ns > line->judge_at_ns)
        silence = 0;
    if (!line->chunk_open) {
        line->first_rx_ns = now_ns;
        line->chunk_after_ns = after_ns < now_ns ? after_ns : now_ns;
        line->chunk_open = true;
        line->silence_before = silence >= line->cfg.t35_ns;
    } else if (line->rx_used) {
        /* A silence waited past here was the port's delay unless the line
         * surely was silent for t3.5. */
        if (gap_at_end(line) && silence < line->cfg.t35_ns)
            line->gap_count--;
        /* A sure silence of t3.5: a frame may start here. A pause longer
         * than t1.5: a frame across either is discarded. */
        if (silence >= line->cfg.t35_ns)
            add_gap_at_end(line, RTU_GAP_WAITED);
        else if (silence > line->cfg.t15_ns)
            add_gap_at_end(line, 0);
    }
    if (line->rx_overrun || line->rx_used + size > sizeof(line->rx)) {
        if (!line->rx_overrun)
            line->stats.overruns++;
        line->rx_overrun = true;
        line->rx_used = 0;
        line->gap_count = 0;
    } else {
        memcpy(line->rx + line->rx_used, data, size);
        line->rx_used += size;
    }
    line->last_rx_ns = now_ns;
    line->judge_at_ns = now_ns + line->cfg.t35_ns;
    line->waited = false;
}

/* Local echo: part of our frame came back and the line surely fell silent
 * since: the reader found the port empty at 'after_ns', t3.5 beyond the
 * port's delivery after those bytes were read (judged from that look, not
 * from a read that a stalled loop makes late). The rest is not coming. */
static bool echo_stalled(const struct rtu_line *line, uint64_t after_ns)
{
    return after_ns >= line->echo_last_ns + line->cfg.delivery_ns + line->cfg.t35_ns;
}

/*
 * Local echo: takes what comes back of our frame off the input. Returns
 * the bytes consumed. The bytes are judged by when they can have come
 * (after 'after_ns', the reader's last look at an empty port), not by
 * when they were read: a loop that stalls, or reads half an echo and then
 * stalls, still takes the echo off. Where the input differs from our
 * frame, what matched of it is input again: a master's request starts as
 * our reply did (unit id, function), so a request on an adapter that gave
 * nothing back is read as a request; a collision leaves bytes that are no
 * frame, and the chunk's judgement (end_chunk) counts it.
 */
static size_t take_echo(struct rtu_line *line, const uint8_t *data, size_t size, uint64_t now_ns,
                        uint64_t after_ns, const struct rtu_line_hooks *hooks)
{
    size_t used = 0;

    if (line->echo_at && echo_stalled(line, after_ns)) {
        /* Part of our frame came back, then the line fell silent: a
         * spoiled echo (a collision). Its bytes are no frame and go; what
         * comes now is the master's. */
        line->echo_pending = false;
        line->stats.collisions++;
        emit(hooks, RTU_EVENT_COLLISION);
        return 0;
    }
    if (after_ns >= line->echo_until_ns) {
        /* Surely not back in its window: what comes now is the master's. */
        line->echo_pending = false;
        line->echo_broken = true;
        append(line, line->sent, line->echo_at, now_ns, after_ns);
        return 0;
    }
    while (used < size && line->echo_pending) {
        if (data[used] == line->sent[line->echo_at]) {
            used++;
            if (++line->echo_at == line->sent_size) {
                line->echo_pending = false;
                line->stats.echoes++;
            }
        } else {
            line->echo_pending = false;
            line->echo_broken = true;
            append(line, line->sent, line->echo_at, now_ns, after_ns);
        }
    }
    if (used)
        line->echo_last_ns = now_ns;
    return used;
}

void rtu_line_input_read(struct rtu_line *line, const uint8_t *data, size_t size, uint64_t now_ns,
                         uint64_t after_ns, const struct rtu_line_hooks *hooks)
{
    if (after_ns > now_ns)
        after_ns = now_ns;
    if (line->echo_pending) {
        size_t echo = take_echo(line, data, size, now_ns, after_ns, hooks);
        data += echo;
        size -= echo;
    }
    append(line, data, size, now_ns, after_ns);
}

void rtu_line_input(struct rtu_line *line, const uint8_t *data, size_t size, uint64_t now_ns,
                    const struct rtu_line_hooks *hooks)
{
    rtu_line_input_read(line, data, size, now_ns, now_ns, hooks);
}

uint64_t rtu_line_deadline(const struct rtu_line *line)
{
    return line->chunk_open ? line->judge_at_ns : 0;
}

/* Is there a pause or a silence strictly inside [from, to)? */
static bool pause_inside(const struct rtu_line *line, size_t from, size_t to)
{
    for (size_t g = 0; g < line->gap_count; g++) {
        size_t at = GAP_AT(line->gaps[g]);
        if (at > from && at < to)
            return true;
    }
    return false;
}

/* Is 'at' after a silence of t3.5 the line is sure of: the chunk's start
 * if one came before it, or a silence proven inside the chunk? */
static bool after_silence(const struct rtu_line *line, size_t at)
{
    if (at == 0)
        return line->silence_before;
    for (size_t g = 0; g < line->gap_count; g++)
        if ((line->gaps[g] & RTU_GAP_WAITED) && GAP_AT(line->gaps[g]) == at)
            return true;
    return false;
}

/* The next sure silence after 'at', or 0. */
static size_t next_silence(const struct rtu_line *line, size_t at)
{
    size_t best = 0;
    for (size_t g = 0; g < line->gap_count; g++) {
        size_t pos = GAP_AT(line->gaps[g]);
        if ((line->gaps[g] & RTU_GAP_WAITED) && pos > at && (!best || pos < best))
            best = pos;
    }
    return best;
}

/* Where a response repeats its request (05, 06: all of it; 15, 16: the
 * address and count), does it? Else the master asking that unit again
 * would pass for the response. */
static bool echoes_request(const uint8_t *request, const uint8_t *rsp, size_t size)
{
    if (rsp[1] & 0x80)
        return true;
    switch (request[1]) {
    case 5: case 6:
        return size == 8 && memcmp(request, rsp, 8) == 0;
    case 15: case 16:
        return memcmp(request, rsp, 6) == 0;
    default:
        return true;
    }
}

/* With local_echo = false: the chunk starts with our last frame, byte
 * for byte, and its first bytes can have arrived within the port's
 * delivery bound after that frame left the wire (judged from the reader's
 * last look at an empty port before them, never from the time of the
 * read): our frame heard back, or the master sending the same bytes at
 * once (rtu_line_bound_end_ns). Returns its size, or 0. With local_echo,
 * take_echo() takes the one echo of each frame off the input instead. */
static size_t echo_at_head(const struct rtu_line *line)
{
    if (line->cfg.local_echo || !line->tx_end_ns || !line->sent_size || line->rx_overrun ||
        line->chunk_after_ns >= rtu_line_bound_end_ns(line) ||
        line->rx_used < line->sent_size || memcmp(line->rx, line->sent, line->sent_size) != 0)
        return 0;
    return line->sent_size;
}

/* Is our last frame also a whole request of ours (05, 06: the reply is
 * the request), so that the master may send the same bytes? */
static bool sent_is_request(const struct rtu_line *line)
{
    size_t len = 0;
    return line->sent_size >= RTU_MIN_ADU && line->sent[0] == line->cfg.unit_id &&
           rtu_request_length(line->sent, line->sent_size, &len) == RTU_LENGTH_EXACT &&
           len == line->sent_size;
}

/* What the walk of a chunk found. */
struct walk {
    enum rtu_conv conv;
    uint8_t await_request[RTU_MAX_ADU];
    size_t await_request_size;
    struct rtu_line_stats stats; /* added to the line's */
    size_t execute_at, execute_size; /* a request of ours, or size 0 */
    size_t missing; /* bytes the tail lacks to be what is expected */
    size_t from;    /* where the walk began (after our echo) */
    bool dropped;   /* something in the chunk was not what was expected */
};

enum frame_kind { FRAME_NONE, FRAME_REQUEST, FRAME_RESPONSE };

/* The length the tail at 'd' ('avail' bytes) lacks to be a frame of the
 * form 'len' says. */
/*@ assigns \nothing;
    ensures \result == 0 || (\result + avail == len && len <= RTU_MAX_ADU);
*/
static size_t lacking(enum rtu_length how, size_t len, size_t avail)
{
    if (how == RTU_LENGTH_UNKNOWN || len > RTU_MAX_ADU || len <= avail)
        return 0;
    return len - avail;
}

/*@ assigns \nothing;
    ensures \result == a || \result == b;
*/
static size_t least_lacking(size_t a, size_t b)
{
    return !a ? b : !b ? a : a < b ? a : b;
}

/* Is a frame of the form 'how', 'len' at 'd' whole, with its CRC? */
/*@ requires rtu_bytes(d, avail);
    assigns \nothing;
    ensures \result ==> RTU_MIN_ADU <= len <= avail && len <= RTU_MAX_ADU;
*/
static bool whole_frame(enum rtu_length how, size_t len, const uint8_t *d, size_t avail)
{
    return how == RTU_LENGTH_EXACT && len >= RTU_MIN_ADU && len <= avail && len <= RTU_MAX_ADU &&
           rtu_crc_ok(d, len);
}

static enum rtu_length request_length_in_chunk(const struct rtu_line *line, size_t at,
                                               size_t avail, size_t *size, unsigned depth,
                                               bool final);

/* How many requests of unknown length (FC08's return query data to units
 * that do not answer) in a row are cut by CRC-valid runs, and how many
 * runs are tried for each: the work stays bounded whatever the data. */
#define RUN_SEARCH_DEPTH 3
#define RUN_SEARCH_TRIES 4

/* Is a whole request at 'at' (its length as the chunk gives it, or the
 * chunk's rest)? */
static bool request_follows(const struct rtu_line *line, size_t at, size_t avail, unsigned depth)
{
    size_t len = 0;
    enum rtu_length how = request_length_in_chunk(line, at, avail, &len, depth, true);
    if (how == RTU_LENGTH_UNKNOWN)
        len = avail, how = RTU_LENGTH_EXACT;
    return whole_frame(how, len, line->rx + at, avail);
}

/* The first k >= 'from' for which the k bytes at 'd' end in the CRC of
 * what precedes them (their running CRC: one pass), and whose next k
 * bytes repeat them if 'repeated'; 0 if none. */
static size_t first_crc_run(const uint8_t *d, size_t avail, size_t from, bool repeated)
{
    uint16_t crc = 0xFFFF;
    /* crc: of the m bytes before d[m], then compared with d[m], d[m+1]. */
    for (size_t m = 1; m + 2 <= avail && m + 2 <= RTU_MAX_ADU; m++) {
        crc = (uint16_t)((crc >> 8) ^ crc_table[(crc ^ d[m - 1]) & 0xFF]);
        if (m + 2 < from || d[m] != (crc & 0xFF) || d[m + 1] != (crc >> 8))
            continue;
        if (!repeated)
            return m + 2;
        if (2 * (m + 2) <= avail && memcmp(d, d + m + 2, m + 2) == 0)
            return m + 2;
    }
    return 0;
}

/*
 * A request's length where the chunk holds what follows it. A function
 * whose request length only its end tells: the run up to the next sure
 * silence, if CRC-valid (no frame goes across one). FC08's return query
 * data carries any data, and its response repeats it byte for byte: the
 * request is the shortest CRC-valid run that the next bytes repeat. For
 * it, for a unit that does not answer, and for a function whose form we
 * do not know (a user-defined code, 65-72, 100-110): the chunk's rest if
 * CRC-valid, else the shortest CRC-valid run if a whole request follows
 * it (the master's next; 'depth': how many such cuts came before, up to
 * RUN_SEARCH_DEPTH, which also turns the search off). Its data is the
 * master's own, never another unit's registers: the awaited unit's
 * response of a form we do not know is never searched. Ours ends its
 * chunk: its rest.
 */
/* A function code the Modbus Application Protocol v1.1b3 assigns (public,
 * 6.1-6.21) or leaves to users (65-72, 100-110). */
static bool function_assigned(uint8_t fc)
{
    switch (fc) {
    case 1: case 2: case 3: case 4: case 5: case 6: case 7: case 8: case 11: case 12:
    case 15: case 16: case 17: case 20: case 21: case 22: case 23: case 24: case 43:
        return true;
    default:
        return (fc >= 65 && fc <= 72) || (fc >= 100 && fc <= 110);
    }
}

static enum rtu_length request_length_in_chunk(const struct rtu_line *line, size_t at,
                                               size_t avail, size_t *size, unsigned depth,
                                               bool final)
{
    const uint8_t *d = line->rx + at;
    enum rtu_length how = rtu_request_length(d, avail, size);
    size_t k, next;

    if (how != RTU_LENGTH_UNKNOWN || d[0] == line->cfg.unit_id || (d[1] & 0x80))
        return how; /* 0x80 and up: an exception, never a request */
    next = next_silence(line, at);
    if (next && next - at <= RTU_MAX_ADU && next - at >= RTU_MIN_ADU &&
        rtu_crc_ok(d, next - at)) {
        *size = next - at;
        return RTU_LENGTH_EXACT;
    }
    /* FC08's return query data: at least 2 bytes of data, and what its
     * response repeats. A code whose form we do not know (a user-defined
     * one): any data, not repeated. */
    size_t least = d[1] == 8 ? 6 : RTU_MIN_ADU;
    if (d[1] == 8 && (k = first_crc_run(d, avail, 6, true)) != 0) {
        *size = k;
        return RTU_LENGTH_EXACT;
    }
    if (avail <= RTU_MAX_ADU && avail >= least && rtu_crc_ok(d, avail)) {
        /* The chunk's rest, once nothing more comes (a port's piece may
         * end where a CRC happens to be valid). */
        *size = final ? avail : avail + 1;
        return final ? RTU_LENGTH_EXACT : RTU_LENGTH_MORE;
    }
    /* The first CRC-valid runs (at most RTU_MAX_ADU bytes are scanned),
     * for a public or a user-defined code only: a code the Modbus
     * specification reserves is no master's (noise, or the tail of an echo
     * read as input), and a run whose CRC passes by chance in it must never
     * make the bytes after it a frame's start (they may be another unit's
     * data). */
    if (!function_assigned(d[1]))
        return RTU_LENGTH_UNKNOWN;
    unsigned tries = 0;
    for (size_t from = least; depth < RUN_SEARCH_DEPTH && tries++ < RUN_SEARCH_TRIES &&
                          (k = first_crc_run(d, avail, from, false)) != 0;
         from = k + 1)
        if (k + RTU_MIN_ADU <= avail && request_follows(line, at + k, avail - k, depth + 1)) {
            *size = k;
            return RTU_LENGTH_EXACT;
        }
    return RTU_LENGTH_UNKNOWN;
}

/* The length of a frame of another unit read as a request of 'len' bytes
 * if it is also a whole response of another length (its own fields
 * giving it), else 0. 05 and 06, whose request and response are alike,
 * have one length. */
/*@ requires rtu_bytes(d, avail);
    assigns \nothing;
    ensures \result <= avail && \result <= RTU_MAX_ADU;
*/
static size_t response_reading(const uint8_t *d, size_t avail, size_t len)
{
    size_t rsp_len = 0;
    enum rtu_length how = response_form_length(d, avail, &rsp_len);
    return rsp_len != len && whole_frame(how, rsp_len, d, avail) ? rsp_len : 0;
}

/* What a frame at 'd' lacks to be a whole response by its own fields. */
/*@ requires rtu_bytes(d, avail);
    assigns \nothing;
    ensures \result <= RTU_MAX_ADU;
*/
static size_t response_lacking(const uint8_t *d, size_t avail)
{
    size_t len = 0;
    enum rtu_length how = response_form_length(d, avail, &len);
    return lacking(how, len, avail);
}

/*
 * The first frame after a silence the line is sure of, where it lost its
 * place: a master's request (its length from its function), or a
 * response to a request the line did not hear (its length from its own
 * fields). FRAME_REQUEST with *len, and *rsp_len if it is also a whole
 * response of another length (two readings); FRAME_RESPONSE; or
 * FRAME_NONE with *missing, what a frame begun there lacks.
 */
static enum frame_kind first_frame(const struct rtu_line *line, const uint8_t *d, size_t avail,
                                   bool final, size_t *len, size_t *rsp_len, size_t *missing)
{
    size_t q = 0, p = 0;
    enum rtu_length qh = request_length_in_chunk(line, (size_t)(d - line->rx), avail, &q, 0, final);
    enum rtu_length ph = response_form_length(d, avail, &p);
    bool q_ok = whole_frame(qh, q, d, avail), p_ok = whole_frame(ph, p, d, avail);

    *missing = 0;
    *rsp_len = 0;
    if (d[0] == line->cfg.unit_id || d[0] == RTU_BROADCAST)
        p_ok = false; /* only we answer as our unit, and nobody as 0 */
    if (q_ok && !p_ok && !final && d[0] != line->cfg.unit_id && d[0] != RTU_BROADCAST &&
        lacking(ph, p, avail)) {
        /* It may still become a whole response: wait for it. */
        *missing = lacking(ph, p, avail);
        return FRAME_NONE;
    }
    if (q_ok) {
        *len = q;
        *rsp_len = p_ok && p != q ? p : 0;
        return FRAME_REQUEST;
    }
    if (p_ok) {
        *len = p;
        return FRAME_RESPONSE;
    }
    *missing = least_lacking(lacking(qh, q, avail), lacking(ph, p, avail));
    if (!*missing && avail < RTU_MIN_ADU)
        *missing = RTU_MIN_ADU - avail;
    return FRAME_NONE;
}

static void walk_from(const struct rtu_line *line, size_t at, bool final, struct walk *w,
                      bool branched);

/* The walk takes the frame at 'at' as 'kind', 'len' bytes, and goes on. */
static void take_frame(const struct rtu_line *line, size_t at, enum frame_kind kind, size_t len,
                       struct walk *w)
{
    const uint8_t *d = line->rx + at;

    w->stats.frames++;
    if (kind == FRAME_RESPONSE) {
        w->stats.foreign_frames++;
        w->conv = RTU_CONV_IDLE;
    } else if (d[0] == RTU_BROADCAST) {
        w->stats.broadcasts++;
        w->conv = RTU_CONV_IDLE;
    } else if (d[0] == line->cfg.unit_id && (d[1] & 0x80)) {
        /* An exception's form addressed to us: no master asks that (our
         * own exception reply heard back, or a unit answering as ours):
         * counted and skipped, never a request. */
        w->stats.exceptions++;
        w->conv = RTU_CONV_IDLE;
    } else if (d[0] == line->cfg.unit_id) {
        w->execute_at = at;
        w->execute_size = len;
        w->conv = RTU_CONV_IDLE; /* our reply ends the exchange */
    } else {
        w->stats.foreign_frames++;
        memcpy(w->await_request, d, len);
        w->await_request_size = len;
        w->conv = RTU_CONV_AWAIT;
    }
}

/*
 * A frame of another unit that reads two ways, a request of 'len' bytes
 * or a response of 'rsp_len' (a response whose first bytes were made to
 * pass for a request, a frame hidden after them; or a request whose bytes
 * happen to be a response's): the walk goes on both ways. The reading
 * that explains the rest of the chunk is the bus; where both do, only
 * what both would execute is (a hidden frame is executed by one reading
 * alone); where neither does, the frame is dropped (false).
 */
static bool take_either(const struct rtu_line *line, size_t at, size_t len, size_t rsp_len,
                        bool final, struct walk *w)
{
    struct walk as_request = *w, as_response = *w;

    take_frame(line, at, FRAME_REQUEST, len, &as_request);
    walk_from(line, at + len, final, &as_request, true);
    take_frame(line, at, FRAME_RESPONSE, rsp_len, &as_response);
    walk_from(line, at + rsp_len, final, &as_response, true);
    bool q = !as_request.dropped, p = !as_response.dropped;
    if (!q && !p)
        return false;
    if (q && p && (as_request.execute_size != as_response.execute_size ||
                   as_request.execute_at != as_response.execute_at)) {
        as_request.execute_size = 0;
        as_request.conv = RTU_CONV_UNSYNCED;
    }
    *w = q ? as_request : as_response;
    /* Still to come: wait for what either reading lacks. */
    if (as_request.missing > w->missing)
        w->missing = as_request.missing;
    if (as_response.missing > w->missing)
        w->missing = as_response.missing;
    return true;
}

/*
 * Walks the chunk from 'from' as the model in rtu_frame.h says, from the
 * state 'conv', without changing the line: the state after it, the
 * counters, the request to execute, and what a frame begun at the end
 * lacks. 'final': the chunk is being judged, nothing more will come.
 */
static void walk_chunk(const struct rtu_line *line, size_t from, enum rtu_conv conv, bool final,
                       struct walk *w)
{
    memset(w, 0, sizeof(*w));
    w->conv = conv;
    memcpy(w->await_request, line->await_request, line->await_request_size);
    w->await_request_size = line->await_request_size;
    w->from = from;
    walk_from(line, from, final, w, false);
}

/*
 * Noise before our request: fewer than RTU_MIN_ADU bytes at a frame
 * boundary (a silence, or where the conversation says a frame starts)
 * that are no frame, then a whole CRC-valid request of ours that ends the
 * chunk, which was judged only once the line surely fell silent after it
 * (t3.5, a port's piece and the delivery bound). Returns the noise's
 * length, 0 if the chunk is not that. Bytes that few can neither be a
 * frame nor hold one, and a frame that began there and went on past the
 * request would have reached the chunk: so the request is no part of
 * another frame, only a frame the master sent after a glitch (a line
 * driver switching, a byte of a collision), whose silence before it a
 * host cannot be sure of (it is shorter than the port's delivery).
 */
/* Can 'size' bytes have come one after another, with a pause of t1.5
 * between the noise and the request, from the chunk's first arrival to
 * its last read? Bytes read together (a frame that would have begun
 * before the noise ended) are one run of something else. */
static bool fits_after_noise(const struct rtu_line *line, size_t size)
{
    return line->last_rx_ns >=
           line->chunk_after_ns + (uint64_t)size * line->cfg.char_ns + line->cfg.t15_ns;
}

static size_t noise_before_ours(const struct rtu_line *line, size_t at)
{
    size_t size = line->rx_used;

    /* Our last frame, glued to noise that came within the delivery bound
     * after it: our echo, never the master's (a retry costs a retry). */
    bool echo_possible = line->tx_end_ns && line->chunk_after_ns < rtu_line_bound_end_ns(line);
    for (size_t k = 1; k < RTU_MIN_ADU && at + k + RTU_MIN_ADU <= size; k++) {
        const uint8_t *d = line->rx + at + k;
        size_t rest = size - at - k, len = 0;
        if (d[0] == line->cfg.unit_id && rtu_crc_ok(d, rest) &&
            rtu_request_length(d, rest, &len) == RTU_LENGTH_EXACT && len == rest &&
            !pause_inside(line, at + k, size) && fits_after_noise(line, k + rest) &&
            !(echo_possible && rest == line->sent_size && memcmp(d, line->sent, rest) == 0))
            return k;
    }
    return 0;
}

/* The walk from 'at' on; 'branched': inside take_either (a second frame
 * that reads two ways is dropped). */
static void walk_from(const struct rtu_line *line, size_t at, bool final, struct walk *w,
                      bool branched)
{
    const uint8_t *rx = line->rx;
    size_t size = line->rx_used;

    while (at < size) {
        const uint8_t *d = rx + at;
        size_t avail = size - at, len = 0, rsp_len = 0, missing = 0;
        bool awaited = false; /* rsp_len is the response awaited */
        /* The awaited unit's response in a form we do not know: its data
         * is that unit's, never searched for runs. */
        bool unknown_response = false;
        /* Where the line knows where it stands, a frame starts at the
         * chunk's start, where the last one ended; where it does not,
         * only after a silence it is sure of. */
        bool silence = w->conv == RTU_CONV_UNSYNCED ? after_silence(line, at)
                                                    : at == w->from || after_silence(line, at);
        enum frame_kind kind = FRAME_NONE;
        enum rtu_length how;

        if (w->conv == RTU_CONV_UNSYNCED) {
            if (silence && avail >= RTU_MIN_ADU && avail <= RTU_MAX_ADU &&
                rtu_crc_ok(d, avail)) {
                /* A whole chunk from a silence to the end: one frame. */
                how = rtu_request_length(d, avail, &len);
                kind = how == RTU_LENGTH_UNKNOWN || (how == RTU_LENGTH_EXACT && len == avail)
                           ? FRAME_REQUEST
                           : FRAME_RESPONSE;
                len = avail;
            } else if (silence) {
                kind = first_frame(line, d, avail, final, &len, &rsp_len, &missing);
            }
        } else {
            size_t as_response = 0, as_request = 0;
            bool response = w->conv == RTU_CONV_AWAIT && avail >= 2 &&
                            d[0] == w->await_request[0] &&
                            (d[1] & 0x7F) == w->await_request[1];
            if (w->conv == RTU_CONV_AWAIT && avail < 2) {
                as_response = RTU_MIN_ADU - avail;
            } else if (response) {
                /* The unit and function awaited: the response. While it
                 * may still become whole it is never read as anything else
                 * (its data is whatever that unit holds); once its length
                 * has come with a bad CRC, or no more is coming (final),
                 * it may be the master asking that unit again. */
                how = rtu_response_length(w->await_request, w->await_request_size, d, avail,
                                          &len);
                unknown_response = how == RTU_LENGTH_UNKNOWN;
                if (how == RTU_LENGTH_UNKNOWN && silence)
                    how = RTU_LENGTH_EXACT, len = avail; /* the rest of the chunk */
                if (whole_frame(how, len, d, avail) && echoes_request(w->await_request, d, len)) {
                    /* Or the master asking U again, with the same
                     * function; where the response repeats the request
                     * (05, 06, FC08's return query data), it is the
                     * response the conversation expects. */
                    size_t q = 0;
                    enum rtu_length qh = request_length_in_chunk(line, at, avail, &q, 0, final);
                    bool repeats = len == w->await_request_size &&
                                   memcmp(d, w->await_request, len) == 0;
                    kind = FRAME_RESPONSE;
                    if (!repeats && whole_frame(qh, q, d, avail) && d[0] != RTU_BROADCAST) {
                        kind = FRAME_REQUEST;
                        rsp_len = len;
                        len = q;
                        awaited = true;
                    }
                } else {
                    as_response = lacking(how, len, avail);
                }
                if (kind == FRAME_NONE && (!as_response || final))
                    response = false;
            }
            /* Not the response awaited (another unit, or a silent one's
             * next request): a master's request, where the last frame
             * ended. */
            if (kind == FRAME_NONE && !response) {
                how = request_length_in_chunk(line, at, avail, &len,
                                              unknown_response ? RUN_SEARCH_DEPTH : 0, final);
                bool rest = how == RTU_LENGTH_UNKNOWN && (silence || d[0] == line->cfg.unit_id);
                if (rest) /* only as the chunk's rest, once nothing more comes */
                    how = final ? RTU_LENGTH_EXACT : RTU_LENGTH_MORE, len = avail + !final;
                if (whole_frame(how, len, d, avail)) {
                    kind = FRAME_REQUEST;
                    if (d[0] != line->cfg.unit_id && d[0] != RTU_BROADCAST) {
                        rsp_len = response_reading(d, avail, len);
                        /* A response it may still become: wait for it. */
                        if (!rsp_len && !final && response_lacking(d, avail)) {
                            kind = FRAME_NONE;
                            as_request = response_lacking(d, avail);
                        }
                    }
                } else {
                    /* A frame of a length only its end tells may still
                     * be coming in the port's next piece. */
                    as_request = rest ? 1 : lacking(how, len, avail);
                }
            }
            /* Whichever form the tail may still become first. */
            missing = least_lacking(as_request, as_response);
        }
        bool paused = kind != FRAME_NONE && pause_inside(line, at, at + len);
        if (paused) {
            w->stats.gap_discards++;
            kind = FRAME_NONE;
            missing = 0;
        }
        if (kind == FRAME_REQUEST && rsp_len) {
            if (!branched && !pause_inside(line, at, at + rsp_len) &&
                take_either(line, at, len, rsp_len, final, w))
                return;
            /* Within a reading already taken: the response awaited, if
             * it was one, else dropped. */
            if (awaited && branched && !pause_inside(line, at, at + rsp_len))
                kind = FRAME_RESPONSE, len = rsp_len;
            else
                kind = FRAME_NONE;
        }
        if (kind == FRAME_NONE && !paused)
            w->stats.crc_errors++;
        size_t noise = 0;
        if (kind == FRAME_NONE && final && silence && !branched &&
            (noise = noise_before_ours(line, at)) != 0) {
            /* A few bytes of noise, too short to be or hold a frame, then
             * a whole request of ours to the chunk's end. */
            take_frame(line, at + noise, FRAME_REQUEST, size - at - noise, w);
            w->dropped = true;
            w->missing = 0;
            return;
        }
        /* A frame begun and not whole: every byte after it may be its
         * late pieces (a silence waited past in it is the port's delay),
         * so nothing after it is searched for frames; it is waited for,
         * and dropped with them if it does not come. */
        if (kind == FRAME_NONE && missing) {
            w->dropped = final; /* else it may still come */
            w->missing = missing;
            w->conv = RTU_CONV_UNSYNCED;
            return;
        }
        if (kind == FRAME_REQUEST && d[0] == line->cfg.unit_id && at + len != size) {
            /* Bytes after our request: the master did not wait for us. */
            w->stats.crc_errors++;
            kind = FRAME_NONE;
        }
        if (kind == FRAME_NONE) {
            /* Dropped up to the next sure silence, where the line takes
             * its place again. */
            size_t next = next_silence(line, at);
            w->dropped = true;
            w->conv = RTU_CONV_UNSYNCED;
            if (!next)
                return;
            at = next;
            continue;
        }
        take_frame(line, at, kind, len, w);
        at += len;
    }
    w->missing = 0; /* the chunk ends with a whole frame */
}

static void add_stats(struct rtu_line_stats *to, const struct rtu_line_stats *add)
{
    to->frames += add->frames;
    to->crc_errors += add->crc_errors;
    to->foreign_frames += add->foreign_frames;
    to->broadcasts += add->broadcasts;
    to->gap_discards += add->gap_discards;
    to->exceptions += add->exceptions;
}

/* Did the chunk begin before our last frame's end plus t3.5 (a master
 * that keeps no silence of its own after our reply)? Counted; served. */
static bool began_in_our_turn(const struct rtu_line *line)
{
    return line->tx_end_ns && line->first_rx_ns < line->tx_end_ns + line->cfg.t35_ns;
}

/* The silence came: the chunk is judged and consumed; then our request,
 * if any, is handed on. */
static void end_chunk(struct rtu_line *line, const struct rtu_line_hooks *hooks)
{
    uint8_t request[RTU_MAX_ADU];
    size_t request_size = 0;
    bool repeat = false;

    if (line->rx_overrun) {
        /* Counted when it happened; nothing in it can be trusted. */
        line->conv = RTU_CONV_UNSYNCED;
    } else {
        size_t echo = echo_at_head(line);
        if (echo == line->rx_used && !line->repeat_answered && sent_is_request(line)) {
            /* The same bytes as our reply, which is the request itself,
             * within the delivery bound: our reply heard back, or the
             * master sending the request again at once (a retry after a
             * reply it lost). Answered again, not acted on again: once
             * per request; the next one is an echo. */
            line->repeat_answered = true;
            line->stats.repeats++;
            emit(hooks, RTU_EVENT_REPEAT);
            line->conv = RTU_CONV_IDLE;
            repeat = true;
        } else if (echo) {
            /* Our reply heard back: skipped; what follows it is the
             * master's next request. */
            line->stats.echoes++;
            emit(hooks, RTU_EVENT_ECHO);
            line->conv = RTU_CONV_IDLE;
        } else if (began_in_our_turn(line)) {
            line->stats.out_of_turn++;
        }
        if (echo < line->rx_used) {
            struct walk w;
            walk_chunk(line, echo, line->conv, true, &w);
            if (line->echo_broken) {
                /* local_echo: our frame did not come back whole. A chunk
                 * that is what the conversation expects means the adapter
                 * gave nothing back; anything else, that another
                 * transmitter spoke over us. */
                bool clean = !w.stats.crc_errors && !w.stats.gap_discards;
                if (!clean)
                    line->stats.collisions++;
                emit(hooks, clean ? RTU_EVENT_NO_ECHO : RTU_EVENT_COLLISION);
            }
            add_stats(&line->stats, &w.stats);
            line->conv = w.conv;
            memcpy(line->await_request, w.await_request, w.await_request_size);
            line->await_request_size = w.await_request_size;
            if (w.execute_size) {
                memcpy(request, line->rx + w.execute_at, w.execute_size);
                request_size = w.execute_size;
                line->stats.executed++;
                line->repeat_answered = false; /* a new request: a new reply */
            }
        }
    }
    clear_chunk(line);
    if (repeat && hooks && hooks->repeat)
        hooks->repeat(hooks->user);
    if (request_size && hooks && hooks->request)
        hooks->request(hooks->user, request, request_size);
}

bool rtu_line_silence(struct rtu_line *line, uint64_t now_ns, const struct rtu_line_hooks *hooks)
{
    if (!line->chunk_open)
        return true;
    if (now_ns < line->judge_at_ns)
        return false;
    size_t echo = echo_at_head(line);
    /* Our echo alone is judged at once: nothing in it is executed. */
    if (!line->waited && !line->rx_overrun && echo < line->rx_used) {
        enum rtu_conv conv = echo ? RTU_CONV_IDLE : line->conv;
        struct walk w;
        walk_chunk(line, echo, conv, false, &w);
        line->waited = true;
        /* A frame begun but not whole waits for its next piece; where the
         * line lost its place (before the chunk or within it), a chunk is
         * judged only once the line surely fell silent after it (the next piece of a frame that
         * merely paused would have come by then), so that a frame inside
         * another unit's data, cut there by a port's delivery, is never
         * taken for a whole one. Either way: t3.5 and what a port hands
         * over at once, and its delivery. */
        if (w.missing || conv == RTU_CONV_UNSYNCED || w.dropped) {
            uint64_t until = line->last_rx_ns + line->cfg.t35_ns +
                             (uint64_t)RTU_PIECE_CHARS * line->cfg.char_ns +
                             line->cfg.delivery_ns;
            if (now_ns < until) {
                /* If the frame was noise after all, the next starts here. */
                if (w.missing)
                    add_gap_at_end(line, RTU_GAP_WAITED);
                line->judge_at_ns = until;
                return false;
            }
        }
    }
    end_chunk(line, hooks);
    return true;
}

void rtu_line_frame_out(struct rtu_line *line, const uint8_t *frame, size_t size)
{
    if (size > sizeof(line->sent))
        size = sizeof(line->sent);
    memcpy(line->sent, frame, size);
    line->sent_size = size;
    line->echo_pending = line->cfg.local_echo && size > 0;
    line->echo_at = 0;
    line->conv = RTU_CONV_IDLE;
}

void rtu_line_bytes_out(struct rtu_line *line, size_t size, uint64_t now_ns)
{
    uint64_t from = line->tx_end_ns > now_ns ? line->tx_end_ns : now_ns;

    line->tx_end_ns = from + (uint64_t)size * line->cfg.tx_char_ns;
    line->echo_until_ns = line->tx_end_ns + RTU_LOCAL_ECHO_WINDOW_NS;
}

uint64_t rtu_line_tx_ready_ns(const struct rtu_line *line)
{
    return line->tx_end_ns ? line->tx_end_ns + line->cfg.t35_ns : 0;
}

uint64_t rtu_line_echo_look_ns(const struct rtu_line *line)
{
    if (!line->echo_pending || !line->echo_at)
        return 0;
    return line->echo_last_ns + line->cfg.delivery_ns + line->cfg.t35_ns;
}

uint64_t rtu_line_bound_end_ns(const struct rtu_line *line)
{
    if (!line->tx_end_ns)
        return 0;
    return line->tx_end_ns +
           (line->cfg.local_echo ? RTU_LOCAL_ECHO_WINDOW_NS : line->cfg.delivery_ns);
}
