"""Modules plugged into the slots of a modular device (ETG.2000, ``Slots`` and ``Module``).

Device-level rules that both the compiler (a topology's ``modules:``) and the virtual segment
(a station emulated from its ESI or its ENI) follow, so they are written once here:

- modules take *positions* on the device, from 1, in slot order: a slot that takes one
  module (``MaxInstances`` 1) is one position even when empty, a slot that takes several
  (a remote I/O station's row of modules: UR20-FBC-EC, UTRIO UC20) one position per module
  plugged.  The position is the module's subindex in the module ident lists 0xF030 and
  0xF050 (ETG.5001 modular device profile);
- the module at position P has its PDO indices moved by (P - 1) x ``SlotPdoIncrement`` and
  its object indices by (P - 1) x ``SlotIndexIncrement`` (ETG.2000 ``Slots/Slot``; a slot's
  own increment wins over the one given for all slots): the UR20's third module has TxPdo
  0x1A02 and objects 0x6020, 0x8020; the Copley XE2's axis B 0x1740 and 0x6840;
- only indices marked ``DependOnSlot`` move; a fixed index stays as written (an Exclude
  by its own marks, else as its PDO's Index);
- a slot may belong to a slot group (``Slot/@SlotGroup``, the group described by
  ``Slots/SlotGroupData``: a drive's axis, a safety terminal's logic): indices marked
  ``DependOnSlotGroup`` move by the group's number x ``SlotGroupPdoIncrement`` (PDOs) or
  ``SlotGroupIndexIncrement`` (objects), the slot's own increment winning over the one given
  for all slots, as for the slot increments.  ETG.2100's ENI schema says it in its words:
  the index "will be adapted depend on the slot group number and the SlotGroupIndexIncrement
  value in the Slots-part of the device description".  An index marked both moves by both;
  the position (for ``DependOnSlot``) is counted over the whole device, groups or not.
  A ``DependOnSlotGroup`` index of a module in a slot of no group has no group number to
  move by: the compiler refuses it (:func:`ungrouped_indices`), lint reports it (ESI604);
- a module PDO without ``Sm`` goes to its direction's process-data SyncManager;
- a device PDO marked ``OverwrittenByModule`` gives way to the PDOs of the plugged modules.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ecatcfg.esc import array_downloads
from ecatcfg.esi.model import Device, Dictionary, Module, Pdo, Profile, Slot, Source


@dataclass(frozen=True, slots=True)
class PluggedModule:
    """``module`` in slot ``slot`` (from 1) at ``position`` (from 1) with its offsets: by
    its position (``DependOnSlot``) and by its slot's group (``DependOnSlotGroup``)."""

    slot: int
    module: Module
    pdo_offset: int
    index_offset: int
    position: int = 0
    default: bool = False          # plugged because the slot's default, not named
    slot_group: int | None = None  # Slot/@SlotGroup of its slot
    group_pdo_offset: int = 0
    group_index_offset: int = 0

    def pdo_index(self, index: int, depend_on_slot: bool, depend_on_slot_group: bool) -> int:
        """Where a PDO index (or an Exclude) of the module lands in this slot."""
        return (index + (self.pdo_offset if depend_on_slot else 0)
                + (self.group_pdo_offset if depend_on_slot_group else 0))

    def object_index(self, index: int, depend_on_slot: bool,
                     depend_on_slot_group: bool) -> int:
        """Where an object index of the module (a dictionary object, a PDO entry, an
        InitCmd's) lands in this slot; 0, a PDO entry's padding, names no object and stays."""
        if not index:
            return index
        return (index + (self.index_offset if depend_on_slot else 0)
                + (self.group_index_offset if depend_on_slot_group else 0))

    @property
    def dictionary(self) -> Dictionary | None:
        return self.module.profile.dictionary if self.module.profile else None

    @property
    def label(self) -> str:
        """How the ENI's PDO and variable names show the module: ``Module 3 (UR20-4DI-P)``."""
        return f"Module {self.position} ({self.module.name or self.module.type_name})"


def increments(device: Device, slot: Slot) -> tuple[int, int]:
    """(PDO, object index) increment of ``slot``: its own, else the one for all slots."""
    assert device.slots is not None
    pdo = slot.slot_pdo_increment if slot.slot_pdo_increment is not None \
        else device.slots.slot_pdo_increment
    idx = slot.slot_index_increment if slot.slot_index_increment is not None \
        else device.slots.slot_index_increment
    return pdo or 0, idx or 0


def group_increments(device: Device, slot: Slot) -> tuple[int, int]:
    """(PDO, object index) increment per slot group number of ``slot``: its own, else the
    one for all slots (ETG.2000 ``SlotGroupPdoIncrement``, ``SlotGroupIndexIncrement``)."""
    assert device.slots is not None
    pdo = slot.slot_group_pdo_increment if slot.slot_group_pdo_increment is not None \
        else device.slots.slot_group_pdo_increment
    idx = slot.slot_group_index_increment if slot.slot_group_index_increment is not None \
        else device.slots.slot_group_index_increment
    return pdo or 0, idx or 0


def takes_several(slot: Slot) -> bool:
    return (slot.max_instances or 1) > 1


def plug(device: Device, by_slot: dict[int, list[tuple[Module, bool]]]) -> list[PluggedModule]:
    """The modules of each slot (number from 1 -> [(module, plugged by default)], in plug
    order) with their positions and offsets, in position order."""
    if device.slots is None:
        raise ValueError(f"{device.type_name} has no Slots")
    plugged: list[PluggedModule] = []
    position = 0
    for number, slot in enumerate(device.slots.slots, start=1):
        pdo_inc, idx_inc = increments(device, slot)
        group_pdo_inc, group_idx_inc = group_increments(device, slot)
        group = slot.slot_group or 0
        modules = by_slot.get(number, [])
        if not takes_several(slot) and not modules:
            position += 1                   # an empty single slot keeps its position
        for module, default in modules:
            position += 1
            plugged.append(PluggedModule(number, module, (position - 1) * pdo_inc,
                                         (position - 1) * idx_inc, position, default,
                                         slot.slot_group, group * group_pdo_inc,
                                         group * group_idx_inc))
    return plugged


def ungrouped_indices(plugged: PluggedModule) -> list[Source]:
    """Where the module's ESI marks an index ``DependOnSlotGroup`` although it sits in a
    slot of no slot group: there is no group number to move it by, and taking it as written
    could configure another group's object."""
    if plugged.slot_group is not None:
        return []
    m = plugged.module
    found = [p.source for p in m.rx_pdos + m.tx_pdos if p.depend_on_slot_group]
    found += [e.source for p in m.rx_pdos + m.tx_pdos for e in p.entries
              if e.depend_on_slot_group]
    if m.mailbox and m.mailbox.coe:
        found += [c.source for c in m.mailbox.coe.init_cmds if c.depend_on_slot_group]
    dic = plugged.dictionary
    if dic is not None:
        found += [o.source for o in dic.objects.values() if o.depend_on_slot_group]
    return sorted(found, key=lambda src: (src.file, src.line))      # in document order


def plugged_module(device: Device, number: int, module: Module) -> PluggedModule:
    """``module`` alone in slot ``number`` (from 1) of ``device``, which must have ``Slots``
    (the other slots empty)."""
    return plug(device, {number: [(module, False)]})[0]


def plug_positions(device: Device, by_position: dict[int, Module]) -> list[PluggedModule]:
    """The modules of a module ident list (position from 1 -> module; 0xF030 or 0xF050) in
    their slots: a single slot takes the position after the previous one, a slot that
    takes several the following positions while it has room and the module fits.  A
    module that fits nowhere is left out."""
    assert device.slots is not None
    slots = device.slots.slots
    by_slot: dict[int, list[tuple[Module, bool]]] = {}
    index, used = 0, 0                     # the slot looked at, the positions before it
    for pos in sorted(by_position):
        module = by_position[pos]
        while index < len(slots):
            slot = slots[index]
            if takes_several(slot):
                inside = by_slot.setdefault(index + 1, [])
                if pos == used + 1 and len(inside) < (slot.max_instances or 1) \
                        and fits(slot, module):
                    inside.append((module, False))
                    used = pos
                    break
                index += 1
                continue
            used += 1                      # a single slot: one position, plugged or empty
            index += 1
            if pos == used and fits(slot, module):
                by_slot[index] = [(module, False)]
                break
    return plug(device, by_slot)


def fits(slot: Slot, module: Module) -> bool:
    """Whether ``module`` may sit in ``slot``: its ident is listed, or its class."""
    return (module.ident is not None and module.ident in slot.module_idents) or (
        module.module_class is not None and module.module_class in slot.module_classes)


def ident_list(plugged: list[PluggedModule]) -> list[int]:
    """The module ident list of ``plugged``: one ident per position, 0 for an empty slot."""
    idents = [0] * max((p.position for p in plugged), default=0)
    for p in plugged:
        idents[p.position - 1] = p.module.ident or 0
    return idents


def moved_objects(plugged: PluggedModule) -> dict[int, int]:
    """Index in the station -> index in the module's dictionary, for each of its objects."""
    dic = plugged.dictionary
    if dic is None:
        return {}
    return {plugged.object_index(index, obj.depend_on_slot, obj.depend_on_slot_group): index
            for index, obj in dic.objects.items()}


def module_dictionaries(plugged: list[PluggedModule]
                        ) -> list[tuple[dict[int, int], Dictionary]]:
    """(station index -> module index, dictionary) of each plugged module that has one."""
    return [(moved_objects(p), p.dictionary) for p in plugged if p.dictionary is not None]


def with_modules(device: Device, plugged: list[PluggedModule]) -> Device:
    """``device`` with the PDOs and dictionaries of its plugged modules, moved by their
    positions' increments; device PDOs marked ``OverwrittenByModule`` give way."""
    if not plugged:
        return device
    own = device.module_pdo_group or 0
    rx = [(own, p) for p in device.rx_pdos if not p.overwritten_by_module]
    tx = [(own, p) for p in device.tx_pdos if not p.overwritten_by_module]
    for p in plugged:
        for pdo in p.module.rx_pdos + p.module.tx_pdos:
            moved = _moved_pdo(device, pdo, p)
            (rx if pdo.direction == "rx" else tx).append((p.module.pdo_group or 0, moved))
    profiles = list(device.profiles) + [
        Profile(dic.source, dictionary=_moved_dictionary(dic, moved))
        for moved, dic in module_dictionaries(plugged)]
    # ETG.2000 ModulePdoGroup: a group's PDOs after those of the groups before it (the
    # compiler orders the assignment the same way).
    return replace(device, rx_pdos=[p for _, p in sorted(rx, key=lambda g: g[0])],
                   tx_pdos=[p for _, p in sorted(tx, key=lambda g: g[0])], profiles=profiles,
                   plugged=tuple(ident_list(plugged)))


def _moved_pdo(device: Device, pdo: Pdo, p: PluggedModule) -> Pdo:
    entries = [replace(e, index=p.object_index(e.index or 0, e.depend_on_slot,
                                               e.depend_on_slot_group)) for e in pdo.entries]
    sm = pdo.sm
    if sm is None:
        found = device.default_sm(pdo.direction)
        sm = found.number if found else None
    return replace(pdo, index=p.pdo_index(pdo.index or 0, pdo.depend_on_slot,
                                          pdo.depend_on_slot_group),
                   excludes=moved_excludes(p, pdo), sm=sm, entries=entries)


def moved_excludes(p: PluggedModule, pdo: Pdo) -> list[int]:
    """The PDO's Excludes where they land in ``p``'s slot: each by its own DependOnSlot /
    DependOnSlotGroup (ETG.2000 puts both on Exclude too), else as the PDO's Index."""
    own = (pdo.depend_on_slot, pdo.depend_on_slot_group)
    return [p.pdo_index(x, *pdo.exclude_depends.get(x, own)) for x in pdo.excludes]


def _moved_dictionary(dic: Dictionary, moved: dict[int, int]) -> Dictionary:
    objects = {at: replace(dic.objects[index], index=at) for at, index in moved.items()}
    return Dictionary(dic.data_types, objects, dic.source)


# -- module ident lists (0xF030 configured, 0xF050 detected; ETG.5001) ------------------------

def ident_list_data(idents: list[int]) -> bytes:
    """A module ident list for a CompleteAccess download from subindex 0: the count (its
    USINT travels in 16 bits) and one UDINT per position."""
    return bytes([len(idents), 0]) + b"".join(i.to_bytes(4, "little") for i in idents)


def ident_list_from_writes(writes: list[tuple[int, bytes, bool]]) -> dict[int, int]:
    """Position -> ident from the downloads of a module ident list: (subindex, data,
    complete access) in order; a CompleteAccess from subindex 0 carries the count, a pad
    byte, then one UDINT per position, from subindex 1 the UDINTs alone."""
    count, idents = array_downloads(writes, 4)
    return {k: v for k, v in idents.items() if count is None or k <= count}
