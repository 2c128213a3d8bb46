/* SPDX-License-Identifier: MIT */
/*
 * regmap.h - the Modbus register map: one table, the single source of truth.
 *
 * Each row of the table places one status field (or a part of an array
 * field), or one gateway value, in one Modbus table: its address, type,
 * scale, unit, access and documentation. From the rows come the register
 * image that the Modbus server answers from, the write checks, and the
 * CSV, Markdown and Structured Text listings (jakagw --print-map csv|md|st).
 *
 * Conventions, which the listings repeat for the integrator:
 * - Addresses are 0-based wire addresses; PLC notation adds 1 and the table
 *   prefix (input register 200 is 30201).
 * - f32, u32 and i32 take two registers; by default the high word comes
 *   first ("ABCD"), configurable to low word first ("CDAB"). Within a
 *   register the high byte comes first, as Modbus defines.
 * - str: two bytes of UTF-8 text per register, the first byte in the high
 *   byte, padded with NUL.
 * - An integer is round(source * scale), clamped to its type's range.
 * - A value the last document did not carry reads 0 (bits and integers) or
 *   NaN (f32); the per-field presence bits and element counts tell which.
 * - Addresses between rows read as 0; addresses past the last row of a
 *   table answer exception 02.
 */
#ifndef JAKAGW_REGMAP_H
#define JAKAGW_REGMAP_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include <modbus.h>

#include "status.h"

#define REGMAP_VERSION 1
#define REGMAP_MAGIC 0x4A4B /* "JK" */
#define REGMAP_PROBE_F32 (-1234.5)
#define REGMAP_PROBE_U32 0x01020304u

enum regmap_table {
    REGMAP_COIL,
    REGMAP_DISCRETE_INPUT,
    REGMAP_INPUT_REGISTER,
    REGMAP_HOLDING_REGISTER,
    REGMAP_TABLE_COUNT
};

enum regmap_type {
    REGMAP_BOOL,
    REGMAP_U16,
    REGMAP_I16,
    REGMAP_U32,
    REGMAP_I32,
    REGMAP_F32,
    REGMAP_STR,
};

enum regmap_word_order {
    REGMAP_HIGH_WORD_FIRST = 0, /* ABCD */
    REGMAP_LOW_WORD_FIRST = 1,  /* CDAB */
};

/* Gateway values a row can show ("gw:<name>"); the gateway fills them. */
#define GW_VALUES(X)                                                           \
    X(map_magic)                                                               \
    X(map_version)                                                             \
    X(map_crc)                                                                 \
    X(word_order)                                                              \
    X(address_base)                                                            \
    X(probe_f32)                                                               \
    X(probe_u32)                                                               \
    X(version_major)                                                           \
    X(version_minor)                                                           \
    X(version_patch)                                                           \
    X(status_link_up)                                                          \
    X(command_link_up)                                                         \
    X(status_fresh)                                                            \
    X(status_link_state)                                                       \
    X(command_link_state)                                                      \
    X(status_age_ms)                                                           \
    X(documents_parsed)                                                        \
    X(status_sequence)                                                         \
    X(start_id)                                                                \
    X(parse_errors)                                                            \
    X(framing_errors)                                                          \
    X(oversize_documents)                                                      \
    X(garbage_bytes)                                                           \
    X(len_mismatches)                                                          \
    X(status_reconnects)                                                       \
    X(command_reconnects)                                                      \
    X(modbus_requests)                                                         \
    X(modbus_exceptions)                                                       \
    X(modbus_clients)                                                          \
    X(modbus_evictions)                                                        \
    X(uptime_s)                                                                \
    X(last_document_bytes)                                                     \
    X(plc_heartbeat)                                                           \
    X(plc_heartbeat_age_ms)                                                    \
    X(clear_counters)                                                          \
    X(can_state)                                                               \
    X(can_frames_sent)                                                         \
    X(can_frames_dropped)                                                      \
    X(can_errors)                                                              \
    X(tls_clients)                                                             \
    X(tls_handshakes_running)                                                  \
    X(tls_handshakes_ok)                                                       \
    X(tls_failed_total)                                                        \
    X(tls_failed_no_certificate)                                               \
    X(tls_failed_untrusted)                                                    \
    X(tls_failed_expired)                                                      \
    X(tls_failed_revoked)                                                      \
    X(tls_failed_protocol)                                                     \
    X(tls_failed_timeout)                                                      \
    X(tls_failed_over_limit)                                                   \
    X(status_link_tls_failure)                                                 \
    X(command_link_tls_failure)                                                \
    X(link_checks)                                                             \
    X(link_checks_failed)                                                      \
    X(rtu_line_state)                                                          \
    X(rtu_frames)                                                              \
    X(rtu_crc_errors)                                                          \
    X(rtu_foreign_frames)                                                      \
    X(rtu_broadcasts)                                                          \
    X(rtu_overruns)                                                            \
    X(rtu_gap_discards)                                                        \
    X(rtu_turnaround_us)                                                       \
    X(rtu_turnaround_max_us)                                                   \
    X(rtu_echoes)                                                              \
    X(rtu_collisions)                                                          \
    X(rtu_out_of_turn)                                                         \
    X(rtu_delivery_ms)                                                         \
    X(rtu_repeats)                                                             \
    X(rtu_exceptions)                                                          \
    X(status_stale_ms)                                                         \
    X(loop_stalls)                                                             \
    X(loop_stall_last_ms)

enum gw_value {
#define GW_ENUM(name) GW_##name,
    GW_VALUES(GW_ENUM)
#undef GW_ENUM
    GW_VALUE_COUNT
};

extern const char *const gw_value_names[GW_VALUE_COUNT];

/*
 * Write classes: every writable row belongs to exactly one (checked by
 * regmap_init), named after what the map groups. A connection's rights are
 * a bit per class (REGMAP_RIGHT); Modbus/TCP Security roles map to them
 * ([roles], regmap_parse_rights).
 */
#define REGMAP_WRITE_CLASSES(X)                                                \
    X(HEARTBEAT, heartbeat)                                                    \
    X(FAULTS, faults)                                                          \
    X(SETPOINTS, setpoints)                                                    \
    X(OUTPUTS, outputs)                                                        \
    X(POWER, power)                                                            \
    X(PROGRAMS, programs)                                                      \
    X(PAYLOAD, payload)                                                        \
    X(MOTION, motion)                                                          \
    X(SHUTDOWN, shutdown)                                                      \
    X(MAILBOXES, mailboxes)                                                    \
    X(COUNTERS, counters)

enum regmap_write_class {
    REGMAP_CLASS_NONE = 0, /* a row that is not writable */
#define REGMAP_CLASS_ENUM(id, name) REGMAP_CLASS_##id,
    REGMAP_WRITE_CLASSES(REGMAP_CLASS_ENUM)
#undef REGMAP_CLASS_ENUM
    REGMAP_CLASS_COUNT
};

#define REGMAP_RIGHT(cls) (1u << (cls))
#define REGMAP_RIGHTS_NONE 0u            /* "read": nothing writable */
#define REGMAP_RIGHTS_ALL 0xFFFFFFFFu    /* "write": every class */

/* "heartbeat", "faults", ...; "" for REGMAP_CLASS_NONE. */
extern const char *const regmap_write_class_names[REGMAP_CLASS_COUNT];

enum regmap_source {
    REGMAP_SRC_STATUS,  /* element of a status field */
    REGMAP_SRC_GW,      /* a gateway value */
    REGMAP_SRC_PRESENT, /* did the last document carry this field */
    REGMAP_SRC_COUNT,   /* how many elements of this field it carried */
    REGMAP_SRC_CMD,     /* a command's trigger or parameter: "cmd:<path>" */
    REGMAP_SRC_PATH,    /* a value the gateway owns, by name: "gw:<path>" */
};

struct regmap_row {
    enum regmap_table table;
    uint16_t address;  /* of the first element */
    uint16_t elements; /* 1 for a scalar */
    uint16_t stride;   /* between elements; 0 means the element's width */
    enum regmap_type type;
    uint16_t str_regs; /* REGMAP_STR: registers per element */
    double scale;      /* 0 means 1 */
    const char *unit;
    bool writable;
    double min, max; /* accepted written values, writable rows only */
    /* Templates: '*' is the source index, '#' the element number from 1. */
    const char *name;
    const char *description;
    enum regmap_source source;
    int id;          /* enum status_field or enum gw_value */
    uint16_t index;  /* first element of the status field this row shows;
                        REGMAP_SRC_CMD/PATH: the source index of element 0 */
    /*
     * REGMAP_SRC_CMD and REGMAP_SRC_PATH: what the row is, as a template
     * ('*' the source index): "power_on" (a command's trigger),
     * "joint_move.jointPosition[*]" (a parameter: the JSON path in the
     * command sent), "result.power_on.state" (a gateway value).
     */
    const char *path;
    /* REGMAP_SRC_CMD rows that send when written: JSON members sent along
     * with the value, as a template ("\"type\": 0, \"index\": *"). */
    const char *fixed;
    /* An output's coil: the name template of the discrete input where the
     * robot's status shows the output ("dout_*"), element for element;
     * the register map's docs name that input's address. NULL: none. */
    const char *readback;
    /* Writable rows: the class a role needs to write it. */
    enum regmap_write_class write_class;
};

/* The built-in table, in src/modbus/regmap_table.c. */
extern const struct regmap_row regmap_table_rows[];
extern const unsigned regmap_table_row_count;

struct regmap {
    struct regmap_row *rows; /* the table plus generated presence/count rows */
    unsigned row_count;
    /* Per table: size in bits/registers, and the row owning each address. */
    unsigned size[REGMAP_TABLE_COUNT];
    const struct regmap_row **owner[REGMAP_TABLE_COUNT];
    uint32_t crc; /* CRC-32 of the CSV listing: changes with any layout change */
    /* The read-only gateway-value rows, re-encoded before every request:
     * a short list, so that refresh does not walk the whole table. */
    const struct regmap_row **gw_rows;
    unsigned gw_row_count;
};

/* For the proofs of the map's readers (make prove), which these
 * functions' contracts below serve (their own bodies are not proved): the
 * map and its table sizes can be read. */
/*@ predicate regmap_readable(struct regmap *map) =
        \valid_read(map) && \valid_read(&map->size[0 .. REGMAP_TABLE_COUNT - 1]);
*/

/*
 * Builds the map from the built-in table. Fails with -EINVAL (and a log line
 * naming the row) when rows overlap or a row does not fit its table or
 * field, or -ENOMEM.
 */
int regmap_init(struct regmap *map);
void regmap_free(struct regmap *map);

/* Registers (or bits) one element of 'row' takes. */
unsigned regmap_element_width(const struct regmap_row *row);
/* The address of element 'i' of 'row'. */
unsigned regmap_element_address(const struct regmap_row *row, unsigned i);

/* The row owning 'address' in 'table', or NULL (hole or out of range). */
/*@ requires regmap_readable(map);
    assigns \nothing;
    ensures \result == \null || \valid_read(\result);
*/
const struct regmap_row *regmap_find(const struct regmap *map,
                                     enum regmap_table table, unsigned address);

/*
 * REGMAP_FORMAT_ST: IEC 61131-3 Structured Text for the PLC library
 * (plc/jaka_map.st): the register image's array types, sized to each
 * table, then one named constant per address (VAR_GLOBAL CONSTANT), so
 * that no PLC program writes an address by hand.
 */
enum regmap_format { REGMAP_FORMAT_CSV, REGMAP_FORMAT_MD, REGMAP_FORMAT_ST };

/* Writes the listing; returns 0 or -EIO. */
int regmap_print(const struct regmap *map, enum regmap_format format, FILE *out);

struct regmap_shown;

/* The register image the Modbus server answers from. */
struct regmap_image {
    const struct regmap *map;
    modbus_mapping_t *mb;
    enum regmap_word_order word_order;
    /* What the status rows and the gateway rows show: regmap_encode_status()
     * and regmap_encode_gw() re-encode only what changed. */
    struct regmap_shown *shown;
};

/* An image's holding registers can be read up to the map's size of that
 * table (regmap_image_init() asks libmodbus for exactly the map's sizes). */
/*@ predicate regmap_image_readable(struct regmap_image *img) =
        \valid_read(img) && regmap_readable(img->map) && \valid_read(img->mb) &&
        \valid_read(img->mb->tab_registers +
                    (0 .. img->map->size[REGMAP_HOLDING_REGISTER] - 1));
*/

int regmap_image_init(struct regmap_image *img, const struct regmap *map,
                      enum regmap_word_order word_order);
void regmap_image_free(struct regmap_image *img);

/*
 * Makes every status-sourced row show 's' (after each document). Only the
 * rows of fields whose elements or count differ from the status encoded
 * last are re-encoded (all of them the first time): on a moving robot a
 * tenth of the fields change from one document to the next. The status
 * rows must be written by nothing else.
 */
void regmap_encode_status(struct regmap_image *img, const struct jaka_status *s);
/*
 * Makes every read-only gateway-sourced row show 'gw' (before each
 * request), encoding only the values that differ from the last call's.
 */
void regmap_encode_gw(struct regmap_image *img, const double gw[GW_VALUE_COUNT]);

/* Encoders of single values, exposed for tests and the CAN side. */
void regmap_encode_value(uint16_t *regs, enum regmap_type type, double value,
                         bool present, double scale,
                         enum regmap_word_order word_order);
void regmap_encode_string(uint16_t *regs, unsigned reg_count, const char *text);

/* The first row whose source is 'source' and whose path is 'path', or NULL. */
const struct regmap_row *regmap_find_path(const struct regmap *map,
                                          enum regmap_source source,
                                          const char *path);

/* Expands a row's template ('*' source index, '#' element number from 1). */
void regmap_expand(char *out, size_t size, const char *tmpl,
                   unsigned source_index, unsigned element);

/* Sets element 'i' of a gateway-owned row (REGMAP_SRC_PATH or _CMD). */
void regmap_set_number(struct regmap_image *img, const struct regmap_row *row,
                       unsigned i, double value, bool present);
void regmap_set_text(struct regmap_image *img, const struct regmap_row *row,
                     unsigned i, const char *text);
/* Reads element 'i' of a row back from the image: a number, unscaled. */
double regmap_get_number(const struct regmap_image *img,
                         const struct regmap_row *row, unsigned i);
/* Reads a text element (UTF-8, up to the first NUL) into 'out'. */
void regmap_get_text(const struct regmap_image *img, const struct regmap_row *row,
                     unsigned i, char *out, size_t size);

/* One row element a write sets, decoded (regmap_decode_write). */
struct regmap_written {
    const struct regmap_row *row;
    unsigned element;      /* within the row, from 0 */
    unsigned source_index; /* row->index + element */
    double value;          /* numbers and bits: the value the row means */
    double previous;       /* what the image held before this write */
    /* REGMAP_STR: the text is in the image (regmap_get_text), checked to
     * be clean UTF-8; this struct stays small enough to keep a whole
     * write's elements. */
};

typedef int (*regmap_written_cb)(void *user, const struct regmap_written *w);

/*
 * Decodes a write of 'count' bits (0 or 1) or registers at 'address' of
 * 'table', as the image would hold them, into the row elements it sets,
 * and calls 'cb' for each in address order. 'previous' comes from
 * 'old_values' (the same range before the write), or from the image when
 * 'old_values' is NULL.
 * A multi-register value (u32, i32, f32, a text) is one unit: the write
 * must cover all of it; a register regmap_write_skips() accepts is passed
 * over. Returns 0, or a Modbus exception code: 02 when the
 * write splits a value or touches an address no writable row owns; 03 for
 * a number outside the row's range, a float that is not finite, or a text
 * that is not valid UTF-8 or holds control characters; or the first
 * non-zero code 'cb' returned, after which no more elements are reported.
 */
int regmap_decode_write(const struct regmap_image *img, enum regmap_table table,
                        unsigned address, unsigned count, const uint16_t *values,
                        const uint16_t *old_values, regmap_written_cb cb, void *user);

/* The discrete input that element 'i' of an output's coil row reads back
 * at (the row's readback name), or -1 for a row without one. */
int regmap_readback_address(const struct regmap *map, const struct regmap_row *row,
                            unsigned i);

/* Copies 'count' bits (0 or 1) or registers of a writable table out of the
 * image, or into it. */
void regmap_save(const struct regmap_image *img, enum regmap_table table,
                 unsigned address, unsigned count, uint16_t *out);
void regmap_load(struct regmap_image *img, enum regmap_table table,
                 unsigned address, unsigned count, const uint16_t *values);

/*
 * Is 'address' a register no row owns inside one command's parameters
 * (HR 357 in moveL's block), in a write of 'count' from 'first' that
 * reaches that command's parameters on both sides of it? Such a write sets
 * the command's parameters from its first to its last register in one
 * request, as PLCs write a block: the unassigned register is accepted and
 * ignored. Alone, or at either end of a write, it is refused (02).
 * Coils likewise: a coil no row owns, in a write that reaches writable
 * coils (not clear_counters) on both sides of it (coils 115-119 in a write
 * of the triggers 100-131, as a vendor's client writes the block whole);
 * the caller refuses a 1 there (02) and ignores a 0.
 */
/*@ requires regmap_readable(map);
    assigns \nothing;
*/
bool regmap_write_skips(const struct regmap *map, enum regmap_table table,
                        unsigned address, unsigned first, unsigned count);

/*
 * Checks that 'value' may be written at 'address' of a writable table.
 * Returns 0, or the Modbus exception code: MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
 * when no writable row owns the address, MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE
 * when the value is outside the row's range.
 */
/*@ requires regmap_readable(map);
    assigns \nothing;
    ensures \result == 0 || \result == MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS ||
            \result == MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
*/
int regmap_check_write(const struct regmap *map, enum regmap_table table,
                       unsigned address, uint16_t value);

/*
 * Rights as [roles] and default_rights write them: "read" (nothing),
 * "write" (everything), or a comma-separated list of write classes.
 * Returns 0, or -EINVAL with the reason in 'why'.
 */
int regmap_parse_rights(const char *text, uint32_t *rights, char *why, size_t why_size);
/* The same, back to text ("read", "write", "heartbeat,outputs"). */
void regmap_format_rights(uint32_t rights, char *out, size_t size);

/*
 * May a connection with 'rights' write 'count' bits or registers at
 * 'address' of 'table'? 0, or MODBUS_EXCEPTION_ILLEGAL_FUNCTION (01) when
 * any address of the range belongs to a writable row of a class outside
 * them. Addresses no writable row owns are left to the write's own checks
 * (exception 02).
 */
int regmap_write_allowed(const struct regmap *map, enum regmap_table table,
                         unsigned address, unsigned count, uint32_t rights);

/* Reads back a written element as a number (u16/i16/bool rows). */
double regmap_read_written(const struct regmap_image *img,
                           const struct regmap_row *row);

#endif
