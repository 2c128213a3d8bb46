/* SPDX-License-Identifier: MIT */
/*
 * can_map.h - the CAN frame map: one table, the single source of truth for
 * the CAN mirror, as regmap.h is for Modbus.
 *
 * Each frame of the table has an identifier offset (added to the configured
 * base id), a length, a group that configuration switches on or off, and a
 * list of signals. Each signal places one value of the status model (or one
 * gateway value) at a bit position, with a width, a factor and a unit. From
 * the table come the frame encoder and the DBC that decodes the frames
 * (jakagw --print-dbc).
 *
 * Conventions, which the DBC repeats in its comments:
 * - Classic CAN, at most 8 data bytes; every signal is little-endian
 *   (Intel, "@1" in DBC), its start bit counted from bit 0 of byte 0.
 * - A number is raw = round(value * source_scale / factor), half away from
 *   zero, clamped to the signal's range (saturation, never wrap-around).
 * - A value the robot did not send is marked, never sent as zero, with the
 *   reserved raw value J1939 uses for "not available":
 *     flags (2 bits): 0 false, 1 true, 3 not sent;
 *     unsigned: all bits set (0xFF, 0xFFFF, 0xFFFFFFFF);
 *     signed: the most negative value (0x80000000 for 32 bits).
 *   A real value never produces the reserved raw value: it saturates one
 *   step short of it. The DBC names each reserved value with VAL_.
 * - Gateway values (links, freshness, counters) are always valid.
 */
#ifndef JAKAGW_CAN_MAP_H
#define JAKAGW_CAN_MAP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "regmap.h"
#include "status.h"

#define CAN_MAP_VERSION 1
#define CAN_FRAME_MAX_DLC 8
#define CAN_MAX_STD_ID 0x7FFu
#define CAN_MAX_EXT_ID 0x1FFFFFFFu
#define CAN_MAP_DEFAULT_BASE_ID 0x500u
#define CAN_MAP_NODE "JAKAGW"

/* X(name): frame groups; configuration key [can] frames lists them. */
#define CAN_GROUPS(X)                                                          \
    X(state)                                                                   \
    X(health)                                                                  \
    X(program)                                                                 \
    X(joints)                                                                  \
    X(tcp)

enum can_group {
#define CAN_GROUP_ENUM(name) CAN_GROUP_##name,
    CAN_GROUPS(CAN_GROUP_ENUM)
#undef CAN_GROUP_ENUM
    CAN_GROUP_COUNT
};

#define CAN_GROUPS_ALL ((1u << CAN_GROUP_COUNT) - 1)

extern const char *const can_group_names[CAN_GROUP_COUNT];

/* Values the CAN mirror itself supplies ("mirror:<name>"). */
#define CAN_MIRROR_VALUES(X)                                                   \
    X(rolling_counter)                                                         \
    X(frames_dropped)

enum can_mirror_value {
#define CAN_MIRROR_ENUM(name) CAN_MIRROR_##name,
    CAN_MIRROR_VALUES(CAN_MIRROR_ENUM)
#undef CAN_MIRROR_ENUM
    CAN_MIRROR_VALUE_COUNT
};

enum can_encoding {
    CAN_ENC_FLAG,     /* 2 bits: 0 false, 1 true, 3 not sent */
    CAN_ENC_BIT,      /* 1 bit, always valid (gateway booleans) */
    CAN_ENC_UNSIGNED, /* all bits set: not sent (status sources) */
    CAN_ENC_SIGNED,   /* most negative value: not sent (status sources) */
};

enum can_source {
    CAN_SRC_STATUS, /* element 'index' of status field 'id' */
    CAN_SRC_GW,     /* gateway value 'id' (enum gw_value) */
    CAN_SRC_MIRROR, /* mirror value 'id' (enum can_mirror_value) */
};

/* A name for one raw value of a signal (DBC VAL_). */
struct can_value_name {
    int64_t raw;
    const char *name;
};

struct can_signal {
    const char *name; /* DBC signal name */
    uint8_t start_bit;
    uint8_t bits;
    enum can_encoding encoding;
    double factor;       /* physical value of one raw step; 0 means 1 */
    double source_scale; /* physical = source * source_scale; 0 means 1 */
    const char *unit;
    const char *description;
    enum can_source source;
    int id;
    uint16_t index;
    /* Names of raw values, ended by a NULL name; NULL for none. The
       reserved 'not sent' value is named automatically. */
    const struct can_value_name *values;
};

struct can_frame_def {
    const char *name; /* DBC message name */
    uint8_t id_offset;
    uint8_t dlc;
    enum can_group group;
    const char *description;
    const struct can_signal *signals;
    uint8_t signal_count;
};

/* The built-in table, in src/can/can_map_table.c. */
extern const struct can_frame_def can_map_frames[];
extern const unsigned can_map_frame_count;

/* What the encoder reads: the status model and the gateway's values. */
struct can_inputs {
    const struct jaka_status *status; /* NULL: nothing received */
    const double *gw;                 /* GW_VALUE_COUNT values; NULL: all 0 */
    double mirror[CAN_MIRROR_VALUE_COUNT];
};

/*
 * Checks the built-in table: every signal inside its frame's length, no two
 * signals of a frame sharing a bit, unique frame offsets and names, sources
 * inside their fields. Returns 0, or -EINVAL with a log line naming the
 * frame or signal.
 */
int can_map_check(void);

/* The raw range of a signal's real values, and its reserved 'not sent' raw
   value (has_invalid false for gateway and mirror sources and 1-bit flags). */
struct can_signal_range {
    int64_t min, max;
    bool has_invalid;
    int64_t invalid;
};
void can_signal_range(const struct can_signal *sig, struct can_signal_range *out);

/* The raw value a signal carries for 'in' (the reserved value if not sent). */
int64_t can_signal_raw(const struct can_signal *sig, const struct can_inputs *in);

/* Encodes one frame's data bytes (frame->dlc of them; unused bits are 0). */
void can_map_encode(const struct can_frame_def *frame, const struct can_inputs *in,
                    uint8_t data[CAN_FRAME_MAX_DLC]);

/* The frame's identifier on the bus, without any flag bit. */
uint32_t can_frame_id(const struct can_frame_def *frame, uint32_t base_id);

/* The largest identifier offset of the table. */
unsigned can_map_max_offset(void);

struct can_dbc_options {
    uint32_t base_id;
    bool extended_ids;
    uint32_t period_ms; /* GenMsgCycleTime */
    uint32_t groups;    /* bit per enum can_group: frames listed */
};

/* Writes the DBC for the frames of 'opt->groups'; returns 0 or -EIO. */
int can_map_print_dbc(const struct can_dbc_options *opt, FILE *out);

/*
 * Parses a group list: "all", or names separated by commas and/or spaces
 * ("state, health, joints"); at least one group (to send nothing, leave
 * [can] enabled = false). Returns 0, or -EINVAL with the reason written to
 * 'why'.
 */
int can_map_parse_groups(const char *text, uint32_t *groups, char *why,
                         size_t why_size);

/* Writes a group list as can_map_parse_groups() reads it. */
void can_map_format_groups(uint32_t groups, char *buf, size_t size);

#endif
