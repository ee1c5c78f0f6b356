"""Completing a partial ENI: the standard register set-up of slaves whose ENI has none.

Some IDEs export an ENI with the mailbox, the process data and the CoE InitCmds of each
slave but no register InitCmds, for a master that does the standard set-up itself
(station address, SyncManagers, FMMUs, state requests).  Everything that set-up needs is
in the file all the same:

- the mailbox SyncManagers: ``Mailbox/Send`` and ``Recv`` (start and length; SM0/SM1 with
  the standard mailbox control bytes 0x26/0x22, ETG.1000.4) and ``Mailbox/BootStrap``;
- the process-data SyncManagers: ``ProcessData/Sm2``... (start address, control byte,
  enable) with the size of the PDOs assigned to each (``RxPdo``/``TxPdo`` entries), else
  its ``DefaultSize``;
- the FMMUs: where the slave's outputs and inputs lie in the process image
  (``ProcessData/Send`` and ``Recv``, in bits) and which cyclic command carries that part
  of the image to which logical address (``Cyclic/Frame/Cmd`` ``Addr`` and
  ``OutputOffs``/``InputOffs``); the mailbox-state bit from ``Mailbox/Recv/StatusBitAddr``
  and ``Master/MailboxStates``;
- DC: ``Slave/DC`` cycle and shift times, activated with SYNC0 (0x0300) or SYNC0 and SYNC1
  (0x0700): the ENI does not carry the ESI's AssignActivate word.

:func:`complete` builds a :class:`~ecatcfg.eni.standard.SlaveSetup` from those elements and
gives it to the same rule the compiler uses (:mod:`ecatcfg.eni.standard`), so a derived
set-up is what ``ecatcfg compile`` writes for the device, except for what only an ESI says:
``OpOnly`` SyncManagers (enabled in PREOP->SAFEOP here), state-machine timeouts (the
tools' defaults here), FMMUs shared by adjacent SyncManagers (one per SM here, which maps
the same bytes).  What cannot be derived is an error naming the slave and the element.
"""

from __future__ import annotations

import copy

from ecatcfg.eni.plan import MailboxArea, NetworkPlan, ProcessData, SlavePlan
from ecatcfg.eni.standard import (PdSm, SlaveSetup, mailbox_state_fmmu, master_init_cmds,
                                  pd_fmmu, pd_sm_config, slave_init_cmds)
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (SM_CONTROL_MBOX_IN, SM_CONTROL_MBOX_OUT, Cmd, FmmuConfig, FmmuType,
                         SmConfig)
from ecatcfg.record import record

# DC activation without the ESI's AssignActivate: cyclic unit and SYNC0, plus SYNC1 when
# the ENI gives it a cycle (register 0x0981, ETG.1000.4; the value IgH and SOEM write).
DC_SYNC0 = 0x0300
DC_SYNC0_SYNC1 = 0x0700


class DeriveError(EcatcfgError):
    """A partial ENI whose standard set-up cannot be derived; ``problems`` per slave."""

    def __init__(self, problems: dict[str, str], file: str | None) -> None:
        lines = "\n".join(f"  slave {name!r}: {text}" for name, text in problems.items())
        super().__init__(
            "the ENI has slaves without register InitCmds (a partial export) whose standard "
            f"set-up cannot be derived from it; nothing was sent:\n{lines}", file)
        self.problems = problems


@record(frozen=True)
class Derived:
    """A slave whose register InitCmds were derived, and what they set up."""

    slave: str
    text: str


def partial_slaves(plan: NetworkPlan) -> list[SlavePlan]:
    """The slaves the ENI gives no register InitCmds (a partial export)."""
    return plan.partial_slaves()


def complete(plan: NetworkPlan, file: str | None = None
             ) -> tuple[NetworkPlan, list[Derived]]:
    """``plan`` with the standard set-up of every slave that has no register InitCmds (and
    the master's standard InitCmds, when it has none), and what was derived; ``plan``
    itself when every slave has its InitCmds.  Raises :class:`DeriveError` listing each
    slave whose set-up cannot be derived."""
    partial = partial_slaves(plan)
    if not partial:
        return plan, []
    setups: dict[str, SlaveSetup] = {}
    problems: dict[str, str] = {}
    for slave in partial:
        try:
            setups[slave.name] = slave_setup(plan, slave)
        except _Missing as exc:
            problems[slave.name] = str(exc)
    if problems:
        raise DeriveError(problems, file)
    done = copy.deepcopy(plan)
    derived = []
    for slave in done.slaves:
        setup = setups.get(slave.name)
        if setup is not None:
            slave.init_cmds = slave_init_cmds(setup)
            derived.append(Derived(slave.name, _describe(setup)))
    if not done.master.init_cmds:
        done.master.init_cmds = master_init_cmds()
        derived.append(Derived("", "the master's standard InitCmds (clear FMMUs, SMs, DC "
                                   "registers, station addresses)"))
    return done, derived


class _Missing(Exception):
    """What the ENI lacks to derive one slave's set-up."""


def slave_setup(plan: NetworkPlan, slave: SlavePlan) -> SlaveSetup:
    """The standard set-up of ``slave`` from what the ENI says of it."""
    pd = slave.process_data or ProcessData()
    sized = _pd_sms(pd)
    fmmus = [(f, "outputs") for f in _fmmus(plan, pd, sized, True)]
    fmmus += [(f, "inputs") for f in _fmmus(plan, pd, sized, False)]
    mailbox = slave.mailbox
    if mailbox is not None and mailbox.status_bit_addr is not None:
        if plan.master.mailbox_states is None:
            raise _Missing("Mailbox/Recv/StatusBitAddr without Master/MailboxStates: where "
                           "the mailbox-state bit lies is not known")
        fmmus.append((mailbox_state_fmmu(plan.master.mailbox_states[0],
                                         mailbox.status_bit_addr), "mailbox state"))
    dc = slave.dc if slave.dc is not None and slave.dc.cycle_time0 else None
    return SlaveSetup(
        position=slave.position, phys_addr=slave.phys_addr, vendor_id=slave.vendor_id,
        product_code=slave.product_code,
        mailbox=((0, _mailbox_sm(mailbox.send, True)), (1, _mailbox_sm(mailbox.recv, False)))
        if mailbox is not None else None,
        bootstrap=(_mailbox_sm(mailbox.bootstrap_send, True),
                   _mailbox_sm(mailbox.bootstrap_recv, False))
        if mailbox is not None and mailbox.bootstrap_send is not None
        and mailbox.bootstrap_recv is not None else None,
        pd_sms=[sm for sm, _ in sized], fmmus=fmmus, dc=dc,
        assign_activate=(DC_SYNC0_SYNC1 if dc.cycle_time1 else DC_SYNC0) if dc else 0)


def _mailbox_sm(area: MailboxArea, out: bool) -> SmConfig:
    return SmConfig(area.start, area.length, SM_CONTROL_MBOX_OUT if out else SM_CONTROL_MBOX_IN,
                    True)


def _pd_sms(pd: ProcessData) -> list[tuple[PdSm, int]]:
    """The process-data SMs with their data in bits: the entries of the PDOs assigned to
    each, else its DefaultSize; a disabled one is written disabled (as the compiler does)."""
    pdos = {p.index: p for p in pd.pdos}
    out = []
    for sm in sorted(pd.sms, key=lambda s: s.number):
        if sm.virtual or sm.type not in ("Outputs", "Inputs"):
            continue
        bits = 0
        if sm.enable:
            known = [pdos[i] for i in sm.pdos if i in pdos]
            if len(known) == len(sm.pdos) and known:
                bits = sum(e.bit_len for p in known for e in p.entries)
            elif known:
                # Some of its PDOs described, some not: the length is not known, and the
                # DefaultSize is the default assignment's, not necessarily this one's.
                missing = [i for i in sm.pdos if i not in pdos]
                raise _Missing(f"ProcessData/Sm{sm.number} assigns PDOs that are not all "
                               f"described ({', '.join(f'0x{i:04X}' for i in missing)} "
                               "missing): its length is not known")
            elif sm.default_size is not None:
                bits = 8 * sm.default_size
            else:
                raise _Missing(f"ProcessData/Sm{sm.number} is enabled but its size is not "
                               f"known (PDOs {', '.join(f'0x{i:04X}' for i in sm.pdos)} not "
                               "described, no DefaultSize)")
        out.append((PdSm(sm.number, sm.type == "Outputs",
                         pd_sm_config(sm.start_address, bits, sm.control_byte)), bits))
    return out


def _fmmus(plan: NetworkPlan, pd: ProcessData, sms: list[tuple[PdSm, int]], outputs: bool
           ) -> list[FmmuConfig]:
    """One FMMU per SM with data of one direction, the SMs laid one after the other over
    the slave's ``Send`` (outputs) or ``Recv`` (inputs) bits, each mapped to the logical
    address of the cyclic command that carries that part of the image."""
    ranges = [(r.bit_start, r.bit_length) for r in (pd.send if outputs else pd.recv)
              if r.bit_length]
    with_data = [(sm, bits) for sm, bits in sms if sm.outputs == outputs and bits]
    what = "Send" if outputs else "Recv"
    if not with_data:
        return []
    fmmus = []
    at = list(ranges)
    for sm, bits in with_data:
        if not at or at[0][1] < bits:
            raise _Missing(f"ProcessData/{what} does not hold the {bits} bits of "
                           f"ProcessData/Sm{sm.number}")
        start, left = at[0]
        logical = _logical_bit(plan, start, bits, outputs)
        if logical is None:
            raise _Missing(f"no cyclic command carries the bits {start}..{start + bits - 1} "
                           f"of the {'output' if outputs else 'input'} image "
                           f"(ProcessData/{what})")
        fmmus.append(pd_fmmu(logical, bits, sm.config.start,
                             FmmuType.WRITE if outputs else FmmuType.READ))
        at[0] = (start + bits, left - bits)
        if not at[0][1]:
            at.pop(0)
    return fmmus


_WRITES_IMAGE = (Cmd.LWR, Cmd.LRW)
_READS_IMAGE = (Cmd.LRD, Cmd.LRW)


def _logical_bit(plan: NetworkPlan, image_bit: int, bits: int, outputs: bool) -> int | None:
    """The logical bit address of ``bits`` bits at ``image_bit`` of the output (input)
    image: from the cyclic command, run in OP, whose data holds that part of the image
    (its offset read in the frame's convention, ``Frame.data_shift``)."""
    kinds = _WRITES_IMAGE if outputs else _READS_IMAGE
    for cyclic in plan.cyclic:
        for frame in cyclic.frames:
            for cmd in frame.cmds:
                if cmd.cmd not in kinds or cmd.addr is None or "OP" not in cmd.states:
                    continue
                offs = 8 * ((cmd.output_offs if outputs else cmd.input_offs)
                            + frame.data_shift)
                if offs <= image_bit and image_bit + bits <= offs + 8 * cmd.length:
                    return 8 * cmd.addr + image_bit - offs
    return None


def _describe(setup: SlaveSetup) -> str:
    parts = ["station address", "state requests"]
    if setup.mailbox is not None:
        parts.append("mailbox SM0/SM1")
    if setup.pd_sms:
        parts.append("process-data " + ", ".join(f"SM{s.number}" for s in setup.pd_sms))
    if setup.fmmus:
        parts.append(f"{len(setup.fmmus)} FMMU{'s' if len(setup.fmmus) != 1 else ''}")
    if setup.dc is not None:
        parts.append(f"DC activation 0x{setup.assign_activate:04X}")
    return ("no register InitCmds in the ENI: derived the standard set-up from its Mailbox, "
            "ProcessData and cyclic frames (" + ", ".join(parts) + ")")
