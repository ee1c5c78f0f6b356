"""Inputs of emulated slaves by name: what ``simulate --input NAME=VALUE`` and its control
channel set, so that someone testing a PLC program against the virtual line can press a
virtual button from a terminal or a script.

An input is named as ``compile`` names the variable of the process image (and TwinCAT and
EC-Engineer name theirs): the slave's name, its TxPDO's name and the entry's name, joined by
dots (``buttons.Channel 1.Input``), or by index (``axis1.0x6064:00``).  The slave puts a held
value where its current PDO mapping places that entry (``EmulatedSlave.hold_input``), so a
master that maps other PDOs finds it where it looks.
"""

from __future__ import annotations

from ecatcfg.record import record
from ecatcfg.runtime.segment.slave import EmulatedSlave
from ecatcfg.runtime.segment.virtual import VirtualSegment

# Words for a one-bit input, as a user types them.
_TRUE = ("1", "true", "on", "yes")
_FALSE = ("0", "false", "off", "no")
_SIGNED = ("SINT", "INT", "DINT", "LINT", "INTEGER8", "INTEGER16", "INTEGER32", "INTEGER64")


@record(frozen=True)
class InputEntry:
    """An input entry of one emulated slave."""

    slave: EmulatedSlave
    index: int
    subindex: int
    bits: int
    data_type: str | None
    name: str                  # slave.PDO.entry

    def parse(self, text: str) -> int:
        """``text`` as a value of this entry: a number (``0x`` hex too), or for one bit
        also true/false/on/off; ValueError naming the entry when it does not fit."""
        word = text.strip().lower()
        if self.bits == 1 and word in _TRUE + _FALSE:
            return 1 if word in _TRUE else 0
        try:
            value = int(word, 0)
        except ValueError:
            raise ValueError(f"{self.name}: {text!r} is not a number") from None
        signed = (self.data_type or "").upper() in _SIGNED
        low = -(1 << (self.bits - 1)) if signed or value < 0 else 0
        high = (1 << (self.bits - 1)) - 1 if signed else (1 << self.bits) - 1
        if not low <= value <= high:
            raise ValueError(f"{self.name}: {value} does not fit {self.bits} bits"
                             f"{' ' + self.data_type if self.data_type else ''} "
                             f"({low}..{high})")
        return value

    def hold(self, value: int) -> None:
        self.slave.hold_input(self.index, self.subindex, self.bits, value)

    def release(self) -> None:
        self.slave.release_input(self.index, self.subindex)


def input_entries(seg: VirtualSegment) -> dict[str, InputEntry]:
    """Every input entry of the segment's slaves by its names: ``slave.PDO.entry`` and
    ``slave.0xIIII:SS`` (the first of a name given twice)."""
    out: dict[str, InputEntry] = {}
    for s in seg.wired:                 # every slave, on the frame or behind a cut cable
        for pdo in s.device.tx_pdos:
            for e in pdo.entries:
                if not e.index or e.subindex is None or not e.bit_len:
                    continue
                name = f"{s.name}.{pdo.name}.{e.name}"
                entry = InputEntry(s, e.index, e.subindex, e.bit_len, e.data_type, name)
                out.setdefault(name, entry)
                out.setdefault(f"{s.name}.0x{e.index:04X}:{e.subindex:02X}", entry)
    return out


def find_input(seg: VirtualSegment, name: str) -> InputEntry:
    """The input entry named ``name``; ValueError listing the slave's inputs (or the
    slaves) when there is none."""
    found = input_entries(seg)
    if name in found:
        return found[name]
    upper = {k.upper(): v for k, v in found.items()}   # 0x6064:00 spelled 0x6064:00 or lower
    if name.upper() in upper and ".0X" in name.upper():
        return upper[name.upper()]
    slave = next((s for s in sorted(seg.wired, key=lambda s: -len(s.name))
                  if name.startswith(s.name + ".")), None)
    if slave is None:
        raise ValueError(f"{name}: no emulated slave of that name (the slaves are "
                         f"{', '.join(s.name for s in seg.wired)})")
    mine = sorted({e.name for e in found.values() if e.slave is slave})
    if not mine:
        raise ValueError(f"{name}: slave {slave.name!r} has no inputs")
    shown = ", ".join(mine[:12]) + (f", ... ({len(mine)} in all)" if len(mine) > 12 else "")
    raise ValueError(f"{name}: slave {slave.name!r} has no input of that name; its inputs: "
                     f"{shown}")


__all__ = ["InputEntry", "find_input", "input_entries"]
