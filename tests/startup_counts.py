"""What ``apply`` costs on its way to OP, in counts that do not depend on the machine: the
frames of each step, the modules its success path imports, the memory a cycle allocates.

Used by ``tests/test_startup_counts.py`` (the guards, against ``tests/startup_budget.toml``)
and ``bench/startup_counts.py`` (the breakdown in docs/BENCHMARKS.md).

Frames: the line is emulated in memory (``runtime/segment``) and answers inside ``send``
(``SimLink``): no thread, no lost frame.  The master's clocks (``time`` in its modules,
``CLOCKED``: the reply timeouts, the deadlines, the pacing of the ENI's cyclic frames during
PS and SO, the DC wait) and the slaves' clock are one simulated clock that moves
``FRAME_NS`` per frame, so the cyclic frames sent while the slaves change state, and the
drift frames the DC wait needs, are the same in every run, and a host that stalls the test
cannot make a reply late: the count is a property of the code, not of the host's load.

Imports: ``apply`` runs as the console script runs it (``ecatcfg.cli.main``) in a fresh
interpreter, on ``--iface`` with the raw socket replaced by one end of a socket pair whose
other end is an emulated line in a second process, so none of the segment's modules
(nor the ESI library it emulates from) are in the master's process.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import types
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
FRAME_NS = 60_000       # simulated time per frame (a 64-slave line's round trip is ~53 us)

DRIVE = "EXD-402"       # CiA 402 drive: PDO assignment by CoE in PS; DC capable
IO = ["EX1004", "EX2008", "EX1008"]


def line(n: int, dc: bool) -> list[tuple[str, str, bool]]:
    """(name, device, DC on) for the fixed lines: 1 = one drive; 8 = the 8-slave line of
    bench/startup.py; 64 = bench/virtual_segment.py's (a coupler, EX1004/EX2008/EX1008
    repeating, a drive in every 16th place).  With ``dc`` the drives run SYNC0 (op mode DC)."""
    if n == 1:
        devices = [DRIVE]
    elif n == 8:
        devices = ["EX1100", "EX1004", "EX1004", "EX2008", "EX1008", DRIVE, "EX2008", DRIVE]
    else:
        devices = ["EX1100"] + [DRIVE if i % 16 == 15 else IO[(i - 1) % 3]
                                for i in range(1, n)]
    return [(f"s{i}", d, dc and d == DRIVE) for i, d in enumerate(devices)]


def topology_text(n: int, dc: bool) -> str:
    return "master: {name: line, cycle_time_us: 1000}\nslaves:\n" + "".join(
        f"  - {{name: {name}, device: {device}" + (", dc: DC" if on else "") + "}\n"
        for name, device, on in line(n, dc))


def compile_line(n: int, dc: bool) -> tuple[Any, Any]:
    """(plan, library) of a fixed line, compiled in memory from the example ESI files."""
    from ecatcfg.compiler import build, topology
    from ecatcfg.esi.library import Library
    library = Library([ESI], cache=False)
    name = f"line{n}{'dc' if dc else ''}.yaml"
    plan = build.compile_topology(topology.loads(topology_text(n, dc), name), library).plan
    return plan, library


try:
    from ecatcfg.runtime.clock import SimClock as _ProductClock
except ImportError:             # a checkout from before runtime/clock.py (bench)
    _ProductClock = None


class SimClock(_ProductClock or object):          # type: ignore[misc]
    """One simulated time (ns) for the slaves and the master: the runtime's own SimClock
    where there is one (the transport of a link with this clock then runs on it), and
    ``t`` and a call for the ns as older checkouts' modules read them."""

    def __init__(self) -> None:
        self.ns = 1_000_000_000_000
        self.slept_ns = 0

    @property
    def t(self) -> int:
        return self.ns

    @t.setter
    def t(self, value: int) -> None:
        self.ns = value

    def __call__(self) -> int:
        return self.ns


class SimLink:
    """The master's end of an emulated line that answers inside ``send``; each frame
    moves the clock by ``FRAME_NS``.  ``frames`` counts what the master sent, ``busy_s`` the
    time the emulation took (for the bench to take it out of the master's)."""

    def __init__(self, segment: Any, clock: SimClock) -> None:
        self.segment, self.clock = segment, clock
        self.replies: deque[bytes] = deque()
        self.frames = 0
        self.busy_s = 0.0

    def send(self, frame: bytes | bytearray) -> None:
        self.frames += 1
        self.clock.t += FRAME_NS
        t = time.perf_counter()
        self.replies.append(bytes(self.segment.process(frame)))
        self.busy_s += time.perf_counter() - t

    def recv(self, timeout: float | None = None) -> bytes | None:
        return self.replies.popleft() if self.replies else None

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        pass


def simulated_time(clock: SimClock) -> types.SimpleNamespace:
    """A stand-in for the ``time`` module of the master's modules on the simulated clock:
    the pacing of the cyclic frames during PS and SO, the DC wait, and every reply timeout
    and deadline, so that a host that stalls the test for a while cannot make a frame count
    as lost and be sent again.  ``sleep`` moves the clock on (a wait that sends nothing
    still ends); ``time_ns`` seeds the DC system time offset; ``perf_counter`` stays the
    host's (the cycle period statistics)."""
    def sleep(seconds: float) -> None:
        clock.t += int(seconds * 1e9)
    return types.SimpleNamespace(monotonic=lambda: clock.t / 1e9, time_ns=lambda: clock.t,
                                 sleep=sleep, perf_counter=time.perf_counter)


# The master's modules that read the clock on the way to OP and while cycling.
CLOCKED = ("bringup", "transport", "lockstep", "replay", "transition", "scan", "cyclic",
           "recovery", "mailbox_pipeline")


def _modules() -> tuple[Any, Any]:
    """The master's bring-up and the emulation's modules; where they were before
    runtime/ had its master/ and segment/ subpackages too, so that the bench can count an
    older checkout the same way."""
    import importlib
    try:
        return (importlib.import_module("ecatcfg.runtime.master.bringup"),
                importlib.import_module("ecatcfg.runtime.segment.emulate"))
    except ModuleNotFoundError:
        return (importlib.import_module("ecatcfg.runtime.master"),
                importlib.import_module("ecatcfg.runtime.emulate"))


def simulated_network(plan: Any, library: Any) -> tuple[Any, SimLink, SimClock, Callable[[], None]]:
    """(network, link, clock, undo): the plan on an emulated line of its devices, the
    master's pacing on the simulated clock until ``undo()``."""
    from ecatcfg.runtime import Network
    bringup, emulate = _modules()
    import importlib
    clock = SimClock()
    segment = emulate.segment(emulate.specs_from_eni(plan, library, "line"), clock_ns=clock)
    link = SimLink(segment, clock)
    package = bringup.__name__.rpartition(".")[0]   # the master's modules are its siblings
    clocked = [bringup]
    for name in CLOCKED:
        try:
            clocked.append(importlib.import_module(f"{package}.{name}"))
        except ImportError:                 # an older checkout (bench): not there
            pass
    fake = simulated_time(clock)
    saved = [(m, m.time) for m in dict.fromkeys(clocked) if getattr(m, "time", None) is time]
    for module, _ in saved:
        module.time = fake

    def undo() -> None:
        for module, real in saved:
            module.time = real
    return Network(plan, link, on_event=None), link, clock, undo


def frames_to_op(n: int, dc: bool) -> dict[str, int]:
    """Frames per step of ``Network.up()`` to OP on a fixed line (see the module
    docstring): the steps as the master's events mark them (:func:`steps`), and
    ``total``."""
    from ecatcfg.esc import AlState
    plan, library = compile_line(n, dc)
    net, link, _, undo = simulated_network(plan, library)
    marks: list[tuple[str, tuple[float, ...]]] = []

    def on_event(event: Any) -> None:
        marks.append((event.text, (link.frames,)))
    net.master.on_event = on_event
    try:
        net.up(AlState.OP)
    finally:
        undo()
    total = link.frames
    net.close()
    return {"total": total, **{k: int(v[0]) for k, v in steps(marks, (total,)).items()}}


def steps(marks: list[tuple[str, tuple[float, ...]]], end: tuple[float, ...]
          ) -> dict[str, tuple[float, ...]]:
    """Counters (frames, ...) between the master's events, per step: ``scan`` (scan and
    verify), each transition by its short name (II, IP, PS, SO), ``read-back IP`` ... (the
    AL status read after it, up to the next step; after PS also the DC wait's reads of
    0x092C), ``dc setup`` (before PS: delays, offsets, static drift frames).  ``marks``:
    (event text, counters then); ``end``: the counters at the end."""
    out: dict[str, tuple[float, ...]] = {}
    last_name, last_at = "", end
    for text, at in [*marks, ("", end)]:
        name = _step_name(text, last_name) if text else ""
        if name != last_name:
            if last_name:
                before = out.get(last_name, tuple(0 for _ in at))
                out[last_name] = tuple(b + x - y for b, x, y in zip(before, at, last_at))
            last_name, last_at = name, at
    return out


def _step_name(text: str, previous: str) -> str:
    if text == "scanning the line":
        return "scan"
    if text.startswith("DC: ") and not text.startswith("DC: every"):
        return "dc setup"
    head, _, rest = text.partition(": ")
    if head in ("II", "IP", "PS", "SO"):              # Transition.value, then "..." or
        return head if rest.endswith("...") else f"read-back {head}"    # its result
    return previous                 # the end of the scan, of the DC wait: the same step


# -------------------------------------------------------------------- imports

SEGMENT = r"""
import os, select, socket, sys
from ecatcfg.eni import reader
try:
    from ecatcfg.runtime.segment import emulate
except ImportError:                 # a checkout from before runtime/segment/ (bench)
    from ecatcfg.runtime import emulate
sock = socket.socket(fileno=int(sys.argv[2]))
segment = emulate.segment(emulate.specs_from_eni(reader.read_file(sys.argv[1]), None, "line"))
print("ready", flush=True)
while True:
    try:
        frame = sock.recv(2048)
    except OSError:
        break
    if not frame:
        break
    sock.send(bytes(segment.process(frame)))
"""

MASTER = r"""
import sys
# How the package is installed is not the package: an editable install's finder (newer
# setuptools) imports importlib.metadata, zipfile and their compressors the first time it
# is asked for the package.  Asking once before counting leaves only what ecatcfg imports.
import importlib.util
importlib.util.find_spec("ecatcfg")
before = set(sys.modules)
import json, os, select, socket


class SocketLink:
    # One end of a socket pair: frames to and from the other process.
    iface = "pair"
    mtu = 1500

    def __init__(self, iface):
        self.sock = socket.socket(fileno=int(os.environ["ECATCFG_PROBE_FD"]))

    def send(self, frame):
        self.sock.send(bytes(frame))

    def recv(self, timeout=None):
        if not select.select([self.sock], [], [], timeout)[0]:
            return None
        return self.sock.recv(2048)

    def fileno(self):
        return self.sock.fileno()

    def close(self):
        self.sock.close()


probe = set(sys.modules) - before
import ecatcfg.runtime.link
ecatcfg.runtime.link.RawLink = SocketLink
import ecatcfg.cli
code = ecatcfg.cli.main(["apply", sys.argv[1], "--iface", "pair", "--cycles", "0",
                         "--stay", "--format", "json"])
sys.stdout.flush()
mods = sorted(m for m in set(sys.modules) - before - probe)
with open(sys.argv[2], "w") as f:
    json.dump({"code": code, "modules": mods}, f)
"""


def apply_imports(eni: Path, out: Path, env: dict[str, str],
                  master_env: dict[str, str] | None = None) -> dict[str, Any]:
    """The modules ``ecatcfg apply ENI --iface ... --cycles 0 --stay --format json``
    imports in its process (``ecatcfg.cli.main``, as the console script runs it), with
    the line emulated in another process; ``{"code": exit code, "modules": [...],
    "report": apply's JSON}``.  ``master_env``: the master's environment, when not ``env``
    (another checkout of the package on its PYTHONPATH)."""
    master_end, segment_end = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    segment = subprocess.Popen(
        [sys.executable, "-c", SEGMENT, str(eni), str(segment_end.fileno())],
        pass_fds=[segment_end.fileno()], stdout=subprocess.PIPE, text=True, env=env)
    segment_end.close()
    try:
        assert segment.stdout is not None
        if segment.stdout.readline().strip() != "ready":
            raise RuntimeError("the emulated line did not start")
        done = subprocess.run(
            [sys.executable, "-c", MASTER, str(eni), str(out)],
            pass_fds=[master_end.fileno()], capture_output=True, text=True, timeout=300,
            env={**(master_env or env), "ECATCFG_PROBE_FD": str(master_end.fileno())})
    finally:
        master_end.close()
        segment.wait(timeout=60)
    if done.returncode not in (0, 1) or not out.exists():
        raise RuntimeError(f"apply failed: {done.stderr[-2000:]}")
    result: dict[str, Any] = json.loads(out.read_text())
    result["report"] = json.loads(done.stdout)
    result["stderr"] = done.stderr
    return result


def third_party(modules: list[str]) -> list[str]:
    """The modules that are neither ecatcfg's nor the standard library's."""
    return sorted(m for m in modules if not m.startswith("ecatcfg")
                  and m.split(".")[0] not in sys.stdlib_module_names
                  and not m.startswith("_"))


# -------------------------------------------------------------------- allocations

class ReplayLink:
    """The line's replies as recorded: while ``recording``, each frame goes to the emulated
    line and its reply is kept under the frame's bytes; afterwards a frame seen before is
    answered with that reply, without running the emulation, so that what is measured in
    this process is the master alone.  A frame not seen before goes to the line
    (``misses``)."""

    def __init__(self, inner: SimLink) -> None:
        self.inner = inner
        self.recording = True
        self.replies: dict[bytes, bytes] = {}
        self.reply: bytes | None = None
        self.misses = 0

    def send(self, frame: bytes | bytearray) -> None:
        key = bytes(frame)
        reply = None if self.recording else self.replies.get(key)
        if reply is None:
            self.misses += not self.recording
            self.inner.send(frame)
            reply = self.replies[key] = self.inner.replies.popleft()
        self.reply = reply

    def recv(self, timeout: float | None = None) -> bytes | None:
        reply, self.reply = self.reply, None
        return reply

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        pass


def cycle_allocations(n: int, dc: bool, cycles: int = 200) -> dict[str, int]:
    """Memory the master allocates while cycling in OP (tracemalloc), the line's replies
    replayed (``ReplayLink``): ``peak``: the most bytes one cycle holds above what was
    allocated before it (the largest of ``cycles`` cycles); ``retained``: bytes still
    allocated after the ``cycles`` cycles that were not before (a leak grows it)."""
    import gc
    import tracemalloc

    from ecatcfg.esc import AlState
    plan, library = compile_line(n, dc)
    net, link, clock, undo = simulated_network(plan, library)
    replay = ReplayLink(link)
    try:
        net.up(AlState.OP)
        net.master.transport.link = replay
        # Warm-up: first-use allocations, the replies recorded, and the cyclic path's cache
        # of what each datagram index's reply looks like (runtime/master/cyclic.py), full
        # once the index has wrapped (256 frames).
        for _ in range(300):
            clock.t += 1_000_000
            net.cycle()
        replay.recording = False
        gc.collect()
        tracemalloc.start()
        try:
            base, _ = tracemalloc.get_traced_memory()
            peak = 0
            for _ in range(cycles):
                clock.t += 1_000_000
                now, _ = tracemalloc.get_traced_memory()
                tracemalloc.reset_peak()
                if not net.cycle():
                    raise AssertionError("a cycle in OP failed")
                _, top = tracemalloc.get_traced_memory()
                peak = max(peak, top - now)
            gc.collect()
            after, _ = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    finally:
        undo()
        net.close()
    return {"peak": peak, "retained": after - base, "misses": replay.misses}


def cycle_allocations_alone(n: int, dc: bool) -> dict[str, int]:
    """:func:`cycle_allocations` in an interpreter of its own: tracemalloc counts every
    thread's allocations, and in the suite's process threads that other tests left (a
    reader, a segment that is still closing) allocate while the master cycles."""
    import json
    import subprocess
    import sys
    here = Path(__file__).resolve().parent
    done = subprocess.run(
        [sys.executable, "-c", "import json, startup_counts; print(json.dumps("
         f"startup_counts.cycle_allocations({n}, {dc!r})))"],
        cwd=here, capture_output=True, text=True, timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(
            p for p in (str(here), os.environ.get("PYTHONPATH", "")) if p)})
    assert done.returncode == 0, done.stderr[-3000:]
    out: dict[str, int] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


def env_for(cache: Path) -> dict[str, str]:
    """The environment of the child processes: a plan cache of their own in ``cache``, and
    a bytecode cache there too (as an installed package has .pyc files; an environment that
    sets PYTHONDONTWRITEBYTECODE would otherwise compile every module from source)."""
    env = dict(os.environ)
    env["XDG_CACHE_HOME"] = str(cache)
    env["PYTHONPYCACHEPREFIX"] = str(cache / "bytecode")
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env

