"""The CoE view of a device: its object dictionary and what one ``index:subindex`` is.

Shared by lint (checks that InitCmds and PDO entries match the dictionary) and the compiler
(typing user SDOs, checking PDO mappings).
"""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.esc import SM_COMM_TYPE, SM_PDO_ASSIGN_RANGE, pdo_mapping_range
from ecatcfg.esi.datatypes import bit_size as base_bit_size
from ecatcfg.esi.datatypes import canonical
from ecatcfg.esi.model import Device, DictObject, Dictionary, ObjectFlags, ObjectInfo

# The AL state an InitCmd's SDO runs in: a transition's commands are sent from its source
# state, except I->P, whose mailbox commands can only run once the mailbox is up (PreOp).
TRANSITION_STATE = {
    "IP": "PreOp", "PS": "PreOp", "PI": "PreOp", "PO": "PreOp",
    "SP": "SafeOp", "SO": "SafeOp", "SI": "SafeOp",
    "OS": "Op", "OP": "Op", "OI": "Op",
}


@dataclass(frozen=True, slots=True)
class DictEntry:
    """What the dictionary says about one (index, subindex)."""

    obj: DictObject
    type: str
    bit_size: int | None
    flags: ObjectFlags | None


def has_coe(dev: Device) -> bool:
    return dev.mailbox is not None and "CoE" in dev.mailbox.protocols


def device_dictionary(dev: Device) -> Dictionary | None:
    """The device's object dictionary, merged over its Profiles (multi-axis drives give one
    Profile per channel); the first definition of an object or type wins."""
    dicts = [p.dictionary for p in dev.profiles if p.dictionary is not None]
    if len(dicts) <= 1:
        return dicts[0] if dicts else None
    merged = Dictionary({}, {}, dicts[0].source)
    for dic in dicts:
        for name, dt in dic.data_types.items():
            merged.data_types.setdefault(name, dt)
        for index, obj in dic.objects.items():
            merged.objects.setdefault(index, obj)
    return merged


def dictionary_with_objects(dev: Device) -> Dictionary | None:
    """The device's dictionary if it describes objects (an empty one says nothing)."""
    dic = device_dictionary(dev)
    return dic if dic is not None and dic.objects else None


def lookup(dic: Dictionary, index: int, subindex: int | None) -> DictEntry | DictObject | None:
    """The dictionary entry for ``index:subindex``; the object alone when the object exists
    but not the subindex; ``None`` when the object is missing."""
    obj = dic.objects.get(index)
    if obj is None:
        return None
    sub = subindex or 0
    dt = dic.data_types.get(obj.type)
    if dt is None or not (dt.sub_items or dt.array_info):
        # A simple variable: only subindex 0.
        return DictEntry(obj, obj.type, obj.bit_size, obj.flags) if sub == 0 else obj
    for item in dt.sub_items:
        if item.subindex == sub:
            return DictEntry(obj, item.type, item.bit_size, item.flags or obj.flags)
    # Records often describe their array part as one SubItem (no SubIdx) whose type is an
    # ARRAY type: it stands for subindices LBound .. LBound + Elements - 1.
    for item in dt.sub_items:
        if item.subindex is None:
            arr = dic.data_types.get(item.type)
            if arr is not None and arr.array_info:
                ai = arr.array_info[0]
                if ai.lbound <= sub < ai.lbound + ai.elements:
                    size = arr.bit_size // ai.elements if arr.bit_size else None
                    return DictEntry(obj, arr.base_type or "", size,
                                     item.flags or obj.flags)
    if dt.array_info:                      # the object's type itself is an array
        ai = dt.array_info[0]
        if sub == 0:                       # CoE arrays: subindex 0 = number of entries
            return DictEntry(obj, "USINT", 8, obj.flags)
        if ai.lbound <= sub < ai.lbound + ai.elements:
            size = dt.bit_size // ai.elements if dt.bit_size else None
            return DictEntry(obj, dt.base_type or "", size, obj.flags)
    return obj


def match_infos(subentries: list[tuple[int, str]],
                infos: list[tuple[str, ObjectInfo]]) -> dict[int, ObjectInfo]:
    """Which ``Object/Info/SubItem`` gives the default of which subindex: by name where the
    name is a subentry's (ETG.2000 names the Info's SubItems after the type's), else by
    position (array elements are listed one Info/SubItem per subindex).  ``subentries``:
    the object's (subindex, name) in subindex order, as its data type lays them out."""
    by_name: dict[str, tuple[int, str]] = {}
    for entry in subentries:
        by_name.setdefault(entry[1].strip().lower(), entry)
    matched: dict[int, ObjectInfo] = {}
    for pos, (name, info) in enumerate(infos):
        match = by_name.get(name.strip().lower())
        if match is None or match[0] in matched:
            match = subentries[pos] if pos < len(subentries) else None
        if match is not None and match[0] not in matched:
            matched[match[0]] = info
    return matched


def write_target(dic: Dictionary, index: int, subindex: int | None,
                 complete_access: bool = False) -> DictEntry | DictObject | None:
    """What a download of ``index:subindex`` writes, as :func:`lookup` says it.  A
    CompleteAccess download writes the whole object from its SubIndex (0 or 1; ETG.1000.6
    5.6.2.1): subindex 0 of a record or array is often read-only (the count is fixed)
    while its entries are writable, and a record may have no subindex 1 (its entries
    numbered from 4, Beckhoff's IO-Link settings 0x80n0), so such a download is judged by
    the first entry it really changes: the first subindex from its SubIndex on (from 1
    past a read-only subindex 0) that the object has."""
    found = lookup(dic, index, subindex)
    if not complete_access or found is None:
        return found
    sub = subindex or 0
    if isinstance(found, DictEntry):
        access = found.flags.access if found.flags else None
        if sub or access is None or "w" in access.value:
            return found
    for later in range(max(sub, 1), 256):
        entry = lookup(dic, index, later)
        if isinstance(entry, DictEntry):
            return entry
    return found


def write_refusal(found: DictEntry | DictObject | None, state: str) -> str | None:
    """Why the slave refuses a download in AL ``state`` to what :func:`write_target`
    found (SDO abort 0x06010002 for a read-only object, 0x08000022 for one writable in
    other states only), from the dictionary's ``Flags/Access`` and its
    ``WriteRestrictions`` (ETG.2000); ``None`` when the download may be made, or when the
    dictionary does not say (no such entry, no access flags)."""
    if not isinstance(found, DictEntry) or found.flags is None or found.flags.access is None:
        return None
    access = found.flags.access
    if access.writable_in(state):
        return None
    if "w" not in access.value:
        return f"access {access.value!r}"
    return "writes allowed only in " + (", ".join(sorted(access.write_states)) or "no state")


def resolve_type(dic: Dictionary | None, name: str) -> tuple[str, int | None]:
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


# -- the communication area as ETG.1000.6 fixes it ------------------------------------------------

# The AL states in which a PDO mapping (0x16xx/0x1Axx) or assignment (0x1C1n) may be written:
# the process data layout is taken at PREOP->SAFEOP (the slave checks its SM2/SM3 lengths
# against it then, AL status codes 0x001D/0x001E), so a change after PREOP has no effect
# whatever an ESI's plain ``rw`` spells (SOES gives these objects ATYPE_RWpre, read in every
# state and written in PREOP; the emulated slave likewise).
PDO_CONFIG_WRITE_STATES = frozenset(("PreOp",))


def standard_entry_type(index: int, subindex: int) -> tuple[str, int] | None:
    """(base type, bits) that ETG.1000.6 fixes for a communication-area entry, or ``None``
    where the device chooses: subindex 0 of the PDO mapping, assignment, SM type and
    identity objects counts entries (USINT); a mapping entry is index<<16 | sub<<8 | bits
    (UDINT); an assignment entry a PDO index (UINT); an SM type entry a code 0..4
    (USINT); the identity's entries and the device type are UDINT."""
    mapping = index in pdo_mapping_range("rx") or index in pdo_mapping_range("tx")
    if index == 0x1000 and subindex == 0:
        return "UDINT", 32
    if mapping or index in SM_PDO_ASSIGN_RANGE or index in (SM_COMM_TYPE, 0x1018):
        if subindex == 0:
            return "USINT", 8
        if mapping or (index == 0x1018 and subindex <= 4):
            return "UDINT", 32
        if index in SM_PDO_ASSIGN_RANGE:
            return "UINT", 16
        if index == SM_COMM_TYPE:
            return "USINT", 8
    return None
