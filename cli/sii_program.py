"""Programming a slave's SII EEPROM from the command line, shared by ``ecatcfg sii write``
and ``ecatcfg alias set``: back up, check the identity, fix the checksum, write, read back.

The protocol itself is ``runtime/master/eeprom.py``; this module decides what is safe to write and
says what happened, with the backup to restore when a write stops part-way.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from ecatcfg.cli.paths import output_file
from ecatcfg.errors import EcatcfgError, UsageError

if TYPE_CHECKING:   # the runtime is imported when a command runs
    from ecatcfg.runtime.master.eeprom import Eeprom


@contextlib.contextmanager
def open_eeprom(iface: str, position: int) -> Iterator[Eeprom]:
    """The EEPROM of the slave at ``position`` on ``iface`` (checked to be on the line)."""
    from ecatcfg.runtime.master.eeprom import Eeprom
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master.scan import count_slaves
    from ecatcfg.runtime.master.transport import Transport

    with RawLink(iface) as link:
        transport = Transport(link)
        n = count_slaves(transport)
        if position >= n:
            raise EcatcfgError(f"no slave at position {position}: {n} slave(s) answer on "
                               f"{iface}")
        yield Eeprom(transport, position)


def describe(image: bytes) -> str:
    """Identity, alias and checksum state of an image, for the output."""
    from ecatcfg.esi.sii import CONFIG_AREA, crc8
    from ecatcfg.runtime.master.eeprom import identity

    vendor, product, revision = identity(image)
    alias = int.from_bytes(image[8:10], "little")
    ok = crc8(image[:CONFIG_AREA]) == image[14]
    return (f"vendor 0x{vendor:x} product 0x{product:x} revision 0x{revision:x}, alias "
            f"{alias}, checksum {'ok' if ok else 'WRONG'}")


def backup_path(given: str | None, position: int) -> Path:
    if given:
        path = Path(given)
    else:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path(f"sii-backup-pos{position}-{stamp}.bin")
        n = 1
        while path.exists():
            n += 1
            path = Path(f"sii-backup-pos{position}-{stamp}-{n}.bin")
    return output_file(path, stdout=False)


def _words(words: list[int]) -> str:
    """0x0004, 0x0007, 0x0040-0x0052 ..."""
    runs: list[list[int]] = []
    for w in words:
        if runs and w == runs[-1][1] + 1:
            runs[-1][1] = w
        else:
            runs.append([w, w])
    return ", ".join(f"0x{a:04X}" if a == b else f"0x{a:04X}-0x{b:04X}" for a, b in runs)


def program(iface: str, position: int, image: bytes, *, backup: str | None, force: bool,
            source: str, alias: int | None = None) -> int:
    """Write ``image`` to the slave's EEPROM with a backup first and a read-back after.
    With ``alias``, ``image`` is ignored: the current image with SII word 4 = ``alias``."""
    from ecatcfg.fileio import write_atomic
    from ecatcfg.runtime.master.eeprom import (InterruptedWrite, alias_image, fix_checksum,
                                               identity)

    where = f"position {position}"
    saved = backup_path(backup, position)
    with open_eeprom(iface, position) as eeprom:
        current = eeprom.read(at_least=len(image))
        try:
            write_atomic(saved, current)
        except OSError as exc:
            raise UsageError(f"cannot write the backup {saved}: {exc.strerror}") from None
        print(f"{where}: {describe(current)}")
        print(f"backup: {saved} ({len(current)} bytes read)")
        if alias is not None:
            image = alias_image(current, alias)
            source = f"the current image with alias {alias}"
        elif identity(image) != identity(current) and not force:
            have = ":".join(f"0x{x:x}" for x in identity(current))
            want = ":".join(f"0x{x:x}" for x in identity(image))
            raise EcatcfgError(f"the image is of device {want}, the slave at {where} is "
                               f"{have}: nothing written (--force writes it anyway)", source)
        image, wrong = fix_checksum(image)
        if wrong is not None:
            print(f"checksum: word 7 said 0x{wrong:02X}, the configuration area's CRC is "
                  f"0x{image[14]:02X}: fixed")
        if len(image) > len(current):
            raise EcatcfgError(f"the image has {len(image)} bytes, the slave's EEPROM "
                               f"{len(current)} (SII word 0x3E): nothing written", source)
        try:
            written = eeprom.write(image, current)
        except InterruptedWrite as exc:
            done = f"{len(exc.written)} word(s) written ({_words(exc.written)})" \
                if exc.written else "no word written"
            done += f", word 0x{exc.word:04X} may or may not be written"
            print(f"ecatcfg: the write stopped: {exc}; {done}. The EEPROM now holds a mix "
                  f"of both images: restore the backup with 'ecatcfg sii write --iface "
                  f"{iface} --slave {position} --force {saved}'", file=sys.stderr)
            return 1
        back = eeprom.read(nbytes=len(image))
    differ = [w for w in range(len(image) // 2) if back[2 * w:2 * w + 2] !=
              image[2 * w:2 * w + 2]]
    print(f"wrote {len(written)} of {len(image) // 2} words (only the words that differ"
          f"{': ' + _words(written) if written and len(written) <= 8 else ''}); "
          f"{eeprom.writes} write commands, {eeprom.refused} refused during the EEPROM's "
          "write cycle and sent again")
    if differ:
        print(f"ecatcfg: the read-back differs from the image at {len(differ)} word(s) "
              f"({_words(differ)}); the backup is {saved}", file=sys.stderr)
        return 1
    print(f"verified: read back {len(image)} bytes, equal to {source}")
    return 0
