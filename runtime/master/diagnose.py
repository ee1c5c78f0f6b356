"""Why a slave refuses a state: the cause next to its AL status code, read from the slave.

An AL status code (0x0134, ETG.1000.6) says which check a slave's firmware failed, not which
value made it fail.  For the codes below the master reads what that check looks at and
says it in one or two lines (``docs/diagnostics.md`` has the table):

- 0x001D / 0x001E invalid output / input configuration: the process-data SyncManagers of
  that direction as the slave's SII places them (its SyncM category) against the ESC's
  (0x0800 + 8·n: start, length, control, activate), the PDO assignment and mappings the
  slave holds over CoE (0x1C10 + n, 0x1600-0x17FF / 0x1A00-0x1BFF, each mapped entry
  uploaded and its mappability taken from the ESI or SDO Information; without CoE the
  SII's fixed PDOs) and the FMMUs (0x0600 + 16·n) over them (SOES ``ESC_checkSM23`` checks
  the same);
- 0x0016 / 0x0015 invalid mailbox configuration: SM0/SM1 against the SII's (bootstrap)
  mailbox words; 0x0011 / 0x0012 / 0x0013: AL control against the AL state machine;
- 0x001B SM watchdog: the watchdog time (0x0420 in the base of 0x0400), its status
  (0x0440) and counter (0x0442): outputs stopped arriving for longer than that time;
- 0x0030 / 0x0035 / 0x0036 / 0x0037 DC SYNC: the activation (0x0981), SYNC0/SYNC1 cycle times
  (0x09A0, 0x09A4), with an ENI the cycle time it asks for, the minimum cycle time the
  slave reports over CoE (0x1C32:05 / 0x1C33:05, ETG.1020: Slave Stack Code firmware
  refuses a shorter SYNC0 cycle) and, with ESI files, the device's SYNC0 op modes and
  its ESI minimum cycle time;
- 0x0045 MBX_SOE (what an emulated SoE drive refuses SAFEOP with, ``runtime/segment/
  al_checks.py``): each drive's S-0-0021, the IDNs it found invalid or missing before
  SAFEOP (the Beckhoff AX5000 documentation of S-0-0021), read over SoE;
- any code: the newest diagnosis message of a slave that has the diagnosis history object
  (0x10F3, ETG.1020 "Diagnosis history": sub 2 newest message, messages from sub 6 on:
  DiagCode u32, Flags u16, TextId u16, time stamp u64, parameters).

Everything is read by auto-increment position, so it works with or without an ENI and
before station addresses are set (``ecatcfg doctor``).  Each cause names the rules it found
broken (``Cause.fields["rules"]``, the names of ``runtime/refusals.py``), the same names the
emulated firmware refuses by.  The diagnosis is a lockstep job
(``lockstep.py``): :func:`explain` runs it to the end, and the recovery
(``recovery.py``) runs :func:`explain_step` between cycles while the others' data goes on.
CoE goes through one mailbox per diagnosis: the master's own channel where it configured the
slave (the ENI's mailbox), else the one ``sdo_tool.open_mailbox`` prepares once from the
slave's SII and SyncManagers, used for every upload that follows.  Nothing here writes a
register except what an SDO upload and an SII read (0x0500-0x0504) need.

With the device's ESI (``esi``: a :class:`~ecatcfg.esi.library.Library`, the device found by
the slave's identity), a DC refusal is compared with what the ESI says of the SYNC0 cycle
(``esi/dc_cycle.py``: the DC op modes and the minimum cycle time of 0x1C32:05/0x1C33:05).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ecatcfg.runtime.clock import monotonic
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (AL_STATE_MASK, AL_STATUS_ERROR, FMMU_SIZE, RX_PDO_MAPPING,
                         SII_BOOTSTRAP_MAILBOX, SII_FIRST_CATEGORY, SII_PRODUCT_CODE,
                         SII_REVISION, SII_STD_MAILBOX, SII_VENDOR_ID, SM_DIR_ECAT_WRITES,
                         SM_DIR_MASK, SM_INPUT_PARAMETER, SM_MODE_BUFFERED, SM_MODE_MAILBOX,
                         SM_MODE_MASK, SM_OUTPUT_PARAMETER, SM_PARAMETER_MIN_CYCLE,
                         SM_PDO_ASSIGN, SM_SIZE, SM_TYPE_CODES, TX_PDO_MAPPING,
                         AlState, AlStatusCode, Cmd, FmmuConfig, FmmuType, Reg, SmConfig,
                         al_state_name, al_status_name, fmmus_cover, sm_register,
                         sync0_running,
                         watchdog_base_ns)
from ecatcfg.record import record
from ecatcfg.runtime.master.lockstep import Job, Step, run_jobs
from ecatcfg.runtime.master.replay import TIMEOUT_COMMAND, ApplyError, MailboxChannel, sdo_job
from ecatcfg.runtime.refusals import Rule
from ecatcfg.runtime.wire import Datagram

if TYPE_CHECKING:
    from ecatcfg.eni.plan import NetworkPlan, SlavePlan
    from ecatcfg.esi.library import Library
    from ecatcfg.esi.model import Device
    from ecatcfg.esi.sii import SiiPdo, SiiSyncManager
    from ecatcfg.runtime.master.scan import Mismatch
    from ecatcfg.runtime.master.transport import Transport

DIAG_HISTORY = 0x10F3          # ETG.1020 diagnosis history object
DIAG_NEWEST = 2                # its subindex "newest message"
DIAG_FIRST_MESSAGE = 6         # messages from this subindex on
_DC_CODES = (AlStatusCode.DC_INVALID_SYNC, AlStatusCode.DC_INVALID_SYNC_CYCLE,
             AlStatusCode.DC_INVALID_SYNC0_CYCLE, AlStatusCode.DC_INVALID_SYNC1_CYCLE)
# SM control bits a slave checks against its own SM configuration: mode and direction.
SM_MODE_AND_DIRECTION = SM_MODE_MASK | SM_DIR_MASK
SDO_TIMEOUT = 1.0              # s per diagnostic upload: a slave that does not answer is said
NO_COE = "does not support CoE"


@record
class Cause:
    """Why a slave is not in the state asked for: its AL status code and the lines that say
    what the slave holds; ``fields`` are the same values for JSON."""

    position: int
    code: int
    lines: list[str]
    fields: dict[str, Any]

    def text(self) -> str:
        head = f"0x{self.code:04X} {al_status_name(self.code)}"
        return head + (": " + "; ".join(self.lines) if self.lines else "")

    def as_json(self) -> dict[str, Any]:
        return {"position": self.position, "al_status_code": self.code,
                "al_status": al_status_name(self.code), "cause": self.lines,
                **self.fields}


class _Unreadable(EcatcfgError):
    """A register or object the diagnosis could not read (``abort_code``: the slave's SDO
    abort, where it answered with one)."""

    def __init__(self, message: str, abort_code: int | None = None) -> None:
        super().__init__(message)
        self.abort_code = abort_code


# -- reading -----------------------------------------------------------------------------------

def _read(position: int, ado: int, length: int, out: dict[int, bytes]) -> Step[None]:
    dg = Datagram.physical(Cmd.APRD, -position & 0xFFFF, ado, length)
    deadline = monotonic() + TIMEOUT_COMMAND
    while True:
        reply = yield [dg]
        if reply is not None and reply[0].wkc == 1:
            out[ado] = bytes(reply[0].data)
            return
        if monotonic() > deadline:
            return


def _registers(position: int, spans: list[tuple[int, int]]) -> Step[dict[int, bytes]]:
    """A job step: ``{address: bytes}`` of each (address, length) read from the slave at
    ``position``, all in one round (again for those not answered); a span without an
    answer by the command timeout is left out."""
    adp = -position & 0xFFFF
    wanted = {ado: Datagram.physical(Cmd.APRD, adp, ado, n) for ado, n in spans}
    out: dict[int, bytes] = {}
    deadline = monotonic() + TIMEOUT_COMMAND
    while True:
        missing = [ado for ado in wanted if ado not in out]
        if not missing:
            return out
        reply = yield [wanted[ado] for ado in missing]
        if reply is not None:
            for ado, dg in zip(missing, reply):
                if dg.wkc == 1:
                    out[ado] = bytes(dg.data)
        if monotonic() > deadline:
            return out


def read_registers(transport: Transport, position: int,
                   spans: list[tuple[int, int]]) -> dict[int, bytes]:
    """``{address: bytes}`` of each (address, length) read from the slave at ``position``;
    a span without an answer is left out."""
    out: dict[int, bytes] = {}

    def job() -> Job:
        out.update((yield from _registers(position, spans)))
    run_jobs(transport, [job()])
    return out


class _Mailbox:
    """The CoE uploads (and SoE reads) of one diagnosis over one mailbox: ``channel`` when
    the master has one for the slave (its ENI mailbox, configured by the master), else
    prepared from the slave's SII at the first transfer (``sdo_tool.open_mailbox``) and kept
    for the others."""

    def __init__(self, position: int, channel: MailboxChannel | None, coe: bool | None
                 ) -> None:
        self.position = position
        self.channel = channel
        self.counter: Callable[[], int] | None = channel.counter if channel else None
        self.no_coe = coe is False
        self.error: str | None = None          # why the mailbox could not be prepared

    def _open(self, protocol: str) -> Step[None]:
        from ecatcfg.runtime.master.sdo_tool import SdoToolError, SlaveMailbox, open_mailbox
        if self.channel is None and self.error is None:
            info = SlaveMailbox(self.position)
            info.protocol = protocol           # the protocol the slave's SII must list
            try:
                self.channel, self.counter = yield from open_mailbox(info)
            except (SdoToolError, ApplyError) as exc:
                self.error = exc.message

    def upload(self, index: int, sub: int) -> Step[bytes]:
        from ecatcfg.runtime.master.sdo_client import SdoUpload
        if self.no_coe:
            raise _Unreadable(f"0x{index:04X}:{sub:02X} not read (slave {self.position} "
                              f"{NO_COE})")
        yield from self._open("CoE")
        if self.error is not None:
            raise _Unreadable(f"0x{index:04X}:{sub:02X} not read ({self.error})")
        assert self.channel is not None and self.counter is not None
        try:
            t = SdoUpload(index, sub, False, self.channel.plan.send.length, self.counter)
            yield from sdo_job(self.channel, t, None, None, SDO_TIMEOUT)
        except (ApplyError, ValueError) as exc:
            raise _Unreadable(f"0x{index:04X}:{sub:02X} not read ("
                              f"{getattr(exc, 'message', str(exc))})",
                              getattr(exc, "abort_code", None)) from None
        return t.result

    def entry_access(self, index: int, sub: int) -> Step[int | None]:
        """The object access word of ``index:sub`` from SDO Information (Get Entry
        Description, ETG.1000.6: bit 6 RxPDO mappable, bit 7 TxPDO mappable);
        None where the slave does not describe it."""
        from ecatcfg.runtime.mailbox import EntryDescription, SdoInfoOpcode
        from ecatcfg.runtime.master.sdo_info import SdoInfoRequest
        if self.no_coe:
            return None
        yield from self._open("CoE")
        if self.error is not None or self.channel is None or self.counter is None:
            return None
        request = SdoInfoRequest(SdoInfoOpcode.ENTRY_DESCRIPTION_REQUEST, index, sub,
                                 mbx_out_size=self.channel.plan.send.length,
                                 counter=self.counter)
        try:
            yield from sdo_job(self.channel, request, None, request.what(), SDO_TIMEOUT)
            return EntryDescription.unpack(request.result).access
        except (ApplyError, ValueError, struct.error):
            return None

    def soe_read(self, idn: int, drive: int) -> Step[bytes]:
        """The value of ``idn`` of drive ``drive``; an SoE error reply raises
        ``SoeRefused`` (its ``soe_error``), anything else :class:`_Unreadable`."""
        from ecatcfg.esi.idn import idn_text
        from ecatcfg.runtime.master.soe_client import SoeRefused, SoeTransfer, soe_job
        yield from self._open("SoE")
        if self.error is not None:
            raise _Unreadable(f"{idn_text(idn)} not read ({self.error})")
        assert self.channel is not None and self.counter is not None
        t = SoeTransfer(idn, drive_no=drive, mbx_out_size=self.channel.plan.send.length,
                        counter=self.counter)
        try:
            yield from soe_job(self.channel, t, None, None, SDO_TIMEOUT)
        except SoeRefused:
            raise
        except ApplyError as exc:
            raise _Unreadable(f"{idn_text(idn)} not read ({exc.message})") from None
        return t.result


def _u(data: bytes) -> int:
    return int.from_bytes(data[:4], "little")


# -- the causes ------------------------------------------------------------------------------

@record
class Context:
    """What the diagnosis knows besides the slave: its ENI entry (``slave``: the cycle the
    ENI asks for; its mailbox channel ``channel`` when the master configured it), the
    ENI's bus cycle, and the ESI files (``esi``) to find the device in."""

    slave: SlavePlan | None = None
    channel: MailboxChannel | None = None
    bus_cycle_ns: int | None = None
    esi: Library | None = None
    identity: tuple[int, int, int] | None = None    # vendor, product, revision (SII)

    def device(self) -> tuple[Device | None, str]:
        """The slave's ESI device by its identity, and where it was found (or why not)."""
        if self.esi is None:
            return None, ""
        ident = self.identity or (
            (self.slave.vendor_id, self.slave.product_code, self.slave.revision)
            if self.slave is not None else None)
        if ident is None:
            return None, "its identity is not known"
        exact, other, note = self.esi.entry_for_identity(*ident)
        entry = exact or other
        if entry is None:
            return None, (f"no device 0x{ident[0]:08X}:0x{ident[1]:08X} in the ESI files "
                          "given")
        where = f"{entry.file}:{entry.line}" + (f"; {note}" if note else "")
        return self.esi.device(entry), where


def explain(transport: Transport, position: int, code: int | None = None,
            slave: SlavePlan | None = None, context: Context | None = None) -> Cause:
    """The cause of the slave at ``position`` not being where it was asked to go: its AL
    status code (read when ``code`` is None) and what its check looks at.  ``slave``: its
    ENI entry, when there is one (the DC cycle time the ENI asks for)."""
    context = context or Context()
    if slave is not None:
        context = Context(slave, context.channel, context.bus_cycle_ns, context.esi,
                          context.identity)
    out: list[Cause] = []

    def job() -> Job:
        out.append((yield from explain_step(position, code, context)))
    run_jobs(transport, [job()])
    return out[0]


def explain_step(position: int, code: int | None, context: Context) -> Step[Cause]:
    """:func:`explain` as a job step (the recovery runs it while the network cycles)."""
    regs = yield from _registers(position, [(Reg.AL_STATUS, 6), (Reg.SM0, 2 * SM_SIZE)])
    status = regs.get(Reg.AL_STATUS)
    fields: dict[str, Any] = {}
    if status is not None:
        al_status, _, read_code = struct.unpack("<HHH", status)
        fields["al_state"] = al_state_name(al_status)
        code = read_code if code is None else code
    code = code or 0
    slave = context.slave
    coe_known = None
    if slave is not None:
        coe_known = slave.mailbox is not None and "CoE" in slave.mailbox.protocols
    mailbox = _Mailbox(position, context.channel, coe_known) if _mailbox_ready(regs) else None
    lines: list[str] = []
    rules: list[Rule] = []
    try:
        if code in (AlStatusCode.INVALID_OUTPUTS, AlStatusCode.INVALID_INPUTS):
            lines += yield from _process_data(position, code == AlStatusCode.INVALID_OUTPUTS,
                                              fields, mailbox, context, rules)
        elif code == AlStatusCode.SM_WATCHDOG:
            lines += yield from _watchdog(position, fields)
            rules.append(Rule.SM_WATCHDOG)
        elif code in _DC_CODES:
            lines += yield from _dc(position, context, fields, mailbox, rules)
        elif code == AlStatusCode.MBX_SOE and mailbox is not None:
            lines += yield from _soe_invalid(mailbox, fields, rules)
        elif code in (AlStatusCode.INVALID_MAILBOX, AlStatusCode.INVALID_MAILBOX_BOOT):
            lines += yield from _mailbox_sms(position, code == AlStatusCode.INVALID_MAILBOX_BOOT,
                                             fields, rules)
        elif code in (AlStatusCode.INVALID_STATE_CHANGE, AlStatusCode.UNKNOWN_STATE,
                      AlStatusCode.BOOT_NOT_SUPPORTED):
            lines += yield from _state_request(position, code, fields, rules)
    except _Unreadable as exc:
        lines.append(exc.message)
    fields["rules"] = [r.value for r in dict.fromkeys(rules)]
    if mailbox is not None:
        lines += yield from _diagnosis_message(mailbox, fields)
    return Cause(position, code, lines, fields)


def _mailbox_ready(regs: dict[int, bytes]) -> bool:
    """Whether the slave's mailbox works as it is: PREOP or above (not BOOT) with SM0/SM1 in
    mailbox mode and enabled.  Only then are CoE objects read: a diagnosis must not set up
    a mailbox or change a slave's state (``sdo_tool`` would, for a slave below PREOP)."""
    if Reg.AL_STATUS not in regs or Reg.SM0 not in regs:
        return False
    state = regs[Reg.AL_STATUS][0] & AL_STATE_MASK
    if state not in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        return False
    sm0, sm1 = (SmConfig.from_bytes(regs[Reg.SM0][SM_SIZE * n:]) for n in (0, 1))
    return all(sm.enable and sm.control & SM_MODE_MASK == SM_MODE_MAILBOX for sm in (sm0, sm1))


def _sms(position: int) -> Step[tuple[list[SmConfig], list[FmmuConfig]]]:
    counts = (yield from _registers(position, [(Reg.FMMUS_SUPPORTED, 2)])).get(
        Reg.FMMUS_SUPPORTED)
    if counts is None:
        raise _Unreadable(f"FMMU and SM counts (0x{Reg.FMMUS_SUPPORTED:04X}) not read")
    fmmus_n, sms_n = counts[0], counts[1]
    regs = yield from _registers(position, [(Reg.SM0, SM_SIZE * sms_n),
                                            (Reg.FMMU0, FMMU_SIZE * fmmus_n)])
    if Reg.SM0 not in regs or Reg.FMMU0 not in regs:
        raise _Unreadable("SyncManager (0x0800) and FMMU (0x0600) registers not read")
    sms = [SmConfig.from_bytes(regs[Reg.SM0][SM_SIZE * n:]) for n in range(sms_n)]
    fmmus = [FmmuConfig.from_bytes(regs[Reg.FMMU0][FMMU_SIZE * n:]) for n in range(fmmus_n)]
    return sms, fmmus


# SDO aborts that say an object or subindex is not there (ETG.1000.6 Table 41).
_MISSING = (0x06020000, 0x06090011)
SII_TIMEOUT = 2.0              # s for the SII reads of one diagnosis
EEPROM_TO_PDI = 0x01           # 0x0500 bit 0: the EEPROM is assigned to the PDI
EEPROM_FORCE_ECAT = 0x02       # 0x0500 bit 1: reset the PDI's access (ESC Section II)
_SII_LAST_WORD = 0x4000        # an SII category walk stops here (a 32 KiB EEPROM)


@record
class _SiiLayout:
    """What the slave's SII says of its SyncManagers and fixed PDOs (ETG.2010 categories
    SyncM 41, TxPDO 50, RxPDO 51), read over the wire."""

    sms: list[SiiSyncManager]
    pdos: list[SiiPdo]


def _sii(position: int) -> Step[_SiiLayout]:
    """The slave's SII SyncManager and PDO categories, walked category by category from
    word 0x40 (only those bodies are read); :class:`_Unreadable` when the EEPROM does not
    answer."""
    owner = (yield from _registers(position, [(Reg.EEPROM_CONFIG, 1)])).get(Reg.EEPROM_CONFIG)
    if owner is None:
        raise _Unreadable(f"the SII is not read: 0x{Reg.EEPROM_CONFIG:04X} does not answer")
    pdi = bool(owner[0] & EEPROM_TO_PDI)
    if pdi:
        # The EEPROM is assigned to the PDI (0x0500 bit 0): taken for the master and given
        # back after, as SOEM does around its SII reads (ecx_eeprom2master writes 2, "force
        # EEPROM from PDI", then 0; ecx_eeprom2pdi writes 1).
        for value in (EEPROM_FORCE_ECAT, 0):
            yield from _write(position, Reg.EEPROM_CONFIG, bytes([value]))
    try:
        return (yield from _sii_categories(position))
    finally:
        if pdi:
            yield from _write(position, Reg.EEPROM_CONFIG, bytes([EEPROM_TO_PDI]))


def _write(position: int, ado: int, data: bytes) -> Step[None]:
    """One register write to the slave at ``position``, again until it is answered;
    :class:`_Unreadable` after the command timeout."""
    dg = Datagram.physical(Cmd.APWR, -position & 0xFFFF, ado, data)
    deadline = monotonic() + TIMEOUT_COMMAND
    while True:
        reply = yield [dg]
        if reply is not None and reply[0].wkc == 1:
            return
        if monotonic() > deadline:
            raise _Unreadable(f"0x{ado:04X} not written (no answer)")


def _sii_categories(position: int) -> Step[_SiiLayout]:
    from ecatcfg.esi.sii import (CAT_END, CAT_RXPDO, CAT_SYNCM, CAT_TXPDO, HEADER_SIZE,
                                 SiiError, decode)
    from ecatcfg.runtime.master.scan import sii_words
    deadline = monotonic() + SII_TIMEOUT
    image = bytearray(HEADER_SIZE)
    image[0] = 1                       # not an erased header (decode refuses those)
    word = SII_FIRST_CATEGORY
    try:
        while word < _SII_LAST_WORD:
            head = yield from sii_words(position, word, deadline)
            kind, size = struct.unpack_from("<HH", head)
            if kind == CAT_END:
                break
            if kind in (CAT_SYNCM, CAT_TXPDO, CAT_RXPDO):
                body = head[4:]
                while len(body) < 2 * size:
                    body += yield from sii_words(position, word + 2 + len(body) // 2,
                                                 deadline)
                image += head[:4] + body[:2 * size]
            word += 2 + size
    except ApplyError as exc:
        raise _Unreadable(f"the SII (EEPROM, 0x0502) not read: {exc.message}") from None
    image += struct.pack("<H", CAT_END)
    try:
        sii = decode(bytes(image))
    except SiiError as exc:
        raise _Unreadable(f"the SII's categories do not read: {exc.message}") from None
    return _SiiLayout(sii.syncms, sii.txpdos + sii.rxpdos)


def _esi_device(context: Context) -> Device | None:
    try:
        return context.device()[0]
    except EcatcfgError:
        return None


def _mappable(mailbox: _Mailbox, device: Device | None, index: int, sub: int,
              direction: str) -> Step[tuple[bool | None, str]]:
    """Whether ``index:sub`` may be mapped into a PDO of ``direction`` ("R" RxPDO, "T"
    TxPDO), and who says so: the device's ESI (the entry's Flags/PdoMapping, or an ESI PDO
    of that direction that maps it), else the slave's SDO Information (object access bits 6
    and 7); None where neither says."""
    from ecatcfg.esi.coe import DictEntry, device_dictionary, lookup
    from ecatcfg.runtime.mailbox import ACCESS_RXPDO, ACCESS_TXPDO
    if device is not None:
        pdos = device.rx_pdos if direction == "R" else device.tx_pdos
        if any(e.index == index and (e.subindex or 0) == sub for p in pdos
               for e in p.entries):
            return True, "an ESI PDO maps it"
        dic = device_dictionary(device)
        found = lookup(dic, index, sub) if dic is not None else None
        if isinstance(found, DictEntry) and found.flags is not None:
            said = (found.flags.pdo_mapping or "").upper()
            return direction in said, f"its ESI PdoMapping is {said or 'absent'}"
        return None, ""
    access = yield from mailbox.entry_access(index, sub)
    if access is None:
        return None, ""
    bit = ACCESS_RXPDO if direction == "R" else ACCESS_TXPDO
    return bool(access & bit), f"SDO Information access 0x{access:04X}"


def _assignment(mailbox: _Mailbox, sm: int, direction: str, device: Device | None,
                problems: list[tuple[Rule, str]]) -> Step[tuple[list[int], int | None] | None]:
    """The PDOs assigned to SM ``sm`` (0x1C10 + sm) and the bits their mappings hold, as the
    slave has them now, walked as its firmware walks them (``problems`` gets each rule the
    walk breaks: an assignment, PDO or mapped entry the slave does not have, an entry not
    mappable in the SM's direction); bits None where the walk cannot go on; None without
    CoE."""
    index = SM_PDO_ASSIGN + sm
    try:
        count = (yield from mailbox.upload(index, 0))[0]
    except _Unreadable as exc:
        if NO_COE in exc.message:
            return None
        if exc.abort_code in _MISSING:
            problems.append((Rule.NO_ASSIGNMENT, f"the slave has no PDO assignment object "
                                                 f"0x{index:04X} (abort 0x{exc.abort_code:08X})"))
            return [], None
        raise
    pdos: list[int] = []
    bits: int | None = 0
    for k in range(1, count + 1):
        try:
            pdo = _u((yield from mailbox.upload(index, k))) & 0xFFFF
        except _Unreadable as exc:
            if exc.abort_code not in _MISSING:
                raise
            problems.append((Rule.NO_ASSIGNMENT, f"0x{index:04X}:00 = {count}, but the slave "
                                                 f"has no 0x{index:04X}:{k:02X}"))
            return pdos, None
        pdos.append(pdo)
        if pdo not in RX_PDO_MAPPING and pdo not in TX_PDO_MAPPING:
            problems.append((Rule.PDO_MISSING, f"0x{index:04X}:{k:02X} = 0x{pdo:04X}, no PDO "
                                               "mapping index (0x1600-0x17FF, 0x1A00-0x1BFF)"))
            return pdos, None
        try:
            entries = (yield from mailbox.upload(pdo, 0))[0]
        except _Unreadable as exc:
            if exc.abort_code not in _MISSING:
                raise
            problems.append((Rule.PDO_MISSING, f"0x{index:04X}:{k:02X} assigns PDO 0x{pdo:04X}, "
                                               f"which the slave does not have (upload of "
                                               f"0x{pdo:04X}: abort 0x{exc.abort_code:08X})"))
            return pdos, None
        for j in range(1, entries + 1):
            try:
                word = _u((yield from mailbox.upload(pdo, j)))
            except _Unreadable as exc:
                if exc.abort_code not in _MISSING:
                    raise
                problems.append((Rule.PDO_MISSING, f"0x{pdo:04X}:00 = {entries}, but the slave "
                                                   f"has no 0x{pdo:04X}:{j:02X}"))
                return pdos, None
            obj, obj_sub, obj_bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            if bits is not None:
                bits += obj_bits
            if not obj:
                continue                        # a gap
            where = f"0x{pdo:04X}:{j:02X} maps 0x{obj:04X}:{obj_sub:02X} ({obj_bits} bits)"
            try:
                yield from mailbox.upload(obj, obj_sub)
            except _Unreadable as exc:
                if exc.abort_code in _MISSING:
                    problems.append((Rule.ENTRY_MISSING, f"{where}, which the slave does not "
                                                         f"have (abort 0x{exc.abort_code:08X})"))
                    continue
            ok, why = yield from _mappable(mailbox, device, obj, obj_sub, direction)
            if ok is False:
                kind = "an RxPDO (outputs)" if direction == "R" else "a TxPDO (inputs)"
                problems.append((Rule.ENTRY_NOT_MAPPABLE,
                                 f"{where}, which may not be mapped into {kind}: {why}"))
    return pdos, bits


def _process_data(position: int, outputs: bool, fields: dict[str, Any],
                  mailbox: _Mailbox | None, context: Context,
                  rules: list[Rule]) -> Step[list[str]]:
    """0x001D / 0x001E: each process-data SM of that direction as the slave's SII gives it
    (start, mode and direction; OpOnly), against what the ESC holds (0x0800 + 8·n), the
    bits the PDO assignment and mappings the slave holds need (over CoE; from the SII's
    fixed PDOs without CoE) and the FMMUs over it: every rule of ``runtime/refusals.py``
    that fails is named."""
    sms, fmmus = yield from _sms(position)
    status = (yield from _registers(position, [(Reg.AL_STATUS, 2)])).get(Reg.AL_STATUS)
    in_preop = status is not None and status[0] & AL_STATE_MASK == AlState.PREOP
    want_dir = SM_DIR_ECAT_WRITES if outputs else 0
    kind = FmmuType.WRITE if outputs else FmmuType.READ
    direction = "R" if outputs else "T"
    lines: list[str] = []
    try:
        sii: _SiiLayout | None = yield from _sii(position)
    except _Unreadable as exc:
        sii = None
        lines.append(exc.message)
    from ecatcfg.esi.sii import SM_OP_ONLY, SM_VIRTUAL
    candidates: list[tuple[int, SiiSyncManager | None]]
    if sii is not None:
        sm_type = SM_TYPE_CODES["Outputs" if outputs else "Inputs"]
        candidates = [(n, ssm) for n, ssm in enumerate(sii.sms)
                      if ssm.type == sm_type and not ssm.enable & SM_VIRTUAL and n < len(sms)]
    else:
        candidates = [(n, None) for n, sm in enumerate(sms)
                      if n >= 2 and sm.control & SM_MODE_MASK == SM_MODE_BUFFERED
                      and sm.control & SM_DIR_MASK == want_dir and (sm.length or sm.enable)]
    device = _esi_device(context)
    found: list[dict[str, Any]] = []
    compared = False
    for n, ssm in candidates:
        sm = sms[n]
        entry: dict[str, Any] = {"sm": n, "register": f"0x{sm_register(n):04X}",
                                 "start": sm.start, "length": sm.length,
                                 "enabled": sm.enable}
        problems: list[tuple[Rule, str]] = []
        held = None
        if mailbox is not None:
            held = yield from _assignment(mailbox, n, direction, device, problems)
        bits: int | None
        if held is not None:
            pdos, bits = held
            shown = ", ".join(f"0x{p:04X}" for p in pdos) or "none"
            source = (f"the PDO assignment the slave holds (0x{SM_PDO_ASSIGN + n:04X} = "
                      f"{shown})")
            entry.update({"assign_object": f"0x{SM_PDO_ASSIGN + n:04X}",
                          "assigned_pdos": [f"0x{p:04X}" for p in pdos]})
        elif sii is not None:
            bits = sum(p.bit_length for p in sii.pdos if p.sm == n)
            shown = ", ".join(f"0x{p.index:04X}" for p in sii.pdos if p.sm == n) or "none"
            source = f"the fixed PDOs of the slave's SII ({shown})"
        else:
            bits, source = None, ""
        if bits is not None:
            need = (bits + 7) // 8
            entry["assigned_bytes"] = need
            compared = True
            if ssm is not None and ssm.enable & SM_OP_ONLY and in_preop and not sm.enable:
                found.append(entry)
                continue                       # enabled only in SAFEOP->OP (SII OpOnly)
            if not need:
                if sm.enable and sm.length:
                    problems.append((Rule.SM_LENGTH,
                                     f"SM{n} length {sm.length} bytes "
                                     f"(0x{sm_register(n) + 2:04X}), but {source} maps no "
                                     "data"))
                found.append(entry)
                _said(problems, lines, rules)
                continue
            if not sm.enable:
                problems.append((Rule.SM_DISABLED, f"SM{n} not enabled "
                                 f"(0x{sm_register(n) + 6:04X} bit 0 = 0), but {source} maps "
                                 f"{need} bytes"))
            if ssm is not None and sm.start != ssm.start:
                problems.append((Rule.SM_START, f"SM{n} starts at 0x{sm.start:04X} "
                                 f"(0x{sm_register(n):04X}), the slave's SII places it at "
                                 f"0x{ssm.start:04X}"))
            if need != sm.length:
                problems.append((Rule.SM_LENGTH,
                                 f"SM{n} length {sm.length} bytes (0x{sm_register(n) + 2:04X}), "
                                 f"but {source} gives {need} bytes; check the ENI's PDO "
                                 "assignment InitCmds were accepted"))
        if ssm is not None and sm.control & SM_MODE_AND_DIRECTION \
                != ssm.control & SM_MODE_AND_DIRECTION:
            problems.append((Rule.SM_CONTROL, f"SM{n} control 0x{sm.control:02X} "
                             f"(0x{sm_register(n) + 4:04X}): mode and direction (bits 0-3) "
                             f"differ from the SII's 0x{ssm.control:02X}"))
        elif ssm is None and bits is None and not sm.enable:
            problems.append((Rule.SM_DISABLED,
                             f"SM{n} not enabled (0x{sm_register(n) + 6:04X} bit 0 = 0)"))
        covered = fmmus_cover([f for f in fmmus if f.active], sm.start, sm.length, kind)
        entry["fmmu_covers"] = covered
        if not covered and (sm.length or bits):
            problems.append((Rule.NO_FMMU,
                             f"no {'write' if outputs else 'read'} FMMU maps all of SM{n} "
                             f"(0x{sm.start:04X}, {sm.length} bytes; FMMUs at 0x0600)"))
        found.append(entry)
        _said(problems, lines, rules)
    fields["sync_managers"] = found
    if not found:
        lines.append(f"no {'output' if outputs else 'input'} SyncManager is configured "
                     "(0x0800: none in buffered mode with that direction)")
    elif not rules and compared:
        lines.append("the SyncManagers, the bits the slave's PDOs map and the FMMUs agree "
                     "with its SII; the rule that refused is none the master can read: the "
                     "slave's firmware checks more (its 0x10F3 or manual)")
    elif not rules:
        lines.append(", ".join(f"SM{e['sm']} length {e['length']} bytes" for e in found)
                     + ", enabled, under an FMMU; no PDO assignment read over CoE (no "
                     "CoE, or no working mailbox) and no SII read: the slave compares the "
                     "length with its fixed PDOs (its ESI)")
    return lines


def _said(problems: list[tuple[Rule, str]], lines: list[str], rules: list[Rule]) -> None:
    for rule, text in problems:
        rules.append(rule)
        lines.append(text)


def _watchdog(position: int, fields: dict[str, Any]) -> Step[list[str]]:
    regs = yield from _registers(position, [(Reg.WATCHDOG_DIVIDER, 2), (Reg.WATCHDOG_SM, 2),
                                            (Reg.WATCHDOG_STATUS, 2),
                                            (Reg.WATCHDOG_COUNTER_SM, 1)])
    if len(regs) < 4:
        raise _Unreadable("watchdog registers (0x0400-0x0442) not read")
    divider = struct.unpack("<H", regs[Reg.WATCHDOG_DIVIDER])[0]
    ticks = struct.unpack("<H", regs[Reg.WATCHDOG_SM])[0]
    expired = not regs[Reg.WATCHDOG_STATUS][0] & 1
    counter = regs[Reg.WATCHDOG_COUNTER_SM][0]
    ms = ticks * watchdog_base_ns(divider) / 1e6
    fields["watchdog"] = {"divider": divider, "sm_watchdog_time": ticks, "time_ms": ms,
                          "expired": expired, "counter": counter}
    return [f"no process data for {ms:g} ms: outputs stopped arriving for longer than the "
            f"SM watchdog time (0x0420 = {ticks} x {watchdog_base_ns(divider) / 1000:g} µs, "
            f"0x0400 = {divider}); watchdog status 0x0440 = "
            f"{'expired' if expired else 'running'}, counter 0x0442 = {counter}"]


def _min_cycle_held(mailbox: _Mailbox | None) -> Step[tuple[int, int] | None]:
    """The minimum cycle time the slave reports over CoE (0x1C32:05, else 0x1C33:05; ETG.1020
    SyncManager parameters) and its index; None where it has neither or no mailbox works."""
    if mailbox is None:
        return None
    for index in (SM_OUTPUT_PARAMETER, SM_INPUT_PARAMETER):
        try:
            value = _u((yield from mailbox.upload(index, SM_PARAMETER_MIN_CYCLE)))
        except _Unreadable:
            continue
        if value:
            return value, index
    return None


def _dc(position: int, context: Context, fields: dict[str, Any],
        mailbox: _Mailbox | None, named: list[Rule]) -> Step[list[str]]:
    from ecatcfg.esi.dc_cycle import min_cycle_time, sync0_rules, us
    regs = yield from _registers(position, [(Reg.DC_CYCLIC_UNIT_CONTROL, 2),
                                            (Reg.DC_SYNC0_CYCLE_TIME, 8)])
    if len(regs) < 2:
        raise _Unreadable("DC registers (0x0980, 0x09A0) not read")
    assign = struct.unpack("<H", regs[Reg.DC_CYCLIC_UNIT_CONTROL])[0]
    activation = assign >> 8
    sync0, sync1 = struct.unpack("<II", regs[Reg.DC_SYNC0_CYCLE_TIME])
    dc: dict[str, Any] = {"activation": activation, "sync0_cycle_ns": sync0,
                          "sync1_cycle_ns": sync1}
    fields["dc"] = dc
    text = (f"SYNC activation 0x0981 = 0x{activation:02X}, SYNC0 cycle time 0x09A0 = "
            f"{sync0} ns, SYNC1 cycle time 0x09A4 = {sync1} ns")
    if sync0_running(activation) and not sync0:
        text += ": SYNC0 is on without a cycle time (no InitCmd wrote 0x09A0?)"
        named.append(Rule.SYNC0_NO_CYCLE)
    lines = [text]
    slave = context.slave
    eni_ns = slave.dc.cycle_time0 if slave is not None and slave.dc is not None else None
    if eni_ns is not None:
        dc["eni_sync0_cycle_ns"] = eni_ns
        lines.append(f"the ENI's SYNC0 cycle time is {eni_ns} ns")
    cycle = sync0 or eni_ns            # the cycle the slave was asked to run at
    whose = "the SYNC0 cycle" if sync0 else "the ENI's SYNC0 cycle"
    held = yield from _min_cycle_held(mailbox)
    if held is not None:
        ns, index = held
        dc["min_cycle_ns"] = ns
        said = (f"the slave's minimum cycle time 0x{index:04X}:{SM_PARAMETER_MIN_CYCLE:02X} "
                f"= {ns} ns")
        if cycle and cycle < ns:
            lines.append(f"{whose} {us(cycle)}, the device allows ≥ {us(ns)} ({said})")
            if sync0_running(activation) and sync0:
                named.append(Rule.SYNC0_BELOW_MINIMUM)
        else:
            lines.append(said)
    try:
        device, where = context.device()
    except EcatcfgError as exc:         # an ESI file that does not read: said, not raised
        device, where = None, f"the device's ESI was not read: {exc.message}"
    if device is None:
        lines.append("with --esi, the cycle would be compared with the device's DC op modes "
                     "and its ESI minimum cycle time" + (f" ({where})" if where else ""))
        return lines
    minimum = min_cycle_time(device)
    rules = sync0_rules(device)
    esi: dict[str, Any] = {"device": where,
                           "min_cycle_ns": minimum.ns if minimum else None,
                           "op_modes": [{"name": r.mode,
                                         "assign_activate": r.assign_activate,
                                         "factor": r.factor, "fixed_ns": r.fixed_ns,
                                         "cycle_ns": r.cycle_ns(context.bus_cycle_ns)}
                                        for r in rules]}
    dc["esi"] = esi
    if minimum is not None and cycle and cycle < minimum.ns and held is None:
        lines.append(f"{whose} {us(cycle)}, the device allows ≥ {us(minimum.ns)} "
                     f"(its ESI: {minimum.text()})")
    elif minimum is not None:
        lines.append(f"the device's ESI gives a {minimum.text()}")
    # The op mode the slave runs (the AssignActivate written), else every one with SYNC0.
    running = [r for r in rules if r.assign_activate >> 8 == activation] or rules
    for rule in running:
        want = rule.cycle_ns(context.bus_cycle_ns)
        line = rule.text()
        if want and cycle and want != cycle:
            line += f" = {us(want)}, not {us(cycle)}"
        elif want:
            line += f" = {us(want)}"
        lines.append(line)
    if not rules:
        lines.append(f"the device's ESI ({where}) has no DC op mode with SYNC0")
    return lines


def _soe_invalid(mailbox: _Mailbox, fields: dict[str, Any],
                 rules: list[Rule]) -> Step[list[str]]:
    """Each drive's S-0-0021 (IDN-list of invalid operation data for CP2), from drive 0 on
    until one the slave does not have (SoE error 0x800A, invalid drive number)."""
    from ecatcfg.esi.idn import IDN_LIST_INVALID_CP2, MAX_DRIVE, idn_text
    from ecatcfg.runtime.master.soe_client import SoeRefused
    from ecatcfg.runtime.soe import SOE_INVALID_DRIVE, decode_list

    lines: list[str] = []
    invalid: dict[int, list[str]] = {}
    for drive in range(MAX_DRIVE + 1):
        try:
            value = yield from mailbox.soe_read(IDN_LIST_INVALID_CP2, drive)
            items, _maximum = decode_list(value)
        except SoeRefused as exc:
            if exc.soe_error != SOE_INVALID_DRIVE or not drive:
                lines.append(f"S-0-0021 of drive {drive} not read ({exc.message})")
            break
        except (_Unreadable, ApplyError) as exc:
            lines.append(f"S-0-0021 of drive {drive} not read ({exc.message})")
            break
        except ValueError as exc:
            lines.append(f"S-0-0021 of drive {drive} not read ({exc})")
            break
        idns = [idn_text(int.from_bytes(items[i:i + 2], "little"))
                for i in range(0, len(items) - 1, 2)]
        invalid[drive] = idns
        if idns:
            rules.append(Rule.SOE_IDNS)
            lines.append(f"S-0-0021 of drive {drive} lists {', '.join(idns)}: IDNs the drive "
                         "needs before SAFEOP that are missing or invalid")
    fields["soe_invalid_idns"] = invalid
    return lines


def _mailbox_sms(position: int, boot: bool, fields: dict[str, Any],
                 rules: list[Rule]) -> Step[list[str]]:
    """0x0016 / 0x0015: SM0 and SM1 (0x0800, 0x0808) against the mailbox the slave's SII
    gives (words 0x18-0x1B, in BOOT the bootstrap mailbox of words 0x14-0x17: receive
    offset and size, send offset and size, ETG.2010): start, length, mailbox mode with the
    master writing SM0 and reading SM1, enabled (SOES ESC_checkmbx)."""
    from ecatcfg.runtime.master.scan import sii_words
    regs = yield from _registers(position, [(Reg.SM0, 2 * SM_SIZE)])
    if Reg.SM0 not in regs:
        raise _Unreadable("SM0/SM1 registers (0x0800) not read")
    word = SII_BOOTSTRAP_MAILBOX if boot else SII_STD_MAILBOX
    try:
        words = yield from sii_words(position, word, monotonic() + SII_TIMEOUT)
    except ApplyError as exc:
        raise _Unreadable(f"SII words 0x{word:04X}-0x{word + 3:04X} not read: "
                          f"{exc.message}") from None
    rx, rx_size, tx, tx_size = struct.unpack_from("<4H", words)
    what = "bootstrap mailbox" if boot else "mailbox"
    rule = Rule.BOOTSTRAP_SM if boot else Rule.MAILBOX_SM
    lines: list[str] = []
    wants = ((rx, rx_size, SM_MODE_MAILBOX | SM_DIR_ECAT_WRITES, "receive"),
             (tx, tx_size, SM_MODE_MAILBOX, "send"))
    found = []
    for n, (start, size, control, side) in enumerate(wants):
        sm = SmConfig.from_bytes(regs[Reg.SM0][SM_SIZE * n:])
        found.append({"sm": n, "start": sm.start, "length": sm.length, "control": sm.control,
                      "enabled": sm.enable, "sii_start": start, "sii_length": size})
        problems = []
        if (sm.start, sm.length) != (start, size):
            problems.append(f"0x{sm.start:04X}, {sm.length} bytes, the SII's {what} {side} "
                            f"area is 0x{start:04X}, {size} bytes (SII word "
                            f"0x{word + 2 * n:04X})")
        if sm.control & SM_MODE_AND_DIRECTION != control:
            problems.append(f"control 0x{sm.control:02X}: mode and direction must be "
                            f"0x{control:02X}")
        if not sm.enable:
            problems.append("not enabled")
        if problems:
            rules.append(rule)
            lines.append(f"SM{n} (0x{sm_register(n):04X}) " + "; ".join(problems))
    fields["mailbox_sms"] = found
    if not lines:
        lines.append(f"SM0 and SM1 are the {what} the SII gives")
    return lines


def _state_request(position: int, code: int, fields: dict[str, Any],
                   rules: list[Rule]) -> Step[list[str]]:
    """0x0011 / 0x0012 / 0x0013: the state the master asked for (AL control 0x0120) and
    the one the slave is in (0x0130), against the AL state machine (ETG.1000.6): INIT to
    PREOP or BOOT, PREOP to SAFEOP, SAFEOP to OP and back down; BOOT only from and to INIT,
    and only with a bootstrap mailbox (SII words 0x14-0x17)."""
    regs = yield from _registers(position, [(Reg.AL_CONTROL, 2), (Reg.AL_STATUS, 2)])
    if len(regs) < 2:
        raise _Unreadable("AL control and status (0x0120, 0x0130) not read")
    asked = regs[Reg.AL_CONTROL][0] & AL_STATE_MASK
    held = regs[Reg.AL_STATUS][0] & AL_STATE_MASK
    fields["requested_state"] = al_state_name(asked)
    text = (f"AL control 0x0120 asks for {al_state_name(asked)}, the slave is in "
            f"{al_state_name(held)}")
    if code == AlStatusCode.UNKNOWN_STATE:
        rules.append(Rule.UNKNOWN_STATE)
        return [f"{text}: 0x{asked:X} is no AL state"]
    if code == AlStatusCode.BOOT_NOT_SUPPORTED:
        rules.append(Rule.BOOT_UNSUPPORTED)
        return [f"{text}: the slave has no boot loader (BOOT needs a bootstrap mailbox, SII "
                f"words 0x{SII_BOOTSTRAP_MAILBOX:04X}-0x{SII_BOOTSTRAP_MAILBOX + 3:04X})"]
    rules.append(Rule.STATE_CHANGE)
    return [f"{text}: not a transition of the AL state machine (INIT-PREOP-SAFEOP-OP step "
            "by step up; BOOT from and to INIT only)"]


def _diagnosis_message(mailbox: _Mailbox, fields: dict[str, Any]) -> Step[list[str]]:
    """The newest 0x10F3 message, where the slave has the object; nothing otherwise."""
    try:
        newest = (yield from mailbox.upload(DIAG_HISTORY, DIAG_NEWEST))[0]
        if newest < DIAG_FIRST_MESSAGE:
            return []
        message = yield from mailbox.upload(DIAG_HISTORY, newest)
    except (_Unreadable, IndexError):
        return []
    if len(message) < 16:
        return []
    diag_code, flags, text_id, stamp = struct.unpack_from("<IHHQ", message)
    fields["diagnosis_message"] = {"subindex": newest, "diag_code": diag_code,
                                   "flags": flags, "text_id": text_id, "time_stamp": stamp,
                                   "parameters": message[16:].hex()}
    return [f"newest diagnosis message 0x10F3:{newest:02X}: code 0x{diag_code:08X}, text ID "
            f"0x{text_id:04X}, flags 0x{flags:04X}"]


# -- identity ----------------------------------------------------------------------------------

def identity_cause(mismatch: Mismatch, found: tuple[int, int, int] | None) -> list[str]:
    """The line of a slave whose SII identity is not the ENI's: where the slave holds it
    (SII words 0x0008, 0x000A, 0x000C) and the values read."""
    if found is None:
        return []
    vendor, product, revision = found
    return [f"position {mismatch.position}: the slave's SII holds vendor ID "
            f"0x{vendor:08X} (word 0x{SII_VENDOR_ID:04X}), product code 0x{product:08X} "
            f"(word 0x{SII_PRODUCT_CODE:04X}), revision 0x{revision:08X} "
            f"(word 0x{SII_REVISION:04X}); the ENI expects {mismatch.expected}"]


@record
class Finding:
    """One slave ``ecatcfg doctor`` reports: not in its target state, or not the ENI's."""

    position: int
    name: str | None            # its ENI name, with an ENI
    state: str                  # AL status as read ("PREOP+ERR"), or "no answer"
    cause: Cause | None
    identity: list[str]         # lines of an identity that is not the ENI's

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"position": self.position, "name": self.name,
                               "state": self.state, "identity": self.identity or None}
        if self.cause is not None:
            out.update(self.cause.as_json())
        return out


def doctor(transport: Transport, target: AlState, plan: NetworkPlan | None = None,
           esi: Library | None = None) -> tuple[int, list[Finding]]:
    """Every slave on the line that is not in ``target`` without the error flag, or, with
    the ENI ``plan``, whose SII identity is not the ENI's: the number of slaves and one
    :class:`Finding` each, with the cause of its AL status code.  ``esi``: the ESI files the
    devices are found in (by the identity in each slave's SII) for what the causes compare
    with the ESI."""
    from ecatcfg.runtime.master.scan import FoundSlave, count_slaves, paired, scan, verify
    count = count_slaves(transport)
    names: dict[int, SlavePlan] = {}
    identity: dict[int, list[str]] = {}
    found: list[FoundSlave] = []
    if plan is not None or esi is not None:
        found = scan(transport)
    if plan is not None:
        pairs = paired(plan, found)
        for s in plan.slaves:
            if pairs.get(s.position) is not None:
                names[pairs[s.position]] = s
        for m in verify(plan, found, accept_newer_revision=True):
            at = pairs.get(m.position) if m.expected != "-" else m.position
            if at is None:
                continue
            lines = identity_cause(m, found[at].identity) if m.problem.startswith(
                ("other device", "other revision")) else [f"{m.problem}: {m.found}"]
            identity.setdefault(at, []).extend(lines)
    bus_cycle_ns = bus_cycle(plan) if plan is not None else None
    sii = {s.position: s.identity for s in found}
    findings = []
    jobs: list[Job] = []
    for position, st in enumerate(states(transport, count)):
        slave = names.get(position)
        name = slave.name if slave is not None else None
        if st is None:
            findings.append(Finding(position, name, "no answer", None,
                                    identity.get(position, [])))
            continue
        state, error, code = st
        shown = al_state_name(state | (AL_STATUS_ERROR if error else 0))
        if state == target and not error and position not in identity:
            continue
        finding = Finding(position, name, shown, None, identity.get(position, []))
        findings.append(finding)
        if code or error:
            context = Context(slave=slave if position not in identity else None,
                              bus_cycle_ns=bus_cycle_ns, esi=esi,
                              identity=sii.get(position))
            jobs.append(_explain_into(finding, code, context))
    # Every slave's diagnosis at once, their frames shared (each its own mailbox).
    run_jobs(transport, jobs)
    return count, findings


def _explain_into(finding: Finding, code: int, context: Context) -> Job:
    finding.cause = yield from explain_step(finding.position, code, context)


def bus_cycle(plan: NetworkPlan) -> int | None:
    """The ENI's bus cycle in ns (``Cyclic/CycleTime``), None where it gives none: what an
    op mode's SYNC0 factor multiplies."""
    us = next((c.cycle_time for c in plan.cyclic if c.cycle_time), None)
    return us * 1000 if us else None


def states(transport: Transport, count: int) -> list[tuple[int, bool, int] | None]:
    """AL state, error flag and status code of the first ``count`` slaves, read in one
    round (None: no answer)."""
    read: dict[int, dict[int, bytes]] = {p: {} for p in range(count)}
    run_jobs(transport, [_read(p, Reg.AL_STATUS, 6, read[p]) for p in range(count)])
    out: list[tuple[int, bool, int] | None] = []
    for position in range(count):
        status = read[position].get(Reg.AL_STATUS)
        if status is None:
            out.append(None)
            continue
        al_status, _, code = struct.unpack("<HHH", status)
        out.append((al_status & AL_STATE_MASK, bool(al_status & AL_STATUS_ERROR), code))
    return out
