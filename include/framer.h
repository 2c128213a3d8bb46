/*
 * framer.h - cut a byte stream of back-to-back JSON objects into objects.
 *
 * JAKA controllers write JSON objects with no delimiter between them, and TCP
 * splits or merges them at will. The framer buffers at most 'max_object'
 * bytes and reports each complete object, in order, through a callback.
 *
 * How an object's end is found: when the object starts with a "len" member
 * (the status port's documents), at the byte "len" gives, provided a '}'
 * stands there; the JSON parser then judges the content, so one corrupt
 * document cannot swallow the ones after it. Otherwise, or when no '}'
 * stands there, a string-aware brace scanner finds the end (braces inside
 * strings and escaped quotes do not count).
 *
 * Recovery: bytes outside any object are garbage and skipped; an object
 * larger than 'max_object' is dropped and skipped to its end; once the stream
 * has shown "len" headers, a new '{"len"' inside an unfinished object means
 * the unfinished one was cut short: it is dropped and framing restarts there.
 * Each of these is reported as an event and counted.
 */
#ifndef JAKAGW_FRAMER_H
#define JAKAGW_FRAMER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define FRAMER_MIN_OBJECT 256
#define FRAMER_DEFAULT_MAX_OBJECT (64 * 1024)

enum framer_event {
    FRAMER_EVENT_OBJECT,    /* data/size: one complete object */
    FRAMER_EVENT_GARBAGE,   /* size: bytes skipped outside objects */
    FRAMER_EVENT_OVERSIZE,  /* an object over max_object was dropped */
    FRAMER_EVENT_TRUNCATED, /* an unfinished object was dropped */
    FRAMER_EVENT_LEN_MISMATCH, /* "len" disagreed with the object's end */
};

typedef void (*framer_event_cb)(void *user, enum framer_event event,
                                const char *data, size_t size);

struct framer_stats {
    uint64_t objects;
    uint64_t garbage_bytes;
    uint64_t garbage_runs;
    uint64_t oversize;
    uint64_t truncated;
    uint64_t len_mismatch;
};

enum framer_state { FRAMER_SEEK, FRAMER_OBJECT, FRAMER_DISCARD };

struct framer {
    char *buf;
    size_t max_object;
    size_t used;  /* bytes held, from buf[0] */
    size_t scan;  /* next byte to scan in buf */
    enum framer_state state;
    int depth;
    bool in_string;
    bool escaped;
    bool in_garbage;      /* inside a run of garbage bytes */
    bool stream_has_len;  /* an object with a "len" header was seen */
    bool resync;          /* recovering from trouble: restart at '{"len"' */
    size_t expect_len;    /* from the current object's "len", or 0 */
    bool header_checked;  /* expect_len is decided for this object */
    uint64_t discarded;   /* bytes skipped in FRAMER_DISCARD */
    framer_event_cb cb;
    void *user;
    struct framer_stats stats;
};

/*
 * Prepares 'f' for objects of at most 'max_object' bytes (at least
 * FRAMER_MIN_OBJECT). Returns 0, -EINVAL or -ENOMEM.
 */
int framer_init(struct framer *f, size_t max_object, framer_event_cb cb,
                void *user);
void framer_free(struct framer *f);

/* Forgets any partial object, e.g. after a reconnect. Keeps the counters. */
void framer_reset(struct framer *f);

/* Feeds 'size' bytes; events are reported before this returns. */
void framer_feed(struct framer *f, const char *data, size_t size);

#endif
