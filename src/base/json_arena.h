/* SPDX-License-Identifier: MIT */
/*
 * json_arena.h - parse a JSON document with cJSON into an arena, so that
 * its thousands of nodes cost a pointer bump each, and freeing the whole
 * tree costs a rewind.
 *
 * cJSON allocates every node and string with malloc and frees them one by
 * one in cJSON_Delete: for a status document of 8.5 KB (about 1,900
 * nodes) that was a quarter of all the instructions the gateway spent on
 * it. json_arena_parse() installs allocation hooks that take memory from
 * the arena's chunks, parses, and puts cJSON's default hooks back before
 * it returns: cJSON_InitHooks() is process-wide, and the command port, the
 * mailboxes and the simulator use cJSON too, with trees that must outlive
 * any document. So only the nodes of the document being parsed come from
 * the arena, and every other cJSON call, before or after, uses malloc and
 * free as usual. This assumes nobody else keeps custom hooks installed
 * (nothing in jakagw does; a test that does restores the defaults too),
 * and one thread using cJSON (the event loop).
 *
 * The tree returned lives until the next json_arena_parse() or
 * json_arena_reset() on the same arena: never cJSON_Delete() it, and copy
 * out any string to keep (status_parse copies into struct jaka_status).
 *
 * Under AddressSanitizer (make san, the fuzz targets) each allocation is a
 * real malloc, recorded and freed by the reset, so ASan still bounds every
 * node and catches a use after the reset; valgrind, on the plain build,
 * sees the chunks (each one malloc'ed) and their leaks, not each node.
 *
 * Not thread-safe: cJSON's hooks are one global.
 */
#ifndef JAKAGW_JSON_ARENA_H
#define JAKAGW_JSON_ARENA_H

#include <stddef.h>

#include <cJSON.h>

#define JSON_ARENA_CHUNK_SIZE (64 * 1024)

struct json_arena_chunk;

struct json_arena {
    struct json_arena_chunk *chunks; /* the current chunk first */
    unsigned char *next, *end; /* the free part of the current chunk */
    size_t held;        /* bytes of all chunks (or blocks, under ASan) */
    size_t taken;       /* bytes taken before the current chunk, or blocks */
    size_t next_size;   /* the next chunk's size (JSON_ARENA_CHUNK_SIZE if less) */
    /* Under AddressSanitizer: every block of the current parse. */
    void **blocks;
    size_t block_count, block_cap;
};

/* Prepares an empty arena (as does zeroing it); it takes memory at the
 * first parse. */
void json_arena_init(struct json_arena *a);

/*
 * Parses 'size' bytes of 'json' (cJSON_ParseWithLength) into the arena,
 * dropping the tree of the previous parse first. Returns the root, or NULL
 * when the text is not JSON or memory ran out. The tree is valid until the
 * next parse or reset.
 */
cJSON *json_arena_parse(struct json_arena *a, const char *json, size_t size);

/*
 * Drops the tree of the last parse. The memory stays for the next one, as
 * one chunk the size the last parse needed (no allocation at all while
 * documents keep their size); a chunk much larger than the last parse
 * needed is given back, so one unusually large document does not hold
 * memory for ever.
 */
void json_arena_reset(struct json_arena *a);

/* Releases every chunk. The arena may be used again (json_arena_init state). */
void json_arena_free(struct json_arena *a);

#endif
