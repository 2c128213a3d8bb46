/* SPDX-License-Identifier: MIT */
/*
 * can_map_table.c - the CAN frames, signal by signal.
 *
 * Identifiers are the configured base id plus the offset. Offsets and bit
 * positions are stable: a receiver is configured against them. Add signals
 * in free bits or frames at new offsets; never move one without bumping
 * CAN_MAP_VERSION. Lower offsets win arbitration: the robot's state first.
 */
#include "can_map.h"

#define SIGNAL(name_, start, bits_, enc, factor_, scale_, unit_, src, id_, idx,  \
               vals, desc)                                                     \
    {.name = (name_), .start_bit = (start), .bits = (bits_), .encoding = (enc),  \
     .factor = (factor_), .source_scale = (scale_), .unit = (unit_),           \
     .description = (desc), .source = (src), .id = (id_), .index = (idx),      \
     .values = (vals)}

/* A robot flag: 2 bits, 0 false, 1 true, 3 not sent. */
#define FLAG(name, start, field, desc)                                         \
    SIGNAL(name, start, 2, CAN_ENC_FLAG, 1, 1, "", CAN_SRC_STATUS,             \
           STATUS_F_##field, 0, flag_values, desc)
/* An unsigned status number. */
#define UNSIGNED(name, start, bits, factor, scale, unit, field, vals, desc)    \
    SIGNAL(name, start, bits, CAN_ENC_UNSIGNED, factor, scale, unit,           \
           CAN_SRC_STATUS, STATUS_F_##field, 0, vals, desc)
/* Element 'idx' of a status array, signed, in thousandths of 'unit'. */
#define MILLI(name, start, unit, field, idx, desc)                             \
    SIGNAL(name, start, 32, CAN_ENC_SIGNED, 0.001, 1, unit, CAN_SRC_STATUS,    \
           STATUS_F_##field, idx, NULL, desc)
#define GW_BIT(name, start, gw, desc)                                          \
    SIGNAL(name, start, 1, CAN_ENC_BIT, 1, 1, "", CAN_SRC_GW, GW_##gw, 0,      \
           NULL, desc)

#define FRAME(name_, offset, dlc_, group_, desc, sigs)                         \
    {.name = (name_), .id_offset = (offset), .dlc = (dlc_),                    \
     .group = CAN_GROUP_##group_, .description = (desc), .signals = (sigs),    \
     .signal_count = sizeof(sigs) / sizeof((sigs)[0])}

static const struct can_value_name flag_values[] = {
    {0, "False"}, {1, "True"}, {0, NULL}};

static const struct can_value_name task_state_values[] = {
    {1, "PoweredOff"}, {2, "PoweredOn"}, {3, "Disabled"}, {4, "Enabled"}, {0, NULL}};

static const struct can_value_name task_mode_values[] = {
    {1, "Manual"}, {2, "Automatic"}, {3, "Reserved"}, {4, "Drag"}, {0, NULL}};

static const struct can_value_name program_state_values[] = {
    {0, "Idle"}, {1, "Loading"}, {2, "Paused"}, {3, "Running"}, {0, NULL}};

static const struct can_value_name status_age_values[] = {
    {4294967295, "NoDocumentYet"}, {0, NULL}};

static const struct can_signal state_signals[] = {
    FLAG("PoweredOn", 0, powered_on, "Robot is powered on"),
    FLAG("Enabled", 2, enabled, "Robot is enabled"),
    FLAG("Paused", 4, paused, "Program is paused"),
    FLAG("InPosition", 6, inpos, "Robot is in position (not moving)"),
    FLAG("EmergencyStop", 8, emergency_stop, "Emergency stop is triggered"),
    FLAG("ProtectiveStop", 10, protective_stop, "Robot is in protective stop"),
    FLAG("OnSoftLimit", 12, on_soft_limit, "Robot is on a soft limit"),
    FLAG("DragMode", 14, drag_status, "Robot is in drag (hand-guiding) mode"),
    UNSIGNED("TaskState", 16, 8, 1, 1, "", task_state, task_state_values,
             "Task state (task_state)"),
    UNSIGNED("TaskMode", 24, 8, 1, 1, "", task_mode, task_mode_values,
             "Task mode (task_mode)"),
    UNSIGNED("ProgramState", 32, 8, 1, 1, "", interp_state, program_state_values,
             "Program state (interp_state)"),
    UNSIGNED("ToolId", 40, 8, 1, 1, "", current_tool_id, NULL,
             "Index of the current tool frame"),
    UNSIGNED("UserId", 48, 8, 1, 1, "", current_user_id, NULL,
             "Index of the current user frame"),
};

static const struct can_signal health_signals[] = {
    GW_BIT("StatusLinkUp", 0, status_link_up, "Status port (10000) connected"),
    GW_BIT("CommandLinkUp", 1, command_link_up, "Command port (10001) connected and answering"),
    GW_BIT("StatusFresh", 2, status_fresh,
           "A status document arrived within status_timeout_ms: the robot "
           "frames carry live data"),
    SIGNAL("RollingCounter", 8, 8, CAN_ENC_UNSIGNED, 1, 1, "", CAN_SRC_MIRROR,
           CAN_MIRROR_rolling_counter, 0, NULL,
           "Adds 1 every period, 255 wraps to 0: a value that stops changing "
           "means a frozen gateway"),
    SIGNAL("StatusAgeMs", 16, 32, CAN_ENC_UNSIGNED, 1, 1, "ms", CAN_SRC_GW,
           GW_status_age_ms, 0, status_age_values,
           "Time since the last status document was parsed"),
    SIGNAL("FramesDropped", 48, 16, CAN_ENC_UNSIGNED, 1, 1, "", CAN_SRC_MIRROR,
           CAN_MIRROR_frames_dropped, 0, NULL,
           "Frames the gateway could not send (queue full, interface down or "
           "absent) since it started, modulo 65536"),
};

static const struct can_signal program_signals[] = {
    UNSIGNED("ErrorCode", 0, 32, 1, 1, "", errcode, NULL,
             "Controller error code (errcode; 0 none)"),
    UNSIGNED("RapidRate", 32, 16, 0.1, 100, "%", rapidrate, NULL,
             "Speed override (rapidrate)"),
};

static const struct can_signal joints_12_signals[] = {
    MILLI("Joint1Position", 0, "deg", joint_actual_position, 0,
          "Joint 1 actual position"),
    MILLI("Joint2Position", 32, "deg", joint_actual_position, 1,
          "Joint 2 actual position"),
};

static const struct can_signal joints_34_signals[] = {
    MILLI("Joint3Position", 0, "deg", joint_actual_position, 2,
          "Joint 3 actual position"),
    MILLI("Joint4Position", 32, "deg", joint_actual_position, 3,
          "Joint 4 actual position"),
};

static const struct can_signal joints_56_signals[] = {
    MILLI("Joint5Position", 0, "deg", joint_actual_position, 4,
          "Joint 5 actual position"),
    MILLI("Joint6Position", 32, "deg", joint_actual_position, 5,
          "Joint 6 actual position"),
};

static const struct can_signal tcp_xy_signals[] = {
    MILLI("TcpX", 0, "mm", actual_position, 0, "TCP actual position x"),
    MILLI("TcpY", 32, "mm", actual_position, 1, "TCP actual position y"),
};

static const struct can_signal tcp_z_rx_signals[] = {
    MILLI("TcpZ", 0, "mm", actual_position, 2, "TCP actual position z"),
    MILLI("TcpRx", 32, "deg", actual_position, 3, "TCP actual orientation rx"),
};

static const struct can_signal tcp_ry_rz_signals[] = {
    MILLI("TcpRy", 0, "deg", actual_position, 4, "TCP actual orientation ry"),
    MILLI("TcpRz", 32, "deg", actual_position, 5, "TCP actual orientation rz"),
};

const struct can_frame_def can_map_frames[] = {
    FRAME("JAKA_State", 0, 7, state,
          "Robot flags, task state and mode, program state, tool and user frame",
          state_signals),
    FRAME("JAKA_Health", 1, 8, health,
          "Gateway health: robot links, status age, rolling counter",
          health_signals),
    FRAME("JAKA_Program", 2, 6, program, "Error code and speed override",
          program_signals),
    FRAME("JAKA_Joints_1_2", 3, 8, joints, "Joint 1 and 2 actual positions",
          joints_12_signals),
    FRAME("JAKA_Joints_3_4", 4, 8, joints, "Joint 3 and 4 actual positions",
          joints_34_signals),
    FRAME("JAKA_Joints_5_6", 5, 8, joints, "Joint 5 and 6 actual positions",
          joints_56_signals),
    FRAME("JAKA_Tcp_X_Y", 6, 8, tcp, "TCP actual pose: x, y", tcp_xy_signals),
    FRAME("JAKA_Tcp_Z_Rx", 7, 8, tcp, "TCP actual pose: z, rx", tcp_z_rx_signals),
    FRAME("JAKA_Tcp_Ry_Rz", 8, 8, tcp, "TCP actual pose: ry, rz", tcp_ry_rz_signals),
};

const unsigned can_map_frame_count = sizeof(can_map_frames) / sizeof(can_map_frames[0]);
