/* SPDX-License-Identifier: MIT */
/* status.c - parse a JAKA status document into struct jaka_status. */
#include "status.h"

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
 * Follows the path steps in [p, end) from 'node': ".key", "key" (at the
 * start) and "[n]". Returns NULL when a step does not exist or has the wrong
 * type; a '*' never reaches here.
 */
static const cJSON *follow_steps(const cJSON *node, const char *p,
                                 const char *end)
{
    char key[64];

    while (node && p < end) {
        if (*p == '[') {
            char *after;
            long n = strtol(p + 1, &after, 10);
            if (!cJSON_IsArray(node) || *after != ']' || n < 0)
                return NULL;
            node = cJSON_GetArrayItem(node, (int)n);
            p = after + 1;
        } else {
            size_t len;
            if (*p == '.')
                p++;
            len = strcspn(p, ".[");
            if (p + len > end)
                len = (size_t)(end - p);
            if (len == 0 || len >= sizeof(key) || !cJSON_IsObject(node))
                return NULL;
            memcpy(key, p, len);
            key[len] = '\0';
            node = cJSON_GetObjectItemCaseSensitive(node, key);
            p += len;
        }
    }
    return node;
}

/* Reads a JSON value as a finite number: numbers, booleans, numeric text. */
static bool read_number(const cJSON *item, double *out)
{
    if (cJSON_IsBool(item)) {
        *out = cJSON_IsTrue(item) ? 1.0 : 0.0;
        return true;
    }
    if (cJSON_IsNumber(item)) {
        *out = item->valuedouble;
        return isfinite(*out);
    }
    if (cJSON_IsString(item) && item->valuestring[0] != '\0') {
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

static void parse_field(struct jaka_status *s, enum status_field id,
                        const cJSON *root)
{
    const struct status_field_info *f = &status_fields[id];
    const char *star = strchr(f->path, '*');
    const char *path_end = f->path + strlen(f->path);
    uint16_t carried = 0;

    if (!star) {
        const cJSON *item = follow_steps(root, f->path, path_end);
        if (item && store_element(s, f, 0, item))
            carried = 1;
        s->count[id] = carried;
        return;
    }

    /* Walk the array once: cJSON arrays are linked lists. */
    const cJSON *array = follow_steps(root, f->path, star - 1);
    const char *suffix = star + 2; /* past "*]" */
    if (cJSON_IsArray(array)) {
        const cJSON *child = array->child;
        for (unsigned i = 0; child && i < f->first; i++)
            child = child->next;
        for (unsigned i = 0; child && i < f->capacity; i++, child = child->next) {
            const cJSON *item = follow_steps(child, suffix, path_end);
            /* Count what the document carried, even if of the wrong type. */
            if (item)
                carried = (uint16_t)(i + 1);
            if (item)
                store_element(s, f, i, item);
        }
    }
    s->count[id] = carried;
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

int status_parse(struct jaka_status *out, const char *json, size_t size)
{
    cJSON *root;

    memset(out, 0, sizeof(*out));
    root = cJSON_ParseWithLength(json, size);
    if (!root)
        return STATUS_PARSE_BAD_JSON;
    if (!cJSON_IsObject(root)) {
        cJSON_Delete(root);
        return STATUS_PARSE_NOT_OBJECT;
    }
    for (int id = 0; id < STATUS_FIELD_COUNT; id++)
        parse_field(out, (enum status_field)id, root);
    /* The manual's overview spells "task mode" with a space. */
    if (!out->task_mode[0].present) {
        const cJSON *alt = cJSON_GetObjectItemCaseSensitive(root, "task mode");
        if (alt && store_element(out, &status_fields[STATUS_F_task_mode], 0, alt))
            out->count[STATUS_F_task_mode] = 1;
    }
    normalise_errcode(&out->errcode[0]);
    cJSON_Delete(root);
    return STATUS_PARSE_OK;
}
