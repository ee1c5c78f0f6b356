"""ESI3xx: the CoE object dictionary and the CoE InitCmds written from it."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esi import datatypes
from ecatcfg.esi.coe import (
    TRANSITION_STATE, DictEntry, device_dictionary, dictionary_with_objects, lookup,
)
from ecatcfg.esi.lint.checks.common import hex4
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule
from ecatcfg.esi.model import CoeInitCmd, Device, DictObject, Source


def _init_cmds(dev: Device) -> list[CoeInitCmd]:
    if dev.mailbox is None or dev.mailbox.coe is None:
        return []
    return [c for c in dev.mailbox.coe.init_cmds if not c.depend_on_slot]


def _init_cmd_targets(dev: Device) -> Iterator[tuple[CoeInitCmd, DictEntry | DictObject | None]]:
    """(InitCmd, dictionary lookup of the subindex it writes) for a device whose dictionary
    lists objects.  A CompleteAccess command writes the whole object from its SubIndex (0 or
    1); subindex 0 of a record is often read-only and is then judged by subindex 1, the
    first entry the command really changes."""
    dic = dictionary_with_objects(dev)
    if dic is None:
        return
    for cmd in _init_cmds(dev):
        if cmd.index is None:
            continue
        found = lookup(dic, cmd.index, cmd.subindex)
        if cmd.complete_access and not cmd.subindex and isinstance(found, DictEntry) \
                and found.flags is not None and found.flags.access is not None \
                and "w" not in found.flags.access.value:
            first = lookup(dic, cmd.index, 1)
            found = first if isinstance(first, DictEntry) else found
        yield cmd, found


@device_rule("ESI301", "error", "a CoE InitCmd writes an object the dictionary does not have", """
    Mailbox/CoE/InitCmd makes every configurator download this value at start-up.  The
    device's dictionary lists objects, but not this one (or not this subindex), so the slave
    will most likely answer abort 0x06020000 / 0x06090011 and the state change fails.""")
def init_cmd_object_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for cmd, found in _init_cmd_targets(dev):
        if found is None:
            yield Hit(cmd.source, f"InitCmd writes {hex4(cmd.index)}:{cmd.subindex or 0:02X}; "
                      f"the dictionary has no object {hex4(cmd.index)}")
        elif not isinstance(found, DictEntry):
            yield Hit(cmd.source, f"InitCmd writes {hex4(cmd.index)}:{cmd.subindex or 0:02X}; "
                      f"object {hex4(cmd.index)} has no such subindex")


@device_rule("ESI302", "error", "a CoE InitCmd writes an object that is read-only then", """
    The dictionary's Flags/Access for the object (or subitem) do not allow writing in the AL
    state the InitCmd runs in (I->P and P->S commands run in PREOP, S->O in SAFEOP, ...): ro,
    or a WriteRestrictions list without that state.  The slave answers abort 0x06010002
    (read-only) or 0x08000022 (wrong state) and the transition fails.""")
def init_cmd_read_only(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for cmd, found in _init_cmd_targets(dev):
        if not isinstance(found, DictEntry) or found.flags is None \
                or found.flags.access is None:
            continue
        access = found.flags.access
        for transition in cmd.transitions:
            state = TRANSITION_STATE.get(transition.upper())
            if state is not None and not access.writable_in(state):
                why = (f"access {access.value!r}" if "w" not in access.value else
                       "writes allowed only in "
                       + (", ".join(sorted(access.write_states)) or "no state"))
                yield Hit(cmd.source, f"InitCmd ({transition}, runs in {state}) writes "
                          f"{hex4(cmd.index)}:{cmd.subindex or 0:02X}: {why}")


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


@device_rule("ESI304", "warning", "a CoE InitCmd's data size differs from the object's size", """
    The InitCmd's Data has another length than the object (or subitem) it writes, from its
    BitSize in the dictionary.  Slaves check the length of an SDO download and answer abort
    0x06070010 (length of service parameter does not match) / 0x06070012 / 0x06070013.
    CompleteAccess commands write whole objects and are not compared.""")
def init_cmd_size(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for cmd, found in _init_cmd_targets(dev):
        if cmd.complete_access or cmd.data is None:
            continue
        if not isinstance(found, DictEntry) or not found.bit_size:
            continue
        want = (found.bit_size + 7) // 8
        if len(cmd.data) != want and datatypes.bit_size(found.type) is not None:
            yield Hit(cmd.source, f"InitCmd writes {len(cmd.data)} byte(s) to "
                      f"{hex4(cmd.index)}:{cmd.subindex or 0:02X}, a {found.type} of "
                      f"{want} byte(s)")
