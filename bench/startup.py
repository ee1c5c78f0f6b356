"""Startup benchmark: time to OP and frames for 1, 8 and 64 emulated slaves, ``ecatcfg
apply`` against SOEM (pysoem) on the same virtual segment, in the same run.

Run from the checkout, as root:
    python3 bench/startup.py [-n N] [--sizes 1,8,64] [--corpus] [--layouts free,same,split]
                             [--breakdown N] [--bytecode cache|env] [--profile SIZE] [--keep]
                             [--realistic]

``--realistic``: slaves that take time (``simulate --realistic``, runtime/segment/timing.py: the
drives' mailbox replies 1.749 ms, PS and SO 100 ms each ...) on lines of CiA 402 drives
only, 8 and 64 (``402x8``, ``402x64``), each with its PDO assignment over CoE.  apply runs
``--cycles 1``; the SOEM script writes the same PDO assignment SDOs as the ENI's PS
InitCmds (pysoem ``sdo_write``, slave after slave, in PREOP before ``config_map``), so both
masters do the same mailbox work.  Target: apply at most 0.2x SOEM's time at 64 drives.

Method (targets: apply's whole process no slower than SOEM's, and apply's frames at most
1.2x the minimum defined below):

  1. Two fresh network namespaces ``ecatstartup-<pid>-a`` / ``-b`` with a veth pair ``va``
     (A) / ``vb`` (B), IPv6 off (``virtual_segment.Bench``).  Both are deleted at the end,
     also on errors, SIGTERM and Ctrl-C.
  2. Lines of the self-written example devices (examples/esi), no ``dc:`` key, so DC is off
     and both masters do the same kind of work: 1 = one EXD-402 CiA 402 drive (CoE: PDO
     assignment by SDO); 8 = EX1100 coupler, EX1004 x2, EX2008 x2, EX1008, EXD-402 x2;
     64 = the line of ``bench/virtual_segment.py`` (coupler, EX1004/EX2008/EX1008
     repeating, an EXD-402 in every 16th place: 4 drives).  ``--corpus`` adds a line of
     corpus devices (EK1100, EL1809, EL2008, Elmo Gold drive) when the corpus is there.
     Each line is compiled once (``ecatcfg compile``, not timed) to an ENI.
  3. Every run starts from power-on: ``ecatcfg simulate`` is started afresh in B for each
     run (slaves in INIT, fresh registers), waited for (``ready:``), and stopped (SIGTERM)
     after the master process ended; its ``stopped after N frames`` line is the frame
     count the segment processed, independent of the master's own count.
  4. The masters, each a whole new process in A, timed from spawn to exit
     (``time.perf_counter`` around ``ip netns exec ...``):
       apply: ``python -m ecatcfg apply ENI --iface va --state op --cycles 0 --stay
              --format json`` (scan + verify, IP, PS, SO; no cyclic run after OP; the
              slaves stay in OP).  Its stderr progress lines are time-stamped as they
              arrive, which splits the process into start-up (spawn to "scanning the
              line": interpreter, imports, ENI read), bus (scan to OP) and exit.
       SOEM:  ``python -c SOEM va``: import pysoem, config_init, config_map, SAFEOP
              request + state_check, one process data exchange, OP request, process data
              + state_check until OP; it times itself from before config_init to OP.
     apply cold: the same command with an empty plan cache ($XDG_CACHE_HOME a new folder
              per run): the first apply of an ENI, which parses it and stores the plan
              (eni/cache.py).  The plain apply runs share this run's cache
              folder, filled by the warm-up run: a machine that applies its ENI at every
              start.  Both are reported; neither touches the user's own cache.
     Runs alternate apply, SOEM, apply cold, apply, ...; the first round is a warm-up, not
     timed (the first layout's is recorded: a recorder in B keeps every frame the
     master sent, so the frames can be sorted: process data = frames with a logical
     datagram; mailbox; SII; AL status reads).  Per CPU layout (``free``: not pinned;
     ``same``: master and simulator on CPU 0; ``split``: CPU 0 / CPU 1, by ``taskset``),
     because SOEM's thousands of ping-pong frames depend on it.  Bytecode: the child
     processes get a bytecode cache in the temporary directory (PYTHONPYCACHEPREFIX,
     PYTHONDONTWRITEBYTECODE dropped), as an installed package has .pyc files;
     ``--bytecode env`` leaves the environment alone.
  4a. Breakdown: ``python -c BREAKDOWN`` runs the steps of cli/apply.py one by one with
     time stamps (imports, ENI read, report, socket, scan, IP, PS, SO, final read), plus
     the interpreter start-up before and the teardown after, from power-on as above.
  5. Minimum frames, from the compiled ENI (``eni.reader``):
       scan:  1 (BRD slave count) + 7 (each slave's identity chain, all slaves in
              parallel: 1 EEPROM-owner write + 2 x (SII read request, status poll, data
              read), 8-byte SII reads);
       per transition IP, PS, SO:  the master's InitCmds of that transition (one frame
              each: apply runs them alone, before and after the slaves) + the longest
              slave chain: that slave's register InitCmds of the transition (one frame
              each: every one waits for the one before) + 2 frames (SM0 write, SM1 read)
              per mailbox round trip of its CoE InitCmds (1 round trip for an expedited
              or normal transfer, + 1 per segment when the data does not fit SM0 - 16),
              less 1 per CoE InitCmd whose request can go ahead, in the frame that reads
              the answer to a download of another object before it
              (runtime/master/mailbox_pipeline.py).
     A state-check InitCmd counts once (no polling), a mailbox response is assumed
     to be there at the first SM1 read.  Commands of different slaves share frames
     without limit in this minimum; "lockstep min" also applies the 1486-byte frame
     limit to the same chains run in lockstep (what apply's scheduler can at best do).
     Not in the minimum: the ENI's cyclic frames that run during PS and SO
     (Requires=cycle; about one per cycle time while the transitions last, so their
     number depends on time, not on the work) and apply's AL status read after OP
     (for its final report).  The ratio is given for apply's configuration frames
     (frames sent minus those two) and for all frames sent.

Reported per line: wall time min / median over the timed runs for apply, apply cold and
SOEM, apply / SOEM (min / median), frames (apply: sent, configuration, cyclic; SOEM: the segment's
count), the minimum and the ratios.  A run whose master does not reach OP is listed as
failed, with what the master said (SOEM's exception, apply's JSON), and the figures are
taken over the runs that did.  Benchmarks are not tests: nothing is asserted.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import os
import platform
import queue
import re
import signal
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from timing import ms
from virtual_segment import (IF_A, IF_B, RECORD, Bench, line, read_frames, run_as_root,
                             signal_group, stop, wait_for)

ROOT = Path(__file__).resolve().parent.parent
ESI_DIR = ROOT / "examples" / "esi"
CORPUS = Path(os.environ.get("ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus")) / "esi"
TIME_TARGET = 1.0
REALISTIC_TARGET = 0.2
FRAME_TARGET = 1.2

# SOEM up to OP and out (no INIT request at the end), timing itself.
SOEM = r"""
import time
t0 = time.monotonic()
import json, sys
import pysoem
r = {"import_s": time.monotonic() - t0}
m = pysoem.Master()
m.open(sys.argv[1])
try:
    t = time.monotonic()
    r["found"] = m.config_init()
    r["init_s"] = time.monotonic() - t
    if r["found"] > 0 and len(sys.argv) > 2:
        # The ENI's PDO assignment SDOs (PS), slave after slave, as a SOEM program writes
        # them; config_map then reads the mapping back.
        m.state_check(pysoem.PREOP_STATE, 5_000_000)
        for i, cmds in enumerate(json.load(open(sys.argv[2]))):
            for index, sub, data, ca in cmds:
                m.slaves[i].sdo_write(index, sub, bytes.fromhex(data), ca)
        r["assign_s"] = time.monotonic() - t
    if r["found"] > 0:
        r["iomap"] = m.config_map()
        r["map_s"] = time.monotonic() - t
        m.state = pysoem.SAFEOP_STATE
        m.write_state()
        r["safeop"] = m.state_check(pysoem.SAFEOP_STATE, 5_000_000)
        r["safeop_s"] = time.monotonic() - t
        m.send_processdata()
        m.receive_processdata(10_000)
        m.state = pysoem.OP_STATE
        m.write_state()
        for _ in range(2000):
            m.send_processdata()
            m.receive_processdata(10_000)
            if m.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        r["op_s"] = time.monotonic() - t
        m.read_state()
        r["states"] = sorted({s.state for s in m.slaves})
        r["op"] = r["states"] == [pysoem.OP_STATE]
except Exception as exc:
    # Reported as a failed run (report_line), with what SOEM said.
    r["error"] = f"{type(exc).__name__}: {exc}"
    raise
finally:
    m.close()
    print(json.dumps(r), flush=True)
"""

# apply's steps in one process, as cli/apply.py runs them, each stamped (ms since the
# interpreter ran this script's first line); argv: ENI IFACE.  Prints one JSON object.
BREAKDOWN = r"""
import time
T0, E0 = time.perf_counter(), time.time()
import json, os, sys
marks = {}
def mark(what):
    marks[what] = round((time.perf_counter() - T0) * 1e3, 1)
import ecatcfg.cli
ecatcfg.cli.build_parser("apply").parse_args(["apply", sys.argv[1], "--iface", sys.argv[2]])
from ecatcfg.eni import cache as eni_cache
from ecatcfg.cli.report import ApplyReport
from ecatcfg.esc import AlState, Transition
from ecatcfg.runtime.network import Network
from ecatcfg.runtime.link import RawLink
mark("imports, parser")
plan = eni_cache.read_file(sys.argv[1]); mark("ENI read (plan cache)")
report = ApplyReport(plan, sys.argv[1], json_output=True); mark("report")
link = RawLink(sys.argv[2]); mark("raw socket")
net = Network(plan, link, on_event=lambda e: None); mark("Network()")
net.master.scan_and_verify(); mark("scan + verify")
for t in ("IP", "PS", "SO"):
    if t == "PS":
        net.master.setup_dc()
    net.master.run_transition(Transition[t]); mark(t)
report.final_states(net.master.read_states(), net.master.progress); mark("final read")
net.close(); mark("close")
report.finish(net, None, AlState.OP); json.dumps(report.as_json()); mark("JSON")
# As ecatcfg.cli.console ends: flush, then os._exit (no interpreter teardown).
print(json.dumps({"marks": marks, "start_at": E0, "exit_at": time.time()}), flush=True)
os._exit(0)
"""

TRANSITION_LINE = re.compile(r"^(.+?) -> (\w+): (\w+) in (\d+) ms, (\d+) frames")
KEYS = {"INIT -> PREOP": "IP", "PREOP -> SAFEOP": "PS", "SAFEOP -> OP": "SO"}


# ------------------------------------------------------------------ the lines

def lines(corpus: bool) -> dict[str, tuple[list[str], list[tuple[str, str]]]]:
    """label -> (ESI paths, [(name, device)])."""
    out = {
        "1": ([str(ESI_DIR)], [("axis1", "EXD-402")]),
        "8": ([str(ESI_DIR)], [("coupler", "EX1100"), ("in1", "EX1004"), ("in2", "EX1004"),
                               ("out1", "EX2008"), ("in3", "EX1008"), ("axis1", "EXD-402"),
                               ("out2", "EX2008"), ("axis2", "EXD-402")]),
        "64": ([str(ESI_DIR)], line(64, True)),
        "402x8": ([str(ESI_DIR)], [(f"axis{i}", "EXD-402") for i in range(8)]),
        "402x64": ([str(ESI_DIR)], [(f"axis{i}", "EXD-402") for i in range(64)]),
    }
    if corpus:
        files = [CORPUS / "beckhoff" / "Beckhoff EK11xx.xml",
                 CORPUS / "beckhoff" / "Beckhoff EL1xxx.xml",
                 CORPUS / "beckhoff" / "Beckhoff EL2xxx.xml",
                 CORPUS / "drives" / "Elmo_ECAT_00010420_V11.xml"]
        if all(f.exists() for f in files):
            out["corpus 8"] = ([str(f) for f in files], [
                ("ek1100", "EK1100"), ("di1", "EL1809"), ("do1", "EL2008"),
                ("di2", "EL1809"), ("do2", "EL2008"),
                ("elmo1", "0x9a:0x30924:0x10420"), ("do3", "EL2008"),
                ("elmo2", "0x9a:0x30924:0x10420")])
        else:
            print(f"# --corpus: not all of {', '.join(f.name for f in files)} under "
                  f"{CORPUS}; corpus line skipped")
    return out


def sizes_of(spec: str, known: dict) -> list[str]:
    return [s for s in spec.split(",") if s in known]


# ------------------------------------------------------------------ minimum frames

@dataclass
class Minimum:
    scan: int = 0
    scan_lockstep: int = 0
    steps: dict[str, tuple[int, int, str]] = field(default_factory=dict)   # chain, lockstep, who

    @property
    def total(self) -> int:
        return self.scan + sum(c for c, _, _ in self.steps.values())

    @property
    def lockstep(self) -> int:
        return self.scan_lockstep + sum(x for _, x, _ in self.steps.values())


def sdo_round_trips(cmd, mbx_out: int) -> int:
    """Mailbox round trips (SM0 write + SM1 read) of one CoE InitCmd at the least."""
    from ecatcfg.runtime.mailbox import NORMAL_OVERHEAD, SEGMENT_OVERHEAD
    if cmd.ccs == 2:                        # upload: one exchange when the answer fits
        return 1
    n = len(cmd.data)
    if n <= mbx_out - NORMAL_OVERHEAD:      # expedited (<= 4 bytes) or normal
        return 1
    return 1 + math.ceil((n - (mbx_out - NORMAL_OVERHEAD)) / (mbx_out - SEGMENT_OVERHEAD))


def packed_frames(sizes: list[int]) -> int:
    """Frames for datagrams of these sizes (header + data + WKC) packed in order, as
    ``runtime.transport.pack`` does."""
    from ecatcfg.runtime.master.transport import FRAME_DATA_LIMIT
    frames, used = 0, FRAME_DATA_LIMIT + 1
    for size in sizes:
        if used + size > FRAME_DATA_LIMIT:
            frames += 1
            used = 0
        used += size
    return frames


def lockstep_frames(chains: list[list[int]]) -> int:
    return sum(packed_frames([c[k] for c in chains if len(c) > k])
               for k in range(max(map(len, chains), default=0)))


def minimum_frames(plan) -> Minimum:
    from ecatcfg.esc import Cmd, Reg, Transition
    dg = 12                                                   # datagram header + WKC
    slaves = sorted(plan.slaves, key=lambda s: s.position)
    m = Minimum()
    identity = [dg + 1] + [dg + 6, dg + 2, dg + 8] * 2        # owner, 2 x (req, poll, read)
    m.scan = 1 + len(identity)
    m.scan_lockstep = 1 + lockstep_frames([identity] * len(slaves))
    for t in (Transition.IP, Transition.PS, Transition.SO):
        master = sum(1 for c in plan.master.init_cmds if t in c.transitions)
        chains, lengths = [], []
        for s in slaves:
            cmds = [c for c in s.init_cmds if t in c.transitions]
            coe = [c for c in (s.mailbox.coe_init_cmds if s.mailbox else [])
                   if t in c.transitions and not c.disabled]
            split = len(cmds)
            if coe and t != Transition.IP:      # CoE before the AL control write (replay.py)
                split = next((i for i, c in enumerate(cmds) if c.ado == Reg.AL_CONTROL
                              and c.cmd in (Cmd.APWR, Cmd.FPWR, Cmd.BWR)), len(cmds))
            mbx: list[int] = []
            before = None
            for c in coe:                   # none for a slave without a mailbox
                write, read = dg + s.mailbox.send.length, dg + s.mailbox.recv.length
                if before is not None and before.ccs != 2 and \
                        (before.index, before.subindex) != (c.index, c.subindex):
                    mbx[-1] += write          # the request ahead, behind the read before
                    mbx.append(read)
                else:
                    mbx += [write, read]
                mbx += [write, read] * (sdo_round_trips(c, s.mailbox.send.length) - 1)
                before = c
            chain = [dg + c.length for c in cmds[:split]] + mbx + \
                    [dg + c.length for c in cmds[split:]]
            chains.append(chain)
            lengths.append((len(chain), s.name))
        longest, who = max(lengths) if lengths else (0, "-")
        m.steps[t.name] = (master + longest, master + lockstep_frames(chains), who)
    return m


def pdo_assignment(plan) -> list[list[tuple[int, int, str, bool]]]:
    """Per slave in line order, the CoE downloads of its PS InitCmds (index, subindex,
    data hex, complete access): what the SOEM script writes in --realistic runs."""
    from ecatcfg.esc import Transition
    out = []
    for s in sorted(plan.slaves, key=lambda s: s.position):
        cmds = s.mailbox.coe_init_cmds if s.mailbox else []
        out.append([(c.index, c.subindex, c.data.hex(), bool(c.complete_access))
                    for c in cmds if Transition.PS in c.transitions and not c.disabled
                    and c.ccs == 1 and c.data is not None])
    return out


# ------------------------------------------------------------------ processes

@dataclass
class Run:
    wall: float                     # s, spawn to exit
    segment_frames: int | None      # the simulator's count
    result: dict                    # the master's JSON
    stamps: list[tuple[float, str]] = field(default_factory=list)   # (s since spawn, stderr)
    recorded: list[bytes] | None = None


class StartupBench(Bench):
    def __init__(self) -> None:
        super().__init__()
        self.ns_a = f"ecatstartup-{os.getpid()}-a"
        self.ns_b = f"ecatstartup-{os.getpid()}-b"

    def timed(self, argv: list[str], timeout: float,
              env: dict[str, str] | None = None) -> tuple[float, str, list]:
        """``argv`` in A to completion: (wall seconds, stdout, stderr lines stamped with
        seconds since the spawn)."""
        stamps: list[tuple[float, str]] = []
        self.spawned_at = time.time()
        t0 = time.perf_counter()
        proc = subprocess.Popen(["ip", "netns", "exec", self.ns_a, *argv],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, env=env)
        self.procs.append(proc)

        out: list[str] = []

        def pump_err() -> None:
            for ln in proc.stderr:                              # type: ignore[union-attr]
                stamps.append((time.perf_counter() - t0, ln.rstrip("\n")))

        def pump_out() -> None:
            out.append(proc.stdout.read())                      # type: ignore[union-attr]
        readers = [threading.Thread(target=f, daemon=True) for f in (pump_err, pump_out)]
        for reader in readers:
            reader.start()
        # A blocking wait(): Popen.wait(timeout) polls with sleeps of up to 50 ms, which
        # would round the wall time up to the next poll.  A timer ends a hung process.
        late = threading.Timer(timeout, stop, (proc,))
        late.start()
        proc.wait()
        wall = time.perf_counter() - t0
        late.cancel()
        if wall >= timeout:
            raise RuntimeError(f"{' '.join(argv[:4])} did not finish in {timeout} s")
        self.ended_at = time.time()
        for reader in readers:
            reader.join(5)
        if proc.returncode not in (0, 1):
            raise RuntimeError(f"{' '.join(argv[:4])} failed ({proc.returncode}): "
                               + "\n".join(s for _, s in stamps[-20:]))
        return wall, "".join(out), stamps


LAYOUTS = {                     # master CPU, simulator CPU (None: the scheduler decides)
    "free": (None, None), "same": (0, 0), "split": (0, 1)}
LAYOUT_TEXT = {"free": "not pinned", "same": "master and simulator pinned to CPU 0",
               "split": "master on CPU 0, simulator on CPU 1"}


def pinned(cpu: int | None, argv: list[str]) -> list[str]:
    return argv if cpu is None else ["taskset", "-c", str(cpu), *argv]


REALISTIC = False          # --realistic: the simulator's slaves take time


def start_simulator(bench: StartupBench, esi: list[str], topo: Path,
                    cpu: int | None = None) -> subprocess.Popen:
    argv = [sys.executable, "-m", "ecatcfg", "simulate", "--topology", str(topo),
            "--iface", IF_B, "--no-cache", "--duration", "900"]
    if REALISTIC:
        argv.append("--realistic")
    for path in esi:
        argv += ["--esi", path]
    sim = bench.start(bench.ns_b, pinned(cpu, argv))
    wait_for(sim, "ready:", 120)
    return sim


def end_simulator(sim: subprocess.Popen) -> int | None:
    signal_group(sim, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        sim.wait(20)
    with contextlib.suppress(queue.Empty):
        while sim.lines.get(timeout=5) is not None:             # type: ignore[attr-defined]
            pass
    stop(sim)
    for ln in sim.seen:                                         # type: ignore[attr-defined]
        if ln.startswith("stopped after"):
            return int(ln.split()[2])
    return None


def one_run(bench: StartupBench, esi: list[str], topo: Path, argv: list[str],
            record: Path | None, timeout: float,
            cpus: tuple[int | None, int | None] = (None, None),
            env: dict[str, str] | None = None) -> Run:
    sim = start_simulator(bench, esi, topo, cpus[1])
    rec = None
    try:
        if record is not None:
            rec = bench.start(bench.ns_b, [sys.executable, "-c", RECORD, IF_B, str(record),
                                           "600"])
            wait_for(rec, "ready", 10)
        wall, out, stamps = bench.timed(pinned(cpus[0], argv), timeout, env)
    finally:
        if rec is not None:
            signal_group(rec, signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                rec.wait(20)
        frames = end_simulator(sim)
    try:
        result = json.loads(out[out.index("{"):])
    except ValueError:
        raise RuntimeError(f"no JSON from {' '.join(argv[:4])}: {out[-500:]!r}; "
                           + "\n".join(s for _, s in stamps[-20:])) from None
    return Run(wall, frames, result, stamps,
               read_frames(record) if record is not None and record.exists() else None)


# ------------------------------------------------------------------ frame census

LOGICAL = {10, 11, 12}                     # LRD, LWR, LRW
SII_REGS = range(0x0500, 0x0510)


def datagrams(frame: bytes):
    """(cmd, ado, len) of each datagram of a master frame."""
    end = 16 + (int.from_bytes(frame[14:16], "little") & 0x7FF)
    pos = 16
    while pos + 12 <= min(end, len(frame)):
        cmd = frame[pos]
        ado = int.from_bytes(frame[pos + 4:pos + 6], "little")
        flags = int.from_bytes(frame[pos + 6:pos + 8], "little")
        n = flags & 0x7FF
        yield cmd, ado, n
        if not flags & 0x8000:
            break
        pos += 12 + n


def census(frames: list[bytes]) -> dict[str, int]:
    """Frames by what they carry (first match): process data (a logical datagram),
    mailbox (SM area >= 0x1000), SII EEPROM interface, AL status read, other."""
    out = {"process data": 0, "mailbox": 0, "SII": 0, "AL status read": 0, "other": 0}
    for f in frames:
        dgs = list(datagrams(f))
        if any(c in LOGICAL for c, _, _ in dgs):
            out["process data"] += 1
        elif any(c not in LOGICAL and a >= 0x1000 for c, a, _ in dgs):
            out["mailbox"] += 1
        elif any(a in SII_REGS for _, a, _ in dgs):
            out["SII"] += 1
        elif dgs and all(a == 0x0130 and c in (1, 4, 7) for c, a, _ in dgs):
            out["AL status read"] += 1
        else:
            out["other"] += 1
    return out


def apply_frames(run: Run, per_cycle: int) -> dict:
    """apply's frames from its JSON: per transition, cyclic, the rest."""
    res = run.result
    steps = {}
    for ev in res.get("events", []):
        hit = TRANSITION_LINE.match(ev)
        if hit and f"{hit.group(1)} -> {hit.group(2)}" in KEYS:
            steps[KEYS[f"{hit.group(1)} -> {hit.group(2)}"]] = int(hit.group(5))
    sent = res["frames"]["sent"]
    cyclic = res["cycles"]["count"] * per_cycle
    return {"sent": sent, "lost": res["frames"]["lost"], "steps": steps, "cyclic": cyclic,
            "scan+final": sent - sum(steps.values())}


def apply_phases(run: Run) -> tuple[float, float, float]:
    """(start-up, bus, exit) seconds from the stamped stderr lines."""
    start = next((t for t, s in run.stamps if s.startswith("scanning")), None)
    op = next((t for t, s in run.stamps if s.startswith("SAFEOP -> OP:")), None)
    if start is None or op is None:
        return math.nan, math.nan, math.nan
    return start, op - start, run.wall - op


# ------------------------------------------------------------------ main

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=5, help="timed runs per master and line")
    ap.add_argument("--sizes", default="1,8,64",
                    help="lines, comma-separated: 1, 8, 64 (and 'corpus 8' with --corpus)")
    ap.add_argument("--corpus", action="store_true",
                    help="also a line of corpus devices (EK1100, EL1809, EL2008, Elmo)")
    ap.add_argument("--profile", metavar="SIZE",
                    help="after the runs, one cProfile'd apply on this line")
    ap.add_argument("--layouts", default="free,same,split",
                    help="CPU placements of master and simulator, comma-separated: free "
                         "(not pinned), same (both on CPU 0), split (CPU 0 / CPU 1)")
    ap.add_argument("--breakdown", type=int, default=3, metavar="N",
                    help="runs of the in-process step breakdown of apply per line (0: none)")
    ap.add_argument("--bytecode", choices=["cache", "env"], default="cache",
                    help="cache (default): the child processes keep compiled bytecode in "
                         "the temporary directory (PYTHONPYCACHEPREFIX), as an installed "
                         "package has .pyc files; env: leave the environment as it is "
                         "(e.g. PYTHONDONTWRITEBYTECODE=1: every run compiles ecatcfg's "
                         "modules from source)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary directory")
    ap.add_argument("--realistic", action="store_true",
                    help="slaves that take time (simulate --realistic) on lines of CiA 402 "
                         "drives (default sizes 402x8,402x64); SOEM writes the same PDO "
                         "assignment SDOs; target apply <= 0.2x SOEM at 64 drives")
    args = ap.parse_args()
    if args.realistic:
        global REALISTIC
        REALISTIC = True
        if args.sizes == ap.get_default("sizes"):
            args.sizes = "402x8,402x64"
    run_as_root(ap, args, LAYOUTS, "startup", run)


def run(args: argparse.Namespace, tmp: Path) -> None:
    import pysoem
    from ecatcfg.eni import reader as eni_reader

    inherited = os.environ.get("PYTHONDONTWRITEBYTECODE")
    if args.bytecode == "cache":            # inherited by every process started here
        os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
        os.environ["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
    # apply's ENI plan cache (eni/cache.py) and the ESI index cache: a folder of
    # this run's, filled by the warm-up run, so the timed "apply" runs find the plan
    # cached, as on a machine that applies its ENI at every start.  "apply cold" runs
    # get a new empty folder each: the first apply of an ENI (parse + store).
    os.environ["XDG_CACHE_HOME"] = str(tmp / "cache")
    fresh = (tmp / f"cold-cache-{i}" for i in range(1_000_000))
    known = lines(args.corpus)
    sizes = sizes_of(args.sizes + (",corpus 8" if args.corpus else ""), known)
    print(f"# {platform.machine()}, {os.cpu_count()} CPUs, {platform.platform()}, Python "
          f"{platform.python_version()}, pysoem {pysoem.__version__}, "
          f"{datetime.date.today()}; {args.n} timed runs per master and line after one "
          f"recorded warm-up run each; bytecode: {args.bytecode} (PYTHONDONTWRITEBYTECODE "
          f"in the environment: {inherited or 'unset'})")
    py = sys.executable

    # compile (not timed)
    prepared = {}
    for label in sizes:
        esi, slaves = known[label]
        topo = tmp / f"line{label.replace(' ', '_')}.yaml"
        topo.write_text("slaves:\n" + "".join(f"  - {{name: {n}, device: '{d}'}}\n"
                                              for n, d in slaves))
        eni = topo.with_suffix(".eni.xml")
        argv = [py, "-m", "ecatcfg", "compile", str(topo), "-o", str(eni)]
        for path in esi:
            argv += ["--esi", path]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
        if done.returncode:
            print(f"# line {label}: compile failed, skipped: {done.stderr.strip()[-500:]}")
            continue
        plan = eni_reader.read_file(eni)
        if any(s.dc is not None for s in plan.slaves):
            print(f"# line {label}: the ENI has DC slaves; this bench wants DC off")
        per_cycle = sum(1 for f in plan.cyclic[0].frames) if plan.cyclic else 0
        mix = {d: sum(1 for _, x in slaves if x == d)
               for d in dict.fromkeys(d for _, d in slaves)}
        assign = topo.with_suffix(".sdo.json")
        assign.write_text(json.dumps(pdo_assignment(plan)))
        prepared[label] = (esi, topo, eni, plan, minimum_frames(plan), per_cycle, assign)
        print(f"# line {label}: {len(slaves)} slaves "
              f"({', '.join(f'{k} x{v}' for k, v in mix.items())}); "
              f"cyclic frames per cycle {per_cycle}, cycle time "
              f"{plan.cyclic[0].cycle_time if plan.cyclic else '-'} us")

    bench = StartupBench()
    previous = signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    results: dict[tuple[str, str], dict] = {}
    layouts = [x for x in args.layouts.split(",") if x]
    try:
        bench.up()
        for label, (esi, topo, eni, plan, minimum, per_cycle, assign) in prepared.items():
            apply_argv = [py, "-m", "ecatcfg", "apply", str(eni), "--iface", IF_A,
                          "--state", "op", "--cycles", "1" if REALISTIC else "0", "--stay",
                          "--format", "json"]
            soem_argv = [py, "-c", SOEM, IF_A] + ([str(assign)] if REALISTIC else [])
            for n_layout, layout in enumerate(layouts):
                cpus = LAYOUTS[layout]
                runs: dict[str, list[Run]] = {"apply": [], "apply cold": [], "SOEM": []}
                warm = {}
                for i in range(args.n + 1):
                    for kind, argv in (("apply", apply_argv), ("SOEM", soem_argv),
                                       ("apply cold", apply_argv)):
                        rec = tmp / f"{kind}.frames" if i == 0 and n_layout == 0 \
                            and kind != "apply cold" else None
                        env = dict(os.environ, XDG_CACHE_HOME=str(next(fresh))) \
                            if kind == "apply cold" else None
                        r = one_run(bench, esi, topo, argv, rec, 300, cpus, env)
                        if i == 0:
                            warm[kind] = r
                        else:
                            runs[kind].append(r)
                results[(label, layout)] = {"runs": runs, "warm": warm}
                report_line(f"{label} slaves, {layout} ({LAYOUT_TEXT[layout]})", runs, warm,
                            minimum, per_cycle)
            if args.breakdown:
                breakdown(bench, label, esi, topo, eni, args.breakdown)
        if args.profile:
            if args.profile not in prepared:
                print(f"--profile {args.profile}: no such line here")
            else:
                profile(bench, prepared[args.profile], tmp)
    finally:
        bench.close()
        signal.signal(signal.SIGTERM, previous)
    summary(results, prepared)


def report_line(label: str, runs: dict[str, list[Run]], warm: dict[str, Run],
                minimum: Minimum, per_cycle: int) -> None:
    print(f"\n## {label}")
    a, s, cold = (reached(runs[k], k) for k in ("apply", "SOEM", "apply cold"))
    for kind, all_runs in runs.items():
        for i, r in enumerate(all_runs, 1):
            if r not in reached(all_runs, kind):
                print(f"{kind} run {i} FAILED (not in OP): "
                      f"{r.result.get('error') or json.dumps(r.result)[:500]}")
    print("runs that reached OP: " + ", ".join(
        f"{k} {len(reached(v, k))} of {len(v)}" for k, v in runs.items()))
    if not (a and s and cold):
        print("no figures: a master has no run that reached OP")
        return
    aw, sw, cw = [r.wall for r in a], [r.wall for r in s], [r.wall for r in cold]
    print(f"wall ms (min / median, runs that reached OP): apply {ms(aw)}, SOEM {ms(sw)}; "
          f"apply / SOEM "
          f"{min(aw) / min(sw):.2f}x / {statistics.median(aw) / statistics.median(sw):.2f}x; "
          f"apply with a cold plan cache {ms(cw)}, / SOEM {min(cw) / min(sw):.2f}x / "
          f"{statistics.median(cw) / statistics.median(sw):.2f}x")
    ph = [apply_phases(r) for r in a]
    print("apply phases ms (median): start-up (spawn -> 'scanning the line') "
          f"{statistics.median(p[0] for p in ph) * 1e3:.0f}, bus (scan -> OP) "
          f"{statistics.median(p[1] for p in ph) * 1e3:.0f}, exit "
          f"{statistics.median(p[2] for p in ph) * 1e3:.0f}; transitions ms (median): "
          + ", ".join(f"{k} {statistics.median(_step_ms(r, k) for r in a):.0f}"
                      for k in ("IP", "PS", "SO")))
    sr = [r.result for r in s]
    print("SOEM in process ms (median): import "
          f"{statistics.median(x['import_s'] for x in sr) * 1e3:.0f}, config_init "
          f"{statistics.median(x['init_s'] for x in sr) * 1e3:.0f}, +config_map "
          f"{statistics.median(x['map_s'] - x['init_s'] for x in sr) * 1e3:.0f}, +SAFEOP "
          f"{statistics.median(x['safeop_s'] - x['map_s'] for x in sr) * 1e3:.0f}, +OP "
          f"{statistics.median(x['op_s'] - x['safeop_s'] for x in sr) * 1e3:.0f}; total "
          f"{statistics.median(x['op_s'] for x in sr) * 1e3:.0f}; the rest of the process "
          "(interpreter, pysoem open/close, exit) "
          f"{statistics.median(r.wall - r.result['op_s'] for r in s) * 1e3:.0f}")
    af = [apply_frames(r, per_cycle) for r in a]
    for kind, r in warm.items():
        if r.recorded is not None:
            print(f"{kind} warm-up run recorded: {len(r.recorded)} frames (segment count "
                  f"{r.segment_frames}): " + ", ".join(f"{k} {v}" for k, v in
                                                       census(r.recorded).items()))
    print("apply frames per run (sent / segment count): "
          + ", ".join(f"{x['sent']}/{r.segment_frames}" for x, r in zip(af, a))
          + f"; lost {sum(x['lost'] for x in af)}")
    x = af[0]
    print(f"apply frames, first timed run: scan + final status read {x['scan+final']}, "
          + ", ".join(f"{k} {v}" for k, v in x["steps"].items())
          + f"; of them cyclic {x['cyclic']} ({x['cyclic'] // max(per_cycle, 1)} cycles)")
    print(f"minimum: scan {minimum.scan} + "
          + " + ".join(f"{k} {c} (longest: {w})" for k, (c, _, w) in minimum.steps.items())
          + f" = {minimum.total}; lockstep with 1486-byte frames: {minimum.lockstep} (scan "
          f"{minimum.scan_lockstep}, "
          + ", ".join(f"{k} {x}" for k, (_, x, _) in minimum.steps.items()) + ")")
    config = [f["sent"] - f["cyclic"] - final_read_frames(len(r.result["slaves"]))
              for f, r in zip(af, a)]
    total = [f["sent"] for f in af]
    sf = [r.segment_frames or 0 for r in s]
    print(f"frames (median): apply all {statistics.median(total):.0f}, apply configuration "
          f"{statistics.median(config):.0f}, SOEM {statistics.median(sf):.0f}; minimum "
          f"{minimum.total}; apply configuration / minimum "
          f"{statistics.median(config) / minimum.total:.2f}x, all / minimum "
          f"{statistics.median(total) / minimum.total:.2f}x (target <= {FRAME_TARGET}x: "
          f"configuration {_met(statistics.median(config) / minimum.total <= FRAME_TARGET)}"
          f", all {_met(statistics.median(total) / minimum.total <= FRAME_TARGET)}); "
          f"time target apply <= {target()}x SOEM (median): "
          f"{_met(statistics.median(aw) <= target() * statistics.median(sw))}, with a "
          f"cold plan cache {_met(statistics.median(cw) <= target() * statistics.median(sw))}")


def reached(runs: list[Run], kind: str) -> list[Run]:
    """The runs of ``kind`` ("apply", "apply cold", "SOEM") whose master reached OP: the
    ones the figures are taken over (a failed run has no phase times to take)."""
    key = "op" if kind == "SOEM" else "ok"
    return [r for r in runs if r.result.get(key) is True]


def target() -> float:
    return REALISTIC_TARGET if REALISTIC else TIME_TARGET


def final_read_frames(n: int) -> int:
    """apply's AL status read after OP (report): one APRD of 6 bytes per slave."""
    return packed_frames([12 + 6] * n)


def _step_ms(run: Run, key: str) -> float:
    for ev in run.result.get("events", []):
        hit = TRANSITION_LINE.match(ev)
        if hit and KEYS.get(f"{hit.group(1)} -> {hit.group(2)}") == key:
            return float(hit.group(4))
    return math.nan


def _met(ok: bool) -> str:
    return "met" if ok else "NOT met"


def summary(results: dict[str, dict], prepared: dict) -> None:
    print("\n| slaves | layout | apply ms (min / median) | SOEM ms (min / median) | apply / SOEM "
          "(min / median) | cold cache: apply ms, / SOEM (median) | apply frames (all / "
          "config / cyclic) | SOEM frames | minimum (lockstep) | config / min | all / min |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for (label, layout), res in results.items():
        a, s, c = (reached(res["runs"][k], k) for k in ("apply", "SOEM", "apply cold"))
        minimum, per_cycle = prepared[label][4], prepared[label][5]
        if not (a and s and c):
            print(f"| {label} | {layout} | no figures: a master has no run that reached OP "
                  "(report above) |")
            continue
        aw, sw = [r.wall for r in a], [r.wall for r in s]
        cw = [r.wall for r in c]
        af = [apply_frames(r, per_cycle) for r in a]
        total = statistics.median(f["sent"] for f in af)
        cyc = statistics.median(f["cyclic"] for f in af)
        config = statistics.median(f["sent"] - f["cyclic"] - final_read_frames(
            len(r.result["slaves"])) for f, r in zip(af, a))
        sf = statistics.median(r.segment_frames or 0 for r in s)
        print(f"| {label} | {layout} | {ms(aw)} | {ms(sw)} | {min(aw) / min(sw):.2f}x / "
              f"{statistics.median(aw) / statistics.median(sw):.2f}x | {ms(cw)}, "
              f"{statistics.median(cw) / statistics.median(sw):.2f}x | {total:.0f} / "
              f"{config:.0f} / {cyc:.0f} | {sf:.0f} | {minimum.total} ({minimum.lockstep}) | "
              f"{config / minimum.total:.2f}x | {total / minimum.total:.2f}x |")


def breakdown(bench: StartupBench, label: str, esi: list[str], topo: Path, eni: Path,
              n: int) -> None:
    """apply's steps in process (BREAKDOWN), medians of ``n`` runs from power-on."""
    rows = []
    for _ in range(n):
        sim = start_simulator(bench, esi, topo)
        try:
            wall, out, stamps = bench.timed([sys.executable, "-c", BREAKDOWN, str(eni), IF_A],
                                            300)
        finally:
            end_simulator(sim)
        try:
            res = json.loads(out.strip().splitlines()[-1])
        except (ValueError, IndexError):
            print(f"breakdown run failed: {out[-300:]!r} "
                  + "\n".join(s for _, s in stamps[-10:]))
            return
        marks, prev, steps = res["marks"], 0.0, {}
        steps["interpreter start-up"] = (res["start_at"] - bench.spawned_at) * 1e3
        for what, at in marks.items():
            steps[what] = at - prev
            prev = at
        steps["exit (socket release)"] = \
            (bench.ended_at - res["exit_at"]) * 1e3
        steps["whole process"] = wall * 1e3
        rows.append(steps)
    print(f"apply in process, {label} slaves, ms (median of {n}; 'python -c BREAKDOWN': "
          "the steps of cli/apply.py, stamped): "
          + ", ".join(f"{k} {statistics.median(r[k] for r in rows):.1f}" for k in rows[0]))


def profile(bench: StartupBench, prepared: tuple, tmp: Path) -> None:
    esi, topo, eni, *_ = prepared
    out = tmp / "apply.prof"
    argv = [sys.executable, "-m", "cProfile", "-o", str(out), "-m", "ecatcfg", "apply",
            str(eni), "--iface", IF_A, "--state", "op", "--cycles", "0", "--stay",
            "--format", "json"]
    r = one_run(bench, esi, topo, argv, None, 300)
    print(f"\n## cProfile of one apply ({len(r.result.get('slaves', []))} slaves, "
          f"{r.wall * 1e3:.0f} ms wall under the profiler)")
    import io
    import pstats
    for key in ("cumulative", "tottime"):
        text = io.StringIO()
        pstats.Stats(str(out), stream=text).sort_stats(key).print_stats(18)
        print(f"by {key}:")
        print("\n".join(ln for ln in text.getvalue().splitlines()[6:] if ln.strip()))


if __name__ == "__main__":
    main()
