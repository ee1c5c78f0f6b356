"""A slave's InitCmds of one transition, chained into one job; the master's own.

Within a transition each slave runs its commands in the order ``eni/sequence.py`` gives
(one definition, which ``show`` prints too): register commands up to the AL-control
request, then CoE, SoE, EoE and FoE mailbox commands (FoE: ``foe_init.py``), then the
request and the rest.  The CoE and SoE commands go with each request ahead of the answer
to the one before (``mailbox_pipeline.py``).  A station's plugged modules are checked
before its CoE InitCmds configure them (``modules.py``).
One command's job is ``replay.py``.
"""

from __future__ import annotations

import struct

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import (CoeInitCmd, DcPlan, EoeInitCmd, FoeInitCmd, InitCmd, SlavePlan,
                              SoeInitCmd)
from ecatcfg.eni.sequence import transition_sequence
from ecatcfg.eni.words import init_cmd_name
from ecatcfg.esc import MODULE_IDENT_LIST, Cmd, Reg, Transition
from ecatcfg.runtime.master.lockstep import Job, Step, until_answered
from ecatcfg.runtime.master.replay import (TIMEOUT_COMMAND, ApplyError, MailboxChannel,
                                           SlaveProgress, eoe_init_cmd_job, init_cmd_job)
from ecatcfg.runtime.wire import Datagram

DC_START_DELAY_NS = 100_000_000    # SYNC start this far ahead of the reference (IgH, SOEM)


def mailbox_init_cmds(slave: SlavePlan, transition: Transition
                      ) -> tuple[list[CoeInitCmd], list[EoeInitCmd]]:
    """The slave's enabled CoE and EoE InitCmds of ``transition``, in file order."""
    sequence = transition_sequence(slave, transition)
    return sequence.coe, sequence.eoe


def slave_transition_job(slave: SlavePlan, transition: Transition,
                         progress: SlaveProgress | None = None,
                         channel: MailboxChannel | None = None) -> Job:
    """``channel``: the slave's mailbox, kept from one transition to the next so message
    counters go on 1..7 (a slave drops a message whose counter equals the previous one)."""
    who = slave.name
    sequence = transition_sequence(slave, transition)      # the order: eni/sequence.py
    for cmd in sequence.before:
        yield from _failing(cmd, _register_cmd(slave, cmd, who, progress))
    mailbox = slave.mailbox
    if mailbox is not None and sequence.has_mailbox:
        channel = channel or MailboxChannel(slave.phys_addr, mailbox)
        if any(c.index == MODULE_IDENT_LIST for c in sequence.coe):
            # A station's plugged modules, before they are configured.  Imported here:
            # modules.py needs the ESI model (esi/slots.py), which apply loads only for an
            # ENI that downloads a module ident list (tests/test_record.py,
            # tests/test_startup_counts.py).
            from ecatcfg.runtime.master.modules import check_modules
            yield from check_modules(channel, slave, transition, who)
        if sequence.coe:            # imported here: only CoE slaves need the SDO client
            from ecatcfg.runtime.master.mailbox_pipeline import coe_init_cmds_job
            yield from coe_init_cmds_job(channel, sequence.coe, who, progress)
        if sequence.soe:            # imported here: only SoE drives need the client
            from ecatcfg.runtime.master.soe_client import soe_init_cmds_job
            yield from soe_init_cmds_job(channel, sequence.soe, who, transition.name,
                                         progress)
        for e in sequence.eoe:
            yield from _failing(e, eoe_init_cmd_job(channel, e, who, progress))
        if sequence.foe:
            from ecatcfg.runtime.master.foe_init import foe_init_cmd_job
            for f in sequence.foe:
                yield from _failing(f, foe_init_cmd_job(channel, f, who, progress))
    for cmd in sequence.after:
        yield from _failing(cmd, _register_cmd(slave, cmd, who, progress))


def _failing(cmd: InitCmd | CoeInitCmd | EoeInitCmd | SoeInitCmd | FoeInitCmd,
             job: Job) -> Job:
    """``job``, whose ApplyError names ``cmd`` as the InitCmd that failed."""
    try:
        yield from job
    except ApplyError as exc:
        exc.init_cmd = exc.init_cmd or cmd
        raise


def _register_cmd(slave: SlavePlan, cmd: InitCmd, who: str,
                  progress: SlaveProgress | None) -> Job:
    data = None
    if (cmd.cmd == Cmd.FPWR and cmd.ado == Reg.DC_START_TIME_CYCLIC and cmd.data is not None
            and not any(cmd.data) and slave.dc is not None):
        data = yield from _dc_start_time(slave, slave.dc, cmd, len(cmd.data), who)
    yield from init_cmd_job(cmd, who, data, progress)


def _dc_start_time(slave: SlavePlan, dc: DcPlan, cmd: InitCmd, length: int,
                   who: str) -> Step[bytes]:
    """The ENI's start time is a zero placeholder (``length`` bytes): start SYNC0 100 ms
    after the slave's (reference-synchronised) system time, on a cycle boundary plus the
    shift (IgH, SOEM)."""
    read = Datagram.physical(Cmd.FPRD, slave.phys_addr, Reg.DC_SYSTEM_TIME, 8)
    [got] = yield from until_answered([read], monotonic() + TIMEOUT_COMMAND, ApplyError(
        "cannot read the DC system time (0x0910)", who, init_cmd_name(cmd)))
    now, = struct.unpack("<Q", got.data)
    cycle = dc.cycle_time0 or 1
    start = (now + DC_START_DELAY_NS) // cycle * cycle + cycle + dc.shift_time
    return struct.pack("<Q", start & 0xFFFF_FFFF_FFFF_FFFF)[:length]


def master_job(cmds: list[InitCmd], transition: Transition, before_slave: bool) -> Job:
    for cmd in cmds:
        if transition in cmd.transitions and bool(cmd.before_slave) == before_slave:
            yield from init_cmd_job(cmd, None)
