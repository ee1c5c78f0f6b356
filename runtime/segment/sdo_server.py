"""The CoE SDO server of an emulated slave: the CoE messages the mailbox hands it
(``mailbox_server.py``, which checks the mailbox header first), the CoE messages to answer.

Handles expedited, normal and segmented upload and download, complete access, toggle
checks and aborts (ETG.1000.6 §5.6.2; ``docs/protocol-notes.md`` §5 mailbox, §6 CoE, cited
below as "protocol-notes §N").  A CoE message the mailbox must refuse raises
:class:`MailboxProtocolError` with the detail of the mailbox error reply (type 0) that
SOES ``MBX_error`` would send.

Choices where those sources are silent:

- SDO information requests (service 8) go to ``sdo_info_server.py`` when the device has
  SDO Information (ESI ``CoE@SdoInfo``); without it they are answered with an SDO
  information error (opcode 7) carrying abort 0x06010000, as SOES answers opcodes it does
  not implement.
- Other CoE services (emergency, PDO over mailbox, an SDO *response* sent to the slave) get a
  mailbox error reply with detail 4 (service not supported).
- The response to an expedited download carries the request's 4 data bytes, where
  ETG.1000.6 has 4 reserved bytes: real Beckhoff firmware echoes them (the EK1914, EL3004
  and EL6910 of ethercrab-rs/ethercrab ``tests/replay-ek1914-el3004-configure.pcapng`` and
  ``tests/replay-mailbox-el6910.pcapng``: 0x1C13:01 = 0x1A00 is answered
  ``60 13 1C 01 00 1A 00 00``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ecatcfg.esc import AlState
from ecatcfg.runtime.mailbox import (
    ABORT_TOGGLE, ABORT_TYPE_MISMATCH, ABORT_UNKNOWN_COMMAND, ABORT_UNSUPPORTED_ACCESS,
    COE_HEADER, COE_HEADER_SIZE, CS_SHIFT, MBX_HEADER_SIZE, NORMAL_OVERHEAD,
    SCS_INITIATE_DOWNLOAD, SDO_MIN_LENGTH, SEGMENT_OVERHEAD, Abort, CoeMessage, CoeService,
    DownloadSegment, InitiateDownload, InitiateUpload, MailboxProtocolError, MbxErrorDetail,
    SdoAbort, SdoInfo, UnknownSdo, UploadSegmentRequest, decode_coe, encode_abort,
    encode_download_response, encode_download_segment_response, encode_sdo_info_error,
    encode_upload_expedited, encode_upload_normal, encode_upload_segment,
)
from ecatcfg.runtime.segment.objects import ObjectDictionary
from ecatcfg.runtime.segment.sdo_info_server import SdoInfoServer


def echo_request_data(response: bytes, request: bytes) -> bytes:
    """A download response (whole mailbox message) with the 4 data bytes of the expedited
    request (its CoE part) in its reserved bytes, as Beckhoff firmware answers (module
    docstring); an abort is left as it is."""
    if len(request) < SDO_MIN_LENGTH or \
            response[MBX_HEADER_SIZE + COE_HEADER_SIZE] >> CS_SHIFT != SCS_INITIATE_DOWNLOAD:
        return response
    return response[:-4] + request[SDO_MIN_LENGTH - 4:SDO_MIN_LENGTH]


@dataclass(slots=True)
class _Download:
    """A segmented download in progress."""

    index: int
    subindex: int
    complete_access: bool
    size: int
    data: bytearray = field(default_factory=bytearray)
    toggle: bool = False            # the toggle the next segment must carry


@dataclass(slots=True)
class _Upload:
    """A segmented upload in progress."""

    index: int
    subindex: int
    data: bytes
    offset: int
    toggle: bool = False


class SdoServer:
    """SDO server over one slave's mailbox.

    ``mbx_out_size`` / ``mbx_in_size`` are the SM0 (master -> slave) and SM1 (slave ->
    master) lengths: they bound the segment sizes sent (SM1 size - 16 bytes of data in an
    initiate upload response, SM1 size - 9 per segment).
    """

    def __init__(self, od: ObjectDictionary, mbx_out_size: int, mbx_in_size: int, *,
                 sdo_info: bool = True) -> None:
        if min(mbx_out_size, mbx_in_size) < NORMAL_OVERHEAD:
            raise ValueError(f"mailbox too small for CoE: SM0 {mbx_out_size}, SM1 "
                             f"{mbx_in_size} bytes")
        self.od = od
        self.mbx_out_size = mbx_out_size
        self.mbx_in_size = mbx_in_size
        self._transfer: _Download | _Upload | None = None
        self.info = SdoInfoServer(od, mbx_in_size) if sdo_info else None

    def reset(self) -> None:
        """The mailbox starts afresh (INIT -> PREOP): forget any transfer in progress, as
        SOES does when it starts the mailbox."""
        self._transfer = None

    def handle(self, data: bytes, state: AlState) -> list[bytes]:
        """The messages answering one CoE message (``data``: what follows the mailbox
        header), as whole mailbox messages with counter 0 and no padding: the mailbox
        (``mailbox_server.py``) gives them the counter and pads them to SM1.  Raises
        :class:`MailboxProtocolError` for a message the mailbox refuses."""
        msg = decode_coe(data)
        service = COE_HEADER.unpack_from(data)[0] >> 12
        if isinstance(msg, SdoInfo):
            if self.info is None:
                return [encode_sdo_info_error(ABORT_UNSUPPORTED_ACCESS)]
            return self.info.handle(msg)
        if service != CoeService.SDO_REQUEST:
            raise MailboxProtocolError(f"CoE service {service} is not served",
                                       detail=MbxErrorDetail.SERVICE_NOT_SUPPORTED)
        return self._sdo(msg, state, data)

    # -- SDO ---------------------------------------------------------------------------

    def _sdo(self, msg: CoeMessage, state: AlState, data: bytes) -> list[bytes]:
        if isinstance(msg, Abort):
            self._transfer = None                # the master gave up: nothing to answer
            return []
        if isinstance(msg, InitiateDownload):
            self._transfer = None
            [response] = self._initiate_download(msg, state)
            return [echo_request_data(response, data) if msg.expedited else response]
        if isinstance(msg, DownloadSegment):
            return self._download_segment(msg, state)
        if isinstance(msg, InitiateUpload):
            self._transfer = None
            return self._initiate_upload(msg, state)
        if isinstance(msg, UploadSegmentRequest):
            return self._upload_segment(msg)
        # An unknown client command specifier (block transfer, ...).
        self._transfer = None
        if isinstance(msg, UnknownSdo):
            return [self._abort(msg.index, msg.subindex, ABORT_UNKNOWN_COMMAND)]
        return [self._abort(0, 0, ABORT_UNKNOWN_COMMAND)]

    def _initiate_download(self, msg: InitiateDownload, state: AlState) -> list[bytes]:
        index, sub, ca = msg.index, msg.subindex, msg.complete_access
        try:
            if msg.expedited:
                data = msg.data
                if msg.size is None:
                    # Expedited without the size indicator: as many of the 4 bytes as the
                    # entry holds.
                    current = self.od.read(index, sub, None, complete_access=ca)
                    data = data[:len(current) or 4]
                self.od.write(index, sub, data, state, complete_access=ca)
            elif msg.size is None or len(msg.data) >= msg.size:
                self.od.write(index, sub, msg.data if msg.size is None
                              else msg.data[:msg.size], state, complete_access=ca)
            else:
                # Segments follow: refuse now what can be refused without the data.
                self.od.check_write(index, sub, msg.size, state, complete_access=ca)
                self._transfer = _Download(index, sub, ca, msg.size, bytearray(msg.data))
        except SdoAbort as abort:
            return [self._abort(index, sub, abort.code)]
        return [encode_download_response(index, sub, complete_access=ca)]

    def _download_segment(self, msg: DownloadSegment, state: AlState) -> list[bytes]:
        transfer = self._transfer
        if not isinstance(transfer, _Download):
            self._transfer = None
            return [self._abort(0, 0, ABORT_UNKNOWN_COMMAND)]
        if msg.toggle != transfer.toggle:
            self._transfer = None
            return [self._abort(transfer.index, transfer.subindex, ABORT_TOGGLE)]
        transfer.data += msg.data
        if len(transfer.data) > transfer.size or (msg.last
                                                  and len(transfer.data) != transfer.size):
            # More (or, at the end, less) data than the initiate announced.
            self._transfer = None
            return [self._abort(transfer.index, transfer.subindex, ABORT_TYPE_MISMATCH)]
        if msg.last:
            self._transfer = None
            try:
                self.od.write(transfer.index, transfer.subindex, bytes(transfer.data), state,
                              complete_access=transfer.complete_access)
            except SdoAbort as abort:
                return [self._abort(transfer.index, transfer.subindex, abort.code)]
        else:
            transfer.toggle = not transfer.toggle
        return [encode_download_segment_response(msg.toggle)]

    def _initiate_upload(self, msg: InitiateUpload, state: AlState) -> list[bytes]:
        index, sub, ca = msg.index, msg.subindex, msg.complete_access
        try:
            data = self.od.read(index, sub, state, complete_access=ca)
        except SdoAbort as abort:
            return [self._abort(index, sub, abort.code)]
        if 1 <= len(data) <= 4:
            # Expedited, also with complete access, as SOES answers (protocol-notes §6).
            return [encode_upload_expedited(index, sub, data, complete_access=ca)]
        first = self.mbx_in_size - NORMAL_OVERHEAD
        if len(data) > first:
            self._transfer = _Upload(index, sub, data, first)
        return [encode_upload_normal(index, sub, len(data), data[:first],
                                     complete_access=ca)]

    def _upload_segment(self, msg: UploadSegmentRequest) -> list[bytes]:
        transfer = self._transfer
        if not isinstance(transfer, _Upload):
            self._transfer = None
            return [self._abort(0, 0, ABORT_UNKNOWN_COMMAND)]
        if msg.toggle != transfer.toggle:
            self._transfer = None
            return [self._abort(transfer.index, transfer.subindex, ABORT_TOGGLE)]
        chunk = self.mbx_in_size - SEGMENT_OVERHEAD
        part = transfer.data[transfer.offset:transfer.offset + chunk]
        transfer.offset += len(part)
        last = transfer.offset >= len(transfer.data)
        transfer.toggle = not transfer.toggle
        if last:
            self._transfer = None
        return [encode_upload_segment(part, msg.toggle, last)]

    def _abort(self, index: int, subindex: int, code: int) -> bytes:
        return encode_abort(index, subindex, code)
