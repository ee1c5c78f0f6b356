"""Where each slave's mailbox-full bit lies in the ENI's ``Master/MailboxStates`` area.

ETG.2100 ``MailboxStates``: a logical area (``StartAddr``, ``Count`` slaves) into which each
slave's ``Mailbox/Recv/StatusBitAddr`` bit is mapped by an FMMU over SM1's status register
(0x080D; TwinCAT and EC-Engineer map its bit 0, "buffer written", which a 1-buffer SM sets
with bit 3, "mailbox full", and clears when the master reads the mailbox: ESC datasheet
section II, SyncManager status).  One LRD over the area then tells the master which
mailboxes hold an answer, for all slaves at once.

The rule is defined here once: ``check`` reports a slave whose bit does not hold it
(:data:`ecatcfg.eni.check.network.MAILBOX_STATE`), and the master polls the bits of the
slaves this accepts and reads SM1's status of the others (``runtime/master/replay.py``).
A bit holds when it lies in the area (0 <= StatusBitAddr < Count), no other slave has it,
and an FMMU the slave's InitCmds write on the way to PREOP (INIT->PREOP) maps SM1's status
byte there, one bit, read.
"""

from __future__ import annotations

from ecatcfg.eni.plan import NetworkPlan, SlavePlan, register_writes
from ecatcfg.esc import (FMMU_SIZE, SM1_STATUS, SM_STATUS_MAILBOX_FULL, SM_STATUS_WRITE_EVENT,
                         FmmuConfig, FmmuType, Reg, Transition)
from ecatcfg.record import record

# The SM1 status bits that say the slave posted a message: "buffer written" (what the real
# exports map) and "mailbox full".
_FULL_BITS = frozenset(b for b in range(8)
                       if (1 << b) & (SM_STATUS_WRITE_EVENT | SM_STATUS_MAILBOX_FULL))


@record(frozen=True)
class StateBit:
    """A slave whose mailbox-full flag the master can read in the MailboxStates area:
    logical bit ``bit`` from ``MailboxStates/StartAddr``."""

    slave: str
    bit: int


@record(frozen=True)
class StateBitProblem:
    """A slave's ``StatusBitAddr`` that does not hold its mailbox-full flag, and why."""

    slave: SlavePlan
    message: str


def mailbox_state_fmmu_maps(fmmu: FmmuConfig, start_addr: int, bit: int) -> bool:
    """Whether ``fmmu`` copies SM1's mailbox-full flag into logical bit ``bit`` from
    ``start_addr`` (one bit, read)."""
    return (fmmu.active and fmmu.type & FmmuType.READ != 0 and fmmu.length == 1
            and fmmu.physical_start == SM1_STATUS and fmmu.physical_start_bit in _FULL_BITS
            and fmmu.logical_start == start_addr + bit // 8
            and fmmu.logical_start_bit == fmmu.logical_stop_bit == bit % 8)


def state_bits(plan: NetworkPlan) -> tuple[list[StateBit], list[StateBitProblem]]:
    """The slaves whose mailbox-full flag the MailboxStates area holds, and the slaves
    whose ``StatusBitAddr`` it does not hold (an ENI error)."""
    good: list[StateBit] = []
    problems: list[StateBitProblem] = []
    claimed = [(s, s.mailbox.status_bit_addr) for s in plan.slaves
               if s.mailbox is not None and s.mailbox.status_bit_addr is not None]
    if not claimed:
        return good, problems
    area = plan.master.mailbox_states
    if area is None:
        return good, [StateBitProblem(s, f"Mailbox/Recv/StatusBitAddr {bit} without "
                                         "Master/MailboxStates: the bit lies in no area")
                      for s, bit in claimed]
    start, count = area
    owners: dict[int, list[SlavePlan]] = {}
    for s, bit in claimed:
        owners.setdefault(bit, []).append(s)
    for s, bit in claimed:
        if not 0 <= bit < count:
            problems.append(StateBitProblem(
                s, f"Mailbox/Recv/StatusBitAddr {bit} lies outside Master/MailboxStates "
                   f"(Count {count}: bits 0 to {count - 1} from 0x{start:08X})"))
        elif len(owners[bit]) > 1:
            others = ", ".join(repr(o.name) for o in owners[bit] if o is not s)
            problems.append(StateBitProblem(
                s, f"Mailbox/Recv/StatusBitAddr {bit} is also that of slave {others}: "
                   "one bit cannot tell whose mailbox is full"))
        elif not any(mailbox_state_fmmu_maps(FmmuConfig.from_bytes(data), start, bit)
                     for writes in register_writes(s, Reg.FMMU0, FMMU_SIZE, 16).values()
                     for data, transitions in writes if Transition.IP in transitions):
            problems.append(StateBitProblem(
                s, f"Mailbox/Recv/StatusBitAddr {bit}: no FMMU its INIT->PREOP InitCmds "
                   f"write maps SM1's status (0x{SM1_STATUS:04X}) to logical bit "
                   f"{bit % 8} of 0x{start + bit // 8:08X}"))
        else:
            good.append(StateBit(s.name, bit))
    return good, problems
