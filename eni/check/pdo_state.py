"""The PDO assignment and mapping the slave holds after its CoE InitCmds, against the ENI's
own ``ProcessData`` and SyncManager lengths.  What the downloads leave is
:func:`ecatcfg.eni.pdo_held.pdo_objects_held`; a slave that holds another assignment or
mapping than the master lays its image out for either refuses SAFEOP (the SM length no
longer fits: AL status code 0x001D/0x001E) or sends other data in the bits the master
reads as a variable.  No ESI file is needed: the file is compared with itself."""

from __future__ import annotations

from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.network import sm_pdos, sm_records
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.pdo_held import HeldObject, pdo_objects_held
from ecatcfg.eni.plan import PdoDesc, SlavePlan, SmSettings
from ecatcfg.eni.words import mapping_entry
from ecatcfg.esc import SM_PDO_ASSIGN, Transition

ASSIGNMENT = declare("ENI205", "error", "the PDO assignment the CoE InitCmds leave is not "
                     "ProcessData's", """
    After the CoE InitCmds of INIT->PREOP and PREOP->SAFEOP, the slave's PDO assignment
    object (0x1C10 + SM number; ETG.1000.6, complete access included) holds other PDOs than
    the ENI's ProcessData/SmN assigns: the slave sizes the SyncManager from the PDOs it
    holds and refuses SAFEOP when the length the InitCmds write does not fit (AL status code
    0x001D for outputs, 0x001E for inputs); where the size happens to fit, the master reads
    and writes other PDOs than the slave exchanges.  A count one short, an entry naming a
    PDO the ENI does not describe (0x16FF) are the usual causes.  Named at the download that
    sets the differing value.""")
MAPPING = declare("ENI206", "error", "a PDO mapping the CoE InitCmds leave is not "
                  "ProcessData's", """
    After the CoE InitCmds up to SAFEOP, a mapping object of an assigned PDO (0x1600-0x17FF,
    0x1A00-0x1BFF) holds other entries (object, subindex, bit length) than the ENI's
    ProcessData describes for that PDO.  With another size, the slave refuses SAFEOP
    (0x001D/0x001E: the SM length no longer fits); with the same size, the bits the master
    reads as one variable are another object.  Named at the download that writes the
    differing entry.""")


def check(ctx: CheckContext) -> None:
    for slave in ctx.plan.slaves:
        if slave.mailbox is None or slave.process_data is None:
            continue
        held = pdo_objects_held(slave.mailbox.coe_init_cmds)
        if held:
            _check_slave(ctx, slave, held)


def _line(ctx: CheckContext, slave: SlavePlan, written: tuple[int, Transition] | None
          ) -> int | None:
    cmds = slave.mailbox.coe_init_cmds if slave.mailbox is not None else []
    if written is None:
        return ctx.lines.child(slave, "Mailbox/CoE/InitCmds")
    return ctx.lines.listed(slave, "Mailbox/CoE/InitCmds", written[0], len(cmds))


def _pdo_list(indices: list[int | None]) -> str:
    return ", ".join("unwritten" if i is None else f"0x{i:04X}" for i in indices) or "none"


def _entries(desc: PdoDesc) -> list[int]:
    """A described PDO's entries as mapping values (index << 16 | subindex << 8 | bits)."""
    return [(e.index << 16 | (e.subindex if e.index else 0) << 8 | e.bit_len) & 0xFFFFFFFF
            for e in desc.entries]


def _bits(index: int, held: dict[int, HeldObject],
          described: dict[int, PdoDesc]) -> int | None:
    """The bits of PDO ``index`` as the slave holds it: its mapping as downloaded, else as
    the ENI describes it; None when neither says."""
    obj = held.get(index)
    values = obj.values() if obj is not None else None
    if values is not None and None not in values:
        return sum((v or 0) & 0xFF for v in values)
    desc = described.get(index)
    return None if desc is None else sum(e.bit_len for e in desc.entries)


def _check_slave(ctx: CheckContext, slave: SlavePlan, held: dict[int, HeldObject]) -> None:
    pd = slave.process_data
    assert pd is not None
    described = {p.index: p for p in pd.pdos}
    lengths = {n: images[-1][0].length for n, images in sm_records(slave).items()}
    assigned: list[int] = []
    for sm in pd.sms:
        if sm.type not in ("Outputs", "Inputs"):
            continue
        listed = [p.index for p in sm_pdos(slave, sm)] or list(sm.pdos)
        obj = held.get(SM_PDO_ASSIGN + sm.number)
        values = obj.values() if obj is not None else None
        if obj is None or values is None:
            assigned += listed
            continue
        assigned += [v for v in values if v]
        if values == listed:
            continue
        _assignment_differs(ctx, slave, sm, obj, values, listed, held, described,
                            lengths.get(sm.number))
    for index in assigned:
        desc = described.get(index)
        obj = held.get(index)
        values = obj.values() if obj is not None else None
        if desc is None or obj is None or values is None:
            continue
        want = _entries(desc)
        if values == want:
            continue
        _mapping_differs(ctx, slave, obj, values, want, desc)


def _assignment_differs(ctx: CheckContext, slave: SlavePlan, sm: SmSettings,
                        obj: HeldObject, values: list[int | None], listed: list[int],
                        held: dict[int, HeldObject], described: dict[int, PdoDesc],
                        length: int | None) -> None:
    if len(values) != len(listed):
        where = obj.command(0)
    else:
        first = next(k for k, (a, b) in enumerate(zip(values, listed), 1) if a != b)
        where = obj.command(first) or obj.command(0)
    after = where[1].value if where is not None else "PS"
    message = (f"0x{obj.index:04X} holds {len(values)} PDO(s) after {after} "
               f"({_pdo_list(values)}); ProcessData/Sm{sm.number} assigns {len(listed)} "
               f"({_pdo_list(list(listed))})")
    sizes = [_bits(v, held, described) if v else 0 for v in values]
    if length is not None and None not in sizes:
        need = (sum(s or 0 for s in sizes) + 7) // 8
        if need != length:
            code = "0x001D" if sm.type == "Outputs" else "0x001E"
            message += (f": SM{sm.number} is set to {length} byte(s), the PDOs the slave "
                        f"holds take {need}; it refuses SAFEOP with AL status code {code}")
    else:
        unknown = [v for v, s in zip(values, sizes) if v and s is None]
        if unknown:
            message += (f"; the ENI describes no PDO {_pdo_list(list(unknown))} (no "
                        "RxPdo/TxPdo, no mapping download): the slave refuses SAFEOP "
                        "unless it has one")
    ctx.add(ASSIGNMENT, _line(ctx, slave, where), message, slave)


def _mapping_differs(ctx: CheckContext, slave: SlavePlan, obj: HeldObject,
                     values: list[int | None], want: list[int], desc: PdoDesc) -> None:
    if len(values) != len(want):
        where = obj.command(0)
        what = (f"0x{obj.index:04X} holds {len(values)} entries after "
                f"{where[1].value if where else 'PS'}, ProcessData's "
                f"{'Rx' if desc.direction == 'rx' else 'Tx'}Pdo 0x{desc.index:04X} "
                f"{len(want)}")
    else:
        k = next(k for k, (a, b) in enumerate(zip(values, want), 1) if a != b)
        where = obj.command(k) or obj.command(0)
        value = values[k - 1]
        what = (f"0x{obj.index:04X}:{k:02X} maps "
                f"{'nothing' if value is None else mapping_entry(value)} after "
                f"{where[1].value if where else 'PS'}; ProcessData's "
                f"{'Rx' if desc.direction == 'rx' else 'Tx'}Pdo 0x{desc.index:04X} has "
                f"{mapping_entry(want[k - 1])} there")
    have = sum((v or 0) & 0xFF for v in values)
    need = sum(v & 0xFF for v in want)
    if have != need:
        what += (f" ({have} bit(s) where the ENI lays out {need}: the SM length no longer "
                 "fits, the slave refuses SAFEOP)")
    else:
        what += " (same size: the master reads and writes another object in these bits)"
    ctx.add(MAPPING, _line(ctx, slave, where), what, slave)
