/* SPDX-License-Identifier: MIT */
/*
 * pyjson.h - write JSON the way JAKA controllers do: Python's json.dumps
 * separators (", " and ": "), floats in Python's shortest repr ("1.0",
 * "0.10000000149011612", "1e-05"), integers without a point.
 */
#ifndef JAKASIM_PYJSON_H
#define JAKASIM_PYJSON_H

#include <stdbool.h>
#include <stddef.h>

struct pyjson {
    char *buf;
    size_t len, cap;
    bool need_comma[32]; /* per nesting level */
    int depth;
    bool failed; /* out of memory */
};

void pyjson_init(struct pyjson *w);
void pyjson_free(struct pyjson *w);
void pyjson_reset(struct pyjson *w);

void pyjson_begin_object(struct pyjson *w);
void pyjson_end_object(struct pyjson *w);
void pyjson_begin_array(struct pyjson *w);
void pyjson_end_array(struct pyjson *w);
void pyjson_key(struct pyjson *w, const char *key);
void pyjson_int(struct pyjson *w, long long v);
void pyjson_float(struct pyjson *w, double v);
void pyjson_bool(struct pyjson *w, bool v);
void pyjson_string(struct pyjson *w, const char *s);
/* An array of floats; with a non-NULL key, as that member's value. */
void pyjson_float_array(struct pyjson *w, const char *key, const double *v, int n);

/* Raw text as one value (e.g. a number formatted elsewhere). */
void pyjson_raw(struct pyjson *w, const char *text);

/* Python's repr() of a float into buf (at least 32 bytes). */
void pyjson_format_float(char *buf, size_t size, double v);

#endif
