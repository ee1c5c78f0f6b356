"""FoE (File access over EtherCAT) codec shared by the master (``master/foe_client.py``) and
the virtual segment (``segment/foe_server.py``).

Layouts follow ETG.1000.6 (FoE, mailbox type 4) as the open stacks implement them: SOEM
``ethercatfoe.c`` (``ec_FOEt``), SOES ``esc_foe.c`` (``FOE_OP_*``, ``FOE_ERR_*``) and
Wireshark's ``packet-ecatmb.c`` (the FoE dissector):

- every FoE message starts with OpCode (1 byte) and a reserved byte;
- read request (1) and write request (2): password (UINT32), then the file name (the rest
  of the mailbox data, no terminator);
- data (3) and ack (4): packet number (UINT32); data then carries the file's bytes;
- error (5): error code (UINT32), then an optional text;
- busy (6): done (UINT16) and entire (UINT16), the slave's progress, then an optional text.

A data packet carries at most mailbox size - 6 (mailbox header) - 6 (FoE header) bytes;
a packet shorter than that, 0 bytes included, is the last of the file (SOEM
``ecx_FOEwrite`` sends a final empty packet after a full one; SOES ends on a short packet).
"""

from __future__ import annotations

import struct
from enum import IntEnum

from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import FOE_HEADER, FoeOpCode
from ecatcfg.record import record
from ecatcfg.runtime.mailbox import MBX_HEADER_SIZE, MbxType, encode_mailbox

FOE_HEADER_SIZE = FOE_HEADER.size         # 6: OpCode, reserved, a UINT32 (esc.FOE_HEADER)
BUSY_BODY = struct.Struct("<HH")          # done, entire (replaces the UINT32 of the header)
# Bytes of a mailbox message in front of a data packet's file bytes: 6 + 6.
FOE_OVERHEAD = MBX_HEADER_SIZE + FOE_HEADER_SIZE


class FoeErrorCode(IntEnum):
    """FoE error codes (ETG.1000.6 FoE error table; SOES ``FOE_ERR_*``)."""

    NOT_DEFINED = 0x8000
    NOT_FOUND = 0x8001
    ACCESS_DENIED = 0x8002
    DISK_FULL = 0x8003
    ILLEGAL = 0x8004
    PACKET_NUMBER_WRONG = 0x8005
    ALREADY_EXISTS = 0x8006
    NO_USER = 0x8007
    BOOTSTRAP_ONLY = 0x8008
    NOT_BOOTSTRAP = 0x8009
    NO_RIGHTS = 0x800A
    PROGRAM_ERROR = 0x800B
    CHECKSUM = 0x800C


# The names are the codes' own (NOT_FOUND -> "not found"), but for the last: SOES calls it
# FOE_ERR_CHECKSUM, a checksum that is wrong.
FOE_ERROR_NAMES: dict[int, str] = {
    code: "checksum wrong" if code == FoeErrorCode.CHECKSUM
    else code.name.lower().replace("_", " ")
    for code in FoeErrorCode}


def foe_error_name(code: int) -> str:
    return FOE_ERROR_NAMES.get(code, "vendor-specific or unknown code")


def packet_data_size(mailbox_size: int) -> int:
    """The most file bytes one data packet carries through a mailbox of ``mailbox_size``
    bytes (the SyncManager the packet is written into)."""
    return mailbox_size - FOE_OVERHEAD


class FoeDecodeError(EcatcfgError):
    """An FoE message too short for its OpCode, or of an unknown OpCode."""


# -- messages -------------------------------------------------------------------------------

@record(frozen=True)
class FoeRequest:
    """Read (1) or write (2) request: the file ``name`` and its ``password``."""

    write: bool
    name: str
    password: int = 0


@record(frozen=True)
class FoeData:
    packet: int
    data: bytes


@record(frozen=True)
class FoeAck:
    packet: int


@record(frozen=True)
class FoeError:
    code: int
    text: str = ""

    @property
    def name(self) -> str:
        return foe_error_name(self.code)


@record(frozen=True)
class FoeBusy:
    done: int
    entire: int
    text: str = ""


FoeMessage = FoeRequest | FoeData | FoeAck | FoeError | FoeBusy


# File names travel as bytes; ETG.1000.6 gives no encoding.  Latin-1 maps every byte to one
# character and back, so whatever a slave names a file survives a round trip.
def _name_bytes(name: str) -> bytes:
    return name.encode("latin-1")


def encode_foe(message: FoeMessage) -> bytes:
    """The FoE part of one message (what follows the mailbox header)."""
    if isinstance(message, FoeRequest):
        op = FoeOpCode.WRITE if message.write else FoeOpCode.READ
        return FOE_HEADER.pack(op, message.password & 0xFFFFFFFF) + _name_bytes(message.name)
    if isinstance(message, FoeData):
        return FOE_HEADER.pack(FoeOpCode.DATA, message.packet) + message.data
    if isinstance(message, FoeAck):
        return FOE_HEADER.pack(FoeOpCode.ACK, message.packet)
    if isinstance(message, FoeError):
        return FOE_HEADER.pack(FoeOpCode.ERROR, message.code) + _name_bytes(message.text)
    return (struct.pack("<Bx", FoeOpCode.BUSY) + BUSY_BODY.pack(message.done, message.entire)
            + _name_bytes(message.text))


def encode_foe_mailbox(message: FoeMessage, counter: int = 0, address: int = 0,
                       mailbox_size: int | None = None) -> bytes:
    """A whole mailbox message (header + FoE), not padded.  With ``mailbox_size``, the
    text of an error or busy message is cut to what the mailbox carries (the text is
    optional; the code is what counts)."""
    data = encode_foe(message)
    if mailbox_size is not None and isinstance(message, FoeError | FoeBusy):
        data = data[:max(FOE_HEADER_SIZE, mailbox_size - MBX_HEADER_SIZE)]
    return encode_mailbox(MbxType.FOE, data, counter, address)


def decode_foe(data: bytes) -> FoeMessage:
    """One FoE message from the mailbox data (what follows the mailbox header)."""
    if len(data) < FOE_HEADER_SIZE:
        raise FoeDecodeError(f"FoE message of {len(data)} bytes: the header has "
                             f"{FOE_HEADER_SIZE}")
    op, word = FOE_HEADER.unpack_from(data)
    rest = bytes(data[FOE_HEADER_SIZE:])
    if op in (FoeOpCode.READ, FoeOpCode.WRITE):
        return FoeRequest(op == FoeOpCode.WRITE, rest.decode("latin-1"), word)
    if op == FoeOpCode.DATA:
        return FoeData(word, rest)
    if op == FoeOpCode.ACK:
        return FoeAck(word)
    if op == FoeOpCode.ERROR:
        return FoeError(word, rest.rstrip(b"\x00").decode("latin-1"))
    if op == FoeOpCode.BUSY:
        done, entire = BUSY_BODY.unpack_from(data, 2)
        return FoeBusy(done, entire, rest.rstrip(b"\x00").decode("latin-1"))
    raise FoeDecodeError(f"FoE OpCode {op} is none of 1-6 (read, write, data, ack, error, "
                         "busy)")


__all__ = ["FOE_ERROR_NAMES", "FOE_HEADER_SIZE", "FOE_OVERHEAD", "FoeAck", "FoeBusy",
           "FoeData", "FoeDecodeError", "FoeError", "FoeErrorCode", "FoeMessage",
           "FoeOpCode", "FoeRequest", "decode_foe", "encode_foe", "encode_foe_mailbox",
           "foe_error_name", "packet_data_size"]
