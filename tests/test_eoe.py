"""EoE IP parameters (ETG.1000.6 §5.7; docs/protocol-notes.md §9): the codec, the virtual
segment's EoE server behind the mailbox dispatcher, the master replaying an ENI's EoE
InitCmds, and the corpus ENI that carries one (Elmo Application Studio's ``eni1.xml``) on
the wire as tshark dissects it.

Expected bytes and addresses are written out by hand from the layouts the public sources
give (SOEM ``ethercateoe.c``, SOES ``esc_eoe.c``, IgH ``fsm_eoe.c``, Wireshark
``packet-ecatmb.c``): an IPv4 address is a little-endian 32-bit number, so 10.0.0.7 is
``07 00 00 0a``.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from ipaddress import IPv4Address
from pathlib import Path

import pytest

from conftest import MAILBOX_PD_SMS, device_xml, esi_xml
from rig import tshark_fields, tshark_malformed
from ecatcfg import eoe
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import EoeInitCmd, MailboxArea, MailboxPlan, NetworkPlan
from ecatcfg.esc import AlState, Cmd, Transition
from ecatcfg.esi.library import Library
from ecatcfg.esi.reader import read_bytes
from ecatcfg.runtime import Network
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.mailbox import (MailboxError, MbxErrorDetail, MbxType, decode,
                                     encode_emergency, encode_mailbox, encode_upload_request,
                                     pad_to)
from ecatcfg.runtime.master.replay import ApplyError, MailboxChannel, eoe_init_cmd_job
from ecatcfg.runtime.wire import Datagram

# ip 10.0.0.7, mask 255.255.0.0, gateway 10.0.0.1, mac 02:00:00:00:00:07: flags 0x0F, then
# every field at its fixed place (58 bytes; IgH ec_fsm_eoe_prepare_set, the ENI files).
FIXED_BODY = bytes.fromhex("0f000000" "020000000007" "0700000a" "0000ffff" "0100000a"
                           "00000000") + bytes(32)
# The same request as EC-Engineer writes it into an ENI: the EoE header (type 2) in front.
FRAMED_BODY = bytes.fromhex("02000000") + FIXED_BODY
# The same parameters with only the flagged fields (SOEM ecx_EOEsetIp, SOES EOE_get_ip).
COMPACT_BODY = bytes.fromhex("0f000000" "020000000007" "0700000a" "0000ffff" "0100000a")
PARAMS = eoe.IpParameters(mac=bytes.fromhex("020000000007"), ip=IPv4Address("10.0.0.7"),
                          subnet_mask=IPv4Address("255.255.0.0"),
                          default_gateway=IPv4Address("10.0.0.1"))
# gateway 10.0.0.2 alone (compact: flags 0x08, one address).
GATEWAY_ONLY = bytes.fromhex("08000000" "0200000a")
# mac 02:00:00:00:00:08 alone, fixed layout.
MAC_ONLY = bytes.fromhex("01000000" "020000000008") + bytes(16 + 32)


# --------------------------------------------------------------------------- the codec

def test_an_address_is_a_little_endian_number():
    body = eoe.encode_ip_parameters(eoe.IpParameters(ip=IPv4Address("192.168.1.4")))
    assert body == bytes.fromhex("02000000") + bytes(6) + bytes.fromhex("0401a8c0") + bytes(44)
    assert eoe.decode_ip_parameters(body).ip == IPv4Address("192.168.1.4")


def test_both_layouts_encode_and_decode():
    assert eoe.encode_ip_parameters(PARAMS) == FIXED_BODY
    assert eoe.encode_ip_parameters(PARAMS, compact=True) == COMPACT_BODY
    assert eoe.decode_ip_parameters(FIXED_BODY) == PARAMS
    assert eoe.decode_ip_parameters(COMPACT_BODY) == PARAMS
    # Every flag set: the two layouts are one.
    full = eoe.IpParameters(mac=b"\x02" * 6, ip=IPv4Address("1.2.3.4"),
                            subnet_mask=IPv4Address("255.0.0.0"),
                            default_gateway=IPv4Address("1.0.0.1"),
                            dns_server=IPv4Address("8.8.4.4"), dns_name="drive-7")
    assert eoe.encode_ip_parameters(full) == eoe.encode_ip_parameters(full, compact=True)
    assert len(eoe.encode_ip_parameters(full)) == 58
    assert eoe.decode_ip_parameters(eoe.encode_ip_parameters(full)) == full
    for params in (eoe.IpParameters(), eoe.IpParameters(dns_name="x"),
                   eoe.IpParameters(default_gateway=IPv4Address("10.1.2.3"),
                                    dns_server=IPv4Address("10.1.2.4"))):
        for compact in (False, True):
            assert eoe.decode_ip_parameters(
                eoe.encode_ip_parameters(params, compact=compact)) == params


def test_soem_writes_the_compact_layout():
    # SOEM 1.x ecx_EOEsetIp: flags, then only the flagged fields: ip and mask here.
    params = eoe.decode_ip_parameters(bytes.fromhex("06000000" "0401a8c0" "00ffffff"))
    assert params == eoe.IpParameters(ip=IPv4Address("192.168.1.4"),
                                      subnet_mask=IPv4Address("255.255.255.0"))
    assert eoe.decode_ip_parameters(GATEWAY_ONLY) == eoe.IpParameters(
        default_gateway=IPv4Address("10.0.0.2"))


def test_bodies_that_do_not_fit_are_refused():
    with pytest.raises(ValueError, match="too short"):
        eoe.decode_ip_parameters(b"\x01\x00")
    with pytest.raises(ValueError, match="bits other than"):
        eoe.decode_ip_parameters(bytes.fromhex("40000000"))
    with pytest.raises(ValueError, match="neither the fixed 58-byte layout"):
        eoe.decode_ip_parameters(COMPACT_BODY + b"\x00")
    with pytest.raises(ValueError, match="not ASCII"):
        eoe.decode_ip_parameters(bytes.fromhex("20000000") + b"\xff" * 32)
    with pytest.raises(ValueError, match="too short for the EoE header"):
        eoe.decode_frame(b"\x02\x00")


def test_init_data_in_either_encoding():
    alone = eoe.decode_init_data(FIXED_BODY)
    assert (alone.params, alone.port, alone.with_header) == (PARAMS, 0, False)
    framed = eoe.decode_init_data(FRAMED_BODY)
    assert (framed.params, framed.port, framed.with_header) == (PARAMS, 0, True)
    with pytest.raises(ValueError, match="not a set IP parameter request"):
        eoe.decode_init_data(b"\xde\xad\xbe\xef\x00")
    with pytest.raises(ValueError, match="EoE header of type 3"):
        eoe.decode_init_data(bytes.fromhex("03000000") + FIXED_BODY)
    # Frame info 2 of a set IP parameter request holds nothing (fragment, offset and frame
    # numbers belong to Ethernet fragments): the master sends it as 0, so a file's other
    # value would be lost on the wire; refused, naming it, not read as the request.
    for info2 in ("0100", "0102", "0010"):
        with pytest.raises(ValueError, match=f"frame info 2 0x{info2[2:]}{info2[:2]}"):
            eoe.decode_init_data(bytes.fromhex("0200" + info2) + FIXED_BODY)
    # 02000000 00000000 reads as a body (flags: IP, 0.0.0.0) and as an EoE header in front
    # of an empty body: refused rather than guessed.
    with pytest.raises(ValueError, match="reads both"):
        eoe.decode_init_data(bytes.fromhex("0200000000000000"))


def test_headers_of_requests_and_responses():
    assert eoe.encode_set_ip_request(PARAMS) == FRAMED_BODY
    assert eoe.encode_set_ip_request(PARAMS, port=1)[:4] == bytes.fromhex("12000000")
    # Type 3, last fragment (0x0100), result 0x0201 in frame info 2.
    assert eoe.encode_set_ip_response(0x0201) == bytes.fromhex("03010102")
    assert eoe.encode_get_ip_request() == bytes.fromhex("06000000")
    assert eoe.encode_get_ip_response(PARAMS) == bytes.fromhex("07010000") + COMPACT_BODY
    frame = eoe.decode_frame(bytes.fromhex("23010102") + b"xy")
    assert (frame.type, frame.port, frame.last_fragment, frame.info2, frame.body) == (
        3, 2, True, 0x0201, b"xy")
    assert eoe.result_name(0x0201) == "no IP support"
    assert eoe.result_name(0x7777) == "unknown result code"


def test_a_later_request_keeps_what_it_does_not_set():
    later = eoe.decode_ip_parameters(GATEWAY_ONLY)
    merged = PARAMS.updated(later)
    assert merged.default_gateway == IPv4Address("10.0.0.2")
    assert (merged.mac, merged.ip, merged.subnet_mask) == (
        bytes.fromhex("020000000007"), IPv4Address("10.0.0.7"), IPv4Address("255.255.0.0"))
    assert not eoe.IpParameters(mac=b"\x02" * 6).sets_ip
    assert eoe.IpParameters(dns_name="x").sets_ip and PARAMS.sets_ip


# The two corpus encodings (docs/eni-exports.md §9), decoded to what the files mean.

def _eoe_cmds(path: Path) -> list[EoeInitCmd]:
    plan = eni_reader.read_file(path)
    return [c for s in plan.slaves if s.mailbox for c in s.mailbox.eoe_init_cmds]


def test_eas_eni_writes_the_body_alone(corpus):
    [cmd] = _eoe_cmds(corpus / "eni" / "rocos-ethercat" / "eni1.xml")
    assert cmd.transitions == [Transition.PS] and cmd.timeout == 10000
    request = cmd.request
    assert not request.with_header and request.port == 0
    assert request.params.ip == IPv4Address("192.168.1.4")
    assert request.params.subnet_mask == IPv4Address("255.255.255.0")
    assert request.params.default_gateway == IPv4Address("192.168.1.10")
    assert request.params.mac == bytes.fromhex("10189eff0104")
    assert len(cmd.data) == 58


def test_ec_engineer_eni_writes_the_eoe_header_in_front(corpus):
    [cmd] = _eoe_cmds(corpus / "eni" / "murrelektronik-variox" / "eni.xml")
    assert cmd.transitions == [Transition.IP]
    request = cmd.request
    assert request.with_header and request.port == 0
    assert cmd.data[:4] == bytes.fromhex("02000000") and len(cmd.data) == 62
    assert request.params == eoe.IpParameters(mac=bytes.fromhex("0200000003ea"),
                                              ip=IPv4Address("192.168.0.102"),
                                              subnet_mask=IPv4Address("255.255.255.0"))


# --------------------------------------------------------------------------- fixture devices

DEVICES = {"FX-EOE": ("#x20", "<EoE/><CoE/>"),                    # EoE and CoE
           "FX-COE": ("#x21", "<CoE/>"),                          # no EoE
           "FX-NOIP": ("#x22", '<EoE IP="false" MAC="true"/><CoE/>'),   # as SV660_EOE
           "FX-EOEONLY": ("#x23", "<EoE/>")}                      # EoE without CoE


def fixture_esi() -> str:
    return esi_xml(*(device_xml(name, product,
                                body=MAILBOX_PD_SMS + f"<Mailbox>{mailbox}</Mailbox>")
                     for name, (product, mailbox) in DEVICES.items()))


@pytest.fixture(scope="module")
def esi_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("eoe-esi") / "eoe-fixtures.xml"
    path.write_text(fixture_esi())
    return path


def emulated(name: str):
    esi = read_bytes(fixture_esi().encode(), "eoe-fixtures.xml")
    device = next(d for d in esi.devices if d.type_name == name)
    return emulate.emulated_slave(emulate.SlaveSpec(device, name))


def test_the_esi_reader_keeps_the_eoe_attributes():
    esi = read_bytes(fixture_esi().encode(), "eoe-fixtures.xml")
    eoe_of = {d.type_name: d.mailbox.eoe for d in esi.devices}
    assert eoe_of["FX-COE"] is None
    assert (eoe_of["FX-EOE"].ip, eoe_of["FX-EOE"].mac, eoe_of["FX-EOE"].timestamp) == (
        None, None, None)
    assert (eoe_of["FX-NOIP"].ip, eoe_of["FX-NOIP"].mac) == (False, True)
    assert eoe_of["FX-NOIP"].source.line > 0


def test_the_corpus_sv660_says_no_ip(corpus):
    from ecatcfg.esi.reader import read_file
    [device] = read_file(corpus / "esi" / "drives" / "SV660_EOE_1Axis_V9.12.xml").devices[:1]
    settings = device.mailbox.eoe
    assert (settings.ip, settings.mac, settings.timestamp) == (False, True, False)


# --------------------------------------------------------------------------- the EoE server

class Mailbox:
    """The master's side of an emulated slave's mailbox, in memory: whole SM0 messages in,
    decoded SM1 messages out."""

    def __init__(self, name: str) -> None:
        self.slave = emulated(name)
        self.server = self.slave.mailbox
        self.counter = 0

    def raw(self, message: bytes, state: AlState = AlState.PREOP) -> list[bytes]:
        return self.server.handle(pad_to(message, 128), state)

    def eoe(self, payload: bytes, state: AlState = AlState.PREOP) -> list:
        self.counter = self.counter % 7 + 1
        return [decode(r) for r in self.raw(encode_mailbox(MbxType.EOE, payload, self.counter),
                                            state)]


def eoe_reply(replies: list) -> eoe.EoeFrame:
    [(header, content)] = replies
    assert header.type == MbxType.EOE and isinstance(content, tuple)
    return eoe.decode_frame(content[1])


def test_set_ip_is_stored_and_answered_with_success():
    box = Mailbox("FX-EOE")
    assert box.slave.eoe_ip is None
    reply = eoe_reply(box.eoe(FRAMED_BODY))
    assert (reply.type, reply.info2, reply.last_fragment, reply.body) == (3, 0, True, b"")
    assert box.slave.eoe_ip == PARAMS
    # In SAFEOP and OP too, and a later request keeps what it does not set (SOES).
    assert eoe_reply(box.eoe(bytes.fromhex("02000000") + GATEWAY_ONLY, AlState.SAFEOP)
                     ).info2 == 0
    assert box.slave.eoe_ip.default_gateway == IPv4Address("10.0.0.2")
    assert box.slave.eoe_ip.ip == IPv4Address("10.0.0.7")
    assert eoe_reply(box.eoe(bytes.fromhex("02000000") + COMPACT_BODY, AlState.OP)).info2 == 0
    assert box.slave.eoe_ip == PARAMS


def test_the_port_is_echoed():
    box = Mailbox("FX-EOE")
    reply = eoe_reply(box.eoe(bytes.fromhex("12000000") + FIXED_BODY))
    assert (reply.type, reply.port, reply.info2) == (3, 1, 0)


def test_get_ip_answers_what_is_stored():
    box = Mailbox("FX-EOE")
    empty = eoe_reply(box.eoe(bytes.fromhex("06000000")))
    assert (empty.type, empty.info2, empty.body) == (7, 0, bytes(4))
    box.eoe(FRAMED_BODY)
    [(header, content)] = box.eoe(bytes.fromhex("06000000"))
    assert header.length == 4 + len(COMPACT_BODY)
    assert content[1] == bytes.fromhex("07010000") + COMPACT_BODY


def test_no_ip_support_refuses_ip_settings_and_stores_nothing():
    box = Mailbox("FX-NOIP")
    for body in (FRAMED_BODY, bytes.fromhex("02000000") + GATEWAY_ONLY):
        reply = eoe_reply(box.eoe(body))
        assert (reply.type, reply.info2) == (3, 0x0201)
    assert box.slave.eoe_ip is None
    # A MAC address alone is no IP setting (MAC="true").
    assert eoe_reply(box.eoe(bytes.fromhex("02000000") + MAC_ONLY)).info2 == 0
    assert box.slave.eoe_ip == eoe.IpParameters(mac=bytes.fromhex("020000000008"))


def test_an_undecodable_body_gets_unspecified_error():
    box = Mailbox("FX-EOE")
    for body in (COMPACT_BODY + b"\x00", bytes.fromhex("ff000000"), b""):
        assert eoe_reply(box.eoe(bytes.fromhex("02000000") + body)).info2 == 0x0001
    assert box.slave.eoe_ip is None


def test_fragments_are_dropped_and_other_types_unsupported():
    box = Mailbox("FX-EOE")
    # An Ethernet frame (type 0, last fragment): no tunnel, no answer.
    assert box.eoe(bytes.fromhex("00010000") + bytes(60)) == []
    # A set address filter request (type 4), a response sent to the slave (type 3): answered
    # with the request's type and result 0x0002 (SOES ESC_eoeprocess).
    for request in ("04000000", "03010000", "21000000"):
        reply = eoe_reply(box.eoe(bytes.fromhex(request) + bytes(8)))
        assert (reply.type, reply.info2, reply.last_fragment) == (
            int(request[1], 16), 0x0002, True)
        assert reply.port == int(request[0], 16)


# Frame info 2 of an Ethernet fragment (ETG.1000.6 EoE header; SOES ``esc_eoe.c``, Wireshark
# ``packet-ecatmb.c``): fragment number in bits 0-5, in fragment 0 the frame's size in
# 32-byte blocks (else the fragment's offset in blocks) in bits 6-11, frame number in 12-15.
def fragment_header(fragment: int, blocks: int, frame: int, last: bool) -> bytes:
    return bytes.fromhex("0001" if last else "0000") + \
        (fragment | blocks << 6 | frame << 12).to_bytes(2, "little")


def test_fragments_with_frame_info_2_are_dropped_without_an_answer():
    """Fragments carry Ethernet frames, never a request: whatever frame info 2 holds, the
    slave answers none of them (a receiver discards a fragment out of sequence, SOES
    ``EOE_receive_fragment``, and delivers a whole frame to its IP stack, not to the
    master), and none is read as a request; the mailbox serves the next request as ever."""
    box = Mailbox("FX-EOE")
    first = fragment_header(0, 2, 1, last=False)       # frame 1: 64 bytes, fragment 0
    assert first == bytes.fromhex("00008010")
    second = fragment_header(1, 1, 1, last=True)       # fragment 1 at 32 bytes, the last
    stray = fragment_header(3, 4, 5, last=True)        # fragment 3 of a frame never begun
    looks_like_a_result = bytes.fromhex("0001" "0102")  # frame info 2 = 0x0201
    for message in (first + bytes(32), second + bytes(32), stray + bytes(16),
                    looks_like_a_result + FIXED_BODY):
        assert box.eoe(message) == []
    assert box.slave.eoe_ip is None
    reply = eoe_reply(box.eoe(FRAMED_BODY))
    assert (reply.type, reply.info2) == (3, 0) and box.slave.eoe_ip == PARAMS


def mailbox_error(replies: list) -> int:
    [(header, content)] = replies
    assert header.type == MbxType.ERROR and isinstance(content, MailboxError)
    return content.detail


def test_a_message_shorter_than_the_eoe_header_is_a_mailbox_error():
    box = Mailbox("FX-EOE")
    assert mailbox_error(box.eoe(b"\x02\x00")) == MbxErrorDetail.SIZE_TOO_SHORT


def test_protocols_the_slave_does_not_speak_are_unsupported():
    coe_only = Mailbox("FX-COE")
    assert mailbox_error(coe_only.eoe(FRAMED_BODY)) == MbxErrorDetail.UNSUPPORTED_PROTOCOL
    eoe_only = Mailbox("FX-EOEONLY")
    assert eoe_only.slave.od is None and eoe_only.server.coe is None
    sdo = [decode(r) for r in eoe_only.raw(encode_upload_request(0x1018, 1, 7))]
    assert mailbox_error(sdo) == MbxErrorDetail.UNSUPPORTED_PROTOCOL
    assert eoe_reply(eoe_only.eoe(FRAMED_BODY)).info2 == 0
    assert eoe_only.slave.eoe_ip == PARAMS


def test_the_mailbox_rules_hold_for_every_protocol():
    """One dispatcher: the repeat rule and the slave's counter span CoE and EoE."""
    box = Mailbox("FX-EOE")
    request = encode_mailbox(MbxType.EOE, bytes.fromhex("06000000"), 3)
    assert len(box.raw(request)) == 1
    assert box.raw(request) == []                           # counter 3 again: a repeat
    coe = [decode(r) for r in box.raw(encode_upload_request(0x1018, 1, 4))]
    eoe_again = [decode(r) for r in box.raw(encode_mailbox(MbxType.EOE,
                                                           bytes.fromhex("06000000"), 5))]
    assert [h.counter for h, _ in coe + eoe_again] == [2, 3]   # the first answer had 1
    too_long = bytes.fromhex("7b00 0000 00 62".replace(" ", "")) + bytes(122)   # > SM0 - 6
    assert mailbox_error([decode(r) for r in box.raw(too_long)]) == \
        MbxErrorDetail.INVALID_HEADER
    channel = encode_mailbox(MbxType.EOE, bytes.fromhex("06000000"), 7, channel=2)
    assert mailbox_error([decode(r) for r in box.raw(channel)]) == \
        MbxErrorDetail.INVALID_CHANNEL


# --------------------------------------------------------------------------- the master

CHANNEL_PLAN = MailboxPlan(MailboxArea(0x1000, 128), MailboxArea(0x1080, 128))


def drive(job, answers: list[bytes]) -> list[bytes]:
    """Run a mailbox job against a mailbox that takes every SM0 write and hands out
    ``answers`` one per SM1 read (then nothing): the messages the job wrote."""
    written: list[bytes] = []
    pending = list(answers)
    request = next(job)
    try:
        while True:
            replies = []
            for dg in request:
                data, wkc = dg.data, 0
                if dg.cmd == Cmd.FPWR and dg.ado == 0x1000:
                    written.append(bytes(dg.data))
                    wkc = 1
                elif dg.cmd == Cmd.FPRD and dg.ado == 0x1080 and pending and written:
                    data, wkc = pad_to(pending.pop(0), len(dg.data)), 1
                replies.append(Datagram(dg.cmd, dg.idx, dg.address, data, wkc=wkc))
            request = job.send(replies)
    except StopIteration:
        return written


def eoe_job(data: bytes = FIXED_BODY, timeout: int = 0, plan: MailboxPlan = CHANNEL_PLAN):
    cmd = EoeInitCmd([Transition.PS], "set ip", data, timeout=timeout)
    return eoe_init_cmd_job(MailboxChannel(0x1001, plan), cmd, "drive")


# Slave answers, written out: mailbox header (length, address, channel, type | counter << 4)
# then the EoE header (frame info 1, result).
SUCCESS = bytes.fromhex("0400 0000 00 22" "0301 0000".replace(" ", ""))
REFUSED = bytes.fromhex("0400 0000 00 32" "0301 0102".replace(" ", ""))


def test_the_master_sends_the_request_with_the_eoe_header():
    for data in (FIXED_BODY, FRAMED_BODY):
        [message] = drive(eoe_job(data), [SUCCESS])
        assert len(message) == 128                           # the whole SM0
        # length 62, type EoE with counter 1, then the header and the fixed body
        assert message[:6] == bytes.fromhex("3e0000000012")
        assert message[6:68] == FRAMED_BODY and not any(message[68:])


def test_the_master_sets_emergencies_and_fragments_aside():
    emergency = encode_emergency(0x8700, 0x01, counter=1)
    fragment = bytes.fromhex("0800 0000 00 32" "0001 0000" "ffffffff".replace(" ", ""))
    assert len(drive(eoe_job(), [emergency, fragment, SUCCESS])) == 1
    # A fragment whose frame info 2 is not 0 (fragment 1, offset 1 block, frame 2; or bits
    # that would read as result 0x0201) is still a fragment, not the response refusing.
    for info2 in ("4120", "0102"):
        fragment = bytes.fromhex("0800 0000 00 32 0001".replace(" ", "") + info2 + "ffffffff")
        assert len(drive(eoe_job(), [fragment, SUCCESS])) == 1


@pytest.mark.parametrize("answer, message", [
    (REFUSED, r"\[set ip\]: EoE set IP parameter refused: result 0x0201 \(no IP support\)"),
    (bytes.fromhex("0400 0000 00 20" "0200 0200".replace(" ", "")),
     r"EoE request with mailbox error 2 \(unsupported protocol\)"),
    (encode_upload_request(0x1018, 1, 2), r"mailbox type 3 where an EoE response"),
    (bytes.fromhex("0400 0000 00 22" "0701 0000".replace(" ", "")),
     r"EoE frame type 7 where a set IP parameter response \(type 3\)"),
    (bytes.fromhex("0200 0000 00 22" "0301".replace(" ", "")), r"unreadable EoE response"),
])
def test_the_master_names_what_went_wrong(answer, message):
    with pytest.raises(ApplyError, match=r"slave 'drive'.*" + message):
        drive(eoe_job(), [answer])


def test_the_master_gives_up_after_the_timeout_and_on_a_small_mailbox():
    with pytest.raises(ApplyError, match="no mailbox response in time"):
        drive(eoe_job(timeout=30), [])
    small = MailboxPlan(MailboxArea(0x1000, 48), MailboxArea(0x1080, 48))
    with pytest.raises(ApplyError, match=r"SM0, 48 bytes\) cannot carry the EoE request "
                                         r"\(68 bytes\)"):
        drive(eoe_job(plan=small), [])


# --------------------------------------------------------------------------- ENI -> OP

def eni_with_eoe(esi_file: Path, kinds: list[str],
                 cmds: dict[int, list[EoeInitCmd]]) -> NetworkPlan:
    """A compiled line with EoE InitCmds added to slaves, as an ENI file carries them
    (written and read back)."""
    text = "slaves:\n" + "".join(f"  - {{name: s{i}, device: {k}}}\n"
                                 for i, k in enumerate(kinds))
    plan = build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library([esi_file], cache=False)).plan
    for position, added in cmds.items():
        plan.slaves[position].mailbox.eoe_init_cmds.extend(copy.deepcopy(added))
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "eoe.eni.xml")


def test_eoe_settings_are_replayed_up_to_op(esi_file):
    plan = eni_with_eoe(esi_file, ["FX-EOE", "FX-EOEONLY", "FX-COE"], {
        0: [EoeInitCmd([Transition.PS], "eoe ip", FIXED_BODY, timeout=2000),
            EoeInitCmd([Transition.SO], "eoe gateway", bytes.fromhex("02000000")
                       + GATEWAY_ONLY)],
        1: [EoeInitCmd([Transition.IP], "eoe init", FRAMED_BODY),
            EoeInitCmd([Transition.PS], "disabled", MAC_ONLY, disabled=True)]})
    events: list[str] = []
    with Network.virtual(plan, esi=[esi_file], on_event=lambda e: events.append(e.text)) \
            as net:
        seen: list[AlState] = []
        server = net.segment.slaves[0].mailbox.eoe
        handle = server.handle
        server.handle = lambda data, state: (seen.append(state), handle(data, state))[1]
        net.up()
        assert net.state == AlState.OP
        drive, eoe_only, coe_only = net.segment.slaves
        assert drive.eoe_ip == eoe.IpParameters(
            mac=bytes.fromhex("020000000007"), ip=IPv4Address("10.0.0.7"),
            subnet_mask=IPv4Address("255.255.0.0"), default_gateway=IPv4Address("10.0.0.2"))
        assert eoe_only.eoe_ip == PARAMS                     # the disabled one not sent
        assert coe_only.eoe_ip is None
        # Before the AL request: PS in PREOP, SO in SAFEOP.
        assert seen == [AlState.PREOP, AlState.SAFEOP]
    assert "EoE IP parameters of 's0' set: ip 10.0.0.7/255.255.0.0, gateway 10.0.0.1, " \
           "mac 02:00:00:00:00:07" in events
    assert "EoE IP parameters of 's0' set: gateway 10.0.0.2" in events


def test_a_slave_without_eoe_fails_with_the_mailbox_error(esi_file):
    plan = eni_with_eoe(esi_file, ["FX-EOE", "FX-COE"],
                        {1: [EoeInitCmd([Transition.PS], "eoe ip", FIXED_BODY)]})
    with Network.virtual(plan, esi=[esi_file]) as net:
        with pytest.raises(ApplyError, match=r"slave 's1' \[eoe ip\]: the slave answered the "
                                             r"EoE request with mailbox error 2 "
                                             r"\(unsupported protocol\)"):
            net.up()
        assert net.master.progress["s1"].last_command == "eoe ip"
        assert net.segment.slaves[1].state == AlState.PREOP    # no SAFEOP request sent


def test_a_slave_without_ip_support_fails_with_0x0201(esi_file):
    plan = eni_with_eoe(esi_file, ["FX-NOIP"],
                        {0: [EoeInitCmd([Transition.PS], "eoe ip", FIXED_BODY)]})
    with Network.virtual(plan, esi=[esi_file]) as net:
        with pytest.raises(ApplyError, match=r"slave 's0' \[eoe ip\]: EoE set IP parameter "
                                             r"refused: result 0x0201 \(no IP support\)"):
            net.up()
        assert net.segment.slaves[0].eoe_ip is None


# --------------------------------------------------------------------------- the corpus ENI

def test_eni1_sets_the_ip_parameters_on_the_wire(corpus, tshark_path, tmp_path):
    eni = corpus / "eni" / "rocos-ethercat" / "eni1.xml"
    pcap = tmp_path / "eni1.pcapng"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(corpus / "esi"), "--simulated-time", "--cycles", "5",
                           "--pcap", str(pcap),
                           "--format", "json"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["ok"] and [(s["highest_state"], s["state"]) for s in report["slaves"]] \
        == [("OP", "INIT")]
    assert "EoE IP parameters of 'Elmo Drive' set: ip 192.168.1.4/255.255.255.0, gateway " \
           "192.168.1.10, dns 0.0.0.0, name '', mac 10:18:9e:ff:01:04" in report["events"]
    fields = ["ecat_mailbox.eoe.type", "ecat_mailbox.eoe.init.ipaddr",
              "ecat_mailbox.eoe.init.subnetmask", "ecat_mailbox.eoe.init.defaultgateway",
              "ecat_mailbox.eoe.init.macaddr"]
    rows = {tuple(v[0] if v else "" for v in p.values())
            for p in tshark_fields(pcap, fields, display_filter="ecat_mailbox.eoe")}
    assert rows == {("2", "192.168.1.4", "255.255.255.0", "192.168.1.10", "10:18:9e:ff:01:04"),
                    ("3", "", "", "", "")}
    assert tshark_malformed(pcap) == []


def test_eni1_settings_are_stored_in_the_emulated_drive(corpus):
    with Network.virtual(corpus / "eni" / "rocos-ethercat" / "eni1.xml",
                         esi=[corpus / "esi"]) as net:
        net.up()
        assert net.state == AlState.OP
        [drive] = net.segment.slaves
        assert drive.eoe_ip == eoe.IpParameters(
            mac=bytes.fromhex("10189eff0104"), ip=IPv4Address("192.168.1.4"),
            subnet_mask=IPv4Address("255.255.255.0"),
            default_gateway=IPv4Address("192.168.1.10"), dns_server=IPv4Address("0.0.0.0"),
            dns_name="")
        net.down()


def test_the_ec_engineer_eni_still_reaches_op(corpus):
    with Network.virtual(corpus / "eni" / "rocos-ethercat" / "eni.xml",
                         esi=[corpus / "esi"]) as net:
        net.up()
        assert net.state == AlState.OP
        assert [s.eoe_ip for s in net.segment.slaves] == [None]
        net.down()
