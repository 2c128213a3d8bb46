/* SPDX-License-Identifier: MIT */
/* rtu_frame.c - see rtu_frame.h. */
#include "rtu_frame.h"

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

    for (size_t i = 0; i < size; i++)
        crc = (uint16_t)((crc >> 8) ^ crc_table[(crc ^ data[i]) & 0xFF]);
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

/*
 * The lengths a frame of function code data[1] can have: its request and
 * its response, where the byte counts they depend on have arrived. Up to
 * two; the caller tries them in order.
 */
static unsigned candidate_lengths(const uint8_t *d, size_t size, size_t out[2])
{
    unsigned n = 0;
    uint8_t fc = d[1];

    if (fc & 0x80) {
        out[n++] = 5; /* an exception response */
        return n;
    }
    switch (fc) {
    case 1: case 2: case 3: case 4:
        out[n++] = 8;
        if (size > 2)
            out[n++] = 5 + (size_t)d[2];
        break;
    case 5: case 6: case 8: case 22:
        out[n++] = fc == 22 ? 10 : 8;
        break;
    case 7:
        out[n++] = 4;
        out[n++] = 5;
        break;
    case 11:
        out[n++] = 4;
        out[n++] = 8;
        break;
    case 12: case 17:
        out[n++] = 4;
        if (size > 2)
            out[n++] = 5 + (size_t)d[2];
        break;
    case 15: case 16:
        if (size > 6)
            out[n++] = 9 + (size_t)d[6];
        out[n++] = 8;
        break;
    case 20: case 21:
        if (size > 2)
            out[n++] = 5 + (size_t)d[2];
        break;
    case 23:
        if (size > 10)
            out[n++] = 13 + (size_t)d[10];
        if (size > 2)
            out[n++] = 5 + (size_t)d[2];
        break;
    case 43:
        out[n++] = 7; /* read device identification, the request */
        if (size > 7 && d[2] == 14) {
            /* The response: MEI type, code, conformity, more follows,
             * next object, the number of objects, then each object's id,
             * length and value. */
            size_t end = 8;
            for (unsigned i = 0; i < d[7] && end + 2 <= size; i++)
                end += 2 + (size_t)d[end + 1];
            if (end + 2 <= size && end + 2 <= RTU_MAX_ADU)
                out[n++] = end + 2;
        }
        break;
    default:
        break;
    }
    return n;
}

size_t rtu_frame_length(const uint8_t *data, size_t size)
{
    size_t lengths[2];
    unsigned n;

    if (size < RTU_MIN_ADU)
        return 0;
    n = candidate_lengths(data, size, lengths);
    for (unsigned i = 0; i < n; i++)
        if (lengths[i] <= size && lengths[i] <= RTU_MAX_ADU &&
            rtu_crc_ok(data, lengths[i]))
            return lengths[i];
    /* A function whose length we do not know: the whole chunk is the
     * frame if its CRC says so. */
    if (size <= RTU_MAX_ADU && rtu_crc_ok(data, size))
        return size;
    return 0;
}

#define GAP_AT(g) ((size_t)((g) & ~RTU_GAP_WAITED))

/* Is there a pause (not a waited silence) inside [from, to)? */
static bool pause_inside(const uint16_t *gaps, size_t g, size_t gap_count, size_t to)
{
    for (; g < gap_count && GAP_AT(gaps[g]) < to; g++)
        if (!(gaps[g] & RTU_GAP_WAITED))
            return true;
    return false;
}

void rtu_split(const uint8_t *chunk, size_t size, const uint16_t *gaps, size_t gap_count,
               const struct rtu_split_hooks *hooks)
{
    size_t off = 0, g = 0;

    while (off < size) {
        size_t len = rtu_frame_length(chunk + off, size - off);
        while (g < gap_count && GAP_AT(gaps[g]) <= off)
            g++;
        if (len) {
            /* A silence inside the frame: the specification discards it. */
            if (pause_inside(gaps, g, gap_count, off + len))
                hooks->dropped(hooks->user, RTU_DROP_GAP, len);
            else
                hooks->frame(hooks->user, chunk + off, len);
            off += len;
            continue;
        }
        /* No frame starts here: a frame can start again only after a
         * silence, at the next gap, or nowhere in this chunk. */
        size_t next = g < gap_count ? GAP_AT(gaps[g]) : size;
        hooks->dropped(hooks->user, RTU_DROP_CRC, next - off);
        off = next;
    }
}

/* The bytes a tail of 'have' bytes lacks to reach its next possible end. */
static size_t missing_at(const uint8_t *d, size_t have)
{
    size_t lengths[2], best = 0;
    unsigned n;

    if (have < 2)
        return RTU_MIN_ADU - have;
    n = candidate_lengths(d, have, lengths);
    for (unsigned i = 0; i < n; i++)
        if (lengths[i] > have && lengths[i] <= RTU_MAX_ADU && (!best || lengths[i] < best))
            best = lengths[i];
    if (!best && have < RTU_MIN_ADU && n == 0)
        best = RTU_MIN_ADU; /* an unknown function: at least a whole frame */
    return best ? best - have : 0;
}

size_t rtu_missing_bytes(const uint8_t *chunk, size_t size, const uint16_t *gaps,
                         size_t gap_count)
{
    size_t off = 0, g = 0;

    while (off < size) {
        size_t len = rtu_frame_length(chunk + off, size - off);
        while (g < gap_count && GAP_AT(gaps[g]) <= off)
            g++;
        if (len) {
            off += len;
            continue;
        }
        if (g < gap_count) {
            off = GAP_AT(gaps[g]); /* no frame here: rtu_split drops up to the gap */
            continue;
        }
        return missing_at(chunk + off, size - off);
    }
    return 0;
}
