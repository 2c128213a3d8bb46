#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The service VM's test agent (runs inside the VM, as root, from
vm-test-agent.service): reads one JSON request a line from the virtio
serial port the host holds, runs it, and writes one JSON reply a line.

  {"id": N, "sh": "shell command", "timeout": S}
      -> {"id": N, "rc": exit status, "out": stdout, "err": stderr, "s": seconds}
  {"id": N, "py": "python code", "timeout": S}
      -> {"id": N, "rc": 0 or 1, "out": repr-free value of 'result', "err": traceback}

First it writes {"hello": uptime}, again each second until the host's
first request, since the host may connect after the guest opens the port.
The Python requests run in one namespace that lives as long as the agent,
so a case can keep a PLC connection open across requests.
"""
import json
import os
import select
import subprocess
import sys
import time
import traceback

PORT = sys.argv[1] if len(sys.argv) > 1 else "/dev/virtio-ports/jakagw.agent"


def uptime():
    with open("/proc/uptime") as f:
        return float(f.read().split()[0])


def main():
    while not os.path.exists(PORT):
        time.sleep(0.1)
    fd = os.open(PORT, os.O_RDWR)

    def send(obj):
        data = (json.dumps(obj) + "\n").encode()
        while data:
            n = os.write(fd, data)
            data = data[n:]

    namespace = {}
    buf = b""
    greeted = False
    last_hello = 0.0
    while True:
        if not greeted and time.monotonic() - last_hello >= 1.0:
            send({"hello": uptime()})
            last_hello = time.monotonic()
        ready, _, _ = select.select([fd], [], [], 0.2)
        if not ready:
            continue
        chunk = os.read(fd, 65536)
        if not chunk:
            time.sleep(0.1)  # the host is not connected
            continue
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            if not line.strip():
                continue
            greeted = True
            req = json.loads(line)
            start = time.monotonic()
            reply = {"id": req.get("id")}
            if "sh" in req:
                try:
                    r = subprocess.run(["/bin/sh", "-c", req["sh"]], capture_output=True,
                                       timeout=req.get("timeout", 60), stdin=subprocess.DEVNULL)
                    reply.update(rc=r.returncode, out=r.stdout.decode(errors="replace"),
                                 err=r.stderr.decode(errors="replace"))
                except subprocess.TimeoutExpired as e:
                    reply.update(rc=124, out=(e.stdout or b"").decode(errors="replace"),
                                 err="timed out after %s s" % req.get("timeout", 60))
            else:
                try:
                    namespace.pop("result", None)
                    exec(req["py"], namespace)
                    reply.update(rc=0, out=namespace.get("result"), err="")
                except Exception:
                    reply.update(rc=1, out=None, err=traceback.format_exc())
            reply["s"] = time.monotonic() - start
            send(reply)


if __name__ == "__main__":
    main()
