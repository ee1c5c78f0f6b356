"""Minimal inputs of the crash classes the fuzz harness found (docs/fuzzing.md), each now a
located error or handled as real hardware does.

ENI inputs are written as the harness reports them: ``Mutant('eni', seed, edits)`` is the
ENI compiled from a seed topology of ``tests/fuzzing.py`` with one value changed; the line
an error must name is found in the mutated text independently of the reader.
"""

from __future__ import annotations

import struct

import pytest

import fuzzing
from ecatcfg.cli import main
from ecatcfg.compiler import topology
from ecatcfg.eni import reader
from ecatcfg.eni.reader import EniReadError
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState, Cmd
from ecatcfg.runtime import wire
from ecatcfg.runtime.master.replay import ApplyError
from ecatcfg.runtime.segment.slave import MEMORY_SIZE
from ecatcfg.runtime.wire import Datagram

TOPOLOGY = "master: {name: m}\nslaves:\n  - {name: a, device: EX1004}\n"


# -- 1. topology: explicit tags that do not parse, integers too long to convert -----------

@pytest.mark.parametrize("value, kind", [
    ("!!float abc", "float"), ("!!timestamp 2001-13-45", "timestamp"), ("!!int zz", "int"),
    ("!!bool 0", "bool"), ("!!timestamp 0", "timestamp"), ("1" * 4301, "int"),
    ("!!int", "int"), ("!!int #x0", "int"),  # empty text (PyYAML: IndexError), long campaign
    ("2001-13-45", "timestamp"),            # no tag: YAML reads it as a date all the same
    # Hex: few decimal digits in the text, over 4300 in the value (compiler --mutations
    # huge-numbers: pydantic's message about it failed to show it).
    pytest.param("0x" + "A" * 3600, "int", id="hex-3600-letters"),
    pytest.param("-0x" + "1A" * 1800, "int", id="negative-hex-3600-digits"),
])
def test_topology_scalar_that_does_not_construct(value, kind):
    text = TOPOLOGY + f"  - name: b\n    device: EX1004\n    station_address: {value}\n"
    with pytest.raises(EcatcfgError) as err:
        topology.loads(text, "t.yaml")
    assert (err.value.file, err.value.line, err.value.column) == ("t.yaml", 6, 22)
    assert f"is not a valid {kind}" in err.value.message


def test_topology_scalar_error_is_exit_1_without_traceback(tmp_path, capsys):
    path = tmp_path / "t.yaml"
    path.write_text(TOPOLOGY + "  - {name: b, device: !!float abc}\n")
    code = main(["compile", str(path), "--esi", str(fuzzing.ESI_DIR),
                 "-o", str(tmp_path / "x.eni.xml")])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert f"{path}:4:" in err and "'abc' is not a valid float" in err
    assert "4301 digits, more than Python converts" in str(pytest.raises(
        EcatcfgError, topology.loads, TOPOLOGY + "  - {name: " + "1" * 4301 + "}", "t").value)


def test_topology_bytes_and_characters_yaml_refuses_have_a_line():
    with pytest.raises(EcatcfgError) as err:
        topology.loads(TOPOLOGY.encode() + b"  - {name: \xa3}\n", "t.yaml")
    assert (err.value.line, err.value.message) == (4, "not UTF-8 text (byte 67)")
    with pytest.raises(EcatcfgError) as err:
        topology.loads(TOPOLOGY + "  - {name: \x1f}\n", "t.yaml")
    assert (err.value.line, err.value.column) == (4, 12)
    assert "U+001F" in err.value.message


# -- 2.-4. ENI values the wire cannot carry: errors at their line ------------------------

def line_of(data: bytes, group: str, index: int) -> int:
    """The line of the index-th ``Parent/Tag`` value, found by the harness's text scan
    (regular expressions over the bytes, not the reader)."""
    start, _ = dict(fuzzing.xml_spans(data).groups)[group][index]
    return data.count(b"\n", 0, start) + 1


@pytest.mark.parametrize("seed, group, index, value, message", [
    (1, "InitCmd/Cmd", 1, "32768", "<Cmd> 32768 is out of range: one byte (0..255)"),  # 2.
    (0, "InitCmd/Cmd", 0, "256", "<Cmd> 256 is out of range"),
    (0, "InitCmd/Index", 0, "-227", "<Index> -227 is out of range: 16 bits"),          # 3.
    (0, "InitCmd/Index", 0, "65536", "<Index> 65536 is out of range"),
    (0, "InitCmd/SubIndex", 0, "256", "<SubIndex> 256 is out of range: one byte"),
    (0, "InitCmd/SubIndex", 0, "-1", "<SubIndex> -1 is out of range"),
    (1, "Cmd/DataLength", 0, "-1", "<DataLength> -1 is out of range"),                # 4.
    (1, "InitCmd/DataLength", 1, "5407", "<DataLength> 5407 is out of range: what one "
                                          "datagram carries (0..1486)"),
    (0, "InitCmd/Adp", 3, "65536", "<Adp> 65536 is out of range"),
    (0, "InitCmd/Ado", 3, "-1", "<Ado> -1 is out of range"),
    (0, "Cmd/InputOffs", 0, "4294967296", "<InputOffs> 4294967296 is out of range"),
    (0, "Variable/BitSize", 0, "0", "<BitSize> 0 is out of range"),
    (0, "Send/Length", 0, "-1172", "<Length> -1172 is out of range"),
    # accepted before and wrapped or kept as nonsense: a station address of 70000 became
    # 4464, a negative working counter could never match
    (0, "Info/PhysAddr", 0, "70000", "<PhysAddr> 70000 is out of range: 16 bits"),
    (0, "Cmd/Cnt", 0, "-1", "<Cnt> -1 is out of range: 16 bits"),
    (0, "DC/CycleTime0", 0, "4294967296", "<CycleTime0> 4294967296 is out of range: 32 bits"),
    (0, "Inputs/ByteSize", 0, "-1", "<ByteSize> -1 is out of range"),
])
def test_eni_value_out_of_range_is_an_error_at_its_line(seed, group, index, value, message):
    data = fuzzing.Mutant("eni", seed, (("value", group, index, value),)).data()
    with pytest.raises(EniReadError) as err:
        reader.read_bytes(data, "x.eni.xml")
    assert err.value.file == "x.eni.xml"
    assert err.value.line == line_of(data, group, index)
    assert err.value.message.startswith(message)


def test_cyclic_frame_larger_than_an_ethernet_frame():
    """Long campaign: two cyclic commands of one Frame, 494 + 1486 data bytes, each one a
    datagram of allowed size but together more than one frame carries (the frame encoder's
    unlocated FrameError at the first cycle).  Refused at the Frame's line."""
    data = fuzzing.Mutant("eni", 0, (("value", "Cmd/DataLength", 0, "494"),
                                     ("value", "Cmd/DataLength", 1, "1486"))).data()
    with pytest.raises(EniReadError) as err:
        reader.read_bytes(data, "x.eni.xml")
    assert err.value.line == data.count(b"\n", 0, data.index(b"<Frame>")) + 1
    # ARMW 494 (was 4), LRD 1486 (was 1), the LRW's 18 and the BRD's 2, with 12 bytes of
    # header and WKC each, after the 2-byte EtherCAT header:
    # 2 + 494 + 1486 + 18 + 2 + 4 * 12 = 2050, in a payload of 1500
    assert err.value.message == ("<Frame> of 4 commands needs 2050 bytes, more than one "
                                 "Ethernet frame carries (1500)")


def test_eni_signed_spellings_still_read():
    """xs:int fields may spell an unsigned value signed (TwinCAT: AutoIncAddr -1)."""
    data = fuzzing.Mutant("eni", 0, (("value", "InitCmd/Adp", 0, "-1"),
                                     ("value", "Info/VendorId", 0, "-1"))).data()
    plan = reader.read_bytes(data, "x.eni.xml")
    assert plan.slaves[0].vendor_id == 0xFFFFFFFF
    assert next(c.adp for s in plan.slaves for c in s.init_cmds if c.adp is not None) \
        in (0, 0xFFFF)


def test_eni_apply_of_cmd_above_255_is_exit_1(tmp_path, capsys):
    data = fuzzing.Mutant("eni", 1, (("value", "InitCmd/Cmd", 1, "32768"),)).data()
    path = tmp_path / "x.eni.xml"
    path.write_bytes(data)
    code = main(["apply", str(path), "--virtual", "--esi", str(fuzzing.ESI_DIR),
                 "--no-cache"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert f"{path}:{line_of(data, 'InitCmd/Cmd', 1)}: <Cmd> 32768 is out of range" in err


def test_sm1_read_shorter_than_the_sm_does_not_hang_the_master():
    """Long campaign: ``Recv/Length`` 16 where SM1 is 128 bytes.  Reading fewer bytes than
    the SM never empties it, so the slave shows its previous message for ever; the master
    skipped such repeats without looking at its deadline (6 minutes, then by chance)."""
    data = fuzzing.Mutant("eni", 0, (("value", "Recv/Length", 0, "16"),)).data()
    plan = reader.read_bytes(data, "x.eni.xml")
    with fuzzing.watchdog(5.0), pytest.raises(ApplyError) as err:
        fuzzing.apply_plan(plan)
    assert err.value.slave == "axis1" and "no mailbox response in time" in err.value.message


def test_mailbox_too_small_for_an_sdo_names_slave_and_command():
    data = fuzzing.Mutant("eni", 1, (("value", "Send/Length", 0, "1"),)).data()
    plan = reader.read_bytes(data, "x.eni.xml")
    with pytest.raises(ApplyError) as err:
        fuzzing.apply_plan(plan)
    assert err.value.slave == "drive" and err.value.command
    assert "the mailbox cannot carry this SDO" in err.value.message


# -- 5. frames from the wire against a line in OP ---------------------------------------

def frame(*dgs: Datagram) -> bytes:
    return wire.encode(list(dgs))


def status(segment, position: int) -> tuple[int, int]:
    mem = segment.slaves[position].mem
    return struct.unpack_from("<H", mem, 0x0130)[0], struct.unpack_from("<H", mem, 0x0134)[0]


def test_sm1_moved_over_the_registers_with_repeat_request_in_op():
    """65 bytes broadcast over 0x0800..: SM0 cleared, SM1 a mailbox-in at 0x0130 with the
    repeat request toggled; then an AL control request of state 0.  The firmware used to
    post its last reply there, over AL status (``0 is not a valid AlState``); it checks its
    mailbox on every SM change in PREOP and above instead (SOES ESC_sm_act_event ->
    ESC_checkmbx) and falls back to INIT with error 0x0016."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])      # in (1001), drive (1002)
    junk = bytes(8) + struct.pack("<HHBBBB", 0x0130, 128, 0x22, 0, 0x03, 0) + bytes(49)
    back = wire.decode(segment.process(frame(Datagram.physical(Cmd.BWR, 0, 0x0800, junk))))
    assert back.datagrams[0].wkc == 2
    assert status(segment, 1) == (AlState.INIT | 0x10, 0x0016)     # the drive: mailbox
    assert status(segment, 0) == (AlState.OP, 0)                   # the I/O has none
    back = wire.decode(segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0120,
                                                               b"\x00\x00"))))
    assert back.datagrams[0].wkc == 1
    # An unacknowledged error: the request is ignored (SOES, KickCAT).
    assert status(segment, 1) == (AlState.INIT | 0x10, 0x0016)
    assert all(len(s.mem) == MEMORY_SIZE for s in segment.slaves)


def test_minimal_frame_sm0_made_a_mailbox_in_over_al_status():
    """The harness's minimal input, one frame: BWR of 8 bytes at 0x0800 making SM0 a
    mailbox-in at 0x0130 of 128 bytes, enabled, repeat requested (crashed with
    ``10 is not a valid AlState``)."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[0])      # coupler .. axis1 (1005)
    image = struct.pack("<HHBBBB", 0x0130, 0x0080, 0x22, 0, 0x03, 0)
    back = wire.decode(segment.process(frame(Datagram.physical(Cmd.BWR, 0, 0x0800, image))))
    assert back.datagrams[0].wkc == 5
    assert status(segment, 4) == (AlState.INIT | 0x10, 0x0016)      # axis1: mailbox broken
    assert [status(segment, i) for i in range(4)] == [(AlState.OP, 0)] * 4    # no mailbox


def test_requested_state_that_is_no_state():
    """AL control 0 (or 5, 6, 7, 9..15) is not a state: 0x0012 'unknown requested state',
    OP falls back to SAFEOP (SOES ESC_state, default branch)."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0120, b"\x00\x00")))
    assert status(segment, 1) == (AlState.SAFEOP | 0x10, 0x0012)


def test_sm1_moved_past_the_end_of_memory():
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    image = struct.pack("<HHBBBB", 0xFFF0, 0xFFFF, 0x22, 0, 0x03, 0)
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0808, image)))
    assert status(segment, 1) == (AlState.INIT | 0x10, 0x0016)
    assert len(segment.slaves[1].mem) == MEMORY_SIZE


def test_repeat_request_on_the_real_sm1_still_reposts():
    """The fix leaves the mailbox repeat alone: toggling SM1's repeat bit in OP posts the
    last reply again at 0x1080 and acknowledges in 0x080F."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    drive = segment.slaves[1]
    assert drive.last_mailbox is not None
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x080E, b"\x03")))
    assert drive.state == AlState.OP and drive.mem[0x080F] & 0x02
    assert bytes(drive.mem[0x1080:0x1080 + len(drive.last_mailbox)]) == drive.last_mailbox
    assert drive.mem[0x080D] & 0x08                                 # SM1 full


@pytest.mark.parametrize("physical, bit", [(0xFFFF, 0), (0xFFFF, 3)])
def test_fmmu_mapping_past_the_end_of_memory(physical, bit):
    """Long campaign: an FMMU whose physical area runs past 0xFFFF.  A logical datagram
    through it raised IndexError (bit-wise mapping) or grew the ESC's memory (byte-wise);
    the bytes past the last address are not there: not read, not written."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    drive = segment.slaves[1]
    fmmu = struct.pack("<IHBBHBBB3x", 0x100000, 8, 0, 7, physical, bit, 3, 1)
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0640, fmmu)))
    before = bytes(drive.mem[0xFFF0:])
    back = wire.decode(segment.process(frame(Datagram.logical(Cmd.LRW, 0x100000, b"\xaa" * 8))))
    assert back.datagrams[0].wkc == 3                     # read and written: 1 + 2
    assert len(drive.mem) == MEMORY_SIZE
    # Only the last byte (from ``bit`` on) was in reach: it took the frame's first bits.
    mask = (0xFF << bit) & 0xFF
    assert drive.mem[0xFFFF] & mask == (0xAA << bit) & mask
    assert bytes(drive.mem[0xFFF0:0xFFFF]) == before[:15]


# -- 6. ENI cross-references later code cannot use, numbers past str() ------------------

def _line(text: str, at: int) -> int:
    return text.count("\n", 0, at) + 1


def _nth(text: str, needle: str, n: int) -> int:
    at = -1
    for _ in range(n + 1):
        at = text.index(needle, at + 1)
    return at


def _sm2_twice() -> tuple[bytes, int]:
    """Seed 1 with the drive's ``<Sm2>`` block written twice in a row; the line of the
    second one, found by text search."""
    text = fuzzing.eni_seeds()[1].decode()
    first, end = text.index("<Sm2>"), text.index("</Sm2>") + len("</Sm2>")
    block = text[first:end]
    text = text[:end] + "\n        " + block + text[end:]
    return text.encode(), _line(text, _nth(text, "<Sm2>", 1))


def _output_past_image() -> tuple[bytes, int]:
    """Seed 1 with the last output variable (32 bits) moved to start at the last bit of the
    20-byte output image; the line of its ``<Variable>``."""
    text = fuzzing.eni_seeds()[1].decode()
    outputs = text.index("<Outputs>")
    assert "<ByteSize>20</ByteSize>" in text[outputs:outputs + 60]
    var = text.rindex("<Variable>")
    offs = text.index("<BitOffs>", var)
    close = text.index("</BitOffs>", offs)
    text = text[:offs] + "<BitOffs>159" + text[close:]
    return text.encode(), _line(text, var)


def test_sm_given_twice_is_an_error_at_the_second():
    """Fuzz class 'what the reader accepts and later code cannot use': two ``Sm2`` in one
    ``ProcessData`` were read, then the ENI writer refused them with a bare ValueError."""
    data, line = _sm2_twice()
    with pytest.raises(EniReadError) as err:
        reader.read_bytes(data, "x.eni.xml")
    assert (err.value.file, err.value.line) == ("x.eni.xml", line)
    assert err.value.message.startswith("<Sm2> given again (first at line ")


def test_pdo_described_twice_is_an_error_at_the_second():
    text = fuzzing.eni_seeds()[1].decode()
    first = text.index("<RxPdo")
    end = text.index("</RxPdo>", first) + len("</RxPdo>")
    text = text[:end] + "\n        " + text[first:end] + text[end:]
    with pytest.raises(EniReadError) as err:
        reader.read_bytes(text.encode(), "x.eni.xml")
    assert err.value.line == _line(text, _nth(text, "<RxPdo", 1))
    assert "described again (first at line " in err.value.message


def test_output_variable_past_the_image_is_an_error_at_its_line():
    """Was read, then ``net[var] = value`` raised BufferError in runtime/network.py."""
    data, line = _output_past_image()
    with pytest.raises(EniReadError) as err:
        reader.read_bytes(data, "x.eni.xml")
    assert err.value.line == line
    assert "ends at bit 191, past the Outputs image of <ByteSize> 20 (160 bits)" \
        in err.value.message
    # The last bit of the image is still a place for a 1-bit variable.
    text = data.decode().replace("<BitSize>32</BitSize>\n          <BitOffs>159",
                                 "<BitSize>1</BitSize>\n          <BitOffs>159")
    assert "<BitOffs>159" in text and text != data.decode()
    assert reader.read_bytes(text.encode(), "x.eni.xml").process_image.outputs[-1].bit_offs \
        == 159


@pytest.mark.parametrize("digits", ["0x" + "f" * 4000, "-0x" + "1" * 4000],
                         ids=["hex", "negative-hex"])
def test_number_of_thousands_of_digits_is_an_error_at_its_line(digits):
    """``<Ado>`` of 4,000 hex digits: the bounds check's own message raised Python's
    4,300-digit ValueError."""
    data = fuzzing.Mutant("eni", 0, (("value", "InitCmd/Ado", 3, digits),)).data()
    with pytest.raises(EniReadError) as err:
        reader.read_bytes(data, "x.eni.xml")
    assert err.value.line == line_of(data, "InitCmd/Ado", 3)
    assert err.value.message.startswith("<Ado> ")
    assert "bits) is out of range: 16 bits (0..65535)" in err.value.message
    assert len(err.value.message) < 200


def test_huge_negative_max_frame_size_is_reported_not_a_crash():
    text = fuzzing.eni_seeds()[0].decode()
    text = text.replace("</Info>", "</Info>\n      <MaxFrameSize>-0x" + "1" * 4000
                        + "</MaxFrameSize>", 1)
    plan = reader.read_bytes(text.encode(), "x.eni.xml")
    found = [u for u in plan.unsupported if "MaxFrameSize" in u.what]
    assert found and "a negative frame size" in found[0].what, plan.unsupported


@pytest.mark.parametrize("make, message", [
    (_sm2_twice, "<Sm2> given again"),
    (_output_past_image, "past the Outputs image"),
    (lambda: (fuzzing.Mutant("eni", 1, (("value", "InitCmd/Ado", 0, "0x" + "f" * 4000),)
                             ).data(), None), "is out of range: 16 bits"),
], ids=["sm-twice", "output-past-image", "huge-ado"])
def test_eni_cross_reference_errors_at_apply_are_exit_1(tmp_path, capsys, make, message):
    data, line = make()
    if line is None:
        line = line_of(data, "InitCmd/Ado", 0)
    path = tmp_path / "x.eni.xml"
    path.write_bytes(data)
    code = main(["apply", str(path), "--virtual", "--esi", str(fuzzing.ESI_DIR),
                 "--no-cache", "--cycles", "3"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert f"{path}:{line}: " in err and message in err


def test_fmmu_cannot_write_al_status():
    """Fuzz class 'assert as error handling': an FMMU write-mapping logical memory onto AL
    status (0x0130), an LWR of 0 there, then an AL control write tripped ``assert`` in the
    firmware's state machine.  AL status is read-only for EtherCAT whatever the command
    (an FMMU only translates the address): it keeps OP, the LWR still counts (the ESC
    answers a write to a read-only register), and the AL control request runs as usual."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    fmmu = struct.pack("<IHBBHBBB3x", 0x200000, 2, 0, 7, 0x0130, 0, 2, 1)   # write, on
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0660, fmmu)))
    back = wire.decode(segment.process(frame(Datagram.logical(Cmd.LWR, 0x200000,
                                                              b"\x00\x00"))))
    assert back.datagrams[0].wkc == 1
    assert status(segment, 1) == (AlState.OP, 0)
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0120, b"\x02\x00")))
    assert status(segment, 1) == (AlState.PREOP, 0)


def test_fmmu_writing_al_control_requests_a_state():
    """The other side of the same rule: a writable register written through an FMMU acts
    as a physical write does; AL control 0x0120 mapped and written with PREOP."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    fmmu = struct.pack("<IHBBHBBB3x", 0x200000, 2, 0, 7, 0x0120, 0, 2, 1)
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0660, fmmu)))
    segment.process(frame(Datagram.logical(Cmd.LWR, 0x200000, b"\x02\x00")))
    assert status(segment, 1) == (AlState.PREOP, 0)
    assert status(segment, 0) == (AlState.OP, 0)


def test_al_status_holding_no_state_starts_over_from_init():
    """Only reachable by tampering with the memory (AL status is read-only from the wire
    and the firmware sets states only): an AL control request then makes the firmware
    start over from INIT with 0x0012 instead of failing."""
    segment = fuzzing.line_in_op(fuzzing.eni_seeds()[1])
    segment.slaves[1].mem[0x0130] = 0
    segment.process(frame(Datagram.physical(Cmd.FPWR, 1002, 0x0120, b"\x02\x00")))
    assert status(segment, 1) == (AlState.INIT | 0x10, 0x0012)
