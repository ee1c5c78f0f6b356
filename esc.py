"""EtherCAT protocol constants and the ESC register layouts that compiler and runtime share.

One module, as python-canopen keeps its SDO constants: the compiler writes SyncManager and
FMMU images into ENI InitCmds with these layouts, the runtime's master replays them and the
virtual segment decodes them, so the byte layout lives in exactly one place.
Register addresses and bit meanings follow ETG.1000.4 and the ESC datasheets as the open
masters and slaves implement them; ``docs/protocol-notes.md`` §1-§2 names the file of each
project (SOEM, IgH, SOES, KickCAT, Wireshark) where a layout can be checked.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
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


# The command classes (ETG.1000.4 "EtherCAT command types"): how a datagram is addressed,
# and whether it reads or writes the slave's memory.
AUTO_INCREMENT_CMDS = frozenset({Cmd.APRD, Cmd.APWR, Cmd.APRW, Cmd.ARMW})
CONFIGURED_ADDRESS_CMDS = frozenset({Cmd.FPRD, Cmd.FPWR, Cmd.FPRW, Cmd.FRMW})
BROADCAST_CMDS = frozenset({Cmd.BRD, Cmd.BWR, Cmd.BRW})
LOGICAL_CMDS = frozenset({Cmd.LRD, Cmd.LWR, Cmd.LRW})
REGISTER_READS = frozenset({Cmd.APRD, Cmd.FPRD, Cmd.BRD, Cmd.APRW, Cmd.FPRW, Cmd.BRW})
REGISTER_WRITES = frozenset({Cmd.APWR, Cmd.FPWR, Cmd.BWR, Cmd.APRW, Cmd.FPRW, Cmd.BRW})
READ_WRITE_CMDS = frozenset({Cmd.APRW, Cmd.FPRW, Cmd.BRW, Cmd.LRW})
# The cyclic commands whose reply data the master copies into its input image
# (runtime/master/cyclic.py), the data a CopyInfo of the command copies from.
INPUT_IMAGE_CMDS = frozenset({Cmd.LRD, Cmd.LRW, Cmd.APRD, Cmd.FPRD, Cmd.BRD, Cmd.ARMW,
                              Cmd.FRMW})


def wkc_increment(cmd: int, read: bool, written: bool) -> int:
    """What one slave adds to a datagram's working counter (ETG.1000.4 §5.4.1.2, "working
    counter"): a read or a write adds 1; a read-write command (APRW, FPRW, BRW, LRW) adds 1
    for the read and 2 for the write; ARMW/FRMW add 1 in every slave (the reader and
    the writers alike, so pass ``read``).  The master's expectations (compiler/layout.py,
    runtime/master/recovery.py) follow this; the emulated ESCs (runtime/segment/virtual.py)
    count the same inline, in their per-frame loop."""
    if cmd in READ_WRITE_CMDS:
        return int(read) + 2 * int(written)
    return int(read or written)


ESC_FEATURE_DC = 0x0004           # 0x0008 bit 2: the ESC has a DC unit (SOEM hasdc, IgH)


class Reg(IntEnum):
    """ESC registers the configuration touches."""

    FMMUS_SUPPORTED = 0x0004      # how many FMMUs the ESC has; 0x0005: how many SMs
    SMS_SUPPORTED = 0x0005
    PORT_DESCRIPTOR = 0x0007      # 2 bits per port: 0 none, 2 E-bus, 3 MII (Section II)
    ESC_FEATURES = 0x0008         # bit 2: DC available (ESC Section II 0x0008)
    STATION_ADDRESS = 0x0010
    STATION_ALIAS = 0x0012
    DL_STATUS = 0x0110
    DL_CONTROL_2 = 0x0103         # second station address enable (TwinCAT "en/disable")
    AL_CONTROL = 0x0120
    AL_STATUS = 0x0130            # + 0x0134 AL status code: 6 bytes with the padding
    AL_STATUS_CODE = 0x0134
    PDI_CONTROL = 0x0140          # + 0x0141 ESC configuration: both loaded from SII word 0
    ESC_CONFIG = 0x0141
    ECAT_EVENT_MASK = 0x0200
    ECAT_EVENT_REQUEST = 0x0210   # bit 2: DL status changed (cleared by reading 0x0110)
    RX_ERROR_COUNTER = 0x0300
    WATCHDOG_DIVIDER = 0x0400
    WATCHDOG_PDI = 0x0410
    WATCHDOG_SM = 0x0420
    WATCHDOG_STATUS = 0x0440      # bit 0: 0 = the process data (SM) watchdog expired
    WATCHDOG_COUNTER_SM = 0x0442  # + 0x0443 the PDI watchdog's counter
    EEPROM_CONFIG = 0x0500        # 0 = EEPROM to ECAT, 1 = to PDI
    EEPROM_CONTROL = 0x0502
    EEPROM_ADDRESS = 0x0504
    EEPROM_DATA = 0x0508
    FMMU0 = 0x0600
    SM0 = 0x0800
    DC_RECEIVE_TIME_PORT0 = 0x0900
    DC_SYSTEM_TIME = 0x0910
    DC_SYSTEM_TIME_DIFFERENCE = 0x092C  # sign-magnitude, bit 31: local copy smaller
    DC_SPEED_COUNTER_START = 0x0930
    DC_TIME_FILTER = 0x0934
    DC_CYCLIC_UNIT_CONTROL = 0x0980   # + 0x0981 activation (AssignActivate, 2 bytes LE)
    DC_START_TIME_CYCLIC = 0x0990
    DC_SYNC0_CYCLE_TIME = 0x09A0      # + 0x09A4 SYNC1 cycle time
    DC_LATCH0_CONTROL = 0x09A8


# -- watchdogs (ESC Section II, registers 0x0400-0x0443; docs/protocol-notes.md) -------------
# The time base of both watchdogs is (0x0400 + 2) x 40 ns; 0x0410 (PDI) and 0x0420 (SM,
# process data) count in that base, 0 disables the watchdog.  The power-on values, which are
# also what TwinCAT and EC-Engineer write when a device's watchdogs are set
# (docs/eni-exports.md §3): 2498 -> 100 us, 1000 x 100 us = 100 ms.
WATCHDOG_DIVIDER_DEFAULT = 0x09C2
WATCHDOG_TIME_DEFAULT = 0x03E8
WATCHDOG_TICK_NS = 40             # one divider step: 40 ns (25 MHz)


def watchdog_base_ns(divider: int) -> int:
    """The watchdog time base in ns that divider ``divider`` (register 0x0400) gives."""
    return (divider + 2) * WATCHDOG_TICK_NS


FMMU_SIZE = 16
SM_SIZE = 8
# Logical address of the mailbox-state bits both TwinCAT and EC-Engineer use.
MAILBOX_STATE_ADDR = 0x09000000
# SM1 (mailbox in) status register: the mailbox-state FMMU maps its bit 0 (TwinCAT and
# EC-Engineer both map bit 0 of 0x080D, reproduced as is: docs/eni-exports.md §3).  The
# master also reads status, activate and PDI control of SM1 together (3 bytes from here) to
# repeat a lost mailbox message.
SM1_STATUS = 0x080D

# -- SyncManager register bits (0x0800 + 8·n: +4 control, +5 status, +6 activate, +7 PDI
# control; ETG.1000.4 and the ESC datasheets; SOES esc.h, SOEM ec_type.h) ------------------

SM_MODE_MASK = 0x03               # control bits 1:0
SM_MODE_BUFFERED = 0x00           # 3-buffer mode, process data
SM_MODE_MAILBOX = 0x02            # 1-buffer mode, mailbox
SM_DIR_MASK = 0x0C                # control bits 3:2
SM_DIR_ECAT_READS = 0x00          # the master reads, the slave writes (MBoxIn, Inputs)
SM_DIR_ECAT_WRITES = 0x04         # the master writes, the slave reads (MBoxOut, Outputs)
SM_ECAT_EVENT = 0x10              # control bit 4: interrupt in the ECAT event register
SM_PDI_EVENT = 0x20               # control bit 5: interrupt in the AL event register
SM_WATCHDOG_ENABLE = 0x40         # control bit 6
# The standard mailbox control bytes (SOEM's EC_DEFAULTMBXSM0/1): mailbox mode, direction,
# PDI interrupt.  A mailbox SM whose ESI gives no ControlByte is programmed with these.
SM_CONTROL_MBOX_OUT = SM_MODE_MAILBOX | SM_DIR_ECAT_WRITES | SM_PDI_EVENT     # 0x26
SM_CONTROL_MBOX_IN = SM_MODE_MAILBOX | SM_DIR_ECAT_READS | SM_PDI_EVENT       # 0x22
SM_STATUS_WRITE_EVENT = 0x01      # status bit 0: a buffer was completely written
SM_STATUS_READ_EVENT = 0x02       # status bit 1: a buffer was completely read
SM_STATUS_MAILBOX_FULL = 0x08     # status bit 3 (1-buffer mode)
SM_STATUS_BUFFER_NONE = 0x30      # status bits 5:4 = 3: no buffer written yet (3-buffer mode)
SM_ACTIVATE_ENABLE = 0x01         # activate bit 0
SM_ACTIVATE_REPEAT = 0x02         # activate bit 1: the master toggles it to get a repeat
SM_PDI_REPEAT_ACK = 0x02          # PDI control bit 1: the slave's acknowledge of a repeat

# The type of each SM as SII SYNCM category byte 7 and CoE object 0x1C00 write it
# (ETG.2010; ETG.1000.6 "sync manager communication type"): the same codes in both.
SM_TYPE_CODES: dict[str | None, int] = {None: 0, "MBoxOut": 1, "MBoxIn": 2, "Outputs": 3,
                                        "Inputs": 4}


def fmmu_register(n: int) -> int:
    return Reg.FMMU0 + FMMU_SIZE * n


def sm_register(n: int) -> int:
    return Reg.SM0 + SM_SIZE * n


# ESC ports.  A frame enters port 0 (the one toward the master) and each ESC forwards it
# through its open ports in the order 0 -> 3 -> 1 -> 2 (ET1100/ET1200 datasheets, "frame
# processing order"; SOEM ethercatdc.c, IgH's next_table in slave.c), so auto-increment
# positions number the slaves depth-first in that order.  ENI ``PreviousPort/Port`` and
# Beckhoff's documentation call ports 0-3 A-D.
PORT_PROCESSING_ORDER = (0, 3, 1, 2)
PORT_LETTERS = "ABCD"


class AlState(IntEnum):
    INIT = 1
    PREOP = 2
    BOOT = 3
    SAFEOP = 4
    OP = 8

    def __str__(self) -> str:
        # print(net.state) shows OP, not 8 (an IntEnum prints its number since Python
        # 3.11); repr() and int() are unchanged, and a format spec (f"{s:02x}") is numeric.
        return self.name


AL_ERROR_ACK = 0x10           # AL control bit 4: acknowledge an error indication
AL_STATUS_ERROR = 0x10        # AL status bit 4: error indication (code in 0x0134)
AL_STATE_MASK = 0x0F          # AL control / status bits 3:0: the state
# Explicit device identification (ETG.1020 "Requesting ID"; ESC Section II 0x0120/0x0130
# bit 5): the master sets AL control bit 5, the slave loads its ID into AL status code
# 0x0134 and sets AL status bit 5 while the request stands.
AL_ID_REQUEST = 0x20          # AL control bit 5: device identification request
AL_STATUS_ID = 0x20           # AL status bit 5: device identification loaded (in 0x0134)

# ESC configuration 0x0141 bit 0, *device emulation*: an ESC without a microcontroller copies
# every AL control write into AL status itself, with no checks (Beckhoff ESC Section II
# register description, AL Control 0x0120 and AL Status 0x0130 notes; Section I "Device
# Emulation").  Loaded from SII word 0 (ESI Eeprom/ConfigData byte 1).
ESC_DEVICE_EMULATION = 0x01
# ESC configuration 0x0141 bits 2 and 3: the DC SYNC output unit and the DC latch input unit
# are enabled (Beckhoff ESC Section II, ESC Configuration 0x0141: "0: disabled (power
# saving)").  Loaded from SII word 0 like bit 0.
ESC_DC_SYNC_UNIT = 0x04
# DC activation 0x0981 (the high byte of AssignActivate): bit 0 cyclic operation, bit 1
# SYNC0, bit 2 SYNC1 (ESC Section II, Activation register 0x0981).
DC_ACTIVATION = 0x0981
DC_ACTIVATE_CYCLIC = 0x01
DC_ACTIVATE_SYNC0 = 0x02
DC_ACTIVATE_SYNC1 = 0x04
ESC_DC_LATCH_UNIT = 0x08


def sync0_running(activation: int) -> bool:
    """Whether the activation byte of 0x0981 (an AssignActivate's high byte) runs SYNC0:
    cyclic operation and SYNC0 both on."""
    on = DC_ACTIVATE_CYCLIC | DC_ACTIVATE_SYNC0
    return activation & on == on


# PDI control 0x0140: the process data interface.  0x04 = digital I/O, the PDI of simple
# terminals (EL1xxx, EL2xxx): the ESC drives the I/O pins from process memory itself
# (ESC Section II, PDI Control 0x0140).
PDI_DIGITAL_IO = 0x04


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
    def source(self) -> AlState:
        return _STATE_BY_LETTER[self.value[0]]

    @property
    def target(self) -> AlState:
        return _STATE_BY_LETTER[self.value[1]]


_STATE_BY_LETTER = {"I": AlState.INIT, "P": AlState.PREOP, "S": AlState.SAFEOP,
                    "O": AlState.OP, "B": AlState.BOOT}


@record(frozen=True)
class TransitionRule:
    """What ``apply`` does with the InitCmds of one transition (ETG.2100 ``TransitionType``).

    ``sent``: where apply's sequence sends them, or ``""`` for a transition apply never
    takes (its commands belong to a path apply does not go: nothing it promises needs
    them).  ``mailbox``: whether the slave's mailbox works during the transition, so that a
    CoE, SoE, EoE or FoE command there can be answered at all (ETG.1000.6: no mailbox in INIT; in
    BOOT only the bootstrap mailbox, for FoE); a mailbox command in a transition without
    one is refused by name, whoever would run it."""

    sent: str
    why: str
    mailbox: bool


_NO_MAILBOX_INIT = "a slave in INIT has no mailbox (SM0/SM1 start working in PREOP)"
_BOOT = ("BOOT is for firmware updates (FoE over the bootstrap mailbox); apply does not "
         "go there")

TRANSITION_RULES: dict[Transition, TransitionRule] = {
    # ETG.2100: II are the commands for a slave in INIT asked for INIT, the state the
    # master starts every slave from; TwinCAT writes "assign EEPROM back to ECAT" there.
    Transition.II: TransitionRule(
        "at the start of each way up from INIT, before INIT->PREOP (at start-up after "
        "the scan; for a slave brought back, after its INIT request)",
        _NO_MAILBOX_INIT, False),
    Transition.IP: TransitionRule(
        "on the way up; the mailbox InitCmds (CoE, SoE, EoE, FoE) once the slave is in "
        "PREOP",
        "the mailbox starts working in PREOP", True),
    Transition.PS: TransitionRule("on the way up", "mailbox in PREOP (the PDO assignment "
                                  "before SAFEOP)", True),
    Transition.SO: TransitionRule("on the way up", "mailbox in SAFEOP", True),
    Transition.OS: TransitionRule("on the way down", "mailbox in OP", True),
    Transition.SP: TransitionRule("on the way down", "mailbox in SAFEOP", True),
    Transition.PI: TransitionRule("on the way down", "mailbox until the INIT request", True),
    # A state requested again of a slave already in it: apply requests each state once on
    # its way up and once on its way down (a running master's restart in that state).
    Transition.PP: TransitionRule("", "PREOP requested of a slave in PREOP: apply requests "
                                  "each state once on each way", True),
    Transition.SS: TransitionRule("", "SAFEOP requested of a slave in SAFEOP: apply requests "
                                  "each state once on each way", True),
    # Direct transitions: apply goes step by step and runs the steps' commands instead
    # (what a direct transition sets up or clears, its steps do too: ETG.2100 exports
    # repeat e.g. "clear sms" in SP and OP, the INIT request in PI, SI and OI).
    Transition.PO: TransitionRule("", "a direct PREOP->OP: apply goes through SAFEOP "
                                  "(PS, SO)", True),
    Transition.SI: TransitionRule("", "a direct SAFEOP->INIT: apply goes through PREOP "
                                  "(SP, PI)", True),
    Transition.OP: TransitionRule("", "a direct OP->PREOP: apply goes through SAFEOP "
                                  "(OS, SP)", True),
    Transition.OI: TransitionRule("", "a direct OP->INIT: apply goes step by step "
                                  "(OS, SP, PI)", True),
    Transition.IB: TransitionRule("", f"{_BOOT}; {_NO_MAILBOX_INIT}", False),
    Transition.BI: TransitionRule("", f"{_BOOT}; in BOOT only the bootstrap mailbox "
                                  "works, for FoE", False),
}


def al_state_name(al_status: int) -> str:
    """The state in an AL status (or control) value as the tools print it: ``OP``,
    ``SAFEOP+ERR``, or ``state 0x5`` for a code that is no state."""
    state = al_status & AL_STATE_MASK
    known = AlState._value2member_map_.get(state)
    name = known.name if known is not None else f"state 0x{state:X}"
    return name + ("+ERR" if al_status & AL_STATUS_ERROR else "")


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
    def from_bytes(cls, data: bytes | bytearray) -> FmmuConfig:
        (start, length, sbit, ebit, phys, pbit, kind,
         active) = cls._LAYOUT.unpack(bytes(data[:FMMU_SIZE]))
        return cls(start, length, sbit, ebit, phys, pbit, FmmuType(kind & 3), bool(active & 1))

    @property
    def bit_length(self) -> int:
        """Logical bits mapped: from the start bit of the first byte to the stop bit of the
        last."""
        return (self.length - 1) * 8 + self.logical_stop_bit - self.logical_start_bit + 1


def fmmus_cover(fmmus: Sequence[FmmuConfig], start: int, length: int,
                kind: FmmuType) -> bool:
    """Whether FMMUs of direction ``kind`` map every byte of ``start``..``start+length``
    (what a slave checks of its process-data SMs before SAFEOP, SOES ``ESC_checkSM23``; the
    emulated firmware and the master's diagnosis both ask it)."""
    covered: set[int] = set()
    for f in fmmus:
        if f.type & kind:
            first = f.physical_start
            covered.update(range(first, first + (f.bit_length + f.physical_start_bit
                                                 + 7) // 8))
    return all(a in covered for a in range(start, start + length))


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
    def from_bytes(cls, data: bytes | bytearray) -> SmConfig:
        start, length, control, status, activate, pdi = cls._LAYOUT.unpack(
            bytes(data[:SM_SIZE]))
        return cls(start, length, control, bool(activate & 1), status, pdi)


# -- the EEPROM (SII) interface: control/status register 0x0502 (ETG.1000.4; SOEM's
# ethercattype.h EC_ECMD_* and EC_ESTAT_*, IgH's master/fsm_sii.c) -------------------------

EEPROM_WRITE_ENABLE = 0x0001      # bit 0: write enable (self-clearing)
EEPROM_R64 = 0x0040               # bit 6: a read returns 8 bytes (else 4)
EEPROM_CMD_MASK = 0x0700          # bits 10:8: the command
EEPROM_CMD_READ = 0x0100
EEPROM_CMD_WRITE = 0x0200
EEPROM_CMD_RELOAD = 0x0400        # (SOEM's EC_ECMD_RELOAD is 0x0300; the emulated ESC
                                  # takes both as a reload)
EEPROM_ERRORS = 0x7800            # bits 14:11: checksum, loading, acknowledge, write enable
EEPROM_ERROR_ACKNOWLEDGE = 0x2000 # bit 13: missing EEPROM acknowledge or invalid command
EEPROM_ERROR_WRITE_ENABLE = 0x4000  # bit 14: a write command without write enable
EEPROM_BUSY = 0x8000              # bit 15


def eeprom_read_request(word_address: int) -> bytes:
    """EEPROM control/status + address (0x0502, 6 bytes): 'read' at ``word_address``."""
    return struct.pack("<HI", EEPROM_CMD_READ, word_address)


def eeprom_write_request(word_address: int, word: int) -> bytes:
    """EEPROM control/status + address + data (0x0502, 8 bytes): 'write' one word with
    write enable, in one datagram as IgH's fsm_sii.c sends it; the ESC starts the command
    once the whole datagram is in."""
    return struct.pack("<HIH", EEPROM_CMD_WRITE | EEPROM_WRITE_ENABLE, word_address, word)


# SII word addresses (ETG.2010 header; esi/sii.py builds and decodes the whole image and
# checks its layout against these).
SII_VENDOR_ID = 0x0008
SII_PRODUCT_CODE = 0x000A
SII_REVISION = 0x000C
SII_SERIAL = 0x000E
SII_ALIAS = 0x0004                # configured station alias, loaded into 0x0012 at power-on
SII_CHECKSUM = 0x0007             # low byte: CRC-8 of words 0-6 (esi/sii.py crc8)
SII_BOOTSTRAP_MAILBOX = 0x0014    # receive offset, size, send offset, size (4 words)
SII_STD_MAILBOX = 0x0018          # receive (SM0) offset, size, send (SM1) offset, size
SII_MAILBOX_PROTOCOLS = 0x001C
SII_SIZE = 0x003E                 # EEPROM size in kbit - 1
SII_VERSION = 0x003F
SII_FIRST_CATEGORY = 0x0040

# Word 0x1C, the mailbox protocols a slave supports (ETG.2010; a different encoding from the
# protocol type of the mailbox header, runtime/mailbox.py).
MAILBOX_PROTOCOL_BITS: dict[str, int] = {"AoE": 0x01, "EoE": 0x02, "CoE": 0x04, "FoE": 0x08,
                                         "SoE": 0x10, "VoE": 0x20}


def mailbox_protocol_names(word: int) -> list[str]:
    """The protocols set in SII word 0x1C."""
    return [name for name, bit in MAILBOX_PROTOCOL_BITS.items() if word & bit]


# -- the mailbox: the smallest message that carries an SDO (ETG.1000.4 mailbox header,
# ETG.1000.6 CoE header and SDO command).  runtime/mailbox.py lays out the headers; these
# sizes are what lint and the compiler need without the codec. -----------------------------

MAILBOX_HEADER_SIZE = 6           # length, address, channel/priority, type/counter
SDO_MIN_SIZE = 2 + 8              # CoE header + SDO command, index, subindex, 4 data bytes
MIN_MAILBOX_SIZE = MAILBOX_HEADER_SIZE + SDO_MIN_SIZE       # 16

# -- FoE (ETG.1000.6 FoE, mailbox type 4): the header every FoE message starts with.  The
# codec of the messages is runtime/foe.py; the ENI's FoE InitCmds (eni/plan.py FoeInitCmd)
# carry one such message as Data, so the header is here, below both (SOEM ec_FOEt, SOES
# FOE_OP_*, Wireshark packet-ecatmb.c). ------------------------------------------------------

FOE_HEADER = struct.Struct("<BxI")    # OpCode, reserved, password / packet number / error code


class FoeOpCode(IntEnum):
    """FoE OpCode, the first byte of every FoE message."""

    READ = 1          # read request: password, file name
    WRITE = 2         # write request: password, file name
    DATA = 3          # packet number, file bytes
    ACK = 4           # packet number
    ERROR = 5         # error code, text
    BUSY = 6          # done, entire (UINT16 each), text


# -- CoE communication area (ETG.1000.6 object dictionary) ---------------------------------

RX_PDO_MAPPING = range(0x1600, 0x1800)        # RxPDO (outputs) mapping objects
TX_PDO_MAPPING = range(0x1A00, 0x1C00)        # TxPDO (inputs) mapping objects
SM_COMM_TYPE = 0x1C00                         # communication type of each SM
SM_PDO_ASSIGN = 0x1C10                        # + SM number: the PDOs assigned to that SM
SM_PDO_ASSIGN_RANGE = range(0x1C10, 0x1C30)   # 32 SyncManagers
MODULE_IDENT_LIST = 0xF030                    # configured module ident list (modular devices)
# The SyncManager parameter objects of the outputs (SM2) and inputs (SM3), ETG.1020
# "Synchronization": subindex 5 is the minimum cycle time in ns the slave supports; the
# Slave Stack Code refuses a SYNC0 cycle time (0x09A0) below it (AL status code 0x0035 or
# 0x0036) and reports MIN_PD_CYCLE_TIME there.
SM_OUTPUT_PARAMETER = 0x1C32
SM_INPUT_PARAMETER = 0x1C33
SM_PARAMETER_MIN_CYCLE = 5
# The most entries a PDO mapping object can hold: subindex 0 counts them in a UINT8, and
# subindex 0xFF is reserved for the object's structure (CiA 301, which CoE follows).
MAX_PDO_ENTRIES = 254
DETECTED_MODULE_IDENT_LIST = 0xF050           # the modules the device detected


def pdo_mapping_range(direction: str) -> range:
    """The mapping objects of a PDO direction: ``rx`` (outputs) or ``tx`` (inputs)."""
    return RX_PDO_MAPPING if direction == "rx" else TX_PDO_MAPPING


def is_pdo_object(index: int) -> bool:
    """A PDO mapping or assignment object: the ones a PDO configuration writes."""
    return index in RX_PDO_MAPPING or index in TX_PDO_MAPPING or index in SM_PDO_ASSIGN_RANGE


def array_downloads(writes: Iterable[tuple[int, bytes, bool]],
                    entry_size: int) -> tuple[int | None, dict[int, int]]:
    """What an array object (subindex 0 = number of entries, then unsigned entries of
    ``entry_size`` bytes: PDO assignment 2, mapping and module ident list 4) holds after
    downloads (subindex, data, complete access) in order: (subindex 0, or None if never
    written; {subindex: value} of the entries written).  A complete access from subindex 0
    carries subindex 0 in a 16-bit slot, then the entries (ETG.1000.6 SDO complete
    access); from subindex k it carries entries k, k + 1, ..."""
    count: int | None = None
    entries: dict[int, int] = {}
    for subindex, data, complete in writes:
        if not complete:
            if subindex == 0:
                count = data[0] if data else 0
            else:
                entries[subindex] = int.from_bytes(data[:entry_size], "little")
            continue
        if subindex == 0 and data:
            count, data, subindex = data[0], data[2:], 1
        for offset in range(0, len(data) - entry_size + 1, entry_size):
            entries[subindex] = int.from_bytes(data[offset:offset + entry_size], "little")
            subindex += 1
    return count, entries

# Ethernet: EtherType, and how much datagram data one frame can carry (1500 payload − 2
# EtherCAT header; every datagram costs a 10-byte header and a 2-byte WKC: IgH
# EC_MAX_DATA_SIZE, SOEM EC_MAXLRWDATA; docs/protocol-notes.md §1).
ETHERTYPE = 0x88A4
ETH_HEADER_SIZE = 14          # destination MAC, source MAC, EtherType
MIN_FRAME = 60                # Ethernet minimum without FCS: shorter frames are padded
FRAME_PAYLOAD = 1500
FRAME_HEADER = 2
DATAGRAM_HEADER = 10          # command, index, address, length, IRQ
DATAGRAM_OVERHEAD = DATAGRAM_HEADER + 2     # ... and the working counter after the data
MAX_DATAGRAM_DATA = FRAME_PAYLOAD - FRAME_HEADER - DATAGRAM_OVERHEAD     # 1486


def frame_bytes(data_lengths: list[int]) -> int:
    """The Ethernet payload a frame of datagrams with these data lengths takes; it fits one
    frame while this is at most ``FRAME_PAYLOAD``."""
    return FRAME_HEADER + sum(DATAGRAM_OVERHEAD + n for n in data_lengths)


# AL status codes (register 0x0134; ETG.1000.6, as SOEM ec_print.c, IgH fsm_change.c, SOES
# and KickCAT name them: docs/protocol-notes.md §4).
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


class AlStatusCode(IntEnum):
    """The AL status codes (0x0134) the emulated firmware gives, or whose cause the master
    reads from a slave (``runtime/master/diagnose.py``); their texts are above."""

    NO_ERROR = 0x0000
    INVALID_STATE_CHANGE = 0x0011
    UNKNOWN_STATE = 0x0012
    BOOT_NOT_SUPPORTED = 0x0013
    INVALID_MAILBOX_BOOT = 0x0015           # invalid mailbox configuration (BOOT)
    INVALID_MAILBOX = 0x0016                # invalid mailbox configuration (PREOP)
    SM_WATCHDOG = 0x001B
    INVALID_OUTPUTS = 0x001D
    INVALID_INPUTS = 0x001E
    DC_INVALID_SYNC = 0x0030                # invalid DC SYNC configuration
    DC_INVALID_SYNC_CYCLE = 0x0035
    DC_INVALID_SYNC0_CYCLE = 0x0036
    DC_INVALID_SYNC1_CYCLE = 0x0037
    MBX_SOE = 0x0045                        # an SoE drive's parameters refuse the state


def al_status_name(code: int) -> str:
    return AL_STATUS_CODES.get(code, "vendor-specific or unknown code")
