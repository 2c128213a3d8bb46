/* SPDX-License-Identifier: MIT */
/*
 * rtu_frame.h - Modbus RTU framing by the serial line specification
 * (Modbus over Serial Line V1.02, 2.5): the CRC-16, the character times
 * and the split of a run of received bytes into frames.
 *
 * What arrives between two silences of 3.5 character times is a "chunk".
 * A chunk normally holds one frame, but a reader that is late (a loaded
 * host, a pty that delivers two writes at once) may find two frames in
 * one chunk, or a foreign unit's frame glued to ours. rtu_split() cuts a
 * chunk into frames by their length, as the function code gives it for a
 * request or a response, checked by the CRC; where no frame starts, it
 * resynchronises at the next place where the line was silent for more
 * than 1.5 character times. A frame with such a gap inside it is
 * discarded, as the specification says. Nothing here allocates or keeps
 * state: the caller owns the bytes and the gap positions.
 */
#ifndef JAKAGW_RTU_FRAME_H
#define JAKAGW_RTU_FRAME_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Unit id, PDU (at most 253 bytes), CRC. */
#define RTU_MAX_ADU 256
#define RTU_MIN_ADU 4
#define RTU_BROADCAST 0

/* The Modbus CRC-16 (polynomial 0xA001 reflected, initial 0xFFFF), by table. */
uint16_t rtu_crc16(const uint8_t *data, size_t size);

/* Does the frame end in the CRC of what precedes it (low byte first)? */
bool rtu_crc_ok(const uint8_t *frame, size_t size);

/* Appends the CRC to 'size' bytes at 'frame' (room for two more). */
size_t rtu_append_crc(uint8_t *frame, size_t size);

/*
 * The character times for a line, in nanoseconds: 1.5 and 3.5 characters
 * of 1 start bit, 8 data bits, the parity bit and the stop bits; above
 * 19200 baud the fixed 750 us and 1750 us the specification gives.
 */
void rtu_char_times(unsigned baud, bool parity, unsigned stop_bits, uint32_t *t15_ns,
                    uint32_t *t35_ns);

/*
 * The length of the frame at the start of 'data' ('size' bytes there):
 * the request or the response form of its function code, or all 'size'
 * bytes, whichever ends in a good CRC first; 0 if none does.
 */
size_t rtu_frame_length(const uint8_t *data, size_t size);

enum rtu_drop {
    RTU_DROP_CRC, /* no frame with a good CRC starts here (cut short, noise) */
    RTU_DROP_GAP, /* a good frame, but the line fell silent inside it */
};

struct rtu_split_hooks {
    /* A frame with a good CRC: unit id, PDU, CRC. */
    void (*frame)(void *user, const uint8_t *frame, size_t size);
    /* 'size' bytes dropped, and why. */
    void (*dropped)(void *user, enum rtu_drop why, size_t size);
    void *user;
};

/*
 * Cuts a chunk of 'size' bytes into frames, calling the hooks in order.
 * 'gaps' lists, in increasing order, the offsets in the chunk of the bytes
 * that came after a silence longer than 1.5 character times: a frame with
 * one inside is discarded, and after bytes that are no frame the next
 * frame is sought at the next gap. An offset with RTU_GAP_WAITED set is a
 * silence of t3.5 the caller waited past for a frame not yet whole
 * (rtu_missing_bytes): the next frame is sought there too, but a frame
 * across it is whole, not discarded (its bytes were late, not paused).
 */
#define RTU_GAP_WAITED 0x8000
void rtu_split(const uint8_t *chunk, size_t size, const uint16_t *gaps, size_t gap_count,
               const struct rtu_split_hooks *hooks);

/*
 * How many more bytes the chunk needs to end in a whole frame: 0 when its
 * last frame is whole, or when its tail is no frame any function code
 * explains; else, for a tail that begins a frame (cut as rtu_split cuts),
 * the bytes up to that frame's next possible end. A UART that hands over
 * its FIFO every 8 characters, or a USB adapter's packets, deliver one
 * frame in pieces further apart than t3.5: the caller waits this many
 * more character times before it takes the silence for the frame's end.
 */
size_t rtu_missing_bytes(const uint8_t *chunk, size_t size, const uint16_t *gaps,
                         size_t gap_count);

#endif
