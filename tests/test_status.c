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

#include <cJSON.h>

/* The .c, to check its table of compiled paths. */
#include "status.c"

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

/* ---- the parser against a reference: every field looked up by its path ---- */

/* The path of element 'index' of field 'id' from the root, as the gateway
 * documents it, followed step by step in the tree. */
static const cJSON *lookup(const cJSON *root, const char *path)
{
    const cJSON *node = root;
    const char *p = path;
    char key[64];

    while (node && *p) {
        if (*p == '[') {
            char *after;
            long n = strtol(p + 1, &after, 10);
            if (!cJSON_IsArray(node))
                return NULL;
            node = cJSON_GetArrayItem(node, (int)n);
            p = after + 1;
        } else {
            if (*p == '.')
                p++;
            size_t len = strcspn(p, ".[");
            if (!cJSON_IsObject(node) || len >= sizeof(key))
                return NULL;
            memcpy(key, p, len);
            key[len] = '\0';
            node = cJSON_GetObjectItemCaseSensitive(node, key);
            p += len;
        }
    }
    return node;
}

/* What the reference expects of one number element. */
static bool expect_number(const cJSON *item, double *v)
{
    if (cJSON_IsBool(item)) {
        *v = cJSON_IsTrue(item);
        return true;
    }
    if (cJSON_IsNumber(item)) {
        *v = item->valuedouble;
        return isfinite(*v);
    }
    if (cJSON_IsString(item) && item->valuestring[0]) {
        char *end;
        *v = strtod(item->valuestring, &end);
        return *end == '\0' && isfinite(*v);
    }
    return false;
}

/* Checks every element of every field of 'st' against 'root'. */
static void check_against_reference(const cJSON *root)
{
    for (int id = 0; id < STATUS_FIELD_COUNT; id++) {
        const struct status_field_info *f = &status_fields[id];
        bool star = strchr(f->path, '*') != NULL;
        unsigned carried = 0;
        for (unsigned i = 0; i < f->capacity; i++) {
            char path[128];
            status_element_path((enum status_field)id, i, path, sizeof(path));
            const cJSON *item = lookup(root, path);
            if (id == STATUS_F_task_mode && !item)
                item = cJSON_GetObjectItemCaseSensitive(root, "task mode");
            if (f->kind == STATUS_KIND_NUM) {
                const struct status_num *n = status_num_at(&st, (enum status_field)id, i);
                double v = 0;
                bool present = item && expect_number(item, &v);
                if (id == STATUS_F_errcode)
                    continue; /* normalised: errcode_forms covers it */
                if (n->present != present || (present && n->value != v))
                    fail_msg("%s: present %d value %g, expected %d %g", path, n->present,
                             n->value, present, v);
                if (item && (star || present))
                    carried = i + 1;
            } else {
                const struct status_str *t = status_str_at(&st, (enum status_field)id, i);
                bool present = cJSON_IsString(item) ||
                               (cJSON_IsNumber(item) && isfinite(item->valuedouble));
                if (t->present != present)
                    fail_msg("%s: present %d, expected %d", path, t->present, present);
                if (cJSON_IsString(item))
                    assert_int_equal(strncmp(t->text, item->valuestring, f->str_size - 1), 0);
                if (item && (star || present))
                    carried = i + 1;
            }
        }
        if (id != STATUS_F_errcode && st.count[id] != carried)
            fail_msg("%s: count %u, expected %u", f->name, st.count[id], carried);
    }
}

static void parse_tree_and_check(const cJSON *root)
{
    char *text = cJSON_PrintUnformatted(root);
    assert_non_null(text);
    assert_int_equal(status_parse(&st, text, strlen(text)), STATUS_PARSE_OK);
    /* cJSON prints a double in 15 digits when that is within an epsilon:
     * the reference is the printed text, parsed again. */
    cJSON *printed = cJSON_Parse(text);
    assert_non_null(printed);
    check_against_reference(printed);
    cJSON_Delete(printed);
    cJSON_free(text);
}

static cJSON *read_sample_tree(const char *name)
{
    char path[512];
    size_t size = 0;
    snprintf(path, sizeof(path), "%s/%s", SAMPLES_DIR, name);
    char *doc = read_file(path, &size);
    assert_non_null(doc);
    cJSON *root = cJSON_ParseWithLength(doc, size);
    free(doc);
    assert_non_null(root);
    return root;
}

/* A value of another type, or none, in place of 'node' (a member of 'parent'). */
static void mutate(cJSON *parent, cJSON *node, unsigned how)
{
    switch (how % 6) {
    case 0:
        cJSON_ReplaceItemViaPointer(parent, node, cJSON_CreateString("12.5"));
        break;
    case 1:
        cJSON_ReplaceItemViaPointer(parent, node, cJSON_CreateNull());
        break;
    case 2:
        cJSON_ReplaceItemViaPointer(parent, node, cJSON_CreateObject());
        break;
    case 3:
        cJSON_ReplaceItemViaPointer(parent, node, cJSON_CreateTrue());
        break;
    case 4:
        cJSON_DetachItemViaPointer(parent, node);
        cJSON_Delete(node);
        break;
    case 5: /* an array cut short, or a scalar turned into one */
        if (cJSON_IsArray(node) && cJSON_GetArraySize(node) > 1)
            cJSON_DeleteItemFromArray(node, cJSON_GetArraySize(node) / 2);
        else
            cJSON_ReplaceItemViaPointer(parent, node, cJSON_CreateIntArray((int[]){7, 8}, 2));
        break;
    }
}

/* The node at random depth under 'root', with its parent. */
static cJSON *pick(cJSON *root, unsigned *seed, cJSON **parent)
{
    cJSON *node = root;
    *parent = NULL;
    while (node->child && (*parent == NULL || rand_r(seed) % 3)) {
        int n = cJSON_GetArraySize(node);
        *parent = node;
        node = cJSON_GetArrayItem(node, rand_r(seed) % n);
    }
    return node;
}

static void one_pass_matches_lookup_by_path(void **state)
{
    (void)state;
    static const char *const samples[] = {"status-controller-a.json", "status-zu5s-1.5.14.json"};
    unsigned seed = 17;

    for (size_t s = 0; s < sizeof(samples) / sizeof(samples[0]); s++) {
        cJSON *root = read_sample_tree(samples[s]);
        parse_tree_and_check(root);
        cJSON_Delete(root);
        for (int round = 0; round < 150; round++) {
            root = read_sample_tree(samples[s]);
            for (int m = 0; m < 1 + round % 5; m++) {
                cJSON *parent;
                cJSON *node = pick(root, &seed, &parent);
                if (parent)
                    mutate(parent, node, (unsigned)rand_r(&seed));
            }
            if (round % 7 == 0) /* a name twice: the first one counts */
                cJSON_AddItemToObject(root, "din", cJSON_CreateIntArray((int[]){1, 1}, 2));
            if (round % 11 == 0) {
                cJSON_DeleteItemFromObjectCaseSensitive(root, "task_mode");
                cJSON_AddNumberToObject(root, "task mode", 3);
            }
            parse_tree_and_check(root);
            cJSON_Delete(root);
        }
    }
}

/* Every path of the field list compiles, and fits its first key's group. */
static void every_path_compiles(void **state)
{
    (void)state;
    assert_int_equal(parse("{}"), STATUS_PARSE_OK);
    assert_true(table.ready);
    for (int id = 0; id < STATUS_FIELD_COUNT; id++)
        if (!table.paths[id].ok)
            fail_msg("%s: path %s does not compile", status_fields[id].name,
                     status_fields[id].path);
}

/* cJSON's default hooks are back after each parse, for every other user. */
static void other_cjson_users_keep_malloc(void **state)
{
    (void)state;
    parse_sample("status-controller-a.json");
    void *p = cJSON_malloc(32);
    assert_non_null(p);
    free(p); /* only right if cJSON_malloc is malloc again */
    cJSON *kept = cJSON_Parse("{\"a\": [1, 2, 3]}");
    assert_int_equal(parse("{\"enabled\": 1}"), STATUS_PARSE_OK);
    assert_int_equal(cJSON_GetArraySize(cJSON_GetObjectItem(kept, "a")), 3);
    cJSON_Delete(kept);
    status_parse_release();
    assert_int_equal(parse("{\"enabled\": 1}"), STATUS_PARSE_OK);
    assert_true(st.enabled[0].present);
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
        cmocka_unit_test(one_pass_matches_lookup_by_path),
        cmocka_unit_test(every_path_compiles),
        cmocka_unit_test(other_cjson_users_keep_malloc),
    };
    int failed = cmocka_run_group_tests_name("status", tests, NULL, NULL);
    status_parse_release();
    return failed;
}
