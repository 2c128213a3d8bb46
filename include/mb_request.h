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
 * Checks the PDU 'pdu' of 'size' bytes (function code first) against the
 * map and the current image. Returns 0 when it may be answered, or the
 * exception code to answer with, in the order the Modbus specification
 * gives: 01 unsupported function; 03 a malformed request or a quantity
 * out of range; 02 an address range outside the table, or a write to an
 * address that is not writable; 03 a written value out of the row's range.
 */
int mb_request_check(const struct regmap_image *img, const uint8_t *pdu,
                     size_t size);

/* True for the function codes that write (5, 6, 15, 16, 22, 23). */
int mb_request_is_write(uint8_t function);

/*
 * The table and address range a write request touches, for a checked
 * request. Returns 0, or -1 for a request that does not write.
 */
int mb_request_write_range(const uint8_t *pdu, size_t size,
                           enum regmap_table *table, unsigned *address,
                           unsigned *count);

#endif
