/* SPDX-License-Identifier: MIT */
/* mb_request.c - see mb_request.h. */
#include "mb_request.h"

#include <modbus.h>

#define ILLEGAL_FUNCTION MODBUS_EXCEPTION_ILLEGAL_FUNCTION
#define ILLEGAL_ADDRESS MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
#define ILLEGAL_VALUE MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE

/* As a product and a sum rather than a shift and an or: the same value,
 * and one the provers can bound (make prove). */
/*@ requires \valid_read(p + (0 .. 1));
    assigns \nothing;
    ensures \result == p[0] * 256 + p[1];
    ensures \result <= 65535;
*/
static unsigned get16(const uint8_t *p) { return p[0] * 256u + p[1]; }

/*@ predicate table_of(enum regmap_table t) = 0 <= t < REGMAP_TABLE_COUNT;
*/

/*@ requires regmap_readable(map) && table_of(table);
    requires mb_pdu_readable(pdu, size);
    assigns \nothing;
    ensures mb_answer(\result) && \result != MB_REQUEST_NOT_A_REQUEST;
    ensures \result == 0 ==> size == 5 && mb_read_inside(map, table, pdu, max);
*/
static int check_read(const struct regmap *map, enum regmap_table table,
                      const uint8_t *pdu, size_t size, unsigned max)
{
    if (size != 5)
        return ILLEGAL_VALUE;
    unsigned address = get16(pdu + 1), count = get16(pdu + 3);
    if (count < 1 || count > max)
        return ILLEGAL_VALUE;
    if (address + count > map->size[table])
        return ILLEGAL_ADDRESS;
    return 0;
}

/*@ requires regmap_readable(map) && table_of(table);
    requires address <= 65535 && count <= 65535;
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS;
    ensures \result == 0 ==> address + count <= map->size[table];
*/
static int check_write_range(const struct regmap *map, enum regmap_table table,
                             unsigned address, unsigned count)
{
    if (address + count > map->size[table])
        return ILLEGAL_ADDRESS;
    /*@ loop invariant address <= a <= address + count;
        loop assigns a;
        loop variant address + count - a;
    */
    for (unsigned a = address; a < address + count; a++) {
        const struct regmap_row *row = regmap_find(map, table, a);
        if ((!row || !row->writable) && !regmap_write_skips(map, table, a, address, count))
            return ILLEGAL_ADDRESS;
    }
    return 0;
}

/*@ requires regmap_readable(map) && table_of(table);
    requires address <= 65535 && count <= 65535;
    requires \valid_read(values + (0 .. count - 1));
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS || \result == ILLEGAL_VALUE;
*/
static int check_values(const struct regmap *map, enum regmap_table table,
                        unsigned address, const uint16_t *values, unsigned count)
{
    /*@ loop invariant 0 <= i <= count;
        loop assigns i;
        loop variant count - i;
    */
    for (unsigned i = 0; i < count; i++) {
        if (regmap_write_skips(map, table, address + i, address, count)) {
            /* A coil no row owns, inside a block of coils: 0 is what it
             * reads and is ignored; 1 asks for something that is not there. */
            if (table == REGMAP_COIL && values[i])
                return ILLEGAL_ADDRESS;
            continue; /* inside a command's parameters: ignored */
        }
        int ex = regmap_check_write(map, table, address + i, values[i]);
        if (ex)
            return ex;
    }
    return 0;
}

/*@ requires regmap_readable(map);
    requires mb_pdu_readable(pdu, size);
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS || \result == ILLEGAL_VALUE;
*/
static int check_write_coils(const struct regmap *map, const uint8_t *pdu,
                             size_t size)
{
    if (size < 6)
        return ILLEGAL_VALUE;
    unsigned address = get16(pdu + 1), count = get16(pdu + 3);
    unsigned bytes = pdu[5];
    if (count < 1 || count > MODBUS_MAX_WRITE_BITS || bytes != (count + 7) / 8 ||
        size != 6 + bytes)
        return ILLEGAL_VALUE;
    int ex = check_write_range(map, REGMAP_COIL, address, count);
    if (ex)
        return ex;
    uint16_t values[MODBUS_MAX_WRITE_BITS];
    /*@ loop invariant 0 <= i <= count;
        loop assigns i, values[0 .. count - 1];
        loop variant count - i;
    */
    for (unsigned i = 0; i < count; i++)
        values[i] = (pdu[6 + i / 8] >> (i % 8)) & 1;
    return check_values(map, REGMAP_COIL, address, values, count);
}

/*@ requires regmap_readable(map);
    requires 1 <= count <= MODBUS_MAX_WRITE_REGISTERS && address <= 65535;
    requires \valid_read(regs + (0 .. 2 * count - 1));
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS || \result == ILLEGAL_VALUE;
*/
static int check_write_registers(const struct regmap *map, const uint8_t *regs,
                                 unsigned address, unsigned count)
{
    int ex = check_write_range(map, REGMAP_HOLDING_REGISTER, address, count);
    if (ex)
        return ex;
    uint16_t values[MODBUS_MAX_WRITE_REGISTERS];
    /*@ loop invariant 0 <= i <= count;
        loop assigns i, values[0 .. count - 1];
        loop variant count - i;
    */
    for (unsigned i = 0; i < count; i++)
        values[i] = (uint16_t)get16(regs + 2 * i);
    return check_values(map, REGMAP_HOLDING_REGISTER, address, values, count);
}

/*@ requires regmap_readable(map);
    requires mb_pdu_readable(pdu, size);
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS || \result == ILLEGAL_VALUE;
*/
static int check_write_multiple(const struct regmap *map, const uint8_t *pdu,
                                size_t size)
{
    if (size < 6)
        return ILLEGAL_VALUE;
    unsigned address = get16(pdu + 1), count = get16(pdu + 3);
    unsigned bytes = pdu[5];
    if (count < 1 || count > MODBUS_MAX_WRITE_REGISTERS || bytes != 2 * count ||
        size != 6 + bytes)
        return ILLEGAL_VALUE;
    return check_write_registers(map, pdu + 6, address, count);
}

/*@ requires regmap_image_readable(img);
    requires mb_pdu_readable(pdu, size);
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS || \result == ILLEGAL_VALUE;
*/
static int check_mask_write(const struct regmap_image *img, const uint8_t *pdu,
                            size_t size)
{
    if (size != 7)
        return ILLEGAL_VALUE;
    unsigned address = get16(pdu + 1);
    int ex = check_write_range(img->map, REGMAP_HOLDING_REGISTER, address, 1);
    if (ex)
        return ex;
    unsigned and_mask = get16(pdu + 3), or_mask = get16(pdu + 5);
    unsigned current = img->mb->tab_registers[address];
    uint16_t result = (uint16_t)((current & and_mask) | (or_mask & ~and_mask));
    return check_values(img->map, REGMAP_HOLDING_REGISTER, address, &result, 1);
}

/*@ requires regmap_readable(map);
    requires mb_pdu_readable(pdu, size);
    assigns \nothing;
    ensures \result == 0 || \result == ILLEGAL_ADDRESS || \result == ILLEGAL_VALUE;
*/
static int check_read_write(const struct regmap *map, const uint8_t *pdu,
                            size_t size)
{
    if (size < 10)
        return ILLEGAL_VALUE;
    unsigned read_address = get16(pdu + 1), read_count = get16(pdu + 3);
    unsigned write_address = get16(pdu + 5), write_count = get16(pdu + 7);
    unsigned bytes = pdu[9];
    if (read_count < 1 || read_count > MODBUS_MAX_WR_READ_REGISTERS ||
        write_count < 1 || write_count > MODBUS_MAX_WR_WRITE_REGISTERS ||
        bytes != 2 * write_count || size != 10 + bytes)
        return ILLEGAL_VALUE;
    if (read_address + read_count > map->size[REGMAP_HOLDING_REGISTER])
        return ILLEGAL_ADDRESS;
    return check_write_registers(map, pdu + 10, write_address, write_count);
}

int mb_request_check(const struct regmap_image *img, const uint8_t *pdu,
                     size_t size)
{
    const struct regmap *map = img->map;

    if (size < 1)
        return ILLEGAL_VALUE;
    if (pdu[0] & 0x80)
        return MB_REQUEST_NOT_A_REQUEST;
    switch (pdu[0]) {
    case MODBUS_FC_READ_COILS:
        return check_read(map, REGMAP_COIL, pdu, size, MODBUS_MAX_READ_BITS);
    case MODBUS_FC_READ_DISCRETE_INPUTS:
        return check_read(map, REGMAP_DISCRETE_INPUT, pdu, size,
                          MODBUS_MAX_READ_BITS);
    case MODBUS_FC_READ_HOLDING_REGISTERS:
        return check_read(map, REGMAP_HOLDING_REGISTER, pdu, size,
                          MODBUS_MAX_READ_REGISTERS);
    case MODBUS_FC_READ_INPUT_REGISTERS:
        return check_read(map, REGMAP_INPUT_REGISTER, pdu, size,
                          MODBUS_MAX_READ_REGISTERS);
    case MODBUS_FC_WRITE_SINGLE_COIL: {
        if (size != 5)
            return ILLEGAL_VALUE;
        unsigned value = get16(pdu + 3);
        if (value != 0x0000 && value != 0xFF00)
            return ILLEGAL_VALUE;
        int ex = check_write_range(map, REGMAP_COIL, get16(pdu + 1), 1);
        return ex ? ex
                  : regmap_check_write(map, REGMAP_COIL, get16(pdu + 1),
                                       value ? 1 : 0);
    }
    case MODBUS_FC_WRITE_SINGLE_REGISTER: {
        if (size != 5)
            return ILLEGAL_VALUE;
        return check_write_registers(map, pdu + 3, get16(pdu + 1), 1);
    }
    case MODBUS_FC_WRITE_MULTIPLE_COILS:
        return check_write_coils(map, pdu, size);
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
        return check_write_multiple(map, pdu, size);
    case MODBUS_FC_MASK_WRITE_REGISTER:
        return check_mask_write(img, pdu, size);
    case MODBUS_FC_WRITE_AND_READ_REGISTERS:
        return check_read_write(map, pdu, size);
    case MODBUS_FC_REPORT_SLAVE_ID:
        return size == 1 ? 0 : ILLEGAL_VALUE;
    case MB_FC_READ_DEVICE_ID:
        if (size < 2 || pdu[1] != MB_MEI_READ_DEVICE_ID)
            return ILLEGAL_FUNCTION;
        if (size != 4 || pdu[2] < 1 || pdu[2] > 4)
            return ILLEGAL_VALUE;
        return 0;
    default:
        return ILLEGAL_FUNCTION;
    }
}

int mb_request_is_write(uint8_t function)
{
    switch (function) {
    case MODBUS_FC_WRITE_SINGLE_COIL:
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
    case MODBUS_FC_WRITE_MULTIPLE_COILS:
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
    case MODBUS_FC_MASK_WRITE_REGISTER:
    case MODBUS_FC_WRITE_AND_READ_REGISTERS:
        return 1;
    default:
        return 0;
    }
}

int mb_request_write_range(const uint8_t *pdu, size_t size,
                           enum regmap_table *table, unsigned *address,
                           unsigned *count)
{
    if (size < 5 || !mb_request_is_write(pdu[0]))
        return -1;
    *table = REGMAP_HOLDING_REGISTER;
    *address = get16(pdu + 1);
    *count = 1;
    switch (pdu[0]) {
    case MODBUS_FC_WRITE_SINGLE_COIL:
        *table = REGMAP_COIL;
        break;
    case MODBUS_FC_WRITE_MULTIPLE_COILS:
        *table = REGMAP_COIL;
        *count = get16(pdu + 3);
        break;
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
        *count = get16(pdu + 3);
        break;
    case MODBUS_FC_WRITE_AND_READ_REGISTERS:
        if (size < 9)
            return -1;
        *address = get16(pdu + 5);
        *count = get16(pdu + 7);
        break;
    }
    return 0;
}

int mb_request_written_values(const struct regmap_image *img, const uint8_t *pdu,
                              size_t size, enum regmap_table *table,
                              unsigned *address, uint16_t *values)
{
    /* Kept apart from the caller's until the end: they cannot alias the
     * image or the PDU then, whatever the caller passed. */
    enum regmap_table written_table;
    unsigned first, count;

    if (mb_request_write_range(pdu, size, &written_table, &first, &count) != 0)
        return -1;
    switch (pdu[0]) {
    case MODBUS_FC_WRITE_SINGLE_COIL:
        values[0] = get16(pdu + 3) ? 1 : 0;
        break;
    case MODBUS_FC_WRITE_MULTIPLE_COILS:
        if (count < 1 || count > MODBUS_MAX_WRITE_BITS || size < 6 + (count + 7) / 8)
            return -1;
        /*@ loop invariant 0 <= i <= count;
            loop assigns i, values[0 .. count - 1];
            loop variant count - i;
        */
        for (unsigned i = 0; i < count; i++)
            values[i] = (pdu[6 + i / 8] >> (i % 8)) & 1;
        break;
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
        values[0] = (uint16_t)get16(pdu + 3);
        break;
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
        if (count < 1 || count > MODBUS_MAX_WRITE_REGISTERS || size < 6 + 2 * count)
            return -1;
        /*@ loop invariant 0 <= i <= count;
            loop assigns i, values[0 .. count - 1];
            loop variant count - i;
        */
        for (unsigned i = 0; i < count; i++)
            values[i] = (uint16_t)get16(pdu + 6 + 2 * i);
        break;
    case MODBUS_FC_MASK_WRITE_REGISTER: {
        if (size < 7 || first >= img->map->size[REGMAP_HOLDING_REGISTER])
            return -1;
        /* The specification's result: (current AND and) OR (or AND NOT and). */
        unsigned current = img->mb->tab_registers[first];
        unsigned and_mask = get16(pdu + 3), or_mask = get16(pdu + 5);
        values[0] = (uint16_t)((current & and_mask) | (or_mask & ~and_mask));
        break;
    }
    case MODBUS_FC_WRITE_AND_READ_REGISTERS:
        if (count < 1 || count > MODBUS_MAX_WR_WRITE_REGISTERS || size < 10 + 2 * count)
            return -1;
        /*@ loop invariant 0 <= i <= count;
            loop assigns i, values[0 .. count - 1];
            loop variant count - i;
        */
        for (unsigned i = 0; i < count; i++)
            values[i] = (uint16_t)get16(pdu + 10 + 2 * i);
        break;
    }
    *table = written_table;
    *address = first;
    return (int)count;
}
