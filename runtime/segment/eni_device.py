"""A device described by an ENI alone: what the virtual segment emulates when no ESI is at
hand for a slave.

An ENI says most of what an emulated slave needs (ETG.2100 ``Config/Slave``): the identity
(``Info``), the mailbox areas and protocols (``Mailbox``), the process data with its
SyncManagers and PDOs (``ProcessData``), and, in its InitCmds, the exact register images
the master writes (SyncManagers 0x0800+8n, FMMUs 0x0600+16n, DC activation 0x0980) and the
CoE objects it downloads.  :func:`device_from_eni` turns that into an ESI model
:class:`~ecatcfg.esi.model.Device`, so that the SII image, the object dictionary and the
emulated ESC are built exactly as for a device read from an ESI file:

- SyncManagers: the mailbox areas, the ``ProcessData/Sm`` settings, and the SM registers
  the InitCmds write (the length of a process-data SM is the one written in PREOP->SAFEOP;
  an SM enabled only in SAFEOP->OP is ``OpOnly``); the direction is the data's
  (``ProcessData/Sm`` Type, else the FMMUs over it), so a control byte written the other
  way is refused as a slave refuses it;
- FMMUs: the types of the FMMUs the InitCmds configure;
- PDOs: the ENI's PDOs; the default assignment (0x1C1n and the SII PDO categories) is the
  final value of the ENI's CoE assignment downloads, else ``ProcessData/Sm/Pdo``, else the
  PDOs' ``Sm`` attribute.  A PDO the ENI assigns without describing it gets its mapping
  from the ENI's mapping downloads, else the slave's process-image variables (as gap
  entries: the ENI names no objects for them), padded to the SM length the ENI writes;
  one that ``ProcessData/Sm``, where it lists PDOs, does not name either (an assignment
  download of 0x16FF beside a described 0x1600) does not exist on the device;
- mailbox: the protocols of ``Mailbox/Protocol``; CoE flags from what the InitCmds do
  (PDO assignment, PDO configuration, complete access); EoE with IP parameters; SoE
  drives with the IDNs the ENI's SoE InitCmds write (those of PS required before SAFEOP,
  ``soe_server.py``), as many drives as the highest drive number they address;
- DC: an op mode with the activation the ENI writes to 0x0980 and its SYNC0 cycle;
- SII configuration area: the value an InitCmd checks at 0x0140, else a slave without a
  mailbox runs in ESC device emulation (0x0141 bit 0), as every such device in the
  vendors' files does (with a digital I/O PDI when it has process data); one with a
  mailbox has firmware.

What an ENI cannot say (object names and types beyond the written data, ESC type and build,
vendor names) takes neutral values; ``runtime/segment/emulate.py`` adds the objects the CoE InitCmds
write, typed by their size.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field

from ecatcfg.esc import (ESC_DC_LATCH_UNIT, ESC_DC_SYNC_UNIT, FMMU_SIZE, RX_PDO_MAPPING,
                         SM1_STATUS, SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES, SM_DIR_MASK, SM_PDO_ASSIGN,
                         SM_PDO_ASSIGN_RANGE, SM_SIZE, TX_PDO_MAPPING, Cmd, FmmuConfig, FmmuType,
                         Reg, SmConfig, Transition, array_downloads)
from ecatcfg.eni.plan import (CoeInitCmd, NetworkPlan, PdoDesc, SlavePlan,
                              register_writes)
from ecatcfg.esi.model import (CoeSettings, Dc, DcOpMode, Device, Eeprom, EoeSettings, Fmmu,
                               Mailbox, Pdo, PdoEntry, Profile, SoeInitCmd, SoeSettings, Source,
                               SyncManager, Vendor)
from ecatcfg.record import replace

# SII configuration area word 0 (PDI control 0x0140, ESC configuration 0x0141) of slaves
# without a mailbox: device emulation, with a digital I/O PDI when they have process data
# (the EL1004 of ethercrab-rs/ethercrab dumps/soem-sdinfo-ek1100-el1004.pcapng reads
# 0x0104), without a PDI otherwise (its EK1100 reads 0x00 at 0x0140); a 16-bit asynchronous
# microcontroller PDI for slaves with a mailbox (firmware).
CONFIG_DEVICE_EMULATION = 0x0104
CONFIG_NO_PDI = 0x0100
CONFIG_FIRMWARE = 0x0008
# SII word 0 bits 10 and 11 (0x0141 bits 2 and 3): the DC SYNC output and latch input units
# enabled, as an EK1100's 0x0D00 has them.
CONFIG_DC_UNITS = (ESC_DC_SYNC_UNIT | ESC_DC_LATCH_UNIT) << 8
_MAX_ENTRY_BITS = 0xFF              # a mapping entry's length field (one byte)
_LANGUAGE = 1033


@dataclass(frozen=True, slots=True)
class _SmWrite:
    config: SmConfig
    transitions: frozenset[Transition]


@dataclass(slots=True)
class _Coe:
    """The ENI's CoE downloads to the PDO objects, and what they tell of the device."""

    writes: dict[int, list[tuple[int, bytes, bool]]] = field(default_factory=dict)
    assigns: bool = False
    configures: bool = False
    complete_access: bool = False

    def entries(self, index: int) -> list[int] | None:
        """Subindex 1..n of ``index`` after the downloads (n = subindex 0), or None if
        subindex 0 was never written."""
        size = 2 if index in SM_PDO_ASSIGN_RANGE else 4
        count, values = array_downloads(self.writes.get(index, []), size)
        return None if count is None else [values.get(s, 0) for s in range(1, count + 1)]


def device_from_eni(slave: SlavePlan, plan: NetworkPlan, file: str) -> Device:
    """The device ``slave`` of ``plan`` describes (``file`` names the ENI in the model's
    sources)."""
    source = Source(file, 0)
    if slave.mailbox is not None and not (slave.mailbox.send.length
                                          and slave.mailbox.recv.length):
        # Mailbox areas of length 0 (Beremiz's EtherLab-plugin file gives every slave
        # one, couplers too) carry nothing: the device the ENI describes has no mailbox.
        slave = replace(slave, mailbox=None)
    coe = _coe_downloads(slave.mailbox.coe_init_cmds if slave.mailbox else [])
    sms = _sync_managers(slave, source)
    pdos = _pdos(slave, plan, sms, coe, source)
    mailbox = _mailbox(slave, coe, source)
    dc = _dc(slave, source)
    boot = None
    if slave.mailbox is not None and slave.mailbox.bootstrap_send is not None \
            and slave.mailbox.bootstrap_recv is not None:
        b_out, b_in = slave.mailbox.bootstrap_send, slave.mailbox.bootstrap_recv
        boot = struct.pack("<4H", b_out.start, b_out.length, b_in.start, b_in.length)
    config = _checked_config(slave)
    if config is None:
        config = (CONFIG_FIRMWARE if slave.mailbox is not None
                  else CONFIG_DEVICE_EMULATION if any(sm.type in ("Outputs", "Inputs")
                                                      for sm in sms)
                  else CONFIG_NO_PDI)
        if dc is not None:
            # The ENI runs the slave's DC unit: its ESC configuration enables it (the rule
            # runtime/segment/esc_chips.py reads back).
            config |= CONFIG_DC_UNITS
    profiles = [Profile(source, profile_no=no) for no, _ in
                (slave.mailbox.coe_profiles if slave.mailbox else [])[:1]]
    return Device(
        type_name=type_name(slave.name), product_code=slave.product_code,
        revision=slave.revision, names={_LANGUAGE: slave.name}, source=source,
        vendor=Vendor(slave.vendor_id, {}, source), physics=slave.physics or "YY",
        fmmus=_fmmus(slave, sms, source), sms=sms,
        rx_pdos=[p for p in pdos if p.direction == "rx"],
        tx_pdos=[p for p in pdos if p.direction == "tx"],
        mailbox=mailbox, dc=dc,
        eeprom=Eeprom(source, config_data=struct.pack("<H", config), boot_strap=boot),
        profiles=profiles)


def type_name(name: str) -> str:
    """The device's order name as configurators write it into the slave's name: TwinCAT's
    "Term 2 (EL2008)", EC-Engineer's "Slave_1002 [54632]"; else the name itself."""
    found = re.search(r"[(\[]\s*([^()\[\]]+?)\s*[)\]]\s*$", name)
    return found.group(1) if found else name


# -- what the InitCmds write ------------------------------------------------------------------

def _sm_writes(slave: SlavePlan) -> dict[int, list[_SmWrite]]:
    return {n: [_SmWrite(SmConfig.from_bytes(data), t) for data, t in records]
            for n, records in register_writes(slave, Reg.SM0, SM_SIZE, 8).items()}


def _enabling(writes: list[_SmWrite]) -> _SmWrite | None:
    """The write that configures the SM for operation: enabled, for INIT->PREOP or a later
    transition up (not the bootstrap mailbox of INIT->BOOT)."""
    ups = (Transition.IP, Transition.PS, Transition.SO)
    for want in ups:
        for w in writes:
            if w.config.enable and want in w.transitions:
                return w
    return None


def _configuring(writes: list[_SmWrite]) -> _SmWrite | None:
    """The write that sets a process-data SM up for SAFEOP (PREOP->SAFEOP, else
    SAFEOP->OP), enabled or not; the clearing writes of INIT->PREOP are not one."""
    for want in (Transition.PS, Transition.SO):
        for w in writes:
            if want in w.transitions:
                return w
    return None


def _checked_config(slave: SlavePlan) -> int | None:
    """The PDI control and ESC configuration (0x0140-0x0141, loaded from SII word 0) when
    the ENI checks them: EtherCAT Automation Studio's "check PDI" InitCmd reads 0x0140 and
    expects the device's value."""
    for cmd in slave.init_cmds:
        v = cmd.validate
        if cmd.cmd in (Cmd.APRD, Cmd.FPRD) and cmd.ado == Reg.PDI_CONTROL and v is not None \
                and len(v.data) >= 2 and (v.mask is None or v.mask[:2] == b"\xff\xff"):
            return int.from_bytes(v.data[:2], "little")
    return None


# -- SyncManagers and FMMUs -------------------------------------------------------------------

def _sync_managers(slave: SlavePlan, source: Source) -> list[SyncManager]:
    writes = _sm_writes(slave)
    sms: dict[int, SyncManager] = {}
    mbx = slave.mailbox
    if mbx is not None:
        for kind, area, default_number in (("MBoxOut", mbx.send, 0), ("MBoxIn", mbx.recv, 1)):
            number = next((n for n, ws in sorted(writes.items())
                           if (w := _enabling(ws)) is not None and Transition.IP in w.transitions
                           and w.config.start == area.start), default_number)
            w = _enabling(writes.get(number, []))
            sms[number] = SyncManager(number, kind, source, start_address=area.start,
                                      control_byte=w.config.control if w else None,
                                      default_size=area.length, enable=1)
    settings = {s.number: s for s in (slave.process_data.sms if slave.process_data else [])}
    for number in sorted(set(settings) | set(writes)):
        if number in sms:
            continue
        setting = settings.get(number)
        w = _enabling(writes.get(number, []))
        if setting is None and w is None:
            continue                        # only ever cleared: not in use
        control = w.config.control if w else (setting.control_byte if setting else 0)
        kind = setting.type if setting and setting.type in ("Outputs", "Inputs") else \
            _fmmu_kind(slave, w.config.start if w else None) or (
                "Outputs" if control & SM_DIR_MASK == SM_DIR_ECAT_WRITES else "Inputs")
        # The device's direction is its data's (ProcessData/Sm Type, else the FMMU over it),
        # not whatever the InitCmds write: a write that says otherwise is refused as a real
        # slave refuses it (0x001D/0x001E, runtime/segment/al_checks.py).
        control = control & ~SM_DIR_MASK | (SM_DIR_ECAT_WRITES if kind == "Outputs"
                                            else SM_DIR_ECAT_READS)
        op_only = w is not None and Transition.SO in w.transitions \
            and Transition.PS not in w.transitions
        # The length the ENI configures, also for an SM it leaves disabled (an EL3692
        # whose outputs the ENI unassigns: SM2 written with length 0 in PREOP->SAFEOP,
        # where the ESI's default, 4, stays in ProcessData/Sm2/DefaultSize).  A master
        # that sizes an SM from the SII when its assignment maps nothing (SOEM keeps the
        # SII length) then finds what the ENI set, and so does its 0x1C1n.
        written = w or _configuring(writes.get(number, []))
        sms[number] = SyncManager(
            number, kind, source,
            start_address=w.config.start if w else setting.start_address if setting else 0,
            control_byte=control,
            default_size=written.config.length if written else setting.default_size
            if setting else None,
            enable=1 if (w is not None or (setting is not None and setting.enable)) else 0,
            op_only=op_only, virtual=bool(setting and setting.virtual))
    top = max(sms, default=-1)
    # The SII's SYNCM category and 0x1C00 list SMs by position: unused numbers stay empty.
    return [sms.get(n) or SyncManager(n, None, source) for n in range(top + 1)]


def _fmmu_kind(slave: SlavePlan, start: int | None) -> str | None:
    """Outputs or Inputs: the direction of the FMMUs the InitCmds set over physical
    ``start`` (all of one direction), else None."""
    if start is None:
        return None
    kinds = {FmmuConfig.from_bytes(data).type
             for records in register_writes(slave, Reg.FMMU0, FMMU_SIZE, 8).values()
             for data, _ in records
             if (cfg := FmmuConfig.from_bytes(data)).active and cfg.length
             and cfg.physical_start <= start < cfg.physical_start + cfg.length}
    return ("Outputs" if kinds == {FmmuType.WRITE} else "Inputs" if kinds == {FmmuType.READ}
            else None)


def _fmmus(slave: SlavePlan, sms: list[SyncManager], source: Source) -> list[Fmmu]:
    """One FMMU per register set the InitCmds configure, typed by what it maps: the SM1
    status byte (the mailbox state), else its direction.  A direction the SMs carry but no
    FMMU write shows (an ENI whose FMMU settings the reader refused) takes the first free
    FMMU."""
    fmmus: dict[int, str] = {}
    for n, records in register_writes(slave, Reg.FMMU0, FMMU_SIZE, 8).items():
        for data, _ in records:
            cfg = FmmuConfig.from_bytes(data)
            if not cfg.active or cfg.type == FmmuType.UNUSED:
                continue
            fmmus[n] = ("MBoxState" if cfg.physical_start == SM1_STATUS
                        else "Outputs" if cfg.type & FmmuType.WRITE else "Inputs")
            break
    for kind in ("Outputs", "Inputs"):
        if any(sm.type == kind for sm in sms) and kind not in fmmus.values():
            fmmus[next(n for n in range(8) if n not in fmmus)] = kind
    top = max(fmmus, default=-1)
    return [Fmmu(n, fmmus.get(n), source) for n in range(top + 1)]


# -- PDOs -------------------------------------------------------------------------------------

def _coe_downloads(cmds: list[CoeInitCmd]) -> _Coe:
    """The ENI's downloads to the PDO assignment and mapping objects, in order (their
    values: :meth:`_Coe.entries`)."""
    coe = _Coe()
    for cmd in cmds:
        if cmd.disabled or cmd.ccs != 1:
            continue
        coe.complete_access |= cmd.complete_access
        index = cmd.index
        if index in SM_PDO_ASSIGN_RANGE:
            coe.assigns = True
        elif index in RX_PDO_MAPPING or index in TX_PDO_MAPPING:
            coe.configures = True
        else:
            continue
        coe.writes.setdefault(index, []).append((cmd.subindex, cmd.data, cmd.complete_access))
    return coe


def _pdos(slave: SlavePlan, plan: NetworkPlan, sms: list[SyncManager], coe: _Coe,
          source: Source) -> list[Pdo]:
    described = {p.index: p for p in (slave.process_data.pdos if slave.process_data else [])}
    assigned = _assignment(slave, sms, coe)
    pdos: list[Pdo] = []
    for desc in described.values():
        sm = next((n for n, indices in assigned.items() if desc.index in indices), None)
        pdos.append(_pdo(desc, sm, source))
    settings = {s.number: s for s in (slave.process_data.sms if slave.process_data else [])}
    for n, indices in assigned.items():
        # A PDO the CoE downloads assign that ProcessData/Sm, where it lists PDOs, does not
        # name is one the ENI knows nothing of (0x16FF for 0x1600): the device has none,
        # and refuses SAFEOP as a real one would (0x001D/0x001E).
        listed = settings[n].pdos if n in settings else []
        missing = [i for i in indices if i not in described and (not listed or i in listed)]
        for index in missing:
            pdos.append(Pdo("rx" if sms[n].type == "Outputs" else "tx", index,
                            {_LANGUAGE: f"PDO 0x{index:04X}"}, source, sm=n,
                            entries=_written_mapping(coe, index, source)))
        if missing:
            _fill(pdos, n, missing[0], sms[n], slave, plan, source)
    return pdos


def _pdo(desc: PdoDesc, sm: int | None, source: Source) -> Pdo:
    entries = [PdoEntry(e.index, e.subindex, e.bit_len, e.data_type, {_LANGUAGE: e.name},
                        source) for e in desc.entries]
    # ``Virtual`` (ETG.2000 Pdo@Virtual, copied by TwinCAT from the ESI: an EL6695 bridge's
    # "IO Outputs") says the master chooses the mapping, so an ESI device does not assign
    # the PDO by default.  The ENI holds that choice: a virtual PDO it assigns has the
    # entries it lists and is in the device's assignment, as on the configured device that
    # SOEM, reading 0x1C1n and the mapping, sizes the SMs from.
    return Pdo(desc.direction, desc.index, {_LANGUAGE: desc.name}, source, sm=sm,
               fixed=desc.fixed, mandatory=desc.mandatory,
               virtual=desc.virtual and sm is None,
               excludes=list(desc.excludes), entries=entries)


def _assignment(slave: SlavePlan, sms: list[SyncManager], coe: _Coe) -> dict[int, list[int]]:
    """The PDOs of each process-data SM after the ENI's configuration."""
    settings = {s.number: s for s in (slave.process_data.sms if slave.process_data else [])}
    descs = slave.process_data.pdos if slave.process_data else []
    out: dict[int, list[int]] = {}
    for sm in sms:
        if sm.type not in ("Outputs", "Inputs"):
            continue
        written = coe.entries(SM_PDO_ASSIGN + sm.number)
        if written is not None:
            out[sm.number] = [i for i in written if i]
        elif sm.number in settings and settings[sm.number].pdos:
            out[sm.number] = list(settings[sm.number].pdos)
        else:
            out[sm.number] = [p.index for p in descs if p.sm == sm.number]
    return out


def _written_mapping(coe: _Coe, index: int, source: Source) -> list[PdoEntry]:
    values = coe.entries(index) or []
    return [PdoEntry(v >> 16, v >> 8 & 0xFF, v & 0xFF, None, {}, source) for v in values]


def _fill(pdos: list[Pdo], sm_number: int, index: int, sm: SyncManager, slave: SlavePlan,
          plan: NetworkPlan, source: Source) -> None:
    """Give PDO ``index`` (assigned, not described) entries that bring the SM's PDOs to
    the length the ENI configures: the slave's process-image variables in that range, as
    gap entries, then padding."""
    have = sum(sum(e.bit_len or 0 for e in p.entries) for p in pdos if p.sm == sm_number)
    want = 8 * (sm.default_size or 0)
    if have >= want:
        return
    pdo = next(p for p in pdos if p.index == index and p.sm == sm_number)
    image = plan.process_image.outputs if sm.type == "Outputs" else plan.process_image.inputs
    ranges = (slave.process_data.send if sm.type == "Outputs" else slave.process_data.recv) \
        if slave.process_data else []
    bits = want - have
    for var in sorted(image, key=lambda v: v.bit_offs):
        if not any(r.bit_start <= var.bit_offs and var.bit_offs + var.bit_size
                   <= r.bit_start + r.bit_length for r in ranges):
            continue
        if var.bit_size > min(bits, _MAX_ENTRY_BITS):
            break
        pdo.entries.append(PdoEntry(0, 0, var.bit_size, var.data_type,
                                    {_LANGUAGE: var.name}, source))
        bits -= var.bit_size
    while bits > 0:
        step = min(bits, 8 * (_MAX_ENTRY_BITS // 8))
        pdo.entries.append(PdoEntry(0, 0, step, None, {}, source))
        bits -= step


# -- mailbox and DC ---------------------------------------------------------------------------

def _mailbox(slave: SlavePlan, coe: _Coe, source: Source) -> Mailbox | None:
    mbx = slave.mailbox
    if mbx is None:
        return None
    protocols = list(dict.fromkeys(mbx.protocols))
    settings = None
    if "CoE" in protocols:
        settings = CoeSettings(source, pdo_assign=coe.assigns,
                               pdo_config=coe.configures,
                               complete_access=coe.complete_access)
    eoe = EoeSettings(source, ip=True) if "EoE" in protocols else None
    soe = None
    if "SoE" in protocols:
        cmds = [SoeInitCmd([t.value for t in c.transitions], c.idn, c.data, source,
                           channel=c.drive_no) for c in mbx.soe_init_cmds]
        soe = SoeSettings(source, cmds, channel_count=1 + max((c.channel for c in cmds),
                                                              default=0))
    return Mailbox(protocols, source, coe=settings, data_link_layer=bool(mbx.data_link_layer),
                   eoe=eoe, soe=soe)


def _dc(slave: SlavePlan, source: Source) -> Dc | None:
    """The DC mode the ENI runs the slave in: the activation it writes to 0x0980-0x0981
    (cyclic unit and SYNC outputs) and its cycle times."""
    activation = None
    for data, _ in register_writes(slave, Reg.DC_CYCLIC_UNIT_CONTROL, 2, 1).get(0, []):
        value = int.from_bytes(data, "little")
        if value:
            activation = value
    if slave.dc is None and activation is None:
        return None
    dc = slave.dc
    modes = [DcOpMode("Free Run", source, desc="no distributed clock", assign_activate=0)]
    modes.append(DcOpMode("DC", source, desc="DC as the ENI configures it",
                          assign_activate=activation or 0,
                          cycle_time_sync0=dc.cycle_time0 if dc else None,
                          shift_time_sync0=dc.shift_time if dc else None,
                          cycle_time_sync1=dc.cycle_time1 if dc else None))
    return Dc(modes, source)
