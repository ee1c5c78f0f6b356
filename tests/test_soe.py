"""SoE (servo drive profile over EtherCAT, ETG.1000.6 5.8), the runtime side: the codec
(``runtime/soe.py``), IDN text (``esi/idn.py``), the emulated drive's IDN store and its
refusal of SAFEOP (``runtime/segment/soe_server.py``), the master's client and the replay of
a plan's SoE InitCmds (``runtime/master/soe_client.py``), ``ecatcfg soe`` and the wire as
tshark dissects it.

Expected bytes are written out by hand from the header layout SOEM (``ethercatsoe.c``
``ec_SoEt``) and Wireshark (``packet-ecatmb.c``) give; the device is the self-written
fixture ``tests/fixtures/soe/soe_drive_rt.xml`` (two drives, SoE only).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from rig import serving, soe_messages, start_simulate, tshark_malformed
# The mailbox that takes every SM0 write and answers from a list: test_eoe's.
from test_eoe import CHANNEL_PLAN
from test_eoe import drive as drive_job

from ecatcfg.compiler import build, topology
from ecatcfg.eni.plan import MailboxArea, MailboxPlan, NetworkPlan, SoeInitCmd
from ecatcfg.esc import AlState, AlStatusCode, Transition
from ecatcfg.esi.library import Library
from ecatcfg.esi.reader import read_file
from ecatcfg.esi.idn import idn_text, parse_idn
from ecatcfg.runtime import Network
from ecatcfg.runtime.link import MemoryLink
from ecatcfg.runtime.mailbox import (MailboxProtocolError, MbxType, decode, encode_emergency,
                                     encode_mailbox, encode_mailbox_error, pad_to)
from ecatcfg.runtime.master import soe_tool
from ecatcfg.runtime.master.replay import ApplyError, MailboxChannel
from ecatcfg.runtime.master.soe_client import SoeTransfer, soe_init_cmd_job
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.segment.soe_server import Idn
from ecatcfg.runtime.segment.virtual import Faults
from ecatcfg.runtime.soe import (ATTR_TYPE_HEX, ATTR_TYPE_IDN, ATTR_TYPE_INT, ELEMENT_ATTRIBUTE,
                                 ELEMENT_NAME, ELEMENT_UNIT, ELEMENT_VALUE, Reassembly,
                                 SoeOpCode, attribute, attribute_element_size, decode_list,
                                 decode_soe, encode_fragments, encode_soe, fragment_sizes,
                                 soe_error_name)

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = ROOT / "tests" / "fixtures" / "soe" / "soe_drive_rt.xml"
TOPOLOGY = "slaves:\n  - {name: axis, device: EXS5102}\n"
S1, S2, S11, S17, S18, S21, S30, S32, P10 = 1, 2, 11, 17, 18, 21, 30, 32, 0x800A


# --------------------------------------------------------------------------- IDN text

@pytest.mark.parametrize("text, number", [
    ("S-0-0001", 1), ("P-0-0010", 0x800A), ("S-7-4095", 0x7FFF), ("P-7-4095", 0xFFFF),
    ("s-0-32", 32), ("32778", 0x800A), ("0x800A", 0x800A), ("#x0020", 32)])
def test_idn_text_and_numbers(text, number):
    assert parse_idn(text, numbers=True) == number
    if text[0].upper() in "SP":
        assert parse_idn(text) == number
    else:                          # a topology writes the notation only
        with pytest.raises(ValueError):
            parse_idn(text)
    if text[0] in "SP":
        assert idn_text(number) == text.upper()


def test_idn_text_that_is_not_an_idn():
    for bad in ("S-8-0001", "S-0-4096", "Q-0-0001", "65536", "S-0-", "x"):
        with pytest.raises(ValueError):
            parse_idn(bad, numbers=True)
    with pytest.raises(ValueError, match=r"'x' is not an IDN: write S-<set>-<number> or "
                       r"P-<set>-<number>, e.g. S-0-0001, P-0-0010$"):
        parse_idn("x")
    with pytest.raises(ValueError, match=r"e\.g\. S-0-0001, P-0-0010, or a 16-bit number$"):
        parse_idn("x", numbers=True)              # the command line takes numbers too
    for bad_number in (-1, 0x10000):
        with pytest.raises(ValueError, match="not a 16-bit number"):
            idn_text(bad_number)


def test_idn_zero_is_an_idn():
    # S-0-0000: the 16-bit number 0 is an IDN like any other (bits 15, 14:12, 11:0 all 0).
    assert idn_text(0) == "S-0-0000"
    assert parse_idn("0", numbers=True) == parse_idn("S-0-0000") == 0


# --------------------------------------------------------------------------- the codec

def test_the_header_bits():
    # mailbox: length 6, address 0, channel 0, type 5 with counter 3; SoE: opcode 3 (write
    # request), incomplete bit 3, error bit 4, drive 5 in bits 5-7; elements 0x40; IDN.
    message = encode_soe(SoeOpCode.WRITE_REQUEST, 0x800A, b"\xd0\x07", drive_no=5,
                         counter=3)
    assert message == bytes.fromhex("0600 0000 00 35" "a3 40 0a80" "d007".replace(" ", ""))
    flags = encode_soe(SoeOpCode.READ_RESPONSE, 7, drive_no=1, incomplete=True, error=True,
                       elements=0x04)
    assert flags[6:10] == bytes.fromhex("3a040700")       # 2 | 8 | 0x10 | 1 << 5
    header, content = decode(message)
    assert header.type == MbxType.SOE and isinstance(content, tuple)
    soe = decode_soe(content[1])
    assert (soe.op_code, soe.drive_no, soe.elements, soe.idn, soe.data, soe.incomplete,
            soe.error) == (3, 5, 0x40, 0x800A, b"\xd0\x07", False, False)
    error = decode_soe(bytes.fromhex("14400100" "0110"))   # write response, error 0x1001
    assert (error.op_code, error.error, error.error_code) == (4, True, 0x1001)
    assert soe_error_name(0x1001) == "no IDN"
    assert soe_error_name(0x800C) == "no element addressed"
    with pytest.raises(ValueError):
        encode_soe(SoeOpCode.READ_REQUEST, 1, drive_no=8)


def test_fragments_count_down_and_are_put_together():
    data = bytes(range(250))
    # A 128-byte mailbox carries 118 data bytes after the mailbox and SoE headers.
    messages = encode_fragments(SoeOpCode.WRITE_REQUEST, S30, data, 128, drive_no=1)
    parts = [decode_soe(decode(m)[1][1]) for m in messages]          # type: ignore[index]
    assert [(p.incomplete, p.idn, len(p.data)) for p in parts] == [
        (True, 2, 118), (True, 1, 118), (False, S30, 14)]
    assert all(len(m) <= 128 for m in messages)
    whole = Reassembly()
    assert [whole.add(p) for p in parts[:2]] == [None, None]
    assert whole.add(parts[2]) == data
    # An exact multiple of a fragment: the last full fragment is the last one.
    exact = encode_fragments(SoeOpCode.WRITE_REQUEST, S30, bytes(236), 128)
    assert [decode_soe(decode(m)[1][1]).idn for m in exact] == [1, S30]   # type: ignore[index]
    # Out of order: a fragment count that skips.
    broken = Reassembly()
    broken.add(parts[0])
    with pytest.raises(ValueError, match="fragments left"):
        broken.add(parts[2])
    assert len(encode_fragments(SoeOpCode.READ_RESPONSE, S1, b"", 16)) == 1


def test_the_attribute_word_bit_fields():
    # SOEM ethercatsoe.h ec_SoEattributet, least significant first: conversion factor 16
    # bits, length 2 (0: 1 byte .. 3: 8 bytes), list 1, command 1, data type 3, reserved 1,
    # decimals 4, write-protected in PREOP, SAFEOP, OP one bit each (28, 29, 30).
    assert attribute(4, ATTR_TYPE_INT, factor=1, wp_op=True) == 0x4022_0001
    assert attribute(2, ATTR_TYPE_HEX, is_list=True, factor=0, wp_safeop=True,
                     wp_op=True) == 0x6035_0000
    assert attribute(8, ATTR_TYPE_IDN, wp_preop=True) == 0x1053_0001
    with pytest.raises(ValueError, match="1, 2, 4 or 8 bytes, not 3"):
        attribute(3)


def test_malformed_lists_and_headers_are_named():
    # A list: current length 5, maximum 8, then 2 bytes (ETG.1000.6 / SOEM ec_SoElistt).
    with pytest.raises(ValueError, match="list of 2 bytes says current length 5, maximum 8"):
        decode_list(bytes.fromhex("0500 0800 6162".replace(" ", "")))
    with pytest.raises(MailboxProtocolError,
                       match="SoE message of 2 bytes is shorter than the 4-byte SoE header") \
            as short:
        decode_soe(bytes.fromhex("0140"))
    assert short.value.detail == 6                    # ETG.1000.4: size too short


def test_a_mailbox_without_room_for_soe_data_is_refused():
    # 6 bytes of mailbox header and 4 of SoE header: an 11-byte mailbox carries 1 data byte.
    assert fragment_sizes(3, 11) == [1, 1, 1]
    with pytest.raises(ValueError, match="a 10-byte mailbox cannot carry SoE data"):
        fragment_sizes(1, 10)


# --------------------------------------------------------------------------- the emulated drive

def fixture_device():
    [device] = read_file(FIXTURE).devices
    return device


class DriveBox:
    """The master's side of the emulated drive's mailbox, in memory."""

    def __init__(self, mbx: int = 128) -> None:
        self.slave = emulate.emulated_slave(emulate.SlaveSpec(fixture_device(), "axis"))
        self.mailbox = self.slave.mailbox
        self.mailbox.mbx_in_size = mbx
        self.mailbox.soe.mbx_in_size = mbx
        self.soe = self.mailbox.soe
        self.counter = 0

    def send(self, op: int, idn: int, data: bytes = b"", state: AlState = AlState.PREOP,
             **kw) -> list:
        self.counter = self.counter % 7 + 1
        message = encode_soe(op, idn, data, counter=self.counter, **kw)
        return [decode_soe(decode(r)[1][1]) for r in self.mailbox.handle(pad_to(message, 128),
                                                                          state)]

    def read(self, idn: int, **kw):
        [reply] = self.send(SoeOpCode.READ_REQUEST, idn, **kw)
        return reply

    def write(self, idn: int, data: bytes, **kw):
        return self.send(SoeOpCode.WRITE_REQUEST, idn, data, **kw)


def test_the_esi_gives_the_drives_and_their_required_idns():
    soe = DriveBox().soe
    assert len(soe.drives) == 2                                 # ChannelCount="2"
    first, second = soe.drives
    assert first.required == [S1, S2, S32] and second.required == [S1]
    assert {S1, S2, S11, S17, S18, S21, S30, S32, P10} <= set(first.idns)
    assert P10 not in second.idns                               # written on drive 0 only
    # S-0-0018 lists the required IDNs, as a Sercos list of 16-bit IDNs.
    items, _maximum = decode_list(first.idns[S18].value)
    assert items == bytes.fromhex("0100 0200 2000".replace(" ", ""))


def test_read_value_attribute_and_name():
    box = DriveBox()
    value = box.read(P10)
    assert (value.op_code, value.error, value.idn, value.data) == (2, False, P10, bytes(8))
    attribute = box.read(S11, elements=ELEMENT_ATTRIBUTE)
    word = int.from_bytes(attribute.data, "little")
    assert attribute_element_size(word) == 2 and word >> 28 & 0x7 == 0x7   # read-only
    name = box.read(S30, elements=ELEMENT_NAME)
    assert decode_list(name.data)[0] == b"Manufacturer version"
    # Several elements: in the order of their flag bits (name, attribute, value).
    both = box.read(S1, elements=ELEMENT_NAME | ELEMENT_ATTRIBUTE | ELEMENT_VALUE)
    assert both.data.endswith(bytes(2)) and b"NC cycle time" in both.data


@pytest.mark.parametrize("kw, code", [
    ({"idn": 0x0999}, 0x1001),                              # no such IDN
    ({"idn": S1, "drive_no": 2}, 0x800A),                   # ChannelCount 2: drives 0, 1
    ({"idn": S1, "elements": ELEMENT_UNIT}, 0x4001),        # no unit
    ({"idn": S1, "elements": 0}, 0x800C),                   # no element addressed
])
def test_read_errors(kw, code):
    reply = DriveBox().read(**kw)
    assert (reply.op_code, reply.error, reply.error_code) == (2, True, code)


def test_writes_are_stored_checked_and_logged():
    box = DriveBox()
    [ok] = box.write(S32, b"\x0b\x00")
    assert (ok.op_code, ok.error, ok.idn) == (SoeOpCode.WRITE_RESPONSE, False, S32)
    assert box.read(S32).data == b"\x0b\x00"
    cases = [((S11, b"\x01\x00"), {}, 0x7004),                      # read-only
             ((S1, b"\xd0\x07"), {"state": AlState.SAFEOP}, 0x7005),   # protected in SAFEOP
             ((S1, b"\xd0"), {}, 0x7002), ((S1, b"\xd0\x07\x00"), {}, 0x7003),
             ((0x0999, b"\x00"), {}, 0x1001),
             ((S1, b"\xd0\x07"), {"elements": ELEMENT_NAME}, 0x2004),
             ((S17, bytes(8)), {}, 0x7004)]
    for args, kw, code in cases:
        [reply] = box.write(*args, **kw)
        assert (reply.op_code, reply.error, reply.error_code) == (4, True, code), (args, kw)
    # A value larger than the mailbox, in fragments: only the last is answered.
    box.soe.drives[1].idns[0x0300] = Idn("long", 0, bytes(200))      # writable, 200 bytes
    long = bytes(range(200))
    replies = [box.mailbox.handle(pad_to(m[:5] + bytes([m[5] | (n + 1) << 4]) + m[6:], 128),
                                  AlState.PREOP)
               for n, m in enumerate(encode_fragments(SoeOpCode.WRITE_REQUEST, 0x0300, long,
                                                      128, drive_no=1))]
    assert [len(r) for r in replies] == [0, 1]
    assert box.soe.drives[1].idns[0x0300].value == long
    assert box.soe.drives[0].log == [(S32, b"\x0b\x00")]
    assert box.soe.drives[1].log == [(0x0300, long)]


def test_an_esi_list_idn_takes_lists_up_to_its_maximum():
    from ecatcfg.esi.model import SoeInitCmd as EsiSoeInitCmd, SoeSettings, Source
    from ecatcfg.runtime.segment.soe_server import build_drives
    source = Source("x.xml", 1)
    # current length 6, maximum 8: a list of up to 8 bytes (10 bytes of data: not a number);
    # written in SO, so not required
    settings = SoeSettings(source, [EsiSoeInitCmd(["SO"], 0x8100, bytes.fromhex(
        "0600 0800 010203040506".replace(" ", "")), source)])
    [drive] = build_drives(settings)
    entry = drive.idns[0x8100]
    assert entry.is_list and entry.list_max == 8 and drive.required == []
    for data, code in ((bytes.fromhex("0600 0800 010203040506"), 0),
                       (bytes.fromhex("0a00 0800") + bytes(10), 0x7003),   # past the maximum
                       (bytes.fromhex("0400 0800 0102"), 0x7002),          # shorter than said
                       (bytes.fromhex("0200 0800 010203"), 0x7003),
                       (bytes.fromhex("0200"), 0x7002)):
        assert entry.write_error(data, AlState.OP) == code, data.hex()


def test_esi_idns_are_sized_by_the_data_their_init_cmds_write():
    from ecatcfg.esi.model import SoeInitCmd as EsiSoeInitCmd, SoeSettings, Source
    from ecatcfg.runtime.segment.soe_server import SoeServer
    source = Source("x.xml", 1)
    settings = SoeSettings(source, [
        EsiSoeInitCmd(["PS"], 0x8103, b"\x01\x00", source, channel=1),   # no drive 1: skipped
        EsiSoeInitCmd(["PS"], 0x8104, None, source),                   # no data: skipped
        EsiSoeInitCmd(["PS"], 0x8101, bytes.fromhex("01020304"), source),   # a UINT32
        EsiSoeInitCmd(["SO"], 0x8102, bytes.fromhex("010203"), source),     # 3 raw bytes
        EsiSoeInitCmd(["SO"], 0x8100, bytes.fromhex("0200 0400 0102".replace(" ", "")),
                      source)])                                        # a list of up to 4
    server = SoeServer(settings, 128)
    assert [d.required for d in server.drives] == [[0x8101]]

    def read(idn: int) -> bytes:
        # Read request (opcode 1), elements name | attribute | value (0x02 | 0x04 | 0x40).
        request = bytes([0x01, 0x46]) + idn.to_bytes(2, "little")
        [reply] = server.handle(request, AlState.PREOP)
        return reply

    # The attribute words, SOEM ec_SoEattributet: factor 1; length code 2 (4 bytes) or 0 (1
    # byte); bit 18 list; data type 1 (unsigned) or 0 (binary) in bits 20-22; an IDN written
    # in PS is write-protected in SAFEOP and OP (bits 29, 30).
    name = b"\x0e\x00\x0e\x00(from the ESI)"
    for idn, attribute_word, value in ((0x8101, "01001260", "00000000"),
                                       (0x8102, "01000000", "000000"),
                                       (0x8100, "01000400", "00000400")):
        body = bytes([0x02, 0x46]) + idn.to_bytes(2, "little") + name + \
            bytes.fromhex(attribute_word + value)
        # Mailbox header: length, address 0, channel 0, type 5 (SoE) with counter 0.
        assert read(idn) == len(body).to_bytes(2, "little") + bytes.fromhex("0000 00 05"
                                                                           .replace(" ", "")) \
            + body, hex(idn)


def test_the_standard_lists_and_the_version_before_any_state_change():
    box = DriveBox()
    # S-0-0021 (invalid operation data) before SAFEOP was ever asked: an empty list of at
    # most 128 bytes (current length 0, maximum 0x0080).
    assert box.read(S21).data == bytes.fromhex("0000 8000".replace(" ", ""))
    # S-0-0030, the manufacturer version: a list (bit 18) of 1-byte (length code 0) string
    # characters (data type 4, bits 20-22), read-only in PREOP, SAFEOP and OP (bits
    # 28-30), factor 1: SOEM ec_SoEattributet.
    word = box.read(S30, elements=ELEMENT_ATTRIBUTE).data
    assert word == (0x7044_0001).to_bytes(4, "little")


def test_a_fragment_out_of_turn_gets_the_general_error():
    box = DriveBox()
    # The first fragment says 2 more follow; the next is the last: one is missing.
    assert box.send(SoeOpCode.WRITE_REQUEST, 2, b"\x0b", incomplete=True) == []
    [reply] = box.write(S32, b"\x00")
    assert (reply.op_code, reply.error, reply.error_code) == (4, True, 0x800B)
    # The drive starts afresh: the next write is a whole one.
    [ok] = box.write(S32, b"\x0b\x00")
    assert (ok.op_code, ok.error) == (4, False)


def test_a_read_larger_than_sm1_comes_in_fragments():
    box = DriveBox(mbx=20)              # 10 data bytes per fragment
    replies = box.send(SoeOpCode.READ_REQUEST, S30)
    assert [r.incomplete for r in replies] == [True, True, False]
    assert [r.idn for r in replies] == [2, 1, S30]
    whole = Reassembly()
    for r in replies:
        got = whole.add(r)
    assert decode_list(got)[0] == b"ecatcfg emulated SoE drive"


def test_other_opcodes_and_short_messages_get_mailbox_errors():
    box = DriveBox()
    for data, detail in ((bytes.fromhex("024000"), 6),            # shorter than the header
                         (bytes.fromhex("05400100"), 4)):          # a notification
        [reply] = box.mailbox.handle(pad_to(encode_mailbox(MbxType.SOE, data, 1 + detail),
                                            128), AlState.PREOP)
        assert decode(reply)[1].detail == detail


def test_safeop_is_refused_until_the_required_idns_are_written():
    box = DriveBox()
    soe = box.soe
    assert soe.safeop_refusal() == [(0, [S1, S2, S32]), (1, [S1])]
    box.write(S1, b"\xd0\x07")
    box.write(S2, b"\xd0\x07")
    box.write(S32, b"\x0b\x00")
    assert soe.safeop_refusal() == [(1, [S1])]
    assert decode_list(soe.drives[1].idns[S21].value)[0] == b"\x01\x00"
    box.write(S1, b"\xd0\x07", drive_no=1)
    assert soe.safeop_refusal() == []
    assert decode_list(soe.drives[0].idns[S21].value)[0] == b""
    # A power cycle forgets what was written.
    box.slave.power_cycle()
    assert box.slave.mailbox.soe.safeop_refusal()[0] == (0, [S1, S2, S32])


def test_the_real_ax5000_esi_makes_a_drive(corpus_extra):
    """A vendor's SoE drive (Beckhoff AX5xxx, corpus-extra): the IDNs its ESI writes in PS
    are required, and the feature flags written in IP are not."""
    esi = read_file(corpus_extra / "esi" / "dls" / "Beckhoff AX5xxx.xml")
    device = next(d for d in esi.devices if d.mailbox is not None and d.mailbox.soe
                  is not None and d.mailbox.soe.init_cmds)
    slave = emulate.emulated_slave(emulate.SlaveSpec(device, "ax"))
    drive = slave.mailbox.soe.drives[0]
    assert drive.required == [S1, S2, S32]
    assert P10 in drive.idns and P10 not in drive.required
    assert len(drive.idns[P10].value) == 8


# --------------------------------------------------------------------------- the master's client



def init_job(cmd: SoeInitCmd, plan: MailboxPlan = CHANNEL_PLAN):
    return soe_init_cmd_job(MailboxChannel(0x1001, plan), cmd, "axis", "PS")


WRITTEN = bytes.fromhex("0400 0000 00 25" "04 40 0100".replace(" ", ""))   # write response


def test_the_master_writes_in_fragments_and_waits_for_one_answer():
    cmd = SoeInitCmd([Transition.PS], "big", S1, bytes(range(250)), drive_no=3)
    stale_read = bytes.fromhex("0600 0000 00 35" "62 40 0100 d007".replace(" ", ""))
    written = drive_job(init_job(cmd), [encode_emergency(0x8700, 1, counter=1), stale_read,
                                        bytes.fromhex("0400 0000 00 45" "64 40 0100"
                                                      .replace(" ", ""))])
    assert len(written) == 3 and all(len(w) == 128 for w in written)
    # counters 1, 2, 3; opcode 3 with drive 3, incomplete in all but the last
    assert [(w[5] >> 4, w[6], int.from_bytes(w[8:10], "little")) for w in written] == [
        (1, 0x6B, 2), (2, 0x6B, 1), (3, 0x63, S1)]
    assert b"".join(w[10:10 + int.from_bytes(w[:2], "little") - 4] for w in written) == \
        bytes(range(250))


@pytest.mark.parametrize("answer, message", [
    (bytes.fromhex("0600 0000 00 25" "14 40 0100 0470".replace(" ", "")),
     r"SoE error 0x7004 \(operation data cannot be changed \(read only\)\) writing "
     r"S-0-0001 of drive 0 \(transition PS\)"),
    # SOEM takes an error reply with the read response opcode too
    (bytes.fromhex("0600 0000 00 25" "12 40 0100 0110".replace(" ", "")),
     r"SoE error 0x1001 \(no IDN\) writing S-0-0001"),
    (encode_mailbox_error(2, counter=2), r"mailbox error 2 \(unsupported protocol\)"),
    (bytes.fromhex("0400 0000 00 25" "04 40 0200".replace(" ", "")),
     r"response for S-0-0002"),
    (bytes.fromhex("0400 0000 00 23" "0000 0000".replace(" ", "")),
     r"mailbox type 3 where an SoE response"),
    # FoE (type 4): an ack of packet 0
    (bytes.fromhex("0600 0000 00 24" "0400 00000000".replace(" ", "")),
     r"mailbox type 4 where an SoE response"),
    # a write response with the Error bit and no code after the header
    (bytes.fromhex("0400 0000 00 25" "14 40 0100".replace(" ", "")),
     r"error reply with opcode 4 and no error code"),
])
def test_the_master_names_what_went_wrong(answer, message):
    cmd = SoeInitCmd([Transition.PS], "", S1, b"\xd0\x07")
    with pytest.raises(ApplyError, match=r"slave 'axis' \[SoE write S-0-0001 \(drive 0\)\]: .*"
                       + message):
        drive_job(init_job(cmd), [answer])


def test_an_emergency_and_a_stale_read_response_before_the_answer_are_set_aside():
    cmd = SoeInitCmd([Transition.PS], "", S1, b"\xd0\x07")
    # A CoE emergency (mailbox type 3, CoE header service 1 in bits 12-15, error code
    # 0x8700, error register 1, 5 bytes), a read response (opcode 2) left by an earlier
    # read, then the drive's refusal of the write: the refusal is the answer.
    emergency = bytes.fromhex("0a00 0000 00 13" "0010 0087 01 0000000000".replace(" ", ""))
    stale_read = bytes.fromhex("0600 0000 00 25" "02 40 0100 d007".replace(" ", ""))
    refusal = bytes.fromhex("0600 0000 00 35" "14 40 0100 0470".replace(" ", ""))
    with pytest.raises(ApplyError, match=r"SoE error 0x7004"):
        drive_job(init_job(cmd), [emergency, stale_read, refusal])


def test_an_init_cmd_the_master_cannot_send_is_refused_by_slave_and_transition():
    from ecatcfg.runtime.master.replay import SlaveProgress
    progress = SlaveProgress("axis")
    read = SoeInitCmd([Transition.PS], "", S1, b"", op_code=1)
    with pytest.raises(ApplyError, match=r"op code 1: only write requests .*\(transition "
                       r"PS\)") as refused:
        next(soe_init_cmd_job(MailboxChannel(0x1001, CHANNEL_PLAN), read, "axis", "PS",
                              progress))
    assert refused.value.slave == "axis"
    assert refused.value.command == progress.last_command == "SoE write S-0-0001 (drive 0)"
    # A 10-byte SM0 holds the mailbox and SoE headers and no data.
    small = MailboxPlan(MailboxArea(0x1000, 10), MailboxArea(0x1080, 128))
    with pytest.raises(ApplyError, match=r"slave 'axis' .*a 10-byte SM0 cannot carry an SoE "
                       r"request \(transition PS\)"):
        drive_job(init_job(SoeInitCmd([Transition.PS], "", S1, b"\xd0\x07"), small), [])


def test_the_master_writes_the_elements_it_was_given():
    # Elements 0x80 (the default value) and drive 2: byte 1 of the SoE header is the
    # element flags; byte 0 opcode 3 with the drive in bits 5-7 (0x43).
    [request] = SoeTransfer(S1, b"\xd0\x07", drive_no=2, elements=0x80).requests()
    assert request[6:12] == bytes.fromhex("43 80 0100 d007".replace(" ", ""))


def test_the_master_gives_up_after_the_timeout():
    cmd = SoeInitCmd([Transition.PS], "cycle", S1, b"\xd0\x07", timeout=30)
    with pytest.raises(ApplyError, match=r"\[cycle\]: no mailbox response in time "
                                         r"\(transition PS\)"):
        drive_job(init_job(cmd), [])
    assert len(drive_job(init_job(cmd), [WRITTEN])) == 1


def test_read_fragments_that_do_not_fit_together_fail():
    from ecatcfg.runtime.master.soe_client import soe_job
    channel = MailboxChannel(0x1001, CHANNEL_PLAN)
    parts = encode_fragments(SoeOpCode.READ_RESPONSE, S30, bytes(300), 128)
    stamped = [m[:5] + bytes([m[5] | (n + 1) << 4]) + m[6:] for n, m in enumerate(parts)]
    with pytest.raises(ApplyError, match=r"read response fragments: fragment with 0 "
                                         r"fragments left after one with 2"):
        drive_job(soe_job(channel, SoeTransfer(S30), "axis", "read"),
                  [stamped[0], stamped[2]])


def test_a_read_reassembles_the_fragments():
    t = SoeTransfer(S30, elements=ELEMENT_VALUE, drive_no=1)
    [request] = t.requests()
    assert request[6:10] == bytes.fromhex("21401e00")          # read request, drive 1
    parts = encode_fragments(SoeOpCode.READ_RESPONSE, S30, b"abcdefghijklmnopqrstu", 20,
                             drive_no=1)
    assert [t.on_response(p) for p in parts] == [False, False, True]
    assert t.result == b"abcdefghijklmnopqrstu"


# --------------------------------------------------------------------------- a plan up to OP

def esi_soe_cmds(drives: int = 2) -> list[SoeInitCmd]:
    """The fixture ESI's SoE InitCmds as a configurator puts them into an ENI."""
    device = fixture_device()
    return [SoeInitCmd([Transition[t] for t in c.transitions], c.comment or "", c.idn,
                       c.data, drive_no=c.channel)
            for c in device.mailbox.soe.init_cmds if c.channel < drives]


def soe_plan(cmds: list[SoeInitCmd]) -> NetworkPlan:
    """The fixture drive compiled, with ``cmds`` as its ``Mailbox/SoE/InitCmds``."""
    plan = build.compile_topology(topology.loads(TOPOLOGY, "t.yaml"),
                                  Library([FIXTURE], cache=False)).plan
    # The compiler's SoE support may add the ESI's InitCmds itself; this test sets its own.
    plan.slaves[0].mailbox.soe_init_cmds = list(cmds)
    plan.unsupported = [u for u in plan.unsupported if "SoE" not in str(u)]
    return plan


def test_a_plan_with_soe_init_cmds_reaches_op_with_every_idn_written_in_order(tmp_path):
    cmds = esi_soe_cmds() + [
        SoeInitCmd([Transition.PS], "long list", 0x0300, bytes(300), disabled=True),
        SoeInitCmd([Transition.SO], "flags again", P10, bytes(8))]
    seen: list[AlState] = []
    with Network.virtual(soe_plan(cmds), esi=[FIXTURE], pcap=tmp_path / "up.pcapng") as net:
        soe = net.segment.slaves[0].mailbox.soe
        handle = soe.handle
        soe.handle = lambda data, state: (seen.append(state), handle(data, state))[1]
        net.up()
        assert net.state == AlState.OP
        first, second = soe.drives
        assert first.log == [(P10, bytes.fromhex("FE7F000000000000")), (S1, b"\xd0\x07"),
                             (S2, b"\xd0\x07"), (S32, b"\x0b\x00"), (P10, bytes(8))]
        assert second.log == [(S1, b"\xd0\x07")]
        assert first.idns[S1].value == b"\xd0\x07"
        net.down()
    # IP once in PREOP, the four PS writes in PREOP (before the AL request), SO in SAFEOP.
    assert seen == [AlState.PREOP] * 5 + [AlState.SAFEOP]


def test_a_drive_emulated_from_the_plan_alone_takes_its_writes():
    """No ESI at hand: the drive has the IDNs the plan's SoE InitCmds write, on as many
    drives as they address (``eni_device.py``), and reaches OP."""
    with Network.virtual(soe_plan(esi_soe_cmds())) as net:
        net.up()
        assert net.state == AlState.OP
        first, second = net.segment.slaves[0].mailbox.soe.drives
        assert [idn for idn, _ in first.log] == [P10, S1, S2, S32]
        assert second.required == [S1] and [idn for idn, _ in second.log] == [S1]
        net.down()


def test_a_missing_required_idn_makes_the_drive_refuse_safeop():
    cmds = [c for c in esi_soe_cmds() if not (c.idn == S2 and c.drive_no == 0)]
    with Network.virtual(soe_plan(cmds), esi=[FIXTURE]) as net:
        with pytest.raises(ApplyError) as info:
            net.up()
        slave = net.segment.slaves[0]
        assert (slave.state, slave.status_code) == (AlState.PREOP, AlStatusCode.MBX_SOE)
        assert decode_list(slave.mailbox.soe.drives[0].idns[S21].value)[0] == b"\x02\x00"
    text = str(info.value)
    assert "slave 'axis'" in text and "PREOP+ERR" in text
    assert "AL status code 0x0045 (MBX_SOE)" in text
    assert "S-0-0021 of drive 0 lists S-0-0002" in text


def test_a_drive_error_names_the_slave_idn_drive_and_transition():
    cmds = esi_soe_cmds() + [SoeInitCmd([Transition.PS], "", S11, b"\x00\x00")]
    with Network.virtual(soe_plan(cmds), esi=[FIXTURE]) as net:
        with pytest.raises(ApplyError, match=r"slave 'axis' \[SoE write S-0-0011 \(drive 0\)"
                                             r"\]: SoE error 0x7004 .* writing S-0-0011 of "
                                             r"drive 0 \(transition PS\)"):
            net.up()


# --------------------------------------------------------------------------- tshark

def test_tshark_decodes_what_was_sent(tmp_path, tshark_path):
    """Our requests and the drive's replies, a fragmented write and a read answered in
    fragments among them, as Wireshark's EtherCAT mailbox dissector reads them: no
    malformed packet, and the opcode, drive, IDN (or fragments left) and data it decodes
    are what was sent."""
    pcap = tmp_path / "soe.pcapng"
    cmds = esi_soe_cmds() + [SoeInitCmd([Transition.PS], "long", S30, bytes(range(200)))]
    with Network.virtual(soe_plan(cmds), esi=[FIXTURE], pcap=pcap) as net:
        with pytest.raises(ApplyError, match="0x7004"):     # S-0-0030 is read-only
            net.up()
        # The drive stays in PREOP: a read whose answer comes in two fragments.
        net.segment.slaves[0].mailbox.soe.drives[0].idns[0x0300] = Idn("long", 0,
                                                                       bytes(range(200)))
        assert soe_tool.soe_transfer(net.master.transport, 0, 0x0300) == bytes(range(200))
    decoded = soe_messages(pcap)
    written = [(c.drive_no, c.idn, c.data) for c in cmds[:5]]
    expected = []
    for drive, idn, data in written:
        expected += [(3, drive, False, False, idn, data), (4, drive, False, False, idn, b"")]
    # 200 bytes through a 128-byte mailbox: 118 with one fragment left, then 82 and the IDN;
    # the drive answers once, with the error bit.  (Wireshark 4.0 shows the IDN word as
    # "SoE Error" too; the error code after the header is checked by hand-written bytes.)
    expected += [(3, 0, True, False, 1, bytes(range(118))),
                 (3, 0, False, False, S30, bytes(range(118, 200))),
                 (4, 0, False, True, S30, b""),
                 (1, 0, False, False, 0x0300, b""),
                 (2, 0, True, False, 1, bytes(range(118))),
                 (2, 0, False, False, 0x0300, bytes(range(118, 200)))]
    assert decoded == expected
    assert tshark_malformed(pcap) == []


# --------------------------------------------------------------------------- ecatcfg soe

@contextmanager
def memory_line(faults: Faults | None = None) -> Iterator[tuple[Transport, Any]]:
    lib = Library([FIXTURE], cache=False)
    seg = emulate.segment([emulate.SlaveSpec(lib.device(lib.find("EXS5102").entry), "axis")],
                          faults)
    ours, theirs = MemoryLink.pair()
    stop = threading.Event()
    thread = threading.Thread(target=seg.serve, args=(theirs,), kwargs={"stop": stop},
                              daemon=True)
    thread.start()
    try:
        yield Transport(ours), seg
    finally:
        stop.set()
        thread.join(5)


def test_the_tool_reads_and_writes_in_memory_over_a_lossy_link():
    with memory_line(Faults(drop=0.15, seed=4)) as (t, seg):
        for n in range(6):
            value = bytes([n, 0x07])
            soe_tool.soe_transfer(t, 0, S32, value, drive_no=n % 2)
            assert soe_tool.soe_transfer(t, 0, S32, drive_no=n % 2) == value
        name = soe_tool.soe_transfer(t, 0, S30, elements=ELEMENT_NAME)
        assert decode_list(name)[0] == b"Manufacturer version"
        with pytest.raises(soe_tool.SoeToolError, match=r"0x1001 \(no IDN\)") as info:
            soe_tool.soe_transfer(t, 0, 0x0999)
        assert info.value.soe_error == 0x1001
        # Values larger than the mailbox, both ways: lost SM0 writes are sent again and
        # dropped by the drive as repeats, lost SM1 reads asked for again.
        drive = seg.slaves[0].mailbox.soe.drives[1]
        drive.idns[0x0300] = Idn("long", 0, bytes(300))
        for n in range(4):
            value = bytes((n + i) % 256 for i in range(300))
            soe_tool.soe_transfer(t, 0, 0x0300, value, drive_no=1)
            assert soe_tool.soe_transfer(t, 0, 0x0300, drive_no=1) == value
        assert [len(v) for idn, v in drive.log if idn == 0x0300] == [300] * 4
        assert t.counters.frames_lost > 0


def ecatcfg_in(rig, *argv: str) -> subprocess.CompletedProcess:
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface",
                                 rig.if_a], timeout=30, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def test_soe_read_and_write_against_simulate(veth_netns, tmp_path):
    topo = tmp_path / "t.yaml"
    topo.write_text("slaves:\n  - {name: coupler, device: EXS5102}\n"
                    "  - {name: axis, device: EXS5102}\n")
    sim, lines = start_simulate(veth_netns, "--esi", str(FIXTURE), "--topology", str(topo))
    assert lines and lines[-1].startswith("ready: 2 slaves"), "".join(lines)
    wrote = ecatcfg_in(veth_netns, "soe", "write", "--slave", "1", "--drive", "1",
                       "S-0-0032", "11", "--type", "UINT")
    back = ecatcfg_in(veth_netns, "soe", "read", "--slave", "1", "--drive", "1", "S-0-0032",
                      "--type", "UINT", "--format", "json")
    text = ecatcfg_in(veth_netns, "soe", "read", "--slave", "1", "P-0-0010")
    name = ecatcfg_in(veth_netns, "soe", "read", "--slave", "1", "30", "--element", "name",
                      "--format", "json")
    attr = ecatcfg_in(veth_netns, "soe", "read", "--slave", "1", "S-0-0011", "--element",
                      "attribute", "--format", "json")
    missing = ecatcfg_in(veth_netns, "soe", "read", "--slave", "1", "S-0-0999")
    read_only = ecatcfg_in(veth_netns, "soe", "write", "--slave", "1", "S-0-0011", "0100")
    sim.terminate()
    sim.communicate(timeout=10)
    assert wrote.returncode == 0 and "S-0-0032 (drive 1) <- 0b 00" in wrote.stdout
    got = json.loads(back.stdout)
    assert (got["value"], got["hex"], got["idn"], got["drive"]) == (11, "0b00", 32, 1)
    assert text.returncode == 0 and "P-0-0010 (drive 0) value = 00 00 00 00 00 00 00 00" \
        in text.stdout
    assert json.loads(name.stdout)["name"] == "Manufacturer version"
    assert json.loads(attr.stdout)["attribute"]["write_protected"] == ["PREOP", "SAFEOP",
                                                                        "OP"]
    assert missing.returncode == 1 and "SoE error 0x1001 (no IDN) reading S-0-0999" \
        in missing.stderr
    assert read_only.returncode == 1 and "0x7004" in read_only.stderr


def test_soe_on_a_slave_without_soe_and_usage_errors(veth_netns):
    from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
    lib = Library([ROOT / "examples" / "esi"], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    with serving(veth_netns, seg):
        done = ecatcfg_in(veth_netns, "soe", "read", "--slave", "0", "S-0-0001")
    assert done.returncode == 1 and "does not support SoE" in done.stderr
    for argv, message in ((["read", "S-0-4096"], "0..4095"),
                          (["read", "S-0-0001", "--drive", "8"], "0..7"),
                          (["write", "S-0-0001", "0g"], "hexadecimal bytes"),
                          (["write", "S-0-0001", "70000", "--type", "UINT"], "UINT")):
        bad = subprocess.run([sys.executable, "-m", "ecatcfg", "soe", *argv, "--slave", "0",
                              "--iface", "no-such-if0"], capture_output=True, text=True,
                             timeout=30)
        assert bad.returncode == 2 and message in bad.stderr, (argv, bad.stderr)
