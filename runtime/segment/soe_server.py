"""The SoE server of an emulated drive: the SoE messages the mailbox hands it
(``mailbox_server.py``, which checks the mailbox header first), the SoE messages to answer
(ETG.1000.6 5.8; the layouts are ``runtime/soe.py``'s).

**The IDN store.**  Each drive behind the slave (ESI ``Mailbox/SoE@ChannelCount``, 1 when
not given; the SoE header's drive number picks one) holds:

- a few standard IDNs every Sercos drive has (the table ``STANDARD_IDNS`` below: the two
  cycle times S-0-0001/S-0-0002, the class 1 diagnostic S-0-0011, the IDN lists S-0-0017,
  S-0-0018 and S-0-0021, the manufacturer version S-0-0030, the operation mode S-0-0032).
  A short table on purpose: the emulation answers what a master writes at start-up and
  what a tool reads to find out why a drive refuses, not a drive's hundreds of parameters;
- every IDN the ESI's SoE InitCmds write (of that drive, ``InitCmd@Chn``), sized by the
  data they give: 1, 2, 4 or 8 bytes as a number of that size, data that reads as a Sercos
  list (current and maximum length first) as a list of that maximum, anything else as raw
  bytes of exactly that length.  Its value starts as zeros: what the drive holds before
  it is configured is not in the ESI.

**Required IDNs.**  A drive checks its operation data before it leaves PREOP: the IDNs its
list S-0-0018 ("IDN-list of operation data for CP2") names must have been written, else it
refuses SAFEOP and lists the ones missing in S-0-0021 ("IDN-list of invalid operation data
for CP2"), as the Beckhoff AX5000 documentation describes those two IDNs.  Which IDNs an
emulated drive requires: those its ESI's SoE InitCmds write in PREOP->SAFEOP (the AX5000
ESI writes the cycle times S-0-0001, S-0-0002 and the operation mode S-0-0032 there).
Written once since power-on is enough: a drive keeps its parameters while it is powered.
Required IDNs are write-protected in SAFEOP and OP (attribute bits 29, 30), as a drive
does not change its cycle times while cyclic data runs; the read-only IDNs (the lists, the
diagnostic, the version) are protected in every state.

**Services**, as the Beckhoff slave sample code and IEC 61800-7-304 answer them:

- read request: the elements asked for (value, attribute, name), in the order of their flag
  bits, fragmented when larger than SM1; an element the IDN does not have gets its "no ..."
  error (0x2001 name, 0x4001 unit, ...), no element at all 0x800C, an unknown IDN 0x1001,
  a drive number past ``ChannelCount`` 0x800A;
- write request: the value only (other elements of an IDN cannot be changed: 0x2004,
  0x3004, ... read only); fragments (Incomplete) are gathered without an answer and the last
  one answered; an unknown IDN 0x1001, a read-only one 0x7004, one protected in the current
  state 0x7005, a value too short 0x7002 or too long 0x7003;
- other opcodes (responses, notifications sent to the slave): mailbox error 4 (service
  not supported); shorter than the SoE header: mailbox error 6 (size too short).

Error replies carry the request's response opcode with the Error bit and the code after
the header.  Each accepted write is logged per drive (``SoeDrive.log``), so tests and the
segment can show the order a master wrote them in.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from ecatcfg.esc import AlState
from ecatcfg.esi.idn import IDN_LIST_ALL, IDN_LIST_CP2, IDN_LIST_INVALID_CP2
from ecatcfg.esi.model import SoeSettings
from ecatcfg.runtime.mailbox import MailboxProtocolError, MbxErrorDetail
from ecatcfg.runtime.soe import (
    ATTR_TYPE_BINARY, ATTR_TYPE_IDN, ATTR_TYPE_STRING, ATTR_TYPE_UINT, ATTR_WP_OP,
    ATTR_WP_PREOP, ATTR_WP_SAFEOP, ELEMENT_ATTRIBUTE, ELEMENT_NAME, ELEMENT_VALUE,
    SOE_DATA_READ_ONLY, SOE_DATA_TOO_LONG, SOE_DATA_TOO_SHORT, SOE_DATA_WRITE_PROTECTED,
    SOE_GENERAL_ERROR, SOE_INVALID_DRIVE, SOE_NO_ELEMENT, SOE_NO_ELEMENT_CODES, SOE_NO_IDN,
    SOE_READ_ONLY_ELEMENT_CODES,
    Reassembly, SoeMessage, SoeOpCode, attribute, decode_list, decode_soe, encode_error,
    encode_fragments, encode_list, encode_write_response,
)

_READ_ONLY = ATTR_WP_PREOP | ATTR_WP_SAFEOP | ATTR_WP_OP
_RUNNING = ATTR_WP_SAFEOP | ATTR_WP_OP
_WP_BY_STATE = {AlState.PREOP: ATTR_WP_PREOP, AlState.SAFEOP: ATTR_WP_SAFEOP,
                AlState.OP: ATTR_WP_OP}

LIST_MAX = 128                      # bytes an emulated IDN list can hold


@dataclass
class Idn:
    """One IDN of a drive: its value (as on the wire: a list with its two length words),
    name and attribute word."""

    name: str
    attribute: int
    value: bytes
    is_list: bool = False
    list_max: int = 0

    def write_error(self, data: bytes, state: AlState) -> int:
        """The SoE error code refusing ``data`` as the new value, 0 when it fits."""
        if self.attribute & _READ_ONLY == _READ_ONLY:
            return SOE_DATA_READ_ONLY
        if self.attribute & _WP_BY_STATE.get(state, 0):
            return SOE_DATA_WRITE_PROTECTED
        if self.is_list:
            # A list value says its current length first: fewer bytes than that is too
            # short, more (or more than the list holds) too long.
            if len(data) < 4:
                return SOE_DATA_TOO_SHORT
            current = int.from_bytes(data[:2], "little")
            if len(data) - 4 < current:
                return SOE_DATA_TOO_SHORT
            if len(data) - 4 > current or current > self.list_max:
                return SOE_DATA_TOO_LONG
            return 0
        if len(data) < len(self.value):
            return SOE_DATA_TOO_SHORT
        if len(data) > len(self.value):
            return SOE_DATA_TOO_LONG
        return 0


def _number(name: str, size: int, protect: int = 0) -> Idn:
    return Idn(name, attribute(size, ATTR_TYPE_UINT) | protect, bytes(size))


def _list(name: str, items: bytes, data_type: int, element: int) -> Idn:
    return Idn(name, attribute(element, data_type, is_list=True) | _READ_ONLY,
               encode_list(items, LIST_MAX), True, LIST_MAX)


# The standard IDNs every emulated drive has (IEC 61800-7-204 numbers and names).
STANDARD_IDNS: dict[int, tuple[str, int, int]] = {   # IDN: name, bytes, protection
    1: ("NC cycle time (TNcyc)", 2, _RUNNING),
    2: ("Communication cycle time (tScyc)", 2, _RUNNING),
    11: ("Class 1 diagnostic", 2, _READ_ONLY),
    32: ("Primary operation mode", 2, _RUNNING),
}
MANUFACTURER_VERSION = b"ecatcfg emulated SoE drive"


@dataclass
class SoeDrive:
    """One drive's IDN store, its required IDNs and the log of what was written."""

    number: int
    idns: dict[int, Idn] = field(default_factory=dict)
    required: list[int] = field(default_factory=list)
    written: set[int] = field(default_factory=set)
    log: list[tuple[int, bytes]] = field(default_factory=list)

    def missing(self) -> list[int]:
        """The required IDNs not written since power-on, in S-0-0018's order."""
        return [idn for idn in self.required if idn not in self.written]

    def set_list(self, idn: int, items: Iterable[int]) -> None:
        body = b"".join(i.to_bytes(2, "little") for i in items)
        self.idns[idn].value = encode_list(body, LIST_MAX)

    def write(self, idn: int, data: bytes) -> None:
        self.idns[idn].value = bytes(data)
        self.written.add(idn)
        self.log.append((idn, bytes(data)))


def _esi_idn(data: bytes, required: bool) -> Idn:
    """An IDN the ESI writes, sized by the data it writes (see the module docstring)."""
    protect = _RUNNING if required else 0
    if len(data) in (1, 2, 4, 8):
        return Idn("(from the ESI)", attribute(len(data), ATTR_TYPE_UINT) | protect,
                   bytes(len(data)))
    try:
        _items, maximum = decode_list(data)
    except ValueError:
        return Idn("(from the ESI)", attribute(1, ATTR_TYPE_BINARY) | protect,
                   bytes(len(data)))
    return Idn("(from the ESI)", attribute(1, ATTR_TYPE_BINARY, is_list=True) | protect,
               encode_list(b"", maximum), True, maximum)


def build_drives(settings: SoeSettings | None) -> list[SoeDrive]:
    """The drives of an ESI's ``Mailbox/SoE``: the standard IDNs, the IDNs its InitCmds
    write, S-0-0018 listing those written in PS."""
    count = settings.drives if settings is not None else 1
    drives = [SoeDrive(n) for n in range(count)]
    for drive in drives:
        for idn, (name, size, protect) in STANDARD_IDNS.items():
            drive.idns[idn] = _number(name, size, protect)
        drive.idns[30] = Idn("Manufacturer version", attribute(1, ATTR_TYPE_STRING,
                                                               is_list=True) | _READ_ONLY,
                             encode_list(MANUFACTURER_VERSION), True,
                             len(MANUFACTURER_VERSION))
        for idn, name in ((IDN_LIST_ALL, "IDN-list of all operation data"),
                          (IDN_LIST_CP2, "IDN-list of operation data for CP2"),
                          (IDN_LIST_INVALID_CP2,
                           "IDN-list of invalid operation data for CP2")):
            drive.idns[idn] = _list(name, b"", ATTR_TYPE_IDN, 2)
    for cmd in settings.init_cmds if settings is not None else []:
        if cmd.idn is None or cmd.data is None or cmd.channel >= len(drives):
            continue
        drive = drives[cmd.channel]
        required = "PS" in cmd.transitions
        if cmd.idn not in drive.idns:
            drive.idns[cmd.idn] = _esi_idn(cmd.data, required)
        elif required:
            drive.idns[cmd.idn].attribute |= _RUNNING
        if required and cmd.idn not in drive.required:
            drive.required.append(cmd.idn)
    for drive in drives:
        drive.set_list(IDN_LIST_ALL, sorted(drive.idns))
        drive.set_list(IDN_LIST_CP2, drive.required)
    return drives


class SoeServer:
    """SoE over one slave's mailbox.  ``settings``: the ESI's ``Mailbox/SoE`` (``None``:
    the ESI gives none); ``mbx_in_size``: the SM1 length, which bounds each response
    fragment."""

    def __init__(self, settings: SoeSettings | None, mbx_in_size: int) -> None:
        self.settings = settings
        self.mbx_in_size = mbx_in_size
        self.drives = build_drives(settings)
        self._write: Reassembly | None = None

    def reset(self) -> None:
        """The mailbox starts afresh (INIT -> PREOP): a write in fragments is dropped; the
        IDNs keep their values (a drive keeps its parameters while powered)."""
        self._write = None

    def power_on(self) -> None:
        """Power cycled: the drives start with their power-on store, nothing written."""
        self.drives = build_drives(self.settings)
        self._write = None

    def safeop_refusal(self) -> list[tuple[int, list[int]]]:
        """PREOP -> SAFEOP: each drive with required IDNs not written, and those IDNs (now
        also in its S-0-0021); empty when every drive may go on."""
        refused = []
        for drive in self.drives:
            missing = drive.missing()
            drive.set_list(IDN_LIST_INVALID_CP2, missing)
            if missing:
                refused.append((drive.number, missing))
        return refused

    def handle(self, data: bytes, state: AlState) -> list[bytes]:
        """The messages answering one SoE message (``data``: what follows the mailbox
        header), whole mailbox messages with counter 0 and no padding."""
        message = decode_soe(data)
        if message.op_code == SoeOpCode.READ_REQUEST:
            return self._read(message)
        if message.op_code == SoeOpCode.WRITE_REQUEST:
            return self._write_fragment(message, state)
        raise MailboxProtocolError(f"SoE opcode {message.op_code} sent to a slave",
                                   detail=MbxErrorDetail.SERVICE_NOT_SUPPORTED)

    def _error(self, op_code: int, message: SoeMessage, code: int) -> list[bytes]:
        return [encode_error(op_code, message.idn, code, drive_no=message.drive_no,
                             elements=message.elements)]

    def _read(self, message: SoeMessage) -> list[bytes]:
        op = SoeOpCode.READ_RESPONSE
        if message.drive_no >= len(self.drives):
            return self._error(op, message, SOE_INVALID_DRIVE)
        if not message.elements:
            return self._error(op, message, SOE_NO_ELEMENT)
        entry = self.drives[message.drive_no].idns.get(message.idn)
        if entry is None:
            return self._error(op, message, SOE_NO_IDN)
        body = b""
        for flag in (1 << bit for bit in range(8)):
            if not message.elements & flag:
                continue
            if flag == ELEMENT_NAME:
                name = entry.name.encode("latin-1", "replace")
                body += encode_list(name)
            elif flag == ELEMENT_ATTRIBUTE:
                body += entry.attribute.to_bytes(4, "little")
            elif flag == ELEMENT_VALUE:
                body += entry.value
            else:
                return self._error(op, message, SOE_NO_ELEMENT_CODES[flag])
        return encode_fragments(op, message.idn, body, self.mbx_in_size,
                                drive_no=message.drive_no, elements=message.elements)

    def _write_fragment(self, message: SoeMessage, state: AlState) -> list[bytes]:
        op = SoeOpCode.WRITE_RESPONSE
        if self._write is None:
            self._write = Reassembly()
        try:
            data = self._write.add(message)
        except ValueError:
            self._write = None
            return self._error(op, message, SOE_GENERAL_ERROR)
        if data is None:
            return []                       # more fragments to come: no answer yet
        self._write = None
        if message.drive_no >= len(self.drives):
            return self._error(op, message, SOE_INVALID_DRIVE)
        if message.elements != ELEMENT_VALUE:
            other = message.elements & ~ELEMENT_VALUE & 0xFF
            if not message.elements:
                return self._error(op, message, SOE_NO_ELEMENT)
            lowest = other & -other
            return self._error(op, message, SOE_READ_ONLY_ELEMENT_CODES.get(lowest, SOE_NO_ELEMENT))
        drive = self.drives[message.drive_no]
        entry = drive.idns.get(message.idn)
        if entry is None:
            return self._error(op, message, SOE_NO_IDN)
        code = entry.write_error(data, state)
        if code:
            return self._error(op, message, code)
        drive.write(message.idn, data)
        return [encode_write_response(message.idn, drive_no=message.drive_no,
                                      elements=message.elements)]
