/* SPDX-License-Identifier: MIT */
/*
 * property.h - the generator of the unit tests' property tests: a seed
 * from the environment (to replay a run) or from the time, printed before
 * the run so that a failure can be replayed, and an xorshift64 sequence
 * from it.
 */
#ifndef JAKAGW_TESTS_PROPERTY_H
#define JAKAGW_TESTS_PROPERTY_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

static uint64_t property_rng;

/* Seeds the sequence from $'env' (any base strtoull reads) or the time
 * and pid, and prints "'what': 'runs' runs, 'env'=0x...". */
static inline void property_seed(const char *what, const char *env, unsigned runs)
{
    const char *given = getenv(env);
    uint64_t seed = given ? strtoull(given, NULL, 0)
                          : (uint64_t)time(NULL) * 2654435761u ^ (uint64_t)getpid() << 32;
    if (!seed)
        seed = 1; /* xorshift stays at 0 */
    printf("%s: %u runs, %s=0x%llx\n", what, runs, env, (unsigned long long)seed);
    fflush(stdout);
    property_rng = seed;
}

/* The next number below 'n' (n > 0). */
static inline unsigned property_next(unsigned n)
{
    property_rng ^= property_rng << 13;
    property_rng ^= property_rng >> 7;
    property_rng ^= property_rng << 17;
    return (unsigned)(property_rng % n);
}

#endif
