"""The PDO assignment and mapping the slave holds after its CoE InitCmds, against the ENI's
own ``ProcessData`` and SyncManager lengths.  What the downloads leave is
:func:`ecatcfg.eni.pdo_held.pdo_objects_held`; a slave that holds another assignment or
mapping than the master lays its image out for either refuses SAFEOP (the SM length no
longer fits: AL status code 0x001D/0x001E) or sends other data in the bits the master
reads as a variable.  No ESI file is needed: the file is compared with itself."""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.network import sm_pdos, sm_records
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.pdo_held import HeldObject, entry_size, pdo_objects_held
from ecatcfg.eni.plan import PdoDesc, SlavePlan, SmSettings
from ecatcfg.eni.words import mapping_entry
from ecatcfg.esc import RX_PDO_MAPPING, SM_PDO_ASSIGN, SM_PDO_ASSIGN_RANGE, Transition

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


COUNT = declare("ENI207", "error", "a complete-access download's count is not its "
                "entries", """
    A CompleteAccess download of a PDO assignment or mapping object from subindex 0 carries
    the count (subindex 0, in a 16-bit slot) and then the entries (ETG.1000.6 SDO complete
    access).  A count larger than the entries it carries leaves the slave with entries the
    download did not write; non-zero entries past the count are written but not used (a
    count one short: the slave holds one PDO less than the SM length needs and refuses
    SAFEOP, or aborts the download with 0x06070012 where the object has no room).""")
HELD_SIZE = declare("ENI208", "error", "an SM length the PDOs the slave holds do not "
                    "fill", """
    The PDOs the slave's assignment object holds after the CoE InitCmds up to SAFEOP, with
    their mappings (as downloaded, else as the ENI's ProcessData describes them, else as the
    device's ESI does), take another number of bytes than the SyncManager's length the
    InitCmds write: the slave refuses SAFEOP (AL status code 0x001D for outputs, 0x001E
    for inputs; SOES ESC_checkSM23).  Judged where ProcessData names no PDO of that SM
    (otherwise ENI205/ENI206 say it), with the device's ESI; an assigned PDO the ESI does not
    have either is named as such.""")


def check(ctx: CheckContext) -> None:
    for slave in ctx.plan.slaves:
        if slave.mailbox is None:
            continue
        _complete_counts(ctx, slave)
        if slave.process_data is None:
            continue
        held = pdo_objects_held(slave.mailbox.coe_init_cmds)
        if held:
            _check_slave(ctx, slave, held)


def _complete_counts(ctx: CheckContext, slave: SlavePlan) -> None:
    cmds = slave.mailbox.coe_init_cmds if slave.mailbox is not None else []
    for position, cmd in enumerate(cmds):
        size = entry_size(cmd.index)
        if cmd.disabled or cmd.ccs != 1 or not size or not cmd.complete_access \
                or cmd.subindex != 0 or len(cmd.data) < 2:
            continue
        count = cmd.data[0]
        carried = [int.from_bytes(cmd.data[k:k + size], "little")
                   for k in range(2, len(cmd.data) - size + 1, size)]
        if count > len(carried) or any(carried[count:]):
            ctx.add(COUNT, _line(ctx, slave, (position, Transition.PS)),
                    f"CompleteAccess download of 0x{cmd.index:04X} sets the count to {count}"
                    f" and carries {len(carried)} entries", slave)


def check_held_sizes(ctx: CheckContext, slave: SlavePlan,
                     esi_entries: Callable[[int], list[int] | None]) -> None:
    """With the device's ESI (``esi_entries``: a PDO's mapping values, None where the
    device has no such PDO): each SM whose assignment the downloads write and whose PDOs
    ProcessData does not name, against the SM length the InitCmds write (ENI208)."""
    pd = slave.process_data
    if slave.mailbox is None or pd is None:
        return
    held = pdo_objects_held(slave.mailbox.coe_init_cmds)
    described = {p.index: p for p in pd.pdos}
    lengths = {n: images[-1][0].length for n, images in sm_records(slave).items()}
    named = {sm.number for sm in pd.sms if sm.pdos} | {p.sm for p in pd.pdos if p.sm is not None}
    for index, obj in sorted(held.items()):
        n = index - SM_PDO_ASSIGN
        values = obj.values()
        if index not in SM_PDO_ASSIGN_RANGE or values is None or n in named \
                or None in values or n not in lengths:
            continue
        bits, unknown = 0, []
        for pdo in values:
            if not pdo:
                continue
            size = _bits(pdo, held, described)
            if size is None:
                mapping = esi_entries(pdo)
                if mapping is None:
                    unknown.append(pdo)
                    continue
                size = sum(v & 0xFF for v in mapping)
            bits += size
        where = obj.command(0)
        if unknown:
            ctx.add(HELD_SIZE, _line(ctx, slave, where),
                    f"0x{index:04X} holds {_pdo_list(list(unknown))} after "
                    f"{where[1].value if where else 'PS'}, which neither the ENI nor the "
                    "device's ESI describes: the slave refuses SAFEOP", slave)
        elif (bits + 7) // 8 != lengths[n]:
            ctx.add(HELD_SIZE, _line(ctx, slave, where),
                    f"0x{index:04X} holds {len(values)} PDO(s) after "
                    f"{where[1].value if where else 'PS'} ({_pdo_list(list(values))}), "
                    f"{(bits + 7) // 8} byte(s); SM{n} is set to {lengths[n]}: the slave "
                    f"refuses SAFEOP", slave)


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
    sms = [sm for sm in pd.sms if sm.type in ("Outputs", "Inputs")]
    known = {sm.number for sm in sms}
    for index, obj in sorted(held.items()):
        # An assignment the downloads write for an SM ProcessData has no Sm element for
        # (the PDOs' Sm attribute says which are its): its type is its PDOs' direction.
        written = obj.values() or []
        n = index - SM_PDO_ASSIGN
        if index in SM_PDO_ASSIGN_RANGE and n not in known and any(written):
            rx = all(v in RX_PDO_MAPPING for v in written if v)
            sms.append(SmSettings(n, "Outputs" if rx else "Inputs", 0, 0, True))
    for sm in sms:
        listed = [p.index for p in sm_pdos(slave, sm)] or list(sm.pdos)
        assignment = held.get(SM_PDO_ASSIGN + sm.number)
        pdos = assignment.values() if assignment is not None else None
        if assignment is None or pdos is None:
            assigned += listed
            continue
        assigned += [v for v in pdos if v]
        if pdos == listed or not listed:
            continue                 # (ProcessData names no PDO of this SM: with ESI below)

        def carrying(indices: list[int | None]) -> list[int | None]:
            # A PDO without entries moves no bit: neither the slave nor the image sees it.
            return [i for i in indices if i is None or _bits(i, held, described) != 0]
        if carrying(pdos) == carrying(list(listed)):
            continue
        _assignment_differs(ctx, slave, sm, assignment, pdos, listed, held, described,
                            lengths.get(sm.number))
    for index in assigned:
        desc = described.get(index)
        mapping = held.get(index)
        entries = mapping.values() if mapping is not None else None
        if desc is None or mapping is None or entries is None:
            continue
        want = _entries(desc)
        if entries == want:
            continue
        _mapping_differs(ctx, slave, mapping, entries, want, desc)


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
