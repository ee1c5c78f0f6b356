"""The in-memory master/segment pair on simulated time (runtime/clock.py, runtime/simwire.py):
deterministic to the byte and the nanosecond, and time-dependent behaviour (an SM watchdog
of 100 ms, a lost frame's timeout) tested without waiting for it."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest
from rig import tshark_fields

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState, Cmd, Reg
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.clock import WALL, SimClock, in_use, monotonic, using
from ecatcfg.runtime.link import LinkError
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.pcap import read_capture
from ecatcfg.runtime.segment.timing import Timing
from ecatcfg.runtime.segment.virtual import Faults
from ecatcfg.runtime.simwire import SimulatedLink
from ecatcfg.runtime.wire import Datagram

ESI = EXAMPLES / "esi"
LAMPS = [f"lamps.Channel 1-8.Output {k}" for k in range(1, 9)]


@pytest.fixture(scope="module")
def plan() -> NetworkPlan:
    built = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                   Library([ESI], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(built), "example.eni.xml")


def bring_up(plan: NetworkPlan, pcap: object, faults: Faults | None = None
             ) -> tuple[list[tuple[int, bool, bytes]], int]:
    """The example line up to OP with the fitted firmware timing and DC, 200 cycles with
    changing outputs, and down again, on a fresh simulated clock: its frame log and the
    simulated ns it took."""
    clock = SimClock()
    log: list[tuple[int, bool, bytes]] = []
    with Network.virtual(plan, esi=[ESI], clock=clock, timing=Timing(), faults=faults,
                         pcap=pcap) as net:
        assert isinstance(net.link, SimulatedLink)
        net.link.log = log
        net.up()
        for n in range(200):
            net[LAMPS[n % 8]] = bool(n & 8)
            net.cycle()
            clock.sleep(0.001)
    return log, clock.ns


def busy() -> threading.Thread:
    """A thread that keeps the interpreter busy (the host's load, as far as one process
    can make it): on wall-clock time it would delay every reply."""
    stop = threading.Event()

    def spin() -> None:
        x = 0
        while not stop.is_set():
            x += 1
    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    thread.stop = stop                          # type: ignore[attr-defined]
    return thread


@pytest.mark.parametrize("faults", [None, Faults(drop=0.05, corrupt=0.01, delay=0.02, seed=7)],
                         ids=["clean", "lossy"])
def test_the_same_eni_brought_up_twice_gives_the_same_frame_log(plan, faults, tmp_path):
    first, took = bring_up(plan, tmp_path / "a.pcapng", faults)
    load = busy()
    try:
        second, took2 = bring_up(plan, tmp_path / "b.pcapng", faults)
    finally:
        load.stop.set()                         # type: ignore[attr-defined]
        load.join()
    assert len(first) > 400
    # Byte for byte and tick for tick: every frame, its direction and its simulated time.
    assert second == first
    assert took2 == took
    assert (tmp_path / "a.pcapng").read_bytes() == (tmp_path / "b.pcapng").read_bytes()
    # Time only moves forward, and every frame that came back took its time on the wire.
    times = [t for t, _, _ in first]
    assert times == sorted(times)
    sent = sum(1 for _, out, _ in first if out)
    back = len(first) - sent
    if faults is None:
        assert back == sent
    else:
        assert 0 < sent - back < sent // 10      # some lost, most back
    # The capture's times are the simulated ones (pcapng: microseconds).
    captured = [t for _, t, _ in read_capture(tmp_path / "a.pcapng")]
    assert len(captured) == len(first)
    assert [b - a for a, b in zip(captured, captured[1:])] == [
        (b - a) // 1000 * 1000 for a, b in zip(captured, captured[1:])]
    assert (captured[-1] - captured[0]) == pytest.approx(times[-1] - times[0], abs=2000)


def watchdog_limit_s(net: Network, name: str) -> float:
    """The SM watchdog time the master wrote, by the ESC's formula (ESC datasheet
    Section I, "Watchdog"): a watchdog divider (0x0400) of n counts (n + 2) x 40 ns, the SM
    watchdog (0x0420) that many units."""
    slave = next(s for s in net.segment.slaves if s.name == name)
    divider = int.from_bytes(slave.mem[Reg.WATCHDOG_DIVIDER:Reg.WATCHDOG_DIVIDER + 2], "little")
    units = int.from_bytes(slave.mem[Reg.WATCHDOG_SM:
                                     Reg.WATCHDOG_SM + 2], "little")
    return (divider + 2) * 40e-9 * units


def test_an_sm_watchdog_expires_on_simulated_time_to_the_millisecond(plan):
    """No process data for just under the watchdog time: nothing happens; just over it: the
    firmware takes SAFEOP+ERR 0x001B.  100 ms of silence cost no host time."""
    clock = SimClock()
    with Network.virtual(plan, esi=[ESI], clock=clock, recovery=False) as net:
        net.up()
        limit = watchdog_limit_s(net, "lamps")
        assert limit == pytest.approx(0.1)     # the ESI's default: 100 ms
        lamps = next(s for s in net.segment.slaves if s.name == "lamps")
        for _ in range(5):
            assert net.cycle()
        host = time.perf_counter()
        clock.sleep(limit - 0.001)
        assert net.cycle()
        assert lamps.state == AlState.OP and not lamps.error
        assert lamps.mem[Reg.WATCHDOG_STATUS] & 1 and lamps.mem[Reg.WATCHDOG_COUNTER_SM] == 0
        clock.sleep(limit + 0.001)
        net.cycle()
        host = time.perf_counter() - host
        assert (lamps.state, lamps.error, lamps.status_code) == (AlState.SAFEOP, True, 0x001B)
        assert lamps.mem[Reg.WATCHDOG_COUNTER_SM] == 1          # expired once
        print(f"{2 * limit * 1e3:.0f} ms of simulated silence in {host * 1e6:.0f} us of host time")


def test_a_lost_frame_costs_its_timeout_in_simulated_time_only(plan):
    """A frame nobody answers: the transport waits its timeout on the simulated clock and
    counts it lost; a reply comes back after its time on the wire."""
    brd = [Datagram.physical(Cmd.BRD, 0, Reg.AL_STATUS, bytes(2))]
    clock = SimClock()
    with Network.virtual(plan, esi=[ESI], clock=clock) as net:
        transport = Transport(net.link)
        assert transport.clock is clock         # the wire's clock, without being told
        start = clock.ns
        got = transport.exchange(brd)
        assert got is not None and got[0].wkc == len(net.segment.slaves) == 5
        # A 44-byte frame padded to 60, with preamble and FCS 72 bytes at 80 ns, and
        # 600 + 200 + 2 x 10 ns for each of the 5 slaves.
        assert clock.ns - start == 72 * 80 + 5 * 820
    clock = SimClock()
    with Network.virtual(plan, esi=[ESI], clock=clock, faults=Faults(drop=1.0)) as net:
        transport = Transport(net.link)
        took = set()
        while transport.counters.frames_lost < 3:      # drop 1.0: three in four lost
            start = clock.ns
            if transport.exchange(brd, timeout=0.02) is None:
                took.add(clock.ns - start)
        # The whole timeout, simulated (to the ns the float seconds of a deadline keep).
        assert took and all(20_000_000 <= t <= 20_000_001 for t in took), took


def test_the_clock_in_use_is_the_transports_inside_a_step_and_the_wall_outside():
    clock = SimClock(5_000_000_000)
    assert in_use() is WALL
    with using(clock):
        assert monotonic() == 5.0
        with using(clock):
            assert in_use() is clock
        clock.sleep(0.25)
        assert monotonic() == 5.25 and clock.slept_ns == 250_000_000
    assert in_use() is WALL
    seen: list[object] = []
    thread = threading.Thread(target=lambda: seen.append(in_use()))
    with using(clock):
        thread.start()
        thread.join()
    assert seen == [WALL]                       # another thread is on its own clock


def test_waiting_for_nothing_on_a_simulated_wire_is_an_error(plan):
    clock = SimClock()
    with Network.virtual(plan, esi=[ESI], clock=clock) as net:
        assert net.link.recv(0) is None and clock.ns == SimClock().ns
        with pytest.raises(LinkError, match="none on its way"):
            net.link.recv(None)


# -- apply --virtual --simulated-time ------------------------------------------------------

def apply(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "apply", *args],
                          capture_output=True, text=True, timeout=300)


def test_apply_on_simulated_time_reports_the_timings_and_repeats_itself(plan, tmp_path):
    """Twice the same run: the same capture, byte for byte; the timings reported are the
    capture's own (read back with tshark), and they include the fitted firmware times
    (an EL7xxx-like drive's PREOP->SAFEOP alone takes more than 100 ms)."""
    eni = tmp_path / "example.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(plan))
    runs = []
    for name in ("a", "b"):
        run = apply(str(eni), "--virtual", "--esi", str(ESI), "--simulated-time",
                    "--cycles", "200", "--format", "json", "--pcap", str(tmp_path / name))
        assert run.returncode == 0, run.stderr
        runs.append(json.loads(run.stdout))
    assert (tmp_path / "a").read_bytes() == (tmp_path / "b").read_bytes()
    took = runs[0]["simulated_time_ms"]
    assert {k: v for k, v in took.items() if k != "host_s"} == {
        k: v for k, v in runs[1]["simulated_time_ms"].items() if k != "host_s"}
    assert list(took) == ["start-up to OP", "200 cycles", "way down", "total", "host_s"]
    assert took["200 cycles"] == pytest.approx(200.0, abs=1.0)    # 1 ms cycles, paced
    assert took["start-up to OP"] > 100
    assert took["total"] == pytest.approx(sum(took[k] for k in list(took)[:3]), abs=0.01)
    times = [float(r["frame.time_epoch"][0]) for r in
             tshark_fields(tmp_path / "a", ["frame.time_epoch"])]
    assert len(times) == 2 * runs[0]["frames"]["sent"]
    # First frame sent to last frame back: the whole run but the moments before the first
    # frame and after the last (both none on simulated time).
    assert (times[-1] - times[0]) * 1e3 == pytest.approx(took["total"], abs=0.01)


@pytest.mark.parametrize("args, says", [
    (["--iface", "lo", "--simulated-time"], "a mode of the virtual segment"),
    (["--virtual", "--simulated-time"], "give --cycles N"),
    (["--virtual", "--simulated-time", "--cycles", "3", "--busy-wait", "50"],
     "no host timing"),
])
def test_simulated_time_options_are_checked(plan, tmp_path, args, says):
    eni = tmp_path / "example.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(plan))
    run = apply(str(eni), *args)
    assert run.returncode == 2 and says in run.stderr, run.stderr
    assert "Traceback" not in run.stderr
