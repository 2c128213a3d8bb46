/* SPDX-License-Identifier: MIT */
/* test_json_arena.c - cJSON trees parsed into an arena. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "json_arena.c"

static cJSON *parse(struct json_arena *a, const char *text)
{
    return json_arena_parse(a, text, strlen(text));
}

static void parses_and_replaces_the_tree(void **state)
{
    (void)state;
    struct json_arena a;
    json_arena_init(&a);

    cJSON *root = parse(&a, "{\"a\": [1, 2.5, \"x\"], \"b\": {\"c\": true}}");
    assert_non_null(root);
    cJSON *arr = cJSON_GetObjectItem(root, "a");
    assert_int_equal(cJSON_GetArraySize(arr), 3);
    assert_true(cJSON_GetArrayItem(arr, 1)->valuedouble == 2.5);
    assert_string_equal(cJSON_GetArrayItem(arr, 2)->valuestring, "x");
    assert_true(cJSON_IsTrue(cJSON_GetObjectItem(cJSON_GetObjectItem(root, "b"), "c")));
    assert_true(a.held > 0);

    root = parse(&a, "[7]");
    assert_non_null(root);
    assert_int_equal(cJSON_GetArrayItem(root, 0)->valueint, 7);
    json_arena_free(&a);
    assert_int_equal(a.held, 0);
}

static void bad_json_returns_null(void **state)
{
    (void)state;
    struct json_arena a = {0}; /* zeroed is empty */

    assert_null(parse(&a, "{\"a\": [1, 2"));
    assert_null(parse(&a, "{\"a\": \"unterminated"));
    assert_non_null(parse(&a, "{}"));
    json_arena_free(&a);
}

/* After a parse, cJSON allocates with malloc again for everyone else. */
static void default_hooks_are_back(void **state)
{
    (void)state;
    struct json_arena a;
    json_arena_init(&a);

    assert_non_null(parse(&a, "{\"k\": \"v\"}"));
    void *p = cJSON_malloc(64);
    assert_non_null(p);
    free(p); /* only right if cJSON_malloc is malloc */
    cJSON *kept = cJSON_CreateString("outlives the arena");
    json_arena_reset(&a);
    json_arena_free(&a);
    assert_string_equal(kept->valuestring, "outlives the arena");
    cJSON_Delete(kept);
}

/* A document of steady size needs no allocation after the first; one
 * unusually large document does not hold its memory for ever. */
static void memory_follows_the_documents(void **state)
{
    (void)state;
    struct json_arena a;
    json_arena_init(&a);
    size_t big_size = 200000, n = 0;
    char *big = malloc(big_size);
    assert_non_null(big);
    n += (size_t)snprintf(big + n, big_size - n, "[0");
    while (n < big_size - 8)
        n += (size_t)snprintf(big + n, big_size - n, ",1");
    snprintf(big + n, big_size - n, "]");

    const char *small = "{\"a\": [1, 2, 3], \"b\": \"text\"}";
    assert_non_null(parse(&a, small));
    assert_non_null(parse(&a, small));
    size_t steady = a.held;
    assert_non_null(json_arena_parse(&a, big, strlen(big)));
    size_t peak = a.held;
    assert_true(peak > 4 * (size_t)JSON_ARENA_CHUNK_SIZE);
    for (int i = 0; i < 3; i++)
        assert_non_null(parse(&a, small));
    json_arena_reset(&a);
    if (!JSON_ARENA_REAL_MALLOC) {
        /* One chunk, back to the size a small document needs. */
        assert_int_equal(a.held, steady);
        assert_non_null(a.chunks);
        assert_null(a.chunks->next);
        /* Steady size: the same chunk again, no new one. */
        struct json_arena_chunk *chunk = a.chunks;
        assert_non_null(parse(&a, small));
        assert_ptr_equal(a.chunks, chunk);
    } else {
        assert_int_equal(a.held, 0); /* every block freed at the reset */
    }
    free(big);
    json_arena_free(&a);
}

/* A reset with nothing parsed since the last one changes nothing. */
static void reset_twice_keeps_the_chunk(void **state)
{
    (void)state;
    struct json_arena a;
    json_arena_init(&a);
    char doc[8192];
    size_t n = (size_t)snprintf(doc, sizeof(doc), "[0");
    while (n < sizeof(doc) - 8)
        n += (size_t)snprintf(doc + n, sizeof(doc) - n, ",1");
    snprintf(doc + n, sizeof(doc) - n, "]");

    assert_non_null(parse(&a, doc));
    json_arena_reset(&a);
    size_t held = a.held;
    json_arena_reset(&a);
    json_arena_reset(&a);
    assert_int_equal(a.held, held);
    json_arena_free(&a);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(parses_and_replaces_the_tree),
        cmocka_unit_test(bad_json_returns_null),
        cmocka_unit_test(default_hooks_are_back),
        cmocka_unit_test(memory_follows_the_documents),
        cmocka_unit_test(reset_twice_keeps_the_chunk),
    };
    return cmocka_run_group_tests_name("json_arena", tests, NULL, NULL);
}
