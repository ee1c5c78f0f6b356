"""Topology slave -> the device it names and the configuration the user chose for it.

Everything the user can get wrong about one slave is checked here, each error pointing at
the topology line: the device selector, modules and slots, the PDO choice (unknown,
excluded, mandatory left out, not changeable), PDO mappings (fixed PDO, object missing or
not mappable, wrong bit length), the DC op mode and startup SDOs (object, subindex, access,
value range).  Errors are collected, not raised one at a time: the user sees all of them.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path

from ecatcfg.eni.plan import (FIRST_STATION_ADDRESS, CoeInitCmd, EoeInitCmd, PdoDesc,
                              PdoEntryDesc, SoeInitCmd)
from ecatcfg.eni.standard import Watchdogs
from ecatcfg.compiler import eoe_params, soe_cmds, watchdogs, wiring
from ecatcfg.compiler.topology import (LoadedTopology, MappingEntry, MappingVariable, Sdo,
                                       Slave)
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (MAX_PDO_ENTRIES, MODULE_IDENT_LIST, SM_PDO_ASSIGN, Transition,
                         pdo_mapping_range)
from ecatcfg.esi import datatypes
from ecatcfg.esi.coe import (TRANSITION_STATE, DictEntry, device_dictionary, has_coe, lookup,
                             write_refusal, write_target)
from ecatcfg.esi.index import DeviceEntry
from ecatcfg.esi.library import EsiChoiceError, Library, SelectorError, Selection
from ecatcfg.esi.model import CoeInitCmd as EsiCoeInitCmd
from ecatcfg.esi.model import DcOpMode, Device, Dictionary, Module, Pdo, SyncManager
from ecatcfg.esi.physics import DEFAULT_PHYSICS
from ecatcfg.esi.slots import (PluggedModule, fits, ident_list, ident_list_data,
                               module_dictionaries, moved_excludes, plug,
                               ungrouped_indices)
from ecatcfg.record import replace


@dataclass(slots=True)
class ResolvedSlave:
    """One slave with its device and the user's choices, checked."""

    cfg: Slave
    position: int                            # bus position (auto-increment order)
    device: Device
    phys_addr: int
    pdos: list[PdoDesc]                      # every PDO, as configured (sm set = assigned)
    dc_mode: DcOpMode | None = None
    esi_cmds: list[CoeInitCmd] = field(default_factory=list)   # device + modules, user-edited
    user_cmds: list[CoeInitCmd] = field(default_factory=list)  # user SDOs replacing nothing
    module_cmds: list[CoeInitCmd] = field(default_factory=list)   # module ident list (0xF030)
    eoe_cmds: list[EoeInitCmd] = field(default_factory=list)     # topology eoe: (IP params)
    soe_cmds: list[SoeInitCmd] = field(default_factory=list)     # ESI SoE + topology soe:
    watchdog: Watchdogs | None = None        # topology watchdog: (slave's, else master's)
    remapped: set[int] = field(default_factory=set)
    pdo_prefix: dict[int, str] = field(default_factory=dict)  # module PDOs: "Module 2 (X)"
    # (station index -> module index, dictionary) of each plugged module (esi/slots.py)
    module_dicts: list[tuple[dict[int, int], Dictionary]] = field(default_factory=list)
    modules: list[PluggedModule] = field(default_factory=list)     # plugged, in slot order
    note: str | None = None                  # e.g. which revision was taken
    notes: list[str] = field(default_factory=list)   # e.g. a slot's default module plugged
    index: int = 0                           # place in the topology file (its errors' lines)
    parent: int | None = None                # bus position of the parent (None: the first)
    parent_port: int | None = None           # the parent's ESC port 0-3 it is plugged into

    @property
    def name(self) -> str:
        return self.cfg.name

    def assigned(self, sm: int) -> list[PdoDesc]:
        return [p for p in self.pdos if p.sm == sm]

    @property
    def dictionary(self) -> Dictionary | None:
        return device_dictionary(self.device)

    def dictionary_for(self, index: int) -> tuple[Dictionary | None, int]:
        """The dictionary that describes object ``index`` and its index there: the device's,
        or a plugged module's (its DependOnSlot objects moved by the slot's offset, so slot
        3's 0x8020 is the module's 0x8000, its DependOnSlotGroup ones by its slot group's).
        Falls back to the device's."""
        dic = self.dictionary
        if dic is not None and index in dic.objects:
            return dic, index
        for moved, mod in self.module_dicts:
            if index in moved:
                return mod, moved[index]
        return dic, index


Where = tuple[str | int, ...]           # a place in the topology: ("slaves", 2, "sdos", 0)


class _Errors:
    def __init__(self, loaded: LoadedTopology) -> None:
        self.loaded = loaded
        self.items: list[EcatcfgError] = []

    def add(self, message: str, *path: str | int) -> None:
        self.items.append(self.loaded.error(message, *path))


def resolve_all(loaded: LoadedTopology, library: Library
                ) -> tuple[list[ResolvedSlave], list[EcatcfgError], list[str]]:
    """Every slave resolved, in bus order (the wiring's: ``wiring.wire``), the errors, and
    the wiring's notes.  Station addresses default to 1001, 1002, ... in bus order."""
    errors = _Errors(loaded)
    slaves = loaded.topology.slaves
    # The devices first: their ports (ESI Physics) decide the wiring, the wiring the bus
    # positions, the positions the default station addresses.
    found: list[tuple[Device, str | None, DeviceEntry] | None] = []
    lookup_errors: list[list[EcatcfgError]] = []
    for index, cfg in enumerate(slaves):
        mine = _Errors(loaded)
        found.append(_find_device(cfg, index, library, mine))
        lookup_errors.append(mine.items)
    tree, wiring_errors = wiring.wire(loaded, [f[0].physics or DEFAULT_PHYSICS if f else None
                                               for f in found])
    resolved: list[ResolvedSlave] = []
    used: dict[int, int] = {}
    names: dict[str, int] = {}
    for index, cfg in enumerate(slaves):
        where = ("slaves", index)
        pos = tree.position(index)
        if cfg.name in names:
            errors.add(f"slave name {cfg.name!r} is already used by the slave at line "
                       f"{loaded.line('slaves', names[cfg.name])}", *where, "name")
        names.setdefault(cfg.name, index)
        phys = cfg.station_address if cfg.station_address is not None \
            else FIRST_STATION_ADDRESS + pos
        if phys in used:
            errors.add(f"station address {phys} is also the address of slave "
                       f"{slaves[used[phys]].name!r}", *where,
                       "station_address" if cfg.station_address is not None else "name")
        used.setdefault(phys, index)
        errors.items += lookup_errors[index]
        choice = found[index]
        if choice is None:
            continue
        before = len(errors.items)
        parent, port = tree.parent[index], tree.port[index]
        slave = ResolvedSlave(cfg, pos, choice[0], phys, [], note=choice[1], index=index,
                              parent=None if parent is None else tree.position(parent),
                              parent_port=port)
        _resolve(slave, library, errors, choice[2])
        if len(errors.items) == before:
            resolved.append(slave)
    errors.items += wiring_errors
    resolved.sort(key=lambda r: r.position)
    return resolved, errors.items, tree.notes


def _find_device(cfg: Slave, index: int, library: Library, errors: _Errors
                 ) -> tuple[Device, str | None, DeviceEntry] | None:
    """The slave's device, and a note when its selector had a choice (of revisions, or of
    ESI files that describe it differently: ``--prefer``), and its library entry."""
    where = ("slaves", index)
    try:
        selection = select(cfg, library, errors.loaded)
        device = library.device(selection.entry)
    except EsiChoiceError as exc:
        errors.add(f"slave {cfg.name!r}: esi: {exc.message}", *where, "esi")
        return None
    except SelectorError as exc:
        errors.add(f"slave {cfg.name!r}: {exc.message}", *where, "device")
        return None
    if device.product_code is None or device.revision is None or device.vendor.id is None:
        errors.add(f"slave {cfg.name!r}: the ESI device at {device.source} has no readable "
                   "identity", *where, "device")
        return None
    # Say which revision was taken only when there was a choice.
    e = selection.entry
    choices = library.revisions(e.vendor_id, e.product_code)
    notes = [selection.note if len(choices) > 1 else None, selection.preferred]
    return device, "; ".join(n for n in notes if n) or None, e


def select(cfg: Slave, library: Library, loaded: LoadedTopology) -> Selection:
    """The library's answer to a slave's ``device`` (and ``esi``: a path relative to the
    topology file's folder, or a library file's name)."""
    return library.select(cfg.device, cfg.esi, Path(loaded.file).parent)


def _resolve(slave: ResolvedSlave, library: Library, errors: _Errors,
             entry: DeviceEntry) -> None:
    modules = _plug_modules(slave, library, entry, errors)
    slave.modules = modules
    slave.module_dicts = module_dictionaries(modules)
    slave.module_cmds = _module_ident_list(slave, modules, errors)
    _choose_pdos(slave, modules, errors)
    _apply_mappings(slave, errors)
    _check_sm_sizes(slave, errors)          # after the mappings: they change the sizes
    slave.dc_mode = _dc_mode(slave, errors)
    _sdos(slave, modules, errors)
    where = ("slaves", slave.index)
    slave.eoe_cmds = eoe_params.init_cmds(slave.name, slave.device, slave.phys_addr,
                                          slave.cfg.eoe, where, errors)
    slave.soe_cmds = soe_cmds.init_cmds(slave.name, slave.device, slave.cfg.soe, where,
                                        errors, [p.module for p in modules])
    slave.watchdog = watchdogs.resolve(slave.name, slave.cfg.watchdog,
                                       errors.loaded.topology.master.watchdog, where, errors)


# -- modules ------------------------------------------------------------------------------

def _plug_modules(slave: ResolvedSlave, library: Library, entry: DeviceEntry,
                  errors: _Errors) -> list[PluggedModule]:
    dev, cfg = slave.device, slave.cfg
    where = ("slaves", slave.index, "modules")
    if dev.slots is None:
        if cfg.modules:
            errors.add(f"slave {cfg.name!r}: {dev.type_name} is not a modular device "
                       "(its ESI has no Slots)", *where)
        return []
    slots = dev.slots.slots
    for number in cfg.modules:
        if not 1 <= number <= len(slots):
            errors.add(f"slave {cfg.name!r}: slot {number} does not exist; {dev.type_name} "
                       f"has {len(slots)} slot{'s' if len(slots) != 1 else ''} (numbered "
                       "from 1)", *where, number)
    library_modules = library.modules_for(entry)
    missing = library.missing_module_libraries(entry)
    by_name: dict[str, Module] = {}
    for m in library_modules.values():
        by_name.setdefault(m.type_name.strip().casefold(), m)
    by_slot: dict[int, list[tuple[Module, bool]]] = {}
    for number, slot in enumerate(slots, start=1):
        here = (*where, number)
        named = cfg.modules.get(number)
        selectors: list[int | str] = list(named) if named else []
        default = not named and slot.default_ident is not None
        if default:
            assert slot.default_ident is not None
            selectors = [slot.default_ident]
        low, high = slot.min_instances or 0, slot.max_instances or 1
        label = f"slot {number} ({slot.name or 'unnamed'})"
        if len(selectors) > high:
            errors.add(f"slave {cfg.name!r}: {label} takes at most {high} module"
                       f"{'s' if high != 1 else ''}; the topology plugs {len(selectors)}",
                       *here)
            continue
        if len(selectors) < low:
            errors.add(f"slave {cfg.name!r}: {label} needs at least {low} module"
                       f"{'s' if low != 1 else ''}; the topology plugs "
                       f"{len(selectors) or 'none'}", *(here if named else where))
            continue
        for i, selector in enumerate(selectors):
            at = (*here, i) if named and len(named) > 1 else here
            module = _find_module(selector, library_modules, by_name)
            if module is None:
                what = (f"module 0x{selector:08X}" if isinstance(selector, int)
                        else f"module {selector!r}")
                if missing:
                    hint = ("its module librar" + ("ies " if len(missing) > 1 else "y ")
                            + ", ".join(missing) + f" (InfoReference in the ESI of "
                            f"{dev.type_name}) {'are' if len(missing) > 1 else 'is'} not "
                            "loaded; pass its folder with --esi")
                else:
                    close = difflib.get_close_matches(str(selector).casefold(), by_name, 3)
                    hint = ("did you mean " + ", ".join(by_name[c].type_name for c in close)
                            if close else "`ecatcfg devices` lists the modules of the files")
                errors.add(f"slave {cfg.name!r}: no {what} in the library of "
                           f"{dev.type_name}; {hint}", *at)
                continue
            if not fits(slot, module):
                allowed = ", ".join(f"0x{i:08X}" for i in slot.module_idents[:12])
                errors.add(f"slave {cfg.name!r}: module 0x{module.ident or 0:08X} "
                           f"({module.type_name}) does not fit {label}; it takes "
                           f"{allowed or 'module classes ' + ', '.join(slot.module_classes)}",
                           *at)
                continue
            by_slot.setdefault(number, []).append((module, default))
    plugged = plug(dev, by_slot)
    for p in plugged:
        ungrouped = ungrouped_indices(p)
        if ungrouped:
            # ETG.2000 DependOnSlotGroup: moved by the slot group's number, and this slot is
            # in no group; as written it could configure another group's object (lint ESI604).
            errors.add(f"slave {cfg.name!r}: module {p.module.type_name} marks an index "
                       f"DependOnSlotGroup (at {ungrouped[0]}), but slot {p.slot} "
                       f"({slots[p.slot - 1].name or 'unnamed'}) belongs to no slot group "
                       "(Slot/@SlotGroup), so there is no group number to move it by",
                       *where, p.slot)
    for p in plugged:
        if p.default:
            slave.notes.append(f"slot {p.slot} ({slots[p.slot - 1].name or 'unnamed'}): "
                               f"no module given, plugged its default {p.module.type_name} "
                               f"(0x{p.module.ident or 0:08X})")
    return plugged


def _module_ident_list(slave: ResolvedSlave, modules: list[PluggedModule],
                       errors: _Errors) -> list[CoeInitCmd]:
    """The configured module ident list (0xF030: one UDINT per module position, 0 for an
    empty slot), written only where the ESI asks for it (ETG.2000
    ``Slots@DownloadModuleIdentList``), in ``DownloadModuleListTransition`` (PS by
    default), as TwinCAT does: a station compares it with what it detected (0xF050).  A
    dictionary that has 0xF030 does not ask for it: a BK1120-style coupler declares it
    read-only and refuses the write (abort 0x06010002).  Asked for but not writable in
    that state by the dictionary is an error naming the ESI's line."""
    dev = slave.device
    coe = dev.mailbox.coe if dev.mailbox else None
    if dev.slots is None or coe is None or not modules \
            or not dev.slots.download_module_ident_list:
        return []
    transition = Transition.__members__.get(dev.slots.download_transition, Transition.PS)
    idents = ident_list(modules)
    comment = "download module ident list (0xF030)"
    if coe.complete_access:
        cmds = [CoeInitCmd([transition], comment, MODULE_IDENT_LIST, 0,
                           ident_list_data(idents), complete_access=True, fixed=True)]
    else:
        cmds = ([CoeInitCmd([transition], f"{comment}: clear", MODULE_IDENT_LIST, 0, b"\x00",
                            fixed=True)]
                + [CoeInitCmd([transition], f"{comment}: position {n}", MODULE_IDENT_LIST, n,
                              ident.to_bytes(4, "little"), fixed=True)
                   for n, ident in enumerate(idents, start=1)]
                + [CoeInitCmd([transition], f"{comment}: count", MODULE_IDENT_LIST, 0,
                              bytes([len(idents)]), fixed=True)])
    refused = [why for c in cmds for why in _refusals(slave, c)]
    if refused:
        errors.add(f"slave {slave.name!r}: the ESI of {dev.type_name} asks for the module "
                   f"ident list download (Slots DownloadModuleIdentList, {dev.slots.source}) "
                   f"but {refused[0]}", "slaves", slave.index, "modules")
        return []
    return cmds


def kept_by_dictionary(slave: ResolvedSlave, index: int) -> str | None:
    """Why the slave keeps PDO object ``index`` (an assignment 0x1C1n or a mapping
    0x16xx/0x1Axx) as it is: its dictionary declares it and refuses its download in PREOP,
    where PREOP->SAFEOP writes it (a device with fixed PDOs often declares 0x1C12
    read-only although its ESI says PdoAssign for its other SyncManager).  ``None`` when
    it may be written or the dictionary does not say."""
    dic, local = slave.dictionary_for(index)
    if dic is None or not dic.objects:
        return None
    coe = slave.device.mailbox.coe if slave.device.mailbox else None
    found = write_target(dic, local, 0, bool(coe and coe.complete_access))
    return write_refusal(found, "PreOp") if isinstance(found, DictEntry) else None


def _refusals(slave: ResolvedSlave, cmd: CoeInitCmd) -> list[str]:
    """Why the slave's dictionary refuses ``cmd`` in the transitions it runs in: one text
    per refused transition naming the object, the transition and the access
    (``esi/coe.py`` ``write_refusal``); empty when every download may be made or the
    dictionary does not say."""
    dic, local = slave.dictionary_for(cmd.index)
    if dic is None or not dic.objects:
        return []
    found = write_target(dic, local, cmd.subindex, cmd.complete_access)
    out = []
    for t in cmd.transitions:
        state = TRANSITION_STATE.get(t.value)
        why = write_refusal(found, state) if state is not None else None
        if why is not None:
            out.append(f"0x{cmd.index:04X}:{cmd.subindex:02X} is not writable in {state}, "
                       f"where its {t.value} download runs ({why})")
    return out


def _find_module(selector: int | str, by_ident: dict[int, Module],
                 by_name: dict[str, Module]) -> Module | None:
    if isinstance(selector, int):
        return by_ident.get(selector)
    return by_name.get(selector.strip().casefold())


# -- PDO choice ---------------------------------------------------------------------------

def _pdo_tag(direction: str) -> str:
    return "RxPdo" if direction == "rx" else "TxPdo"


def _desc(pdo: Pdo, plug: PluggedModule | None = None) -> PdoDesc:
    """A plan PDO from an ESI PDO; a module's PDOs moved by its slot and slot group
    (ETG.2000 DependOnSlot, DependOnSlotGroup: ``PluggedModule``, esi/slots.py); only an
    index so marked moves, a fixed index stays as written."""
    def pdo_index(i: int) -> int:
        return plug.pdo_index(i, pdo.depend_on_slot, pdo.depend_on_slot_group) if plug else i
    entries = [PdoEntryDesc(
        index=plug.object_index(e.index or 0, e.depend_on_slot, e.depend_on_slot_group)
        if plug else e.index or 0,
        subindex=e.subindex or 0, bit_len=e.bit_len or 0, name=e.name,
        data_type=e.data_type) for e in pdo.entries]
    return PdoDesc(pdo.direction, pdo_index(pdo.index or 0), pdo.name, entries, sm=pdo.sm,
                   fixed=pdo.fixed, mandatory=pdo.mandatory, virtual=pdo.virtual,
                   excludes=moved_excludes(plug, pdo) if plug else list(pdo.excludes))


def _choose_pdos(slave: ResolvedSlave, modules: list[PluggedModule], errors: _Errors) -> None:
    """The slave's PDOs (its own and its modules'), each on its SyncManager, and the
    assignment the topology chooses (``rx_pdos``, ``tx_pdos``) checked and applied."""
    dev, cfg = slave.device, slave.cfg
    described = _device_pdos(slave, modules, errors)
    pdos = [d for d, _ in described]
    slave.pdos = pdos
    # What the ESI says, before the PDOs are placed: the Sm each names, where each is.
    esi_sm = {d.index: d.sm for d in pdos if d.sm is not None}
    sources = {d.index: raw.source for d, raw in described}
    coe = dev.mailbox.coe if dev.mailbox else None
    can_assign = bool(coe and coe.pdo_assign)
    for direction, chosen, key in (("rx", cfg.rx_pdos, "rx_pdos"), ("tx", cfg.tx_pdos, "tx_pdos")):
        mine = [p for p in pdos if p.direction == direction]
        sm = dev.default_sm(direction)
        _place_on_sms(slave, mine, direction, sm)
        if chosen is None:
            for p in mine:
                if p.sm is None and not p.virtual and (p.mandatory or p.index in esi_sm):
                    # ETG.2000 Pdo@Sm: "if set, this PDO will be included in the process
                    # image"; Pdo@Mandatory: it must be.  Left out, the device's process
                    # data would be lost without a word.
                    wanted = "Outputs" if direction == "rx" else "Inputs"
                    errors.add(f"slave {cfg.name!r}: {dev.type_name} has no {wanted} "
                               f"SyncManager for the {'Mandatory ' if p.mandatory else ''}"
                               f"{'RxPdo' if direction == 'rx' else 'TxPdo'} 0x{p.index:04X} "
                               f"({p.name}) at {sources[p.index]}"
                               f"{_sm_named(dev, esi_sm.get(p.index))}",
                               "slaves", slave.index, "device")
            continue
        where = ("slaves", slave.index, key)
        by_index = {p.index: p for p in mine}
        if _chosen_ok(slave, direction, chosen, by_index, mine, where, errors):
            _assign(slave, direction, chosen, by_index, mine, sm, can_assign, where, errors)


def _device_pdos(slave: ResolvedSlave, modules: list[PluggedModule],
                 errors: _Errors) -> list[tuple[PdoDesc, Pdo]]:
    """The device's PDOs and its plugged modules' (named after their slot), in ESI order
    within each ModulePdoGroup, each with its ESI description; a PDO without an Index, or
    described twice, is an error."""
    dev, cfg = slave.device, slave.cfg
    # ESI document order (the ENI lists PDOs, and EC-Engineer clears them, in that order).
    # A device PDO marked OverwrittenByModule gives way to the plugged modules' PDOs (the
    # same index when SlotPdoIncrement is 0: keeping both assigned it twice).
    own = [p for p in dev.rx_pdos + dev.tx_pdos if not (modules and p.overwritten_by_module)]
    # A PDO without an Index (ETG.2000 requires one; older Beckhoff files wrote a Ref to a
    # shared description instead) cannot be assigned: compiled as 0x0000 with no entries, the
    # device's process data would be lost without a word.
    for raw in own + [q for plug in modules for q in plug.module.rx_pdos + plug.module.tx_pdos]:
        if raw.index is None:
            errors.add(f"slave {cfg.name!r}: the "
                       f"{'RxPdo' if raw.direction == 'rx' else 'TxPdo'} at {raw.source} has "
                       "no Index; it cannot be assigned", "slaves", slave.index, "device")
    grouped: list[tuple[int, PdoDesc, Pdo]] = [
        (dev.module_pdo_group or 0, _desc(p), p) for p in sorted(own, key=lambda p: p.source.line)]
    for plug in modules:
        for esi_pdo in plug.module.rx_pdos + plug.module.tx_pdos:
            d = _desc(esi_pdo, plug)
            allowed = pdo_mapping_range(d.direction)
            if has_coe(dev) and not d.virtual and esi_pdo.index is not None \
                    and d.index not in allowed:
                # Moved by its slot and slot group past the mapping objects of its direction
                # (ETG.1000.6; lint ESI101 checks the indices as written): the slave's
                # assignment check would refuse it.
                errors.add(f"slave {cfg.name!r}: the {_pdo_tag(d.direction)} "
                           f"0x{esi_pdo.index:04X} at {esi_pdo.source} is 0x{d.index:04X} in "
                           f"slot {plug.slot}, moved by its slot and slot group outside "
                           f"0x{allowed.start:04X}-0x{allowed.stop - 1:04X}", "slaves",
                           slave.index, "modules", plug.slot)
            # The module's position in the PDO's name, as EC-Engineer writes it:
            # "Module 3 (UR20-4DI-P / 1315170000).Input"; the variables carry it on.
            d.name = f"{plug.label}.{d.name}"
            slave.pdo_prefix[d.index] = plug.label
            grouped.append((plug.module.pdo_group or 0, d, esi_pdo))
    # ETG.2000 ModulePdoGroup: the PDOs of each group follow those of the groups before it
    # (the UR20's own 0x16FF/0x1AFF, group 0, before its modules', group 1).
    grouped.sort(key=lambda g: g[0])
    described = [(d, raw) for _, d, raw in grouped]
    _one_pdo_per_index(slave, described, errors)
    return described


def _place_on_sms(slave: ResolvedSlave, mine: list[PdoDesc], direction: str,
                  sm: SyncManager | None) -> None:
    """Each PDO of ``direction`` on a SyncManager of that direction: one the ESI puts on a
    missing SM, a mailbox SM or one of the other direction goes to the direction's first
    SM (``sm``); a virtual PDO without a user mapping stays out of the process image."""
    wanted = "Outputs" if direction == "rx" else "Inputs"
    fitting = {s.number for s in slave.device.sms if s.type == wanted}
    for p in mine:
        if p.virtual and p.sm is not None and p.index not in slave.cfg.pdo_mapping:
            # ETG.2100 Pdo@Virtual: the PDO is configured from the variables mapped
            # into it.  Without a user mapping it stays out of the process image; with
            # one it goes to the SM its Sm names (a bridge terminal's "IO Outputs").
            p.sm = None
        elif p.sm is not None and p.sm not in fitting:
            p.sm = sm.number if sm else None
        elif p.sm is None and p.mandatory and not p.virtual:
            # ETG.2000 Pdo@Mandatory: "pdo must be configured in a sync manager"; one
            # whose ESI names no Sm goes where a PDO without Sm goes when chosen.
            p.sm = sm.number if sm else None


def _chosen_ok(slave: ResolvedSlave, direction: str, chosen: list[int],
               by_index: dict[int, PdoDesc], mine: list[PdoDesc],
               where: tuple[str, int, str], errors: _Errors) -> bool:
    """Whether the topology's list of PDOs of ``direction`` names each PDO of the device
    once (virtual ones only with entries or a mapping); if so, its exclusions and the
    mandatory PDOs it leaves out are errors too."""
    dev, cfg = slave.device, slave.cfg
    seen: set[int] = set()
    ok = True
    for i, index in enumerate(chosen):
        pick = by_index.get(index)
        if pick is None:
            listed = ", ".join(f"0x{x:04X}" for x in sorted(by_index)[:16])
            errors.add(f"slave {cfg.name!r}: {dev.type_name} has no "
                       f"{'RxPdo' if direction == 'rx' else 'TxPdo'} 0x{index:04X}"
                       f"{'; it has ' + listed if listed else ''}", *where, i)
            ok = False
        elif index in seen:
            errors.add(f"slave {cfg.name!r}: PDO 0x{index:04X} is listed twice", *where, i)
            ok = False
        elif pick.virtual and not pick.entries and index not in cfg.pdo_mapping:
            # Entries the ESI gives a virtual PDO are its default mapping; without
            # them there is nothing to assign until the user maps its variables.
            errors.add(f"slave {cfg.name!r}: PDO 0x{index:04X} ({pick.name}) is virtual "
                       "and its ESI gives it no entries: give its variables in "
                       "pdo_mapping", *where, i)
            ok = False
        seen.add(index)
    if not ok:
        return False
    for i, index in enumerate(chosen):
        for other in by_index[index].excludes:
            if other in seen and other != index:
                errors.add(f"slave {cfg.name!r}: PDO 0x{index:04X} excludes 0x{other:04X}, "
                           "which is also chosen", *where, i)
    for p in mine:
        if p.mandatory and p.index not in seen:
            errors.add(f"slave {cfg.name!r}: mandatory PDO 0x{p.index:04X} "
                       f"({p.name}) is left out", *where)
    return True


def _assign(slave: ResolvedSlave, direction: str, chosen: list[int],
            by_index: dict[int, PdoDesc], mine: list[PdoDesc], sm: SyncManager | None,
            can_assign: bool, where: tuple[str, int, str], errors: _Errors) -> None:
    """Put the chosen PDOs on ``sm`` in the order given, the others off it; an error where
    the device cannot change its assignment (no CoE PdoAssign, or 0x1C1n not writable)."""
    dev, cfg = slave.device, slave.cfg
    default = [p.index for p in mine if p.sm is not None]
    kept = kept_by_dictionary(slave, SM_PDO_ASSIGN + sm.number) if sm else None
    if list(chosen) != default and (not can_assign or kept):
        why = (f"its dictionary declares 0x{SM_PDO_ASSIGN + sm.number:04X} not "
               f"writable in PreOp: {kept}" if can_assign and sm else
               "no CoE PdoAssign in its ESI")
        errors.add(f"slave {cfg.name!r}: {dev.type_name} does not support PDO assignment "
                   f"({why}); its fixed assignment is "
                   + (", ".join(f"0x{x:04X}" for x in default) or "empty"), *where)
        return
    if sm is None and chosen:
        errors.add(f"slave {cfg.name!r}: {dev.type_name} has no "
                   f"{'Outputs' if direction == 'rx' else 'Inputs'} SyncManager", *where)
        return
    for p in mine:
        p.sm = None
    for index in chosen:      # the order the user gave is the assignment order
        p = by_index[index]
        p.sm = sm.number if sm else None
    # keep assignment order = list order: move chosen PDOs to the end in that order
    order = {index: n for n, index in enumerate(chosen)}
    others = [p for p in slave.pdos if p.direction != direction or p.index not in order]
    picked = sorted((p for p in slave.pdos if p.direction == direction
                     and p.index in order), key=lambda p: order[p.index])
    slave.pdos = others + picked


def _sm_named(dev: Device, number: int | None) -> str:
    """What the SyncManager a PDO's ESI ``Sm`` names is, for a message: why the PDO cannot
    go there (empty when the PDO names none)."""
    if number is None:
        return ""
    if not 0 <= number < len(dev.sms):
        return f", which names Sm {number}; the device has {len(dev.sms)} SyncManager(s)"
    sm = dev.sms[number]
    if sm.type is None:
        why = (f"its ControlByte 0x{sm.control_byte:02X} gives none (reserved bits)"
               if sm.control_byte is not None else "nor a ControlByte")
        return f", which names Sm {number} at {sm.source}: it has no type, and {why}"
    return f", which names Sm {number} at {sm.source}, whose type is {sm.type}"


def _one_pdo_per_index(slave: ResolvedSlave, pdos: list[tuple[PdoDesc, Pdo]],
                       errors: _Errors) -> None:
    """A PDO index names one PDO of a slave, virtual or not, of either direction, the
    device's own or a module's: an ENI's SyncManager lists it by index (ETG.2100
    ``ProcessData/SmN/Pdo``; a second description of one index is refused, ENI004), and
    so do 0x1C12/0x1C13 and a topology's ``rx_pdos``, ``tx_pdos`` and ``pdo_mapping``.  Two
    descriptions of one index are a contradiction of the ESI (lint ESI102), not a choice
    compile can make for the user: an error naming both, ``--allow-esi-errors`` or not."""
    first: dict[int, tuple[PdoDesc, Pdo]] = {}
    for d, raw in pdos:
        seen = first.setdefault(d.index, (d, raw))
        if seen[0] is d:
            continue
        other, other_raw = seen
        modules = d.index in slave.pdo_prefix
        errors.add(f"slave {slave.cfg.name!r}: {slave.device.type_name} describes PDO "
                   f"0x{d.index:04X} twice"
                   f"{' (by the device and a module, or by two modules)' if modules else ''}: "
                   f"{_pdo_text(other, other_raw)} and {_pdo_text(d, raw)}; an ENI names a "
                   "PDO by its index, so one of them could not be told from the other",
                   "slaves", slave.index, "modules" if modules else "device")


def _pdo_text(d: PdoDesc, raw: Pdo) -> str:
    kind = "RxPdo" if d.direction == "rx" else "TxPdo"
    return f"{kind} {d.name!r}{' (virtual)' if d.virtual else ''} at {raw.source}"


def _check_sm_sizes(slave: ResolvedSlave, errors: _Errors) -> None:
    for sm in slave.device.sms:
        if sm.is_mailbox or sm.max_size is None:
            continue
        size = (sum(e.bit_len for p in slave.assigned(sm.number) for e in p.entries) + 7) // 8
        if size > sm.max_size:
            errors.add(f"slave {slave.name!r}: the PDOs assigned to SM{sm.number} need {size} "
                       f"bytes, more than its MaxSize {sm.max_size}", "slaves", slave.index)


# -- PDO mapping --------------------------------------------------------------------------

def _apply_mappings(slave: ResolvedSlave, errors: _Errors) -> None:
    cfg, dev = slave.cfg, slave.device
    if not cfg.pdo_mapping:
        return
    coe = dev.mailbox.coe if dev.mailbox else None
    dic = slave.dictionary
    by_index = {p.index: p for p in slave.pdos}
    for index, entries in cfg.pdo_mapping.items():
        where = ("slaves", slave.index, "pdo_mapping", index)
        pdo = by_index.get(index)
        if pdo is None:
            errors.add(f"slave {cfg.name!r}: {dev.type_name} has no PDO 0x{index:04X} to map",
                       *where)
            continue
        if not (coe and coe.pdo_config) and not pdo.virtual:
            # A virtual PDO needs no PdoConfig: without it the device configures the PDO
            # itself from the SM length the master gives (ETG.2100 Pdo@Virtual, "configured
            # internally"; an EL6690 bridge, a CX's EtherCAT slave): the ENI carries its
            # variables, and no mapping is downloaded (compiler/pdocmds.py).
            errors.add(f"slave {cfg.name!r}: {dev.type_name} does not support PDO mapping "
                       "(no CoE PdoConfig in its ESI)", *where)
            continue
        kept = kept_by_dictionary(slave, index)
        if pdo.fixed or kept:
            why = "Fixed in the ESI" if pdo.fixed else \
                f"its object is not writable in PreOp in the dictionary: {kept}"
            errors.add(f"slave {cfg.name!r}: PDO 0x{index:04X} ({pdo.name}) has a fixed "
                       f"mapping ({why})", *where)
            continue
        if pdo.sm is None:
            key = "rx_pdos" if pdo.direction == "rx" else "tx_pdos"
            errors.add(f"slave {cfg.name!r}: PDO 0x{index:04X} is mapped but not assigned; "
                       f"add it to {key}", *where)
            continue
        # The mapping object's own dictionary entry says how many entries it holds;
        # without one, what any mapping object can hold.
        room = sum(1 for n in range(1, 256)
                   if dic is not None and isinstance(lookup(dic, index, n), DictEntry))
        if len(entries) > (room or MAX_PDO_ENTRIES):
            held = "its object in the dictionary" if room else "a mapping object's count"
            errors.add(f"slave {cfg.name!r}: PDO 0x{index:04X} holds at most "
                       f"{room or MAX_PDO_ENTRIES} entries ({held}), not {len(entries)}",
                       *where)
            continue
        new: list[PdoEntryDesc] = []
        for i, given in enumerate(entries):
            entry = _mapped_entry(slave, pdo, dic, _Mapped.of(given), (*where, i), errors)
            if entry is not None:
                new.append(entry)
        if len(new) == len(entries):
            pdo.entries = new
            slave.remapped.add(index)


@dataclass(frozen=True, slots=True)
class _Mapped:
    """One entry of a user mapping, from either spelling of the topology."""

    index: int
    subindex: int
    bits: int
    name: str | None = None
    type: str | None = None

    @staticmethod
    def of(given: MappingEntry) -> _Mapped:
        if isinstance(given, MappingVariable):
            return _Mapped(given.index, given.subindex, given.bit_len, given.name,
                           datatypes.canonical(given.type) if given.type else None)
        return _Mapped(*given)


def _mapped_entry(slave: ResolvedSlave, pdo: PdoDesc, dic: Dictionary | None, m: _Mapped,
                  where: Where, errors: _Errors) -> PdoEntryDesc | None:
    obj, sub, bits = m.index, m.subindex, m.bits
    if obj == 0:                                  # a gap (padding) of `bits` bits
        if sub or m.type or m.name:
            errors.add(f"slave {slave.name!r}: a gap (index 0) has subindex 0, and neither "
                       "a type nor a name", *where)
            return None
        return PdoEntryDesc(0, 0, bits)
    described, local = slave.dictionary_for(obj)
    if pdo.virtual and (described is None or lookup(described, local, sub) is None):
        # A variable of a virtual PDO that the dictionary does not describe: the device
        # configures itself from the mapping the master downloads (ETG.2100 Pdo@Virtual),
        # as a bridge terminal does with the variables its user adds.
        return PdoEntryDesc(obj, sub, bits, m.name or "", m.type)
    if dic is None and described is None:
        errors.add(f"slave {slave.name!r}: {slave.device.type_name} has no object dictionary "
                   f"in its ESI, so 0x{obj:04X}:{sub:02X} cannot be checked or mapped", *where)
        return None
    dic, local = slave.dictionary_for(obj)
    found = lookup(dic, local, sub) if dic is not None else None
    if dic is None or found is None:
        errors.add(f"slave {slave.name!r}: object 0x{obj:04X} is not in the dictionary of "
                   f"{slave.device.type_name}", *where)
        return None
    if not isinstance(found, DictEntry):
        errors.add(f"slave {slave.name!r}: object 0x{obj:04X} has no subindex {sub}", *where)
        return None
    letter = "R" if pdo.direction == "rx" else "T"
    mapping = (found.flags.pdo_mapping if found.flags else None) or ""
    if letter not in mapping.upper():
        kind = "an RxPDO" if letter == "R" else "a TxPDO"
        errors.add(f"slave {slave.name!r}: object 0x{obj:04X}:{sub:02X} ({found.obj.name}) "
                   f"cannot be mapped into {kind} (PdoMapping is "
                   f"{mapping or 'not set'} in the dictionary)", *where)
        return None
    if found.bit_size is not None and found.bit_size != bits:
        errors.add(f"slave {slave.name!r}: object 0x{obj:04X}:{sub:02X} is {found.bit_size} "
                   f"bits, not {bits}", *where)
        return None
    if m.type is not None and found.type and datatypes.canonical(found.type) not in (
            None, m.type):
        errors.add(f"slave {slave.name!r}: object 0x{obj:04X}:{sub:02X} is {found.type}, "
                   f"not {m.type}", *where)
        return None
    name = found.obj.name if sub == 0 or found.obj.type == found.type else \
        _sub_name(dic, found.obj.type, sub) or f"{found.obj.name} {sub}"
    return PdoEntryDesc(obj, sub, bits, m.name or name, found.type or None)


def _sub_name(dic: Dictionary, type_name: str, sub: int) -> str | None:
    dt = dic.data_types.get(type_name)
    if dt is None:
        return None
    return next((s.name for s in dt.sub_items if s.subindex == sub), None)


# -- DC -----------------------------------------------------------------------------------

def _dc_mode(slave: ResolvedSlave, errors: _Errors) -> DcOpMode | None:
    name = slave.cfg.dc
    if name is None:
        return None
    where = ("slaves", slave.index, "dc")
    dc = slave.device.dc
    modes = dc.opmodes if dc else []
    if not modes:
        errors.add(f"slave {slave.name!r}: {slave.device.type_name} has no DC op modes",
                   *where)
        return None
    matches = [m for m in modes if m.name == name] or [
        m for m in modes if m.name.strip().casefold() == name.strip().casefold()]
    if not matches:
        names = ", ".join(dict.fromkeys(m.name for m in modes))
        errors.add(f"slave {slave.name!r}: no DC op mode {name!r}; {slave.device.type_name} "
                   f"has {names}", *where)
        return None
    # Beckhoff files give build-dependent variants of one mode: take the current one.
    current = [m for m in matches if m.ignore_from_build is None]
    return max(current or matches, key=lambda m: m.use_from_build or 0)


# -- SDOs ---------------------------------------------------------------------------------

def _coe_cmd(cmd: EsiCoeInitCmd, plug: PluggedModule | None = None) -> CoeInitCmd:
    index = cmd.index or 0
    if plug is not None:
        index = plug.object_index(index, cmd.depend_on_slot, cmd.depend_on_slot_group)
    transitions = [Transition(t) for t in cmd.transitions if t in Transition.__members__]
    return CoeInitCmd(transitions, cmd.comment or f"download 0x{index:04X}:{cmd.subindex or 0:02X}",
                      index, cmd.subindex or 0, cmd.data or b"",
                      complete_access=cmd.complete_access, fixed=cmd.fixed)


def _sdos(slave: ResolvedSlave, modules: list[PluggedModule], errors: _Errors) -> None:
    dev, cfg = slave.device, slave.cfg
    # The device's own InitCmds, then each plugged module's (ETG.2000
    # Module/Mailbox/CoE/InitCmd), in module order, DependOnSlot indices moved by the slot,
    # DependOnSlotGroup ones by its slot group.
    given: list[tuple[EsiCoeInitCmd, PluggedModule | None, str]] = [
        (c, None, "") for c in (dev.mailbox.coe.init_cmds if dev.mailbox and dev.mailbox.coe
                                else [])]
    for plug in modules:
        mb = plug.module.mailbox
        if mb and mb.coe:
            given += [(c, plug, f" of {plug.label}") for c in mb.coe.init_cmds]
    esi = []
    for c, owner_plug, owner in given:
        cmd = _coe_cmd(c, owner_plug)
        if cmd.index > 0xFFFF:
            # An object index is 16 bits (ETG.1000.6); moved by the slot and its slot
            # group past it, the InitCmd would address no object.
            errors.add(f"slave {slave.name!r}: the InitCmd{owner} at {c.source}: its index "
                       f"0x{c.index or 0:04X} moved by its slot and slot group is "
                       f"0x{cmd.index:X}, outside 0..0xFFFF", "slaves", slave.index,
                       "modules" if owner else "device")
            continue
        refused = _refusals(slave, cmd)
        if refused:
            # The slave would refuse it and stop in that transition: the ESI contradicts
            # its own dictionary, which lint reports as ESI302.
            errors.add(f"slave {slave.name!r}: the InitCmd{owner} at {c.source}: "
                       f"{refused[0]}; the slave would refuse it (lint ESI302)", "slaves",
                       slave.index, "modules" if owner else "device")
        esi.append(cmd)
    slave.esi_cmds = esi
    if not cfg.sdos:
        return
    for i, user in enumerate(cfg.sdos):
        where = ("slaves", slave.index, "sdos", i)
        if not has_coe(dev):
            errors.add(f"slave {slave.name!r}: {dev.type_name} has no CoE mailbox, so SDOs "
                       "cannot be written", *where)
            return
        state = TRANSITION_STATE.get(user.transition.value)
        if state is None:
            errors.add(f"slave {slave.name!r}: SDOs cannot run in transition "
                       f"{user.transition.value} (the mailbox works from PREOP on); use one of "
                       + ", ".join(TRANSITION_STATE), *where, "transition")
            continue
        dic, local = slave.dictionary_for(user.index)
        data = _sdo_data(slave, dic, local, user, where, errors)
        if data is None:
            continue
        cmd = CoeInitCmd([user.transition], user.comment or _sdo_comment(
            dic, local, user.index, user.subindex), user.index, user.subindex, data,
            complete_access=user.complete_access)
        refused = _refusals(slave, cmd)
        if refused:
            errors.add(f"slave {slave.name!r}: {refused[0]}", *where)
            continue
        _place_sdo(slave, cmd)


def _sdo_data(slave: ResolvedSlave, dic: Dictionary | None, local: int, user: Sdo,
              where: Where, errors: _Errors) -> bytes | None:
    """``local``: the object's index in ``dic`` (a module's own, for a slot object)."""
    if user.data is not None:
        return bytes.fromhex(user.data.replace(" ", ""))
    value = user.value
    assert value is not None                # Sdo's validator: one of value and data is given
    type_name, bit_size = user.type, None
    target = f"0x{user.index:04X}:{user.subindex:02X}"
    if dic is not None and dic.objects:
        found = lookup(dic, local, user.subindex)
        if found is None:
            errors.add(f"slave {slave.name!r}: object 0x{user.index:04X} is not in the "
                       f"dictionary of {slave.device.type_name}", *where, "index")
            return None
        if not isinstance(found, DictEntry):
            errors.add(f"slave {slave.name!r}: object 0x{user.index:04X} ({found.name}) has "
                       f"no subindex {user.subindex}", *where, "subindex")
            return None
        # A 'type' of another size than the object would be refused by the slave (SDO abort
        # "length of service parameter does not match"): say so here instead.
        given = datatypes.bit_size(type_name) if type_name else None
        if given is not None and found.bit_size is not None and given != found.bit_size:
            errors.add(f"slave {slave.name!r}: {target} ({found.obj.name}) is "
                       f"{found.bit_size} bits ({found.type}), but 'type' {type_name} is "
                       f"{given} bits", *where, "type")
            return None
        type_name = type_name or found.type
        bit_size = found.bit_size
    if not type_name:
        errors.add(f"slave {slave.name!r}: {slave.device.type_name} has no object dictionary "
                   f"in its ESI; give 'type' (e.g. UINT) or 'data' for {target}", *where)
        return None
    try:
        return datatypes.encode(value, type_name, bit_size)
    except datatypes.ValueTypeError as exc:
        errors.add(f"slave {slave.name!r}: {target}: {exc}", *where, "value")
        return None


def _sdo_comment(dic: Dictionary | None, local: int, index: int, subindex: int) -> str:
    """The object's name (and the subindex's) from the dictionary, as startup lists show it."""
    obj = dic.objects.get(local) if dic else None
    if dic is None or obj is None or not obj.name:
        return f"download 0x{index:04X}:{subindex:02X}"
    sub = _sub_name(dic, obj.type, subindex) if subindex else None
    return f"{obj.name}: {sub}" if sub else obj.name


def _place_sdo(slave: ResolvedSlave, cmd: CoeInitCmd) -> None:
    """A user SDO on the same object and transition as an ESI InitCmd replaces it in place
    and keeps its comment (as EC-Engineer does with Elmo's 0x60C2:01)."""
    t = cmd.transitions[0]
    for n, esi in enumerate(slave.esi_cmds):
        if (esi.index, esi.subindex) == (cmd.index, cmd.subindex) and t in esi.transitions:
            replaced = replace(cmd, comment=esi.comment)
            if esi.transitions == [t]:
                slave.esi_cmds[n] = replaced
            else:
                esi.transitions = [x for x in esi.transitions if x != t]
                slave.esi_cmds.insert(n + 1, replaced)
            return
    slave.user_cmds.append(cmd)
