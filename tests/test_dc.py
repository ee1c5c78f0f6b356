"""Distributed clocks on the virtual segment: the numbers the master writes, checked against
what the line's model implies, not against the master's own arithmetic.

The emulated line (``runtime/segment/dc_clock.py``) delays a frame by P (``PROCESSING_DELAY_NS``,
port 0 -> processing unit -> port 1) in each slave on the way out, F
(``FORWARDING_DELAY_NS``, port 1 -> port 0) on the way back and C (``CABLE_DELAY_NS``) on
every cable; the last slave turns the frame round in its processing unit (P).  The
propagation delay from the reference clock to a slave k further down the line is half the
difference of the loop times (port 1 - port 0 receive times) of the two (ETG.1000.4
propagation delay measurement; SOEM ``ethercatdc.c`` ``ecx_configdc``: "assumption: forward
delay equals return delay", ``pdelay = (dt3 - dt1) / 2 + ...``).  The loop time below a
middle slave j is P + 2C + F more than below j + 1, and 0 at the last slave (port 1
closed), whose own turn-round costs P:

    delay(k) = (k - ref) * ((P + F) / 2 + C)                  k in the middle
    delay(n - 1) = ((n - 1 - ref) * (P + 2C + F) + P - F) / 2   the last slave

The system time offset (0x0920) must make every slave's system time at the moment the
latching frame passed equal to the master's time plus that delay:
``offset(k) + receive_time(k) = master_time + delay(k)``, one ``master_time`` for all.
The SYNC0 start time (0x0990) lies on a cycle boundary plus the slave's shift time, the
first boundary more than 100 ms after the system time read just before (SOEM
``ecx_dcsync0``: ``((t1 + SyncDelay) / CyclTime) * CyclTime + CyclTime + CyclShift`` with
``SyncDelay`` = 100 ms).
"""


from __future__ import annotations

import datetime
import struct
import subprocess
import sys

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import AlState, Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.clock import SimClock
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.master import bringup as master_module
from ecatcfg.runtime.segment.dc_clock import (CABLE_DELAY_NS, FORWARDING_DELAY_NS,
                                              PROCESSING_DELAY_NS, DcModel)
from ecatcfg.runtime.master.bringup import DC_THRESHOLD_NS, DcSyncError
from ecatcfg.runtime.master.replay import ApplyError
from ecatcfg.runtime.simwire import SimulatedLink

ESI = EXAMPLES / "esi"
DRIVE = '"0xE0000ECA:0x7201"'
# Bus order: the coupler and a digital input terminal (no DC) sit between the drives, so the
# delays count every slave on the way, not only the DC ones.
TOPOLOGY = f"""
master: {{name: dc-line, cycle_time_us: 1000}}
slaves:
  - {{name: coupler, device: EX1100}}
  - {{name: d1, device: {DRIVE}, dc: DC}}
  - {{name: io, device: EX1004}}
  - {{name: d2, device: {DRIVE}, dc: DC}}
  - {{name: d3, device: {DRIVE}, dc: DC}}
"""
SHIFT_NS = {"d1": 125_000, "d2": 250_000, "d3": 333_000}     # ENI DC/ShiftTime per slave
CYCLE_NS = 1_000_000
START_MARGIN_NS = 100_000_000
# EtherCAT system time counts nanoseconds from 2000-01-01 00:00 UTC (ETG.1000.4).
EPOCH_2000_NS = int(datetime.datetime(2000, 1, 1, tzinfo=datetime.timezone.utc)
                    .timestamp()) * 1_000_000_000


@pytest.fixture(scope="module")
def dc_plan():
    plan = build.compile_topology(topology.loads(TOPOLOGY, "dc.yaml"),
                                  Library([ESI], cache=False)).plan
    # The ESI's drive has shift time 0: give each drive its own in the ENI, as a user who
    # compensates output delays would.
    root = etree.fromstring(eni_writer.to_bytes(plan))
    for slave in root.iter("Slave"):
        name = slave.findtext("Info/Name")
        if name in SHIFT_NS:
            slave.find("DC/ShiftTime").text = str(SHIFT_NS[name])
    return eni_reader.read_bytes(etree.tostring(root), "dc.eni.xml")


@pytest.fixture(scope="module")
def dc_run(dc_plan) -> dict:
    """Bring the DC line up to SAFEOP once; what was sent and received, and the registers
    the emulated slaves hold afterwards, by slave name."""
    positions = {s.phys_addr: s.position for s in dc_plan.slaves}
    names = {s.position: s.name for s in dc_plan.slaves}
    assert [names[p] for p in sorted(names)] == ["coupler", "d1", "io", "d2", "d3"]
    frames: list[tuple[bytes, bool]] = []
    with Network.virtual(dc_plan, esi=[ESI], clock=SimClock()) as net:
        net.master.transport.recorder = lambda frame, sent: frames.append((bytes(frame), sent))
        before = _now_2000(net)
        net.up(AlState.SAFEOP)
        after = _now_2000(net)
        mem = {s.name: bytes(s.mem[0x0900:0x09A0]) for s in net.segment.slaves}

    def reg(name: str, address: int, fmt: str) -> int:
        return struct.unpack_from(fmt, mem[name], address - 0x0900)[0]

    def by_name(out: bool) -> list[tuple[str, wire.Datagram]]:
        return [(names[positions[d.adp]], d) for f, sent in frames if sent == out
                for d in wire.decode(f).datagrams
                if d.cmd in (Cmd.FPWR, Cmd.FPRD) and d.adp in positions]

    return {"before": before, "after": after, "reg": reg, "sent": by_name(True),
            "back": by_name(False)}


REF = 1                                                   # d1: the first DC slave
P, F, C = PROCESSING_DELAY_NS, FORWARDING_DELAY_NS, CABLE_DELAY_NS
EXPECTED_DELAY = {"d1": 0, "d2": (3 - REF) * ((P + F) // 2 + C),
                  "d3": ((4 - REF) * (P + 2 * C + F) + P - F) // 2}


def test_propagation_delays_are_half_the_extra_round_trip(dc_run):
    assert (P, F, C) == (600, 200, 10)
    assert EXPECTED_DELAY == {"d1": 0, "d2": 820, "d3": 1430}
    # The master writes offset (0x0920, 8 bytes) and delay (0x0928, 4 bytes) in one FPWR.
    written = {name: struct.unpack("<qI", d.data)[1] for name, d in dc_run["sent"]
               if d.cmd == Cmd.FPWR and d.ado == 0x0920 and len(d.data) == 12}
    # The receive times come from clocks that drift (up to 100 ppm of a ~3 us loop) and
    # count whole ns: a delay may be 1 ns off the line's figure.
    assert written.keys() == EXPECTED_DELAY.keys()
    assert all(abs(written[n] - EXPECTED_DELAY[n]) <= 1 for n in written), written
    assert {n: dc_run["reg"](n, 0x0928, "<I") for n in written} == written


def test_system_time_offsets_give_every_slave_the_master_time_plus_its_delay(dc_run):
    offsets = {name: struct.unpack("<qI", d.data)[0] for name, d in dc_run["sent"]
               if d.cmd == Cmd.FPWR and d.ado == 0x0920 and len(d.data) == 12}
    assert set(offsets) == {"d1", "d2", "d3"}
    # offset + receive time (0x0918, latched when the 0x0900 write passed) - delay is the
    # same master time for every slave, and that is the wall clock of the set-up.
    # As for the delays: latches of drifting clocks in whole ns may be 1 ns off each.
    master_times = {n: offset + dc_run["reg"](n, 0x0918, "<Q") - EXPECTED_DELAY[n]
                    for n, offset in offsets.items()}
    assert max(master_times.values()) - min(master_times.values()) <= 2, master_times
    assert dc_run["before"] <= master_times["d1"] <= dc_run["after"]


def test_sync0_start_time_is_a_cycle_boundary_plus_the_shift_time(dc_run):
    for name, shift in SHIFT_NS.items():
        written = [struct.unpack("<Q", d.data)[0] for n, d in dc_run["sent"]
                   if n == name and d.cmd == Cmd.FPWR and d.ado == 0x0990]
        start = dc_run["reg"](name, 0x0990, "<Q")
        assert written == [start], name
        assert (start - shift) % CYCLE_NS == 0, (name, start % CYCLE_NS, shift)
        # >= 100 ms after the system time the master read from that slave just before,
        # and no more than one cycle later than that needs.
        now = [struct.unpack("<Q", d.data)[0] for n, d in dc_run["back"]
               if n == name and d.cmd == Cmd.FPRD and d.ado == 0x0910 and d.wkc == 1][-1]
        assert now + START_MARGIN_NS < start - shift <= now + START_MARGIN_NS + CYCLE_NS, name


def _now_2000(net: Network) -> int:
    return net.clock.time_ns() - EPOCH_2000_NS


# -- clocks that drift: the runtime's DC set-up checked in numbers, on simulated time -------

def drive_line(n: int):
    topo = f"master: {{name: dc{n}, cycle_time_us: 1000}}\nslaves:\n" + "".join(
        f"  - {{name: d{i}, device: {DRIVE}, dc: DC}}\n" for i in range(n))
    library = Library([ESI], cache=False)
    plan = build.compile_topology(topology.loads(topo, "line.yaml"), library).plan
    return plan, library


def simulated(n: int, dc: DcModel | None = None, **network):
    plan, library = drive_line(n)
    clock = SimClock(1_000_000_000_000)
    segment = emulate.segment(emulate.specs_from_eni(plan, library, "line"), clock_ns=clock.monotonic_ns,
                              dc=dc)
    return Network(plan, SimulatedLink(clock, segment), **network), segment, clock


def system_times(segment, t: int) -> list[int]:
    """Each slave's system time at one instant, as no master can read it."""
    return [s.dc.local(t) + struct.unpack_from("<q", s.mem, 0x0920)[0] for s in segment.slaves]


def registers_092c(segment) -> list[int]:
    """0x092C of each emulated slave as signed ns (bit 31: the local copy is smaller)."""
    raw = [struct.unpack_from("<I", s.mem, 0x092C)[0] for s in segment.slaves]
    return [-(r & 0x7FFF_FFFF) if r & 0x8000_0000 else r for r in raw]


N_LINE = 64


@pytest.fixture(scope="module")
def line64():
    """64 DC drives with quartzes within ±100 ppm: set-up to SAFEOP (offsets, delays,
    static drift frames), then 500 cycles of 1 ms with the ENI's cyclic ARMW."""
    net, segment, clock = simulated(N_LINE, DcModel(drift_ppm=100.0, seed=7),
                                    dc_threshold_ns=0)
    net.up(AlState.SAFEOP)
    after_setup = registers_092c(segment)
    for _ in range(500):
        clock.advance(1_000_000)
        assert net.cycle()
    return {"net": net, "segment": segment, "clock": clock, "after_setup": after_setup}


def test_64_drifting_clocks_converge_under_100_ns(line64):
    segment = line64["segment"]
    drifts = [s.dc.drift * 1e6 for s in segment.slaves]
    assert min(drifts) < -80 and max(drifts) > 80          # the quartzes really differ
    read = line64["net"].master.read_dc_differences()
    assert len(read) == N_LINE and set(read.values()) != {None}
    assert max(abs(d) for d in read.values() if d is not None) < 100, read
    assert list(read.values()) == registers_092c(segment)
    # The loops did the work: each learned its quartz's deviation from the reference's.
    ref = segment.slaves[0].dc.drift
    assert all(abs(s.dc.freq + (s.dc.drift - ref)) < 1e-6 for s in segment.slaves[1:])


def test_64_clocks_agree_with_the_reference_up_to_the_lines_asymmetry(line64):
    """The master's delays assume a frame needs as long out as back; on the emulated line
    a middle slave forwards the way back faster (F < P), so slave k's system time is
    (k - ref) * (F - P) / 2 off the reference's, the last slave's ((n - 2 - ref) * (F - P)
    / 2 (the delays above).  Beyond that, every clock is within 100 ns."""
    segment, clock = line64["segment"], line64["clock"]
    times = system_times(segment, clock.ns)
    for k, t in enumerate(times):
        bias = (k * (F - P) if k < N_LINE - 1 else (N_LINE - 2) * (F - P)) // 2
        assert abs(t - times[0] - bias) < 100, (k, t - times[0], bias)


def test_sync0_start_time_is_in_the_future_when_written(line64):
    """Each slave saw a start time 100 ms (+ up to a cycle) after its own system time at
    the moment the write passed it (not only after what the master read before)."""
    leads = [s.sync0_start_lead_ns for s in line64["segment"].slaves]
    assert None not in leads
    assert all(START_MARGIN_NS - 5_000_000 < lead <= START_MARGIN_NS + CYCLE_NS
               for lead in leads), leads


def test_the_clocks_drift_apart_without_drift_compensation(monkeypatch):
    """Control for the tests above: offsets and delays alone, no drift frame, leave each
    clock at its quartz's speed, and a second later they are microseconds apart."""
    monkeypatch.setattr(master_module, "DRIFT_FRAMES", 0)
    net, segment, clock = simulated(8, DcModel(drift_ppm=100.0, seed=7), dc_threshold_ns=0)
    net.up(AlState.PREOP)
    net.master.setup_dc()
    clock.advance(1_000_000_000)
    times = system_times(segment, clock.ns)
    assert max(abs(t - times[0] - k * (F - P) // 2) for k, t in enumerate(times[:-1])) > 10_000


# -- the convergence wait before SAFEOP->OP ------------------------------------------------

def test_apply_waits_for_the_clocks_before_op(monkeypatch):
    """Without static drift frames the clocks are still off when SAFEOP is reached; up()
    sends drift compensation until every |0x092C| is under the threshold, then OP."""
    monkeypatch.setattr(master_module, "DRIFT_FRAMES", 0)
    events = []
    net, segment, clock = simulated(8, DcModel(drift_ppm=100.0, seed=3), dc_threshold_ns=50,
                                    on_event=events.append)
    # A larger start error than the set-up leaves: every slave but the reference 2 us off.
    original = net.master.setup_dc

    def setup_then_disturb() -> None:
        original()
        for s in segment.slaves[1:]:
            offset, = struct.unpack_from("<q", s.mem, 0x0920)
            struct.pack_into("<q", s.mem, 0x0920, offset + 2_000)

    net.master.setup_dc = setup_then_disturb
    net.up(AlState.OP)
    assert net.state == AlState.OP
    done = [e.text for e in events if e.kind == "dc" and "under 50 ns" in e.text]
    assert len(done) == 1 and " 0 drift frames" not in done[0], done
    # The wait saw every |0x092C| under 50 ns; read again after OP was requested, the
    # filtered difference may stand a few ns either side of where it was (51 in one run).
    assert max(abs(d) for d in registers_092c(segment)) < 60


def test_apply_names_the_slave_whose_clock_does_not_converge():
    """A quartz 3000 ppm off is beyond what the time control loop corrects (~781 ppm):
    after the timeout, up() stops before OP naming that slave and its last difference."""
    net, segment, clock = simulated(8, DcModel(drift_ppm=50.0, seed=1), dc_timeout_s=0.05)
    segment.slaves[5].dc.drift = 3000e-6
    with pytest.raises(DcSyncError) as err:
        net.up(AlState.OP)
    assert net.state == AlState.SAFEOP
    assert err.value.slave == "d5"
    last = err.value.differences["d5"]
    assert last is not None and abs(last) > DC_THRESHOLD_NS
    assert f"slave 'd5': DC did not converge: system time difference (0x092C) is {last} ns" \
        in str(err.value)
    assert "threshold 1000 ns, after 0.05 s" in str(err.value)
    assert all(abs(d) < DC_THRESHOLD_NS for n, d in err.value.differences.items()
               if n != "d5" and d is not None)


def test_dc_wait_options_are_checked(tmp_path):
    eni = tmp_path / "line.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(drive_line(2)[0]))
    for option, value, says in (("--dc-threshold", "-1", "--dc-threshold: the DC threshold"),
                                ("--dc-timeout", "0", "--dc-timeout: the DC timeout")):
        proc = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                               option, value], capture_output=True, text=True)
        assert proc.returncode == 2, proc.stderr
        assert says in proc.stderr and "Traceback" not in proc.stderr


# -- the emulated ESC's registers --------------------------------------------------------

def two_slaves(clock: SimClock):
    plan, library = drive_line(2)
    segment = emulate.segment(emulate.specs_from_eni(plan, library, "line"), clock_ns=clock.monotonic_ns,
                              dc=DcModel(drift_ppm=0.0, start_spread_ns=0))
    return segment


def _armw(segment) -> None:
    segment.process(wire.encode([wire.Datagram.physical(Cmd.ARMW, 0, 0x0910, 8)]))


def test_system_time_difference_is_sign_and_magnitude_and_the_clock_slews():
    """0x092C bit 31 is set when the local copy is smaller than the received time (ESC
    Section II); with no averaging (0x0934 = 0) it shows the one difference.  The loop
    corrects it by slewing the clock, not by a jump; a write of 0x0930 resets 0x092C."""
    clock = SimClock(1_000_000_000_000)
    segment = two_slaves(clock)
    ref, slave = segment.slaves
    # Same start, no drift: slave 1 sees the reference's time P + C later, so with a delay
    # of P + C its copy matches; 500 ns less offset puts it 500 ns behind.
    struct.pack_into("<qI", slave.mem, 0x0920, -500, P + C)
    slave.mem[0x0934] = 0
    before = slave.dc.local(clock.ns + 1)
    _armw(segment)
    assert struct.unpack_from("<I", slave.mem, 0x092C)[0] == 0x8000_0000 | 500
    assert slave.dc.local(clock.ns + 1) == before                    # no jump
    clock.advance(10_000)
    moved = slave.dc.local(clock.ns) - before - 10_000
    assert 0 < moved <= 8                                           # <= 781 ppm of 10 us
    segment.process(wire.encode([wire.Datagram.physical(Cmd.FPWR, slave.station_address,
                                                         0x0930, struct.pack("<H", 0x1000))]))
    assert slave.mem[0x092C:0x0930] == bytes(4)
    # 0x092C is read-only from the wire.
    segment.process(wire.encode([wire.Datagram.physical(Cmd.BWR, 0, 0x092C, bytes([7] * 4))]))
    assert slave.mem[0x092C:0x0930] == bytes(4)


def test_receive_times_follow_the_line():
    """A BWR of 0x0900 latches port 0 and port 1 receive times (local time) as the frame
    passes: slave 1 (the last) sees it P + C after slave 0, and slave 0's port 1 sees it
    come back after P + C out, the turn-round P in slave 1, and C back."""
    clock = SimClock(1_000_000_000_000)
    segment = two_slaves(clock)                      # both clocks start at 0 now, no drift
    clock.advance(5_000)
    segment.process(wire.encode([wire.Datagram.physical(Cmd.BWR, 0, 0x0900, bytes(4))]))
    (a0, a1), (b0, b1) = (struct.unpack_from("<II", s.mem, 0x0900) for s in segment.slaves)
    assert (a0, a1) == (5_000, 5_000 + 2 * P + 2 * C)
    assert b0 == 5_000 + P + C
    assert b1 == 0                                   # port 1 of the last slave: closed
    assert [struct.unpack_from("<Q", s.mem, 0x0918)[0] for s in segment.slaves] == [a0, b0]


def test_sync0_without_a_cycle_time_is_refused_in_preop_to_safeop():
    """An ENI that activates SYNC0 (0x0981 = 0x03, the drive's AssignActivate 0x0300) but
    never writes its cycle time (0x09A0) asks for a SYNC signal without a period: the
    drive's firmware refuses SAFEOP with AL status code 0x0035, "DC invalid sync cycle
    time" (ETG.1000.6 AL status codes; the slave stays in PREOP with the error flag)."""
    plan, library = drive_line(1)
    [slave] = plan.slaves
    slave.init_cmds = [c for c in slave.init_cmds if c.comment != "set DC cycle time"]
    clock = SimClock(1_000_000_000_000)
    segment = emulate.segment(emulate.specs_from_eni(plan, library, "line"), clock_ns=clock.monotonic_ns)
    net = Network(plan, SimulatedLink(clock, segment))
    with pytest.raises(ApplyError) as err:
        net.up(AlState.SAFEOP)
    assert err.value.al_code == 0x0035
    assert (segment.slaves[0].state, segment.slaves[0].error) == (AlState.PREOP, True)
