/* SPDX-License-Identifier: MIT */
/* json_arena.c - see json_arena.h. */
#include "json_arena.h"

#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>

/*
 * Under AddressSanitizer every allocation is a real malloc, so that ASan
 * bounds each node and reports a use after the reset; the arena then only
 * records the blocks and frees them at the reset. The choice is made here,
 * from the compiler's own flag, so make san and the fuzz targets need no
 * flag of their own.
 */
#if defined(__SANITIZE_ADDRESS__)
#define JSON_ARENA_REAL_MALLOC 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define JSON_ARENA_REAL_MALLOC 1
#endif
#endif
#ifndef JSON_ARENA_REAL_MALLOC
#define JSON_ARENA_REAL_MALLOC 0
#endif

/* malloc's alignment: cJSON keeps doubles and pointers in its nodes. */
#define ALIGNMENT 16

struct json_arena_chunk {
    struct json_arena_chunk *next;
    size_t size; /* of data[] */
    _Alignas(ALIGNMENT) unsigned char data[];
};

/* The arena of the parse under way; the hooks have no user pointer. */
static struct json_arena *active;

void json_arena_init(struct json_arena *a)
{
    *a = (struct json_arena){0};
}

static size_t round_up(size_t n)
{
    return (n + (ALIGNMENT - 1)) & ~(size_t)(ALIGNMENT - 1);
}

static void *take_block(struct json_arena *a, size_t n)
{
    if (a->block_count == a->block_cap) {
        size_t cap = a->block_cap ? 2 * a->block_cap : 1024;
        void **blocks = realloc(a->blocks, cap * sizeof(*blocks));
        if (!blocks)
            return NULL;
        a->blocks = blocks;
        a->block_cap = cap;
    }
    void *p = malloc(n);
    if (p) {
        a->blocks[a->block_count++] = p;
        a->held += n;
        a->taken += n;
    }
    return p;
}

/* Starts a new chunk, at least 'n' bytes, as the current one. */
static bool add_chunk(struct json_arena *a, size_t n)
{
    size_t size = a->next_size > JSON_ARENA_CHUNK_SIZE ? a->next_size : JSON_ARENA_CHUNK_SIZE;
    if (size < n)
        size = n;
    struct json_arena_chunk *c = malloc(sizeof(*c) + size);

    if (!c)
        return false;
    if (a->chunks)
        a->taken += (size_t)(a->next - a->chunks->data);
    c->next = a->chunks;
    c->size = size;
    a->chunks = c;
    a->next = c->data;
    a->end = c->data + size;
    a->held += size;
    return true;
}

/* What the current parse has taken so far, alignment included. */
static size_t taken(const struct json_arena *a)
{
    return a->taken + (a->chunks ? (size_t)(a->next - a->chunks->data) : 0);
}

/* The way out of the fast path: a new chunk, or a real malloc under ASan. */
static __attribute__((noinline)) void *take_slow(struct json_arena *a, size_t n)
{
    if (JSON_ARENA_REAL_MALLOC)
        return take_block(a, n);
    if (!add_chunk(a, n))
        return NULL;
    void *p = a->next;
    a->next += n;
    return p;
}

/* Called for every node and string: a bump of 'next' while the chunk lasts. */
static void *hook_malloc(size_t n)
{
    struct json_arena *a = active;

    n = round_up(n ? n : 1);
    if (!JSON_ARENA_REAL_MALLOC && (size_t)(a->end - a->next) >= n) {
        void *p = a->next;
        a->next += n;
        return p;
    }
    return take_slow(a, n);
}

/* cJSON frees parts of a tree that failed to parse: the reset takes them. */
static void hook_free(void *p)
{
    (void)p;
}

static void free_chunks(struct json_arena *a)
{
    while (a->chunks) {
        struct json_arena_chunk *c = a->chunks;
        a->chunks = c->next;
        a->held -= c->size;
        free(c);
    }
    a->next = a->end = NULL;
}

static void free_blocks(struct json_arena *a)
{
    for (size_t i = 0; i < a->block_count; i++)
        free(a->blocks[i]);
    a->block_count = 0;
    a->held = 0;
}

void json_arena_reset(struct json_arena *a)
{
    if (JSON_ARENA_REAL_MALLOC) {
        free_blocks(a);
        a->taken = 0;
        return;
    }
    size_t last = taken(a);
    if (last == 0)
        return; /* nothing since the last reset: keep its decision */
    /* One chunk that fits what the last parse took, with room to spare:
     * more chunks, or a chunk over four times too large, are remade. */
    size_t want = round_up(last + last / 4);
    if (want < JSON_ARENA_CHUNK_SIZE)
        want = JSON_ARENA_CHUNK_SIZE;
    bool one = a->chunks && !a->chunks->next;
    if (!one || a->chunks->size > 4 * want) {
        free_chunks(a);
        a->next_size = want;
    }
    if (a->chunks)
        a->next = a->chunks->data;
    a->taken = 0;
}

cJSON *json_arena_parse(struct json_arena *a, const char *json, size_t size)
{
    cJSON_Hooks hooks = {.malloc_fn = hook_malloc, .free_fn = hook_free};

    json_arena_reset(a);
    active = a;
    cJSON_InitHooks(&hooks);
    cJSON *root = cJSON_ParseWithLength(json, size);
    /* Back to malloc and free for every other user of cJSON. */
    cJSON_InitHooks(NULL);
    active = NULL;
    return root;
}

void json_arena_free(struct json_arena *a)
{
    free_chunks(a);
    free_blocks(a);
    free(a->blocks);
    json_arena_init(a);
}
