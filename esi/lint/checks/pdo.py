"""ESI1xx: PDOs, their entries, their SyncManager assignment and exclusions."""

from __future__ import annotations

from collections import defaultdict
from typing import Iterator

from ecatcfg.esi import datatypes
from ecatcfg.esi.coe import (
    DictEntry, device_dictionary, dictionary_with_objects, has_coe, lookup,
)
from ecatcfg.esc import pdo_mapping_range
from ecatcfg.esi.lint.checks.common import hex4, repeats
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule
from ecatcfg.esi.model import Device, DictObject, Pdo, PdoEntry

SM_TYPE_FOR = {"rx": "Outputs", "tx": "Inputs"}
# A PDO mapping entry (0x16xx/0x1Axx subindex value) holds the bit length in 8 bits.
MAX_ENTRY_BITS = 255


def _tag(pdo: Pdo) -> str:
    return f"{'RxPdo' if pdo.direction == 'rx' else 'TxPdo'} {hex4(pdo.index)}"


def _mapped_entries(dev: Device) -> Iterator[tuple[Pdo, PdoEntry, DictEntry | DictObject | None]]:
    """(pdo, entry, dictionary lookup) for every non-padding entry of a device whose
    dictionary lists objects.  Slot-dependent entries are left out: their index is only known
    once a module sits in the slot."""
    dic = dictionary_with_objects(dev)
    if dic is None:
        return
    for pdo in dev.pdos:
        for entry in pdo.entries:
            if entry.index is None or entry.is_padding or entry.depend_on_slot \
                    or entry.depend_on_slot_group:
                continue
            yield pdo, entry, lookup(dic, entry.index, entry.subindex)


@device_rule("ESI101", "error", "PDO index outside the CoE range for its direction", """
    In a CoE slave the PDO index is the mapping object the master reads or writes and the
    value it puts into the assignment objects 0x1C12 (RxPDOs) / 0x1C13 (TxPDOs).  ETG.1000.6
    reserves 0x1600-0x17FF for RxPDO mappings and 0x1A00-0x1BFF for TxPDO mappings; any other
    index is refused by the slave's assignment check.  Checked for devices that speak CoE;
    virtual PDOs (never assigned through CoE) are not checked.""")
def pdo_index_range(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if not has_coe(dev):
        return
    for pdo in dev.pdos:
        allowed = pdo_mapping_range(pdo.direction)
        if pdo.index is not None and not pdo.virtual and pdo.index not in allowed:
            yield Hit(pdo.source, f"{_tag(pdo)} is outside 0x{allowed.start:04X}-"
                      f"0x{allowed.stop - 1:04X}")


@device_rule("ESI102", "error", "two PDOs of a device have the same index", """
    A PDO is assigned, excluded and (re)mapped by its index; two PDOs with one index make
    0x1C12/0x1C13 ambiguous and one of them unreachable.  A virtual PDO too: an ENI lists
    the PDOs of each SyncManager by index (ETG.2100 ``ProcessData/SmN/Pdo``), so a virtual
    0x1602 on a virtual SM and a real 0x1602 cannot both be configured; compile refuses
    the device.""")
def duplicate_pdo_index(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo, first in repeats(dev.pdos, lambda p: p.index):
        yield Hit(pdo.source, f"{_tag(pdo)} repeats the index of the PDO at line "
                  f"{first.source.line}")


@device_rule("ESI103", "warning", "a PDO entry maps an object the dictionary does not have", """
    The device's dictionary (Profile/Dictionary) lists objects, but not the one this PDO entry
    maps.  The configurator cannot check the entry's type and size, and a master that
    downloads this mapping gets abort 0x06020000 from a slave that really lacks the object.
    Often the dictionary is merely incomplete (Beckhoff terminals map TxPDO-state bits of
    0x1800 objects that older ESI files do not describe): add the object to the dictionary.""")
def entry_object_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo, entry, found in _mapped_entries(dev):
        if found is None:
            yield Hit(entry.source, f"{_tag(pdo)} maps {hex4(entry.index)}:"
                      f"{entry.subindex or 0:02X}, but the dictionary has no object "
                      f"{hex4(entry.index)}")


@device_rule("ESI104", "warning", "a PDO entry maps a subindex the object does not have", """
    The object exists in the dictionary, but its data type has no such subindex.  Check the
    entry's SubIndex against the object's DataType (record SubItems, or the array bounds).""")
def entry_subindex_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo, entry, found in _mapped_entries(dev):
        if found is not None and not isinstance(found, DictEntry):
            yield Hit(entry.source, f"{_tag(pdo)} maps {hex4(entry.index)}:"
                      f"{entry.subindex or 0:02X}; object {hex4(entry.index)} ({found.type}) "
                      "has no such subindex")


@device_rule("ESI105", "error", "a PDO entry is longer than the object it maps", """
    The entry's BitLen is larger than the dictionary's BitSize for that object or subitem.  A
    slave cannot deliver more bits than the object has: the mapping download is refused
    (0x06040041 / 0x06070012) and the process image layout the configurator computes is
    wrong.""")
def entry_longer_than_object(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo, entry, found in _mapped_entries(dev):
        if isinstance(found, DictEntry) and found.bit_size is not None \
                and entry.bit_len is not None and entry.bit_len > found.bit_size:
            yield Hit(entry.source, f"{_tag(pdo)} entry {hex4(entry.index)}:"
                      f"{entry.subindex or 0:02X} has BitLen {entry.bit_len}, the dictionary "
                      f"says {found.bit_size}")


@device_rule("ESI106", "warning", "a PDO entry is shorter than the object it maps", """
    The entry maps fewer bits than the object has.  Some devices implement such partial
    mappings (Beckhoff's compact PDOs map the low 16 bits of a 32-bit counter object), but a
    generic slave refuses the download (0x06070013) and a tool that types the entry from the
    dictionary gets it wrong.  Make the dictionary and the entry agree, or document the
    device's partial mapping.""")
def entry_shorter_than_object(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo, entry, found in _mapped_entries(dev):
        if isinstance(found, DictEntry) and found.bit_size is not None \
                and entry.bit_len is not None and entry.bit_len < found.bit_size:
            yield Hit(entry.source, f"{_tag(pdo)} entry {hex4(entry.index)}:"
                      f"{entry.subindex or 0:02X} has BitLen {entry.bit_len}, the dictionary "
                      f"says {found.bit_size}")


def _same_type(a: str, b: str) -> bool:
    ca, cb = datatypes.canonical(a), datatypes.canonical(b)
    if ca is not None and cb is not None:
        return ca == cb or {ca, cb} <= {"BOOL", "BIT", "BIT1"}
    return a.strip() == b.strip()


@device_rule("ESI107", "warning", "a PDO entry's DataType differs from the dictionary's", """
    The entry's DataType names another type than the dictionary gives for the object (after
    treating spellings such as UINT16/UINT/UNSIGNED16 as one).  Tools that show or convert
    process data (a PLC variable, a C header) take the entry's type, so the value is
    misread: a signed value shown unsigned, a REAL shown as DINT.""")
def entry_type_differs(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo, entry, found in _mapped_entries(dev):
        if isinstance(found, DictEntry) and entry.data_type and found.type \
                and not _same_type(entry.data_type, found.type):
            dic = device_dictionary(dev)
            # A dictionary type derived from a base type (an enum, say) matches its base.
            dt = dic.data_types.get(found.type) if dic else None
            if dt is not None and dt.base_type and _same_type(entry.data_type, dt.base_type):
                continue
            yield Hit(entry.source, f"{_tag(pdo)} entry {hex4(entry.index)}:"
                      f"{entry.subindex or 0:02X} has DataType {entry.data_type}, the "
                      f"dictionary says {found.type}")


@device_rule("ESI108", "error", "a PDO is assigned to a SyncManager the device does not have", """
    PDO/@Sm is the number of the SyncManager (the n-th Sm element, counting from 0) the PDO is
    assigned to by default.  This device has no Sm with that number, so the configurator
    cannot place the PDO.""")
def pdo_sm_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo in dev.pdos:
        if pdo.sm is not None and not 0 <= pdo.sm < len(dev.sms):
            yield Hit(pdo.source, f"{_tag(pdo)} names Sm {pdo.sm}, but the device has "
                      f"{len(dev.sms)} SyncManager(s)")


@device_rule("ESI109", "error", "a PDO is assigned to a SyncManager of the other direction", """
    RxPDOs (outputs, master to slave) belong in an "Outputs" SyncManager, TxPDOs (inputs) in
    an "Inputs" one.  Assigned to a mailbox SM or one of the other direction, the data would
    travel the wrong way, and the slave refuses SAFEOP (AL status 0x001D/0x001E).""")
def pdo_sm_direction(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo in dev.pdos:
        if pdo.sm is not None and 0 <= pdo.sm < len(dev.sms):
            sm = dev.sms[pdo.sm]
            want = SM_TYPE_FOR[pdo.direction]
            if sm.type is not None and sm.type != want:
                yield Hit(pdo.source, f"{_tag(pdo)} is assigned to Sm {pdo.sm}, a {sm.type} "
                          f"SyncManager; it needs an {want} one")


@device_rule("ESI110", "warning", "a PDO excludes a PDO the device does not have", """
    PDO/Exclude lists PDOs that cannot be assigned together with this one.  The index named
    here matches no PDO of the device: a leftover from another revision or a typo, in which
    case the PDO that should be excluded is not.""")
def exclude_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    known = {p.index for p in dev.pdos}
    for pdo in dev.pdos:
        for ex in pdo.excludes:
            if ex not in known:
                yield Hit(pdo.source, f"{_tag(pdo)} excludes {hex4(ex)}, which the device "
                          "does not have")


@device_rule("ESI111", "error", "a Mandatory PDO is excluded by a PDO that is always there", """
    A Mandatory PDO must always be assigned.  Here it is excluded by another PDO that is
    Mandatory itself or assigned by default (has an Sm), so the default configuration (or
    every configuration) breaks the device's own exclusion rules.""")
def mandatory_excluded(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    excluded_by: dict[int, list[Pdo]] = defaultdict(list)   # index -> PDOs always there
    for other in dev.pdos:
        if other.mandatory or other.sm is not None:
            for ex in other.excludes:
                excluded_by[ex].append(other)
    for pdo in dev.pdos:
        if not pdo.mandatory or pdo.index is None:
            continue
        for other in excluded_by.get(pdo.index, ()):
            if other is not pdo:
                why = "Mandatory" if other.mandatory else f"assigned to Sm {other.sm}"
                yield Hit(pdo.source, f"Mandatory {_tag(pdo)} is excluded by {_tag(other)} "
                          f"({why}, line {other.source.line})")


@device_rule("ESI112", "error", "the default-assigned PDOs do not fit their SyncManager", """
    The PDOs assigned to a SyncManager by default (PDO/@Sm) together need more bytes than the
    SM's MaxSize allows, so the default configuration cannot be written to the ESC.""")
def default_assignment_overflow(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    groups: dict[int, list[Pdo]] = defaultdict(list)
    for pdo in dev.pdos:
        if pdo.sm is not None and not pdo.virtual:
            groups[pdo.sm].append(pdo)
    for number, pdos in sorted(groups.items()):
        if not 0 <= number < len(dev.sms):
            continue
        sm = dev.sms[number]
        size = (sum(p.bit_length for p in pdos) + 7) // 8
        if sm.max_size is not None and size > sm.max_size:
            names = ", ".join(hex4(p.index) for p in pdos)
            yield Hit(sm.source, f"Sm {number}: the default PDOs ({names}) need {size} bytes, "
                      f"MaxSize is {sm.max_size}")


@device_rule("ESI113", "error", "a PDO entry has an impossible bit length", """
    A PDO entry is 1 to 255 bits long: the mapping object stores the length in one byte
    (ETG.1000.6, objects 0x1600-0x1BFF).  A BitLen of 0 or above 255 cannot be mapped and
    would make the configurator compute an absurd process image.""")
def entry_bit_length(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo in dev.pdos:
        for entry in pdo.entries:
            if entry.bit_len is not None and not 1 <= entry.bit_len <= MAX_ENTRY_BITS:
                yield Hit(entry.source, f"{_tag(pdo)} entry has BitLen {entry.bit_len}; "
                          f"it must be 1-{MAX_ENTRY_BITS}")


@device_rule("ESI114", "error", "a PDO has no Index", """
    ETG.2000 requires every RxPdo and TxPdo to have an Index: it is the mapping object and
    the value of the assignment objects 0x1C12/0x1C13, and the SII PDO category stores it.
    Some old Beckhoff files describe a PDO by ``Ref`` and ``Chn`` attributes that point at a
    shared description; no ETG schema defines them, and a configurator cannot assign such a
    PDO (``ecatcfg compile`` refuses it rather than lose the device's process data).""")
def pdo_without_index(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for pdo in dev.pdos:
        if pdo.index is None:
            yield Hit(pdo.source, f"{'RxPdo' if pdo.direction == 'rx' else 'TxPdo'} has no "
                      "Index")
