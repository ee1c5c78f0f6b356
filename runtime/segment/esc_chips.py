"""The EtherCAT slave controller (ESC) inside an emulated slave: what no ESI says.

An ESI describes a device's application (SyncManager use, PDOs, the SII), not the chip that
carries it.  Yet a master sees the chip: the device information registers (0x0000-0x0009:
type, revision, build, number of FMMUs and SyncManagers, RAM size, features), and the
working counter of every access to an FMMU, SyncManager or DC register the chip does not
have (an ESC does not answer for registers it lacks; a BWR to FMMU 3 counts only on the
ESCs that have it).

:data:`KNOWN` records the chip of the devices whose real replies we have, each with the
public capture that shows it.  Every other device gets :data:`GENERIC`, the most capable
ESC (the ET1100's 8 FMMUs and 8 SyncManagers), with RAM up to the end of the address space
so any SyncManager address an ESI gives fits, and a DC unit where its description says the
device's ESC runs one (:func:`has_dc_unit`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ecatcfg.esc import ESC_DC_LATCH_UNIT, ESC_DC_SYNC_UNIT

if TYPE_CHECKING:
    from ecatcfg.esi.model import Device


@dataclass(frozen=True, slots=True)
class EscChip:
    """The device information registers (ESC Section II, 0x0000-0x0009) and which
    optional units the ESC has."""

    name: str
    type: int                       # 0x0000
    revision: int                   # 0x0001
    build: int                      # 0x0002-0x0003
    fmmus: int                      # 0x0004
    sms: int                        # 0x0005
    ram_kb: int                     # 0x0006: process RAM in KiB
    features: int                   # 0x0008-0x0009
    # The DC system-time unit (0x0910-0x09FF: system time, offset, delay, the time control
    # loop, SYNC and latch).  The receive-time latches (0x0900-0x090F) answer on every ESC.
    dc_unit: bool = True
    source: str = ""


# Read from real devices with an FPRD of 0x0000-0x0009 (ethercrab-rs/ethercrab
# dumps/twincat-scan-boxes.pcapng: an EK1100 answers 11 00 0300 08 08 08 3b fc00, an EL1004
# 12 01 0100 03 04 01 4a fc01; the port descriptor 0x0007 follows the ESI's Physics).
ET1100 = EscChip("ET1100", 0x11, 0x00, 0x0003, 8, 8, 8, 0x00FC,
                 source="EK1100 in ethercrab-rs/ethercrab dumps/twincat-scan-boxes.pcapng")
ET1200 = EscChip("ET1200", 0x12, 0x01, 0x0001, 3, 4, 1, 0x01FC,
                 source="EL1004 in ethercrab-rs/ethercrab dumps/twincat-scan-boxes.pcapng")
GENERIC = EscChip("ET1100-class", 0x11, 0x00, 0x0003, 8, 8, 60, 0x00FC,
                  source="no capture of this device: the most capable ESC")

# Devices by (vendor id, product code): the chip their real replies show.
KNOWN: dict[tuple[int, int], EscChip] = {
    # EK1100: device information read in twincat-scan-boxes; its DC registers answer in
    # tests/replay-dc.pcapng.
    (0x2, 0x044C2C52): ET1100,
    # EL1004: an ET1200 (twincat-scan-boxes); no working counter for 0x0910-0x09A7 in
    # dumps/soem-sdinfo-ek1100-el1004.pcapng (its DC unit is not in use).
    (0x2, 0x03EC3052): EscChip("ET1200", 0x12, 0x01, 0x0001, 3, 4, 1, 0x01FC, dc_unit=False,
                               source="EL1004 in dumps/twincat-scan-boxes.pcapng and "
                                      "dumps/soem-sdinfo-ek1100-el1004.pcapng"),
    # EL2828 and EL2889: a BWR to FMMU 3-7 or SM 4-7 counts only on the EK1100 in front of
    # them (tests/replay-ek1100-el2828-el2889.pcapng): 3 FMMUs, 4 SyncManagers.  The
    # EL2828 gives no working counter for any DC register from 0x0910 (FPRD 0x0918,
    # 0x092C; FPWR 0x0920, 0x0928, 0x0981, 0x0990, 0x09A0; FRMW 0x0910), the EL2889 counts
    # for each (tests/replay-dc.pcapng).  Their type register is not read alone in any
    # capture; the BRD of 0x0000 gives 0x13 = ET1100 0x11 | ET1200 0x12.
    (0x2, 0x0B0C3052): EscChip("ET1200", 0x12, 0x01, 0x0001, 3, 4, 1, 0x01FC, dc_unit=False,
                               source="EL2828 in ethercrab-rs/ethercrab tests/replay-*.pcapng"),
    (0x2, 0x0B493052): EscChip("ET1200", 0x12, 0x01, 0x0001, 3, 4, 1, 0x01FC,
                               source="EL2889 in ethercrab-rs/ethercrab tests/replay-*.pcapng"),
    # EL2004: the BWR clearing FMMU 3 counts only on the EK1100 in front of two EL2004, the
    # BWRs to SM 0-3 on all three (ethercrab-rs/ethercrab dumps/rs-example-sii-el2004.pcapng):
    # 3 FMMUs, at least 4 SyncManagers, as the ET1200 of the other Beckhoff terminals.  No
    # DC register is accessed there: the DC unit stays the default.
    (0x2, 0x07D43052): EscChip("ET1200", 0x12, 0x01, 0x0001, 3, 4, 1, 0x01FC,
                               source="EL2004 in ethercrab-rs/ethercrab "
                                      "dumps/rs-example-sii-el2004.pcapng"),
}


def chip_for(vendor: int | None, product: int | None) -> EscChip:
    """The ESC of a device: the one its real replies show, else :data:`GENERIC`."""
    return KNOWN.get((vendor or 0, product or 0), GENERIC)


def esc_configuration(device: Device) -> int | None:
    """ESC configuration 0x0141 as the device's SII loads it: byte 1 of SII word 0, i.e. of
    the ESI's ``Eeprom/ConfigData`` (or of a whole ``Eeprom/Data`` image); None when the
    ESI gives neither."""
    eeprom = device.eeprom
    if eeprom is None:
        return None
    for data in (eeprom.config_data, eeprom.data):
        if data is not None and len(data) >= 2:
            return data[1]
    return None


def has_dc_unit(device: Device) -> bool:
    """Whether the device's ESC runs a DC system-time unit (0x0910-0x09FF), from what its
    ESI (and so its SII) says:

    1. a DC op mode with a non-zero ``AssignActivate``: the master writes it to the SYNC
       activation registers 0x0980-0x0981 (ETG.2000 ``Dc/OpMode``; the SII DC category
       carries it, ETG.2010), which only an ESC with a DC unit has;
    2. else the ESC configuration the SII loads into 0x0141: the DC SYNC output or latch
       input unit enabled (bit 2 or 3; ESC Section II, 0x0141, where 0 means "disabled,
       power saving").  A real EK1100 loads 0x0D and runs its DC unit; a real EK1914
       (0x00), EL1004 and EL2828 (0x01) give no working counter for 0x0910-0x09FF;
    3. an ESI that gives no ESC configuration at all says nothing either way: the most
       capable ESC, with a DC unit.

    The rule cannot see every chip: a real EL2889 runs a DC unit with 0x0141 = 0x01 and no
    DC op mode, so :data:`KNOWN` keeps what its capture shows (docs/protocol-notes.md §2).
    The feature register 0x0008 is the chip's and keeps bit 2 either way, as on those
    real EK1914s, EL1004s and EL2828s."""
    modes = device.dc.opmodes if device.dc is not None else []
    if any(mode.assign_activate for mode in modes):
        return True
    config = esc_configuration(device)
    return config is None or bool(config & (ESC_DC_SYNC_UNIT | ESC_DC_LATCH_UNIT))


def chip_of(device: Device, chip: EscChip) -> EscChip:
    """The ESC an emulated ``device`` gets: ``chip`` (from :func:`chip_for`) when a capture
    shows the device's own, else :data:`GENERIC` with the DC unit its description gives."""
    if chip is not GENERIC or has_dc_unit(device):
        return chip
    return replace(GENERIC, dc_unit=False,
                   source="no capture of this device: the most capable ESC, without the "
                          "DC unit its ESC configuration leaves off")
