"""The ESC register table: name, size, unit and decoded fields of each register, one
definition for every tool that names a register (``ecatcfg reg`` and ``counters``, the words
of ``show``, ``diff``, ``report`` and apply's messages in ``eni/words.py``): ETG.1000.4 and
the Beckhoff ESC datasheet Section II register descriptions.  Every register an ENI of the
corpora writes or reads is here (``tests/test_registers.py`` sweeps them).  Layouts that
configuration also writes are esc.py's (``SmConfig``, ``FmmuConfig``, the SyncManager, AL
and watchdog bits); this module only puts names on them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ecatcfg.esc import (AL_ERROR_ACK, AL_ID_REQUEST, AL_STATE_MASK, AL_STATUS_ERROR,
                         AL_STATUS_ID, FMMU_SIZE, PORT_LETTERS, SM_ACTIVATE_ENABLE,
                         SM_ACTIVATE_REPEAT, SM_DIR_ECAT_WRITES, SM_DIR_MASK, SM_ECAT_EVENT,
                         SM_MODE_MAILBOX, SM_MODE_MASK, SM_PDI_EVENT, SM_SIZE,
                         SM_STATUS_MAILBOX_FULL, SM_WATCHDOG_ENABLE, FmmuConfig, Reg,
                         SmConfig, al_state_name, al_status_name, fmmu_register,
                         sm_register, watchdog_base_ns)
from ecatcfg.record import record

Fields = dict[str, Any]
N_FMMU = 16            # register space for 16 FMMUs and 16 SyncManagers (Section II)
N_SM = 16


@record(frozen=True)
class Register:
    address: int
    size: int
    name: str
    decode: Callable[[bytes], Fields]
    unit: str | None = None        # of the value: "ns", "watchdog steps", ...


@record(frozen=True)
class Decoded:
    """One known register inside a read: its raw value (little-endian) and fields."""

    address: int
    size: int
    name: str
    value: int
    fields: Fields


def _u(data: bytes) -> int:
    return int.from_bytes(data, "little")


def _plain(data: bytes) -> Fields:
    return {}


def _al_status(data: bytes) -> Fields:
    v = _u(data)
    return {"state": al_state_name(v & AL_STATE_MASK), "error": bool(v & AL_STATUS_ERROR),
            "id_loaded": bool(v & AL_STATUS_ID)}


def _al_control(data: bytes) -> Fields:
    v = _u(data)
    return {"state": al_state_name(v & AL_STATE_MASK), "acknowledge": bool(v & AL_ERROR_ACK),
            "id_request": bool(v & AL_ID_REQUEST)}


def _al_code(data: bytes) -> Fields:
    return {"text": al_status_name(_u(data))}


def _dl_status(data: bytes) -> Fields:
    # 0x0110: bit 0 PDI operational, bit 1 PDI watchdog status (1 = reloaded), bit 2
    # enhanced link detection; bits 4-7 physical link on port 0-3; bits 8+2n loop of port
    # n closed, 9+2n communication established on port n (ESC Section II 0x0110).
    v = _u(data)
    fields: Fields = {"pdi_operational": bool(v & 1), "pdi_watchdog_reloaded": bool(v & 2),
                      "enhanced_link_detection": bool(v & 4)}
    for n in range(4):
        fields[f"port_{PORT_LETTERS[n]}"] = {
            "link": bool(v >> (4 + n) & 1), "loop": "closed" if v >> (8 + 2 * n) & 1
            else "open", "communication": bool(v >> (9 + 2 * n) & 1)}
    return fields


def _sm(data: bytes) -> Fields:
    sm = SmConfig.from_bytes(data)
    return {"start": sm.start, "length": sm.length, "control": sm.control,
            "mode": "mailbox" if sm.control & SM_MODE_MASK == SM_MODE_MAILBOX
            else "buffered" if sm.control & SM_MODE_MASK == 0 else "reserved",
            "direction": "ECAT writes" if sm.control & SM_DIR_MASK == SM_DIR_ECAT_WRITES
            else "ECAT reads" if sm.control & SM_DIR_MASK == 0 else "reserved",
            "ecat_event": bool(sm.control & SM_ECAT_EVENT),
            "pdi_event": bool(sm.control & SM_PDI_EVENT),
            "watchdog": bool(sm.control & SM_WATCHDOG_ENABLE),
            "status": sm.status, "mailbox_full": bool(sm.status & SM_STATUS_MAILBOX_FULL),
            "enable": bool(data[6] & SM_ACTIVATE_ENABLE),
            "repeat": bool(data[6] & SM_ACTIVATE_REPEAT),
            "pdi_control": sm.pdi_control}


def _fmmu(data: bytes) -> Fields:
    f = FmmuConfig.from_bytes(data)
    return {"logical_start": f.logical_start, "length": f.length,
            "logical_start_bit": f.logical_start_bit, "logical_stop_bit": f.logical_stop_bit,
            "physical_start": f.physical_start, "physical_start_bit": f.physical_start_bit,
            "type": f.type.name, "active": f.active}


def _time_difference(data: bytes) -> Fields:
    # 0x092C: sign and magnitude; bit 31 set: the local copy of the system time is smaller
    # than the received one (ESC Section II 0x092C).
    v = _u(data)
    return {"ns": -(v & 0x7FFFFFFF) if v & 0x80000000 else v & 0x7FFFFFFF}


def _activation(data: bytes) -> Fields:
    # 0x0981: bit 0 cyclic operation, bit 1 SYNC0, bit 2 SYNC1 (ETG.1000.4; AssignActivate
    # high byte).
    v = _u(data)
    return {"cyclic_operation": bool(v & 1), "sync0": bool(v & 2), "sync1": bool(v & 4)}


def _counter_pair(data: bytes) -> Fields:
    return {"invalid_frames": data[0], "rx_errors": data[1]}


def _dl_control(data: bytes) -> Fields:
    # 0x0100-0x0103 (ESC Section II): bit 0 forwarding rule (1: non-EtherCAT frames
    # destroyed), bit 1 temporary loop control, bits 8+2n loop port n (0 auto, 1 auto
    # close, 2 open, 3 closed), bits 16-18 RX FIFO size, bit 24 station alias (1: the
    # alias 0x0012 is also a configured address for FPxx commands).
    v = _u(data)
    fields: Fields = {"forward_non_ethercat": not v & 1, "temporary_loop": bool(v & 2)}
    for n in range(4):
        fields[f"loop_port_{PORT_LETTERS[n]}"] = ("auto", "auto close", "open", "closed")[
            v >> (8 + 2 * n) & 3]
    if len(data) >= 3:
        fields["rx_fifo_size"] = v >> 16 & 7
    if len(data) >= 4:
        fields["station_alias_for_fp_commands"] = bool(v >> 24 & 1)
    return fields


def _watchdog_divider(data: bytes) -> Fields:
    return {"step_ns": watchdog_base_ns(_u(data))}


WATCHDOG_STEPS = "watchdog steps (100 us each at the default divider)"

REGISTERS: tuple[Register, ...] = (
    Register(0x0000, 1, "ESC type", _plain),
    Register(0x0001, 1, "ESC revision", _plain),
    Register(0x0002, 2, "ESC build", _plain),
    Register(0x0004, 1, "FMMUs supported", _plain),
    Register(0x0005, 1, "SyncManagers supported", _plain),
    Register(0x0006, 1, "RAM size", _plain, "KiB"),
    Register(Reg.PORT_DESCRIPTOR, 1, "port descriptor", _plain),
    Register(Reg.ESC_FEATURES, 2, "ESC features", _plain),
    Register(Reg.STATION_ADDRESS, 2, "configured station address", _plain),
    Register(Reg.STATION_ALIAS, 2, "configured station alias", _plain),
    Register(0x0100, 4, "DL control", _dl_control),
    Register(Reg.DL_STATUS, 2, "DL status", _dl_status),
    Register(Reg.AL_CONTROL, 2, "AL control", _al_control),
    Register(Reg.AL_STATUS, 2, "AL status", _al_status),
    Register(Reg.AL_STATUS_CODE, 2, "AL status code", _al_code),
    Register(Reg.PDI_CONTROL, 1, "PDI control", _plain),
    Register(Reg.ESC_CONFIG, 1, "ESC configuration", _plain),
    Register(Reg.ECAT_EVENT_MASK, 2, "ECAT event mask", _plain),
    Register(0x0204, 4, "AL event mask", _plain),
    Register(Reg.ECAT_EVENT_REQUEST, 2, "ECAT event request", _plain),
    Register(0x0220, 4, "AL event request", _plain),
    *(Register(Reg.RX_ERROR_COUNTER + 2 * n, 2, f"RX error counter port {PORT_LETTERS[n]}",
               _counter_pair) for n in range(4)),
    *(Register(0x0308 + n, 1, f"forwarded RX error counter port {PORT_LETTERS[n]}", _plain)
      for n in range(4)),
    Register(0x030C, 1, "ECAT processing unit error counter", _plain),
    Register(0x030D, 1, "PDI error counter", _plain),
    *(Register(0x0310 + n, 1, f"lost link counter port {PORT_LETTERS[n]}", _plain)
      for n in range(4)),
    Register(Reg.WATCHDOG_DIVIDER, 2, "watchdog divider", _watchdog_divider,
             "40 ns steps, plus 2"),
    Register(Reg.WATCHDOG_PDI, 2, "PDI watchdog time", _plain, WATCHDOG_STEPS),
    Register(Reg.WATCHDOG_SM, 2, "SM watchdog time", _plain, WATCHDOG_STEPS),
    Register(Reg.WATCHDOG_STATUS, 2, "SM watchdog status", _plain),
    Register(Reg.EEPROM_CONFIG, 1, "EEPROM configuration", _plain),
    Register(Reg.EEPROM_CONTROL, 2, "EEPROM control/status", _plain),
    Register(Reg.EEPROM_ADDRESS, 4, "EEPROM address", _plain, "words"),
    Register(Reg.EEPROM_DATA, 8, "EEPROM data", _plain),
    *(Register(fmmu_register(n), FMMU_SIZE, f"FMMU{n}", _fmmu) for n in range(N_FMMU)),
    *(Register(sm_register(n), SM_SIZE, f"SM{n}", _sm) for n in range(N_SM)),
    *(Register(Reg.DC_RECEIVE_TIME_PORT0 + 4 * n, 4,
               f"DC receive time port {PORT_LETTERS[n]}", _plain, "ns") for n in range(4)),
    Register(Reg.DC_SYSTEM_TIME, 8, "DC system time", _plain, "ns"),
    Register(0x0918, 8, "DC receive time ECAT processing unit", _plain, "ns"),
    Register(0x0920, 8, "DC system time offset", _plain, "ns"),
    Register(0x0928, 4, "DC system time delay", _plain, "ns"),
    Register(Reg.DC_SYSTEM_TIME_DIFFERENCE, 4, "DC system time difference",
             _time_difference, "ns"),
    Register(Reg.DC_SPEED_COUNTER_START, 2, "DC speed counter start", _plain),
    Register(0x0932, 2, "DC speed counter difference", _plain),
    Register(Reg.DC_TIME_FILTER, 1, "DC system time difference filter depth", _plain),
    Register(Reg.DC_TIME_FILTER + 1, 1, "DC speed counter filter depth", _plain),
    Register(Reg.DC_CYCLIC_UNIT_CONTROL, 1, "DC cyclic unit control", _plain),
    Register(Reg.DC_CYCLIC_UNIT_CONTROL + 1, 1, "DC activation", _activation),
    Register(Reg.DC_START_TIME_CYCLIC, 8, "DC start time cyclic operation", _plain, "ns"),
    Register(Reg.DC_SYNC0_CYCLE_TIME, 4, "DC SYNC0 cycle time", _plain, "ns"),
    Register(Reg.DC_SYNC0_CYCLE_TIME + 4, 4, "DC SYNC1 cycle time", _plain, "ns"),
    Register(Reg.DC_LATCH0_CONTROL, 1, "DC latch0 control", _plain),
    Register(Reg.DC_LATCH0_CONTROL + 1, 1, "DC latch1 control", _plain),
)
_BY_ADDRESS = {r.address: r for r in REGISTERS}


def known(address: int) -> Register | None:
    """The register that starts at ``address``, if it is one of ours."""
    return _BY_ADDRESS.get(address)


def containing(address: int) -> tuple[Register, int] | None:
    """The register ``address`` lies in and the byte offset inside it, if it is one of
    ours (a write of 0x0103 is byte 3 of DL control)."""
    for r in REGISTERS:
        if r.address <= address < r.address + r.size:
            return r, address - r.address
    return None


def covered(address: int, size: int) -> list[Register]:
    """The registers of ours a write or read of ``size`` bytes at ``address`` touches, in
    address order."""
    return sorted((r for r in REGISTERS
                   if r.address < address + size and address < r.address + r.size),
                  key=lambda r: r.address)


def decode(address: int, data: bytes) -> list[Decoded]:
    """The known registers wholly inside ``data`` read from ``address``, in address
    order."""
    out: list[Decoded] = []
    end = address + len(data)
    for r in REGISTERS:
        if address <= r.address and r.address + r.size <= end:
            raw = data[r.address - address:r.address - address + r.size]
            out.append(Decoded(r.address, r.size, r.name, _u(raw), r.decode(raw)))
    return sorted(out, key=lambda d: d.address)


def fields_text(fields: Fields) -> str:
    """``state PREOP, error no``; nested fields (a DL status port) in brackets."""
    def one(v: Any, key: str = "") -> str:
        if isinstance(v, bool):
            return "yes" if v else "no"
        if isinstance(v, dict):
            return "[" + ", ".join(f"{k} {one(x)}" for k, x in v.items()) + "]"
        if isinstance(v, int) and v > 9 and key not in _DECIMAL:
            return f"0x{v:X}"
        return str(v)
    return ", ".join(f"{k.replace('_', ' ')} {one(v, k)}" for k, v in fields.items())


_DECIMAL = {"length", "ns", "invalid_frames", "rx_errors"}


__all__ = ["Decoded", "REGISTERS", "Register", "containing", "covered", "decode",
           "fields_text", "known"]
