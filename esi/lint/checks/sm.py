"""ESI2xx: SyncManagers, FMMUs and the mailbox."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esc import (MIN_MAILBOX_SIZE, SM_CONTROL_MBOX_IN, SM_CONTROL_MBOX_OUT,
                         SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES, SM_DIR_MASK, SM_MODE_BUFFERED,
                         SM_MODE_MAILBOX, SM_MODE_MASK)
from ecatcfg.esi.lint.checks.common import (
    ADDRESS_SPACE_END, DIGITAL_OUTPUT_AREA, PROCESS_RAM_START, sm_length,
)
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule
from ecatcfg.esi.model import Device, SyncManager

# The direction bits each SM type needs in its control byte (ESC register 0x0804 bits 3:2).
SM_DIRECTION = {"MBoxOut": SM_DIR_ECAT_WRITES, "MBoxIn": SM_DIR_ECAT_READS,
                "Outputs": SM_DIR_ECAT_WRITES, "Inputs": SM_DIR_ECAT_READS}
DIRECTION_TEXT = {0x00: "master reads", 0x04: "master writes", 0x08: "reserved (10)",
                  0x0C: "reserved (11)"}
# An ESC has at most 16 SyncManagers (0x0800-0x087F) and 16 FMMUs (0x0600-0x06FF).
MAX_UNITS = 16


def _real_sms(dev: Device) -> list[tuple[SyncManager, int, int]]:
    """(SM, start address, programmed length) for the SMs that occupy ESC memory: not
    virtual, with a start address and a non-zero length.  Empty beyond the ESC's 16 SMs
    (ESI211 reports those), so the pairwise checks stay cheap on absurd input."""
    if len(dev.sms) > MAX_UNITS:
        return []
    out = []
    for sm in dev.sms:
        if sm.virtual or sm.start_address is None:
            continue
        length = sm_length(dev, sm)
        if length > 0:
            out.append((sm, sm.start_address, length))
    return out


def _has_size(sm: SyncManager) -> bool:
    return (sm.default_size, sm.min_size, sm.max_size) != (None, None, None)


def _is_buffered(sm: SyncManager) -> bool:
    return not sm.is_mailbox and sm.control_byte is not None \
        and sm.control_byte & SM_MODE_MASK != SM_MODE_MAILBOX


@device_rule("ESI201", "error", "two SyncManager areas overlap", """
    Each SyncManager guards its own window of ESC memory (StartAddress, length).  Two windows
    that share bytes corrupt each other's data: a mailbox response overwrites inputs, outputs
    land in the mailbox.  The length is the one a configurator programs: the default-assigned
    PDOs' size for process data, else DefaultSize.""")
def sm_overlap(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    sms = _real_sms(dev)
    for i, (a, sa, la) in enumerate(sms):
        for b, sb, lb in sms[i + 1:]:
            if sa < sb + lb and sb < sa + la:
                yield Hit(b.source, f"Sm {b.number} (0x{sb:04X}, {lb} bytes) "
                          f"overlaps Sm {a.number} (0x{sa:04X}, {la} bytes)")


@device_rule("ESI202", "warning", "a buffered SyncManager's three buffers reach into another SM",
             """
    A process-data SM in buffered (3-buffer) mode uses three times its length of ESC memory
    from its start address (the master only sees the first), so the next SM must start at
    least 3 x length further on.  Here the hidden buffers overlap another SM's window; the
    slave refuses SAFEOP or its data is corrupted (SOES checks start + 3 x length).  Not
    checked for the digital-output area 0x0F00, which has no buffers.""")
def sm_triple_buffer_overlap(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    sms = _real_sms(dev)
    for a, sa, la in sms:
        if not _is_buffered(a) or sa in DIGITAL_OUTPUT_AREA:
            continue
        end = sa + 3 * la
        for b, sb, _ in sms:
            if b is a:
                continue
            if sa + la <= sb < end:
                yield Hit(a.source, f"Sm {a.number} at 0x{sa:04X} with {la} bytes "
                          f"uses 0x{sa:04X}-0x{end - 1:04X} in 3-buffer mode, "
                          f"reaching Sm {b.number} at 0x{sb:04X}")


@device_rule("ESI203", "error", "a SyncManager area lies outside ESC process memory", """
    SyncManagers guard process RAM, which starts at 0x1000 in every ESC and cannot go past
    0xFFFF; below 0x1000 lie the ESC registers (only the digital-output area 0x0F00-0x0F7F
    of simple I/O ESCs may be used).  An SM there would overwrite registers or cannot be
    programmed at all.  Virtual SMs, which only describe data, are not checked.""")
def sm_outside_memory(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm, start, length in _real_sms(dev):
        end = start + length
        low_ok = start >= PROCESS_RAM_START or (start in DIGITAL_OUTPUT_AREA
                                                and end <= DIGITAL_OUTPUT_AREA.stop)
        if not low_ok or end > ADDRESS_SPACE_END:
            yield Hit(sm.source, f"Sm {sm.number} covers 0x{start:04X}-0x{end - 1:04X}, "
                      "outside process memory 0x1000-0xFFFF")


@device_rule("ESI204", "error", "a mailbox SyncManager is too small for one SDO", """
    A mailbox SM must hold the 6-byte mailbox header plus the smallest CoE SDO request
    (2-byte CoE header + 8 bytes), 16 bytes in all; masters size their mailbox buffers from
    it.  Smaller, no SDO can be exchanged and the mailbox is useless.""")
def mailbox_too_small(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if sm.is_mailbox and not sm.virtual:
            size = sm.mailbox_size
            if _has_size(sm) and size < MIN_MAILBOX_SIZE:      # no size at all: ESI213
                yield Hit(sm.source, f"{sm.type} Sm {sm.number} is {size} bytes; a mailbox "
                          f"needs at least {MIN_MAILBOX_SIZE}")


@device_rule("ESI205", "error", "a mailbox SyncManager's control byte is not a mailbox mode", """
    The control byte (ESC register 0x0804) of a mailbox SM must select mailbox (1-buffer)
    mode, bits 1:0 = 10, and the SM's direction, bits 3:2: 01 (master writes) for MBoxOut,
    00 (master reads) for MBoxIn.  The usual values are 0x26 and 0x22.  Anything else and the
    slave refuses PREOP with AL status 0x0016 (invalid mailbox configuration).""")
def mailbox_control_byte(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if not sm.is_mailbox or sm.control_byte is None:
            continue
        cb = sm.control_byte
        direction = SM_DIRECTION[sm.type or ""]       # a mailbox SM's type is MBoxOut/MBoxIn
        if cb & SM_MODE_MASK != SM_MODE_MAILBOX or cb & SM_DIR_MASK != direction:
            want = f"0x{SM_CONTROL_MBOX_OUT if sm.type == 'MBoxOut' else SM_CONTROL_MBOX_IN:02X}"
            yield Hit(sm.source, f"{sm.type} Sm {sm.number} has ControlByte 0x{cb:02X}, not "
                      f"a {sm.type} mailbox mode (e.g. {want})")


@device_rule("ESI206", "warning", "a process-data SyncManager uses mailbox (1-buffer) mode", """
    Process data normally uses buffered (3-buffer) mode: the master always reads the newest
    complete inputs and writes outputs without waiting.  In 1-buffer (mailbox) mode, control
    byte bits 1:0 = 10, the master only gets inputs after the slave wrote them and a write
    waits until the slave read the last one; cyclic reads see WKC 0 in between.  Some
    devices do this on purpose (Beckhoff EL1252 inputs); otherwise it is a mistake.""")
def process_data_mailbox_mode(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if sm.type in ("Outputs", "Inputs") and not sm.virtual and sm.control_byte is not None \
                and sm.control_byte & SM_MODE_MASK == SM_MODE_MAILBOX:
            yield Hit(sm.source, f"{sm.type} Sm {sm.number} has ControlByte "
                      f"0x{sm.control_byte:02X}: 1-buffer (mailbox) mode")


@device_rule("ESI207", "error", "a process-data SyncManager's control byte has the wrong mode "
             "or direction", """
    Control byte bits 3:2 (ESC register 0x0804) set who writes the SM: 01 = the master
    (Outputs), 00 = the slave (Inputs); 10 and 11 are reserved.  Bits 1:0 select buffered
    (00) or mailbox (10) mode; 01 and 11 are reserved.  This SM's bits disagree with its type
    or use a reserved value, so the ESC blocks the direction the data needs to go or does not
    work as a SyncManager at all.""")
def process_data_control_byte(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if sm.type not in ("Outputs", "Inputs") or sm.virtual or sm.control_byte is None:
            continue
        cb = sm.control_byte
        mode = cb & SM_MODE_MASK
        if cb & SM_DIR_MASK != SM_DIRECTION[sm.type]:
            yield Hit(sm.source, f"{sm.type} Sm {sm.number} has ControlByte 0x{cb:02X}, whose "
                      f"direction bits say {DIRECTION_TEXT[cb & SM_DIR_MASK]}")
        elif mode not in (SM_MODE_BUFFERED, SM_MODE_MAILBOX):
            yield Hit(sm.source, f"{sm.type} Sm {sm.number} has ControlByte 0x{cb:02X}, whose "
                      f"mode bits {mode:02b} are reserved")


@device_rule("ESI208", "error", "mailbox protocols are declared but there is no mailbox SM", """
    Device/Mailbox lists protocols (CoE, FoE, EoE ...) but the device has no MBoxOut and
    MBoxIn SyncManager to carry them, so a master can neither send a request nor read a
    response.""")
def mailbox_without_sm(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if dev.mailbox is None or not dev.mailbox.protocols:
        return
    types = {sm.type for sm in dev.sms if not sm.virtual}
    missing = [t for t in ("MBoxOut", "MBoxIn") if t not in types]
    if missing:
        yield Hit(dev.mailbox.source, f"Mailbox declares {', '.join(dev.mailbox.protocols)} "
                  f"but the device has no {' and no '.join(missing)} SyncManager")


def _directions_in_use(dev: Device) -> list[str]:
    need = []
    if any(not p.virtual for p in dev.rx_pdos):
        need.append("Outputs")
    if any(not p.virtual for p in dev.tx_pdos):
        need.append("Inputs")
    return need


@device_rule("ESI209", "error", "no FMMU for a process-data direction the device uses", """
    Each direction of process data needs an FMMU to map it into the logical process image:
    an "Outputs" FMMU for RxPDOs, an "Inputs" FMMU for TxPDOs.  The device lists its FMMUs
    but none for this direction, so configurators that follow the list (as the SII FMMU
    category tells masters) cannot map the data.""")
def fmmu_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if not dev.fmmus:
        return
    have = {f.type for f in dev.fmmus}
    for direction in _directions_in_use(dev):
        if direction not in have:
            listed = ", ".join(f.type or "(empty)" for f in dev.fmmus)
            yield Hit(dev.fmmus[0].source, f"the device has {direction.lower()} PDOs but no "
                      f"{direction} FMMU (listed: {listed})")


@device_rule("ESI210", "warning", "a device with process data lists no FMMU", """
    The device has PDOs but no Fmmu elements.  Configurators then guess (FMMU0 outputs,
    FMMU1 inputs, FMMU2 mailbox state), and the SII image built from the ESI has no FMMU
    category for masters to read.  List the FMMUs the ESC uses.""")
def fmmu_list_missing(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    if not dev.fmmus and _directions_in_use(dev):
        yield Hit(dev.source, f"{dev.type_name!r} has process data but lists no Fmmu")


@device_rule("ESI211", "error", "more SyncManagers or FMMUs than an ESC has", """
    An ESC has at most 16 SyncManagers (registers 0x0800-0x087F) and 16 FMMUs
    (0x0600-0x06FF); the SII categories describe no more.  A device listing more cannot be
    configured (and the SyncManager layout checks are skipped for it).""")
def too_many_units(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for what, units in (("Sm", dev.sms), ("Fmmu", dev.fmmus)):
        if len(units) > MAX_UNITS:
            yield Hit(units[MAX_UNITS].source, f"the device lists {len(units)} {what} "
                      f"elements; an ESC has at most {MAX_UNITS}")


@device_rule("ESI212", "warning", "a mailbox SyncManager has no DefaultSize", """
    ETG.2000 gives a mailbox SM's DefaultSize as the size a configurator programs, and
    MinSize/MaxSize as the sizes the slave accepts.  Without DefaultSize every tool must
    choose: ecatcfg takes MaxSize, else MinSize, for the ENI's SM0/SM1 settings and mailbox
    lengths and for the SII's standard mailbox words alike; another configurator may choose
    differently, and a slave whose firmware expects another size refuses PREOP with AL
    status 0x0016 (invalid mailbox configuration).  Give DefaultSize, the size the
    firmware's mailbox has.""")
def mailbox_without_default_size(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if sm.is_mailbox and not sm.virtual and sm.default_size is None \
                and (sm.max_size is not None or sm.min_size is not None):
            taken = "MaxSize" if sm.max_size is not None else "MinSize"
            yield Hit(sm.source, f"{sm.type} Sm {sm.number} has no DefaultSize; configurators "
                      f"must guess (ecatcfg takes {taken}, {sm.mailbox_size} bytes)")


@device_rule("ESI213", "error", "a mailbox SyncManager has no size", """
    A mailbox SM without DefaultSize, MinSize or MaxSize has no length: the ENI would
    program SM0/SM1 with 0 bytes and the SII's standard mailbox words would say 0, so no
    master can exchange a mailbox message and the slave refuses PREOP (AL status 0x0016).
    Give DefaultSize, the size of the firmware's mailbox.""")
def mailbox_without_size(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if sm.is_mailbox and not sm.virtual and not _has_size(sm):
            yield Hit(sm.source, f"{sm.type} Sm {sm.number} has no DefaultSize, MinSize or "
                      "MaxSize: the mailbox would be 0 bytes")


@device_rule("ESI214", "error", "an EoE InitCmd ecatcfg does not send", """
    ETG.2000 lets an ESI give EoE InitCmds (Mailbox/EoE/InitCmd: Transition, Type, Data) for
    the master to send, but no public source says how their Type and Data are encoded, so
    ecatcfg does not implement them: compile refuses the device rather than leave out what
    its file asks for.  Set the device's IP parameters with the topology's 'eoe:' key
    instead (docs/compile.md), and remove the InitCmd from a file ecatcfg is to use.""")
def eoe_init_cmds(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    eoe = dev.mailbox.eoe if dev.mailbox else None
    for source in eoe.init_cmds if eoe else []:
        yield Hit(source, "an EoE InitCmd: ecatcfg does not implement them; compile refuses "
                  "the device (set IP parameters with the topology's 'eoe:')")


@device_rule("ESI215", "warning", "a SyncManager has no type", """
    ETG.2000 gives each Sm its type as text: MBoxOut, MBoxIn, Outputs or Inputs (IgH's
    ``ethercat xml`` dumps leave it out).  ecatcfg then takes the type from the SM's
    ControlByte (ESC register 0x0804), as the ESC itself does: bits 3:2 the direction, bits
    1:0 mailbox (one buffer) or process data (three buffers), a one-buffer SM that PDOs name
    being process data; IgH's master derives the direction from the same bits.  Without a
    ControlByte, or with reserved bits in it, the SM has no type, and compile refuses a
    Mandatory or default-assigned PDO that names it rather than leave it out.  Write the
    type.""")
def sm_without_type(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    for sm in dev.sms:
        if sm.type is not None and sm.type_from_control:
            yield Hit(sm.source, f"Sm {sm.number} has no type; its ControlByte "
                      f"0x{sm.control_byte or 0:02X} makes it {sm.type}")
        elif sm.type is None:
            why = (f"its ControlByte 0x{sm.control_byte:02X} has reserved bits"
                   if sm.control_byte is not None else "nor a ControlByte to take one from")
            yield Hit(sm.source, f"Sm {sm.number} has no type, and {why}: a PDO that names "
                      "it cannot be placed")
