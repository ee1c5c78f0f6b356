"""ESI6xx: modular devices (ETG.2000 MDP): slots, modules and module libraries."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esc import MODULE_IDENT_LIST
from ecatcfg.esi.coe import TRANSITION_STATE, dictionary_with_objects, write_refusal, write_target
from ecatcfg.esi.lint.checks.common import repeats
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule, file_rule
from ecatcfg.esi.model import Device
from ecatcfg.esi.slots import fits, plugged_module, ungrouped_indices


@device_rule("ESI601", "error", "a Slot names a module ident no known module has", """
    Slot/ModuleIdent (and Slot/@Default) list the modules that fit the slot by their
    Type/@ModuleIdent.  No module of this file or of the module libraries it references
    (InfoReference) has this ident, so the slot cannot be filled with it.  Not checked while
    a referenced library is missing (ESI602 reports that).""")
def slot_ident_unknown(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if dev.slots is None:
        return
    known = ctx.known_module_idents()
    if known is None:
        return
    for slot in dev.slots.slots:
        idents = list(slot.module_idents)
        if slot.default_ident is not None and slot.default_ident not in idents:
            idents.append(slot.default_ident)
        for ident in idents:
            if ident not in known:
                yield Hit(slot.source, f"Slot {slot.name!r} names module ident "
                          f"0x{ident:08X}, which no known module has")


@file_rule("ESI602", "error", "an InfoReference names a module library that is not found", """
    <InfoReference> names a file (an EtherCATModule library) that holds module descriptions
    this file's slots use.  It is looked for relative to this file (Windows separators
    accepted), then by file name beside it and among the files being linted.  Without it,
    modules cannot be configured; keep the library with the device file.""")
def info_reference_missing(ctx: FileContext) -> Iterator[Hit]:
    for ref in ctx.references:
        if ref.error:
            yield Hit(ref.source, f"InfoReference {ref.text!r}: {ref.error}")
        elif ref.path is None:
            yield Hit(ref.source, f"InfoReference {ref.text!r}: module library not found")


@file_rule("ESI603", "error", "two modules of a file have the same ident", """
    Slots and topologies name a module by Type/@ModuleIdent; two modules with one ident make
    the choice arbitrary.""")
def duplicate_module_ident(ctx: FileContext) -> Iterator[Hit]:
    for mod, first in repeats(ctx.esi.modules, lambda m: m.ident):
        yield Hit(mod.source, f"Module {mod.type_name!r} has the ident 0x{mod.ident:08X} "
                  f"of {first.type_name!r} at line {first.source.line}")


@device_rule("ESI604", "error", "a module marks an index DependOnSlotGroup but fits a slot of no "
             "slot group", """
    Index@DependOnSlotGroup moves a module's PDO or object index by the number of the slot
    group its slot belongs to (Slot/@SlotGroup) times SlotGroupPdoIncrement or
    SlotGroupIndexIncrement (ETG.2000 Slots; esi/slots.py).  This slot belongs to no group,
    so there is no number to move the index by: taken as written it could configure another
    group's object, and ``ecatcfg compile`` refuses the module in this slot.  Give the slot
    its SlotGroup, or take the attribute off indices that do not depend on a group.""")
def ungrouped_slot_group_index(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if dev.slots is None:
        return
    for number, slot in enumerate(dev.slots.slots, start=1):
        if slot.slot_group is not None:
            continue
        for mod in ctx.esi.modules:
            if not fits(slot, mod):
                continue
            found = ungrouped_indices(plugged_module(dev, number, mod))
            if found:
                yield Hit(slot.source, f"Slot {slot.name!r} belongs to no slot group, but "
                          f"module {mod.type_name!r}, which fits it, marks the index at "
                          f"line {found[0].line} DependOnSlotGroup")


@device_rule("ESI606", "warning", "a slot group is described twice, or not at all", """
    Slots/SlotGroupData describes a slot group (its name for a configuration tool) by the
    number the slots give in Slot/@SlotGroup.  Two descriptions of one number, or a slot of a
    number no SlotGroupData describes while the device describes others, leave a tool to
    guess which group is meant.  The indices a group moves depend on the number alone, so
    nothing sent changes; a device without any SlotGroupData (Beckhoff's EL69xx, EP1908)
    is not reported.""")
def slot_group_data(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if dev.slots is None or not dev.slots.groups:
        return
    for group, first in repeats(dev.slots.groups, lambda g: g.number):
        yield Hit(group.source, f"SlotGroupData describes slot group {group.number} again "
                  f"(first at line {first.source.line})")
    described = {g.number for g in dev.slots.groups}
    for slot in dev.slots.slots:
        if slot.slot_group is not None and slot.slot_group not in described:
            yield Hit(slot.source, f"Slot {slot.name!r} belongs to slot group "
                      f"{slot.slot_group}, which no SlotGroupData describes")


@device_rule("ESI605", "error", "the module ident list is to be downloaded but 0xF030 cannot be "
             "written", """
    Slots/@DownloadModuleIdentList makes a configurator download the configured module
    ident list (object 0xF030, ETG.5001) in DownloadModuleListTransition (PS by default).
    The device's dictionary lists objects, but not 0xF030, or declares it read-only in the
    state that transition runs in: the slave answers abort 0x06020000 or 0x06010002 and
    never reaches SAFEOP (compile refuses such a device with modules plugged).  Without
    the attribute the list is not downloaded, whatever the dictionary has.""")
def module_ident_list_not_writable(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    slots = dev.slots
    dic = dictionary_with_objects(dev)
    if slots is None or not slots.download_module_ident_list or dic is None:
        return
    transition = slots.download_transition.upper()
    state = TRANSITION_STATE.get(transition)
    coe = dev.mailbox.coe if dev.mailbox else None
    found = write_target(dic, MODULE_IDENT_LIST, 0, bool(coe and coe.complete_access))
    if found is None:
        yield Hit(slots.source, "DownloadModuleIdentList, but the dictionary has no object "
                  f"0x{MODULE_IDENT_LIST:04X}")
        return
    why = write_refusal(found, state) if state is not None else None
    if why is not None:
        yield Hit(slots.source, f"DownloadModuleIdentList ({transition}, runs in {state}), "
                  f"but 0x{MODULE_IDENT_LIST:04X} is not writable then: {why}")
