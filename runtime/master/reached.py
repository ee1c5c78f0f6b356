"""Whether an ENI can take its slaves to a state, and whether they are there.

ETG.2100 leaves every register write of a start-up to the ENI's InitCmds: the master sends
what the file lists and nothing else.  A slave leaves INIT only when a command writes the
state it should go to into its AL control register (0x0120, ETG.1000.4); TwinCAT and
EC-Engineer write one per slave and transition ("set device state to PREOP", ...,
``docs/eni-exports.md`` §3).  Some IDEs export *partial* ENIs (mailbox, process data and
CoE InitCmds only) for a master that does the standard set-up itself; replayed as they
are, nothing asks a slave to change state, and a run that counts the transitions as done
would report a success that never happened.

Two checks keep ``apply`` and the ``Network`` honest:

- :func:`missing_requests`, before anything is sent: every slave's way to the target has a
  command that requests each state on it (its own, or the master's broadcast); otherwise the
  ENI is refused, naming the slave, its line and the transitions without one;
- :func:`not_reached`, after each transition: every slave's AL status, read back, shows the
  transition's target state without the error flag.  The read-back waits for a slave on its
  way (:func:`awaited_al_status`): a slave's application takes a request from AL control in
  its own time (milliseconds on real firmware), and an ENI without "check device state"
  InitCmds, which would have waited, is read back right after the request.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

from ecatcfg.esc import (AL_STATE_MASK, AL_STATUS_ERROR, AlState, Cmd, Reg, Transition,
                         al_state_name)
from ecatcfg.record import record
from ecatcfg.runtime.clock import monotonic
from ecatcfg.runtime.master.replay import ERROR_GRACE, FAST_POLLS, POLL_INTERVAL, pause
from ecatcfg.runtime.wire import Datagram

if TYPE_CHECKING:
    from ecatcfg.eni.plan import InitCmd, NetworkPlan, SlavePlan
    from ecatcfg.runtime.master.lockstep import Step

# Writes that reach a slave's register: addressed to it (auto-increment or configured
# address), or to every slave (broadcast; the master's InitCmds).
_OWN_WRITES = (Cmd.APWR, Cmd.FPWR, Cmd.APRW, Cmd.FPRW)
_BROADCAST_WRITES = (Cmd.BWR, Cmd.BRW)


@record(frozen=True)
class SlaveState:
    """A slave's AL status as read back (0x0130, 0x0134)."""

    state: int                 # AL status bits 0-3
    error: bool
    code: int                  # AL status code (0x0134)

    @property
    def name(self) -> str:
        return al_state_name(self.state | (AL_STATUS_ERROR if self.error else 0))


def _requested_state(cmd: InitCmd, transition: Transition) -> int | None:
    """The AL state ``cmd`` writes into AL control in ``transition`` (``None`` if it
    writes none there)."""
    if transition not in cmd.transitions or cmd.ado is None:
        return None
    payload = cmd.payload
    offset = Reg.AL_CONTROL - cmd.ado        # a write may start below 0x0120 and cover it
    if offset < 0 or offset + 2 > len(payload):
        return None
    value, = struct.unpack_from("<H", payload, offset)
    return int(value & AL_STATE_MASK)


def requests(cmds: list[InitCmd], transition: Transition, kinds: tuple[Cmd, ...]) -> bool:
    """Whether a command of ``kinds`` among ``cmds`` requests ``transition``'s target."""
    target = transition.target          # an enum property: looked up once, not per command
    return any(c.cmd in kinds and _requested_state(c, transition) == target for c in cmds)


def missing_requests(plan: NetworkPlan, slaves: list[SlavePlan],
                     transitions: list[Transition]) -> dict[str, list[Transition]]:
    """The transitions among ``transitions`` whose target no command requests, per slave
    (only slaves with some)."""
    # The master's broadcasts request a state of every slave: asked once, not per slave
    # (apply checks before anything is sent, on the success path too).
    by_master = {t for t in transitions
                 if requests(plan.master.init_cmds, t, _BROADCAST_WRITES)}
    missing = {}
    for slave in slaves:
        steps = [t for t in transitions
                 if t not in by_master and not requests(slave.init_cmds, t, _OWN_WRITES)]
        if steps:
            missing[slave.name] = steps
    return missing


def describe_missing(plan: NetworkPlan, name: str, steps: list[Transition]) -> str:
    """``no InitCmd requests PREOP (INIT -> PREOP)``, with ``; no register InitCmds at all``
    for a slave of a partial ENI."""
    text = "no InitCmd requests " + ", ".join(
        f"{t.target.name} ({t.source.name} -> {t.target.name})" for t in steps)
    return text + ("; no register InitCmds at all" if not plan.slave(name).init_cmds else "")


# Said once under the lines of missing_requests.
EXPLAIN = (f"A state is requested by a write of AL control (0x{Reg.AL_CONTROL:04X}) in the "
           "transition (ETG.1000.4); apply sends the ENI's commands and nothing else. An ENI "
           "whose slaves have no register InitCmds is a partial export (mailbox and process "
           "data only, for a master that does the SyncManager, FMMU and state set-up "
           "itself): export it with the register InitCmds (TwinCAT and EC-Engineer write "
           "them), or compile one with ecatcfg compile.")


def not_reached(slaves: list[SlavePlan], states: list[SlaveState | None],
                target: AlState) -> list[str]:
    """One line per slave whose AL status, read back, is not ``target`` without error."""
    from ecatcfg.esc import al_status_name
    lines = []
    for slave, st in zip(slaves, states):
        if st is None:
            lines.append(f"slave {slave.name!r} (position {slave.position}): no answer to "
                         f"the read of its AL status")
        elif st.state != target or st.error:
            code = f", AL status code 0x{st.code:04X} ({al_status_name(st.code)})" \
                if st.code else ""
            lines.append(f"slave {slave.name!r} (position {slave.position}) is in "
                         f"{st.name}, not {target.name}{code}")
    return lines


def al_status_read(position: int) -> Datagram:
    """A read of 0x0130..0x0135 (AL status, reserved, AL status code) by position, so it
    works before the station addresses are set."""
    return Datagram.physical(Cmd.APRD, -position & 0xFFFF, Reg.AL_STATUS, 6)


# Reads in a row without an answer after which a slave is taken for one that does not answer.
UNANSWERED_READS = 5


def awaited_al_status(read: Datagram, target: int, timeout: float) -> Step[bytes | None]:
    """Send ``read`` (a read of one slave's 0x0130..0x0135, by position or station address:
    :func:`al_status_read`) until the AL status shows ``target`` (bits 0-4: a state, or
    a state with the error flag) or, when ``target`` has no error flag, shows the error
    flag for ``ERROR_GRACE`` (a refusal; a flag being cleared by an acknowledge is not
    taken for one), or ``timeout`` s pass.  Returns the last 6 bytes read (0x0130..0x0135),
    ``None`` if the slave never answered (``UNANSWERED_READS`` reads in a row).  The first
    reads go out at once, then one every ``POLL_INTERVAL``, as a state-check InitCmd's."""
    deadline = monotonic() + timeout
    last: bytes | None = None
    error_since: float | None = None
    unanswered = polls = 0
    while True:
        reply = yield [read]
        now = monotonic()
        if reply is not None and reply[0].wkc == 1:
            last = bytes(reply[0].data)
            unanswered = 0
            status = last[0] & (AL_STATE_MASK | AL_STATUS_ERROR)
            if status == target:
                return last
            if status & AL_STATUS_ERROR and not target & AL_STATUS_ERROR:
                error_since = error_since or now
                if now - error_since >= ERROR_GRACE:
                    return last
            else:
                error_since = None
        else:
            unanswered += 1
            if last is None and unanswered >= UNANSWERED_READS:
                return None
        if now > deadline:
            return last
        polls += 1
        if polls > FAST_POLLS:
            yield from pause(POLL_INTERVAL)
