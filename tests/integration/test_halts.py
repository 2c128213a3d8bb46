#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Pausing and stopping, end to end against jakasim (--log-commands shows
what the robot got): the PLC's stop passes before the robot has accepted
its network-exception handler and ahead of a command waiting for a slow
reply; a pause owed while the command link is down goes out when it
comes back."""
import time

from harness import ModbusPlc, check, log_lines, map_rows, run, running, sim_commands, wait_until

ADDR = {}
for _row in map_rows():
    ADDR.setdefault((_row["table"], _row["name"]), int(_row["address"]))

HEARTBEAT = ADDR[("holding_register", "plc_heartbeat")]
STOP = ADDR[("coil", "cmd_stop_program")]
CLEAR_ERROR = ADDR[("coil", "cmd_clear_error")]
ROBOT_HANDLE = ADDR[("input_register", "robot_handle")]
FAULT = ADDR[("input_register", "fault")]
INTERP_STATE = ADDR[("input_register", "interp_state")]
STATUS_FRESH = ADDR[("discrete_input", "status_fresh")]
CMD_LINK_UP = ADDR[("discrete_input", "command_link_up")]
HANDLE_ACCEPTED, HANDLE_FAILED = 2, 3
RUNNING = 3
SIM = ["--log-commands", "--period-ms", "20"]


def count(sim, name):
    return len(sim_commands(sim, name))


def test_stop_passes_before_the_handler_is_accepted():
    """The robot refuses set_network_exception_handle (an older firmware):
    the PLC's stop_program, the one command that passes every gate, is
    refused with 01 and never reaches the robot."""
    sim_args = SIM + ["--auto-run", "--fail-command", "set_network_exception_handle"]
    with running(sim_args, "[robot]\nreconnect_min_ms = 50\n") as (sim, gw):
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: plc.ir(ROBOT_HANDLE)[0] == HANDLE_FAILED, 10, "handler state 3")
        wait_until(lambda: plc.ir(INTERP_STATE)[0] == RUNNING, 10, "the program running")
        check(plc.coil(STOP, 0) == 0, "re-arm refused")
        ex = plc.coil(STOP, 1)
        if ex == 0:
            wait_until(lambda: count(sim, "stop_program") >= 1, 5, "stop_program on the wire")
        check(ex == 0 and count(sim, "stop_program") == 1,
              "stop_program while the program runs: exception %02X, %d sent to the robot, "
              "program state %d" % (ex, count(sim, "stop_program"), plc.ir(INTERP_STATE)[0]))
        plc.close()


def test_heartbeat_loss_while_command_link_down():
    """The heartbeat stops while the command link is reconnecting (here
    after a reply timeout): the fault latches, the pause cannot be sent, and
    it is never sent once the link is back: the program keeps running
    with the PLC gone."""
    config = ("[robot]\nreconnect_min_ms = 2000\nreconnect_max_ms = 2000\n"
              "[commands]\nreply_timeout_ms = 300\n"
              "[network_exception]\ntime_limit_ms = 500\nrobot_time_limit_ms = 10000\n")
    sim_args = SIM + ["--auto-run", "--ignore-command", "clear_error"]
    with running(sim_args, config) as (sim, gw):
        plc = ModbusPlc(gw.modbus_port)
        value = [0]

        def beat():
            value[0] += 1
            check(plc.reg(HEARTBEAT, value[0]) == 0, "heartbeat refused")

        deadline = time.monotonic() + 10
        while not (plc.ir(ROBOT_HANDLE)[0] == HANDLE_ACCEPTED and
                   plc.di(STATUS_FRESH)[0] == 1 and plc.ir(INTERP_STATE)[0] == RUNNING):
            check(time.monotonic() < deadline, "not ready")
            beat()
            time.sleep(0.1)
        beat()
        check(plc.coil(CLEAR_ERROR, 1) == 0, "clear_error refused")
        # The last heartbeat: clear_error times out after 300 ms, the command
        # link is down for 2 s, the heartbeat expires after 500 ms meanwhile.
        wait_until(lambda: plc.ir(FAULT)[0] == 1, 5, "fault 1")
        check(plc.di(CMD_LINK_UP)[0] == 0, "the command link is up at the fault")
        wait_until(lambda: plc.ir(ROBOT_HANDLE)[0] == HANDLE_ACCEPTED, 10,
                   "the command link back")
        wait_until(lambda: count(sim, "pause_program") >= 1, 5, "the owed pause on the wire")
        time.sleep(0.5)  # a window in which a repeated pause would show
        check(count(sim, "pause_program") == 1,
              "heartbeat lost while the command link was down: pause_program sent %d times; "
              "fault %d latched; program state %d (3 = running); gateway log: %s"
              % (count(sim, "pause_program"), plc.ir(FAULT)[0], plc.ir(INTERP_STATE)[0],
                 " | ".join(log_lines(gw, "network exception"))))
        plc.close()


def test_plc_stop_goes_ahead_of_a_slow_reply():
    """The PLC stops the robot (coil 110) while another command's reply is
    outstanding: stop_program waits in the queue behind it, and when that
    reply times out it fails with the rest, never sent. (The gateway's own
    pause/stop goes out at once through the urgent path.)"""
    config = "[commands]\nreply_timeout_ms = 2000\n[network_exception]\nwatch = connection\n"
    sim_args = SIM + ["--auto-run", "--ignore-command", "clear_error"]
    with running(sim_args, config) as (sim, gw):
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: plc.ir(ROBOT_HANDLE)[0] == HANDLE_ACCEPTED and
                   plc.ir(INTERP_STATE)[0] == RUNNING, 10, "ready, program running")
        wait_until(lambda: count(sim, "get_dh_param") == 1, 5, "the information fetched")
        time.sleep(0.3)
        check(plc.coil(CLEAR_ERROR, 1) == 0, "clear_error refused")
        wait_until(lambda: count(sim, "clear_error") == 1, 5, "clear_error on the wire")
        check(plc.coil(STOP, 1) == 0, "stop_program refused")
        asked = time.monotonic()
        try:
            wait_until(lambda: count(sim, "stop_program") == 1, 4, "stop_program")
            took = "%.0f ms" % (1000 * (time.monotonic() - asked))
        except Exception:
            took = None
        state = plc.ir(ADDR[("input_register", "result_stop_program_state")])[0]
        check(took is not None and count(sim, "stop_program") == 1 and
              float(took.split()[0]) < 500,
              "PLC stop_program behind an unanswered clear_error: %s; its result state %d "
              "(5 = link down); program state %d (3 = running)"
              % ("reached the robot after " + took if took else "never reached the robot",
                 state, plc.ir(INTERP_STATE)[0]))
        plc.close()


if __name__ == "__main__":
    run([test_stop_passes_before_the_handler_is_accepted,
         test_heartbeat_loss_while_command_link_down,
         test_plc_stop_goes_ahead_of_a_slow_reply])
