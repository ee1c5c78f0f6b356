"""ESI6xx: modular devices (ETG.2000 MDP): slots, modules and module libraries."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esc import MODULE_IDENT_LIST
from ecatcfg.esi.coe import TRANSITION_STATE, dictionary_with_objects, write_refusal, write_target
from ecatcfg.esi.lint.checks.common import repeats
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule, file_rule
from ecatcfg.esi.model import Device


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


@device_rule("ESI604", "error", "a Slot belongs to a slot group, which ecatcfg cannot compile", """
    Slot/@SlotGroup puts a slot in a group of ``SlotGroupData``: the object and PDO indices
    of a module marked ``DependOnSlotGroup`` move by the group's place as well as by the
    slot's (ETG.2000 modular device profile).  ecatcfg does not compute those offsets, and a
    wrong index would configure another object, so ``ecatcfg compile`` refuses any module
    in such a slot: the device can only be compiled with its grouped slots empty.  This is
    a limit of ecatcfg, not a fault of the file; ``--ignore ESI604`` where the grouped slots
    stay empty.""")
def slot_group(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if dev.slots is None:
        return
    for slot in dev.slots.slots:
        if slot.slot_group is not None:
            yield Hit(slot.source, f"Slot {slot.name!r} belongs to slot group "
                      f"{slot.slot_group}; ecatcfg compile refuses modules in it "
                      "(SlotGroupData offsets are not implemented)")
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
