/* test_framer.c - cutting the robot's byte stream into documents. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "framer.h"

#define MAX_SEEN 64

struct seen {
    char objects[MAX_SEEN][512];
    int count;
    int events[8];
};

static void record(void *user, enum framer_event ev, const char *data, size_t size)
{
    struct seen *s = user;
    s->events[ev]++;
    if (ev == FRAMER_EVENT_OBJECT && s->count < MAX_SEEN) {
        size_t n = size < 511 ? size : 511;
        memcpy(s->objects[s->count], data, n);
        s->objects[s->count][n] = '\0';
        s->count++;
    }
}

/* A status-like document with an exact "len". */
static void make_doc(char *out, size_t size, int n)
{
    char body[160];
    snprintf(body, sizeof(body), ", \"n\": %d, \"s\": \"a } { \\\" ] [\", \"x\": {\"y\": [1, {}]}}", n);
    size_t guess = 0;
    for (int i = 0; i < 3; i++) {
        int head = snprintf(out, size, "{\"len\": %zu", guess);
        guess = (size_t)head + strlen(body);
    }
    snprintf(out, size, "{\"len\": %zu%s", guess, body);
    assert_int_equal(strlen(out), guess);
}

static struct framer f;
static struct seen seen;

static int setup(void **state)
{
    (void)state;
    memset(&seen, 0, sizeof(seen));
    return framer_init(&f, 1024, record, &seen);
}

static int teardown(void **state)
{
    (void)state;
    framer_free(&f);
    return 0;
}

static void one_document(void **state)
{
    (void)state;
    char doc[256];
    make_doc(doc, sizeof(doc), 1);
    framer_feed(&f, doc, strlen(doc));
    assert_int_equal(seen.count, 1);
    assert_string_equal(seen.objects[0], doc);
    assert_int_equal(seen.events[FRAMER_EVENT_LEN_MISMATCH], 0);
}

static void split_at_every_byte(void **state)
{
    (void)state;
    char doc[256];
    make_doc(doc, sizeof(doc), 2);
    for (size_t i = 0; i < strlen(doc); i++)
        framer_feed(&f, doc + i, 1);
    assert_int_equal(seen.count, 1);
    assert_string_equal(seen.objects[0], doc);
}

static void several_in_one_read(void **state)
{
    (void)state;
    char a[256], b[256], c[256], all[800];
    make_doc(a, sizeof(a), 1);
    make_doc(b, sizeof(b), 22);
    make_doc(c, sizeof(c), 333);
    snprintf(all, sizeof(all), "%s%s\r\n%s", a, b, c);
    /* Merged, and the last one split across two reads. */
    framer_feed(&f, all, strlen(all) - 10);
    assert_int_equal(seen.count, 2);
    framer_feed(&f, all + strlen(all) - 10, 10);
    assert_int_equal(seen.count, 3);
    assert_string_equal(seen.objects[0], a);
    assert_string_equal(seen.objects[1], b);
    assert_string_equal(seen.objects[2], c);
    assert_int_equal(seen.events[FRAMER_EVENT_GARBAGE], 0);
}

static void garbage_between_documents(void **state)
{
    (void)state;
    char a[256], b[256], all[800];
    make_doc(a, sizeof(a), 1);
    make_doc(b, sizeof(b), 2);
    /* Garbage with a stray nested-looking object and a quote. */
    snprintf(all, sizeof(all), "%s\x01\xffjunk \"x\": {\"status\": [1]} ]]%s", a, b);
    framer_feed(&f, all, strlen(all));
    assert_int_equal(seen.count, 2);
    assert_string_equal(seen.objects[1], b);
    assert_true(seen.events[FRAMER_EVENT_GARBAGE] >= 1);
    assert_true(f.stats.garbage_bytes > 10);
}

static void truncated_document_then_a_whole_one(void **state)
{
    (void)state;
    char a[256], b[256], all[800];
    make_doc(a, sizeof(a), 1);
    make_doc(b, sizeof(b), 2);
    snprintf(all, sizeof(all), "%.*s%s", (int)strlen(a) / 2, a, b);
    framer_feed(&f, all, strlen(all));
    assert_int_equal(seen.count, 1);
    assert_string_equal(seen.objects[0], b);
    assert_int_equal(seen.events[FRAMER_EVENT_TRUNCATED], 1);
}

static void oversize_is_dropped_and_stream_recovers(void **state)
{
    (void)state;
    char big[3000], b[256];
    int n = snprintf(big, sizeof(big), "{\"len\": 2500, \"pad\": \"");
    memset(big + n, 'x', 2400);
    snprintf(big + n + 2400, sizeof(big) - (size_t)n - 2400, "\", \"z\": {\"q\": 1}}");
    make_doc(b, sizeof(b), 7);
    framer_feed(&f, big, strlen(big));
    framer_feed(&f, b, strlen(b));
    assert_int_equal(seen.events[FRAMER_EVENT_OVERSIZE], 1);
    assert_int_equal(seen.count, 1);
    assert_string_equal(seen.objects[0], b);
}

static void wrong_len_is_counted_but_the_object_kept(void **state)
{
    (void)state;
    const char *doc = "{\"len\": 99, \"a\": 1}{\"len\": 10, \"b\": 2}";
    /* The first is whole with a wrong len; the second's len points inside. */
    framer_feed(&f, doc, strlen(doc));
    assert_int_equal(seen.count, 2);
    assert_string_equal(seen.objects[0], "{\"len\": 99, \"a\": 1}");
    assert_string_equal(seen.objects[1], "{\"len\": 10, \"b\": 2}");
    assert_int_equal(seen.events[FRAMER_EVENT_LEN_MISMATCH], 2);
    assert_int_equal(seen.events[FRAMER_EVENT_TRUNCATED], 0);
}

static void corrupt_inside_is_cut_at_len(void **state)
{
    (void)state;
    /* An unbalanced quote inside would swallow the next document; "len"
     * cuts it where it says, and the next document still comes through. */
    char bad[256], good[256], all[600];
    make_doc(good, sizeof(good), 5);
    strcpy(bad, good);
    char *s = strstr(bad, "\"n\"");
    s[0] = 'Q'; /* now the string quoting is off by one */
    snprintf(all, sizeof(all), "%s%s", bad, good);
    framer_feed(&f, all, strlen(all));
    assert_int_equal(seen.count, 2);
    assert_string_equal(seen.objects[1], good);
}

static void objects_without_len(void **state)
{
    (void)state;
    const char *replies = "{\"errorCode\": \"0\", \"errorMsg\": \"a}\"}"
                          "{\"errorCode\": \"1\", \"errorMsg\": \"Exception:function call failed\"}";
    framer_feed(&f, replies, strlen(replies));
    assert_int_equal(seen.count, 2);
    assert_string_equal(seen.objects[0], "{\"errorCode\": \"0\", \"errorMsg\": \"a}\"}");
}

static void reset_drops_partial(void **state)
{
    (void)state;
    char a[256];
    make_doc(a, sizeof(a), 1);
    framer_feed(&f, a, 20);
    framer_reset(&f);
    framer_feed(&f, a, strlen(a));
    assert_int_equal(seen.count, 1);
    assert_string_equal(seen.objects[0], a);
}

static void init_rejects_tiny_buffers(void **state)
{
    (void)state;
    struct framer g;
    assert_int_equal(framer_init(&g, 10, record, &seen), -22);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(one_document, setup, teardown),
        cmocka_unit_test_setup_teardown(split_at_every_byte, setup, teardown),
        cmocka_unit_test_setup_teardown(several_in_one_read, setup, teardown),
        cmocka_unit_test_setup_teardown(garbage_between_documents, setup, teardown),
        cmocka_unit_test_setup_teardown(truncated_document_then_a_whole_one, setup, teardown),
        cmocka_unit_test_setup_teardown(oversize_is_dropped_and_stream_recovers, setup, teardown),
        cmocka_unit_test_setup_teardown(wrong_len_is_counted_but_the_object_kept, setup, teardown),
        cmocka_unit_test_setup_teardown(corrupt_inside_is_cut_at_len, setup, teardown),
        cmocka_unit_test_setup_teardown(objects_without_len, setup, teardown),
        cmocka_unit_test_setup_teardown(reset_drops_partial, setup, teardown),
        cmocka_unit_test(init_rejects_tiny_buffers),
    };
    return cmocka_run_group_tests_name("framer", tests, NULL, NULL);
}
