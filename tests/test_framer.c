/* SPDX-License-Identifier: MIT */
/* test_framer.c - cutting the robot's byte stream into documents. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* The .c, to reach the brace scanner's bulk skip (skip_plain). */
#include "framer.c"

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
    /* The first is whole with a wrong len (settled by the header after
     * it); the second's len points inside, where no '}' stands. */
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


/* Feeds 'text' in reads of 'chunk' bytes. */
static void feed_in_chunks(struct framer *fr, const char *text, size_t size, size_t chunk)
{
    for (size_t off = 0; off < size; off += chunk)
        framer_feed(fr, text + off, size - off < chunk ? size - off : chunk);
}

/*
 * A "len" header followed by endless white space once kept the framer
 * waiting for the header's end with a full buffer: framer_feed() spun for
 * ever. Every header is decided within FRAMER_HEADER_MAX bytes.
 */
static void len_header_then_endless_spaces(void **state)
{
    (void)state;
    struct framer big;
    struct seen s2;
    char doc[256];
    size_t n = 70000;
    char *junk = malloc(n);

    memset(&s2, 0, sizeof(s2));
    assert_int_equal(framer_init(&big, FRAMER_DEFAULT_MAX_OBJECT, record, &s2), 0);
    memcpy(junk, "{\"len\"", 6);
    memset(junk + 6, ' ', n - 6);
    make_doc(doc, sizeof(doc), 3);
    /* A stream that has shown "len" headers, as the status port's does. */
    framer_feed(&big, doc, strlen(doc));
    framer_feed(&f, doc, strlen(doc));
    alarm(10); /* a regression is a hang: fail it instead */
    feed_in_chunks(&big, junk, n, 16384);
    framer_feed(&big, doc, strlen(doc));
    /* The same with the small buffer, byte by byte. */
    feed_in_chunks(&f, junk, n, 1);
    framer_feed(&f, doc, strlen(doc));
    alarm(0);
    assert_true(big.used < big.max_object);
    /* The white space is the inside of an oversize object; resync finds doc. */
    assert_int_equal(s2.events[FRAMER_EVENT_OVERSIZE], 1);
    assert_int_equal(seen.events[FRAMER_EVENT_OVERSIZE], 1);
    framer_feed(&big, doc, strlen(doc));
    framer_feed(&f, doc, strlen(doc));
    assert_true(s2.count >= 1);
    assert_string_equal(s2.objects[s2.count - 1], doc);
    assert_true(seen.count >= 1);
    assert_string_equal(seen.objects[seen.count - 1], doc);
    framer_free(&big);
    free(junk);
}

/*
 * A full buffer whose last bytes are the start of a "len" header ('{"le')
 * once returned "need more" before the oversize check: another endless loop.
 */
static void header_cut_at_the_end_of_a_full_buffer(void **state)
{
    (void)state;
    struct framer big;
    struct seen s2;
    size_t max = FRAMER_DEFAULT_MAX_OBJECT;
    char *stream = malloc(max + 4096);
    char doc[256];

    memset(&s2, 0, sizeof(s2));
    assert_int_equal(framer_init(&big, max, record, &s2), 0);
    int head = snprintf(stream, max, "{\"len\": %zu, \"pad\": \"", max);
    memset(stream + head, 'x', max - (size_t)head);
    memcpy(stream + max - 4, "{\"le", 4);
    make_doc(doc, sizeof(doc), 9);
    alarm(10);
    framer_feed(&big, stream, max);
    framer_feed(&big, "n\": 5}", 6);
    framer_feed(&big, "\"}", 2);
    framer_feed(&big, doc, strlen(doc));
    alarm(0);
    assert_true(big.used < max);
    assert_int_equal(s2.events[FRAMER_EVENT_OVERSIZE], 1);
    assert_true(s2.count >= 1);
    assert_string_equal(s2.objects[s2.count - 1], doc);
    framer_free(&big);
    free(stream);
}

/* A document with an exact "len" and a nested object that opens with "len". */
static void make_doc_with_nested_len(char *out, size_t size, int n)
{
    char body[200];
    snprintf(body, sizeof(body),
             ", \"n\": %d, \"extra\": {\"len\": 3, \"x\": 1}, \"more\": [{\"len\": 999}], \"z\": 2}", n);
    size_t guess = 0;
    for (int i = 0; i < 3; i++) {
        int head = snprintf(out, size, "{\"len\": %zu", guess);
        guess = (size_t)head + strlen(body);
    }
    snprintf(out, size, "{\"len\": %zu%s", guess, body);
    assert_int_equal(strlen(out), guess);
}

/*
 * A nested object that starts with "len" once replaced the document it is
 * part of: framing must only start documents at depth 0.
 */
static void nested_len_object_is_content(void **state)
{
    (void)state;
    char a[256], b[256], all[600];
    make_doc_with_nested_len(a, sizeof(a), 1);
    make_doc_with_nested_len(b, sizeof(b), 2);
    snprintf(all, sizeof(all), "%s%s", a, b);
    for (size_t chunk = 1; chunk <= strlen(all); chunk++) {
        memset(&seen, 0, sizeof(seen));
        framer_reset(&f);
        feed_in_chunks(&f, all, strlen(all), chunk);
        assert_int_equal(seen.count, 2);
        assert_string_equal(seen.objects[0], a);
        assert_string_equal(seen.objects[1], b);
        assert_int_equal(seen.events[FRAMER_EVENT_TRUNCATED], 0);
        assert_int_equal(seen.events[FRAMER_EVENT_LEN_MISMATCH], 0);
        assert_int_equal(seen.events[FRAMER_EVENT_GARBAGE], 0);
    }
}

/* A document cut short inside a string, then whole ones, at every split. */
static void cut_inside_a_string_at_every_split(void **state)
{
    (void)state;
    char a[256], b[256], c[256], all[800];
    make_doc(a, sizeof(a), 1);
    make_doc(b, sizeof(b), 2);
    make_doc(c, sizeof(c), 3);
    const char *cut = strstr(a, "\"a }") + 3; /* inside the string */
    snprintf(all, sizeof(all), "%.*s%s%s", (int)(cut - a), a, b, c);
    for (size_t chunk = 1; chunk <= strlen(all); chunk++) {
        memset(&seen, 0, sizeof(seen));
        framer_reset(&f);
        feed_in_chunks(&f, all, strlen(all), chunk);
        assert_int_equal(seen.count, 2);
        assert_string_equal(seen.objects[0], b);
        assert_string_equal(seen.objects[1], c);
        assert_int_equal(seen.events[FRAMER_EVENT_TRUNCATED], 1);
    }
}

/* Callbacks that reset or free the framer, as a link restart or close does. */
struct reentry {
    struct framer *fr;
    int objects;
    bool do_free;
};

static void reenter(void *user, enum framer_event ev, const char *data, size_t size)
{
    struct reentry *r = user;
    (void)data;
    (void)size;
    if (ev != FRAMER_EVENT_OBJECT)
        return;
    r->objects++;
    if (r->do_free)
        framer_free(r->fr);
    else
        framer_reset(r->fr);
}

static void callback_may_reset_or_free(void **state)
{
    (void)state;
    char a[256], b[256], all[600];
    make_doc(a, sizeof(a), 1);
    make_doc(b, sizeof(b), 2);
    snprintf(all, sizeof(all), "%s%s%.20s", a, b, a);

    struct framer g;
    struct reentry r = {&g, 0, false};
    assert_int_equal(framer_init(&g, 1024, reenter, &r), 0);
    framer_feed(&g, all, strlen(all));
    /* The reset dropped the rest of that read. */
    assert_int_equal(r.objects, 1);
    assert_int_equal(g.used, 0);
    framer_feed(&g, b, strlen(b));
    assert_int_equal(r.objects, 2);

    r.do_free = true;
    framer_feed(&g, all, strlen(all));
    assert_int_equal(r.objects, 3);
    assert_null(g.buf);
    framer_feed(&g, all, strlen(all)); /* freed: ignored, no crash */
    assert_int_equal(r.objects, 3);
}

static void init_rejects_tiny_buffers(void **state)
{
    (void)state;
    struct framer g;
    assert_int_equal(framer_init(&g, 10, record, &seen), -22);
}

/*
 * The brace scanner skips plain bytes eight at a time: on any bytes, from
 * any starting state, it must stop where scanning byte by byte stops.
 */
static void bulk_skip_matches_byte_by_byte(void **state)
{
    (void)state;
    static const char alphabet[] = "{}[]\"\\ ,0123456789.-eEtrufalsn:_xyzXYZ\x7f\xc3\xa9\x80";
    unsigned seed = 42;
    char buf[300];

    for (int round = 0; round < 20000; round++) {
        size_t n = (size_t)(rand_r(&seed) % sizeof(buf));
        for (size_t i = 0; i < n; i++)
            buf[i] = rand_r(&seed) % 4 ? alphabet[rand_r(&seed) % (sizeof(alphabet) - 1)]
                                        : (char)(rand_r(&seed) % 256);
        struct framer_scanner fast = {.depth = 1, .in_string = round % 3 == 1,
                                      .escaped = round % 7 == 1};
        struct framer_scanner slow = fast;
        size_t closed_fast = 0, closed_slow = 0;
        for (size_t i = 0; i < n && !closed_slow; i++)
            if (scan_byte(&slow, buf[i]))
                closed_slow = i + 1;
        for (size_t i = skip_plain(&fast, buf, 0, n); i < n && !closed_fast;
             i = skip_plain(&fast, buf, i, n))
            if (scan_byte(&fast, buf[i++]))
                closed_fast = i;
        assert_int_equal(closed_fast, closed_slow);
        if (!closed_slow) {
            assert_int_equal(fast.depth, slow.depth);
            assert_int_equal(fast.in_string, slow.in_string);
            assert_int_equal(fast.escaped, slow.escaped);
        }
    }
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
        cmocka_unit_test_setup_teardown(len_header_then_endless_spaces, setup, teardown),
        cmocka_unit_test_setup_teardown(header_cut_at_the_end_of_a_full_buffer, setup, teardown),
        cmocka_unit_test_setup_teardown(nested_len_object_is_content, setup, teardown),
        cmocka_unit_test_setup_teardown(cut_inside_a_string_at_every_split, setup, teardown),
        cmocka_unit_test(callback_may_reset_or_free),
        cmocka_unit_test(bulk_skip_matches_byte_by_byte),
    };
    return cmocka_run_group_tests_name("framer", tests, NULL, NULL);
}
