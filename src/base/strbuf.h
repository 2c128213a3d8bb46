/* SPDX-License-Identifier: MIT */
/*
 * strbuf.h - a growing text buffer for the HTTP answers (metrics, JSON).
 *
 * Appends never fail visibly: once an allocation fails the buffer is
 * marked failed, further appends do nothing, and strbuf_take() returns
 * NULL, so a caller checks once at the end.
 */
#ifndef JAKAGW_STRBUF_H
#define JAKAGW_STRBUF_H

#include <stdbool.h>
#include <stddef.h>

struct strbuf {
    char *data;
    size_t len, cap;
    bool failed;
};

void strbuf_init(struct strbuf *b, size_t initial);
void strbuf_append(struct strbuf *b, const char *text, size_t len);
void strbuf_printf(struct strbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* The text (NUL-terminated, *len without the NUL), now the caller's to
 * free(); NULL if an allocation failed (then nothing is left to free).
 * The buffer is left empty: appends after it start a new text, which
 * strbuf_take() or strbuf_free() ends. */
char *strbuf_take(struct strbuf *b, size_t *len);
void strbuf_free(struct strbuf *b);

#endif
