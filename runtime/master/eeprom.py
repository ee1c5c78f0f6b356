"""Reading and writing a slave's SII EEPROM through its ESC's EEPROM interface.

The ESC gives the master its EEPROM through registers 0x0500-0x050F (ESC Section II,
ETG.1000.4): 0x0500 = 0 hands the EEPROM to EtherCAT; a command is written to 0x0502 with
the word address in 0x0504 (and, for a write, the word in 0x0508); 0x0502 bit 15 stays set
while the ESC is busy, bits 11-14 report errors.  A read returns 4 or 8 bytes (bit 6); a
write stores one word and needs write enable (bit 0) in the same access.  After a word is
written the EEPROM chip runs its own write cycle (a few ms) and does not acknowledge a new
command meanwhile: the ESC reports that as bit 13, and the command is simply sent again.

Reading reuses the scan's SII reader (``runtime/master/scan.py``); nothing here knows the image's
layout beyond the identity and the configuration-area checksum (``esi/sii.py``).
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from ecatcfg.runtime.clock import monotonic
from ecatcfg.esc import (EEPROM_BUSY, EEPROM_ERROR_ACKNOWLEDGE, EEPROM_ERRORS, SII_ALIAS,
                         SII_CHECKSUM, SII_SIZE, SII_VENDOR_ID, Cmd, Reg,
                         eeprom_write_request)
from ecatcfg.esi.sii import CONFIG_AREA, SIZE_STEP, crc8
from ecatcfg.runtime.master.lockstep import Step, run_jobs, until_answered
from ecatcfg.runtime.master.replay import ApplyError
from ecatcfg.runtime.master.scan import sii_words
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram

READ_TIMEOUT = 0.5         # s per 4-word read (as the scan: IgH allows 500 ms for loading)
WRITE_TIMEOUT = 0.5        # s per word: the write cycle (5 ms at most for I2C EEPROMs) and
                           # the refused commands during it, with room for lost frames and
                           # for a master descheduled on a busy host (as READ_TIMEOUT)
HEADER_BYTES = 128         # words 0-0x3F: config area, identity, mailbox, size, version
IDENTITY = slice(2 * SII_VENDOR_ID, 2 * SII_VENDOR_ID + 12)   # vendor, product, revision


def identity(image: bytes) -> tuple[int, int, int]:
    """(vendor, product, revision) from SII words 8-13."""
    vendor, product, revision = struct.unpack("<III", image[IDENTITY])
    return vendor, product, revision


def fix_checksum(image: bytes) -> tuple[bytes, int | None]:
    """The image with a correct configuration-area checksum (word 7 low byte: CRC-8 of
    words 0-6), and the wrong value it had (None when it was right)."""
    crc = crc8(image[:CONFIG_AREA])
    if image[2 * SII_CHECKSUM] == crc:
        return image, None
    old = image[2 * SII_CHECKSUM]
    return image[:2 * SII_CHECKSUM] + bytes([crc]) + image[2 * SII_CHECKSUM + 1:], old


class InterruptedWrite(ApplyError):
    """A write that stopped part-way: which words were written (their write command
    completed without error) before it stopped, and the word it stopped at."""

    def __init__(self, message: str, written: list[int], word: int) -> None:
        super().__init__(message)
        self.written = written     # words written and confirmed, in order
        self.word = word           # the word being written: its command may have gone in


class Eeprom:
    """One slave's EEPROM, addressed by position (auto-increment), over ``transport``."""

    def __init__(self, transport: Transport, position: int) -> None:
        self.transport = transport
        self.position = position
        self.adp = -position & 0xFFFF
        self.reads = 0          # EEPROM read commands done (4 words each)
        self.writes = 0         # word write commands done, retries included
        self.refused = 0        # commands the EEPROM did not acknowledge (write cycle)

    def _run(self, step: Step[bytes]) -> bytes:
        out: list[bytes] = []

        def job() -> Step[None]:
            out.append((yield from step))
        run_jobs(self.transport, [job()])
        return out[0]

    def _take(self) -> Step[bytes]:
        """0x0500 = 0: the EEPROM belongs to EtherCAT (not the PDI) for what follows."""
        owner = Datagram.physical(Cmd.APWR, self.adp, Reg.EEPROM_CONFIG, b"\x00")
        yield from until_answered([owner], monotonic() + READ_TIMEOUT,
                                  ApplyError(f"position {self.position}: no answer"))
        return b""

    def read(self, nbytes: int | None = None, at_least: int = 0,
             progress: Callable[[int], None] | None = None) -> bytes:
        """``nbytes`` from word 0, or the whole EEPROM as its size word (0x3E) gives it
        and at least ``at_least`` bytes (an erased size word, 0xFFFF, counts as the header
        alone: an erased EEPROM has no size to trust)."""
        def step() -> Step[bytes]:
            yield from self._take()
            data = b""
            size = nbytes
            while size is None or len(data) < size:
                data += yield from self._words(len(data) // 2)
                if size is None and len(data) >= HEADER_BYTES:
                    word, = struct.unpack_from("<H", data, 2 * SII_SIZE)
                    size = max(HEADER_BYTES if word == 0xFFFF else (word + 1) * SIZE_STEP,
                               at_least + at_least % 2)
                if progress is not None:
                    progress(len(data))
            return data[:size]
        return self._run(step())

    def _words(self, word: int) -> Step[bytes]:
        self.reads += 1
        return (yield from sii_words(self.position, word, monotonic() + READ_TIMEOUT))

    def write(self, image: bytes, current: bytes,
              progress: Callable[[int], None] | None = None) -> list[int]:
        """Write the words of ``image`` that differ from ``current`` (what the EEPROM holds
        now), lowest address first; returns their addresses.  Raises
        :class:`InterruptedWrite` naming the words written when a word cannot be written."""
        todo = [w for w in range(len(image) // 2)
                if image[2 * w:2 * w + 2] != current[2 * w:2 * w + 2]]
        written: list[int] = []

        def step() -> Step[bytes]:
            yield from self._take()
            for word in todo:
                value, = struct.unpack_from("<H", image, 2 * word)
                try:
                    yield from self._write_word(word, value)
                except ApplyError as exc:
                    raise InterruptedWrite(f"word 0x{word:04X}: {exc}", written, word) from exc
                written.append(word)
                if progress is not None:
                    progress(len(written))
            return b""
        self._run(step())
        return written

    def _write_word(self, word: int, value: int) -> Step[None]:
        """One word: send the write command, poll 0x0502 until not busy; a refused command
        (no acknowledge: the last word's write cycle) is sent again until the deadline."""
        deadline = monotonic() + WRITE_TIMEOUT
        request = Datagram.physical(Cmd.APWR, self.adp, Reg.EEPROM_CONTROL,
                                    eeprom_write_request(word, value))
        status = Datagram.physical(Cmd.APRD, self.adp, Reg.EEPROM_CONTROL, 2)
        where = f"position {self.position}"
        while True:
            self.writes += 1
            yield from until_answered([request], deadline,
                                      ApplyError(f"{where}: no answer to the write command"))
            while True:
                got = yield from until_answered(
                    [status], deadline, ApplyError(f"{where}: no answer to the EEPROM status"))
                control, = struct.unpack("<H", got[0].data)
                if not control & EEPROM_BUSY:
                    break
                if monotonic() > deadline:
                    raise ApplyError(f"{where}: the EEPROM stays busy (0x0502 = "
                                     f"0x{control:04X})")
            if control & EEPROM_ERRORS == EEPROM_ERROR_ACKNOWLEDGE:
                self.refused += 1
                if monotonic() > deadline:
                    raise ApplyError(f"{where}: the EEPROM does not acknowledge (0x0502 = "
                                     f"0x{control:04X})")
                continue
            if control & EEPROM_ERRORS:
                raise ApplyError(f"{where}: EEPROM error (0x0502 = 0x{control:04X}: "
                                 f"{_errors(control)})")
            return


def _errors(control: int) -> str:
    names = {11: "checksum", 12: "loading", 13: "no acknowledge", 14: "write enable"}
    return ", ".join(name for bit, name in names.items() if control >> bit & 1)


def alias_image(current: bytes, alias: int) -> bytes:
    """``current`` with SII word 4 = ``alias`` and the checksum fixed."""
    image = bytearray(current)
    struct.pack_into("<H", image, 2 * SII_ALIAS, alias)
    return fix_checksum(bytes(image))[0]
