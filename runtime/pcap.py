"""Recording every frame a master sends and receives as pcapng (opens in Wireshark), and
reading captures back.

scapy writes the file (its pcapng writer, fed the raw frame bytes: nothing is dissected on
the way).  The file is written beside its final name and renamed when the recording closes,
so a reader never sees half a capture under that name; a FIFO (Wireshark reading live) or a
character device is written directly (``fileio.OutputFile``).

:func:`read_capture` reads what tcpdump, Wireshark and dumpcap write: pcapng (any number of
interface blocks, each with its own ``if_tsresol``: microseconds by default, nanoseconds
from Wireshark's and ethercrab's writers) and classic libpcap (magic 0xA1B2C3D4 for
microseconds, 0xA1B23C4D for nanoseconds, in either byte order).  scapy's readers parse
both; this function gives each frame its number and time in nanoseconds.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecatcfg.fileio import OutputFile
from ecatcfg.runtime.clock import WALL

if TYPE_CHECKING:                   # scapy is imported when a recording starts
    from scapy.utils import RawPcapNgWriter

    from ecatcfg.runtime.clock import Clock

LINKTYPE_ETHERNET = 1
DIRECTION_INBOUND, DIRECTION_OUTBOUND = 1, 2     # pcapng EPB flags, bits 0-1


def read_capture(path: str | os.PathLike[str]) -> Iterator[tuple[int, int, bytes]]:
    """``(number, time_ns, frame)`` of every Ethernet frame of a pcapng or libpcap file, the
    number counted from 1 over all records, as Wireshark numbers them.  A file of neither
    format is a ``ValueError`` naming it."""
    from scapy.error import Scapy_Exception
    from scapy.utils import RawPcapNgReader, RawPcapReader

    try:
        reader: Any = RawPcapReader(str(path))     # picks pcapng or libpcap by the magic
    except Scapy_Exception as exc:
        raise ValueError(f"{path}: not a pcapng or libpcap capture ({exc})") from None
    with reader:
        pcapng = isinstance(reader, RawPcapNgReader)
        # libpcap: one link type for the file; the fraction is µs or, with the
        # nanosecond magic, ns (scapy calls it usec either way).
        scale = 1 if getattr(reader, "nano", False) else 1000
        for number, (data, meta) in enumerate(reader, 1):
            if pcapng:
                if meta.linktype != LINKTYPE_ETHERNET:
                    continue
                ticks = (meta.tshigh << 32) | meta.tslow
                time_ns = ticks * 1_000_000_000 // meta.tsresol
            else:
                if reader.linktype != LINKTYPE_ETHERNET:
                    continue
                time_ns = meta.sec * 1_000_000_000 + meta.usec * scale
            yield number, time_ns, bytes(data)


class _Frame(bytes):
    """Frame bytes that can carry scapy's ``direction`` attribute."""

    direction: int


class PcapRecorder:
    """``recorder(frame, sent)`` appends one frame; ``close()`` publishes the file."""

    def __init__(self, path: str | os.PathLike[str], clock: Clock | None = None) -> None:
        """``clock``: where the frames' times come from (``time_ns``); the host's by
        default, a simulated wire's for a capture on simulated time."""
        from scapy.utils import RawPcapNgWriter

        self._time_ns = (clock or WALL).time_ns

        self.path = Path(path)
        self._out = OutputFile(self.path, mode=0o644)
        # scapy's pcapng writer opens its file by name (no file object): the temporary file,
        # or the device node or FIFO itself.
        writer = RawPcapNgWriter(self._out.name)
        writer.linktype = LINKTYPE_ETHERNET
        writer.write_header(None)                # section and interface blocks
        self._writer: RawPcapNgWriter | None = writer
        self.frames = 0

    def __call__(self, frame: bytes, sent: bool) -> None:
        # scapy's writer takes the pcapng direction flag from the packet's ``direction``
        # attribute, and the time as float seconds.
        if self._writer is None:
            raise ValueError(f"the pcap recording {self.path} is closed")
        packet = _Frame(frame)
        packet.direction = DIRECTION_OUTBOUND if sent else DIRECTION_INBOUND
        self._writer.write_packet(packet, sec=self._time_ns() / 1e9)
        self.frames += 1

    def close(self) -> None:
        if self._writer is None:
            return
        self._writer.close()
        self._writer = None
        self._out.commit()

    def discard(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._out.discard()

    def __enter__(self) -> PcapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
