"""SII (EEPROM) images: build one from an ESI device, decode any image (ETG.2010 layout).

Every ESC loads its Slave Information Interface from an EEPROM: a 64-word header (config
area with its CRC, identity, mailbox settings, size) followed by typed categories (strings,
general, FMMU, SyncManager, PDO, DC ...).  Masters read it while scanning the bus; SOEM,
for one, sizes the process image of slaves without CoE from the PDO categories alone.

* :func:`build` writes the image a device described by an ESI file should carry, so an
  emulated segment can serve it through the ESC's SII registers (0x0500-0x050F);
* :func:`decode` reads any image, ours or a dump of a real EEPROM, and raises
  :class:`SiiError` naming the byte offset for anything that is not one.

All layouts below follow ``docs/protocol-notes.md`` ("protocol-notes §7"), which names the
open-source implementations they were read from (siitool, KickCAT, EtherCrab, IgH, SOEM) and
the real EEPROM dumps they were checked against; all fields are little-endian.  Addresses in
the SII are 16-bit words: byte offset = 2 x word.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (MAILBOX_PROTOCOL_BITS, SII_BOOTSTRAP_MAILBOX, SII_FIRST_CATEGORY,
                         SII_MAILBOX_PROTOCOLS, SII_SIZE, SII_STD_MAILBOX, SII_VENDOR_ID,
                         SM_TYPE_CODES, mailbox_protocol_names)
from ecatcfg.esi import datatypes
from ecatcfg.esi.model import Device, DcOpMode, Pdo, SyncManager
from ecatcfg.esi.physics import EBUS, ETHERNET, port_kinds

# -- layouts (protocol-notes §7), declared once ----------------------------------------------

# Words 0x00-0x3F.  0x00-0x06 config area (PDI control, PDI configuration, SYNC impulse,
# PDI configuration 2, station alias, 2 reserved), 0x07 checksum (low byte), 0x08-0x0F
# vendor/product/revision/serial, 0x10-0x13 reserved (8 bytes), 0x14-0x1B bootstrap and
# standard mailbox offset/size pairs, 0x1C mailbox protocols, 0x1D-0x3D reserved (66 bytes),
# 0x3E EEPROM size (kbit - 1), 0x3F version.
HEADER = struct.Struct("<7HH4I8x8HH66xHH")
HEADER_SIZE = HEADER.size                       # 128 bytes = 64 words
# The word addresses the master reads one by one (esc.py) are the fields of this layout.
assert (struct.calcsize("<7HH") == 2 * SII_VENDOR_ID
        and struct.calcsize("<7HH4I8x") == 2 * SII_BOOTSTRAP_MAILBOX
        and struct.calcsize("<7HH4I8x4H") == 2 * SII_STD_MAILBOX
        and struct.calcsize("<7HH4I8x8H") == 2 * SII_MAILBOX_PROTOCOLS
        and struct.calcsize("<7HH4I8x8HH66x") == 2 * SII_SIZE
        and HEADER_SIZE == 2 * SII_FIRST_CATEGORY)
CONFIG_AREA = 14                                # words 0-6: what the CRC covers
CATEGORY_HEADER = struct.Struct("<HH")          # type, data length in words
GENERAL = struct.Struct("<12BhBBHH12x")         # exactly 32 bytes (IgH rejects others)
SYNCM = struct.Struct("<HHBBBB")                # start, length, control, status, enable, type
PDO_HEADER = struct.Struct("<HBBBBH")           # index, entries, SM, DC sync, name, flags
PDO_ENTRY = struct.Struct("<HBBBBH")            # index, subindex, name, type, bit length, flags
DC_MODE = struct.Struct("<IIIhHhBB4x")          # ETG.2010 Table 12: 24 bytes per op mode
assert HEADER_SIZE == 128 and GENERAL.size == 32 and DC_MODE.size == 24

# Category types (protocol-notes §7).
CAT_NOP, CAT_STRINGS, CAT_DATATYPES, CAT_GENERAL = 0, 10, 20, 30
CAT_FMMU, CAT_SYNCM, CAT_FMMU_EX, CAT_SYNC_UNIT = 40, 41, 42, 43
CAT_TXPDO, CAT_RXPDO, CAT_DC, CAT_END = 50, 51, 60, 0xFFFF
CATEGORY_NAMES = {CAT_NOP: "NOP", CAT_STRINGS: "STRINGS", CAT_DATATYPES: "DataTypes",
                  CAT_GENERAL: "GENERAL", CAT_FMMU: "FMMU", CAT_SYNCM: "SYNCM",
                  CAT_FMMU_EX: "FMMU_EX", CAT_SYNC_UNIT: "SyncUnit", CAT_TXPDO: "TXPDO",
                  CAT_RXPDO: "RXPDO", CAT_DC: "DC", CAT_END: "END"}
# Categories decode() interprets: the first of each SINGLE type, every REPEATABLE one.
SINGLE = frozenset((CAT_STRINGS, CAT_GENERAL, CAT_FMMU, CAT_SYNCM))
REPEATABLE = frozenset((CAT_TXPDO, CAT_RXPDO, CAT_DC))
# Categories the builder writes from the device description; explicit ESI <Category> data
# of these types is not copied (the generated one is authoritative, see build()).
GENERATED = frozenset((CAT_STRINGS, CAT_GENERAL, CAT_FMMU, CAT_SYNCM, CAT_TXPDO, CAT_RXPDO,
                       CAT_DC))


# GENERAL byte 5, CoE details.
COE_SDO, COE_SDO_INFO, COE_PDO_ASSIGN, COE_PDO_CONFIG, COE_UPLOAD, COE_COMPLETE_ACCESS = (
    0x01, 0x02, 0x04, 0x08, 0x10, 0x20)
COE_DETAIL_NAMES = {COE_SDO: "SDO", COE_SDO_INFO: "SDO info", COE_PDO_ASSIGN: "PDO assign",
                    COE_PDO_CONFIG: "PDO config", COE_UPLOAD: "upload at startup",
                    COE_COMPLETE_ACCESS: "complete access"}
# GENERAL byte 11, flags.
FLAG_SAFEOP, FLAG_NOT_LRW, FLAG_MBOX_DLL, FLAG_IDENT_AL_STS, FLAG_IDENT_PHY_M = (
    0x01, 0x02, 0x04, 0x08, 0x10)
GENERAL_FLAG_NAMES = {FLAG_SAFEOP: "enable SafeOp", FLAG_NOT_LRW: "not LRW",
                      FLAG_MBOX_DLL: "mailbox data link layer",
                      FLAG_IDENT_AL_STS: "ident AL status", FLAG_IDENT_PHY_M: "ident phys. memory"}
# GENERAL bytes 16-17: 4 bits per port (port 0 = low nibble).
PORT_TYPES = {0: "-", 1: "MII", 2: "reserved", 3: "EBUS"}
# The nibble of each port kind (esi/physics.py reads the ESI Physics letters): Ethernet
# ports sit behind an MII, E-bus ports are EBUS; a port that does not exist is 0.
PORT_TYPE_CODES = {ETHERNET: 1, EBUS: 3}

# SYNCM enable byte: b0 enable (protocol-notes §7), b2 virtual SM (IgH), b3 OpOnly (ETG.2010; the
# Beckhoff dumps show 0x09 for the OpOnly output SMs of EL2004/EL2828/EL2889), b1 fixed
# content (ETG.2010, not set by the builder: the ESI has no matching flag).
SM_ENABLE, SM_FIXED, SM_VIRTUAL, SM_OP_ONLY = 0x01, 0x02, 0x04, 0x08
SM_TYPE_NAMES = {code: name or "unused" for name, code in SM_TYPE_CODES.items()}
# FMMU usage byte; an odd count is padded with 0xFF.
FMMU_TYPES = {"Outputs": 1, "Inputs": 2, "MBoxState": 3}
FMMU_TYPE_NAMES = {0: "unused", 1: "outputs", 2: "inputs", 3: "SyncM status", 0xFF: "unused"}
FMMU_PAD = 0xFF
# PDO header flags (siitool; the NI 9144 dump has 0x0010 for Fixed, EL2004 0x0011 for
# Mandatory + Fixed).
PDO_MANDATORY, PDO_FIXED, PDO_VIRTUAL = 0x0001, 0x0010, 0x0020
PDO_FLAG_NAMES = {PDO_MANDATORY: "mandatory", PDO_FIXED: "fixed", PDO_VIRTUAL: "virtual"}
SM_UNASSIGNED = 0xFF

DEFAULT_SIZE = 2048          # bytes, when the ESI gives no Eeprom/ByteSize
SIZE_STEP = 128              # word 0x3E counts 128-byte (1 kbit) steps
MAX_SIZE = 0x10000 * SIZE_STEP
# SOEM caches the SII bytes below EC_MAXEEPBUF (ethercattype.h: EC_MAXEEPBITMAP << 5, 4 KiB)
# and reads 0xFF past it (ethercatmain.c ecx_siigetbyte), so ecx_siifind does not find a
# category that starts there: an image that grows past ByteSize keeps its names only while
# it stays within that window.
SOEM_SII_WINDOW = 4096
MAX_STRINGS = 255            # string indices are one byte; 0 = no string
PAD = 0xFF                   # erased EEPROM


class SiiError(EcatcfgError):
    """Bytes that are not an SII image, or a device that cannot be written into one.

    ``offset`` is the byte offset in the image where decoding failed (``None`` for build
    errors, which name the ESI file and line instead).
    """

    def __init__(self, message: str, *, offset: int | None = None, file: str | None = None,
                 line: int | None = None) -> None:
        super().__init__(message, file, line)
        self.offset = offset

    def __str__(self) -> str:
        if self.offset is None:
            return super().__str__()
        where = f"byte {self.offset} (0x{self.offset:x})"
        return f"{self.file}: {where}: {self.message}" if self.file else f"{where}: {self.message}"


# -- decoded image --------------------------------------------------------------------------

@dataclass(slots=True)
class SiiGeneral:
    """The GENERAL category (protocol-notes §7); ``*_index`` are 1-based STRINGS indices."""

    group_index: int
    image_index: int
    order_index: int
    name_index: int
    group: str | None
    image: str | None
    order: str | None
    name: str | None
    physical_layer: int            # byte 4: legacy 2 bits per port (IgH); meaning unverified
    coe_details: int
    foe_details: int
    eoe_details: int
    soe_channels: int
    ds402_channels: int
    sysman_class: int
    flags: int
    ebus_current: int              # mA, negative = the device feeds the E-Bus
    group_index2: int              # byte 14 (KC: group string index again)
    physical_ports: int            # 4 bits per port, port 0 in the low nibble
    ident_address: int             # bytes 18-19, used with the IdentPhyM flag

    @property
    def ports(self) -> list[str]:
        return [PORT_TYPES.get((self.physical_ports >> (4 * n)) & 0xF, "?") for n in range(4)]


@dataclass(slots=True)
class SiiSyncManager:
    start: int
    length: int
    control: int
    status: int
    enable: int
    type: int


@dataclass(slots=True)
class SiiPdoEntry:
    index: int
    subindex: int
    name_index: int
    name: str | None
    data_type: int
    bit_len: int
    flags: int


@dataclass(slots=True)
class SiiPdo:
    index: int
    sm: int                        # 0xFF = not assigned to a SyncManager
    dc_sync: int
    name_index: int
    name: str | None
    flags: int
    entries: list[SiiPdoEntry] = field(default_factory=list)

    @property
    def bit_length(self) -> int:
        return sum(e.bit_len for e in self.entries)


@dataclass(slots=True)
class SiiDcMode:
    cycle_time0: int
    shift_time0: int
    shift_time1: int
    sync1_cycle_factor: int
    assign_activate: int
    sync0_cycle_factor: int
    name_index: int
    desc_index: int
    name: str | None
    desc: str | None


@dataclass(slots=True)
class SiiCategory:
    """Where a category lies: ``offset`` of its 4-byte header, ``size`` of its data."""

    type: int
    offset: int
    size: int
    decoded: bool = False          # False: kept as raw data in SiiImage.other_categories


@dataclass(slots=True)
class SiiImage:
    pdi_control: int
    pdi_config: int
    sync_impulse: int
    pdi_config2: int
    alias: int
    checksum: int
    checksum_ok: bool
    vendor_id: int
    product_code: int
    revision: int
    serial: int
    bootstrap_rx: tuple[int, int]  # (offset, size)
    bootstrap_tx: tuple[int, int]
    std_rx: tuple[int, int]        # SM0, master -> slave
    std_tx: tuple[int, int]        # SM1, slave -> master
    mailbox_protocols: int
    eeprom_size_bytes: int
    version: int
    strings: list[str] = field(default_factory=list)
    general: SiiGeneral | None = None
    fmmus: list[int] = field(default_factory=list)
    syncms: list[SiiSyncManager] = field(default_factory=list)
    txpdos: list[SiiPdo] = field(default_factory=list)
    rxpdos: list[SiiPdo] = field(default_factory=list)
    dc: list[SiiDcMode] = field(default_factory=list)
    other_categories: list[tuple[int, bytes]] = field(default_factory=list)
    categories: list[SiiCategory] = field(default_factory=list)   # in image order
    checksum_computed: int = 0     # CRC-8 of words 0-6 as stored
    data_size: int = 0             # bytes given to decode()
    end_offset: int | None = None  # where the END marker is; None: the data ended first

    @property
    def protocols(self) -> list[str]:
        return mailbox_protocol_names(self.mailbox_protocols)

    def string(self, index: int) -> str | None:
        """The 1-based string ``index``; ``None`` for 0 or an index past the list."""
        return self.strings[index - 1] if 0 < index <= len(self.strings) else None


# -- CRC ------------------------------------------------------------------------------------

def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc8(data: bytes) -> int:
    """CRC-8 of the config area: polynomial 0x07, init 0xFF, MSB first, no final XOR."""
    crc = 0xFF
    for byte in data:
        crc = _CRC_TABLE[crc ^ byte]
    return crc


# -- decoding -------------------------------------------------------------------------------

def decode(data: bytes, *, source: str | None = None) -> SiiImage:
    """Decode an SII image (the whole EEPROM or any prefix that holds its categories).

    ``source`` names the file in error messages.  Raises :class:`SiiError` with the byte
    offset for data that is not an image: shorter than the 128-byte header, erased, or with
    a category that runs past the data or has an impossible length.
    """
    data = bytes(data)
    if len(data) < HEADER_SIZE:
        raise SiiError(f"not an SII image: {len(data)} bytes, shorter than the "
                       f"{HEADER_SIZE}-byte header", offset=len(data), file=source)
    if data.count(data[0]) == len(data) and data[0] in (0x00, 0xFF):
        raise SiiError(f"not an SII image: every byte is 0x{data[0]:02X} (an erased EEPROM)",
                       offset=0, file=source)
    (pdi_control, pdi_config, sync_impulse, pdi_config2, alias, _r5, _r6, checksum_word,
     vendor, product, revision, serial, bs_rx_off, bs_rx_size, bs_tx_off, bs_tx_size,
     rx_off, rx_size, tx_off, tx_size, protocols, size_word, version) = HEADER.unpack_from(data)
    checksum, computed = checksum_word & 0xFF, crc8(data[:CONFIG_AREA])
    img = SiiImage(
        pdi_control=pdi_control, pdi_config=pdi_config, sync_impulse=sync_impulse,
        pdi_config2=pdi_config2, alias=alias, checksum=checksum,
        checksum_ok=computed == checksum, checksum_computed=computed, vendor_id=vendor,
        product_code=product, revision=revision, serial=serial,
        bootstrap_rx=(bs_rx_off, bs_rx_size), bootstrap_tx=(bs_tx_off, bs_tx_size),
        std_rx=(rx_off, rx_size), std_tx=(tx_off, tx_size), mailbox_protocols=protocols,
        eeprom_size_bytes=(size_word + 1) * SIZE_STEP, version=version, data_size=len(data))
    try:
        cats = list(_walk(data, img, source))
    except SiiError as exc:
        if not img.checksum_ok:
            exc.message += (f"; the config-area checksum does not match either (stored "
                            f"0x{checksum:02X}, computed 0x{computed:02X}): probably not an "
                            "SII image")
        raise
    # The first category of a single-instance type is decoded (SOEM's ecx_siifind takes the
    # first too); PDO and DC categories add up (KickCAT writes one per PDO).
    seen: set[int] = set()
    for cat, _ in cats:
        if cat.type in REPEATABLE or (cat.type in SINGLE and cat.type not in seen):
            cat.decoded = True
            seen.add(cat.type)
    # STRINGS first: the other categories refer to them by index.
    for cat, body in cats:
        if cat.decoded and cat.type == CAT_STRINGS:
            img.strings = _strings(body, cat.offset, source)
    for cat, body in cats:
        if not cat.decoded:
            img.other_categories.append((cat.type, body))
        elif cat.type != CAT_STRINGS:
            _category(img, cat, body, source)
    return img


def _walk(data: bytes, img: SiiImage,
          source: str | None) -> Iterator[tuple[SiiCategory, bytes]]:
    """Yield (category, data) from byte 0x80 to the END marker or the end of the data."""
    offset = HEADER_SIZE
    while offset < len(data):
        if offset + CATEGORY_HEADER.size > len(data):
            if data[offset:].count(PAD) == len(data) - offset:
                break                   # erased bytes too few for a header: the end
            raise SiiError(f"truncated category header: the data ends {len(data) - offset} "
                           "bytes into it", offset=offset, file=source)
        cat_type, words = CATEGORY_HEADER.unpack_from(data, offset)
        if cat_type == CAT_END:
            img.end_offset = offset
            return
        start, end = offset + CATEGORY_HEADER.size, offset + CATEGORY_HEADER.size + 2 * words
        if end > len(data):
            raise SiiError(
                f"category {cat_type} ({CATEGORY_NAMES.get(cat_type, 'unknown')}) declares "
                f"{words} words ({2 * words} bytes) but only {len(data) - start} bytes follow "
                "its header", offset=offset, file=source)
        cat = SiiCategory(cat_type, offset, 2 * words)
        img.categories.append(cat)
        yield cat, data[start:end]
        offset = end


def _strings(body: bytes, offset: int, source: str | None) -> list[str]:
    """STRINGS: a count, then length-prefixed strings (no NUL); index 1 is the first."""
    if not body:
        return []
    count, pos, out = body[0], 1, []
    for n in range(1, count + 1):
        if pos >= len(body):
            raise SiiError(f"STRINGS category: string {n} of {count} starts past the end of "
                           f"the category ({len(body)} bytes)", offset=offset, file=source)
        length = body[pos]
        if pos + 1 + length > len(body):
            raise SiiError(f"STRINGS category: string {n} of {count} ({length} bytes) runs "
                           f"past the end of the category ({len(body)} bytes)",
                           offset=offset + CATEGORY_HEADER.size + pos, file=source)
        # Latin-1 maps every byte: real images hold cp1252/Latin-1 text ("1µs" in EL2262).
        out.append(body[pos + 1:pos + 1 + length].decode("latin-1"))
        pos += 1 + length
    return out


def _category(img: SiiImage, cat: SiiCategory, body: bytes, source: str | None) -> None:
    def bad(message: str) -> SiiError:
        name = CATEGORY_NAMES.get(cat.type, str(cat.type))
        return SiiError(f"{name} category: {message}", offset=cat.offset, file=source)

    if cat.type == CAT_GENERAL:
        if len(body) < GENERAL.size:
            raise bad(f"{len(body)} bytes, the category has {GENERAL.size}")
        v = GENERAL.unpack_from(body)
        img.general = SiiGeneral(
            group_index=v[0], image_index=v[1], order_index=v[2], name_index=v[3],
            group=img.string(v[0]), image=img.string(v[1]), order=img.string(v[2]),
            name=img.string(v[3]), physical_layer=v[4], coe_details=v[5], foe_details=v[6],
            eoe_details=v[7], soe_channels=v[8], ds402_channels=v[9], sysman_class=v[10],
            flags=v[11], ebus_current=v[12], group_index2=v[13], physical_ports=v[15],
            ident_address=v[16])
    elif cat.type == CAT_FMMU:
        img.fmmus = list(body)
        while img.fmmus and img.fmmus[-1] == FMMU_PAD:     # the pad of an odd count
            img.fmmus.pop()
    elif cat.type == CAT_SYNCM:
        if len(body) % SYNCM.size:
            raise bad(f"{len(body)} bytes is not a whole number of {SYNCM.size}-byte entries")
        img.syncms = [SiiSyncManager(*SYNCM.unpack_from(body, pos))
                      for pos in range(0, len(body), SYNCM.size)]
    elif cat.type in (CAT_TXPDO, CAT_RXPDO):
        (img.txpdos if cat.type == CAT_TXPDO else img.rxpdos).extend(
            _pdos(img, body, cat, bad))
    else:                               # CAT_DC
        if len(body) % DC_MODE.size:
            raise bad(f"{len(body)} bytes is not a whole number of {DC_MODE.size}-byte modes")
        for pos in range(0, len(body), DC_MODE.size):
            c0, s0, s1, f1, aa, f0, name, desc = DC_MODE.unpack_from(body, pos)
            img.dc.append(SiiDcMode(c0, s0, s1, f1, aa, f0, name, desc, img.string(name),
                                    img.string(desc)))


def _pdos(img: SiiImage, body: bytes, cat: SiiCategory,
          bad: Callable[[str], SiiError]) -> list[SiiPdo]:
    """One or more PDOs back to back (Beckhoff) or one per category (KickCAT)."""
    pdos, pos = [], 0
    while len(body) - pos >= PDO_HEADER.size:       # IgH: loop while a header fits
        index, count, sm, dc_sync, name, flags = PDO_HEADER.unpack_from(body, pos)
        pos += PDO_HEADER.size
        if pos + count * PDO_ENTRY.size > len(body):
            raise bad(f"PDO 0x{index:04X} at category byte {pos - PDO_HEADER.size} declares "
                      f"{count} entries ({count * PDO_ENTRY.size} bytes) but only "
                      f"{len(body) - pos} bytes follow")
        pdo = SiiPdo(index, sm, dc_sync, name, img.string(name), flags)
        for _ in range(count):
            e_index, sub, e_name, dtype, bits, e_flags = PDO_ENTRY.unpack_from(body, pos)
            pdo.entries.append(SiiPdoEntry(e_index, sub, e_name, img.string(e_name), dtype,
                                           bits, e_flags))
            pos += PDO_ENTRY.size
        pdos.append(pdo)
    return pdos


# -- building -------------------------------------------------------------------------------

class _Strings:
    """The STRINGS category being built: each distinct text once, 1-based indices."""

    def __init__(self) -> None:
        self.texts: list[bytes] = []
        self._index: dict[bytes, int] = {}

    def add(self, text: str | None) -> int:
        """The index of ``text`` (0 for none, or once all 255 indices are taken)."""
        if not text:
            return 0
        raw = text.encode("latin-1", errors="replace")[:255]
        found = self._index.get(raw)
        if found is not None:
            return found
        if len(self.texts) >= MAX_STRINGS:
            return 0
        self.texts.append(raw)
        self._index[raw] = len(self.texts)
        return len(self.texts)

    def category(self) -> bytes:
        return bytes([len(self.texts)]) + b"".join(bytes([len(t)]) + t for t in self.texts)


@dataclass(slots=True)
class BuildResult:
    """An image and what the builder had to leave out or change to make it (for the CLI)."""

    data: bytes
    notes: list[str] = field(default_factory=list)


# How much naming the PDO and DC categories carry; the builder drops names (never data) when
# the image would not fit the EEPROM size the ESI declares.
NAMES_ALL, NAMES_NO_ENTRIES, NAMES_NONE = 2, 1, 0


def build(device: Device, *, serial: int = 0, alias: int = 0) -> bytes:
    """The EEPROM image ``device`` should carry, padded with 0xFF to its size.

    - Config area (words 0-6) from ``Eeprom/ConfigData`` when given, else zero; ``alias``
      always goes to word 4; the checksum (word 7) is computed.
    - Identity from the ESI, ``serial`` in words 0x0E-0x0F; mailbox words from the MBoxOut
      (SM0, standard receive) and MBoxIn (SM1, standard send) SyncManagers; bootstrap
      mailbox from ``Eeprom/BootStrap``; size from ``Eeprom/ByteSize`` (default 2 KiB).
    - Categories: the ESI's explicit ``Eeprom/Category`` data of types the builder does not
      generate (device specific, vendor), then STRINGS, GENERAL, FMMU, SYNCM, TXPDO, RXPDO,
      DC and END.  TXPDO/RXPDO hold the default assignment: the PDOs that name a SyncManager
      (``Sm``) and are not virtual.
    - When that does not fit ``ByteSize``, the names of PDO entries, then of PDOs and DC
      modes are left out (string index 0); if it still does not fit, the image grows to the
      next power of two and word 0x3E says so, with the names as long as the image stays
      within the 4 KiB SOEM reads (``SOEM_SII_WINDOW``), else without them as before.  :func:`build_image` reports both.
    """
    return build_image(device, serial=serial, alias=alias).data


def build_image(device: Device, *, serial: int = 0, alias: int = 0) -> BuildResult:
    """:func:`build` with notes on names left out or a size beyond ``Eeprom/ByteSize``."""
    source = device.source
    if not 0 <= serial <= 0xFFFFFFFF:
        raise SiiError(f"serial {serial} does not fit in 32 bits")
    if not 0 <= alias <= 0xFFFF:
        raise SiiError(f"alias {alias} does not fit in 16 bits")
    for what, value in (("vendor id", device.vendor.id), ("product code", device.product_code),
                        ("revision", device.revision)):
        if value is None or not 0 <= value <= 0xFFFFFFFF:
            raise SiiError(f"device {device.type_name!r}: no valid {what} to write into the "
                           "SII", file=source.file, line=source.line)
    declared = _declared_size(device)
    notes: list[str] = []
    for names in (NAMES_ALL, NAMES_NO_ENTRIES, NAMES_NONE):
        body = _categories(device, names)
        if HEADER_SIZE + len(body) <= declared:
            break
    else:
        # It grows anyway: the names stay unless they push categories (SYNCM, the PDOs of
        # a device from an ENI with 113 TxPdos) out of what SOEM reads.
        for names in (NAMES_ALL, NAMES_NO_ENTRIES, NAMES_NONE):
            body = _categories(device, names)
            if HEADER_SIZE + len(body) <= SOEM_SII_WINDOW:
                break
    needed = HEADER_SIZE + len(body)
    size = declared
    given = _byte_size(device)
    what = f"Eeprom/ByteSize {given}" if given else f"the default {DEFAULT_SIZE} bytes"
    if needed > size:
        while size < needed:
            size = 1 << size.bit_length() if size & (size - 1) else size * 2
        if size > MAX_SIZE:
            raise SiiError(f"device {device.type_name!r}: the SII needs {needed} bytes, more "
                           "than an EEPROM can address", file=source.file, line=source.line)
        notes.append(f"the image needs {needed} bytes, more than {what}; written as a "
                     f"{size}-byte EEPROM")
    if names != NAMES_ALL:
        left = "PDO entry names" if names == NAMES_NO_ENTRIES else "PDO, entry and DC mode names"
        notes.append(f"{left} left out of STRINGS to fit "
                     + (what if needed <= declared
                        else f"the {SOEM_SII_WINDOW} bytes SOEM reads"))
    image = bytearray(_header(device, serial, alias, size) + body)
    image += bytes([PAD]) * (size - len(image))
    return BuildResult(bytes(image), notes)


def _categories(device: Device, names: int) -> bytes:
    """Everything after the header, up to and including the END marker."""
    source = device.source
    strings = _Strings()
    # GENERAL's strings come first: order number (the Type), group, name (protocol-notes §7).
    order_index = strings.add(device.type_name)
    group_index = strings.add(device.group_type)
    name_index = strings.add(device.name or device.type_name)
    sections: list[tuple[int, bytes]] = []
    if device.eeprom is not None:
        sections += [(no, data) for no, data in device.eeprom.categories if no not in GENERATED]
    general = _general(device, group_index, order_index, name_index)
    txpdo = _pdo_category(device.tx_pdos, strings, device, names)
    rxpdo = _pdo_category(device.rx_pdos, strings, device, names)
    dc = _dc(device.dc.opmodes if device.dc else [], strings, names)
    sections.append((CAT_STRINGS, strings.category()))
    sections.append((CAT_GENERAL, general))
    sections += [(t, body) for t, body in ((CAT_FMMU, _fmmu(device)), (CAT_SYNCM, _syncm(device)),
                                           (CAT_TXPDO, txpdo), (CAT_RXPDO, rxpdo), (CAT_DC, dc))
                 if body]
    out = bytearray()
    for cat_type, data in sections:
        if len(data) % 2:               # categories are whole words
            data += bytes([FMMU_PAD]) if cat_type == CAT_FMMU else b"\x00"
        if len(data) // 2 > 0xFFFF:
            raise SiiError(f"device {device.type_name!r}: category {cat_type} is "
                           f"{len(data)} bytes, more than an SII category can hold",
                           file=source.file, line=source.line)
        out += CATEGORY_HEADER.pack(cat_type, len(data) // 2) + data
    out += CATEGORY_HEADER.pack(CAT_END, 0)
    return bytes(out)


def _byte_size(device: Device) -> int | None:
    eep = device.eeprom
    return eep.byte_size if eep is not None and eep.byte_size else None


def _declared_size(device: Device) -> int:
    """Eeprom/ByteSize rounded up to 128 bytes (word 0x3E counts 128-byte steps), else 2 KiB."""
    given = _byte_size(device)
    size = DEFAULT_SIZE if given is None else -(-given // SIZE_STEP) * SIZE_STEP
    return min(max(size, SIZE_STEP), MAX_SIZE)


def _header(device: Device, serial: int, alias: int, size: int) -> bytes:
    eep = device.eeprom
    config = bytearray(CONFIG_AREA)
    if eep is not None and eep.config_data:
        given = eep.config_data[:CONFIG_AREA]          # bytes 14+ would be the checksum
        config[:len(given)] = given
    config[8:10] = alias.to_bytes(2, "little")
    words = struct.unpack("<7H", config)
    boot = (0, 0, 0, 0)
    if eep is not None and eep.boot_strap and len(eep.boot_strap) >= 8:
        boot = struct.unpack_from("<4H", eep.boot_strap)
    rx = _mailbox_sm(device, "MBoxOut")
    tx = _mailbox_sm(device, "MBoxIn")
    protocols = 0
    if device.mailbox is not None:
        for name in device.mailbox.protocols:
            protocols |= MAILBOX_PROTOCOL_BITS.get(name, 0)
    return HEADER.pack(*words, crc8(bytes(config)), device.vendor.id, device.product_code,
                       device.revision, serial, *boot, *rx, *tx, protocols,
                       size // SIZE_STEP - 1, 1)


def _mailbox_sm(device: Device, sm_type: str) -> tuple[int, int]:
    """(offset, size) of the first SyncManager of ``sm_type``; (0, 0) without one."""
    for sm in device.sm_by_type(sm_type):
        return (sm.start_address or 0) & 0xFFFF, sm_length(sm)
    return 0, 0


def sm_length(sm: SyncManager) -> int:
    """The SYNCM length: a mailbox SM's size (:attr:`SyncManager.mailbox_size`, the rule the
    ENI follows too); for process data DefaultSize, else 0 (the master sizes process data
    from the PDOs)."""
    size = sm.mailbox_size if sm.is_mailbox else sm.default_size or 0
    return size & 0xFFFF


def sm_control(sm: SyncManager) -> int:
    """The SYNCM control byte: a mailbox SM's (:attr:`SyncManager.mailbox_control`), else
    the ESI's ControlByte (0 without one)."""
    return (sm.mailbox_control if sm.is_mailbox else sm.control_byte or 0) & 0xFF


def _general(device: Device, group: int, order: int, name: int) -> bytes:
    mbx = device.mailbox
    protocols = set(mbx.protocols) if mbx is not None else set()
    coe = 0
    if mbx is not None and "CoE" in protocols:
        coe = COE_SDO
        settings = mbx.coe
        if settings is not None:
            for flag, bit in ((settings.sdo_info, COE_SDO_INFO),
                              (settings.pdo_assign, COE_PDO_ASSIGN),
                              (settings.pdo_config, COE_PDO_CONFIG),
                              (settings.pdo_upload, COE_UPLOAD),
                              (settings.complete_access, COE_COMPLETE_ACCESS)):
                if flag:
                    coe |= bit
    flags = FLAG_MBOX_DLL if mbx is not None and mbx.data_link_layer else 0
    ebus = device.info.ebus_current if device.info and device.info.ebus_current else 0
    ebus = max(-0x8000, min(0x7FFF, ebus))
    return GENERAL.pack(group, 0, order, name, 0, coe, int("FoE" in protocols),
                        int("EoE" in protocols), int("SoE" in protocols), 0, 0, flags, ebus,
                        group, 0, physical_ports(device.physics), 0)


def physical_ports(physics: str | None) -> int:
    """GENERAL bytes 16-17 from ESI ``Physics`` ("YKY" -> 0x0131): 4 bits per port."""
    value = 0
    for port, kind in enumerate(port_kinds(physics)):
        value |= (PORT_TYPE_CODES[kind] if kind else 0) << (4 * port)
    return value


def _fmmu(device: Device) -> bytes:
    usage = bytes(FMMU_TYPES.get(f.type or "", 0) for f in device.fmmus)
    return usage + (bytes([FMMU_PAD]) if len(usage) % 2 else b"")


def _syncm(device: Device) -> bytes:
    return b"".join(SYNCM.pack((sm.start_address or 0) & 0xFFFF, sm_length(sm),
                               sm_control(sm), 0, sm_enable(sm),
                               SM_TYPE_CODES.get(sm.type, 0))
                    for sm in device.sms)


def sm_enable(sm: SyncManager) -> int:
    """The SYNCM enable byte of an ESI SyncManager (see SM_ENABLE ...)."""
    return ((SM_ENABLE if sm.enable else 0) | (SM_VIRTUAL if sm.virtual else 0)
            | (SM_OP_ONLY if sm.op_only else 0))


def assigned_pdos(pdos: list[Pdo]) -> list[Pdo]:
    """The ESI's default PDO assignment: PDOs that name a SyncManager and are not virtual."""
    return [p for p in pdos if p.sm is not None and not p.virtual and p.index is not None]


def _pdo_category(pdos: list[Pdo], strings: _Strings, device: Device, names: int) -> bytes:
    out = bytearray()
    for pdo in assigned_pdos(pdos):
        index, sm = pdo.index, pdo.sm
        assert index is not None and sm is not None        # what assigned_pdos keeps
        if len(pdo.entries) > 0xFF:
            raise SiiError(f"device {device.type_name!r}: PDO 0x{pdo.index:04X} has "
                           f"{len(pdo.entries)} entries; the SII holds at most 255",
                           file=pdo.source.file, line=pdo.source.line)
        flags = ((PDO_MANDATORY if pdo.mandatory else 0) | (PDO_FIXED if pdo.fixed else 0))
        out += PDO_HEADER.pack(index & 0xFFFF, len(pdo.entries), sm & 0xFF, 0,
                               strings.add(pdo.name) if names > NAMES_NONE else 0, flags)
        for e in pdo.entries:
            bits = e.bit_len or 0
            if bits > 0xFF:
                raise SiiError(f"device {device.type_name!r}: PDO 0x{pdo.index:04X} entry "
                               f"0x{e.index or 0:04X}:{e.subindex or 0:02X} is {bits} bits; an "
                               "SII PDO entry holds at most 255", file=e.source.file,
                               line=e.source.line)
            padding = e.is_padding
            out += PDO_ENTRY.pack((e.index or 0) & 0xFFFF, (e.subindex or 0) & 0xFF,
                                  strings.add(e.name) if names == NAMES_ALL and not padding
                                  else 0,
                                  0 if padding else datatypes.coe_type(e.data_type), bits, 0)
    return bytes(out)


def _dc(opmodes: list[DcOpMode], strings: _Strings, names: int) -> bytes:
    out = bytearray()
    for mode in current_modes(opmodes):
        # The name only: the real NI 9144 and EL2262 images leave the description string
        # index 0 although their ESIs give every mode a Desc.
        name = mode.name if names > NAMES_NONE else None
        sync0_factor = mode.cycle_time_sync0_factor
        if sync0_factor is None:
            # No factor: the cycle time is absolute, or (not given either) the bus cycle.
            # The real NI 9144 images write 1 for their DcOff mode, which has no
            # CycleTimeSync0 in the ESI (as the AKD's and SOES's images for theirs).
            sync0_factor = 0 if mode.cycle_time_sync0 else 1
        out += DC_MODE.pack(
            (mode.cycle_time_sync0 or 0) & 0xFFFFFFFF, (mode.shift_time_sync0 or 0) & 0xFFFFFFFF,
            (mode.shift_time_sync1 or 0) & 0xFFFFFFFF,
            _i16(mode.cycle_time_sync1_factor), (mode.assign_activate or 0) & 0xFFFF,
            _i16(sync0_factor), strings.add(name), 0)
    return bytes(out)


def current_modes(opmodes: list[DcOpMode]) -> list[DcOpMode]:
    """The op modes an image lists: one per name, leaving out the versions Beckhoff files
    keep for old TwinCAT builds (``IgnoreFromBuildNo``), as the EL2262 image does (4 of
    the ESI's 34 modes)."""
    current = [m for m in opmodes if m.ignore_from_build is None] or opmodes
    chosen: dict[str, DcOpMode] = {}
    for mode in current:
        chosen.setdefault(mode.name, mode)
    return list(chosen.values())


def _i16(value: int | None) -> int:
    return max(-0x8000, min(0x7FFF, value or 0))


# -- JSON -----------------------------------------------------------------------------------

def to_json(img: SiiImage) -> dict[str, Any]:
    """The decoded image as plain JSON types (``sii show --format json``); numbers stay
    numbers, category data is hex text."""
    out = asdict(img)
    out["bootstrap_rx"] = list(img.bootstrap_rx)
    out["bootstrap_tx"] = list(img.bootstrap_tx)
    out["std_rx"] = list(img.std_rx)
    out["std_tx"] = list(img.std_tx)
    out["protocols"] = img.protocols
    out["other_categories"] = [{"type": t, "data": data.hex()}
                               for t, data in img.other_categories]
    if img.general is not None:
        out["general"]["ports"] = img.general.ports
    return out
