/* SPDX-License-Identifier: MIT */
/*
 * fuzz_util.h - what every libFuzzer target here shares: a rule check that
 * aborts with one line saying which rule broke, and a cursor that reads
 * the input as a program of steps (zeros once it runs out).
 */
#ifndef JAKAGW_FUZZ_UTIL_H
#define JAKAGW_FUZZ_UTIL_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#define FUZZ_REQUIRE(cond, ...)                                                \
    do {                                                                       \
        if (!(cond)) {                                                         \
            fprintf(stderr, "fuzz: rule broken: " __VA_ARGS__);                \
            fputc('\n', stderr);                                               \
            abort();                                                           \
        }                                                                      \
    } while (0)

struct cursor {
    const uint8_t *p;
    size_t left;
};

static inline uint8_t next(struct cursor *c)
{
    if (!c->left)
        return 0;
    c->left--;
    return *c->p++;
}

static inline uint16_t next16(struct cursor *c)
{
    uint16_t hi = next(c);
    return (uint16_t)(hi << 8 | next(c));
}

#endif
