"""The compiled exchange of a cyclic frame (runtime/_exchange.c) against the pure-Python path.

Both paths run on raw Ethernet between two namespaces (tests/rig.py): the same frames must
go out and the same images, working counters and counters come back; a short reply, a
reply under another index and a reply that never comes are handled alike (strays counted,
the frame lost after the timeout); a closed link raises the same error; the compiled path
lets other threads run while it waits; cycles on a raw link allocate within the budget on
both paths.  And the cycle's shortcut for working counters that repeat the last good ones
(both paths): checked again once an expectation or the state changes.  The references are the emulated slaves (what they
received and sent) and frames made by hand here, not the code under test.

The compiled module exists where the package was built with a C compiler (README command
2's editable install builds it into the checkout); elsewhere these tests skip locally and
fail in CI (tests/prereq.py), and the pure-Python path is what runs (tests/test_wheel.py
builds without a compiler).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import pytest

from conftest import EXAMPLES, ROOT, compile_example
from prereq import TOOLS, missing
from ecatcfg.esc import AlState, Cmd
from ecatcfg.runtime import link as link_module
from ecatcfg.runtime.link import LinkError, RawLink
from ecatcfg.runtime.master.cyclic import CyclicFrames
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.network import Network

ESI = [EXAMPLES / "esi"]
SENSORS_IN = 4          # input bits 4..7: the sensors' channels 1-4
LAMPS_OUT = 8           # output bits 8..15: the lamps' channels 1-8

@pytest.fixture
def compiled_exchange() -> None:
    """The compiled module, built here: where it is not, the test skips locally and fails
    in CI (a C compiler is a tool CI provides: tests/prereq.py), unless the pure-Python
    path was asked for on purpose."""
    if link_module._COMPILED is not None:
        return
    if os.environ.get(link_module.PURE_PYTHON_VARIABLE, "") not in ("", "0"):
        pytest.skip(f"{link_module.PURE_PYTHON_VARIABLE} is set: only the pure-Python path runs")
    missing("the compiled cyclic exchange (runtime/_exchange.c)",
            "not built at install (no C compiler, or an install older than the C file)", TOOLS)


compiled_only = pytest.mark.usefixtures("compiled_exchange")


def _open(rig, ns: str, compiled: bool) -> RawLink:
    link = rig.socket_in(ns)
    if not compiled:
        link.exchange_frame = None            # as an install without the extension
    return link


def _sniffer(rig):
    """Every frame that reaches namespace B (the master's), read in a thread."""
    sniff = rig.socket_in(rig.ns_b)
    frames: list[bytes] = []
    stop = threading.Event()

    def read() -> None:
        while not stop.is_set():
            got = sniff.recv(0.05)
            if got is not None:
                frames.append(got)
    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    return frames, stop, thread


def _cycles(rig, plan, compiled: bool) -> dict:
    from rig import serving
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate
    seg = emulate.segment(emulate.specs_from_eni(plan, Library(ESI, cache=False), "line"))
    out: dict = {"per_cycle": []}
    with serving(rig, seg):
        with Network(plan, _open(rig, rig.ns_a, compiled)) as net:
            assert (net.master.transport._exchange_frame is not None) is compiled
            net.up()
            assert net.state == AlState.OP
            cyclic = net.master.cyclic
            # The reference clock's time (the ARMW's data) differs from run to run.
            clock = [(c.in_at, c.in_at + c.cmd.length) for f in cyclic.working_counters()
                     for c in f if c.cmd.cmd in (Cmd.ARMW, Cmd.FRMW)]
            frames, stop, thread = _sniffer(rig)
            sent_before = net.master.transport.counters.frames_sent
            for k in range(12):
                seg.slaves[2].set_inputs(bytes([k & 0xF]))
                cyclic.outputs[LAMPS_OUT // 8] = (k * 37) & 0xFF
                ok = net.cycle()
                inputs = bytearray(cyclic.inputs)
                for start, end in clock:
                    inputs[start:end] = bytes(end - start)
                out["per_cycle"].append((ok, bytes(inputs), [
                    (c.wkc, c.expected) for f in cyclic.working_counters() for c in f]))
            out["lamps"] = seg.slaves[3].outputs()  # before the outputs' watchdog expires
            time.sleep(0.2)
            stop.set()
            thread.join(2)
            counters = net.master.transport.counters
            out["sent"] = counters.frames_sent - sent_before
            out["lost"], out["strays"] = counters.frames_lost, counters.stray_replies
            stats = cyclic.stats
            out["stats"] = (stats.lost_frames, stats.wkc_errors, dict(stats.wkc_error_cmds))
            prepared = cyclic.prepared(AlState.OP)
            # The cyclic frames as they went out, datagram indices zeroed (each run's
            # counter starts where its start-up left it).
            cyclic_frames = []
            shapes = {bytes(p.frame[12:16]) for p in prepared}
            for f in frames:
                if bytes(f[12:16]) in shapes and len(f) == len(prepared[0].frame):
                    g = bytearray(f)
                    for at in prepared[0].index_at:
                        g[at] = 0
                    cyclic_frames.append(bytes(g))
            out["frames"] = cyclic_frames[-12:]
    return out


@compiled_only
def test_both_paths_send_the_same_frames_and_read_the_same_data(veth_netns, example_plan):
    """Twelve cycles of changing inputs and outputs on each path, on fresh lines: the same
    frames on the wire, the same input images, working counters and results; and what the
    emulated slaves hold is what was written (the sensors' inputs in bits 4..7 of the
    image, the last output byte at the lamps)."""
    compiled = _cycles(veth_netns, example_plan, True)
    pure = _cycles(veth_netns, example_plan, False)
    assert compiled["per_cycle"] == pure["per_cycle"]
    assert compiled["frames"] == pure["frames"] and len(compiled["frames"]) == 12
    for key in ("lamps", "sent", "stats"):
        assert compiled[key] == pure[key], key
    assert compiled["sent"] == 12 and compiled["stats"][:2] == (0, 0)
    for k, (ok, inputs, _) in enumerate(compiled["per_cycle"]):
        assert ok
        assert inputs[SENSORS_IN // 8] >> 4 == k & 0xF
    assert compiled["lamps"] == bytes([(11 * 37) & 0xFF])
    # the outputs of cycle k are in the k-th frame sent (LRW data, at the lamps' offset)
    assert all(bytes([(k * 37) & 0xFF]) in f for k, f in enumerate(compiled["frames"]))


def _reply_to(frame: bytes, idx: int | None = None) -> bytearray:
    """``frame`` as a slave line sends it back: the same, with working counter 1 on each
    datagram (and, for a stray, another index)."""
    from ecatcfg.runtime import wire
    back = bytearray(frame)
    for pos, n in wire.datagram_offsets(back):
        end = pos + wire.DG_HEADER_LEN + n
        back[end:end + 2] = (1).to_bytes(2, "little")
        if idx is not None:
            back[pos + 1] = idx
    return back


def _peer(rig, script):
    """A hand-made slave line in namespace B: for each frame the master sends, ``script``
    gives the frames to send back; stopped by the event returned."""
    peer = rig.socket_in(rig.ns_b)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():            # until the test is done, however slow
            got = peer.recv(0.1)
            if got is not None:
                for frame in script(got):
                    peer.send(frame)
    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return thread, stop


@pytest.mark.parametrize("compiled", [
    pytest.param(True, id="compiled"),
    pytest.param(False, id="pure-python")])
def test_strays_short_frames_and_a_lost_frame(veth_netns, example_plan, compiled, request):
    """Before the real reply: a reply under another index, one cut short, one with another
    command; the exchange takes the real one and counts three strays.  Then no reply: 0
    after the timeout, one frame lost.  The same counts on both paths."""
    if compiled:
        request.getfixturevalue("compiled_exchange")
    frames = CyclicFrames(example_plan)
    p = frames.prepared(AlState.OP)[0]
    p.bind(frames.inputs, frames.outputs, bytearray(2048))
    answered = [0]

    def script(got: bytes) -> list[bytes]:
        answered[0] += 1
        if answered[0] > 1:
            return []                             # the second frame is lost
        idx = got[p.index_at[0]]
        other_cmd = _reply_to(got)
        other_cmd[16] ^= 0x01
        return [bytes(_reply_to(got, (idx + 1) & 0xFF)), bytes(_reply_to(got))[:p.length - 1],
                bytes(other_cmd), bytes(_reply_to(got))]
    thread, stop = _peer(veth_netns, script)
    try:
        _strays_then_lost(veth_netns, p, compiled)
    finally:
        stop.set()
        thread.join(5)


def _strays_then_lost(rig, p, compiled: bool) -> None:
    link = _open(rig, rig.ns_a, compiled)
    transport = Transport(link)
    assert (transport._exchange_frame is not None) is compiled
    reply = bytearray(2048)
    # 5 s: the peer is a thread of this process, which a loaded host may not run for a
    # while; the exchange returns as soon as the reply is there.
    size = transport.exchange_prepared(p, reply, 5.0)
    assert size == len(p.frame)
    assert bytes(reply[:size]) == bytes(_reply_to(bytes(p.frame)))
    assert (transport.counters.stray_replies, transport.counters.frames_lost) == (3, 0)
    start = time.monotonic()
    assert transport.exchange_prepared(p, reply, 0.05) == 0
    assert time.monotonic() - start >= 0.05
    assert (transport.counters.frames_sent, transport.counters.stray_replies,
            transport.counters.frames_lost) == (2, 3, 1)
    link.close()
    with pytest.raises(LinkError, match="link is closed"):
        transport.exchange_prepared(p, reply, 0.05)


@compiled_only
def test_other_threads_run_while_the_compiled_exchange_waits(veth_netns, example_plan):
    """While the cycling thread waits 0.3 s for a reply that never comes, another Python
    thread keeps running (the C code lets go of the interpreter lock while blocked)."""
    frames = CyclicFrames(example_plan)
    p = frames.prepared(AlState.OP)[0]
    p.bind(frames.inputs, frames.outputs, bytearray(2048))
    transport = Transport(_open(veth_netns, veth_netns.ns_a, True))
    counted = [0]
    done = threading.Event()

    def count() -> None:
        while not done.is_set():
            counted[0] += 1
    thread = threading.Thread(target=count, daemon=True)
    thread.start()
    time.sleep(0.05)
    before = counted[0]
    assert transport.exchange_prepared(p, bytearray(2048), 0.3) == 0
    during = counted[0] - before
    done.set()
    thread.join(2)
    # Holding the lock, the counter would stand still for the whole 0.3 s; a busy host
    # still gives the counting thread thousands of steps in that time.
    assert during > 1000, during


def test_the_pure_python_fallback_is_chosen_by_the_environment_and_reported():
    """ECATCFG_PURE_PYTHON=1 (docs/architecture.md): ``ecatcfg --version`` says which path
    runs; without the variable, the compiled one where it is built."""
    env = {**os.environ, "ECATCFG_PURE_PYTHON": "1"}
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "--version"], env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[1] == "cyclic exchange: pure Python"
    env.pop("ECATCFG_PURE_PYTHON")
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "--version"], env=env,
                          capture_output=True, text=True, timeout=60)
    want = "compiled" if link_module._COMPILED is not None else "pure Python"
    assert done.stdout.splitlines()[1] == f"cyclic exchange: {want}"


# The measurement, in an interpreter of its own inside the master's namespace: tracemalloc
# counts every thread's allocations, and in the suite's process threads other tests left
# (a reader, a segment that is still closing) allocate while the master cycles.
ALLOCATIONS = """
import gc, json, sys, tracemalloc
from ecatcfg.runtime.link import RawLink
from ecatcfg.runtime.network import Network
link = RawLink(sys.argv[2])
if sys.argv[3] == "pure":
    link.exchange_frame = None
with Network(sys.argv[1], link) as net:
    net.up()
    compiled = net.master.transport._exchange_frame is not None
    for _ in range(300):                      # warm-up: first-use allocations, caches
        net.cycle()
    gc.collect()
    tracemalloc.start()
    base, _ = tracemalloc.get_traced_memory()
    peak = 0
    for _ in range(200):
        now, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        net.cycle()
        _, top = tracemalloc.get_traced_memory()
        peak = max(peak, top - now)
    gc.collect()
    after, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(json.dumps({"peak": peak, "retained": after - base, "compiled": compiled,
                      "lost": net.master.cyclic.stats.lost_frames}))
"""


@pytest.mark.parametrize("compiled", [
    pytest.param(True, id="compiled"),
    pytest.param(False, id="pure-python")])
def test_cycles_on_a_raw_link_allocate_nothing_that_stays(veth_netns, compiled, tmp_path,
                                                          request):
    """The allocation guard of tests/startup_budget.toml measures cycles on a link in
    memory, which always runs the Python path; this is the same measure on a raw link,
    where the compiled exchange runs: the line served by ``ecatcfg simulate`` in another
    process.  Within the budget of the line with DC (the example line has DC on its
    drive: the ARMW in the cyclic frame too)."""
    if compiled:
        request.getfixturevalue("compiled_exchange")
    import json
    import tomllib
    from rig import start_simulate
    budget = tomllib.loads((ROOT / "tests" / "startup_budget.toml").read_text())["allocations"]
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(EXAMPLES / "topology.yaml"))
    assert lines and lines[-1].startswith("ready:"), lines
    eni = compile_example(tmp_path / "line.eni.xml")
    # What a cycle allocates when its reply comes back: a frame the busy host delivered
    # too late (counted lost) takes another path, so such a run is measured again.
    for _ in range(3):
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-c", ALLOCATIONS, str(eni), veth_netns.if_a,
            "compiled" if compiled else "pure"], timeout=120)
        assert done.returncode == 0, done.stderr
        got = json.loads(done.stdout.strip().splitlines()[-1])
        if got["lost"] == 0:
            break
    assert got["compiled"] is compiled and got["lost"] == 0, got
    assert got["peak"] <= budget["64 dc peak"], got
    assert got["retained"] <= budget["64 dc retained"], got


def test_a_repeat_of_the_last_good_counts_is_checked_again_after_a_change(example_plan):
    """A reply whose working counters repeat the last good cycle's skips the look at each
    command (runtime/master/cyclic.py); once what a command expects changes (the recovery
    supervisor lowers or raises it for a slave that leaves or comes back) or the state
    changes, the same counts are checked again: here the LRW is made to expect one more,
    and the very next cycle is a working-counter error, counted, as without the shortcut."""
    with Network.virtual(example_plan, esi=ESI, recovery=False) as net:
        net.up()
        assert net.cycle() and net.cycle()          # the second: the shortcut
        cyclic = net.master.cyclic
        lrw = next(s for f in cyclic.frames for s in f if s.cmd.cmd == Cmd.LRW)
        assert lrw.wkc == lrw.expected == lrw.cmd.cnt
        lrw.expected += 1                            # as recovery.Supervisor._online does
        cyclic.expected_changed()
        errors = cyclic.stats.wkc_errors
        assert not net.cycle()
        assert cyclic.stats.wkc_errors == errors + 1
        assert not net.cycle()                       # and again: an error is never "good"
        lrw.expected -= 1
        cyclic.expected_changed()
        assert net.cycle() and net.cycle()
        # Through SAFEOP (other frames, the same slots) and back: OP's counts again.
        net.down(AlState.SAFEOP)
        assert net.cycle()
        net.up()
        assert net.cycle() and lrw.wkc == lrw.cmd.cnt


def test_the_recovery_supervisor_tells_the_cyclic_frames_when_an_expectation_moves(
        example_plan):
    """The supervisor lowers what the LRW expects when a slave drops out and raises it
    when it is back; each time the frames must forget their last good counts."""
    with Network.virtual(example_plan, esi=ESI) as net:
        net.up()
        net.cycle()
        cyclic = net.master.cyclic
        calls = []
        original = cyclic.expected_changed
        cyclic.expected_changed = lambda: (calls.append(1), original())[1]  # type: ignore[method-assign]
        net.segment.remove_cable("axis1")
        for _ in range(20):
            net.cycle()
        assert not net.online("axis1") and calls
