"""Helpers several checks share: SyncManager constants and lengths, repeated keys.

Dictionary lookups live in :mod:`ecatcfg.esi.coe` (the compiler uses them too)."""

from __future__ import annotations

from typing import Callable, Hashable, Iterable, Iterator, TypeVar

from ecatcfg.esi.model import Device, SyncManager

# Mailbox header (6 bytes) + the smallest SDO request (CoE header 2 + SDO command 8).
MIN_MAILBOX_SIZE = 6 + 10

# Mode bits 1:0 and direction bits 3:2 of an SM control byte (ESC register 0x0804).
SM_MODE_MASK, SM_MODE_BUFFERED, SM_MODE_MAILBOX = 0x03, 0x00, 0x02
SM_DIR_MASK, SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES = 0x0C, 0x00, 0x04

# ESC address space: registers below 0x1000 (0x0F00.. is the digital-output area that simple
# I/O terminals map an SM onto), process RAM from 0x1000 to at most 0xFFFF.
PROCESS_RAM_START, ADDRESS_SPACE_END = 0x1000, 0x10000
DIGITAL_OUTPUT_AREA = range(0x0F00, 0x0F80)


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
