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

const struct regmap_row regmap_table_rows[] = {
    /* ---- coils ---- */
    {.table = REGMAP_COIL, .address = 0, .elements = 1, .type = REGMAP_BOOL,
     .scale = 1, .unit = "", .writable = true, .min = 0, .max = 1,
     .name = "clear_counters",
     .description = "Write 1 to reset the gateway's counters to 0; reads 0",
     .source = REGMAP_SRC_GW, .id = GW_clear_counters},

    /* ---- holding registers ---- */
    {.table = REGMAP_HOLDING_REGISTER, .address = 0, .elements = 1,
     .type = REGMAP_U16, .scale = 1, .unit = "", .writable = true, .min = 0,
     .max = 65535, .name = "plc_heartbeat",
     .description = "PLC watchdog: write a changing value; its age is "
                    "plc_heartbeat_age_ms",
     .source = REGMAP_SRC_GW, .id = GW_plc_heartbeat},

    /* ---- discrete inputs: gateway ---- */
    G_DI(0, status_link_up, "Status port (10000) connected"),
    G_DI(1, command_link_up, "Command port (10001) connected"),
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
    S_DI(32, homed, 16, "homed_*", "Joint * homed (obsolete)"),
    S_DI(48, drag_near_limit, 8, "drag_near_limit_*",
         "Joint * dragged near its limit"),
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

    /* ---- input registers: gateway diagnostics ---- */
    G_IR(16, status_link_state, REGMAP_U16, "",
         "Status port: 0 disconnected, 1 connecting, 2 connected, 3 connected but silent"),
    G_IR(17, command_link_state, REGMAP_U16, "",
         "Command port: 0 disconnected, 1 connecting, 2 connected"),
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
};

const unsigned regmap_table_row_count =
    sizeof(regmap_table_rows) / sizeof(regmap_table_rows[0]);
