"""Helpers several checks share: dictionary lookups, SyncManager lengths, CoE support."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Hashable, Iterable, Iterator, TypeVar

from ecatcfg.esi.model import (
    Device, DictObject, Dictionary, ObjectFlags, SyncManager,
)

# Mailbox header (6 bytes) + the smallest SDO request (CoE header 2 + SDO command 8).
MIN_MAILBOX_SIZE = 6 + 10

# Mode bits 1:0 and direction bits 3:2 of an SM control byte (ESC register 0x0804).
SM_MODE_MASK, SM_MODE_BUFFERED, SM_MODE_MAILBOX = 0x03, 0x00, 0x02
SM_DIR_MASK, SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES = 0x0C, 0x00, 0x04

# ESC address space: registers below 0x1000 (0x0F00.. is the digital-output area that simple
# I/O terminals map an SM onto), process RAM from 0x1000 to at most 0xFFFF.
PROCESS_RAM_START, ADDRESS_SPACE_END = 0x1000, 0x10000
DIGITAL_OUTPUT_AREA = range(0x0F00, 0x0F80)

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


def sm_length(dev: Device, sm: SyncManager) -> int:
    """The length a configurator programs: the default-assigned PDOs' size for a
    process-data SM that has any, else the ESI's DefaultSize (0 if none)."""
    if not sm.is_mailbox:
        pdos = [p for p in dev.pdos if p.sm == sm.number and not p.virtual]
        if pdos:
            return (sum(p.bit_length for p in pdos) + 7) // 8
    if sm.default_size is not None:
        return sm.default_size
    return (sm.max_size or 0) if sm.is_mailbox else 0


T = TypeVar("T")


def repeats(items: Iterable[T], key: Callable[[T], Hashable | None]) -> Iterator[tuple[T, T]]:
    """(item, the first item with the same key) for every later item sharing a key; items
    whose key is ``None`` are left out."""
    first: dict[Hashable, T] = {}
    for item in items:
        k = key(item)
        if k is None:
            continue
        if k in first:
            yield item, first[k]
        else:
            first[k] = item


def hex4(value: int | None) -> str:
    return "?" if value is None else f"0x{value:04X}"
