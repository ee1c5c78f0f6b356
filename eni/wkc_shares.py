"""Which slaves each cyclic datagram serves, and what each adds to its working counter.

A slave takes part in a datagram when the datagram addresses it: a broadcast (BRD, BWR,
BRW) every slave with an ESC, an auto-increment command (AP**) the slave at its position, a
configured-address one (FP**) the slave with that station address, a read-multiple-write
(ARMW, FRMW) every slave (the addressed one reads, the others write), a logical one (LRD, LWR,
LRW) each slave with an FMMU whose logical range meets the datagram's, read or written as
the FMMU's type says (ETG.1000.4 "FMMU").  What the slave adds is ETG.1000.4's working
counter rule (``esc.wkc_increment``): +1 for a read, +1 for a write, LRW +1 read and +2
written.  The FMMUs are the ones the slave's InitCmds write into 0x0600 (``fmmu_records``,
the same reading ``check``'s ENI104 does), counted when written on the way up to the
highest state the command is sent in.  The sum is compared with the ENI's ``Cnt`` on the
report page; where they differ the page says so (``check`` reports it as ENI104).
"""

from __future__ import annotations

from ecatcfg.eni.check.network import fmmu_records
from ecatcfg.eni.plan import CyclicCmd, NetworkPlan, SlavePlan
from ecatcfg.esc import (AUTO_INCREMENT_CMDS, BROADCAST_CMDS, CONFIGURED_ADDRESS_CMDS,
                         LOGICAL_CMDS, REGISTER_READS, REGISTER_WRITES, AlState, Cmd,
                         FmmuType,
                         Transition, wkc_increment)
from ecatcfg.record import record

# Rank of the states a cyclic command names (ENI Cyclic/Frame/Cmd/State) and of the
# states a transition joins.
_RANK = {"INIT": 0, "PREOP": 1, "SAFEOP": 2, "OP": 3}
_STATE_RANK = {AlState.INIT: 0, AlState.PREOP: 1, AlState.SAFEOP: 2, AlState.OP: 3}


@record
class Share:
    """One slave's part in a datagram: its index in ``NetworkPlan.in_file_order()``."""

    index: int
    name: str
    read: bool
    written: bool
    adds: int                                 # to the working counter


@record
class CommandShares:
    shares: list[Share]
    known: bool                               # False: a slave's FMMUs were not readable

    @property
    def total(self) -> int:
        return sum(s.adds for s in self.shares)


def _up_to(transitions: frozenset[Transition], top: int) -> bool:
    """Whether an FMMU written in these transitions is set on the way up to rank ``top``."""
    return any(_STATE_RANK.get(t.source, 9) < _STATE_RANK.get(t.target, 9) <= top
               for t in transitions)


def _logical(cmd: CyclicCmd, slave: SlavePlan, top: int) -> tuple[bool, bool]:
    read = written = False
    if cmd.addr is None:
        return read, written
    for fmmu, transitions in fmmu_records(slave):
        if not _up_to(transitions, top):
            continue
        lo, hi = fmmu.logical_start, fmmu.logical_start + fmmu.length
        if lo < cmd.addr + cmd.length and cmd.addr < hi:
            read |= fmmu.type in (FmmuType.READ, FmmuType.READ_WRITE)
            written |= fmmu.type in (FmmuType.WRITE, FmmuType.READ_WRITE)
    # An LWR reads nothing back, an LRD writes nothing (ETG.1000.4 logical commands).
    return read and cmd.cmd != Cmd.LWR, written and cmd.cmd != Cmd.LRD


def command_shares(plan: NetworkPlan, cmd: CyclicCmd) -> CommandShares:
    index = {id(s): k for k, s in enumerate(plan.in_file_order())}
    top = max((_RANK[s] for s in cmd.states if s in _RANK), default=3)
    shares: list[Share] = []
    for slave in plan.slaves:
        if cmd.cmd in LOGICAL_CMDS:
            read, written = _logical(cmd, slave, top)
        else:
            addressed = (cmd.cmd in BROADCAST_CMDS
                         or (cmd.cmd in AUTO_INCREMENT_CMDS and cmd.adp is not None
                             and (-cmd.adp) & 0xFFFF == slave.position)
                         or (cmd.cmd in CONFIGURED_ADDRESS_CMDS and cmd.adp == slave.phys_addr))
            read = addressed and cmd.cmd in REGISTER_READS
            written = addressed and cmd.cmd in REGISTER_WRITES
            if cmd.cmd in (Cmd.ARMW, Cmd.FRMW):
                # Read multiple write (DC system time): the addressed slave reads, every
                # other one writes what it read; each adds 1 (esc.wkc_increment).
                if cmd.cmd == Cmd.ARMW:
                    addressed = cmd.adp is not None and (-cmd.adp) & 0xFFFF == slave.position
                else:
                    addressed = cmd.adp == slave.phys_addr
                read, written = addressed, not addressed
        adds = wkc_increment(cmd.cmd, read, written)
        if adds:
            shares.append(Share(index[id(slave)], slave.name, read, written, adds))
    known = not (cmd.cmd in LOGICAL_CMDS and any(
        u.what.startswith("FMMU") for u in plan.unsupported if u.slave is not None))
    return CommandShares(shares, known)


def frame_shares(plan: NetworkPlan) -> list[list[CommandShares]]:
    """Per frame (in ``show``'s order: each Cyclic's frames in turn), per command."""
    return [[command_shares(plan, c) for c in f.cmds] for cy in plan.cyclic for f in cy.frames]
