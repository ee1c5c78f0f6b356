"""Topology + device library -> NetworkPlan: the compiler's one entry point.

``compile_topology`` resolves every slave (``resolve``), lays out the process image
(``layout``), then writes each slave's register InitCmds (``initcmds``) and CoE InitCmds
(``pdocmds`` + the ESI's own + the user's SDOs).  Nothing is returned when any slave has an
error: all errors are raised together as one :class:`TopologyError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ecatcfg.compiler import (copies, esi_errors, hotconnect, initcmds,
                              layout as layout_mod, passive, pdocmds)
from ecatcfg.eni.plan import (Cyclic, DcPlan, MailboxArea, MailboxPlan, MasterPlan,
                                   NetworkPlan, PreviousPort, ProcessData, ProcessImage,
                                   SlavePlan, SmSettings, Variable)
from ecatcfg.compiler.resolve import ResolvedSlave, resolve_all
from ecatcfg.compiler.topology import LoadedTopology, TopologyError
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import MAILBOX_STATE_ADDR, PORT_LETTERS, SmConfig
from ecatcfg.esi.library import Library
from ecatcfg.esi.dc_cycle import sync_cycle
from ecatcfg.esi.model import Device
from ecatcfg.esi.physics import DEFAULT_PHYSICS, eni_physics

# How often a master polls SM1 of a slave without a mailbox-state bit (ms; EC-Engineer
# writes 10 for the Elmo Gold).
MAILBOX_POLL_TIME = 10
# The ENI schema's ProcessData has elements Sm0..Sm3 only.
ENI_MAX_SM = 3
SYNC1_BIT = 0x0400            # AssignActivate bit for SYNC1 (0x0981 bit 2)
U32_MAX = 0xFFFFFFFF


@dataclass(slots=True)
class CompileResult:
    plan: NetworkPlan
    warnings: list[EcatcfgError] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def compile_topology(loaded: LoadedTopology, library: Library,
                     allow_esi_errors: bool = False) -> CompileResult:
    """The :class:`NetworkPlan` of a loaded topology, its devices taken from ``library``.

    Every slave is resolved first (device, modules, PDO choice, DC mode, SDOs) and every
    mistake is collected: if there is any, all of them are raised together as one
    :class:`TopologyError`, each naming its topology line, and nothing is laid out.  Then
    the process image, FMMUs and cyclic frames are laid out (``layout``) and the DC settings
    and InitCmds of every slave are written; a layout or a SYNC cycle that cannot be made is
    a :class:`TopologyError` too.  The result carries the plan with the warnings (E-bus
    current budget) and notes (which revision a selector took) for the user.  The plan is
    written as an ENI by :mod:`ecatcfg.eni.writer`.
    """
    # Passive terminals (no ESC) take no position or address: the slaves with an ESC are
    # compiled alone, the passive ones placed beside them at the end (compiler/passive.py).
    whole = loaded
    parts = passive.split(whole, library)
    loaded = parts.active
    resolved, errors, wiring_notes = resolve_all(loaded, library)
    errors = parts.errors + errors
    errors += _esi_value_errors(loaded, resolved)
    errors += _fmmu_errors(loaded, resolved)
    defects = esi_errors.esi_errors(loaded, resolved, library, allow_esi_errors)
    if not allow_esi_errors:
        errors += defects
    if errors:
        raise TopologyError(errors)
    groups, group_errors = hotconnect.groups(loaded, resolved)
    if group_errors:
        raise TopologyError(group_errors)
    topo = loaded.topology
    cycle_ns = topo.master.cycle_time_us * 1000
    ref = next((s for s in resolved if s.dc_mode and s.dc_mode.assign_activate), None)
    polled = [i for i, s in enumerate(resolved) if _uses_state_bit(s)]
    try:
        lay = layout_mod.build(resolved, topo.master.layout, ref is not None, polled)
    except layout_mod.LayoutError as exc:
        raise TopologyError([loaded.error(exc.message, "slaves", exc.slave)]) from None

    dcs = [_dc_plan(s, cycle_ns, s is ref) for s in resolved]
    # 0x09A0/0x09A4 hold 32-bit nanoseconds: a SYNC cycle of more than 4.29 s cannot be set.
    too_long = [loaded.error(f"slave {s.name!r}: DC op mode {s.dc_mode.name!r} gives a SYNC "
                             f"cycle of {max(dc.cycle_time0, dc.cycle_time1)} ns, more than "
                             f"the {U32_MAX} ns the ESC register holds; shorten "
                             "master.cycle_time_us", "slaves", s.index, "dc")
                for s, dc in zip(resolved, dcs)
                if dc and s.dc_mode and not (0 <= dc.cycle_time0 <= U32_MAX
                                             and 0 <= dc.cycle_time1 <= U32_MAX)]
    if too_long:
        raise TopologyError(too_long)

    slaves: list[SlavePlan] = []
    for i, s in enumerate(resolved):
        sl = lay.slaves[i]
        dc = dcs[i]
        init = initcmds.slave_init_cmds(
            s, sl, dc, (s.dc_mode.assign_activate or 0) if dc and s.dc_mode else 0,
            _bootstrap(s))
        slaves.append(SlavePlan(
            name=s.name, phys_addr=s.phys_addr, auto_inc_addr=(-s.position) & 0xFFFF,
            vendor_id=s.device.vendor.id or 0, product_code=s.device.product_code or 0,
            revision=s.device.revision or 0,
            physics=eni_physics(s.device.physics or DEFAULT_PHYSICS),
            process_data=_process_data(s, sl), mailbox=_mailbox(s, sl), init_cmds=init, dc=dc,
            previous_ports=_previous_port(s, resolved), hot_connect=groups.get(s.position)))

    outputs = _unique([v for sl in lay.slaves for v in sl.outputs])
    inputs = _unique([v for sl in lay.slaves for v in sl.inputs])
    plan = NetworkPlan(
        master=MasterPlan(topo.master.name, init_cmds=initcmds.master_init_cmds(),
                          mailbox_states=(MAILBOX_STATE_ADDR, len(polled)) if polled else None),
        slaves=slaves,
        cyclic=[Cyclic(lay.frames, cycle_time=topo.master.cycle_time_us)],
        process_image=ProcessImage(lay.image_size, lay.image_size, inputs, outputs))
    copy_errors = copies.add_copies(loaded, plan)
    if copy_errors:
        raise TopologyError(copy_errors)
    placed = passive.place(plan, parts.passive, whole)
    if placed:
        raise TopologyError(placed)
    notes = wiring_notes + _notes(resolved)
    line = passive.in_line([(s.name, s.device, parts.file_index[s.index]) for s in resolved],
                           parts.passive)
    parents = {parts.file_index[s.index]: None if s.parent is None
               else parts.file_index[resolved[s.parent].index] for s in resolved}
    warnings = (defects if allow_esi_errors else []) + ebus_warnings(whole, line, parents)
    return CompileResult(plan, warnings, notes)


def _previous_port(s: ResolvedSlave, resolved: list[ResolvedSlave]) -> list[PreviousPort]:
    """Where the slave is plugged, as TwinCAT and EC-Engineer write it: the parent's port
    letter and station address, Selected (the first slave, on the master, has none)."""
    if s.parent is None or s.parent_port is None:
        return []
    return [PreviousPort(PORT_LETTERS[s.parent_port], resolved[s.parent].phys_addr, True)]


def _notes(resolved: list[ResolvedSlave]) -> list[str]:
    """One line per distinct note (e.g. the revision taken), naming the slaves it concerns."""
    by_note: dict[str, list[str]] = {}
    for s in resolved:
        for note in ([s.note] if s.note else []) + s.notes:
            by_note.setdefault(note, []).append(s.name)
    out = []
    for note, names in by_note.items():
        who = ", ".join(repr(n) for n in names[:3]) + (
            f" and {len(names) - 3} more" if len(names) > 3 else "")
        out.append(f"slave{'s' if len(names) > 1 else ''} {who}: {note}")
    return out


def _uses_state_bit(s: ResolvedSlave) -> bool:
    """Poll the mailbox through the logical state bit when the ESI offers an MBoxState FMMU
    (Beckhoff terminals, EC-train); otherwise poll SM1 every MAILBOX_POLL_TIME ms."""
    kinds = [f.type for f in s.device.fmmus]
    mailboxes = [sm for sm in s.device.sms if sm.is_mailbox]
    return len(mailboxes) >= 2 and "MBoxState" in kinds and \
        len(kinds) >= _pd_fmmu_count(s) + 1


def _pd_fmmu_count(s: ResolvedSlave) -> int:
    out, inp = layout_mod.pd_bits(s)
    return (len(layout_mod.fmmu_groups(s, out, "Outputs"))
            + len(layout_mod.fmmu_groups(s, inp, "Inputs")))


def _esi_value_errors(loaded: LoadedTopology,
                      resolved: list[ResolvedSlave]) -> list[EcatcfgError]:
    """ESI numbers that go into register images and SDO data must fit their fields (a broken
    ESI must be an error naming it, not a struct.error)."""
    errors = []
    for s in resolved:
        dev = s.device
        checks: list[tuple[str, int | None, int]] = [
            ("VendorId", dev.vendor.id, U32_MAX), ("ProductCode", dev.product_code, U32_MAX),
            ("RevisionNo", dev.revision, U32_MAX)]
        for sm in dev.sms:
            checks += [(f"Sm {sm.number} StartAddress", sm.start_address, 0xFFFF),
                       (f"Sm {sm.number} ControlByte", sm.control_byte, 0xFF),
                       (f"Sm {sm.number} DefaultSize", sm.default_size, 0xFFFF),
                       (f"Sm {sm.number} MinSize", sm.min_size, 0xFFFF),
                       (f"Sm {sm.number} MaxSize", sm.max_size, 0xFFFF)]
        if s.dc_mode is not None:
            checks.append((f"OpMode {s.dc_mode.name!r} AssignActivate",
                           s.dc_mode.assign_activate, 0xFFFF))
        coe = dev.mailbox.coe if dev.mailbox else None
        for p in s.pdos:
            checks.append(("a PDO index", p.index, 0xFFFF))
            for e in p.entries:
                checks += [(f"PDO 0x{p.index:X} entry index", e.index, 0xFFFF),
                           (f"PDO 0x{p.index:X} entry subindex", e.subindex, 0xFF)]
                # A mapping entry (0x16xx/0x1Axx) holds the bit length in one byte.
                if coe and coe.pdo_config and not p.fixed and p.sm is not None:
                    checks.append((f"PDO 0x{p.index:X} entry BitLen", e.bit_len, 0xFF))
        for what, value, limit in checks:
            if value is not None and not 0 <= value <= limit:
                errors.append(loaded.error(
                    f"slave {s.name!r}: the ESI of {dev.type_name} ({dev.source}) has "
                    f"{what} {value:#x}, outside 0..{limit:#x}", "slaves", s.index,
                    "device"))
    return errors


def _fmmu_errors(loaded: LoadedTopology, resolved: list[ResolvedSlave]) -> list[EcatcfgError]:
    errors = []
    for s in resolved:
        have, need = len(s.device.fmmus), _pd_fmmu_count(s)
        if have and need > have:
            errors.append(loaded.error(
                f"slave {s.name!r}: its process data needs {need} FMMUs, the ESI of "
                f"{s.device.type_name} declares {have}", "slaves", s.index))
    return errors


def _dc_plan(s: ResolvedSlave, cycle_ns: int, reference: bool) -> DcPlan | None:
    mode = s.dc_mode
    if mode is None or not mode.assign_activate:
        return None
    cycle0 = sync_cycle(mode.cycle_time_sync0, mode.cycle_time_sync0_factor, cycle_ns) or cycle_ns
    cycle1 = 0
    if mode.assign_activate & SYNC1_BIT:
        # ETG.2000: the SYNC1 factor multiplies the SYNC0 cycle; 0x09A4 counts from SYNC0
        # and includes the SYNC1 shift (as IgH writes it).
        cycle1 = (sync_cycle(mode.cycle_time_sync1, mode.cycle_time_sync1_factor, cycle0) or 0) \
            + (mode.shift_time_sync1 or 0)
    return DcPlan(reference, cycle0, cycle1, mode.shift_time_sync0 or 0)


def _bootstrap(s: ResolvedSlave) -> tuple[SmConfig, SmConfig] | None:
    """SM0/SM1 for BOOT from the ESI ``Eeprom/BootStrap`` (out start, out size, in start,
    in size; 2 bytes each)."""
    boot = s.device.eeprom.boot_strap if s.device.eeprom else None
    mailboxes = [sm for sm in s.device.sms if sm.is_mailbox]
    if not boot or len(boot) < 8 or len(mailboxes) < 2:
        return None
    o_start, o_len, i_start, i_len = (int.from_bytes(boot[i:i + 2], "little")
                                      for i in range(0, 8, 2))
    if not o_len or not i_len:
        return None
    return (SmConfig(o_start, o_len, mailboxes[0].mailbox_control, True),
            SmConfig(i_start, i_len, mailboxes[1].mailbox_control, True))


def _process_data(s: ResolvedSlave, sl: layout_mod.SlaveLayout) -> ProcessData | None:
    pd_sms = [sm for sm in sorted(s.device.sms, key=lambda x: x.number)
              if not sm.is_mailbox and sm.type in ("Outputs", "Inputs")
              and sm.number <= ENI_MAX_SM]
    if not pd_sms and not s.pdos:
        return None
    out, inp = layout_mod.pd_bits(s)
    bits = dict(out + inp)
    sms = []
    for sm in pd_sms:
        length = (bits.get(sm.number, 0) + 7) // 8
        sms.append(SmSettings(
            sm.number, sm.type or "", sm.start_address or 0,
            sm.control_byte or 0 if length else 0, bool(length),
            [p.index for p in s.assigned(sm.number)], sm.min_size, sm.max_size,
            sm.default_size, True if sm.virtual else None))
    return ProcessData([sl.send] if sl.send else [], [sl.recv] if sl.recv else [], sms,
                       list(s.pdos))


def _mailbox(s: ResolvedSlave, sl: layout_mod.SlaveLayout) -> MailboxPlan | None:
    dev = s.device
    mailboxes = [sm for sm in dev.sms if sm.is_mailbox]
    if dev.mailbox is None or len(mailboxes) < 2:
        return None
    out, inp = mailboxes[0], mailboxes[1]
    boot = _bootstrap(s)
    # The module ident list first: the station builds its PDOs from it (TwinCAT writes it
    # at the head of PREOP->SAFEOP).
    coe = s.module_cmds + pdocmds.pdo_cmds(s) + s.esi_cmds + s.user_cmds
    return MailboxPlan(
        send=MailboxArea(out.start_address or 0, out.mailbox_size),
        recv=MailboxArea(inp.start_address or 0, inp.mailbox_size),
        protocols=list(dev.mailbox.protocols),
        poll_time=None if sl.status_bit is not None else MAILBOX_POLL_TIME,
        status_bit_addr=sl.status_bit,
        bootstrap_send=MailboxArea(boot[0].start, boot[0].length) if boot else None,
        bootstrap_recv=MailboxArea(boot[1].start, boot[1].length) if boot else None,
        coe_init_cmds=coe, eoe_init_cmds=list(s.eoe_cmds), soe_init_cmds=list(s.soe_cmds),
        coe_profiles=[(p.profile_no, None if p.add_info is None else str(p.add_info))
                      for p in dev.profiles if p.profile_no is not None]
        if "CoE" in dev.mailbox.protocols else [],
        data_link_layer=True if dev.mailbox.data_link_layer else None)


def _unique(variables: list[Variable]) -> list[Variable]:
    """Variable names must be unique (C header, lookups): later duplicates get _2, _3, ..."""
    seen: dict[str, int] = {}
    for v in variables:
        n = seen.get(v.name, 0)
        seen[v.name] = n + 1
        if n:
            v.name = f"{v.name}_{n + 1}"
    return variables


def ebus_warnings(loaded: LoadedTopology, line: list[tuple[str, Device, int]],
                  parents: dict[int, int | None]) -> list[EcatcfgError]:
    """E-bus budget (ESI ``Electrical/EBusCurrent``, mA): a negative value supplies current
    (a coupler: -2000; also a passive power feed, e.g. Beckhoff's EL9400), positive values
    draw it; warn when the terminals a supplier feeds draw more than it gives.

    ``line``: ``(name, device, index in the topology file)`` of every slave, passive ones
    included, in the order of the line; ``parents``: the file index of the slave each slave
    with an ESC is plugged into (None: the first).  A terminal draws from the supplier its
    E-bus leads back to, not from the last supplier in bus order: the frame visits a
    junction's Ethernet branches (a second coupler and its terminals) before the junction's
    own E-bus goes on, so the terminals after a branch still hang on the first coupler."""
    at = {index: k for k, (_, _, index) in enumerate(line)}

    def current(k: int) -> int | None:
        device = line[k][1]
        return device.info.ebus_current if device.info else None

    def feeder(k: int) -> int | None:
        """The slave line[k] is plugged into (its E-bus neighbour towards the master): the
        parent, or a passive terminal between them.  Not ``Physics``: the E-bus current a
        device draws says it is on an E-bus, whatever letters its ESI gives its ports."""
        index = line[k][2]
        if index not in parents:                # passive: the terminal before it in the row
            return k - 1 if k else None
        parent = parents[index]
        if parent is None:
            return None
        before = k - 1                          # passive terminals in the row between them
        while before >= 0 and line[before][2] not in parents:
            before -= 1
        return k - 1 if before == at[parent] and before < k - 1 else at[parent]

    def supplier(k: int) -> int | None:
        up = feeder(k)
        while up is not None and not (current(up) or 0) < 0:
            up = feeder(up)
        return up

    warnings: list[EcatcfgError] = []
    drawn: dict[int, int] = {}
    for k, (name, _, index) in enumerate(line):
        draw = current(k)
        source = supplier(k) if draw is not None and draw > 0 else None
        if draw is None or source is None:
            continue
        budget = -(current(source) or 0)
        before = drawn.get(source, 0)
        drawn[source] = before + draw
        if before <= budget < drawn[source]:
            feeder_name, feeder_device, _ = line[source]
            warnings.append(loaded.error(
                f"E-bus current: the terminals on the E-bus of {feeder_name!r} "
                f"({feeder_device.type_name}) draw {drawn[source]} mA up to slave {name!r}, "
                f"more than the {budget} mA it supplies; add a power feed terminal",
                "slaves", index))
    return warnings
