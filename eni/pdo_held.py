"""What a slave's CoE InitCmds leave in its PDO assignment (0x1C10 + n) and mapping objects
(0x1600-0x17FF, 0x1A00-0x1BFF) on the way up to SAFEOP, with the command behind each value.

A slave checks its process-data SyncManagers against these objects before SAFEOP (SOES
``ESC_checkSM23``, ETG.1000.6 PDO assignment and mapping): what they hold after the INIT->PREOP
and PREOP->SAFEOP downloads is what ``check`` compares with the ENI's ``ProcessData``, its SM
lengths and FMMUs.  The downloads are decoded by :func:`ecatcfg.esc.array_downloads` (complete
access included), one write at a time, so each value keeps the command that wrote it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from ecatcfg.eni.plan import CoeInitCmd
from ecatcfg.esc import (RX_PDO_MAPPING, SM_PDO_ASSIGN_RANGE, TX_PDO_MAPPING, Transition,
                         array_downloads)

# The downloads that run before the slave checks its PDO configuration for SAFEOP, in the
# order the master sends them (apply: INIT->PREOP, then PREOP->SAFEOP).
UP_TO_SAFEOP = (Transition.IP, Transition.PS)


def entry_size(index: int) -> int:
    """The entry size of a PDO assignment (2) or mapping (4) object, 0 for any other."""
    if index in SM_PDO_ASSIGN_RANGE:
        return 2
    return 4 if index in RX_PDO_MAPPING or index in TX_PDO_MAPPING else 0


@dataclass(slots=True)
class HeldObject:
    """One PDO object after the downloads: subindex 0 and the entries, and for each the
    position (in the slave's ``coe_init_cmds``) and transition of the command that wrote it
    last."""

    index: int
    count: int | None = None
    entries: dict[int, int] = field(default_factory=dict)
    written_by: dict[int, tuple[int, Transition]] = field(default_factory=dict)

    def values(self) -> list[int | None] | None:
        """Subindex 1..count (None where no download wrote one); None without a count."""
        if self.count is None:
            return None
        return [self.entries.get(k) for k in range(1, self.count + 1)]

    def command(self, subindex: int) -> tuple[int, Transition] | None:
        return self.written_by.get(subindex)


def pdo_objects_held(cmds: Sequence[CoeInitCmd]) -> dict[int, HeldObject]:
    """The PDO assignment and mapping objects the enabled downloads of ``cmds`` write in
    INIT->PREOP and PREOP->SAFEOP, as they hold them when the slave is asked for SAFEOP."""
    held: dict[int, HeldObject] = {}
    for transition in UP_TO_SAFEOP:
        for position, cmd in enumerate(cmds):
            size = entry_size(cmd.index)
            if cmd.disabled or cmd.ccs != 1 or not size or transition not in cmd.transitions:
                continue
            obj = held.setdefault(cmd.index, HeldObject(cmd.index))
            count, entries = array_downloads([(cmd.subindex, cmd.data, cmd.complete_access)],
                                             size)
            if count is not None:
                obj.count = count
                obj.written_by[0] = (position, transition)
            for subindex, value in entries.items():
                obj.entries[subindex] = value
                obj.written_by[subindex] = (position, transition)
    return held
