# SPDX-License-Identifier: MIT
"""Modbus RTU on a serial line ([rtu]): the real jakagw on one end of a
socat pty pair, an independent master on the other: mbpoll -m rtu,
pymodbus's serial client, and a raw master that writes each frame in one
write() call (on a pty, the bytes of one write arrive together, so the
framing the tests see is the one they wrote; a mid-frame gap is a write of
half a frame, a pause, and the rest)."""
import os
import select
import signal
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time
import tty

sys.path.insert(0, os.path.dirname(__file__))
from harness import (Gateway, JAKAGW, ModbusPlc, Process, Sim, TestFailure, check, free_port, log_lines,
                     run, sim_commands, wait_until)

UNIT = 17
IR_MAGIC = 0
MAGIC = 0x4A4B
COIL_POWER_ON = 100
COIL_MOTION_ENABLE = 131
IR_TASK_STATE = 100
IR_LINE_STATE = 5540
IR_FRAMES = 5542
IR_CRC_ERRORS = 5544
IR_FOREIGN = 5546
IR_BROADCASTS = 5548
IR_OVERRUNS = 5550
IR_GAP_DISCARDS = 5552
IR_TURNAROUND = 5554
IR_MODBUS_CLIENTS = 40
IR_MODBUS_EXCEPTIONS_LOW = 39
LINE_IDLE, LINE_POLLED, LINE_FAULT = 1, 2, 3
NO_REPLY_S = 0.4  # how long a master waits before it calls a request unanswered


def crc16(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


def frame(unit, pdu):
    body = bytes([unit]) + pdu
    return body + crc16(body)


def read_ir_pdu(address, count):
    return struct.pack(">BHH", 4, address, count)


def write_coil_pdu(address, value):
    return struct.pack(">BHH", 5, address, 0xFF00 if value else 0)


class SerialPair:
    """socat joining two ptys, named by links in a temporary directory: the
    gateway's device and the master's. stop() is the cable pulled (the
    gateway's pty goes away), start() the adapter plugged back in."""

    def __init__(self):
        self.dir = tempfile.mkdtemp(prefix="jakagw-rtu-")
        self.device = os.path.join(self.dir, "gw")
        self.master = os.path.join(self.dir, "plc")
        self.proc = None
        self.start()

    def start(self):
        self.proc = subprocess.Popen(
            ["socat", "pty,raw,echo=0,link=%s" % self.device,
             # ignoreeof: a master that closes its end (mbpoll -1) does
             # not end socat, as closing a real port leaves the line.
             "pty,raw,echo=0,ignoreeof,link=%s" % self.master],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_until(lambda: os.path.exists(self.device) and os.path.exists(self.master), 10,
                   "socat's ptys")

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=10)
        self.proc = None
        wait_until(lambda: not os.path.exists(self.device), 10, "socat's links gone")

    def close(self):
        self.stop()
        os.rmdir(self.dir)


class RawMaster:
    """A master that writes each frame in one write() and reads replies."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        termios.tcflush(self.fd, termios.TCIOFLUSH)

    def close(self):
        os.close(self.fd)

    def send(self, data):
        check(os.write(self.fd, data) == len(data), "one write of %d bytes" % len(data))

    def reply(self, timeout=3.0):
        """The next whole frame (good CRC), or None when none came in time."""
        buf = b""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            r, _, _ = select.select([self.fd], [], [], max(0, deadline - time.monotonic()))
            if not r:
                break
            buf += os.read(self.fd, 512)
            for n in range(4, len(buf) + 1):
                if buf[n - 2:n] == crc16(buf[:n - 2]):
                    check(n == len(buf), "extra bytes after a reply: %r" % buf)
                    return buf
        check(not buf, "a partial reply: %r" % buf)
        return None

    def request(self, unit, pdu, timeout=3.0):
        self.send(frame(unit, pdu))
        return self.reply(timeout)

    def read_ir(self, address, count=1, unit=UNIT):
        rsp = self.request(unit, read_ir_pdu(address, count))
        check(rsp is not None, "no reply to a read of input register %d" % address)
        check(rsp[:3] == bytes([unit, 4, 2 * count]), "reply %r" % rsp)
        return list(struct.unpack(">%dH" % count, rsp[3:3 + 2 * count]))

    def no_reply(self, timeout=NO_REPLY_S):
        rsp = self.reply(timeout)
        check(rsp is None, "an answer where none is due: %r" % rsp)


def rtu_config(device, **keys):
    values = dict(enabled="true", device=device, unit_id=str(UNIT))
    values.update(keys)
    return "[rtu]\n" + "".join("%s = %s\n" % kv for kv in values.items())


def u32(plc, address):
    return plc.u32(address)


class Rig:
    """jakasim, a serial pair, jakagw serving both the pty and TCP."""

    def __init__(self, sim_args=("--log-commands",), **keys):
        self.line = SerialPair()
        self.sim = self.gw = self.plc = None
        try:
            self.sim = Sim(*sim_args)
            self.gw = Gateway(self.sim, rtu_config(self.line.device, **keys))
            self.plc = ModbusPlc(self.gw.modbus_port)
            wait_until(lambda: self.plc.ir(IR_LINE_STATE)[0] == LINE_IDLE, 10, "the line open")
        except BaseException:
            # A rig that fails to start stops what it started (no __exit__).
            self.close()
            raise

    def master(self):
        return RawMaster(self.line.master)

    def close(self):
        try:
            if self.plc:
                self.plc.close()
            if self.gw:
                self.gw.stop()
        finally:
            try:
                if self.sim:
                    self.sim.stop()
            finally:
                self.line.close()


def rig(**keys):
    class Ctx:
        def __enter__(self):
            self.r = Rig(**keys)
            return self.r

        def __exit__(self, *exc):
            self.r.close()
    return Ctx()


def test_mbpoll_and_pymodbus_read_the_map():
    """mbpoll -m rtu and pymodbus's serial client read the map magic at the
    configured unit, with the line's settings (19200 baud; no parity: some
    kernels refuse a parity bit on a pty, where it means nothing)."""
    with rig(parity="none") as r:
        out = subprocess.run(["mbpoll", "-m", "rtu", "-a", str(UNIT), "-b", "19200", "-P",
                              "none", "-t", "3:hex", "-0", "-r", "0", "-c", "1", "-1", "-o",
                              "2", r.line.master], capture_output=True, text=True, timeout=30)
        check(out.returncode == 0 and "[0]: \t0x4A4B" in out.stdout,
              "mbpoll: %s %s" % (out.stdout, out.stderr))
        from pymodbus.client import ModbusSerialClient
        client = ModbusSerialClient(port=r.line.master, baudrate=19200, parity="N",
                                    stopbits=1, bytesize=8, timeout=2, retries=0)
        check(client.connect(), "pymodbus serial connect")
        try:
            rr = client.read_input_registers(IR_MAGIC, 13, slave=UNIT)
            check(not rr.isError(), "pymodbus read: %s" % rr)
            check(rr.registers[0] == MAGIC, "magic %r" % rr.registers)
            rr = client.read_input_registers(IR_LINE_STATE, 1, slave=UNIT)
            check(not rr.isError() and rr.registers[0] == LINE_POLLED,
                  "the line polled, read over the line: %s" % rr)
        finally:
            client.close()
        check(r.plc.ir(IR_LINE_STATE)[0] == LINE_POLLED, "the line polled, read over TCP")
        check(r.plc.u32(IR_FRAMES) >= 3, "frames counted")
        turnaround = r.plc.u32(IR_TURNAROUND)
        # 19200 baud, 10 bits a character: t3.5 is 1823 us.
        check(1823 <= turnaround < 1000000, "turnaround %d us: t3.5 at least" % turnaround)


def test_command_once_with_rights_and_01_outside():
    """rights = read: a trigger coil is refused with exception 01 and
    nothing reaches the robot. rights = power: power_on goes to the robot
    exactly once."""
    with rig() as r:
        m = r.master()
        try:
            rsp = m.request(UNIT, write_coil_pdu(COIL_POWER_ON, 1))
            check(rsp == frame(UNIT, bytes([0x85, 0x01])), "exception 01: %r" % rsp)
            time.sleep(0.3)
            check(not sim_commands(r.sim, "power_on"), "nothing sent to the robot")
        finally:
            m.close()
    with rig(rights="power") as r:
        m = r.master()
        try:
            wait_until(lambda: r.plc.ir(IR_TASK_STATE)[0] in (1, 2, 3, 4), 10, "robot status")
            for value in (0, 1):
                req = write_coil_pdu(COIL_POWER_ON, value)
                check(m.request(UNIT, req) == frame(UNIT, req), "coil write echoed")
            wait_until(lambda: len(sim_commands(r.sim, "power_on")) == 1, 10,
                       "power_on at the robot")
            wait_until(lambda: r.plc.ir(IR_TASK_STATE)[0] == 2, 10, "the robot powered on")
            time.sleep(0.5)
            check(len(sim_commands(r.sim, "power_on")) == 1, "power_on exactly once")
        finally:
            m.close()


def test_bad_crc_and_mid_frame_gap_are_not_answered():
    """A frame with a bad CRC, and a frame with a silence in its middle, get
    no reply; the next frame is answered."""
    with rig() as r:
        m = r.master()
        try:
            good = frame(UNIT, read_ir_pdu(IR_MAGIC, 1))
            m.send(good[:-1] + bytes([good[-1] ^ 0x55]))
            m.no_reply()
            check(m.read_ir(IR_MAGIC) == [MAGIC], "the next frame answered")
            crc_before = r.plc.u32(IR_CRC_ERRORS)
            check(crc_before >= 1, "the bad CRC counted")
            m.send(good[:4])
            time.sleep(0.3)
            m.send(good[4:])
            m.no_reply()
            check(m.read_ir(IR_MAGIC) == [MAGIC], "the next frame answered")
            check(r.plc.u32(IR_CRC_ERRORS) + r.plc.u32(IR_GAP_DISCARDS) > crc_before,
                  "the broken frame counted")
        finally:
            m.close()


def test_frame_handed_over_in_pieces_is_answered():
    """A UART hands a frame over in pieces (its FIFO every 8 characters),
    as does a USB adapter (its packets), further apart than t3.5 though the
    wire had no pause: the frame is answered once whole, and a real pause
    in a frame still discards it. 4800 baud, no parity: a character is
    2.08 ms, t3.5 7.3 ms; 8 bytes, then the last 3 six characters later
    (12.5 ms; the previous code took the first 8 for a frame that failed
    its CRC, and answered nothing)."""
    with rig(rights="heartbeat", baud="4800", parity="none") as r:
        m = r.master()
        try:
            for value in range(1, 6):
                pdu = struct.pack(">BHHBH", 16, 0, 1, 2, value)
                whole = frame(UNIT, pdu)
                m.send(whole[:8])
                time.sleep(6 * 10 / 4800)
                m.send(whole[8:])
                rsp = m.reply(timeout=1.0)
                check(rsp == frame(UNIT, pdu[:5]), "write %d: %r" % (value, rsp))
            check(r.plc.hr(0)[0] == 5, "the last value written")
            check(r.plc.u32(IR_CRC_ERRORS) == 0 and r.plc.u32(IR_GAP_DISCARDS) == 0,
                  "nothing dropped")
            # A byte of noise (it begins a frame for this unit), t3.5 and
            # more of silence, a frame: the noise ends at the silence.
            m.send(bytes([UNIT]))
            time.sleep(0.012)
            check(m.read_ir(IR_MAGIC) == [MAGIC], "the frame after the noise answered")
            whole = frame(UNIT, read_ir_pdu(IR_MAGIC, 1))
            m.send(whole[:4])
            time.sleep(0.3)
            m.send(whole[4:])
            m.no_reply()
            check(m.read_ir(IR_MAGIC) == [MAGIC], "the next frame answered")
        finally:
            m.close()


def test_multidrop_keeps_sync():
    """Requests for other units, and their replies, interleaved with ours at
    the line's pace (t3.5 apart) and glued to ours in one write: every one of
    ours is answered, no other is."""
    with rig(baud="115200", parity="none") as r:
        m = r.master()
        try:
            rounds = 60
            for i in range(rounds):
                other = 18 + i % 3
                m.send(frame(other, read_ir_pdu(i, 2)))
                time.sleep(0.002)
                m.send(frame(other, struct.pack(">BBHH", 4, 4, i, i)))  # its reply
                time.sleep(0.002)
                if i % 2:
                    check(m.read_ir(IR_MAGIC) == [MAGIC], "round %d answered" % i)
                else:
                    # A late reader sees both frames at once: cut by length.
                    m.send(frame(other, read_ir_pdu(i, 1)) + frame(UNIT, read_ir_pdu(0, 1)))
                    rsp = m.reply()
                    check(rsp == frame(UNIT, struct.pack(">BBH", 4, 2, MAGIC)),
                          "round %d: %r" % (i, rsp))
            m.no_reply()
            foreign = r.plc.u32(IR_FOREIGN)
            check(foreign == 2 * rounds + rounds // 2, "foreign frames counted: %d" % foreign)
            check(r.plc.u32(IR_CRC_ERRORS) == 0, "no CRC error")
        finally:
            m.close()


def test_broadcast_is_counted_never_acted_on():
    """A broadcast write of the power_on trigger (unit 0): no reply, nothing
    sent to the robot, counted; the line's rights would allow it."""
    with rig(rights="power") as r:
        m = r.master()
        try:
            for value in (0, 1):
                m.send(frame(0, write_coil_pdu(COIL_POWER_ON, value)))
                m.no_reply()
            wait_until(lambda: r.plc.u32(IR_BROADCASTS) == 2, 5, "broadcasts counted")
            time.sleep(0.5)
            check(not sim_commands(r.sim, "power_on"), "nothing sent to the robot")
            check(r.plc.read_coils(COIL_POWER_ON) == [0], "the coil untouched")
            check(m.read_ir(IR_MAGIC) == [MAGIC], "the unit still answers")
        finally:
            m.close()


def test_device_removed_and_restored():
    """socat stopped: one log line, the line's state 3, TCP still served;
    socat started again: the line comes back within a few seconds."""
    with rig() as r:
        m = r.master()
        check(m.read_ir(IR_MAGIC) == [MAGIC], "served before")
        m.close()
        r.line.stop()
        wait_until(lambda: r.plc.ir(IR_LINE_STATE)[0] == LINE_FAULT, 10, "the line fault")
        time.sleep(2.5)  # two retries, not logged again
        check(r.plc.ir(IR_MAGIC) == [MAGIC], "TCP unaffected")
        check(len(log_lines(r.gw, "line down")) == 1, r.gw.output())
        r.line.start()
        wait_until(lambda: r.plc.ir(IR_LINE_STATE)[0] == LINE_IDLE, 10, "the line back")
        check(len(log_lines(r.gw, "line up again")) == 1, r.gw.output())
        m = r.master()
        try:
            check(m.read_ir(IR_MAGIC) == [MAGIC], "served again")
        finally:
            m.close()


def test_absent_device_at_start_is_a_link_fault():
    """A device that does not exist at start: the gateway runs (TCP served),
    the line in fault; once it appears, it is opened."""
    line = SerialPair()
    line.stop()
    sim = Sim()
    gw = Gateway(sim, rtu_config(line.device))
    try:
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: plc.ir(IR_LINE_STATE)[0] == LINE_FAULT, 10, "the line fault")
        line.start()
        wait_until(lambda: plc.ir(IR_LINE_STATE)[0] == LINE_IDLE, 10, "the line opened")
        m = RawMaster(line.master)
        check(m.read_ir(IR_MAGIC) == [MAGIC], "served")
        m.close()
        plc.close()
    finally:
        gw.stop()
        sim.stop()
        line.close()


def test_rs485_refused_exits_2_naming_the_device():
    """rs485 = true on a port whose driver refuses TIOCSRS485 (a pty): exit
    2, the device named."""
    line = SerialPair()
    try:
        conf = tempfile.NamedTemporaryFile("w", suffix=".conf", delete=False)
        conf.write(rtu_config(line.device, rs485="true"))
        conf.close()
        p = Process("jakagw", [JAKAGW, "-c", conf.name, "--modbus-bind", "127.0.0.1",
                               "--modbus-port", str(free_port())])
        wait_until(lambda: not p.alive(), 30, "jakagw to exit")
        out = p.stop(expect_code=2)
        os.unlink(conf.name)
        check("rtu: device %s" % line.device in out and "TIOCSRS485" in out, out)
    finally:
        line.close()


def test_device_back_but_refusing_rs485_is_logged():
    """rs485 = true and the device absent at start (a link fault); it comes
    back on a driver that refuses TIOCSRS485 (a pty): one error line naming
    the device and TIOCSRS485, not a silent line down (the previous code
    said nothing), TCP served."""
    line = SerialPair()
    line.stop()
    sim = Sim()
    gw = Gateway(sim, rtu_config(line.device, rs485="true"))
    try:
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: plc.ir(IR_LINE_STATE)[0] == LINE_FAULT, 10, "the line fault")
        line.start()
        wait_until(lambda: log_lines(gw, "TIOCSRS485"), 10, "the refusal logged")
        time.sleep(2.5)  # retries, not logged again
        lines = log_lines(gw, "TIOCSRS485")
        check(len(lines) == 1 and line.device in lines[0], gw.output())
        check(plc.ir(IR_LINE_STATE)[0] == LINE_FAULT, "still a fault")
        check(plc.ir(IR_MAGIC) == [MAGIC], "TCP served")
        plc.close()
    finally:
        gw.stop()
        sim.stop()
        line.close()


def test_write_pending_at_stop_is_never_acted_on_unanswered():
    """SIGTERM while a write's frame waits for its t3.5 silence (1200 baud,
    no parity: 29 ms): the frame is dropped, neither acted on nor answered;
    if the silence came first, the write is acted on and answered. Never
    acted on without a reply (up to 6 stops, until one came within the
    silence)."""
    dropped = 0
    for _ in range(6):  # until one stop has come within the silence
        if dropped:
            break
        with rig(rights="power", baud="1200", parity="none") as r:
            m = r.master()
            try:
                wait_until(lambda: r.plc.ir(IR_TASK_STATE)[0] in (1, 2, 3, 4), 10,
                           "robot status")
                req = write_coil_pdu(COIL_POWER_ON, 1)
                m.send(frame(UNIT, req))
                r.gw.proc.send_signal(signal.SIGTERM)
                rsp = m.reply(timeout=1.0)
                r.gw.proc.wait(timeout=10)
                sent = len(sim_commands(r.sim, "power_on"))
                check((rsp is None and sent == 0) or (rsp == frame(UNIT, req) and sent == 1),
                      "reply %r, power_on sent %d times" % (rsp, sent))
                dropped += rsp is None
            finally:
                m.close()
    check(dropped >= 1, "the stop never came within the silence")


def test_rtu_and_tcp_at_once():
    """An RTU master and a TCP client polling together: every request of
    both answered."""
    with rig(baud="115200") as r:
        m = r.master()
        errors = []
        tcp_reads = [0]
        done = threading.Event()

        def poll_tcp():
            plc = ModbusPlc(r.gw.modbus_port)
            try:
                while not done.is_set():
                    if plc.ir(IR_MAGIC) != [MAGIC]:
                        errors.append("TCP read")
                    tcp_reads[0] += 1
            except Exception as e:  # reported below
                errors.append(repr(e))
            finally:
                plc.close()

        t = threading.Thread(target=poll_tcp)
        t.start()
        try:
            for i in range(200):
                check(m.read_ir(IR_MAGIC, 13)[0] == MAGIC, "RTU read %d" % i)
        finally:
            done.set()
            t.join()
            m.close()
        check(not errors and tcp_reads[0] > 20, "TCP: %d reads, %s" % (tcp_reads[0], errors))


def test_line_counts_as_a_client_while_polled():
    """For the policy's watch = connection, the line is a connected client
    while a request for this unit came within time_limit_ms, and no longer
    once none came for that long; frames for other units do not count."""
    with rig() as r:
        r.gw.stop()
        r.gw = Gateway(r.sim, rtu_config(r.line.device) +
                       "[network_exception]\nwatch = connection\ntime_limit_ms = 600\n")
        r.plc.close()
        r.plc = ModbusPlc(r.gw.modbus_port)
        wait_until(lambda: r.plc.ir(IR_LINE_STATE)[0] == LINE_IDLE, 10, "the line open")
        check(r.plc.ir(IR_MODBUS_CLIENTS)[0] == 1, "only the TCP client")
        m = r.master()
        try:
            for _ in range(5):
                m.send(frame(UNIT + 1, read_ir_pdu(0, 1)))
                time.sleep(0.1)
            check(r.plc.ir(IR_MODBUS_CLIENTS)[0] == 1, "foreign frames do not count")
            check(m.read_ir(IR_MAGIC) == [MAGIC], "a request for this unit")
            check(r.plc.ir(IR_MODBUS_CLIENTS)[0] == 2 and
                  r.plc.ir(IR_LINE_STATE)[0] == LINE_POLLED, "the line counted")
            start = time.monotonic()
            wait_until(lambda: r.plc.ir(IR_MODBUS_CLIENTS)[0] == 1, 10, "the line let go")
            check(time.monotonic() - start >= 0.4, "not before time_limit_ms")
            check(r.plc.ir(IR_LINE_STATE)[0] == LINE_IDLE, "idle again")
            check(m.read_ir(IR_MAGIC) == [MAGIC], "served again")
            check(r.plc.ir(IR_MODBUS_CLIENTS)[0] == 2, "counted again")
            # A master's pause is no news: no warning for it.
            check(not log_lines(r.gw, "rtu:" + r.line.device), r.gw.output())
        finally:
            m.close()


def test_overrun_drops_to_the_next_silence():
    """More bytes without a silence than the receive buffer holds (1024):
    counted as an overrun, dropped up to the next silence, no reply; the
    next frame is answered. 1024 bytes of frames glued together still fit."""
    with rig() as r:
        m = r.master()
        try:
            m.send(bytes((i * 7 + 3) & 0xFF for i in range(1100)))
            m.no_reply()
            wait_until(lambda: r.plc.u32(IR_OVERRUNS) == 1, 5, "the overrun counted")
            check(m.read_ir(IR_MAGIC) == [MAGIC], "the next frame answered")
            # 127 foreign requests and ours, 1024 bytes in one write: all cut.
            glued = b"".join(frame(UNIT + 1, read_ir_pdu(i, 1)) for i in range(127))
            m.send(glued + frame(UNIT, read_ir_pdu(0, 1)))
            check(m.reply() == frame(UNIT, struct.pack(">BBH", 4, 2, MAGIC)), "ours answered")
            check(r.plc.u32(IR_OVERRUNS) == 1, "no second overrun")
            check(r.plc.u32(IR_FOREIGN) == 127, "127 foreign frames")
        finally:
            m.close()


def test_own_reply_heard_back_is_not_a_request():
    """An adapter that hears its own transmitter gives every reply back to
    the gateway: that frame is not taken for a request (answering it would
    be heard again); a real request after it is answered."""
    with rig(rights="faults") as r:
        m = r.master()
        try:
            req = frame(UNIT, read_ir_pdu(IR_MAGIC, 1))
            for _ in range(3):
                m.send(req)
                rsp = m.reply()
                check(rsp == frame(UNIT, struct.pack(">BBH", 4, 2, MAGIC)), "reply %r" % rsp)
                m.send(rsp)  # the echo
                m.no_reply()
            check(r.plc.ir(IR_MODBUS_EXCEPTIONS_LOW)[0] == 0, "no exception answered")
            # On a line that echoes, a write's echo (equal to the request) is
            # not the write again.
            write = frame(UNIT, write_coil_pdu(COIL_MOTION_ENABLE, 1))
            m.send(write)
            check(m.reply() == write, "the write answered")
            m.send(write)  # its echo
            m.no_reply()
        finally:
            m.close()


def test_repeated_write_answered_where_the_line_does_not_echo():
    """A master that writes the same value again at once (05 or 06: the
    reply equals the request, as an echo would): on a line that has shown
    it gives no reply back, every such write is answered (the previous
    code skipped every second one as an echo)."""
    with rig(rights="faults") as r:
        m = r.master()
        try:
            for _ in range(3):
                check(m.read_ir(IR_MAGIC) == [MAGIC], "a read")
            write = frame(UNIT, write_coil_pdu(COIL_MOTION_ENABLE, 1))
            for i in range(6):
                m.send(write)
                check(m.reply(timeout=1.0) == write, "write %d answered" % i)
                time.sleep(0.02)
        finally:
            m.close()


if __name__ == "__main__":
    run([test_mbpoll_and_pymodbus_read_the_map, test_command_once_with_rights_and_01_outside,
         test_bad_crc_and_mid_frame_gap_are_not_answered,
         test_frame_handed_over_in_pieces_is_answered, test_multidrop_keeps_sync,
         test_broadcast_is_counted_never_acted_on, test_device_removed_and_restored,
         test_absent_device_at_start_is_a_link_fault,
         test_rs485_refused_exits_2_naming_the_device,
         test_device_back_but_refusing_rs485_is_logged,
         test_write_pending_at_stop_is_never_acted_on_unanswered, test_rtu_and_tcp_at_once,
         test_line_counts_as_a_client_while_polled, test_overrun_drops_to_the_next_silence,
         test_own_reply_heard_back_is_not_a_request,
         test_repeated_write_answered_where_the_line_does_not_echo])
