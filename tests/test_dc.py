"""Distributed clocks on the virtual segment: the numbers the master writes, checked against
what the line's model implies, not against the master's own arithmetic.

The emulated line (``runtime/dc_clock.py``) delays a frame by P (``PROCESSING_DELAY_NS``,
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
import time

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import AlState, Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.dc_clock import CABLE_DELAY_NS, FORWARDING_DELAY_NS, PROCESSING_DELAY_NS

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
    with Network.virtual(dc_plan, esi=[ESI]) as net:
        net.master.transport.recorder = lambda frame, sent: frames.append((bytes(frame), sent))
        before = _now_2000()
        net.up(AlState.SAFEOP)
        after = _now_2000()
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
    assert written == EXPECTED_DELAY
    assert {n: dc_run["reg"](n, 0x0928, "<I") for n in written} == EXPECTED_DELAY


def test_system_time_offsets_give_every_slave_the_master_time_plus_its_delay(dc_run):
    offsets = {name: struct.unpack("<qI", d.data)[0] for name, d in dc_run["sent"]
               if d.cmd == Cmd.FPWR and d.ado == 0x0920 and len(d.data) == 12}
    assert set(offsets) == {"d1", "d2", "d3"}
    # offset + receive time (0x0918, latched when the 0x0900 write passed) - delay is the
    # same master time for every slave, and that is the wall clock of the set-up.
    master_times = {n: offset + dc_run["reg"](n, 0x0918, "<Q") - EXPECTED_DELAY[n]
                    for n, offset in offsets.items()}
    assert len(set(master_times.values())) == 1, master_times
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


def _now_2000() -> int:
    return time.time_ns() - EPOCH_2000_NS
