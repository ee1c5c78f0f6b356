"""EtherCAT frames and datagrams on the wire: one codec for the master and the virtual segment.

A frame is Ethernet (dst, src, EtherType 0x88A4) + a 2-byte EtherCAT header (bits 0-10
length of all datagrams, bits 12-15 type, 1 = DLPDU) + datagrams.  A datagram is a 10-byte
header (cmd, idx, address, length/flags, irq), its data and a 2-byte working counter
(ETG.1000.4; ``docs/protocol-notes.md`` §1).  Everything is built and taken apart with ``struct``:
this runs once per frame on both sides, where scapy would cost a millisecond a frame.
scapy (``scapy.contrib.ethercat``) describes the same layout and serves the tests as an
independent dissector.

The virtual segment works on a frame *in place*: :func:`datagram_offsets` says where each
datagram's header, data and WKC sit in the frame's ``bytearray``, so processing a datagram
is slicing, not copying.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (DATAGRAM_OVERHEAD, ETH_HEADER_SIZE, ETHERTYPE, FRAME_HEADER, MIN_FRAME,
                         LOGICAL_CMDS)
from ecatcfg.record import field, record

if TYPE_CHECKING:
    from ecatcfg.eni.plan import CyclicCmd, InitCmd

ETH_HEADER = struct.Struct("!6s6sH")
ECAT_HEADER = struct.Struct("<H")
DATAGRAM_HEADER = struct.Struct("<BBHHHH")       # cmd, idx, adp, ado, len|flags, irq
LOGICAL_HEADER = struct.Struct("<BBIHH")         # cmd, idx, 32-bit logical address, ...
WKC = struct.Struct("<H")

ETH_LEN = ETH_HEADER.size                        # 14
FRAME_HEADER_END = ETH_LEN + ECAT_HEADER.size    # 16: the first datagram starts here
DG_HEADER_LEN = DATAGRAM_HEADER.size             # 10
ECAT_TYPE_DLPDU = 1
# The sizes esc.py gives the compiler (frame budgets) are these layouts' sizes.
assert (ETH_LEN, ECAT_HEADER.size, DG_HEADER_LEN + WKC.size) == (
    ETH_HEADER_SIZE, FRAME_HEADER, DATAGRAM_OVERHEAD)

LEN_MASK = 0x07FF            # datagram length, bits 0-10
CIRCULATING = 0x4000         # bit 14: the frame has passed a closed port 0 once
MORE = 0x8000                # bit 15: another datagram follows

MASTER_MAC = bytes.fromhex("010101010101")     # SOEM's source address (priMAC, nicdrv.c)
BROADCAST_MAC = b"\xff" * 6



class FrameError(EcatcfgError):
    """A frame that is not a well-formed EtherCAT frame (too short, lengths that disagree)."""


@record
class Datagram:
    """One datagram.  ``address`` is ADP | ADO << 16 for physical and broadcast commands and
    the 32-bit logical address for LRD/LWR/LRW, as it sits on the wire."""

    cmd: int
    idx: int
    address: int
    data: bytes | bytearray
    wkc: int = 0
    irq: int = 0
    circulating: bool = False

    @classmethod
    def physical(cls, cmd: int, adp: int, ado: int, data: bytes | int, idx: int = 0) -> Datagram:
        """A physical or broadcast datagram; ``data`` may be a length for a read."""
        payload = bytes(data)
        return cls(cmd, idx, (adp & 0xFFFF) | (ado & 0xFFFF) << 16, payload)

    @classmethod
    def logical(cls, cmd: int, address: int, data: bytes | int, idx: int = 0) -> Datagram:
        payload = bytes(data)
        return cls(cmd, idx, address & 0xFFFFFFFF, payload)

    @property
    def adp(self) -> int:
        return self.address & 0xFFFF

    @property
    def ado(self) -> int:
        return self.address >> 16

    @property
    def size(self) -> int:
        """Bytes this datagram takes in a frame: header, data, WKC."""
        return DG_HEADER_LEN + len(self.data) + WKC.size


def datagram_for(cmd: InitCmd | CyclicCmd, data: bytes) -> Datagram:
    """The datagram an ENI command describes (an InitCmd or a cyclic Cmd: ``cmd`` with
    ``addr`` for logical commands, ``adp``/``ado`` otherwise), carrying ``data``."""
    if cmd.cmd in LOGICAL_CMDS:
        return Datagram.logical(cmd.cmd, cmd.addr or 0, data)
    return Datagram.physical(cmd.cmd, cmd.adp or 0, cmd.ado or 0, data)


@record
class Frame:
    """A decoded EtherCAT frame."""

    datagrams: list[Datagram] = field(default_factory=list)
    dst: bytes = BROADCAST_MAC
    src: bytes = MASTER_MAC


def encode(datagrams: list[Datagram], src: bytes = MASTER_MAC, dst: bytes = BROADCAST_MAC,
           pad: bool = True) -> bytes:
    """The Ethernet frame carrying ``datagrams`` (padded to 60 bytes unless ``pad=False``)."""
    body = bytearray()
    last = len(datagrams) - 1
    for i, dg in enumerate(datagrams):
        n = len(dg.data)
        flags = n | (MORE if i < last else 0) | (CIRCULATING if dg.circulating else 0)
        body += struct.pack("<BBIHH", dg.cmd, dg.idx, dg.address, flags, dg.irq)
        body += dg.data
        body += WKC.pack(dg.wkc)
    if len(body) > LEN_MASK:
        raise FrameError(f"{len(body)} bytes of datagrams do not fit one frame (at most "
                         f"{LEN_MASK})")
    frame = (ETH_HEADER.pack(dst, src, ETHERTYPE)
             + ECAT_HEADER.pack(len(body) | ECAT_TYPE_DLPDU << 12) + body)
    if pad and len(frame) < MIN_FRAME:
        frame += bytes(MIN_FRAME - len(frame))
    return frame


def datagram_offsets(frame: bytes | bytearray | memoryview) -> list[tuple[int, int]]:
    """Where each datagram's header and data start: ``[(header_offset, data_length), ...]``.

    Raises :class:`FrameError` for a frame that is not EtherCAT or whose lengths disagree
    (the datagrams must lie within the EtherCAT header's length; padding may follow them,
    inside that length as well as after it).
    """
    if len(frame) < FRAME_HEADER_END + DG_HEADER_LEN + WKC.size:
        raise FrameError(f"frame of {len(frame)} bytes is too short for one datagram")
    (ethertype,) = struct.unpack_from("!H", frame, 12)
    if ethertype != ETHERTYPE:
        raise FrameError(f"EtherType 0x{ethertype:04X} is not EtherCAT (0x{ETHERTYPE:04X})")
    (word,) = ECAT_HEADER.unpack_from(frame, ETH_LEN)
    if word >> 12 != ECAT_TYPE_DLPDU:
        raise FrameError(f"EtherCAT frame type {word >> 12} is not a DLPDU (1)")
    total = word & LEN_MASK
    end = FRAME_HEADER_END + total
    if end > len(frame):
        raise FrameError(f"EtherCAT header says {total} bytes of datagrams, the frame holds "
                         f"{len(frame) - FRAME_HEADER_END}")
    out = []
    pos = FRAME_HEADER_END
    while True:
        if pos + DG_HEADER_LEN + WKC.size > end:
            raise FrameError(f"datagram at byte {pos} runs past the EtherCAT length ({total})")
        (flags,) = struct.unpack_from("<H", frame, pos + 6)
        n = flags & LEN_MASK
        if pos + DG_HEADER_LEN + n + WKC.size > end:
            raise FrameError(f"datagram at byte {pos} with {n} data bytes runs past the "
                             f"EtherCAT length ({total})")
        out.append((pos, n))
        pos += DG_HEADER_LEN + n + WKC.size
        if not flags & MORE:
            break
    # Bytes after the last datagram but inside the header's length are padding: TwinCAT
    # sends a 13-byte BWR with an EtherCAT length of 14 and real ESCs process it
    # (ethercrab-rs/ethercrab dumps/twincat-scan-devices-2.pcapng: working counter 2).
    return out


def decode(frame: bytes | bytearray) -> Frame:
    """Take a frame apart (copies the data; the segment's hot path uses offsets instead)."""
    result = Frame(dst=bytes(frame[0:6]), src=bytes(frame[6:12]))
    for pos, n in datagram_offsets(frame):
        cmd, idx, address, flags, irq = struct.unpack_from("<BBIHH", frame, pos)
        data = bytes(frame[pos + DG_HEADER_LEN:pos + DG_HEADER_LEN + n])
        (wkc,) = WKC.unpack_from(frame, pos + DG_HEADER_LEN + n)
        result.datagrams.append(Datagram(cmd, idx, address, data, wkc, irq,
                                         bool(flags & CIRCULATING)))
    return result
