/* SPDX-License-Identifier: MIT */
/*
 * fuzz_modbus.c - libFuzzer target: an arbitrary Modbus TCP request, on the
 * server's path. What mb_request_check() passes goes, for a write, through
 * the gateway's write path first (fuzz_robot.h: the values into the image,
 * regmap_decode_write() with the command rows' check, restored on refusal,
 * applied otherwise, commands to a fake robot), then to libmodbus's
 * modbus_reply() on the real image, as the server does. Rules:
 * - a request that passes the check gets a reply, and never an exception
 *   from libmodbus;
 * - no request makes libmodbus, the decoder or the command rows read or
 *   write out of bounds;
 * - a refused write leaves the image as it was; an accepted one leaves
 *   exactly the values the write path judged (what libmodbus writes is
 *   what was checked);
 * - what reaches the robot is one JSON command, never motion (off here).
 * Each input starts from the same image and an idle command queue, so a
 * crash reproduces from its input alone.
 */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "fuzz_robot.h"
#include "log.h"
#include "mb_request.h"
#include "regmap.h"

static struct regmap map;
static struct regmap_image img;
static modbus_t *ctx;
static int pair[2];
static struct cmd_queue queue;
static struct fake_robot robot;
static struct plc_commands pc, pc_initial;
static struct fuzz_gateway gw;
static struct policy policy_initial;
static modbus_mapping_t initial;

static uint16_t *copy_of(const void *p, size_t n)
{
    uint16_t *c = malloc(n ? n : 1);
    if (!c)
        abort();
    memcpy(c, p, n);
    return c;
}

static void setup(void)
{
    struct plc_commands_config cfg = {0};

    log_set_level((enum log_level)0);
    if (regmap_init(&map) || regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST) ||
        socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_NONBLOCK, 0, pair) < 0)
        abort();
    ctx = modbus_new_tcp(NULL, 0);
    modbus_set_socket(ctx, pair[0]);
    modbus_set_response_timeout(ctx, 0, 1);
    fake_robot_init(&robot, &queue, NULL, 2000);
    if (plc_commands_init(&pc, &img, &queue, &cfg, fake_now, &robot))
        abort();
    robot.pc = &pc;
    fuzz_gateway_init(&gw, &img, &pc, &robot, false);
    pc_initial = pc;
    policy_initial = gw.policy;
    /* The image as the gateway starts with it. */
    initial = *img.mb;
    initial.tab_bits = (uint8_t *)copy_of(img.mb->tab_bits, (size_t)img.mb->nb_bits);
    initial.tab_input_bits =
        (uint8_t *)copy_of(img.mb->tab_input_bits, (size_t)img.mb->nb_input_bits);
    initial.tab_registers = copy_of(img.mb->tab_registers, (size_t)img.mb->nb_registers * 2);
    initial.tab_input_registers =
        copy_of(img.mb->tab_input_registers, (size_t)img.mb->nb_input_registers * 2);
}

static void reset(void)
{
    modbus_mapping_t *mb = img.mb;
    memcpy(mb->tab_bits, initial.tab_bits, (size_t)mb->nb_bits);
    memcpy(mb->tab_input_bits, initial.tab_input_bits, (size_t)mb->nb_input_bits);
    memcpy(mb->tab_registers, initial.tab_registers, (size_t)mb->nb_registers * 2);
    memcpy(mb->tab_input_registers, initial.tab_input_registers,
           (size_t)mb->nb_input_registers * 2);
    pc = pc_initial;
    gw.policy = policy_initial;
    robot.connected = true;
    robot.outstanding = 0;
    cmd_queue_set_connected(&queue, true);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    static uint16_t values[MODBUS_MAX_WRITE_BITS], image_after[MODBUS_MAX_WRITE_BITS];
    uint8_t req[7 + 253];
    uint8_t rsp[512];

    if (!ready) {
        setup();
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
    reset();

    enum regmap_table table = REGMAP_COIL;
    unsigned address = 0;
    int count = mb_request_written_values(&img, req + 7, size, &table, &address, values);
    FUZZ_REQUIRE(count != 0, "a checked write sets nothing");
    if (count > 0 && fuzz_write(&gw, table, address, (unsigned)count, values, false) != 0) {
        fake_drain(&robot);
        return 0; /* refused: answered with an exception, nothing applied */
    }
    FUZZ_REQUIRE(modbus_reply(ctx, req, (int)(7 + size), img.mb) >= 0,
                 "libmodbus could not answer a checked request");
    ssize_t n = recv(pair[1], rsp, sizeof(rsp), MSG_DONTWAIT);
    FUZZ_REQUIRE(n >= 9 && !(rsp[7] & 0x80),
                 "libmodbus answered a checked request with an exception");
    if (count > 0) {
        regmap_save(&img, table, address, (unsigned)count, image_after);
        FUZZ_REQUIRE(memcmp(values, image_after, (size_t)count * 2) == 0,
                     "libmodbus wrote other values than the write path judged");
        plc_write_after(&gw.writes); /* as the server does once libmodbus answered */
    }
    fake_drain(&robot);
    return 0;
}
