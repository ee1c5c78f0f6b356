"""The master's side of the wire: datagrams out in frames, replies matched back in.

One frame is in flight at a time (ping-pong, as SOEM and IgH do at startup); a frame whose
reply does not come back within the timeout counts as lost and the caller decides what to
resend.  Replies are matched on the datagram index the master chose (slaves never change
it) plus the command and length of every datagram, so a late reply to an earlier frame is
never taken for the current one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from ecatcfg.esc import MAX_DATAGRAM_DATA
from ecatcfg.record import record
from ecatcfg.runtime import wire
from ecatcfg.runtime.clock import Clock, clock_of
from ecatcfg.runtime.wire import Datagram, FrameError

if TYPE_CHECKING:
    from ecatcfg.runtime.link import Link

DEFAULT_TIMEOUT = 0.02          # s: a frame through even a long line returns within this
# Datagram bytes one frame carries: 1500 - 2 (EtherCAT header) = 1486 data + 12 overhead.
FRAME_DATA_LIMIT = MAX_DATAGRAM_DATA + wire.DG_HEADER_LEN + wire.WKC.size


@record
class Counters:
    frames_sent: int = 0
    frames_lost: int = 0
    stray_replies: int = 0


class Transport:
    """Send datagrams in one frame and wait for that frame to come back."""

    def __init__(self, link: Link, *, recorder: Callable[[bytes, bool], None] | None = None,
                 timeout: float = DEFAULT_TIMEOUT, clock: Clock | None = None) -> None:
        """``clock``: the time deadlines are on (``runtime/clock.py``); by default the
        link's own (a simulated wire's), else the wall clock."""
        self.link = link
        self.clock: Clock = clock or clock_of(link)
        self.recorder = recorder             # (frame, sent?) for pcap recording
        self.timeout = timeout
        self.counters = Counters()
        self._idx = 0
        self._recv_into = getattr(link, "recv_into", None)   # links that have it
        # A RawLink's compiled exchange (runtime/_exchange.c), unless the build had no C
        # compiler or ECATCFG_PURE_PYTHON is set: then the loop below, in Python.
        self._exchange_frame: Callable[..., tuple[int, int]] | None = getattr(
            link, "exchange_frame", None)
        self._exchange_error: Callable[[OSError, int], Exception] | None = getattr(
            link, "exchange_error", None)

    def exchange(self, datagrams: list[Datagram],
                 timeout: float | None = None) -> list[Datagram] | None:
        """The datagrams as they came back, or ``None`` if the frame was lost."""
        self._idx = (self._idx + 1) & 0xFF
        idx = self._idx
        for dg in datagrams:
            dg.idx = idx
        frame = wire.encode(datagrams)
        shape = [(dg.cmd, len(dg.data)) for dg in datagrams]
        self.link.send(frame)
        self.counters.frames_sent += 1
        if self.recorder:
            self.recorder(frame, True)
        monotonic = self.clock.monotonic
        deadline = monotonic() + (self.timeout if timeout is None else timeout)
        last = False
        while True:
            if last:
                self.counters.frames_lost += 1
                return None
            left = deadline - monotonic()
            if left <= 0:
                # Past the deadline, one last look at what is back: a reply that came in
                # time while this thread was not scheduled is not a lost frame.
                last, left = True, 0
            reply = self.link.recv(left)
            if reply is None:
                continue
            if self.recorder:
                self.recorder(reply, False)
            try:
                back = wire.decode(reply).datagrams
            except FrameError:
                self.counters.stray_replies += 1
                continue
            if back and back[0].idx == idx and [(d.cmd, len(d.data)) for d in back] == shape:
                return back
            self.counters.stray_replies += 1

    def exchange_prepared(self, prepared: Prepared, reply: bytearray,
                          timeout: float | None = None) -> int:
        """Fill a prepared frame from the output image, send it under the next index, wait
        for it in ``reply`` and take its inputs: the reply's length, or 0 if the frame was
        lost.  The same matching as :meth:`exchange`
        (index and shape; anything else is a stray reply), without building objects: the
        cyclic frames' path."""
        self._idx = idx = (self._idx + 1) & 0xFF
        compiled = self._exchange_frame
        if compiled is not None and not self.recorder:
            # The same steps in C: fill, index, send, wait, the shape check (reply_mask
            # holds the bits matches() compares), take; strays counted, a lost frame is 0.
            try:
                size, strays = compiled(prepared.compiled, reply, idx,
                                        self.timeout if timeout is None else timeout)
            except OSError as exc:
                assert self._exchange_error is not None     # a RawLink's
                raise self._exchange_error(exc, len(prepared.frame)) from None
            counters = self.counters
            counters.frames_sent += 1
            if strays:
                counters.stray_replies += strays
            if not size:
                counters.frames_lost += 1
            return size
        prepared.fill()
        frame = prepared.frame
        for at in prepared.index_at:
            frame[at] = idx
        link = self.link
        link.send(frame)
        self.counters.frames_sent += 1
        recorder = self.recorder
        if recorder:
            recorder(bytes(frame), True)
        receive = self._recv_into
        monotonic = self.clock.monotonic
        deadline = monotonic() + (self.timeout if timeout is None else timeout)
        last = False
        while True:
            if last:
                self.counters.frames_lost += 1
                return 0
            left = deadline - monotonic()
            if left <= 0:
                last, left = True, 0        # past it: one last look (as in exchange)
            if receive is not None:
                size = int(receive(reply, left))
            else:
                got = link.recv(left)
                size = 0 if got is None else len(got)
                if got is not None:
                    reply[:size] = got
            if not size:
                continue
            if recorder:
                recorder(bytes(reply[:size]), False)
            if prepared.matches(reply, size, idx):
                prepared.take()
                return size
            self.counters.stray_replies += 1


class Prepared(Protocol):
    """A frame built once whose replies :meth:`Transport.exchange_prepared` matches without
    decoding it (``runtime/master/cyclic.py``)."""

    frame: bytearray            # the Ethernet frame as sent, datagram indices aside
    index_at: tuple[int, ...]   # offset of each datagram's index byte
    index_le: bytes             # the same, 16-bit little-endian each (the compiled path)
    reply_mask: bytes           # per byte of a reply, the bits matches() compares with frame
    # For the compiled path: (frame, index_le, reply_mask, the output copies as int32
    # triples, the output image, the input copies, the input image), made by bind().
    compiled: tuple[bytearray, bytes, bytes, bytes, bytearray, bytes, bytearray]

    def fill(self) -> None:
        """The output image into the frame."""
        ...

    def take(self) -> None:
        """The read data of a reply that matched into the input image."""
        ...

    def matches(self, reply: bytearray, size: int, idx: int) -> bool:
        """``reply[:size]`` is this frame come back with index ``idx`` on every datagram:
        same EtherCAT header, same command and length on each datagram."""
        ...


def pack(datagrams: list[Datagram]) -> list[list[Datagram]]:
    """Split datagrams, in order, into frames that respect the 1486-byte data limit."""
    frames: list[list[Datagram]] = [[]]
    used = 0
    for dg in datagrams:
        size = dg.size
        if frames[-1] and used + size > FRAME_DATA_LIMIT:
            frames.append([])
            used = 0
        frames[-1].append(dg)
        used += size
    return [f for f in frames if f]
