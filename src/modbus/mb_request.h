/* SPDX-License-Identifier: MIT */
/*
 * mb_request.h - check a Modbus request before anything answers it.
 *
 * libmodbus 3.1.6's modbus_reply() answers some malformed requests by
 * sleeping for the response timeout and flushing the socket, which would
 * stall the event loop and drop requests pipelined behind the bad one; and it
 * reads past a request whose byte count lies. So every request is checked
 * here first, completely, and modbus_reply() only sees requests it can
 * answer directly.
 */
#ifndef JAKAGW_MB_REQUEST_H
#define JAKAGW_MB_REQUEST_H

#include <stddef.h>
#include <stdint.h>

#include "regmap.h"

/* Function codes beyond what <modbus.h> names. */
#define MB_FC_READ_DEVICE_ID 0x2B
#define MB_MEI_READ_DEVICE_ID 0x0E

/* Exception codes beyond what <modbus.h> names as enum values. */
#define MB_EXCEPTION_GATEWAY_PATH 0x0A

/*
 * mb_request_check()'s answer for function codes 128-255. The Modbus
 * specification reserves them for exception responses, whose function code
 * is the request's plus 0x80: a request that carries one has no exception
 * reply (0x84 | 0x80 is 0x84 again, which a master reads as exception 01 to
 * function 4, and libmodbus's 8-bit sum makes it 04, a normal reply). Such a
 * PDU is a response, not a request; whoever sent it gets no answer, and the
 * server closes the connection (answering responses with responses could
 * also keep two servers busy with each other forever).
 */
#define MB_REQUEST_NOT_A_REQUEST (-1)

/*
 * The facts the proofs of this module rest on (make prove checks every
 * function below against its contract, and that nothing in it can fault
 * or overflow): a PDU is 'size' readable bytes; a written value is room
 * for the most a request can write; an answer is 0, an exception code or
 * MB_REQUEST_NOT_A_REQUEST.
 */
/*@ predicate mb_pdu_readable(uint8_t *pdu, size_t size) =
        \valid_read(pdu + (0 .. size - 1));
    predicate mb_values_room(uint16_t *values) =
        \valid(values + (0 .. MODBUS_MAX_WRITE_BITS - 1));
    predicate mb_answer(integer a) =
        a == 0 || a == MB_REQUEST_NOT_A_REQUEST ||
        a == MODBUS_EXCEPTION_ILLEGAL_FUNCTION ||
        a == MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS ||
        a == MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    predicate mb_read_inside(struct regmap *map, enum regmap_table table, uint8_t *pdu,
                             integer max) =
        1 <= pdu[3] * 256 + pdu[4] <= max &&
        pdu[1] * 256 + pdu[2] + pdu[3] * 256 + pdu[4] <= map->size[table];
*/

/*
 * Checks the PDU 'pdu' of 'size' bytes (function code first) against the
 * map and the current image. Returns 0 when it may be answered,
 * MB_REQUEST_NOT_A_REQUEST for a function code of 128 or more, or the
 * exception code to answer with, in the order the Modbus specification
 * gives: 01 unsupported function; 03 a malformed request or a quantity
 * out of range; 02 an address range outside the table, or a write to an
 * address that is not writable; 03 a written value out of the row's range.
 */
/*@ requires regmap_image_readable(img);
    requires mb_pdu_readable(pdu, size);
    assigns \nothing;
    ensures mb_answer(\result);
    ensures size >= 1 && (pdu[0] & 0x80) != 0 <==> \result == MB_REQUEST_NOT_A_REQUEST;
    ensures \result == 0 && pdu[0] == MODBUS_FC_READ_COILS ==> size == 5 &&
            mb_read_inside(img->map, REGMAP_COIL, pdu, MODBUS_MAX_READ_BITS);
    ensures \result == 0 && pdu[0] == MODBUS_FC_READ_DISCRETE_INPUTS ==> size == 5 &&
            mb_read_inside(img->map, REGMAP_DISCRETE_INPUT, pdu, MODBUS_MAX_READ_BITS);
    ensures \result == 0 && pdu[0] == MODBUS_FC_READ_HOLDING_REGISTERS ==> size == 5 &&
            mb_read_inside(img->map, REGMAP_HOLDING_REGISTER, pdu, MODBUS_MAX_READ_REGISTERS);
    ensures \result == 0 && pdu[0] == MODBUS_FC_READ_INPUT_REGISTERS ==> size == 5 &&
            mb_read_inside(img->map, REGMAP_INPUT_REGISTER, pdu, MODBUS_MAX_READ_REGISTERS);
*/
int mb_request_check(const struct regmap_image *img, const uint8_t *pdu,
                     size_t size);

/* True for the function codes that write (5, 6, 15, 16, 22, 23). */
/*@ assigns \nothing;
    ensures \result == 0 || \result == 1;
    ensures \result == 1 <==> function == 5 || function == 6 || function == 15 ||
                              function == 16 || function == 22 || function == 23;
*/
int mb_request_is_write(uint8_t function);

/*
 * The table and address range a write request touches, for a checked
 * request. Returns 0, or -1 for a request that does not write (or is
 * too short to say).
 */
/*@ requires mb_pdu_readable(pdu, size);
    requires \valid(table) && \valid(address) && \valid(count);
    requires \separated(table, address, count);
    assigns *table, *address, *count;
    ensures \result == 0 || \result == -1;
    ensures \result == 0 ==> size >= 5 && *address <= 65535 && *count <= 65535 &&
                             (*table == REGMAP_COIL || *table == REGMAP_HOLDING_REGISTER);
    ensures \result == 0 ==> pdu[0] == 5 || pdu[0] == 6 || pdu[0] == 15 || pdu[0] == 16 ||
                             pdu[0] == 22 || pdu[0] == 23;
    ensures \result == 0 && (pdu[0] == 5 || pdu[0] == 6 || pdu[0] == 22) ==> *count == 1;
*/
int mb_request_write_range(const uint8_t *pdu, size_t size,
                           enum regmap_table *table, unsigned *address,
                           unsigned *count);

/*
 * The values a checked write request sets, as the image will hold them:
 * one per bit (0 or 1) for coils, one per register otherwise, in address
 * order; for mask write (22) the masked result from 'img'. 'values' has
 * room for MODBUS_MAX_WRITE_BITS. Returns the count, or -1 for a request
 * that does not write, or whose quantity, byte count or address
 * mb_request_check() would refuse (so it reads and writes only inside
 * the PDU, the image and 'values', whatever it is given).
 */
/*@ requires regmap_image_readable(img);
    requires mb_pdu_readable(pdu, size);
    requires mb_values_room(values);
    requires \valid(table) && \valid(address);
    requires \separated(values + (0 .. MODBUS_MAX_WRITE_BITS - 1), table, address);
    assigns *table, *address, values[0 .. MODBUS_MAX_WRITE_BITS - 1];
    ensures \result == -1 || 1 <= \result <= MODBUS_MAX_WRITE_BITS;
*/
int mb_request_written_values(const struct regmap_image *img, const uint8_t *pdu,
                              size_t size, enum regmap_table *table,
                              unsigned *address, uint16_t *values);

#endif
