"""Many slaves' command chains on one wire, in lockstep rounds.

Each slave's work in a step (its InitCmds of a transition, its mailbox transfers, the
identity reading of a scan) is a *job*: a generator that yields the datagrams it needs next
and is sent back the same datagrams as they returned (``None`` when their frame was lost).
A job that has nothing to send this round but is not finished yields an empty list.
A job is built from *steps*, generators of the same kind that return a value at the end
(``reply = yield from until_answered(...)``); a job itself returns nothing.

Every round the scheduler takes the pending datagrams of all jobs, packs them into as few
frames as the 1486-byte limit allows and hands each job its replies.  Commands of different
slaves that do not depend on each other thus share frames, and the number of frames a step
costs is about the length of its longest per-slave chain.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Mapping
from typing import TypeVar

from ecatcfg.runtime.clock import monotonic, using
from ecatcfg.runtime.master.transport import Transport, pack
from ecatcfg.runtime.wire import Datagram

R = TypeVar("R")
Step = Generator[list[Datagram], "list[Datagram] | None", R]     # a part of a job, returns R
Job = Step[None]

IDLE_S = 0.0005     # when every job only waits, do not spin the wire


def run_jobs(transport: Transport, jobs: list[Job],
             on_round: Callable[[], None] | None = None) -> None:
    """Run ``jobs`` to completion; an exception from any job ends the step and propagates.
    The jobs run on the transport's clock (their deadlines: :func:`~ecatcfg.runtime.clock.monotonic`)."""
    clock = transport.clock
    with using(clock):
        active = start(jobs)
        while active:
            if on_round is not None:
                on_round()
            if not any(request for _, request in active):
                clock.sleep(IDLE_S)
            active = one_round(transport, active)


Pending = list[tuple[Job, list[Datagram]]]     # running jobs and the datagrams each wants


def start(jobs: list[Job]) -> Pending:
    """The jobs that have something to do, each with its first datagrams."""
    active: Pending = []
    for job in jobs:
        try:
            active.append((job, next(job)))
        except StopIteration:
            pass
    return active


def one_round(transport: Transport, active: Pending, timeout: float | None = None,
              on_error: Callable[[Job, Exception], None] | None = None,
              answered: Mapping[int, Datagram] | None = None) -> Pending:
    """One round: the pending datagrams of every job in as few frames as fit, each job
    sent its replies (``None`` when a frame was lost); returns the jobs still running.
    An exception from a job propagates, or goes to ``on_error(job, exception)`` (the job
    then ends) when that is given.  ``answered``: replies already known this round, by
    the ``id`` of the datagram asked for (the mailbox-state LRD the cyclic frame just
    carried: ``recovery.py``); those datagrams are not sent."""
    with using(transport.clock):
        return _round(transport, active, timeout, on_error, answered)


def _round(transport: Transport, active: Pending, timeout: float | None,
           on_error: Callable[[Job, Exception], None] | None,
           answered: Mapping[int, Datagram] | None = None) -> Pending:
    # A datagram several jobs ask for in one round (the same object: the LRD of the
    # mailbox-state bits, replay.MailboxStatePoll) goes once; each of them gets its reply.
    back: dict[int, Datagram | None] = {}
    unique: dict[int, Datagram] = {}
    for _, request in active:
        for dg in request:
            key = id(dg)
            if answered is not None and key in answered:
                back[key] = answered[key]
            else:
                unique.setdefault(key, dg)
    for frame in pack(list(unique.values())):
        came = transport.exchange(frame, timeout)
        for k, dg in enumerate(frame):
            back[id(dg)] = None if came is None else came[k]
    still: Pending = []
    for job, request in active:
        got = [back[id(dg)] for dg in request]
        reply = None if any(g is None for g in got) else [g for g in got if g is not None]
        try:
            still.append((job, job.send(reply)))
        except StopIteration:
            pass
        except Exception as exc:
            if on_error is None:
                raise
            on_error(job, exc)
    return still


def until_answered(datagrams: list[Datagram], deadline: float,
                   error: Exception) -> Step[list[Datagram]]:
    """A job step: send ``datagrams`` every round until each comes back with working
    counter 1 (lost frames and refusals are sent again); returns the replies, or raises
    ``error`` once ``deadline`` (:func:`~ecatcfg.runtime.clock.monotonic`) has passed."""
    while True:
        reply = yield datagrams
        if reply is not None and all(d.wkc == 1 for d in reply):
            return reply
        if monotonic() > deadline:
            raise error
