"""Faults of the virtual segment a running network must survive: a device swapped for
another in its place, and a power cycle (registers, firmware and object dictionary afresh,
EEPROM kept).

What a real slave does is taken from the ESC datasheet (Section II: registers after reset,
the station address 0x0010 is 0 until the master writes it, the alias 0x0012 and PDI
control come from the EEPROM) and from what the new device's own EEPROM says; expected
values are written by hand from the SlaveSpecs the tests build, and read back over
datagrams the way a master reads them.
"""

from __future__ import annotations

import struct

import pytest
from conftest import EXAMPLES

from ecatcfg.compiler import build, topology
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import SII_PRODUCT_CODE, SII_SERIAL, AlState, Cmd, eeprom_read_request
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, emulated_slave, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment
from ecatcfg.runtime.segment.timing import Timing

ESI = EXAMPLES / "esi"


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI, EXAMPLES / "tree" / "esi"], cache=False)


def spec(lib: Library, type_name: str, name: str, **kw) -> SlaveSpec:
    return SlaveSpec(lib.device(lib.find(type_name).entry), name, **kw)


class SimClock:
    def __init__(self) -> None:
        self.t = 5_000_000_000_000           # the segment has been up for 5000 s

    def __call__(self) -> int:
        return self.t


def line(lib: Library, **kw) -> VirtualSegment:
    return segment([spec(lib, "EX1100", "coupler", serial=1),
                    spec(lib, "EXD-402", "drive", serial=2, alias=0x0011),
                    spec(lib, "EX1004", "inputs", serial=3)], **kw)


def send(seg: VirtualSegment, *datagrams: wire.Datagram) -> list[wire.Datagram]:
    return list(wire.decode(seg.process(wire.encode(list(datagrams)))).datagrams)


def aprd(seg: VirtualSegment, position: int, ado: int, n: int) -> wire.Datagram:
    got, = send(seg, wire.Datagram.physical(Cmd.APRD, -position & 0xFFFF, ado, n))
    return got


def u16(seg: VirtualSegment, position: int, ado: int) -> int:
    got = aprd(seg, position, ado, 2)
    assert got.wkc == 1
    value: int = struct.unpack("<H", got.data)[0]
    return value


def sii_dword(seg: VirtualSegment, position: int, word: int) -> int:
    """A 32-bit SII value read as a master reads it: request at 0x0502, data at 0x0508."""
    send(seg, wire.Datagram.physical(Cmd.APWR, -position & 0xFFFF, 0x0502,
                                     eeprom_read_request(word)))
    got = aprd(seg, position, 0x0508, 4)
    value: int = struct.unpack("<I", got.data)[0]
    return value


def configure(seg: VirtualSegment, position: int, station: int) -> None:
    """Station address, then PREOP (the drive has a mailbox: SM0/SM1 first)."""
    send(seg, wire.Datagram.physical(Cmd.APWR, -position & 0xFFFF, 0x0010,
                                     struct.pack("<H", station)))


# -- swap ---------------------------------------------------------------------------------

def test_a_device_of_the_same_type_with_another_alias_takes_the_place(lib):
    seg = line(lib)
    configure(seg, 1, 1002)
    assert u16(seg, 1, 0x0010) == 1002 and u16(seg, 1, 0x0012) == 0x0011
    links = u16(seg, 1, 0x0110) & 0xFFF0
    new = emulated_slave(spec(lib, "EXD-402", "drive-b", serial=99, alias=0x0022))
    old = seg.swap("drive", new)
    assert old.name == "drive" and old.on_state_change is None
    assert [s.name for s in seg.slaves] == ["coupler", "drive-b", "inputs"]
    assert new.position == 1
    # Fresh from power-on: INIT, no station address, its own EEPROM's alias and serial.
    assert u16(seg, 1, 0x0130) & 0x0F == AlState.INIT
    assert u16(seg, 1, 0x0010) == 0
    assert u16(seg, 1, 0x0012) == 0x0022
    assert sii_dword(seg, 1, SII_SERIAL) == 99
    # The same cables: the same links in DL status; the old station address answers no more.
    assert u16(seg, 1, 0x0110) & 0xFFF0 == links
    got, = send(seg, wire.Datagram.physical(Cmd.FPRD, 1002, 0x0130, 2))
    assert got.wkc == 0
    brd, = send(seg, wire.Datagram.physical(Cmd.BRD, 0, 0x0130, 2))
    assert brd.wkc == 3


def test_a_different_device_shows_its_own_identity(lib):
    seg = line(lib)
    new = emulated_slave(spec(lib, "EX1008", "other", serial=5))
    seg.swap(1, new)
    assert sii_dword(seg, 1, SII_PRODUCT_CODE) == 0x2008       # EX1008, not the drive's
    assert sii_dword(seg, 2, SII_PRODUCT_CODE) == 0x2004       # the inputs behind it


def test_a_used_device_swapped_in_starts_from_power_on(lib):
    """A device taken from another machine (its registers set) is switched on afresh."""
    other = line(lib)
    configure(other, 1, 1234)
    moved = other.swap("drive", emulated_slave(spec(lib, "EXD-402", "spare")))
    seg = line(lib)
    seg.swap("drive", moved)
    assert u16(seg, 1, 0x0010) == 0 and u16(seg, 1, 0x0012) == 0x0011


def test_a_device_whose_ports_do_not_fit_is_refused(lib):
    seg = line(lib)
    terminal = emulated_slave(spec(lib, "EXB1018", "ebus"))      # Physics KK: E-bus ports
    with pytest.raises(ValueError, match="port 0 is E-bus, the cable there needs Ethernet"):
        seg.swap("drive", terminal)
    assert [s.name for s in seg.slaves] == ["coupler", "drive", "inputs"]
    with pytest.raises(ValueError, match="already in the segment"):
        seg.swap("drive", seg.slaves[2])


def test_the_swapped_in_device_gets_the_segments_clock_timing_and_callbacks(lib):
    clock = SimClock()
    seg = line(lib, timing=Timing(), clock_ns=clock)
    changes = []
    seg.on_state_change = changes.append
    new = emulated_slave(spec(lib, "EXD-402", "drive-b"))
    seg.swap("drive", new)
    assert new.timing is not None and new in seg._timed       # (private: the settle list)
    assert new.clock_ns() == clock.t
    # Its local clock started when it was switched on: 0x0910 counts from the swap.
    clock.t += 1_000_000
    local = struct.unpack("<Q", aprd(seg, 1, 0x0910, 8).data)[0]
    assert 990_000 < local < 1_010_000
    old_local = struct.unpack("<Q", aprd(seg, 0, 0x0910, 8).data)[0]
    assert old_local > 1_010_000 or old_local == 0              # the coupler's own clock
    # A state change of the new device is reported; the old one's are not.
    send(seg, wire.Datagram.physical(Cmd.APWR, 0xFFFF, 0x0120, b"\x02\x00"))
    clock.t += 1_000_000_000
    seg.settle()
    assert [c.name for c in changes] == ["drive-b"]


# -- power cycle ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def example_eni(tmp_path_factory):
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([ESI], cache=False)).plan
    path = tmp_path_factory.mktemp("eni") / "line.xml"
    path.write_bytes(eni_writer.to_bytes(plan))
    return path


def test_a_power_cycle_in_op_leaves_the_slave_in_init_with_its_registers_reset(example_eni):
    """Up to OP by our master, whose link is then closed (the segment stays as it was, no
    more frames but the test's own); then the drive is switched off and on."""
    net = Network.virtual(example_eni, esi=[ESI])
    try:
        net.up()
    finally:
        net.close()
    seg = net.segment
    drive = next(s for s in seg.slaves if s.name == "axis1")
    pos = drive.position
    # OP (or SAFEOP+ERR if the SM watchdog ran out without cyclic frames).
    assert drive.state in (AlState.OP, AlState.SAFEOP)
    assert drive.fmmus and drive.station_address == 1005
    eeprom = bytes(drive.eeprom)
    # topology.yaml assigns RxPDO 0x1601 where the ESI's default (0x1C12:01) is 0x1600.
    assert drive.od.value(0x1C12, 1) == b"\x01\x16"
    logical = [wire.Datagram.logical(c.cmd, c.addr, bytes(c.length))
               for f in net.plan.cyclic[0].frames for c in f.cmds if c.addr is not None]
    assert [d.cmd for d in logical] == [Cmd.LRD, Cmd.LRW]
    before = sum(d.wkc for d in send(seg, *logical))
    seg.power_cycle("axis1")
    assert u16(seg, pos, 0x0130) == AlState.INIT and u16(seg, pos, 0x0134) == 0
    assert u16(seg, pos, 0x0010) == 0                       # station address: none
    assert not drive.fmmus and not any(sm.active for sm in drive.sms)
    assert aprd(seg, pos, 0x0800, 16).data == bytes(16)      # SM0, SM1 cleared
    assert bytes(drive.eeprom) == eeprom
    # The firmware restarted: the dictionary is back at power-on, as the ESI says
    # (DefaultData 0016), until the master downloads the assignment again.
    assert drive.od.value(0x1C12, 1) == b"\x00\x16" and drive.od.value(0x1C12, 0) == b"\x01"
    got, = send(seg, wire.Datagram.physical(Cmd.FPRD, 1005, 0x0130, 2))
    assert got.wkc == 0
    after = sum(d.wkc for d in send(seg, *logical))
    # The drive's share is gone from the working counters: 3 in the LRW of the process
    # data (it reads and writes: ETG.1000.4), 1 in the LRD of the mailbox-state bits.
    assert before - after == 3 + 1


def test_a_power_cycle_restarts_the_local_clock_and_keeps_the_quartz(lib):
    clock = SimClock()
    seg = line(lib, clock_ns=clock)
    drive = seg.slaves[1]
    drift = drive.dc.drift
    assert struct.unpack("<Q", aprd(seg, 1, 0x0910, 8).data)[0] > 1_000_000_000
    seg.power_cycle(1)
    clock.t += 2_000_000
    local = struct.unpack("<Q", aprd(seg, 1, 0x0910, 8).data)[0]
    assert 1_990_000 < local < 2_010_000                     # counting from power-on
    assert drive.dc.drift == drift
