"""The real-time options of the cycling thread (runtime/master/realtime.py, docs/runtime.md
"Real-time options") and the cyclic hot path they run (runtime/master/cyclic.py):

- the options reach the cycling thread (read back with os.sched_getscheduler /
  sched_getaffinity / /proc VmLck from inside it) and are undone after the run;
- a refused permission (CAP_SYS_NICE and CAP_IPC_LOCK removed from the bounding set of a
  root process) is exit 1 with a message saying how to grant it, never a traceback, before
  a frame is sent; usage mistakes are exit 2;
- the prepared frames are the bytes wire.encode gives for the same datagrams, and tshark
  dissects a recorded cyclic frame as the ENI's commands;
- a late reply to an earlier frame, or a reply of another shape, is never taken (stray);
- no per-cycle allocation growth over thousands of cycles (tracemalloc).
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
import threading
import time
import tracemalloc
from pathlib import Path

import pytest
import rig
from conftest import EXAMPLES
from ecatcfg.eni import writer as eni_writer
from ecatcfg.errors import UsageError
from ecatcfg.esc import AlState, Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.master import realtime

ESI = EXAMPLES / "esi"
CYCLE_US = 1000
# Real-time options pace a real line: these tests measure the host's periods and CPU time,
# so their in-memory networks stay on the host's clock (tests/conftest.py).
pytestmark = pytest.mark.wallclock



@pytest.fixture(scope="module")
def example_eni(example_plan, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("eni") / "example.eni.xml"
    path.write_bytes(eni_writer.to_bytes(example_plan))
    return path


def _vm_locked_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    raise AssertionError("no VmLck in /proc/self/status")


def _thread_view() -> tuple[int, int, set[int], int]:
    return (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority,
            os.sched_getaffinity(0), _vm_locked_kb())


# -- options applied -------------------------------------------------------------------------

@pytest.mark.parametrize("background", [False, True])
def test_options_reach_the_cycling_thread_and_are_undone(example_plan, background):
    cpu = max(os.sched_getaffinity(0))
    opts = realtime.options(priority=7, lock_memory=True, cpus=[cpu], busy_wait_us=100)
    before = _thread_view()
    assert before[0] != os.SCHED_FIFO and before[3] == 0
    seen: list[tuple[tuple[int, int, set[int], int], str]] = []
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        run = net.run(20, lambda n: seen.append((_thread_view(),
                                                 threading.current_thread().name)),
                      background=background, realtime=opts)
        if background:
            assert run is not None and run.join(10)
        assert net.run_stats is not None and net.run_stats.cycles == 20
    assert len(seen) == 20
    (policy, priority, cpus, locked), thread = seen[0]
    assert (policy, priority, cpus) == (os.SCHED_FIFO, 7, {cpu})
    assert locked > 0
    assert thread == ("ecat-cycle" if background else threading.current_thread().name)
    after = _thread_view()
    assert after[:3] == before[:3] and after[3] == 0      # restored, memory unlocked


def test_without_options_nothing_changes(example_plan):
    before = _thread_view()
    seen = []
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        net.run(5, lambda n: seen.append(_thread_view()))
    assert seen == [before] * 5


def test_busy_wait_spins_to_the_period_boundary(example_plan):
    """With a margin the cycling thread spends it on the CPU every cycle (sleeping to the
    boundary costs next to none); the absolute deadline keeps the period nominal."""
    cycles, margin = 300, 400

    def cpu_per_cycle(opts) -> float:
        with Network.virtual(example_plan, esi=[ESI]) as net:
            net.up()
            start = time.thread_time()
            net.run(cycles, realtime=opts)
            used = (time.thread_time() - start) / cycles * 1e6
            periods = net.run_stats.periods_us
        # The median: a loaded machine preempts a spinning normal thread now and then.
        median = sorted(periods)[len(periods) // 2]
        assert abs(median - CYCLE_US) < 0.02 * CYCLE_US, median
        return used

    plain = cpu_per_cycle(None)
    spinning = cpu_per_cycle(realtime.options(busy_wait_us=margin))
    assert spinning > plain + margin * 0.5, (plain, spinning)


def test_option_values_are_checked():
    for bad in (dict(priority=0), dict(priority=100), dict(cpus=[]), dict(cpus=[-1]),
                dict(busy_wait_us=-1), dict(busy_wait_us=realtime.MAX_BUSY_WAIT_US + 1)):
        with pytest.raises(UsageError):
            realtime.options(**bad)
    assert realtime.parse_cpus("0,2-3") == {0, 2, 3}
    for bad in ("", "a", "3-1", "1,,2"):
        with pytest.raises(UsageError):
            realtime.parse_cpus(bad)


def test_a_cpu_that_does_not_exist_is_refused_and_nothing_stays_changed():
    before = _thread_view()
    with pytest.raises(realtime.RealtimeError, match=r"CPU 4096 does not exist"):
        realtime.apply(realtime.options(priority=5, lock_memory=True, cpus=[4096]))
    assert _thread_view() == before          # the memory lock made first was undone


# -- refused permissions through the CLI -----------------------------------------------------

def _apply(eni: Path, *args: str, drop: str | None = None) -> subprocess.CompletedProcess:
    argv = [sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual", "--esi",
            str(ESI), "--cycles", "20", *args]
    if drop is not None:
        # A root process without the capability: what root in a container without it, or
        # a service with a CapabilityBoundingSet=, gets.
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            rig.unavailable("setpriv", "util-linux setpriv is not installed")
        argv = [setpriv, f"--bounding-set=-{drop}", "--", *argv]
    return subprocess.run(argv, capture_output=True, text=True, timeout=90)


def _require_root() -> None:
    if os.geteuid() != 0:
        rig.unavailable("root", "refusals are tested by dropping capabilities from root")


@pytest.mark.parametrize("flags, drop, expected", [
    (["--rt-priority", "50"], "sys_nice",
     ["SCHED_FIFO priority 50", "CAP_SYS_NICE", "ulimit -r 50", "LimitRTPRIO=50"]),
    (["--lock-memory"], "ipc_lock",
     ["mlockall", "CAP_IPC_LOCK", "ulimit -l unlimited", "LimitMEMLOCK=infinity"]),
])
def test_refused_permission_is_exit_1_with_how_to_grant_it(example_eni, flags, drop,
                                                           expected):
    _require_root()
    done = _apply(example_eni, *flags, drop=drop)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    for words in expected:
        assert words in done.stderr, done.stderr
    assert "scanning" not in done.stderr      # refused before the line is touched
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_a_cpu_that_does_not_exist_is_exit_1(example_eni):
    done = _apply(example_eni, "--cpu", "4096")
    assert done.returncode == 1 and "CPU 4096 does not exist" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("flags, words", [
    (["--rt-priority", "0"], "--rt-priority: real-time priority 0: must be 1 to"),
    (["--cpu", "x"], "--cpu: CPU list 'x'"),
    (["--busy-wait", "-5"], "--busy-wait: busy-wait -5 us"),
])
def test_option_mistakes_are_usage_errors(example_eni, flags, words):
    done = _apply(example_eni, *flags)
    assert done.returncode == 2 and words in done.stderr, done.stderr


def test_apply_flags_run_the_cycle_with_the_options(example_eni, monkeypatch, capsys):
    from ecatcfg.cli import main
    _require_root()
    seen: list[tuple[realtime.RealtimeOptions | None, int, set[int]]] = []
    real_run = Network.run

    def watching(self, cycles=None, callback=None, **kwargs):
        def each(net):
            seen.append((kwargs.get("realtime"), os.sched_getscheduler(0),
                         os.sched_getaffinity(0)))
            if callback is not None:
                callback(net)
        return real_run(self, cycles, each, **kwargs)
    monkeypatch.setattr(Network, "run", watching)
    cpu = max(os.sched_getaffinity(0))
    rc = main(["apply", str(example_eni), "--virtual", "--esi", str(ESI), "--cycles", "10",
               "--rt-priority", "3", "--lock-memory", "--cpu", str(cpu),
               "--busy-wait", "50"])
    assert rc == 0, capsys.readouterr()
    assert len(seen) == 10
    assert seen[0] == (realtime.RealtimeOptions(3, True, frozenset({cpu}), 50),
                       os.SCHED_FIFO, {cpu})
    assert os.sched_getscheduler(0) != os.SCHED_FIFO


def test_a_large_heap_is_frozen_before_the_slaves_reach_op(example_eni, capsys):
    """With real-time options the run freezes the heap before its first cycle (a full
    collection, then gc.freeze).  In a process with a large heap (an application, the test
    runner) that collection alone outlasts the slaves' 100 ms SM watchdog; done between OP
    and the first cycle, the drive dropped to SAFEOP+ERR 0x001B and apply failed.  It is
    done before the slaves leave PREOP (cli/apply.prepare_cycling)."""
    import gc

    from ecatcfg.cli import main
    _require_root()
    heap = [[i] for i in range(200_000)]          # many small tracked objects
    started = time.monotonic()
    gc.collect()
    while time.monotonic() - started < 0.25:      # a collection must take 250 ms or more
        heap.extend([[i] for i in range(len(heap))])
        started = time.monotonic()
        gc.collect()
    try:
        rc = main(["apply", str(example_eni), "--virtual", "--esi", str(ESI), "--cycles",
                   "10", "--rt-priority", "3", "--lock-memory"])
        assert rc == 0, capsys.readouterr()
        assert not gc.get_freeze_count()          # the heap is not left frozen
    finally:
        del heap


# -- the hot path ----------------------------------------------------------------------------

def _old_way(net: Network, state: AlState, idx: int) -> list[bytes]:
    """The frames as the master built them before frames were prepared: a Datagram per
    command, the output image's bytes for LWR/LRW, the ENI's data (or zeros) otherwise."""
    frames = []
    cyclic = net.master.cyclic
    for slots in cyclic.frames:
        dgs = []
        for s in slots:
            if state.name not in s.cmd.states:
                continue
            c = s.cmd
            if c.cmd in (Cmd.LWR, Cmd.LRW):
                data = bytes(cyclic.outputs[s.out_at:s.out_at + c.length])
            else:
                data = c.data if c.data is not None else bytes(c.length)
            dg = wire.datagram_for(c, data)
            dg.idx = idx
            dgs.append(dg)
        if dgs:
            frames.append(wire.encode(dgs))
    return frames


def test_prepared_frames_are_the_bytes_wire_encode_gives(example_plan):
    rng = random.Random(20)
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        cyclic = net.master.cyclic
        for state in (AlState.SAFEOP, AlState.OP):
            for _ in range(3):
                cyclic.outputs[:] = bytes(rng.randrange(256) for _ in cyclic.outputs)
                prepared = cyclic.prepared(state)
                assert prepared
                for p in prepared:
                    p.bind(cyclic.inputs, cyclic.outputs, bytearray(2048))
                    p.fill()
                    for at in p.index_at:
                        p.frame[at] = 0x5A
                assert [bytes(p.frame) for p in prepared] == _old_way(net, state, 0x5A)


def test_tshark_reads_the_cyclic_frames_as_the_eni_says(example_plan, tshark_path,
                                                         tmp_path):
    """Wireshark's dissector, on a recording of cycles: the ENI's commands, addresses and
    lengths, a new index per frame, zero working counters out, and the LRW carrying the
    output image."""
    pcap = tmp_path / "cyclic.pcapng"
    cmds = [c for f in example_plan.cyclic[0].frames for c in f.cmds if "OP" in c.states]
    lrw_at = next(k for k, c in enumerate(cmds) if c.cmd == Cmd.LRW)
    with Network.virtual(example_plan, esi=[ESI], pcap=pcap) as net:
        net.up()
        net["lamps.Channel 1-8.Output 3"] = True
        net["axis1.RxPDO 2 (CSV).Target velocity"] = -123456
        slot = next(s for slots in net.master.cyclic.frames for s in slots
                    if s.cmd is cmds[lrw_at])
        image = bytes(net.master.cyclic.outputs[slot.out_at:slot.out_at + slot.cmd.length])
        first = net.master.transport.counters.frames_sent
        net.run(4)
        sent = net.master.transport.counters.frames_sent - first
    assert sent == 4 * len(net.master.cyclic.prepared(AlState.OP))
    rows = rig.tshark_fields(pcap, ["ecat.cmd", "ecat.idx", "ecat.lad", "ecat.ado",
                                    "ecat.data", "ecat.cnt", "eth.src"])
    out = [r for r in rows if r["eth.src"] == ["01:01:01:01:01:01"]
           and [int(v, 0) for v in r["ecat.cmd"]] == [c.cmd for c in cmds]]
    assert len(out) >= sent
    indices = set()
    for r in out[-sent:]:
        # (tshark shows register datagrams as registers, not as ecat.data)
        data = [bytes.fromhex(d.replace(":", "")) for d in r["ecat.data"]]
        assert image in data and any(image)
        assert [int(v, 0) for v in r["ecat.lad"]] == [c.addr for c in cmds
                                                      if c.cmd in wire.LOGICAL_CMDS]
        assert [int(v, 0) for v in r["ecat.ado"]] == [c.ado for c in cmds
                                                      if c.cmd not in wire.LOGICAL_CMDS]
        assert [int(v, 0) for v in r["ecat.cnt"]] == [0] * len(cmds)
        indices.add(r["ecat.idx"][0])
    assert len(indices) == sent                      # a new index every frame


class _TamperingLink:
    """The master's end of a segment that answers at once, with extra replies first: the
    previous frame's reply (late), then a copy of this one with a datagram's length
    changed (another shape)."""

    def __init__(self, segment, circulate: bool = False) -> None:
        self.segment = segment
        self.queue: list[bytes] = []
        self.last: bytes | None = None
        self.circulate = circulate          # set the circulating bit in every reply

    def send(self, frame) -> None:
        reply = bytes(self.segment.process(bytes(frame)))
        if self.circulate:
            marked = bytearray(reply)
            for pos, _n in wire.datagram_offsets(marked):
                marked[pos + 7] |= wire.CIRCULATING >> 8
            reply = bytes(marked)
        if self.last is not None:
            self.queue.append(self.last)
        reshaped = bytearray(reply)
        pos, _n = wire.datagram_offsets(reshaped)[0]
        reshaped[pos + 6] ^= 0x01                     # length one off
        self.queue += [bytes(reshaped), reply]
        self.last = reply

    def recv(self, timeout=None):
        return self.queue.pop(0) if self.queue else None

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        pass


@pytest.mark.parametrize("circulate", [False, True])
def test_late_and_reshaped_replies_are_never_taken(example_plan, circulate):
    """... and a reply whose datagrams carry the circulating bit (ETG.1000.4: set by a
    slave, not a change of shape) is taken, as Transport.exchange takes it."""
    from ecatcfg.runtime.segment import emulate
    seg = emulate.segment(emulate.specs_from_eni(example_plan, Library([ESI], cache=False),
                                                 "x"))
    link = _TamperingLink(seg, circulate)
    with Network(example_plan, link) as net:           # type: ignore[arg-type]
        net.up()                    # the way up meets the same extra replies, and copes
        counters, cyclic = net.master.transport.counters, net.master.cyclic
        frames = len(cyclic.prepared(AlState.OP))
        net["lamps.Channel 1-8.Output 2"] = True
        strays = counters.stray_replies
        for n in range(1, 4):
            assert net.cycle()
            assert counters.stray_replies == strays + 2 * n * frames
        assert seg.slaves[3].state == AlState.OP
        checked = [s for slots in cyclic.frames for s in slots
                   if "OP" in s.cmd.states and s.cmd.cnt is not None]
        assert checked and [(s.wkc, s.expected) for s in checked] == [
            (s.cmd.cnt, s.cmd.cnt) for s in checked]
        # A lost frame: every slot of it says so.
        link.send = lambda frame: None                             # type: ignore
        link.queue.clear()
        assert not net.master.cyclic.exchange(net.master.transport, AlState.OP,
                                              timeout=0.005)
        assert cyclic.stats.lost_frames == frames
        assert all(s.wkc == -1 for slots in cyclic.frames for s in slots
                   if "OP" in s.cmd.states)
        link.send = _TamperingLink.send.__get__(link)             # type: ignore


def test_a_host_slow_to_return_after_the_cycles_does_not_fail_the_run(
        example_eni, monkeypatch, capsys):
    """Outputs that stop for longer than a slave's SM watchdog (100 ms) take it to
    SAFEOP+ERR 0x001B, as they should once the cycles have ended.  Whether a slave left OP
    *while the line ran* is judged on the states read right after the last cycle, in the
    cycling thread (Network.states_after_run), not when a busy host gets back to the
    caller: here the caller gets the CPU back 300 ms after the last cycle.  A watchdog
    that runs out while the line cycles still fails the run (test_apply, the agreement
    tests)."""
    from ecatcfg.cli import main
    real_run = Network.run

    def slow_return(self, *args, **kwargs):
        result = real_run(self, *args, **kwargs)
        time.sleep(0.3)
        return result
    monkeypatch.setattr(Network, "run", slow_return)
    rc = main(["apply", str(example_eni), "--virtual", "--esi", str(ESI), "--cycles", "10",
               "--format", "json"])
    out = capsys.readouterr()
    assert rc == 0, out
    assert json.loads(out.out)["ok"] is True


def test_no_allocation_grows_per_cycle(example_plan):
    """Thousands of in-memory cycles (master and segment in this process): what is still
    allocated afterwards does not grow with the number of cycles.  tracemalloc sees every
    thread of the process; the test runner's own (pytest-xdist's execnet channel to its
    controller) and tracemalloc's bookkeeping are left out of the count.  On simulated time
    (this module's other tests are on the host's clock): what a cycle allocates does not
    depend on when the host runs it."""
    from ecatcfg.runtime.clock import SimClock
    with Network.virtual(example_plan, esi=[ESI], clock=SimClock()) as net:
        net.up()
        net.reset_stats()
        for _ in range(500):                              # warm up: prepared frames, ring
            net.cycle()
        tracemalloc.start()
        try:
            for _ in range(200):
                net.cycle()
            snap0 = tracemalloc.take_snapshot()
            for _ in range(4000):
                net.cycle()
            snap1 = tracemalloc.take_snapshot()
        finally:
            tracemalloc.stop()
        assert net.master.cyclic.stats.lost_frames == 0
    runner = [tracemalloc.Filter(False, pattern) for pattern in
              ("*/xdist/*", "*/execnet/*", "*/_pytest/*", "*/pluggy/*", tracemalloc.__file__)]
    diff = snap1.filter_traces(runner).compare_to(snap0.filter_traces(runner), "lineno")
    grown = sum(d.size_diff for d in diff)
    # 4000 cycles: a byte per cycle would be 4000; allow the allocator's noise.
    assert grown < 2000, "\n".join(map(str, diff[:5]))


def test_the_periods_of_a_run_start_with_the_run(example_plan):
    """The first period of a run is measured from its first cycle, not from a cycle run
    before it (a pause before run() is not a period of the run)."""
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        net.cycle()
        time.sleep(0.2)
        net.run(5)
        periods = net.run_stats.periods_us
    assert len(periods) == 4 and max(periods) < 100_000, periods


def test_a_refusal_on_the_background_thread_is_raised_in_the_caller(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        with pytest.raises(realtime.RealtimeError, match="CPU 4096 does not exist"):
            net.run(10, background=True, realtime=realtime.options(cpus=[4096]))
        assert not [t for t in threading.enumerate() if t.name == "ecat-cycle"]
        assert net.cycle()                       # nothing ran, the network is as it was
