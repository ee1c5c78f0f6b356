"""How long real slaves take: the timing model of emulated slaves (``simulate --realistic``).

An emulated slave is instantaneous unless it gets a :class:`SlaveTiming`: then its mailbox
reply shows in SM1 only after the reply latency, AL status keeps the old state until the
state change has had its time, and an EEPROM read keeps 0x0502 busy until it completes.

The figures come per device kind from :data:`TABLE`, each with its source (docs/timing.md
has the table and how ``bench/capture_timing.py`` measures the captures); a device an ESI
describes whose own capture is out of step with its kind has its measured figures in
:data:`DEVICES`, by vendor and product, taken before its kind's.  A device maps to a kind
by what it is (:func:`kind_of`):

- ``esc``: an ESC in device emulation (SII word 0 bit 8, 0x0141 bit 0): no firmware, the
  ESC itself mirrors AL control into AL status; simple Beckhoff I/O terminals and couplers;
- ``drive``: a CiA 402 device (ESI profile 402, or the 0x6040/0x6041 control and status
  words in its PDOs);
- ``firmware``: any other slave (firmware behind the ESC: mailbox devices, SOES slaves).

Override with a JSON file (:func:`load`): per kind any of ``mailbox_reply_ms``,
``reply_start_ms``, ``eeprom_read_ms``, ``eeprom_write_ms`` and ``state_change_ms`` (a map
of transitions: ``IP``, ``PS``, ``SO``, ``OS``, ``SP``, ``SI``, ``OP``, ``OI``, ``PI``),
merged over the table; figures given for a kind also replace the measured figures of that
kind's devices in :data:`DEVICES`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from ecatcfg.errors import EcatcfgError
from ecatcfg.fileio import read_input

if TYPE_CHECKING:
    from ecatcfg.esi.model import Device

KINDS = ("esc", "firmware", "drive")
TRANSITIONS = ("IP", "PS", "SO", "OS", "SP", "SI", "OP", "OI", "PI")
_MS = 1_000_000
# Objects that make a device a CiA 402 drive when its ESI names no profile.
CIA402_WORDS = (0x6040, 0x6041)


@dataclass(frozen=True, slots=True)
class SlaveTiming:
    """One device kind's times, in ns (0: at once)."""

    kind: str
    mailbox_reply_ns: int = 0
    eeprom_read_ns: int = 0
    state_change_ns: dict[str, int] = field(default_factory=dict)
    # The EEPROM's own write cycle after a word is written: a command in that time is not
    # acknowledged (0x0502 bit 13) and not carried out.
    eeprom_write_ns: int = 0
    # From a mailbox request until the firmware writes the first byte of its reply into
    # SM1, which clears the read event (SM1 status bit 1) of the master's last read (ESC
    # datasheet, 0x0805: "cleared after first byte of buffer was written"); the reply
    # shows when its last byte is written, after mailbox_reply_ns.  None: at that time.
    reply_start_ns: int | None = None

    def transition_ns(self, transition: str) -> int:
        """Time of a state change, e.g. ``"PS"`` for PREOP -> SAFEOP."""
        return self.state_change_ns.get(transition, 0)


def _ms(value: float) -> int:
    return round(value * _MS)


# The table: figures in ms, fitted to every capture of both test corpora by
# bench/capture_timing.py (docs/timing.md has the windows, the fit and what stays out of it).
# Every slave's ESC: every one of 1254 reads lies in [0.663, 0.714] ms (the EL6910 of
# ethercrab-rs/ethercrab tests/replay-mailbox-el6910.pcapng bounds it from above).
EEPROM_READ_MS = 0.69
# An EK1100 whose alias EtherCrab writes (ethercrab-rs/ethercrab
# tests/replay-ek1100-alias-address.pcapng): the next write 1.2-3.2 ms after a word write
# reads back 0x2040 (no acknowledge) and is retried; 3.7 and 4.4 ms after, it is taken.
EEPROM_WRITE_MS = 3.5
# Firmware: a real EK1914 coupler with CoE (ethercrab-rs/ethercrab
# tests/replay-ek1914-*.pcapng, the one firmware device with an ESI in the corpora) and the
# EL3004 beside it: CoE SDO replies in [0.35, 0.72] ms (97 of 97), IP in [0.94, 1.73] ms,
# PS in [0.48, 6.28] ms, SO in [0, 1.10] ms.  The SOES demo firmware on a LAN9252
# (dumps/soem-*-lan9252.pcapng: SDO replies after 37-40 ms, IP/PS after 9-19 ms) cannot
# share one figure with them; no ESI describes it, it is left out (docs/timing.md).
FIRMWARE_BACK_MS = 1.335   # no capture shows the transitions back: taken as IP
# The EK1914 (tests/replay-sdo-error.pcapng, tests/replay-ek1914-*.pcapng): SM1's read event
# is cleared by the first poll after a request, within [0, 0.521] ms (7 of 7).
FIRMWARE_REPLY_START_MS = 0.26
# A Kollmorgen AKD servo drive (no ESI in the corpora; classified from its real SII,
# ethercrab-rs/ethercrab dumps/eeprom/akd.hex): CoE SDO replies in [1.54, 1.96] ms (35 of
# 39 mailbox replies; the 4 EoE IP-parameter replies of dumps/twincat-akd-nc-mode.pcapng
# take 7-46 ms and do not even agree with each other), IP in [3.62, 5.00] ms (4 of 5), PI
# in [2.987, 2.991] ms.  PS and SO are in no capture: 100 ms each, the order a SOEM
# maintainer reports for drives entering OP (OpenEtherCATsociety/SOEM#527: "some slaves
# take more than 100ms").  The other transitions back take the PI figure.
DRIVE_BACK_MS = 2.989      # PI
TABLE: dict[str, SlaveTiming] = {
    # Device emulation: the ESC mirrors AL control at once (every state change of the
    # EK1100/EL1004/EL2828/EL2889 captures is visible at the first poll, <= 0.46-0.55 ms).
    "esc": SlaveTiming("esc", 0, _ms(EEPROM_READ_MS), {}, _ms(EEPROM_WRITE_MS)),
    "firmware": SlaveTiming("firmware", _ms(0.535), _ms(EEPROM_READ_MS), {
        "IP": _ms(1.335), "PS": _ms(3.377), "SO": _ms(0.547)} | {
        t: _ms(FIRMWARE_BACK_MS) for t in ("OS", "SP", "SI", "OP", "OI", "PI")},
        _ms(EEPROM_WRITE_MS), reply_start_ns=_ms(FIRMWARE_REPLY_START_MS)),
    "drive": SlaveTiming("drive", _ms(1.749), _ms(EEPROM_READ_MS), {
        "IP": _ms(4.308), "PS": _ms(100.0), "SO": _ms(100.0)} | {
        t: _ms(DRIVE_BACK_MS) for t in ("OS", "SP", "SI", "OP", "OI", "PI")},
        _ms(EEPROM_WRITE_MS)),
}


# Devices an ESI of the corpora describes whose capture puts them out of step with their
# kind: their own figures, by (vendor, product).  What their captures do not show stays the
# kind's.
# EL6910 TwinSAFE logic terminal (ethercrab-rs/ethercrab tests/replay-mailbox-el6910.pcapng,
# EtherCrab polling every 0.1 ms): 10 CoE SDO replies in 1.65-2.07 ms, three times the
# EK1914's; no one figure holds them all, 1.763 ms holds 7 (0x1C00 reads; the 0x100A
# upload and the 0xF008 download take 1.94-2.07 ms); its firmware starts writing a reply
# (SM1's read event clears) within [1.122, 1.196] ms (9 of 10; 0x100A within 0.98-1.09 ms),
# 0.5-0.9 ms before the reply is there; IP within [1.514, 1.600] ms.
EL6910 = (0x2, 0x1AFE3052)
DEVICES: dict[tuple[int, int], SlaveTiming] = {
    EL6910: replace(TABLE["firmware"], mailbox_reply_ns=_ms(1.763),
                    reply_start_ns=_ms(1.159),
                    state_change_ns=TABLE["firmware"].state_change_ns | {"IP": _ms(1.557)}),
}


class EmulatedDevice(Protocol):
    """What the kind of a slave depends on; an emulated slave
    (:class:`~ecatcfg.runtime.segment.slave.EmulatedSlave`) has it.  The slave holds its
    :class:`SlaveTiming`, so this module does not import the slave's."""

    @property
    def device(self) -> Device: ...

    @property
    def device_emulation(self) -> bool: ...


@dataclass(frozen=True, slots=True)
class Timing:
    """The kinds' times a segment gives its slaves."""

    kinds: dict[str, SlaveTiming] = field(default_factory=lambda: dict(TABLE))
    devices: dict[tuple[int, int], SlaveTiming] = field(default_factory=lambda: dict(DEVICES))

    def for_slave(self, slave: EmulatedDevice) -> SlaveTiming:
        device = slave.device
        measured = self.devices.get((device.vendor.id or 0, device.product_code or 0))
        return measured if measured is not None else self.kinds[kind_of(slave)]


def kind_of(slave: EmulatedDevice) -> str:
    """The device kind of an emulated slave (module docstring)."""
    if slave.device_emulation:
        return "esc"
    device = slave.device
    if any(p.profile_no == 402 for p in device.profiles):
        return "drive"
    if any(e.index in CIA402_WORDS for p in device.rx_pdos + device.tx_pdos
           for e in p.entries):
        return "drive"
    return "firmware"


def load(path: str | Path) -> Timing:
    """The table with the overrides of a JSON file (module docstring)."""
    try:
        raw = json.loads(read_input(path).decode("utf-8"))
    except OSError as exc:
        raise EcatcfgError(f"{path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise EcatcfgError(f"{path}:{exc.lineno}: not JSON: {exc.msg}") from None
    return overridden(raw, str(path))


def overridden(raw: object, source: str = "timing") -> Timing:
    """The table with ``raw`` (the parsed JSON of :func:`load`) merged over it."""
    if not isinstance(raw, dict):
        raise EcatcfgError(f"{source}: expected an object of device kinds "
                           f"({', '.join(KINDS)})")
    kinds = dict(TABLE)
    for kind, values in raw.items():
        where = f"{source}: {kind!r}"
        if kind not in KINDS:
            raise EcatcfgError(f"{where}: no such device kind ({', '.join(KINDS)})")
        if not isinstance(values, dict):
            raise EcatcfgError(f"{where}: expected an object")
        t = kinds[kind]
        for key, value in values.items():
            if key == "state_change_ms":
                if not isinstance(value, dict):
                    raise EcatcfgError(f"{where}: state_change_ms: expected an object of "
                                       f"transitions ({', '.join(TRANSITIONS)})")
                changes = dict(t.state_change_ns)
                for tr, ms in value.items():
                    if tr not in TRANSITIONS:
                        raise EcatcfgError(f"{where}: state_change_ms: no transition "
                                           f"{tr!r} ({', '.join(TRANSITIONS)})")
                    changes[tr] = _ms(_milliseconds(ms, f"{where}: {tr}"))
                t = replace(t, state_change_ns=changes)
            elif key == "mailbox_reply_ms":
                t = replace(t, mailbox_reply_ns=_ms(_milliseconds(value, f"{where}: {key}")))
            elif key == "eeprom_read_ms":
                t = replace(t, eeprom_read_ns=_ms(_milliseconds(value, f"{where}: {key}")))
            elif key == "eeprom_write_ms":
                t = replace(t, eeprom_write_ns=_ms(_milliseconds(value, f"{where}: {key}")))
            elif key == "reply_start_ms":
                t = replace(t, reply_start_ns=_ms(_milliseconds(value, f"{where}: {key}")))
            else:
                raise EcatcfgError(f"{where}: unknown key {key!r} (mailbox_reply_ms, "
                                   "reply_start_ms, eeprom_read_ms, eeprom_write_ms, "
                                   "state_change_ms)")
        kinds[kind] = t
    # The user's figures for a kind are for all its devices, the measured ones included.
    return Timing(kinds, {key: t for key, t in DEVICES.items() if t.kind not in raw})


def _milliseconds(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not \
            0 <= value <= 600_000:
        raise EcatcfgError(f"{where}: {value!r} is not a time in ms (0 to 600000)")
    return float(value)
