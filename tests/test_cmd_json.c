/* SPDX-License-Identifier: MIT */
/*
 * test_cmd_json.c - a command's JSON written as bytes (cmd_json.h) is
 * exactly what the gateway printed before with cJSON: for every command
 * of the register map (triggers with their parameters, every setpoint
 * row and element, every mailbox code), with generated values (random
 * float bits, NaN and infinities, negative zero, integers at int's
 * limits, scaled values, texts with quotes, backslashes, control bytes
 * and UTF-8), the bytes plc_commands.c builds are compared with the
 * bytes of the cJSON tree built by the code it replaced, kept below as
 * the reference.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "plc_commands.c"

#define ROUNDS 200 /* generated value sets per command */
#define NUMBERS 100000

/* Under qemu-user (an ARM build's make test: JAKAGW_ARCH set), a tenth. */
static unsigned rounds = ROUNDS, numbers = NUMBERS;

static struct regmap map;
static struct regmap_image img;
static struct plc_commands commands;
static uint64_t rng_state = 0x9E3779B97F4A7C15u;

static uint64_t next_random(void)
{
    /* xorshift64*: reproducible, so a failure names its round. */
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return rng_state * 0x2545F4914F6CDD1Du;
}

/* ---- the reference: the cJSON builders plc_commands.c had before ---- */

/* A number as JSON shows it: floats from f32 registers at their precision. */
static cJSON *ref_number_item(double v, bool from_float)
{
    if (from_float) {
        char text[32];
        snprintf(text, sizeof(text), "%.7g", v);
        v = strtod(text, NULL);
    }
    return cJSON_CreateNumber(v);
}

/*
 * Sets obj.key, where key may be "name[i]" (the array grows with nulls).
 * Takes 'item', which may be NULL (its allocation failed). Returns false
 * when an allocation failed: 'item' is freed then, and 'obj' stays valid.
 */
static bool ref_set_member(cJSON *obj, const char *key, cJSON *item)
{
    char name[64];
    const char *bracket = strchr(key, '[');

    if (!item)
        return false;
    if (!bracket) {
        cJSON_DeleteItemFromObjectCaseSensitive(obj, key);
        if (!cJSON_AddItemToObject(obj, key, item)) {
            cJSON_Delete(item);
            return false;
        }
        return true;
    }
    snprintf(name, sizeof(name), "%.*s", (int)(bracket - key), key);
    int index = atoi(bracket + 1);
    cJSON *array = cJSON_GetObjectItemCaseSensitive(obj, name);
    if (!cJSON_IsArray(array)) {
        array = cJSON_CreateArray();
        if (!array || !cJSON_AddItemToObject(obj, name, array)) {
            cJSON_Delete(array);
            cJSON_Delete(item);
            return false;
        }
    }
    /* Every create is checked: an unchecked one left the array short and
     * this loop spinning for ever. */
    while (cJSON_GetArraySize(array) <= index) {
        cJSON *filler = cJSON_CreateNull();
        if (!filler || !cJSON_AddItemToArray(array, filler)) {
            cJSON_Delete(filler);
            cJSON_Delete(item);
            return false;
        }
    }
    if (!cJSON_ReplaceItemInArray(array, index, item)) {
        cJSON_Delete(item);
        return false;
    }
    return true;
}

/* Adds the value of element 'i' of a parameter row under its JSON path. */
static enum build_result ref_add_param(const struct plc_commands *pc, cJSON *obj,
                                   const struct regmap_row *row, unsigned i)
{
    char path[96];
    regmap_expand(path, sizeof(path), row->path, row->index + i, i);
    const char *key = strchr(path, '.') + 1;
    cJSON *item;

    if (row->type == REGMAP_STR) {
        char text[256];
        regmap_get_text(pc->img, row, i, text, sizeof(text));
        if (!text[0])
            return BUILD_INVALID; /* a text parameter must be given */
        item = cJSON_CreateString(text);
    } else {
        item = ref_number_item(regmap_get_number(pc->img, row, i), row->type == REGMAP_F32);
    }
    return ref_set_member(obj, key, item) ? BUILT : BUILD_NO_MEMORY;
}

/* A new object with cmdName first, as the manual writes commands. */
static cJSON *ref_new_command(const char *name)
{
    cJSON *obj = cJSON_CreateObject();
    if (obj && !cJSON_AddStringToObject(obj, "cmdName", name)) {
        cJSON_Delete(obj);
        return NULL;
    }
    return obj;
}


/* The command 'def' with the parameters in its holding registers. */
static cJSON *ref_build_triggered(const struct plc_commands *pc, const struct cmd_def *def,
                              enum build_result *result)
{
    cJSON *obj = ref_new_command(def->name);

    *result = obj ? BUILT : BUILD_NO_MEMORY;
    for (unsigned r = 0; obj && r < pc->img->map->row_count; r++) {
        const struct regmap_row *row = &pc->img->map->rows[r];
        if (!param_rows_is_param_of(row, def->name))
            continue;
        for (unsigned i = 0; i < row->elements; i++) {
            *result = ref_add_param(pc, obj, row, i);
            if (*result != BUILT) {
                cJSON_Delete(obj);
                return NULL;
            }
        }
    }
    return obj;
}

/* A setpoint row's command: its fixed members and the value written. */
static cJSON *ref_build_setpoint(const struct regmap_written *w, const struct cmd_def *def,
                             enum build_result *result)
{
    const struct regmap_row *row = w->row;
    char fixed[160], text[176], path[96];

    *result = BUILD_NO_MEMORY;
    regmap_expand(fixed, sizeof(fixed), row->fixed, w->source_index, w->element);
    snprintf(text, sizeof(text), "{%s}", fixed);
    /* The members come from the register table, so only a failed
     * allocation keeps them from parsing. */
    cJSON *members = cJSON_Parse(text);
    cJSON *obj = cJSON_IsObject(members) ? ref_new_command(def->name) : NULL;
    if (!obj) {
        cJSON_Delete(members);
        return NULL;
    }
    while (members->child) {
        cJSON *m = cJSON_DetachItemViaPointer(members, members->child);
        if (!cJSON_AddItemToObject(obj, m->string, m)) {
            cJSON_Delete(m);
            cJSON_Delete(members);
            cJSON_Delete(obj);
            return NULL;
        }
    }
    cJSON_Delete(members);
    regmap_expand(path, sizeof(path), row->path, w->source_index, w->element);
    if (!ref_set_member(obj, strchr(path, '.') + 1,
                    ref_number_item(w->value, row->type == REGMAP_F32))) {
        cJSON_Delete(obj);
        return NULL;
    }
    *result = BUILT;
    return obj;
}

/* The mailbox's command, from its code and arguments (cmd_def.mailbox_args). */
static cJSON *ref_build_mailbox(const struct plc_commands *pc, const struct cmd_def *def,
                            enum build_result *result)
{
    char args[128], name[64];
    unsigned next = 0;
    cJSON *obj = ref_new_command(def->name);

    *result = BUILD_NO_MEMORY;
    if (!obj)
        return NULL;
    snprintf(args, sizeof(args), "%s", def->mailbox_args);
    for (char *save = NULL, *tok = strtok_r(args, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        size_t n = strlen(tok);
        char mark = n && (tok[n - 1] == '#' || tok[n - 1] == '$') ? tok[--n] : 0;
        tok[n] = '\0';
        if (mark == '$') {
            char path[96];
            snprintf(path, sizeof(path), "%s.%s", def->name, tok);
            const struct regmap_row *row =
                regmap_find_path(pc->img->map, REGMAP_SRC_CMD, path);
            *result = row ? ref_add_param(pc, obj, row, 0) : BUILD_INVALID;
            if (*result != BUILT)
                goto fail;
            continue;
        }
        unsigned count = 1;
        char *bracket = strchr(tok, '[');
        if (bracket) {
            count = (unsigned)atoi(bracket + 1);
            *bracket = '\0';
        }
        for (unsigned k = 0; k < count; k++) {
            if (next >= pc->mailbox_arg->elements)
                goto invalid;
            double v = regmap_get_number(pc->img, pc->mailbox_arg, next++);
            if (mark == '#' && v != nearbyint(v))
                goto invalid; /* a whole number was expected */
            if (bracket)
                snprintf(name, sizeof(name), "%s[%u]", tok, k);
            else
                snprintf(name, sizeof(name), "%s", tok);
            if (!ref_set_member(obj, name, ref_number_item(v, mark != '#'))) {
                *result = BUILD_NO_MEMORY;
                goto fail;
            }
        }
    }
    *result = BUILT;
    return obj;
invalid:
    *result = BUILD_INVALID;
fail:
    cJSON_Delete(obj);
    return NULL;
}


/* ---- generated values ---- */

static const double special_values[] = {
    0.0, -0.0, 1.0, -1.0, 0.5, 0.1, 1e-5, 1e-4, 123456.7, 1e15, 1e16, -1e17,
    2147483647.0, -2147483648.0, 2147483648.0, 4294967295.0, 1e300, 5e-324,
    3.4028234663852886e38, 1.1754943508222875e-38, 16777217.0, 0.30000000000000004,
};

/* A number of the kind a row of 'type' holds. */
static double generated_number(enum regmap_type type, double scale)
{
    uint64_t r = next_random();
    unsigned pick = (unsigned)(r % 8);

    if (pick == 0)
        return special_values[(r >> 8) % (sizeof(special_values) / sizeof(special_values[0]))];
    switch (type) {
    case REGMAP_F32: {
        if (pick == 1)
            return (double)(int32_t)(r >> 16) / 1000.0; /* a plain decimal */
        if (pick == 2)
            return (double)(int)((r >> 20) % 2001) - 1000; /* a whole number */
        float f;
        uint32_t bits = (uint32_t)(r >> 32);
        memcpy(&f, &bits, sizeof(f)); /* any float: NaN, infinities, subnormals */
        return (double)f;
    }
    case REGMAP_U16:
        return (double)((r >> 16) % 65536) / scale;
    case REGMAP_I16:
        return (double)(int16_t)(r >> 16) / scale;
    case REGMAP_U32:
        return (double)(uint32_t)(r >> 16) / scale;
    case REGMAP_I32:
        return (double)(int32_t)(r >> 16) / scale;
    default:
        return (double)((r >> 16) % 2);
    }
}

/* Text of 1 to 60 bytes: quotes, backslashes, control bytes, UTF-8. */
static void generated_text(char *out, size_t size)
{
    static const char *const pieces[] = {"a", "Z", "9", " ", "\"", "\\", "/", "\n", "\t",
                                         "\x01", "\x1f", "\x7f", "\xc3\xa9",
                                         "\xe2\x82\xac", "track/test.jks", "{}", "[,]"};
    size_t n = 0;
    unsigned count = 1 + (unsigned)(next_random() % 20);

    for (unsigned i = 0; i < count; i++) {
        const char *p = pieces[next_random() % (sizeof(pieces) / sizeof(pieces[0]))];
        size_t len = strlen(p);
        if (n + len >= size)
            break;
        memcpy(out + n, p, len);
        n += len;
    }
    out[n] = '\0';
}

/* Fills every command parameter row and the mailbox arguments. */
static void fill_parameters(void)
{
    for (unsigned r = 0; r < map.row_count; r++) {
        const struct regmap_row *row = &map.rows[r];
        bool mailbox = row == commands.mailbox_arg;
        if (!mailbox && (row->source != REGMAP_SRC_CMD || row->fixed || !strchr(row->path, '.')))
            continue;
        for (unsigned i = 0; i < row->elements; i++) {
            if (row->type == REGMAP_STR) {
                char text[64];
                generated_text(text, sizeof(text));
                regmap_set_text(&img, row, i, next_random() % 10 ? text : "");
            } else {
                regmap_set_number(&img, row, i, generated_number(row->type, row->scale), true);
            }
        }
    }
}

/* The reference's bytes and result against the writer's. */
static void compare(cJSON *ref, enum build_result ref_result, enum build_result result,
                    struct cmd_json *cmd, const char *what, unsigned round)
{
    char *expected = ref ? cJSON_PrintUnformatted(ref) : NULL;
    char *got = result == BUILT ? cmd_json_finish(cmd) : NULL;

    cJSON_Delete(ref);
    if (ref_result != result || (expected == NULL) != (got == NULL) ||
        (expected && strcmp(expected, got) != 0))
        fail_msg("%s, round %u: cJSON %s (%d), writer %s (%d)", what, round,
                 expected ? expected : "-", ref_result, got ? got : "-", result);
    cJSON_free(expected);
    free(got);
}

static void every_trigger_command_is_byte_identical(void **state)
{
    (void)state;
    struct cmd_json cmd;
    unsigned compared = 0;

    for (unsigned round = 0; round < rounds; round++) {
        fill_parameters();
        for (unsigned c = 0; c < cmd_table_count; c++) {
            const struct cmd_def *def = &cmd_table[c];
            enum build_result ref_result;
            cJSON *ref = ref_build_triggered(&commands, def, &ref_result);
            enum build_result result = build_triggered(&commands, def, &cmd);
            compare(ref, ref_result, result, &cmd, def->name, round);
            compared++;
        }
    }
    assert_true(compared >= rounds * 20);
}

static void every_setpoint_is_byte_identical(void **state)
{
    (void)state;
    struct cmd_json cmd;
    unsigned compared = 0;

    for (unsigned r = 0; r < map.row_count; r++) {
        const struct regmap_row *row = &map.rows[r];
        if (row->source != REGMAP_SRC_CMD || !row->fixed)
            continue;
        const struct cmd_def *def = param_rows_command_of(row->path);
        assert_non_null(def);
        for (unsigned e = 0; e < row->elements; e++)
            for (unsigned round = 0; round < rounds; round++) {
                struct regmap_written w = {.row = row, .element = e,
                                           .source_index = row->index + e,
                                           .value = generated_number(row->type, row->scale)};
                enum build_result ref_result;
                cJSON *ref = ref_build_setpoint(&w, def, &ref_result);
                enum build_result result = build_setpoint(&w, def, &cmd);
                compare(ref, ref_result, result, &cmd, row->name, round);
                compared++;
            }
    }
    assert_true(compared > 0);
}

static void every_mailbox_code_is_byte_identical(void **state)
{
    (void)state;
    struct cmd_json cmd;
    unsigned compared = 0;

    for (unsigned round = 0; round < rounds; round++) {
        fill_parameters();
        /* Whole numbers in half the rounds, so '#' arguments build too. */
        if (round % 2)
            for (unsigned i = 0; i < commands.mailbox_arg->elements; i++)
                regmap_set_number(&img, commands.mailbox_arg, i,
                                  (double)(int)(next_random() % 200) - 100, true);
        for (unsigned c = 0; c < cmd_table_count; c++) {
            const struct cmd_def *def = &cmd_table[c];
            if (!def->code)
                continue;
            enum build_result ref_result;
            cJSON *ref = ref_build_mailbox(&commands, def, &ref_result);
            enum build_result result = build_mailbox(&commands, def, &cmd);
            compare(ref, ref_result, result, &cmd, def->name, round);
            compared++;
        }
    }
    assert_true(compared > rounds * 10);
}

/* Numbers alone, over many more values than the commands carry. */
static void numbers_print_as_cjson_prints_them(void **state)
{
    (void)state;
    for (unsigned i = 0; i < numbers; i++) {
        bool from_float = i % 2;
        enum regmap_type type = from_float ? REGMAP_F32 : (i % 4 == 0 ? REGMAP_U32 : REGMAP_I16);
        double v = generated_number(type, (i / 2) % 3 == 0 ? 1000 : (i / 2) % 3 == 1 ? 10 : 1);
        if (i % 7 == 0) {
            uint64_t bits = next_random();
            memcpy(&v, &bits, sizeof(v)); /* any double */
        }
        cJSON *ref = ref_number_item(v, from_float);
        char *expected = cJSON_PrintUnformatted(ref);
        char got[40];
        got[cmd_json_number(got, v, from_float)] = '\0';
        if (strcmp(expected, got) != 0)
            fail_msg("%.17g (%s): cJSON %s, writer %s", v, from_float ? "float" : "double",
                     expected, got);
        cJSON_free(expected);
        cJSON_Delete(ref);
    }
}

/* Past the writer's limits it fails, as cJSON failed without memory. */
static void too_much_fails_whole(void **state)
{
    (void)state;
    struct cmd_json cmd;
    char key[16];

    cmd_json_begin(&cmd, "joint_move");
    for (unsigned i = 0; i <= CMD_JSON_MEMBERS; i++) {
        snprintf(key, sizeof(key), "k%u", i);
        cmd_json_set_number(&cmd, key, i, false);
    }
    assert_null(cmd_json_finish(&cmd));
    cmd_json_begin(&cmd, "joint_move");
    cmd_json_set_number(&cmd, "a[16]", 1, false);
    assert_null(cmd_json_finish(&cmd));
    cmd_json_begin(&cmd, "set_analog_output");
    assert_int_equal(cmd_json_set_fixed(&cmd, "\"type\": 1.5"), -EINVAL);
    assert_int_equal(cmd_json_set_fixed(&cmd, "\"type\" 1"), -EINVAL);
}

static int setup(void **state)
{
    (void)state;
    assert_int_equal(regmap_init(&map), 0);
    assert_int_equal(regmap_image_init(&img, &map, REGMAP_HIGH_WORD_FIRST), 0);
    commands.img = &img;
    commands.mailbox_arg = regmap_find_path(&map, REGMAP_SRC_PATH, "mailbox.arg[*]");
    assert_non_null(commands.mailbox_arg);
    assert_int_equal(param_rows_init(&commands.params, &map), 0);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    param_rows_free(&commands.params);
    regmap_image_free(&img);
    regmap_free(&map);
    return 0;
}

int main(void)
{
    const char *arch = getenv("JAKAGW_ARCH");
    if (arch && arch[0]) {
        rounds /= 10;
        numbers /= 10;
    }
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(numbers_print_as_cjson_prints_them),
        cmocka_unit_test(every_trigger_command_is_byte_identical),
        cmocka_unit_test(every_setpoint_is_byte_identical),
        cmocka_unit_test(every_mailbox_code_is_byte_identical),
        cmocka_unit_test(too_much_fails_whole),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
