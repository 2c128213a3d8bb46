/* SPDX-License-Identifier: MIT */
/* test_can_map.c - the CAN frame table, its encoder and the DBC it generates. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "can_map.h"

static const struct can_frame_def *frame(const char *name)
{
    for (unsigned i = 0; i < can_map_frame_count; i++)
        if (strcmp(can_map_frames[i].name, name) == 0)
            return &can_map_frames[i];
    fail_msg("no frame %s", name);
    return NULL;
}

static const struct can_signal *signal_named(const char *name)
{
    for (unsigned i = 0; i < can_map_frame_count; i++)
        for (unsigned k = 0; k < can_map_frames[i].signal_count; k++)
            if (strcmp(can_map_frames[i].signals[k].name, name) == 0)
                return &can_map_frames[i].signals[k];
    fail_msg("no signal %s", name);
    return NULL;
}

static void set(struct jaka_status *s, enum status_field field, unsigned index, double v)
{
    struct status_num *n = (struct status_num *)status_num_at(s, field, index);
    n->value = v;
    n->present = true;
}

static uint32_t le32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static struct jaka_status *new_status(void)
{
    struct jaka_status *s = calloc(1, sizeof(*s));
    assert_non_null(s);
    return s;
}

static void table_is_valid(void **state)
{
    (void)state;
    assert_int_equal(can_map_check(), 0);
    /* Every group has a frame, and every frame fits a classic CAN frame. */
    for (int g = 0; g < CAN_GROUP_COUNT; g++) {
        bool found = false;
        for (unsigned i = 0; i < can_map_frame_count; i++)
            found |= can_map_frames[i].group == (enum can_group)g;
        assert_true(found);
    }
    assert_int_equal(can_map_max_offset(), 8);
    assert_int_equal(can_frame_id(frame("JAKA_Health"), 0x500), 0x501);
}

static void state_frame_flags_and_bytes(void **state)
{
    (void)state;
    struct jaka_status *s = new_status();
    struct can_inputs in = {.status = s};
    uint8_t d[8];

    set(s, STATUS_F_powered_on, 0, 1);
    set(s, STATUS_F_enabled, 0, 0);
    set(s, STATUS_F_paused, 0, 1);
    set(s, STATUS_F_inpos, 0, 1);
    set(s, STATUS_F_emergency_stop, 0, 0);
    /* protective_stop not sent */
    set(s, STATUS_F_on_soft_limit, 0, 1);
    set(s, STATUS_F_drag_status, 0, 0);
    set(s, STATUS_F_task_state, 0, 4);
    set(s, STATUS_F_task_mode, 0, 2);
    set(s, STATUS_F_interp_state, 0, 3);
    set(s, STATUS_F_current_tool_id, 0, 3);
    /* current_user_id not sent */
    can_map_encode(frame("JAKA_State"), &in, d);
    /* Byte 0: PoweredOn 1, Enabled 0, Paused 1, InPosition 1 (2 bits each). */
    assert_int_equal(d[0], 0x01 | 0x00 << 2 | 0x01 << 4 | 0x01 << 6);
    /* Byte 1: EStop 0, ProtectiveStop 3 (not sent), OnSoftLimit 1, Drag 0. */
    assert_int_equal(d[1], 0x00 | 0x03 << 2 | 0x01 << 4 | 0x00 << 6);
    assert_int_equal(d[2], 4);
    assert_int_equal(d[3], 2);
    assert_int_equal(d[4], 3);
    assert_int_equal(d[5], 3);
    assert_int_equal(d[6], 0xFF); /* UserId not sent */
    assert_int_equal(d[7], 0);    /* beyond the frame's 7 bytes */
    free(s);
}

static void nothing_sent_is_marked_not_zero(void **state)
{
    (void)state;
    struct jaka_status *s = new_status();
    struct can_inputs with_empty = {.status = s}, without = {.status = NULL};
    uint8_t d[8], e[8];

    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        if (f->group == CAN_GROUP_health)
            continue;
        can_map_encode(f, &with_empty, d);
        can_map_encode(f, &without, e);
        assert_memory_equal(d, e, 8);
        for (unsigned k = 0; k < f->signal_count; k++) {
            struct can_signal_range r;
            can_signal_range(&f->signals[k], &r);
            assert_true(r.has_invalid);
            assert_true(can_signal_raw(&f->signals[k], &with_empty) == r.invalid);
        }
    }
    can_map_encode(frame("JAKA_State"), &with_empty, d);
    assert_int_equal(d[0], 0xFF);
    assert_int_equal(d[1], 0xFF);
    can_map_encode(frame("JAKA_Program"), &with_empty, d);
    assert_int_equal(le32(d), 0xFFFFFFFFu);
    assert_int_equal(d[4], 0xFF);
    assert_int_equal(d[5], 0xFF);
    can_map_encode(frame("JAKA_Joints_1_2"), &with_empty, d);
    assert_int_equal(le32(d), 0x80000000u);
    assert_int_equal(le32(d + 4), 0x80000000u);
    /* Present elements next to absent ones: each is marked on its own. */
    set(s, STATUS_F_joint_actual_position, 1, 0.0);
    can_map_encode(frame("JAKA_Joints_1_2"), &with_empty, d);
    assert_int_equal(le32(d), 0x80000000u);
    assert_int_equal(le32(d + 4), 0);
    free(s);
}

static void scaling_rounding_saturation(void **state)
{
    (void)state;
    struct jaka_status *s = new_status();
    struct can_inputs in = {.status = s};
    const struct can_signal *j1 = signal_named("Joint1Position");
    const struct can_signal *tool = signal_named("ToolId");
    const struct can_signal *rate = signal_named("RapidRate");
    const struct can_signal *err = signal_named("ErrorCode");
    const struct can_signal *z = signal_named("TcpZ");

    struct { double v; int64_t raw; } joint[] = {
        {12.3456, 12346}, {12.3454, 12345}, {-12.3456, -12346}, {-12.3454, -12345},
        {-263.40236, -263402}, {0.0004, 0}, {-0.0004, 0},
        {1e9, 2147483647}, {-1e9, -2147483647}, /* saturates short of the marker */
        {2147483.647, 2147483647}, {-2147483.647, -2147483647},
    };
    for (unsigned i = 0; i < sizeof(joint) / sizeof(joint[0]); i++) {
        set(s, STATUS_F_joint_actual_position, 0, joint[i].v);
        if (can_signal_raw(j1, &in) != joint[i].raw)
            fail_msg("joint %g: raw %lld, expected %lld", joint[i].v,
                     (long long)can_signal_raw(j1, &in), (long long)joint[i].raw);
    }
    /* Ties round half away from zero, not to even. */
    struct { double v; int64_t raw; } ids[] = {
        {2.5, 3}, {3.5, 4}, {2.4999, 2}, {254, 254}, {255, 254}, {300, 254}, {-3, 0},
    };
    for (unsigned i = 0; i < sizeof(ids) / sizeof(ids[0]); i++) {
        set(s, STATUS_F_current_tool_id, 0, ids[i].v);
        assert_int_equal(can_signal_raw(tool, &in), ids[i].raw);
    }
    /* rapidrate 0..1 is sent in 0.1 % steps. */
    set(s, STATUS_F_rapidrate, 0, 0.625);
    assert_int_equal(can_signal_raw(rate, &in), 625);
    set(s, STATUS_F_rapidrate, 0, 1.0);
    assert_int_equal(can_signal_raw(rate, &in), 1000);
    set(s, STATUS_F_rapidrate, 0, 0.00049);
    assert_int_equal(can_signal_raw(rate, &in), 0);
    set(s, STATUS_F_rapidrate, 0, 1e6);
    assert_int_equal(can_signal_raw(rate, &in), 65534);
    set(s, STATUS_F_errcode, 0, (double)0x2B0C0001);
    assert_int_equal(can_signal_raw(err, &in), 0x2B0C0001);
    set(s, STATUS_F_errcode, 0, 5e9);
    assert_int_equal(can_signal_raw(err, &in), 0xFFFFFFFEu);
    set(s, STATUS_F_actual_position, 2, 663.65);
    assert_int_equal(can_signal_raw(z, &in), 663650);
    /* A NaN that got into the model is not sent as a number. */
    set(s, STATUS_F_actual_position, 2, NAN);
    assert_true(can_signal_raw(z, &in) == INT32_MIN);
    free(s);
}

static void byte_order_is_little_endian(void **state)
{
    (void)state;
    struct jaka_status *s = new_status();
    struct can_inputs in = {.status = s};
    uint8_t d[8];

    set(s, STATUS_F_joint_actual_position, 2, 0x12345678 / 1000.0);
    set(s, STATUS_F_joint_actual_position, 3, -1 / 1000.0);
    can_map_encode(frame("JAKA_Joints_3_4"), &in, d);
    const uint8_t expect[8] = {0x78, 0x56, 0x34, 0x12, 0xFF, 0xFF, 0xFF, 0xFF};
    assert_memory_equal(d, expect, 8);

    set(s, STATUS_F_errcode, 0, (double)0x2B0C0001);
    set(s, STATUS_F_rapidrate, 0, 0.625); /* 625 = 0x0271 */
    can_map_encode(frame("JAKA_Program"), &in, d);
    const uint8_t program[8] = {0x01, 0x00, 0x0C, 0x2B, 0x71, 0x02, 0, 0};
    assert_memory_equal(d, program, 8);

    for (unsigned i = 0; i < 6; i++)
        set(s, STATUS_F_actual_position, i, (double)(i + 1) * 100.5);
    can_map_encode(frame("JAKA_Tcp_Ry_Rz"), &in, d);
    assert_int_equal(le32(d), 502500);
    assert_int_equal(le32(d + 4), 603000);
    free(s);
}

static void health_frame_from_gateway_values(void **state)
{
    (void)state;
    double gw[GW_VALUE_COUNT] = {0};
    struct can_inputs in = {.status = NULL, .gw = gw};
    uint8_t d[8];

    gw[GW_status_link_up] = 1;
    gw[GW_command_link_up] = 0;
    gw[GW_status_fresh] = 1;
    gw[GW_status_age_ms] = 31;
    in.mirror[CAN_MIRROR_rolling_counter] = 200;
    in.mirror[CAN_MIRROR_frames_dropped] = 0x1234;
    can_map_encode(frame("JAKA_Health"), &in, d);
    const uint8_t expect[8] = {0x05, 200, 31, 0, 0, 0, 0x34, 0x12};
    assert_memory_equal(d, expect, 8);
    /* Gateway values have no 'not sent' marker: all ones is "no document yet". */
    gw[GW_status_age_ms] = 4294967295.0;
    gw[GW_status_link_up] = 0;
    gw[GW_status_fresh] = 0;
    can_map_encode(frame("JAKA_Health"), &in, d);
    assert_int_equal(d[0], 0);
    assert_int_equal(le32(d + 2), 0xFFFFFFFFu);
    /* With no gateway values at all, everything reads 0. */
    in.gw = NULL;
    can_map_encode(frame("JAKA_Health"), &in, d);
    assert_int_equal(d[0], 0);
    assert_int_equal(le32(d + 2), 0);
}

static char *dbc_text(const struct can_dbc_options *opt)
{
    char *text = NULL;
    size_t size = 0;
    FILE *mem = open_memstream(&text, &size);

    assert_non_null(mem);
    assert_int_equal(can_map_print_dbc(opt, mem), 0);
    fclose(mem);
    return text;
}

static void dbc_lists_every_frame_and_signal(void **state)
{
    (void)state;
    struct can_dbc_options opt = {.base_id = 0x500, .period_ms = 100,
                                  .groups = CAN_GROUPS_ALL};
    char *text = dbc_text(&opt);
    char line[256];

    assert_non_null(strstr(text, "VERSION \"jakagw "));
    assert_non_null(strstr(text, "\nBU_: JAKAGW\n"));
    for (unsigned i = 0; i < can_map_frame_count; i++) {
        const struct can_frame_def *f = &can_map_frames[i];
        unsigned id = 0x500 + f->id_offset;
        snprintf(line, sizeof(line), "\nBO_ %u %s: %u JAKAGW\n", id, f->name, f->dlc);
        if (!strstr(text, line))
            fail_msg("missing '%s'", line + 1);
        snprintf(line, sizeof(line), "BA_ \"GenMsgCycleTime\" BO_ %u 100;", id);
        assert_non_null(strstr(text, line));
        for (unsigned k = 0; k < f->signal_count; k++) {
            const struct can_signal *s = &f->signals[k];
            snprintf(line, sizeof(line), " SG_ %s : %u|%u@1%c ", s->name, s->start_bit,
                     s->bits, s->encoding == CAN_ENC_SIGNED ? '-' : '+');
            if (!strstr(text, line))
                fail_msg("missing '%s'", line);
            snprintf(line, sizeof(line), "CM_ SG_ %u %s \"", id, s->name);
            assert_non_null(strstr(text, line));
        }
    }
    /* Scaling, units and the reserved values. */
    assert_non_null(strstr(text, " SG_ Joint1Position : 0|32@1- (0.001,0) "
                                 "[-2147483.647|2147483.647] \"deg\" Vector__XXX\n"));
    assert_non_null(strstr(text, " SG_ RapidRate : 32|16@1+ (0.1,0) [0|6553.4] \"%\""));
    assert_non_null(strstr(text, " SG_ PoweredOn : 0|2@1+ (1,0) [0|1] \"\""));
    assert_non_null(strstr(text, "VAL_ 1280 PoweredOn 3 \"NotSent\" 0 \"False\" 1 \"True\" ;"));
    assert_non_null(strstr(text, "VAL_ 1280 TaskState 255 \"NotSent\" 1 \"PoweredOff\""));
    assert_non_null(strstr(text, "VAL_ 1283 Joint1Position -2147483648 \"NotSent\" ;"));
    assert_non_null(strstr(text, "VAL_ 1282 ErrorCode 4294967295 \"NotSent\" ;"));
    assert_non_null(strstr(text, "VAL_ 1281 StatusAgeMs 4294967295 \"NoDocumentYet\" ;"));
    assert_null(strstr(text, "VAL_ 1281 RollingCounter"));
    free(text);
}

static void dbc_follows_the_configuration(void **state)
{
    (void)state;
    struct can_dbc_options opt = {.base_id = 0x18FF0000, .extended_ids = true,
                                  .period_ms = 20,
                                  .groups = 1u << CAN_GROUP_state | 1u << CAN_GROUP_tcp};
    char *text = dbc_text(&opt);
    char line[128];

    /* Extended identifiers carry bit 31 in a DBC. */
    snprintf(line, sizeof(line), "BO_ %lu JAKA_State: 7 JAKAGW",
             0x80000000ul | 0x18FF0000ul);
    assert_non_null(strstr(text, line));
    snprintf(line, sizeof(line), "BA_ \"GenMsgCycleTime\" BO_ %lu 20;",
             0x80000000ul | 0x18FF0006ul);
    assert_non_null(strstr(text, line));
    assert_non_null(strstr(text, "JAKA_Tcp_Ry_Rz"));
    assert_null(strstr(text, " JAKA_Health:"));
    assert_null(strstr(text, "Joint1Position"));
    assert_null(strstr(text, "ErrorCode"));
    free(text);
}

static void group_lists(void **state)
{
    (void)state;
    uint32_t g = 0;
    char why[256], buf[128];

    assert_int_equal(can_map_parse_groups("all", &g, why, sizeof(why)), 0);
    assert_int_equal(g, CAN_GROUPS_ALL);
    assert_int_equal(can_map_parse_groups(" state, joints ,health", &g, why, sizeof(why)), 0);
    assert_int_equal(g, 1u << CAN_GROUP_state | 1u << CAN_GROUP_joints |
                            1u << CAN_GROUP_health);
    can_map_format_groups(g, buf, sizeof(buf));
    assert_string_equal(buf, "state,health,joints");
    assert_int_equal(can_map_parse_groups("tcp program", &g, why, sizeof(why)), 0);
    can_map_format_groups(g, buf, sizeof(buf));
    assert_string_equal(buf, "program,tcp");
    can_map_format_groups(CAN_GROUPS_ALL, buf, sizeof(buf));
    assert_string_equal(buf, "all");
    assert_int_equal(can_map_parse_groups("state,joint", &g, why, sizeof(why)), -EINVAL);
    assert_non_null(strstr(why, "'joint' is not a frame group"));
    assert_non_null(strstr(why, "state,health,program,joints,tcp"));
    assert_int_equal(can_map_parse_groups(" , ", &g, why, sizeof(why)), -EINVAL);
    assert_string_equal(why, "lists no frame group");
    assert_int_equal(can_map_parse_groups("", &g, why, sizeof(why)), -EINVAL);
    assert_int_equal(can_map_parse_groups("allx", &g, why, sizeof(why)), -EINVAL);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(table_is_valid),
        cmocka_unit_test(state_frame_flags_and_bytes),
        cmocka_unit_test(nothing_sent_is_marked_not_zero),
        cmocka_unit_test(scaling_rounding_saturation),
        cmocka_unit_test(byte_order_is_little_endian),
        cmocka_unit_test(health_frame_from_gateway_values),
        cmocka_unit_test(dbc_lists_every_frame_and_signal),
        cmocka_unit_test(dbc_follows_the_configuration),
        cmocka_unit_test(group_lists),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
