"""ESI3xx: the CoE object dictionary and the CoE InitCmds written from it."""

from __future__ import annotations

from typing import Iterator, NamedTuple

from ecatcfg.esi import datatypes
from ecatcfg.esi.coe import (
    TRANSITION_STATE, DictEntry, device_dictionary, dictionary_with_objects, write_refusal,
    write_target,
)
from ecatcfg.esi.lint.checks.common import hex4
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule, file_rule
from ecatcfg.esi.model import CoeInitCmd, Device, Dictionary, DictObject, Source
from ecatcfg.esi.slots import PluggedModule, fits, plugged_module


def _init_cmds(dev: Device) -> list[CoeInitCmd]:
    if dev.mailbox is None or dev.mailbox.coe is None:
        return []
    return [c for c in dev.mailbox.coe.init_cmds
            if not (c.depend_on_slot or c.depend_on_slot_group)]


class _Target(NamedTuple):
    """A CoE InitCmd of the file, what the dictionary says of the subindex it writes
    (``write_target``), and whose command it is: ``""`` for a device's own, ``"Module
    'X': "`` for a module's (the findings' prefix)."""

    cmd: CoeInitCmd
    found: DictEntry | DictObject | None
    owner: str
    shown: str           # the object written, as messages show it



def _init_cmd_targets(ctx: FileContext) -> Iterator[_Target]:
    """Every CoE InitCmd of the file with its dictionary lookup: each device's own
    commands against the device's dictionary, then each module's (ETG.2000
    ``Module/Mailbox/CoE/InitCmd``, downloaded for the plugged module after the device's)
    against the module's own dictionary and the dictionaries of this file's devices that
    take the module in a slot, its ``DependOnSlot`` index moved to the first slot it fits
    (``esi/slots.py``).  A command is left out when no dictionary that could hold its
    object lists objects (a device without a dictionary, a module library whose stations
    are in other files): nothing to check it against."""
    for dev in ctx.esi.devices:
        dic = dictionary_with_objects(dev)
        if dic is None:
            continue
        for cmd in _init_cmds(dev):
            if cmd.index is not None:
                yield _Target(cmd, write_target(dic, cmd.index, cmd.subindex,
                                                cmd.complete_access), "", hex4(cmd.index))
    for mod in ctx.esi.modules:
        coe = mod.mailbox.coe if mod.mailbox else None
        if coe is None or not coe.init_cmds:
            continue
        own = mod.profile.dictionary if mod.profile else None
        # (dictionary, the module plugged in the station, where)
        places: list[tuple[Dictionary, PluggedModule | None, str]] = []
        if own is not None and own.objects:
            places.append((own, None, ""))
        stations = 0
        for dev in ctx.esi.devices:
            dic = dictionary_with_objects(dev)
            number = next((n for n, slot in enumerate(dev.slots.slots, start=1)
                           if fits(slot, mod)), None) if dev.slots else None
            if dic is not None and number is not None:
                places.append((dic, plugged_module(dev, number, mod),
                               f"{dev.type_name} slot {number}"))
                stations += 1
        for cmd in coe.init_cmds:
            if cmd.index is None or not places:
                continue
            found: DictEntry | DictObject | None = None
            shown = hex4(cmd.index)
            for dic, plugged, where in places:
                moved = cmd.index if plugged is None else plugged.object_index(
                    cmd.index, cmd.depend_on_slot, cmd.depend_on_slot_group)
                found = write_target(dic, moved, cmd.subindex, cmd.complete_access)
                shown = hex4(cmd.index) + (f" ({hex4(moved)} in {where})"
                                           if moved != cmd.index else "")
                if found is not None:
                    break
            if found is None and not stations:
                continue          # maybe the station's object: its file is another
            yield _Target(cmd, found, f"Module {mod.type_name!r}: ", shown)


@file_rule("ESI301", "error", "a CoE InitCmd writes an object the dictionary does not have", """
    Mailbox/CoE/InitCmd makes every configurator download this value at start-up.  The
    device's dictionary lists objects, but not this one (or not this subindex), so the slave
    will most likely answer abort 0x06020000 / 0x06090011 and the state change fails.  A
    module's InitCmds (downloaded when it is plugged) are looked up in the module's own
    dictionary and in the dictionaries of the file's devices whose slots take it.""")
def init_cmd_object_missing(ctx: FileContext) -> Iterator[Hit]:
    for cmd, found, owner, shown in _init_cmd_targets(ctx):
        what = f"{owner}InitCmd writes {shown}:{cmd.subindex or 0:02X}"
        if found is None:
            yield Hit(cmd.source, f"{what}; the dictionary has no such object")
        elif not isinstance(found, DictEntry):
            yield Hit(cmd.source, f"{what}; the object has no such subindex")


@file_rule("ESI302", "error", "a CoE InitCmd writes an object that is read-only then", """
    The dictionary's Flags/Access for the object (or subitem) do not allow writing in the AL
    state the InitCmd runs in (I->P and P->S commands run in PREOP, S->O in SAFEOP, ...): ro,
    or a WriteRestrictions list without that state.  The slave answers abort 0x06010002
    (read-only) or 0x08000022 (wrong state) and the transition fails.  Module InitCmds
    are checked too (see ESI301 for their dictionaries); compile refuses such a command.""")
def init_cmd_read_only(ctx: FileContext) -> Iterator[Hit]:
    for cmd, found, owner, shown in _init_cmd_targets(ctx):
        for transition in cmd.transitions:
            state = TRANSITION_STATE.get(transition.upper())
            why = write_refusal(found, state) if state is not None else None
            if why is not None:
                yield Hit(cmd.source, f"{owner}InitCmd ({transition}, runs in {state}) "
                          f"writes {shown}:{cmd.subindex or 0:02X}: {why}")


@device_rule("ESI303", "error", "a data type name is not known", """
    The type is neither an ETG.2000 base type (BOOL, USINT, UINT, UDINT, REAL, STRING(n),
    ARRAY [a..b] OF T, and the CoE spellings UNSIGNED16, INTEGER32 ...) nor defined in the
    device's Dictionary/DataTypes.  Its size and encoding are then unknown: SDO values cannot
    be typed and process data cannot be decoded.""")
def unknown_data_type(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    dic = device_dictionary(dev)
    defined = set(dic.data_types) if dic is not None else set()

    def unknown(name: str | None, source: Source, what: str) -> Iterator[Hit]:
        if name and name not in defined and datatypes.canonical(name) is None:
            yield Hit(source, f"{what} has the unknown data type {name!r}")

    if dic is not None:
        for dt in dic.data_types.values():
            if dt.base_type:
                yield from unknown(dt.base_type, dt.source, f"DataType {dt.name!r} BaseType")
            for item in dt.sub_items:
                yield from unknown(item.type, item.source,
                                   f"DataType {dt.name!r} SubItem {item.name!r}")
        for obj in dic.objects.values():
            yield from unknown(obj.type, obj.source, f"Object {hex4(obj.index)}")
    for pdo in dev.pdos:
        for entry in pdo.entries:
            yield from unknown(entry.data_type, entry.source,
                               f"PDO {hex4(pdo.index)} entry {hex4(entry.index)}")


@file_rule("ESI304", "error", "a CoE InitCmd's data does not fit the object's size", """
    The InitCmd's Data has a length the object (or subitem) it writes does not take, from
    its BitSize in the dictionary: a number of another size, a string longer than declared
    or empty (a shorter string fits: CANopen strings are as long as written).  Slaves check
    the length of an SDO download and answer abort 0x06070010 (length of service parameter
    does not match) / 0x06070012 (too long) / 0x06070013 (too short), and the transition
    fails.  CompleteAccess commands write whole objects and are not compared.  Module
    InitCmds are checked too (see ESI301 for their dictionaries).""")
def init_cmd_size(ctx: FileContext) -> Iterator[Hit]:
    for cmd, found, owner, shown in _init_cmd_targets(ctx):
        if cmd.complete_access or cmd.data is None:
            continue
        if not isinstance(found, DictEntry) or not found.bit_size:
            continue
        want = (found.bit_size + 7) // 8
        if datatypes.bit_size(found.type) is not None \
                and not datatypes.download_fits(found.type, want, len(cmd.data)):
            yield Hit(cmd.source, f"{owner}InitCmd writes {len(cmd.data)} byte(s) to "
                      f"{shown}:{cmd.subindex or 0:02X}, a {found.type} of {want} byte(s)")
