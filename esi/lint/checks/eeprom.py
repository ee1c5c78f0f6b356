"""ESI5xx: the EEPROM (SII) description, Device/Eeprom."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule
from ecatcfg.esi.model import Device

# ConfigData is the SII config area before its checksum: words 0-6 (PDI control, PDI
# configuration, SYNC impulse length, extended PDI configuration, station alias, 2 reserved);
# word 7 is the CRC the EEPROM programmer computes (ETG.2010).
CONFIG_DATA_MAX = 14
# SII word 0x003E holds the size in kbit minus one: 128-byte steps, at most 0x10000 of them.
EEPROM_STEP, EEPROM_MAX = 128, 0x10000 * 128


@device_rule("ESI501", "error", "Eeprom/ConfigData is longer than the SII config area", """
    ConfigData fills SII words 0-6 (14 bytes): PDI control and configuration, SYNC impulse
    length, extended PDI configuration and the station alias; word 7 is the checksum the
    EEPROM programmer computes.  Longer data would overwrite the checksum and the identity
    (vendor id from word 8), so tools truncate it or refuse it.""")
def config_data_length(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    eep = dev.eeprom
    if eep is not None and eep.config_data is not None and len(eep.config_data) > CONFIG_DATA_MAX:
        yield Hit(eep.source, f"ConfigData is {len(eep.config_data)} bytes; the config area "
                  f"before the checksum is {CONFIG_DATA_MAX}")


@device_rule("ESI502", "warning", "Eeprom/ConfigData does not end on a word", """
    The SII is organised in 16-bit words and each config word is read whole (word 0 feeds
    registers 0x0140/0x0141).  An odd number of bytes leaves the last word half-given; the
    programmer pads it with 0, which may not be what was meant.""")
def config_data_odd(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    eep = dev.eeprom
    if eep is not None and eep.config_data is not None and len(eep.config_data) % 2:
        yield Hit(eep.source, f"ConfigData is {len(eep.config_data)} bytes, not a whole "
                  "number of words")


@device_rule("ESI503", "error", "Eeprom/ByteSize is not a size an SII can have", """
    The SII records its size in word 0x003E as kilobits minus one, so an EEPROM is a
    multiple of 128 bytes between 128 bytes and 8 MiB.  Another ByteSize cannot be written
    into the image, and tools size their EEPROM reads from it.""")
def eeprom_size(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    eep = dev.eeprom
    if eep is None or eep.byte_size is None:
        return
    size = eep.byte_size
    if size % EEPROM_STEP or not EEPROM_STEP <= size <= EEPROM_MAX:
        yield Hit(eep.source, f"ByteSize {size} is not a multiple of {EEPROM_STEP} between "
                  f"{EEPROM_STEP} and {EEPROM_MAX}")
