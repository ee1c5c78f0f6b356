"""What the IgH EtherCAT master must be told of each slave of an ENI, in the terms of its
application interface (``ecrt.h``, IgH master 1.6), which the igh-c export writes as C.

IgH configures a slave by itself from a slave configuration (``ecrt_master_slave_config``
by alias and position, vendor and product code): it sets the station address, reads the
SII, sets up the mailbox, then in PREOP, before it requests SAFEOP, it downloads the
configured SDOs (``ecrt_slave_config_sdo*``, CompleteAccess with
``ecrt_slave_config_complete_sdo``) and SoE IDNs of PREOP (``ecrt_slave_config_idn``), writes
the PDO assignment and mapping it was given (``ecrt_slave_config_pdos``: its ``ecrt.h``
says the assignment 0x1C10-0x1C2F and mapping 0x1600-0x17FF/0x1A00-0x1BFF objects are not
to be given as SDOs), the watchdogs (``ecrt_slave_config_watchdog``: registers 0x0400 and
0x0420), the process data SyncManagers and FMMUs and the DC set-up
(``ecrt_slave_config_dc``: AssignActivate to 0x0980, SYNC0/1 cycles, SYNC0 shift); SoE
IDNs of SAFEOP are written in SAFEOP before OP.

So of an ENI each slave's configuration becomes:

- its PDO assignment and mapping from ``ProcessData`` (``RxPdo``/``TxPdo`` assigned to an
  ``Sm``), checked against the ENI's CoE downloads of the assignment and mapping objects,
  which IgH then makes itself (a download that leaves another assignment or mapping than
  ``ProcessData`` says is refused);
- the other CoE downloads of INIT->PREOP and PREOP->SAFEOP, in ENI order (those of IP
  first), CompleteAccess where the ENI says (from subindex 0: IgH's complete SDO starts
  there);
- the SoE writes of PREOP->SAFEOP (written in PREOP) and SAFEOP->OP (in SAFEOP);
- the DC AssignActivate word (the ENI's PREOP->SAFEOP write of 0x0980) with ``Slave/DC``'s
  cycles and shift, and the reference clock;
- the watchdog divider and SM watchdog time of the ENI's writes of 0x0400 and 0x0420;
- the EoE set IP parameter requests as IgH's EoE configuration (MAC, IP address, subnet
  mask, gateway, DNS server and name: ``ecrt_slave_config_eoe_*``), which IgH sends in
  PREOP.

Anything else that would change what the master does is an :class:`ExportError` naming the
file, line and slave (a command in a transition IgH has no place for, a register write IgH
cannot make, FoE commands, EoE to another port than 0, slave-to-slave copies, parts of the
ENI ``apply`` does not implement).  Two register writes that leave an ESC register at its
reset value, which IgH never changes, are kept as notes in the output (DC latch control
0x09A8 = 0, PDI watchdog 0x0410 = 1000): any other value is refused.
"""

from __future__ import annotations

from pathlib import Path

from ecatcfg.eni.export.steps import ExportError, SdoStep, refuse_unexported, soem_register
from ecatcfg.eni.plan import (CoeInitCmd, EoeInitCmd, FoeInitCmd, InitCmd, NetworkPlan,
                              PdoDesc, SlavePlan, SoeInitCmd, Variable)
from ecatcfg.eni.source import init_cmd_line
from ecatcfg.eni.words import (coe_words, eoe_words, foe_words, init_cmd_words,
                               soe_words)
from ecatcfg.eoe import IpParameters
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (REGISTER_READS, REGISTER_WRITES, RX_PDO_MAPPING,
                         SM_PDO_ASSIGN, SM_PDO_ASSIGN_RANGE, SM_WATCHDOG_ENABLE,
                         TX_PDO_MAPPING, WATCHDOG_TIME_DEFAULT, Reg, Transition,
                         array_downloads)
from ecatcfg.esi.idn import VALUE_ELEMENT, WRITE_REQUEST
from ecatcfg.record import field, record

# The transitions whose commands IgH makes in PREOP before it requests SAFEOP: those of
# INIT->PREOP need the mailbox, which works from PREOP on, as IgH's configuration has it.
PREOP_TRANSITIONS = frozenset({Transition.IP, Transition.PS})

# ESC registers IgH leaves at their reset value (ESC datasheet Section II): an ENI write of
# that value changes nothing IgH would have changed; any other value is refused.
RESET_VALUES: dict[int, tuple[int, str]] = {
    Reg.DC_LATCH0_CONTROL: (0x0000, "DC latch control"),
    Reg.WATCHDOG_PDI: (WATCHDOG_TIME_DEFAULT, "PDI watchdog time"),
}


@record
class PdoEntry:
    index: int                                # 0: a gap
    subindex: int
    bit_len: int
    name: str
    data_type: str | None = None


@record
class Pdo:
    index: int
    name: str
    entries: list[PdoEntry]


@record
class Sync:
    index: int                                # the SyncManager
    output: bool                              # EC_DIR_OUTPUT (RxPDOs) or EC_DIR_INPUT
    pdos: list[Pdo]
    watchdog: bool | None                     # the control byte's bit 6; None: SII default


@record
class Idn:
    drive_no: int
    idn: int
    safeop: bool                              # written in SAFEOP (SO), else in PREOP (IP/PS)
    data: bytes
    words: str


@record
class Eoe:
    """The EoE IP parameters IgH sets in PREOP (``ecrt_slave_config_eoe_*``): the ENI's
    set IP parameter requests of the slave, each field the last one given."""

    params: IpParameters
    words: str


@record
class Dc:
    assign_activate: int
    sync0_cycle: int                          # ns
    sync0_shift: int
    sync1_cycle: int


@record
class Watchdog:
    divider: int                              # 0x0400
    intervals: int                            # 0x0420


@record
class Registration:
    """An ENI variable that is one PDO entry: where IgH finds it (the SM, the PDO's and the
    entry's places, for the entries whose index and subindex are not unique)."""

    name: str
    position: int
    vendor_id: int
    product_code: int
    index: int                                # the (first) PDO entry
    subindex: int
    bit_len: int                              # the variable's: one entry's or more
    data_type: str | None
    output: bool
    sync: int
    pdo_pos: int
    entry_pos: int
    unique: bool                              # (index, subindex) once in the slave's PDOs
    lead: int = 0                             # bits from the variable's start to the entry


@record
class IghSlave:
    position: int
    name: str
    vendor_id: int
    product_code: int
    revision: int
    syncs: list[Sync] = field(default_factory=list)
    sdos: list[SdoStep] = field(default_factory=list)
    idns: list[Idn] = field(default_factory=list)
    dc: Dc | None = None
    reference_clock: bool = False
    watchdog: Watchdog | None = None
    notes: list[str] = field(default_factory=list)    # ENI commands IgH makes itself
    eoe: Eoe | None = None


@record
class IghConfig:
    slaves: list[IghSlave]
    registrations: list[Registration]
    other_variables: list[str]                # no slave's PDO data: the master's own
    cycle_ns: int


def _pdo_object(index: int) -> bool:
    return index in SM_PDO_ASSIGN_RANGE or index in RX_PDO_MAPPING or \
        index in TX_PDO_MAPPING


class _Slave:
    """The refusal context of one slave."""

    def __init__(self, file: str, plan: NetworkPlan, position: int) -> None:
        self.file, self.plan, self.position = file, plan, position
        self.slave = plan.slaves[position]

    def refuse(self, cmd: InitCmd | CoeInitCmd | SoeInitCmd | EoeInitCmd | FoeInitCmd | None,
               what: str) -> ExportError:
        line = init_cmd_line(self.file, self.plan, cmd) if cmd is not None else None
        return slave_error(self.file, self.position, self.slave.name, what, line)

    def preop_only(self, cmd: InitCmd | CoeInitCmd | SoeInitCmd | EoeInitCmd, words: str,
                   allowed: frozenset[Transition] = PREOP_TRANSITIONS) -> None:
        """Refuse a command of a transition IgH has no place for, also when it runs in an
        allowed one too: made once, its repeat (on the way down, say) would be lost."""
        other = [t.value for t in cmd.transitions if t not in allowed]
        if other:
            also = " (and SoE IDNs in SAFEOP)" if allowed != PREOP_TRANSITIONS else ""
            raise self.refuse(cmd, f"{words} in {'/'.join(t.value for t in cmd.transitions)}:"
                                   f" IgH makes start-up commands in PREOP before SAFEOP "
                                   f"only{also}")


def slave_error(file: str, position: int, name: str, what: str,
            line: int | None = None) -> ExportError:
    """An error naming the slave and the line of its command, else of its element."""
    return ExportError(f"slave {position} ({name!r}): {what}", file,
                       line if line is not None else slave_line(file, position))


def slave_line(file: str, position: int) -> int | None:
    """The line of the ``position``-th ``Config/Slave`` element of ``file`` that has an ESC
    (a ``PhysAddr`` or ``AutoIncAddr``: the reader's passive slaves have neither)."""
    from ecatcfg.esi import xmlsafe
    from ecatcfg.fileio import read_input
    try:
        root = xmlsafe.parse_bytes(read_input(file), file).getroot()
    except (OSError, EcatcfgError):
        return None
    slaves = [s for s in root.iterfind("Config/Slave")
              if s.find("Info/PhysAddr") is not None or s.find("Info/AutoIncAddr") is not None]
    line: int | None = slaves[position].sourceline if position < len(slaves) else None
    return line


def _syncs(ctx: _Slave) -> list[Sync]:
    """``ProcessData``'s SyncManagers with their assigned PDOs, in SM order (each SM's PDOs
    in the order ``SmN/Pdo`` lists them, else in file order)."""
    pd = ctx.slave.process_data
    if pd is None:
        return []
    settings = {sm.number: sm for sm in pd.sms}
    numbers = sorted(set(settings) | {p.sm for p in pd.pdos if p.sm is not None})
    out = []
    for n in numbers:
        assigned = [p for p in pd.pdos if p.sm == n]
        sm = settings.get(n)
        if sm is not None and sm.pdos:
            by_index = {p.index: p for p in assigned}
            missing = [i for i in sm.pdos if i not in by_index]
            if missing or len(sm.pdos) != len(assigned):
                raise ctx.refuse(None, f"ProcessData/Sm{n} assigns PDOs "
                                       f"{', '.join(f'0x{i:04X}' for i in sm.pdos)} but the "
                                       f"RxPdo/TxPdo elements with Sm={n} are "
                                       f"{', '.join(f'0x{p.index:04X}' for p in assigned)}")
            assigned = [by_index[i] for i in sm.pdos]
        if sm is not None:
            output = sm.type == "Outputs"
        elif assigned:
            output = assigned[0].direction == "rx"
        else:
            continue
        if sm is not None and sm.type not in ("Outputs", "Inputs"):
            continue                          # a mailbox SM listed: IgH sets it from SII
        wrong = [p for p in assigned if (p.direction == "rx") != output]
        if wrong:
            raise ctx.refuse(None, f"PDO 0x{wrong[0].index:04X} ({wrong[0].direction}) is "
                                   f"assigned to Sm{n} of the other direction")
        empty = [p for p in assigned if not p.entries]
        if empty:
            # ecrt.h: a PDO of no entries stands for the slave's default mapping.
            raise ctx.refuse(None, f"PDO 0x{empty[0].index:04X} assigned to Sm{n} has no "
                                   f"entries, which IgH's PDO table reads as 'the default "
                                   f"mapping'")
        out.append(Sync(n, output, [_pdo(p) for p in assigned],
                        None if sm is None else bool(sm.control_byte & SM_WATCHDOG_ENABLE)))
    return out


def _pdo(p: PdoDesc) -> Pdo:
    return Pdo(p.index, p.name, [PdoEntry(e.index, e.subindex, e.bit_len, e.name,
                                          e.data_type) for e in p.entries])


def _check_pdo_downloads(ctx: _Slave, syncs: list[Sync]) -> tuple[set[int], list[str]]:
    """The ENI's downloads of the PDO assignment objects and of the mapping of the assigned
    PDOs must leave what ``ProcessData`` says, which ``ecrt_slave_config_pdos`` gives IgH:
    returns (those objects, notes).  A download that leaves anything else is refused by
    its line.  The mapping of a PDO no SM is assigned is no part of IgH's PDO
    configuration: it stays a start-up SDO."""
    mailbox = ctx.slave.mailbox
    by_sm = {s.index: s for s in syncs}
    pdos = {p.index: p for s in syncs for p in s.pdos}
    writes: dict[int, list[CoeInitCmd]] = {}
    for cmd in mailbox.coe_init_cmds if mailbox else []:
        if not cmd.disabled and cmd.ccs == 1 and (
                cmd.index in SM_PDO_ASSIGN_RANGE or
                (_pdo_object(cmd.index) and cmd.index in pdos)):
            ctx.preop_only(cmd, coe_words(cmd))
            writes.setdefault(cmd.index, []).append(cmd)
    notes = []
    for index, cmds in sorted(writes.items()):
        size = 2 if index in SM_PDO_ASSIGN_RANGE else 4
        count, entries = array_downloads(
            [(c.subindex, c.data, c.complete_access) for c in cmds], size)
        if count is None:
            raise ctx.refuse(cmds[-1], f"{coe_words(cmds[-1])}: 0x{index:04X} is written "
                                       f"without its subindex 0 (the count)")
        held = [entries.get(k, 0) for k in range(1, count + 1)]
        if index in SM_PDO_ASSIGN_RANGE:
            sync = by_sm.get(index - SM_PDO_ASSIGN)
            want = [p.index for p in sync.pdos] if sync else []
            what = "assignment"
        else:
            want = [e.index << 16 | e.subindex << 8 | e.bit_len for e in pdos[index].entries]
            what = "mapping"
        if held != want:
            raise ctx.refuse(cmds[-1], f"the PDO {what} 0x{index:04X} its CoE downloads "
                                       f"leave ({', '.join(f'0x{v:X}' for v in held)}) is "
                                       f"not ProcessData's "
                                       f"({', '.join(f'0x{v:X}' for v in want)}): IgH "
                                       f"writes the assignment and mapping from one table")
        notes.append(f"0x{index:04X} ({what}, {len(cmds)} CoE download"
                     f"{'s' if len(cmds) != 1 else ''}): by ecrt_slave_config_pdos")
    return set(writes), notes


def _sdos(ctx: _Slave, by_pdos: set[int]) -> list[SdoStep]:
    mailbox = ctx.slave.mailbox
    if mailbox is None:
        return []
    for foe in mailbox.foe_init_cmds:
        if not foe.disabled:
            raise ctx.refuse(foe, f"FoE InitCmd ({foe.comment or foe_words(foe)}): IgH has "
                                  f"no start-up FoE")
    steps = []
    for ip_first in (True, False):            # IP's downloads before PS's (ETG.2100 order)
        for cmd in mailbox.coe_init_cmds:
            if cmd.disabled or (Transition.IP in cmd.transitions) != ip_first:
                continue
            words = coe_words(cmd)
            ctx.preop_only(cmd, words)
            if cmd.ccs != 1:
                raise ctx.refuse(cmd, f"{words}: IgH's start-up SDOs are downloads")
            if cmd.index in by_pdos:
                continue                      # _check_pdo_downloads: ecrt_slave_config_pdos
            if cmd.complete_access and cmd.subindex != 0:
                raise ctx.refuse(cmd, f"{words}: CompleteAccess from subindex "
                                      f"{cmd.subindex}: IgH's complete SDO download "
                                      f"starts at subindex 0")
            if not cmd.data:
                raise ctx.refuse(cmd, f"{words}: a download without data")
            steps.append(SdoStep(cmd.index, cmd.subindex, cmd.data, cmd.complete_access,
                                 words))
    return steps


def _eoe(ctx: _Slave) -> Eoe | None:
    """The slave's EoE set IP parameter requests of INIT->PREOP and PREOP->SAFEOP as the
    parameters IgH sends in PREOP; later requests set the fields they name."""
    params: IpParameters | None = None
    words = []
    for cmd in ctx.slave.mailbox.eoe_init_cmds if ctx.slave.mailbox else []:
        if cmd.disabled:
            continue
        text = eoe_words(cmd)
        ctx.preop_only(cmd, text)
        request = cmd.request
        if request.port:
            raise ctx.refuse(cmd, f"{text}: to EoE port {request.port}: IgH's EoE "
                                  f"configuration has no port")
        params = request.params if params is None else params.updated(request.params)
        words.append(text)
    return None if params is None else Eoe(params, "; ".join(words))


def _idns(ctx: _Slave) -> list[Idn]:
    """The SoE writes in ENI order, each in the state IgH writes it: PREOP (for IP and PS)
    or SAFEOP (for SO); one of both gets both."""
    out = []
    allowed = PREOP_TRANSITIONS | {Transition.SO}
    for cmd in ctx.slave.mailbox.soe_init_cmds if ctx.slave.mailbox else []:
        if cmd.disabled:
            continue
        words = soe_words(cmd)
        ctx.preop_only(cmd, words, allowed)
        if cmd.op_code != WRITE_REQUEST or cmd.elements != VALUE_ELEMENT:
            raise ctx.refuse(cmd, f"{words}: IgH's IDN configuration writes an IDN's value "
                                  f"(element 0x40) only")
        states = sorted({t == Transition.SO for t in cmd.transitions})
        out += [Idn(cmd.drive_no, cmd.idn, safeop, cmd.data, words) for safeop in states]
    return out


def _registers(ctx: _Slave) -> tuple[int, Watchdog | None, list[str]]:
    """(the AssignActivate word, the watchdogs, notes) from the slave's register commands;
    refuses what IgH cannot write."""
    assign = 0
    divider = intervals = 0
    notes = []
    for cmd in ctx.slave.init_cmds:
        if cmd.ado is None:
            continue                          # logical or broadcast: the master's own
        write = cmd.cmd in REGISTER_WRITES
        words = init_cmd_words(cmd)
        if write and Transition.PS in cmd.transitions and \
                cmd.ado <= Reg.DC_CYCLIC_UNIT_CONTROL + 1 and \
                cmd.ado + len(cmd.payload) > Reg.DC_CYCLIC_UNIT_CONTROL:
            # The AssignActivate word is 0x0980 (cyclic unit control) and 0x0981 (SYNC
            # activation), little-endian, as IgH writes it; the ENI's last PS write of
            # either byte holds it (its IP write of 0 and the way down are IgH's own).
            for ado in (Reg.DC_CYCLIC_UNIT_CONTROL, Reg.DC_CYCLIC_UNIT_CONTROL + 1):
                if cmd.ado <= ado < cmd.ado + len(cmd.payload):
                    shift = 8 * (ado - Reg.DC_CYCLIC_UNIT_CONTROL)
                    assign = assign & ~(0xFF << shift) | cmd.payload[ado - cmd.ado] << shift
            continue
        if soem_register(cmd.ado, cmd.length):
            continue                          # what IgH configures itself (as SOEM does)
        if not write and (cmd.cmd not in REGISTER_READS or cmd.validate is None):
            continue                          # a read nobody checks changes nothing
        if not write:
            raise ctx.refuse(cmd, f"{words}: IgH has no start-up register check")
        ctx.preop_only(cmd, words)
        for offset in range(0, len(cmd.payload) - 1, 2):
            ado, value = cmd.ado + offset, int.from_bytes(cmd.payload[offset:offset + 2],
                                                          "little")
            if ado == Reg.WATCHDOG_DIVIDER and value:
                divider = value
            elif ado == Reg.WATCHDOG_SM and value:
                intervals = value
            elif ado in RESET_VALUES and value == RESET_VALUES[ado][0]:
                notes.append(f"{words}: the {RESET_VALUES[ado][1]}'s reset value, which "
                             f"IgH does not change")
            else:
                raise ctx.refuse(cmd, f"{words}: IgH writes no register 0x{ado:04X} = "
                                      f"0x{value:04X} at start-up (of the watchdogs only "
                                      f"a non-zero divider 0x0400 and SM time 0x0420)")
        if len(cmd.payload) % 2:
            raise ctx.refuse(cmd, f"{words}: IgH writes no such register at start-up")
    watchdog = Watchdog(divider, intervals) if divider or intervals else None
    return assign, watchdog, notes


def _dc(ctx: _Slave, assign: int) -> Dc | None:
    if not assign:
        return None
    dc = ctx.slave.dc
    if dc is None:
        raise ctx.refuse(None, f"DC activation 0x{assign:04X} without a Slave/DC element "
                               f"(its cycle time)")
    # ecrt.h: "The sync1_shift time is ignored": IgH writes sync1_cycle to 0x09A4, the
    # register ETG.2100 gives CycleTime1 for.
    return Dc(assign, dc.cycle_time0, dc.shift_time, dc.cycle_time1)


def _slave(file: str, plan: NetworkPlan, position: int) -> IghSlave:
    ctx = _Slave(file, plan, position)
    slave = ctx.slave
    if slave.hot_connect is not None:
        raise ctx.refuse(None, "a hot-connect group: IgH's slave configurations are by "
                               "alias and position, with no group identification")
    syncs = _syncs(ctx)
    by_pdos, notes = _check_pdo_downloads(ctx, syncs)
    sdos = _sdos(ctx, by_pdos)
    idns = _idns(ctx)
    assign, watchdog, register_notes = _registers(ctx)
    return IghSlave(position, slave.name, slave.vendor_id, slave.product_code,
                    slave.revision, syncs, sdos, idns, _dc(ctx, assign),
                    bool(slave.dc and slave.dc.reference_clock), watchdog,
                    notes + register_notes, _eoe(ctx))


def _registrations(file: str, plan: NetworkPlan, slaves: list[IghSlave]
                   ) -> tuple[list[Registration], list[str]]:
    """Each ENI variable as the PDO entry it is: its slave's ``Send``/``Recv`` range holds
    the slave's PDO entries, SM after SM, each PDO's entries in order (ETG.2100
    ``ProcessData``).  A variable outside every slave's range is the master's own (TwinCAT's
    frame and working-counter states); one inside that is not one entry is refused."""
    regs: list[Registration] = []
    others: list[str] = []
    for output, variables in ((True, plan.process_image.outputs),
                              (False, plan.process_image.inputs)):
        owners: list[tuple[IghSlave, SlavePlan, dict[int, tuple[PdoEntry, int, int, int]]]] = []
        for ig, sp in zip(slaves, plan.slaves):
            pd = sp.process_data
            ranges = (pd.send if output else pd.recv) if pd else []
            if not ranges:
                continue
            places: dict[int, tuple[PdoEntry, int, int, int]] = {}
            bit = 0
            for sync in ig.syncs:
                if sync.output != output:
                    continue
                for p, pdo in enumerate(sync.pdos):
                    for e, entry in enumerate(pdo.entries):
                        places[bit] = (entry, sync.index, p, e)
                        bit += entry.bit_len
            total = sum(r.bit_length for r in ranges)
            if bit != total:
                raise slave_error(file, ig.position, sp.name,
                              f"its {'outputs' if output else 'inputs'} are {total} bits "
                              f"(ProcessData/{'Send' if output else 'Recv'}) but its "
                              f"assigned PDOs map {bit}")
            owners.append((ig, sp, places))
        for v in sorted(variables, key=lambda v: v.bit_offs):
            found = _owner(v, owners, output)
            if found is None:
                others.append(v.name)
                continue
            ig, sp, local, places = found
            end = local + v.bit_size
            covered = sorted(b for b in places if local <= b < end)
            last = covered[-1] if covered else local
            first = next((b for b in covered if places[b][0].index), None)
            if local not in places or first is None or \
                    last + places[last][0].bit_len != end or \
                    len({places[b][1:3] for b in covered}) != 1:
                raise slave_error(file, ig.position, sp.name,
                              f"variable {v.name!r} (bit {local} of its "
                              f"{'outputs' if output else 'inputs'}, {v.bit_size} bit) is not "
                              f"a run of PDO entries of one PDO: IgH registers PDO entries")
            # A variable of several entries (TwinCAT's status words over bit entries and
            # gaps) is registered by its first entry that is not a gap, ``lead`` bits in.
            entry, sm, p, e = places[first]
            keys = [(x.index, x.subindex) for s in ig.syncs for q in s.pdos
                    for x in q.entries]
            regs.append(Registration(v.name, ig.position, ig.vendor_id, ig.product_code,
                                     entry.index, entry.subindex, v.bit_size, v.data_type,
                                     output, sm, p, e,
                                     keys.count((entry.index, entry.subindex)) == 1,
                                     first - local))
    return regs, others


def _owner(v: Variable, owners: list[tuple[IghSlave, SlavePlan,
                                           dict[int, tuple[PdoEntry, int, int, int]]]],
           output: bool) -> tuple[IghSlave, SlavePlan, int,
                                  dict[int, tuple[PdoEntry, int, int, int]]] | None:
    """The slave whose range holds ``v``'s first bit and ``v``'s bit within that slave's
    data (its ranges follow each other, each from a whole byte)."""
    for ig, sp, places in owners:
        assert sp.process_data is not None
        base = 0
        for r in sp.process_data.send if output else sp.process_data.recv:
            if r.bit_start <= v.bit_offs < r.bit_start + r.bit_length:
                return ig, sp, base + v.bit_offs - r.bit_start, places
            base += r.bit_length
    return None


def igh_config(plan: NetworkPlan, file: str | Path) -> IghConfig:
    """The IgH configuration of the plan read from ``file``; raises :class:`ExportError`
    for what IgH cannot be told."""
    name = str(file)
    # IgH's domains exchange process data with the slaves only: a copy from one slave's
    # inputs to another's outputs is the application's job.
    refuse_unexported(plan, name, "not exported for IgH", "IgH has no start-up register "
                      "writes")
    # IgH's position is the slave's place on the bus, which is its place among the ENI's
    # slaves (ETG.2100 lists them in bus order; some writers' AutoIncAddr say otherwise).
    slaves = [_slave(name, plan, k) for k in range(len(plan.slaves))]
    regs, others = _registrations(name, plan, slaves)
    cycle_us = next((c.cycle_time for c in plan.cyclic if c.cycle_time), None)
    dc_cycle = next((s.dc.sync0_cycle for s in slaves if s.dc), None)
    cycle_ns = cycle_us * 1000 if cycle_us else dc_cycle or 1_000_000
    return IghConfig(slaves, regs, others, cycle_ns)
