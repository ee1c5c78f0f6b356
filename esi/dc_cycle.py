"""What a device's ESI says about the SYNC0 cycle time it runs at.

ETG.2000 gives no attribute for the cycle times a device accepts (``Dc`` has only
``UnknownFRMW``, ``Unknown64Bit``, ``ExternalRefClock``, ``PotentialReferenceClock``,
``TimeLoopControlOnly``; ``Info`` has none either: schema EtherCATInfo.xsd 1.17).  What it
does say, and what this module reads:

- ``Dc/OpMode``: per operation mode its ``AssignActivate`` (the value of 0x0980/0x0981)
  and ``CycleTimeSync0``: with a non-zero ``Factor``, SYNC0 runs at that many bus cycles
  (a negative factor: the bus cycle divided by it, as Beckhoff's oversampling terminals
  give -1 .. -1000); without one (or factor 0), at the value in ns, a fixed cycle; value
  0 without a factor gives no cycle (the master's choice).  ``CycleTimeSync1`` is the
  same against the SYNC0 cycle.  An OpMode's ``VendorSpecific`` is free XML
  (``VendorSpecificType``, ``xs:any``) with no meaning the standard defines, so it is not
  read.
- The dictionary's SyncManager parameter objects (ETG.1020): 0x1C32:05 (outputs) and
  0x1C33:05 (inputs) "Minimum cycle time" in ns, their ``DefaultData`` the value the
  device reports; real ESIs give it (Beckhoff terminals 0x1F40 = 8 µs and up).  Firmware
  built on the Slave Stack Code refuses a SYNC0 cycle shorter than it.

Shared by the compiler (the SYNC0 and SYNC1 cycle an ENI gets from the op mode) and the
diagnosis of a DC refusal (``runtime/master/diagnose.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.esc import (SM_INPUT_PARAMETER, SM_OUTPUT_PARAMETER, SM_PARAMETER_MIN_CYCLE,
                         sync0_running)
from ecatcfg.esi.coe import device_dictionary, match_infos
from ecatcfg.esi.model import DcOpMode, Device, Source


def sync_cycle(value: int | None, factor: int | None, base: int) -> int | None:
    """A SYNC cycle time in ns from an OpMode's ``CycleTimeSync0``/``CycleTimeSync1``:
    ``factor`` times ``base`` (the bus cycle for SYNC0, the SYNC0 cycle for SYNC1), a
    fraction of it for a negative factor, else the fixed ``value``; None when neither."""
    if factor is not None and factor != 0:
        return base * factor if factor > 0 else base // -factor
    return value or None


@dataclass(frozen=True, slots=True)
class Sync0Rule:
    """How one OpMode sets the SYNC0 cycle."""

    mode: str
    assign_activate: int
    factor: int | None          # non-zero: times the bus cycle (negative: a fraction)
    fixed_ns: int | None        # without a factor: this cycle in ns
    source: Source

    def cycle_ns(self, bus_cycle_ns: int | None) -> int | None:
        """The SYNC0 cycle this mode gives at ``bus_cycle_ns`` (None when it depends on a
        bus cycle that is not known, or the mode gives none)."""
        if self.factor:
            return sync_cycle(None, self.factor, bus_cycle_ns) if bus_cycle_ns else None
        return self.fixed_ns

    def text(self) -> str:
        if self.factor and self.factor > 0:
            how = ("SYNC0 every bus cycle" if self.factor == 1
                   else f"SYNC0 every {self.factor} bus cycles")
        elif self.factor:
            how = f"SYNC0 {-self.factor} times per bus cycle"
        elif self.fixed_ns:
            how = f"a fixed SYNC0 cycle of {us(self.fixed_ns)}"
        else:
            how = "no SYNC0 cycle of its own"
        return (f"DC OpMode {self.mode!r} (AssignActivate 0x{self.assign_activate:04X}, "
                f"{self.source.file}:{self.source.line}): {how}")


def sync0_rules(device: Device) -> list[Sync0Rule]:
    """The device's OpModes that switch SYNC0 on (AssignActivate bits 8 and 9, cyclic unit
    and SYNC0: ETG.1000.4 0x0981), with how each sets its cycle."""
    if device.dc is None:
        return []
    return [_rule(m) for m in device.dc.opmodes
            if m.assign_activate is not None and sync0_running(m.assign_activate >> 8)]


def _rule(mode: DcOpMode) -> Sync0Rule:
    assert mode.assign_activate is not None
    factor = mode.cycle_time_sync0_factor or None
    return Sync0Rule(mode.name, mode.assign_activate, factor,
                     None if factor else (mode.cycle_time_sync0 or None), mode.source)


@dataclass(frozen=True, slots=True)
class MinCycleTime:
    """A minimum cycle time the device's dictionary gives (0x1C32:05 or 0x1C33:05)."""

    ns: int
    index: int
    source: Source | None

    def text(self) -> str:
        where = f", {self.source.file}:{self.source.line}" if self.source else ""
        return (f"minimum cycle time {us(self.ns)} (ESI 0x{self.index:04X}:"
                f"{SM_PARAMETER_MIN_CYCLE:02X} default{where})")


def min_cycle_time(device: Device) -> MinCycleTime | None:
    """The larger non-zero default of 0x1C32:05 and 0x1C33:05 in the device's dictionary
    (the firmware checks SYNC0 against its outputs' and inputs' minimum alike); None when
    the dictionary gives neither."""
    dic = device_dictionary(device)
    if dic is None:
        return None
    found: list[MinCycleTime] = []
    for index in (SM_OUTPUT_PARAMETER, SM_INPUT_PARAMETER):
        obj = dic.objects.get(index)
        dt = dic.data_types.get(obj.type) if obj is not None else None
        if obj is None or obj.info is None or dt is None:
            continue
        # The record's subentries as its type lists them (a SubItem without SubIdx takes
        # the next number), subindex 0 first when the type leaves it out.
        subentries: list[tuple[int, str]] = []
        last = -1
        for item in dt.sub_items:
            sub = item.subindex if item.subindex is not None else last + 1
            subentries.append((sub, item.name))
            last = max(last, sub)
        if not any(sub == 0 for sub, _ in subentries):
            subentries.insert(0, (0, "SubIndex 000"))
        info = match_infos(sorted(subentries), obj.info.sub_items).get(SM_PARAMETER_MIN_CYCLE)
        if info is None:
            continue
        if info.default_data is not None:
            ns = int.from_bytes(info.default_data[:4], "little")
        elif info.default_value is not None:
            ns = info.default_value
        else:
            continue
        if ns:
            found.append(MinCycleTime(ns, index, info.source))
    return max(found, key=lambda m: m.ns) if found else None


def us(ns: int) -> str:
    """A time in ns as µs, the unit cycle times are spoken of in (250000 -> "250 µs")."""
    return f"{ns / 1000:g} µs"
