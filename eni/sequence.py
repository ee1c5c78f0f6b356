"""The order in which the master sends one slave's InitCmds of one transition: one
definition, which ``apply`` runs (``runtime/master/transition.py``) and ``show`` prints.

The ENI keeps a slave's register commands (``Slave/InitCmds``) apart from its mailbox ones
(``Mailbox/CoE/InitCmds``, SoE, EoE, FoE) and says nothing of how the two lists interleave.
The master sends, within a transition:

1. the register commands in file order, up to the write of the AL control register
   (0x0120) that requests the next state: the SyncManager and FMMU settings;
2. the mailbox commands: CoE first, then SoE, then EoE, then FoE, each list in file order.
   The PDO assignment must be in place before the slave checks it on the way to SAFEOP
   (ETG.2100; ETG.1000.6 "SyncManager PDO assignment"), and IgH's
   ``fsm_slave_config.c`` writes the SoE configuration after the SDO configuration and
   sets the IP parameters last;
3. the rest of the register commands, from the AL control write on: the state request and
   the check of the state reached.

In INIT->PREOP (``IP``) the mailbox is not up until the slave is in PREOP, so all register
commands come first and the mailbox commands of IP (there should be none) after them.
"""

from __future__ import annotations

from ecatcfg.eni.plan import (CoeInitCmd, EoeInitCmd, FoeInitCmd, InitCmd, SlavePlan,
                              SoeInitCmd)
from ecatcfg.esc import Cmd, Reg, Transition
from ecatcfg.record import field, record

MailboxInitCmd = CoeInitCmd | SoeInitCmd | EoeInitCmd | FoeInitCmd


def writes_al_control(cmd: InitCmd) -> bool:
    """A write of the AL control register: the state request of a transition."""
    return cmd.cmd in (Cmd.APWR, Cmd.FPWR, Cmd.BWR) and cmd.ado == Reg.AL_CONTROL


@record
class TransitionSequence:
    """One slave's InitCmds of one transition, in the order the master sends them."""

    before: list[InitCmd] = field(default_factory=list)   # register commands before ...
    coe: list[CoeInitCmd] = field(default_factory=list)   # ... the mailbox commands ...
    soe: list[SoeInitCmd] = field(default_factory=list)
    eoe: list[EoeInitCmd] = field(default_factory=list)
    foe: list[FoeInitCmd] = field(default_factory=list)
    after: list[InitCmd] = field(default_factory=list)    # ... then the state request on

    @property
    def has_mailbox(self) -> bool:
        return bool(self.coe or self.soe or self.eoe or self.foe)

    def in_order(self) -> list[InitCmd | MailboxInitCmd]:
        return [*self.before, *self.coe, *self.soe, *self.eoe, *self.foe, *self.after]


def transition_sequence(slave: SlavePlan, transition: Transition,
                        with_disabled: bool = False) -> TransitionSequence:
    """The slave's InitCmds of ``transition`` in sending order; mailbox commands the ENI
    marks disabled are left out (the master skips them) unless ``with_disabled``."""
    cmds = [c for c in slave.init_cmds if transition in c.transitions]
    mailbox = slave.mailbox
    out = TransitionSequence()
    if mailbox is not None:
        def wanted(c: MailboxInitCmd) -> bool:
            return transition in c.transitions and (with_disabled or not c.disabled)
        out.coe = [c for c in mailbox.coe_init_cmds if wanted(c)]
        out.soe = [c for c in mailbox.soe_init_cmds if wanted(c)]
        out.eoe = [c for c in mailbox.eoe_init_cmds if wanted(c)]
        out.foe = [c for c in mailbox.foe_init_cmds if wanted(c)]
    # The split follows what is sent: disabled commands shown alongside do not move it.
    mailbox_cmds: list[MailboxInitCmd] = [*out.coe, *out.soe, *out.eoe, *out.foe]
    sent = any(not c.disabled for c in mailbox_cmds)
    split = len(cmds)
    if sent and transition != Transition.IP:
        split = next((i for i, c in enumerate(cmds) if writes_al_control(c)), len(cmds))
    out.before, out.after = cmds[:split], cmds[split:]
    return out


__all__ = ["MailboxInitCmd", "TransitionSequence", "transition_sequence", "writes_al_control"]
