"""The object dictionary of an emulated CoE slave, built from its ESI (ETG.2000 Dictionary,
PDOs and CoE flags): each object's subentries with their types, sizes, access rights and
ESI defaults, and the objects a master needs that many ESIs leave out (0x1000, 0x1018, the
PDO mapping objects 0x16xx/0x1Axx, 0x1C00 and the PDO assignment objects 0x1C1n, and every
object an ESI PDO maps).  :meth:`ObjectDictionary.from_device
<ecatcfg.runtime.segment.objects.ObjectDictionary.from_device>` calls :func:`build`; what
the dictionary does with SDO requests is ``objects.py``.
"""

from __future__ import annotations

from ecatcfg.esc import MAX_PDO_ENTRIES, SM_COMM_TYPE, SM_PDO_ASSIGN, SM_TYPE_CODES, AlState
from ecatcfg.esi.coe import (
    PDO_CONFIG_WRITE_STATES, device_dictionary, match_infos, standard_entry_type,
)
from ecatcfg.esi.coe import resolve_type as _resolve_type
from ecatcfg.esi.datatypes import canonical
from ecatcfg.esi.model import (
    Device, DictObject, Dictionary, ObjectFlags, ObjectInfo, Pdo, pick_name,
)
from ecatcfg.runtime.segment.od_entries import MAILBOX_STATES, OdEntry, OdObject, fit_bytes

# ETG.2000 access restriction names -> AL states (esi.model.STATES).
_STATE_BY_NAME = {"PreOp": AlState.PREOP, "SafeOp": AlState.SAFEOP, "Op": AlState.OP}
# Where a PDO mapping or assignment takes writes (esi.coe: PREOP only).
PREOP_ONLY = frozenset(_STATE_BY_NAME[s] for s in PDO_CONFIG_WRITE_STATES)


# Capacity of a configurable mapping object the ESI does not describe (no dictionary
# entry): our choice, large enough for the mappings seen in the corpus ENIs (EC-murr maps
# 32 entries with one complete-access download, docs/eni-exports.md §5).
CONFIGURABLE_MAPPING_CAPACITY = 32


def _int_bytes(value: int, nbytes: int) -> bytes:
    nbytes = max(nbytes, 1)
    return (value & ((1 << (8 * nbytes)) - 1)).to_bytes(nbytes, "little")


def _signed_bound(value: int | None, bits: int, signed: bool) -> int | None:
    # ESIs write negative limits of signed types either with a sign or as the two's
    # complement bit pattern (#xFFFF8000); read both as the signed number.
    if value is None or not signed or bits <= 0:
        return value
    if value >= 1 << (bits - 1) and value < 1 << bits:
        return value - (1 << bits)
    return value


class _EntrySpec:
    """A subentry as the dictionary's data types describe it, before values are set."""

    __slots__ = ("subindex", "name", "type", "bit_size", "flags", "bit_offset")

    def __init__(self, subindex: int, name: str, type_: str, bit_size: int | None,
                 flags: ObjectFlags | None, bit_offset: int | None = None) -> None:
        self.subindex = subindex
        self.name = name
        self.type = type_
        self.bit_size = bit_size
        self.flags = flags
        self.bit_offset = bit_offset


def _object_layout(dic: Dictionary, obj: DictObject) -> tuple[bool, list[_EntrySpec]]:
    """(is a simple variable, subentries) of a dictionary object."""
    dt = dic.data_types.get(obj.type)
    if dt is not None and dt.sub_items:
        specs: list[_EntrySpec] = []
        last = -1
        for item in dt.sub_items:
            sdt = dic.data_types.get(item.type)
            if item.subindex is None and sdt is not None and sdt.array_info \
                    and not sdt.sub_items:
                # The array part of a record, one SubItem for LBound..LBound+Elements-1
                # (as esi.coe.lookup reads it).
                ai = sdt.array_info[0]
                etype, esize = _resolve_type(dic, sdt.base_type or "")
                if sdt.bit_size and ai.elements:
                    esize = sdt.bit_size // ai.elements
                start = max(ai.lbound, last + 1, 1)
                for k in range(ai.elements):
                    sub = start + k
                    specs.append(_EntrySpec(sub, f"SubIndex {sub:03d}", etype, esize,
                                            item.flags or obj.flags))
                last = start + ai.elements - 1
                continue
            sub = item.subindex if item.subindex is not None else last + 1
            etype, esize = _resolve_type(dic, item.type)
            if item.bit_size is not None:
                esize = item.bit_size
            specs.append(_EntrySpec(sub, item.name, etype, esize, item.flags or obj.flags,
                                    item.bit_offset))
            last = max(last, sub)
        if not any(s.subindex == 0 for s in specs):
            specs.insert(0, _EntrySpec(0, "SubIndex 000", "USINT", 8, obj.flags))
        return False, sorted(specs, key=lambda s: s.subindex)
    if dt is not None and dt.array_info and dt.array_info[0].lbound >= 1:
        # The object's type is itself a CoE array: subindex 0 = number of entries.
        ai = dt.array_info[0]
        etype, esize = _resolve_type(dic, dt.base_type or "")
        if dt.bit_size and ai.elements:
            esize = dt.bit_size // ai.elements
        specs = [_EntrySpec(0, "SubIndex 000", "USINT", 8, obj.flags)]
        specs += [_EntrySpec(ai.lbound + k, f"SubIndex {ai.lbound + k:03d}", etype, esize,
                             obj.flags) for k in range(ai.elements)]
        return False, specs
    # A simple variable (a base type, a renamed base type, or an ARRAY [0..n] type used as
    # one octet value as Copley's 0x2000 does).
    vtype, vsize = _resolve_type(dic, obj.type)
    if obj.bit_size is not None and (vsize is None or canonical(obj.type) is None):
        vsize = obj.bit_size
    return True, [_EntrySpec(0, pick_name(obj.names), vtype, vsize, obj.flags)]


def _is_array(dic: Dictionary, obj: DictObject) -> bool:
    """Whether the ESI describes ``obj`` as an array: its type has an ArrayInfo, or its
    SubItems are subindex 0 and one array-typed SubItem (ETG.2000 "Elements")."""
    dt = dic.data_types.get(obj.type)
    if dt is None:
        return False
    if not dt.sub_items:
        return bool(dt.array_info) and dt.array_info[0].lbound >= 1
    rest = [item for item in dt.sub_items if item.subindex != 0]
    if len(rest) != 1 or rest[0].subindex is not None:
        return False
    element = dic.data_types.get(rest[0].type)
    return element is not None and bool(element.array_info) and not element.sub_items


def _access(flags: ObjectFlags | None) -> tuple[str, frozenset[AlState], frozenset[AlState]]:
    # No Flags/Access at all: our choice is read/write in every mailbox state, so that a
    # master's InitCmd for such an object is not refused by the emulation.
    if flags is None or flags.access is None:
        return "rw", MAILBOX_STATES, MAILBOX_STATES
    acc = flags.access
    value = acc.value.strip()
    mode = "rw" if "r" in value and "w" in value else "wo" if "w" in value else "ro"
    reads = frozenset(_STATE_BY_NAME[s] for s in acc.read_states if s in _STATE_BY_NAME)
    writes = frozenset(_STATE_BY_NAME[s] for s in acc.write_states if s in _STATE_BY_NAME)
    return mode, reads, writes


def _mappable(flags: ObjectFlags | None) -> str:
    mapping = (flags.pdo_mapping or "") if flags is not None else ""
    return "".join(c for c in "RT" if c in mapping.upper())


def _default(info: ObjectInfo | None, kind: str, nbytes: int) -> bytes | None:
    """The ESI default as wire bytes (``nbytes`` long for a number: negative values in
    two's complement of the entry's size; strings and data not yet fitted)."""
    if info is None:
        return None
    if info.default_data is not None:
        return info.default_data
    if info.default_value is not None:
        value = info.default_value
        if nbytes <= 0:
            nbytes = max((value.bit_length() + 8) // 8, 1)
        return _int_bytes(value, nbytes)
    if info.default_string is not None:
        return info.default_string.encode("utf-8") if kind == "string" else None
    return None


def _bounds(info: ObjectInfo | None, entry: OdEntry) -> None:
    if info is None or entry.kind not in ("signed", "unsigned"):
        return
    signed = entry.kind == "signed"
    lo, hi = info.min_value, info.max_value
    if lo is None and info.min_data is not None:
        lo = int.from_bytes(info.min_data, "little", signed=signed)
    if hi is None and info.max_data is not None:
        hi = int.from_bytes(info.max_data, "little", signed=signed)
    lo = _signed_bound(lo, entry.bit_size, signed)
    hi = _signed_bound(hi, entry.bit_size, signed)
    if lo is not None and hi is not None and lo > hi:
        return                        # contradictory limits in the ESI: not enforced
    entry.min_value, entry.max_value = lo, hi


def _entry_from_spec(spec: _EntrySpec, info: ObjectInfo | None,
                     defaults: set[int]) -> OdEntry:
    mode, reads, writes = _access(spec.flags)
    entry = OdEntry(spec.subindex, spec.name, spec.type, max(spec.bit_size or 0, 0), b"",
                    mode, reads, writes, _mappable(spec.flags), bit_offset=spec.bit_offset,
                    mapping_said=spec.flags is not None)
    raw = _default(info, entry.kind, entry.byte_size)
    if raw is not None:
        defaults.add(spec.subindex)
    if entry.kind == "string" and entry.variable_length:
        entry.value = raw or b""
    else:
        entry.value = fit_bytes(raw or b"", entry.byte_size)
    _bounds(info, entry)
    return entry


def _fixed(index: int, subindex: int) -> tuple[str, int]:
    """The type ETG.1000.6 fixes for a communication-area entry (esi.coe)."""
    fixed = standard_entry_type(index, subindex)
    assert fixed is not None, f"0x{index:04X}:{subindex:02X} has no fixed type"
    return fixed


def _standard(entry: OdEntry, type_: str, bits: int) -> None:
    """Give a communication-area entry its ETG.1000.6 type, whatever the ESI declares:
    masters read these into fixed-size buffers (SOEM reads 0x1C00:n into one byte and fails
    with "data container too small" on more), and a real slave answers with the standard
    size.  Elmo's Gold ESI, for one, declares 0x1C00's entries as UINT."""
    if entry.type != type_ or entry.bit_size != bits:
        entry.type, entry.bit_size = type_, bits
        entry.value = fit_bytes(entry.value, (bits + 7) // 8)
        entry.min_value = entry.max_value = None
        entry.bit_offset = None               # the ESI's record layout no longer applies


class _Builder:
    """Builds the object dictionary of one device; remembers which entries the ESI gave a
    default for, so that derived values fill only the gaps."""

    def __init__(self, device: Device) -> None:
        self.device = device
        self.dic = device_dictionary(device)
        self.objects: dict[int, OdObject] = {}
        self.esi_defaults: set[tuple[int, int]] = set()
        coe = device.mailbox.coe if device.mailbox is not None else None
        self.pdo_assign = bool(coe and coe.pdo_assign)
        self.pdo_config = bool(coe and coe.pdo_config)

    def build(self) -> dict[int, OdObject]:
        if self.dic is not None:
            for index in sorted(self.dic.objects):
                self.objects[index] = self.from_dictionary(self.dic, index,
                                                           self.dic.objects[index])
        pdos = [p for p in self.device.pdos if not p.virtual and p.index is not None]
        virtual = [p for p in self.device.pdos if p.virtual and p.index is not None]
        self.mapped_objects(pdos + virtual)     # a virtual PDO's ESI entries: its default
        self.mapping_objects(pdos)
        self.virtual_mapping_objects(virtual, {p.index for p in pdos})
        self.sm_objects(pdos, virtual)
        self.identity()
        return dict(sorted(self.objects.items()))

    def from_dictionary(self, dic: Dictionary, index: int, obj: DictObject) -> OdObject:
        variable, specs = _object_layout(dic, obj)
        od_obj = OdObject(index, pick_name(obj.names), variable=variable,
                          array=not variable and _is_array(dic, obj))
        if variable:
            infos = {0: obj.info} if obj.info is not None else {}
        else:
            infos = match_infos([(sp.subindex, sp.name) for sp in specs],
                                obj.info.sub_items) if obj.info is not None else {}
        defaults: set[int] = set()
        for spec in specs:
            od_obj.entries[spec.subindex] = _entry_from_spec(spec, infos.get(spec.subindex),
                                                             defaults)
        if not variable and 0 not in defaults:
            # No default for subindex 0: the number of entries the type declares.
            si0 = od_obj.entries[0]
            si0.value = _int_bytes(od_obj.max_subindex, si0.byte_size)
        self.esi_defaults.update((index, s) for s in defaults)
        return od_obj

    def _object(self, index: int, name: str) -> OdObject:
        obj = self.objects.get(index)
        if obj is None:
            obj = self.objects[index] = OdObject(index, name)
        return obj

    def _si0(self, obj: OdObject, value: int, writes: frozenset[AlState]) -> None:
        si0 = obj.entries.get(0)
        if si0 is None:
            si0 = obj.add(OdEntry(0, "SubIndex 000", "USINT", 8, b"\0"))
        _standard(si0, "USINT", 8)
        si0.value = _int_bytes(value, si0.byte_size)
        si0.access = "rw" if writes else "ro"
        si0.read_states, si0.write_states = MAILBOX_STATES, writes
        obj.variable = False

    def mapped_objects(self, pdos: list[Pdo]) -> None:
        """Every object:subindex an ESI PDO maps exists and is mappable that way (ESIs
        such as the SOES demos map objects whose dictionary gives no PdoMapping flag, and
        dictionary-less ESIs map objects that are described nowhere else)."""
        for pdo in pdos:
            direction = "R" if pdo.direction == "rx" else "T"
            for pe in pdo.entries:
                if not pe.index:
                    continue                       # padding gap, or unreadable index
                sub = pe.subindex or 0
                obj = self.objects.get(pe.index)
                if obj is None:
                    obj = self.objects[pe.index] = OdObject(pe.index, pe.name,
                                                            variable=sub == 0)
                entry = obj.entries.get(sub)
                if entry is None:
                    etype, esize = _resolve_type(self.dic, pe.data_type or "")
                    bits = pe.bit_len if pe.bit_len is not None else esize or 0
                    # Outputs are written by the master, inputs only read (our choice for
                    # objects the ESI does not describe).
                    entry = obj.add(OdEntry(sub, pe.name, etype, bits,
                                            bytes((bits + 7) // 8),
                                            "rw" if direction == "R" else "ro"))
                    if sub > 0:
                        if 0 not in obj.entries or obj.variable:
                            obj.entries.pop(0, None)
                            self._si0(obj, 0, frozenset())
                        si0 = obj.entries[0]
                        if (pe.index, 0) not in self.esi_defaults:
                            si0.value = _int_bytes(max(si0.as_int(), sub), si0.byte_size)
                if direction not in entry.mappable:
                    entry.mappable += direction

    def mapping_objects(self, pdos: list[Pdo]) -> None:
        """0x16xx / 0x1Axx for every non-virtual PDO, values from the ESI PDO entries;
        writable in PREOP only when the PDO is not fixed and the device says PdoConfig."""
        done: set[int] = set()
        for pdo in pdos:
            if pdo.index is None or pdo.index in done:
                continue                         # alternatives with the same index
            done.add(pdo.index)
            configurable = not pdo.fixed and self.pdo_config
            writes = PREOP_ONLY if configurable else frozenset()
            obj = self._object(pdo.index, pdo.name)
            values = [((pe.index or 0) << 16 | (pe.subindex or 0) << 8
                       | (pe.bit_len or 0) & 0xFF) for pe in pdo.entries]
            capacity = max(len(values), obj.max_subindex,
                           CONFIGURABLE_MAPPING_CAPACITY
                           if configurable and not obj.entries else 0)
            self._array(obj, values, capacity, *_fixed(pdo.index, 1), writes)

    def virtual_mapping_objects(self, pdos: list[Pdo], taken: set[int | None]) -> None:
        """0x16xx / 0x1Axx of the virtual PDOs (where no fixed PDO has the index): the
        master chooses their mapping (ETG.2000 Pdo@Virtual), so they hold the ESI's entries
        as the default (none for a bridge terminal's "IO Outputs") and take the master's
        downloads in PREOP unless the PDO is fixed or the device has no PdoConfig.  Without
        a dictionary object, room for as many entries as a mapping object can count."""
        for pdo in pdos:
            if pdo.index is None or pdo.index in taken:
                continue                    # a fixed PDO or an alternative has the index
            taken.add(pdo.index)
            configurable = not pdo.fixed and self.pdo_config
            writes = PREOP_ONLY if configurable else frozenset()
            obj = self._object(pdo.index, pdo.name)
            obj.virtual_pdo = True
            values = [((pe.index or 0) << 16 | (pe.subindex or 0) << 8
                       | (pe.bit_len or 0) & 0xFF) for pe in pdo.entries]
            capacity = max(len(values), obj.max_subindex,
                           MAX_PDO_ENTRIES if configurable and not obj.entries else 0)
            self._array(obj, values, capacity, *_fixed(pdo.index, 1), writes)

    def sm_objects(self, pdos: list[Pdo], virtual: list[Pdo]) -> None:
        """0x1C00 (SM communication types) and 0x1C10+n (PDO assignment of each
        process-data SM n; default = the (non-virtual) PDOs whose ``Sm`` is n, in ESI
        order, with room for the virtual ones the master may assign)."""
        sms = self.device.sms
        types = [SM_TYPE_CODES.get(sm.type, 0) for sm in sms]
        obj = self._object(SM_COMM_TYPE, "Sync manager type")
        if (SM_COMM_TYPE, 0) not in self.esi_defaults:
            self._si0(obj, len(types), frozenset())
        for n, code in enumerate(types):
            sub = n + 1
            entry = obj.entries.get(sub)
            if entry is None:
                entry = obj.add(OdEntry(sub, f"SubIndex {sub:03d}", "USINT", 8, b"\0", "ro"))
            _standard(entry, *_fixed(SM_COMM_TYPE, sub))
            if (SM_COMM_TYPE, sub) not in self.esi_defaults:
                entry.value = _int_bytes(code, entry.byte_size)
        writes = PREOP_ONLY if self.pdo_assign else frozenset()
        for sm in sms:
            if sm.type not in ("Outputs", "Inputs"):
                continue
            direction = "rx" if sm.type == "Outputs" else "tx"
            assigned: list[int] = []
            for p in pdos:
                if p.sm == sm.number and p.index is not None and p.index not in assigned:
                    assigned.append(p.index)
            obj = self._object(SM_PDO_ASSIGN + sm.number, f"SM{sm.number} PDO assignment")
            if obj.entries:
                # Declared in the ESI dictionary: its size, unless the default needs more.
                capacity = max(len(assigned), obj.max_subindex)
            else:
                # Room for every PDO that could go to this SM (our choice).
                candidates = {p.index for p in pdos + virtual if p.direction == direction}
                capacity = max(len(assigned), len(candidates), 1)
            self._array(obj, assigned, capacity, *_fixed(obj.index, 1), writes)

    def _array(self, obj: OdObject, values: list[int], capacity: int, data_type: str,
               bits: int, writes: frozenset[AlState]) -> None:
        """A PDO mapping or assignment: subindex 0 = ``len(values)``, subindexes 1..capacity
        of ``data_type`` holding ``values`` and zeros after them, writable in ``writes``."""
        self._si0(obj, len(values), writes)
        if self.dic is None or obj.index not in self.dic.objects:
            obj.array = True                  # the ESI's own description wins
        for sub in range(1, capacity + 1):
            entry = obj.entries.get(sub)
            if entry is None:
                entry = obj.add(OdEntry(sub, f"SubIndex {sub:03d}", data_type, bits,
                                        bytes(bits // 8)))
            _standard(entry, data_type, bits)
            entry.access = "rw" if writes else "ro"
            entry.read_states, entry.write_states = MAILBOX_STATES, writes
            value = values[sub - 1] if sub <= len(values) else 0
            entry.value = _int_bytes(value, entry.byte_size)

    def identity(self) -> None:
        """0x1000 (ESI default, else AddInfo<<16 | ProfileNo) and 0x1018 with the device's
        own identity: it has to agree with the SII, whatever the ESI default says."""
        dev = self.device
        profile = next((p for p in dev.profiles if p.profile_no is not None), None)
        device_type = ((profile.add_info or 0) << 16 | (profile.profile_no or 0)
                       if profile is not None else 0)
        obj = self.objects.get(0x1000)
        if obj is None:
            obj = self.objects[0x1000] = OdObject(0x1000, "Device type", variable=True)
            obj.add(OdEntry(0, "Device type", "UDINT", 32, bytes(4), "ro"))
        if 0 in obj.entries:
            _standard(obj.entries[0], *_fixed(0x1000, 0))
            if (0x1000, 0) not in self.esi_defaults:
                obj.entries[0].value = _int_bytes(device_type, 4)
        obj = self._object(0x1018, "Identity")
        self._si0(obj, max(4, obj.max_subindex), frozenset())
        values = [dev.vendor.id or 0, dev.product_code or 0, dev.revision or 0, 0]
        names = ["Vendor ID", "Product code", "Revision", "Serial number"]
        for sub, (name, value) in enumerate(zip(names, values), start=1):
            entry = obj.entries.get(sub)
            if entry is None:
                entry = obj.add(OdEntry(sub, name, "UDINT", 32, bytes(4), "ro"))
            _standard(entry, *_fixed(0x1018, sub))
            entry.value = _int_bytes(value, 4)


def build(device: Device) -> list[OdObject]:
    """The objects of ``device``'s dictionary, in index order."""
    return list(_Builder(device).build().values())
