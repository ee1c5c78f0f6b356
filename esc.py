"""EtherCAT protocol constants and the ESC register layouts that compiler and runtime share.

One module, as python-canopen keeps its SDO constants: the compiler writes SyncManager and
FMMU images into ENI InitCmds with these layouts, the runtime's master replays them and the
virtual segment decodes them, so the byte layout lives in exactly one place.
Register addresses and bit meanings follow ETG.1000.4 and the ESC datasheets (see
``docs/ethercat-facts.md`` in the shared docs for the sources).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum, IntEnum


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


@dataclass(frozen=True, slots=True)
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


@dataclass(frozen=True, slots=True)
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
