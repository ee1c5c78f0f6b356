"""Branched networks on the runtime side: the virtual segment as a tree, scan and verify of
the tree, DC propagation delays over it.

Expectations are worked out by hand from the wiring rule (a frame enters port 0 and each
ESC takes its open ports in the order 0 -> 3 -> 1 -> 2, ETG.1000.4; SOEM ``ethercatdc.c``,
IgH ``slave.c``) and from the delay model of ``runtime/dc_clock.py``: P on the way from
port 0 through the processing unit to the first open port, F from a port the frame comes
back on to the next one (or out of port 0), C per cable, P to turn round in a slave with
no open downstream port.

The tree used throughout, six DC drives (given to the segment in this order)::

    t0 --D--> t1 --B--> t2
    t0 --B--> t3 --B--> t5
    t0 --C--> t4

Bus order: t0, t1, t2 (port D first), t3, t5 (port B), t4 (port C).
"""

from __future__ import annotations

import dataclasses
import struct

import pytest

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.esc import Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import emulate, wire
from ecatcfg.runtime.dc_clock import (CABLE_DELAY_NS, FORWARDING_DELAY_NS, PROCESSING_DELAY_NS,
                                      DcModel)
from ecatcfg.runtime.wiring import Plug

ESI = EXAMPLES / "esi"
DRIVE = '"0xE0000ECA:0x7201"'
P, F, C = PROCESSING_DELAY_NS, FORWARDING_DELAY_NS, CABLE_DELAY_NS
A, B_, C_, D = 0, 1, 2, 3                     # ESC ports by ENI letter
TREE = [None, Plug(0, D), Plug(1, B_), Plug(0, B_), Plug(0, C_), Plug(3, B_)]
BUS_ORDER = ["t0", "t1", "t2", "t3", "t5", "t4"]
# When a frame sent at 0 reaches each port (None: no frame there), by hand from the model:
# t0 sends it down D at P; t1 (P + C) down its B at 2P + C, t2 (2P + 2C) turns it round
# (P) and it is back at t1's B at 3P + 3C, out of t1's A at 3P + 3C + F, at t0's D at
# 3P + 4C + F; t0 forwards it down B (F): t3 at 3P + 5C + 2F ...
HAND_TIMES = {
    "t0": (0, 5 * P + 8 * C + 3 * F, 6 * P + 10 * C + 4 * F, 3 * P + 4 * C + F),
    "t1": (P + C, 3 * P + 3 * C, None, None),
    "t2": (2 * P + 2 * C, None, None, None),
    "t3": (3 * P + 5 * C + 2 * F, 5 * P + 7 * C + 2 * F, None, None),
    "t5": (4 * P + 6 * C + 2 * F, None, None, None),
    "t4": (5 * P + 9 * C + 4 * F, None, None, None),
}
LINK = 0x0010                                 # DL status: link on port n = LINK << n
OPEN = 0x0200                                 # loop open, communication: OPEN << 2n
CLOSED = 0x0100                               # loop closed: CLOSED << 2n


def dl_status(*linked: int) -> int:
    """DL status bits 4-15 with links on the ports given (by hand from ESC Section II)."""
    value = 0
    for port in range(4):
        value |= (LINK << port | OPEN << 2 * port) if port in linked else CLOSED << 2 * port
    return value


@pytest.fixture(scope="module")
def drives():
    topo = "master: {name: tree, cycle_time_us: 1000}\nslaves:\n" + "".join(
        f"  - {{name: t{i}, device: {DRIVE}, dc: DC}}\n" for i in range(6))
    library = Library([ESI], cache=False)
    plan = build.compile_topology(topology.loads(topo, "tree.yaml"), library).plan
    return plan, library


class SimClock:
    def __init__(self) -> None:
        self.t = 1_000_000_000_000

    def __call__(self) -> int:
        return self.t


def tree_segment(drives, clock=None, dc=None):
    plan, library = drives
    specs = [dataclasses.replace(s, plug=plug) for s, plug in
             zip(emulate.specs_from_eni(plan, library, "tree"), TREE)]
    return emulate.segment(specs, clock_ns=clock,
                           dc=dc or DcModel(drift_ppm=0.0, start_spread_ns=0))


def send(segment, *datagrams):
    return wire.decode(segment.process(wire.encode(list(datagrams)))).datagrams


def aprd(segment, position: int, ado: int, n: int):
    got, = send(segment, wire.Datagram.physical(Cmd.APRD, -position & 0xFFFF, ado, n))
    return got


# -- the segment --------------------------------------------------------------------------

def test_bus_order_follows_the_ports_processing_order(drives):
    segment = tree_segment(drives)
    assert [s.name for s in segment.slaves] == BUS_ORDER
    assert [s.position for s in segment.slaves] == list(range(6))
    # Auto-increment reaches them in that order; a broadcast counts each once.
    for pos, name in enumerate(BUS_ORDER):
        got = aprd(segment, pos, 0x0110, 2)
        assert got.wkc == 1
    brd, = send(segment, wire.Datagram.physical(Cmd.BRD, 0, 0x0130, 2))
    assert brd.wkc == 6


def test_dl_status_shows_the_ports_with_a_link(drives):
    segment = tree_segment(drives)
    want = {"t0": dl_status(A, B_, C_, D), "t1": dl_status(A, B_), "t2": dl_status(A),
            "t3": dl_status(A, B_), "t5": dl_status(A), "t4": dl_status(A)}
    got = {name: struct.unpack("<H", aprd(segment, pos, 0x0110, 2).data)[0] & 0xFFF0
           for pos, name in enumerate(BUS_ORDER)}
    assert got == want


def test_receive_times_latch_per_port_with_the_hop_delays(drives):
    clock = SimClock()
    segment = tree_segment(drives, clock)           # clocks start at 0 now, no drift
    clock.t += 5_000
    send(segment, wire.Datagram.physical(Cmd.BWR, 0, 0x0900, bytes(4)))
    got = {s.name: struct.unpack_from("<4I", s.mem, 0x0900) for s in segment.slaves}
    want = {name: tuple(0 if t is None else 5_000 + t for t in times)
            for name, times in HAND_TIMES.items()}
    assert got == want


def test_a_removed_cable_takes_the_slaves_behind_it_out_of_the_frame(drives):
    segment = tree_segment(drives)
    gone = segment.remove_cable("t3")
    assert sorted(s.name for s in gone) == ["t3", "t5"]
    assert [s.name for s in segment.slaves] == ["t0", "t1", "t2", "t4"]
    brd, = send(segment, wire.Datagram.physical(Cmd.BRD, 0, 0x0130, 2))
    assert brd.wkc == 4
    assert aprd(segment, 3, 0x0110, 2).wkc == 1                     # t4 moved up to 3
    assert aprd(segment, 4, 0x0110, 2).wkc == 0
    t0 = struct.unpack("<H", aprd(segment, 0, 0x0110, 2).data)[0] & 0xFFF0
    assert t0 == dl_status(A, C_, D)                                # port B: no link
    segment.restore_cable("t3")
    assert [s.name for s in segment.slaves] == BUS_ORDER


def test_a_line_is_the_default_wiring(drives):
    plan, library = drives
    segment = emulate.segment(emulate.specs_from_eni(plan, library, "line"))
    assert [s.name for s in segment.slaves] == [f"t{i}" for i in range(6)]
    assert segment.wiring.is_line


def test_plugging_errors_name_the_slaves(drives):
    plan, library = drives
    specs = emulate.specs_from_eni(plan, library, "tree")
    two = [specs[0], dataclasses.replace(specs[1], plug=Plug(0, D)),
           dataclasses.replace(specs[2], plug=Plug(0, D))]
    with pytest.raises(ValueError, match="both plugged into port 3 of slave 0.*'t2'"):
        emulate.segment(two)
    with pytest.raises(ValueError, match="port 0 faces the master"):
        emulate.segment([specs[0], dataclasses.replace(specs[1], plug=Plug(0, 0))])
