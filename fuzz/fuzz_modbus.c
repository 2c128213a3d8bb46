/*
 * fuzz_modbus.c - libFuzzer target: an arbitrary Modbus TCP request. What
 * mb_request_check() passes goes to libmodbus's modbus_reply() on the real
 * image, as the server does; a request that passes the check must get a
 * reply, and no request may make libmodbus read or write out of bounds.
 */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "mb_request.h"
#include "regmap.h"

static struct regmap map;
static struct regmap_image img;
static modbus_t *ctx;
static int pair[2];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    uint8_t req[7 + 253];
    uint8_t rsp[512];

    if (!ready) {
        if (regmap_init(&map) || regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST) ||
            socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_NONBLOCK, 0, pair) < 0)
            abort();
        ctx = modbus_new_tcp(NULL, 0);
        modbus_set_socket(ctx, pair[0]);
        modbus_set_response_timeout(ctx, 0, 1);
        ready = 1;
    }
    if (size < 1 || size > 253)
        return 0;
    /* MBAP header as the server's framer has validated it. */
    req[0] = 0x12;
    req[1] = 0x34;
    req[2] = req[3] = 0;
    req[4] = (uint8_t)((size + 1) >> 8);
    req[5] = (uint8_t)(size + 1);
    req[6] = 1;
    memcpy(req + 7, data, size);
    if (mb_request_check(&img, req + 7, size) != 0)
        return 0;
    if (req[7] == 0x11 || req[7] == 0x2B)
        return 0; /* answered by the server itself, not libmodbus */
    if (modbus_reply(ctx, req, (int)(7 + size), img.mb) < 0)
        abort(); /* a checked request must always get a reply */
    ssize_t n = recv(pair[1], rsp, sizeof(rsp), MSG_DONTWAIT);
    if (n < 9 || (rsp[7] & 0x80))
        abort(); /* a checked request is never an exception */
    return 0;
}
