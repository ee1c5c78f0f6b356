"""Emulated slaves from ESI devices: what ``ecatcfg simulate`` and the tests put on a line.

Each device gets its SII image (``esi/sii.py``) and, when it has a mailbox, a mailbox server
(``runtime/segment/mailbox_server.py``) with a server for each protocol the ESI declares that the
emulation speaks: CoE, a runtime object dictionary with an SDO server
(``runtime/segment/objects.py``, ``runtime/segment/sdo_server.py``); EoE, the IP parameter services
(``runtime/segment/eoe_server.py``); SoE, the drives' IDNs and the ones they require before
SAFEOP (``runtime/segment/soe_server.py``); FoE, files and firmware
(``runtime/segment/foe_server.py``), in BOOT over the bootstrap mailbox of the SII.  Other protocols get the mailbox error "unsupported protocol".
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ecatcfg.esc import (DETECTED_MODULE_IDENT_LIST, MIN_MAILBOX_SIZE, MODULE_IDENT_LIST,
                         Cmd, Reg, is_pdo_object)
from ecatcfg.esi import sii
from ecatcfg.esi.coe import dictionary_with_objects, has_coe
from ecatcfg.eni.plan import NetworkPlan, PdoDesc, SlavePlan
from ecatcfg.esi.model import Device, Module, Pdo, PdoEntry, Slots
from ecatcfg.esi.slots import ident_list_from_writes, plug_positions, with_modules
from ecatcfg.runtime.segment.esc_chips import chip_for, chip_of
from ecatcfg.runtime.segment.virtual import Faults, VirtualSegment
from ecatcfg.runtime.segment.slave import EmulatedSlave
from ecatcfg.runtime.wiring import Plug, Wiring, eni_plugs

if TYPE_CHECKING:
    from collections.abc import Callable

    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment.dc_clock import DcModel
    from ecatcfg.runtime.segment.mailbox_server import MailboxServer
    from ecatcfg.runtime.segment.objects import ObjectDictionary
    from ecatcfg.runtime.segment.timing import Timing


@dataclass(frozen=True, slots=True)
class SlaveSpec:
    """One slave of a virtual line: its device and how it is told apart."""

    device: Device
    name: str = ""
    serial: int = 0
    alias: int = 0
    device_id: int | None = None    # an ID switch (ETG.1020 explicit device identification)
    # Downloads the configuration makes that the dictionary may not have: a modular device
    # from an ENI whose modules cannot be told, a device from the ENI alone (specs_from_eni).
    extra_writes: tuple[Write, ...] = ()
    # Emulated from the ENI alone (no ESI device): why, e.g. "no device 0x2:0x... in the
    # library"; None for a device from an ESI file.
    eni_only: str | None = None
    # Where its port 0 is plugged: a port of an earlier slave (index into the list of
    # specs).  None: port 1 of the slave before it (a line), the master for the first.
    plug: Plug | None = None
    # Which of several ESI descriptions of its identity it behaves as, and why (the one that
    # agrees with the ENI: esi/library.py ``find(..., evidence=...)``); None when its
    # identity has one description.
    esi_choice: str | None = None


@dataclass(frozen=True, slots=True)
class Write:
    """A CoE download the configuration makes: the emulated dictionary must hold its
    object."""

    index: int
    subindex: int
    data: bytes
    complete_access: bool = False


def _add_foe(mailbox: MailboxServer, image: bytes) -> None:
    """An FoE server (``runtime/segment/foe_server.py``), with the bootstrap mailbox the
    SII image gives (words 0x14-0x17: receive offset, size, send offset, size; ETG.2010)
    for BOOT."""
    import struct

    from ecatcfg.esc import SII_BOOTSTRAP_MAILBOX, SII_VENDOR_ID
    from ecatcfg.runtime.segment.foe_server import FoeServer

    # The firmware knows its identity: the one its SII holds (words 0x08, 0x0A).
    vendor, product = struct.unpack_from("<II", image, 2 * SII_VENDOR_ID)
    _rx, rx_size, _tx, tx_size = struct.unpack_from("<4H", image, 2 * SII_BOOTSTRAP_MAILBOX)
    boot = rx_size >= MIN_MAILBOX_SIZE and tx_size >= MIN_MAILBOX_SIZE
    mailbox.foe = FoeServer(vendor, product, bootstrap=boot)
    mailbox.boot_sizes = (rx_size, tx_size) if boot else None


def emulated_slave(spec: SlaveSpec) -> EmulatedSlave:
    dev = spec.device
    od = mailbox = None
    out, inp = (next((s for s in dev.sms if s.type == t), None) for t in ("MBoxOut", "MBoxIn"))
    # The slave's mailbox is the size its SMs get (the rule the ENI and the SII follow).
    sizes = (out.mailbox_size if out else 0, inp.mailbox_size if inp else 0)
    if has_coe(dev):
        from ecatcfg.runtime.segment.objects import ObjectDictionary
        od = ObjectDictionary.from_device(dev)
        esi_cmds = dev.mailbox.coe.init_cmds if dev.mailbox and dev.mailbox.coe else []
        _add_written_objects(od, [Write(c.index, c.subindex or 0, c.data, c.complete_access)
                                  for c in esi_cmds
                                  if c.index is not None and c.data is not None]
                             + list(spec.extra_writes))
        if dev.plugged:
            _detected_modules(od, list(dev.plugged))
    # One too small for an SDO (lint ESI204, ESI213): no mailbox server, as such firmware
    # could not answer one either.
    if dev.mailbox is not None and min(sizes) >= MIN_MAILBOX_SIZE:
        from ecatcfg.runtime.segment.mailbox_server import MailboxServer
        mailbox = MailboxServer(*sizes)
        if od is not None:
            from ecatcfg.runtime.segment.sdo_server import SdoServer
            coe = dev.mailbox.coe
            # SDO Information only where the ESI says the device has it (CoE@SdoInfo).
            mailbox.coe = SdoServer(od, *sizes, sdo_info=coe is not None and coe.sdo_info)
        if "EoE" in dev.mailbox.protocols:
            from ecatcfg.runtime.segment.eoe_server import EoeServer
            mailbox.eoe = EoeServer(dev.mailbox.eoe, sizes[1])
        if "SoE" in dev.mailbox.protocols:
            from ecatcfg.runtime.segment.soe_server import SoeServer
            mailbox.soe = SoeServer(dev.mailbox.soe, sizes[1])
    image = sii.build(dev, serial=spec.serial, alias=spec.alias)
    if mailbox is not None and dev.mailbox is not None and "FoE" in dev.mailbox.protocols:
        _add_foe(mailbox, image)
    slave = EmulatedSlave(dev, image, name=spec.name, od=od, mailbox=mailbox,
                          chip=chip_of(dev, chip_for(dev.vendor.id, dev.product_code)),
                          device_id=spec.device_id)
    slave.eni_only = spec.eni_only
    return slave


def _add_written_objects(od: ObjectDictionary, writes: list[Write]) -> None:
    """Objects that startup commands write but the dictionary does not describe: the ESI's
    own CoE InitCmds (Weidmueller UR20-FBC writes 0xF810:01, lint ESI301; the vendor's
    configurator writes it, so the real device has it) and ``SlaveSpec.extra_writes``.

    Each is created writable in every mailbox state, typed by the data written: 1, 2, 4 or
    8 bytes as an unsigned number of that size, other lengths as an octet string of that
    length, and an entry written with several lengths as a variable-length one.  A complete
    access to an object not described splits its data into equal entries after subindex 0
    (which travels in a 16-bit slot, ETG.1000.6 complete access); one from subindex 1
    (ETG.1000.6 allows 0 or 1; TwinCAT writes a terminal's settings record that way)
    carries no count, so its data becomes one octet-string entry, subindex 1, that a
    complete access from subindex 1 writes and reads back whole (our choice: nothing says
    how the bytes split into entries)."""
    from ecatcfg.runtime.segment.od_entries import OdEntry, OdObject

    sizes: dict[tuple[int, int], set[int]] = {}
    for w in writes:
        if w.index in od and not w.complete_access and w.subindex in od[w.index].entries:
            continue
        if w.complete_access:
            if w.index in od or w.subindex > 1 or len(w.data) < 2 - w.subindex:
                continue
            if w.subindex == 1:
                sizes.setdefault((w.index, 1), set()).add(len(w.data))
                sizes.setdefault((w.index, 0), set()).add(1)
                continue
            count, body = w.data[0], w.data[2:]
            if count and len(body) % count == 0:
                for sub in range(1, count + 1):
                    sizes.setdefault((w.index, sub), set()).add(len(body) // count)
            sizes.setdefault((w.index, 0), set()).add(1)
        else:
            sizes.setdefault((w.index, w.subindex), set()).add(len(w.data))
    for (index, sub), lengths in sorted(sizes.items()):
        obj = od[index] if index in od else None
        if obj is None:
            has_subs = any(i == index and s for i, s in sizes)
            obj = od.add(OdObject(index, f"0x{index:04X}", variable=not has_subs))
            if has_subs and (index, 0) not in sizes:
                obj.add(OdEntry(0, "Number of entries", "USINT", 8, b"\0", access="ro"))
        if sub in obj.entries:
            continue
        size = max(lengths)
        kind = _NUMBER_TYPES.get(size, "OCTET_STRING") if len(lengths) == 1 \
            else "OCTET_STRING"
        bits = 8 * size if len(lengths) == 1 else 0
        obj.add(OdEntry(sub, f"subindex {sub}", kind, bits, bytes(size if bits else 0)))
        if sub and not obj.variable and 0 in obj.entries and obj[0].as_int() < sub:
            obj[0].value = bytes([sub])


def _detected_modules(od: ObjectDictionary, idents: list[int]) -> None:
    """The station's detected module ident list (0xF050; ETG.5001): the idents of the
    modules plugged, by position, read-only; and room in the configured list (0xF030) the
    master downloads.  Objects the ESI dictionary declares keep their size."""
    from ecatcfg.runtime.segment.od_entries import OdEntry, OdObject

    for index, name, access in ((MODULE_IDENT_LIST, "Configured module ident list", "rw"),
                                (DETECTED_MODULE_IDENT_LIST, "Detected module ident list",
                                 "ro")):
        obj = od[index] if index in od else od.add(OdObject(index, name, variable=False))
        if 0 not in obj.entries:
            obj.add(OdEntry(0, "Number of entries", "USINT", 8, b"\0", access=access))
        # Positions beyond those the ESI lists take the rights of its first one: a device
        # whose ESI declares 0xF030 read-only (a BK1120-style coupler) refuses every
        # download of it with 0x06010002, as the real one does.
        like = obj.entries.get(1)
        for sub in range(1, len(idents) + 1):
            if sub not in obj.entries:
                entry = obj.add(OdEntry(sub, f"SubIndex {sub:03d}", "UDINT", 32, bytes(4),
                                        access=like.access if like else access))
                if like is not None:
                    entry.read_states, entry.write_states = like.read_states, like.write_states
        if index == DETECTED_MODULE_IDENT_LIST:
            obj[0].value = bytes([len(idents)])
            for sub, ident in enumerate(idents, start=1):
                obj[sub].value = ident.to_bytes(4, "little")


# Unsigned CoE types by size: the type of an object known only by the data written to it.
_NUMBER_TYPES = {1: "USINT", 2: "UINT", 4: "UDINT", 8: "ULINT"}


def segment(specs: list[SlaveSpec], faults: Faults | None = None,
            timing: Timing | None = None, *, clock_ns: Callable[[], int] | None = None,
            dc: DcModel | None = None) -> VirtualSegment:
    """The emulated slaves, plugged as their specs say (a line in the order given by
    default); ``timing``: how long they take (``runtime/segment/timing.py``, ``simulate
    --realistic``), none by default; ``clock_ns`` and ``dc`` as for
    :class:`VirtualSegment`."""
    return VirtualSegment([emulated_slave(s) for s in specs], faults, timing=timing,
                          clock_ns=clock_ns, dc=dc, wiring=wiring(specs))


def wiring(specs: list[SlaveSpec]) -> Wiring:
    """The cables the specs describe; ValueError naming the slaves when they cannot be."""
    plugs = [s.plug if s.plug is not None or k == 0 else Plug(k - 1, 1)
             for k, s in enumerate(specs)]
    try:
        return Wiring(plugs)
    except ValueError as exc:
        names = ", ".join(f"{k} = {s.name!r}" for k, s in enumerate(specs))
        raise ValueError(f"{exc} (slaves {names})") from None


def specs_from_eni(plan: NetworkPlan, library: Library | None, shown: str) -> list[SlaveSpec]:
    """The slaves an ENI describes (identity and order).  A slave whose vendor, product and
    revision the ESI ``library`` holds behaves as that device: a modular device gets the
    modules of the ENI's module ident list (CoE 0xF030, written in PREOP->SAFEOP) and the
    PDOs the ENI lists for it; when the ENI names no modules (UR20 keeps its idents in
    vendor objects), the objects its startup SDOs write are accepted as they are.  Any
    other slave (and every slave without a library) is emulated from the ENI alone
    (``runtime/segment/eni_device.py``), with the objects its CoE InitCmds write; its spec says why
    (``eni_only``).  Where several ESI files describe a slave's identity differently, the
    one whose PDOs, SyncManagers and mailbox agree with the ENI's slave is taken
    (``eni/evidence.py``; ``esi_choice`` says which and why), and none or several agreeing
    is an error naming the files and what differs.  ``shown`` names the ENI in the model's
    sources.  The plan's passive
    slaves (``NetworkPlan.passive``: no ESC) are not among ``plan.slaves``: nothing answers
    for them on the wire, so nothing emulates them."""
    from ecatcfg.eni.evidence import EniSlaveEvidence
    from ecatcfg.esi.library import DuplicateError, SelectorError
    from ecatcfg.runtime.segment.eni_device import device_from_eni

    specs: list[SlaveSpec] = []
    ordered = sorted(plan.slaves, key=lambda s: s.position)
    plugs = eni_plugs(ordered, shown)
    for s in ordered:
        selector = f"0x{s.vendor_id:x}:0x{s.product_code:x}:0x{s.revision:x}"
        coe = s.mailbox.coe_init_cmds if s.mailbox else []
        alias, device_id = _head_identification(s)
        try:
            if library is None:
                raise SelectorError("no ESI files given")
            found = library.find(selector, evidence=EniSlaveEvidence(s, shown))
            entry = found.entry
        except DuplicateError as exc:
            # Files that describe the device differently, and the ENI does not tell which
            # it was configured with: emulating either, or the ENI alone, would hide the
            # choice.
            from ecatcfg.errors import EcatcfgError
            raise EcatcfgError(f"slave {s.name!r}: {exc.message}", shown) from None
        except SelectorError as exc:
            # The objects the ENI writes exist on the device, and so do those it reads
            # (Ccs 2, an upload, typed by the data it gives: SOEM's sample ENI reads
            # 0x1C13 of a device it describes no process data for).
            writes = tuple(Write(c.index, c.subindex, c.data, c.complete_access)
                           for c in coe if not c.disabled
                           and (c.ccs == 1 or c.ccs == 2 and c.data))
            specs.append(SlaveSpec(device_from_eni(s, plan, shown), s.name,
                                   serial=s.serial_no, alias=alias, device_id=device_id,
                                   extra_writes=writes,
                                   eni_only=exc.message, plug=plugs[len(specs)]))
            continue
        device = library.device(entry)     # a broken ESI file is an error, not a fallback
        extra: tuple[Write, ...] = ()
        if device.slots is not None:
            device, known = _eni_modules(device, device.slots, s, library.modules_for(entry))
            if not known:
                # Modules the ENI does not name: accept the objects its startup SDOs write.
                extra = tuple(Write(c.index, c.subindex, c.data) for c in coe
                              if not c.complete_access and not is_pdo_object(c.index))
        elif has_coe(device) and dictionary_with_objects(device) is None:
            # An ESI without an object dictionary says nothing of the objects the device
            # has: it takes what the ENI's CoE InitCmds write, as a slave from the ENI alone.
            extra = tuple(Write(c.index, c.subindex, c.data, c.complete_access) for c in coe
                          if not c.disabled and c.ccs == 1 and not is_pdo_object(c.index))
        specs.append(SlaveSpec(device, s.name, serial=s.serial_no, alias=alias,
                               device_id=device_id, extra_writes=extra,
                               plug=plugs[len(specs)], esi_choice=found.preferred))
    try:
        wiring(specs)
    except ValueError as exc:
        from ecatcfg.errors import EcatcfgError
        raise EcatcfgError(f"{shown}: PreviousPort: {exc}") from None
    return specs


def _head_identification(slave: SlavePlan) -> tuple[int, int | None]:
    """The station alias and the device ID a hot-connect group's head is identified by
    (what its IdentifyCmds expect to read: 0x0012; the ID in AL status code 0x0134 after
    the ETG.1020 request, or at the ID address the device's ESI names): the emulated head
    has them, as the real one was given them; (0, None) for any other slave, but for the
    alias an InitCmd checks at 0x0012 (compile's check of a slave given an ``alias:``, as
    an IgH user's slave addressed alias:position was given it)."""
    alias, device_id = 0, None
    for cmd in slave.init_cmds:
        want = cmd.validate.data if cmd.validate is not None else b""
        if cmd.cmd in (Cmd.APRD, Cmd.FPRD) and cmd.ado == Reg.STATION_ALIAS \
                and len(want) >= 2:
            alias = int.from_bytes(want[:2], "little")
    group = slave.hot_connect
    for cmd in group.identify_cmds if group is not None else []:
        want = cmd.validate.data if cmd.validate is not None else b""
        if cmd.ado == Reg.STATION_ALIAS and len(want) >= 2:
            alias = int.from_bytes(want[:2], "little")
        elif cmd.ado == Reg.AL_STATUS and len(want) >= 6:
            device_id = int.from_bytes(want[4:6], "little")
        elif cmd.ado is not None and cmd.ado != Reg.AL_STATUS and len(want) >= 2:
            device_id = int.from_bytes(want[:2], "little")
    return alias, device_id


# -- modular devices --------------------------------------------------------------------------

def _eni_modules(device: Device, slots: Slots, slave: SlavePlan,
                 library_modules: dict[int, Module]) -> tuple[Device, bool]:
    """A modular device as an ENI configures it: the modules named by its 0xF030 InitCmds
    (one subindex per slot, or the whole list with CompleteAccess) bring their dictionaries;
    the PDOs are the ENI's."""
    coe = slave.mailbox.coe_init_cmds if slave.mailbox else []
    idents = ident_list_from_writes([(c.subindex, c.data, c.complete_access) for c in coe
                                     if c.index == MODULE_IDENT_LIST and c.data
                                     and c.ccs == 1 and not c.disabled])
    plugged = plug_positions(device, {n: library_modules[i] for n, i in idents.items()
                                      if i in library_modules})
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
