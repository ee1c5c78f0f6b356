"""SoE benchmark: what a drive's start-up IDN writes cost against the same number of CoE SDO
downloads, a large IDN written and read in fragments against the mailbox's minimum, and
``ecatcfg soe read`` as a process against ``ecatcfg scan``.

Run from the checkout:  python3 bench/soe.py [--writes 0,8,32] [--sizes 1024,4096]
[--mailboxes 128,1024] [--repeat R] [--no-veth] [--json FILE]   (root for the veth part)

1. **Start-up writes** (in memory: ``Network.virtual``, the segment answering in the
   master's thread, ``SynchronousLink``).  The self-written two-axis SoE drive ``tests/fixtures/esi/soe_drive.xml``
   (TSD-2, 128-byte mailbox) compiled with ``ecatcfg.compiler``: its ESI's own 7 SoE writes
   (the IDNs it needs before SAFEOP), plus N more PS writes of S-0-0032 (2 bytes, drive 0
   and drive 1 in turn: a write cannot go ahead of the answer to a write of the same
   object, whose answer it could not be told from);
   the baseline, in the same run and interleaved, the CiA 402 example drive EXD-402
   (``examples/esi``, 128-byte mailbox) with its 9 PDO-assignment SDOs plus N more PS SDO
   downloads of 0x6040:00 and 0x6060:00 in turn (2 and 1 bytes, expedited).  Each run from
   power-on (a new segment),
   INIT -> OP (``net.up()``); every frame the master sends is recorded
   (``Transport.recorder``) and sorted: process data (a logical datagram: the ENI's cyclic
   frames, which run while PS and SO last, so their number follows time, not work) and
   configuration (the rest).  Per added write: (configuration frames at N - at 0) / N and
   (PS time at N - at 0) / N, medians of R runs; the least a write can cost is 1 frame:
   the one that reads the answer to the write before and, behind that read, writes this
   request into SM0 (runtime/master/mailbox_pipeline.py); one after the other, 2 frames.
   Over veth too (root): each ENI written (``eni.writer``) and run by ``ecatcfg apply ENI
   --cycles 0 --format json`` as a process in one namespace, ``ecatcfg simulate`` of the
   device started afresh for each device and round in the other; PS time and frames from
   apply's own events (whole ms; its frames include the cyclic ones).
2. **Fragmented transfers** (in memory: ``VirtualSegment.serve`` on a thread, the master's
   ``sdo_tool.mailbox_session`` + ``soe_client.soe_job``, what ``ecatcfg soe`` runs).  The
   same drive, its ESI rewritten into a temporary folder with both mailbox SyncManagers of
   each size of ``--mailboxes`` and one more IDN, P-0-0300: a list of as many bytes as the
   largest ``--sizes`` (the emulation sizes a list IDN by the maximum its ESI InitCmd
   gives).  A list of SIZE bytes (4 length bytes + SIZE - 4 data) written, then read back
   (checked equal).  Fragments: ceil(SIZE / (mbx - 10)) (6 bytes mailbox header, 4 SoE
   header), computed here, checked against the SM0 writes (write) and the SM1 reads that
   brought data (read) seen in the recorded frames.  Minimum frames: a write, one SM0 write
   per fragment + one SM1 read for the drive's single answer; a read, one SM0 write + one
   SM1 read per fragment.  Time is the transfer's alone (after the session's preparation);
   the baseline of the same run, a read of the 2-byte S-0-0032 (1 fragment each way).
3. **Processes over veth** (root): ``ecatcfg simulate`` of the drive in one network
   namespace (``bench/virtual_segment.py``'s namespaces and veth pair); in the other,
   alternately ``ecatcfg scan --iface va`` and ``ecatcfg soe read --iface va --slave 0
   S-0-0030 --format json``, each a whole new process timed from spawn to exit
   (``bench/startup.py``'s ``StartupBench.timed``).

Nothing is asserted but what makes the figures mean something: OP reached, the drive's
log holding the writes, the fragment counts, the list read back equal to the list
written, the version string read.  The figures go to docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Generator, Iterator
from pathlib import Path
from typing import Any

from startup import LOGICAL, StartupBench, datagrams
from virtual_segment import IF_A, IF_B, stop, wait_for

ROOT = Path(__file__).resolve().parent.parent
SOE_ESI = ROOT / "tests" / "fixtures" / "esi" / "soe_drive.xml"
COE_ESI = ROOT / "examples" / "esi" / "ecatcfg-EXD402-drive.xml"
SOE_DEVICE, COE_DEVICE = "TSD-2 SoE", "EXD-402"
S_0_0030, S_0_0032 = 30, 32                 # manufacturer version, primary operation mode
LIST_IDN = 0x8000 | 300                     # P-0-0300, the benchmark's list IDN
SOE_HEADER = 6 + 4                          # mailbox header + SoE header (ETG.1000.6 5.8)


# ------------------------------------------------------------------ the machine

def loadavg() -> str:
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def cpu_model() -> str:
    try:
        for ln in Path("/proc/cpuinfo").read_text().splitlines():
            if ln.startswith("model name"):
                return ln.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def med(values: list[float]) -> float:
    return statistics.median(values)


# ------------------------------------------------------------------ 1. start-up writes

class Recorder:
    """The frames the master sends (``Transport.recorder``), with marks at the events."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.marks: list[tuple[str, int, float]] = []       # event text, frames, time

    def __call__(self, frame: bytes, outgoing: bool) -> None:
        if outgoing:
            self.sent.append(bytes(frame))

    def event(self, event: Any) -> None:
        self.marks.append((event.text, len(self.sent), time.perf_counter()))

    def between(self, start: str, end: str) -> tuple[list[bytes], float]:
        """The frames sent and the seconds from the event starting with ``start`` to the
        one starting with ``end``."""
        [a] = [m for m in self.marks if m[0].startswith(start)]
        [b] = [m for m in self.marks if m[0].startswith(end)]
        return self.sent[a[1]:b[1]], b[2] - a[2]


def process_data(frames: list[bytes]) -> int:
    return sum(1 for f in frames if any(c in LOGICAL for c, _, _ in datagrams(f)))


def startup_plan(kind: str, n: int) -> Any:
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni.plan import CoeInitCmd, SoeInitCmd
    from ecatcfg.esc import Transition
    from ecatcfg.esi.library import Library

    esi, device = (SOE_ESI, SOE_DEVICE) if kind == "SoE" else (COE_ESI, COE_DEVICE)
    plan = build.compile_topology(
        topology.loads(f"slaves:\n  - {{name: axis, device: {device}}}\n", "bench.yaml"),
        Library([esi], cache=False)).plan
    mailbox = plan.slaves[0].mailbox
    assert mailbox is not None
    # Two objects in turn, as a start-up list writes (a write to the object just written
    # cannot go ahead of its answer: the two answers could not be told apart).
    if kind == "SoE":
        mailbox.soe_init_cmds += [SoeInitCmd([Transition.PS], f"bench {i}", S_0_0032,
                                             b"\x0b\x00", drive_no=i % 2) for i in range(n)]
    else:
        mailbox.coe_init_cmds += [
            CoeInitCmd([Transition.PS], f"bench {i}", 0x6040, 0, b"\x06\x00") if i % 2 == 0
            else CoeInitCmd([Transition.PS], f"bench {i}", 0x6060, 0, b"\x08")
            for i in range(n)]
    return plan


def startup_run(kind: str, n: int) -> dict[str, float]:
    from ecatcfg.esc import AlState
    from ecatcfg.runtime import Network

    plan = startup_plan(kind, n)
    rec = Recorder()
    with Network.virtual(plan, esi=[SOE_ESI if kind == "SoE" else COE_ESI],
                         on_event=rec.event) as net:
        net.master.transport.recorder = rec
        t0 = time.perf_counter()
        net.up()
        wall = time.perf_counter() - t0
        if net.state != AlState.OP:
            raise SystemExit(f"{kind} with {n} writes did not reach OP")
        if kind == "SoE":
            drives = net.segment.slaves[0].mailbox.soe.drives
            # each drive: the ESI's own S-0-0032 and ours
            for drive, want in ((0, 1 + (n + 1) // 2), (1, 1 + n // 2)):
                logged = [idn for idn, _ in drives[drive].log].count(S_0_0032)
                if logged != want:
                    raise SystemExit(f"drive {drive} took {logged} writes of S-0-0032, "
                                     f"not {want}")
    ps, ps_s = rec.between("PS: PS", "PS: SAFEOP")
    return {"wall_s": wall, "frames": len(rec.sent),
            "config": len(rec.sent) - process_data(rec.sent),
            "ps_frames": len(ps), "ps_config": len(ps) - process_data(ps), "ps_s": ps_s}


def startup(writes: list[int], repeat: int) -> dict[str, Any]:
    runs: dict[tuple[str, int], list[dict[str, float]]] = {}
    for _ in range(repeat + 1):                          # the first round warms up
        for n in writes:
            for kind in ("CoE", "SoE"):
                runs.setdefault((kind, n), []).append(startup_run(kind, n))
    out: dict[str, Any] = {}
    for (kind, n), rows in runs.items():
        rows = rows[1:]
        out[f"{kind} {n}"] = {k: med([r[k] for r in rows]) for k in rows[0]} | {
            "min_wall_s": min(r["wall_s"] for r in rows), "kind": kind, "writes": n}
    for kind in ("CoE", "SoE"):
        base = out[f"{kind} 0"] if 0 in writes else None
        for n in writes:
            row = out[f"{kind} {n}"]
            if base is not None and n:
                row["per_write_frames"] = (row["config"] - base["config"]) / n
                row["per_write_ps_frames"] = (row["ps_config"] - base["ps_config"]) / n
                row["per_write_us"] = (row["ps_s"] - base["ps_s"]) / n * 1e6
    return out


def print_startup(res: dict[str, Any]) -> None:
    print("\n| device, added PS writes | INIT -> OP ms (min / median) | frames all / "
          "configuration | PS: ms, configuration frames | per added write: frames (PS), "
          "us in PS |")
    print("|---|---|---|---|---|")
    for key, r in res.items():
        per = (f"{r['per_write_frames']:.2f} ({r['per_write_ps_frames']:.2f}), "
               f"{r['per_write_us']:.0f}" if "per_write_frames" in r else "-")
        print(f"| {key} | {r['min_wall_s'] * 1e3:.1f} / {r['wall_s'] * 1e3:.1f} | "
              f"{r['frames']:.0f} / {r['config']:.0f} | {r['ps_s'] * 1e3:.1f}, "
              f"{r['ps_config']:.0f} | {per} |")
    for n in sorted({r["writes"] for r in res.values()} - {0}):
        c, s = res.get(f"CoE {n}", {}), res.get(f"SoE {n}", {})
        if "per_write_frames" in c and "per_write_frames" in s and c["per_write_us"] > 0:
            print(f"{n} writes: SoE / CoE per write: frames "
                  f"{s['per_write_frames'] / c['per_write_frames']:.2f}x, time "
                  f"{s['per_write_us'] / c['per_write_us']:.2f}x")


# ------------------------------------------------------------------ 2. fragmented transfers

def esi_variant(folder: Path, mbx: int, list_bytes: int) -> Path:
    """The fixture drive with ``mbx``-byte mailbox SyncManagers (SM1 right after SM0) and
    an SO write of P-0-0300, a list of ``list_bytes`` - 4 bytes at most."""
    text = SOE_ESI.read_text()
    size = f'MinSize="{mbx}" MaxSize="{mbx}" DefaultSize="{mbx}"'
    text, n = re.subn(r'MinSize="128" MaxSize="128" DefaultSize="128"', size, text)
    text, m = re.subn(r'StartAddress="#x1A00"', f'StartAddress="#x{0x1800 + mbx:04X}"', text)
    # A list with one 2-byte item: 4 length bytes + 2 (data of 1, 2, 4 or 8 bytes would
    # make a number of that size).
    short_list = (2).to_bytes(2, "little") + (list_bytes - 4).to_bytes(2, "little") + b"\0\0"
    cmd = (f"<InitCmd Chn=\"0\"><Transition>SO</Transition><IDN>{LIST_IDN}</IDN>"
           f"<Data>{short_list.hex()}</Data><Comment>bench list</Comment></InitCmd>\n"
           "          </SoE>")
    text, k = re.subn(r"</SoE>", cmd, text)
    if (n, m, k) != (2, 1, 1):
        raise SystemExit(f"{SOE_ESI.name} is not laid out as this benchmark expects")
    path = folder / f"soe_drive_mbx{mbx}.xml"
    path.write_text(text)
    return path


def fragments(size: int, mbx: int) -> int:
    return max(1, math.ceil(size / (mbx - SOE_HEADER)))


class MailboxCensus:
    """SM0 writes, SM1 reads (and those that brought a message) and the other frames
    among the frames recorded (``Transport.recorder``: each sent frame, then its reply)."""

    def __init__(self, sm0: int, sm1: int) -> None:
        self.sm0, self.sm1 = sm0, sm1
        self.frames: list[tuple[bytes, bool]] = []

    def __call__(self, frame: bytes, outgoing: bool) -> None:
        self.frames.append((bytes(frame), outgoing))

    def count(self, start: int) -> dict[str, int]:
        out = {"frames": 0, "sm0 writes": 0, "sm1 reads": 0, "sm1 messages": 0}
        for frame, outgoing in self.frames[start:]:
            if not outgoing:
                for cmd, ado, n, wkc in _with_wkc(frame):
                    if ado == self.sm1 and cmd in (1, 4) and wkc:      # APRD, FPRD
                        out["sm1 messages"] += 1
                continue
            out["frames"] += 1
            for cmd, ado, _ in datagrams(frame):
                if ado == self.sm0 and cmd in (2, 5):                   # APWR, FPWR
                    out["sm0 writes"] += 1
                elif ado == self.sm1 and cmd in (1, 4):
                    out["sm1 reads"] += 1
        return out


def _with_wkc(frame: bytes) -> Iterator[tuple[int, int, int, int]]:
    pos = 16
    for cmd, ado, n in datagrams(frame):
        yield cmd, ado, n, int.from_bytes(frame[pos + 10 + n:pos + 12 + n], "little")
        pos += 12 + n


def transfers(sizes: list[int], mailboxes: list[int], repeat: int) -> dict[str, Any]:
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.link import MemoryLink
    from ecatcfg.runtime.master import soe_tool
    from ecatcfg.runtime.master.transport import Transport
    from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
    from ecatcfg.runtime.soe import encode_list

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for mbx in mailboxes:
            esi = esi_variant(Path(tmp), mbx, max(sizes))
            lib = Library([esi], cache=False)
            seg = segment([SlaveSpec(lib.device(lib.find(SOE_DEVICE).entry), "axis")])
            a, b = MemoryLink.pair()
            stop = threading.Event()
            thread = threading.Thread(target=seg.serve, args=(b,), kwargs={"stop": stop},
                                      daemon=True)
            thread.start()
            census = MailboxCensus(0x1800, 0x1800 + mbx)
            transport = Transport(a, recorder=census)
            cases: list[tuple[str, int, bytes | None, int, int]] = [
                ("read S-0-0032 (baseline)", S_0_0032, None, 2, 1)]
            for size in sizes:
                body = bytes((i * 31 + 7) & 0xFF for i in range(size - 4))
                listed = encode_list(body, max(sizes) - 4)
                cases += [(f"write {size} B", LIST_IDN, listed, size, fragments(size, mbx)),
                          (f"read {size} B", LIST_IDN, None, size, fragments(size, mbx))]
            rows: dict[str, list[dict[str, Any]]] = {}
            for _ in range(repeat + 1):
                for label, idn, data, size, frags in cases:
                    rows.setdefault(label, []).append(
                        one_transfer(transport, census, idn, data))
                    got = rows[label][-1]
                    want = frags if data is not None else 1
                    if got["sm0 writes"] != want or (data is None
                                                     and got["sm1 messages"] != frags):
                        raise SystemExit(f"mbx {mbx}, {label}: {got}, expected {frags} "
                                         "fragments")
                    if data is None and idn == LIST_IDN and got["result"] != written(cases,
                                                                                    size):
                        raise SystemExit(f"mbx {mbx}, {label}: the list read back differs")
            # What ``ecatcfg soe`` sends in all (soe_tool.soe_transfer): the preparation,
            # and for a write in fragments the attribute read that goes first.
            sessions = {}
            for label, idn, data, _size, _frags in cases:
                before = transport.counters.frames_sent
                soe_tool.soe_transfer(transport, 0, idn, data)
                sessions[label] = transport.counters.frames_sent - before
            stop.set()
            thread.join(2)
            for label, idn, data, size, frags in cases:
                timed = rows[label][1:]
                minimum = frags + 1
                out[f"mbx {mbx}, {label}"] = {
                    "mbx": mbx, "size": size, "fragments": frags, "minimum": minimum,
                    "frames": med([r["frames"] for r in timed]),
                    "sm1 reads": med([r["sm1 reads"] for r in timed]),
                    "min_us": min(r["seconds"] for r in timed) * 1e6,
                    "median_us": med([r["seconds"] for r in timed]) * 1e6,
                    "tool_session_frames": sessions[label]}
            base = out[f"mbx {mbx}, read S-0-0032 (baseline)"]
            for label, *_ in cases:
                row = out[f"mbx {mbx}, {label}"]
                row["frames_ratio"] = row["frames"] / row["minimum"]
                row["time_ratio"] = row["median_us"] / base["median_us"]
                row["us_per_frame"] = row["median_us"] / row["frames"]
    return out


def written(cases: list[tuple[str, int, bytes | None, int, int]], size: int) -> bytes:
    [data] = [d for label, _, d, s, _ in cases if s == size and label.startswith("write")]
    assert data is not None
    return data


def one_transfer(transport: Any, census: MailboxCensus, idn: int,
                 data: bytes | None) -> dict[str, Any]:
    """One transfer in a session of its own (``ecatcfg soe``'s preparation); frames and
    time of the transfer alone."""
    from ecatcfg.runtime.master.sdo_tool import SlaveMailbox, mailbox_session
    from ecatcfg.runtime.master.soe_client import SoeTransfer, soe_job

    row: dict[str, Any] = {}
    info = SlaveMailbox(0)
    info.protocol = "SoE"

    def work(channel: Any, size: int, counter: Callable[[], int]) -> Generator[Any, Any, None]:
        transfer = SoeTransfer(idn, data, mbx_out_size=size, counter=counter)
        start, t0 = len(census.frames), time.perf_counter()
        yield from soe_job(channel, transfer, None, None)
        row["seconds"] = time.perf_counter() - t0
        row.update(census.count(start))
        row["result"] = transfer.result

    mailbox_session(transport, 0, work, info)
    return row


def print_transfers(res: dict[str, Any]) -> None:
    print("\n| mailbox, transfer | fragments | frames (ratio to the minimum) | SM1 reads "
          "| time us min / median | us per frame | / baseline read (median) | `ecatcfg soe` "
          "session frames |")
    print("|---|---|---|---|---|---|---|---|")
    for key, r in res.items():
        print(f"| {key} | {r['fragments']} | {r['frames']:.0f} of {r['minimum']} "
              f"({r['frames_ratio']:.2f}x) | {r['sm1 reads']:.0f} | {r['min_us']:.0f} / "
              f"{r['median_us']:.0f} | {r['us_per_frame']:.0f} | {r['time_ratio']:.1f}x | "
              f"{r['tool_session_frames']} |")


# ------------------------------------------------------------------ over veth

PS_LINE = re.compile(r"^PREOP -> SAFEOP: SAFEOP in (\d+) ms, (\d+) frames")


def simulator(bench: StartupBench, esi: Path, device: str, folder: Path) -> Any:
    """``ecatcfg simulate`` of one ``device`` in B, from power-on, once it is ready."""
    topo = folder / f"{device.replace(' ', '_')}.yaml"
    topo.write_text(f"slaves:\n  - {{name: axis, device: {device}}}\n")
    sim = bench.start(bench.ns_b, [sys.executable, "-m", "ecatcfg", "simulate", "--esi",
                                   str(esi), "--topology", str(topo), "--iface", IF_B,
                                   "--duration", "3600", "--no-cache"])
    wait_for(sim, "ready:", 60)
    return sim


def startup_veth(bench: StartupBench, writes: list[int], repeat: int,
                 folder: Path) -> dict[str, Any]:
    """``ecatcfg apply`` of each ENI as a process in A against a simulator started afresh
    for each device and round; PS time and frames from apply's JSON events (whole ms; the
    frames include the few cyclic frames PS runs)."""
    from ecatcfg.eni import writer

    enis = {}
    for kind in ("CoE", "SoE"):
        for n in writes:
            enis[kind, n] = folder / f"{kind}-{n}.xml"
            writer.write(startup_plan(kind, n), enis[kind, n])
    runs: dict[tuple[str, int], list[dict[str, float]]] = {}
    for i in range(repeat + 1):                          # the first round warms up
        for kind, esi, device in (("CoE", COE_ESI, COE_DEVICE), ("SoE", SOE_ESI, SOE_DEVICE)):
            sim = simulator(bench, esi, device, folder)
            try:
                for n in writes:
                    argv = [sys.executable, "-m", "ecatcfg", "apply", str(enis[kind, n]),
                            "--iface", IF_A, "--state", "op", "--cycles", "0",
                            "--format", "json"]
                    wall, stdout, _ = bench.timed(argv, 120)
                    res = json.loads(stdout)
                    if res.get("ok") is not True:
                        raise SystemExit(f"apply {kind} {n} over veth: {stdout[:500]}")
                    [ps] = [h for h in map(PS_LINE.match, res["events"]) if h]
                    if i:
                        runs.setdefault((kind, n), []).append(
                            {"wall_s": wall, "frames": res["frames"]["sent"],
                             "ps_ms": float(ps.group(1)), "ps_frames": float(ps.group(2))})
            finally:
                stop(sim)
    out: dict[str, Any] = {}
    for (kind, n), rows in runs.items():
        out[f"{kind} {n}"] = {k: med([r[k] for r in rows]) for k in rows[0]} | {
            "min_wall_s": min(r["wall_s"] for r in rows), "kind": kind, "writes": n}
    for kind in ("CoE", "SoE"):
        if 0 not in writes:
            break
        base = out[f"{kind} 0"]
        for n in writes:
            if n:
                row = out[f"{kind} {n}"]
                row["per_write_ps_frames"] = (row["ps_frames"] - base["ps_frames"]) / n
                row["per_write_us"] = (row["ps_ms"] - base["ps_ms"]) / n * 1e3
    return out


def print_startup_veth(res: dict[str, Any]) -> None:
    # No time per write here: PS's whole-ms time varies between runs by more than 32
    # writes cost (the JSON has it all the same).
    print("\n| over veth: device, added PS writes | apply process ms (min / median) | "
          "frames | PS: ms, frames | per added write: PS frames |")
    print("|---|---|---|---|---|")
    for key, r in res.items():
        per = (f"{r['per_write_ps_frames']:.2f}" if "per_write_ps_frames" in r else "-")
        print(f"| {key} | {r['min_wall_s'] * 1e3:.0f} / {r['wall_s'] * 1e3:.0f} | "
              f"{r['frames']:.0f} | {r['ps_ms']:.0f}, {r['ps_frames']:.0f} | {per} |")


def processes(bench: StartupBench, repeat: int, folder: Path) -> dict[str, Any]:
    """``ecatcfg scan`` and ``ecatcfg soe read`` as processes in A, alternately."""
    walls: dict[str, list[float]] = {"scan": [], "soe read": []}
    argvs = {"scan": [sys.executable, "-m", "ecatcfg", "scan", "--iface", IF_A],
             "soe read": [sys.executable, "-m", "ecatcfg", "soe", "read", "--iface", IF_A,
                          "--slave", "0", "S-0-0030", "--format", "json"]}
    sim = simulator(bench, SOE_ESI, SOE_DEVICE, folder)
    try:
        for i in range(repeat + 1):
            for kind, argv in argvs.items():
                wall, out, _ = bench.timed(argv, 120)
                if kind == "soe read" and "ecatcfg emulated SoE drive" not in \
                        bytes.fromhex(json.loads(out)["hex"]).decode("latin-1"):
                    raise SystemExit(f"soe read answered {out[:300]!r}")
                if i:
                    walls[kind].append(wall)
    finally:
        stop(sim)
    s, r = walls["scan"], walls["soe read"]
    return {"scan_ms": [min(s) * 1e3, med(s) * 1e3],
            "soe_read_ms": [min(r) * 1e3, med(r) * 1e3],
            "ratio": [min(r) / min(s), med(r) / med(s)]}


# ------------------------------------------------------------------ main

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    ap.add_argument("--writes", default="0,8,32", help="added start-up writes per case")
    ap.add_argument("--sizes", default="1024,4096", help="list IDN sizes in bytes")
    ap.add_argument("--mailboxes", default="128,1024", help="mailbox sizes in bytes")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-veth", action="store_true")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args()
    writes = [int(x) for x in args.writes.split(",")]
    sizes = [int(x) for x in args.sizes.split(",")]
    mailboxes = [int(x) for x in args.mailboxes.split(",")]
    if min(sizes) < 4 or min(mailboxes) <= SOE_HEADER:
        ap.error("a list is at least 4 bytes, a mailbox more than 10")
    machine = (f"{platform.machine()}, {os.cpu_count()} CPUs ({cpu_model()}), Python "
               f"{platform.python_version()}, repeat {args.repeat}")
    print(f"# {machine}; load average at the start {loadavg()}")
    results: dict[str, Any] = {"machine": machine, "load": {"start": loadavg()}}
    results["startup"] = startup(writes, args.repeat)
    results["load"]["after start-up"] = loadavg()
    print_startup(results["startup"])
    results["transfers"] = transfers(sizes, mailboxes, args.repeat)
    results["load"]["after transfers"] = loadavg()
    print_transfers(results["transfers"])
    if not args.no_veth:
        bench = StartupBench()
        try:
            bench.up()
            with tempfile.TemporaryDirectory() as tmp:
                results["startup_veth"] = startup_veth(bench, writes, args.repeat, Path(tmp))
                results["load"]["after start-up over veth"] = loadavg()
                print_startup_veth(results["startup_veth"])
                results["processes"] = p = processes(bench, args.repeat, Path(tmp))
                results["load"]["after processes"] = loadavg()
        finally:
            bench.close()
        print(f"\nprocesses over veth, ms min / median: ecatcfg scan {p['scan_ms'][0]:.0f} / "
              f"{p['scan_ms'][1]:.0f}, ecatcfg soe read {p['soe_read_ms'][0]:.0f} / "
              f"{p['soe_read_ms'][1]:.0f}; soe read / scan {p['ratio'][0]:.2f}x / "
              f"{p['ratio'][1]:.2f}x")
    print("# load average: " + ", ".join(f"{k} {v}" for k, v in results["load"].items()))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
