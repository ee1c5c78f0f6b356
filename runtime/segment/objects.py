"""The runtime object dictionary of an emulated CoE slave, built from its ESI.

Every object has subentries with a type, a bit size, access rights per AL state and a
current value (little-endian bytes, as on the wire) initialised from the ESI defaults.
On top of what the ESI dictionary declares, :meth:`ObjectDictionary.from_device` makes sure
the objects a master needs exist (many ESIs declare CoE but give no dictionary):
0x1000, 0x1018, the PDO mapping objects 0x16xx/0x1Axx, 0x1C00 and the PDO assignment objects
0x1C1n, plus every object an ESI PDO maps.

Access rules and abort codes follow ``docs/protocol-notes.md`` §6 ("protocol-notes §6") and
SOES (``esc_coe.c``, ``ESC_download_pre_objecthandler``); where both are silent the choice is
commented where it is made.  The SDO server (``sdo_server``) is the wire side; this module
only knows objects, bytes and AL states.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from ecatcfg.esc import (MAX_PDO_ENTRIES, RX_PDO_MAPPING, SM_COMM_TYPE, SM_PDO_ASSIGN,
                         SM_TYPE_CODES, TX_PDO_MAPPING, AlState, is_pdo_object)
from ecatcfg.esi.coe import device_dictionary
from ecatcfg.esi.datatypes import bit_size as base_bit_size
from ecatcfg.esi.datatypes import canonical, download_fits
from ecatcfg.esi.model import (
    Device, DictObject, Dictionary, ObjectFlags, ObjectInfo, Pdo, pick_name,
)
from ecatcfg.runtime.mailbox import (
    ABORT_CA_NOT_SUPPORTED, ABORT_LENGTH_TOO_HIGH, ABORT_LENGTH_TOO_LOW, ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX, ABORT_READ_ONLY, ABORT_SUBINDEX0_NOT_ZERO, ABORT_TYPE_MISMATCH,
    ABORT_UNSUPPORTED_ACCESS, ABORT_VALUE_RANGE, ABORT_VALUE_TOO_HIGH, ABORT_VALUE_TOO_LOW,
    ABORT_WRITE_ONLY, ABORT_WRONG_STATE, SdoAbort,
)

# ETG.2000 access restriction names -> AL states (esi.model.STATES).
_STATE_BY_NAME = {"PreOp": AlState.PREOP, "SafeOp": AlState.SAFEOP, "Op": AlState.OP}
MAILBOX_STATES = frozenset((AlState.PREOP, AlState.SAFEOP, AlState.OP))
PREOP_ONLY = frozenset((AlState.PREOP,))


# Capacity of a configurable mapping object the ESI does not describe (no dictionary
# entry): our choice, large enough for the mappings seen in the corpus ENIs (EC-murr maps
# 32 entries with one complete-access download, docs/eni-exports.md §5).
CONFIGURABLE_MAPPING_CAPACITY = 32

_SIGNED = frozenset(("SINT", "INT", "INT24", "DINT", "INT40", "INT48", "INT56", "LINT"))
_FLOAT = frozenset(("REAL", "LREAL"))
_STRINGS = ("STRING", "WSTRING", "OCTET_STRING", "UNICODE_STRING", "DOMAIN")


def _kind(type_name: str) -> str:
    """``unsigned``, ``signed``, ``float``, ``string`` (visible/octet/unicode/domain) or
    ``octets`` (arrays, records used as values, unknown types)."""
    if type_name in _SIGNED:
        return "signed"
    if type_name in _FLOAT:
        return "float"
    if type_name.startswith(_STRINGS):
        return "string"
    if type_name.startswith("ARRAY") or canonical(type_name) is None:
        return "octets"
    return "unsigned"


@dataclass(slots=True)
class OdEntry:
    """One subindex: its type, size, access and current value (wire bytes)."""

    subindex: int
    name: str
    type: str                     # canonical base type name when known, else the ESI name
    bit_size: int                 # 0: variable length (STRING(0), DOMAIN)
    value: bytes
    access: str = "rw"            # "ro", "rw" or "wo"
    read_states: frozenset[AlState] = MAILBOX_STATES
    write_states: frozenset[AlState] = MAILBOX_STATES
    mappable: str = ""            # "R" (RxPDO), "T" (TxPDO) or both
    min_value: int | None = None
    max_value: int | None = None
    # Where the entry sits in the object's complete-access image (ESI DataType SubItem
    # BitOffs, counted from subindex 0); None: packed by the rule in ObjectDictionary._layout.
    bit_offset: int | None = None

    @property
    def kind(self) -> str:
        return _kind(self.type)

    @property
    def byte_size(self) -> int:
        return (self.bit_size + 7) // 8

    @property
    def variable_length(self) -> bool:
        return self.bit_size == 0

    def readable(self, state: AlState) -> bool:
        return "r" in self.access and state in self.read_states

    def writable(self, state: AlState) -> bool:
        return "w" in self.access and state in self.write_states

    def as_int(self) -> int:
        return int.from_bytes(self.value, "little", signed=self.kind == "signed")


@dataclass(slots=True)
class OdObject:
    """One index.  A simple variable (``variable``) has only subindex 0; arrays and records
    have subindex 0 = number of entries and their entries."""

    index: int
    name: str
    entries: dict[int, OdEntry] = field(default_factory=dict)
    variable: bool = False
    # The mapping object of a virtual PDO (ETG.2000 Pdo@Virtual): the device configures its
    # variables from the mapping the master writes, so an entry may name an object the
    # dictionary does not have.
    virtual_pdo: bool = False

    def __getitem__(self, subindex: int) -> OdEntry:
        return self.entries[subindex]

    def add(self, entry: OdEntry) -> OdEntry:
        self.entries[entry.subindex] = entry
        self.entries = dict(sorted(self.entries.items()))
        return entry

    @property
    def max_subindex(self) -> int:
        return max(self.entries, default=0)

    @property
    def count(self) -> int:
        """The current value of subindex 0 (number of entries in use)."""
        si0 = self.entries.get(0)
        return si0.as_int() if si0 is not None and not self.variable else 0


# -- building from the ESI --------------------------------------------------------------

def _resolve_type(dic: Dictionary | None, name: str) -> tuple[str, int | None]:
    """(type name, bit size) of an ESI type: a base type by its canonical name, a
    dictionary type that only renames a base type (enums, ``DT0800EN03``) by that base type
    and its own BitSize, anything else by the dictionary's BitSize."""
    seen: set[str] = set()
    current = name
    size: int | None = None
    while current and current not in seen:
        seen.add(current)
        base = canonical(current)
        if base is not None:
            return base, size if size is not None else base_bit_size(base)
        dt = dic.data_types.get(current) if dic is not None else None
        if dt is None:
            break
        if size is None:
            size = dt.bit_size
        if dt.base_type and not dt.sub_items and not dt.array_info:
            current = dt.base_type
            continue
        break
    return name, size


def _int_bytes(value: int, nbytes: int) -> bytes:
    nbytes = max(nbytes, 1)
    return (value & ((1 << (8 * nbytes)) - 1)).to_bytes(nbytes, "little")


def _fit(data: bytes, nbytes: int) -> bytes:
    """``data`` truncated or zero-padded to ``nbytes`` (as is for variable length)."""
    if nbytes <= 0:
        return bytes(data)
    return bytes(data[:nbytes]).ljust(nbytes, b"\0")


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
                    mode, reads, writes, _mappable(spec.flags), bit_offset=spec.bit_offset)
    raw = _default(info, entry.kind, entry.byte_size)
    if raw is not None:
        defaults.add(spec.subindex)
    if entry.kind == "string" and entry.variable_length:
        entry.value = raw or b""
    else:
        entry.value = _fit(raw or b"", entry.byte_size)
    _bounds(info, entry)
    return entry


def _match_infos(specs: list[_EntrySpec],
                 infos: list[tuple[str, ObjectInfo]]) -> dict[int, ObjectInfo]:
    """Info/SubItem -> subindex: by name where the name is a subentry's, else by
    position (array elements are listed one Info/SubItem per subindex)."""
    by_name: dict[str, _EntrySpec] = {}
    for spec in specs:
        by_name.setdefault(spec.name.strip().lower(), spec)
    matched: dict[int, ObjectInfo] = {}
    for pos, (name, info) in enumerate(infos):
        match = by_name.get(name.strip().lower())
        if match is None or match.subindex in matched:
            match = specs[pos] if pos < len(specs) else None
        if match is not None and match.subindex not in matched:
            matched[match.subindex] = info
    return matched


def _standard(entry: OdEntry, type_: str, bits: int) -> None:
    """Give a communication-area entry its ETG.1000.6 type, whatever the ESI declares:
    masters read these into fixed-size buffers (SOEM reads 0x1C00:n into one byte and fails
    with "data container too small" on more), and a real slave answers with the standard
    size.  Elmo's Gold ESI, for one, declares 0x1C00's entries as UINT."""
    if entry.type != type_ or entry.bit_size != bits:
        entry.type, entry.bit_size = type_, bits
        entry.value = _fit(entry.value, (bits + 7) // 8)
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
        od_obj = OdObject(index, pick_name(obj.names), variable=variable)
        if variable:
            infos = {0: obj.info} if obj.info is not None else {}
        else:
            infos = _match_infos(specs, obj.info.sub_items) if obj.info is not None else {}
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
            self._array(obj, values, capacity, "UDINT", 32, writes)

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
            self._array(obj, values, capacity, "UDINT", 32, writes)

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
            _standard(entry, "USINT", 8)
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
            self._array(obj, assigned, capacity, "UINT", 16, writes)

    def _array(self, obj: OdObject, values: list[int], capacity: int, data_type: str,
               bits: int, writes: frozenset[AlState]) -> None:
        """A PDO mapping or assignment: subindex 0 = ``len(values)``, subindexes 1..capacity
        of ``data_type`` holding ``values`` and zeros after them, writable in ``writes``."""
        self._si0(obj, len(values), writes)
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
            _standard(obj.entries[0], "UDINT", 32)
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
            _standard(entry, "UDINT", 32)
            entry.value = _int_bytes(value, 4)


# -- the dictionary ---------------------------------------------------------------------

class ObjectDictionary:
    """Objects by index, with SDO-style access (:meth:`read`, :meth:`write`) that raises
    :class:`SdoAbort` with the code a slave would answer, and the process-data views an
    emulated ESC needs (:meth:`sm_bits`, :meth:`rx_entries`, :meth:`tx_entries`).

    ``state=None`` means internal access (the ESC or a test): no access-right checks.
    """

    def __init__(self, objects: Iterable[OdObject] = ()) -> None:
        self.objects: dict[int, OdObject] = {o.index: o for o in objects}
        self._injected: dict[tuple[int, int], int] = {}

    @classmethod
    def from_device(cls, device: Device) -> ObjectDictionary:
        return cls(_Builder(device).build().values())

    def __contains__(self, index: object) -> bool:
        return index in self.objects

    def __getitem__(self, index: int) -> OdObject:
        return self.objects[index]

    def __iter__(self) -> Iterator[OdObject]:
        return iter(self.objects.values())

    def __len__(self) -> int:
        return len(self.objects)

    def add(self, obj: OdObject) -> OdObject:
        self.objects[obj.index] = obj
        return obj

    def inject_abort(self, index: int, sub: int, code: int | None) -> None:
        """Make every SDO read or write of ``index:sub`` (also a complete access covering
        it) abort with ``code``; ``None`` removes the fault."""
        if code is None:
            self._injected.pop((index, sub), None)
        else:
            self._injected[(index, sub)] = code

    # -- internal access (no rights checked) ----------------------------------------------

    def value(self, index: int, sub: int = 0) -> bytes:
        return self._entry(index, sub).value

    def int_value(self, index: int, sub: int = 0) -> int:
        return self._entry(index, sub).as_int()

    def set_value(self, index: int, sub: int, data: bytes) -> None:
        entry = self._entry(index, sub)
        entry.value = bytes(data) if entry.variable_length else _fit(data, entry.byte_size)

    # -- SDO access -----------------------------------------------------------------------

    def read(self, index: int, sub: int, state: AlState | None, *,
             complete_access: bool = False) -> bytes:
        obj = self._object(index)
        if complete_access:
            return self._read_complete(obj, sub, state)
        entry = self._sub(obj, sub)
        self._check_injected(index, (sub,))
        if state is not None:
            self._check_read(index, entry, state)
        return entry.value

    def write(self, index: int, sub: int, data: bytes, state: AlState | None, *,
              complete_access: bool = False) -> None:
        obj = self._object(index)
        if complete_access:
            self._write_complete(obj, sub, bytes(data), state)
            return
        entry = self._sub(obj, sub)
        self._check_injected(index, (sub,))
        if state is not None:
            self._check_write(index, entry, state)
        value = self._sized(index, entry, bytes(data))
        if state is not None:
            self._check_si0_rule(obj, sub)
        self._check_range(obj, entry, value)
        entry.value = value

    def check_write(self, index: int, sub: int, size: int | None, state: AlState | None, *,
                    complete_access: bool = False) -> None:
        """The aborts a download of ``size`` bytes to ``index:sub`` gets before its data
        is there (a server checks this at the initiate of a segmented download, as SOES
        compares the announced size with the object's)."""
        obj = self._object(index)
        if complete_access:
            entries = self._ca_entries(obj, sub)
            self._check_injected(index, [e.subindex for e in entries])
            if state is not None:
                self._check_any(index, entries, state, write=True)
            _, total = self._layout(obj, entries)
            if size is not None and size > (total + 7) // 8:
                raise SdoAbort(ABORT_LENGTH_TOO_HIGH, index, sub)
            return
        entry = self._sub(obj, sub)
        self._check_injected(index, (sub,))
        if state is not None:
            self._check_write(index, entry, state)
        code = self._length_abort(entry, size) if size is not None else None
        if code is not None:
            raise SdoAbort(code, index, sub)
        if state is not None:
            self._check_si0_rule(obj, sub)

    # -- checks ---------------------------------------------------------------------------

    def _object(self, index: int) -> OdObject:
        obj = self.objects.get(index)
        if obj is None:
            raise SdoAbort(ABORT_NO_OBJECT, index, 0)
        return obj

    @staticmethod
    def _sub(obj: OdObject, sub: int) -> OdEntry:
        entry = obj.entries.get(sub)
        if entry is None:
            raise SdoAbort(ABORT_NO_SUBINDEX, obj.index, sub)
        return entry

    def _entry(self, index: int, sub: int) -> OdEntry:
        return self._sub(self._object(index), sub)

    def _check_injected(self, index: int, subs: Iterable[int]) -> None:
        for sub in subs:
            code = self._injected.get((index, sub))
            if code is not None:
                raise SdoAbort(code, index, sub)

    @staticmethod
    def _check_read(index: int, entry: OdEntry, state: AlState) -> None:
        if "r" not in entry.access or not entry.read_states:
            raise SdoAbort(ABORT_WRITE_ONLY, index, entry.subindex)
        if state not in entry.read_states:
            raise SdoAbort(ABORT_WRONG_STATE, index, entry.subindex)

    @staticmethod
    def _check_write(index: int, entry: OdEntry, state: AlState) -> None:
        if "w" not in entry.access or not entry.write_states:
            raise SdoAbort(ABORT_READ_ONLY, index, entry.subindex)
        if state not in entry.write_states:
            # Writable, but not in this AL state (e.g. 0x1C12 in SAFEOP; SOES ATYPE_RWpre).
            raise SdoAbort(ABORT_WRONG_STATE, index, entry.subindex)

    @staticmethod
    def _check_any(index: int, entries: list[OdEntry], state: AlState, write: bool) -> None:
        """Complete access: fine if some entry may be accessed now; else the code for the
        entry that comes closest (wrong state before no access at all)."""
        able: Callable[[OdEntry], bool] = ((lambda e: e.writable(state)) if write
                                           else (lambda e: e.readable(state)))
        if not entries or any(able(e) for e in entries):
            return
        letter = "w" if write else "r"
        if any(letter in e.access and (e.write_states if write else e.read_states)
               for e in entries):
            raise SdoAbort(ABORT_WRONG_STATE, index, entries[0].subindex)
        raise SdoAbort(ABORT_READ_ONLY if write else ABORT_WRITE_ONLY, index,
                       entries[0].subindex if entries else 0)

    @staticmethod
    def _length_abort(entry: OdEntry, length: int) -> int | None:
        """The abort for writing ``length`` bytes to ``entry`` (None: fine)."""
        # Which lengths fit is the rule lint checks ESI InitCmds by (esi/datatypes.py): a
        # visible/octet string may be written shorter than its declared size, the rest
        # zero (CANopen visible strings are NUL-terminated); a number takes its size.
        if entry.variable_length or download_fits(entry.type, entry.byte_size, length):
            return None
        if entry.kind == "string":
            return ABORT_LENGTH_TOO_HIGH if length > entry.byte_size else ABORT_LENGTH_TOO_LOW
        # Numbers: SOES answers any length mismatch with 0x06070010 (ABORT_TYPEMISMATCH).
        return ABORT_TYPE_MISMATCH

    def _sized(self, index: int, entry: OdEntry, data: bytes) -> bytes:
        """The value to store for ``data`` written to ``entry``, or the length abort."""
        code = self._length_abort(entry, len(data))
        if code is not None:
            raise SdoAbort(code, index, entry.subindex)
        return data if entry.variable_length else data.ljust(entry.byte_size, b"\0")

    @staticmethod
    def _check_si0_rule(obj: OdObject, sub: int) -> None:
        # PDO mapping and assignment objects: entries may only be written while SI0 is 0
        # (SOES ESC_download_pre_objecthandler; protocol-notes §6 abort 0x06010003).
        if sub >= 1 and is_pdo_object(obj.index) and obj.count != 0:
            raise SdoAbort(ABORT_SUBINDEX0_NOT_ZERO, obj.index, sub)

    @staticmethod
    def _check_range(obj: OdObject, entry: OdEntry, value: bytes) -> None:
        kind = entry.kind
        if kind not in ("signed", "unsigned") or not 0 < entry.bit_size <= 64:
            return
        number = int.from_bytes(value, "little", signed=kind == "signed")
        if entry.subindex == 0 and not obj.variable and number > obj.max_subindex:
            # More entries in use than the object has.
            raise SdoAbort(ABORT_VALUE_TOO_HIGH, obj.index, entry.subindex)
        if entry.bit_size % 8 and not 0 <= number < 1 << entry.bit_size:
            # BOOL / BITn written with a value that does not fit its bits.
            raise SdoAbort(ABORT_VALUE_RANGE, obj.index, entry.subindex)
        if entry.max_value is not None and number > entry.max_value:
            raise SdoAbort(ABORT_VALUE_TOO_HIGH, obj.index, entry.subindex)
        if entry.min_value is not None and number < entry.min_value:
            raise SdoAbort(ABORT_VALUE_TOO_LOW, obj.index, entry.subindex)

    # -- complete access (protocol-notes §6) ------------------------------------------------

    def _ca_entries(self, obj: OdObject, sub: int, *, upload: bool = False) -> list[OdEntry]:
        """The entries a complete access starting at ``sub`` covers, in order.

        Subindex must be 0 or 1 (SOES aborts 0x06010000 otherwise).  Uploads cover the
        entries up to the current value of SI0; downloads may cover every entry the object
        has (the data length says how many).  Where SOES (all declared entries) and the
        Beckhoff SSC (arrays: up to the current SI0) differ on uploads, we follow the SSC:
        a 0x1C12 with one PDO assigned reads back as ``01 00 xx xx``, as TwinCAT writes it.
        """
        if sub > 1:
            raise SdoAbort(ABORT_UNSUPPORTED_ACCESS, obj.index, sub)
        if obj.variable:
            entry = self._sub(obj, sub)
            if entry.kind == "string" or entry.variable_length:
                raise SdoAbort(ABORT_CA_NOT_SUPPORTED, obj.index, sub)
            return [entry]
        if sub == 0 or not any(s >= 1 for s in obj.entries):
            self._sub(obj, sub)
        # From subindex 1: the entries from 1 on, also when the ESI declares no subindex 1
        # (a record whose first bits are reserved, as many Beckhoff settings objects).
        last = min(obj.count, obj.max_subindex) if upload else obj.max_subindex
        entries = [e for s, e in obj.entries.items() if sub <= s and (s == 0 or s <= last)]
        if any(e.variable_length for e in entries):
            raise SdoAbort(ABORT_CA_NOT_SUPPORTED, obj.index, sub)
        return entries

    @staticmethod
    def _layout(obj: OdObject,
                entries: list[OdEntry]) -> tuple[list[tuple[OdEntry, int, int]], int]:
        """(entry, bit offset, bit length on the wire) and the total bits.

        Where the ESI places every entry of a record (DataType SubItem BitOffs, consistent:
        SI0 at 0, the others from bit 16 on, none overlapping), the image follows it, gaps
        included: the bits of subindices the ESI does not describe are the device's
        reserved bits, and a configurator writes the record as the ESI lays it out (a
        complete access from subindex 1 starts at the record's bit 16).  Otherwise SI0
        takes 16 bits unless the object is a variable, bit-sized entries are packed, the
        others start on a byte boundary (SOES ``complete_access_subindex_loop``)."""
        placed = ObjectDictionary._placed(obj)
        if placed is not None and entries:
            start = 0 if entries[0].subindex == 0 else 16
            out = [(e, placed[e.subindex] - start, 8 if e.subindex == 0 else e.bit_size)
                   for e in entries]
            return out, max(off + bits for _, off, bits in out)
        out = []
        pos = 0
        for e in entries:
            if e.subindex == 0 and not obj.variable:
                out.append((e, pos, 8))
                pos += 16
                continue
            if e.bit_size % 8 == 0 and pos % 8:
                pos += 8 - pos % 8
            out.append((e, pos, e.bit_size))
            pos += e.bit_size
        return out, pos

    @staticmethod
    def _placed(obj: OdObject) -> dict[int, int] | None:
        """Subindex -> BitOffs when the ESI gives a consistent one for every entry of the
        record, else None."""
        if obj.variable or any(e.bit_offset is None for e in obj.entries.values()):
            return None
        end = 0
        placed: dict[int, int] = {}
        for sub, e in obj.entries.items():                  # in subindex order
            off = e.bit_offset
            assert off is not None
            if (sub == 0) != (off == 0) or (sub > 0 and off < 16) or off < end \
                    or e.variable_length:
                return None
            placed[sub] = off
            end = off + (16 if sub == 0 else e.bit_size)
        return placed

    def _read_complete(self, obj: OdObject, sub: int, state: AlState | None) -> bytes:
        entries = self._ca_entries(obj, sub, upload=True)
        self._check_injected(obj.index, [e.subindex for e in entries])
        if state is not None:
            self._check_any(obj.index, entries, state, write=False)
        layout, total = self._layout(obj, entries)
        acc = 0
        for e, off, bits in layout:
            if state is not None and not e.readable(state):
                continue                      # unreadable entries read as zeros (SOES)
            value = int.from_bytes(e.value, "little") & ((1 << bits) - 1)
            acc |= value << off
        return acc.to_bytes((total + 7) // 8, "little")

    def _write_complete(self, obj: OdObject, sub: int, data: bytes,
                        state: AlState | None) -> None:
        entries = self._ca_entries(obj, sub)
        layout, total = self._layout(obj, entries)
        if not data:
            raise SdoAbort(ABORT_LENGTH_TOO_LOW, obj.index, sub)
        if len(data) > (total + 7) // 8:
            raise SdoAbort(ABORT_LENGTH_TOO_HIGH, obj.index, sub)
        end = len(data) * 8
        covered = [(e, off, bits) for e, off, bits in layout if off < end]
        if any(off + bits > end for _, off, bits in covered):
            # The data stops inside an entry (SOES accepts shorter data for the conformance
            # tool, but only whole entries make sense).
            raise SdoAbort(ABORT_TYPE_MISMATCH, obj.index, sub)
        self._check_injected(obj.index, [e.subindex for e, _, _ in covered])
        if state is not None:
            self._check_any(obj.index, [e for e, _, _ in covered], state, write=True)
        acc = int.from_bytes(data, "little")
        updates: list[tuple[OdEntry, bytes]] = []
        for e, off, bits in covered:
            if state is not None and not e.writable(state):
                continue                      # read-only entries are skipped (SOES)
            value = ((acc >> off) & ((1 << bits) - 1)).to_bytes(e.byte_size, "little")
            self._check_range(obj, e, value)
            updates.append((e, value))
        for e, value in updates:
            e.value = value

    # -- process data views ---------------------------------------------------------------

    def sm_entries(self, sm: int) -> list[tuple[int, int, int]] | None:
        """(index, subindex, bit length) of every mapped entry of SM ``sm``, in process
        image order (padding gaps have index 0); ``None`` when the current assignment
        (0x1C10+sm) or a mapping it names is invalid."""
        assign = self.objects.get(SM_PDO_ASSIGN + sm)
        if assign is None or assign.variable:
            return None
        out: list[tuple[int, int, int]] = []
        for n in range(1, assign.count + 1):
            slot = assign.entries.get(n)
            if slot is None:
                return None
            pdo_index = slot.as_int() & 0xFFFF
            if pdo_index in RX_PDO_MAPPING:
                direction = "R"
            elif pdo_index in TX_PDO_MAPPING:
                direction = "T"
            else:
                return None
            mapping = self.objects.get(pdo_index)
            if mapping is None or mapping.variable:
                return None
            for k in range(1, mapping.count + 1):
                item = mapping.entries.get(k)
                if item is None:
                    return None
                word = item.as_int() & 0xFFFFFFFF
                index, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
                if index != 0:
                    target = self.objects.get(index)
                    entry = target.entries.get(sub) if target is not None else None
                    # The mapping's bit length is taken as given (not compared with the
                    # object's size), as SOES sizes PDOs from the mapping alone.  A
                    # virtual PDO's variable need not be an object (OdObject.virtual_pdo).
                    variable = target is None and mapping.virtual_pdo
                    if not variable and (entry is None or direction not in entry.mappable):
                        return None
                out.append((index, sub, bits))
        return out

    def sm_bits(self, sm: int) -> int | None:
        """Process-data size of SM ``sm`` in bits from the current 0x1C1n assignment and
        mapping objects; ``None`` if that assignment is invalid (the ESC then refuses
        SAFEOP with 0x001D / 0x001E, protocol-notes §3)."""
        entries = self.sm_entries(sm)
        return None if entries is None else sum(bits for _, _, bits in entries)

    def rx_entries(self, sm: int) -> list[tuple[int, int, int]]:
        """The output (RxPDO) entries of SM ``sm``; empty when its assignment is invalid."""
        return self.sm_entries(sm) or []

    def tx_entries(self, sm: int) -> list[tuple[int, int, int]]:
        """The input (TxPDO) entries of SM ``sm``; empty when its assignment is invalid."""
        return self.sm_entries(sm) or []

