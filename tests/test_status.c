/* SPDX-License-Identifier: MIT */
/* test_status.c - parsing status documents into struct jaka_status. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "status.h"

#ifndef SAMPLES_DIR
#define SAMPLES_DIR "../shared/samples"
#endif

static struct jaka_status st;

static int parse(const char *json)
{
    return status_parse(&st, json, strlen(json));
}

static char *read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    assert_non_null(buf);
    assert_int_equal(fread(buf, 1, (size_t)n, f), (size_t)n);
    fclose(f);
    buf[n] = '\0';
    *size = (size_t)n;
    return buf;
}

/* Parses a recorded document from tests/data; it must be there. */
static void parse_sample(const char *name)
{
    char path[512];
    size_t size = 0;
    snprintf(path, sizeof(path), "%s/%s", SAMPLES_DIR, name);
    char *doc = read_file(path, &size);
    if (!doc)
        fail_msg("cannot read %s", path);
    assert_int_equal(status_parse(&st, doc, size), STATUS_PARSE_OK);
    free(doc);
}

static void real_zu5s_document(void **state)
{
    (void)state;
    parse_sample("status-zu5s-1.5.14.json");
    assert_true(st.len[0].present);
    assert_int_equal((int)st.len[0].value, 3208);
    assert_true(st.errcode[0].present);
    assert_true(st.errcode[0].value == 0);
    assert_float_equal(st.joint_actual_position[0].value, -263.40236, 1e-9);
    assert_float_equal(st.actual_position[5].value, -159.85328, 1e-9);
    /* This controller sends 135 din, 64 ain, 2 tio_ain, 11 values a joint. */
    assert_int_equal(st.count[STATUS_F_din], 135);
    assert_int_equal(st.count[STATUS_F_ain], 64);
    assert_int_equal(st.count[STATUS_F_tio_ain], 2);
    assert_true(st.joint_monitor_extra[5].present);
    assert_float_equal(st.joint_monitor_extra[5].value, -0.12064021426485122, 1e-15);
    assert_false(st.din[135].present);
    /* No extio, no extras on this version. */
    assert_int_equal(st.count[STATUS_F_extio_num], 0);
    assert_int_equal(st.count[STATUS_F_motion_line], 0);
    assert_false(st.enabled[0].present && st.enabled[0].value != 0);
    assert_true(st.enabled[0].present);
    assert_int_equal((int)st.current_user_id[0].value, 1);
    assert_int_equal((int)st.funcdi_type[14].value, -1);
    assert_true(st.torq_address[0].present);
    assert_string_equal(st.torq_address[0].text, "192.168.2.100");
    assert_float_equal(st.torq_comm[0].value, 8080, 0);
}

static void real_controller_a_document(void **state)
{
    (void)state;
    parse_sample("status-controller-a.json");
    assert_int_equal(st.count[STATUS_F_din], 199);
    assert_int_equal(st.count[STATUS_F_ain], 128);
    assert_int_equal(st.count[STATUS_F_eip_adpt_ain], 48);
    assert_string_equal(st.extio_alias[0].text, "AS228P");
    assert_string_equal(st.extio_comm_0[0].text, "192.168.1.5");
    assert_float_equal(st.extio_di_start[0].value, 104096, 0);
    assert_float_equal(st.monitor_extra[3].value, 23.389999389648438, 1e-12);
    assert_int_equal(st.count[STATUS_F_monitor_extra], 4);
    assert_int_equal(st.count[STATUS_F_tio_rs_name], 8);
    assert_true(st.tio_rs_name[0].present);
    assert_string_equal(st.tio_rs_name[0].text, "");
    assert_int_equal(st.count[STATUS_F_torq_extra], 6);
}

static void missing_fields_are_not_present(void **state)
{
    (void)state;
    assert_int_equal(parse("{\"enabled\": true}"), STATUS_PARSE_OK);
    assert_true(st.enabled[0].present);
    assert_true(status_flag(&st.enabled[0]));
    assert_false(st.powered_on[0].present);
    assert_false(st.joint_actual_position[0].present);
    assert_int_equal(st.count[STATUS_F_din], 0);
    assert_false(st.errmsg[0].present);
}

static void wrong_types_are_not_present(void **state)
{
    (void)state;
    assert_int_equal(parse("{\"task_state\": \"four\", \"din\": {\"a\": 1}, "
                           "\"ain\": [1.5, \"x\", null, 2], \"errmsg\": 42, "
                           "\"monitor_data\": 7, \"joint_actual_position\": [[1]]}"),
                     STATUS_PARSE_OK);
    assert_false(st.task_state[0].present);
    assert_int_equal(st.count[STATUS_F_din], 0);
    assert_int_equal(st.count[STATUS_F_ain], 4);
    assert_true(st.ain[0].present);
    assert_false(st.ain[1].present);
    assert_false(st.ain[2].present);
    assert_true(st.ain[3].present);
    /* A number where text is expected is kept as text. */
    assert_string_equal(st.errmsg[0].text, "42");
    assert_false(st.cabinet_temperature[0].present);
    assert_false(st.joint_actual_position[0].present);
}

static void huge_and_non_finite_numbers(void **state)
{
    (void)state;
    assert_int_equal(parse("{\"rapidrate\": 1e999, \"curr_tcp_trans_vel\": -1e308, "
                           "\"task_state\": 1e300, \"len\": \"NaN\"}"),
                     STATUS_PARSE_OK);
    assert_false(st.rapidrate[0].present); /* inf */
    assert_true(st.curr_tcp_trans_vel[0].present);
    assert_true(st.task_state[0].present); /* finite: the encoder clamps it */
    assert_false(st.len[0].present);       /* "NaN" is not a finite number */
}

static void errcode_forms(void **state)
{
    (void)state;
    static const struct { const char *json; double value; bool present; } cases[] = {
        {"{\"errcode\": \"0x0\"}", 0, true},
        {"{\"errcode\": \"0x2B0C0001\"}", 0x2B0C0001, true},
        {"{\"errcode\": \"0xffffffff\"}", 4294967295.0, true},
        {"{\"errcode\": 4096}", 4096, true},
        {"{\"errcode\": \"123\"}", 123, true},
        {"{\"errcode\": -1}", 4294967295.0, true},
        {"{\"errcode\": \"0x1ffffffff\"}", 0, false},
        {"{\"errcode\": \"\"}", 0, false},
        {"{\"errcode\": \"0xZZ\"}", 0, false},
        {"{\"errcode\": 1.5}", 0, false},
        {"{\"errcode\": null}", 0, false},
    };
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        assert_int_equal(parse(cases[i].json), STATUS_PARSE_OK);
        assert_int_equal(st.errcode[0].present, cases[i].present);
        assert_true(st.errcode[0].value == cases[i].value);
    }
}

static void longer_arrays_are_cut_at_capacity(void **state)
{
    (void)state;
    char doc[8192];
    size_t n = (size_t)snprintf(doc, sizeof(doc), "{\"din\": [");
    for (int i = 0; i < 300; i++)
        n += (size_t)snprintf(doc + n, sizeof(doc) - n, "%s%d", i ? ", " : "", i % 2);
    snprintf(doc + n, sizeof(doc) - n, "], \"joint_actual_position\": [1,2,3,4,5,6,7]}");
    assert_int_equal(parse(doc), STATUS_PARSE_OK);
    assert_int_equal(st.count[STATUS_F_din], 256);
    assert_true(st.din[255].present);
    assert_float_equal(st.din[255].value, 1, 0);
    assert_int_equal(st.count[STATUS_F_joint_actual_position], 6);
}

static void bad_json_and_non_objects(void **state)
{
    (void)state;
    assert_int_equal(parse("{\"len\": 12, "), STATUS_PARSE_BAD_JSON);
    assert_int_equal(parse("not json"), STATUS_PARSE_BAD_JSON);
    assert_int_equal(parse("[1, 2]"), STATUS_PARSE_NOT_OBJECT);
    assert_int_equal(parse("\"x\""), STATUS_PARSE_NOT_OBJECT);
    assert_false(st.len[0].present);
}

static void manual_spelling_task_mode(void **state)
{
    (void)state;
    assert_int_equal(parse("{\"task mode\": 2}"), STATUS_PARSE_OK);
    assert_true(st.task_mode[0].present);
    assert_float_equal(st.task_mode[0].value, 2, 0);
}

static void long_strings_are_truncated(void **state)
{
    (void)state;
    char doc[1024];
    char msg[400];
    memset(msg, 'm', sizeof(msg) - 1);
    msg[sizeof(msg) - 1] = '\0';
    snprintf(doc, sizeof(doc), "{\"errmsg\": \"%s\"}", msg);
    assert_int_equal(parse(doc), STATUS_PARSE_OK);
    assert_int_equal(strlen(st.errmsg[0].text), STATUS_MSG_SIZE - 1);
}

static void element_paths(void **state)
{
    (void)state;
    char path[64];
    status_element_path(STATUS_F_joint_temperature, 3, path, sizeof(path));
    assert_string_equal(path, "monitor_data[5][3][2]");
    status_element_path(STATUS_F_monitor_extra, 0, path, sizeof(path));
    assert_string_equal(path, "monitor_data[6]");
    status_element_path(STATUS_F_enabled, 0, path, sizeof(path));
    assert_string_equal(path, "enabled");
    status_element_path(STATUS_F_extio_di_count, 2, path, sizeof(path));
    assert_string_equal(path, "extio.setup[2][3][0][1]");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(real_zu5s_document),
        cmocka_unit_test(real_controller_a_document),
        cmocka_unit_test(missing_fields_are_not_present),
        cmocka_unit_test(wrong_types_are_not_present),
        cmocka_unit_test(huge_and_non_finite_numbers),
        cmocka_unit_test(errcode_forms),
        cmocka_unit_test(longer_arrays_are_cut_at_capacity),
        cmocka_unit_test(bad_json_and_non_objects),
        cmocka_unit_test(manual_spelling_task_mode),
        cmocka_unit_test(long_strings_are_truncated),
        cmocka_unit_test(element_paths),
    };
    return cmocka_run_group_tests_name("status", tests, NULL, NULL);
}
