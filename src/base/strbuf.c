/* SPDX-License-Identifier: MIT */
/* strbuf.c - see strbuf.h. */
#include "strbuf.h"

#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void strbuf_init(struct strbuf *b, size_t initial)
{
    b->len = 0;
    b->cap = initial ? initial : 256;
    b->data = malloc(b->cap);
    b->failed = !b->data;
    if (b->data)
        b->data[0] = '\0';
}

static void fail(struct strbuf *b)
{
    free(b->data);
    b->data = NULL;
    b->failed = true;
}

static bool reserve(struct strbuf *b, size_t more)
{
    if (b->failed)
        return false;
    if (more > SIZE_MAX / 2 - b->len) {
        fail(b); /* no allocation can hold it: doubling would wrap */
        return false;
    }
    if (b->data && b->len + more + 1 <= b->cap)
        return true;
    /* After strbuf_take() the buffer holds nothing and has no room (cap
     * 0, which doubling would keep 0 forever): it starts again at 256. */
    size_t cap = b->cap ? b->cap : 256;
    while (b->len + more + 1 > cap)
        cap *= 2;
    char *data = realloc(b->data, cap);
    if (!data) {
        fail(b);
        return false;
    }
    b->data = data;
    b->cap = cap;
    return true;
}

void strbuf_append(struct strbuf *b, const char *text, size_t len)
{
    if (!reserve(b, len))
        return;
    memcpy(b->data + b->len, text, len);
    b->len += len;
    b->data[b->len] = '\0';
}

void strbuf_printf(struct strbuf *b, const char *fmt, ...)
{
    va_list ap;
    if (!reserve(b, 0)) /* a buffer taken has no room even for the NUL */
        return;
    va_start(ap, fmt);
    int n = vsnprintf(b->data + b->len, b->cap - b->len, fmt, ap);
    va_end(ap);
    if (n < 0)
        return;
    if ((size_t)n >= b->cap - b->len) {
        if (!reserve(b, (size_t)n))
            return;
        va_start(ap, fmt);
        vsnprintf(b->data + b->len, b->cap - b->len, fmt, ap);
        va_end(ap);
    }
    b->len += (size_t)n;
}

char *strbuf_take(struct strbuf *b, size_t *len)
{
    char *data = b->failed ? NULL : b->data;
    if (len)
        *len = data ? b->len : 0;
    b->data = NULL;
    b->len = b->cap = 0;
    return data;
}

void strbuf_free(struct strbuf *b)
{
    free(b->data);
    b->data = NULL;
    b->len = b->cap = 0;
}
