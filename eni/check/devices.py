"""Checks of an ENI against the ESI files of its devices: identity, PDO assignment and
mapping, CoE InitCmds, DC and the mailbox.  The device of a slave is the library's device
of the slave's exact identity (vendor, product, revision: ``Config/Slave/Info``), found as
every command finds one (``esi/library.py``); a slave whose device is not found is said so
once and checked against the ENI alone (``network.py``); one whose identity several ESI
files describe differently is checked against each description (``_every_candidate``)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

from ecatcfg.eni.check import dc as dc_sync
from ecatcfg.eni.check import pdo_state
from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.network import sm_pdos, sm_records
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.plan import CoeInitCmd, PdoDesc, SlavePlan
from ecatcfg.eni.words import foe_words, soe_words
from ecatcfg.esi import datatypes
from ecatcfg.esi.coe import (TRANSITION_STATE, DictEntry, dictionary_with_objects, lookup,
                             write_refusal, write_target)
from ecatcfg.esi.dc_cycle import min_cycle_time, us
from ecatcfg.esi.library import DuplicateError, Library, SelectorError
from ecatcfg.esi.lint.finding import Finding
from ecatcfg.esi.model import Device, Pdo

IDENTITY = declare("ENI001", "warning", "no ESI device of the slave's identity", """
    The ESI files given with --esi hold no device of the slave's vendor, product and
    revision (a revision is matched exactly, as the library does everywhere; the message
    lists the revisions it has).  The slave is checked against the ENI alone; add its ESI
    file to check the PDOs, InitCmds and DC settings against the device.""")
DUPLICATE = declare("ENI002", "error", "the slave's identity has differing ESI files", """
    Several ESI files describe the slave's identity differently (esi/duplicates.py:
    what changes what a master does); the message names each file and what differs.
    apply and simulate refuse such a device until --prefer FILE_OR_FOLDER chooses one, so
    check fails too.  The device rules still run, against every description: a finding
    all of them give is reported as usual (once), one that only some give is named in this
    finding, with the descriptions that give it.""")
MANDATORY = declare("ENI201", "error", "a Mandatory PDO is not assigned", """
    The ESI marks the PDO Mandatory: the device needs it assigned to its SyncManager
    (ETG.2000 RxPdo/TxPdo @Mandatory).  A slave whose mandatory PDO is missing refuses
    SAFEOP or runs without the data it needs.""")
EXCLUDED = declare("ENI202", "error", "two assigned PDOs exclude each other", """
    The ESI lists one of the assigned PDOs in the other's Exclude elements (alternative
    mappings of the same objects, ETG.2000): the device takes only one of them and refuses
    the assignment.""")
FIXED = declare("ENI203", "error", "a Fixed PDO's mapping differs from the ESI", """
    The ESI marks the PDO Fixed: its mapping cannot be changed (ETG.2000 @Fixed; the
    mapping object is read-only).  The ENI gives it other entries, so the process image
    the master lays out is not what the slave sends or reads.""")
MAPPABLE = declare("ENI204", "error", "a PDO maps an object that is not PDO-mappable", """
    A PDO entry maps an object whose dictionary entry says it cannot be mapped in that
    direction (Flags/PdoMapping: R for RxPDOs, T for TxPDOs; without PdoMapping the object
    is not mappable), and the ESI's own PDOs do not map it either.  The slave answers the
    mapping download with abort 0x06040041 (object cannot be mapped).""")
MISSING = declare("ENI301", "warning", "a CoE InitCmd writes an object the ESI lacks", """
    The device's dictionary lists objects, but not this one (or not this subindex).  ESI
    dictionaries are often partial, so this is a warning: the real slave's dictionary
    decides, and a missing object makes it answer abort 0x06020000 / 0x06090011.""")
READ_ONLY = declare("ENI302", "error", "a CoE InitCmd writes an object read-only then", """
    The dictionary's Flags/Access for the object (or subitem) do not allow writing in the
    AL state the InitCmd runs in (I->P and P->S commands run in PREOP, S->O in SAFEOP):
    ro, or a WriteRestrictions list without that state (esi/coe.py).  The slave answers
    abort 0x06010002 (read-only) or 0x08000022 (wrong state) and the transition fails.""")
SIZE = declare("ENI303", "error", "a CoE InitCmd's data does not fit the object", """
    The InitCmd's Data has a length the object (or subitem) does not take, from its BitSize
    in the dictionary: a number of another size, a string longer than declared or empty.
    The slave answers abort 0x06070010 / 0x06070012 / 0x06070013 and the transition fails.
    CompleteAccess commands write whole objects and are not compared.""")
ASSIGN_ACTIVATE = declare("ENI401", "error", "a DC AssignActivate the device does not have", """
    The value the slave's InitCmds write to the DC activation register (0x0980, 2 bytes)
    is none of the AssignActivate values of the device's Dc/OpMode elements (ETG.2000).
    The SYNC signals are then not the ones the device's firmware works with.""")
CYCLE = declare("ENI402", "warning", "a DC cycle time the device's OpMode does not give", """
    The ENI's DC CycleTime0/1 differ from the fixed CycleTimeSync0/1 (in ns, without a
    Factor) of the device's OpMode with the AssignActivate the ENI writes: the device's
    description says it takes that cycle only.""")
MIN_CYCLE = declare("ENI403", "error", "a SYNC0 cycle shorter than the device's minimum", """
    The ENI switches SYNC0 on (AssignActivate) with a DC CycleTime0 below the minimum cycle
    time the device's dictionary gives (the default of 0x1C32:05 or 0x1C33:05, ETG.1020
    "Minimum cycle time"). Slave Stack Code firmware checks the SYNC0 cycle against it
    and refuses SAFEOP with AL status code 0x0035 (invalid sync cycle time).""")
MAILBOX_SIZE = declare("ENI501", "error", "a mailbox outside the ESI's SyncManager sizes", """
    Mailbox/Send or Recv has a length outside the ESI's SM0/SM1 MinSize..MaxSize (or not
    the DefaultSize when no bounds are given) or a start address other than the ESI's
    StartAddress.  The slave checks its mailbox SyncManagers before PREOP and refuses them
    (AL status code 0x0016, invalid mailbox configuration).""")
FOE = declare("ENI503", "error", "an FoE InitCmd for a device without FoE", """
    The slave has an enabled FoE InitCmd (Mailbox/FoE/InitCmds) but its ESI does not list
    FoE under Mailbox (ETG.2000).  A slave answers an FoE message with mailbox error 2
    (unsupported protocol), and the transition fails.""")


NO_MAILBOX = declare("ENI504", "error", "no mailbox for a device that has one", """
    The slave has no Mailbox element and its InitCmds set neither SM0 nor SM1, but its
    device's ESI has a mailbox (MBoxOut/MBoxIn SyncManagers).  A slave with a mailbox
    checks its mailbox SyncManagers before PREOP and refuses it with AL status code 0x0016
    (invalid mailbox configuration; SOES ESC_checkmbx); a partial ENI is completed from its
    own Mailbox element only (eni/derive.py), never from the ESI.""")


SOE_DRIVE = declare("ENI502", "error", "an SoE InitCmd the device cannot take", """
    The slave's ESI has no SoE in its mailbox (Mailbox/SoE), or the InitCmd's DriveNo is
    beyond the drives the ESI gives (Mailbox/SoE@ChannelCount; one drive, 0, without it).
    The slave answers such a write with a mailbox or SoE error, and the transition
    fails.""")


def check(ctx: CheckContext, library: Library) -> None:
    for slave in ctx.plan.slaves:
        devices = _devices(ctx, library, slave)
        if len(devices) == 1:
            _device_rules(ctx, slave, devices[0][1])
        elif devices:
            _every_candidate(ctx, slave, devices)


def _device_rules(ctx: CheckContext, slave: SlavePlan, device: Device) -> None:
    if device.slots is None:      # modular devices: the PDOs come from their modules
        _pdos(ctx, slave, device)
    _coe(ctx, slave, device)
    pdo_state.check_held_sizes(ctx, slave, lambda index: _esi_mapping(device, index))
    _dc(ctx, slave, device)
    _mailbox(ctx, slave, device)
    _soe(ctx, slave, device)


# A finding's words without the ESI places it names (file:line), to tell one finding made
# against two descriptions of a device from two findings.
_PLACE = re.compile(r"[^\s(),]+\.xml:\d+")


def _every_candidate(ctx: CheckContext, slave: SlavePlan,
                     devices: list[tuple[str, Device]]) -> None:
    """An identity several ESI files describe differently (ENI002, an error: apply refuses
    it too unless --prefer chooses): the device rules run against every description; a
    finding they all give is reported once (as the first description words it), the others
    are named in the ENI002 finding, with the descriptions that give them."""
    per: list[list[Finding]] = []
    for _, device in devices:
        before = len(ctx.findings)
        _device_rules(ctx, slave, device)
        per.append(ctx.findings[before:])
        del ctx.findings[before:]

    def key(f: Finding) -> tuple[str, int | None, str]:
        return (f.rule, f.line, _PLACE.sub("ESI", f.message))

    keys = [{key(f) for f in found} for found in per]
    common = set.intersection(*keys)
    for f in per[0]:
        if key(f) in common:
            ctx.findings.append(f)
    # What only some give, by rule and line: how many findings with which description.
    some: dict[tuple[str, int | None], dict[str, int]] = {}
    for (where, _), found in zip(devices, per):
        for f in found:
            if key(f) not in common:
                counts = some.setdefault((f.rule, f.line), {})
                counts[where] = counts.get(where, 0) + 1
    duplicate = next((f for f in ctx.findings[::-1] if f.rule == DUPLICATE
                      and f.message.startswith(f"slave {slave.name!r}")), None)
    if some and duplicate is not None:
        said = "; ".join(f"{rule} at line {line} only with " + ", ".join(
            f"{Path(w).name}" + (f" ({n} findings)" if n > 1 else "")
            for w, n in counts.items()) for (rule, line), counts in some.items())
        index = ctx.findings.index(duplicate)
        ctx.findings[index] = dataclasses.replace(
            duplicate, message=duplicate.message + f"; the device rules differ by "
            f"description: {said}")


def _soe(ctx: CheckContext, slave: SlavePlan, device: Device) -> None:
    cmds = slave.mailbox.soe_init_cmds if slave.mailbox else []
    soe = device.mailbox.soe if device.mailbox else None
    esi = f"{device.source.file}:{device.source.line}"
    for n, cmd in enumerate(cmds):
        if cmd.disabled:
            continue
        line = ctx.lines.listed(slave, "Mailbox/SoE/InitCmds", n, len(cmds))
        if soe is None:
            ctx.add(SOE_DRIVE, line, f"{soe_words(cmd)}: the device has no SoE mailbox "
                    f"({esi})", slave)
            return
        if cmd.drive_no >= soe.drives:
            ctx.add(SOE_DRIVE, line, f"{soe_words(cmd)}: the device has {soe.drives} "
                    f"drive(s), numbered from 0 (ChannelCount, {esi})", slave)


def _devices(ctx: CheckContext, library: Library, slave: SlavePlan
             ) -> list[tuple[str, Device]]:
    """The slave's device, or each description of it where several ESI files describe its
    identity differently (ENI002), with where each is; none when the library has none."""
    selector = f"0x{slave.vendor_id:x}:0x{slave.product_code:x}:0x{slave.revision:x}"
    line = ctx.lines.child(slave, "Info")
    try:
        entry = library.find(selector).entry
    except DuplicateError as exc:
        ctx.add(DUPLICATE, line, exc.message + " (the device rules ran against each)", slave)
        same = [e for e in library.entries
                if (e.vendor_id, e.product_code, e.revision)
                == (slave.vendor_id, slave.product_code, slave.revision)]
        described: dict[str, tuple[str, Device]] = {}
        for e in same:
            digest = library.description(e).digest
            if digest not in described:
                described[digest] = (f"{e.file}:{e.line}", library.device(e))
        return list(described.values())
    except SelectorError as exc:
        ctx.add(IDENTITY, line, exc.message, slave)
        return []
    return [(f"{entry.file}:{entry.line}", library.device(entry))]


def _esi_mapping(device: Device, index: int) -> list[int] | None:
    """PDO ``index`` of the device as mapping values, None when it has none."""
    pdo = next((p for p in device.pdos if p.index == index), None)
    if pdo is None:
        return None
    return [((e.index or 0) << 16 | ((e.subindex or 0) if e.index else 0) << 8
             | (e.bit_len or 0)) for e in pdo.entries]


def _esi_pdo(device: Device, pdo: PdoDesc) -> Pdo | None:
    own = device.rx_pdos if pdo.direction == "rx" else device.tx_pdos
    return next((p for p in own if p.index == pdo.index), None)


def _pdos(ctx: CheckContext, slave: SlavePlan, device: Device) -> None:
    pd = slave.process_data
    if pd is None:
        return
    assigned = [p for sm in pd.sms if sm.type in ("Outputs", "Inputs")
                for p in sm_pdos(slave, sm)]
    line = ctx.lines.child(slave, "ProcessData")
    indices = {(p.direction, p.index) for p in assigned}
    for own in device.pdos:
        if own.mandatory and own.index is not None and not own.virtual \
                and (own.direction, own.index) not in indices:
            ctx.add(MANDATORY, line, f"{'Rx' if own.direction == 'rx' else 'Tx'}Pdo "
                    f"0x{own.index:04X} ({own.name}) is Mandatory in {own.source.file}:"
                    f"{own.source.line} but not assigned", slave)
    excluded: set[tuple[str, int, int]] = set()
    for pdo in assigned:
        esi = _esi_pdo(device, pdo)
        if esi is None:
            continue
        for other in assigned:
            # One Exclude element is enough: a vendor may list it on one PDO only.
            if other is not pdo and other.direction == pdo.direction \
                    and other.index in esi.excludes:
                pair = (pdo.direction, min(pdo.index, other.index), max(pdo.index, other.index))
                if pair not in excluded:
                    excluded.add(pair)
                    ctx.add(EXCLUDED, line, f"PDOs 0x{pair[1]:04X} and 0x{pair[2]:04X} are "
                            f"both assigned; {esi.source.file}:{esi.source.line} (PDO "
                            f"0x{pdo.index:04X}) excludes 0x{other.index:04X}", slave)
        if esi.fixed:
            mine = [(e.index, e.subindex if e.index else 0, e.bit_len) for e in pdo.entries]
            theirs = [(e.index or 0, (e.subindex or 0) if e.index else 0, e.bit_len or 0)
                      for e in esi.entries]
            if mine != theirs:
                ctx.add(FIXED, line, f"PDO 0x{pdo.index:04X} is Fixed in {esi.source.file}:"
                        f"{esi.source.line} with {len(theirs)} entries; the ENI maps other "
                        f"ones ({len(mine)} entries)", slave)
    _mappable(ctx, slave, device, assigned)


def _mappable(ctx: CheckContext, slave: SlavePlan, device: Device,
              assigned: list[PdoDesc]) -> None:
    dic = dictionary_with_objects(device)
    if dic is None:
        return
    # What the ESI's own PDOs map in a direction is mappable there, flags or not.
    esi_mapped = {(p.direction, e.index, e.subindex or 0) for p in device.pdos
                  for e in p.entries}
    for pdo in assigned:
        letter = "R" if pdo.direction == "rx" else "T"
        for position, e in enumerate(pdo.entries):
            if not e.index or (pdo.direction, e.index, e.subindex) in esi_mapped:
                continue
            found = lookup(dic, e.index, e.subindex)
            if not isinstance(found, DictEntry) or found.flags is None \
                    or found.flags.access is None:
                continue                     # the dictionary does not say
            mapping = (found.flags.pdo_mapping or "").upper()
            if letter not in mapping:
                why = (f"its PdoMapping is {mapping!r}" if mapping
                       else "it has no PdoMapping")
                ctx.add(MAPPABLE, ctx.lines.pdo_entry(slave, pdo.direction, pdo.index,
                                                      position),
                        f"PDO 0x{pdo.index:04X} maps 0x{e.index:04X}:"
                        f"{e.subindex:02X}, which the dictionary does not let a "
                        f"{letter}xPDO map ({why})", slave)


def _coe(ctx: CheckContext, slave: SlavePlan, device: Device) -> None:
    mb = slave.mailbox
    dic = dictionary_with_objects(device)
    if mb is None or dic is None:
        return
    cmds = mb.coe_init_cmds
    # One finding per object and cause, however many of its subindexes the InitCmds write
    # (a PDO object written entry by entry is one read-only object, not nine findings).
    missing: dict[tuple[int, str], list[tuple[str, int | None]]] = {}
    refused: dict[tuple[int, str], list[tuple[str, int | None]]] = {}
    for n, cmd in enumerate(cmds):
        if cmd.disabled or cmd.ccs != 1:
            continue
        line = ctx.lines.listed(slave, "Mailbox/CoE/InitCmds", n, len(cmds))
        shown = f"0x{cmd.index:04X}:{cmd.subindex:02X}"
        found = write_target(dic, cmd.index, cmd.subindex, cmd.complete_access)
        if found is None or not isinstance(found, DictEntry):
            # Objects of a module's dictionary are not in a modular device's own.
            if device.slots is None:
                kind = "object" if found is None else "subindex"
                missing.setdefault((cmd.index, kind), []).append((shown, line))
            continue
        for transition in cmd.transitions:
            state = TRANSITION_STATE.get(transition.value)
            why = write_refusal(found, state) if state is not None else None
            if why is not None:
                what = "read-only" if why.startswith("access") else "not writable then"
                refused.setdefault((cmd.index, f"({transition.value}, in {state}) "
                                    f"write{{}} {{}}, {what} in {device.source.file}:"
                                    f"{found.obj.source.line} ({why})"), []).append(
                    (shown, line))
                break
        _size(ctx, slave, cmd, found, shown, line)
    for (_, kind), written in missing.items():
        ctx.add(MISSING, written[0][1], f"CoE InitCmd{_s(written)} write{_s1(written)} "
                f"{_spelled(written)}; the device's dictionary has no such {kind} "
                f"({device.source.file}:{device.source.line})", slave)
    for (_, words), written in refused.items():
        ctx.add(READ_ONLY, written[0][1], f"CoE InitCmd{_s(written)} "
                + words.format(_s1(written), _spelled(written)), slave)


def _s(written: list[tuple[str, int | None]]) -> str:
    return "s" if len(written) > 1 else ""


def _s1(written: list[tuple[str, int | None]]) -> str:
    return "" if len(written) > 1 else "s"


def _spelled(written: list[tuple[str, int | None]]) -> str:
    """``0x1C12:00, 0x1C12:01`` and, for more than one, the lines of the others."""
    shown = list(dict.fromkeys(w for w, _ in written))
    lines = sorted({ln for _, ln in written[1:] if ln is not None and ln != written[0][1]})
    return ", ".join(shown) + (f" (also at line{'s' if len(lines) > 1 else ''} "
                               + ", ".join(map(str, lines)) + ")" if lines else "")


def _size(ctx: CheckContext, slave: SlavePlan, cmd: CoeInitCmd, found: DictEntry,
          shown: str, line: int | None) -> None:
    typed = datatypes.bit_size(found.type)
    if cmd.complete_access or not found.bit_size or typed is None:
        return
    # A base type's own size decides (the slave encodes a UINT in 2 bytes); an array's
    # element size derived from its BitSize can say otherwise (IS620N: 1 UINT in 32 bits).
    want = ((typed or found.bit_size) + 7) // 8
    if not datatypes.download_fits(found.type, want, len(cmd.data)):
        ctx.add(SIZE, line, f"CoE InitCmd writes {len(cmd.data)} byte(s) to {shown}, a "
                f"{found.type} of {want} byte(s)", slave)


def _dc(ctx: CheckContext, slave: SlavePlan, device: Device) -> None:
    found = dc_sync.assign_activate(slave)
    if found is None:
        return
    value, n = found
    line = ctx.lines.listed(slave, "InitCmds", n, len(slave.init_cmds))
    modes = device.dc.opmodes if device.dc is not None else []
    # A write of 0x0981 alone leaves 0x0980 (the cyclic unit's PDI/ECAT control) as it is.
    matching = [m for m in modes if m.assign_activate is not None and (
        m.assign_activate == value or (value & 0xFF == 0
                                       and m.assign_activate & 0xFF00 == value))]
    if not matching:
        have = ", ".join(f"{m.name} 0x{m.assign_activate:04X}" for m in modes
                         if m.assign_activate is not None) or "no DC OpMode"
        ctx.add(ASSIGN_ACTIVATE, line, f"InitCmds write AssignActivate 0x{value:04X}; the "
                f"device has {have}", slave)
        return
    # The cycle the slave gets: what the InitCmds write to 0x09A0, else DC CycleTime0.
    running = dc_sync.sync0(slave)
    minimum = min_cycle_time(device)
    if running is not None and running.cycle_ns and minimum is not None \
            and running.cycle_ns < minimum.ns:
        if running.cycle_at is None:
            where, what = ctx.lines.child(slave, "DC"), "DC CycleTime0"
        else:
            where = ctx.lines.listed(slave, "InitCmds", running.cycle_at,
                                     len(slave.init_cmds))
            what = "the SYNC0 cycle the InitCmds write (0x09A0)"
        ctx.add(MIN_CYCLE, where, f"{what} is {us(running.cycle_ns)} with SYNC0 on; the "
                f"device's {minimum.text()}: its firmware refuses SAFEOP with AL status "
                "code 0x0035", slave)
    dc = slave.dc
    if dc is None:
        return
    for mode in matching:
        fixed = [(name, want, got) for name, want, factor, got in (
            ("CycleTime0", mode.cycle_time_sync0, mode.cycle_time_sync0_factor, dc.cycle_time0),
            ("CycleTime1", mode.cycle_time_sync1, mode.cycle_time_sync1_factor, dc.cycle_time1))
            if want and factor is None and got and want != got]
        if not fixed:
            return
    for name, want, got in fixed:
        ctx.add(CYCLE, ctx.lines.child(slave, "DC"), f"DC {name} is {got} ns; OpMode "
                f"{matching[-1].name} of the device gives {want} ns", slave)


def _mailbox(ctx: CheckContext, slave: SlavePlan, device: Device) -> None:
    mb = slave.mailbox
    if mb is None:
        boxes = [sm for sm in device.sms if sm.is_mailbox]
        if boxes and not {0, 1} & set(sm_records(slave)):
            ctx.add(NO_MAILBOX, ctx.lines.slave(slave),
                    f"the ENI sets up no mailbox, the device has one (SM{boxes[0].number}, "
                    f"{boxes[0].source.file}:{boxes[0].source.line}): the slave refuses "
                    "PREOP with AL status code 0x0016", slave)
        return
    if device.mailbox is None or "FoE" not in device.mailbox.protocols:
        cmds = mb.foe_init_cmds
        for index, cmd in enumerate(cmds):
            if not cmd.disabled:
                ctx.add(FOE, ctx.lines.listed(slave, "Mailbox/FoE/InitCmds", index, len(cmds)),
                        f"FoE InitCmd {cmd.comment or foe_words(cmd)!r}: the device's ESI "
                        f"lists no FoE ({device.source.file}:{device.source.line})", slave)
    boxes = [sm for sm in device.sms if sm.is_mailbox]
    for area, name, sm in ((mb.send, "Send", device.sms[0] if device.sms else None),
                           (mb.recv, "Recv", device.sms[1] if len(device.sms) > 1 else None)):
        if sm is None or sm not in boxes:
            continue
        problems = []
        # The one rule of the lengths a slave takes (the emulated firmware's too).
        if not sm.takes_mailbox_length(area.length):
            problems.append(f"length {area.length}, the ESI allows "
                            + sm.mailbox_lengths_text())
        if sm.start_address is not None and area.start != sm.start_address:
            problems.append(f"start 0x{area.start:04X}, the ESI's is 0x{sm.start_address:04X}")
        if problems:
            ctx.add(MAILBOX_SIZE, ctx.lines.child(slave, f"Mailbox/{name}"),
                    f"Mailbox/{name}: " + "; ".join(problems) + f" (SM{sm.number}, "
                    f"{sm.source.file}:{sm.source.line})", slave)

