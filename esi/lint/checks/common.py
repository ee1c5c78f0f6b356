"""Helpers several checks share: SyncManager areas and lengths, repeated keys.

Dictionary lookups live in :mod:`ecatcfg.esi.coe` (the compiler uses them too); protocol
constants (SM control bits, the smallest mailbox) in :mod:`ecatcfg.esc`."""

from __future__ import annotations

from typing import Callable, Hashable, Iterable, Iterator, TypeVar

from ecatcfg.esi.model import Device, SyncManager

# ESC address space: registers below 0x1000 (0x0F00.. is the digital-output area that simple
# I/O terminals map an SM onto), process RAM from 0x1000 to at most 0xFFFF.
PROCESS_RAM_START, ADDRESS_SPACE_END = 0x1000, 0x10000
DIGITAL_OUTPUT_AREA = range(0x0F00, 0x0F80)


def sm_length(dev: Device, sm: SyncManager) -> int:
    """The length a configurator programs: a mailbox SM's size
    (:attr:`~ecatcfg.esi.model.SyncManager.mailbox_size`); for process data the
    default-assigned PDOs' size when there are any, else the ESI's DefaultSize (0 if none)."""
    if sm.is_mailbox:
        return sm.mailbox_size
    pdos = [p for p in dev.pdos if p.sm == sm.number and not p.virtual]
    if pdos:
        return (sum(p.bit_length for p in pdos) + 7) // 8
    return sm.default_size or 0


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
