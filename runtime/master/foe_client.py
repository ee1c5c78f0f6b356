"""FoE client transfers of the master: pure protocol logic, no I/O (as ``sdo_client.py``).

A transfer makes the requests to write into the slave's SM0 and digests what the slave puts
into SM1; the caller moves the bytes::

    t = FoeWrite("app.efw", content, password=0, mbx_out_size=128, mbx_in_size=128)
    request = t.first_request()
    while True:
        if request is not None:
            write_sm0(request)
        if t.done:
            break
        request = t.on_response(read_sm1())

The rules are ETG.1000.6 FoE as SOEM ``ethercatfoe.c`` and IgH ``fsm_foe.c`` implement
them (layouts in ``runtime/foe.py``):

- **write**: write request (password, name); the slave acknowledges packet 0; then data
  packets 1, 2, ... of up to SM0 size - 12 bytes, each sent once the slave has acknowledged
  the one before with its number; a packet shorter than that ends the file, so a file that
  fills its last packet is followed by an empty one.  A busy reply means the slave did not
  take the last data packet (it is writing flash): the packet is sent again.
- **read**: read request; the slave sends data packets of up to SM1 size - 12 bytes, the
  master acknowledges each with its number; the short one is the last (its ack is sent
  too).  A busy reply is progress only: the data follows.
- an FoE error from the slave ends the transfer with :class:`FoeTransferError` (code and
  name); a packet or ack with an unexpected number is answered with FoE error 0x8005
  (packet number wrong) and ends it too; a mailbox error reply (type 0) ends it with its
  detail.  Messages of other protocols (a CoE emergency) are skipped.
"""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.errors import EcatcfgError
from ecatcfg.record import record
from ecatcfg.runtime.foe import (FOE_OVERHEAD, FoeAck, FoeBusy, FoeData, FoeDecodeError,
                                 FoeError, FoeErrorCode, FoeMessage, FoeRequest, decode_foe,
                                 encode_foe_mailbox, foe_error_name, packet_data_size)
from ecatcfg.runtime.mailbox import (MBX_ERROR_DETAILS, MBX_ERROR_TYPE, MailboxCounter,
                                     MailboxProtocolError, MbxType, decode_mailbox, pad_to)

CounterSource = Callable[[], int]


class FoeTransferError(EcatcfgError):
    """The slave refused the transfer (``code``: its FoE error code) or broke the
    protocol (``code`` None)."""

    def __init__(self, message: str, code: int | None = None, text: str = "") -> None:
        super().__init__(message)
        self.code = code
        self.text = text


@record
class Progress:
    """Where a transfer is: file bytes moved so far, the size when known (a write), and
    the slave's last busy report (done, entire)."""

    done: int
    total: int | None
    busy: tuple[int, int] | None = None


ProgressHook = Callable[[Progress], None]


class _Transfer:
    def __init__(self, name: str, password: int, mbx_out_size: int, mbx_in_size: int,
                 counter: CounterSource | None, progress: ProgressHook | None) -> None:
        for what, size in (("SM0", mbx_out_size), ("SM1", mbx_in_size)):
            if size <= FOE_OVERHEAD:
                raise ValueError(f"a {size}-byte {what} cannot carry FoE data "
                                 f"(mailbox and FoE headers take {FOE_OVERHEAD})")
        self.name = name
        self.password = password
        self.mbx_out_size = mbx_out_size
        self.mbx_in_size = mbx_in_size
        self.counter: CounterSource = counter if counter is not None else MailboxCounter()
        self.progress = progress
        self.done = False
        self.packets = 0               # data packets that crossed (each once)
        self.busy_replies = 0
        self.last_busy: tuple[int, int] | None = None
        self._started = False

    def first_request(self) -> bytes:
        if self._started:
            raise RuntimeError("first_request() called twice")
        self._started = True
        return self._message(FoeRequest(self._writes, self.name, self.password))

    _writes = False

    def on_response(self, msg: bytes) -> bytes | None:
        """Digest one message from SM1: the next request for SM0, or ``None`` (nothing to
        send: the transfer is ``done``, or the slave's next message is awaited)."""
        if not self._started or self.done:
            raise RuntimeError("no FoE request is waiting for a response")
        try:
            header, data = decode_mailbox(msg)
        except MailboxProtocolError as exc:
            raise self._fail(f"unreadable mailbox response: {exc}") from None
        if header.type == MbxType.ERROR:
            detail = int.from_bytes(data[2:4], "little") if len(data) >= 4 and \
                int.from_bytes(data[:2], "little") == MBX_ERROR_TYPE else 0
            raise self._fail(f"the slave answered with mailbox error {detail} "
                             f"({MBX_ERROR_DETAILS.get(detail, 'unknown detail')})")
        if header.type != MbxType.FOE:
            return None                  # e.g. a CoE emergency: not part of the transfer
        try:
            message = decode_foe(data)
        except FoeDecodeError as exc:
            raise self._fail(str(exc)) from None
        if isinstance(message, FoeError):
            self.done = True
            text = f": {message.text!r}" if message.text else ""
            raise FoeTransferError(f"FoE error 0x{message.code:04X} ({message.name}){text}",
                                   message.code, message.text)
        if isinstance(message, FoeBusy):
            self.busy_replies += 1
            self.last_busy = (message.done, message.entire)
            self._report()
        return self._step(message)

    def abort_request(self, code: int = FoeErrorCode.NOT_DEFINED, text: str = "") -> bytes:
        """An FoE error for the slave, ending the transfer on its side too."""
        self.done = True
        return self._message(FoeError(code, text))

    def _message(self, message: FoeMessage) -> bytes:
        return pad_to(encode_foe_mailbox(message, self.counter(),
                                         mailbox_size=self.mbx_out_size), self.mbx_out_size)

    def _fail(self, what: str) -> FoeTransferError:
        self.done = True
        return FoeTransferError(what)

    def _wrong_number(self, what: str) -> FoeTransferError:
        self.done = True
        return FoeTransferError(f"{what} (FoE error 0x{FoeErrorCode.PACKET_NUMBER_WRONG:04X}, "
                                f"{foe_error_name(FoeErrorCode.PACKET_NUMBER_WRONG)}, sent "
                                "to the slave)", FoeErrorCode.PACKET_NUMBER_WRONG)

    def _report(self) -> None:
        if self.progress is not None:
            self.progress(Progress(self.bytes_done, self.total, self.last_busy))

    @property
    def bytes_done(self) -> int:
        raise NotImplementedError

    @property
    def total(self) -> int | None:
        return None

    def _step(self, message: FoeMessage) -> bytes | None:
        raise NotImplementedError


class FoeWrite(_Transfer):
    """Write ``data`` into the slave's file ``name``."""

    _writes = True

    def __init__(self, name: str, data: bytes, password: int = 0, *, mbx_out_size: int,
                 mbx_in_size: int, counter: CounterSource | None = None,
                 progress: ProgressHook | None = None) -> None:
        super().__init__(name, password, mbx_out_size, mbx_in_size, counter, progress)
        self.data = bytes(data)
        self.chunk = packet_data_size(mbx_out_size)
        self._sent = 0                 # the last data packet sent (0: the request)
        self._offset = 0               # file bytes before that packet
        self._final = False            # the last packet sent ends the file
        self.wrong_number: FoeTransferError | None = None

    @property
    def bytes_done(self) -> int:
        return self._offset

    @property
    def total(self) -> int:
        return len(self.data)

    def _step(self, message: FoeMessage) -> bytes | None:
        if isinstance(message, FoeBusy):
            # The slave did not take the last data packet: send it again (SOEM, IgH).
            return self._data_packet() if self._sent else None
        if not isinstance(message, FoeAck):
            return self._refuse(f"{type(message).__name__} where an ack was expected")
        if message.packet != self._sent:
            return self._refuse(f"ack {message.packet}, expected {self._sent}")
        if self._sent:
            self._offset += min(self.chunk, len(self.data) - self._offset)
            self.packets += 1
            self._report()
            if self._final:
                self.done = True
                return None
        self._sent += 1
        return self._data_packet()

    def _data_packet(self) -> bytes:
        chunk = self.data[self._offset:self._offset + self.chunk]
        self._final = len(chunk) < self.chunk
        return self._message(FoeData(self._sent, chunk))

    def _refuse(self, what: str) -> bytes:
        self.wrong_number = self._wrong_number(what)
        return self.abort_request(FoeErrorCode.PACKET_NUMBER_WRONG, what)


class FoeRead(_Transfer):
    """Read the slave's file ``name``; ``result`` holds it once ``done``."""

    def __init__(self, name: str, password: int = 0, *, mbx_out_size: int,
                 mbx_in_size: int, counter: CounterSource | None = None,
                 progress: ProgressHook | None = None, limit: int | None = None) -> None:
        super().__init__(name, password, mbx_out_size, mbx_in_size, counter, progress)
        self.chunk = packet_data_size(mbx_in_size)
        self.limit = limit
        self._received = bytearray()
        self._expected = 1
        self.wrong_number: FoeTransferError | None = None

    @property
    def bytes_done(self) -> int:
        return len(self._received)

    @property
    def result(self) -> bytes:
        if not self.done:
            raise RuntimeError("the FoE read is not done")
        return bytes(self._received)

    def _step(self, message: FoeMessage) -> bytes | None:
        if isinstance(message, FoeBusy):
            return None                 # progress only: the data follows
        if not isinstance(message, FoeData):
            return self._refuse(f"{type(message).__name__} where data was expected")
        if message.packet != self._expected:
            return self._refuse(f"data packet {message.packet}, expected {self._expected}")
        if len(message.data) > self.chunk:
            return self._refuse(f"data packet {message.packet} of {len(message.data)} "
                                f"bytes: SM1 carries {self.chunk}")
        self._received += message.data
        if self.limit is not None and len(self._received) > self.limit:
            self.done = True
            raise FoeTransferError(f"the file is longer than {self.limit} bytes")
        self.packets += 1
        self._expected += 1
        self._report()
        ack = self._message(FoeAck(message.packet))
        if len(message.data) < self.chunk:
            self.done = True
        return ack

    def _refuse(self, what: str) -> bytes:
        self.wrong_number = self._wrong_number(what)
        return self.abort_request(FoeErrorCode.PACKET_NUMBER_WRONG, what)


FoeTransfer = FoeWrite | FoeRead

__all__ = ["FoeRead", "FoeTransfer", "FoeTransferError", "FoeWrite", "Progress",
           "ProgressHook"]
