/* SPDX-License-Identifier: MIT */
/*
 * framer.h - cut a byte stream of back-to-back JSON objects into objects.
 *
 * JAKA controllers write JSON objects with no delimiter between them, and TCP
 * splits or merges them at will. The framer buffers at most 'max_object'
 * bytes and reports each complete object, in order, through a callback.
 *
 * Where an object starts: only at a '{' outside any object (depth 0). A '{'
 * nested in a document never starts a new one, even if it opens with "len".
 *
 * How an object's end is found: when the object starts with a "len" member
 * (the status port's documents), at the byte "len" gives, provided a '}'
 * stands there; the JSON parser then judges the content, so one corrupt
 * document cannot swallow the ones after it. Otherwise, or when no '}'
 * stands there, a string-aware brace scanner finds the end (braces inside
 * strings and escaped quotes do not count). When the two disagree, a
 * "len" header right after the brace scanner's end settles it for the
 * braces; an object whose "len" is wrong is therefore reported once the
 * bytes after it have arrived. Every such decision waits for the bytes that
 * settle it, so the objects reported never depend on how TCP split the
 * stream.
 *
 * Recovery: bytes outside any object are garbage and skipped. An object
 * larger than 'max_object' is dropped and skipped to its end. Once the
 * stream has shown "len" headers, an unfinished object was cut short when a
 * '{"len": N' inside it is itself a whole document of exactly N bytes: the
 * unfinished one is dropped and framing restarts there. A nested object
 * whose "len" does not frame it exactly is content, not a new document.
 * Each of these is reported as an event and counted.
 *
 * Every decision is made within a bounded look-ahead (FRAMER_HEADER_MAX
 * bytes for a "len" header), and a full buffer is always resolved (the
 * object is dropped as oversize), so no input can stall framer_feed().
 *
 * Callbacks may re-enter: the callback may call framer_reset() or
 * framer_free() on the same framer (for example when it closes or restarts
 * the connection); they take effect when the callback returns, and the rest
 * of the bytes given to that framer_feed() call are dropped. The struct
 * itself must stay valid until the callback returns.
 */
#ifndef JAKAGW_FRAMER_H
#define JAKAGW_FRAMER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define FRAMER_MIN_OBJECT 256
#define FRAMER_DEFAULT_MAX_OBJECT (64 * 1024)
/* A "len" header ('{', "len", ':', digits and white space) fits in this. */
#define FRAMER_HEADER_MAX 64

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

/* Where the string-aware brace scanner stands. */
struct framer_scanner {
    size_t pos; /* next byte to scan */
    int depth;
    bool in_string;
    bool escaped;
};

struct framer {
    char *buf;
    size_t max_object;
    size_t used; /* bytes held, from buf[0] */
    enum framer_state state;
    struct framer_scanner scan; /* over the current object, from buf[0] */
    size_t restart_scan;  /* next byte to test as a '{"len"' restart */
    size_t end;           /* where the brace scanner closed the object, or 0 */
    size_t expect_len;    /* from the current object's "len", or 0 */
    bool header_checked;  /* expect_len is decided for this object */
    bool len_failed;      /* the object had a "len" that proved wrong */
    bool in_garbage;      /* inside a run of garbage bytes */
    bool stream_has_len;  /* an object with a "len" header was seen */
    bool resync;          /* recovering from trouble: restart at '{"len"' */
    uint64_t discarded;    /* bytes skipped in FRAMER_DISCARD */
    /* Re-entry from the callback (see above). */
    bool in_callback;
    bool reset_pending;
    bool free_pending;
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

/* Releases the buffer. From a callback: when the callback returns. */
void framer_free(struct framer *f);

/*
 * Forgets any partial object, e.g. after a reconnect. Keeps the counters.
 * From a callback: when the callback returns.
 */
void framer_reset(struct framer *f);

/* Feeds 'size' bytes; events are reported before this returns. */
void framer_feed(struct framer *f, const char *data, size_t size);

#endif
