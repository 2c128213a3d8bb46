/* SPDX-License-Identifier: MIT */
/* log.c - see log.h. */
#include "log.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static enum log_level max_level = LOG_LEVEL_INFO;

void log_set_level(enum log_level level) { max_level = level; }

bool log_enabled(enum log_level level) { return level <= max_level; }

/*
 * The length of the valid UTF-8 sequence of 2 to 4 bytes at 'p' (RFC 3629:
 * no overlong forms, no surrogates, nothing above U+10FFFF), or 0.
 */
size_t utf8_sequence(const unsigned char *p, size_t left)
{
    unsigned char b = p[0];
    size_t n;
    unsigned char lo = 0x80, hi = 0xBF; /* the second byte's range */

    if (b >= 0xC2 && b <= 0xDF)
        n = 2;
    else if (b >= 0xE0 && b <= 0xEF)
        n = 3;
    else if (b >= 0xF0 && b <= 0xF4)
        n = 4;
    else
        return 0;
    if (b == 0xE0)
        lo = 0xA0; /* overlong */
    else if (b == 0xED)
        hi = 0x9F; /* surrogates */
    else if (b == 0xF0)
        lo = 0x90; /* overlong */
    else if (b == 0xF4)
        hi = 0x8F; /* beyond U+10FFFF */
    if (left < n || p[1] < lo || p[1] > hi)
        return 0;
    for (size_t i = 2; i < n; i++)
        if (p[i] < 0x80 || p[i] > 0xBF)
            return 0;
    return n;
}

/* Appends 'piece' whole, or not at all, keeping room for the NUL. */
static void append(char *out, size_t size_out, size_t *used, const char *piece, size_t n)
{
    if (*used + n < size_out) {
        memcpy(out + *used, piece, n);
        out[*used + n] = '\0';
    }
    *used += n;
}

size_t log_escape(char *out, size_t size_out, const char *in, size_t size)
{
    const unsigned char *p = (const unsigned char *)in;
    size_t used = 0;
    /* Once a piece has not fitted, nothing after it may be added. */
    size_t fitted = 0;
    char esc[8];

    if (size_out > 0)
        out[0] = '\0';
    for (size_t i = 0; i < size;) {
        size_t n = p[i] < 0x80 ? 1 : utf8_sequence(p + i, size - i);
        const char *piece = (const char *)p + i;
        size_t piece_len = n;

        if (n == 1 && (p[i] < 0x20 || p[i] == 0x7F)) {
            piece_len = (size_t)snprintf(esc, sizeof(esc), "\\x%02x", p[i]);
            piece = esc;
        } else if (n == 1 && p[i] == '\\') {
            piece = "\\\\";
            piece_len = 2;
        } else if (n == 2 && p[i] == 0xC2 && p[i + 1] <= 0x9F) {
            piece_len = (size_t)snprintf(esc, sizeof(esc), "\\u%04x", p[i + 1]);
            piece = esc;
        } else if (n == 0) {
            piece_len = (size_t)snprintf(esc, sizeof(esc), "\\x%02x", p[i]);
            piece = esc;
            n = 1;
        }
        if (used == fitted) {
            append(out, size_out, &used, piece, piece_len);
            if (used < size_out)
                fitted = used;
        } else {
            used += piece_len;
        }
        i += n;
    }
    return used;
}

/* Formats and escapes one line into 'out' (LOG_LINE_MAX * 6 + 4 bytes). */
static void format_line(char *out, size_t size_out, const char *fmt, va_list ap)
{
    char line[LOG_LINE_MAX];
    int n = vsnprintf(line, sizeof(line), fmt, ap);
    size_t len = n < 0 ? 0 : (size_t)n;
    bool cut = len >= sizeof(line);

    if (cut) {
        /* Drop a character the cut left incomplete: it is not invalid text. */
        len = sizeof(line) - 1;
        size_t start = len;
        while (start > 0 && len - start < 3 && ((unsigned char)line[start - 1] & 0xC0) == 0x80)
            start--;
        if (start > 0 && (unsigned char)line[start - 1] >= 0xC0 &&
            utf8_sequence((const unsigned char *)line + start - 1, len - start + 1) == 0)
            len = start - 1;
    }
    size_t used = log_escape(out, size_out, line, len);
    if (cut && used + 3 < size_out)
        memcpy(out + used, "...", 4);
}

void log_print(enum log_level level, const char *fmt, ...)
{
    char line[LOG_LINE_MAX * 6 + 4];
    va_list ap;

    if (!log_enabled(level))
        return;
    va_start(ap, fmt);
    format_line(line, sizeof(line), fmt, ap);
    va_end(ap);
    /* One fprintf per line so that lines from one process never interleave. */
    fprintf(stderr, "<%d>%s\n", (int)level, line);
}

void log_plain(const char *fmt, ...)
{
    char line[LOG_LINE_MAX * 6 + 4];
    va_list ap;

    va_start(ap, fmt);
    format_line(line, sizeof(line), fmt, ap);
    va_end(ap);
    fprintf(stderr, "%s\n", line);
}

bool log_ratelimit_pass(struct log_ratelimit *rl, uint64_t now_ms,
                        uint64_t *suppressed)
{
    if (rl->primed && now_ms - rl->last_ms < rl->interval_ms) {
        rl->suppressed++;
        return false;
    }
    *suppressed = rl->suppressed;
    rl->suppressed = 0;
    rl->last_ms = now_ms;
    rl->primed = true;
    return true;
}
