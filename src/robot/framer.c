/* SPDX-License-Identifier: MIT */
/* framer.c - see framer.h. */
#include "framer.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#define LEN_MARKER "\"len\""
#define LEN_MARKER_SIZE (sizeof(LEN_MARKER) - 1)

/* What a '{' inside the current object turns out to be. */
enum restart {
    RESTART_NONE,        /* every '{' before the limit is content */
    RESTART_PENDING,     /* the '{' at *at needs more bytes to tell */
    RESTART_CUT_SHORT,   /* a whole document starts at *at */
};

int framer_init(struct framer *f, size_t max_object, framer_event_cb cb,
                void *user)
{
    if (!f || !cb || max_object < FRAMER_MIN_OBJECT)
        return -EINVAL;
    memset(f, 0, sizeof(*f));
    f->buf = malloc(max_object);
    if (!f->buf)
        return -ENOMEM;
    f->max_object = max_object;
    f->cb = cb;
    f->user = user;
    return 0;
}

void framer_free(struct framer *f)
{
    if (f->in_callback) {
        f->free_pending = true;
        return;
    }
    free(f->buf);
    f->buf = NULL;
    f->used = 0;
}

/* Prepares to frame an object that starts at buf[0]. */
static void start_object(struct framer *f)
{
    f->state = FRAMER_OBJECT;
    memset(&f->scan, 0, sizeof(f->scan));
    f->restart_scan = 1;
    f->end = 0;
    f->expect_len = 0;
    f->header_checked = false;
    f->len_failed = false;
}

static void start_seek(struct framer *f)
{
    start_object(f);
    f->state = FRAMER_SEEK;
}

void framer_reset(struct framer *f)
{
    if (f->in_callback) {
        f->reset_pending = true;
        return;
    }
    f->used = 0;
    f->in_garbage = false;
    f->resync = false;
    start_seek(f);
}

static size_t shift(size_t offset, size_t n)
{
    return offset > n ? offset - n : 0;
}

/* Drops buf[0, n), keeping every offset pointing at the same byte. */
static void consume(struct framer *f, size_t n)
{
    memmove(f->buf, f->buf + n, f->used - n);
    f->used -= n;
    f->scan.pos = shift(f->scan.pos, n);
    f->restart_scan = shift(f->restart_scan, n);
    f->end = shift(f->end, n);
}

/*
 * Reports an event. The callback may reset or free the framer; the caller
 * finishes its bookkeeping and process() stops before the next step.
 */
static void emit(struct framer *f, enum framer_event ev, const char *d, size_t n)
{
    f->in_callback = true;
    f->cb(f->user, ev, d, n);
    f->in_callback = false;
}

static bool stop_requested(const struct framer *f)
{
    return f->reset_pending || f->free_pending;
}

static bool is_space(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\n';
}

static size_t skip_spaces(const char *b, size_t p, size_t n)
{
    while (p < n && is_space(b[p]))
        p++;
    return p;
}

/*
 * Reads a '{"len": N' header at b[0] (b[0] is '{'). Returns N, 0 when b
 * holds no usable header, or -1 when more bytes are needed. Undecided only
 * while fewer than FRAMER_HEADER_MAX bytes are there: spaces or digits
 * without end cannot keep the decision open.
 */
static long parse_len_header(const char *b, size_t n)
{
    bool capped = n >= FRAMER_HEADER_MAX;
    long more = capped ? 0 : -1;
    long value = 0;
    int digits = 0;

    if (capped)
        n = FRAMER_HEADER_MAX;
    size_t p = skip_spaces(b, 1, n);
    if (n - p < LEN_MARKER_SIZE)
        return memcmp(b + p, LEN_MARKER, n - p) == 0 ? more : 0;
    if (memcmp(b + p, LEN_MARKER, LEN_MARKER_SIZE) != 0)
        return 0;
    p = skip_spaces(b, p + LEN_MARKER_SIZE, n);
    if (p >= n)
        return more;
    if (b[p++] != ':')
        return 0;
    p = skip_spaces(b, p, n);
    while (p < n && b[p] >= '0' && b[p] <= '9' && digits < 9) {
        value = value * 10 + (b[p++] - '0');
        digits++;
    }
    if (p >= n)
        return more;
    if (digits == 0 || (b[p] != ',' && b[p] != '}' && !is_space(b[p])))
        return 0;
    return value;
}

/* Does the byte '{' at b[0] open a "len" header? 1 yes, 0 no, -1 undecided. */
static int opens_len_header(const char *b, size_t n)
{
    long len = parse_len_header(b, n);
    return len < 0 ? -1 : len > 0;
}

/*
 * Advances the brace scanner over one byte. Returns true when the byte
 * closes the outermost object.
 */
static bool scan_byte(struct framer_scanner *s, char c)
{
    if (s->in_string) {
        if (s->escaped)
            s->escaped = false;
        else if (c == '\\')
            s->escaped = true;
        else if (c == '"')
            s->in_string = false;
        return false;
    }
    if (c == '"')
        s->in_string = true;
    else if (c == '{' || c == '[')
        s->depth++;
    else if (c == '}' || c == ']')
        return --s->depth == 0;
    return false;
}

/*
 * Bytes that can change the brace scanner's state: outside strings a quote
 * or a brace or bracket, inside one a quote or a backslash. Every other
 * byte is skipped in bulk (skip_plain), which is most of a document.
 */
enum { SPECIAL_OUTSIDE = 1, SPECIAL_INSIDE = 2 };
static const uint8_t special[256] = {
    ['"'] = SPECIAL_OUTSIDE | SPECIAL_INSIDE, ['\\'] = SPECIAL_INSIDE,
    ['{'] = SPECIAL_OUTSIDE, ['}'] = SPECIAL_OUTSIDE,
    ['['] = SPECIAL_OUTSIDE, [']'] = SPECIAL_OUTSIDE,
};

#define ONES UINT64_C(0x0101010101010101)
#define HIGHS UINT64_C(0x8080808080808080)

/* Non-zero when a byte of 'w' equals 'c' (exact for whether, not where). */
static uint64_t has_byte(uint64_t w, uint8_t c)
{
    uint64_t x = w ^ (ONES * c);
    return (x - ONES) & ~x & HIGHS;
}

/*
 * Might the 8-byte word hold a byte that acts outside strings? Braces and
 * brackets are 0x5B-0x7D: any byte with bit 6 or 7 set is looked at, and
 * the quote exactly. A false alarm (a letter of true, false, null or an
 * exponent) is settled by the byte loop; numbers, commas and spaces, most
 * of a status document, pass 8 at a time.
 */
static bool word_may_act_outside(uint64_t w)
{
    return ((w & (ONES * 0xC0)) | has_byte(w, '"')) != 0;
}

static bool word_may_act_inside(uint64_t w)
{
    return (has_byte(w, '"') | has_byte(w, '\\')) != 0;
}

/*
 * The first byte at or after 'p' (before 'limit') that scan_byte() would
 * act on, or 'limit'. Eight bytes at a time while none of them can be one.
 */
static size_t skip_plain(const struct framer_scanner *s, const char *b, size_t p, size_t limit)
{
    uint64_t w;

    if (s->escaped)
        return p; /* the next byte is taken whatever it is */
    if (s->in_string) {
        for (; limit - p >= sizeof(w); p += sizeof(w)) {
            memcpy(&w, b + p, sizeof(w));
            if (word_may_act_inside(w))
                break;
        }
        while (p < limit && !(special[(uint8_t)b[p]] & SPECIAL_INSIDE))
            p++;
        return p;
    }
    for (; limit - p >= sizeof(w); p += sizeof(w)) {
        memcpy(&w, b + p, sizeof(w));
        if (!word_may_act_outside(w))
            continue;
        /* Settle the word here: a false alarm must not end the skip. */
        for (size_t i = 0; i < sizeof(w); i++)
            if (special[(uint8_t)b[p + i]] & SPECIAL_OUTSIDE)
                return p + i;
    }
    while (p < limit && !(special[(uint8_t)b[p]] & SPECIAL_OUTSIDE))
        p++;
    return p;
}

/* Is b[0, n) one balanced object that closes exactly at its last byte? */
static bool is_whole_object(const char *b, size_t n)
{
    struct framer_scanner s = {0};

    for (size_t i = skip_plain(&s, b, 0, n); i < n; i = skip_plain(&s, b, i, n))
        if (scan_byte(&s, b[i++]))
            return i == n;
    return false;
}

/* Skips to the next object start; returns false when more bytes are needed. */
static bool seek_object(struct framer *f)
{
    size_t p = 0;
    bool need_more = false;

    while (p < f->used) {
        char c = f->buf[p];
        if (c == '{') {
            /* After trouble, only a '{"len"' restarts a stream that has them:
             * any other '{' may open an object nested in a lost document. */
            bool strict = f->stream_has_len && (f->resync || f->in_garbage);
            int opens = strict ? opens_len_header(f->buf + p, f->used - p) : 1;
            if (opens < 0) {
                need_more = true;
                break;
            }
            if (opens > 0)
                break;
        }
        if (!is_space(c) || f->in_garbage) {
            if (!f->in_garbage) {
                f->in_garbage = true;
                f->stats.garbage_runs++;
            }
            f->stats.garbage_bytes++;
        }
        p++;
    }
    if (p > 0) {
        if (f->in_garbage)
            emit(f, FRAMER_EVENT_GARBAGE, f->buf, p);
        consume(f, p);
    }
    if (need_more || f->used == 0)
        return false;
    f->in_garbage = false;
    start_object(f);
    return true;
}

/*
 * Tests the '{' at buf[at], inside the current object, as the start of a
 * new document: one whose "len" header frames a whole object exactly. With
 * 'prefix_held', the current object's bytes before 'at' are still in the
 * buffer, so a document that could not fit after them is left to be judged
 * once the current object is dropped as oversize.
 */
static enum restart test_restart(const struct framer *f, size_t at, bool prefix_held)
{
    long len = parse_len_header(f->buf + at, f->used - at);

    if (len < 0)
        return RESTART_PENDING;
    if ((size_t)len < 2 || (size_t)len > f->max_object)
        return RESTART_NONE;
    if (prefix_held && (size_t)len > f->max_object - at)
        return RESTART_NONE;
    if (f->used - at < (size_t)len)
        return RESTART_PENDING;
    if (f->buf[at + (size_t)len - 1] == '}' && is_whole_object(f->buf + at, (size_t)len))
        return RESTART_CUT_SHORT;
    return RESTART_NONE;
}

/*
 * Looks for a document starting inside the current object, before 'limit'.
 * Stops at the first '{' that is not plain content, setting *at.
 */
static enum restart find_restart(struct framer *f, size_t limit, bool prefix_held,
                                 size_t *at)
{
    if (!f->stream_has_len) {
        f->restart_scan = limit;
        return RESTART_NONE;
    }
    for (; f->restart_scan < limit; f->restart_scan++) {
        const char *brace = memchr(f->buf + f->restart_scan, '{', limit - f->restart_scan);
        if (!brace) {
            f->restart_scan = limit;
            break;
        }
        f->restart_scan = (size_t)(brace - f->buf);
        enum restart r = test_restart(f, f->restart_scan, prefix_held);
        if (r != RESTART_NONE) {
            *at = f->restart_scan;
            return r;
        }
    }
    return RESTART_NONE;
}

/* Decides the current object's "len" from its first bytes. */
static bool check_header(struct framer *f)
{
    long len = parse_len_header(f->buf, f->used);

    if (len < 0)
        return false;
    f->header_checked = true;
    if (len > 0) {
        f->stream_has_len = true;
        f->expect_len = (size_t)len;
        /* A "len" that cannot be right leaves the end to the brace scanner. */
        f->len_failed = (size_t)len < 2 || (size_t)len > f->max_object;
    }
    return true;
}

/* Runs the brace scanner up to 'limit'; returns where it closed the object, or 0. */
static size_t scan_to_end(struct framer *f, size_t limit)
{
    while (!f->end && f->scan.pos < limit) {
        f->scan.pos = skip_plain(&f->scan, f->buf, f->scan.pos, limit);
        if (f->scan.pos < limit && scan_byte(&f->scan, f->buf[f->scan.pos++]))
            f->end = f->scan.pos;
    }
    return f->end;
}

/*
 * Does a "len" header follow buf[pos] (after white space)? 1 yes, 0 no, -1
 * when more bytes are needed; a header cut by a full buffer counts as no.
 */
static int document_follows(const struct framer *f, size_t pos)
{
    size_t p = skip_spaces(f->buf, pos, f->used);
    bool full = f->used == f->max_object;
    int opens = p < f->used ? (f->buf[p] == '{' ? opens_len_header(f->buf + p, f->used - p) : 0)
                            : -1;
    return opens < 0 && full ? 0 : opens;
}

static size_t min_size(size_t a, size_t b)
{
    return a < b ? a : b;
}

/*
 * Decides where the current object ends; 0 while unknown. Without a usable
 * "len", where the brace scanner closes it. With one: where the brace
 * scanner closes it if that is before "len" and a "len" header follows
 * there (the object's "len" was too large); else at "len" if a '}' stands
 * there; else where the brace scanner closes it. Whatever the end turns
 * out to be, the object surely extends to '*inside'.
 */
static size_t decide_end(struct framer *f, size_t *inside)
{
    size_t braces = scan_to_end(f, f->used);
    size_t len = f->expect_len;
    bool by_len = len && !f->len_failed;

    *inside = braces ? braces : f->used;
    if (braces && by_len && braces == len)
        return len; /* the usual case: both agree */
    if (by_len && f->used >= len && f->buf[len - 1] != '}') {
        f->len_failed = true; /* settled: "len" is wrong */
        by_len = false;
    }
    if (!by_len)
        return braces;
    if (braces && braces < len) {
        int follows = document_follows(f, braces);
        if (follows > 0)
            return braces;
        if (follows < 0)
            return 0;
    }
    if (f->used < len) {
        *inside = min_size(*inside, len);
        return 0;
    }
    *inside = len;
    return len;
}

static void finish_object(struct framer *f, size_t size)
{
    f->stats.objects++;
    f->resync = false;
    if (f->expect_len && f->expect_len != size) {
        f->stats.len_mismatch++;
        emit(f, FRAMER_EVENT_LEN_MISMATCH, f->buf, size);
    }
    emit(f, FRAMER_EVENT_OBJECT, f->buf, size);
    consume(f, size);
    start_seek(f);
}

/* A new document begins at 'at': drops what came before and restarts there. */
static void restart_at(struct framer *f, size_t at, bool report)
{
    if (report) {
        f->stats.truncated++;
        emit(f, FRAMER_EVENT_TRUNCATED, f->buf, at);
    }
    consume(f, at);
    start_object(f);
    f->resync = true;
}

/* Drops the object as too large, keeping buf[keep_from...) to judge next. */
static void drop_oversize(struct framer *f, size_t keep_from)
{
    f->stats.oversize++;
    emit(f, FRAMER_EVENT_OVERSIZE, f->buf, keep_from);
    f->state = FRAMER_DISCARD;
    f->resync = true;
    f->discarded = keep_from;
    consume(f, keep_from);
    f->restart_scan = 0;
    f->end = 0;
}

/*
 * Frames the object at buf[0]; returns false when more bytes are needed.
 * Each decision waits until the bytes that settle it are there, so the
 * objects reported do not depend on how TCP split the stream.
 */
static bool scan_object(struct framer *f)
{
    size_t at = 0, inside = 0;

    if (!f->header_checked && !check_header(f))
        return false; /* fewer than FRAMER_HEADER_MAX bytes held */
    size_t end = decide_end(f, &inside);
    switch (find_restart(f, end ? end : inside, true, &at)) {
    case RESTART_CUT_SHORT:
        restart_at(f, at, true);
        return true;
    case RESTART_PENDING:
        if (f->used < f->max_object)
            return false;
        /* Full, with a header cut at the end: the object is too large. */
        drop_oversize(f, at);
        return true;
    case RESTART_NONE:
        break;
    }
    if (end) {
        finish_object(f, end);
        return true;
    }
    if (f->used < f->max_object)
        return false;
    drop_oversize(f, f->used);
    return true;
}

/*
 * Skips the rest of a dropped object; returns false when more are needed.
 * At most 4 x max_object bytes are skipped, counted to the byte, before
 * the structure is taken as lost and the next document is sought.
 */
static bool discard_object(struct framer *f)
{
    uint64_t cap = 4 * (uint64_t)f->max_object;
    size_t limit = f->used;
    size_t at = 0;

    if (cap - f->discarded < limit)
        limit = (size_t)(cap - f->discarded);
    size_t end = scan_to_end(f, limit);
    enum restart r = find_restart(f, end ? end : limit, false, &at);
    if (r == RESTART_CUT_SHORT) {
        f->discarded += at;
        restart_at(f, at, false);
        return true;
    }
    if (r == RESTART_NONE && end) {
        consume(f, end);
        start_seek(f);
        return true;
    }
    /* Keep only the bytes an undecided '{' needs. */
    size_t keep_from = r == RESTART_PENDING ? at : limit;
    f->discarded += keep_from;
    consume(f, keep_from);
    if (f->discarded >= cap) {
        /* The structure is lost; look for the next document from here on. */
        start_seek(f);
        return true;
    }
    return false;
}

static void process(struct framer *f)
{
    bool progress = true;

    while (progress && !stop_requested(f)) {
        switch (f->state) {
        case FRAMER_SEEK:
            progress = seek_object(f);
            break;
        case FRAMER_OBJECT:
            progress = scan_object(f);
            break;
        case FRAMER_DISCARD:
            progress = discard_object(f);
            break;
        }
    }
}

/* Carries out a reset or free asked for from a callback. */
static bool apply_pending(struct framer *f)
{
    if (f->free_pending) {
        f->free_pending = f->reset_pending = false;
        framer_free(f);
        return true;
    }
    if (f->reset_pending) {
        f->reset_pending = false;
        framer_reset(f);
        return true;
    }
    return false;
}

void framer_feed(struct framer *f, const char *data, size_t size)
{
    while (size > 0 && f->buf) {
        size_t room = f->max_object - f->used;
        size_t n = size < room ? size : room;
        memcpy(f->buf + f->used, data, n);
        f->used += n;
        data += n;
        size -= n;
        process(f);
        if (apply_pending(f))
            return;
        /* Each step above leaves room; this guards the loop regardless. */
        if (f->used == f->max_object)
            drop_oversize(f, f->used);
    }
}
