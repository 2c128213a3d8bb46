/* SPDX-License-Identifier: MIT */
/*
 * test_log.c - outside text is data, never markup: every line the logger
 * prints is one line without control bytes, whatever a configuration, a
 * flag, the robot or a PLC put into it, and valid UTF-8 stays readable.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "log.h"

static const char *escaped(const char *in, size_t size)
{
    static char out[LOG_LINE_MAX * 6 + 4];
    size_t n = log_escape(out, sizeof(out), in, size);
    assert_int_equal(n, strlen(out));
    return out;
}

#define ESCAPED(literal) escaped(literal, sizeof(literal) - 1)

static void c0_controls_and_del_are_escaped(void **state)
{
    (void)state;
    assert_string_equal(ESCAPED("a\x1b[31mRED\vX\rY"), "a\\x1b[31mRED\\x0bX\\x0dY");
    assert_string_equal(ESCAPED("one\ntwo\ttab\x7f"), "one\\x0atwo\\x09tab\\x7f");
    assert_string_equal(escaped("nul\0after", 9), "nul\\x00after");
    /* A backslash doubles, so "\x1b" typed by a peer reads back as typed. */
    assert_string_equal(ESCAPED("C:\\x1b"), "C:\\\\x1b");
}

static void valid_utf8_is_kept(void **state)
{
    (void)state;
    /* A Chinese program name and a controller's message, as they are. */
    assert_string_equal(ESCAPED("程序_焊接.jks"), "程序_焊接.jks");
    assert_string_equal(ESCAPED("机器人未上电 é ü 𝄞"), "机器人未上电 é ü 𝄞");
    /* The last code points of each length. */
    assert_string_equal(ESCAPED("\xdf\xbf\xef\xbf\xbf\xf4\x8f\xbf\xbf"),
                        "\xdf\xbf\xef\xbf\xbf\xf4\x8f\xbf\xbf");
}

static void c1_controls_are_escaped(void **state)
{
    (void)state;
    /* U+009B, CSI, moves a terminal's cursor as ESC [ does. */
    assert_string_equal(ESCAPED("a\xc2\x9b" "2Jb\xc2\x85"), "a\\u009b2Jb\\u0085");
    /* U+00A0 is the first character past C1: kept. */
    assert_string_equal(ESCAPED("\xc2\xa0"), "\xc2\xa0");
}

static void invalid_utf8_is_marked(void **state)
{
    (void)state;
    assert_string_equal(ESCAPED("a\xff" "b"), "a\\xffb");
    assert_string_equal(ESCAPED("\x80\xbf"), "\\x80\\xbf");          /* lone continuations */
    assert_string_equal(ESCAPED("\xc0\xaf"), "\\xc0\\xaf");          /* overlong '/' */
    assert_string_equal(ESCAPED("\xe0\x80\xaf"), "\\xe0\\x80\\xaf"); /* overlong */
    assert_string_equal(ESCAPED("\xed\xa0\x80"), "\\xed\\xa0\\x80"); /* a surrogate */
    assert_string_equal(ESCAPED("\xf4\x90\x80\x80"), "\\xf4\\x90\\x80\\x80"); /* > U+10FFFF */
    /* A sequence cut short, then text: the text is not swallowed. */
    assert_string_equal(ESCAPED("\xe6\x9c" "ok"), "\\xe6\\x9cok");
    assert_string_equal(ESCAPED("end\xe6"), "end\\xe6");
}

static void a_small_buffer_gets_whole_escapes_only(void **state)
{
    (void)state;
    char out[8];
    /* "ab\x1b" escapes to 6 bytes; then "cd" would need 8 + NUL. */
    size_t n = log_escape(out, sizeof(out), "ab\x1b" "cd", 5);
    assert_int_equal(n, 8);
    assert_string_equal(out, "ab\\x1bc");
    n = log_escape(out, 4, "ab\x1b", 3);
    assert_int_equal(n, 6);
    assert_string_equal(out, "ab"); /* never half an escape */
    n = log_escape(out, 4, "程", 3);
    assert_string_equal(out, "程");
    n = log_escape(out, 3, "程", 3);
    assert_string_equal(out, ""); /* never half a character */
}

/* Runs log_print or log_plain with stderr on a pipe; returns what came out. */
static const char *captured(void (*emit)(const char *text), const char *text)
{
    static char out[LOG_LINE_MAX * 8];
    int fds[2];
    int saved = dup(STDERR_FILENO);

    assert_int_equal(pipe(fds), 0);
    fflush(stderr);
    dup2(fds[1], STDERR_FILENO);
    emit(text);
    fflush(stderr);
    dup2(saved, STDERR_FILENO);
    close(saved);
    close(fds[1]);
    ssize_t n = read(fds[0], out, sizeof(out) - 1);
    close(fds[0]);
    out[n > 0 ? n : 0] = '\0';
    return out;
}

static void emit_warning(const char *text)
{
    log_warn("command power_on: robot error (2) %s", text);
}

static void emit_plain(const char *text)
{
    log_plain("jakagw: --robot-host: '%s' is not an IP address or a host name", text);
}

static size_t count_lines(const char *text)
{
    size_t n = 0;
    for (; *text; text++)
        n += *text == '\n';
    return n;
}

static void a_forged_journal_entry_stays_inside_its_line(void **state)
{
    (void)state;
    const char *out = captured(emit_warning, "boom\n<3>jakagw: forged entry\r\x1b[2K");
    assert_int_equal(count_lines(out), 1);
    assert_string_equal(out, "<4>command power_on: robot error (2) boom\\x0a<3>jakagw: forged "
                             "entry\\x0d\\x1b[2K\n");
    out = captured(emit_plain, "a\x1b[2J\rb");
    assert_string_equal(out, "jakagw: --robot-host: 'a\\x1b[2J\\x0db' is not an IP address "
                             "or a host name\n");
}

static void a_long_line_is_cut_at_a_character_boundary(void **state)
{
    (void)state;
    char text[LOG_LINE_MAX * 2];
    /* 3-byte characters after an odd prefix, so the cut falls inside one. */
    size_t used = (size_t)snprintf(text, sizeof(text), "x");
    while (used + 3 < sizeof(text) - 1)
        used += (size_t)snprintf(text + used, sizeof(text) - used, "程");
    const char *out = captured(emit_warning, text);
    assert_int_equal(count_lines(out), 1);
    assert_null(strstr(out, "\\x"));      /* no character marked invalid by the cut */
    assert_non_null(strstr(out, "程...\n")); /* whole characters, then the mark */
    assert_true(strlen(out) <= LOG_LINE_MAX + 8);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(c0_controls_and_del_are_escaped),
        cmocka_unit_test(valid_utf8_is_kept),
        cmocka_unit_test(c1_controls_are_escaped),
        cmocka_unit_test(invalid_utf8_is_marked),
        cmocka_unit_test(a_small_buffer_gets_whole_escapes_only),
        cmocka_unit_test(a_forged_journal_entry_stays_inside_its_line),
        cmocka_unit_test(a_long_line_is_cut_at_a_character_boundary),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
