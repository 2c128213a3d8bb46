#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""make screenshot: the status page of a running demo (scripts/demo.sh:
jakasim running a program, jakagw with [http] enabled) as headless
Chromium shows it on a 390 px phone screen:
  docs/status-page.png        after a PLC has connected, fed its heartbeat
                              and sent a few commands;
  docs/status-page-fault.png  once that PLC stopped its heartbeat while the
                              program ran (fault 1 latched: the red header
                              and its banner)."""
import os
import signal
import subprocess
import sys
import threading
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from harness import ModbusPlc, free_port, wait_until  # noqa: E402
from test_http import COIL, Http, browser, close_browser  # noqa: E402

OUT = os.path.join(ROOT, "docs", "status-page.png")
OUT_FAULT = os.path.join(ROOT, "docs", "status-page-fault.png")


def main():
    ports = {name: str(free_port()) for name in
             ("MODBUS_PORT", "STATUS_PORT", "COMMAND_PORT", "HTTP_PORT")}
    demo = subprocess.Popen([os.path.join(ROOT, "scripts", "demo.sh")], cwd=ROOT,
                            env=dict(os.environ, **ports), stdout=subprocess.DEVNULL)
    try:
        web = Http(int(ports["HTTP_PORT"]))
        wait_until(lambda: _answers(web) and web.status()["policy"]["handler"] == "accepted",
                   30, "the demo's gateway")
        plc = ModbusPlc(int(ports["MODBUS_PORT"]))
        lock = threading.Lock()
        stop = threading.Event()

        def heartbeat():  # as a PLC feeds it: this PLC owns the write side
            n = 0
            while not stop.is_set():
                n += 1
                with lock:
                    plc.reg(0, n & 0xFFFF)
                time.sleep(0.2)
        beat = threading.Thread(target=heartbeat, daemon=True)
        beat.start()
        time.sleep(0.5)
        with lock:
            plc.coil(COIL["cabinet_do_1"], 1)
            plc.pulse(COIL["cmd_enable_robot"])
        driver = browser(390, 844)
        try:
            driver.get("http://127.0.0.1:%s/" % ports["HTTP_PORT"])
            time.sleep(2)
            wait_until(lambda: "enable_robot" in driver.find_element("id", "commands").text,
                       10, "the commands on the page")
            driver.save_screenshot(OUT)
            # The PLC goes silent while the program runs: fault 1.
            stop.set()
            beat.join(5)
            wait_until(lambda: driver.find_element("id", "fault").is_displayed(), 15,
                       "the fault banner")
            time.sleep(1.5)
            driver.save_screenshot(OUT_FAULT)
        finally:
            close_browser(driver)
            stop.set()
            beat.join(5)
            plc.close()
    finally:
        demo.send_signal(signal.SIGTERM)
        demo.wait(20)
    print("wrote %s and %s" % (os.path.relpath(OUT, ROOT), os.path.relpath(OUT_FAULT, ROOT)))


def _answers(web):
    try:
        return web.get("/")[0] == 200
    except OSError:
        return False


if __name__ == "__main__":
    main()
