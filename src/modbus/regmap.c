/* SPDX-License-Identifier: MIT */
/* regmap.c - build, check, list and encode the register map (regmap.h). */
#include "regmap.h"

#include "log.h"

#include <ctype.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define PRESENCE_BASE 1536 /* discrete inputs: one per status field */
#define COUNT_BASE 3000    /* input registers: one per array field */

const char *const gw_value_names[GW_VALUE_COUNT] = {
#define GW_NAME(name) [GW_##name] = #name,
    GW_VALUES(GW_NAME)
#undef GW_NAME
};

static const char *const table_names[REGMAP_TABLE_COUNT] = {
    [REGMAP_COIL] = "coil",
    [REGMAP_DISCRETE_INPUT] = "discrete_input",
    [REGMAP_INPUT_REGISTER] = "input_register",
    [REGMAP_HOLDING_REGISTER] = "holding_register",
};

/* PLC notation: the table's leading digit, then the address from 1. */
static const unsigned table_plc_base[REGMAP_TABLE_COUNT] = {
    [REGMAP_COIL] = 1,
    [REGMAP_DISCRETE_INPUT] = 10001,
    [REGMAP_INPUT_REGISTER] = 30001,
    [REGMAP_HOLDING_REGISTER] = 40001,
};

static const char *const type_names[] = {
    [REGMAP_BOOL] = "bool", [REGMAP_U16] = "u16", [REGMAP_I16] = "i16",
    [REGMAP_U32] = "u32",   [REGMAP_I32] = "i32", [REGMAP_F32] = "f32",
    [REGMAP_STR] = "str",
};

static bool is_bit_table(enum regmap_table t)
{
    return t == REGMAP_COIL || t == REGMAP_DISCRETE_INPUT;
}

unsigned regmap_element_width(const struct regmap_row *row)
{
    switch (row->type) {
    case REGMAP_BOOL:
    case REGMAP_U16:
    case REGMAP_I16:
        return 1;
    case REGMAP_U32:
    case REGMAP_I32:
    case REGMAP_F32:
        return 2;
    case REGMAP_STR:
        return row->str_regs;
    }
    return 1;
}

unsigned regmap_element_address(const struct regmap_row *row, unsigned i)
{
    unsigned stride = row->stride ? row->stride : regmap_element_width(row);
    return row->address + i * stride;
}

static bool is_array_field(enum status_field id)
{
    return strchr(status_fields[id].path, '*') != NULL;
}

/* Appends the generated rows: presence bits and element counts. */
static unsigned add_generated_rows(struct regmap_row *rows, unsigned n)
{
    for (int id = 0; id < STATUS_FIELD_COUNT; id++) {
        rows[n++] = (struct regmap_row){
            .table = REGMAP_DISCRETE_INPUT, .address = PRESENCE_BASE + id,
            .elements = 1, .type = REGMAP_BOOL, .scale = 1, .unit = "",
            .name = "present_", .description = "The last document carried ",
            .source = REGMAP_SRC_PRESENT, .id = id};
        if (is_array_field((enum status_field)id))
            rows[n++] = (struct regmap_row){
                .table = REGMAP_INPUT_REGISTER, .address = COUNT_BASE + id,
                .elements = 1, .type = REGMAP_U16, .scale = 1, .unit = "",
                .name = "count_",
                .description = "Elements the last document carried of ",
                .source = REGMAP_SRC_COUNT, .id = id};
    }
    return n;
}

static int check_row(const struct regmap_row *row)
{
    bool bits = is_bit_table(row->table);

    if ((row->type == REGMAP_BOOL) != bits)
        return -EINVAL;
    if (row->writable != (row->table == REGMAP_COIL ||
                          row->table == REGMAP_HOLDING_REGISTER))
        return -EINVAL;
    if (row->elements == 0 || (row->type == REGMAP_STR && row->str_regs == 0))
        return -EINVAL;
    if (row->source == REGMAP_SRC_STATUS) {
        const struct status_field_info *f = &status_fields[row->id];
        if (row->index + row->elements > f->capacity)
            return -EINVAL;
        if ((f->kind == STATUS_KIND_STR) != (row->type == REGMAP_STR))
            return -EINVAL;
    }
    return 0;
}

static int index_rows(struct regmap *map)
{
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        unsigned last = regmap_element_address(row, row->elements - 1) +
                        regmap_element_width(row);
        if (last > map->size[row->table])
            map->size[row->table] = last;
    }
    for (int t = 0; t < REGMAP_TABLE_COUNT; t++) {
        map->owner[t] = calloc(map->size[t] ? map->size[t] : 1,
                               sizeof(*map->owner[t]));
        if (!map->owner[t])
            return -ENOMEM;
    }
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        for (unsigned i = 0; i < row->elements; i++) {
            unsigned a = regmap_element_address(row, i);
            for (unsigned w = 0; w < regmap_element_width(row); w++) {
                if (map->owner[row->table][a + w]) {
                    log_err("register map: row '%s' overlaps row '%s' at %s %u",
                            row->name, map->owner[row->table][a + w]->name,
                            table_names[row->table], a + w);
                    return -EINVAL;
                }
                map->owner[row->table][a + w] = row;
            }
        }
    }
    return 0;
}

static uint32_t crc32_update(uint32_t crc, const unsigned char *p, size_t n)
{
    crc = ~crc;
    while (n--) {
        crc ^= *p++;
        for (int k = 0; k < 8; k++)
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

static int compute_crc(struct regmap *map)
{
    char *text = NULL;
    size_t size = 0;
    FILE *mem = open_memstream(&text, &size);

    if (!mem)
        return -ENOMEM;
    int rc = regmap_print(map, REGMAP_FORMAT_CSV, mem);
    fclose(mem);
    if (rc == 0)
        map->crc = crc32_update(0, (const unsigned char *)text, size);
    free(text);
    return rc;
}

/* Written values belong to the PLC: only read-only gateway rows refresh. */
static int list_gw_rows(struct regmap *map)
{
    map->gw_rows = calloc(map->row_count, sizeof(*map->gw_rows));
    if (!map->gw_rows)
        return -ENOMEM;
    for (unsigned r = 0; r < map->row_count; r++)
        if (map->rows[r].source == REGMAP_SRC_GW && !map->rows[r].writable)
            map->gw_rows[map->gw_row_count++] = &map->rows[r];
    return 0;
}

int regmap_init(struct regmap *map)
{
    unsigned max_rows = regmap_table_row_count + 2 * STATUS_FIELD_COUNT;
    int rc;

    memset(map, 0, sizeof(*map));
    map->rows = calloc(max_rows, sizeof(*map->rows));
    if (!map->rows)
        return -ENOMEM;
    memcpy(map->rows, regmap_table_rows,
           regmap_table_row_count * sizeof(*map->rows));
    map->row_count = add_generated_rows(map->rows, regmap_table_row_count);
    for (unsigned r = 0; r < map->row_count; r++) {
        if (check_row(&map->rows[r]) != 0) {
            log_err("register map: row '%s' does not fit its table or field",
                    map->rows[r].name);
            regmap_free(map);
            return -EINVAL;
        }
        /* Every writable row is in exactly one write class; no other is. */
        if (map->rows[r].writable != (map->rows[r].write_class != REGMAP_CLASS_NONE) ||
            map->rows[r].write_class >= REGMAP_CLASS_COUNT) {
            log_err("register map: row '%s' %s", map->rows[r].name,
                    map->rows[r].writable ? "is writable but in no write class"
                                          : "is not writable but has a write class");
            regmap_free(map);
            return -EINVAL;
        }
    }
    rc = index_rows(map);
    if (rc == 0)
        rc = compute_crc(map);
    if (rc == 0)
        rc = list_gw_rows(map);
    if (rc != 0)
        regmap_free(map);
    return rc;
}

void regmap_free(struct regmap *map)
{
    for (int t = 0; t < REGMAP_TABLE_COUNT; t++)
        free(map->owner[t]);
    free(map->gw_rows);
    free(map->rows);
    memset(map, 0, sizeof(*map));
}

const struct regmap_row *regmap_find(const struct regmap *map,
                                     enum regmap_table table, unsigned address)
{
    if (table >= REGMAP_TABLE_COUNT || address >= map->size[table])
        return NULL;
    return map->owner[table][address];
}

/* ---- listings ---- */

/* Expands a template: '*' is the source index, '#' the element from 1. */
void regmap_expand(char *out, size_t size, const char *tmpl, unsigned source_index,
                   unsigned element)
{
    size_t n = 0;

    for (const char *p = tmpl; *p && n + 1 < size; p++) {
        int w;
        if (*p == '*')
            w = snprintf(out + n, size - n, "%u", source_index);
        else if (*p == '#')
            w = snprintf(out + n, size - n, "%u", element + 1);
        else {
            out[n++] = *p;
            continue;
        }
        if (w < 0 || (size_t)w >= size - n)
            break;
        n += (size_t)w;
    }
    out[n] = '\0';
}

struct element_text {
    char name[96];
    char source[96];
    char description[256];
};

static void describe_element(const struct regmap_row *row, unsigned i,
                             struct element_text *t)
{
    const char *fname = "";
    const char *fpath = "";
    unsigned source_index = i;

    if (row->source == REGMAP_SRC_CMD || row->source == REGMAP_SRC_PATH) {
        char path[88];
        source_index = row->index + i;
        regmap_expand(t->name, sizeof(t->name), row->name, source_index, i);
        regmap_expand(path, sizeof(path), row->path, source_index, i);
        snprintf(t->source, sizeof(t->source), "%s:%.88s",
                 row->source == REGMAP_SRC_CMD ? "cmd" : "gw", path);
        regmap_expand(t->description, sizeof(t->description), row->description,
                      source_index, i);
        return;
    }
    if (row->source != REGMAP_SRC_GW) {
        fname = status_fields[row->id].name;
        fpath = status_fields[row->id].path;
        source_index = status_fields[row->id].first + row->index + i;
    }
    switch (row->source) {
    case REGMAP_SRC_STATUS:
        regmap_expand(t->name, sizeof(t->name), row->name, source_index, i);
        status_element_path((enum status_field)row->id, row->index + i, t->source,
                            sizeof(t->source));
        regmap_expand(t->description, sizeof(t->description), row->description,
               source_index, i);
        break;
    case REGMAP_SRC_GW:
        snprintf(t->name, sizeof(t->name), "%s", row->name);
        snprintf(t->source, sizeof(t->source), "gw:%s", gw_value_names[row->id]);
        snprintf(t->description, sizeof(t->description), "%s", row->description);
        break;
    case REGMAP_SRC_CMD:
    case REGMAP_SRC_PATH:
        break; /* handled above */
    case REGMAP_SRC_PRESENT:
    case REGMAP_SRC_COUNT: {
        bool present = row->source == REGMAP_SRC_PRESENT;
        snprintf(t->name, sizeof(t->name), "%s%s", row->name, fname);
        snprintf(t->source, sizeof(t->source), "gw:%s(%s)",
                 present ? "present" : "count", fpath);
        if (present || !is_array_field((enum status_field)row->id))
            snprintf(t->description, sizeof(t->description), "%s%s",
                     row->description, fpath);
        else
            snprintf(t->description, sizeof(t->description),
                     "%s%s (indices %u to %u)", row->description, fpath,
                     status_fields[row->id].first,
                     status_fields[row->id].first + status_fields[row->id].capacity - 1);
        break;
    }
    }
}

static void put_csv_field(FILE *out, const char *s)
{
    if (!strpbrk(s, ",\"\n")) {
        fputs(s, out);
        return;
    }
    fputc('"', out);
    for (; *s; s++) {
        if (*s == '"')
            fputc('"', out);
        fputc(*s, out);
    }
    fputc('"', out);
}

static void put_md_field(FILE *out, const char *s)
{
    for (; *s; s++) {
        if (*s == '|')
            fputc('\\', out);
        fputc(*s, out);
    }
}

static void print_md_intro(const struct regmap *map, FILE *out)
{
    fprintf(out,
            "# jakagw register map\n\n"
            "Generated by `jakagw --print-map md` (map version %d, CRC-32 "
            "0x%08X); do not edit by hand.\n\n"
            "- **Address** is the 0-based address on the wire; **PLC** is the "
            "1-based notation (coils 00001, discrete inputs 10001, input "
            "registers 30001, holding registers 40001).\n"
            "- **Count** is the number of registers (or bits) of the entry. "
            "`f32`, `u32` and `i32` take two registers, high word first by "
            "default (`word_order = high_first`, \"ABCD\"); with `word_order = "
            "low_first` (\"CDAB\") the low word comes first. Input register 4 "
            "says which is in force; registers 6 and 8 hold fixed probe values "
            "to check it.\n"
            "- `str` holds two bytes of UTF-8 text per register, the first byte "
            "in the high byte, NUL-padded.\n"
            "- Integers hold round(source x **Scale**), clamped to the type's "
            "range.\n"
            "- **Source** is the JSON path in the status document (port "
            "10000), `gw:<name>` for a gateway value, `gw:present(path)` and "
            "`gw:count(path)` for what the last document carried.\n"
            "- A value the last document did not carry reads 0, or NaN for "
            "`f32`. Addresses between entries read 0; an address past a "
            "table's last entry answers exception 02.\n"
            "- Input register 18 (`status_age_ms`) and discrete input 2 "
            "(`status_fresh`) tell live data from stale.\n"
            "- **Write class** groups the writable entries: over Modbus/TCP "
            "Security (port 802), a client writes an entry only if the role "
            "of its certificate has that class (`[roles]`, "
            "docs/security.md).\n",
            REGMAP_VERSION, map->crc);
}

/*
 * An output coil's description ends with the discrete input it reads back
 * at, found by its name in the table: a PLC checks that the output is set
 * without a second table to keep in step.
 */
int regmap_readback_address(const struct regmap *map, const struct regmap_row *row,
                            unsigned i)
{
    char want[96];
    struct element_text di;

    if (!row->readback)
        return -1;
    regmap_expand(want, sizeof(want), row->readback, row->index + i, i);
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *in = &map->rows[r];
        if (in->table != REGMAP_DISCRETE_INPUT || strcmp(in->name, row->readback) != 0)
            continue;
        for (unsigned k = 0; k < in->elements; k++) {
            describe_element(in, k, &di);
            if (strcmp(di.name, want) == 0)
                return (int)regmap_element_address(in, k);
        }
    }
    return -1;
}

static void add_readback(const struct regmap *map, const struct regmap_row *row, unsigned i,
                         struct element_text *t)
{
    int at = regmap_readback_address(map, row, i);
    struct element_text di;

    if (at < 0)
        return;
    describe_element(regmap_find(map, REGMAP_DISCRETE_INPUT, (unsigned)at),
                     (unsigned)at - regmap_find(map, REGMAP_DISCRETE_INPUT, (unsigned)at)->address,
                     &di);
    size_t n = strlen(t->description);
    snprintf(t->description + n, sizeof(t->description) - n,
             "; reads back at discrete input %d (%s)", at, di.name);
}

static void print_element(const struct regmap *map, const struct regmap_row *row, unsigned i,
                          enum regmap_format format, FILE *out)
{
    struct element_text t;
    unsigned address = regmap_element_address(row, i);
    const char *access = row->writable ? "rw" : "r";
    double scale = row->scale != 0 ? row->scale : 1;

    describe_element(row, i, &t);
    add_readback(map, row, i, &t);
    if (format == REGMAP_FORMAT_CSV) {
        fprintf(out, "%s,%u,%u,%s,%g,", table_names[row->table], address,
                regmap_element_width(row), type_names[row->type], scale);
        put_csv_field(out, row->unit);
        fprintf(out, ",%s,%s,", access, regmap_write_class_names[row->write_class]);
        put_csv_field(out, t.name);
        fputc(',', out);
        put_csv_field(out, t.source);
        fputc(',', out);
        put_csv_field(out, t.description);
        fputc('\n', out);
        return;
    }
    fprintf(out, "| %u | %05u | %u | %s | %g | ", address,
            table_plc_base[row->table] + address, regmap_element_width(row),
            type_names[row->type], scale);
    put_md_field(out, row->unit);
    fprintf(out, " | %s | %s | `%s` | `", access, regmap_write_class_names[row->write_class],
            t.name);
    put_md_field(out, t.source);
    fputs("` | ", out);
    put_md_field(out, t.description);
    fputs(" |\n", out);
}

/* ---- Structured Text (IEC 61131-3) ---- */

/* The prefix of a table's constants and the name of its image type. */
static const char *const st_prefix[REGMAP_TABLE_COUNT] = {
    [REGMAP_COIL] = "JAKA_CO_",
    [REGMAP_DISCRETE_INPUT] = "JAKA_DI_",
    [REGMAP_INPUT_REGISTER] = "JAKA_IR_",
    [REGMAP_HOLDING_REGISTER] = "JAKA_HR_",
};
static const char *const st_image_type[REGMAP_TABLE_COUNT] = {
    [REGMAP_COIL] = "JAKA_COILS",
    [REGMAP_DISCRETE_INPUT] = "JAKA_DISCRETE_INPUTS",
    [REGMAP_INPUT_REGISTER] = "JAKA_INPUT_REGISTERS",
    [REGMAP_HOLDING_REGISTER] = "JAKA_HOLDING_REGISTERS",
};

/* IEC identifiers are case-insensitive; upper case reads as a constant. */
static void put_st_name(FILE *out, const char *s)
{
    for (; *s; s++)
        fputc(toupper((unsigned char)*s), out);
}

/* A comment's text: "(*" and "*)" inside it would open or close one. */
static void put_st_comment(FILE *out, const char *s)
{
    for (; *s; s++) {
        fputc(*s, out);
        if ((*s == '(' && s[1] == '*') || (*s == '*' && s[1] == ')'))
            fputc(' ', out);
    }
}

static void print_st_intro(const struct regmap *map, FILE *out)
{
    fprintf(out,
            "(* jakagw register map as IEC 61131-3 constants (2nd edition, no vendor\n"
            "   extensions). Generated by `jakagw --print-map st` (map version %d,\n"
            "   CRC-32 16#%08X); do not edit by hand.\n\n"
            "   JAKA_CO_*, JAKA_DI_*, JAKA_IR_* and JAKA_HR_* are 0-based wire\n"
            "   addresses of coils, discrete inputs, input and holding registers,\n"
            "   and index the image arrays below (JAKA_IR_MOTION_STATE indexes a\n"
            "   JAKA_INPUT_REGISTERS). A 32-bit value takes two registers from its\n"
            "   address, high word first unless input register 4 reads 1; a text\n"
            "   holds two bytes per register. docs/register-map.md describes every\n"
            "   entry; docs/plc-library.md how to import this file.\n\n"
            "   The TYPE block goes where a program's types go (DUTs); the\n"
            "   VAR_GLOBAL CONSTANT block into a global variable list, or (strict\n"
            "   IEC 61131-3) into the CONFIGURATION. *)\n\n",
            REGMAP_VERSION, map->crc);
    fputs("TYPE\n", out);
    for (int t = 0; t < REGMAP_TABLE_COUNT; t++)
        fprintf(out, "  %s : ARRAY[0..%u] OF %s;\n", st_image_type[t], map->size[t] - 1,
                is_bit_table((enum regmap_table)t) ? "BOOL" : "WORD");
    fputs("END_TYPE\n\nVAR_GLOBAL CONSTANT\n", out);
    fprintf(out,
            "  JAKA_MAP_MAGIC_VALUE : WORD := 16#%04X; (* what input register map_magic reads *)\n"
            "  JAKA_MAP_VERSION_VALUE : UINT := %d; (* the map version this file describes *)\n"
            "  JAKA_MAP_CRC_VALUE : DWORD := 16#%08X; (* the map CRC-32 this file describes *)\n"
            "  JAKA_PROBE_U32_VALUE : DWORD := 16#%08X; (* what input register probe_u32 reads *)\n",
            REGMAP_MAGIC, REGMAP_VERSION, map->crc, REGMAP_PROBE_U32);
    for (int t = 0; t < REGMAP_TABLE_COUNT; t++)
        fprintf(out, "  %sSIZE : UINT := %u; (* %s: addresses 0 to %u *)\n", st_prefix[t],
                map->size[t], table_names[t], map->size[t] - 1);
}

static void print_st_element(const struct regmap_row *row, unsigned i, FILE *out)
{
    struct element_text t;
    unsigned address = regmap_element_address(row, i);

    describe_element(row, i, &t);
    fprintf(out, "  %s", st_prefix[row->table]);
    put_st_name(out, t.name);
    fprintf(out, " : UINT := %u; (* %s", address, type_names[row->type]);
    if (regmap_element_width(row) > 1 && !is_bit_table(row->table))
        fprintf(out, " x%u", regmap_element_width(row));
    fprintf(out, " %s: ", row->writable ? "rw" : "r");
    put_st_comment(out, t.description);
    fputs(" *)\n", out);
}

int regmap_print(const struct regmap *map, enum regmap_format format, FILE *out)
{
    static const char *const md_titles[REGMAP_TABLE_COUNT] = {
        [REGMAP_COIL] = "Coils (FC 1, 5, 15)",
        [REGMAP_DISCRETE_INPUT] = "Discrete inputs (FC 2)",
        [REGMAP_INPUT_REGISTER] = "Input registers (FC 4)",
        [REGMAP_HOLDING_REGISTER] = "Holding registers (FC 3, 6, 16, 22, 23)",
    };

    if (format == REGMAP_FORMAT_ST) {
        print_st_intro(map, out);
        for (int t = 0; t < REGMAP_TABLE_COUNT; t++)
            for (unsigned a = 0; a < map->size[t]; a++) {
                const struct regmap_row *row = map->owner[t][a];
                for (unsigned i = 0; row && i < row->elements; i++)
                    if (regmap_element_address(row, i) == a)
                        print_st_element(row, i, out);
            }
        fputs("END_VAR\n", out);
        return ferror(out) ? -EIO : 0;
    }
    if (format == REGMAP_FORMAT_CSV)
        fputs("table,address,count,type,scale,unit,access,write_class,name,source,"
              "description\n",
              out);
    else
        print_md_intro(map, out);
    for (int t = 0; t < REGMAP_TABLE_COUNT; t++) {
        if (format == REGMAP_FORMAT_MD)
            fprintf(out,
                    "\n## %s\n\n| Address | PLC | Count | Type | Scale | Unit "
                    "| Access | Write class | Name | Source | Description |\n"
                    "|---:|---:|---:|---|---:|---|---|---|---|---|---|\n",
                    md_titles[t]);
        /* In address order, element by element. */
        for (unsigned a = 0; a < map->size[t]; a++) {
            const struct regmap_row *row = map->owner[t][a];
            if (!row)
                continue;
            for (unsigned i = 0; i < row->elements; i++) {
                if (regmap_element_address(row, i) == a)
                    print_element(map, row, i, format, out);
            }
        }
    }
    return ferror(out) ? -EIO : 0;
}

/* ---- the image ---- */

/* What the status rows show, to encode only what changed. */
struct regmap_shown {
    bool valid; /* 'status' was encoded: false until the first encode */
    struct jaka_status status;
    /* The status-sourced rows of field f: rows[start[f], start[f + 1]). */
    const struct regmap_row **rows;
    unsigned start[STATUS_FIELD_COUNT + 1];
    /* The gateway values the read-only gateway rows show: they are
     * refreshed before every request, and few change from one to the next. */
    bool gw_valid;
    double gw[GW_VALUE_COUNT];
};

static bool is_status_row(const struct regmap_row *row)
{
    return row->source == REGMAP_SRC_STATUS || row->source == REGMAP_SRC_PRESENT ||
           row->source == REGMAP_SRC_COUNT;
}

/* Buckets the status rows by field (a counting sort, in table order). */
static struct regmap_shown *new_shown(const struct regmap *map)
{
    struct regmap_shown *sh = calloc(1, sizeof(*sh));
    unsigned fill[STATUS_FIELD_COUNT] = {0};

    if (!sh)
        return NULL;
    sh->rows = calloc(map->row_count ? map->row_count : 1, sizeof(sh->rows[0]));
    if (!sh->rows) {
        free(sh);
        return NULL;
    }
    for (unsigned r = 0; r < map->row_count; r++)
        if (is_status_row(&map->rows[r]))
            sh->start[map->rows[r].id + 1]++;
    for (unsigned f = 0; f < STATUS_FIELD_COUNT; f++)
        sh->start[f + 1] += sh->start[f];
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        if (is_status_row(row))
            sh->rows[sh->start[row->id] + fill[row->id]++] = row;
    }
    return sh;
}

static void free_shown(struct regmap_shown *sh)
{
    if (sh)
        free(sh->rows);
    free(sh);
}

int regmap_image_init(struct regmap_image *img, const struct regmap *map,
                      enum regmap_word_order word_order)
{
    img->map = map;
    img->word_order = word_order;
    img->shown = new_shown(map);
    img->mb = modbus_mapping_new((int)map->size[REGMAP_COIL],
                                 (int)map->size[REGMAP_DISCRETE_INPUT],
                                 (int)map->size[REGMAP_HOLDING_REGISTER],
                                 (int)map->size[REGMAP_INPUT_REGISTER]);
    if (img->mb && img->shown)
        return 0;
    regmap_image_free(img);
    return -ENOMEM;
}

void regmap_image_free(struct regmap_image *img)
{
    if (img->mb)
        modbus_mapping_free(img->mb);
    img->mb = NULL;
    free_shown(img->shown);
    img->shown = NULL;
}

/* Rounds and clamps without undefined double-to-integer conversions. */
static double clamp_round(double v, double lo, double hi)
{
    if (isnan(v))
        return 0;
    v = nearbyint(v);
    return v < lo ? lo : v > hi ? hi : v;
}

static void put_u32(uint16_t *regs, uint32_t v, enum regmap_word_order wo)
{
    uint16_t hi = (uint16_t)(v >> 16), lo = (uint16_t)(v & 0xFFFF);
    regs[0] = wo == REGMAP_HIGH_WORD_FIRST ? hi : lo;
    regs[1] = wo == REGMAP_HIGH_WORD_FIRST ? lo : hi;
}

void regmap_encode_value(uint16_t *regs, enum regmap_type type, double value,
                         bool present, double scale,
                         enum regmap_word_order word_order)
{
    double v = value * (scale != 0 ? scale : 1);

    switch (type) {
    case REGMAP_BOOL:
        regs[0] = present && value != 0;
        return;
    case REGMAP_U16:
        regs[0] = present ? (uint16_t)clamp_round(v, 0, 65535) : 0;
        return;
    case REGMAP_I16:
        regs[0] = present ? (uint16_t)(int16_t)clamp_round(v, -32768, 32767) : 0;
        return;
    case REGMAP_U32:
        put_u32(regs, present ? (uint32_t)clamp_round(v, 0, 4294967295.0) : 0,
                word_order);
        return;
    case REGMAP_I32:
        put_u32(regs,
                present ? (uint32_t)(int32_t)clamp_round(v, -2147483648.0,
                                                          2147483647.0)
                        : 0,
                word_order);
        return;
    case REGMAP_F32: {
        float f;
        uint32_t bits;
        if (!present)
            f = NAN;
        else if (v > FLT_MAX)
            f = INFINITY;
        else if (v < -FLT_MAX)
            f = -INFINITY;
        else
            f = (float)v;
        memcpy(&bits, &f, sizeof(bits));
        put_u32(regs, bits, word_order);
        return;
    }
    case REGMAP_STR:
        return;
    }
}

void regmap_encode_string(uint16_t *regs, unsigned reg_count, const char *text)
{
    /* Whole pairs, an odd last byte, then zeros: no test per byte (a
     * result's message is written on every command's reply). */
    size_t len = strnlen(text, 2 * (size_t)reg_count);
    const unsigned char *t = (const unsigned char *)text;
    unsigned r = 0;

    for (; r < len / 2; r++)
        regs[r] = (uint16_t)(t[2 * r] << 8 | t[2 * r + 1]);
    if (len % 2)
        regs[r++] = (uint16_t)(t[len - 1] << 8);
    memset(&regs[r], 0, (reg_count - r) * sizeof(regs[0]));
}

static void encode_bit(struct regmap_image *img, const struct regmap_row *row,
                       unsigned address, bool value)
{
    uint8_t *bits = row->table == REGMAP_COIL ? img->mb->tab_bits
                                              : img->mb->tab_input_bits;
    bits[address] = value ? 1 : 0;
}

static uint16_t *row_registers(struct regmap_image *img,
                               const struct regmap_row *row, unsigned address)
{
    uint16_t *regs = row->table == REGMAP_INPUT_REGISTER
                         ? img->mb->tab_input_registers
                         : img->mb->tab_registers;
    return &regs[address];
}

static void encode_number(struct regmap_image *img, const struct regmap_row *row,
                          unsigned address, double value, bool present)
{
    if (row->type == REGMAP_BOOL)
        encode_bit(img, row, address, present && value != 0);
    else
        regmap_encode_value(row_registers(img, row, address), row->type, value,
                            present, row->scale, img->word_order);
}

static void encode_status_row(struct regmap_image *img,
                              const struct regmap_row *row,
                              const struct jaka_status *s)
{
    enum status_field id = (enum status_field)row->id;

    if (row->source == REGMAP_SRC_PRESENT) {
        encode_bit(img, row, row->address, s->count[id] > 0);
        return;
    }
    if (row->source == REGMAP_SRC_COUNT) {
        encode_number(img, row, row->address, s->count[id], true);
        return;
    }
    for (unsigned i = 0; i < row->elements; i++) {
        unsigned address = regmap_element_address(row, i);
        if (row->type == REGMAP_STR) {
            const struct status_str *t = status_str_at(s, id, row->index + i);
            regmap_encode_string(row_registers(img, row, address), row->str_regs,
                                 t->present ? t->text : "");
        } else {
            const struct status_num *n = status_num_at(s, id, row->index + i);
            encode_number(img, row, address, n->value, n->present);
        }
    }
}

/* Do the elements of field 'id' differ between 'a' and 'b'? */
static bool field_changed(const struct jaka_status *a, const struct jaka_status *b,
                          enum status_field id)
{
    const struct status_field_info *f = &status_fields[id];

    if (a->count[id] != b->count[id])
        return true;
    if (f->kind == STATUS_KIND_NUM) {
        /* Bytes, padding included: a false "changed" only costs an encode. */
        return memcmp(status_num_at(a, id, 0), status_num_at(b, id, 0),
                      f->capacity * sizeof(struct status_num)) != 0;
    }
    for (unsigned i = 0; i < f->capacity; i++) {
        const struct status_str *x = status_str_at(a, id, i), *y = status_str_at(b, id, i);
        if (x->present != y->present || strcmp(x->text, y->text) != 0)
            return true;
    }
    return false;
}

/* Remembers field 'id' of 's' as shown. */
static void keep_field(struct jaka_status *shown, const struct jaka_status *s,
                       enum status_field id)
{
    const struct status_field_info *f = &status_fields[id];
    size_t size = f->kind == STATUS_KIND_NUM ? sizeof(struct status_num)
                                             : sizeof(struct status_str);

    memcpy((char *)shown + f->offset, (const char *)s + f->offset, f->capacity * size);
    shown->count[id] = s->count[id];
}

void regmap_encode_status(struct regmap_image *img, const struct jaka_status *s)
{
    struct regmap_shown *sh = img->shown;

    for (unsigned f = 0; f < STATUS_FIELD_COUNT; f++) {
        enum status_field id = (enum status_field)f;
        if (sh->valid && !field_changed(&sh->status, s, id))
            continue;
        for (unsigned r = sh->start[f]; r < sh->start[f + 1]; r++)
            encode_status_row(img, sh->rows[r], s);
        keep_field(&sh->status, s, id);
    }
    sh->valid = true;
}

void regmap_encode_gw(struct regmap_image *img, const double gw[GW_VALUE_COUNT])
{
    struct regmap_shown *sh = img->shown;

    for (unsigned r = 0; r < img->map->gw_row_count; r++) {
        const struct regmap_row *row = img->map->gw_rows[r];
        double v = gw[row->id];
        /* Bits, not ==: -0.0 and 0.0 may encode apart. */
        if (sh->gw_valid && memcmp(&sh->gw[row->id], &v, sizeof(v)) == 0)
            continue;
        encode_number(img, row, row->address, v, true);
    }
    /* After the loop: two rows may show one value. */
    memcpy(sh->gw, gw, sizeof(sh->gw));
    sh->gw_valid = true;
}

/* A command's parameter row ("<cmdName>.<param>", not a setpoint). */
static bool is_parameter(const struct regmap_row *row)
{
    return row && row->writable && row->source == REGMAP_SRC_CMD && !row->fixed &&
           strchr(row->path, '.');
}

/* Do two parameter rows belong to the same command? */
static bool same_command(const struct regmap_row *a, const struct regmap_row *b)
{
    size_t n = strcspn(a->path, ".");
    return strncmp(a->path, b->path, n) == 0 && b->path[n] == '.';
}

/* A coil that takes part in a block of coils a PLC writes whole: a
 * trigger, a policy coil or an output (not clear_counters, alone at 0). */
static bool is_block_coil(const struct regmap_row *row)
{
    return row && row->table == REGMAP_COIL && row->writable &&
           row->write_class != REGMAP_CLASS_COUNTERS;
}

bool regmap_write_skips(const struct regmap *map, enum regmap_table table,
                        unsigned address, unsigned first, unsigned count)
{
    const struct regmap_row *below = NULL, *above = NULL;

    if (regmap_find(map, table, address) || address <= first || address + 1 >= first + count)
        return false;
    for (unsigned a = address; a-- > first && !below;)
        below = regmap_find(map, table, a);
    for (unsigned a = address + 1; a < first + count && !above; a++)
        above = regmap_find(map, table, a);
    if (table == REGMAP_COIL)
        return is_block_coil(below) && is_block_coil(above);
    return is_parameter(below) && is_parameter(above) && same_command(below, above);
}

int regmap_check_write(const struct regmap *map, enum regmap_table table,
                       unsigned address, uint16_t value)
{
    const struct regmap_row *row = regmap_find(map, table, address);
    double v;

    if (!row || !row->writable)
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    if (regmap_element_width(row) > 1)
        return 0; /* judged whole, by regmap_decode_write() */
    v = row->type == REGMAP_I16 ? (double)(int16_t)value : (double)value;
    if (v < row->min || v > row->max)
        return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    return 0;
}

double regmap_read_written(const struct regmap_image *img,
                           const struct regmap_row *row)
{
    if (row->table == REGMAP_COIL)
        return img->mb->tab_bits[row->address];
    uint16_t v = img->mb->tab_registers[row->address];
    return row->type == REGMAP_I16 ? (double)(int16_t)v : (double)v;
}

const struct regmap_row *regmap_find_path(const struct regmap *map,
                                          enum regmap_source source,
                                          const char *path)
{
    for (unsigned r = 0; r < map->row_count; r++) {
        const struct regmap_row *row = &map->rows[r];
        if (row->source == source && row->path && strcmp(row->path, path) == 0)
            return row;
    }
    return NULL;
}

void regmap_set_number(struct regmap_image *img, const struct regmap_row *row,
                       unsigned i, double value, bool present)
{
    encode_number(img, row, regmap_element_address(row, i), value, present);
}

void regmap_set_text(struct regmap_image *img, const struct regmap_row *row,
                     unsigned i, const char *text)
{
    regmap_encode_string(row_registers(img, row, regmap_element_address(row, i)),
                         row->str_regs, text);
}

static uint32_t get_u32(const uint16_t *regs, enum regmap_word_order wo)
{
    uint16_t hi = wo == REGMAP_HIGH_WORD_FIRST ? regs[0] : regs[1];
    uint16_t lo = wo == REGMAP_HIGH_WORD_FIRST ? regs[1] : regs[0];
    return (uint32_t)hi << 16 | lo;
}

/* The value raw registers (or a bit) mean for 'row', unscaled. */
static double decode_number(const struct regmap_row *row, const uint16_t *regs,
                            enum regmap_word_order wo)
{
    double scale = row->scale != 0 ? row->scale : 1;
    double v = 0;

    switch (row->type) {
    case REGMAP_BOOL:
        return regs[0] != 0;
    case REGMAP_U16:
        v = regs[0];
        break;
    case REGMAP_I16:
        v = (int16_t)regs[0];
        break;
    case REGMAP_U32:
        v = get_u32(regs, wo);
        break;
    case REGMAP_I32:
        v = (int32_t)get_u32(regs, wo);
        break;
    case REGMAP_F32: {
        uint32_t bits = get_u32(regs, wo);
        float f;
        memcpy(&f, &bits, sizeof(f));
        v = f;
        break;
    }
    case REGMAP_STR:
        return 0;
    }
    return v / scale;
}

/* The raw value as the row's range sees it (before scaling). */
static double raw_number(const struct regmap_row *row, const uint16_t *regs,
                         enum regmap_word_order wo)
{
    double scale = row->scale != 0 ? row->scale : 1;
    return row->type == REGMAP_F32 ? decode_number(row, regs, wo)
                                   : decode_number(row, regs, wo) * scale;
}

static void decode_text(const uint16_t *regs, unsigned count, char *out, size_t size)
{
    size_t n = 0;
    for (unsigned r = 0; r < count && n + 2 < size; r++) {
        out[n++] = (char)(regs[r] >> 8);
        out[n++] = (char)(regs[r] & 0xFF);
    }
    out[n] = '\0';
}

/* Valid UTF-8 with no control characters (NUL ends the text). */
static bool is_clean_utf8(const char *text)
{
    const unsigned char *p = (const unsigned char *)text;

    while (*p) {
        unsigned extra;
        uint32_t cp;
        if (*p < 0x80) {
            if (*p < 0x20 || *p == 0x7F)
                return false;
            p++;
            continue;
        }
        if ((*p & 0xE0) == 0xC0) {
            extra = 1;
            cp = *p & 0x1F;
        } else if ((*p & 0xF0) == 0xE0) {
            extra = 2;
            cp = *p & 0x0F;
        } else if ((*p & 0xF8) == 0xF0) {
            extra = 3;
            cp = *p & 0x07;
        } else {
            return false;
        }
        p++;
        for (unsigned k = 0; k < extra; k++, p++) {
            if ((*p & 0xC0) != 0x80)
                return false;
            cp = cp << 6 | (*p & 0x3F);
        }
        /* Overlong forms, surrogates and values past Unicode's end. */
        if ((extra == 1 && cp < 0x80) || (extra == 2 && cp < 0x800) ||
            (extra == 3 && cp < 0x10000) || cp > 0x10FFFF ||
            (cp >= 0xD800 && cp <= 0xDFFF))
            return false;
    }
    return true;
}

double regmap_get_number(const struct regmap_image *img,
                         const struct regmap_row *row, unsigned i)
{
    unsigned a = regmap_element_address(row, i);
    if (is_bit_table(row->table)) {
        const uint8_t *bits = row->table == REGMAP_COIL ? img->mb->tab_bits
                                                        : img->mb->tab_input_bits;
        return bits[a];
    }
    return decode_number(row, row_registers((struct regmap_image *)img, row, a),
                         img->word_order);
}

void regmap_get_text(const struct regmap_image *img, const struct regmap_row *row,
                     unsigned i, char *out, size_t size)
{
    decode_text(row_registers((struct regmap_image *)img, row,
                              regmap_element_address(row, i)),
                row->str_regs, out, size);
}

void regmap_save(const struct regmap_image *img, enum regmap_table table,
                 unsigned address, unsigned count, uint16_t *out)
{
    for (unsigned i = 0; i < count; i++)
        out[i] = table == REGMAP_COIL ? img->mb->tab_bits[address + i]
                                      : img->mb->tab_registers[address + i];
}

void regmap_load(struct regmap_image *img, enum regmap_table table,
                 unsigned address, unsigned count, const uint16_t *values)
{
    for (unsigned i = 0; i < count; i++) {
        if (table == REGMAP_COIL)
            img->mb->tab_bits[address + i] = values[i] ? 1 : 0;
        else
            img->mb->tab_registers[address + i] = values[i];
    }
}

int regmap_decode_write(const struct regmap_image *img, enum regmap_table table,
                        unsigned address, unsigned count, const uint16_t *values,
                        const uint16_t *old_values, regmap_written_cb cb, void *user)
{
    const struct regmap *map = img->map;
    unsigned a = address;

    while (a < address + count) {
        const struct regmap_row *row = regmap_find(map, table, a);
        if (regmap_write_skips(map, table, a, address, count)) {
            a++; /* inside a command's parameters: ignored */
            continue;
        }
        if (!row || !row->writable)
            return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
        unsigned width = regmap_element_width(row);
        unsigned stride = row->stride ? row->stride : width;
        unsigned i = (a - row->address) / stride;
        unsigned start = regmap_element_address(row, i);
        if (start != a || a + width > address + count)
            return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS; /* splits a value */
        const uint16_t *regs = values + (a - address);
        struct regmap_written w = {.row = row, .element = i,
                                   .source_index = row->index + i};
        if (row->type == REGMAP_STR) {
            char text[256]; /* the image holds it; only its validity matters here */
            decode_text(regs, width, text, sizeof(text));
            if (!is_clean_utf8(text))
                return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        } else {
            double raw = raw_number(row, regs, img->word_order);
            if (!isfinite(raw) || raw < row->min || raw > row->max)
                return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
            w.value = decode_number(row, regs, img->word_order);
            w.previous = old_values ? decode_number(row, old_values + (a - address),
                                                    img->word_order)
                                    : regmap_get_number(img, row, i);
        }
        int rc = cb(user, &w);
        if (rc)
            return rc;
        a += width;
    }
    return 0;
}
