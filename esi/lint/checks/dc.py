"""ESI4xx: distributed-clock op modes (Dc/OpMode)."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule
from ecatcfg.esi.model import DcOpMode, Device

# AssignActivate: the low byte goes to ESC register 0x0980, the high byte to 0x0981, whose
# bit 0 enables cyclic operation and bits 1/2 generate SYNC0/SYNC1.
AA_CYCLIC, AA_SYNC0, AA_SYNC1 = 0x0100, 0x0200, 0x0400


def _modes(dev: Device) -> list[DcOpMode]:
    return dev.dc.opmodes if dev.dc is not None else []


@device_rule("ESI401", "warning", "a DC op mode's AssignActivate generates no SYNC signal", """
    AssignActivate enables the cyclic unit (0x0981 bit 0) but neither SYNC0 nor SYNC1
    (bits 1 and 2), so the slave gets no sync pulse: the mode behaves like free run while
    the configurator treats it as DC-synchronous.  Latch-only modes may do this on purpose;
    a synchronous mode needs 0x0300 (SYNC0) or 0x0700 (SYNC0 + SYNC1).""")
def assign_activate_no_sync(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for mode in _modes(dev):
        aa = mode.assign_activate
        if aa is not None and aa & AA_CYCLIC and not aa & (AA_SYNC0 | AA_SYNC1):
            yield Hit(mode.source, f"OpMode {mode.name!r}: AssignActivate 0x{aa:04X} "
                      "activates neither SYNC0 nor SYNC1")


@device_rule("ESI402", "error", "a DC op mode activates SYNC without the cyclic unit", """
    AssignActivate sets SYNC0 or SYNC1 (0x0981 bits 1/2) but not bit 0, which starts cyclic
    operation: the SYNC signals never start, and a slave that waits for them refuses OP
    (AL status 0x0030 / 0x002C).  Use 0x0300 or 0x0700.""")
def assign_activate_without_cyclic(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for mode in _modes(dev):
        aa = mode.assign_activate
        if aa is not None and aa & (AA_SYNC0 | AA_SYNC1) and not aa & AA_CYCLIC:
            yield Hit(mode.source, f"OpMode {mode.name!r}: AssignActivate 0x{aa:04X} sets "
                      "SYNC bits but not the cyclic-operation bit 0x0100")


@device_rule("ESI403", "error", "a DC op mode's cycle settings contradict each other", """
    A cycle time is negative, or a fixed shift time is not shorter than the fixed cycle time
    of the same SYNC signal (the shift moves the pulse within one cycle).  No configurator
    can program 0x09A0/0x09A4 and the start time 0x0990 from such values.""")
def cycle_settings(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for mode in _modes(dev):
        for n, cycle, factor, shift in (
                (0, mode.cycle_time_sync0, mode.cycle_time_sync0_factor, mode.shift_time_sync0),
                (1, mode.cycle_time_sync1, mode.cycle_time_sync1_factor, mode.shift_time_sync1)):
            if cycle is not None and cycle < 0:
                yield Hit(mode.source, f"OpMode {mode.name!r}: CycleTimeSync{n} is negative "
                          f"({cycle} ns)")
            elif cycle and not factor and shift is not None and abs(shift) >= cycle:
                yield Hit(mode.source, f"OpMode {mode.name!r}: ShiftTimeSync{n} {shift} ns is "
                          f"not shorter than CycleTimeSync{n} {cycle} ns")


@device_rule("ESI404", "error", "two DC op modes of a device have the same name", """
    Topologies and configurators choose a DC op mode by its Name; with two modes of one name
    the choice is arbitrary.  Beckhoff files give two versions of a mode under one name for
    different TwinCAT builds (VendorSpecific/TwinCAT @UseFromBuildNo / @IgnoreFromBuildNo);
    such pairs, whose build ranges do not overlap, are not reported.""")
def duplicate_opmode(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    by_name: dict[str, list[DcOpMode]] = {}
    for mode in _modes(dev):
        earlier = by_name.setdefault(mode.name, [])
        clash = next((m for m in earlier if m.overlaps(mode)), None)
        earlier.append(mode)
        if clash is not None:
            yield Hit(mode.source, f"OpMode {mode.name!r} repeats the name of line "
                      f"{clash.source.line}")
