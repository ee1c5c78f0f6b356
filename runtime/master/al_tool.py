"""Show or request the AL states of the slaves on a line no ENI describes (``ecatcfg
states``), the way IgH's ``ethercat states`` does.

Slaves are addressed by position (auto-increment), so this works before any station
address is set.  A request writes AL control (0x0120) = the state, with the error
acknowledge bit (0x10) when the slave shows an error indication (AL status bit 4): a slave
leaves an error state only when the master acknowledges it (ETG.1000.6 AL state machine,
"error acknowledge"; ESC Section II 0x0120).  Then AL status (0x0130) and the AL status
code (0x0134) are read until the slave is in the state, shows an error (the refusal, after
``ERROR_GRACE`` so a flag being cleared is not taken for one), or ``timeout`` passes.
"""

from __future__ import annotations

import struct

from ecatcfg.runtime.clock import monotonic
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (AL_ERROR_ACK, AL_STATE_MASK, AL_STATUS_ERROR, AlState, Cmd, Reg,
                         al_state_name, al_status_name)
from ecatcfg.record import record
from ecatcfg.runtime.master.lockstep import Job, run_jobs
from ecatcfg.runtime.master.reached import al_status_read, awaited_al_status
from ecatcfg.runtime.master.replay import TIMEOUT_COMMAND, TIMEOUT_STATE
from ecatcfg.runtime.master.scan import count_slaves
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram


class StatesError(EcatcfgError):
    """A slave that is not on the line, or that does not answer."""


@record(frozen=True)
class SlaveAlStatus:
    """One slave's AL status as read (``al_status``: 0x0130, ``code``: 0x0134); after a
    request, ``requested`` and whether the slave is in it (``reached``)."""

    position: int
    al_status: int
    code: int
    requested: AlState | None = None
    timed_out: bool = False

    @property
    def state(self) -> int:
        return self.al_status & AL_STATE_MASK

    @property
    def error(self) -> bool:
        return bool(self.al_status & AL_STATUS_ERROR)

    @property
    def reached(self) -> bool:
        return self.requested is not None and self.al_status & 0x1F == self.requested

    def text(self) -> str:
        """``OP``, ``SAFEOP+ERR 0x001D invalid output configuration``: the code only with
        the error indication (a slave may leave an old code in 0x0134 after the
        acknowledge)."""
        shown = al_state_name(self.al_status)
        if self.error:
            shown += f" 0x{self.code:04X} {al_status_name(self.code)}"
        return shown


def positions_on_line(transport: Transport, slave: int | None) -> list[int]:
    """All positions of the line, or ``[slave]`` once it is known to be on it."""
    n = count_slaves(transport)
    if slave is None:
        return list(range(n))
    if not 0 <= slave < n:
        raise StatesError(f"no slave at position {slave}: the line has {n} "
                          f"slave{'s' if n != 1 else ''}"
                          + (f" (positions 0..{n - 1})" if n > 1 else ""))
    return [slave]


def _decode(position: int, data: bytes | bytearray, requested: AlState | None = None,
            timed_out: bool = False) -> SlaveAlStatus:
    al_status, = struct.unpack_from("<H", data)
    code, = struct.unpack_from("<H", data, 4)
    return SlaveAlStatus(position, al_status, code, requested, timed_out)


def _read_job(position: int, out: dict[int, SlaveAlStatus]) -> Job:
    deadline = monotonic() + TIMEOUT_COMMAND
    while True:
        reply = yield [al_status_read(position)]
        if reply is not None and reply[0].wkc == 1:
            out[position] = _decode(position, reply[0].data)
            return
        if monotonic() > deadline:
            raise StatesError(f"slave {position}: no answer to the AL status read (0x0130)")


def read_states(transport: Transport, positions: list[int]) -> list[SlaveAlStatus]:
    """The AL status and status code of each slave in ``positions``."""
    out: dict[int, SlaveAlStatus] = {}
    run_jobs(transport, [_read_job(p, out) for p in positions])
    return [out[p] for p in positions]


def _request_job(before: SlaveAlStatus, target: AlState, timeout: float,
                 out: dict[int, SlaveAlStatus]) -> Job:
    position = before.position
    adp = -position & 0xFFFF
    control = int(target) | (AL_ERROR_ACK if before.error else 0)
    write = Datagram.physical(Cmd.APWR, adp, Reg.AL_CONTROL, struct.pack("<H", control))
    deadline = monotonic() + TIMEOUT_COMMAND
    while True:
        reply = yield [write]
        if reply is not None and reply[0].wkc == 1:
            break
        if monotonic() > deadline:
            raise StatesError(f"slave {position}: the AL control write (0x0120) of "
                              f"{target.name} was not answered")
    data = yield from awaited_al_status(al_status_read(position), target, timeout)
    got = _decode(position, data, target) if data is not None else before
    out[position] = got if got.reached or (data is not None and got.error) else \
        SlaveAlStatus(position, got.al_status, got.code, target, timed_out=True)


def request_state(transport: Transport, positions: list[int], target: AlState,
                  timeout: float = TIMEOUT_STATE) -> list[SlaveAlStatus]:
    """Request ``target`` of each slave in ``positions`` (all at once) and wait for each
    to reach it or refuse it; returns what each shows at the end (``reached`` or not)."""
    before = read_states(transport, positions)
    out: dict[int, SlaveAlStatus] = {}
    run_jobs(transport, [_request_job(s, target, timeout, out) for s in before])
    return [out[p] for p in positions]


__all__ = ["SlaveAlStatus", "StatesError", "positions_on_line", "read_states",
           "request_state"]
