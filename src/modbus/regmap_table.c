/* SPDX-License-Identifier: MIT */
/*
 * regmap_table.c - the register map, row by row.
 *
 * Addresses are stable: a PLC program is written against them. Add rows in
 * free space; never move a row without bumping REGMAP_VERSION. The gaps
 * between blocks are room for fields future controllers may send.
 */
#include "regmap.h"

#define ROW(tbl, addr, n, stride_, type_, regs, scale_, unit_, name_, desc,    \
            src, id_, idx)                                                     \
    {.table = (tbl), .address = (addr), .elements = (n), .stride = (stride_), \
     .type = (type_), .str_regs = (regs), .scale = (scale_), .unit = (unit_),  \
     .name = (name_), .description = (desc), .source = (src), .id = (id_),    \
     .index = (idx)}

/* Status rows. */
#define S_DI(addr, field, n, name, desc)                                       \
    ROW(REGMAP_DISCRETE_INPUT, addr, n, 0, REGMAP_BOOL, 0, 1, "", name, desc,  \
        REGMAP_SRC_STATUS, STATUS_F_##field, 0)
#define S_IR(addr, field, n, type, unit, name, desc)                           \
    ROW(REGMAP_INPUT_REGISTER, addr, n, 0, type, 0, 1, unit, name, desc,       \
        REGMAP_SRC_STATUS, STATUS_F_##field, 0)
#define S_IRS(addr, field, type, scale, unit, name, desc)                      \
    ROW(REGMAP_INPUT_REGISTER, addr, 1, 0, type, 0, scale, unit, name, desc,   \
        REGMAP_SRC_STATUS, STATUS_F_##field, 0)
/* One value per joint, in per-joint blocks of 'stride' registers. */
#define S_JOINT(addr, field, unit, name, desc)                                 \
    ROW(REGMAP_INPUT_REGISTER, addr, STATUS_JOINTS, 22, REGMAP_F32, 0, 1,      \
        unit, name, desc, REGMAP_SRC_STATUS, STATUS_F_##field, 0)
#define S_STR(addr, field, n, regs, name, desc)                                \
    ROW(REGMAP_INPUT_REGISTER, addr, n, 0, REGMAP_STR, regs, 1, "", name,      \
        desc, REGMAP_SRC_STATUS, STATUS_F_##field, 0)

/* Gateway rows: the name is the gateway value's name. */
#define G_DI(addr, gw, desc)                                                   \
    ROW(REGMAP_DISCRETE_INPUT, addr, 1, 0, REGMAP_BOOL, 0, 1, "", #gw, desc,   \
        REGMAP_SRC_GW, GW_##gw, 0)
#define G_IR(addr, gw, type, unit, desc)                                       \
    ROW(REGMAP_INPUT_REGISTER, addr, 1, 0, type, 0, 1, unit, #gw, desc,        \
        REGMAP_SRC_GW, GW_##gw, 0)


/* Command rows ("cmd:<path>"): a trigger coil sends on 0 -> 1. */
#define C_TRIGGER(addr, cls, cmd, desc)                                        \
    {.table = REGMAP_COIL, .address = (addr), .elements = 1,                   \
     .write_class = REGMAP_CLASS_##cls,                                        \
     .type = REGMAP_BOOL, .scale = 1, .unit = "", .writable = true, .min = 0,  \
     .max = 1, .name = "cmd_" cmd, .description = (desc),                      \
     .source = REGMAP_SRC_CMD, .path = cmd}
/* A parameter: held until its command's trigger. */
#define C_PARAM(addr, cls, n, type_, regs, min_, max_, unit_, name_, path_, desc) \
    {.table = REGMAP_HOLDING_REGISTER, .address = (addr), .elements = (n),     \
     .write_class = REGMAP_CLASS_##cls,                                        \
     .type = (type_), .str_regs = (regs), .scale = 1, .unit = (unit_),         \
     .writable = true, .min = (min_), .max = (max_), .name = (name_),          \
     .description = (desc), .source = REGMAP_SRC_CMD, .path = (path_)}
/* A setpoint: each write sends its command, with the 'fixed' members. */
#define C_SET(tbl, addr, cls, n, first, type_, scale_, min_, max_, unit_, name_, \
              path_, fixed_, desc)                                             \
    {.table = (tbl), .address = (addr), .elements = (n), .index = (first),     \
     .write_class = REGMAP_CLASS_##cls,                                        \
     .type = (type_), .scale = (scale_), .unit = (unit_), .writable = true,    \
     .min = (min_), .max = (max_), .name = (name_), .description = (desc),     \
     .source = REGMAP_SRC_CMD, .path = (path_), .fixed = (fixed_)}
/* An output's coil: a setpoint that reads back at discrete input 'rb_'. */
#define C_OUT(addr, n, first, name_, fixed_, desc, rb_)                        \
    {.table = REGMAP_COIL, .address = (addr), .elements = (n), .index = (first), \
     .write_class = REGMAP_CLASS_OUTPUTS, .type = REGMAP_BOOL, .scale = 1,     \
     .unit = "", .writable = true, .min = 0, .max = 1, .name = (name_),        \
     .description = (desc), .source = REGMAP_SRC_CMD,                          \
     .path = "set_digital_output.value", .fixed = (fixed_), .readback = (rb_)}
/* A gateway value by name ("gw:<path>"), read-only or written by the PLC. */
#define P_ROW(tbl, addr, n, type_, regs, unit_, name_, path_, desc)           \
    {.table = (tbl), .address = (addr), .elements = (n), .type = (type_),     \
     .str_regs = (regs), .scale = 1, .unit = (unit_), .name = (name_),        \
     .description = (desc), .source = REGMAP_SRC_PATH, .path = (path_)}
#define P_HOLD(addr, cls, n, type_, min_, max_, regs, name_, path_, desc)     \
    {.table = REGMAP_HOLDING_REGISTER, .address = (addr), .elements = (n),    \
     .write_class = REGMAP_CLASS_##cls,                                       \
     .type = (type_), .str_regs = (regs), .scale = 1, .unit = "",             \
     .writable = true, .min = (min_), .max = (max_), .name = (name_),         \
     .description = (desc), .source = REGMAP_SRC_PATH, .path = (path_)}
/* Where one command's result shows: 24 input registers from 'base'. */
#define RESULT(base, cmd)                                                      \
    P_ROW(REGMAP_INPUT_REGISTER, (base), 1, REGMAP_U16, 0, "",                \
          "result_" cmd "_state", "result." cmd ".state",                     \
          cmd ": 0 idle, 1 pending, 2 done (accepted by the robot), 3 robot "  \
          "error, 4 reply timeout and 5 link lost after it was written: "      \
          "outcome unknown (the robot may have acted), 6 invalid, 7 refused, " \
          "8 not sent (the robot never received it)"),                         \
    P_ROW(REGMAP_INPUT_REGISTER, (base) + 1, 1, REGMAP_I32, 0, "",            \
          "result_" cmd "_error_code", "result." cmd ".error_code",           \
          cmd ": the robot's errorCode of the last reply"),                    \
    P_ROW(REGMAP_INPUT_REGISTER, (base) + 3, 1, REGMAP_STR, 20, "",           \
          "result_" cmd "_error_msg", "result." cmd ".error_msg",             \
          cmd ": the robot's errorMsg, or the gateway's reason"),              \
    P_ROW(REGMAP_INPUT_REGISTER, (base) + 23, 1, REGMAP_U16, 0, "",           \
          "result_" cmd "_count", "result." cmd ".count",                     \
          cmd ": triggers handled, whatever their outcome (sent, refused or "  \
          "invalid); wraps at 65535. A PLC reads it before its trigger and "   \
          "waits for it to change")

/* Bounds for float parameters: any finite value a controller could take. */
#define FMAX 1e9

const struct regmap_row regmap_table_rows[] = {
    /* ---- coils ---- */
    {.table = REGMAP_COIL, .address = 0, .elements = 1, .type = REGMAP_BOOL,
     .scale = 1, .unit = "", .writable = true, .min = 0, .max = 1,
     .name = "clear_counters", .write_class = REGMAP_CLASS_COUNTERS,
     .description = "Write 1 to reset the gateway's counters to 0; reads 0",
     .source = REGMAP_SRC_GW, .id = GW_clear_counters},

    /* ---- coils: command triggers (0 -> 1 sends; write 0 to re-arm) ---- */
    C_TRIGGER(100, POWER, "power_on", "Power on (4.1)"),
    C_TRIGGER(101, POWER, "power_off", "Power off (4.2)"),
    C_TRIGGER(102, POWER, "enable_robot", "Enable the robot (4.3)"),
    C_TRIGGER(103, POWER, "disable_robot", "Disable the robot (4.4)"),
    C_TRIGGER(104, POWER, "clear_error", "Recover from collision protection (4.48)"),
    C_TRIGGER(105, SHUTDOWN, "shutdown",
              "Shut down robot and controller (4.5); only with allow_shutdown"),
    C_TRIGGER(106, PROGRAMS, "load_program", "Load the program named in load_program_name (4.18)"),
    C_TRIGGER(107, PROGRAMS, "play_program", "Play the loaded program (4.20)"),
    C_TRIGGER(108, PROGRAMS, "pause_program", "Pause the program (4.21)"),
    C_TRIGGER(109, PROGRAMS, "resume_program", "Resume the program (4.22)"),
    C_TRIGGER(110, PROGRAMS, "stop_program", "Stop the program and any motion (4.23)"),
    C_TRIGGER(111, PAYLOAD, "set_payload", "Set the payload in set_payload_* (4.42)"),
    C_TRIGGER(112, MOTION, "joint_move",
              "Joint move to joint_move_* (4.7); only with [commands] motion"),
    C_TRIGGER(113, MOTION, "end_move",
              "TCP move to end_move_* (4.8); only with [commands] motion"),
    C_TRIGGER(114, MOTION, "moveL",
              "Linear move to movel_* (4.9); only with [commands] motion"),
    {.table = REGMAP_COIL, .address = 120, .elements = 1, .type = REGMAP_BOOL,
     .scale = 1, .unit = "", .writable = true, .min = 0, .max = 1,
     .name = "json_trigger", .source = REGMAP_SRC_PATH, .path = "json.trigger",
     .write_class = REGMAP_CLASS_MAILBOXES,
     .description = "JSON mailbox: 0 -> 1 sends the text in json_request"},
    /* ---- coils: the network-exception policy ---- */
    {.table = REGMAP_COIL, .address = 130, .elements = 1, .type = REGMAP_BOOL,
     .scale = 1, .unit = "", .writable = true, .min = 0, .max = 1,
     .name = "fault_reset", .source = REGMAP_SRC_PATH, .path = "fault_reset",
     .write_class = REGMAP_CLASS_FAULTS,
     .description = "Write 1 to clear the latched network-exception fault; reads 0"},
    {.table = REGMAP_COIL, .address = 131, .elements = 1, .type = REGMAP_BOOL,
     .scale = 1, .unit = "", .writable = true, .min = 0, .max = 1,
     .name = "motion_enable", .source = REGMAP_SRC_PATH, .path = "motion_enable",
     .write_class = REGMAP_CLASS_FAULTS,
     .description = "Hold at 1 for the robot to run (with [network_exception] "
                    "motion_enable); dropping it pauses the program at once"},
    /* ---- coils: outputs; each write sends set_digital_output (4.25) ---- */
    C_OUT(200, 16, 1, "cabinet_do_*", "\"type\": 0, \"index\": *",
          "Cabinet digital output * (type 0, index *)", "dout_*"),
    C_OUT(216, 2, 0, "tool_do_*", "\"type\": 1, \"index\": *",
          "Tool digital output * (type 1, index *)", "tio_dout_*"),
    C_OUT(224, 16, 0, "extio_do_*", "\"type\": 2, \"index\": *",
          "Extension IO digital output * (type 2, index *)", "extio_do_*"),

    /* ---- holding registers ---- */
    {.table = REGMAP_HOLDING_REGISTER, .address = 0, .elements = 1,
     .type = REGMAP_U16, .scale = 1, .unit = "", .writable = true, .min = 0,
     .max = 65535, .name = "plc_heartbeat", .write_class = REGMAP_CLASS_HEARTBEAT,
     .description = "PLC watchdog: write a changing value; its age is "
                    "plc_heartbeat_age_ms",
     .source = REGMAP_SRC_GW, .id = GW_plc_heartbeat},

    /* ---- holding registers: setpoints; each write sends its command ---- */
    C_SET(REGMAP_HOLDING_REGISTER, 100, SETPOINTS, 1, 0, REGMAP_U16, 1000, 0, 1000, "1/1000",
          "rapid_rate", "rapid_rate.rate_value", "",
          "Speed override in per mille, 0..1000 (4.17; sent as 0..1); read back "
          "from rapid_rate in the status"),
    C_SET(REGMAP_HOLDING_REGISTER, 101, SETPOINTS, 1, 0, REGMAP_U16, 1, 0, 10, "", "tool_id",
          "set_tool_id.tool_id", "", "Select tool frame 0..10 (4.30)"),
    C_SET(REGMAP_HOLDING_REGISTER, 102, SETPOINTS, 1, 0, REGMAP_U16, 1, 0, 10, "", "user_id",
          "set_user_id.user_frame_id", "", "Select user frame 0..10 (4.33)"),
    C_SET(REGMAP_HOLDING_REGISTER, 103, SETPOINTS, 1, 0, REGMAP_U16, 1, 0, 5, "",
          "collision_level", "set_clsn_sensitivity.sensitivityVal", "",
          "Collision sensitivity level 0..5 (4.44)"),
    C_SET(REGMAP_HOLDING_REGISTER, 110, OUTPUTS, 7, 1, REGMAP_F32, 1, -FMAX, FMAX, "",
          "cabinet_ao_*", "set_analog_output.value", "\"type\": 0, \"index\": *",
          "Cabinet analog output * (type 0, index *: the manual numbers them 1-7; 4.27)"),
    C_SET(REGMAP_HOLDING_REGISTER, 126, OUTPUTS, 8, 0, REGMAP_F32, 1, -FMAX, FMAX, "",
          "extio_ao_*", "set_analog_output.value", "\"type\": 2, \"index\": *",
          "Extension IO analog output * (type 2, index *; 4.27)"),
    /* ---- holding registers: parameters, sent by the command's trigger ---- */
    C_PARAM(150, PAYLOAD, 1, REGMAP_F32, 0, 0, FMAX, "kg", "set_payload_mass",
            "set_payload.mass", "Payload mass for set_payload"),
    C_PARAM(152, PAYLOAD, 3, REGMAP_F32, 0, -FMAX, FMAX, "mm", "set_payload_centroid_#",
            "set_payload.centroid[*]", "Payload centroid, coordinate # (x, y, z)"),
    C_PARAM(200, PROGRAMS, 1, REGMAP_STR, 32, 0, 0, "", "load_program_name",
            "load_program.programName",
            "Program to load, UTF-8 text, NUL-padded (e.g. track/test.jks)"),
    C_PARAM(300, MOTION, 6, REGMAP_F32, 0, -FMAX, FMAX, "deg", "joint_move_joint_#",
            "joint_move.jointPosition[*]", "joint_move target, joint #"),
    C_PARAM(312, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "deg/s", "joint_move_speed",
            "joint_move.speed", "joint_move speed"),
    C_PARAM(314, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "deg/s2", "joint_move_accel",
            "joint_move.accel", "joint_move acceleration"),
    C_PARAM(316, MOTION, 1, REGMAP_U16, 0, 0, 1, "", "joint_move_relative",
            "joint_move.relFlag", "joint_move: 0 absolute, 1 relative"),
    C_PARAM(320, MOTION, 6, REGMAP_F32, 0, -FMAX, FMAX, "mm, deg", "end_move_pose_#",
            "end_move.endPosition[*]", "end_move target, x y z rx ry rz: element #"),
    C_PARAM(332, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "deg/s", "end_move_speed",
            "end_move.speed", "end_move joint speed"),
    C_PARAM(334, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "deg/s2", "end_move_accel",
            "end_move.accel", "end_move joint acceleration"),
    C_PARAM(340, MOTION, 6, REGMAP_F32, 0, -FMAX, FMAX, "mm, deg", "movel_pose_#",
            "moveL.cartPosition[*]", "moveL target, x y z rx ry rz: element #"),
    C_PARAM(352, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "mm/s", "movel_speed", "moveL.speed",
            "moveL linear speed"),
    C_PARAM(354, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "mm/s2", "movel_accel", "moveL.accel",
            "moveL linear acceleration"),
    C_PARAM(356, MOTION, 1, REGMAP_U16, 0, 0, 1, "", "movel_relative", "moveL.relFlag",
            "moveL: 0 absolute, 1 relative"),
    C_PARAM(358, MOTION, 1, REGMAP_F32, 0, 0, FMAX, "mm", "movel_tol", "moveL.tol",
            "moveL: maximum permissible error, 0 if not needed"),
    /* ---- holding registers: the exactly-once mailbox ---- */
    P_HOLD(400, MAILBOXES, 1, REGMAP_U16, 0, 65535, 0, "mailbox_code", "mailbox.code",
           "Exactly-once mailbox: command code (see the PLC guide)"),
    P_HOLD(401, MAILBOXES, 12, REGMAP_F32, -FMAX, FMAX, 0, "mailbox_arg_#", "mailbox.arg[*]",
           "Exactly-once mailbox: argument #"),
    P_HOLD(425, MAILBOXES, 1, REGMAP_U16, 0, 65535, 0, "mailbox_seq", "mailbox.seq",
           "Exactly-once mailbox: write a new number last (in the same write) "
           "to run the command once"),
    /* ---- holding registers: the JSON mailbox ---- */
    P_HOLD(500, MAILBOXES, 1, REGMAP_STR, 0, 0, 120, "json_request", "json.request",
           "JSON mailbox: a whole command as UTF-8 text, NUL-padded, written in "
           "one write (up to 240 bytes)"),

    /* ---- discrete inputs: gateway ---- */
    G_DI(0, status_link_up, "Status port (10000) connected"),
    G_DI(1, command_link_up,
         "Command port (10001) connected and answering (a reply on this connection; "
         "an idle link is checked every link_check_ms)"),
    G_DI(2, status_fresh,
         "A status document arrived within status_timeout_ms: data is live"),

    /* ---- discrete inputs: robot flags ---- */
    S_DI(16, drag_status, 1, "drag_status", "Robot is in drag (hand-guiding) mode"),
    S_DI(17, enabled, 1, "enabled", "Robot is enabled"),
    S_DI(18, paused, 1, "paused", "Program is paused"),
    S_DI(19, inpos, 1, "inpos", "Robot is in position (not moving)"),
    S_DI(20, on_soft_limit, 1, "on_soft_limit", "Robot is on a soft limit"),
    S_DI(21, emergency_stop, 1, "emergency_stop", "Emergency stop is triggered"),
    S_DI(22, powered_on, 1, "powered_on", "Robot is powered on"),
    S_DI(23, protective_stop, 1, "protective_stop", "Robot is in protective stop"),
    S_DI(32, homed, 16, "homed_#", "Joint # homed (obsolete)"),
    S_DI(48, drag_near_limit, 8, "drag_near_limit_#",
         "Joint # dragged near its limit"),
    S_DI(64, tio_din, 8, "tio_din_*", "Tool digital input *"),
    S_DI(72, tio_dout, 8, "tio_dout_*", "Tool digital output *"),
    S_DI(80, tio_key, 4, "tio_key_*", "Tool button * (not in the manual)"),
    S_DI(84, relay_io, 4, "relay_io_*", "Relay output * (not in the manual)"),
    S_DI(128, extio_di, 64, "extio_di_*", "Extension IO digital input *"),
    S_DI(192, extio_do, 64, "extio_do_*", "Extension IO digital output *"),
    S_DI(256, din, 256, "din_*", "Cabinet digital input *"),
    S_DI(512, dout, 256, "dout_*", "Cabinet digital output *"),
    S_DI(768, mb_slave_din, 128, "mb_slave_din_*",
         "Modbus slave digital input * (not in the manual)"),
    S_DI(896, mb_slave_dout, 128, "mb_slave_dout_*",
         "Modbus slave digital output * (not in the manual)"),
    S_DI(1024, pn_dev_din, 64, "pn_dev_din_*",
         "PROFINET device digital input * (not in the manual)"),
    S_DI(1088, pn_dev_dout, 64, "pn_dev_dout_*",
         "PROFINET device digital output * (not in the manual)"),
    S_DI(1152, eip_adpt_din, 64, "eip_adpt_din_*",
         "EtherNet/IP adapter digital input * (not in the manual)"),
    S_DI(1216, eip_adpt_dout, 64, "eip_adpt_dout_*",
         "EtherNet/IP adapter digital output * (not in the manual)"),
    /* 1536..: one presence bit per status field, generated (regmap.c). */

    /* ---- input registers: self-description ---- */
    G_IR(0, map_magic, REGMAP_U16, "",
         "0x4A4B ('JK'): this is a jakagw map at the expected address"),
    G_IR(1, map_version, REGMAP_U16, "", "Register map version"),
    G_IR(2, map_crc, REGMAP_U32, "",
         "CRC-32 of the map's CSV listing: changes with any layout change"),
    G_IR(4, word_order, REGMAP_U16, "",
         "Word order of 32-bit values: 0 high word first (ABCD), 1 low word first (CDAB)"),
    G_IR(5, address_base, REGMAP_U16, "",
         "Wire address of the first register: always 0 (PLC notation adds 1)"),
    G_IR(6, probe_f32, REGMAP_F32, "",
         "Always -1234.5: read it to check float word order"),
    G_IR(8, probe_u32, REGMAP_U32, "",
         "Always 0x01020304 (16909060): read it to check 32-bit word order"),
    G_IR(10, version_major, REGMAP_U16, "", "Gateway version, major"),
    G_IR(11, version_minor, REGMAP_U16, "", "Gateway version, minor"),
    G_IR(12, version_patch, REGMAP_U16, "", "Gateway version, patch"),
    G_IR(13, status_sequence, REGMAP_U16, "",
         "One more per status document parsed; wraps at 65535, never cleared: a "
         "PLC that reads a new value knows its image was refreshed from a new "
         "document (its stale check)"),
    G_IR(14, start_id, REGMAP_U16, "",
         "A number drawn when the gateway starts: another one than before means "
         "the gateway restarted and lost what it was written (write it again)"),

    /* ---- input registers: gateway diagnostics ---- */
    G_IR(16, status_link_state, REGMAP_U16, "",
         "Status port: 0 disconnected, 1 connecting, 2 connected, 3 connected but silent"),
    G_IR(17, command_link_state, REGMAP_U16, "",
         "Command port: 0 disconnected, 1 connecting, 2 connected and answering, "
         "3 connected but no reply on this connection yet"),
    G_IR(18, status_age_ms, REGMAP_U32, "ms",
         "Time since the last status document was parsed; 4294967295 if none yet"),
    G_IR(20, documents_parsed, REGMAP_U32, "", "Status documents parsed"),
    G_IR(22, parse_errors, REGMAP_U32, "",
         "Framed status documents that were not a JSON object"),
    G_IR(24, framing_errors, REGMAP_U32, "",
         "Garbage runs, oversize and cut-short documents on the status stream"),
    G_IR(26, oversize_documents, REGMAP_U32, "",
         "Status documents dropped for exceeding max_document_bytes"),
    G_IR(28, garbage_bytes, REGMAP_U32, "bytes",
         "Bytes skipped outside documents on the status stream"),
    G_IR(30, len_mismatches, REGMAP_U32, "",
         "Documents whose \"len\" disagreed with their real end"),
    G_IR(32, status_reconnects, REGMAP_U32, "",
         "Status port connections made after the first"),
    G_IR(34, command_reconnects, REGMAP_U32, "",
         "Command port connections made after the first"),
    G_IR(36, modbus_requests, REGMAP_U32, "", "Modbus requests answered"),
    G_IR(38, modbus_exceptions, REGMAP_U32, "",
         "Modbus requests answered with an exception"),
    G_IR(40, modbus_clients, REGMAP_U16, "", "Modbus clients connected now"),
    G_IR(42, modbus_evictions, REGMAP_U32, "",
         "Idle Modbus clients closed to admit a new one at max_clients"),
    G_IR(44, uptime_s, REGMAP_U32, "s", "Gateway uptime"),
    G_IR(46, last_document_bytes, REGMAP_U32, "bytes",
         "Size of the last status document"),
    G_IR(48, plc_heartbeat_age_ms, REGMAP_U32, "ms",
         "Time since holding register plc_heartbeat last changed; 4294967295 if never"),
    G_IR(50, can_state, REGMAP_U16, "",
         "CAN mirror: 0 off, 1 sending, 2 transmit queue full, 3 bus-off, "
         "4 interface down, 5 interface absent, 6 other error"),
    G_IR(52, can_frames_sent, REGMAP_U32, "", "CAN frames sent"),
    G_IR(54, can_frames_dropped, REGMAP_U32, "",
         "CAN frames due but not sent (queue full, interface down or absent)"),
    G_IR(56, can_errors, REGMAP_U32, "",
         "CAN send, open and poll failures and bus-off reports"),
    G_IR(58, link_checks, REGMAP_U32, "",
         "Command link checks sent (get_robot_state after link_check_ms idle)"),
    G_IR(98, link_checks_failed, REGMAP_U32, "",
         "Command link checks unanswered within min(reply_timeout_ms, link_check_ms): "
         "each restarted the link"),
    /* ---- input registers: the network-exception policy ---- */
    P_ROW(REGMAP_INPUT_REGISTER, 60, 1, REGMAP_U16, 0, "", "fault", "fault",
          "Latched network-exception fault: 0 none, 1 PLC heartbeat lost, 2 no "
          "Modbus client, 3 motion enable dropped, 4 the gateway's own loop stalled; "
          "commands but stop are refused"),
    P_ROW(REGMAP_INPUT_REGISTER, 61, 1, REGMAP_U32, 0, "ms", "fault_age_ms",
          "fault_age_ms", "Time since the fault latched; 0 when none"),
    P_ROW(REGMAP_INPUT_REGISTER, 63, 1, REGMAP_U16, 0, "", "faults", "faults",
          "Network-exception faults latched since start (wraps at 65535)"),
    P_ROW(REGMAP_INPUT_REGISTER, 64, 1, REGMAP_U16, 0, "", "robot_handle",
          "network_exception.robot_handle",
          "The robot's own network-exception handler: 0 not set (no command "
          "link), 1 pending, 2 accepted, 3 refused or unanswered (a fault)"),
    P_ROW(REGMAP_INPUT_REGISTER, 65, 1, REGMAP_U16, 0, "", "motion_enabled",
          "motion_enabled", "The motion-enable coil as the policy sees it"),
    P_ROW(REGMAP_INPUT_REGISTER, 66, 1, REGMAP_STR, 24, "", "write_owner",
          "write_owner", "Address of the client that owns the write side; empty: none"),

    /* ---- input registers: motion and the policy's reaction ---- */
    P_ROW(REGMAP_INPUT_REGISTER, 5600, 1, REGMAP_U16, 0, "", "motion_state",
          "motion.state", "Last motion command: 0 none yet, 1 moving (from its reply on), "
          "2 arrived (a later status shows it in position at its target), 3 stopped "
          "before arriving (stop, fault, e-stop, robot error), 4 not arrived in time"),
    P_ROW(REGMAP_INPUT_REGISTER, 5601, 1, REGMAP_U16, 0, "", "motion_count",
          "motion.count", "Motion commands sent (joint_move, end_move, moveL, from a "
          "trigger or a mailbox); wraps at 65535"),
    P_ROW(REGMAP_INPUT_REGISTER, 5602, 1, REGMAP_U16, 0, "", "fault_reaction",
          "network_exception.reaction", "What the robot did about the latched fault: "
          "0 nothing due (no fault, or idle), 1 flag only (action keep), 2 action sent, "
          "awaiting the status, 3 paused, 4 stopped, 5 still moving: stop sent, "
          "6 still moving after the stop (see the page)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5603, 1, REGMAP_U16, 0, "", "plc_heartbeat_state",
          "plc_heartbeat_state", "The PLC heartbeat: 0 never seen changing (motion "
          "refused with require_heartbeat), 1 running, 2 lost"),

    /* ---- input registers: Modbus/TCP Security (mbaps, [tls]) ---- */
    G_IR(90, tls_clients, REGMAP_U16, "", "Modbus/TCP Security clients connected now"),
    G_IR(91, tls_handshakes_running, REGMAP_U16, "",
         "TLS handshakes running now (at most [tls] max_handshakes)"),
    G_IR(92, tls_handshakes_ok, REGMAP_U32, "", "TLS handshakes completed"),
    G_IR(94, tls_failed_total, REGMAP_U32, "",
         "TLS handshakes failed or refused, every reason (input registers 5500-5513)"),
    G_IR(5500, tls_failed_no_certificate, REGMAP_U32, "",
         "TLS handshakes failed: the client sent no certificate"),
    G_IR(5502, tls_failed_untrusted, REGMAP_U32, "",
         "TLS handshakes failed: certificate not from client_ca (or a bad signature)"),
    G_IR(5504, tls_failed_expired, REGMAP_U32, "",
         "TLS handshakes failed: certificate expired or not yet valid"),
    G_IR(5506, tls_failed_revoked, REGMAP_U32, "",
         "TLS handshakes failed: certificate revoked by the crl"),
    G_IR(5508, tls_failed_protocol, REGMAP_U32, "",
         "TLS handshakes failed: not TLS, TLS 1.0/1.1, no shared cipher, renegotiation"),
    G_IR(5510, tls_failed_timeout, REGMAP_U32, "",
         "TLS handshakes not finished within handshake_timeout_ms"),
    G_IR(5512, tls_failed_over_limit, REGMAP_U32, "",
         "TLS connections closed at once: max_handshakes were running"),
    G_IR(96, status_link_tls_failure, REGMAP_U16, "",
         "[robot] tls: why the last handshake on the status port failed: 0 none (or "
         "plain TCP), 2 certificate not trusted by tls_ca (or its name), 3 expired or "
         "not yet valid, 5 protocol (not TLS, no shared version), 6 timeout, "
         "8 tls_fingerprint mismatch; 0 again once a handshake succeeds"),
    G_IR(97, command_link_tls_failure, REGMAP_U16, "",
         "[robot] tls: the same for the command port"),

    /* ---- input registers: the gateway's own health ---- */
    G_IR(5520, status_stale_ms, REGMAP_U32, "ms",
         "How long the status has been stale, reconnects included: from when it went "
         "stale until documents have flowed with no gap for 2 x status_timeout_ms; "
         "0 while healthy"),
    G_IR(5522, loop_stalls, REGMAP_U32, "",
         "Gateway loop stalls: a gap between loop turns longer than time_limit_ms "
         "(network-exception fault 4 when the robot may move)"),
    G_IR(5524, loop_stall_last_ms, REGMAP_U32, "ms", "Length of the last loop stall"),
    /* ---- input registers: Modbus RTU on the serial line ([rtu]) ---- */
    G_IR(5540, rtu_line_state, REGMAP_U16, "",
         "Serial line: 0 off ([rtu] enabled = false), 1 open, no request for this unit "
         "within time_limit_ms, 2 open and polled, 3 device absent or failed (opened "
         "again every second)"),
    G_IR(5542, rtu_frames, REGMAP_U32, "",
         "RTU frames with a good CRC on the line, for every unit"),
    G_IR(5544, rtu_crc_errors, REGMAP_U32, "",
         "RTU byte runs dropped for a bad CRC (noise, a frame cut short)"),
    G_IR(5546, rtu_foreign_frames, REGMAP_U32, "",
         "RTU frames for other unit ids, skipped"),
    G_IR(5548, rtu_broadcasts, REGMAP_U32, "",
         "RTU broadcasts (unit 0): counted, never acted on"),
    G_IR(5550, rtu_overruns, REGMAP_U32, "",
         "RTU receive or send buffer overruns (bytes dropped up to the next silence)"),
    G_IR(5552, rtu_gap_discards, REGMAP_U32, "",
         "RTU frames discarded for a silence over 1.5 characters inside them"),
    G_IR(5554, rtu_turnaround_us, REGMAP_U32, "us",
         "The last RTU reply: from the request's last byte read to the reply written, "
         "the 3.5-character silence included"),
    G_IR(5556, rtu_turnaround_max_us, REGMAP_U32, "us",
         "The longest RTU turnaround since start or the last counter reset"),
    G_IR(5558, rtu_echoes, REGMAP_U32, "",
         "RTU replies of ours read back from the line and skipped: with local_echo = true "
         "the one echo of each reply; with false, a frame equal to the last reply within "
         "the delivery bound (rtu_delivery_ms) once it was answered again (a hint to set "
         "local_echo = true is logged once)"),
    G_IR(5560, rtu_collisions, REGMAP_U32, "",
         "local_echo = true: a reply read back different from what was sent (another "
         "sender on the line at the same time, or noise)"),
    G_IR(5562, rtu_out_of_turn, REGMAP_U32, "",
         "RTU frames begun before our reply's wire time + t3.5 that were not our reply "
         "heard back: served all the same (a master that does not keep the 3.5-character "
         "silence)"),
    G_IR(5564, rtu_delivery_ms, REGMAP_U16, "ms",
         "The serial adapter's delivery bound: how late it may hand over bytes it received "
         "(a USB adapter's latency timer, read back from sysfs after setting it to 1 ms; "
         "else [rtu] delivery_ms). A gap the host sees shorter than this is never a "
         "silence, and a frame equal to the last reply within it is answered again, "
         "not acted on again; 0 while the line is off or down"),
    G_IR(5566, rtu_repeats, REGMAP_U32, "",
         "local_echo = false: a frame equal to our last reply (an FC05 or FC06 write) "
         "within the delivery bound, answered again and not acted on again (a master "
         "that retries at once, or our reply heard back: see rtu_echoes)"),
    G_IR(5568, rtu_exceptions, REGMAP_U32, "",
         "RTU frames in an exception's form addressed to this unit (our own exception "
         "reply heard back, or another device answering as this unit): counted and "
         "skipped, never a request"),

    /* ---- input registers: robot state ---- */
    S_IR(100, task_state, 1, REGMAP_U16, "", "task_state",
         "1 powered off, 2 powered on, 3 disabled, 4 enabled"),
    S_IR(101, task_mode, 1, REGMAP_U16, "", "task_mode",
         "1 manual, 2 automatic, 3 reserved, 4 drag"),
    S_IR(102, interp_state, 1, REGMAP_U16, "", "interp_state",
         "Program: 0 idle, 1 loading, 2 paused, 3 running"),
    S_IR(103, motion_mode, 1, REGMAP_U16, "", "motion_mode", "Motion mode (obsolete)"),
    S_IR(104, current_tool_id, 1, REGMAP_U16, "", "current_tool_id",
         "Index of the current tool frame"),
    S_IR(105, current_user_id, 1, REGMAP_U16, "", "current_user_id",
         "Index of the current user frame"),
    S_IR(106, point_key, 1, REGMAP_U16, "", "point_key",
         "Tool point button: 0 pressed, otherwise released"),
    S_IR(107, net_state, 1, REGMAP_U16, "", "net_state",
         "Socket connection state (obsolete)"),
    S_IR(108, len, 1, REGMAP_U32, "bytes", "len", "Document length the controller declared"),
    S_IR(110, errcode, 1, REGMAP_U32, "", "errcode", "Controller error code (0 none)"),
    S_IR(112, rapidrate, 1, REGMAP_F32, "", "rapidrate", "Speed override, 0 to 1"),
    S_IRS(114, rapidrate, REGMAP_U16, 1000, "permille", "rapidrate_permille",
          "Speed override in 1/1000"),
    S_IR(116, curr_tcp_trans_vel, 1, REGMAP_F32, "mm/s", "curr_tcp_trans_vel",
         "TCP speed"),
    S_IR(118, motion_line, 1, REGMAP_I32, "", "motion_line",
         "Program line in motion (not in the manual)"),
    S_IR(120, err_add_line, 1, REGMAP_I32, "", "err_add_line",
         "Program line of the error (not in the manual)"),
    S_STR(130, errmsg, 1, 64, "errmsg", "Controller error message (128 chars)"),

    /* ---- input registers: positions ---- */
    S_IR(200, joint_actual_position, 6, REGMAP_F32, "deg",
         "joint_actual_position_#", "Joint # actual position"),
    S_IR(212, actual_position, 6, REGMAP_F32, "mm|deg", "actual_position_*",
         "TCP actual pose [x,y,z,rx,ry,rz] element *"),
    S_IR(224, joint_position, 6, REGMAP_F32, "deg", "joint_position_#",
         "Joint # commanded position (not in the manual)"),
    S_IR(236, position, 6, REGMAP_F32, "mm|deg", "position_*",
         "TCP commanded pose element * (not in the manual)"),
    S_IR(248, inst_vel, 6, REGMAP_F32, "deg/s", "inst_vel_#",
         "Joint # instantaneous velocity (not in the manual)"),

    /* ---- input registers: monitor data ---- */
    S_IR(300, scb_major, 1, REGMAP_U16, "", "scb_major", "SCB major version"),
    S_IR(301, scb_minor, 1, REGMAP_U16, "", "scb_minor", "SCB minor version"),
    S_IR(302, cabinet_temperature, 1, REGMAP_F32, "degC", "cabinet_temperature",
         "Control cabinet temperature"),
    S_IR(304, cabinet_power, 1, REGMAP_F32, "W", "cabinet_power",
         "Control cabinet bus average power"),
    S_IR(306, cabinet_current, 1, REGMAP_F32, "A", "cabinet_current",
         "Control cabinet bus average current"),
    S_IR(308, monitor_extra, 4, REGMAP_F32, "", "monitor_data_*",
         "monitor_data[*] (undocumented)"),
    S_JOINT(320, joint_current, "A", "j#_current", "Joint # instantaneous current"),
    S_JOINT(322, joint_voltage, "V", "j#_voltage", "Joint # instantaneous voltage"),
    S_JOINT(324, joint_temperature, "degC", "j#_temperature", "Joint # temperature"),
    S_JOINT(326, joint_power, "W", "j#_power", "Joint # average power"),
    S_JOINT(328, joint_current_fluctuation, "", "j#_current_fluctuation",
            "Joint # current fluctuation"),
    S_JOINT(330, joint_total_turns, "", "j#_total_turns",
            "Joint # cumulative running circles"),
    S_JOINT(332, joint_total_time, "", "j#_total_time",
            "Joint # cumulative running time"),
    S_JOINT(334, joint_boot_turns, "", "j#_boot_turns",
            "Joint # running circles since boot"),
    S_JOINT(336, joint_boot_time, "", "j#_boot_time", "Joint # running time since boot"),
    S_JOINT(338, joint_torque, "Nm", "j#_torque", "Joint # torque"),
    S_JOINT(340, joint_monitor_extra, "", "j#_monitor_10",
            "Joint # monitor value 10 (undocumented)"),

    /* ---- input registers: torque sensor ---- */
    S_IR(460, torq_comm_type, 1, REGMAP_U16, "", "torq_comm_type",
         "Torque sensor link: 0 TCP/IP, 1 serial"),
    S_STR(461, torq_address, 1, 8, "torq_address",
          "Torque sensor IP address (or baud rate, serial)"),
    S_IR(469, torq_comm, 3, REGMAP_U32, "", "torq_comm_*",
         "Torque sensor link parameter * (port, or serial settings)"),
    S_IR(475, torq_payload_mass, 1, REGMAP_F32, "kg", "torq_payload_mass",
         "Payload mass at the torque sensor"),
    S_IR(477, torq_payload_centroid, 3, REGMAP_F32, "mm", "torq_payload_centroid_*",
         "Payload centroid element *"),
    S_IR(483, torq_status, 1, REGMAP_U16, "", "torq_status",
         "Torque sensor: 1 working, 0 off"),
    S_IR(484, torq_errcode, 1, REGMAP_I32, "", "torq_errcode", "Torque sensor error code"),
    S_IR(486, torq_force, 6, REGMAP_F32, "N|Nm", "torq_force_*",
         "Torque sensor contact force element *"),
    S_IR(498, torq_raw, 6, REGMAP_F32, "", "torq_raw_*",
         "Torque sensor raw reading element *"),
    S_IR(510, torq_extra, 6, REGMAP_F32, "", "torq_extra_*",
         "torqsensor[1][4] element * (undocumented)"),

    /* ---- input registers: function DIs ---- */
    S_IR(600, funcdi_type, 16, REGMAP_I16, "", "funcdi_*_type",
         "Function DI * source: 0 cabinet, 1 tool, 2 extension, -1 none"),
    S_IR(616, funcdi_index, 16, REGMAP_I16, "", "funcdi_*_index",
         "Function DI * pin index, -1 none"),
    S_IR(640, tio_ain, 4, REGMAP_F32, "", "tio_ain_*", "Tool analog input *"),

    /* ---- input registers: extension IO ---- */
    S_IR(660, extio_num, 1, REGMAP_U16, "", "extio_num", "Extension IO modules"),
    S_IR(661, extio_mode, 1, REGMAP_U16, "", "extio_mode",
         "Extension IO: 0 running, 1 off"),
    S_IR(662, extio_comm_type, 8, REGMAP_U16, "", "extio_*_comm_type",
         "Extension module * link: 0 Modbus RTU, 1 Modbus TCP"),
    S_STR(670, extio_alias, 8, 8, "extio_*_alias", "Extension module * name"),
    S_STR(734, extio_comm_0, 8, 8, "extio_*_address",
          "Extension module * IP address (TCP) or baud rate (RTU)"),
    S_IR(798, extio_comm_1, 8, REGMAP_U32, "", "extio_*_comm_1",
         "Extension module * port (TCP) or data bits (RTU)"),
    S_IR(814, extio_comm_2, 8, REGMAP_U32, "", "extio_*_comm_2",
         "Extension module * slave id"),
    S_IR(830, extio_comm_3, 8, REGMAP_U32, "", "extio_*_comm_3",
         "Extension module * data bits (RTU)"),
    S_IR(846, extio_comm_4, 8, REGMAP_U32, "", "extio_*_comm_4",
         "Extension module * parity (RTU)"),
    S_IR(862, extio_comm_5, 8, REGMAP_U32, "", "extio_*_comm_5",
         "Extension module * stop bits (RTU)"),
    S_IR(878, extio_di_start, 8, REGMAP_U32, "", "extio_*_di_start",
         "Extension module * first DI register"),
    S_IR(894, extio_di_count, 8, REGMAP_U32, "", "extio_*_di_count",
         "Extension module * DI count"),
    S_IR(910, extio_do_start, 8, REGMAP_U32, "", "extio_*_do_start",
         "Extension module * first DO register"),
    S_IR(926, extio_do_count, 8, REGMAP_U32, "", "extio_*_do_count",
         "Extension module * DO count"),
    S_IR(942, extio_ai_start, 8, REGMAP_U32, "", "extio_*_ai_start",
         "Extension module * first AI register"),
    S_IR(958, extio_ai_count, 8, REGMAP_U32, "", "extio_*_ai_count",
         "Extension module * AI count"),
    S_IR(974, extio_ao_start, 8, REGMAP_U32, "", "extio_*_ao_start",
         "Extension module * first AO register"),
    S_IR(990, extio_ao_count, 8, REGMAP_U32, "", "extio_*_ao_count",
         "Extension module * AO count"),
    S_IR(1006, extio_pinmap_di, 8, REGMAP_U32, "", "extio_*_pinmap_di",
         "Extension module * DI pin offset"),
    S_IR(1022, extio_pinmap_do, 8, REGMAP_U32, "", "extio_*_pinmap_do",
         "Extension module * DO pin offset"),
    S_IR(1038, extio_pinmap_ai, 8, REGMAP_U32, "", "extio_*_pinmap_ai",
         "Extension module * AI pin offset"),
    S_IR(1054, extio_pinmap_ao, 8, REGMAP_U32, "", "extio_*_pinmap_ao",
         "Extension module * AO pin offset"),
    S_IR(1100, extio_ai, 32, REGMAP_F32, "", "extio_ai_*", "Extension analog input *"),
    S_IR(1164, extio_ao, 32, REGMAP_F32, "", "extio_ao_*", "Extension analog output *"),

    /* ---- input registers: cabinet and fieldbus analog IO ---- */
    S_IR(1300, ain, 128, REGMAP_F32, "", "ain_*", "Cabinet analog input *"),
    S_IR(1556, aout, 128, REGMAP_F32, "", "aout_*", "Cabinet analog output *"),
    S_IR(1900, mb_slave_ain, 64, REGMAP_F32, "", "mb_slave_ain_*",
         "Modbus slave analog input * (not in the manual)"),
    S_IR(2028, mb_slave_aout, 64, REGMAP_F32, "", "mb_slave_aout_*",
         "Modbus slave analog output * (not in the manual)"),
    S_IR(2200, pn_dev_ain, 64, REGMAP_F32, "", "pn_dev_ain_*",
         "PROFINET device analog input * (not in the manual)"),
    S_IR(2328, pn_dev_aout, 64, REGMAP_F32, "", "pn_dev_aout_*",
         "PROFINET device analog output * (not in the manual)"),
    S_IR(2500, eip_adpt_ain, 64, REGMAP_F32, "", "eip_adpt_ain_*",
         "EtherNet/IP adapter analog input * (not in the manual)"),
    S_IR(2628, eip_adpt_aout, 64, REGMAP_F32, "", "eip_adpt_aout_*",
         "EtherNet/IP adapter analog output * (not in the manual)"),

    /* ---- input registers: tool RS485 signals (not in the manual) ---- */
    S_STR(2800, tio_rs_name, 8, 8, "tio_rs_*_name", "Tool RS485 signal * name"),
    S_IR(2864, tio_rs_1, 8, REGMAP_I32, "", "tio_rs_*_1", "Tool RS485 signal * field 1"),
    S_IR(2880, tio_rs_2, 8, REGMAP_I32, "", "tio_rs_*_2", "Tool RS485 signal * field 2"),
    S_IR(2896, tio_rs_3, 8, REGMAP_I32, "", "tio_rs_*_3", "Tool RS485 signal * field 3"),
    S_IR(2912, tio_rs_4, 8, REGMAP_I32, "", "tio_rs_*_4", "Tool RS485 signal * field 4"),
    S_IR(2928, tio_rs_value, 8, REGMAP_F32, "", "tio_rs_*_value",
         "Tool RS485 signal * value"),
    /* 3000..: one element count per status field, generated (regmap.c). */

    /* ---- input registers: command results, 24 registers each ---- */
    RESULT(4000, "power_on"),
    RESULT(4024, "power_off"),
    RESULT(4048, "enable_robot"),
    RESULT(4072, "disable_robot"),
    RESULT(4096, "clear_error"),
    RESULT(4120, "shutdown"),
    RESULT(4144, "load_program"),
    RESULT(4168, "play_program"),
    RESULT(4192, "pause_program"),
    RESULT(4216, "resume_program"),
    RESULT(4240, "stop_program"),
    RESULT(4264, "rapid_rate"),
    RESULT(4288, "set_digital_output"),
    RESULT(4312, "set_analog_output"),
    RESULT(4336, "set_tool_id"),
    RESULT(4360, "set_user_id"),
    RESULT(4384, "set_payload"),
    RESULT(4408, "set_clsn_sensitivity"),
    RESULT(4432, "joint_move"),
    RESULT(4456, "end_move"),
    RESULT(4480, "moveL"),
    /* ---- input registers: mailboxes ---- */
    P_ROW(REGMAP_INPUT_REGISTER, 4600, 1, REGMAP_U16, 0, "", "mailbox_ack_seq",
          "mailbox.ack_seq", "Exactly-once mailbox: the sequence number accepted"),
    P_ROW(REGMAP_INPUT_REGISTER, 4601, 1, REGMAP_U16, 0, "", "mailbox_done_seq",
          "mailbox.done_seq", "Exactly-once mailbox: the sequence number finished"),
    P_ROW(REGMAP_INPUT_REGISTER, 4602, 1, REGMAP_U16, 0, "", "mailbox_state",
          "mailbox.state", "Exactly-once mailbox: state, as result_*_state"),
    P_ROW(REGMAP_INPUT_REGISTER, 4603, 1, REGMAP_I32, 0, "", "mailbox_error_code",
          "mailbox.error_code", "Exactly-once mailbox: the robot's errorCode"),
    P_ROW(REGMAP_INPUT_REGISTER, 4605, 1, REGMAP_STR, 20, "", "mailbox_error_msg",
          "mailbox.error_msg", "Exactly-once mailbox: errorMsg or the gateway's reason"),
    P_ROW(REGMAP_INPUT_REGISTER, 4625, 1, REGMAP_U16, 0, "", "mailbox_count",
          "mailbox.count", "Exactly-once mailbox: writes of a sequence number handled, "
          "whatever their outcome; wraps at 65535"),
    P_ROW(REGMAP_INPUT_REGISTER, 4650, 1, REGMAP_U16, 0, "", "json_state",
          "json.state", "JSON mailbox: state, as result_*_state"),
    P_ROW(REGMAP_INPUT_REGISTER, 4651, 1, REGMAP_I32, 0, "", "json_error_code",
          "json.error_code", "JSON mailbox: the robot's errorCode"),
    P_ROW(REGMAP_INPUT_REGISTER, 4653, 1, REGMAP_STR, 20, "", "json_error_msg",
          "json.error_msg", "JSON mailbox: errorMsg or the gateway's reason"),
    P_ROW(REGMAP_INPUT_REGISTER, 4673, 1, REGMAP_U16, 0, "", "json_reply_truncated",
          "json.reply_truncated", "JSON mailbox: 1 when the reply is longer than json_reply"),
    P_ROW(REGMAP_INPUT_REGISTER, 4674, 1, REGMAP_U32, 0, "bytes", "json_reply_length",
          "json.reply_length", "JSON mailbox: the whole reply's length"),
    P_ROW(REGMAP_INPUT_REGISTER, 4676, 1, REGMAP_U16, 0, "", "json_count",
          "json.count", "JSON mailbox: triggers handled, whatever their outcome; "
          "wraps at 65535"),
    P_ROW(REGMAP_INPUT_REGISTER, 4700, 1, REGMAP_STR, 256, "", "json_reply",
          "json.reply", "JSON mailbox: the reply, UTF-8 text (its first 512 bytes)"),
    /* ---- input registers: robot information from the command port ---- */
    P_ROW(REGMAP_INPUT_REGISTER, 5000, 1, REGMAP_U32, 0, "ms", "info_age_ms",
          "info.age_ms", "Time since the robot information below was last fetched"),
    P_ROW(REGMAP_INPUT_REGISTER, 5002, 1, REGMAP_STR, 32, "", "loaded_program",
          "info.loaded_program", "Loaded program name (get_loaded_program, 4.19)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5034, 1, REGMAP_U16, 0, "", "program_state",
          "info.program_state", "Program state: 0 idle, 1 running, 2 paused (4.24)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5035, 1, REGMAP_STR, 16, "", "controller_version",
          "info.controller_version", "Controller version (get_version, 4.51)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5052, 1, REGMAP_F32, 0, "kg", "payload_mass",
          "info.payload_mass", "Payload mass (get_payload, 4.43)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5054, 3, REGMAP_F32, 0, "mm", "payload_centroid_#",
          "info.payload_centroid[*]", "Payload centroid, coordinate # (x, y, z)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5060, 1, REGMAP_U16, 0, "", "collision_level",
          "info.collision_level", "Collision sensitivity level (4.45)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5061, 1, REGMAP_U16, 0, "", "robot_enabled",
          "info.robot_enabled",
          "Robot enabled, 0 or 1, as the last command link check's reply says "
          "(get_robot_state, 4.12)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5062, 1, REGMAP_U16, 0, "", "robot_powered_on",
          "info.robot_powered_on",
          "Robot powered on, 0 or 1, as the last command link check's reply says"),
    P_ROW(REGMAP_INPUT_REGISTER, 5100, 66, REGMAP_F32, 0, "mm, deg", "tool_offset_#",
          "info.tool_offsets[*]",
          "Tool frames 0-10 (4.29), six values each (x y z rx ry rz): value #"),
    P_ROW(REGMAP_INPUT_REGISTER, 5240, 66, REGMAP_F32, 0, "mm, deg", "user_offset_#",
          "info.user_offsets[*]",
          "User frames 0-10 (4.32), six values each (x y z rx ry rz): value #"),
    P_ROW(REGMAP_INPUT_REGISTER, 5380, 6, REGMAP_F32, 0, "", "dh_alpha_#",
          "info.dh_alpha[*]", "DH parameter alpha of joint #, as the controller reports it (4.82)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5392, 6, REGMAP_F32, 0, "mm", "dh_a_#", "info.dh_a[*]",
          "DH parameter a of joint # (4.82)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5404, 6, REGMAP_F32, 0, "mm", "dh_d_#", "info.dh_d[*]",
          "DH parameter d of joint # (4.82)"),
    P_ROW(REGMAP_INPUT_REGISTER, 5416, 6, REGMAP_F32, 0, "", "dh_joint_homeoff_#",
          "info.dh_joint_homeoff[*]", "Home offset of joint # (4.82)"),
};

const unsigned regmap_table_row_count =
    sizeof(regmap_table_rows) / sizeof(regmap_table_rows[0]);
