"""In-memory wires whose far end answers in the master's thread: on simulated time, or on
the wall clock.

:class:`SimulatedLink` is the master's end of a line whose far end (a virtual segment,
``runtime/segment/virtual.py``) is run synchronously: ``send`` hands the frame to the far
end at once, which lets the slaves do what is due by now (their timing model, SM
watchdogs: ``tick``), processes the frame through the wire's faults (``answer``) and puts
the reply in the queue for the time it is back (``round_trip_ns``: the bytes at
100 Mbit/s and the slaves' delays).  ``recv`` moves the :class:`~ecatcfg.runtime.clock.SimClock`
to the reply's time, or by the whole timeout when no reply is due within it (a lost frame
costs its timeout, as on a real wire, but no host time).

Everything happens in the caller's thread, in an order that depends on nothing but the
calls made: the same start-up gives the same frames at the same simulated times, on an
idle host or a busy one (``tests/test_simtime.py``).  The far end is anything with the
three methods of :class:`FarEnd`; this module imports no segment code (the master and the
segment never import each other, and the wire sits between them).

:class:`SynchronousLink` is the same wire on the host's clock (``ecatcfg apply --virtual``,
``watch --virtual``, ``Network.virtual`` without a ``SimClock``): ``send`` lets the slaves
catch up with the wall clock (``tick``: SM watchdogs that expired meanwhile, work the
timing model finished, the DC clocks read the time) and answers the frame at once, in the
sender's thread.  A real slave answers in microseconds, in hardware; a segment served on a
thread of its own answers when the host schedules that thread, and on a busy host that
is late enough for the master to count the frame lost.  Here a frame is lost only when
the wire's faults drop it, and late only when they delay it.  Only the master's own
pacing (its cycle, its timeouts) reads real time.
"""

from __future__ import annotations

import heapq
import threading
from typing import Protocol

from ecatcfg.esc import ETH_HEADER_SIZE
from ecatcfg.runtime.clock import WALL, Clock, SimClock
from ecatcfg.runtime.link import DEFAULT_MTU, LinkError, _Base, check_frame

__all__ = ["FarEnd", "SimulatedLink", "SynchronousLink"]


class FarEnd(Protocol):
    """What a simulated wire needs from the slaves at its far end."""

    def tick(self) -> None:
        """Let the slaves do what is due by now (the clock's time)."""
        ...

    def answer(self, frame: bytes | bytearray) -> tuple[bytearray | None, float]:
        """The reply to ``frame`` (``None``: lost) and how many seconds late it comes."""
        ...

    def round_trip_ns(self, size: int) -> int:
        """ns from the first byte of a ``size``-byte frame sent to its last byte back."""
        ...


# (when the reply is back, ns; the order it was sent in; the reply's bytes)
_Due = tuple[int, int, bytes]


class SimulatedLink(_Base):
    """The master's end of a wire to ``far`` on ``clock`` (see the module docstring).

    ``log``: a list that gets one ``(ns, sent, frame)`` per frame that crosses the
    master's end (sent, or received back), the frame log of a run.  Thread-safe: a run on
    its own thread and the caller's changes to the far end are serialised by :attr:`lock`
    (hold it to change the far end between two frames)."""

    def __init__(self, clock: SimClock, far: FarEnd, *, name: str = "sim",
                 mtu: int = DEFAULT_MTU,
                 log: list[tuple[int, bool, bytes]] | None = None) -> None:
        self.clock = clock
        self.far = far
        self.iface = name
        self.mtu = mtu
        self.log = log
        self.lock = threading.RLock()
        self._due: list[_Due] = []
        self._sent = 0
        self._closed = False

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"{len(self._due)} due, {self.clock!r}"
        return f"SimulatedLink({self.iface!r}, {state})"

    def send(self, frame: bytes | bytearray) -> None:
        check_frame(self.iface, self._closed, len(frame), self.mtu)
        with self.lock:
            sent_at = self.clock.ns
            if self.log is not None:
                self.log.append((sent_at, True, bytes(frame)))
            far = self.far
            far.tick()
            reply, late = far.answer(frame)
            if reply is None:
                return
            self._sent += 1
            back = sent_at + far.round_trip_ns(len(frame)) + round(late * 1e9)
            heapq.heappush(self._due, (back, self._sent, bytes(reply)))

    def recv(self, timeout: float | None = None) -> bytes | None:
        """The next reply, the clock moved to when it is back; ``None`` after moving the
        clock by ``timeout`` when none is back by then (``0``: just look).  ``None`` as
        the timeout with nothing on its way raises :class:`LinkError`: on a simulated
        wire nothing else will ever come."""
        with self.lock:
            if self._closed:
                raise LinkError(f"{self.iface}: link is closed")
            clock, due = self.clock, self._due
            if due and due[0][0] <= clock.ns:
                return self._take()
            if timeout is None:
                if not due:
                    raise LinkError(f"{self.iface}: waiting for a frame with none on its way "
                                    "(a simulated wire has nothing else to deliver)")
                clock.advance_to(due[0][0])
                return self._take()
            if timeout <= 0:
                return None
            until = clock.ns + max(1, round(timeout * 1e9))
            if due and due[0][0] <= until:
                clock.advance_to(due[0][0])
                return self._take()
            clock.advance_to(until)
            return None

    def _take(self) -> bytes:
        _, _, frame = heapq.heappop(self._due)
        if self.log is not None:
            self.log.append((self.clock.ns, False, frame))
        return frame

    def fileno(self) -> int:
        raise LinkError(f"{self.iface}: a simulated wire has no descriptor to wait on "
                        "(nothing arrives while the caller waits; call recv)")

    def close(self) -> None:
        with self.lock:
            self._closed = True
            self._due.clear()


class SynchronousLink(_Base):
    """The master's end of a wire to ``far`` on the wall clock (see the module docstring).

    A reply is there as soon as ``send`` returns: the microseconds a frame takes on a real
    wire (:meth:`FarEnd.round_trip_ns`) are less than the host can sleep for, so they are
    not waited for.  A reply the wire's faults delay is there that much later, in real
    time: ``recv`` waits for it as for a frame on a real line.

    Thread-safe: any thread may send and receive (the cycle thread of a run and a caller
    that changes the far end between two frames under :attr:`lock`); a thread waiting in
    ``recv`` takes a reply another thread's ``send`` queued."""

    def __init__(self, far: FarEnd, *, clock: Clock = WALL, name: str = "sync",
                 mtu: int = DEFAULT_MTU) -> None:
        self.clock = clock
        self.far = far
        self.iface = name
        self.mtu = mtu
        self.lock = threading.RLock()
        self._ready = threading.Condition(self.lock)
        self._due: list[_Due] = []
        self._sent = 0
        self._closed = False

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"{len(self._due)} due"
        return f"SynchronousLink({self.iface!r}, {state})"

    def send(self, frame: bytes | bytearray) -> None:
        check_frame(self.iface, self._closed, len(frame), self.mtu)
        with self._ready:
            far = self.far
            far.tick()                  # the slaves caught up with the wall clock
            reply, late = far.answer(frame)
            if reply is None:
                return                  # the wire's faults lost it
            self._sent += 1
            back = self.clock.monotonic_ns() + round(late * 1e9)
            heapq.heappush(self._due, (back, self._sent, bytes(reply)))
            self._ready.notify()

    def recv(self, timeout: float | None = None) -> bytes | None:
        """The next reply that is back, waiting up to ``timeout`` s (``None``: until one
        is, ``0``: just look) for one; ``None`` when none is back by then."""
        clock = self.clock
        with self._ready:
            deadline = None if timeout is None else clock.monotonic_ns() + round(timeout * 1e9)
            while True:
                if self._closed:
                    raise LinkError(f"{self.iface}: link is closed")
                due = self._due
                now = clock.monotonic_ns()
                if due and due[0][0] <= now:
                    return heapq.heappop(due)[2]
                until = deadline
                if due and (until is None or due[0][0] < until):
                    until = due[0][0]
                if until is None:
                    self._ready.wait()
                elif until <= now:
                    return None
                else:
                    self._ready.wait((until - now) / 1e9)

    def fileno(self) -> int:
        raise LinkError(f"{self.iface}: a synchronous wire has no descriptor to wait on "
                        "(replies are there when send returns; call recv)")

    def close(self) -> None:
        with self._ready:
            self._closed = True
            self._due.clear()
            self._ready.notify_all()
