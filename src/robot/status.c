/* SPDX-License-Identifier: MIT */
/* status.c - parse a JAKA status document into struct jaka_status. */
#include "status.h"

#include "json_arena.h"

#include <cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const struct status_field_info status_fields[STATUS_FIELD_COUNT] = {
#define STATUS_INFO_NUM(n, p, f, c)                                            \
    [STATUS_F_##n] = {#n, p, STATUS_KIND_NUM, f, c, 0,                         \
                      offsetof(struct jaka_status, n)},
#define STATUS_INFO_STR(n, p, f, c, size)                                      \
    [STATUS_F_##n] = {#n, p, STATUS_KIND_STR, f, c, size,                      \
                      offsetof(struct jaka_status, n)},
    JAKA_STATUS_NUM_FIELDS(STATUS_INFO_NUM)
    JAKA_STATUS_STR_FIELDS(STATUS_INFO_STR)
#undef STATUS_INFO_NUM
#undef STATUS_INFO_STR
};

const struct status_num *status_num_at(const struct jaka_status *s,
                                       enum status_field field, unsigned index)
{
    const struct status_field_info *f = &status_fields[field];
    const struct status_num *base =
        (const struct status_num *)((const char *)s + f->offset);
    return &base[index];
}

const struct status_str *status_str_at(const struct jaka_status *s,
                                       enum status_field field, unsigned index)
{
    const struct status_field_info *f = &status_fields[field];
    const struct status_str *base =
        (const struct status_str *)((const char *)s + f->offset);
    return &base[index];
}

int status_element_path(enum status_field field, unsigned index, char *buf,
                        size_t size)
{
    const struct status_field_info *f = &status_fields[field];
    const char *star = strchr(f->path, '*');

    if (!star)
        return snprintf(buf, size, "%s", f->path);
    return snprintf(buf, size, "%.*s%u%s", (int)(star - f->path), f->path,
                    f->first + index, star + 1);
}

/*
 * The paths, compiled once into steps, and grouped by their first key: the
 * parser walks the document's top-level members once and hands each one to
 * the fields whose path starts with its name, instead of looking every
 * field's path up from the root (cJSON objects are linked lists, and a
 * lookup is a strcmp per member).
 */
enum step_kind { STEP_KEY, STEP_INDEX, STEP_STAR };

struct path_step {
    enum step_kind kind;
    unsigned index;  /* STEP_INDEX */
    const char *key; /* STEP_KEY, NUL-terminated */
};

#define MAX_STEPS 8
#define KEY_POOL_SIZE 4096

struct compiled_path {
    struct path_step steps[MAX_STEPS];
    unsigned count;
    unsigned star; /* the index of the STEP_STAR, or count when none */
    bool ok;
};

/* A top-level key and the fields whose path starts with it. */
_Static_assert(STATUS_FIELD_COUNT <= 256, "field ids are kept in a uint8_t");
struct root_key {
    const char *key;
    uint8_t fields[32];
    unsigned field_count;
};

struct path_table {
    bool ready;
    struct compiled_path paths[STATUS_FIELD_COUNT];
    struct root_key roots[STATUS_FIELD_COUNT]; /* sorted by key */
    unsigned root_count;
    char key_pool[KEY_POOL_SIZE];
    size_t key_pool_used;
};

/* Built from status_fields at the first parse; read-only after. */
static struct path_table table;

static const char *pool_key(const char *p, size_t len)
{
    if (len == 0 || table.key_pool_used + len + 1 > sizeof(table.key_pool))
        return NULL;
    char *k = table.key_pool + table.key_pool_used;
    memcpy(k, p, len);
    k[len] = '\0';
    table.key_pool_used += len + 1;
    return k;
}

/* "extio.setup[*][2][1]": key extio, key setup, star, index 2, index 1. */
static bool compile_path(const char *p, struct compiled_path *out)
{
    out->count = 0;
    out->star = MAX_STEPS;
    while (*p) {
        if (out->count == MAX_STEPS)
            return false;
        struct path_step *step = &out->steps[out->count];
        if (*p == '[') {
            char *after;
            if (p[1] == '*' && p[2] == ']') {
                if (out->star != MAX_STEPS)
                    return false;
                step->kind = STEP_STAR;
                out->star = out->count;
                p += 3;
            } else {
                long n = strtol(p + 1, &after, 10);
                if (after == p + 1 || *after != ']' || n < 0 || n > 65535)
                    return false;
                step->kind = STEP_INDEX;
                step->index = (unsigned)n;
                p = after + 1;
            }
        } else {
            if (*p == '.' && out->count > 0)
                p++;
            size_t len = strcspn(p, ".[");
            step->kind = STEP_KEY;
            step->key = pool_key(p, len);
            if (!step->key)
                return false;
            p += len;
        }
        out->count++;
    }
    if (out->star == MAX_STEPS)
        out->star = out->count;
    return out->count > 0 && out->steps[0].kind == STEP_KEY;
}

static int compare_roots(const void *a, const void *b)
{
    return strcmp(((const struct root_key *)a)->key, ((const struct root_key *)b)->key);
}

static struct root_key *find_root(const char *key)
{
    struct root_key probe = {.key = key};
    return bsearch(&probe, table.roots, table.root_count, sizeof(table.roots[0]),
                   compare_roots);
}

static void build_table(void)
{
    for (int id = 0; id < STATUS_FIELD_COUNT; id++) {
        struct compiled_path *c = &table.paths[id];
        c->ok = compile_path(status_fields[id].path, c);
        if (!c->ok)
            continue;
        const char *first = c->steps[0].key;
        struct root_key *r = NULL;
        for (unsigned i = 0; i < table.root_count && !r; i++)
            if (strcmp(table.roots[i].key, first) == 0)
                r = &table.roots[i];
        if (!r) {
            r = &table.roots[table.root_count++];
            r->key = first;
        }
        if (r->field_count == sizeof(r->fields) / sizeof(r->fields[0])) {
            c->ok = false; /* test_status checks that every path compiles */
            continue;
        }
        r->fields[r->field_count++] = (uint8_t)id;
    }
    qsort(table.roots, table.root_count, sizeof(table.roots[0]), compare_roots);
    table.ready = true;
}

/*
 * Follows steps [from, to) of a compiled path from 'node'. Returns NULL
 * when a step does not exist or meets the wrong type.
 */
static const cJSON *follow_steps(const cJSON *node, const struct path_step *step,
                                 const struct path_step *end)
{
    for (; node && step < end; step++) {
        if (step->kind == STEP_INDEX) {
            if (!cJSON_IsArray(node))
                return NULL;
            node = node->child;
            for (unsigned i = 0; node && i < step->index; i++)
                node = node->next;
        } else {
            if (!cJSON_IsObject(node))
                return NULL;
            node = cJSON_GetObjectItemCaseSensitive(node, step->key);
        }
    }
    return node;
}

/* Reads a JSON value as a finite number: numbers, booleans, numeric text. */
static bool read_number(const cJSON *item, double *out)
{
    /* cJSON_IsNumber() and friends, without a call into the library each:
     * this runs for every element of a document. */
    int type = item->type & 0xFF;

    if (type == cJSON_Number) {
        *out = item->valuedouble;
        return isfinite(*out);
    }
    if (type == cJSON_True || type == cJSON_False) {
        *out = type == cJSON_True ? 1.0 : 0.0;
        return true;
    }
    if (type == cJSON_String && item->valuestring[0] != '\0') {
        /* Some fields (errcode) come as text, e.g. "0x0"; strtod reads hex. */
        char *end;
        double v = strtod(item->valuestring, &end);
        if (*end != '\0' || !isfinite(v))
            return false;
        *out = v;
        return true;
    }
    return false;
}

static bool read_text(const cJSON *item, char *out, size_t size)
{
    if (cJSON_IsString(item)) {
        snprintf(out, size, "%s", item->valuestring);
        return true;
    }
    if (cJSON_IsNumber(item) && isfinite(item->valuedouble)) {
        /* An RTU module's baud rate stands where a TCP module's IP does. */
        snprintf(out, size, "%.15g", item->valuedouble);
        return true;
    }
    return false;
}

static bool store_element(struct jaka_status *s, const struct status_field_info *f,
                          unsigned index, const cJSON *item)
{
    char *member = (char *)s + f->offset;

    if (f->kind == STATUS_KIND_NUM) {
        struct status_num *n = &((struct status_num *)member)[index];
        n->present = read_number(item, &n->value);
        if (!n->present)
            n->value = 0.0;
        return n->present;
    }
    struct status_str *t = &((struct status_str *)member)[index];
    t->present = read_text(item, t->text, f->str_size);
    if (!t->present)
        t->text[0] = '\0';
    return t->present;
}

/* A plain array of numbers ("din[*]"), the bulk of a document. */
static uint16_t store_numbers(struct status_num *out, const cJSON *child, unsigned capacity)
{
    unsigned i = 0;

    for (; child && i < capacity; i++, child = child->next) {
        out[i].present = read_number(child, &out[i].value);
        if (!out[i].present)
            out[i].value = 0.0;
    }
    return (uint16_t)i;
}

/* Element 'index' of field 'f' in 's', as not present. */
static void clear_element(struct jaka_status *s, const struct status_field_info *f,
                          unsigned index)
{
    char *member = (char *)s + f->offset;

    if (f->kind == STATUS_KIND_NUM)
        ((struct status_num *)member)[index] = (struct status_num){0};
    else
        memset(&((struct status_str *)member)[index], 0, sizeof(struct status_str));
}

/*
 * Stores field 'id' from 'node', the document's top-level member named by
 * the first step of the field's path, and sets its count. Returns how many
 * of the field's first elements it wrote (present or not): status_parse()
 * clears the rest, instead of clearing the whole struct first.
 */
static unsigned parse_field(struct jaka_status *s, enum status_field id, const cJSON *node)
{
    const struct status_field_info *f = &status_fields[id];
    const struct compiled_path *c = &table.paths[id];
    const struct path_step *steps = c->steps, *star = steps + c->star;
    const struct path_step *end = steps + c->count;
    uint16_t carried = 0;
    unsigned written = 0;

    if (star == end) {
        const cJSON *item = follow_steps(node, steps + 1, end);
        if (item && store_element(s, f, 0, item))
            carried = 1;
        else if (!item)
            clear_element(s, f, 0);
        s->count[id] = carried;
        return 1;
    }

    /* Walk the array once: cJSON arrays are linked lists. */
    const cJSON *array = follow_steps(node, steps + 1, star);
    if (cJSON_IsArray(array)) {
        const cJSON *child = array->child;
        for (unsigned i = 0; child && i < f->first; i++)
            child = child->next;
        if (star + 1 == end && f->kind == STATUS_KIND_NUM) {
            carried = store_numbers((struct status_num *)((char *)s + f->offset), child,
                                    f->capacity);
            written = carried;
        } else {
            for (; child && written < f->capacity; written++, child = child->next) {
                const cJSON *item = follow_steps(child, star + 1, end);
                /* Count what the document carried, even if of the wrong type. */
                if (item) {
                    carried = (uint16_t)(written + 1);
                    store_element(s, f, written, item);
                } else {
                    clear_element(s, f, written);
                }
            }
        }
    }
    s->count[id] = carried;
    return written;
}

/* Clears elements [from, capacity) of field 'id': what the document left. */
static void clear_rest(struct jaka_status *s, enum status_field id, unsigned from)
{
    const struct status_field_info *f = &status_fields[id];
    size_t size = f->kind == STATUS_KIND_NUM ? sizeof(struct status_num) : sizeof(struct status_str);

    if (from < f->capacity)
        memset((char *)s + f->offset + from * size, 0, (f->capacity - from) * size);
}

/* Hands one top-level member to the fields whose path starts with its name. */
static void parse_member(struct jaka_status *s, const cJSON *member, uint64_t *seen,
                         uint16_t *written, const cJSON **task_mode_alt)
{
    const struct root_key *r = member->string ? find_root(member->string) : NULL;

    if (!r) {
        /* The manual's overview spells "task mode" with a space. */
        if (!*task_mode_alt && member->string && strcmp(member->string, "task mode") == 0)
            *task_mode_alt = member;
        return;
    }
    /* As a lookup by name would, take the first member of a name only. */
    unsigned k = (unsigned)(r - table.roots);
    if (seen[k / 64] & (UINT64_C(1) << (k % 64)))
        return;
    seen[k / 64] |= UINT64_C(1) << (k % 64);
    for (unsigned i = 0; i < r->field_count; i++) {
        enum status_field id = (enum status_field)r->fields[i];
        written[id] = (uint16_t)parse_field(s, id, member);
    }
}

/* errcode is a 32-bit pattern: "-1" means 0xffffffff, not a clamp to 0. */
static void normalise_errcode(struct status_num *errcode)
{
    if (!errcode->present)
        return;
    double v = errcode->value;
    if (v < 0 && v >= -2147483648.0)
        v += 4294967296.0;
    if (v < 0 || v > 4294967295.0 || v != floor(v)) {
        errcode->present = false;
        errcode->value = 0;
        return;
    }
    errcode->value = v;
}

/*
 * The tree of the document being read: cJSON's nodes come from this arena
 * (json_arena.h), one per process as cJSON's hooks are. Nothing of the tree
 * outlives status_parse(): numbers and text are copied into 'out'.
 */
static struct json_arena arena;

int status_parse(struct jaka_status *out, const char *json, size_t size)
{
    uint64_t seen[(STATUS_FIELD_COUNT + 63) / 64] = {0};
    uint16_t written[STATUS_FIELD_COUNT] = {0};
    const cJSON *task_mode_alt = NULL;

    if (!table.ready)
        build_table();
    const cJSON *root = json_arena_parse(&arena, json, size);
    if (!root || !cJSON_IsObject(root)) {
        memset(out, 0, sizeof(*out));
        json_arena_reset(&arena);
        return root ? STATUS_PARSE_NOT_OBJECT : STATUS_PARSE_BAD_JSON;
    }
    /* Each field writes what the document carries and clears the rest:
     * clearing all 48 KB first cost more than the fields themselves. */
    memset(out->count, 0, sizeof(out->count));
    for (const cJSON *member = root->child; member; member = member->next)
        parse_member(out, member, seen, written, &task_mode_alt);
    for (int id = 0; id < STATUS_FIELD_COUNT; id++)
        clear_rest(out, (enum status_field)id, written[id]);
    if (!out->task_mode[0].present && task_mode_alt &&
        store_element(out, &status_fields[STATUS_F_task_mode], 0, task_mode_alt))
        out->count[STATUS_F_task_mode] = 1;
    normalise_errcode(&out->errcode[0]);
    json_arena_reset(&arena);
    return STATUS_PARSE_OK;
}

void status_parse_release(void)
{
    json_arena_free(&arena);
}

/* ---- marks: the members whose changes are events, without a parse ---- */

static const struct {
    const char *name;
    size_t size;
} mark_members[STATUS_MARK_COUNT] = {
#define STATUS_MARK_ROW(n) {n, sizeof(n) - 1},
    STATUS_MARK_MEMBERS(STATUS_MARK_ROW)
#undef STATUS_MARK_ROW
};

static int mark_of(const char *key, size_t size)
{
    for (int i = 0; i < STATUS_MARK_COUNT; i++)
        if (mark_members[i].size == size && memcmp(mark_members[i].name, key, size) == 0)
            return i;
    return -1;
}

/* FNV-1a of a value's text, never 0 (0 is "absent"). */
static uint64_t hash_text(const char *p, size_t n)
{
    uint64_t h = UINT64_C(0xcbf29ce484222325);
    for (size_t i = 0; i < n; i++)
        h = (h ^ (uint8_t)p[i]) * UINT64_C(0x100000001b3);
    return h ? h : 1;
}

/* The end of the string whose opening quote is at json[p]: after its closing quote. */
static size_t skip_string(const char *json, size_t p, size_t size)
{
    for (p++; p < size; p++) {
        if (json[p] == '\\')
            p++;
        else if (json[p] == '"')
            return p + 1;
    }
    return size;
}

/* The end of the value at json[p]: a string, a scalar or a nested value. */
static size_t skip_value(const char *json, size_t p, size_t size)
{
    int depth = 0;

    while (p < size) {
        char c = json[p];
        if (c == '"') {
            p = skip_string(json, p, size);
            if (depth == 0)
                return p;
            continue;
        }
        if (c == '{' || c == '[') {
            depth++;
        } else if (c == '}' || c == ']') {
            if (depth == 0)
                return p;
            if (--depth == 0)
                return p + 1;
        } else if (depth == 0 && (c == ',' || c == ' ' || c == '\t' || c == '\r' || c == '\n')) {
            return p;
        }
        p++;
    }
    return size;
}

static size_t skip_blanks(const char *json, size_t p, size_t size)
{
    while (p < size && (json[p] == ' ' || json[p] == '\t' || json[p] == '\r' || json[p] == '\n'))
        p++;
    return p;
}

void status_marks_of(const char *json, size_t size, struct status_marks *m)
{
    size_t p = skip_blanks(json, 0, size);

    memset(m, 0, sizeof(*m));
    if (p >= size || json[p] != '{')
        return;
    p++;
    /* Members of the top-level object: "key" : value , ... */
    while (p < size) {
        p = skip_blanks(json, p, size);
        if (p >= size || json[p] != '"')
            return; /* '}' or not JSON: done */
        size_t key = p + 1;
        p = skip_string(json, p, size);
        size_t key_size = p - 1 - key;
        p = skip_blanks(json, p, size);
        if (p >= size || json[p] != ':')
            return;
        p = skip_blanks(json, p + 1, size);
        size_t value = p;
        p = skip_value(json, p, size);
        int mark = mark_of(json + key, key_size);
        if (mark >= 0 && m->value[mark] == 0)
            m->value[mark] = hash_text(json + value, p - value);
        p = skip_blanks(json, p, size);
        if (p >= size || json[p] != ',')
            return;
        p++;
    }
}

bool status_marks_differ(const struct status_marks *a, const struct status_marks *b)
{
    return memcmp(a->value, b->value, sizeof(a->value)) != 0;
}
