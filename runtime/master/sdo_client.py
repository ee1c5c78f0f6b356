"""SDO client transactions of the master: pure protocol logic, no I/O.

A transaction makes the requests to write into the slave's SM0 and digests what the slave
puts into SM1; the caller moves the bytes (mailbox SyncManagers, polling, timeouts)::

    t = SdoUpload(0x1018, 1, mbx_out_size=128, counter=counter)
    request = t.first_request()
    while request is not None or not t.done:
        if request is not None:
            write_sm0(request)
        request = t.on_response(read_sm1())
    value = t.result

Mirrors ``sdo_server`` and uses the same codec (``mailbox``).  Expedited transfer for
up to 4 bytes without complete access, normal (plus segments) otherwise: the first message
carries up to SM0 size - 16 bytes, each segment up to SM0 size - 9 (IgH ``fsm_coe.c``, SOEM
``ec_coe.c``; ``docs/protocol-notes.md`` §6).
CoE emergencies that arrive in between are kept in ``emergencies`` and otherwise ignored
(IgH ``ec_fsm_coe_check_emergency``); messages of other mailbox protocols must be
dispatched by the caller before they reach a transaction.
"""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.runtime.mailbox import (
    ABORT_TOGGLE, ABORT_TYPE_MISMATCH, ABORT_UNKNOWN_COMMAND, NORMAL_OVERHEAD,
    SEGMENT_OVERHEAD, Abort, CoeMessage, Decoded, DownloadResponse, DownloadSegmentResponse,
    Emergency, MailboxCounter, MailboxError, MailboxProtocolError, SdoAbort, UploadResponse,
    UploadSegment, decode, encode_abort, encode_download_expedited, encode_download_normal,
    encode_download_segment, encode_upload_request, encode_upload_segment_request, pad_to,
)

CounterSource = Callable[[], int]


class _Transaction:
    def __init__(self, index: int, subindex: int, complete_access: bool, mbx_out_size: int,
                 counter: CounterSource | None, address: int) -> None:
        if mbx_out_size < NORMAL_OVERHEAD + 1:
            raise ValueError(f"a {mbx_out_size}-byte SM0 cannot carry an SDO transfer")
        self.index = index
        self.subindex = subindex
        self.complete_access = complete_access
        self.mbx_out_size = mbx_out_size
        self.counter: CounterSource = counter if counter is not None else MailboxCounter()
        self.address = address
        self.emergencies: list[Emergency] = []
        self.done = False
        self._started = False

    def first_request(self) -> bytes:
        if self._started:
            raise RuntimeError("first_request() called twice")
        self._started = True
        return self._pad(self._first())

    def on_response(self, msg: bytes) -> bytes | None:
        """Digest one message from SM1.  Returns the next request to write into SM0, or
        ``None`` when there is nothing to send: then either the transfer is ``done`` or the
        message was an emergency and the answer is still to come."""
        if not self._started or self.done:
            raise RuntimeError("no SDO request is waiting for a response")
        content = self._decode(msg)
        if isinstance(content, Emergency):
            self.emergencies.append(content)
            return None
        if isinstance(content, Abort):
            self.done = True
            raise SdoAbort(content.code, self.index, self.subindex)
        request = self._step(content)
        return None if request is None else self._pad(request)

    def abort_request(self, code: int) -> bytes:
        """An abort for the slave, e.g. with ``MailboxProtocolError.abort_code``."""
        self.done = True
        return self._pad(encode_abort(self.index, self.subindex, code, self.counter(),
                                      address=self.address))

    def _decode(self, msg: bytes) -> CoeMessage:
        try:
            _header, content = decode(msg)
        except MailboxProtocolError as error:
            raise self._fail(f"unreadable mailbox response: {error}",
                             ABORT_UNKNOWN_COMMAND) from None
        return self._coe(content)

    def _coe(self, content: Decoded) -> CoeMessage:
        if isinstance(content, MailboxError):
            self.done = True
            raise MailboxProtocolError(
                f"0x{self.index:04X}:{self.subindex:02X}: the slave answered with mailbox "
                f"error {content.detail} ({content.name})", detail=content.detail)
        if isinstance(content, tuple):
            raise self._fail(f"mailbox type {content[0]} where a CoE response was expected",
                             ABORT_UNKNOWN_COMMAND)
        return content

    def _fail(self, what: str, abort_code: int) -> MailboxProtocolError:
        self.done = True
        return MailboxProtocolError(f"0x{self.index:04X}:{self.subindex:02X}: {what}",
                                    abort_code=abort_code)

    def _check_echo(self, index: int, subindex: int) -> None:
        if (index, subindex) != (self.index, self.subindex):
            raise self._fail(f"response for 0x{index:04X}:{subindex:02X}",
                             ABORT_UNKNOWN_COMMAND)

    def _pad(self, msg: bytes) -> bytes:
        return pad_to(msg, self.mbx_out_size)

    def _first(self) -> bytes:
        raise NotImplementedError

    def _step(self, content: CoeMessage) -> bytes | None:
        raise NotImplementedError


class SdoDownload(_Transaction):
    """Write ``data`` to ``index:subindex`` (the whole object with complete access)."""

    def __init__(self, index: int, subindex: int, data: bytes, complete_access: bool = False,
                 mbx_out_size: int = 128, counter: CounterSource | None = None, *,
                 address: int = 0) -> None:
        super().__init__(index, subindex, complete_access, mbx_out_size, counter, address)
        self.data = bytes(data)
        self._offset = 0                 # bytes sent so far
        self._toggle = False             # toggle of the segment in flight
        self._segments = False           # initiate answered: now in the segment phase

    @property
    def last_request_out(self) -> bool:
        """All the data has gone out: the answer to the request out ends the transfer (or
        refuses it); no further request of this transfer depends on it."""
        return self._started and not self.done and self._offset >= len(self.data)

    def _first(self) -> bytes:
        counter = self.counter()
        if 1 <= len(self.data) <= 4 and not self.complete_access:
            self._offset = len(self.data)
            return encode_download_expedited(self.index, self.subindex, self.data, counter,
                                             address=self.address)
        first = self.data[:self.mbx_out_size - NORMAL_OVERHEAD]
        self._offset = len(first)
        return encode_download_normal(self.index, self.subindex, len(self.data), first,
                                      counter, complete_access=self.complete_access,
                                      address=self.address)

    def _step(self, content: CoeMessage) -> bytes | None:
        if not self._segments:
            if not isinstance(content, DownloadResponse):
                raise self._fail(f"unexpected {type(content).__name__} to an initiate "
                                 "download", ABORT_UNKNOWN_COMMAND)
            self._check_echo(content.index, content.subindex)
            self._segments = True
        else:
            if not isinstance(content, DownloadSegmentResponse):
                raise self._fail(f"unexpected {type(content).__name__} to a download "
                                 "segment", ABORT_UNKNOWN_COMMAND)
            if content.toggle != self._toggle:
                raise self._fail("download segment response with the wrong toggle bit",
                                 ABORT_TOGGLE)
            self._toggle = not self._toggle
        if self._offset >= len(self.data):
            self.done = True
            return None
        part = self.data[self._offset:self._offset + self.mbx_out_size - SEGMENT_OVERHEAD]
        self._offset += len(part)
        return encode_download_segment(part, self._toggle, self._offset >= len(self.data),
                                       self.counter(), address=self.address)


class SdoUpload(_Transaction):
    """Read ``index:subindex`` (the whole object with complete access); the value is
    ``result`` once ``done``."""

    def __init__(self, index: int, subindex: int, complete_access: bool = False,
                 mbx_out_size: int = 128, counter: CounterSource | None = None, *,
                 address: int = 0) -> None:
        super().__init__(index, subindex, complete_access, mbx_out_size, counter, address)
        self._data = bytearray()
        self._size: int | None = None
        self._toggle = False
        self._segments = False

    @property
    def result(self) -> bytes:
        if not self.done:
            raise RuntimeError("the upload has not finished")
        return bytes(self._data)

    def _first(self) -> bytes:
        return encode_upload_request(self.index, self.subindex, self.counter(),
                                     complete_access=self.complete_access,
                                     address=self.address)

    def _step(self, content: CoeMessage) -> bytes | None:
        if not self._segments:
            if not isinstance(content, UploadResponse):
                raise self._fail(f"unexpected {type(content).__name__} to an initiate "
                                 "upload", ABORT_UNKNOWN_COMMAND)
            self._check_echo(content.index, content.subindex)
            self._data += content.data
            self._size = content.size
            if content.expedited or content.size is None or len(self._data) >= content.size:
                if content.size is not None:
                    del self._data[content.size:]
                self.done = True
                return None
            self._segments = True
            return encode_upload_segment_request(self._toggle, self.counter(),
                                                 address=self.address)
        if not isinstance(content, UploadSegment):
            raise self._fail(f"unexpected {type(content).__name__} to an upload segment "
                             "request", ABORT_UNKNOWN_COMMAND)
        if content.toggle != self._toggle:
            raise self._fail("upload segment with the wrong toggle bit", ABORT_TOGGLE)
        self._data += content.data
        size = self._size or 0           # known: segments follow only a sized response
        if len(self._data) > size or (content.last and len(self._data) < size):
            raise self._fail(f"{len(self._data)} bytes uploaded, {size} announced",
                             ABORT_TYPE_MISMATCH)
        if content.last:
            self.done = True
            return None
        self._toggle = not self._toggle
        return encode_upload_segment_request(self._toggle, self.counter(),
                                             address=self.address)
