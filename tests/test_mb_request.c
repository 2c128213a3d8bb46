/* SPDX-License-Identifier: MIT */
/* test_mb_request.c - which requests get which exception. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdlib.h>
#include <string.h>

#include "mb_request.h"

static struct regmap map;
static struct regmap_image img;

static int setup(void **state)
{
    (void)state;
    if (regmap_init(&map) || regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST))
        return -1;
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    regmap_image_free(&img);
    regmap_free(&map);
    return 0;
}

#define CHECK(...)                                                             \
    ({                                                                         \
        const uint8_t pdu_[] = {__VA_ARGS__};                                  \
        mb_request_check(&img, pdu_, sizeof(pdu_));                            \
    })

static void reads(void **state)
{
    (void)state;
    unsigned ir = map.size[REGMAP_INPUT_REGISTER];
    assert_int_equal(CHECK(0x04, 0, 0, 0, 20), 0);
    assert_int_equal(CHECK(0x04, 0, 0, 0, 125), 0);
    assert_int_equal(CHECK(0x04, 0, 0, 0, 126), 3);  /* quantity */
    assert_int_equal(CHECK(0x04, 0, 0, 0, 0), 3);
    assert_int_equal(CHECK(0x04, (ir - 1) >> 8, (ir - 1) & 0xFF, 0, 1), 0);
    assert_int_equal(CHECK(0x04, (ir - 1) >> 8, (ir - 1) & 0xFF, 0, 2), 2);
    assert_int_equal(CHECK(0x04, 0xFF, 0xFF, 0, 1), 2);
    assert_int_equal(CHECK(0x04, 0, 0, 0), 3);        /* short PDU */
    assert_int_equal(CHECK(0x04, 0, 0, 0, 1, 9), 3);  /* long PDU */
    /* 2000 bits is a valid quantity, beyond this table: address error;
     * 2001 is an invalid quantity, which is checked first. */
    assert_true(map.size[REGMAP_DISCRETE_INPUT] < 2000);
    assert_int_equal(CHECK(0x02, 0, 0, 0x07, 0xD0), 2);
    assert_int_equal(CHECK(0x02, 0, 0, 0x07, 0xD1), 3);
    assert_int_equal(CHECK(0x02, 0, 0, 0x04, 0x00), 0); /* 1024 bits */
    assert_int_equal(CHECK(0x01, 0, 0, 0, 1), 0);
    unsigned coils = map.size[REGMAP_COIL], hrs = map.size[REGMAP_HOLDING_REGISTER];
    assert_int_equal(CHECK(0x01, 0, 0, coils >> 8, coils & 0xFF), 0);
    assert_int_equal(CHECK(0x01, 0, 0, (coils + 1) >> 8, (coils + 1) & 0xFF), 2);
    assert_int_equal(CHECK(0x03, 0, 0, 0, 1), 0);
    assert_int_equal(CHECK(0x03, hrs >> 8, hrs & 0xFF, 0, 1), 2); /* past the end */
}

static void writes(void **state)
{
    (void)state;
    assert_int_equal(CHECK(0x06, 0, 0, 0x12, 0x34), 0);
    assert_int_equal(CHECK(0x06, 0, 1, 0, 1), 2);
    assert_int_equal(CHECK(0x05, 0, 0, 0xFF, 0x00), 0);
    assert_int_equal(CHECK(0x05, 0, 0, 0x00, 0x00), 0);
    assert_int_equal(CHECK(0x05, 0, 0, 0x12, 0x34), 3); /* not ON/OFF */
    assert_int_equal(CHECK(0x05, 0, 5, 0xFF, 0x00), 2);
    assert_int_equal(CHECK(0x0F, 0, 0, 0, 1, 1, 0x01), 0);
    assert_int_equal(CHECK(0x0F, 0, 0, 0, 1, 2, 0x01, 0), 3); /* byte count */
    assert_int_equal(CHECK(0x0F, 0, 0, 0, 2, 1, 0x03), 2);
    assert_int_equal(CHECK(0x10, 0, 0, 0, 1, 2, 0xAB, 0xCD), 0);
    assert_int_equal(CHECK(0x10, 0, 0, 0, 1, 4, 0xAB, 0xCD, 0, 0), 3);
    assert_int_equal(CHECK(0x10, 0, 0, 0, 1, 2, 0xAB), 3); /* byte count lies */
    assert_int_equal(CHECK(0x10, 0, 0, 0, 2, 4, 0, 1, 0, 2), 2);
    assert_int_equal(CHECK(0x16, 0, 0, 0xFF, 0x00, 0x00, 0x12), 0);
    assert_int_equal(CHECK(0x16, 0, 3, 0xFF, 0x00, 0x00, 0x12), 2);
    assert_int_equal(CHECK(0x17, 0, 0, 0, 1, 0, 0, 0, 1, 2, 0, 9), 0);
    unsigned hrs = map.size[REGMAP_HOLDING_REGISTER];
    assert_int_equal(CHECK(0x17, hrs >> 8, hrs & 0xFF, 0, 1, 0, 0, 0, 1, 2, 0, 9), 2);
    assert_int_equal(CHECK(0x17, 0, 0, 0, 1, 0, 1, 0, 1, 2, 0, 9), 2); /* a hole */
    assert_int_equal(CHECK(0x17, 0, 0, 0, 1, 0, 0, 0, 1, 3, 0, 9), 3);
}

/* The trigger block (coils 100-131) written whole, as a vendor's client
 * channel writes it: its unassigned coils 115-119 and 121-129 take 0 and
 * refuse 1; alone, or reaching clear_counters' side, they refuse. */
static void coil_block_holes(void **state)
{
    (void)state;
    assert_null(regmap_find(&map, REGMAP_COIL, 117));
    /* FC15, 100-131: 32 coils, 4 bytes, coils 100 (power_on) and 131 set. */
    assert_int_equal(CHECK(0x0F, 0, 100, 0, 32, 4, 0x01, 0x00, 0x00, 0x80), 0);
    assert_int_equal(CHECK(0x0F, 0, 100, 0, 32, 4, 0x00, 0x00, 0x00, 0x00), 0);
    /* 117 = bit 17: byte 2, bit 1. */
    assert_int_equal(CHECK(0x0F, 0, 100, 0, 32, 4, 0x00, 0x00, 0x02, 0x00), 2);
    /* 125 = bit 25: byte 3, bit 1. */
    assert_int_equal(CHECK(0x0F, 0, 100, 0, 32, 4, 0x00, 0x00, 0x00, 0x02), 2);
    assert_int_equal(CHECK(0x0F, 0, 115, 0, 5, 1, 0x00), 2);   /* the hole alone */
    assert_int_equal(CHECK(0x0F, 0, 110, 0, 10, 2, 0, 0), 2);  /* ends in it */
    assert_int_equal(CHECK(0x05, 0, 117, 0x00, 0x00), 2);
    assert_int_equal(CHECK(0x0F, 0, 0, 0, 101, 13, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0), 2);
    /* The outputs, 200-239 whole (holes 218-223 between tool and extension IO). */
    assert_int_equal(CHECK(0x0F, 0, 200, 0, 40, 5, 0xFF, 0xFF, 0x03, 0xFF, 0xFF), 0);
    assert_int_equal(CHECK(0x0F, 0, 200, 0, 40, 5, 0xFF, 0xFF, 0x07, 0xFF, 0xFF), 2);
}

static void other_functions(void **state)
{
    (void)state;
    assert_int_equal(CHECK(0x11), 0);
    assert_int_equal(CHECK(0x11, 0), 3);
    assert_int_equal(CHECK(0x2B, 0x0E, 1, 0), 0);
    assert_int_equal(CHECK(0x2B, 0x0E, 4, 0x80), 0);
    assert_int_equal(CHECK(0x2B, 0x0E, 5, 0), 3);
    assert_int_equal(CHECK(0x2B, 0x0D, 1, 0), 1); /* CANopen: not supported */
    assert_int_equal(CHECK(0x07), 1);
    assert_int_equal(CHECK(0x08, 0, 0, 0, 0), 1);
    assert_int_equal(CHECK(0x00), 1);
    assert_int_equal(CHECK(0x7F), 1);
}

/* Codes 128-255 mark exception responses: no exception reply to them
 * exists, so they are not answered at all (the server closes). */
static void reserved_function_codes(void **state)
{
    (void)state;
    for (unsigned fc = 0x80; fc <= 0xFF; fc++) {
        const uint8_t pdu[] = {(uint8_t)fc, 0, 0, 0, 1};
        assert_int_equal(mb_request_check(&img, pdu, sizeof(pdu)),
                         MB_REQUEST_NOT_A_REQUEST);
        assert_int_equal(mb_request_check(&img, pdu, 1), MB_REQUEST_NOT_A_REQUEST);
    }
    /* 0x84 is a read of input registers with bit 7 set: not a read. */
    assert_int_equal(CHECK(0x84, 0, 0, 0, 1), MB_REQUEST_NOT_A_REQUEST);
    assert_int_equal(CHECK(0x04, 0, 0, 0, 1), 0);
}

static void write_ranges(void **state)
{
    (void)state;
    enum regmap_table t;
    unsigned a, n;
    const uint8_t fc16[] = {0x10, 0, 5, 0, 3, 6, 0, 0, 0, 0, 0, 0};
    assert_int_equal(mb_request_write_range(fc16, sizeof(fc16), &t, &a, &n), 0);
    assert_int_equal(t, REGMAP_HOLDING_REGISTER);
    assert_int_equal(a, 5);
    assert_int_equal(n, 3);
    const uint8_t fc23[] = {0x17, 0, 0, 0, 1, 0, 7, 0, 1, 2, 0, 9};
    assert_int_equal(mb_request_write_range(fc23, sizeof(fc23), &t, &a, &n), 0);
    assert_int_equal(a, 7);
    const uint8_t fc4[] = {0x04, 0, 0, 0, 1};
    assert_int_equal(mb_request_write_range(fc4, sizeof(fc4), &t, &a, &n), -1);
}

/* The values of a request whose counts lie, or whose address is outside
 * the table, are not read at all (-1): each PDU sits in a buffer of its
 * own size, so the sanitizer build sees any byte read past it. */
static int written(const uint8_t *bytes, size_t size, uint16_t *values)
{
    uint8_t *pdu = malloc(size);
    enum regmap_table t;
    unsigned a;
    memcpy(pdu, bytes, size);
    int n = mb_request_written_values(&img, pdu, size, &t, &a, values);
    free(pdu);
    return n;
}

static void written_values_of_unchecked_requests(void **state)
{
    (void)state;
    static uint16_t values[MODBUS_MAX_WRITE_BITS];
    unsigned hrs = map.size[REGMAP_HOLDING_REGISTER];
    /* Whole requests: their values. */
    const uint8_t fc15[] = {0x0F, 0, 0, 0, 10, 2, 0xFF, 0x01};
    assert_int_equal(written(fc15, sizeof(fc15), values), 10);
    assert_int_equal(values[8], 1);
    const uint8_t fc16[] = {0x10, 0, 5, 0, 2, 4, 0x12, 0x34, 0x56, 0x78};
    assert_int_equal(written(fc16, sizeof(fc16), values), 2);
    assert_int_equal(values[1], 0x5678);
    /* 200 coils claimed, one byte of them sent. */
    const uint8_t fc15_short[] = {0x0F, 0, 0, 0, 200, 1, 0xFF};
    assert_int_equal(written(fc15_short, sizeof(fc15_short), values), -1);
    /* 65535 coils: more than values holds. */
    const uint8_t fc15_many[] = {0x0F, 0, 0, 0xFF, 0xFF, 0xFF, 0};
    assert_int_equal(written(fc15_many, sizeof(fc15_many), values), -1);
    const uint8_t fc15_none[] = {0x0F, 0, 0, 0, 0, 0};
    assert_int_equal(written(fc15_none, sizeof(fc15_none), values), -1);
    /* 100 registers claimed, one sent; 124, over the limit. */
    const uint8_t fc16_short[] = {0x10, 0, 5, 0, 100, 200, 0, 1};
    assert_int_equal(written(fc16_short, sizeof(fc16_short), values), -1);
    const uint8_t fc16_many[] = {0x10, 0, 5, 0, 124, 248, 0, 1};
    assert_int_equal(written(fc16_many, sizeof(fc16_many), values), -1);
    /* 121 registers claimed by a write-and-read, none sent. */
    const uint8_t fc23_short[] = {0x17, 0, 0, 0, 1, 0, 7, 0, 121, 242};
    assert_int_equal(written(fc23_short, sizeof(fc23_short), values), -1);
    /* Mask write: short, and past the holding registers' end. */
    const uint8_t fc22_short[] = {0x16, 0, 5, 0xFF, 0xFF};
    assert_int_equal(written(fc22_short, sizeof(fc22_short), values), -1);
    const uint8_t fc22_past[] = {0x16, hrs >> 8, hrs & 0xFF, 0xFF, 0xFF, 0, 0};
    assert_int_equal(written(fc22_past, sizeof(fc22_past), values), -1);
    const uint8_t fc22_last[] = {0x16, (hrs - 1) >> 8, (hrs - 1) & 0xFF, 0xFF, 0xFF, 0, 0};
    assert_int_equal(written(fc22_last, sizeof(fc22_last), values), 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(reads),
        cmocka_unit_test(writes),
        cmocka_unit_test(coil_block_holes),
        cmocka_unit_test(other_functions),
        cmocka_unit_test(reserved_function_codes),
        cmocka_unit_test(write_ranges),
        cmocka_unit_test(written_values_of_unchecked_requests),
    };
    return cmocka_run_group_tests_name("mb_request", tests, setup, teardown);
}
