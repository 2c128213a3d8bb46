/* framer.c - see framer.h. */
#include "framer.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

/* How many bytes after '{' decide whether it opens a "len" header. */
#define LEN_MARKER "\"len\""
#define LEN_MARKER_SIZE (sizeof(LEN_MARKER) - 1)

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
    free(f->buf);
    f->buf = NULL;
}

static void start_seek(struct framer *f)
{
    f->state = FRAMER_SEEK;
    f->depth = 0;
    f->in_string = false;
    f->escaped = false;
    f->expect_len = 0;
    f->header_checked = false;
}

void framer_reset(struct framer *f)
{
    f->used = 0;
    f->scan = 0;
    f->in_garbage = false;
    f->resync = false;
    start_seek(f);
}

static void consume(struct framer *f, size_t n)
{
    memmove(f->buf, f->buf + n, f->used - n);
    f->used -= n;
    f->scan = f->scan > n ? f->scan - n : 0;
}

static void emit(struct framer *f, enum framer_event ev, const char *d, size_t n)
{
    f->cb(f->user, ev, d, n);
}

static bool is_space(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\n';
}

/*
 * Is buf[at] a '{' opening a "len" header? Returns 1 yes, 0 no, -1 when
 * more bytes are needed to tell.
 */
static int opens_len_header(const struct framer *f, size_t at)
{
    size_t p = at + 1;

    while (p < f->used && is_space(f->buf[p]))
        p++;
    size_t have = f->used - p;
    if (have >= LEN_MARKER_SIZE)
        return memcmp(f->buf + p, LEN_MARKER, LEN_MARKER_SIZE) == 0;
    /* Undecided only while every byte so far matches the marker. */
    if (memcmp(f->buf + p, LEN_MARKER, have) != 0 || f->used - at > 64)
        return 0;
    return -1;
}

/*
 * Reads the "len" value of the object at buf[0]. Returns the value, 0 when
 * the object has no usable "len" header, or -1 when more bytes are needed.
 */
static long read_len_header(const struct framer *f)
{
    size_t p = 1;
    long value = 0;
    int digits = 0;

    int opens = opens_len_header(f, 0);
    if (opens <= 0)
        return opens;
    while (f->buf[p] != '"')
        p++;
    p += LEN_MARKER_SIZE;
    while (p < f->used && is_space(f->buf[p]))
        p++;
    if (p >= f->used)
        return -1;
    if (f->buf[p++] != ':')
        return 0;
    while (p < f->used && is_space(f->buf[p]))
        p++;
    while (p < f->used && f->buf[p] >= '0' && f->buf[p] <= '9' && digits < 9) {
        value = value * 10 + (f->buf[p++] - '0');
        digits++;
    }
    if (p >= f->used)
        return -1;
    if (digits == 0 || (f->buf[p] != ',' && f->buf[p] != '}' && !is_space(f->buf[p])))
        return 0;
    return value;
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
            int opens = strict ? opens_len_header(f, p) : 1;
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
        bool garbage = f->in_garbage;
        if (garbage)
            emit(f, FRAMER_EVENT_GARBAGE, f->buf, p);
        consume(f, p);
    }
    if (need_more || f->used == 0)
        return false;
    f->in_garbage = false;
    f->state = FRAMER_OBJECT;
    f->scan = 0;
    f->depth = 0;
    f->in_string = false;
    f->escaped = false;
    f->header_checked = false;
    f->expect_len = 0;
    return true;
}

/* A new document begins at 'at': drops what came before and restarts there. */
static void restart_at(struct framer *f, size_t at, bool report)
{
    if (report) {
        f->stats.truncated++;
        emit(f, FRAMER_EVENT_TRUNCATED, f->buf, at);
    }
    consume(f, at);
    start_seek(f);
    f->resync = true;
}

static void finish_object(struct framer *f, size_t size)
{
    f->stats.objects++;
    f->resync = false;
    emit(f, FRAMER_EVENT_OBJECT, f->buf, size);
    consume(f, size);
    start_seek(f);
}

/*
 * Advances the brace scanner over one byte. Returns true when the byte
 * closes the outermost object.
 */
static bool scan_byte(struct framer *f, char c)
{
    if (f->in_string) {
        if (f->escaped)
            f->escaped = false;
        else if (c == '\\')
            f->escaped = true;
        else if (c == '"')
            f->in_string = false;
        return false;
    }
    if (c == '"')
        f->in_string = true;
    else if (c == '{' || c == '[')
        f->depth++;
    else if (c == '}' || c == ']')
        return --f->depth == 0;
    return false;
}

/* Is buf[0, n) exactly one balanced object, by the brace scanner? */
static bool is_whole_object(const char *buf, size_t n)
{
    int depth = 0;
    bool in_string = false, escaped = false;

    for (size_t i = 0; i < n; i++) {
        char c = buf[i];
        if (in_string) {
            if (escaped)
                escaped = false;
            else if (c == '\\')
                escaped = true;
            else if (c == '"')
                in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '{' || c == '[') {
            depth++;
        } else if ((c == '}' || c == ']') && --depth == 0) {
            return i + 1 == n || buf[i + 1] == ' ' || buf[i + 1] == '\n' ||
                   buf[i + 1] == '\r' || buf[i + 1] == '\t';
        }
    }
    return false;
}

/*
 * Frames an object that declares its length: a '}' where "len" says the
 * object ends confirms it (the JSON parser judges the content). A new
 * '{"len"' before that point means this object was cut short; it is found
 * by a raw search, because a cut inside a string fools a brace scanner.
 * Returns 1 when done with this object, 0 when more bytes are needed, -1
 * when "len" proved wrong and the brace scanner must decide.
 */
static int frame_by_len(struct framer *f)
{
    size_t k = f->scan > 0 ? f->scan : 1;

    for (; k < f->used && k < f->expect_len; k++) {
        if (f->buf[k] != '{')
            continue;
        int opens = opens_len_header(f, k);
        if (opens < 0) {
            f->scan = k;
            return 0;
        }
        if (opens > 0) {
            size_t end = k;
            while (end > 0 && is_space(f->buf[end - 1]))
                end--;
            if (is_whole_object(f->buf, end)) {
                /* Complete, only its "len" was wrong. */
                f->stats.len_mismatch++;
                emit(f, FRAMER_EVENT_LEN_MISMATCH, f->buf, end);
                finish_object(f, end);
                return 1;
            }
            restart_at(f, k, true);
            return 1;
        }
    }
    f->scan = k;
    if (f->used < f->expect_len)
        return 0;
    if (f->buf[f->expect_len - 1] == '}') {
        finish_object(f, f->expect_len);
        return 1;
    }
    f->stats.len_mismatch++;
    emit(f, FRAMER_EVENT_LEN_MISMATCH, f->buf, f->expect_len);
    f->expect_len = 0;
    f->scan = 0;
    return -1;
}

/* Scans the current object; returns false when more bytes are needed. */
static bool scan_object(struct framer *f)
{
    if (!f->header_checked) {
        long len = read_len_header(f);
        if (len < 0)
            return false;
        f->header_checked = true;
        if (len > 0) {
            f->stream_has_len = true;
            if ((size_t)len >= 2 && (size_t)len <= f->max_object)
                f->expect_len = (size_t)len;
        }
    }
    if (f->expect_len) {
        int done = frame_by_len(f);
        if (done >= 0)
            return done == 1;
    }
    while (f->scan < f->used) {
        size_t at = f->scan;
        char c = f->buf[at];

        if (c == '{' && f->depth > 0 && !f->in_string && f->stream_has_len) {
            int opens = opens_len_header(f, at);
            if (opens < 0)
                break;
            if (opens > 0) {
                /* A new document began before this one ended. */
                restart_at(f, at, true);
                return true;
            }
        }
        f->scan++;
        if (scan_byte(f, c)) {
            finish_object(f, at + 1);
            return true;
        }
    }
    if (f->used == f->max_object) {
        f->stats.oversize++;
        emit(f, FRAMER_EVENT_OVERSIZE, f->buf, f->used);
        f->state = FRAMER_DISCARD;
        f->resync = true;
        f->discarded = f->used;
        f->used = 0;
        f->scan = 0;
    }
    return false;
}

/* Skips the rest of a dropped object; returns false when more are needed. */
static bool discard_object(struct framer *f)
{
    while (f->scan < f->used) {
        size_t at = f->scan;
        char c = f->buf[at];
        if (c == '{' && f->depth > 0 && !f->in_string && f->stream_has_len) {
            int opens = opens_len_header(f, at);
            if (opens < 0)
                break;
            if (opens > 0) {
                restart_at(f, at, false);
                return true;
            }
        }
        f->scan++;
        if (scan_byte(f, c)) {
            consume(f, f->scan);
            start_seek(f);
            return true;
        }
    }
    /* Keep only what an undecided lookahead needs. */
    f->discarded += f->scan;
    consume(f, f->scan);
    if (f->discarded > 4 * f->max_object) {
        /* The structure is lost; look for the next object from here on. */
        start_seek(f);
        return true;
    }
    return false;
}

static void process(struct framer *f)
{
    bool progress = true;

    while (progress) {
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

void framer_feed(struct framer *f, const char *data, size_t size)
{
    while (size > 0) {
        size_t room = f->max_object - f->used;
        size_t n = size < room ? size : room;
        memcpy(f->buf + f->used, data, n);
        f->used += n;
        data += n;
        size -= n;
        process(f);
    }
}
