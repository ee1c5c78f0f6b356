"""The checks emulated firmware makes before it enters PREOP, SAFEOP and OP: what a slave's
AL state machine (``slave.py``) refuses, and with which AL status code.

- INIT->BOOT: SM0/SM1 as the bootstrap mailbox of the slave's SII (0x0015 otherwise);
- INIT->PREOP: the mailbox SyncManagers as the slave's ESI places them, of a length its
  MinSize..MaxSize allows (``SyncManager.takes_mailbox_length``; the Slave Stack Code's
  mailbox check: otherwise 0x0016, invalid mailbox configuration);
- PREOP->SAFEOP (and SAFEOP->OP for SyncManagers the ESI marks OpOnly): each process-data
  SyncManager with the length the assigned PDOs need and an FMMU over it (SOES
  ``ESC_checkSM23``: 0x001D for outputs, 0x001E for inputs); with SYNC0 on, a cycle time
  no shorter than the device's minimum (0x0035, invalid sync cycle time); an SoE drive
  whose required IDNs were not written (0x0045, MBX_SOE: ``soe_refusal``).

Each check reads what the ESC holds (its SyncManagers, FMMUs, registers) and the device's
ESI; none changes anything.  A refusal is a :class:`~ecatcfg.runtime.refusals.Refusal`: the
code, the rule that failed and the values that failed it, which the slave keeps
(``EmulatedSlave.refusal``) and the master's diagnosis must name from what it reads
(``tests/test_diagnosis_agreement.py``).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ecatcfg.esc import (SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES, SM_DIR_MASK, SM_MODE_MAILBOX,
                         SM_MODE_MASK, AlStatusCode, FmmuConfig, FmmuType, Reg,
                         fmmus_cover, sync0_running)
from ecatcfg.esi.model import Device
from ecatcfg.runtime.refusals import Refusal, Rule
from ecatcfg.runtime.segment.syncman import SmState

if TYPE_CHECKING:       # only SoE drives have one
    from ecatcfg.runtime.segment.soe_server import SoeServer

# SM control bits a slave checks against its own SM configuration: mode and direction.
SM_MODE_AND_DIRECTION = SM_MODE_MASK | SM_DIR_MASK


def mailbox_refusal(device: Device, sms: Sequence[SmState]) -> Refusal | None:
    """INIT->PREOP: SM0/SM1 as the slave's own mailbox (start, mode and direction as
    its ESI gives them, a length its MinSize..MaxSize allows), enabled (otherwise 0x0016,
    as the Slave Stack Code's and SOES' mailbox checks); None when they are."""
    for esi_sm in device.sms:
        if esi_sm.type not in ("MBoxOut", "MBoxIn"):
            continue
        sm = sms[esi_sm.number]
        want = (esi_sm.start_address, esi_sm.mailbox_control & SM_MODE_AND_DIRECTION)
        got = (sm.start, sm.control & SM_MODE_AND_DIRECTION)
        # The length: any the ESI's MinSize..MaxSize allows (the one rule, shared with
        # the ENI check: SyncManager.takes_mailbox_length).
        if not sm.enabled or got != want or not esi_sm.takes_mailbox_length(sm.length):
            return Refusal(AlStatusCode.INVALID_MAILBOX, Rule.MAILBOX_SM,
                           f"SM{esi_sm.number} {_sm_text(sm)}, the mailbox is "
                           f"0x{want[0] or 0:04X}+{esi_sm.mailbox_lengths_text()} "
                           f"control 0x{want[1]:02X}")
    return None


def _sm_text(sm: SmState) -> str:
    return (f"0x{sm.start:04X}+{sm.length} control 0x{sm.control:02X} "
            + ("enabled" if sm.enabled else "disabled"))


def bootstrap_refusal(bootstrap: tuple[int, int, int, int], sms: Sequence[SmState]
                      ) -> Refusal | None:
    """INIT->BOOT: SM0/SM1 as the slave's bootstrap mailbox, SII words 0x14-0x17 (receive
    offset, size, send offset, size; ETG.2010), master-written SM0 and master-read SM1 in
    mailbox mode, enabled (SOES ``ESC_checkmbx`` in BOOT: otherwise 0x0015, invalid
    mailbox configuration (BOOT)); None when they are.  A slave without a bootstrap mailbox
    does not support BOOT (0x0013), which the caller decides before."""
    rx_start, rx_size, tx_start, tx_size = bootstrap
    wants = ((rx_start, rx_size, SM_MODE_MAILBOX | SM_DIR_ECAT_WRITES),
             (tx_start, tx_size, SM_MODE_MAILBOX | SM_DIR_ECAT_READS))
    for sm, want in zip(sms[:2], wants, strict=True):
        if not sm.enabled or (sm.start, sm.length,
                              sm.control & SM_MODE_AND_DIRECTION) != want:
            return Refusal(AlStatusCode.INVALID_MAILBOX_BOOT, Rule.BOOTSTRAP_SM,
                           f"SM{sm.number} {_sm_text(sm)}, the bootstrap mailbox is "
                           f"0x{want[0]:04X}+{want[1]} control 0x{want[2]:02X}")
    return None


def default_pd_bits(device: Device) -> dict[int, int]:
    """Process-data bits per SyncManager that the ESI's default PDOs need."""
    bits: dict[int, int] = {sm.number: 0 for sm in device.sms
                            if sm.type in ("Outputs", "Inputs") and not sm.virtual}
    for pdo in device.rx_pdos + device.tx_pdos:
        if pdo.sm in bits and not pdo.virtual:
            bits[pdo.sm] += sum(e.bit_len or 0 for e in pdo.entries)
    return bits


def internally_mapped_sms(device: Device, expected_pd: dict[int, int]) -> frozenset[int]:
    """The process-data SMs whose length the master decides: those of a virtual PDO on
    a device the master cannot map over CoE (no PdoConfig).  ETG.2100 Pdo@Virtual: "pdo
    will be configured internally (based on the configured variables)"; a bridge such
    as the EL6690 or a PC's EtherCAT slave (CX, FC11xx) takes the length its SM is given
    for the variables its user configured on both sides."""
    coe = device.mailbox.coe if device.mailbox is not None else None
    if coe is not None and coe.pdo_config:
        return frozenset()
    numbers: set[int] = set()
    for pdo in device.rx_pdos + device.tx_pdos:
        if not pdo.virtual:
            continue
        sm = device.default_sm(pdo.direction)
        number = pdo.sm if pdo.sm in expected_pd else sm.number if sm else None
        if number is not None:
            numbers.add(number)
    return frozenset(numbers)


def process_data_refusal(device: Device, sms: Sequence[SmState],
                         fmmus: Sequence[FmmuConfig], needed: dict[int, int | None],
                         internal: frozenset[int], op: bool,
                         why: dict[int, tuple[Rule, str]] | None = None) -> Refusal | None:
    """PREOP->SAFEOP (and SAFEOP->OP for OpOnly SMs): each process-data SM as the ESI
    places it, with the length the assigned PDOs need (``needed``: bits per SM, None
    where the assignment cannot be used, ``why`` then says why), enabled exactly when
    there is data, and an FMMU of the right direction over it (SOES ESC_checkSM23: 0x001D
    for outputs, 0x001E for inputs); None when all are.  Control bytes are compared on mode
    and direction.  The first SM that fails, in SM order, gives the refusal."""
    for esi_sm in device.sms:
        if esi_sm.number not in needed:
            continue
        code = (AlStatusCode.INVALID_OUTPUTS if esi_sm.type == "Outputs"
                else AlStatusCode.INVALID_INPUTS)
        n = esi_sm.number
        bits = needed[n]
        if bits is None:
            rule, detail = (why or {}).get(n, (Rule.NO_ASSIGNMENT,
                                                f"SM{n}: no usable PDO assignment"))
            return Refusal(code, rule, detail)
        length = (bits + 7) // 8
        sm = sms[n]
        if esi_sm.op_only and not op and not sm.enabled:
            continue               # enabled only in SAFEOP->OP (ESI OpOnly)
        # An internally mapped SM takes any length from the fixed PDOs' bits on.
        free = n in internal
        if not length and not (free and sm.active):
            if sm.active:
                return Refusal(code, Rule.SM_LENGTH,
                               f"SM{n} length {sm.length}, its assigned PDOs map no data")
            continue
        if not sm.enabled:
            return Refusal(code, Rule.SM_DISABLED,
                           f"SM{n} disabled, its assigned PDOs map {length} bytes")
        if sm.start != esi_sm.start_address:
            return Refusal(code, Rule.SM_START,
                           f"SM{n} starts at 0x{sm.start:04X}, the slave's at "
                           f"0x{esi_sm.start_address or 0:04X}")
        if sm.length < length if free else sm.length != length:
            return Refusal(code, Rule.SM_LENGTH,
                           f"SM{n} length {sm.length}, its assigned PDOs map {length} bytes"
                           + (" or more" if free else ""))
        want = (esi_sm.control_byte or 0) & SM_MODE_AND_DIRECTION
        if sm.control & SM_MODE_AND_DIRECTION != want:
            return Refusal(code, Rule.SM_CONTROL,
                           f"SM{n} control 0x{sm.control:02X}, mode and direction of the "
                           f"slave's 0x{want:02X}")
        kind = FmmuType.WRITE if esi_sm.type == "Outputs" else FmmuType.READ
        if not fmmus_cover(fmmus, sm.start, sm.length, kind):
            return Refusal(code, Rule.NO_FMMU,
                           f"no {'write' if kind == FmmuType.WRITE else 'read'} FMMU covers "
                           f"SM{n} (0x{sm.start:04X}+{sm.length})")
    return None


def dc_refusal(mem: bytearray, min_cycle_ns: int = 0) -> Refusal | None:
    """PREOP->SAFEOP with SYNC0 in cyclic operation (0x0981 bits 0-1): a SYNC0 cycle time
    (0x09A0) that is 0 or shorter than the device's minimum cycle time (its 0x1C32:05 /
    0x1C33:05, ETG.1020; 0 where it has none) is refused with 0x0035, invalid sync cycle
    time, as the Slave Stack Code's StartInputHandler checks it (V4: the cycle against
    MIN_PD_CYCLE_TIME, which it also reports in 0x1C32:05); None otherwise."""
    activation = mem[Reg.DC_CYCLIC_UNIT_CONTROL + 1]
    if sync0_running(activation):
        cycle, = struct.unpack_from("<I", mem, Reg.DC_SYNC0_CYCLE_TIME)
        if not cycle:
            return Refusal(AlStatusCode.DC_INVALID_SYNC_CYCLE, Rule.SYNC0_NO_CYCLE,
                           f"SYNC0 on (0x0981 = 0x{activation:02X}), 0x09A0 = 0")
        if cycle < min_cycle_ns:
            return Refusal(AlStatusCode.DC_INVALID_SYNC_CYCLE, Rule.SYNC0_BELOW_MINIMUM,
                           f"SYNC0 cycle {cycle} ns, the minimum {min_cycle_ns} ns")
    return None


def soe_refusal(soe: SoeServer) -> Refusal | None:
    """PREOP->SAFEOP of an SoE drive: every IDN its S-0-0018 lists must have been written,
    else it refuses and lists the missing ones in S-0-0021 (``soe_server.py``).  Which AL
    status code a real drive gives then, no public source says (the AX5000 manual says the
    switch "is acknowledged with an error" and lists the IDNs in S-0-0021): the emulation
    gives 0x0045, the code ETG.1000.6 keeps for SoE (MBX_SOE), so a master can tell an SoE
    parameter refusal from a SyncManager or DC one (docs/diagnostics.md)."""
    return (Refusal(AlStatusCode.MBX_SOE, Rule.SOE_IDNS, "IDNs missing (S-0-0021)")
            if soe.safeop_refusal() else None)


def sm_length_note(sms: Sequence[SmState], expected_pd: dict[int, int]) -> str:
    """The process-data SMs whose length differs from what the ESI's default PDOs
    need (legal with device emulation: the slave then moves that many bytes)."""
    diffs = []
    for number, bits in expected_pd.items():
        sm = sms[number]
        got, want = (sm.length if sm.active else 0), (bits + 7) // 8
        if got != want:
            diffs.append(f"SM{number} {got} (ESI {want})")
    return "SM lengths in bytes differ from the ESI: " + ", ".join(diffs) if diffs else ""
