/* SPDX-License-Identifier: MIT */
/*
 * test_regmap_changes.c - the image encodes only what changed, and always
 * shows the same registers as an image encoded from scratch.
 */
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

static struct regmap map;
static struct jaka_status statuses[3];

static int setup(void **state)
{
    (void)state;
    return regmap_init(&map);
}

static int teardown(void **state)
{
    (void)state;
    regmap_free(&map);
    status_parse_release();
    return 0;
}

/* The two images hold the same bits and registers in every table. */
static void assert_same_image(const struct regmap_image *a, const struct regmap_image *b)
{
    const modbus_mapping_t *x = a->mb, *y = b->mb;
    assert_memory_equal(x->tab_bits, y->tab_bits, (size_t)x->nb_bits);
    assert_memory_equal(x->tab_input_bits, y->tab_input_bits, (size_t)x->nb_input_bits);
    assert_memory_equal(x->tab_registers, y->tab_registers,
                        (size_t)x->nb_registers * sizeof(uint16_t));
    assert_memory_equal(x->tab_input_registers, y->tab_input_registers,
                        (size_t)x->nb_input_registers * sizeof(uint16_t));
}

/* What an image encoded once from 's' shows, against 'img' after its history. */
static void assert_shows(const struct regmap_image *img, const struct jaka_status *s,
                         enum regmap_word_order wo)
{
    struct regmap_image fresh;
    assert_int_equal(regmap_image_init(&fresh, &map, wo), 0);
    regmap_encode_status(&fresh, s);
    assert_same_image(img, &fresh);
    regmap_image_free(&fresh);
}

static void parse_into(struct jaka_status *s, const char *json)
{
    assert_int_equal(status_parse(s, json, strlen(json)), STATUS_PARSE_OK);
}

/* Documents in turn, with fields that change, vanish, shrink and return:
 * the image follows each exactly. */
static void follows_every_change(void **state)
{
    (void)state;
    static const char *const docs[] = {
        "{\"enabled\": true, \"joint_actual_position\": [1, 2, 3, 4, 5, 6], "
        "\"din\": [1, 0, 1], \"errmsg\": \"first\", \"task_state\": 4}",
        "{\"enabled\": true, \"joint_actual_position\": [1, 2.5, 3, 4, 5, 6], "
        "\"din\": [1, 0, 1], \"errmsg\": \"first\", \"task_state\": 4}",
        "{\"enabled\": false, \"din\": [1], \"errmsg\": \"second, longer\"}",
        "{\"joint_actual_position\": [-0.0, 0, 0, 0, 0, 0], \"din\": [], \"errmsg\": \"\"}",
        "{\"joint_actual_position\": [0, 0, 0, 0, 0, 0], \"errmsg\": \"x\", "
        "\"tio_rs_signals\": [[\"a\", 1, 2, 3, 4, 5]]}",
        "{\"enabled\": true, \"joint_actual_position\": [1, 2, 3, 4, 5, 6], "
        "\"din\": [1, 0, 1], \"errmsg\": \"first\", \"task_state\": 4}",
    };
    const enum regmap_word_order orders[] = {REGMAP_HIGH_WORD_FIRST, REGMAP_LOW_WORD_FIRST};

    for (size_t o = 0; o < 2; o++) {
        struct regmap_image img;
        assert_int_equal(regmap_image_init(&img, &map, orders[o]), 0);
        for (size_t round = 0; round < 3; round++)
            for (size_t d = 0; d < sizeof(docs) / sizeof(docs[0]); d++) {
                /* As the gateway does: parse into the spare, swap. */
                struct jaka_status *s = &statuses[(d + round) % 3];
                parse_into(s, docs[d]);
                regmap_encode_status(&img, s);
                assert_shows(&img, s, orders[o]);
            }
        regmap_image_free(&img);
    }
}

/* The real documents, and a copy with one value changed at a time. */
static void follows_single_value_changes(void **state)
{
    (void)state;
    char path[512];
    snprintf(path, sizeof(path), "%s/status-controller-a.json", SAMPLES_DIR);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    static char doc[1 << 16];
    size_t n = fread(doc, 1, sizeof(doc), f);
    fclose(f);

    struct regmap_image img;
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    assert_int_equal(status_parse(&statuses[0], doc, n), STATUS_PARSE_OK);
    regmap_encode_status(&img, &statuses[0]);
    assert_shows(&img, &statuses[0], REGMAP_HIGH_WORD_FIRST);
    /* Each element of each numeric field in turn, on a copy of the status. */
    for (int id = 0; id < STATUS_FIELD_COUNT; id += 3) {
        const struct status_field_info *fi = &status_fields[id];
        if (fi->kind != STATUS_KIND_NUM)
            continue;
        statuses[1] = statuses[0];
        struct status_num *num =
            (struct status_num *)((char *)&statuses[1] + fi->offset) + fi->capacity - 1;
        num->present = !num->present;
        num->value = num->present ? 7 : 0;
        regmap_encode_status(&img, &statuses[1]);
        assert_shows(&img, &statuses[1], REGMAP_HIGH_WORD_FIRST);
        regmap_encode_status(&img, &statuses[0]);
        assert_shows(&img, &statuses[0], REGMAP_HIGH_WORD_FIRST);
    }
    regmap_image_free(&img);
}

/* Gateway values: only changed ones are encoded, all of them shown. */
static void gateway_values_follow(void **state)
{
    (void)state;
    struct regmap_image img, fresh;
    double gw[GW_VALUE_COUNT] = {0};

    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    for (int round = 0; round < 50; round++) {
        for (int v = 0; v < GW_VALUE_COUNT; v++)
            if ((v * 7 + round) % 5 == 0)
                gw[v] = round % 3 == 0 ? -0.0 : round * 1.5 + v;
        regmap_encode_gw(&img, gw);
        assert_int_equal(regmap_image_init(&fresh, &map, REGMAP_HIGH_WORD_FIRST), 0);
        regmap_encode_gw(&fresh, gw);
        assert_same_image(&img, &fresh);
        regmap_image_free(&fresh);
    }
    regmap_image_free(&img);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(follows_every_change),
        cmocka_unit_test(follows_single_value_changes),
        cmocka_unit_test(gateway_values_follow),
    };
    return cmocka_run_group_tests_name("regmap_changes", tests, setup, teardown);
}
