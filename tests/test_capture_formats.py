"""The conformance harness reads classic libpcap (tcpdump's format: microsecond and
nanosecond magic, both byte orders) as well as pcapng (several interface blocks, each with
its own ``if_tsresol``), through ``runtime/pcap.py``'s ``read_capture``.

The self-made files are written here with ``struct`` from the formats' specifications
(libpcap: the tcpdump.org file format; pcapng: IETF draft-ietf-opsawg-pcapng), not with the
reader under test.  A real capture of the corpus is converted to libpcap with editcap (the
Wireshark suite) into a temporary folder; tshark's own reading of the same file gives the
frame times, and the harness's replay of the converted file must equal its replay of the
original.
"""

from __future__ import annotations

import shutil
import struct
import subprocess
from decimal import Decimal
from pathlib import Path

import pytest
from conformance import exchanges, replay, sii_dumps

import prereq
from ecatcfg.esi.library import Library
from ecatcfg.runtime.pcap import read_capture

# Two EtherCAT frames: a BRD of register 0x0000 from the master (source MAC bit 1 clear)
# and the same frame returned by the line (the first ESC sets the U/L bit) with wkc 2.
MASTER = bytes.fromhex("ffffffffffff") + bytes.fromhex("010101010101")
RETURNED = bytes.fromhex("ffffffffffff") + bytes.fromhex("030101010101")


def _ecat(source: bytes, wkc: int) -> bytes:
    datagram = struct.pack("<BBHHHHH", 7, 0x11, 0, 0x0000, 2, 0, 0) + b"\0\0" + \
        struct.pack("<H", wkc)
    header = struct.pack("<H", len(datagram) | 0x1000)
    frame = source + b"\x88\xa4" + header + datagram
    return frame.ljust(60, b"\0")


FRAMES = [(1_700_000_000, 123_456_789, _ecat(MASTER, 0)),
          (1_700_000_000, 123_556_789, _ecat(RETURNED, 2))]


def _libpcap(endian: str, nano: bool) -> bytes:
    magic = 0xA1B23C4D if nano else 0xA1B2C3D4
    out = struct.pack(endian + "IHHiIII", magic, 2, 4, 0, 0, 65535, 1)
    for sec, ns, frame in FRAMES:
        fraction = ns if nano else ns // 1000
        out += struct.pack(endian + "IIII", sec, fraction, len(frame), len(frame)) + frame
    return out


@pytest.mark.parametrize("endian", ["<", ">"])
@pytest.mark.parametrize("nano", [False, True])
def test_libpcap_in_both_byte_orders_and_resolutions(tmp_path, endian, nano):
    path = tmp_path / "line.pcap"
    path.write_bytes(_libpcap(endian, nano))
    got = list(read_capture(path))
    want = [(n, sec * 10**9 + (ns if nano else ns // 1000 * 1000), frame)
            for n, (sec, ns, frame) in enumerate(FRAMES, 1)]
    assert got == want
    [ex] = exchanges(path)                          # the harness pairs request and reply
    assert (ex.number, ex.request, ex.reply) == (1, FRAMES[0][2], FRAMES[1][2])


def _block(kind: int, body: bytes) -> bytes:
    body = body.ljust((len(body) + 3) // 4 * 4, b"\0")
    length = 12 + len(body)
    return struct.pack("<II", kind, length) + body + struct.pack("<I", length)


def _option(code: int, value: bytes) -> bytes:
    return struct.pack("<HH", code, len(value)) + value.ljust((len(value) + 3) // 4 * 4, b"\0")


def _pcapng_two_interfaces() -> bytes:
    """SHB; IDB 0 without if_tsresol (microseconds); IDB 1 with if_tsresol 9 (ns);
    the master's frame on interface 0, the returned one on interface 1."""
    shb = _block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1))
    idb0 = _block(1, struct.pack("<HHI", 1, 0, 65535))
    idb1 = _block(1, struct.pack("<HHI", 1, 0, 65535) + _option(9, b"\x09") + _option(0, b""))
    blocks = shb + idb0 + idb1
    for interface, (sec, ns, frame) in enumerate(FRAMES):
        ticks = sec * 10**6 + ns // 1000 if interface == 0 else sec * 10**9 + ns
        blocks += _block(6, struct.pack("<IIIII", interface, ticks >> 32, ticks & 0xFFFFFFFF,
                                        len(frame), len(frame)) + frame)
    return blocks


def test_pcapng_with_two_interfaces_of_different_resolutions(tmp_path):
    path = tmp_path / "line.pcapng"
    path.write_bytes(_pcapng_two_interfaces())
    (sec0, ns0, f0), (sec1, ns1, f1) = FRAMES
    assert list(read_capture(path)) == [(1, sec0 * 10**9 + ns0 // 1000 * 1000, f0),
                                        (2, sec1 * 10**9 + ns1, f1)]
    [ex] = exchanges(path)
    assert ex.reply == f1


def test_a_file_of_neither_format_is_named(tmp_path):
    path = tmp_path / "notes.pcap"
    path.write_bytes(b"not a capture at all, just text\n" * 4)
    with pytest.raises(ValueError, match="not a pcapng or libpcap capture"):
        list(read_capture(path))


# -- a real capture, converted ------------------------------------------------------------

CAPTURE = "ethercrab/soem-sdinfo-ek1100-el1004.pcapng"


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        prereq.missing(name, "not installed (the Wireshark suite)", prereq.TOOLS)
    return str(path)


@pytest.mark.parametrize("fmt", ["pcap", "nsecpcap"])
def test_a_real_capture_converted_to_libpcap_replays_as_the_original(corpus, tmp_path, fmt):
    original = corpus / "pcap" / CAPTURE
    converted = tmp_path / "capture.pcap"
    subprocess.run([_tool("editcap"), "-F", fmt, str(original), str(converted)], check=True,
                   capture_output=True, timeout=60)
    assert converted.read_bytes()[:4] in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1")
    # tshark's own reading of the converted file: frame numbers and times.
    fields = subprocess.run([_tool("tshark"), "-r", str(converted), "-T", "fields",
                             "-e", "frame.number", "-e", "frame.time_epoch"],
                            check=True, capture_output=True, text=True, timeout=120).stdout
    want = [(int(n), int(Decimal(t) * 10**9)) for n, t in
            (line.split("\t") for line in fields.splitlines())]
    assert [(n, t) for n, t, _ in read_capture(converted)] == want
    library = Library([corpus / "esi"], cache=False)
    dumps = sii_dumps(corpus / "sii")
    a = replay(original, library, CAPTURE, dumps)
    b = replay(converted, library, CAPTURE, dumps)
    assert a.usable and b.usable
    assert (b.compared, b.counts, b.slaves) == (a.compared, a.counts, a.slaves)
    assert b.compared > 200
