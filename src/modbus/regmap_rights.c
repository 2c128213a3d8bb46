/* SPDX-License-Identifier: MIT */
/* regmap_rights.c - write classes and rights (regmap.h). */
#include "regmap.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

const char *const regmap_write_class_names[REGMAP_CLASS_COUNT] = {
    [REGMAP_CLASS_NONE] = "",
#define REGMAP_CLASS_NAME(id, name) [REGMAP_CLASS_##id] = #name,
    REGMAP_WRITE_CLASSES(REGMAP_CLASS_NAME)
#undef REGMAP_CLASS_NAME
};

int regmap_parse_rights(const char *text, uint32_t *rights, char *why, size_t why_size)
{
    char list[256];
    uint32_t out = 0;

    if (strcasecmp(text, "read") == 0) {
        *rights = REGMAP_RIGHTS_NONE;
        return 0;
    }
    if (strcasecmp(text, "write") == 0) {
        *rights = REGMAP_RIGHTS_ALL;
        return 0;
    }
    if (strlen(text) >= sizeof(list)) {
        snprintf(why, why_size, "too long");
        return -EINVAL;
    }
    snprintf(list, sizeof(list), "%s", text);
    for (char *save = NULL, *word = strtok_r(list, ", \t", &save); word;
         word = strtok_r(NULL, ", \t", &save)) {
        unsigned cls;
        for (cls = 1; cls < REGMAP_CLASS_COUNT; cls++)
            if (strcasecmp(word, regmap_write_class_names[cls]) == 0)
                break;
        if (cls == REGMAP_CLASS_COUNT) {
            char names[200] = "";
            for (unsigned i = 1; i < REGMAP_CLASS_COUNT; i++)
                snprintf(names + strlen(names), sizeof(names) - strlen(names), "%s%s",
                         i > 1 ? ", " : "", regmap_write_class_names[i]);
            snprintf(why, why_size,
                     "'%.40s' is not a write class: read, write, or a list of %s", word,
                     names);
            return -EINVAL;
        }
        out |= REGMAP_RIGHT(cls);
    }
    if (out == 0) {
        snprintf(why, why_size, "empty: read, write, or a list of write classes");
        return -EINVAL;
    }
    *rights = out;
    return 0;
}

void regmap_format_rights(uint32_t rights, char *out, size_t size)
{
    uint32_t every = 0;

    for (unsigned cls = 1; cls < REGMAP_CLASS_COUNT; cls++)
        every |= REGMAP_RIGHT(cls);
    if ((rights & every) == every) {
        snprintf(out, size, "write");
        return;
    }
    if ((rights & every) == 0) {
        snprintf(out, size, "read");
        return;
    }
    out[0] = '\0';
    for (unsigned cls = 1; cls < REGMAP_CLASS_COUNT; cls++)
        if (rights & REGMAP_RIGHT(cls))
            snprintf(out + strlen(out), size - strlen(out), "%s%s", out[0] ? ", " : "",
                     regmap_write_class_names[cls]);
}

int regmap_write_allowed(const struct regmap *map, enum regmap_table table,
                         unsigned address, unsigned count, uint32_t rights)
{
    if (rights == REGMAP_RIGHTS_ALL)
        return 0;
    if (table >= REGMAP_TABLE_COUNT)
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    for (unsigned a = address; a < address + count && a < map->size[table]; a++) {
        const struct regmap_row *row = map->owner[table][a];
        if (row && row->writable && !(rights & REGMAP_RIGHT(row->write_class)))
            return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    return 0;
}
