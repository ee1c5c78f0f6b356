"""The FoE server of an emulated slave: files read and written over the mailbox the way a
slave's firmware (or its boot loader) answers them (ETG.1000.6 FoE; layouts in
``runtime/foe.py``; behaviour as SOES ``esc_foe.c``, the open slave stack, implements it).

- **Where**: in BOOT over the bootstrap mailbox, and in PREOP, SAFEOP and OP over the
  standard mailbox: the ESI's ``Mailbox/FoE`` says the device speaks FoE and gives no
  state, and SOES serves FoE in every mailbox state.  Firmware files (below) are the
  exception when the device has a bootstrap mailbox (SII words 0x14-0x17): like SOES's
  ``write_only_in_boot`` files, they are written in BOOT only, and a write request in
  another state gets error 0x8009 (not bootstrap), the code SOES answers there.
- **Files** are kept by name in memory ("flash") and survive a power cycle; their total is
  bounded by ``disk_size``: a data packet that would pass it gets 0x8003 (disk full) and
  the partial file is dropped.  A read of a name that is not there gets 0x8001 (not found).
- **Password**: a request whose password is not the slave's (``password``, 0 by default)
  gets 0x800A (no rights), what SOES answers (``FOE_ERR_NORIGHTS``).
- **Packets**: a write is acknowledged with ack 0, then each data packet with its number;
  a packet with another number than the next gets 0x8005 (packet number wrong) and ends
  the transfer.  A read answers with data packets of up to SM1 size - 12 bytes, each
  after the master's ack of the one before; a packet shorter than that ends the file (an
  empty one when the file fills the last packet exactly).  An error from the master ends
  the transfer without an answer (SOES: an FoE error is never acknowledged).
- **Busy**: with ``busy_every`` N > 0, every Nth data packet of a write is answered with
  busy (done/entire: flash sectors written of the disk's) instead of an ack, like a
  firmware still writing flash; the packet is not taken, and the master sends it again
  (SOEM ``ecx_FOEwrite`` and IgH ``fsm_foe.c`` resend the last data packet on busy).
- **Firmware files**: a name ending in ``.efw`` whose content starts with the 16-byte
  header ``b"ECFW"``, vendor ID, product code, revision (UINT32 little-endian each;
  ecatcfg's own test format, no vendor's) is a firmware image.  One for this device
  (vendor and product equal) is installed at the next power cycle: the slave then reports
  the header's revision in SII word 0x0C and, with CoE, in 0x1018:03.  One for another
  device, or a ``.efw`` without the header, gets 0x8004 (illegal) instead of the last ack
  and is not kept.
"""

from __future__ import annotations

import struct

from ecatcfg.esc import AlState
from ecatcfg.runtime.foe import (FoeAck, FoeBusy, FoeData, FoeDecodeError, FoeError,
                                 FoeErrorCode, FoeMessage, FoeRequest, decode_foe,
                                 encode_foe_mailbox, packet_data_size)
from ecatcfg.runtime.mailbox import MailboxProtocolError, MbxErrorDetail

FIRMWARE_SUFFIX = ".efw"
FIRMWARE_MAGIC = b"ECFW"
FIRMWARE_HEADER = struct.Struct("<4sIII")    # magic, vendor ID, product code, revision
DEFAULT_DISK_SIZE = 4 * 1024 * 1024
SECTOR = 4096                                # the flash sector busy replies count in


def firmware_revision(name: str, content: bytes, vendor_id: int,
                      product_code: int) -> int | None | str:
    """What a firmware file means to a device: its revision, ``None`` when the file is no
    firmware file (another name), or the reason it is refused (a text)."""
    if not name.lower().endswith(FIRMWARE_SUFFIX):
        return None
    if len(content) < FIRMWARE_HEADER.size or content[:4] != FIRMWARE_MAGIC:
        return "no firmware header (ECFW)"
    _magic, vendor, product, revision = FIRMWARE_HEADER.unpack_from(content)
    if (vendor, product) != (vendor_id, product_code):
        return (f"firmware for vendor 0x{vendor:08X} product 0x{product:08X}, not this "
                f"device (0x{vendor_id:08X}, 0x{product_code:08X})")
    rev: int = revision
    return rev


class FoeServer:
    """FoE over one slave's mailbox.  ``vendor_id``/``product_code``: the device's
    identity (firmware files are checked against it); ``bootstrap``: whether the device
    has a bootstrap mailbox (then firmware files are written in BOOT only)."""

    def __init__(self, vendor_id: int, product_code: int, *, bootstrap: bool,
                 password: int = 0, disk_size: int = DEFAULT_DISK_SIZE,
                 busy_every: int = 0) -> None:
        self.vendor_id = vendor_id
        self.product_code = product_code
        self.bootstrap = bootstrap
        self.password = password
        self.disk_size = disk_size
        self.busy_every = busy_every
        self.files: dict[str, bytes] = {}
        self.pending_revision: int | None = None     # installed at the next power cycle
        self.busy_replies = 0
        self._write: tuple[str, bytearray] | None = None
        self._read: tuple[str, bytes] | None = None
        self._packet = 0               # write: the last packet taken; read: the last sent
        self._offset = 0               # read: bytes sent before the last packet
        self._data_packets = 0         # write: data packets seen (for busy_every)
        self._busy_for: int | None = None    # the packet answered busy, not yet taken
        self._full_packet = 0          # file bytes in a data packet that fills SM0

    def reset(self) -> None:
        """The mailbox starts afresh: a transfer in progress is dropped (files stay)."""
        self._write = self._read = None
        self._busy_for = None

    def take_pending_revision(self) -> int | None:
        """The revision of a firmware written since the last power cycle (and forget it)."""
        revision, self.pending_revision = self.pending_revision, None
        return revision

    def handle(self, data: bytes, state: AlState, mbx_out_size: int,
               mbx_in_size: int) -> list[bytes]:
        """The messages answering one FoE message (``data``: what follows the mailbox
        header), as whole mailbox messages with counter 0 (the mailbox stamps and pads
        them).  ``mbx_out_size``/``mbx_in_size``: the SM0/SM1 lengths now (bootstrap or
        standard mailbox): a data packet that fills SM0 is not the last."""
        self._full_packet = packet_data_size(mbx_out_size)
        try:
            message = decode_foe(data)
        except FoeDecodeError as exc:
            raise MailboxProtocolError(f"FoE: {exc}",
                                       detail=MbxErrorDetail.SIZE_TOO_SHORT) from None
        reply = self._answer(message, state, mbx_in_size)
        return [] if reply is None else [encode_foe_mailbox(reply, mailbox_size=mbx_in_size)]

    def _answer(self, message: FoeMessage, state: AlState,
                mbx_in_size: int) -> FoeMessage | None:
        if isinstance(message, FoeRequest):
            self.reset()
            return self._request(message, state, mbx_in_size)
        if isinstance(message, FoeData):
            return self._data(message)
        if isinstance(message, FoeAck):
            return self._ack(message, mbx_in_size)
        if isinstance(message, FoeError):
            self.reset()                 # the master ends the transfer: no answer
            return None
        self.reset()                     # busy is the slave's to send, never the master's
        return FoeError(FoeErrorCode.ILLEGAL, "unexpected busy")

    def _request(self, request: FoeRequest, state: AlState,
                 mbx_in_size: int) -> FoeMessage | None:
        if request.password != self.password:
            return FoeError(FoeErrorCode.NO_RIGHTS, "wrong password")
        if not request.write:
            content = self.files.get(request.name)
            if content is None:
                return FoeError(FoeErrorCode.NOT_FOUND, f"no file {request.name!r}")
            self._read = (request.name, content)
            self._packet, self._offset = 0, 0
            return self._next_read_packet(mbx_in_size)
        if (self.bootstrap and state != AlState.BOOT
                and request.name.lower().endswith(FIRMWARE_SUFFIX)):
            return FoeError(FoeErrorCode.NOT_BOOTSTRAP, "firmware is written in BOOT only")
        self._write = (request.name, bytearray())
        self._packet = self._data_packets = 0
        return FoeAck(0)

    def _data(self, packet: FoeData) -> FoeMessage | None:
        if self._write is None:
            return FoeError(FoeErrorCode.ILLEGAL, "data without a write request")
        name, buffer = self._write
        if packet.packet != self._packet + 1:
            self.reset()
            return FoeError(FoeErrorCode.PACKET_NUMBER_WRONG,
                            f"packet {packet.packet}, expected {self._packet + 1}")
        if self.busy_every and self._busy_for != packet.packet:
            self._data_packets += 1
            if self._data_packets % self.busy_every == 0:
                self._busy_for = packet.packet
                self.busy_replies += 1
                used = sum(len(c) for n, c in self.files.items() if n != name) + len(buffer)
                return FoeBusy(min(used // SECTOR, 0xFFFF),
                               min(self.disk_size // SECTOR, 0xFFFF))
        self._busy_for = None
        others = sum(len(c) for n, c in self.files.items() if n != name)
        if others + len(buffer) + len(packet.data) > self.disk_size:
            self.reset()
            return FoeError(FoeErrorCode.DISK_FULL,
                            f"{self.disk_size} bytes of flash are full")
        buffer += packet.data
        self._packet = packet.packet
        if len(packet.data) >= self._full_packet:
            return FoeAck(packet.packet)
        return self._complete(name, bytes(buffer), packet.packet)

    def _complete(self, name: str, content: bytes, packet: int) -> FoeMessage:
        self._write = None
        meaning = firmware_revision(name, content, self.vendor_id, self.product_code)
        if isinstance(meaning, str):
            return FoeError(FoeErrorCode.ILLEGAL, meaning)
        self.files[name] = content
        if meaning is not None:
            self.pending_revision = meaning
        return FoeAck(packet)

    def _ack(self, ack: FoeAck, mbx_in_size: int) -> FoeMessage | None:
        if self._read is None:
            return FoeError(FoeErrorCode.ILLEGAL, "ack without a read in progress")
        if ack.packet != self._packet:
            self.reset()
            return FoeError(FoeErrorCode.PACKET_NUMBER_WRONG,
                            f"ack {ack.packet}, expected {self._packet}")
        return self._next_read_packet(mbx_in_size)

    def _next_read_packet(self, mbx_in_size: int) -> FoeMessage | None:
        assert self._read is not None
        _name, content = self._read
        size = packet_data_size(mbx_in_size)
        if self._packet:
            last = min(size, len(content) - self._offset)
            if last < size:              # the master acknowledged the last packet
                self._read = None
                return None
            self._offset += last
        chunk = content[self._offset:self._offset + size]
        self._packet += 1
        return FoeData(self._packet, chunk)
