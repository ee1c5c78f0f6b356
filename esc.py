"""EtherCAT protocol constants and the ESC register layouts that compiler and runtime share.

One module, as python-canopen keeps its SDO constants: the compiler writes SyncManager and
FMMU images into ENI InitCmds with these layouts, the runtime's master replays them and the
virtual segment decodes them, so the byte layout lives in exactly one place.
Register addresses and bit meanings follow ETG.1000.4 and the ESC datasheets (see
``docs/ethercat-facts.md`` in the shared docs for the sources).
"""

from __future__ import annotations

import struct
from enum import Enum, IntEnum

from ecatcfg.record import record


class Cmd(IntEnum):
    """Datagram command codes (ETG.1000.4 table 'EtherCAT command types')."""

    NOP = 0
    APRD = 1
    APWR = 2
    APRW = 3
    FPRD = 4
    FPWR = 5
    FPRW = 6
    BRD = 7
    BWR = 8
    BRW = 9
    LRD = 10
    LWR = 11
    LRW = 12
    ARMW = 13
    FRMW = 14


class Reg(IntEnum):
    """ESC registers the configuration touches."""

    STATION_ADDRESS = 0x0010
    STATION_ALIAS = 0x0012
    DL_CONTROL_2 = 0x0103         # second station address enable (TwinCAT "en/disable")
    AL_CONTROL = 0x0120
    AL_STATUS = 0x0130            # + 0x0134 AL status code: 6 bytes with the padding
    ECAT_EVENT_MASK = 0x0200
    RX_ERROR_COUNTER = 0x0300
    WATCHDOG_DIVIDER = 0x0400
    WATCHDOG_PDI = 0x0410
    WATCHDOG_SM = 0x0420
    EEPROM_CONFIG = 0x0500        # 0 = EEPROM to ECAT, 1 = to PDI
    EEPROM_CONTROL = 0x0502
    EEPROM_DATA = 0x0508
    FMMU0 = 0x0600
    SM0 = 0x0800
    DC_RECEIVE_TIME_PORT0 = 0x0900
    DC_SYSTEM_TIME = 0x0910
    DC_SPEED_COUNTER_START = 0x0930
    DC_TIME_FILTER = 0x0934
    DC_CYCLIC_UNIT_CONTROL = 0x0980   # + 0x0981 activation (AssignActivate, 2 bytes LE)
    DC_START_TIME_CYCLIC = 0x0990
    DC_SYNC0_CYCLE_TIME = 0x09A0      # + 0x09A4 SYNC1 cycle time
    DC_LATCH0_CONTROL = 0x09A8


FMMU_SIZE = 16
SM_SIZE = 8
# Logical address of the mailbox-state bits both TwinCAT and EC-Engineer use.
MAILBOX_STATE_ADDR = 0x09000000
# SM1 (mailbox in) status register: the mailbox-state FMMU maps its bit 0 (see
# eni-observations §3: both tools map bit 0 of 0x080D, reproduced as is).
SM1_STATUS = 0x080D


def fmmu_register(n: int) -> int:
    return Reg.FMMU0 + FMMU_SIZE * n


def sm_register(n: int) -> int:
    return Reg.SM0 + SM_SIZE * n


class AlState(IntEnum):
    INIT = 1
    PREOP = 2
    BOOT = 3
    SAFEOP = 4
    OP = 8


AL_ERROR_ACK = 0x10           # AL control bit 4: acknowledge an error indication


class Transition(str, Enum):
    """AL state transitions as ENI ``<Transition>`` names them (first letter from, second to)."""

    II = "II"
    IP = "IP"
    PP = "PP"
    PO = "PO"
    PS = "PS"
    PI = "PI"
    SS = "SS"
    SP = "SP"
    SO = "SO"
    SI = "SI"
    OS = "OS"
    OP = "OP"
    OI = "OI"
    IB = "IB"
    BI = "BI"

    @property
    def target(self) -> AlState:
        return _STATE_BY_LETTER[self.value[1]]


_STATE_BY_LETTER = {"I": AlState.INIT, "P": AlState.PREOP, "S": AlState.SAFEOP,
                    "O": AlState.OP, "B": AlState.BOOT}


class FmmuType(IntEnum):
    """FMMU register +0x0B: which direction the mapping works (ETG.1000.4)."""

    UNUSED = 0
    READ = 1          # inputs: the slave's memory is read into the frame
    WRITE = 2         # outputs: frame data is written into the slave
    READ_WRITE = 3


@record(frozen=True)
class FmmuConfig:
    """One FMMU's 16-byte register image (0x0600 + 16·n)."""

    logical_start: int
    length: int                 # logical bytes touched
    logical_start_bit: int
    logical_stop_bit: int
    physical_start: int
    physical_start_bit: int
    type: FmmuType
    active: bool = True

    _LAYOUT = struct.Struct("<IHBBHBBB3x")

    def to_bytes(self) -> bytes:
        return self._LAYOUT.pack(self.logical_start, self.length, self.logical_start_bit,
                                 self.logical_stop_bit, self.physical_start,
                                 self.physical_start_bit, int(self.type), int(self.active))

    @classmethod
    def from_bytes(cls, data: bytes) -> FmmuConfig:
        (start, length, sbit, ebit, phys, pbit, kind,
         active) = cls._LAYOUT.unpack(bytes(data[:FMMU_SIZE]))
        return cls(start, length, sbit, ebit, phys, pbit, FmmuType(kind & 3), bool(active & 1))

    @property
    def bit_length(self) -> int:
        """Logical bits mapped: from the start bit of the first byte to the stop bit of the
        last."""
        return (self.length - 1) * 8 + self.logical_stop_bit - self.logical_start_bit + 1


@record(frozen=True)
class SmConfig:
    """One SyncManager's 8-byte register image (0x0800 + 8·n)."""

    start: int
    length: int
    control: int
    enable: bool
    status: int = 0
    pdi_control: int = 0

    _LAYOUT = struct.Struct("<HHBBBB")

    def to_bytes(self) -> bytes:
        return self._LAYOUT.pack(self.start, self.length, self.control, self.status,
                                 int(self.enable), self.pdi_control)

    @classmethod
    def from_bytes(cls, data: bytes) -> SmConfig:
        start, length, control, status, activate, pdi = cls._LAYOUT.unpack(
            bytes(data[:SM_SIZE]))
        return cls(start, length, control, bool(activate & 1), status, pdi)


def eeprom_read_request(word_address: int) -> bytes:
    """EEPROM control/status + address (0x0502, 6 bytes): 'read' at ``word_address``."""
    return struct.pack("<HI", 0x0100, word_address)


# SII word addresses of the identity (ETG.1000.6 / ETG.2010).
SII_VENDOR_ID = 0x0008
SII_PRODUCT_CODE = 0x000A
SII_REVISION = 0x000C
SII_SERIAL = 0x000E

# Ethernet: EtherType, and how much datagram data one frame can carry (ethercat-facts §frame:
# 1500 payload − 2 EtherCAT header; every datagram costs a 10-byte header and a 2-byte WKC).
ETHERTYPE = 0x88A4
FRAME_PAYLOAD = 1500
FRAME_HEADER = 2
DATAGRAM_OVERHEAD = 12
MAX_DATAGRAM_DATA = FRAME_PAYLOAD - FRAME_HEADER - DATAGRAM_OVERHEAD     # 1486


# AL status codes (register 0x0134; ETG.1000.6, as SOEM, IgH, SOES and KickCAT name them:
# ethercat-facts.md §4).
AL_STATUS_CODES: dict[int, str] = {
    0x0000: "no error", 0x0001: "unspecified error", 0x0002: "no memory",
    0x0003: "invalid device setup", 0x0004: "invalid revision",
    0x0006: "SII/EEPROM information does not match firmware",
    0x0007: "firmware update not successful, old firmware still running",
    0x000E: "license error",
    0x0011: "invalid requested state change", 0x0012: "unknown requested state",
    0x0013: "bootstrap not supported", 0x0014: "no valid firmware",
    0x0015: "invalid mailbox configuration (BOOT)",
    0x0016: "invalid mailbox configuration (PREOP)",
    0x0017: "invalid sync manager configuration", 0x0018: "no valid inputs available",
    0x0019: "no valid outputs", 0x001A: "synchronization error",
    0x001B: "sync manager watchdog", 0x001C: "invalid sync manager types",
    0x001D: "invalid output configuration", 0x001E: "invalid input configuration",
    0x001F: "invalid watchdog configuration", 0x0020: "slave needs cold start",
    0x0021: "slave needs INIT", 0x0022: "slave needs PREOP", 0x0023: "slave needs SAFEOP",
    0x0024: "invalid input mapping", 0x0025: "invalid output mapping",
    0x0026: "inconsistent settings", 0x0027: "freerun not supported",
    0x0028: "synchronization not supported", 0x0029: "freerun needs 3-buffer mode",
    0x002A: "background watchdog", 0x002B: "no valid inputs and outputs",
    0x002C: "fatal sync error", 0x002D: "no sync error",
    0x0030: "invalid DC SYNC configuration", 0x0031: "invalid DC latch configuration",
    0x0032: "PLL error", 0x0033: "DC sync IO error", 0x0034: "DC sync timeout",
    0x0035: "DC invalid sync cycle time", 0x0036: "DC invalid SYNC0 cycle time",
    0x0037: "DC invalid SYNC1 cycle time",
    0x0041: "MBX_AOE", 0x0042: "MBX_EOE", 0x0043: "MBX_COE", 0x0044: "MBX_FOE",
    0x0045: "MBX_SOE", 0x004F: "MBX_VOE",
    0x0050: "EEPROM no access", 0x0051: "EEPROM error",
    0x0052: "external hardware not ready",
    0x0060: "slave restarted locally", 0x0061: "device identification value updated",
    0x0070: "detected module ident list does not match",
    0x0080: "supply voltage too low", 0x0081: "supply voltage too high",
    0x0082: "temperature too low", 0x0083: "temperature too high",
    0x00F0: "application controller available",
}


def al_status_name(code: int) -> str:
    return AL_STATUS_CODES.get(code, "vendor-specific or unknown code")
