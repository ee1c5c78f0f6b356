"""Mailbox and CoE/SDO wire codec shared by the master (SDO client) and the virtual slave
(SDO server).

One module for the constants and byte layouts, the way python-canopen's ``sdo/constants.py``
serves its client and server: both sides import the same encoders and decoders, so a layout
lives in exactly one place.  Plain ``struct``: this runs per mailbox message.

Layouts follow ETG.1000.6 (mailbox §5.5, CoE §5.6) as SOEM, SOES, IgH, KickCAT and
Wireshark implement them; ``docs/protocol-notes.md`` ("protocol-notes §5" mailbox, "§6" CoE)
names the file of each project where a layout can be checked.
Every ``encode_*`` function returns a whole mailbox message: the 6-byte mailbox header plus
its data, *not* padded; a writer pads it to the SyncManager length with :func:`pad_to`.
"""

from __future__ import annotations

import struct
from enum import IntEnum

from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import MAILBOX_HEADER_SIZE, MIN_MAILBOX_SIZE, SDO_MIN_SIZE
from ecatcfg.record import record

# -- mailbox header (protocol-notes §5) --------------------------------------------------

MBX_HEADER = struct.Struct("<HHBB")       # length, address, channel|priority, type|counter
MBX_HEADER_SIZE = MBX_HEADER.size         # 6
COE_HEADER = struct.Struct("<H")          # number bits 0-8, service bits 12-15
COE_HEADER_SIZE = COE_HEADER.size         # 2
# SDO frame after the CoE header: command, index, subindex, data/size/abort code
# (protocol-notes §6).
SDO_HEADER = struct.Struct("<BHBI")
SDO_MIN_LENGTH = COE_HEADER_SIZE + SDO_HEADER.size      # 10: mailbox length of an SDO
# Bytes of mailbox (header included) in front of the data of a normal initiate download or
# upload (6 mailbox + 2 CoE + 8 SDO) and of a segment (6 + 2 + 1 command byte).
NORMAL_OVERHEAD = MBX_HEADER_SIZE + SDO_MIN_LENGTH      # 16: first data at SM size - 16
SEGMENT_OVERHEAD = MBX_HEADER_SIZE + COE_HEADER_SIZE + 1   # 9: segment data = SM size - 9
SEGMENT_MIN_DATA = 7                      # a shorter segment is padded to mailbox length 10
# The sizes esc.py gives lint and the compiler (the smallest useful mailbox) are these.
assert (MBX_HEADER_SIZE, SDO_MIN_LENGTH, NORMAL_OVERHEAD) == (
    MAILBOX_HEADER_SIZE, SDO_MIN_SIZE, MIN_MAILBOX_SIZE)


class MbxType(IntEnum):
    """Mailbox header byte 5, bits 0-3 (protocol-notes §5)."""

    ERROR = 0
    AOE = 1
    EOE = 2
    COE = 3
    FOE = 4
    SOE = 5
    VOE = 15


class MbxErrorDetail(IntEnum):
    """Detail word of a mailbox error reply (type 0, body 0x0001 + detail; protocol-notes §5)."""

    SYNTAX = 1
    UNSUPPORTED_PROTOCOL = 2
    INVALID_CHANNEL = 3
    SERVICE_NOT_SUPPORTED = 4
    INVALID_HEADER = 5
    SIZE_TOO_SHORT = 6
    NO_MORE_MEMORY = 7
    INVALID_SIZE = 8
    SERVICE_IN_WORK = 9          # KickCAT only (protocol-notes §5: one source)


MBX_ERROR_DETAILS: dict[int, str] = {
    1: "syntax error", 2: "unsupported protocol", 3: "invalid channel",
    4: "service not supported", 5: "invalid mailbox header", 6: "size too short",
    7: "no more memory", 8: "invalid size", 9: "service in work",
}
MBX_ERROR_TYPE = 0x0001          # the u16 in front of the detail


class CoeService(IntEnum):
    """CoE header bits 12-15 (protocol-notes §6)."""

    EMERGENCY = 1
    SDO_REQUEST = 2
    SDO_RESPONSE = 3
    TXPDO = 4
    RXPDO = 5
    TXPDO_REMOTE_REQUEST = 6
    RXPDO_REMOTE_REQUEST = 7
    SDO_INFO = 8


# -- SDO command byte (protocol-notes §6 table) ------------------------------------------

CS_SHIFT = 5                     # top 3 bits: command specifier
# Client (master) command specifiers, CoE service 2.
CCS_DOWNLOAD_SEGMENT = 0
CCS_INITIATE_DOWNLOAD = 1
CCS_INITIATE_UPLOAD = 2
CCS_UPLOAD_SEGMENT = 3
CS_ABORT = 4                     # either side, always sent with service 2
# Server (slave) command specifiers, CoE service 3.
SCS_UPLOAD_SEGMENT = 0
SCS_DOWNLOAD_SEGMENT = 1
SCS_INITIATE_UPLOAD = 2
SCS_INITIATE_DOWNLOAD = 3

SIZE_INDICATED = 0x01            # initiate: s bit, size given
EXPEDITED = 0x02                 # initiate: e bit, data at +6
TOGGLE = 0x10                    # segments: toggle bit
COMPLETE_ACCESS = 0x10           # initiate: complete access (same bit as the toggle)
LAST_SEGMENT = 0x01              # segments: c bit, no more segments

SDO_INFO_ERROR = 7               # SDO information opcode "error" (+6 = abort code)

ABORT_CODES: dict[int, str] = {
    0x05030000: "toggle bit not changed",
    0x05040000: "SDO protocol timeout",
    0x05040001: "client/server command specifier not valid or unknown",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "out of memory",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write-only object",
    0x06010002: "attempt to write a read-only object",
    0x06010003: "subindex cannot be written, SI0 must be 0 for write access",
    0x06010004: "SDO complete access not supported for variable-length objects",
    0x06010005: "object length exceeds mailbox size",
    0x06010006: "object mapped to RxPDO, SDO download blocked",
    0x06020000: "object does not exist in the object directory",
    0x06040041: "object cannot be mapped into the PDO",
    0x06040042: "number and length of mapped objects would exceed PDO length",
    0x06040043: "general parameter incompatibility",
    0x06040047: "general internal incompatibility in the device",
    0x06060000: "access failed due to a hardware error",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06070012: "data type does not match, length too high",
    0x06070013: "data type does not match, length too low",
    0x06090011: "subindex does not exist",
    0x06090030: "value range of parameter exceeded (only for write access)",
    0x06090031: "value of parameter written too high",
    0x06090032: "value of parameter written too low",
    0x06090033: "detected module ident list does not match",
    0x06090036: "maximum value is less than minimum value",
    0x060A0023: "resource not available",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000021: "data cannot be transferred or stored to the application because of local "
                "control",
    0x08000022: "data cannot be transferred or stored to the application because of the "
                "present device state",
    0x08000023: "object dictionary dynamic generation fails or no object dictionary is "
                "present",
    0x08000024: "no data available",
}

# Abort codes by name, for the code that raises them (names after SOES' ABORT_* macros).
ABORT_TOGGLE = 0x05030000
ABORT_UNKNOWN_COMMAND = 0x05040001
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_SUBINDEX0_NOT_ZERO = 0x06010003
ABORT_CA_NOT_SUPPORTED = 0x06010004
ABORT_NO_OBJECT = 0x06020000
ABORT_TYPE_MISMATCH = 0x06070010
ABORT_LENGTH_TOO_HIGH = 0x06070012
ABORT_LENGTH_TOO_LOW = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032
ABORT_GENERAL_ERROR = 0x08000000
ABORT_WRONG_STATE = 0x08000022


def abort_name(code: int) -> str:
    return ABORT_CODES.get(code, "unknown abort code")


class SdoAbort(EcatcfgError):
    """An SDO transfer ended with an abort code (received, or to be sent by a server)."""

    def __init__(self, code: int, index: int | None = None,
                 subindex: int | None = None) -> None:
        where = "" if index is None else f" at 0x{index:04X}:{subindex or 0:02X}"
        super().__init__(f"SDO abort 0x{code:08X} ({abort_name(code)}){where}")
        self.code = code
        self.index = index
        self.subindex = subindex


class MailboxProtocolError(EcatcfgError):
    """A mailbox message that breaks the protocol (or a mailbox error reply).

    ``detail`` is the mailbox error detail that describes it (what a slave answers with a
    type-0 reply); ``abort_code`` is the SDO abort a client should send to end the transfer
    when the problem is inside an SDO exchange (e.g. a wrong toggle bit).
    """

    def __init__(self, message: str, detail: int | None = None,
                 abort_code: int | None = None) -> None:
        super().__init__(message)
        self.detail = detail
        self.abort_code = abort_code


# -- mailbox header ----------------------------------------------------------------------

@record(frozen=True)
class MailboxHeader:
    length: int                  # bytes after the 6-byte header
    address: int = 0             # 0 = master (SOES answers with 0; protocol-notes §5)
    channel: int = 0             # bits 0-5 of byte 4
    priority: int = 0            # bits 6-7 of byte 4
    type: int = MbxType.COE      # bits 0-3 of byte 5
    counter: int = 0             # bits 4-6 of byte 5; 0 = not used, else 1..7

    def pack(self) -> bytes:
        return MBX_HEADER.pack(self.length, self.address,
                               (self.channel & 0x3F) | (self.priority & 0x03) << 6,
                               (self.type & 0x0F) | (self.counter & 0x07) << 4)

    @classmethod
    def unpack(cls, data: bytes) -> MailboxHeader:
        if len(data) < MBX_HEADER_SIZE:
            raise MailboxProtocolError(f"mailbox message of {len(data)} bytes is shorter "
                                       "than the 6-byte header",
                                       detail=MbxErrorDetail.SIZE_TOO_SHORT)
        length, address, chp, tc = MBX_HEADER.unpack_from(data)
        return cls(length, address, chp & 0x3F, chp >> 6, tc & 0x0F, (tc >> 4) & 0x07)


def next_counter(counter: int) -> int:
    """The mailbox counter after ``counter``: 1..7, wrapping 7 -> 1, never 0 (SOEM
    ``ec_nextmbxcnt``, SOES ``ESC_claimbuffer``)."""
    return counter % 7 + 1


class MailboxCounter:
    """A counter source: each call returns the next counter value (1, 2, ... 7, 1, ...)."""

    def __init__(self, last: int = 0) -> None:
        self.last = last

    def __call__(self) -> int:
        self.last = next_counter(self.last)
        return self.last


def encode_mailbox(mbx_type: int, data: bytes, counter: int = 0, address: int = 0,
                   channel: int = 0, priority: int = 0) -> bytes:
    return MailboxHeader(len(data), address, channel, priority, mbx_type,
                         counter).pack() + data


def decode_mailbox(msg: bytes) -> tuple[MailboxHeader, bytes]:
    """The header and the data of one mailbox message (trailing SM padding ignored).

    A length of 0 or one that runs past the bytes given is an invalid header (SOES sends
    detail 5 for length 0 or > SM0 size - 6; protocol-notes §5).
    """
    header = MailboxHeader.unpack(msg)
    if header.length == 0 or header.length > len(msg) - MBX_HEADER_SIZE:
        raise MailboxProtocolError(f"mailbox length {header.length} does not fit the "
                                   f"{len(msg)} bytes received",
                                   detail=MbxErrorDetail.INVALID_HEADER)
    return header, bytes(msg[MBX_HEADER_SIZE:MBX_HEADER_SIZE + header.length])


def pad_to(msg: bytes, length: int) -> bytes:
    """``msg`` padded with zeros to ``length`` bytes: masters write the whole SM0 area,
    because writing its last byte is what marks the mailbox full (protocol-notes §3)."""
    if len(msg) > length:
        raise ValueError(f"mailbox message of {len(msg)} bytes does not fit a "
                         f"{length}-byte SyncManager")
    return bytes(msg) + bytes(length - len(msg))


# -- mailbox error reply ----------------------------------------------------------------

@record(frozen=True)
class MailboxError:
    """A mailbox error reply (type 0): body 0x0001 + detail (protocol-notes §5)."""

    detail: int

    @property
    def name(self) -> str:
        return MBX_ERROR_DETAILS.get(self.detail, "unknown detail")


def encode_mailbox_error(detail: int, counter: int = 0, address: int = 0) -> bytes:
    return encode_mailbox(MbxType.ERROR, struct.pack("<HH", MBX_ERROR_TYPE, detail),
                          counter, address)


# -- CoE messages -----------------------------------------------------------------------

@record(frozen=True)
class InitiateDownload:
    """Initiate download request (ccs 1).  Expedited: ``data`` is the whole value.  Normal:
    ``size`` is the complete size and ``data`` the part carried in this message."""

    index: int
    subindex: int
    data: bytes
    size: int | None             # None: expedited without the size indicator (4 bytes)
    expedited: bool
    complete_access: bool = False


@record(frozen=True)
class DownloadResponse:
    """Initiate download response (scs 3), index and subindex echoed."""

    index: int
    subindex: int
    complete_access: bool = False


@record(frozen=True)
class DownloadSegment:
    data: bytes
    toggle: bool
    last: bool


@record(frozen=True)
class DownloadSegmentResponse:
    toggle: bool


@record(frozen=True)
class InitiateUpload:
    """Initiate upload request (ccs 2)."""

    index: int
    subindex: int
    complete_access: bool = False


@record(frozen=True)
class UploadResponse:
    """Initiate upload response (scs 2).  Normal: ``size`` is the complete size and ``data``
    the part carried in this message; segments follow while data is short of size."""

    index: int
    subindex: int
    data: bytes
    size: int | None
    expedited: bool
    complete_access: bool = False


@record(frozen=True)
class UploadSegmentRequest:
    toggle: bool


@record(frozen=True)
class UploadSegment:
    data: bytes
    toggle: bool
    last: bool


@record(frozen=True)
class Abort:
    index: int
    subindex: int
    code: int

    @property
    def name(self) -> str:
        return abort_name(self.code)


@record(frozen=True)
class UnknownSdo:
    """An SDO message whose command specifier this codec does not know (e.g. block
    transfer): a server answers it with abort 0x05040001."""

    service: int
    command: int
    index: int
    subindex: int


@record(frozen=True)
class Emergency:
    """CoE emergency (service 1): error code, error register, 5 bytes manufacturer data."""

    error_code: int
    error_register: int
    data: bytes


@record(frozen=True)
class SdoInfo:
    """SDO information (service 8): opcode (bits 0-6), incomplete flag, fragments left and
    the rest of the message.  For opcode 7 (error) ``abort_code`` is set."""

    opcode: int
    incomplete: bool
    fragments_left: int
    body: bytes

    @property
    def abort_code(self) -> int | None:
        if self.opcode != SDO_INFO_ERROR or len(self.body) < 4:
            return None
        code: int = struct.unpack_from("<I", self.body)[0]
        return code


@record(frozen=True)
class OtherCoe:
    """A CoE service this codec does not decode (PDO over mailbox, ...)."""

    service: int
    number: int
    body: bytes


SdoMessage = (InitiateDownload | DownloadResponse | DownloadSegment | DownloadSegmentResponse
              | InitiateUpload | UploadResponse | UploadSegmentRequest | UploadSegment | Abort
              | UnknownSdo)
CoeMessage = SdoMessage | Emergency | SdoInfo | OtherCoe


def _coe(service: int, body: bytes, counter: int, address: int, number: int = 0) -> bytes:
    return encode_mailbox(MbxType.COE,
                          COE_HEADER.pack((number & 0x1FF) | service << 12) + body,
                          counter, address)


def _sdo(service: int, command: int, index: int, subindex: int, word: int, extra: bytes,
         counter: int, address: int) -> bytes:
    return _coe(service, SDO_HEADER.pack(command, index, subindex, word) + extra, counter,
                address)


def _segment(service: int, command: int, data: bytes, counter: int, address: int) -> bytes:
    # Segment data from +3; fewer than 7 bytes: pad to mailbox length 10 and give the number
    # of unused bytes in bits 1-3 (protocol-notes §6).
    if len(data) < SEGMENT_MIN_DATA:
        command |= (SEGMENT_MIN_DATA - len(data)) << 1
        data = data + bytes(SEGMENT_MIN_DATA - len(data))
    return _coe(service, bytes((command,)) + data, counter, address)


def _expedited_command(base: int, data: bytes, complete_access: bool) -> int:
    if not 1 <= len(data) <= 4:
        raise ValueError(f"expedited transfer carries 1..4 bytes, not {len(data)}")
    return (base | (4 - len(data)) << 2 | EXPEDITED | SIZE_INDICATED
            | (COMPLETE_ACCESS if complete_access else 0))


def encode_download_expedited(index: int, subindex: int, data: bytes, counter: int = 0, *,
                              complete_access: bool = False, address: int = 0) -> bytes:
    """Initiate download, expedited: ``0x23 | (4-n)<<2`` (0x2F for 1 byte), data at +6."""
    command = _expedited_command(CCS_INITIATE_DOWNLOAD << CS_SHIFT, data, complete_access)
    word = int.from_bytes(data.ljust(4, b"\0"), "little")
    return _sdo(CoeService.SDO_REQUEST, command, index, subindex, word, b"", counter, address)


def encode_download_normal(index: int, subindex: int, size: int, data: bytes,
                           counter: int = 0, *, complete_access: bool = False,
                           address: int = 0) -> bytes:
    """Initiate download, normal (0x21, 0x31 with complete access): complete size at +6,
    the first ``data`` from +10."""
    command = (CCS_INITIATE_DOWNLOAD << CS_SHIFT | SIZE_INDICATED
               | (COMPLETE_ACCESS if complete_access else 0))
    return _sdo(CoeService.SDO_REQUEST, command, index, subindex, size, data, counter,
                address)


def encode_download_segment(data: bytes, toggle: bool, last: bool, counter: int = 0, *,
                            address: int = 0) -> bytes:
    command = (CCS_DOWNLOAD_SEGMENT << CS_SHIFT | (TOGGLE if toggle else 0)
               | (LAST_SEGMENT if last else 0))
    return _segment(CoeService.SDO_REQUEST, command, data, counter, address)


def encode_download_response(index: int, subindex: int, counter: int = 0, *,
                             complete_access: bool = False, address: int = 0) -> bytes:
    """0x60, plus 0x10 with complete access as SOES answers (protocol-notes §6)."""
    command = SCS_INITIATE_DOWNLOAD << CS_SHIFT | (COMPLETE_ACCESS if complete_access else 0)
    return _sdo(CoeService.SDO_RESPONSE, command, index, subindex, 0, b"", counter, address)


def encode_download_segment_response(toggle: bool, counter: int = 0, *,
                                     address: int = 0) -> bytes:
    command = SCS_DOWNLOAD_SEGMENT << CS_SHIFT | (TOGGLE if toggle else 0)
    return _coe(CoeService.SDO_RESPONSE, bytes((command,)) + bytes(7), counter, address)


def encode_upload_request(index: int, subindex: int, counter: int = 0, *,
                          complete_access: bool = False, address: int = 0) -> bytes:
    """Initiate upload request: 0x40 (0x50 with complete access), +6..9 zero."""
    command = CCS_INITIATE_UPLOAD << CS_SHIFT | (COMPLETE_ACCESS if complete_access else 0)
    return _sdo(CoeService.SDO_REQUEST, command, index, subindex, 0, b"", counter, address)


def encode_upload_expedited(index: int, subindex: int, data: bytes, counter: int = 0, *,
                            complete_access: bool = False, address: int = 0) -> bytes:
    """Initiate upload response, expedited: ``0x43 | (4-n)<<2``, data at +6."""
    command = _expedited_command(SCS_INITIATE_UPLOAD << CS_SHIFT, data, complete_access)
    word = int.from_bytes(data.ljust(4, b"\0"), "little")
    return _sdo(CoeService.SDO_RESPONSE, command, index, subindex, word, b"", counter,
                address)


def encode_upload_normal(index: int, subindex: int, size: int, data: bytes,
                         counter: int = 0, *, complete_access: bool = False,
                         address: int = 0) -> bytes:
    """Initiate upload response, normal (0x41): complete size at +6, data from +10."""
    command = (SCS_INITIATE_UPLOAD << CS_SHIFT | SIZE_INDICATED
               | (COMPLETE_ACCESS if complete_access else 0))
    return _sdo(CoeService.SDO_RESPONSE, command, index, subindex, size, data, counter,
                address)


def encode_upload_segment_request(toggle: bool, counter: int = 0, *,
                                  address: int = 0) -> bytes:
    """``0x60 | t<<4`` and 7 zero bytes (length 10)."""
    command = CCS_UPLOAD_SEGMENT << CS_SHIFT | (TOGGLE if toggle else 0)
    return _coe(CoeService.SDO_REQUEST, bytes((command,)) + bytes(7), counter, address)


def encode_upload_segment(data: bytes, toggle: bool, last: bool, counter: int = 0, *,
                          address: int = 0) -> bytes:
    command = (SCS_UPLOAD_SEGMENT << CS_SHIFT | (TOGGLE if toggle else 0)
               | (LAST_SEGMENT if last else 0))
    return _segment(CoeService.SDO_RESPONSE, command, data, counter, address)


def encode_abort(index: int, subindex: int, code: int, counter: int = 0, *,
                 address: int = 0) -> bytes:
    """Abort (0x80, code at +6), always with CoE service 2, by either side (protocol-notes §6)."""
    return _sdo(CoeService.SDO_REQUEST, CS_ABORT << CS_SHIFT, index, subindex, code, b"",
                counter, address)


def encode_emergency(error_code: int, error_register: int, data: bytes = b"",
                     counter: int = 0, *, address: int = 0) -> bytes:
    if len(data) > 5:
        raise ValueError("an emergency carries at most 5 bytes of manufacturer data")
    body = struct.pack("<HB", error_code, error_register) + data.ljust(5, b"\0")
    return _coe(CoeService.EMERGENCY, body, counter, address)


def encode_sdo_info_error(code: int, counter: int = 0, *, address: int = 0) -> bytes:
    """SDO information error (opcode 7): mailbox length 10, abort code at +6 (SOES
    ``SDO_infoerror``)."""
    body = struct.pack("<BBHI", SDO_INFO_ERROR, 0, 0, code)
    return _coe(CoeService.SDO_INFO, body, counter, address)

# -- SDO information (ETG.1000.6 §5.6.3) ---------------------------------------------------
# Header after the CoE header: opcode (bits 0-6) with the incomplete flag (bit 7), a
# reserved byte, fragments left (u16).  The service data of a response that does not fit
# SM1 goes in fragments, each with this header; "fragments left" counts down to 0 and all
# but the last carry the incomplete flag (SOEM ``ecx_readODlist``, Wireshark's EtherCAT
# mailbox dissector).

class SdoInfoOpcode(IntEnum):
    OD_LIST_REQUEST = 1
    OD_LIST_RESPONSE = 2
    OBJECT_DESCRIPTION_REQUEST = 3
    OBJECT_DESCRIPTION_RESPONSE = 4
    ENTRY_DESCRIPTION_REQUEST = 5
    ENTRY_DESCRIPTION_RESPONSE = 6
    ERROR = SDO_INFO_ERROR


SDO_INFO_HEADER = struct.Struct("<BBH")
SDO_INFO_INCOMPLETE = 0x80
# Bytes of mailbox in front of the service data of each fragment (6 + 2 + 4).
SDO_INFO_OVERHEAD = MBX_HEADER_SIZE + COE_HEADER_SIZE + SDO_INFO_HEADER.size

# Get OD List: list types (u16 in front of the list).  Type 0 answers the five counts.
OD_LIST_LENGTHS = 0
OD_LIST_ALL = 1
OD_LIST_RXPDO_MAPPABLE = 2
OD_LIST_TXPDO_MAPPABLE = 3
OD_LIST_BACKUP = 4
OD_LIST_SETTINGS = 5

# Object codes of an object description (CiA 301 as ETG.1000.6 takes them).
OBJECT_CODE_VAR = 7
OBJECT_CODE_ARRAY = 8
OBJECT_CODE_RECORD = 9
OBJECT_CODE_NAMES = {OBJECT_CODE_VAR: "VAR", OBJECT_CODE_ARRAY: "ARRAY",
                     OBJECT_CODE_RECORD: "RECORD"}

# Object access word of an entry description: read in PREOP/SAFEOP/OP (bits 0-2), write in
# PREOP/SAFEOP/OP (bits 3-5), RxPDO and TxPDO mappable (bits 6, 7), backup, setting.
ACCESS_READ_SHIFT = 0
ACCESS_WRITE_SHIFT = 3
ACCESS_RXPDO = 0x0040
ACCESS_TXPDO = 0x0080
# Value info byte of an entry description request/response: which optional fields follow
# the access word (unit type u16, default, minimum, maximum value, each of the entry's size).
VALUE_INFO_UNIT = 0x08
VALUE_INFO_DEFAULT = 0x10
VALUE_INFO_MINIMUM = 0x20
VALUE_INFO_MAXIMUM = 0x40


@record(frozen=True)
class ObjectDescription:
    """Get Object Description response data: index, data type, max subindex, object code,
    name (the rest, no terminator)."""

    index: int
    data_type: int
    max_subindex: int
    object_code: int
    name: str

    _LAYOUT = struct.Struct("<HHBB")

    def pack(self) -> bytes:
        return (self._LAYOUT.pack(self.index, self.data_type, self.max_subindex,
                                  self.object_code) + self.name.encode("utf-8"))

    @classmethod
    def unpack(cls, data: bytes) -> ObjectDescription:
        if len(data) < cls._LAYOUT.size:
            raise MailboxProtocolError(f"object description of {len(data)} bytes; at "
                                       f"least {cls._LAYOUT.size} expected")
        index, dtype, max_sub, code = cls._LAYOUT.unpack_from(data)
        return cls(index, dtype, max_sub, code,
                   data[cls._LAYOUT.size:].decode("utf-8", "replace").rstrip("\0"))


@record(frozen=True)
class EntryDescription:
    """Get Entry Description response data: index, subindex, value info, data type, bit
    length, object access, the optional values the value info names (raw), name."""

    index: int
    subindex: int
    value_info: int
    data_type: int
    bit_length: int
    access: int
    name: str
    values: bytes = b""

    _LAYOUT = struct.Struct("<HBBHHH")

    def pack(self) -> bytes:
        return (self._LAYOUT.pack(self.index, self.subindex, self.value_info,
                                  self.data_type, self.bit_length, self.access)
                + self.values + self.name.encode("utf-8"))

    @classmethod
    def unpack(cls, data: bytes) -> EntryDescription:
        if len(data) < cls._LAYOUT.size:
            raise MailboxProtocolError(f"entry description of {len(data)} bytes; at "
                                       f"least {cls._LAYOUT.size} expected")
        index, sub, info, dtype, bits, access = cls._LAYOUT.unpack_from(data)
        nbytes = (bits + 7) // 8
        skip = ((2 if info & VALUE_INFO_UNIT else 0)
                + nbytes * sum(1 for flag in (VALUE_INFO_DEFAULT, VALUE_INFO_MINIMUM,
                                              VALUE_INFO_MAXIMUM) if info & flag))
        rest = data[cls._LAYOUT.size:]
        return cls(index, sub, info, dtype, bits, access,
                   rest[skip:].decode("utf-8", "replace").rstrip("\0"), rest[:skip])


def encode_sdo_info(opcode: int, data: bytes, counter: int = 0, *, incomplete: bool = False,
                    fragments_left: int = 0, address: int = 0) -> bytes:
    """One SDO information message: header and (a fragment of) the service data."""
    body = SDO_INFO_HEADER.pack((opcode & 0x7F) | (SDO_INFO_INCOMPLETE if incomplete else 0),
                                0, fragments_left) + data
    return _coe(CoeService.SDO_INFO, body, counter, address)


def encode_sdo_info_fragments(opcode: int, data: bytes, mbx_size: int) -> list[bytes]:
    """The messages of one SDO information response in a ``mbx_size``-byte SM1: the service
    data cut into fragments of ``mbx_size - 12`` bytes (rounded down to even)."""
    # An even fragment size keeps each index of an OD list in one fragment, as SOEM's
    # client reads them (whole u16 per fragment).
    chunk = (mbx_size - SDO_INFO_OVERHEAD) & ~1
    if chunk < 2:
        raise ValueError(f"a {mbx_size}-byte mailbox cannot carry SDO information")
    parts = [data[i:i + chunk] for i in range(0, len(data), chunk)] or [b""]
    return [encode_sdo_info(opcode, part, incomplete=k < len(parts) - 1,
                            fragments_left=len(parts) - 1 - k)
            for k, part in enumerate(parts)]


def encode_od_list_request(list_type: int = OD_LIST_ALL, counter: int = 0, *,
                           address: int = 0) -> bytes:
    return encode_sdo_info(SdoInfoOpcode.OD_LIST_REQUEST, struct.pack("<H", list_type),
                           counter, address=address)


def encode_object_description_request(index: int, counter: int = 0, *,
                                      address: int = 0) -> bytes:
    return encode_sdo_info(SdoInfoOpcode.OBJECT_DESCRIPTION_REQUEST,
                           struct.pack("<H", index), counter, address=address)


def encode_entry_description_request(index: int, subindex: int, value_info: int = 0,
                                     counter: int = 0, *, address: int = 0) -> bytes:
    return encode_sdo_info(SdoInfoOpcode.ENTRY_DESCRIPTION_REQUEST,
                           struct.pack("<HBB", index, subindex, value_info), counter,
                           address=address)


def od_list_data(list_type: int, indices: list[int]) -> bytes:
    """The service data of a Get OD List response: list type, then the indices (u16)."""
    return struct.pack(f"<H{len(indices)}H", list_type, *indices)


def decode_od_list(data: bytes) -> tuple[int, list[int]]:
    """(list type, indices) of a reassembled Get OD List response."""
    if len(data) < 2 or len(data) % 2:
        raise MailboxProtocolError(f"OD list of {len(data)} bytes (a list type and u16 "
                                   "indices expected)")
    words = struct.unpack(f"<{len(data) // 2}H", data)
    return words[0], list(words[1:])



def decode_coe(data: bytes) -> CoeMessage:
    """One CoE message from the mailbox data (what follows the mailbox header).

    Command specifiers are read by the service: service 2 carries requests (ccs) and aborts,
    service 3 responses (scs).  Raises :class:`MailboxProtocolError` with detail 6 (size too
    short) when the message is shorter than its service needs.
    """
    if len(data) < COE_HEADER_SIZE:
        raise MailboxProtocolError("CoE message without a CoE header",
                                   detail=MbxErrorDetail.SIZE_TOO_SHORT)
    (word,) = COE_HEADER.unpack_from(data)
    service, number = word >> 12, word & 0x1FF
    body = bytes(data[COE_HEADER_SIZE:])
    if service == CoeService.EMERGENCY:
        if len(body) < 3:
            raise MailboxProtocolError("CoE emergency shorter than 3 bytes",
                                       detail=MbxErrorDetail.SIZE_TOO_SHORT)
        code, register = struct.unpack_from("<HB", body)
        return Emergency(code, register, body[3:8])
    if service == CoeService.SDO_INFO:
        if len(body) < 4:
            raise MailboxProtocolError("SDO information header shorter than 4 bytes",
                                       detail=MbxErrorDetail.SIZE_TOO_SHORT)
        opcode, _reserved, frags = struct.unpack_from("<BBH", body)
        return SdoInfo(opcode & 0x7F, bool(opcode & 0x80), frags, body[4:])
    if service not in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE):
        return OtherCoe(service, number, body)
    if len(data) < SDO_MIN_LENGTH:
        raise MailboxProtocolError(f"SDO message of {len(data)} bytes; at least "
                                   f"{SDO_MIN_LENGTH} expected",
                                   detail=MbxErrorDetail.SIZE_TOO_SHORT)
    return _decode_sdo(service, body)


def _decode_sdo(service: int, body: bytes) -> SdoMessage:
    command, index, subindex, word = SDO_HEADER.unpack_from(body)
    cs = command >> CS_SHIFT
    toggle = bool(command & TOGGLE)
    ca = bool(command & COMPLETE_ACCESS)
    if cs == CS_ABORT:
        return Abort(index, subindex, word)
    request = service == CoeService.SDO_REQUEST
    if (request and cs in (CCS_DOWNLOAD_SEGMENT, CCS_UPLOAD_SEGMENT)) or (
            not request and cs in (SCS_UPLOAD_SEGMENT, SCS_DOWNLOAD_SEGMENT)):
        if request and cs == CCS_UPLOAD_SEGMENT:
            return UploadSegmentRequest(toggle)
        if not request and cs == SCS_DOWNLOAD_SEGMENT:
            return DownloadSegmentResponse(toggle)
        data = body[1:]
        if len(body) == SDO_HEADER.size:
            # Only a minimum-length segment gives its unused bytes (IgH; protocol-notes §6).
            data = data[:SEGMENT_MIN_DATA - ((command >> 1) & 0x07)]
        last = bool(command & LAST_SEGMENT)
        return (DownloadSegment(data, toggle, last) if request
                else UploadSegment(data, toggle, last))
    if request and cs == CCS_INITIATE_UPLOAD:
        return InitiateUpload(index, subindex, ca)
    if not request and cs == SCS_INITIATE_DOWNLOAD:
        return DownloadResponse(index, subindex, ca)
    if (request and cs == CCS_INITIATE_DOWNLOAD) or (not request
                                                      and cs == SCS_INITIATE_UPLOAD):
        if command & EXPEDITED:
            n = 4 - ((command >> 2) & 0x03) if command & SIZE_INDICATED else 4
            data, size = body[4:4 + n], (n if command & SIZE_INDICATED else None)
            expedited = True
        else:
            size = word if command & SIZE_INDICATED else None
            data = body[8:] if size is None else body[8:8 + size]
            expedited = False
        cls = InitiateDownload if request else UploadResponse
        return cls(index, subindex, data, size, expedited, ca)
    return UnknownSdo(service, command, index, subindex)


Decoded = MailboxError | CoeMessage | tuple[int, bytes]


def decode(msg: bytes) -> tuple[MailboxHeader, Decoded]:
    """Header and content of one mailbox message: a :class:`MailboxError`, a CoE message,
    or ``(type, data)`` for the other protocols."""
    header, data = decode_mailbox(msg)
    if header.type == MbxType.ERROR:
        if len(data) < 4:
            raise MailboxProtocolError("mailbox error reply shorter than 4 bytes",
                                       detail=MbxErrorDetail.SIZE_TOO_SHORT)
        return header, MailboxError(struct.unpack_from("<H", data, 2)[0])
    if header.type == MbxType.COE:
        return header, decode_coe(data)
    return header, (header.type, data)
