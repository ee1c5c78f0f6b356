"""FoE: the codec (``runtime/foe.py``), the master's transfers and session
(``runtime/master/foe_client.py``, ``foe_tool.py``), the emulated slave's FoE server and BOOT
state (``runtime/segment/foe_server.py``, ``slave.py``), and ``ecatcfg foe``.

Expected bytes are written out by hand from the FoE layout (ETG.1000.6; SOEM
``ethercatfoe.c``, SOES ``esc_foe.c``); packet counts from the fixture's mailbox sizes (the
bootstrap mailbox of EXF1000 is 0xF4 = 244 bytes: 232 file bytes per packet).  tshark
dissects the frames independently, and SOEM (pysoem) is a second, independent FoE master.
"""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rig import serving, start_simulate, tshark_fields, tshark_malformed

from ecatcfg.eni.plan import FoeInitCmd, MailboxArea, MailboxPlan
from ecatcfg.esc import AlState, Reg, SmConfig, Transition, sm_register
from ecatcfg.esi.library import Library
from ecatcfg.runtime import foe
from ecatcfg.runtime.link import MemoryLink
from ecatcfg.runtime.master import foe_tool, sdo_tool
from ecatcfg.runtime.master.foe_client import FoeRead, FoeTransferError, FoeWrite
from ecatcfg.runtime.master.foe_init import foe_init_cmd_job
from ecatcfg.runtime.master.replay import ApplyError, MailboxChannel
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.pcap import PcapRecorder
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "tests" / "fixtures" / "ecatcfg-EXF-foe.xml"
VENDOR, BOOT_PRODUCT, REVISION = 0xE0000ECA, 0xF100, 0x00010000
BOOT_MBX = 244                 # EXF1000 <BootStrap>0010F400F410F400: 0x00F4 each way
STD_MBX_EXF1001 = 64
PROBE = ROOT / "tests" / "soem_probe.py"


def firmware(revision: int, size: int = 5000, product: int = BOOT_PRODUCT) -> bytes:
    """A firmware file in the emulation's format (docs/runtime.md, FoE): b"ECFW", vendor,
    product, revision as UINT32 little-endian, then the image."""
    head = b"ECFW" + struct.pack("<III", VENDOR, product, revision)
    return head + bytes((i * 7 + 3) & 0xFF for i in range(size - len(head)))


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def build(lib: Library, *types: str) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(t).entry), f"s{i}", serial=0x40 + i)
                    for i, t in enumerate(types)])


@pytest.fixture
def line(lib) -> Iterator[tuple[VirtualSegment, Transport]]:
    """EXF1000 (boot loader), EXF1001 (FoE in PREOP only), EXF1002 (no FoE) in memory."""
    seg = build(lib, "EXF1000", "EXF1001", "EXF1002")
    a, b = MemoryLink.pair()
    stop = threading.Event()
    thread = threading.Thread(target=seg.serve, args=(b,), kwargs={"stop": stop},
                              daemon=True)
    thread.start()
    yield seg, Transport(a)
    stop.set()
    thread.join(2)


# --------------------------------------------------------------------------- the codec

def test_messages_encode_as_the_layout_says():
    assert foe.encode_foe(foe.FoeRequest(True, "app.efw", 0x12345678)) == \
        bytes.fromhex("0200" "78563412") + b"app.efw"
    assert foe.encode_foe(foe.FoeRequest(False, "a", 0)) == bytes.fromhex("0100 00000000 61")
    assert foe.encode_foe(foe.FoeData(3, b"\xAA\xBB")) == bytes.fromhex("0300 03000000 aabb")
    assert foe.encode_foe(foe.FoeAck(0x0102)) == bytes.fromhex("0400 02010000")
    assert foe.encode_foe(foe.FoeError(0x8001, "x")) == bytes.fromhex("0500 01800000 78")
    assert foe.encode_foe(foe.FoeBusy(3, 10)) == bytes.fromhex("0600 0300 0a00")
    # The mailbox header: length 6 + data, type 4 (FoE) with the counter in bits 4-6.
    assert foe.encode_foe_mailbox(foe.FoeAck(1), counter=2) == \
        bytes.fromhex("0600 0000 00 24" "0400 01000000")


def test_messages_decode_back():
    for message in (foe.FoeRequest(True, "fw.bin", 7), foe.FoeRequest(False, "", 0),
                    foe.FoeData(9, b"xyz"), foe.FoeData(1, b""), foe.FoeAck(0),
                    foe.FoeError(0x800A, "wrong password"), foe.FoeBusy(1, 2, "flash")):
        assert foe.decode_foe(foe.encode_foe(message)) == message
    with pytest.raises(foe.FoeDecodeError, match="header has 6"):
        foe.decode_foe(b"\x04\x00\x01")
    with pytest.raises(foe.FoeDecodeError, match="OpCode 7"):
        foe.decode_foe(bytes.fromhex("0700 00000000"))


def test_the_text_of_an_error_or_busy_ends_at_its_padding():
    # A slave pads its message with zeros (SOES fills the mailbox): the text is what comes
    # before them, its own spaces included.
    assert foe.decode_foe(bytes.fromhex("0600 0100 0200") + b"flash \x00\x00") == \
        foe.FoeBusy(1, 2, "flash ")
    assert foe.decode_foe(bytes.fromhex("0500 01800000") + b"no file \x00") == \
        foe.FoeError(0x8001, "no file ")


def test_error_codes_have_their_names():
    assert foe.foe_error_name(0x8001) == "not found"
    assert foe.foe_error_name(0x8003) == "disk full"
    assert foe.foe_error_name(0x800A) == "no rights"
    assert foe.foe_error_name(0x9999) == "vendor-specific or unknown code"
    assert foe.packet_data_size(BOOT_MBX) == 232


@settings(max_examples=300, database=None, deadline=None)
@given(st.binary(max_size=64), st.sampled_from([AlState.BOOT, AlState.PREOP]),
       st.sampled_from([16, 20, 64, 244]))
def test_any_bytes_get_an_answer_or_a_mailbox_error_from_the_server(data, state, size):
    """Whatever an FoE message holds, the emulated firmware answers with FoE messages that
    fit its SM1 or a mailbox error; it never breaks."""
    from ecatcfg.runtime.mailbox import MailboxProtocolError
    from ecatcfg.runtime.segment.foe_server import FoeServer
    server = FoeServer(VENDOR, BOOT_PRODUCT, bootstrap=True, disk_size=100)
    server.files["a"] = bytes(50)
    for message in (data, bytes([1, 0]) + bytes(4) + b"a", data):
        try:
            replies = server.handle(message, state, size, size)
        except MailboxProtocolError:
            continue
        for reply in replies:
            assert len(reply) <= size
            foe.decode_foe(reply[6:])


def test_the_server_refuses_in_the_bytes_of_an_foe_error():
    """Hand-written requests and the error replies they get, byte for byte: opcode 5, a
    reserved byte, the UINT32 code, the text (ETG.1000.6 FoE; SOES ``FOE_ERR_*``)."""
    from ecatcfg.runtime.segment.foe_server import FoeServer
    server = FoeServer(VENDOR, BOOT_PRODUCT, bootstrap=True)

    def reply(request: bytes, state: AlState) -> bytes:
        [answer] = server.handle(request, state, 128, 128)
        return answer

    def error(code: int, text: bytes) -> bytes:
        # Mailbox header: length, address 0, channel 0, type 4 (FoE) with counter 0.
        return struct.pack("<HHBB", 6 + len(text), 0, 0, 0x04) + \
            bytes.fromhex("0500") + struct.pack("<I", code) + text
    # A firmware file written outside BOOT on a device with a boot loader: 0x8009.
    assert reply(bytes.fromhex("0200 00000000") + b"app.efw", AlState.PREOP) == \
        error(0x8009, b"firmware is written in BOOT only")
    # Busy is the slave's to send (ETG.1000.6): from the master it is illegal, 0x8004.
    assert reply(bytes.fromhex("0600 0100 0200"), AlState.BOOT) == \
        error(0x8004, b"unexpected busy")
    # An ack or a data packet with no transfer going on: 0x8004 (illegal).
    assert reply(bytes.fromhex("0400 01000000"), AlState.BOOT) == \
        error(0x8004, b"ack without a read in progress")
    assert reply(bytes.fromhex("0300 01000000") + b"z", AlState.BOOT) == \
        error(0x8004, b"data without a write request")
    # Password 7, not the slave's 0: 0x800A (no rights).
    assert reply(bytes.fromhex("0100 07000000") + b"a", AlState.BOOT) == \
        error(0x800A, b"wrong password")
    # A write acknowledged with ack 0, then data packet 3 where 1 is due: 0x8005.
    assert reply(bytes.fromhex("0200 00000000") + b"b", AlState.BOOT) == \
        struct.pack("<HHBB", 6, 0, 0, 0x04) + bytes.fromhex("0400 00000000")
    assert reply(bytes.fromhex("0300 03000000") + b"xy", AlState.BOOT) == \
        error(0x8005, b"packet 3, expected 1")
    # A read of a file: data packet 1, then an ack of packet 5 where 1 is due: 0x8005.
    server.files["c"] = b"hello"
    assert reply(bytes.fromhex("0100 00000000") + b"c", AlState.BOOT) == \
        struct.pack("<HHBB", 11, 0, 0, 0x04) + bytes.fromhex("0300 01000000") + b"hello"
    assert reply(bytes.fromhex("0400 05000000"), AlState.BOOT) == \
        error(0x8005, b"ack 5, expected 1")


def test_a_firmware_file_may_be_its_header_alone():
    """The 16-byte header (b"ECFW", vendor, product, revision) with no image after it is
    still this device's firmware file, of revision 3."""
    from ecatcfg.runtime.segment.foe_server import firmware_revision
    header = b"ECFW" + struct.pack("<III", VENDOR, BOOT_PRODUCT, 3)
    assert firmware_revision("app.efw", header, VENDOR, BOOT_PRODUCT) == 3
    assert firmware_revision("app.efw", header[:15], VENDOR, BOOT_PRODUCT) == \
        "no firmware header (ECFW)"


# --------------------------------------------------------------------------- the client alone

def test_a_write_sends_a_final_empty_packet_after_a_full_one():
    """Packets of SM0 - 12 bytes; a file filling its last packet ends with an empty one."""
    t = FoeWrite("f", bytes(40), mbx_out_size=32, mbx_in_size=32)
    sent = [foe.decode_foe(t.first_request()[6:12])]

    def ack(n: int) -> bytes:
        return foe.encode_foe_mailbox(foe.FoeAck(n)).ljust(32, b"\x00")
    lengths = []
    for n in range(3):
        request = t.on_response(ack(n))
        assert request is not None
        length = struct.unpack_from("<H", request)[0] - 6
        lengths.append(length)
        assert foe.decode_foe(request[6:6 + 6 + length]).packet == n + 1
    assert lengths == [20, 20, 0]
    assert t.on_response(ack(3)) is None and t.done and t.packets == 3
    assert isinstance(sent[0], foe.FoeRequest)


def test_a_busy_reply_sends_the_last_packet_again():
    t = FoeWrite("f", bytes(30), mbx_out_size=32, mbx_in_size=32)
    t.first_request()
    first = t.on_response(foe.encode_foe_mailbox(foe.FoeAck(0)).ljust(32, b"\x00"))
    again = t.on_response(foe.encode_foe_mailbox(foe.FoeBusy(1, 4)).ljust(32, b"\x00"))
    assert again is not None and first is not None
    assert again[6:] == first[6:] and t.busy_replies == 1


def test_a_wrong_packet_number_is_answered_with_error_0x8005():
    t = FoeRead("f", mbx_out_size=32, mbx_in_size=32)
    t.first_request()
    answer = t.on_response(foe.encode_foe_mailbox(foe.FoeData(2, b"ab")).ljust(32, b"\x00"))
    assert answer is not None and t.done
    assert foe.decode_foe(answer[6:12]) == foe.FoeError(0x8005)
    assert isinstance(t.wrong_number, FoeTransferError) and t.wrong_number.code == 0x8005
    assert str(t.wrong_number) == ("data packet 2, expected 1 (FoE error 0x8005, packet "
                                   "number wrong, sent to the slave)")


def test_the_slaves_error_text_and_a_mailbox_error_without_its_type_word():
    t = FoeRead("f", mbx_out_size=32, mbx_in_size=32)
    t.first_request()
    # FoE error 0x8001 (not found) with the text "no file", zero-padded.
    with pytest.raises(FoeTransferError, match=r"FoE error 0x8001 \(not found\): 'no file'") \
            as refused:
        t.on_response((bytes.fromhex("0d00 0000 00 04" "0500 01800000".replace(" ", ""))
                       + b"no file").ljust(32, b"\x00"))
    assert (refused.value.code, refused.value.text) == (0x8001, "no file")
    # A mailbox error reply (type 0) whose first word is not Type 0x0001: no detail read.
    t = FoeRead("f", mbx_out_size=32, mbx_in_size=32)
    t.first_request()
    with pytest.raises(FoeTransferError, match=r"mailbox error 0 \(unknown detail\)"):
        t.on_response(bytes.fromhex("0400 0000 00 00" "0200 0200".replace(" ", ""))
                      .ljust(32, b"\x00"))


def test_a_mailbox_error_reply_ends_the_transfer_with_its_detail():
    t = FoeWrite("f", bytes(30), mbx_out_size=32, mbx_in_size=32)
    t.first_request()
    # ETG.1000.4 mailbox error: header type 0, then Type 0x0001 and Detail 0x0002
    # (unsupported protocol), each UINT16 little-endian.
    reply = bytes.fromhex("0400 0000 00 00" "0100 0200".replace(" ", "")).ljust(32, b"\x00")
    with pytest.raises(FoeTransferError, match=r"mailbox error 2 \(unsupported protocol\)") \
            as refused:
        t.on_response(reply)
    assert t.done and refused.value.code is None and refused.value.text == ""


def test_the_master_stamps_its_counter_and_refuses_a_wrong_ack_by_text():
    t = FoeWrite("f", bytes(30), mbx_out_size=32, mbx_in_size=32, counter=lambda: 5)
    # Mailbox header byte 5: type 4 (FoE) in bits 0-3, the counter 5 in bits 4-6.
    assert t.first_request()[5] == 0x54
    answer = t.on_response(foe.encode_foe_mailbox(foe.FoeAck(3)).ljust(32, b"\x00"))
    text = b"ack 3, expected 0"
    assert answer == (struct.pack("<HHBB", 6 + len(text), 0, 0, 0x54) + bytes.fromhex("0500")
                      + struct.pack("<I", 0x8005) + text).ljust(32, b"\x00")
    read = FoeRead("f", mbx_out_size=32, mbx_in_size=32, counter=lambda: 3)
    assert read.first_request()[:6] == bytes.fromhex("0700 0000 00 34".replace(" ", ""))


def test_a_read_past_its_limit_ends_the_transfer():
    t = FoeRead("f", mbx_out_size=32, mbx_in_size=32, limit=30)
    t.first_request()
    # SM1 of 32 bytes carries 20 file bytes a packet: the second full one passes 30.
    assert t.on_response(foe.encode_foe_mailbox(foe.FoeData(1, bytes(20))).ljust(32, b"\x00"))
    with pytest.raises(FoeTransferError, match="longer than 30 bytes"):
        t.on_response(foe.encode_foe_mailbox(foe.FoeData(2, bytes(20))).ljust(32, b"\x00"))
    assert t.done is True


# --------------------------------------------------------------------------- in memory

def test_firmware_update_write_read_back_and_revision_after_power_cycle(line):
    seg, transport = line
    image = firmware(0x00020000, size=5000)
    report = foe_tool.foe_transfer(transport, 0, "app.efw", image)
    assert report.state == "BOOT" and report.mailbox == (BOOT_MBX, BOOT_MBX)
    assert report.packets == math.ceil(len(image) / (BOOT_MBX - 12)) == 22
    assert report.identity_before == report.identity_after == foe_tool.Identity(
        VENDOR, BOOT_PRODUCT, REVISION, 0x40)
    assert seg.slaves[0].state == AlState.INIT
    back = foe_tool.foe_transfer(transport, 0, "app.efw")
    assert back.data == image and back.packets == 22
    # The new firmware runs after a power cycle: SII revision and 0x1018:03.
    seg.power_cycle(0)
    again = foe_tool.foe_transfer(transport, 0, "app.efw")
    assert again.identity_before is not None and again.identity_before.revision == 0x00020000
    rev = sdo_tool.sdo_transfer(transport, 0, 0x1018, 3)
    assert struct.unpack("<I", rev)[0] == 0x00020000


def test_wrong_password_and_missing_file_are_named_errors(line):
    seg, transport = line
    seg.slaves[0].mailbox.foe.password = 0xCAFE
    foe_tool.foe_transfer(transport, 0, "notes.txt", b"hello", password=0xCAFE)
    with pytest.raises(foe_tool.FoeToolError,
                       match=r"slave 0, FoE read of 'notes.txt': FoE error 0x800A "
                             r"\(no rights\)") as wrong:
        foe_tool.foe_transfer(transport, 0, "notes.txt", password=0x1234)
    assert wrong.value.foe_code == 0x800A
    with pytest.raises(foe_tool.FoeToolError,
                       match=r"slave 0, FoE read of 'gone.bin': FoE error 0x8001 "
                             r"\(not found\)") as missing:
        foe_tool.foe_transfer(transport, 0, "gone.bin", password=0xCAFE)
    assert missing.value.foe_code == 0x8001
    assert seg.slaves[0].state == AlState.INIT            # left as an update leaves it


def test_busy_replies_are_counted_and_the_file_arrives_whole(line):
    seg, transport = line
    seg.slaves[0].mailbox.foe.busy_every = 4
    image = firmware(0x00030000, size=4000)
    seen = []
    report = foe_tool.foe_transfer(transport, 0, "app.efw", image, progress=seen.append)
    packets = math.ceil(len(image) / 232)
    assert report.packets == packets and report.busy_replies == packets // 4
    assert [p.busy for p in seen if p.busy] and seen[-1].done == len(image)
    assert seg.slaves[0].mailbox.foe.files["app.efw"] == image


def test_disk_full_foreign_firmware_and_firmware_outside_boot(line):
    seg, transport = line
    seg.slaves[0].mailbox.foe.disk_size = 1000
    with pytest.raises(foe_tool.FoeToolError, match=r"0x8003 \(disk full\)"):
        foe_tool.foe_transfer(transport, 0, "big.bin", bytes(2000))
    seg.slaves[0].mailbox.foe.disk_size = 1 << 20
    with pytest.raises(foe_tool.FoeToolError, match=r"0x8004 \(illegal\).*product "
                                                    r"0x0000F101"):
        foe_tool.foe_transfer(transport, 0, "app.efw", firmware(2, product=0xF101))
    # A device with a boot loader takes firmware in BOOT only (SOES: 0x8009).
    with pytest.raises(foe_tool.FoeToolError, match=r"0x8009 \(not bootstrap\)"):
        foe_tool.foe_transfer(transport, 0, "app.efw", firmware(2), state=AlState.PREOP)
    assert "big.bin" not in seg.slaves[0].mailbox.foe.files


def test_without_a_boot_loader_the_transfer_runs_in_preop(line):
    seg, transport = line
    data = bytes(range(256)) * 2
    report = foe_tool.foe_transfer(transport, 1, "log.bin", data)
    assert report.state == "PREOP" and report.mailbox == (STD_MBX_EXF1001,) * 2
    assert report.packets == math.ceil(len(data) / (STD_MBX_EXF1001 - 12))
    assert foe_tool.foe_transfer(transport, 1, "log.bin").data == data
    with pytest.raises(foe_tool.FoeToolError, match="SII gives no bootstrap"):
        foe_tool.foe_transfer(transport, 1, "log.bin", state=AlState.BOOT)
    with pytest.raises(foe_tool.FoeToolError, match=r"slave 2 does not support FoE"):
        foe_tool.foe_transfer(transport, 2, "log.bin")


def test_the_emulated_esc_checks_boot_like_firmware(lib):
    """INIT->BOOT needs SM0/SM1 as the SII's bootstrap mailbox (else 0x0015); BOOT goes
    back to INIT only (0x0011); a device without a boot loader refuses BOOT (0x0013)."""
    seg = build(lib, "EXF1000", "EXF1002")
    boot, plain = seg.slaves

    def request(slave, state: int) -> tuple[int, int]:
        slave.write(Reg.AL_CONTROL, struct.pack("<H", state | 0x10))
        return slave.al_status, slave.status_code

    def sms(slave, length: int) -> None:
        slave.write(sm_register(0), SmConfig(0x1000, length, 0x26, True).to_bytes()
                    + SmConfig(0x10F4, length, 0x22, True).to_bytes())

    sms(boot, 128)                          # the standard mailbox's size: not BOOT's
    assert request(boot, AlState.BOOT) == (0x11, 0x0015)
    sms(boot, BOOT_MBX)
    assert request(boot, AlState.BOOT) == (AlState.BOOT, 0)
    assert request(boot, AlState.PREOP) == (0x13, 0x0011)
    assert request(boot, AlState.INIT) == (AlState.INIT, 0)
    assert request(plain, AlState.BOOT) == (0x11, 0x0013)


def test_tshark_dissects_the_transfer(line, tshark_path, tmp_path):
    seg, _ = line
    a, b = MemoryLink.pair()
    stop = threading.Event()
    pcap = tmp_path / "foe.pcapng"
    with PcapRecorder(pcap) as recorder:
        thread = threading.Thread(target=seg.serve, args=(b,), kwargs={"stop": stop},
                                  daemon=True)
        thread.start()
        transport = Transport(a, recorder=recorder)
        seg.slaves[0].mailbox.foe.busy_every = 3
        image = firmware(0x00020000, size=1000)
        foe_tool.foe_transfer(transport, 0, "app.efw", image)
        with pytest.raises(foe_tool.FoeToolError):
            foe_tool.foe_transfer(transport, 0, "missing.bin")
        stop.set()
        thread.join(2)
    fields = ["ecat_mailbox.foe_opmode", "ecat_mailbox.foe_packetno",
              "ecat_mailbox.foe_filename", "ecat_mailbox.foe_errcode",
              "ecat_mailbox.foe_busyentire"]
    rows = [tuple(v[0] if v else "" for v in p.values())
            for p in tshark_fields(pcap, fields, display_filter="ecat_mailbox.foe")]
    ops = {r[0] for r in rows}
    assert {"0x01", "0x02", "0x03", "0x04", "0x05", "0x06"} <= ops, rows
    assert ("0x02", "", "app.efw", "", "") in rows
    packets = sorted({int(r[1], 0) for r in rows if r[0] == "0x03" and r[1]})
    assert packets == list(range(1, math.ceil(1000 / 232) + 1))
    assert [int(r[3], 0) for r in rows if r[0] == "0x05"] == [0x8001]
    assert ("0x06", "", "", "", "0x0400") in rows           # busy: 1024 sectors of 4 KiB
    assert tshark_malformed(pcap) == []


# --------------------------------------------------------------------------- over veth

def ecatcfg_in(rig, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface",
                                 rig.if_a], timeout=timeout, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def test_foe_command_against_ecatcfg_simulate(veth_netns, tmp_path):
    """The update workflow against ``ecatcfg simulate``: write in BOOT, read back, named
    errors, then the line's power off and on (SIGUSR1) and ``ecatcfg scan`` shows the
    firmware's revision."""
    import signal
    topo = tmp_path / "line.yaml"
    topo.write_text("slaves:\n  - {name: box, device: EXF1000}\n")
    sim, lines = start_simulate(veth_netns, "--esi", str(ESI), "--topology", str(topo))
    assert lines and lines[-1].startswith("ready: 1 slaves"), "".join(lines)
    image = tmp_path / "app.efw"
    image.write_bytes(firmware(0x00020000, size=3000))
    done = ecatcfg_in(veth_netns, "foe", "write", "--slave", "0", str(image),
                      "--format", "json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert (out["state"], out["bytes"], out["packets"]) == ("BOOT", 3000,
                                                            math.ceil(3000 / 232))
    assert out["identity_before"]["revision"] == REVISION
    back = tmp_path / "back.efw"
    earlier = tmp_path / "earlier.efw"
    earlier.write_bytes(b"an earlier image")
    os.link(earlier, back)          # FILE is replaced whole, never rewritten in place
    done = ecatcfg_in(veth_netns, "foe", "read", "--slave", "0", str(back), "--name",
                      "app.efw")
    assert done.returncode == 0, done.stderr
    assert back.read_bytes() == image.read_bytes()
    assert earlier.read_bytes() == b"an earlier image"
    assert "3000 bytes read from slave 0 in BOOT" in done.stdout
    wrong = ecatcfg_in(veth_netns, "foe", "read", "--slave", "0", str(back), "--name",
                       "app.efw", "--password", "0x1234")
    assert wrong.returncode == 1
    assert "FoE error 0x800A (no rights)" in wrong.stderr and "app.efw" in wrong.stderr
    missing = ecatcfg_in(veth_netns, "foe", "read", "--slave", "0", str(back), "--name",
                         "nothing.bin")
    assert missing.returncode == 1 and "FoE error 0x8001 (not found)" in missing.stderr
    usage = ecatcfg_in(veth_netns, "foe", "write", "--slave", "0", str(tmp_path / "no"))
    assert usage.returncode == 2
    sim.send_signal(signal.SIGUSR1)
    assert sim.stdout is not None
    for line in sim.stdout:
        if line.startswith("power cycle:"):
            break
    scan = ecatcfg_in(veth_netns, "scan", "--format", "json")
    assert scan.returncode == 0, scan.stderr
    assert json.loads(scan.stdout)["slaves"][0]["revision"] == 0x00020000
    sim.terminate()
    sim.communicate(timeout=10)


def test_revision_changes_after_a_power_cycle_over_veth(veth_netns, lib, tmp_path):
    seg = build(lib, "EXF1000")
    image = tmp_path / "app.efw"
    image.write_bytes(firmware(0x00050001, size=2000))
    with serving(veth_netns, seg):
        done = ecatcfg_in(veth_netns, "foe", "write", "--slave", "0", str(image),
                          "--format", "json")
        assert done.returncode == 0, done.stderr
        seg.power_cycle(0)
        scan = ecatcfg_in(veth_netns, "scan", "--format", "json")
    assert scan.returncode == 0, scan.stderr
    assert json.loads(scan.stdout)["slaves"][0]["revision"] == 0x00050001


def test_soem_writes_and_reads_files_of_the_emulated_slave(veth_netns, pysoem_module, lib):
    """SOEM's FoE client (an independent master) in PREOP over the standard mailbox: a
    file it writes is read back by it and by ecatcfg; firmware is refused outside BOOT."""
    seg = build(lib, "EXF1000")
    data = bytes((i * 13) & 0xFF for i in range(700))
    ops = [[0, "write", "cal.bin", 0, data.hex()], [0, "read", "cal.bin", 0, 4096],
           [0, "read", "none.bin", 0, 4096],
           [0, "write", "app.efw", 0, firmware(2, size=300).hex()]]
    with serving(veth_netns, seg):
        done = veth_netns.run_in(veth_netns.ns_a, [sys.executable, str(PROBE),
                                                   veth_netns.if_a,
                                                   json.dumps({"foe": ops})], timeout=120)
    assert done.returncode == 0, done.stderr
    results = json.loads(done.stdout.strip().splitlines()[-1])["foe"]
    assert results[0].get("result", 0) > 0, results
    assert results[1] == {"hex": data.hex()}
    # SOEM reads nothing of a missing file, and reports an FoE error reply as
    # -EC_ERR_TYPE_FOE_ERROR (ethercattype.h: 5): firmware outside BOOT (0x8009).
    assert results[2] == {"hex": ""} and results[3] == {"result": -5}, results
    assert seg.slaves[0].mailbox.foe.files["cal.bin"] == data
    assert "app.efw" not in seg.slaves[0].mailbox.foe.files


# --------------------------------------------------------------------------- FoE InitCmds

def read_request(name: str, password: int = 0) -> bytes:
    """An FoE read request as an ENI's Data holds it (ETG.2100 MailboxCmdType: the message
    without the mailbox header): OpCode 1, reserved, password, name."""
    return bytes([1, 0]) + struct.pack("<I", password) + name.encode()


def plan_with_foe(lib: Library, cmds: list) -> object:
    from ecatcfg.compiler import build, topology
    text = "slaves:\n  - {name: box, device: EXF1000}\n"
    plan = build.compile_topology(topology.loads(text, "t.yaml"), lib).plan
    plan.slaves[0].mailbox.foe_init_cmds.extend(cmds)
    return plan


def test_foe_init_cmds_round_trip_and_follow_the_schema(lib, eni_schema):
    from lxml import etree

    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.eni.plan import FoeInitCmd
    from ecatcfg.esc import Transition
    cmds = [FoeInitCmd([Transition.PS], "check calibration", read_request("cal.bin", 0x2A),
                       timeout=2500, fixed=True),
            FoeInitCmd([Transition.IP, Transition.PS], "", read_request("x"), disabled=True)]
    plan = plan_with_foe(lib, cmds)
    data = eni_writer.to_bytes(plan)
    assert eni_schema.validate(etree.fromstring(data)), eni_schema.error_log
    back = eni_reader.read_bytes(data, "foe.xml")
    assert back.slaves[0].mailbox.foe_init_cmds == cmds and back.unsupported == []
    assert back == eni_reader.read_bytes(eni_writer.to_bytes(back), "again.xml")
    text = data.decode()
    assert "<FoE>" in text and "<Data>01002a000000" + b"cal.bin".hex() + "</Data>" in text


# -- an FoE InitCmd's job against hand-written mailbox answers -------------------------------

MAILBOX_PLAN = MailboxPlan(MailboxArea(0x1000, 128), MailboxArea(0x1080, 128))


def run_mailbox_job(job, answers: list[bytes], *, answer_after: float = 0.0,
                    refuse_writes: int = 0, give_up: float = 10.0) -> list[bytes]:
    """Run a mailbox job against a slave whose SM0 (0x1000) takes each write but the first
    ``refuse_writes`` (working counter 0: the mailbox is full) and whose SM1 (0x1080) hands
    out ``answers``, one per read once a request was written and ``answer_after`` s have
    passed (its status, 0x080D bit 3, says so); the messages written.  A job still running after ``give_up`` s fails the
    test."""
    from ecatcfg.esc import Cmd
    from ecatcfg.runtime.mailbox import pad_to
    from ecatcfg.runtime.wire import Datagram
    started = time.monotonic()
    written: list[bytes] = []
    pending = list(answers)
    request = next(job)
    try:
        while True:
            if time.monotonic() - started > give_up:
                pytest.fail(f"the job still runs after {give_up} s")
            replies = []
            for dg in request:
                data, wkc = dg.data, 0
                if dg.cmd == Cmd.FPWR and dg.ado == 0x1000:
                    if refuse_writes:
                        refuse_writes -= 1
                    else:
                        written.append(bytes(dg.data))
                        wkc = 1
                elif dg.cmd == Cmd.FPRD and dg.ado == 0x1080 and pending and written and \
                        time.monotonic() - started >= answer_after:
                    data, wkc = pad_to(pending.pop(0), len(dg.data)), 1
                elif dg.cmd == Cmd.FPRD and dg.ado == 0x080D:      # SM1 status: bit 3 full
                    full = bool(pending and written) and \
                        time.monotonic() - started >= answer_after
                    data, wkc = bytes([0x08 if full else 0]).ljust(len(dg.data), b"\0"), 1
                replies.append(Datagram(dg.cmd, dg.idx, dg.address, data, wkc=wkc))
            request = job.send(replies)
    except StopIteration:
        return written


def foe_read_cmd(data: bytes, comment: str = "", timeout: int = 0) -> FoeInitCmd:
    return FoeInitCmd([Transition.PS], comment, data, timeout=timeout)


def test_a_foe_init_cmd_reads_with_its_password_on_the_channels_counter():
    channel = MailboxChannel(0x1001, MAILBOX_PLAN)
    assert channel.counter() == 1          # an earlier mailbox command took counter 1
    # Read request (OpCode 1), password 0x1234, file "cal.bin"; the slave answers late,
    # with data packet 1 of 3 bytes (short: the last), mailbox counter 1.
    cmd = foe_read_cmd(bytes.fromhex("0100 34120000") + b"cal.bin")
    last = bytes.fromhex("0900 0000 00 14" "0300 01000000".replace(" ", "")) + b"abc"
    written = run_mailbox_job(foe_init_cmd_job(channel, cmd, "s1"), [last],
                              answer_after=0.3, refuse_writes=1)
    # Mailbox header: length 13, address 0, channel 0, type 4 (FoE) with counter 2, then 3.
    assert [w[:19] for w in written] == [
        bytes.fromhex("0d00 0000 00 24" "0100 34120000".replace(" ", "")) + b"cal.bin",
        bytes.fromhex("0600 0000 00 34" "0400 01000000".replace(" ", "")).ljust(19, b"\x00")]


def test_a_foe_init_cmd_gives_up_after_its_own_timeout():
    started = time.monotonic()
    with pytest.raises(ApplyError) as late:
        run_mailbox_job(foe_init_cmd_job(MailboxChannel(0x1001, MAILBOX_PLAN),
                                         foe_read_cmd(bytes.fromhex("0100 00000000") + b"x",
                                                      timeout=100), "s1"), [])
    assert time.monotonic() - started < 2.5        # 100 ms, not the 3 s default
    # The slave and the command named once.
    assert str(late.value) == ("slave 's1' [FoE read 'x']: FoE read of 'x': no mailbox "
                               "response in time")


def test_a_foe_init_cmd_whose_request_sm0_never_takes_names_the_slave():
    with pytest.raises(ApplyError) as refused:
        run_mailbox_job(foe_init_cmd_job(MailboxChannel(0x1001, MAILBOX_PLAN),
                                         foe_read_cmd(bytes.fromhex("0100 00000000") + b"x"),
                                         "s1"), [], refuse_writes=10**9)
    assert str(refused.value) == ("slave 's1' [FoE read 'x']: the mailbox (SM0) did not take "
                                  "the request")


def test_a_foe_init_cmd_apply_cannot_run_is_refused_by_name():
    write = foe_read_cmd(bytes.fromhex("0200 00000000") + b"x", comment="firmware")
    with pytest.raises(ApplyError, match=r"slave 's1' \[firmware\]: FoE InitCmd with OpCode "
                       r"2: apply runs read requests \(1\) only$") as refused:
        next(foe_init_cmd_job(MailboxChannel(0x1001, MAILBOX_PLAN), write, "s1"))
    assert refused.value.command == "firmware"
    small = MailboxPlan(MailboxArea(0x1000, 12), MailboxArea(0x1080, 128))
    with pytest.raises(ApplyError, match=r"slave 's1' \[FoE read 'x'\]: a 12-byte SM0 "
                       "cannot carry FoE data"):
        next(foe_init_cmd_job(MailboxChannel(0x1001, small),
                              foe_read_cmd(bytes.fromhex("0100 00000000") + b"x"), "s1"))


def test_apply_reads_the_file_of_a_read_request_and_names_a_refusal(lib, tmp_path):
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.eni.plan import FoeInitCmd
    from ecatcfg.esc import Transition
    from ecatcfg.runtime import Network
    from ecatcfg.runtime.master.replay import ApplyError
    ok = FoeInitCmd([Transition.PS], "calibration present", read_request("cal.bin"))
    eni = tmp_path / "ok.xml"
    eni.write_bytes(eni_writer.to_bytes(plan_with_foe(lib, [ok])))
    with Network.virtual(eni, esi=[ESI]) as net:
        foe_server = net.segment.slaves[0].mailbox.foe
        foe_server.files["cal.bin"] = bytes(range(250)) * 3     # 3 packets of 116
        net.up()
        assert net.state == AlState.OP
    missing = FoeInitCmd([Transition.PS], "calibration present", read_request("none.bin"))
    eni = tmp_path / "missing.xml"
    eni.write_bytes(eni_writer.to_bytes(plan_with_foe(lib, [missing])))
    with Network.virtual(eni, esi=[ESI]) as net:
        with pytest.raises(ApplyError, match=r"slave 'box' \[calibration present\]: FoE read "
                                             r"of 'none.bin': FoE error 0x8001 \(not found\)"
                           ) as refused:
            net.up()
    line = next(i for i, text in enumerate(eni.read_text().splitlines(), 1)
                if "<Comment>calibration present</Comment>" in text) - 2
    assert str(refused.value).startswith(f"{eni}:{line}: slave 'box'")     # file and line


@pytest.mark.parametrize("data, why", [
    (bytes([2, 0]) + bytes(4) + b"fw.efw", "FoE InitCmd: a write request: Data holds the "
                                           "file name but an ENI has no place"),
    (bytes.fromhex("0400 01000000"), "FoE InitCmd: an ack: part of a transfer"),
    (bytes.fromhex("0100"), "FoE InitCmd: <Data> of 2 bytes"),
])
def test_other_foe_init_cmds_are_refused_by_name(lib, tmp_path, data, why):
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.eni.plan import FoeInitCmd
    from ecatcfg.esc import Transition
    eni = tmp_path / "refused.xml"
    eni.write_bytes(eni_writer.to_bytes(plan_with_foe(
        lib, [FoeInitCmd([Transition.PS], "update", data)])))
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(ESI)], capture_output=True, text=True, timeout=120,
                          cwd=ROOT)
    line = next(i for i, text in enumerate(eni.read_text().splitlines(), 1)
                if "<Comment>update</Comment>" in text) - 2
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert f"{eni}:{line}: slave 'box': {why}" in done.stderr, done.stderr
    assert "[FoE/InitCmds/InitCmd]: 1 command would be lost" in done.stderr
    skipped = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                              "--esi", str(ESI), "--skip-unsupported", "--simulated-time",
                              "--cycles", "3", "--format", "json"],
                             capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert skipped.returncode == 0, skipped.stderr
    assert json.loads(skipped.stdout)["skipped"][0]["element"] == "FoE/InitCmds/InitCmd"


def test_a_foe_init_cmd_in_boot_transitions_is_refused(lib, tmp_path):
    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.eni.plan import FoeInitCmd
    from ecatcfg.esc import Transition
    plan = plan_with_foe(lib, [FoeInitCmd([Transition.IB], "boot", read_request("a"))])
    back = eni_reader.read_bytes(eni_writer.to_bytes(plan), "boot.xml")
    [part] = back.unsupported
    assert part.element == "FoE/InitCmds/InitCmd" and "transition IB" in part.what
    assert back.slaves[0].mailbox.foe_init_cmds == []       # left out: never sent


def test_a_negative_max_size_is_refused_before_the_line_is_touched(tmp_path):
    """--max-size is checked with the other options (exit 2 naming it), not after the
    slave has been taken to BOOT and its first data packet has come."""
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "foe", "read", "--iface",
                           "ecatcfg-none0", "--slave", "0", str(tmp_path / "back.efw"),
                           "--max-size", "-1"], capture_output=True, text=True, cwd=ROOT,
                          timeout=60)
    assert done.returncode == 2, done.stderr
    assert "--max-size -1" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "back.efw").exists()
