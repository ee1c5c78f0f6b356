"""Why a slave refuses a state: the cause next to its AL status code, read from the slave.

An AL status code (0x0134, ETG.1000.6) says which check a slave's firmware failed, not which
value made it fail.  For the codes below the master reads what that check looks at and
says it in one or two lines (``docs/diagnostics.md`` has the table):

- 0x001D / 0x001E invalid output / input configuration: the process-data SyncManagers of
  that direction (0x0800 + 8·n: start, length, control, activate), the PDO assignment and
  mapping the slave holds over CoE (0x1C10 + n, 0x1600-0x17FF / 0x1A00-0x1BFF) and the FMMUs
  (0x0600 + 16·n) over them: a length that differs from the assigned PDOs' bits, an SM not
  enabled, or no FMMU of that direction over it (SOES ``ESC_checkSM23`` checks the same);
- 0x001B SM watchdog: the watchdog time (0x0420 in the base of 0x0400), its status
  (0x0440) and counter (0x0442): outputs stopped arriving for longer than that time;
- 0x0035 / 0x0036 / 0x0030 DC SYNC: the activation (0x0981), SYNC0/SYNC1 cycle times
  (0x09A0, 0x09A4) and, with an ENI, the cycle time it asks for;
- 0x0045 MBX_SOE (what an emulated SoE drive refuses SAFEOP with, ``runtime/segment/
  al_checks.py``): each drive's S-0-0021, the IDNs it found invalid or missing before
  SAFEOP (the Beckhoff AX5000 documentation of S-0-0021), read over SoE;
- any code: the newest diagnosis message of a slave that has the diagnosis history object
  (0x10F3, ETG.1020 "Diagnosis history": sub 2 newest message, messages from sub 6 on:
  DiagCode u32, Flags u16, TextId u16, time stamp u64, parameters).

Everything is read by auto-increment position, so it works with or without an ENI and
before station addresses are set (``ecatcfg doctor``); CoE goes through ``sdo_tool`` (the
slave's mailbox as its SII and SyncManagers give it).  Nothing here writes a register
except what an SDO upload needs.
"""

from __future__ import annotations

import struct
import time
from typing import TYPE_CHECKING, Any

from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (AL_STATE_MASK, AL_STATUS_ERROR, FMMU_SIZE, SII_PRODUCT_CODE,
                         SII_REVISION, SII_VENDOR_ID, SM_DIR_ECAT_WRITES, SM_DIR_MASK,
                         SM_MODE_BUFFERED, SM_MODE_MAILBOX, SM_MODE_MASK, SM_PDO_ASSIGN,
                         SM_SIZE, AlState, AlStatusCode, Cmd, FmmuConfig, FmmuType, Reg,
                         SmConfig, al_state_name, al_status_name, fmmus_cover, sm_register,
                         watchdog_base_ns)
from ecatcfg.record import record
from ecatcfg.runtime.master.lockstep import Step, run_jobs
from ecatcfg.runtime.master.replay import TIMEOUT_COMMAND, ApplyError
from ecatcfg.runtime.wire import Datagram

if TYPE_CHECKING:
    from ecatcfg.eni.plan import NetworkPlan, SlavePlan
    from ecatcfg.runtime.master.scan import Mismatch
    from ecatcfg.runtime.master.transport import Transport

DIAG_HISTORY = 0x10F3          # ETG.1020 diagnosis history object
DIAG_NEWEST = 2                # its subindex "newest message"
DIAG_FIRST_MESSAGE = 6         # messages from this subindex on
_DC_CODES = (AlStatusCode.DC_INVALID_SYNC, AlStatusCode.DC_INVALID_SYNC_CYCLE,
             AlStatusCode.DC_INVALID_SYNC0_CYCLE, AlStatusCode.DC_INVALID_SYNC1_CYCLE)
SOE_INVALID_CP2 = 21           # S-0-0021, IDN-list of invalid operation data for CP2
SDO_TIMEOUT = 1.0              # s per diagnostic upload: a slave that does not answer is said


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
    """A register or object the diagnosis could not read."""


# -- reading -----------------------------------------------------------------------------------

def _read(position: int, ado: int, length: int, out: dict[int, bytes]) -> Step[None]:
    dg = Datagram.physical(Cmd.APRD, -position & 0xFFFF, ado, length)
    deadline = time.monotonic() + TIMEOUT_COMMAND
    while True:
        reply = yield [dg]
        if reply is not None and reply[0].wkc == 1:
            out[ado] = bytes(reply[0].data)
            return
        if time.monotonic() > deadline:
            return


def read_registers(transport: Transport, position: int,
                   spans: list[tuple[int, int]]) -> dict[int, bytes]:
    """``{address: bytes}`` of each (address, length) read from the slave at ``position``
    (one job per span, sharing frames); a span without an answer is left out."""
    out: dict[int, bytes] = {}
    run_jobs(transport, [_read(position, ado, n, out) for ado, n in spans])
    return out


def _upload(transport: Transport, position: int, index: int, sub: int) -> bytes:
    from ecatcfg.runtime.master.sdo_tool import SdoToolError, sdo_transfer
    try:
        return sdo_transfer(transport, position, index, sub, timeout=SDO_TIMEOUT)
    except (SdoToolError, ApplyError) as exc:
        raise _Unreadable(f"0x{index:04X}:{sub:02X} not read ({exc.message})") from None


def _u(data: bytes) -> int:
    return int.from_bytes(data[:4], "little")


# -- the causes ------------------------------------------------------------------------------

def explain(transport: Transport, position: int, code: int | None = None,
            slave: SlavePlan | None = None) -> Cause:
    """The cause of the slave at ``position`` not being where it was asked to go: its AL
    status code (read when ``code`` is None) and what its check looks at.  ``slave``: its
    ENI entry, when there is one (the DC cycle time the ENI asks for)."""
    regs = read_registers(transport, position, [(Reg.AL_STATUS, 6)])
    status = regs.get(Reg.AL_STATUS)
    fields: dict[str, Any] = {}
    if status is not None:
        al_status, _, read_code = struct.unpack("<HHH", status)
        fields["al_state"] = al_state_name(al_status)
        code = read_code if code is None else code
    code = code or 0
    coe = _mailbox_ready(transport, position)
    lines: list[str] = []
    try:
        if code in (AlStatusCode.INVALID_OUTPUTS, AlStatusCode.INVALID_INPUTS):
            lines += _process_data(transport, position, code == AlStatusCode.INVALID_OUTPUTS,
                                   fields, coe)
        elif code == AlStatusCode.SM_WATCHDOG:
            lines += _watchdog(transport, position, fields)
        elif code in _DC_CODES:
            lines += _dc(transport, position, slave, fields)
        elif code == AlStatusCode.MBX_SOE and coe:
            lines += _soe_invalid(transport, position, fields)
    except _Unreadable as exc:
        lines.append(exc.message)
    if coe:
        lines += _diagnosis_message(transport, position, fields)
    return Cause(position, code, lines, fields)


def _mailbox_ready(transport: Transport, position: int) -> bool:
    """Whether the slave's mailbox works as it is: PREOP or above (not BOOT) with SM0/SM1 in
    mailbox mode and enabled.  Only then are CoE objects read: a diagnosis must not set up
    a mailbox or change a slave's state (``sdo_tool`` would, for a slave below PREOP)."""
    regs = read_registers(transport, position, [(Reg.AL_STATUS, 2), (Reg.SM0, 2 * SM_SIZE)])
    if len(regs) < 2:
        return False
    state = regs[Reg.AL_STATUS][0] & AL_STATE_MASK
    if state not in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        return False
    sm0, sm1 = (SmConfig.from_bytes(regs[Reg.SM0][SM_SIZE * n:]) for n in (0, 1))
    return all(sm.enable and sm.control & SM_MODE_MASK == SM_MODE_MAILBOX for sm in (sm0, sm1))


def _sms(transport: Transport, position: int) -> tuple[list[SmConfig], list[FmmuConfig]]:
    counts = read_registers(transport, position, [(Reg.FMMUS_SUPPORTED, 2)]).get(
        Reg.FMMUS_SUPPORTED)
    if counts is None:
        raise _Unreadable(f"FMMU and SM counts (0x{Reg.FMMUS_SUPPORTED:04X}) not read")
    fmmus_n, sms_n = counts[0], counts[1]
    regs = read_registers(transport, position,
                          [(Reg.SM0, SM_SIZE * sms_n), (Reg.FMMU0, FMMU_SIZE * fmmus_n)])
    if Reg.SM0 not in regs or Reg.FMMU0 not in regs:
        raise _Unreadable("SyncManager (0x0800) and FMMU (0x0600) registers not read")
    sms = [SmConfig.from_bytes(regs[Reg.SM0][SM_SIZE * n:]) for n in range(sms_n)]
    fmmus = [FmmuConfig.from_bytes(regs[Reg.FMMU0][FMMU_SIZE * n:]) for n in range(fmmus_n)]
    return sms, fmmus


def _assigned_bits(transport: Transport, position: int, sm: int
                   ) -> tuple[list[int], int] | None:
    """The PDOs assigned to SM ``sm`` (0x1C10 + sm) and the bits their mappings hold, as the
    slave has them now; None without CoE."""
    index = SM_PDO_ASSIGN + sm
    try:
        count = _upload(transport, position, index, 0)[0]
    except _Unreadable as exc:
        if "does not support CoE" in exc.message:
            return None
        raise
    pdos = [_u(_upload(transport, position, index, k)) & 0xFFFF for k in range(1, count + 1)]
    bits = 0
    for pdo in pdos:
        entries = _upload(transport, position, pdo, 0)[0]
        for k in range(1, entries + 1):
            bits += _u(_upload(transport, position, pdo, k)) & 0xFF
    return pdos, bits


def _process_data(transport: Transport, position: int, outputs: bool,
                  fields: dict[str, Any], coe: bool) -> list[str]:
    sms, fmmus = _sms(transport, position)
    want_dir = SM_DIR_ECAT_WRITES if outputs else 0
    kind = FmmuType.WRITE if outputs else FmmuType.READ
    lines: list[str] = []
    found: list[dict[str, Any]] = []
    for n, sm in enumerate(sms):
        if n < 2 or sm.control & SM_MODE_MASK != SM_MODE_BUFFERED \
                or sm.control & SM_DIR_MASK != want_dir or not (sm.length or sm.enable):
            continue
        held = _assigned_bits(transport, position, n) if coe else None
        entry: dict[str, Any] = {"sm": n, "register": f"0x{sm_register(n):04X}",
                                 "start": sm.start, "length": sm.length,
                                 "enabled": sm.enable}
        problems: list[str] = []
        if held is not None:
            pdos, bits = held
            need = (bits + 7) // 8
            entry.update({"assign_object": f"0x{SM_PDO_ASSIGN + n:04X}",
                          "assigned_pdos": [f"0x{p:04X}" for p in pdos],
                          "assigned_bytes": need})
            if need != sm.length:
                shown = ", ".join(f"0x{p:04X}" for p in pdos) or "none"
                problems.append(
                    f"SM{n} length {sm.length} bytes (0x{sm_register(n) + 2:04X}), but the "
                    f"PDO assignment the slave holds (0x{SM_PDO_ASSIGN + n:04X} = {shown}) "
                    f"gives {need} bytes; check the ENI's PDO assignment InitCmds were "
                    f"accepted")
        if not sm.enable:
            problems.append(f"SM{n} not enabled (0x{sm_register(n) + 6:04X} bit 0 = 0)")
        covered = fmmus_cover([f for f in fmmus if f.active], sm.start, sm.length,
                              kind)
        entry["fmmu_covers"] = covered
        if not covered:
            problems.append(f"no {'write' if outputs else 'read'} FMMU maps all of SM{n} "
                            f"(0x{sm.start:04X}, {sm.length} bytes; FMMUs at 0x0600)")
        found.append(entry)
        lines += problems
    fields["sync_managers"] = found
    if not found:
        lines.append(f"no {'output' if outputs else 'input'} SyncManager is configured "
                     "(0x0800: none in buffered mode with that direction)")
    elif not lines and all("assign_object" in e for e in found):
        lines.append("the SyncManagers, the PDO assignment the slave holds and the FMMUs "
                     "agree; the slave's firmware checks more (its 0x10F3 or manual)")
    elif not lines:
        lines.append(", ".join(f"SM{e['sm']} length {e['length']} bytes" for e in found)
                     + ", enabled, under an FMMU; no PDO assignment read over CoE (no "
                     "CoE, or no working mailbox): the slave compares the length with its "
                     "fixed PDOs (its ESI)")
    return lines


def _watchdog(transport: Transport, position: int, fields: dict[str, Any]) -> list[str]:
    regs = read_registers(transport, position, [(Reg.WATCHDOG_DIVIDER, 2),
                                                (Reg.WATCHDOG_SM, 2),
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


def _dc(transport: Transport, position: int, slave: SlavePlan | None,
        fields: dict[str, Any]) -> list[str]:
    regs = read_registers(transport, position, [(Reg.DC_CYCLIC_UNIT_CONTROL, 2),
                                                (Reg.DC_SYNC0_CYCLE_TIME, 8)])
    if len(regs) < 2:
        raise _Unreadable("DC registers (0x0980, 0x09A0) not read")
    activation = regs[Reg.DC_CYCLIC_UNIT_CONTROL][1]
    sync0, sync1 = struct.unpack("<II", regs[Reg.DC_SYNC0_CYCLE_TIME])
    fields["dc"] = {"activation": activation, "sync0_cycle_ns": sync0,
                    "sync1_cycle_ns": sync1}
    text = (f"SYNC activation 0x0981 = 0x{activation:02X}, SYNC0 cycle time 0x09A0 = "
            f"{sync0} ns, SYNC1 cycle time 0x09A4 = {sync1} ns")
    if activation & 0x03 == 0x03 and not sync0:
        text += ": SYNC0 is on without a cycle time (no InitCmd wrote 0x09A0?)"
    lines = [text]
    if slave is not None and slave.dc is not None:
        eni_ns = slave.dc.cycle_time0
        fields["dc"]["eni_sync0_cycle_ns"] = eni_ns
        lines.append(f"the ENI's SYNC0 cycle time is {eni_ns} ns; the device's DC op modes "
                     "(ESI Dc/OpMode) give the cycle times it accepts")
    return lines


def _soe_invalid(transport: Transport, position: int, fields: dict[str, Any]) -> list[str]:
    """Each drive's S-0-0021 (IDN-list of invalid operation data for CP2), from drive 0 on
    until one the slave does not have (SoE error 0x800A, invalid drive number)."""
    from ecatcfg.esi.idn import idn_text
    from ecatcfg.runtime.master.sdo_tool import SdoToolError
    from ecatcfg.runtime.master.soe_tool import SoeToolError, soe_transfer
    from ecatcfg.runtime.soe import SOE_INVALID_DRIVE, decode_list

    lines: list[str] = []
    invalid: dict[int, list[str]] = {}
    for drive in range(8):
        try:
            value = soe_transfer(transport, position, SOE_INVALID_CP2, drive_no=drive,
                                 timeout=SDO_TIMEOUT)
            items, _maximum = decode_list(value)
        except SoeToolError as exc:
            if exc.soe_error != SOE_INVALID_DRIVE or not drive:
                lines.append(f"S-0-0021 of drive {drive} not read ({exc.message})")
            break
        except (SdoToolError, ApplyError, ValueError) as exc:
            lines.append(f"S-0-0021 of drive {drive} not read ({exc})")
            break
        idns = [idn_text(int.from_bytes(items[i:i + 2], "little"))
                for i in range(0, len(items) - 1, 2)]
        invalid[drive] = idns
        if idns:
            lines.append(f"S-0-0021 of drive {drive} lists {', '.join(idns)}: IDNs the drive "
                         "needs before SAFEOP that are missing or invalid")
    fields["soe_invalid_idns"] = invalid
    return lines


def _diagnosis_message(transport: Transport, position: int,
                       fields: dict[str, Any]) -> list[str]:
    """The newest 0x10F3 message, where the slave has the object; nothing otherwise."""
    try:
        newest = _upload(transport, position, DIAG_HISTORY, DIAG_NEWEST)[0]
        if newest < DIAG_FIRST_MESSAGE:
            return []
        message = _upload(transport, position, DIAG_HISTORY, newest)
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


def doctor(transport: Transport, target: AlState, plan: NetworkPlan | None = None
           ) -> tuple[int, list[Finding]]:
    """Every slave on the line that is not in ``target`` without the error flag, or, with
    the ENI ``plan``, whose SII identity is not the ENI's: the number of slaves and one
    :class:`Finding` each, with the cause of its AL status code."""
    from ecatcfg.runtime.master.scan import count_slaves, paired, scan, verify
    count = count_slaves(transport)
    names: dict[int, SlavePlan] = {}
    identity: dict[int, list[str]] = {}
    if plan is not None:
        found = scan(transport)
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
    findings = []
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
        cause = explain(transport, position, code, slave) if code or error else None
        findings.append(Finding(position, name, shown, cause, identity.get(position, [])))
    return count, findings


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
