"""Modules plugged into the slots of a modular device (ETG.2000, ``Slots`` and ``Module``).

Device-level rules that both the compiler (a topology's ``modules:``) and the virtual segment
(a station emulated from its ESI or its ENI) follow, so they are written once here:

- a module in slot N (from 1) has its PDO indices moved by (N - 1) x ``SlotPdoIncrement``
  and its object indices by (N - 1) x ``SlotIndexIncrement``; a slot's own increment wins
  over the one given for all slots (ETG.2000, ``Slots/Slot``);
- only indices marked ``DependOnSlot`` move; a fixed index stays as written;
- a module PDO without ``Sm`` goes to its direction's process-data SyncManager.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ecatcfg.esi.model import Device, Dictionary, Module, Pdo, Profile


@dataclass(frozen=True, slots=True)
class PluggedModule:
    """``module`` in slot ``slot`` (from 1) with the offsets that slot gives it."""

    slot: int
    module: Module
    pdo_offset: int
    index_offset: int

    @property
    def dictionary(self) -> Dictionary | None:
        return self.module.profile.dictionary if self.module.profile else None


def plugged_module(device: Device, number: int, module: Module) -> PluggedModule:
    """``module`` in slot ``number`` (from 1) of ``device``, which must have ``Slots``."""
    if device.slots is None:
        raise ValueError(f"{device.type_name} has no Slots")
    slot = device.slots.slots[number - 1]
    pdo_inc = slot.slot_pdo_increment if slot.slot_pdo_increment is not None \
        else device.slots.slot_pdo_increment
    idx_inc = slot.slot_index_increment if slot.slot_index_increment is not None \
        else device.slots.slot_index_increment
    return PluggedModule(number, module, (number - 1) * (pdo_inc or 0),
                         (number - 1) * (idx_inc or 0))


def module_dictionaries(plugged: list[PluggedModule]) -> list[tuple[int, Dictionary]]:
    """(object index offset, dictionary) of each plugged module that has a dictionary."""
    return [(p.index_offset, p.dictionary) for p in plugged if p.dictionary is not None]


def with_modules(device: Device, plugged: list[PluggedModule]) -> Device:
    """``device`` with the PDOs and dictionaries of its plugged modules, moved by their
    slots' increments."""
    if not plugged:
        return device
    rx, tx = list(device.rx_pdos), list(device.tx_pdos)
    for p in plugged:
        for pdo in p.module.rx_pdos + p.module.tx_pdos:
            moved = _moved_pdo(device, pdo, p.pdo_offset, p.index_offset)
            (rx if pdo.direction == "rx" else tx).append(moved)
    profiles = list(device.profiles) + [
        Profile(dic.source, dictionary=_moved_dictionary(dic, offset))
        for offset, dic in module_dictionaries(plugged)]
    return replace(device, rx_pdos=rx, tx_pdos=tx, profiles=profiles)


def _moved_pdo(device: Device, pdo: Pdo, pdo_offset: int, index_offset: int) -> Pdo:
    entries = [replace(e, index=(e.index or 0) + (index_offset if e.depend_on_slot and e.index
                                                   else 0)) for e in pdo.entries]
    sm = pdo.sm
    if sm is None:
        found = device.default_sm(pdo.direction)
        sm = found.number if found else None
    return replace(pdo, index=(pdo.index or 0) + (pdo_offset if pdo.depend_on_slot else 0),
                   sm=sm, entries=entries)


def _moved_dictionary(dic: Dictionary, offset: int) -> Dictionary:
    objects = {}
    for index, obj in dic.objects.items():
        moved = index + offset if obj.depend_on_slot else index
        objects[moved] = replace(obj, index=moved)
    return Dictionary(dic.data_types, objects, dic.source)
