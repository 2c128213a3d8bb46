/* SPDX-License-Identifier: MIT */
/* test_regmap.c - the register map table, its encoders and its listings. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "regmap.h"

static float as_float(const uint16_t r[2], enum regmap_word_order wo)
{
    uint32_t bits = wo == REGMAP_HIGH_WORD_FIRST ? (uint32_t)r[0] << 16 | r[1]
                                                 : (uint32_t)r[1] << 16 | r[0];
    float f;
    memcpy(&f, &bits, sizeof(f));
    return f;
}

static void encodes_every_type(void **state)
{
    (void)state;
    uint16_t r[4];
    const enum regmap_word_order H = REGMAP_HIGH_WORD_FIRST, L = REGMAP_LOW_WORD_FIRST;

    regmap_encode_value(r, REGMAP_BOOL, 2, true, 1, H);
    assert_int_equal(r[0], 1);
    regmap_encode_value(r, REGMAP_U16, 65535.4, true, 1, H);
    assert_int_equal(r[0], 65535);
    regmap_encode_value(r, REGMAP_U16, 70000, true, 1, H); /* clamped */
    assert_int_equal(r[0], 65535);
    regmap_encode_value(r, REGMAP_U16, -5, true, 1, H);
    assert_int_equal(r[0], 0);
    regmap_encode_value(r, REGMAP_U16, 0.625, true, 1000, H); /* scaled */
    assert_int_equal(r[0], 625);
    regmap_encode_value(r, REGMAP_I16, -1, true, 1, H);
    assert_int_equal(r[0], 0xFFFF);
    regmap_encode_value(r, REGMAP_I16, -1e9, true, 1, H);
    assert_int_equal(r[0], 0x8000);
    regmap_encode_value(r, REGMAP_U32, 0x2B0C0001, true, 1, H);
    assert_int_equal(r[0], 0x2B0C);
    assert_int_equal(r[1], 0x0001);
    regmap_encode_value(r, REGMAP_U32, 0x2B0C0001, true, 1, L);
    assert_int_equal(r[0], 0x0001);
    assert_int_equal(r[1], 0x2B0C);
    regmap_encode_value(r, REGMAP_U32, 1e300, true, 1, H);
    assert_int_equal(r[0], 0xFFFF);
    assert_int_equal(r[1], 0xFFFF);
    regmap_encode_value(r, REGMAP_I32, -2, true, 1, H);
    assert_int_equal(r[0], 0xFFFF);
    assert_int_equal(r[1], 0xFFFE);
    regmap_encode_value(r, REGMAP_I32, 3e9, true, 1, H);
    assert_int_equal(r[0], 0x7FFF);
    assert_int_equal(r[1], 0xFFFF);
    regmap_encode_value(r, REGMAP_F32, -1234.5, true, 1, H);
    assert_int_equal(r[0], 0xC49A);
    assert_int_equal(r[1], 0x5000);
    regmap_encode_value(r, REGMAP_F32, -1234.5, true, 1, L);
    assert_int_equal(r[0], 0x5000);
    assert_int_equal(r[1], 0xC49A);
    regmap_encode_value(r, REGMAP_F32, 1e300, true, 1, H);
    assert_true(isinf(as_float(r, H)) && as_float(r, H) > 0);
    regmap_encode_value(r, REGMAP_F32, -1e300, true, 1, L);
    assert_true(isinf(as_float(r, L)) && as_float(r, L) < 0);
    regmap_encode_value(r, REGMAP_F32, 0.1, true, 1, H);
    assert_true(as_float(r, H) == 0.1f);
}

static void absent_values(void **state)
{
    (void)state;
    uint16_t r[2] = {7, 7};
    regmap_encode_value(r, REGMAP_U32, 123, false, 1, REGMAP_HIGH_WORD_FIRST);
    assert_int_equal(r[0], 0);
    assert_int_equal(r[1], 0);
    regmap_encode_value(r, REGMAP_F32, 123, false, 1, REGMAP_HIGH_WORD_FIRST);
    assert_true(isnan(as_float(r, REGMAP_HIGH_WORD_FIRST)));
    regmap_encode_value(r, REGMAP_BOOL, 1, false, 1, REGMAP_HIGH_WORD_FIRST);
    assert_int_equal(r[0], 0);
}

static void encodes_strings(void **state)
{
    (void)state;
    uint16_t r[4];
    regmap_encode_string(r, 4, "ABC");
    assert_int_equal(r[0], 0x4142);
    assert_int_equal(r[1], 0x4300);
    assert_int_equal(r[2], 0);
    assert_int_equal(r[3], 0);
    regmap_encode_string(r, 2, "too long for two");
    assert_int_equal(r[0], 0x746F); /* "to" */
    assert_int_equal(r[1], 0x6F20); /* "o " */
}

static void map_is_valid_and_stable(void **state)
{
    (void)state;
    struct regmap map;
    assert_int_equal(regmap_init(&map), 0);
    /* Anchors a PLC program relies on. */
    const struct regmap_row *row = regmap_find(&map, REGMAP_INPUT_REGISTER, 0);
    assert_non_null(row);
    assert_string_equal(row->name, "map_magic");
    row = regmap_find(&map, REGMAP_INPUT_REGISTER, 18);
    assert_string_equal(row->name, "status_age_ms");
    row = regmap_find(&map, REGMAP_INPUT_REGISTER, 201);
    assert_int_equal(row->id, STATUS_F_joint_actual_position);
    row = regmap_find(&map, REGMAP_DISCRETE_INPUT, 17);
    assert_int_equal(row->id, STATUS_F_enabled);
    row = regmap_find(&map, REGMAP_INPUT_REGISTER, 13);
    assert_string_equal(row->name, "status_sequence");
    row = regmap_find(&map, REGMAP_INPUT_REGISTER, 14);
    assert_string_equal(row->name, "start_id");
    /* A hole reads as no row; past the end as well. */
    assert_null(regmap_find(&map, REGMAP_INPUT_REGISTER, 15));
    assert_null(regmap_find(&map, REGMAP_INPUT_REGISTER, 60000));
    /* Every status field appears in the map. */
    for (int id = 0; id < STATUS_FIELD_COUNT; id++) {
        bool found = false;
        for (unsigned r = 0; r < map.row_count; r++)
            if (map.rows[r].source == REGMAP_SRC_STATUS && map.rows[r].id == id)
                found = true;
        if (!found)
            fail_msg("status field %s has no register", status_fields[id].name);
    }
    regmap_free(&map);
}

static void image_follows_a_document(void **state)
{
    (void)state;
    struct regmap map;
    struct regmap_image img;
    struct jaka_status st;
    const char *doc = "{\"enabled\": true, \"task_state\": 4, \"errcode\": \"0x10\","
                      " \"joint_actual_position\": [1.5, -2.25], \"din\": [0, 1, 1],"
                      " \"errmsg\": \"hi\", \"rapidrate\": 0.5}";

    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_LOW_WORD_FIRST), 0);
    assert_int_equal(status_parse(&st, doc, strlen(doc)), 0);
    regmap_encode_status(&img, &st);
    assert_int_equal(img.mb->tab_input_bits[17], 1);      /* enabled */
    assert_int_equal(img.mb->tab_input_registers[100], 4); /* task_state */
    assert_int_equal(img.mb->tab_input_registers[110], 0x10); /* errcode low */
    assert_int_equal(img.mb->tab_input_registers[111], 0);
    assert_true(as_float(&img.mb->tab_input_registers[200], REGMAP_LOW_WORD_FIRST) == 1.5f);
    assert_true(as_float(&img.mb->tab_input_registers[202], REGMAP_LOW_WORD_FIRST) == -2.25f);
    assert_true(isnan(as_float(&img.mb->tab_input_registers[204], REGMAP_LOW_WORD_FIRST)));
    assert_int_equal(img.mb->tab_input_bits[256 + 1], 1);  /* din[1] */
    assert_int_equal(img.mb->tab_input_bits[256 + 3], 0);  /* not carried */
    assert_int_equal(img.mb->tab_input_registers[114], 500); /* rapidrate permille */
    assert_int_equal(img.mb->tab_input_registers[130], 0x6869); /* "hi" */
    assert_int_equal(img.mb->tab_input_bits[1536 + STATUS_F_enabled], 1);
    assert_int_equal(img.mb->tab_input_bits[1536 + STATUS_F_powered_on], 0);
    assert_int_equal(img.mb->tab_input_registers[3000 + STATUS_F_din], 3);
    regmap_image_free(&img);
    regmap_free(&map);
}

static void write_checks_follow_the_table(void **state)
{
    (void)state;
    struct regmap map;
    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_check_write(&map, REGMAP_HOLDING_REGISTER, 0, 12345), 0);
    assert_int_equal(regmap_check_write(&map, REGMAP_HOLDING_REGISTER, 1, 1),
                     MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    assert_int_equal(regmap_check_write(&map, REGMAP_COIL, 0, 1), 0);
    assert_int_equal(regmap_check_write(&map, REGMAP_COIL, 0, 2),
                     MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE);
    assert_int_equal(regmap_check_write(&map, REGMAP_INPUT_REGISTER, 0, 1),
                     MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    regmap_free(&map);
}

static void csv_listing_has_the_contract_header(void **state)
{
    (void)state;
    struct regmap map;
    char *text = NULL;
    size_t size = 0;
    assert_int_equal(regmap_init(&map), 0);
    FILE *mem = open_memstream(&text, &size);
    assert_int_equal(regmap_print(&map, REGMAP_FORMAT_CSV, mem), 0);
    fclose(mem);
    assert_memory_equal(text,
                        "table,address,count,type,scale,unit,access,write_class,name,"
                        "source,description\n",
                        strlen("table,address,count,type,scale,unit,access,write_class,"
                               "name,source,description\n"));
    assert_non_null(strstr(text, "\ninput_register,200,2,f32,1,deg,r,,"
                                 "joint_actual_position_1,joint_actual_position[0],"));
    assert_non_null(strstr(text, "\ninput_register,114,1,u16,1000,permille,r,,"));
    /* Every writable row, with its write class. */
    assert_non_null(strstr(text, "\nholding_register,0,1,u16,1,,rw,heartbeat,plc_heartbeat,"));
    assert_non_null(strstr(text, "\ncoil,100,1,bool,1,,rw,power,cmd_power_on,"));
    assert_non_null(strstr(text, ",monitor_data[5][5][10],"));
    free(text);
    regmap_free(&map);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(encodes_every_type),
        cmocka_unit_test(absent_values),
        cmocka_unit_test(encodes_strings),
        cmocka_unit_test(map_is_valid_and_stable),
        cmocka_unit_test(image_follows_a_document),
        cmocka_unit_test(write_checks_follow_the_table),
        cmocka_unit_test(csv_listing_has_the_contract_header),
    };
    return cmocka_run_group_tests_name("regmap", tests, NULL, NULL);
}
