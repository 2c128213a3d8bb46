/* SPDX-License-Identifier: MIT */
/*
 * status.h - the robot's status document (port 10000) as one typed struct.
 *
 * Every field the gateway understands is one line of JAKA_STATUS_FIELDS
 * below: its member name, its JSON path in the document, the index of its
 * first element and its capacity. The list generates the struct members, the
 * field ids and the parser's table, so adding a field is adding a line.
 *
 * Paths use dots for object keys and [n] for array items; one '*' stands for
 * the varying index, which runs from 'first' for 'capacity' elements.
 * Real controllers send more fields and longer or shorter arrays than the
 * manual lists, so every element records whether the last document carried
 * it ('present') and every field how many elements it carried ('count').
 *
 * Append new fields at the end of a list: field ids number the gateway's
 * per-field presence and count registers.
 */
#ifndef JAKAGW_STATUS_H
#define JAKAGW_STATUS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define STATUS_JOINTS 6
#define STATUS_STR_SIZE 16  /* short strings: names, addresses */
#define STATUS_MSG_SIZE 128 /* errmsg */

/* X(name, path, first, capacity): numbers, booleans and errcode. */
#define JAKA_STATUS_NUM_FIELDS(X)                                              \
    X(len, "len", 0, 1)                                                        \
    X(drag_status, "drag_status", 0, 1)                                        \
    X(errcode, "errcode", 0, 1)                                                \
    X(extio_num, "extio.num", 0, 1)                                            \
    X(extio_mode, "extio.mode", 0, 1)                                          \
    X(extio_di, "extio.status[0][*]", 0, 64)                                   \
    X(extio_do, "extio.status[1][*]", 0, 64)                                   \
    X(extio_ai, "extio.status[2][*]", 0, 32)                                   \
    X(extio_ao, "extio.status[3][*]", 0, 32)                                   \
    X(extio_comm_type, "extio.setup[*][0]", 0, 8)                              \
    X(extio_comm_1, "extio.setup[*][2][1]", 0, 8)                              \
    X(extio_comm_2, "extio.setup[*][2][2]", 0, 8)                              \
    X(extio_comm_3, "extio.setup[*][2][3]", 0, 8)                              \
    X(extio_comm_4, "extio.setup[*][2][4]", 0, 8)                              \
    X(extio_comm_5, "extio.setup[*][2][5]", 0, 8)                              \
    X(extio_di_start, "extio.setup[*][3][0][0]", 0, 8)                         \
    X(extio_di_count, "extio.setup[*][3][0][1]", 0, 8)                         \
    X(extio_do_start, "extio.setup[*][3][1][0]", 0, 8)                         \
    X(extio_do_count, "extio.setup[*][3][1][1]", 0, 8)                         \
    X(extio_ai_start, "extio.setup[*][3][2][0]", 0, 8)                         \
    X(extio_ai_count, "extio.setup[*][3][2][1]", 0, 8)                         \
    X(extio_ao_start, "extio.setup[*][3][3][0]", 0, 8)                         \
    X(extio_ao_count, "extio.setup[*][3][3][1]", 0, 8)                         \
    X(extio_pinmap_di, "extio.pinmap[*][0]", 0, 8)                             \
    X(extio_pinmap_do, "extio.pinmap[*][1]", 0, 8)                             \
    X(extio_pinmap_ai, "extio.pinmap[*][2]", 0, 8)                             \
    X(extio_pinmap_ao, "extio.pinmap[*][3]", 0, 8)                             \
    X(scb_major, "monitor_data[0]", 0, 1)                                      \
    X(scb_minor, "monitor_data[1]", 0, 1)                                      \
    X(cabinet_temperature, "monitor_data[2]", 0, 1)                            \
    X(cabinet_power, "monitor_data[3]", 0, 1)                                  \
    X(cabinet_current, "monitor_data[4]", 0, 1)                                \
    X(monitor_extra, "monitor_data[*]", 6, 4)                                  \
    X(joint_current, "monitor_data[5][*][0]", 0, STATUS_JOINTS)                \
    X(joint_voltage, "monitor_data[5][*][1]", 0, STATUS_JOINTS)                \
    X(joint_temperature, "monitor_data[5][*][2]", 0, STATUS_JOINTS)            \
    X(joint_power, "monitor_data[5][*][3]", 0, STATUS_JOINTS)                  \
    X(joint_current_fluctuation, "monitor_data[5][*][4]", 0, STATUS_JOINTS)    \
    X(joint_total_turns, "monitor_data[5][*][5]", 0, STATUS_JOINTS)            \
    X(joint_total_time, "monitor_data[5][*][6]", 0, STATUS_JOINTS)             \
    X(joint_boot_turns, "monitor_data[5][*][7]", 0, STATUS_JOINTS)             \
    X(joint_boot_time, "monitor_data[5][*][8]", 0, STATUS_JOINTS)              \
    X(joint_torque, "monitor_data[5][*][9]", 0, STATUS_JOINTS)                 \
    X(joint_monitor_extra, "monitor_data[5][*][10]", 0, STATUS_JOINTS)         \
    X(torq_comm_type, "torqsensor[0][0]", 0, 1)                                \
    X(torq_comm, "torqsensor[0][1][*]", 1, 3)                                  \
    X(torq_payload_mass, "torqsensor[0][2][0]", 0, 1)                          \
    X(torq_payload_centroid, "torqsensor[0][2][1][*]", 0, 3)                   \
    X(torq_status, "torqsensor[1][0]", 0, 1)                                   \
    X(torq_errcode, "torqsensor[1][1]", 0, 1)                                  \
    X(torq_force, "torqsensor[1][2][*]", 0, 6)                                 \
    X(torq_raw, "torqsensor[1][3][*]", 0, 6)                                   \
    X(torq_extra, "torqsensor[1][4][*]", 0, 6)                                 \
    X(joint_actual_position, "joint_actual_position[*]", 0, STATUS_JOINTS)     \
    X(actual_position, "actual_position[*]", 0, 6)                             \
    X(joint_position, "joint_position[*]", 0, STATUS_JOINTS)                   \
    X(position, "position[*]", 0, 6)                                           \
    X(inst_vel, "instVel[*]", 0, STATUS_JOINTS)                                \
    X(din, "din[*]", 0, 256)                                                   \
    X(dout, "dout[*]", 0, 256)                                                 \
    X(ain, "ain[*]", 0, 128)                                                   \
    X(aout, "aout[*]", 0, 128)                                                 \
    X(tio_din, "tio_din[*]", 0, 8)                                             \
    X(tio_dout, "tio_dout[*]", 0, 8)                                           \
    X(tio_ain, "tio_ain[*]", 0, 4)                                             \
    X(tio_key, "tio_key[*]", 0, 4)                                             \
    X(relay_io, "relay_io[*]", 0, 4)                                           \
    X(mb_slave_din, "mb_slave_din[*]", 0, 128)                                 \
    X(mb_slave_dout, "mb_slave_dout[*]", 0, 128)                               \
    X(mb_slave_ain, "mb_slave_ain[*]", 0, 64)                                  \
    X(mb_slave_aout, "mb_slave_aout[*]", 0, 64)                                \
    X(pn_dev_din, "pn_dev_din[*]", 0, 64)                                      \
    X(pn_dev_dout, "pn_dev_dout[*]", 0, 64)                                    \
    X(pn_dev_ain, "pn_dev_ain[*]", 0, 64)                                      \
    X(pn_dev_aout, "pn_dev_aout[*]", 0, 64)                                    \
    X(eip_adpt_din, "eip_adpt_din[*]", 0, 64)                                  \
    X(eip_adpt_dout, "eip_adpt_dout[*]", 0, 64)                                \
    X(eip_adpt_ain, "eip_adpt_ain[*]", 0, 64)                                  \
    X(eip_adpt_aout, "eip_adpt_aout[*]", 0, 64)                                \
    X(task_state, "task_state", 0, 1)                                          \
    X(homed, "homed[*]", 0, 16)                                                \
    X(task_mode, "task_mode", 0, 1)                                            \
    X(interp_state, "interp_state", 0, 1)                                      \
    X(enabled, "enabled", 0, 1)                                                \
    X(paused, "paused", 0, 1)                                                  \
    X(rapidrate, "rapidrate", 0, 1)                                            \
    X(current_tool_id, "current_tool_id", 0, 1)                                \
    X(current_user_id, "current_user_id", 0, 1)                                \
    X(on_soft_limit, "on_soft_limit", 0, 1)                                    \
    X(emergency_stop, "emergency_stop", 0, 1)                                  \
    X(drag_near_limit, "drag_near_limit[*]", 0, 8)                             \
    X(funcdi_type, "funcdi[*][0]", 0, 16)                                      \
    X(funcdi_index, "funcdi[*][1]", 0, 16)                                     \
    X(powered_on, "powered_on", 0, 1)                                          \
    X(inpos, "inpos", 0, 1)                                                    \
    X(motion_mode, "motion_mode", 0, 1)                                        \
    X(curr_tcp_trans_vel, "curr_tcp_trans_vel", 0, 1)                          \
    X(protective_stop, "protective_stop", 0, 1)                                \
    X(point_key, "point_key", 0, 1)                                            \
    X(net_state, "netState", 0, 1)                                             \
    X(motion_line, "motion_line", 0, 1)                                        \
    X(err_add_line, "err_add_line", 0, 1)                                      \
    X(tio_rs_1, "tio_rs_signals[*][1]", 0, 8)                                  \
    X(tio_rs_2, "tio_rs_signals[*][2]", 0, 8)                                  \
    X(tio_rs_3, "tio_rs_signals[*][3]", 0, 8)                                  \
    X(tio_rs_4, "tio_rs_signals[*][4]", 0, 8)                                  \
    X(tio_rs_value, "tio_rs_signals[*][5]", 0, 8)

/* X(name, path, first, capacity, size): strings (a number is kept as text). */
#define JAKA_STATUS_STR_FIELDS(X)                                              \
    X(errmsg, "errmsg", 0, 1, STATUS_MSG_SIZE)                                 \
    X(extio_alias, "extio.setup[*][1]", 0, 8, STATUS_STR_SIZE)                 \
    X(extio_comm_0, "extio.setup[*][2][0]", 0, 8, STATUS_STR_SIZE)             \
    X(torq_address, "torqsensor[0][1][0]", 0, 1, STATUS_STR_SIZE)              \
    X(tio_rs_name, "tio_rs_signals[*][0]", 0, 8, STATUS_STR_SIZE)

/* Field ids: numeric fields first, then strings. */
enum status_field {
#define STATUS_ENUM_NUM(name, path, first, cap) STATUS_F_##name,
#define STATUS_ENUM_STR(name, path, first, cap, size) STATUS_F_##name,
    JAKA_STATUS_NUM_FIELDS(STATUS_ENUM_NUM)
    JAKA_STATUS_STR_FIELDS(STATUS_ENUM_STR)
#undef STATUS_ENUM_NUM
#undef STATUS_ENUM_STR
    STATUS_FIELD_COUNT
};

/* One number of the document and whether the last document carried it. */
struct status_num {
    double value;
    bool present;
};

struct status_str {
    bool present;
    char text[STATUS_MSG_SIZE];
};

struct jaka_status {
#define STATUS_MEMBER_NUM(name, path, first, cap) struct status_num name[cap];
#define STATUS_MEMBER_STR(name, path, first, cap, size) struct status_str name[cap];
    JAKA_STATUS_NUM_FIELDS(STATUS_MEMBER_NUM)
    JAKA_STATUS_STR_FIELDS(STATUS_MEMBER_STR)
#undef STATUS_MEMBER_NUM
#undef STATUS_MEMBER_STR
    /* Elements of each field the last document carried, by field id. */
    uint16_t count[STATUS_FIELD_COUNT];
};

enum status_kind { STATUS_KIND_NUM, STATUS_KIND_STR };

/* The parser's view of one field; status_fields[id] describes field 'id'. */
struct status_field_info {
    const char *name;
    const char *path;
    enum status_kind kind;
    uint16_t first;
    uint16_t capacity;
    uint16_t str_size; /* STATUS_KIND_STR only, NUL included */
    size_t offset;     /* of the member in struct jaka_status */
};

extern const struct status_field_info status_fields[STATUS_FIELD_COUNT];

enum status_parse_result {
    STATUS_PARSE_OK = 0,
    STATUS_PARSE_BAD_JSON = -1,   /* not JSON at all */
    STATUS_PARSE_NOT_OBJECT = -2, /* JSON, but not an object */
};

/*
 * Parses one status document of 'size' bytes into 'out', replacing all of
 * its contents: a field the document does not carry, or carries with a type
 * that cannot be read as the field's kind, is left not present. Numbers that
 * are not finite are not present. "errcode" may be a hex string ("0x1a"), a
 * decimal string or a number. Returns STATUS_PARSE_OK or a negative
 * enum status_parse_result; 'out' is cleared on error.
 *
 * One pass over the document's top-level members, each handed to the
 * fields whose path starts with its name (a duplicated name counts once,
 * the first, as a lookup would). cJSON parses into an arena (json_arena.h),
 * installed for this call only: other users of cJSON keep malloc and free.
 * Not thread-safe (cJSON's hooks are one global): call it from the loop.
 */
int status_parse(struct jaka_status *out, const char *json, size_t size);

/*
 * Gives back the memory status_parse() keeps between documents (the arena
 * its cJSON tree is parsed into, about 20 times a document's size), so a
 * leak checker at exit sees nothing held. status_parse() works again after.
 */
void status_parse_release(void);

/*
 * The top-level members whose changes are events: the events log's robot
 * view (power, enable, program, stops, mode, speed override), the motion
 * tracker's states (in position, program), errors. A document that changes
 * one of them from the document before must be handled even when a newer
 * one already waits (robot_link.h, newest_only): its marks tell, from a
 * scan of its bytes without a parse.
 */
#define STATUS_MARK_MEMBERS(X)                                                 \
    X("powered_on") X("enabled") X("interp_state") X("task_state")             \
    X("task_mode") X("task mode") X("emergency_stop") X("protective_stop")     \
    X("inpos") X("paused") X("errcode") X("rapidrate") X("motion_mode")

enum {
#define STATUS_MARK_COUNT_ONE(name) +1
    STATUS_MARK_COUNT = 0 STATUS_MARK_MEMBERS(STATUS_MARK_COUNT_ONE)
#undef STATUS_MARK_COUNT_ONE
};

/* A document's marks: a hash of each mark member's text as written (0: absent). */
struct status_marks {
    uint64_t value[STATUS_MARK_COUNT];
};

/*
 * The marks of the object 'json' of 'size' bytes (complete, as the framer
 * cut it): one pass over its bytes, members nested in others skipped. A
 * member given twice counts with its first value, as status_parse reads it.
 * Text that differs in form only ("1" and "1.0") counts as a change: at
 * worst a document is parsed that need not have been.
 */
void status_marks_of(const char *json, size_t size, struct status_marks *m);

/* Does any mark differ? */
bool status_marks_differ(const struct status_marks *a, const struct status_marks *b);

/* The numeric slot 'index' of numeric field 'field' (index < capacity). */
const struct status_num *status_num_at(const struct jaka_status *s,
                                       enum status_field field, unsigned index);
const struct status_str *status_str_at(const struct jaka_status *s,
                                       enum status_field field, unsigned index);

/*
 * Writes the JSON path of element 'index' of 'field' (the path with '*'
 * replaced by first + index) into 'buf'. Returns the length written.
 */
int status_element_path(enum status_field field, unsigned index, char *buf,
                        size_t size);

/* True when a status number reads as a set boolean (present and non-zero). */
static inline bool status_flag(const struct status_num *n)
{
    return n->present && n->value != 0.0;
}

#endif
