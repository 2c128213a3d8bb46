/* SPDX-License-Identifier: MIT */
/*
 * test_http_text.c - the text the HTTP endpoints write: the growing buffer
 * (strbuf.h), Prometheus label values escaped (metrics.h), and outside
 * text in /status.json kept inert (<, > and & as \u escapes).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdlib.h>
#include <string.h>

#include "metrics.h"
#include "strbuf.h"

/* harden() is static: the module is included whole. */
#include "status_json.c"

static void strbuf_grows_past_its_first_size(void **state)
{
    (void)state;
    struct strbuf b;
    size_t len;
    strbuf_init(&b, 8);
    for (unsigned i = 0; i < 1000; i++)
        strbuf_printf(&b, "%04u,", i);
    strbuf_append(&b, "end", 3);
    char *text = strbuf_take(&b, &len);
    assert_non_null(text);
    assert_int_equal(len, 5000 + 3);
    assert_int_equal(strlen(text), len);
    assert_memory_equal(text, "0000,0001,", 10);
    assert_string_equal(text + 4995, "0999,end");
    free(text);
    assert_null(strbuf_take(&b, &len)); /* taken: nothing left */
    assert_int_equal(len, 0);
}

/* A buffer taken starts a new text: an append after strbuf_take() once
 * doubled a capacity of 0 forever. */
static void strbuf_appends_after_take_start_a_new_text(void **state)
{
    (void)state;
    struct strbuf b;
    size_t len;
    strbuf_init(&b, 8);
    strbuf_append(&b, "first", 5);
    free(strbuf_take(&b, NULL));
    strbuf_append(&b, "second", 6);
    strbuf_printf(&b, ",%d", 3);
    char *text = strbuf_take(&b, &len);
    assert_non_null(text);
    assert_string_equal(text, "second,3");
    assert_int_equal(len, 8);
    free(text);
    strbuf_printf(&b, "%s", "third"); /* printf first, into no room at all */
    text = strbuf_take(&b, &len);
    assert_non_null(text);
    assert_string_equal(text, "third");
    free(text);
    strbuf_append(&b, "left", 4);
    strbuf_free(&b); /* what was not taken is freed */
}

static void label_values_are_escaped(void **state)
{
    (void)state;
    struct strbuf b;
    strbuf_init(&b, 4);
    metrics_label_value(&b, "a\"b\\c\nd");
    metrics_label_value(&b, "");
    metrics_label_value(&b, "plain");
    char *text = strbuf_take(&b, NULL);
    assert_string_equal(text, "a\\\"b\\\\c\\ndplain");
    free(text);
}

static void markup_in_json_strings_becomes_escapes(void **state)
{
    (void)state;
    size_t size;
    char *out = harden("{\"m\":\"<img src=x onerror=alert(1)>&amp;\"}", &size);
    assert_non_null(out);
    assert_string_equal(out, "{\"m\":\"\\u003cimg src=x onerror=alert(1)\\u003e\\u0026amp;\"}\n");
    assert_int_equal(size, strlen(out));
    assert_null(strpbrk(out, "<>&"));
    free(out);
}

/*
 * A robot's errorMsg (or a program name) is any bytes: /status.json must
 * still be UTF-8 (RFC 8259), or a strict consumer (Python's json, the
 * monitoring's collectors) rejects the whole document. Bytes that are no
 * UTF-8 become U+FFFD; U+2028 and U+2029, legal in JSON but line ends to
 * JavaScript before ES2019, become \u escapes.
 */
static void invalid_utf8_in_json_becomes_replacement_characters(void **state)
{
    (void)state;
    size_t size;
    /* A stray byte, a cut sequence, an overlong '/', a surrogate, U+2028,
     * a good e-acute and a good 4-byte sequence. */
    char *out = harden("{\"m\":\"a\xff b\xc3 c\xc0\xaf d\xed\xa0\x80 "
                       "e\xe2\x80\xa8 \xc3\xa9\xf0\x9f\x98\x80\"}",
                       &size);
    assert_non_null(out);
    assert_string_equal(out, "{\"m\":\"a\xef\xbf\xbd b\xef\xbf\xbd c\xef\xbf\xbd"
                             "\xef\xbf\xbd d\xef\xbf\xbd\xef\xbf\xbd\xef\xbf\xbd "
                             "e\\u2028 \xc3\xa9\xf0\x9f\x98\x80\"}\n");
    assert_int_equal(size, strlen(out));
    free(out);
}

/* Prometheus refuses a scrape with a label value that is not UTF-8 (a
 * command name from the JSON mailbox is the PLC's text). */
static void invalid_utf8_in_label_values_becomes_replacement_characters(void **state)
{
    (void)state;
    struct strbuf b;
    strbuf_init(&b, 4);
    metrics_label_value(&b, "x\xff\"\xc3\xa9\xe2\x82");
    char *text = strbuf_take(&b, NULL);
    assert_string_equal(text, "x\xef\xbf\xbd\\\"\xc3\xa9\xef\xbf\xbd\xef\xbf\xbd");
    free(text);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(strbuf_grows_past_its_first_size),
        cmocka_unit_test(strbuf_appends_after_take_start_a_new_text),
        cmocka_unit_test(label_values_are_escaped),
        cmocka_unit_test(markup_in_json_strings_becomes_escapes),
        cmocka_unit_test(invalid_utf8_in_json_becomes_replacement_characters),
        cmocka_unit_test(invalid_utf8_in_label_values_becomes_replacement_characters),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
