"""The mailbox/CoE codec against byte-exact references: the tables of docs/protocol-notes.md
§5 and §6 ("protocol-notes §N"), SOEM's own first SDO upload request as pysoem sent it to an
emulated slave, the abort codes of SOEM and SOES (SOEM's list also read from the pysoem
source in the corpus); and, when tshark is installed, Wireshark's EtherCAT mailbox
dissector reading our bytes."""

from __future__ import annotations

import logging
import re
import struct
import subprocess
import tarfile

import pytest
from conftest import _require

from ecatcfg.runtime import mailbox as mbx
from ecatcfg.runtime.mailbox import (
    ABORT_CODES, Abort, DownloadResponse, DownloadSegment, DownloadSegmentResponse,
    Emergency, InitiateDownload, InitiateUpload, MailboxCounter, MailboxError,
    MailboxHeader, MailboxProtocolError, MbxErrorDetail, MbxType, SdoAbort, SdoInfo,
    UnknownSdo, UploadResponse, UploadSegment, UploadSegmentRequest, decode, next_counter,
    pad_to,
)


def h(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


# -- references from SOEM and Wireshark --------------------------------------------------

def test_soem_upload_request_for_1c00_is_byte_identical():
    # pysoem 1.1.13 (SOEM's ecx_SDOread, ethercatcoe.c), captured on a veth pair: SOEM writes
    # mailbox `0a00 0000 00 13`, then `0020 40 001c 00` and four zero bytes into SM0 for its
    # first SDO (upload 0x1C00:00, counter 1).
    soem = h("0a00 0000 00 13") + h("0020 40 001c 00") + bytes(4)
    assert mbx.encode_upload_request(0x1C00, 0, 1) == soem
    header, msg = decode(pad_to(soem, 128))
    assert header == MailboxHeader(10, 0, 0, 0, MbxType.COE, 1)
    assert msg == InitiateUpload(0x1C00, 0, False)


def test_tshark_example_expedited_download_of_1c12():
    # Wireshark decodes SDO `2F 12 1C 00 01000000` (CoE, counter 1) as an expedited
    # 'Initiate Download' of 0x1C12:00 = 1 (packet-ecatmb.c).
    msg = mbx.encode_download_expedited(0x1C12, 0, b"\x01", 1)
    assert msg == h("0a00 0000 00 13 0020") + h("2F 12 1C 00 01000000")
    assert decode(msg)[1] == InitiateDownload(0x1C12, 0, b"\x01", 1, True, False)


# -- header and counter (protocol-notes §5) ----------------------------------------------

def test_header_bit_fields():
    header = MailboxHeader(length=0x1234, address=0x1001, channel=5, priority=3,
                           type=MbxType.FOE, counter=6)
    raw = header.pack()
    assert raw == h("3412 0110") + bytes((5 | 3 << 6, 4 | 6 << 4))
    assert MailboxHeader.unpack(raw) == header


@pytest.mark.parametrize("mbx_type,value", [("ERROR", 0), ("AOE", 1), ("EOE", 2), ("COE", 3),
                                            ("FOE", 4), ("SOE", 5), ("VOE", 15)])
def test_mailbox_types(mbx_type, value):
    assert MbxType[mbx_type] == value


def test_counter_runs_1_to_7_and_never_0():
    assert [next_counter(c) for c in range(8)] == [1, 2, 3, 4, 5, 6, 7, 1]
    counter = MailboxCounter()
    assert [counter() for _ in range(16)] == [1, 2, 3, 4, 5, 6, 7] * 2 + [1, 2]


def test_mailbox_error_reply():
    # Type 0, length 4, body 0x0001 + detail (SOES MBX_error, SOEM ec_mbxerrort).
    msg = mbx.encode_mailbox_error(MbxErrorDetail.UNSUPPORTED_PROTOCOL, 3)
    assert msg == h("0400 0000 00 30 0100 0200")
    header, content = decode(msg)
    assert header.type == MbxType.ERROR and header.counter == 3
    assert content == MailboxError(2) and content.name == "unsupported protocol"
    assert [d.value for d in MbxErrorDetail] == list(range(1, 10))
    assert MbxErrorDetail.INVALID_HEADER == 5 and MbxErrorDetail.SIZE_TOO_SHORT == 6


def test_pad_to_the_sm_length():
    msg = mbx.encode_upload_request(0x1000, 0, 2)
    padded = pad_to(msg, 128)
    assert len(padded) == 128 and padded[:16] == msg and padded[16:] == bytes(112)
    assert decode(padded) == decode(msg)          # padding is not part of the message
    with pytest.raises(ValueError, match="does not fit"):
        pad_to(msg, 15)


def test_bad_headers_name_the_mailbox_error_detail():
    with pytest.raises(MailboxProtocolError) as err:
        decode(h("0a00 0000"))
    assert err.value.detail == MbxErrorDetail.SIZE_TOO_SHORT
    for raw in (h("0000 0000 00 13") + bytes(10), h("0b00 0000 00 13") + bytes(10)):
        with pytest.raises(MailboxProtocolError) as err:
            decode(raw)                         # length 0, or longer than what is there
        assert err.value.detail == MbxErrorDetail.INVALID_HEADER
    with pytest.raises(MailboxProtocolError) as err:
        decode(h("0600 0000 00 13 0020 40 001c 00 00"))   # an SDO needs 10 bytes
    assert err.value.detail == MbxErrorDetail.SIZE_TOO_SHORT


# -- SDO command bytes (protocol-notes §6 table) ------------------------------------------

@pytest.mark.parametrize("n,command", [(1, 0x2F), (2, 0x2B), (3, 0x27), (4, 0x23)])
def test_expedited_download_command_byte(n, command):
    data = bytes(range(1, n + 1))
    msg = mbx.encode_download_expedited(0x6040, 0, data, 1)
    assert msg[8] == command
    assert msg[12:16] == data.ljust(4, b"\0")          # data at +6, zero-padded
    assert decode(msg)[1] == InitiateDownload(0x6040, 0, data, n, True, False)


@pytest.mark.parametrize("n,command", [(1, 0x4F), (2, 0x4B), (3, 0x47), (4, 0x43)])
def test_expedited_upload_response_command_byte(n, command):
    data = bytes(range(0xA1, 0xA1 + n))
    msg = mbx.encode_upload_expedited(0x1018, 1, data, 2)
    assert msg[6:10] == h("0030") + bytes((command, 0x18))    # service 3 = SDO response
    assert decode(msg)[1] == UploadResponse(0x1018, 1, data, n, True, False)


def test_expedited_upload_without_size_indicator_is_4_bytes():
    # IgH: expedited without the s bit -> 4 bytes.
    msg = h("0a00 0000 00 13 0030 42 0010 00 11223344")
    assert decode(msg)[1] == UploadResponse(0x1000, 0, h("11223344"), None, True, False)


def test_normal_download_with_complete_access():
    # As EC-Engineer writes it (docs/eni-exports.md §5): 0x1C12 complete access = 02 00 0016 0116.
    data = h("020000160116")
    msg = mbx.encode_download_normal(0x1C12, 0, len(data), data, 4, complete_access=True)
    assert msg == h("1000 0000 00 43 0020 31 121C 00 06000000") + data
    assert decode(msg)[1] == InitiateDownload(0x1C12, 0, data, 6, False, True)
    assert mbx.encode_download_normal(0x2000, 0, 300, b"abc", 1)[8] == 0x21


def test_responses_and_requests_without_data():
    assert mbx.encode_download_response(0x1C12, 0, 1) == h("0a00 0000 00 13 0030 60 121C 00") \
        + bytes(4)
    assert mbx.encode_download_response(0x1C12, 0, 1, complete_access=True)[8] == 0x70
    assert mbx.encode_upload_request(0x1C12, 0, 1, complete_access=True)[8] == 0x50
    assert mbx.encode_upload_segment_request(False, 1)[6:] == h("0020 60") + bytes(7)
    assert mbx.encode_upload_segment_request(True, 1)[8] == 0x70
    assert mbx.encode_download_segment_response(True, 1)[6:] == h("0030 30") + bytes(7)
    assert decode(mbx.encode_download_response(0x1C12, 0, 1, complete_access=True))[1] == \
        DownloadResponse(0x1C12, 0, True)
    assert decode(mbx.encode_download_segment_response(True, 1))[1] == \
        DownloadSegmentResponse(True)
    assert decode(mbx.encode_upload_segment_request(True, 1))[1] == UploadSegmentRequest(True)


def test_short_segments_are_padded_to_length_10_with_the_unused_count():
    # 0x00 | t<<4 | (7-n)<<1 | last: 3 bytes, toggle, last = 0x19; length 10.
    msg = mbx.encode_download_segment(b"abc", True, True, 5)
    assert msg == h("0a00 0000 00 53 0020 19") + b"abc" + bytes(4)
    assert decode(msg)[1] == DownloadSegment(b"abc", True, True)
    msg = mbx.encode_upload_segment(b"xy", False, True, 5)
    assert msg[8] == 0x0B and decode(msg)[1] == UploadSegment(b"xy", False, True)


def test_long_segments_take_their_length_from_the_mailbox_header():
    data = bytes(range(100))
    msg = mbx.encode_upload_segment(data, True, False, 1)
    assert struct.unpack_from("<H", msg)[0] == 3 + 100 and msg[8] == 0x10
    assert decode(pad_to(msg, 128))[1] == UploadSegment(data, True, False)
    # Exactly 7 bytes: no unused count, still length 10.
    msg = mbx.encode_download_segment(b"1234567", False, True, 1)
    assert msg[:2] == h("0a00") and msg[8] == 0x01
    assert decode(msg)[1] == DownloadSegment(b"1234567", False, True)


def test_abort_is_sent_with_service_2_by_either_side():
    msg = mbx.encode_abort(0x1C12, 1, 0x06010003, 7)
    assert msg == h("0a00 0000 00 73 0020 80 121C 01 03000106")
    assert decode(msg)[1] == Abort(0x1C12, 1, 0x06010003)
    # An abort that arrives with service 3 is read as an abort too.
    assert decode(h("0a00 0000 00 13 0030 80 0010 00 00000206"))[1] == \
        Abort(0x1000, 0, 0x06020000)


def test_unknown_command_specifier_is_reported_not_guessed():
    # ccs 6 = block upload (CANopen), not an EtherCAT SDO service.
    msg = h("0a00 0000 00 13 0020 C0 0010 00 00000000")
    assert decode(msg)[1] == UnknownSdo(2, 0xC0, 0x1000, 0)


def test_emergency_and_sdo_info():
    msg = mbx.encode_emergency(0x8130, 0x11, h("0102"), 2)
    assert msg == h("0a00 0000 00 23 0010 3081 11 0102000000")
    assert decode(msg)[1] == Emergency(0x8130, 0x11, h("0102000000"))
    msg = mbx.encode_sdo_info_error(0x06010000, 1)
    assert msg == h("0a00 0000 00 13 0080 07 00 0000 00000106")
    info = decode(msg)[1]
    assert isinstance(info, SdoInfo) and info.opcode == 7 and info.abort_code == 0x06010000


def test_other_protocols_are_returned_raw():
    msg = mbx.encode_mailbox(MbxType.FOE, b"\x01\x00abcd", 2)
    assert decode(msg) == (MailboxHeader(6, 0, 0, 0, MbxType.FOE, 2), (4, b"\x01\x00abcd"))


# -- abort codes (protocol-notes §6) ---------------------------------------------------------

def test_abort_code_names_follow_the_facts_sheet():
    assert len(ABORT_CODES) == 36
    assert ABORT_CODES[0x05030000] == "toggle bit not changed"
    assert ABORT_CODES[0x06020000] == "object does not exist in the object directory"
    assert ABORT_CODES[0x06010003] == \
        "subindex cannot be written, SI0 must be 0 for write access"
    assert ABORT_CODES[0x08000022].endswith("because of the present device state")
    error = SdoAbort(0x06090011, 0x1018, 5)
    assert str(error) == "SDO abort 0x06090011 (subindex does not exist) at 0x1018:05"
    assert error.code == 0x06090011 and error.exit_code == 1


# SOEM's list of SDO abort codes (soem/ethercatprint.c, ec_sdoerrorlist, after ETG.1000.6's
# table): 30 codes besides its "no error" and "unknown" entries ...
SOEM_ABORT_CODES = {
    0x05030000, 0x05040000, 0x05040001, 0x05040005, 0x06010000, 0x06010001, 0x06010002,
    0x06010003, 0x06010004, 0x06010005, 0x06010006, 0x06020000, 0x06040041, 0x06040042,
    0x06040043, 0x06040047, 0x06060000, 0x06070010, 0x06070012, 0x06070013, 0x06090011,
    0x06090030, 0x06090031, 0x06090032, 0x06090036, 0x08000000, 0x08000020, 0x08000021,
    0x08000022, 0x08000023,
}
# ... and the codes that SOES defines (soes/esc.h, ABORT_*) and SOEM's list lacks: the CiA 301
# block-transfer codes (ABORT_INVALID_BLOCK_SIZE, _INVALID_SEQUENCE_NUMBER, _BLOCK_CRC_ERROR),
# the module ident list mismatch of modular devices (ABORT_MODULE_LIST_MISMATCH),
# ABORT_RESOURCE_NOT_AVAILABLE and ABORT_NO_DATA_AVAILABLE.
SOES_ONLY_ABORT_CODES = {0x05040002, 0x05040003, 0x05040004, 0x06090033, 0x060A0023,
                         0x08000024}


def test_abort_codes_are_soems_list_plus_soes_extras(corpus):
    # SOEM's own table (ec_sdoerrorlist in ethercatprint.c, as bundled in pysoem's source
    # distribution), read from the corpus: every code it names, without its "no error" (0)
    # and "unknown" (0xFFFFFFFF) entries.
    tarball = corpus / "third-party" / "pysoem-1.1.13.tar.gz"
    if not tarball.is_file():
        _require(str(tarball))
    with tarfile.open(tarball) as tar:
        member = next(m for m in tar.getmembers() if m.name.endswith("/ethercatprint.c"))
        source = tar.extractfile(member).read().decode("latin-1")
    table = source.split("ec_sdoerrorlist[]", 1)[1].split("};", 1)[0]
    soem = {int(code, 16) for code in re.findall(r"\{\s*0x([0-9a-fA-F]{8})\s*,", table)}
    assert len(soem) == 32 and 0x06020000 in soem
    assert soem - {0, 0xFFFFFFFF} == SOEM_ABORT_CODES          # the list written out above
    assert set(ABORT_CODES) == (soem - {0, 0xFFFFFFFF}) | SOES_ONLY_ABORT_CODES


def test_abort_codes_cover_the_public_lists():
    assert set(ABORT_CODES) == SOEM_ABORT_CODES | SOES_ONLY_ABORT_CODES
    assert not SOEM_ABORT_CODES & SOES_ONLY_ABORT_CODES
    assert ABORT_CODES[0x06090033] == "detected module ident list does not match"
    assert ABORT_CODES[0x08000024] == "no data available"


# -- Wireshark as an independent decoder ------------------------------------------------------

FIELDS = ["ecat_mailbox.length", "ecat_mailbox.type", "ecat_mailbox.counter",
          "ecat_mailbox.coe.type", "ecat_mailbox.coe.sdoreq", "ecat_mailbox.coe.sdores",
          "ecat_mailbox.coe.sdoidx", "ecat_mailbox.coe.sdosub", "ecat_mailbox.coe.sdodata",
          "ecat_mailbox.coe.abortcode", "ecat_mailbox.coe.sdolength",
          "ecat_mailbox.coe.dsoldata", "ecat_mailbox.coe.sdoccsid.complete",
          "ecat_mailbox.coe.sdoccsds.toggle", "ecat_mailbox.coe.sdoccsds.lastseg",
          "ecat_mailbox.coe.sdoscsiu_expedited", "ecat_mailbox.coe.sdoinfoopcode",
          "ecat_mailbox.coe.sdoinfoerrorcode", "ecat_mailbox.coe.invalid",
          "ecat_mailbox.invalid"]


def test_tshark_decodes_our_mailbox_bytes(tmp_path, tshark_path):
    tshark = tshark_path
    logging.getLogger("scapy.runtime").setLevel(logging.CRITICAL)
    from scapy.contrib.ethercat import EtherCat, EtherCatFPWR
    from scapy.layers.l2 import Ether
    from scapy.utils import wrpcap

    messages = [
        mbx.encode_download_expedited(0x1C12, 0, b"\x01", 1),
        mbx.encode_upload_request(0x1C00, 0, 2),
        mbx.encode_abort(0x1234, 5, 0x06020000, 3),
        mbx.encode_upload_expedited(0x1018, 1, h("9a000000"), 4),
        mbx.encode_download_normal(0x1C12, 0, 6, h("020000160116"), 5, complete_access=True),
        mbx.encode_download_segment(b"abc", True, True, 6),
        mbx.encode_upload_normal(0x1008, 0, 20, b"Elmo Motion Control\0", 7),
        mbx.encode_sdo_info_error(0x06010000, 1),
    ]
    frames = [Ether(dst="ff:ff:ff:ff:ff:ff", src="01:01:01:01:01:01", type=0x88A4)
              / EtherCat() / EtherCatFPWR(idx=i, adp=0x1001, ado=0x1000,
                                          data=list(pad_to(m, 128)))
              for i, m in enumerate(messages)]
    pcap = tmp_path / "mailbox.pcap"
    wrpcap(str(pcap), frames)
    cmd = [tshark, "-r", str(pcap), "-T", "fields", "-E", "separator=\t",
           "-E", "occurrence=f"]
    for f in FIELDS:
        cmd += ["-e", f]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    rows = [dict(zip(FIELDS, line.split("\t"))) for line in out.splitlines()]
    assert len(rows) == len(messages)
    for row in rows:
        assert row["ecat_mailbox.coe.invalid"] == row["ecat_mailbox.invalid"] == ""
        assert row["ecat_mailbox.type"] == "3"

    def pick(row, *names):
        return tuple(row[f"ecat_mailbox.{n}"] for n in names)

    exp, upl, abort, exp_res, ca, seg, normal, info = rows
    assert pick(exp, "length", "counter", "coe.type", "coe.sdoreq", "coe.sdoidx", "coe.sdosub",
                "coe.sdodata", "coe.sdoccsid.complete") == \
        ("10", "1", "2", "1", "0x1c12", "0x00", "0x01", "0")
    assert pick(upl, "counter", "coe.sdoreq", "coe.sdoidx", "coe.sdosub") == \
        ("2", "2", "0x1c00", "0x00")
    assert pick(abort, "coe.type", "coe.sdoreq", "coe.abortcode") == ("2", "4", "0x06020000")
    assert pick(exp_res, "coe.type", "coe.sdores", "coe.sdoidx", "coe.sdosub",
                "coe.sdodata", "coe.sdoscsiu_expedited") == \
        ("3", "2", "0x1018", "0x01", "0x0000009a", "1")
    assert pick(ca, "length", "coe.sdoreq", "coe.sdoidx", "coe.sdolength",
                "coe.sdoccsid.complete") == ("16", "1", "0x1c12", "0x00000006", "1")
    assert pick(seg, "length", "coe.sdoreq", "coe.sdoccsds.toggle",
                "coe.sdoccsds.lastseg") == ("10", "0", "1", "1")
    # Wireshark shows all 7 bytes of a minimum segment (it ignores the unused count).
    assert bytes.fromhex(seg["ecat_mailbox.coe.dsoldata"].replace(":", "")) == \
        b"abc" + bytes(4)
    assert pick(normal, "length", "coe.sdores", "coe.sdoidx", "coe.sdolength") == \
        ("30", "2", "0x1008", "0x00000014")
    assert pick(info, "coe.type", "coe.sdoinfoopcode", "coe.sdoinfoerrorcode") == \
        ("8", "7", "0x06010000")
