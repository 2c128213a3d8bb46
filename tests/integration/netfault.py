# SPDX-License-Identifier: MIT
"""Network faults on loopback, for the fault-injection suite.

Each test runs in a private network namespace (`unshare -n`): the test
script starts itself again there, once per test, so nothing it does to the
network reaches the host or another test, and whatever rule a failing test
leaves behind goes with its namespace. Inside, only the loopback interface
exists (brought up here); jakasim, jakagw and the PLC clients all talk over
127.0.0.0/8 and ::1.

Faults are nftables rules in one table of the namespace, on the output
hook (on loopback every packet passes it once). Each fault is its own base
chain, added and removed in one nft transaction:

  pull(port, direction)   every packet to and/or from a port dropped: no
                          FIN, no RST, a cable pulled or a switch port dead
  reset(port)             packets to a port answered with a TCP reset, a
                          connection reset mid-stream
  loss(port, percent)     random loss ("numgen random mod 100 < N"), both
                          directions
  restore(fault)          the rule gone: the cable back

A port names a TCP port of the server side. direction "both", "to" (only
packets towards the server: the server hears nothing, its replies still go
out) or "from" (only packets from the server). 'peer' narrows a fault to one
client address and port (a single PLC connection).

This needs root (CAP_SYS_ADMIN for the namespace, CAP_NET_ADMIN for nft):
CI runs as root. Without it, or without unshare, ip or nft, the suite fails
with a line saying so; it is never skipped."""
import os
import shutil
import subprocess
import sys
import time

from harness import TestFailure, check

IN_NETNS = "JAKAGW_IN_NETNS"
TABLE = "jakagw_faults"
TOOLS = (("unshare", "util-linux"), ("ip", "iproute2"), ("nft", "nftables"), ("ss", "iproute2"))


def _run(argv, stdin=None):
    return subprocess.run(argv, input=stdin, capture_output=True, text=True)


def nft(script):
    """Runs an nft script as one transaction; a failure fails the test."""
    out = _run(["nft", "-f", "-"], stdin=script)
    check(out.returncode == 0, "nft failed (%s):\n%s" % (out.stderr.strip(), script))


def _setup_namespace():
    """Inside the new namespace: loopback up, an empty fault table."""
    out = _run(["ip", "link", "set", "lo", "up"])
    if out.returncode != 0:
        raise TestFailure("ip link set lo up: " + out.stderr.strip())
    nft("add table inet %s\n" % TABLE)


class Fault:
    """One fault in force: a base chain of the fault table."""
    serial = 0

    def __init__(self, what, rules):
        Fault.serial += 1
        self.chain = "fault_%d" % Fault.serial
        self.what = what
        self.rules = rules
        body = "".join("add rule inet %s %s %s\n" % (TABLE, self.chain, r) for r in rules)
        nft("add chain inet %s %s { type filter hook output priority 0; policy accept; }\n%s"
            % (TABLE, self.chain, body))
        self.since = time.monotonic()
        self.active = True

    def restore(self):
        """The rule gone, at once; the time it happened."""
        if self.active:
            nft("flush chain inet %s %s\ndelete chain inet %s %s\n"
                % (TABLE, self.chain, TABLE, self.chain))
            self.active = False
        return time.monotonic()


def _matches(port, direction, peer):
    """nft matches for the packets of one direction of a server port."""
    to, frm = "tcp dport %d" % port, "tcp sport %d" % port
    if peer:
        address, peer_port = peer
        family = "ip6" if ":" in address else "ip"
        to = "%s saddr %s tcp sport %d %s" % (family, address, peer_port, to)
        frm = "%s daddr %s tcp dport %d %s" % (family, address, peer_port, frm)
    check(direction in ("both", "to", "from"), "direction %r" % direction)
    return {"both": [to, frm], "to": [to], "from": [frm]}[direction]


def pull(port, direction="both", peer=None):
    """A silent pull: every packet of that direction dropped."""
    return Fault("pull %d %s" % (port, direction),
                 [m + " drop" for m in _matches(port, direction, peer)])


def reset(port, peer=None):
    """Every packet sent to the server port is answered with a TCP reset
    (the sender's connection is reset; the server hears nothing more)."""
    return Fault("reset %d" % port,
                 [m + " reject with tcp reset" for m in _matches(port, "to", peer)])


def loss(ports, percent):
    """Random loss of 'percent' of the packets to and from each port."""
    check(0 < percent < 100, "loss %r%%" % percent)
    rules = []
    for port in ports:
        rules += ["%s numgen random mod 100 < %d drop" % (m, percent)
                  for m in _matches(port, "both", None)]
    return Fault("loss %s %d%%" % (ports, percent), rules)


def unacknowledged_bytes(port):
    """Bytes sent to 'port' that its peer has not acknowledged, over every
    socket of the namespace, orphans (closed by their program, still in the
    kernel) included: while this is not 0 the kernel may still deliver
    them."""
    out = _run(["ss", "-tnH", "state", "all", "dport", "= :%d" % port])
    check(out.returncode == 0, "ss: " + out.stderr.strip())
    total = 0
    for line in out.stdout.splitlines():
        fields = line.split()
        if len(fields) >= 3 and fields[2].isdigit():
            total += int(fields[2])  # Send-Q
    return total


def _preflight():
    """Whether this machine can run the suite: None, or why not."""
    missing = ["%s (package %s)" % (t, p) for t, p in TOOLS if shutil.which(t) is None]
    if missing:
        return "missing " + ", ".join(missing) + ": run scripts/install-deps.sh netfault"
    out = _run(["unshare", "-n", "--", "sh", "-c",
                "ip link set lo up && nft add table inet probe && nft list tables"])
    if out.returncode != 0:
        return ("cannot make a network namespace with nftables (unshare -n, ip, nft; "
                "this needs root: CAP_SYS_ADMIN and CAP_NET_ADMIN): " +
                (out.stderr.strip() or out.stdout.strip()))
    return None


def main(tests, extra=()):
    """The suite's entry point. Outside a namespace: each test (or those
    named on the command line, 'extra' ones only so) runs in a new one, in
    a child process; one "PASS"/"FAIL" line each and a closing count.
    Inside: the one test."""
    from harness import run
    by_name = {t.__name__: t for t in list(tests) + list(extra)}
    if os.environ.get(IN_NETNS) == "1":
        try:
            _setup_namespace()
        except TestFailure as e:
            print("FAIL %s: the network namespace: %s" % (sys.argv[1], e))
            print("0 passed, 1 failed")
            sys.exit(1)
        run([by_name[sys.argv[1]]])
        return
    names = sys.argv[1:] or [t.__name__ for t in tests]
    for name in names:
        check(name in by_name, "no test %s (tests: %s)" % (name, " ".join(by_name)))
    why = _preflight()
    if why:
        print("FAIL network namespace: %s" % why)
        print("0 passed, %d failed" % len(names))
        sys.exit(1)
    passed = failed = 0
    env = dict(os.environ, **{IN_NETNS: "1"})
    for name in names:
        # The child prints its own PASS/FAIL line (and a count of one,
        # which the closing count below follows).
        child = subprocess.run(["unshare", "-n", "--", sys.executable,
                                os.path.abspath(sys.argv[0]), name], env=env)
        if child.returncode == 0:
            passed += 1
        else:
            failed += 1
    print("%d passed, %d failed" % (passed, failed))
    sys.exit(1 if failed else 0)
