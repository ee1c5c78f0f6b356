"""The time the master and the virtual segment live in: the host's clock, or one a test owns.

Every timing read of the runtime goes through a :class:`Clock`: frame deadlines, the
lock-step rounds' idle wait, the cycle loop's sleep, recovery back-offs, the DC start time
(master); SM and PDI watchdogs, DC system time, the timing model's delays (segment).

- :class:`WallClock` (:data:`WALL`): the host's monotonic clock and real sleeps, what the
  product runs on over a real line.
- :class:`SimClock`: time that moves only when someone says so.  ``sleep(s)`` advances it
  by ``s`` and returns at once; a simulated wire (``runtime/simwire.py``) advances it by the
  time frames take.  Nothing waits for the host, and a busy host changes nothing: the same
  steps give the same times, tick for tick.

Master code that has no clock at hand (a job's deadline, in ``runtime/master``) reads the
clock *in use* with :func:`monotonic`: the transport puts its clock in use around every step it
runs (:func:`using`), and outside any step it is the wall clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol

__all__ = ["Clock", "WallClock", "SimClock", "WALL", "monotonic", "using", "in_use",
           "clock_of"]

# Unix time (ns) a simulated clock reads as wall time at its start: 2026-01-01 00:00:00
# UTC, a fixed instant so that the DC start time a master derives from it is the same on
# every run.
SIM_EPOCH_NS = 1_767_225_600 * 1_000_000_000


class Clock(Protocol):
    """What the runtime needs to know about time."""

    def monotonic(self) -> float:
        """Seconds, monotonic (deadlines, periods)."""
        ...

    def monotonic_ns(self) -> int:
        """The same time in ns (the slaves' clocks)."""
        ...

    def time_ns(self) -> int:
        """Unix time in ns (the DC system time's start)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (at least 0)."""
        ...


class WallClock:
    """The host's clocks; the product's default on real lines."""

    __slots__ = ("monotonic", "monotonic_ns", "time_ns", "sleep")

    def __init__(self) -> None:
        # The time module's functions themselves: a call costs what time.monotonic() costs
        # (the cyclic path, tests/startup_budget.toml).
        self.monotonic = time.monotonic
        self.monotonic_ns = time.monotonic_ns
        self.time_ns = time.time_ns
        self.sleep = time.sleep

    def __repr__(self) -> str:
        return "WallClock()"


WALL = WallClock()


class SimClock:
    """Simulated time: an integer count of ns that only :meth:`advance` (and
    :meth:`sleep`, :meth:`advance_to`) moves.  Starts at ``start_ns`` (1 s: a slave's
    "last output write at 0" is then not taken for a write at the start)."""

    __slots__ = ("ns", "slept_ns")

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self.ns = start_ns
        self.slept_ns = 0           # of which in sleep(): the time nobody was on the wire

    def __repr__(self) -> str:
        return f"SimClock({self.ns} ns)"

    def monotonic(self) -> float:
        return self.ns / 1e9

    def monotonic_ns(self) -> int:
        return self.ns

    def time_ns(self) -> int:
        return SIM_EPOCH_NS + self.ns

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            step = max(1, round(seconds * 1e9))
            self.ns += step
            self.slept_ns += step

    def advance(self, ns: int) -> None:
        """Let ``ns`` (at least 0) pass."""
        if ns > 0:
            self.ns += ns

    def advance_to(self, t_ns: int) -> None:
        """Move to ``t_ns`` if that is later than now."""
        if t_ns > self.ns:
            self.ns = t_ns


def clock_of(link: object) -> Clock:
    """The clock a link's frames live on: a simulated wire's :class:`SimClock`
    (its ``clock``), else the wall clock."""
    clock = getattr(link, "clock", None)
    return clock if isinstance(clock, SimClock) else WALL


class _InUse(threading.local):
    clock: Clock = WALL             # each thread starts on the wall clock


_IN_USE = _InUse()


def monotonic() -> float:
    """Seconds on the clock in use (:func:`using`; the wall clock outside any)."""
    return _IN_USE.clock.monotonic()


def in_use() -> Clock:
    """The clock in use in this thread (:func:`using`)."""
    return _IN_USE.clock


@contextmanager
def using(clock: Clock) -> Iterator[Clock]:
    """Put ``clock`` in use in this thread for the block: :func:`monotonic` reads it."""
    before = _IN_USE.clock
    _IN_USE.clock = clock
    try:
        yield clock
    finally:
        _IN_USE.clock = before
