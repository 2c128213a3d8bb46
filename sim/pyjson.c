/* SPDX-License-Identifier: MIT */
/* pyjson.c - see pyjson.h. */
#include "pyjson.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void pyjson_init(struct pyjson *w) { memset(w, 0, sizeof(*w)); }

void pyjson_free(struct pyjson *w)
{
    free(w->buf);
    memset(w, 0, sizeof(*w));
}

void pyjson_reset(struct pyjson *w)
{
    w->len = 0;
    w->depth = 0;
    w->failed = false;
    memset(w->need_comma, 0, sizeof(w->need_comma));
    if (w->buf)
        w->buf[0] = '\0';
}

static void put(struct pyjson *w, const char *s, size_t n)
{
    if (w->failed)
        return;
    if (w->len + n + 1 > w->cap) {
        size_t cap = w->cap ? w->cap * 2 : 4096;
        while (cap < w->len + n + 1)
            cap *= 2;
        char *b = realloc(w->buf, cap);
        if (!b) {
            w->failed = true;
            return;
        }
        w->buf = b;
        w->cap = cap;
    }
    memcpy(w->buf + w->len, s, n);
    w->len += n;
    w->buf[w->len] = '\0';
}

static void puts_(struct pyjson *w, const char *s) { put(w, s, strlen(s)); }

/* Separates a value from the one before it, unless it follows a key. */
static void value_prefix(struct pyjson *w)
{
    if (w->depth > 0 && w->need_comma[w->depth])
        puts_(w, ", ");
    if (w->depth > 0)
        w->need_comma[w->depth] = true;
}

static void open_(struct pyjson *w, const char *c)
{
    value_prefix(w);
    puts_(w, c);
    if (w->depth < 31)
        w->depth++;
    w->need_comma[w->depth] = false;
}

static void close_(struct pyjson *w, const char *c)
{
    if (w->depth > 0)
        w->depth--;
    puts_(w, c);
}

void pyjson_begin_object(struct pyjson *w) { open_(w, "{"); }
void pyjson_end_object(struct pyjson *w) { close_(w, "}"); }
void pyjson_begin_array(struct pyjson *w) { open_(w, "["); }
void pyjson_end_array(struct pyjson *w) { close_(w, "]"); }

void pyjson_key(struct pyjson *w, const char *key)
{
    pyjson_string(w, key);
    puts_(w, ": ");
    /* The value after a key takes no separator of its own. */
    w->need_comma[w->depth] = false;
}

void pyjson_raw(struct pyjson *w, const char *text)
{
    value_prefix(w);
    puts_(w, text);
}

void pyjson_int(struct pyjson *w, long long v)
{
    char b[32];
    snprintf(b, sizeof(b), "%lld", v);
    pyjson_raw(w, b);
}

void pyjson_format_float(char *buf, size_t size, double v)
{
    char digits[40];
    int exp10 = 0, p;

    if (isnan(v)) {
        snprintf(buf, size, "NaN");
        return;
    }
    if (isinf(v)) {
        snprintf(buf, size, v > 0 ? "Infinity" : "-Infinity");
        return;
    }
    if (v == 0) {
        snprintf(buf, size, signbit(v) ? "-0.0" : "0.0");
        return;
    }
    /* The shortest mantissa that reads back as the same double. */
    for (p = 1; p <= 17; p++) {
        snprintf(digits, sizeof(digits), "%.*e", p - 1, v);
        if (strtod(digits, NULL) == v)
            break;
    }
    char *e = strchr(digits, 'e');
    exp10 = atoi(e + 1);
    *e = '\0';
    /* digits: "-d.ddd" -> sign and bare digit string */
    char mant[24];
    size_t m = 0;
    bool neg = digits[0] == '-';
    for (char *c = digits + neg; *c; c++)
        if (*c != '.')
            mant[m++] = *c;
    mant[m] = '\0';
    if (exp10 < -4 || exp10 >= 16) {
        /* Python: 1e-05, 1.5e+16 */
        snprintf(buf, size, "%s%c%s%s%se%c%02d", neg ? "-" : "", mant[0],
                 m > 1 ? "." : "", m > 1 ? mant + 1 : "", "", exp10 < 0 ? '-' : '+',
                 abs(exp10));
        return;
    }
    char out[64];
    size_t o = 0;
    if (neg)
        out[o++] = '-';
    if (exp10 < 0) {
        out[o++] = '0';
        out[o++] = '.';
        for (int z = 0; z < -exp10 - 1; z++)
            out[o++] = '0';
        for (size_t i = 0; i < m; i++)
            out[o++] = mant[i];
    } else {
        for (int i = 0; i <= exp10; i++)
            out[o++] = (size_t)i < m ? mant[i] : '0';
        out[o++] = '.';
        if ((size_t)exp10 + 1 < m)
            for (size_t i = (size_t)exp10 + 1; i < m; i++)
                out[o++] = mant[i];
        else
            out[o++] = '0';
    }
    out[o] = '\0';
    snprintf(buf, size, "%s", out);
}

void pyjson_float(struct pyjson *w, double v)
{
    char b[40];
    pyjson_format_float(b, sizeof(b), v);
    pyjson_raw(w, b);
}

void pyjson_float_array(struct pyjson *w, const char *key, const double *v, int n)
{
    if (key)
        pyjson_key(w, key);
    pyjson_begin_array(w);
    for (int i = 0; i < n; i++)
        pyjson_float(w, v[i]);
    pyjson_end_array(w);
}

void pyjson_bool(struct pyjson *w, bool v) { pyjson_raw(w, v ? "true" : "false"); }

void pyjson_string(struct pyjson *w, const char *s)
{
    value_prefix(w);
    puts_(w, "\"");
    for (const unsigned char *c = (const unsigned char *)s; *c; c++) {
        char esc[8];
        if (*c == '"' || *c == '\\') {
            esc[0] = '\\';
            esc[1] = (char)*c;
            put(w, esc, 2);
        } else if (*c < 0x20) {
            snprintf(esc, sizeof(esc), "\\u%04x", *c);
            puts_(w, esc);
        } else {
            put(w, (const char *)c, 1);
        }
    }
    puts_(w, "\"");
}
