"""SoE (Servo drive profile over EtherCAT, ETG.1000.6 5.8 / IEC 61800-7-304) wire codec,
shared by the master (``runtime/master/soe_client.py``) and the emulated drive
(``runtime/segment/soe_server.py``), as ``mailbox.py`` serves CoE.

An SoE message is a mailbox message of type 5 whose data starts with a 4-byte SoE header
(SOEM ``ethercatsoe.c`` ``ec_SoEt``, Wireshark ``packet-ecatmb.c``
``ETHERCAT_SOE_HEADER``, the Beckhoff slave sample code ``TSOEHEADER``):

- byte 0: OpCode (bits 0-2: 1 read request, 2 read response, 3 write request, 4 write
  response, 5 notification, 6 slave info, 7 reserved), Incomplete (bit 3: more fragments
  follow), Error (bit 4: an error code follows), DriveNo (bits 5-7: the drive behind the
  slave, 0..7);
- byte 1: the element flags: which parts of the IDN the service reads or writes (0x01 data
  state, 0x02 name, 0x04 attribute, 0x08 unit, 0x10 minimum, 0x20 maximum, 0x40 value,
  0x80 default value);
- bytes 2-3: the IDN (little endian) or, in a fragment with Incomplete set, the number of
  fragments still to come.

Then the data.  An error reply carries its 16-bit SoE error code after the header (the
Beckhoff slave code appends it there; SOEM reads the last two bytes of the message, which is
the same word).

**Fragments.**  A value that does not fit one mailbox goes in several messages: every one
but the last has Incomplete set and the fragments left in place of the IDN; the last carries
the IDN.  The fragments left count down to 1 in the one before the last (IgH
``fsm_soe.c``; SOEM's ``psize / maxdata`` gives one more when the size is an exact
multiple of a fragment, which its slaves ignore).  A write's fragments are not answered;
the drive answers the last (SOEM ``ecx_SoEwrite`` waits only for the mailbox to empty in
between).  A read response is fragmented the same way by the drive.
"""

from __future__ import annotations

import struct
from enum import IntEnum

from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.idn import MAX_DRIVE, VALUE_ELEMENT, idn_text
from ecatcfg.esi.idn import WRITE_REQUEST as WRITE_REQUEST_OPCODE
from ecatcfg.record import record
from ecatcfg.runtime.mailbox import (MBX_HEADER_SIZE, MailboxProtocolError, MbxErrorDetail,
                                     MbxType, encode_mailbox)

SOE_HEADER = struct.Struct("<BBH")        # opcode|incomplete|error|drive, elements, IDN
SOE_HEADER_SIZE = SOE_HEADER.size         # 4
SOE_OVERHEAD = MBX_HEADER_SIZE + SOE_HEADER_SIZE     # 10: data of a fragment = SM size - 10

OPCODE_MASK = 0x07
INCOMPLETE = 0x08
ERROR = 0x10
DRIVE_SHIFT = 5


class SoeOpCode(IntEnum):
    """SoE header byte 0, bits 0-2 (SOEM ``ECT_SOE_*``, Wireshark ``ECAT_SOE_OPCODE_*``)."""

    READ_REQUEST = 1
    READ_RESPONSE = 2
    WRITE_REQUEST = WRITE_REQUEST_OPCODE
    WRITE_RESPONSE = 4
    NOTIFICATION = 5
    SLAVE_INFO = 6


# The element flags byte (SOEM EC_SOE_*_B), in the order their parts follow in a message
# that carries several.
ELEMENT_DATA_STATE = 0x01
ELEMENT_NAME = 0x02
ELEMENT_ATTRIBUTE = 0x04
ELEMENT_UNIT = 0x08
ELEMENT_MIN = 0x10
ELEMENT_MAX = 0x20
ELEMENT_VALUE = VALUE_ELEMENT
ELEMENT_DEFAULT = 0x80
ELEMENT_NAMES: dict[int, str] = {
    ELEMENT_DATA_STATE: "data state", ELEMENT_NAME: "name", ELEMENT_ATTRIBUTE: "attribute",
    ELEMENT_UNIT: "unit", ELEMENT_MIN: "minimum", ELEMENT_MAX: "maximum",
    ELEMENT_VALUE: "value", ELEMENT_DEFAULT: "default value",
}

# SoE error codes (IEC 61800-7-304; the table of IgH ``master/soe_errors.c`` and SOEM
# ``ethercatprint.c`` ``ec_soeerrorlist``, whose last three entries all read 0x800A where
# IgH has 0x800A, 0x800B, 0x800C).
SOE_ERRORS: dict[int, str] = {
    0x0000: "no error",
    0x1001: "no IDN",
    0x1009: "invalid access to element 1",
    0x2001: "no name",
    0x2002: "name transmission too short",
    0x2003: "name transmission too long",
    0x2004: "name cannot be changed (read only)",
    0x2005: "name is write-protected at this time",
    0x3002: "attribute transmission too short",
    0x3003: "attribute transmission too long",
    0x3004: "attribute cannot be changed (read only)",
    0x3005: "attribute is write-protected at this time",
    0x4001: "no units",
    0x4002: "unit transmission too short",
    0x4003: "unit transmission too long",
    0x4004: "unit cannot be changed (read only)",
    0x4005: "unit is write-protected at this time",
    0x5001: "no minimum input value",
    0x5002: "minimum input value transmission too short",
    0x5003: "minimum input value transmission too long",
    0x5004: "minimum input value cannot be changed (read only)",
    0x5005: "minimum input value is write-protected at this time",
    0x6001: "no maximum input value",
    0x6002: "maximum input value transmission too short",
    0x6003: "maximum input value transmission too long",
    0x6004: "maximum input value cannot be changed (read only)",
    0x6005: "maximum input value is write-protected at this time",
    0x7002: "operation data transmission too short",
    0x7003: "operation data transmission too long",
    0x7004: "operation data cannot be changed (read only)",
    0x7005: "operation data is write-protected at this time (state)",
    0x7006: "operation data is smaller than the minimum input value",
    0x7007: "operation data is greater than the maximum input value",
    0x7008: "invalid operation data: configured IDN will not be supported",
    0x7009: "operation data write-protected by a password",
    0x700A: "operation data is write-protected, it is configured cyclically",
    0x700B: "invalid indirect addressing (data container, list handling)",
    0x700C: "operation data is write-protected due to other settings",
    0x7010: "procedure command already active",
    0x7011: "procedure command not interruptible",
    0x7012: "procedure command at this time not executable (state)",
    0x7013: "procedure command not executable (invalid or false parameters)",
    0x7014: "no data state",
    0x8001: "no default value",
    0x8002: "default value transmission too long",
    0x8004: "default value cannot be changed, read only",
    0x800A: "invalid drive number",
    0x800B: "general error",
    0x800C: "no element addressed",
}

# Error codes by name, for the code that sends them.
SOE_NO_IDN = 0x1001
SOE_DATA_TOO_SHORT = 0x7002
SOE_DATA_TOO_LONG = 0x7003
SOE_DATA_READ_ONLY = 0x7004
SOE_DATA_WRITE_PROTECTED = 0x7005
SOE_INVALID_DRIVE = 0x800A
SOE_GENERAL_ERROR = 0x800B
SOE_NO_ELEMENT = 0x800C
# "no <element>": what a drive answers for an element the IDN does not have.
SOE_NO_ELEMENT_CODES: dict[int, int] = {
    ELEMENT_NAME: 0x2001, ELEMENT_UNIT: 0x4001, ELEMENT_MIN: 0x5001, ELEMENT_MAX: 0x6001,
    ELEMENT_DATA_STATE: 0x7014, ELEMENT_DEFAULT: 0x8001,
}
# "<element> cannot be changed (read only)": what a drive answers for a write of an
# element other than the value (the name, attribute, unit, limits and default are the
# drive's own, IEC 61800-7-204).
SOE_READ_ONLY_ELEMENT_CODES: dict[int, int] = {
    ELEMENT_NAME: 0x2004, ELEMENT_ATTRIBUTE: 0x3004, ELEMENT_UNIT: 0x4004,
    ELEMENT_MIN: 0x5004, ELEMENT_MAX: 0x6004, ELEMENT_DEFAULT: 0x8004,
}


def soe_error_name(code: int) -> str:
    return SOE_ERRORS.get(code, "vendor-specific or unknown SoE error")


class SoeError(EcatcfgError):
    """A drive answered an SoE request with an error code."""

    def __init__(self, code: int, idn: int, drive_no: int = 0, action: str = "") -> None:
        what = f" {action}" if action else ""
        super().__init__(f"SoE error 0x{code:04X} ({soe_error_name(code)}){what} "
                         f"{idn_text(idn)} of drive {drive_no}")
        self.code = code
        self.idn = idn
        self.drive_no = drive_no


# -- the Sercos attribute word (element 3) --------------------------------------------------

# Bit fields of the 32-bit attribute (SOEM ``ec_SoEattributet``): bits 0-15 conversion factor,
# 16-17 the length of the value or of a list element (1, 2, 4, 8 bytes), 18 list, 19 procedure
# command, 20-22 data type, 24-27 decimal places, 28-30 write-protected in PREOP, SAFEOP, OP.
ATTR_LENGTH_SHIFT = 16
ATTR_LIST = 1 << 18
ATTR_COMMAND = 1 << 19
ATTR_TYPE_SHIFT = 20
ATTR_WP_PREOP = 1 << 28
ATTR_WP_SAFEOP = 1 << 29
ATTR_WP_OP = 1 << 30
ATTR_TYPE_BINARY, ATTR_TYPE_UINT, ATTR_TYPE_INT, ATTR_TYPE_HEX, ATTR_TYPE_STRING, \
    ATTR_TYPE_IDN = range(6)
_LENGTH_CODES = {1: 0, 2: 1, 4: 2, 8: 3}


def attribute(length: int, data_type: int = ATTR_TYPE_UINT, *, is_list: bool = False,
              factor: int = 1, wp_preop: bool = False, wp_safeop: bool = False,
              wp_op: bool = False) -> int:
    """The attribute word of an IDN whose value (or list element) is ``length`` bytes."""
    code = _LENGTH_CODES.get(length)
    if code is None:
        raise ValueError(f"an IDN element is 1, 2, 4 or 8 bytes, not {length}")
    return (factor & 0xFFFF | code << ATTR_LENGTH_SHIFT | (ATTR_LIST if is_list else 0)
            | (data_type & 0x7) << ATTR_TYPE_SHIFT | (ATTR_WP_PREOP if wp_preop else 0)
            | (ATTR_WP_SAFEOP if wp_safeop else 0) | (ATTR_WP_OP if wp_op else 0))


def attribute_element_size(word: int) -> int:
    """The bytes of the value (or of one list element) an attribute word gives."""
    return 1 << (word >> ATTR_LENGTH_SHIFT & 0x3)


def encode_list(data: bytes, max_length: int | None = None) -> bytes:
    """A Sercos list or string value: current length and maximum length in bytes (16 bits
    each), then the data (SOEM ``ec_SoElistt``, ``ec_SoEnamet``)."""
    maximum = len(data) if max_length is None else max_length
    return struct.pack("<HH", len(data), maximum) + data


def decode_list(value: bytes) -> tuple[bytes, int]:
    """The data and maximum length of a list value; ValueError when the lengths do not
    fit."""
    if len(value) < 4:
        raise ValueError(f"a list value starts with 4 length bytes, not {len(value)}")
    current, maximum = struct.unpack_from("<HH", value)
    if current != len(value) - 4 or current > maximum:
        raise ValueError(f"list of {len(value) - 4} bytes says current length {current}, "
                         f"maximum {maximum}")
    return bytes(value[4:]), maximum


# -- messages --------------------------------------------------------------------------------

@record(frozen=True)
class SoeMessage:
    """One SoE message (what follows the mailbox header).  ``idn`` holds the fragments
    left when ``incomplete`` is set; ``data`` is what follows the SoE header."""

    op_code: int
    drive_no: int
    elements: int
    idn: int
    data: bytes = b""
    incomplete: bool = False
    error: bool = False

    @property
    def fragments_left(self) -> int:
        return self.idn

    @property
    def error_code(self) -> int | None:
        """The SoE error code of an error reply (its last two bytes, as SOEM reads it)."""
        if not self.error or len(self.data) < 2:
            return None
        code: int = struct.unpack_from("<H", self.data, len(self.data) - 2)[0]
        return code


def encode_soe(op_code: int, idn: int, data: bytes = b"", *, drive_no: int = 0,
               elements: int = ELEMENT_VALUE, incomplete: bool = False, error: bool = False,
               counter: int = 0, address: int = 0) -> bytes:
    """A whole mailbox message (type 5) with one SoE header and ``data``."""
    if not 0 <= drive_no <= MAX_DRIVE:
        raise ValueError(f"drive number {drive_no}: the SoE header has 3 bits (0..7)")
    first = (op_code & OPCODE_MASK | (INCOMPLETE if incomplete else 0)
             | (ERROR if error else 0) | drive_no << DRIVE_SHIFT)
    return encode_mailbox(MbxType.SOE, SOE_HEADER.pack(first, elements & 0xFF, idn & 0xFFFF)
                          + bytes(data), counter, address)


def decode_soe(data: bytes) -> SoeMessage:
    """The SoE message in a mailbox message's data; shorter than the header is mailbox
    error 6 (size too short), as for every protocol."""
    if len(data) < SOE_HEADER_SIZE:
        raise MailboxProtocolError(f"SoE message of {len(data)} bytes is shorter than the "
                                   "4-byte SoE header", detail=MbxErrorDetail.SIZE_TOO_SHORT)
    first, elements, idn = SOE_HEADER.unpack_from(data)
    return SoeMessage(first & OPCODE_MASK, first >> DRIVE_SHIFT, elements, idn,
                      bytes(data[SOE_HEADER_SIZE:]), bool(first & INCOMPLETE),
                      bool(first & ERROR))


def encode_read_request(idn: int, *, drive_no: int = 0, elements: int = ELEMENT_VALUE,
                        counter: int = 0) -> bytes:
    return encode_soe(SoeOpCode.READ_REQUEST, idn, drive_no=drive_no, elements=elements,
                      counter=counter)


def encode_write_response(idn: int, *, drive_no: int = 0,
                          elements: int = ELEMENT_VALUE) -> bytes:
    return encode_soe(SoeOpCode.WRITE_RESPONSE, idn, drive_no=drive_no, elements=elements)


def encode_error(op_code: int, idn: int, code: int, *, drive_no: int = 0,
                 elements: int = ELEMENT_VALUE) -> bytes:
    """An error reply: the response opcode with the Error bit, the IDN, the error code."""
    return encode_soe(op_code, idn, struct.pack("<H", code), drive_no=drive_no,
                      elements=elements, error=True)


def fragment_sizes(size: int, mbx_size: int) -> list[int]:
    """The data bytes of each message carrying ``size`` bytes through a ``mbx_size``-byte
    mailbox (at least one message, also for no data)."""
    room = mbx_size - SOE_OVERHEAD
    if room < 1:
        raise ValueError(f"a {mbx_size}-byte mailbox cannot carry SoE data")
    sizes = [room] * (size // room)
    if size % room or not sizes:
        sizes.append(size % room)
    return sizes


def encode_fragments(op_code: int, idn: int, data: bytes, mbx_size: int, *,
                     drive_no: int = 0, elements: int = ELEMENT_VALUE) -> list[bytes]:
    """``data`` as one or more messages of ``op_code`` (a write request, or a read
    response), each fitting a ``mbx_size``-byte mailbox; counters 0."""
    sizes = fragment_sizes(len(data), mbx_size)
    messages = []
    offset = 0
    for n, size in enumerate(sizes):
        left = len(sizes) - 1 - n
        messages.append(encode_soe(op_code, idn if not left else left,
                                   data[offset:offset + size], drive_no=drive_no,
                                   elements=elements, incomplete=bool(left)))
        offset += size
    return messages


class Reassembly:
    """The fragments of one write request or read response put together: :meth:`add`
    each message in turn; it returns the whole data once the last (not incomplete) one has
    come, ``None`` before.  A fragment count that does not go down by one, or a change of
    drive, elements or opcode in between, raises ValueError."""

    def __init__(self) -> None:
        self.data = bytearray()
        self._first: SoeMessage | None = None
        self._left: int | None = None

    @property
    def started(self) -> bool:
        return self._first is not None

    def add(self, message: SoeMessage) -> bytes | None:
        first = self._first
        if first is not None and (message.op_code, message.drive_no, message.elements) != (
                first.op_code, first.drive_no, first.elements):
            raise ValueError("a fragment of another service, drive or element came in "
                             "between")
        if self._left is not None:
            expected = self._left - 1
            got = message.fragments_left if message.incomplete else 0
            if got != expected:
                raise ValueError(f"fragment with {got} fragments left after one with "
                                 f"{self._left}")
        self._first = self._first or message
        self.data += message.data
        if message.incomplete:
            self._left = message.fragments_left
            if self._left < 1:
                raise ValueError("an incomplete fragment with no fragments left")
            return None
        return bytes(self.data)
