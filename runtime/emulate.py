"""Emulated slaves from ESI devices: what ``ecatcfg simulate`` and the tests put on a line.

Each device gets its SII image (``esi/sii.py``) and, when it has a mailbox, a mailbox server
(``runtime/mailbox_server.py``) with a server for each protocol the ESI declares that the
emulation speaks: CoE, a runtime object dictionary with an SDO server
(``runtime/objects.py``, ``runtime/sdo_server.py``); EoE, the IP parameter services
(``runtime/eoe_server.py``).  Other protocols get the mailbox error "unsupported protocol".
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ecatcfg.esc import MIN_MAILBOX_SIZE, MODULE_IDENT_LIST, is_pdo_object
from ecatcfg.esi import sii
from ecatcfg.esi.coe import has_coe
from ecatcfg.eni.plan import NetworkPlan, PdoDesc, SlavePlan
from ecatcfg.esi.model import Device, Module, Pdo, PdoEntry, Slots
from ecatcfg.esi.slots import plugged_module, with_modules
from ecatcfg.runtime.segment import Faults, VirtualSegment
from ecatcfg.runtime.slave import EmulatedSlave

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.objects import ObjectDictionary


@dataclass(frozen=True, slots=True)
class SlaveSpec:
    """One slave of a virtual line: its device and how it is told apart."""

    device: Device
    name: str = ""
    serial: int = 0
    alias: int = 0
    # (index, subindex, data) the configuration writes that the dictionary may not have:
    # a modular device from an ENI whose modules cannot be told (see specs_from_eni).
    extra_writes: tuple[tuple[int, int, bytes], ...] = ()


def emulated_slave(spec: SlaveSpec) -> EmulatedSlave:
    dev = spec.device
    od = mailbox = None
    out, inp = (next((s for s in dev.sms if s.type == t), None) for t in ("MBoxOut", "MBoxIn"))
    # The slave's mailbox is the size its SMs get (the rule the ENI and the SII follow).
    sizes = (out.mailbox_size if out else 0, inp.mailbox_size if inp else 0)
    if has_coe(dev):
        from ecatcfg.runtime.objects import ObjectDictionary
        od = ObjectDictionary.from_device(dev)
        esi_cmds = dev.mailbox.coe.init_cmds if dev.mailbox and dev.mailbox.coe else []
        _add_written_objects(od, [(c.index, c.subindex or 0, c.data) for c in esi_cmds
                                  if c.index is not None and c.data is not None
                                  and not c.complete_access] + list(spec.extra_writes))
    # One too small for an SDO (lint ESI204, ESI213): no mailbox server, as such firmware
    # could not answer one either.
    if dev.mailbox is not None and min(sizes) >= MIN_MAILBOX_SIZE:
        from ecatcfg.runtime.mailbox_server import MailboxServer
        mailbox = MailboxServer(*sizes)
        if od is not None:
            from ecatcfg.runtime.sdo_server import SdoServer
            mailbox.coe = SdoServer(od, *sizes)
        if "EoE" in dev.mailbox.protocols:
            from ecatcfg.runtime.eoe_server import EoeServer
            mailbox.eoe = EoeServer(dev.mailbox.eoe, sizes[1])
    image = sii.build(dev, serial=spec.serial, alias=spec.alias)
    return EmulatedSlave(dev, image, name=spec.name, od=od, mailbox=mailbox)


def _add_written_objects(od: ObjectDictionary, writes: list[tuple[int, int, bytes]]) -> None:
    """Objects that startup commands write but the dictionary does not describe: the ESI's
    own CoE InitCmds (Weidmueller UR20-FBC writes 0xF810:01, lint ESI301; the vendor's
    configurator writes it, so the real device has it) and ``SlaveSpec.extra_writes``.
    They are created as writable octets of the written length."""
    from ecatcfg.runtime.objects import OdEntry, OdObject

    for index, sub, data in writes:
        obj = od[index] if index in od else None
        if obj is None:
            obj = od.add(OdObject(index, f"0x{index:04X}", variable=sub == 0))
            if sub:
                obj.add(OdEntry(0, "Number of entries", "USINT", 8, bytes([sub]),
                                access="ro"))
        if sub not in obj.entries:
            obj.add(OdEntry(sub, f"subindex {sub}", "OCTET_STRING", 8 * len(data),
                            bytes(len(data))))
            if sub and not obj.variable and 0 in obj.entries and obj[0].as_int() < sub:
                obj[0].value = bytes([sub])


def segment(specs: list[SlaveSpec], faults: Faults | None = None) -> VirtualSegment:
    """A line of emulated slaves in the order given."""
    return VirtualSegment([emulated_slave(s) for s in specs], faults)


def specs_from_eni(plan: NetworkPlan, library: Library, shown: str) -> list[SlaveSpec]:
    """The slaves an ENI describes (identity and order); their behaviour comes from the
    ESI devices with exactly that vendor, product and revision.  A modular device gets the
    modules of the ENI's module ident list (CoE 0xF030, written in PREOP->SAFEOP) and the
    PDOs the ENI lists for it; when the ENI names no modules (UR20 keeps its idents in
    vendor objects), the objects its startup SDOs write are accepted as they are."""
    from ecatcfg.errors import EcatcfgError

    specs, missing = [], []
    for s in sorted(plan.slaves, key=lambda s: s.position):
        selector = f"0x{s.vendor_id:x}:0x{s.product_code:x}:0x{s.revision:x}"
        try:
            device = library.device(library.find(selector).entry)
        except EcatcfgError as exc:
            missing.append(f"slave {s.name!r} (position {s.position}): {exc.message}")
            continue
        extra: tuple[tuple[int, int, bytes], ...] = ()
        if device.slots is not None:
            device, known = _eni_modules(device, device.slots, s, library.modules_for(
                library.find(selector).entry))
            if not known and s.mailbox is not None:
                # Modules the ENI does not name: accept the objects its startup SDOs write.
                extra = tuple((c.index, c.subindex, c.data) for c in s.mailbox.coe_init_cmds
                              if not c.complete_access and not is_pdo_object(c.index))
        specs.append(SlaveSpec(device, s.name, serial=s.serial_no, extra_writes=extra))
    if missing:
        raise EcatcfgError(f"{shown}: no ESI for " + "; ".join(missing))
    return specs


# -- modular devices --------------------------------------------------------------------------

def _eni_modules(device: Device, slots: Slots, slave: SlavePlan,
                 library_modules: dict[int, Module]) -> tuple[Device, bool]:
    """A modular device as an ENI configures it: the modules named by its 0xF030 InitCmds
    (one subindex per slot, or the whole list with CompleteAccess) bring their dictionaries;
    the PDOs are the ENI's."""
    idents: dict[int, int] = {}
    coe = slave.mailbox.coe_init_cmds if slave.mailbox else []
    for cmd in coe:
        if cmd.index != MODULE_IDENT_LIST or not cmd.data:
            continue
        if cmd.complete_access:              # count, pad byte, then one u32 per slot
            words = cmd.data[2:] if cmd.subindex == 0 else cmd.data
            for n in range(len(words) // 4):
                idents[n + 1] = int.from_bytes(words[4 * n:4 * n + 4], "little")
        elif cmd.subindex and len(cmd.data) >= 4:
            idents[cmd.subindex] = int.from_bytes(cmd.data[:4], "little")
    plugged = [plugged_module(device, n, library_modules[ident])
               for n, ident in sorted(idents.items())
               if 1 <= n <= len(slots.slots) and ident in library_modules]
    device = with_modules(device, plugged)
    if slave.process_data is not None and slave.process_data.pdos:
        device = _with_eni_pdos(device, slave.process_data.pdos)
    return device, bool(plugged)


def _with_eni_pdos(device: Device, pdos: list[PdoDesc]) -> Device:
    """The ENI's PDO list as the device's own (module PDOs included)."""
    rx: list[Pdo] = []
    tx: list[Pdo] = []
    for p in pdos:
        entries = [PdoEntry(e.index, e.subindex, e.bit_len, e.data_type, {1033: e.name},
                            device.source) for e in p.entries]
        pdo = Pdo(p.direction, p.index, {1033: p.name}, device.source, sm=p.sm,
                  fixed=p.fixed, mandatory=p.mandatory, virtual=p.virtual,
                  excludes=list(p.excludes), entries=entries)
        (rx if p.direction == "rx" else tx).append(pdo)
    return replace(device, rx_pdos=rx, tx_pdos=tx)
