"""Virtual segment benchmark: one LRW round trip through 64 emulated slaves on a veth pair,
against a bare raw-socket echo on the same veth pair, in the same run.

Run from the checkout, as root:
    python3 bench/virtual_segment.py [-n N] [--rounds R] [--layouts same,split] [--profile]

Method (target: median round trip within 3x of the bare echo):

  1. Two fresh network namespaces ``ecatbench-<pid>-a`` / ``-b`` with a veth pair ``va`` (A)
     / ``vb`` (B), IPv6 off.  Both are deleted at the end, also on errors and Ctrl-C.
  2. In B, ``python -m ecatcfg simulate`` serves a 64-slave line of the example devices
     (coupler + EX1004 / EX2008 / EX1008 repeating; EXD-402 CiA 402 drives too when the CoE
     runtime, ``runtime/segment/objects.py`` + ``runtime/segment/sdo_server.py``, exists).
     A recorder in B keeps a copy of every frame the master sends while it configures the line.
  3. In A, SOEM (pysoem) configures the line: config_init, config_map, SAFEOP, process
     data, OP; it reports the IOmap size and its expected WKC and leaves (no INIT request).
     The LRW frame SOEM sends for that IOmap (LRW, logical address 0, IOmap-size bytes) is
     built with ``runtime.wire.encode`` and checked against the LRW SOEM really sent (from
     the recording).
  4. For each CPU layout (``same``: pinger and responder both pinned to CPU 0; ``split``:
     pinger on CPU 0, responder on CPU 1; ``free``: not pinned, on request only, because the
     scheduler then places the echo and the segment differently and the ratio flips between
     two modes), rounds, baseline first and last, so noise is shared: echo, segment, echo,
     segment, ..., echo.  Between segment rounds the simulator is paused (SIGSTOP), an echo
     responder in B (a tiny Python process: recv on vb, WKC + 1, U/L bit of the source MAC
     set, send back) answers instead; it is ended before the segment is resumed (SIGCONT).
     Each round a pinger process in A opens a raw AF_PACKET socket bound to (va, 0x88A4)
     that ignores PACKET_OUTGOING, drains stale frames, and sends the same LRW frame N times
     one at a time (ping-pong), timing each send -> matching reply with
     ``time.perf_counter_ns``.  Every reply is checked: same index and length, U/L bit set,
     WKC as expected (for the segment the ETG.1000.4 count from SOEM's mapping: +1 per
     slave read, +2 per slave written; 1 for the echo); and for the segment, that the input
     bits came back overwritten by the slaves (the frame is sent with all data bytes 0xFF).
     Before each segment round the pinger acknowledges the SM-watchdog errors of the pause
     and requests OP (BWR 0x0120 = 0x0018), and it reads the OR of all AL status registers
     (BRD 0x0130) before and after the round, so the state measured in is known (OP: 0x08).
  5. In-process: the same 64-slave segment is built with ``runtime.emulate.segment``, fed
     the recorded SOEM configuration frames (same register writes, so the same FMMUs, SMs
     and states), and ``VirtualSegment.process(lrw)`` is timed on its own; ``--profile``
     adds a cProfile of it.  That is the segment's per-frame work without the wire.  Also
     timed: one SM-watchdog tick (``check_watchdog`` on every slave, which ``serve`` does
     every 2 ms between frames), since a frame arriving during it waits for it.

Reported per layout: min / median / p99 (and max) of each, segment over echo (median, p99,
min, and the median of the per-round ratios against the echo rounds either side).
Benchmarks are not tests: nothing here asserts the target; it is printed as met or not.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import datetime
import importlib.util
import io
import json
import os
import platform
import pstats
import queue
import shutil
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ESI_DIR = ROOT / "examples" / "esi"
IF_A, IF_B = "va", "vb"
TARGET = 3.0

# ------------------------------------------------------------------ helper processes
# Each runs as `python -c SCRIPT ...` inside a namespace (`ip netns exec`); none imports
# ecatcfg, and each ends by itself after its time limit.

_SOCKET = r"""
import socket, struct, sys, time
ETH_P = 0x88A4
def open_raw(iface, timeout):
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P))
    s.bind((iface, ETH_P))
    try:
        s.setsockopt(263, 23, 1)                 # SOL_PACKET, PACKET_IGNORE_OUTGOING
    except OSError:
        pass
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    set_timeout(s, timeout)
    return s
def set_timeout(s, seconds):
    # kernel receive timeout on a blocking socket: one recvfrom() per frame, no poll()
    sec = int(seconds)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO,
                 struct.pack("ll", sec, int((seconds - sec) * 1e6)))
OUTGOING = socket.PACKET_OUTGOING
def pin(cpu):
    import os
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
"""

# The bare echo: what any responder on this wire must at least do.
ECHO = _SOCKET + r"""
iface, limit = sys.argv[1], float(sys.argv[2])
pin(None if sys.argv[3] == "-" else int(sys.argv[3]))
s = open_raw(iface, 0.5)
print("ready", flush=True)
end = time.monotonic() + limit
while time.monotonic() < end:
    try:
        data, addr = s.recvfrom(2048)
    except BlockingIOError:
        continue
    if addr[2] == OUTGOING:
        continue
    buf = bytearray(data)
    buf[6] |= 0x02                               # U/L bit of the source MAC, as an ESC does
    end_dg = 16 + (struct.unpack_from("<H", buf, 14)[0] & 0x7FF)
    pos = 16
    while pos + 12 <= end_dg:                    # WKC + 1 on every datagram
        flags, = struct.unpack_from("<H", buf, pos + 6)
        at = pos + 10 + (flags & 0x7FF)
        struct.pack_into("<H", buf, at, (struct.unpack_from("<H", buf, at)[0] + 1) & 0xFFFF)
        if not flags & 0x8000:
            break
        pos = at + 2
    s.send(buf)
"""

# Keeps every frame the master sends (the replies are PACKET_OUTGOING here and ignored).
RECORD = _SOCKET + r"""
import signal
iface, out, limit = sys.argv[1], sys.argv[2], float(sys.argv[3])
stop = []
signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
s = open_raw(iface, 0.1)
frames = []
print("ready", flush=True)
end = time.monotonic() + limit
while not stop and time.monotonic() < end:
    try:
        data, addr = s.recvfrom(2048)
    except BlockingIOError:
        continue
    if addr[2] != OUTGOING:
        frames.append(data)
with open(out, "wb") as f:
    for fr in frames:
        f.write(struct.pack("<H", len(fr)) + fr)
print(f"recorded {len(frames)}", flush=True)
"""

# Ping-pong of one frame; JSON out.  opts: frame, n, warmup, wkc, check_inputs, setup/state
# frames (segment rounds only).
PING = _SOCKET + r"""
import json
iface, opts = sys.argv[1], json.loads(sys.argv[2])
pin(opts.get("cpu"))
s = open_raw(iface, 0.3)
def drain(quiet):
    set_timeout(s, quiet)
    n = 0
    end = time.monotonic() + 30
    while time.monotonic() < end:
        try:
            s.recvfrom(2048)
            n += 1
        except BlockingIOError:
            break
    set_timeout(s, 1.0)
    return n
def exchange(frame):
    s.send(frame)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        try:
            data, addr = s.recvfrom(2048)
        except BlockingIOError:
            return None
        if addr[2] != OUTGOING and data[17] == frame[17]:
            return data
    return None
def wkc_and_data(reply, n):
    return (struct.unpack_from("<H", reply, 26 + n)[0], bytes(reply[26:26 + n]))
result = {"stale": drain(0.3)}
for key in ("setup", "state"):
    if key in opts:
        frame = bytes.fromhex(opts[key])
        reply = exchange(frame)
        n = struct.unpack_from("<H", frame, 22)[0] & 0x7FF
        result[key + "_before"] = (None if reply is None
                                   else [*map(lambda x: x.hex() if isinstance(x, bytes) else x,
                                              wkc_and_data(reply, n))])
# no pause from here on: the SM watchdog (100 ms) runs from the OP request
frame = bytearray.fromhex(opts["frame"])
n = struct.unpack_from("<H", frame, 22)[0] & 0x7FF
sent_data = bytes(frame[26:26 + n])
rtts, lost, bad, stale, wkcs, changed = [], 0, 0, 0, set(), None
clock = time.perf_counter_ns
for i in range(opts["warmup"] + opts["n"]):
    frame[17] = i & 0xFF
    t0 = clock()
    s.send(frame)
    while True:
        try:
            data, addr = s.recvfrom(2048)
        except BlockingIOError:
            data = None
            break
        if addr[2] != OUTGOING and data[17] == frame[17] and len(data) == len(frame):
            break
        stale += 1
    t1 = clock()
    if data is None:
        lost += 1
        if lost > 20:
            break                                # the responder is gone: report, stop
        continue
    wkc, back = wkc_and_data(data, n)
    wkcs.add(wkc)
    ok = wkc == opts["wkc"] and data[6] & 0x02
    if opts.get("check_inputs"):
        ok = ok and back != sent_data
    if changed is None:
        changed = sum(bin(a ^ b).count("1") for a, b in zip(back, sent_data))
    if not ok:
        bad += 1
    if i >= opts["warmup"]:
        rtts.append(t1 - t0)
result.update(rtts=rtts, lost=lost, bad=bad, stale=stale, wkcs=sorted(wkcs),
              changed_bits=changed)
if "state" in opts:
    reply = exchange(bytes.fromhex(opts["state"]))
    result["state_after"] = None if reply is None else [
        *map(lambda x: x.hex() if isinstance(x, bytes) else x, wkc_and_data(reply, 2))]
print(json.dumps(result), flush=True)
"""

# SOEM configures the line and leaves it in OP (no INIT request at the end).
SOEM = r"""
import json, sys, time
import pysoem
m = pysoem.Master()
m.open(sys.argv[1])
r = {}
try:
    t = time.monotonic()
    r["found"] = m.config_init()
    r["init_s"] = round(time.monotonic() - t, 2)
    if r["found"] > 0:
        r["iomap"] = m.config_map()
        r["sizes"] = [(len(s.output), len(s.input)) for s in m.slaves]
        m.state = pysoem.SAFEOP_STATE
        m.write_state()
        r["safeop"] = m.state_check(pysoem.SAFEOP_STATE, 5_000_000)
        m.send_processdata()
        m.receive_processdata(10_000)
        m.state = pysoem.OP_STATE
        m.write_state()
        for _ in range(400):
            m.send_processdata()
            r["wkc"] = m.receive_processdata(10_000)
            if m.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        for _ in range(20):
            m.send_processdata()
            r["wkc"] = m.receive_processdata(10_000)
            time.sleep(0.001)
        r["op"] = m.read_state()
        r["expected_wkc"] = m.expected_wkc
        r["config_s"] = round(time.monotonic() - t, 2)
finally:
    m.close()
    print(json.dumps(r), flush=True)
"""

# ------------------------------------------------------------------ namespaces, processes


class Bench:
    """The two namespaces, the veth pair and every process started in them."""

    def __init__(self) -> None:
        self.ns_a = f"ecatbench-{os.getpid()}-a"
        self.ns_b = f"ecatbench-{os.getpid()}-b"
        self.procs: list[subprocess.Popen] = []
        self.created: list[str] = []

    def up(self) -> None:
        for ns in (self.ns_a, self.ns_b):
            _run(["ip", "netns", "add", ns])
            self.created.append(ns)
            _run(["ip", "netns", "exec", ns, "sysctl", "-q", "-w",
                  "net.ipv6.conf.all.disable_ipv6=1", "net.ipv6.conf.default.disable_ipv6=1"])
        _run(["ip", "link", "add", IF_A, "netns", self.ns_a, "type", "veth",
              "peer", "name", IF_B, "netns", self.ns_b])
        for ns, iface in ((self.ns_a, IF_A), (self.ns_b, IF_B)):
            _run(["ip", "-n", ns, "link", "set", "lo", "up"])
            _run(["ip", "-n", ns, "link", "set", iface, "up"])

    def start(self, ns: str, argv: list[str]) -> subprocess.Popen:
        """``argv`` in ``ns``, in a session of its own; stdout read line by line into
        ``proc.lines`` (a queue), stderr into a temporary file."""
        err = tempfile.TemporaryFile(mode="w+")
        proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], stdout=subprocess.PIPE,
                                stderr=err, text=True, start_new_session=True)
        proc.err = err                                          # type: ignore[attr-defined]
        proc.lines = queue.Queue()                              # type: ignore[attr-defined]
        proc.seen = []                                          # type: ignore[attr-defined]
        proc.stamps = []                                        # type: ignore[attr-defined]

        def pump() -> None:
            for line in proc.stdout:                            # type: ignore[union-attr]
                proc.seen.append(line)                          # type: ignore[attr-defined]
                proc.stamps.append((time.monotonic(), line))    # type: ignore[attr-defined]
                proc.lines.put(line)                            # type: ignore[attr-defined]
            proc.lines.put(None)                                # type: ignore[attr-defined]
        threading.Thread(target=pump, daemon=True).start()
        self.procs.append(proc)
        return proc

    def run(self, ns: str, argv: list[str], timeout: float) -> str:
        """``argv`` in ``ns`` to completion; its stdout.  Killed after ``timeout``."""
        proc = self.start(ns, argv)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            stop(proc)
            raise RuntimeError(f"{argv[:3]} did not finish in {timeout} s") from None
        with contextlib.suppress(queue.Empty):                  # stdout read to the end
            while proc.lines.get(timeout=5) is not None:        # type: ignore[attr-defined]
                pass
        out = "".join(proc.seen)                                # type: ignore[attr-defined]
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(argv[:3])} failed ({proc.returncode}): "
                               f"{stderr_of(proc)}")
        return out

    def close(self) -> None:
        for proc in self.procs:
            stop(proc)
        for ns in self.created:
            # Anything still inside our private namespaces was started here.
            pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True,
                                  text=True, timeout=10).stdout.split()
            for pid in pids:
                with contextlib.suppress(ProcessLookupError, ValueError):
                    os.kill(int(pid), signal.SIGKILL)
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10)


def _run(argv: list[str]) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=20)
    if done.returncode:
        raise RuntimeError(f"`{' '.join(argv)}` failed: {done.stderr.strip()}")


def stderr_of(proc: subprocess.Popen) -> str:
    proc.err.seek(0)                                            # type: ignore[attr-defined]
    return proc.err.read().strip()[-2000:]                      # type: ignore[attr-defined]


def wait_for(proc: subprocess.Popen, prefix: str, timeout: float) -> str:
    end = time.monotonic() + timeout
    while True:
        try:
            line = proc.lines.get(timeout=max(0.0, end - time.monotonic()))  # type: ignore
        except queue.Empty:
            raise RuntimeError(f"no {prefix!r} line after {timeout} s") from None
        if line is None:
            raise RuntimeError(f"process ended before {prefix!r}: {stderr_of(proc)}")
        if line.startswith(prefix):
            return line.strip()


def signal_group(proc: subprocess.Popen, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)


def stop(proc: subprocess.Popen) -> None:
    """End a process started here (SIGCONT first: it may be paused), then its group."""
    if proc.poll() is not None:
        return
    signal_group(proc, signal.SIGCONT)
    for sig, grace in ((signal.SIGTERM, 5), (signal.SIGKILL, 5)):
        signal_group(proc, sig)
        try:
            proc.wait(grace)
            return
        except subprocess.TimeoutExpired:
            continue


# ------------------------------------------------------------------ the line, frames, stats

def line(n: int, drives: bool) -> list[tuple[str, str]]:
    """(name, device): a coupler, then EX1004 / EX2008 / EX1008 repeating; with ``drives``
    an EXD-402 in every 16th place."""
    io = ["EX1004", "EX2008", "EX1008"]
    out = [("coupler", "EX1100")]
    for i in range(1, n):
        dev = "EXD-402" if drives and i % 16 == 15 else io[(i - 1) % len(io)]
        out.append((f"s{i}", dev))
    return out


def coe_runtime() -> bool:
    return all(importlib.util.find_spec(f"ecatcfg.runtime.{m}") is not None
               for m in ("objects", "sdo_server"))


def read_frames(path: Path) -> list[bytes]:
    data, frames, pos = path.read_bytes(), [], 0
    while pos < len(data):
        n, = struct.unpack_from("<H", data, pos)
        frames.append(data[pos + 2:pos + 2 + n])
        pos += 2 + n
    return frames


def transitions(lines: list[str]) -> str:
    """``slave N (name): STATE`` lines as runs: ``24 x SAFEOP ERR 0x001B -> 24 x OP``."""
    runs: list[list] = []
    for ln in lines:
        what = ln.split("): ", 1)[-1].strip()
        if runs and runs[-1][1] == what:
            runs[-1][0] += 1
        else:
            runs.append([1, what])
    return " -> ".join(f"{n} x {w}" for n, w in runs) or "none"


LAYOUTS = {                     # pinger CPU, responder CPU (None: the scheduler decides)
    "same": (0, 0), "split": (0, 1), "free": (None, None)}
LAYOUT_TEXT = {"same": "pinger and responder pinned to CPU 0",
               "split": "pinger on CPU 0, responder on CPU 1",
               "free": "not pinned"}


def report(layout: str, results: dict[str, list[dict]]) -> tuple[float, float]:
    """Print one layout's numbers; return the echo and segment medians (ns)."""
    print(f"\n## {layout}: {LAYOUT_TEXT[layout]}")
    rtt = {k: [x for res in v for x in res["rtts"]] for k, v in results.items()}
    for kind, rounds in results.items():
        meds = ", ".join(f"{statistics.median(r['rtts']) / 1e3:.1f}" for r in rounds)
        lost = sum(r["lost"] for r in rounds)
        bad = sum(r["bad"] for r in rounds)
        wkcs = sorted({w for r in rounds for w in r["wkcs"]})
        slow = sum(1 for x in rtt[kind] if x > 1e6)
        print(f"{kind:8} RTT us (min / median / p99): {us(rtt[kind])}, max "
              f"{max(rtt[kind]) / 1e3:.0f}, > 1 ms {slow}; per-round medians {meds}; "
              f"lost {lost}, failed checks {bad}, WKC {wkcs}, data bits changed "
              f"{rounds[0]['changed_bits']}")
    per_round: list[float] = []
    for i, r in enumerate(results["segment"]):
        echo_med = (statistics.median(results["echo"][i]["rtts"])
                    + statistics.median(results["echo"][i + 1]["rtts"])) / 2
        per_round.append(statistics.median(r["rtts"]) / echo_med)
        print(f"  segment round {i + 1}: {per_round[-1]:.2f}x the echo rounds around it; "
              f"OP+ACK WKC {(r.get('setup_before') or ['-'])[0]}, before "
              f"{al_state(r.get('state_before'))}, after {al_state(r.get('state_after'))}; "
              f"stale frames drained {r['stale']}; state changes: {r['changes']}")
    e_med, s_med = statistics.median(rtt["echo"]), statistics.median(rtt["segment"])
    ratio = s_med / e_med
    print(f"segment / echo: median {ratio:.2f}x, p99 {p99(rtt['segment']) / p99(rtt['echo']):.2f}x"
          f", min {min(rtt['segment']) / min(rtt['echo']):.2f}x, median of the per-round "
          f"ratios {statistics.median(per_round):.2f}x; target median <= {TARGET:.0f}x: "
          f"{'met' if ratio <= TARGET else 'NOT met'}")
    return e_med, s_med


def p99(values: list[int | float]) -> float:
    return statistics.quantiles(values, n=100)[98]


def us(values: list[int]) -> str:
    """``min / median / p99`` in microseconds (values in ns)."""
    return (f"{min(values) / 1e3:.1f} / {statistics.median(values) / 1e3:.1f} / "
            f"{p99(values) / 1e3:.1f}")


def al_state(pair: list | None) -> str:
    if not pair:
        return "no reply"
    wkc, data = pair
    return f"AL status OR 0x{int.from_bytes(bytes.fromhex(data), 'little'):04X} (WKC {wkc})"


# ------------------------------------------------------------------ main

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=3000, help="timed round trips per round")
    ap.add_argument("--rounds", type=int, default=5,
                    help="segment rounds (echo rounds: one more)")
    ap.add_argument("--warmup", type=int, default=200, help="untimed round trips per round")
    ap.add_argument("--slaves", type=int, default=64)
    ap.add_argument("--layouts", default="same,split",
                    help="CPU placements of pinger and responder, comma-separated: same "
                         "(both on CPU 0), split (CPU 0 / CPU 1), free (not pinned)")
    ap.add_argument("--no-drives", action="store_true",
                    help="only the non-CoE devices even when the CoE runtime exists")
    ap.add_argument("--profile", action="store_true",
                    help="cProfile of the in-process VirtualSegment.process(lrw)")
    ap.add_argument("--keep", action="store_true",
                    help="keep the temporary directory (line.yaml, soem.frames: SOEM's "
                         "configuration frames, 2-byte length + frame each) for profiling")
    args = ap.parse_args()
    run_as_root(ap, args, LAYOUTS, "vseg", run)


def run_as_root(ap: argparse.ArgumentParser, args: argparse.Namespace, layouts: dict,
                name: str, run: Callable[[argparse.Namespace, Path], None]) -> None:
    """The common frame of the namespace benchmarks: check ``--layouts`` and root, then
    ``run(args, tmp)`` in a temporary folder removed afterwards (kept with ``--keep``)."""
    unknown = set(args.layouts.split(",")) - set(layouts)
    if unknown:
        ap.error(f"--layouts: unknown {', '.join(sorted(unknown))} (known: {', '.join(layouts)})")
    if os.geteuid() != 0:
        sys.exit("needs root (network namespaces, veth, AF_PACKET)")
    sys.path.insert(0, str(ROOT.parent))
    tmp = Path(tempfile.mkdtemp(prefix=f"ecatcfg-bench-{name}-"))
    try:
        run(args, tmp)
    except KeyboardInterrupt:
        sys.exit("interrupted (namespaces and processes removed)")
    finally:
        if args.keep:
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


def run(args: argparse.Namespace, tmp: Path) -> None:
    import pysoem
    from ecatcfg.esc import Cmd, Reg
    from ecatcfg.runtime.wire import Datagram, encode

    drives = coe_runtime() and not args.no_drives
    slaves = line(args.slaves, drives)
    topo = tmp / "line.yaml"
    topo.write_text("slaves:\n" + "".join(f"  - {{name: {n}, device: '{d}'}}\n"
                                          for n, d in slaves))
    mix = {d: sum(1 for _, x in slaves if x == d) for d in dict.fromkeys(d for _, d in slaves)}
    print(f"# {len(slaves)} slaves ({', '.join(f'{k} x{v}' for k, v in mix.items())})"
          + ("" if drives else "; no CoE drives (runtime/segment/objects.py + sdo_server.py "
             "missing)" if not coe_runtime() else "; --no-drives"))
    print(f"# {platform.machine()}, {os.cpu_count()} CPUs, {platform.platform()}, "
          f"Python {platform.python_version()}, pysoem {pysoem.__version__}, "
          f"{datetime.date.today()}; n {args.n} x {args.rounds} rounds, warmup {args.warmup}")

    bench = Bench()
    previous = signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        bench.up()
        py = sys.executable
        sim = bench.start(bench.ns_b, [
            py, "-m", "ecatcfg", "simulate", "--esi", str(ESI_DIR), "--topology", str(topo),
            "--iface", IF_B, "--no-cache", "--duration", "900"])
        ready = wait_for(sim, "ready:", 60)
        rec_path = tmp / "soem.frames"
        rec = bench.start(bench.ns_b, [py, "-c", RECORD, IF_B, str(rec_path), "300"])
        wait_for(rec, "ready", 10)
        soem = json.loads(bench.run(bench.ns_a, [py, "-c", SOEM, IF_A], timeout=300)
                          .strip().splitlines()[-1])
        signal_group(rec, signal.SIGTERM)
        rec.wait(10)
        recorded = read_frames(rec_path)
        print(f"{ready}; SOEM found {soem.get('found')} in {soem.get('init_s')} s, "
              f"in {soem.get('config_s')} s to OP: IOmap {soem.get('iomap')} bytes, OP "
              f"reached: {soem.get('op') == 8} (state {soem.get('op')}), WKC in OP "
              f"{soem.get('wkc')} (SOEM's expected_wkc {soem.get('expected_wkc')}); "
              f"{len(recorded)} frames recorded")
        if soem.get("found") != len(slaves) or not soem.get("iomap"):
            raise RuntimeError(f"SOEM did not configure the line: {soem}")
        iomap = soem["iomap"]
        # ETG.1000.4: an LRW adds 1 for each slave it reads from and 2 for each it writes to
        # (3 for both).  SOEM's own expected_wkc leaves out bit-oriented input slaves.
        expected = sum(2 * (o > 0) + (i > 0) for o, i in soem["sizes"])

        lrw = encode([Datagram.logical(Cmd.LRW, 0, b"\xff" * iomap)])
        soem_lrw = [f for f in recorded if len(f) > 16 and f[16] == Cmd.LRW]
        if soem_lrw:
            last = soem_lrw[-1]
            same = (last[16], last[18:22], len(last), last[14:16]) == \
                   (lrw[16], lrw[18:22], len(lrw), lrw[14:16])
            print(f"LRW frame: {len(lrw)} bytes ({iomap} data bytes at logical 0); SOEM's "
                  f"own LRW frame: {len(last)} bytes, same header/length: "
                  f"{'yes' if same else 'NO'}")
        else:
            print(f"LRW frame: {len(lrw)} bytes; (no LRW in the recording to compare)")
        op_ack = encode([Datagram.physical(Cmd.BWR, 0, Reg.AL_CONTROL, b"\x18\x00",
                                           idx=0xE0)])
        al_brd = encode([Datagram.physical(Cmd.BRD, 0, Reg.AL_STATUS, 2, idx=0xE1)])

        def ping(opts: dict, cpu: int | None) -> dict:
            base = {"frame": lrw.hex(), "n": args.n, "warmup": args.warmup, "cpu": cpu}
            out = bench.run(bench.ns_a, [py, "-c", PING, IF_A, json.dumps({**base, **opts})],
                            timeout=120)
            return json.loads(out.strip().splitlines()[-1])

        def echo_round(cpus: tuple[int | None, int | None]) -> dict:
            echo = bench.start(bench.ns_b, [py, "-c", ECHO, IF_B, "120",
                                            "-" if cpus[1] is None else str(cpus[1])])
            wait_for(echo, "ready", 10)
            try:
                return ping({"wkc": 1}, cpus[0])
            finally:
                stop(echo)

        def segment_round(cpus: tuple[int | None, int | None]) -> dict:
            os.sched_setaffinity(sim.pid, all_cpus if cpus[1] is None else {cpus[1]})
            start = time.monotonic()
            signal_group(sim, signal.SIGCONT)
            try:
                result = ping({"wkc": expected, "check_inputs": True,
                               "setup": op_ack.hex(), "state": al_brd.hex()}, cpus[0])
            finally:
                end = time.monotonic()
                signal_group(sim, signal.SIGSTOP)
            result["changes"] = transitions(
                [ln for t, ln in sim.stamps if start <= t <= end and ln.startswith("slave ")])
            return result

        all_cpus = os.sched_getaffinity(0)
        signal_group(sim, signal.SIGSTOP)
        measured = {}
        for layout in args.layouts.split(","):
            cpus = LAYOUTS[layout]
            if any(c is not None and c not in all_cpus for c in cpus):
                print(f"layout {layout}: CPUs {cpus} not available here, skipped")
                continue
            results: dict[str, list[dict]] = {"echo": [], "segment": []}
            for _ in range(args.rounds):
                results["echo"].append(echo_round(cpus))
                results["segment"].append(segment_round(cpus))
            results["echo"].append(echo_round(cpus))
            measured[layout] = results
        signal_group(sim, signal.SIGCONT)
        stop(sim)
        changes = [ln for ln in sim.seen if ln.startswith("slave ")]   # type: ignore
        wire_diff = {}
        for layout, results in measured.items():
            wire_diff[layout] = report(layout, results)
        print(f"(the simulator printed {len(changes)} state changes in all: the SM watchdog "
              f"while it was paused between rounds, then OP again)")
    finally:
        bench.close()
        signal.signal(signal.SIGTERM, previous)

    # In process: the same line configured by replaying SOEM's frames, process() alone.
    from ecatcfg.compiler import topology
    from ecatcfg.compiler.plugged import plugged_devices
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate
    lib = Library([str(ESI_DIR)], cache=False)
    seg = emulate.segment([emulate.SlaveSpec(d.device, d.name, alias=d.alias)
                           for d in plugged_devices(topology.load(topo), lib)])
    for frame in recorded:
        seg.process(frame)
    states = {s.state.name + ("+ERR" if s.error else "") for s in seg.slaves}
    reply = seg.process(lrw)
    wkc, = struct.unpack_from("<H", reply, 26 + iomap)
    clock = time.perf_counter_ns
    for _ in range(args.warmup):
        seg.process(lrw)
    times = []
    for _ in range(args.n * args.rounds):
        t0 = clock()
        seg.process(lrw)
        times.append(clock() - t0)
    share = ", ".join(f"{statistics.median(times) / (s - e) * 100:.0f}% of the median "
                      f"segment - echo difference ({layout})"
                      for layout, (e, s) in wire_diff.items() if s > e)
    print(f"in process: {len(recorded)} SOEM frames replayed -> states {sorted(states)}; "
          f"VirtualSegment.process(lrw) us (min / median / p99): {us(times)}; WKC {wkc} "
          f"(ETG rule {expected}); {share}")
    ticks = []
    for _ in range(500):
        seg.process(lrw)                        # feeds the watchdog: the slaves stay in OP
        t0 = clock()
        now = time.monotonic()
        for slave in seg.slaves:
            slave.check_watchdog(now)
        ticks.append(clock() - t0)
    print(f"in process: one SM-watchdog tick over all {len(seg.slaves)} slaves (serve() does "
          f"one every 2 ms) us (min / median / p99): {us(ticks)}; states after "
          f"{sorted({s.state.name for s in seg.slaves})}")
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        for _ in range(2000):
            seg.process(lrw)
        prof.disable()
        text = io.StringIO()
        pstats.Stats(prof, stream=text).sort_stats("tottime").print_stats(12)
        print("cProfile of 2000 x process(lrw), by own time:")
        print("\n".join(text.getvalue().splitlines()[4:]))


if __name__ == "__main__":
    main()
