"""The mailbox-full bits of Master/MailboxStates (ETG.2100): each slave's FMMU copies SM1's
status (0x080D) into its StatusBitAddr bit, and one LRD tells the master which mailboxes
hold an answer (eni/mailbox_states.py, runtime/master/replay.py MailboxStatePoll).

The emulated ESC maps the register bit as any FMMU maps physical memory; the expected
values are the ESC datasheet's (SM status bit 0 set when the firmware wrote the whole
buffer, bit 3 mailbox full, both cleared when the master read it), the rule is checked
against the exports of TwinCAT and EC-Engineer in the corpora."""

from __future__ import annotations

import copy
import struct
from pathlib import Path

import pytest

from conftest import EXAMPLES
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.check.run import check_eni
from ecatcfg.eni.mailbox_states import state_bits
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState, Cmd, FmmuConfig, FmmuType, SmConfig, sm_register
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.pcap import read_capture
from ecatcfg.runtime.segment import timing
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.timing import Timing
from ecatcfg.runtime.segment.virtual import VirtualSegment
from ecatcfg.runtime.wire import Datagram

ESI = EXAMPLES / "esi"
MS = 1_000_000
AREA = 0x0900_0000
# An SDO upload request of 0x1018:01 (ETG.1000.6), padded to the 128-byte mailbox.
SDO_UPLOAD_1018_01 = bytes.fromhex("0a00000000" "13" "0020" "40181001" "00000000")


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def drives_plan(lib: Library, n: int) -> NetworkPlan:
    from ecatcfg.compiler import build, topology
    text = "slaves:\n" + "".join(f"  - {{name: axis{i}, device: EXD-402}}\n" for i in range(n))
    plan = build.compile_topology(topology.loads(text, "t.yaml"), lib).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "t.eni.xml")


# -- the emulated ESC: an FMMU over a register bit ---------------------------------------------

class Clock:
    def __init__(self) -> None:
        self.now = 1_000 * MS

    def __call__(self) -> int:
        return self.now


def _run(seg: VirtualSegment, *dgs: Datagram) -> list[Datagram]:
    return wire.decode(seg.process(wire.encode(list(dgs)))).datagrams


@pytest.mark.parametrize("physical_bit", [0, 3])
def test_an_fmmu_maps_sm1_status_bits_into_logical_space(lib, physical_bit):
    """Two drives, FMMU 2 of each mapping SM1 status bit 0 (as the exports do) or bit 3
    (mailbox full) onto logical bit 0 and 1 of the area: an LRD counts both slaves and
    shows 1 exactly for the drive whose reply is posted, until the master read it."""
    clock = Clock()
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), f"d{i}")
                   for i in range(2)])
    seg = VirtualSegment(seg.slaves, clock_ns=clock, timing=Timing())
    for i in range(2):
        addr = 0x1001 + i
        [d] = _run(seg, Datagram.physical(Cmd.APWR, (-i) & 0xFFFF, 0x0010,
                                          struct.pack("<H", addr)))
        assert d.wkc == 1
        fmmu = FmmuConfig(AREA, 1, i, i, 0x080D, physical_bit, FmmuType.READ)
        got = _run(seg,
                   Datagram.physical(Cmd.FPWR, addr, sm_register(0),
                                     SmConfig(0x1000, 128, 0x26, True).to_bytes()),
                   Datagram.physical(Cmd.FPWR, addr, sm_register(1),
                                     SmConfig(0x1080, 128, 0x22, True).to_bytes()),
                   Datagram.physical(Cmd.FPWR, addr, 0x0620, fmmu.to_bytes()),
                   Datagram.physical(Cmd.FPWR, addr, 0x0120, struct.pack("<H", AlState.PREOP)))
        assert [g.wkc for g in got] == [1, 1, 1, 1]
    clock.now += timing.TABLE["drive"].transition_ns("IP")
    lrd = Datagram.logical(Cmd.LRD, AREA, 1)
    [states] = _run(seg, lrd)
    assert (states.wkc, states.data[0]) == (2, 0x00)           # both mapped, both empty
    [d] = _run(seg, Datagram.physical(Cmd.FPWR, 0x1002, 0x1000,
                                      SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    assert d.wkc == 1
    [states] = _run(seg, lrd)
    assert states.data[0] == 0x00                               # not answered yet
    clock.now += timing.TABLE["drive"].mailbox_reply_ns
    [states] = _run(seg, lrd)
    assert (states.wkc, states.data[0]) == (2, 0x02)            # drive 2's bit only
    [reply, states] = _run(seg, Datagram.physical(Cmd.FPRD, 0x1002, 0x1080, 128), lrd)
    assert reply.wkc == 1 and reply.data[9:12] == b"\x18\x10\x01"
    assert (states.wkc, states.data[0]) == (2, 0x00)            # read: empty again


# -- the rule and check ------------------------------------------------------------------------

def test_the_compiled_drives_poll_their_bits(lib):
    plan = drives_plan(lib, 3)
    assert plan.master.mailbox_states == (AREA, 3)
    good, problems = state_bits(plan)
    assert [(b.slave, b.bit) for b in good] == [("axis0", 0), ("axis1", 1), ("axis2", 2)]
    assert problems == []


def _defective(tmp_path: Path, lib: Library, old: str, new: str, count: int = 1) -> Path:
    text = eni_writer.to_bytes(drives_plan(lib, 3)).decode()
    assert text.count(old) >= count
    path = tmp_path / "eni.xml"
    path.write_text(text.replace(old, new, count))
    return path


def _line_of(path: Path, needle: str, nth: int = 0) -> int:
    lines = [n for n, line in enumerate(path.read_text().splitlines(), 1) if needle in line]
    return lines[nth]


@pytest.mark.parametrize("old, new, message", [
    ("<StatusBitAddr>2</StatusBitAddr>", "<StatusBitAddr>3</StatusBitAddr>",
     "StatusBitAddr 3 lies outside Master/MailboxStates (Count 3"),
    ("<StatusBitAddr>2</StatusBitAddr>", "<StatusBitAddr>1</StatusBitAddr>",
     "StatusBitAddr 1 is also that of slave 'axis"),
    ("<StatusBitAddr>2</StatusBitAddr>", "<StatusBitAddr>-1</StatusBitAddr>",
     "StatusBitAddr -1 lies outside"),
])
def test_check_names_a_bit_the_area_does_not_hold_at_its_line(tmp_path, lib, old, new,
                                                              message):
    path = _defective(tmp_path, lib, old, new)
    result = check_eni(path, None, use_cache=False)
    found = [f for f in result.findings if f.rule == "ENI122"]
    assert found and all(f.severity == "error" for f in found)
    assert any(message in f.message for f in found), [f.message for f in found]
    # The bit's line; two slaves on one bit: both slaves' lines.
    lines = {n for n, line in enumerate(path.read_text().splitlines(), 1) if new in line}
    assert {f.line for f in found} == lines and len(found) == len(lines)


def test_check_names_a_bit_no_fmmu_maps(tmp_path, lib):
    """StatusBitAddr 2 with axis2's FMMU moved to logical bit 5: the master would read a
    bit nothing sets."""
    plan = drives_plan(lib, 3)
    axis2 = plan.slaves[2]
    cmd = next(c for c in axis2.init_cmds if c.comment.endswith("(mailbox state)"))
    assert cmd.data is not None
    fmmu = FmmuConfig.from_bytes(cmd.data)
    assert (fmmu.logical_start, fmmu.logical_start_bit, fmmu.physical_start) == (AREA, 2, 0x080D)
    moved = FmmuConfig(AREA, 1, 5, 5, 0x080D, fmmu.physical_start_bit, FmmuType.READ)
    old = cmd.data.hex()
    path = _defective(tmp_path, lib, old, moved.to_bytes().hex())
    result = check_eni(path, None, use_cache=False)
    found = [f for f in result.findings if f.rule == "ENI122"]
    assert len(found) == 1 and "axis2" in found[0].message
    assert "no FMMU" in found[0].message
    assert found[0].line == _line_of(path, "<StatusBitAddr>2</StatusBitAddr>")


def _mailbox_state_enis(corpus: Path, corpus_extra: Path) -> list[Path]:
    return sorted(p for root in (corpus / "eni", corpus_extra / "eni")
                  for p in root.rglob("*.xml") if b"<MailboxStates>" in p.read_bytes())


def test_the_real_exports_hold_every_bit(corpus, corpus_extra):
    """TwinCAT and EC-Engineer ENIs (29 files with MailboxStates): every slave's
    StatusBitAddr is held, and check finds nothing to say."""
    files = _mailbox_state_enis(corpus, corpus_extra)
    assert len(files) >= 20
    slaves = 0
    for path in files:
        plan = eni_reader.read_file(path)
        good, problems = state_bits(plan)
        claimed = [s for s in plan.slaves
                   if s.mailbox is not None and s.mailbox.status_bit_addr is not None]
        assert problems == [] and len(good) == len(claimed), path
        slaves += len(good)
        result = check_eni(path, None, use_cache=False)
        assert not [f for f in result.findings if f.rule == "ENI122"], path
    assert slaves >= 80


# -- the master ------------------------------------------------------------------------------

def _datagrams(pcap: Path) -> list[list[Datagram]]:
    """The datagrams of each frame the master sent."""
    frames = [wire.decode(f).datagrams for _, _, f in read_capture(pcap)]
    return frames[::2]                # sent, reply, sent, ...: the pcap holds both


def _status_polls(frames: list[list[Datagram]]) -> tuple[int, int]:
    """(FPRDs of SM1's status byte alone, frames with an LRD of the area and no BRD of the
    AL status: the cyclic frame's LRD goes with that BRD)."""
    fprd = sum(1 for f in frames for d in f
               if d.cmd == Cmd.FPRD and d.ado == 0x080D and len(d.data) == 1)
    lrd = 0
    for f in frames:
        lrds = [d for d in f if d.cmd == Cmd.LRD and d.address == AREA]
        assert len(lrds) <= 1                   # the waiting slaves share one
        if lrds and not any(d.cmd == Cmd.BRD and d.ado == 0x0130 for d in f):
            lrd += 1
    return fprd, lrd


def test_the_master_polls_the_mailbox_states_with_one_lrd(tmp_path, lib):
    """Four drives that answer a mailbox request after the table's 1.749 ms: while the
    PDO-assignment SDOs wait, the master reads the area with one LRD for all drives, and
    no SM1 status byte; without MailboxStates in the ENI it polls SM1's status byte
    (the fallback), and both reach OP."""
    plan = drives_plan(lib, 4)
    seen = {}
    for name, p in (("bits", plan), ("fallback", _without_area(plan))):
        pcap = tmp_path / f"{name}.pcap"
        with Network.virtual(p, esi=[ESI], timing=Timing(), pcap=pcap) as net:
            net.up()
            assert [s.state for s in net.segment.slaves] == [AlState.OP] * 4
        seen[name] = _status_polls(_datagrams(pcap))
    fprd, lrd = seen["bits"]
    assert fprd == 0 and lrd > 0, seen
    fprd, lrd = seen["fallback"]
    assert fprd > 0 and lrd == 0, seen


def _without_area(plan: NetworkPlan) -> NetworkPlan:
    out = copy.deepcopy(plan)
    out.master.mailbox_states = None
    return out


def _between_cycles(frames: list[list[Datagram]]) -> tuple[int, int, int]:
    """In frames that are not the cyclic frame (no BRD of the AL status): (LRDs of the area,
    FPRDs of SM1's status byte, reads of SM1 at 0x1080)."""
    lrd = fprd = sm1 = 0
    for f in frames:
        if any(d.cmd == Cmd.BRD and d.ado == 0x0130 for d in f):
            continue
        lrd += sum(1 for d in f if d.cmd == Cmd.LRD and d.address == AREA)
        fprd += sum(1 for d in f if d.cmd == Cmd.FPRD and d.ado == 0x080D and len(d.data) == 1)
        sm1 += sum(1 for d in f if d.cmd == Cmd.FPRD and d.ado == 0x1080)
    return lrd, fprd, sm1


def test_in_op_the_cyclic_frame_polls_the_mailboxes_of_a_drive_brought_back(tmp_path, lib):
    """A drive power-cycled in OP is configured again between the cycles, its 9 PDO-
    assignment SDOs answered after 1.749 ms each: the cyclic frame's LRD of the area
    (1 ms cycle) tells the master when to read SM1, and no poll of any kind goes between
    the cycles; without MailboxStates the master polls SM1's status byte there."""
    plan = drives_plan(lib, 2)
    seen = {}
    for name, p in (("bits", plan), ("fallback", _without_area(plan))):
        pcap = tmp_path / f"{name}.pcap"
        with Network.virtual(p, esi=[ESI], timing=Timing(), pcap=pcap) as net:
            net.up()
            for _ in range(50):
                net.cycle()
                net.clock.sleep(0.001)
            before = net.master.transport.counters.frames_sent
            net.segment.remove_cable("axis1")
            net.segment.power_cycle("axis1")
            for _ in range(20):
                net.cycle()
                net.clock.sleep(0.001)
            assert not net.online("axis1")
            net.segment.restore_cable("axis1")
            for _ in range(3000):
                net.cycle()
                net.clock.sleep(0.001)
                if net.online("axis1"):
                    break
            assert net.online("axis1")
            assert [s.state for s in net.segment.slaves] == [AlState.OP] * 2
            after = net.master.transport.counters.frames_sent
        # Both directions are recorded: the master's frames are every other one.
        seen[name] = _between_cycles(_datagrams(pcap)[before:after])
    lrd, fprd, sm1 = seen["bits"]
    assert (lrd, fprd) == (0, 0) and sm1 >= 9, seen
    lrd, fprd, sm1 = seen["fallback"]
    assert lrd == 0 and fprd > 0 and sm1 >= 9, seen


def test_a_bit_the_area_does_not_hold_is_polled_through_sm1_status(tmp_path, lib):
    """axis1's StatusBitAddr set to axis0's bit (ENI122: two slaves on one bit, which
    cannot tell whose mailbox is full): neither bit is trusted, apply polls both drives'
    SM1 status bytes, and the line reaches OP."""
    plan = drives_plan(lib, 2)
    bad = copy.deepcopy(plan)
    axis1 = bad.slaves[1]
    assert axis1.mailbox is not None
    axis1.mailbox.status_bit_addr = 0
    assert state_bits(bad)[0] == []
    pcap = tmp_path / "bad.pcap"
    with Network.virtual(bad, esi=[ESI], timing=Timing(), pcap=pcap) as net:
        net.up()
        assert [s.state for s in net.segment.slaves] == [AlState.OP] * 2
    fprd, lrd = _status_polls(_datagrams(pcap))
    assert fprd > 0 and lrd == 0
