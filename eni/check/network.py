"""Checks of an ENI against itself: SyncManagers, FMMUs, the process image, expected
working counters, mailbox areas and protocols, SoE InitCmds (a frame too long for Ethernet is refused by
the reader already: ENI004).  They need no ESI file: the registers a slave's
InitCmds write (SyncManagers 0x0800 + 8·n, FMMUs 0x0600 + 16·n; ESC Section II) are
compared with what the same file's ``ProcessData``, ``Mailbox`` and ``Cyclic`` say."""

from __future__ import annotations

from collections.abc import Sequence

from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.contents import ENCRYPTED_FMMU, UNMAPPED_FMMU
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.mailbox_states import state_bits
from ecatcfg.eni.plan import (COPY_ELEMENT, BitRange, CoeInitCmd, EoeInitCmd, FoeInitCmd,
                              PdoDesc, SlavePlan, SmSettings, SoeInitCmd, register_writes,
                              register_writes_at)
from ecatcfg.eni.words import soe_words
from ecatcfg.esi.idn import ENI_TRANSITIONS
from ecatcfg.esc import (FMMU_SIZE, LOGICAL_CMDS, SM_SIZE, AlState, Cmd, FmmuConfig,
                         FmmuType, Reg, SmConfig, Transition, wkc_increment)

SM_LENGTH = declare("ENI101", "error", "a SyncManager's length is not its PDOs' size", """
    The length a slave's InitCmds write into a process-data SyncManager (register
    0x0802 + 8·n) must be the size of the PDOs the ENI assigns to it (ProcessData/SmN/Pdo,
    the sum of their entries' BitLen, rounded up to bytes).  A slave checks the length
    against its own PDO configuration before SAFEOP and refuses the transition (AL status
    code 0x001D/0x001E, invalid output/input configuration); a longer SyncManager moves the
    data of every later variable.  InitCmds that set a slave's SyncManagers but never
    enable one that has PDOs leave its data unexchanged (a partial ENI without register
    InitCmds is completed by the standard set-up and not judged here).""")
FMMU_COVER = declare("ENI102", "error", "a process-data SyncManager no FMMU maps", """
    Each byte of a process-data SyncManager must be mapped into the logical process image
    by an FMMU of its direction (write FMMU for Outputs, read FMMU for Inputs; registers
    0x0600 + 16·n): bytes no FMMU covers are never exchanged, so outputs stay at zero
    and inputs are never read, and the slave's watchdog expires on an output SyncManager
    that is never written.""")
OVERLAP = declare("ENI103", "error", "two slaves' process data overlap", """
    Two slaves' ProcessData/Send (outputs) or Recv (inputs) bit ranges, or two slaves'
    read FMMUs, cover the same bits of the process image: both slaves write the same input
    bits in the frame (the last one wins) or a variable of one slave is another's.""")
WKC = declare("ENI104", "error", "an expected working counter the FMMUs do not give", """
    A logical cyclic command's Cnt must be what the slaves' FMMUs make of it: each slave
    with a read FMMU in the command's logical range adds 1 (LRD, LRW), each with a write
    FMMU adds 1 for LWR and 2 for LRW (ETG.1000.4, working counter).  A master that
    expects another count takes every cycle as failed, or misses a slave that dropped
    out.""")
UNSUPPORTED = declare("ENI003", "warning", "a part of the ENI apply does not carry out", """
    The ENI asks the master for something ecatcfg does not implement (eni/contents.py
    lists it: FoE requests other than reads, SoE requests other than writes, encrypted FMMU
    settings, ...).
    ``apply`` refuses such a file unless told to skip the part; ``check`` names it and
    cannot check it.  Where the part is a slave's FMMU settings, ENI102 and ENI104 are not
    checked for that slave's process data (its FMMUs are unknown).""")
MAILBOX = declare("ENI105", "error", "a mailbox area is not what SM0/SM1 are set to", """
    Mailbox/Send and Mailbox/Recv (start and length) are where the master writes and reads
    mailbox messages; the slave's InitCmds set SyncManager 0 and 1 (registers 0x0800 and
    0x0808).  When they differ, the master writes requests where no SyncManager takes
    them, or reads replies of a wrong length.""")


PROTOCOL = declare("ENI106", "error", "mailbox InitCmds of a protocol the slave's mailbox "
                   "lacks", """
    The slave's Mailbox lists the protocols it speaks (Mailbox/Protocol), and the protocol
    of some of its enabled mailbox InitCmds (Mailbox/CoE, SoE, EoE or FoE/InitCmds) is not
    among them, yet the master is asked to send them (ETG.1000.6).  A slave answers a
    mailbox message of a protocol it does not have with the mailbox error "unsupported
    protocol", and the transition fails.  A file that lists no protocol at all is not
    judged.""")
SOE_TRANSITION = declare("ENI107", "warning", "an SoE InitCmd in a transition the schema "
                         "does not allow", """
    ETG.2100 allows an SoE InitCmd in PS, SO, SP, OP and OS only: the transitions in which
    the mailbox works and the drive is past INIT->PREOP.  apply sends one of IP once the
    slave is in PREOP (and refuses one of II, IB or BI, where no mailbox answers), but the
    file does not validate against the schema, and other masters may refuse it.  An ESI
    SoE InitCmd of IP belongs to PS (ecatcfg's compiler writes it there, first).""")
MAILBOX_STATE = declare("ENI122", "error", "a mailbox-state bit MailboxStates does not hold",
                        """
    A slave's Mailbox/Recv/StatusBitAddr is the bit of Master/MailboxStates (StartAddr,
    Count slaves; ETG.2100) where an FMMU of the slave copies its mailbox-full flag (SM1
    status, 0x080D), so that one LRD tells the master which mailboxes hold an answer. The
    bit must lie in the area (0 to Count - 1), belong to this slave alone, and be where an
    FMMU the slave's INIT->PREOP InitCmds write maps SM1's status (one bit, read). Else the
    master reads another slave's flag, or one nothing sets, and waits for an answer that
    is there, or reads an empty mailbox: apply then reads this slave's SM1 status itself
    (eni/mailbox_states.py), and other masters take the bit as it is.""")


def check(ctx: CheckContext) -> None:
    for item in ctx.plan.unsupported:
        if item.element == COPY_ELEMENT or is_unmapped_fmmu(item.what):
            continue           # their own rules: ENI111 (copies.py), ENI108 (fmmus.py)
        slave = next((s for s in ctx.plan.slaves if s.name == item.slave), None)
        ctx.add(UNSUPPORTED, item.line, item.describe(), slave)
    for slave in ctx.plan.slaves:
        _sm_lengths(ctx, slave)
        _mailbox(ctx, slave)
        _protocols(ctx, slave)
        _soe(ctx, slave)
    _overlaps(ctx)
    _frames(ctx)
    for problem in state_bits(ctx.plan)[1]:
        slave = problem.slave
        ctx.add(MAILBOX_STATE, ctx.lines.child(slave, "Mailbox/Recv/StatusBitAddr"),
                problem.message, slave)


def is_unmapped_fmmu(what: str) -> bool:
    """An unsupported item that is an FMMU setting outside every cyclic command: a fault
    of the file (ENI108, eni/check/fmmus.py), not a part ecatcfg cannot do (ENI003)."""
    return UNMAPPED_FMMU in what and ENCRYPTED_FMMU not in what


def sm_records(slave: SlavePlan) -> dict[int, list[tuple[SmConfig, frozenset[Transition]]]]:
    """SyncManager ``n``'s enabled images with a length, as the slave's InitCmds write
    them, and the transitions of each write."""
    out: dict[int, list[tuple[SmConfig, frozenset[Transition]]]] = {}
    for n, writes in register_writes(slave, Reg.SM0, SM_SIZE, 16).items():
        for data, transitions in writes:
            sm = SmConfig.from_bytes(data)
            if sm.enable and sm.length:
                out.setdefault(n, []).append((sm, transitions))
    return out


def fmmu_records(slave: SlavePlan) -> list[tuple[FmmuConfig, frozenset[Transition]]]:
    """The active FMMU images with a length the slave's InitCmds write."""
    out = []
    for writes in register_writes(slave, Reg.FMMU0, FMMU_SIZE, 16).values():
        for data, transitions in writes:
            fmmu = FmmuConfig.from_bytes(data)
            if fmmu.active and fmmu.length and fmmu.type != FmmuType.UNUSED:
                out.append((fmmu, transitions))
    return out


def sm_pdos(slave: SlavePlan, sm: SmSettings) -> list[PdoDesc]:
    """The PDOs the ENI assigns to a SyncManager: its ``Pdo`` list, else the PDOs whose
    ``Sm`` attribute names it."""
    pd = slave.process_data
    if pd is None:
        return []
    direction = "rx" if sm.type == "Outputs" else "tx"
    by_index = {p.index: p for p in pd.pdos if p.direction == direction}
    if sm.pdos:
        return [by_index[i] for i in sm.pdos if i in by_index]
    return [p for p in pd.pdos if p.direction == direction and p.sm == sm.number]


def _sm_lengths(ctx: CheckContext, slave: SlavePlan) -> None:
    pd = slave.process_data
    if pd is None:
        return
    written = sm_records(slave)
    fmmus = fmmu_records(slave)
    for sm in pd.sms:
        if sm.type not in ("Outputs", "Inputs"):
            continue
        pdos = sm_pdos(slave, sm)
        bits = sum(e.bit_len for p in pdos for e in p.entries)
        want = (bits + 7) // 8
        line = ctx.lines.child(slave, f"ProcessData/Sm{sm.number}")
        images = written.get(sm.number, [])
        if want and not images and written:
            # InitCmds that set SyncManagers but never this one (a partial ENI without
            # register InitCmds is completed by the standard set-up: eni/derive.py).
            ctx.add(SM_LENGTH, line, f"SM{sm.number} ({sm.type}) has PDOs of {want} byte(s) "
                    "but no InitCmd enables it with a length", slave)
        for image, _ in images:
            if image.length != want:
                listed = ", ".join(f"0x{p.index:04X}" for p in pdos) or "none"
                ctx.add(SM_LENGTH, line, f"SM{sm.number} ({sm.type}) is set to "
                        f"{image.length} byte(s), its PDOs ({listed}) take {want}", slave)
                break
        if images and want and not _fmmus_unknown(ctx, slave):
            _cover(ctx, slave, sm, images[-1][0], fmmus, line)


def _cover(ctx: CheckContext, slave: SlavePlan, sm: SmSettings, image: SmConfig,
           fmmus: list[tuple[FmmuConfig, frozenset[Transition]]], line: int | None) -> None:
    kinds = ((FmmuType.WRITE, FmmuType.READ_WRITE) if sm.type == "Outputs"
             else (FmmuType.READ, FmmuType.READ_WRITE))
    covered: set[int] = set()
    for fmmu, _ in fmmus:
        if fmmu.type in kinds:
            end_bit = fmmu.physical_start_bit + fmmu.bit_length
            covered.update(range(fmmu.physical_start, fmmu.physical_start + (end_bit + 7) // 8))
    missing = [a for a in range(image.start, image.start + image.length) if a not in covered]
    if missing:
        ctx.add(FMMU_COVER, line, f"SM{sm.number} ({sm.type}, 0x{image.start:04X}, "
                f"{image.length} byte(s)): {len(missing)} byte(s) from 0x{missing[0]:04X} "
                f"mapped by no {'write' if sm.type == 'Outputs' else 'read'} FMMU", slave)


def _mailbox(ctx: CheckContext, slave: SlavePlan) -> None:
    mb = slave.mailbox
    if mb is None:
        return
    written = sm_records(slave)
    for n, area, name in ((0, mb.send, "Send"), (1, mb.recv, "Recv")):
        # The standard mailbox is set in INIT -> PREOP; the bootstrap one (INIT -> BOOT)
        # has its own area (Mailbox/BootStrap).
        images = [sm for sm, tr in written.get(n, []) if Transition.IP in tr]
        line = ctx.lines.child(slave, f"Mailbox/{name}")
        for sm in images:
            if (sm.start, sm.length) != (area.start, area.length):
                ctx.add(MAILBOX, line, f"Mailbox/{name} is 0x{area.start:04X}, "
                        f"{area.length} byte(s), SM{n} is set to 0x{sm.start:04X}, "
                        f"{sm.length} byte(s)", slave)
                break


def _protocols(ctx: CheckContext, slave: SlavePlan) -> None:
    mb = slave.mailbox
    if mb is None or not mb.protocols:
        return
    lists: list[tuple[str, Sequence[CoeInitCmd | SoeInitCmd | EoeInitCmd | FoeInitCmd]]] = [
        ("CoE", mb.coe_init_cmds), ("SoE", mb.soe_init_cmds), ("EoE", mb.eoe_init_cmds),
        ("FoE", mb.foe_init_cmds)]
    for protocol, cmds in lists:
        enabled = [c for c in cmds if not c.disabled]
        if enabled and protocol not in mb.protocols:
            ctx.add(PROTOCOL, ctx.lines.child(slave, f"Mailbox/{protocol}"),
                    f"{len(enabled)} {protocol} InitCmd(s), but Mailbox/Protocol lists "
                    + ", ".join(mb.protocols), slave)


def _soe(ctx: CheckContext, slave: SlavePlan) -> None:
    mb = slave.mailbox
    cmds = [] if mb is None else mb.soe_init_cmds
    if mb is None or not cmds:
        return
    for n, cmd in enumerate(cmds):
        bad = [t.value for t in cmd.transitions if t not in ENI_TRANSITIONS]
        if bad:
            ctx.add(SOE_TRANSITION, ctx.lines.listed(slave, "Mailbox/SoE/InitCmds", n,
                                                     len(cmds)),
                    f"{soe_words(cmd)} in {', '.join(bad)} (the schema allows "
                    + ", ".join(t.value for t in ENI_TRANSITIONS) + ")", slave)


def _overlaps(ctx: CheckContext) -> None:
    for kind in ("send", "recv"):
        owners: list[tuple[BitRange, SlavePlan]] = []
        for slave in ctx.plan.slaves:
            pd = slave.process_data
            for r in (getattr(pd, kind) if pd is not None else []):
                if r.bit_length:
                    owners.append((r, slave))
        owners.sort(key=lambda o: o[0].bit_start)
        for (a, sa), (b, sb) in zip(owners, owners[1:]):
            if sa is not sb and b.bit_start < a.bit_start + a.bit_length:
                what = "Send (outputs)" if kind == "send" else "Recv (inputs)"
                ctx.add(OVERLAP, ctx.lines.child(sb, f"ProcessData/{kind.title()}"),
                        f"ProcessData/{what} bits {b.bit_start}..{b.bit_start + b.bit_length - 1}"
                        f" overlap slave {sa.name!r}'s {a.bit_start}.."
                        f"{a.bit_start + a.bit_length - 1}", sb)
    reads: list[tuple[int, int, SlavePlan, int]] = []
    for slave in ctx.plan.slaves:
        for _, record, _, position in register_writes_at(slave, Reg.FMMU0, FMMU_SIZE, 16):
            fmmu = FmmuConfig.from_bytes(record)
            if fmmu.active and fmmu.length and fmmu.type in (FmmuType.READ,
                                                             FmmuType.READ_WRITE):
                start = fmmu.logical_start * 8 + fmmu.logical_start_bit
                reads.append((start, start + fmmu.bit_length, slave, position))
    reads.sort(key=lambda r: r[0])
    for (_, end0, first, _), (start1, _, second, position) in zip(reads, reads[1:]):
        if first is not second and start1 < end0:
            ctx.add(OVERLAP, ctx.lines.listed(second, "InitCmds", position,
                                              len(second.init_cmds)),
                    f"a read FMMU maps logical 0x{start1 // 8:08X}.{start1 % 8}, which slave "
                    f"{first.name!r}'s read FMMU maps too", second)


_RANK = {AlState.INIT: 0, AlState.PREOP: 1, AlState.SAFEOP: 2, AlState.OP: 3}
_STATE_NAMES = {"INIT": AlState.INIT, "PREOP": AlState.PREOP, "SAFEOP": AlState.SAFEOP,
                "OP": AlState.OP}


def _frames(ctx: CheckContext) -> None:
    fmmus = {id(s): fmmu_records(s) for s in ctx.plan.slaves}
    for ci, cyclic in enumerate(ctx.plan.cyclic):
        for fi, frame in enumerate(cyclic.frames):
            for k, cmd in enumerate(frame.cmds):
                if cmd.cmd not in LOGICAL_CMDS or cmd.addr is None or cmd.cnt is None \
                        or any(_fmmus_unknown(ctx, s) for s in ctx.plan.slaves):
                    continue
                states = [_STATE_NAMES[s] for s in cmd.states if s in _STATE_NAMES]
                top = max((_RANK[s] for s in states), default=3)
                want = 0
                for slave in ctx.plan.slaves:
                    read = written = False
                    for fmmu, transitions in fmmus[id(slave)]:
                        if not _configured_by(transitions, top):
                            continue
                        lo, hi = fmmu.logical_start, fmmu.logical_start + fmmu.length
                        if lo < cmd.addr + cmd.length and cmd.addr < hi:
                            read |= fmmu.type in (FmmuType.READ, FmmuType.READ_WRITE)
                            written |= fmmu.type in (FmmuType.WRITE, FmmuType.READ_WRITE)
                    want += wkc_increment(cmd.cmd, read and cmd.cmd != Cmd.LWR,
                                          written and cmd.cmd != Cmd.LRD)
                if want != cmd.cnt:
                    ctx.add(WKC, ctx.lines.cyclic_cmd(ci, fi, k),
                            f"cyclic {Cmd(cmd.cmd).name} 0x{cmd.addr:08X} ({cmd.length} "
                            f"byte(s)) expects working counter {cmd.cnt}; the slaves' FMMUs "
                            f"in that range give {want}")


def _fmmus_unknown(ctx: CheckContext, slave: SlavePlan) -> bool:
    """Whether FMMU settings of the slave were left out of the plan as unsupported (the
    reader records them: encrypted data, eni/contents.py)."""
    return any(u.slave == slave.name and u.what.startswith("FMMU")
               for u in ctx.plan.unsupported)


def _configured_by(transitions: frozenset[Transition], top: int) -> bool:
    """Whether an FMMU written in these transitions is set up on the way to the state of
    rank ``top`` (written going up, into a state no higher)."""
    return any(_RANK.get(t.source, 9) < _RANK.get(t.target, 9) <= top for t in transitions)
