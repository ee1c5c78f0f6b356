"""Bringing a network up from its ENI: verify, replay the InitCmds, DC, cyclic frames.

The order follows what TwinCAT and EC-Engineer do (``docs/eni-exports.md`` §2-§3):

1. scan the line and compare it with the ENI before any configuration write;
2. per transition (INIT->PREOP, PREOP->SAFEOP, SAFEOP->OP; OP->SAFEOP->PREOP->INIT on the
   way down): the master's ``BeforeSlave`` InitCmds, every slave's InitCmds (in lockstep,
   see ``lockstep.py``), then the master's other InitCmds;
3. before PREOP->SAFEOP, for slaves with DC: propagation delays, system time offsets and
   static drift compensation (not in the ENI; ``docs/protocol-notes.md`` §8); before
   SAFEOP->OP, drift compensation until every DC slave's system time difference (0x092C)
   is under a threshold;
4. from PREOP->SAFEOP on (the ENI's ``Requires=cycle``) the cyclic frames run between the
   rounds of InitCmds, so slaves see process data before OP and their SM watchdogs are fed.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TYPE_CHECKING

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import NetworkPlan, SlavePlan
from ecatcfg.esc import (AL_ERROR_ACK, AL_STATE_MASK, AL_STATUS_ERROR, ESC_FEATURE_DC,
                         AlState, Cmd, Reg, Transition)
from ecatcfg.record import record
from ecatcfg.runtime.master import hotconnect
from ecatcfg.runtime.master.cyclic import CyclicFrames
from ecatcfg.runtime.master.lockstep import Job, Step, run_jobs, until_answered
from ecatcfg.runtime.master.reached import (EXPLAIN, UNANSWERED_READS, SlaveState,
                                            al_status_read, awaited_al_status,
                                            describe_missing, missing_requests, not_reached)
from ecatcfg.runtime.master.replay import (TIMEOUT_COMMAND, TIMEOUT_STATE, ApplyError,
                                           SlaveProgress, mailbox_channels)
from ecatcfg.runtime.master.scan import FoundSlave, Mismatch, scan, verify
from ecatcfg.runtime.master.transition import mailbox_init_cmds, master_job, slave_transition_job
from ecatcfg.runtime.master.transport import Transport, pack
from ecatcfg.runtime.wire import Datagram
from ecatcfg.runtime.wiring import CHILD_PORTS, active_ports

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.link import Link
    from ecatcfg.runtime.master.recovery import Supervisor

UP = [Transition.IP, Transition.PS, Transition.SO]
DOWN = {AlState.OP: [Transition.OS, Transition.SP, Transition.PI],
        AlState.SAFEOP: [Transition.SP, Transition.PI],
        AlState.PREOP: [Transition.PI]}
# EtherCAT system time counts nanoseconds from 2000-01-01 (ETG.1000.4; SOEM, KickCAT).
EPOCH_2000_NS = 946_684_800 * 1_000_000_000
# Static drift compensation: ARMW frames of the reference clock's system time before the
# cycle starts (EtherCrab and KickCAT send 15 000; the convergence wait below goes on
# until the clocks agree, however many that takes).
DRIFT_FRAMES = 2000
# Before SAFEOP->OP: drift compensation until |0x092C| of every DC slave is under the
# threshold, or an error after the timeout (IgH fsm_slave_config.c waits up to
# EC_DC_SYNC_WAIT_MS = 5000 ms for EC_DC_MAX_SYNC_DIFF_NS = 10 us; a settled line is within
# 100 ns, Beckhoff's DC figure, and 1 us leaves room for a loaded host).
DC_THRESHOLD_NS = 1000
DC_TIMEOUT_S = 5.0
DC_CHECK_FRAMES = 100          # drift frames between two reads of 0x092C
# 0x092C is a mean over 2^(0x0934) samples (16 at the reset value, Beckhoff ESC Section II
# 0x0934); after a reset of the loop (0x0930) it starts again from the first samples, so a
# slave rejoining is not judged before four times that many drift frames.
DC_SETTLE_SAMPLES = 4 << 4


class VerifyError(ApplyError):
    """The line does not match the ENI; nothing was configured."""

    def __init__(self, mismatches: list[Mismatch]) -> None:
        lines = [f"  {m.position:>3}  {m.expected:48} {m.found:32} {m.problem}"
                 for m in mismatches]
        super().__init__("the slaves on the line do not match the ENI; nothing was "
                         "configured\n  pos  expected (ENI)" + " " * 35 + "found" + " " * 28
                         + "problem\n" + "\n".join(lines))
        self.mismatches = mismatches


@record
class Event:
    """Progress for the reporter: a step that starts or ends."""

    kind: str                  # "scan", "transition", "dc", "eoe", "done"; from the
                               # Network: "skipped", "ignored", "emulated"; while cycling
                               # (runtime/master/recovery.py): "offline", "online", "retry",
                               # "refused"
    text: str
    slave: str | None = None   # the slave it is about, when it is about one


class NotReachedError(ApplyError):
    """Slaves whose AL status, read back after a transition, is not its target state."""

    def __init__(self, transition: Transition, lines: list[str]) -> None:
        super().__init__(f"after {transition.value} ({transition.target.name} requested), "
                         f"{len(lines)} slave{'s' if len(lines) != 1 else ''} not in "
                         f"{transition.target.name}:\n" + "\n".join(f"  {x}" for x in lines))
        self.transition = transition
        self.lines = lines


class LeftStateError(ApplyError):
    """Slaves found out of the state the line was brought to, after it ran there."""

    def __init__(self, state: AlState, lines: list[str]) -> None:
        super().__init__(f"while the line ran in {state.name}, {len(lines)} "
                         f"slave{'s' if len(lines) != 1 else ''} left it:\n"
                         + "\n".join(f"  {x}" for x in lines))
        self.state = state
        self.lines = lines


class IncompleteEniError(ApplyError):
    """An ENI whose InitCmds do not request every state on the way to the target
    (``runtime/master/reached.py``); raised before any frame is sent.  ``missing``: per slave,
    the transitions whose state nothing requests."""

    def __init__(self, plan: NetworkPlan, target: AlState,
                 missing: dict[str, list[Transition]], eni: str | None) -> None:
        self.missing = {name: describe_missing(plan, name, steps)
                        for name, steps in missing.items()}
        super().__init__(
            f"{eni + ': ' if eni else ''}the ENI cannot take its slaves to {target.name}; "
            f"nothing was sent:\n" + "\n".join(f"  slave {name!r}: {text}"
                                                for name, text in self.missing.items())
            + "\n" + EXPLAIN)


def up_to(target: AlState) -> list[Transition]:
    """The transitions from INIT to ``target`` (none for INIT)."""
    return [t for t in UP if t.target <= target]


def check_requests(plan: NetworkPlan, target: AlState, eni: str | None = None) -> None:
    """Raise :class:`IncompleteEniError` when some slave's way to ``target`` has a state
    that no InitCmd requests (a partial ENI), before anything is sent."""
    missing = missing_requests(plan, plan.slaves, up_to(target))
    if missing:
        raise IncompleteEniError(plan, target, missing, eni)


class DcSyncError(ApplyError):
    """The DC slaves' clocks did not converge onto the reference clock in time."""

    def __init__(self, message: str, slave: str | None, differences: dict[str, int | None]
                 ) -> None:
        super().__init__(message, slave)
        self.differences = differences


class Master:
    """Runs one ENI on one link."""

    def __init__(self, plan: NetworkPlan, link: Link, *,
                 recorder: Callable[[bytes, bool], None] | None = None,
                 on_event: Callable[[Event], None] | None = None,
                 dc_threshold_ns: int = DC_THRESHOLD_NS,
                 dc_timeout_s: float = DC_TIMEOUT_S, recovery: bool = True,
                 esi: Library | None = None) -> None:
        """``dc_threshold_ns``, ``dc_timeout_s``: before SAFEOP->OP, wait until every DC
        slave's system time difference (0x092C) is under the threshold, for at most the
        timeout (then :class:`DcSyncError`); a threshold of 0 skips the wait.
        ``recovery``: bring back slaves that drop out while the network cycles.  ``esi``:
        the ESI files a refusal's cause is compared with (``diagnose.py``); the master
        configures from the ENI alone."""
        check_dc_wait(dc_threshold_ns, dc_timeout_s)
        self.recovery = recovery
        self.esi = esi
        self.dc_threshold_ns = dc_threshold_ns
        self.dc_timeout_s = dc_timeout_s
        self.plan = plan
        self.slaves = sorted(plan.slaves, key=lambda s: s.position)
        self.transport = Transport(link, recorder=recorder)
        self.cyclic = CyclicFrames(plan)
        self._cyclic_plan = plan.cyclic
        self.line = plan                # the plan as the line is (hot-connect groups absent)
        self.state = AlState.INIT
        self.progress = {s.name: SlaveProgress(s.name) for s in self.slaves}
        self.mailboxes = mailbox_channels(plan)
        self.on_event = on_event
        self._cycling = False
        self._next_cycle = 0.0
        self.found: list[FoundSlave] | None = None     # the last scan: identity, plugs
        self.scanned: list[FoundSlave] | None = None   # the last scan, also when it failed
        self.accept_newer_revision = False
        self.dc_delays: dict[str, int] = {}            # propagation delays set (ns)
        # Watches the slaves once the network cycles in SAFEOP or OP (runtime/master/recovery.py).
        self.supervisor: Supervisor | None = None

    def _event(self, kind: str, text: str, slave: str | None = None) -> None:
        if self.on_event:
            self.on_event(Event(kind, text, slave))

    # -- scan -------------------------------------------------------------------------------

    def scan_and_verify(self, accept_newer_revision: bool = False) -> list[FoundSlave]:
        self._event("scan", "scanning the line")
        self.accept_newer_revision = accept_newer_revision
        found = scan(self.transport)
        present = {s.name for s in self.plan.slaves}
        absent_heads: set[str] = set()
        if any(s.hot_connect is not None for s in self.plan.slaves):
            # Which hot-connect groups are there (runtime/master/hotconnect.py); the line is
            # verified without the others.
            identified: dict[tuple[str, int], bool] = {}
            run_jobs(self.transport, [hotconnect.identify_job(head, position, identified)
                                      for head, position in hotconnect.candidates(
                                          self.plan, found)])
            heads = hotconnect.present_groups(self.plan, found, identified)
            absent_heads = {h for h in hotconnect.groups(self.plan.slaves) if h not in heads}
            present -= set(hotconnect.absent_slaves(self.plan, heads))
        self.layout(present)
        problems = verify(self.line, found, accept_newer_revision)
        self.scanned = found                # what is on the line, verified or not
        if problems:
            raise VerifyError(problems)
        self.found = found
        # Passive slaves (no ESC) are in the ENI but never on the wire (eni/plan.py).
        passive = len(self.plan.passive)
        self._event("scan", f"{len(found)} slaves match the ENI" + (
            f" ({passive} passive slave{'s' if passive != 1 else ''} without an ESC not "
            "on the wire)" if passive else ""))
        self.supervisor = None
        if absent_heads:
            for head, members in hotconnect.groups(self.plan.slaves).items():
                if head in absent_heads:
                    self._event("hot-connect", f"hot-connect group {head!r} "
                                f"({hotconnect.slaves(len(members))}) is not on the line; "
                                f"the others go on", head)
            if self.recovery:
                from ecatcfg.runtime.master.recovery import Supervisor
                self.supervisor = Supervisor(self, absent_heads)
        return found

    def layout(self, present: set[str]) -> None:
        """Run the line as it is with the slaves named in ``present`` (the others belong
        to hot-connect groups that are not there): their plans moved to where they are
        (``hotconnect.as_found``), the cyclic frames' position-addressed commands too (the
        process image and the statistics carry over)."""
        line = hotconnect.as_found(self.plan, present)
        self.line = line
        self.slaves = sorted(line.slaves, key=lambda s: s.position)
        if line.cyclic != self._cyclic_plan:
            outputs, stats = self.cyclic.outputs, self.cyclic.stats
            self.cyclic = CyclicFrames(line)
            self.cyclic.outputs[:] = outputs
            self.cyclic.stats = stats
            self._cyclic_plan = line.cyclic

    # -- state changes ----------------------------------------------------------------------

    def bring_up(self, target: AlState = AlState.OP) -> None:
        """Up to ``target`` transition by transition; after each one every slave's AL
        status is read back, and a slave that is not in the transition's target state is
        an :class:`ApplyError` (``runtime/master/reached.py``): the state is reached when the
        slaves say so, not when the ENI's commands have been sent."""
        # INIT->INIT first, where ETG.2100 puts it (esc.TRANSITION_RULES): only when the
        # ENI has such commands, so the wire of an ENI without them stays the same.
        if self.state == AlState.INIT and self._has_commands(Transition.II):
            self.run_transition(Transition.II)
        for transition in UP:
            if self.state >= target:
                return
            if transition == Transition.PS:
                self.setup_dc()
            if transition == Transition.SO:
                self.wait_dc()
            self.run_transition(transition)
            self.check_reached(transition)

    def check_reached(self, transition: Transition) -> None:
        """Raise :class:`NotReachedError` unless every slave on the line reads back in
        ``transition``'s target state without the error flag.  A slave still on its way is
        read again until it is there, refuses (error flag) or ``TIMEOUT_STATE`` passes
        (``reached.awaited_al_status``); the cyclic frames go on meanwhile where the
        transition needs them."""
        lines = not_reached(self.slaves, self.await_states(transition.target),
                            transition.target)
        if lines:
            raise NotReachedError(transition, lines)

    def await_states(self, target: AlState, skip: frozenset[str] | set[str] = frozenset()
                     ) -> list[SlaveState | None]:
        """Each slave's AL status once it shows ``target``, refuses it (error flag) or
        ``TIMEOUT_STATE`` passes (``None``: no answer, or a slave named in ``skip``)."""
        out: dict[int, SlaveState] = {}
        run_jobs(self.transport, [_await_state(s.position, target, out)
                                  for s in self.slaves if s.name not in skip],
                 self._tick if self._cycling else None)
        return [out.get(s.position) for s in self.slaves]

    def check_kept(self, states: list[SlaveState | None]) -> None:
        """Raise :class:`LeftStateError` if a slave that answered the read of ``states``
        (:meth:`read_states`, after the line ran) is no longer in the state the line was
        brought to, or shows the error flag: a slave whose SM watchdog ran out between two
        cycles (0x001B) drops to SAFEOP+ERR while every working counter still adds up, so
        the cycles alone cannot tell.  A slave that did not answer is the working
        counters' and the recovery's to judge (a hot-connect group may be away)."""
        answered = [(slave, st) for slave, st in zip(self.slaves, states) if st is not None]
        lines = not_reached([slave for slave, _ in answered], [st for _, st in answered],
                            self.state)
        if lines:
            raise LeftStateError(self.state, lines)

    def _has_commands(self, transition: Transition) -> bool:
        return any(transition in c.transitions for c in self.plan.master.init_cmds) or any(
            transition in c.transitions for s in self.slaves for c in s.init_cmds) or any(
            any(mailbox_init_cmds(s, transition)) for s in self.slaves)

    def bring_down(self, target: AlState = AlState.INIT) -> None:
        """Down to ``target`` in order (OP->SAFEOP->PREOP->INIT).  Slaves with an AL error
        are acknowledged first (a slave ignores requests while its error is not
        acknowledged); a failed step does not stop the way down: the first failure is
        raised at the end."""
        # Slaves that dropped out while cycling are not taken down step by step (they are
        # not in the network's state); they are only asked for INIT at the end.
        offline = {n for n, h in self.supervisor.health.items() if not h.online} \
            if self.supervisor is not None else set()
        self._acknowledge_errors()
        first: ApplyError | None = None
        for transition in DOWN.get(self.state, []):
            if self.state <= target:
                break
            try:
                self.run_transition(transition, offline)
                # The slaves take the request in their own time: the next step (or the
                # caller's final read) finds them there.  What they show is the caller's
                # to report; the way down goes on regardless.
                self.await_states(transition.target, offline)
            except ApplyError as exc:
                first = first or exc
                self.state = transition.target
                self._acknowledge_errors()
        if offline and target == AlState.INIT:
            run_jobs(self.transport, [
                _write_by_position(s.position, Reg.AL_CONTROL,
                                   struct.pack("<H", AlState.INIT | AL_ERROR_ACK))
                for s in self.slaves if s.name in offline])
        if first is not None:
            raise first

    def down_bound(self, target: AlState = AlState.INIT) -> float:
        """Seconds :meth:`bring_down` can take at most from the current state: per
        transition, the master's InitCmds and the slowest slave's (their timeouts, lost
        frames included: the slaves run in parallel), its mailbox InitCmds, the wait for
        the slaves to show the step's state, and the AL error acknowledgements (a state
        read and a write) before and after each step.  A service
        manager's stop timeout must be above this (docs/runtime.md)."""
        from ecatcfg.runtime.master.replay import TIMEOUT_MAILBOX, command_timeout
        ack = 2 * TIMEOUT_COMMAND
        total = ack
        for transition in DOWN.get(self.state, []):
            if transition.target < target:
                break
            master = sum(command_timeout(c) for c in self.plan.master.init_cmds
                         if transition in c.transitions)
            slowest = 0.0
            for s in self.slaves:
                coe, eoe = mailbox_init_cmds(s, transition)
                t = sum(command_timeout(c) for c in s.init_cmds if transition in c.transitions)
                t += sum(c.timeout / 1000 if c.timeout else TIMEOUT_MAILBOX for c in coe + eoe)
                slowest = max(slowest, t)
            total += master + slowest + ack + TIMEOUT_STATE
        return total

    def _acknowledge_errors(self) -> None:
        states = self.read_states()
        jobs = [_write_by_position(s.position, Reg.AL_CONTROL,
                                   struct.pack("<H", st.state | AL_ERROR_ACK))
                for s, st in zip(self.slaves, states) if st is not None and st.error]
        if jobs:
            run_jobs(self.transport, jobs)

    def run_transition(self, transition: Transition,
                       skip: frozenset[str] | set[str] = frozenset()) -> None:
        """Every slave's InitCmds of ``transition`` (but the slaves named in ``skip``)."""
        start = self.transport.clock.monotonic()
        frames = self.transport.counters.frames_sent
        self._event("transition", f"{transition.value}: {transition.name} ...")
        # Requires=cycle: from PREOP->SAFEOP on, process data runs while slaves change state.
        self._cycling = transition in (Transition.PS, Transition.SO, Transition.OS,
                                       Transition.SP)
        tick = self._tick if self._cycling else None
        master = self.plan.master.init_cmds
        try:
            run_jobs(self.transport, [master_job(master, transition, True)], tick)
            run_jobs(self.transport,
                     [slave_transition_job(s, transition, self.progress[s.name],
                                           self.mailboxes.get(s.name))
                      for s in self.slaves if s.name not in skip], tick)
            run_jobs(self.transport, [master_job(master, transition, False)], tick)
            for s in self.slaves:
                for cmd in mailbox_init_cmds(s, transition)[1]:
                    self._event("eoe", f"EoE IP parameters of {s.name!r} set: "
                                f"{cmd.request.params.describe()}")
        except BaseException:
            # Some slaves may have changed state (also when a signal or Ctrl-C interrupts
            # the step): going down must cover them too.
            if transition.target > self.state:
                self.state = transition.target
            raise
        self.state = transition.target
        self._event("transition", f"{transition.value}: {self.state.name} in "
                    f"{(self.transport.clock.monotonic() - start) * 1000:.0f} ms, "
                    f"{self.transport.counters.frames_sent - frames} frames")

    def _tick(self) -> None:
        now = self.transport.clock.monotonic()
        if now >= self._next_cycle:
            self._next_cycle = now + self.cyclic.cycle_time_us / 1e6
            self.cyclic.exchange(self.transport, self.state)

    def read_states(self) -> list[SlaveState | None]:
        """Each slave's AL status and status code (by position, so it works before the
        station addresses are set); ``None`` for a slave that did not answer."""
        out: dict[int, SlaveState] = {}
        run_jobs(self.transport, [_read_state(s.position, out) for s in self.slaves])
        return [out.get(s.position) for s in self.slaves]

    # -- cyclic -----------------------------------------------------------------------------

    def cycle(self) -> bool:
        """One cycle of the ENI's cyclic frames in the current state; in SAFEOP and OP the
        supervisor then looks after slaves that drop out (``runtime/master/recovery.py``), and the
        result says whether every online slave's data came back as expected."""
        ok = self.cyclic.exchange(self.transport, self.state)
        supervisor = self.supervisor
        if supervisor is None:
            if self.state < AlState.SAFEOP or not self.recovery:
                return ok
            from ecatcfg.runtime.master.recovery import Supervisor
            supervisor = self.supervisor = Supervisor(self)
        return supervisor.after_cycle(ok)

    # -- distributed clocks ------------------------------------------------------------------

    def _dc_slaves(self) -> tuple[list[SlavePlan], SlavePlan | None]:
        dc = [s for s in self.slaves if s.dc is not None]
        reference = next((s for s in dc if s.dc is not None and s.dc.reference_clock),
                         dc[0] if dc else None)
        return dc, reference

    def setup_dc(self) -> None:
        dc, reference = self._dc_slaves()
        if reference is None:
            return
        self._event("dc", f"DC: {len(dc)} slaves")
        self._broadcast_write(Reg.DC_RECEIVE_TIME_PORT0, bytes(4))
        times: dict[str, tuple[tuple[int, int, int, int], int]] = {}
        run_jobs(self.transport, [_read_receive_times(s, times) for s in dc])
        # Every ESC with a DC unit latches its port times, also one the ENI sets no DC for
        # (a coupler, a junction): its times measure the branches between the DC slaves.
        ports = {name: t[0] for name, t in times.items()}
        run_jobs(self.transport, [_read_port_times(s, ports) for s in self.slaves
                                  if s.dc is None])
        measured = [s for s in self.slaves if s.name in ports]
        delays = propagation_delays(measured, reference, ports, self.found)
        self.dc_delays = {s.name: delays[s.name] for s in dc}
        ref_rx = times[reference.name][1]
        master_time = self.transport.clock.time_ns() - EPOCH_2000_NS
        writes = []
        for s in dc:
            delay = delays[s.name]
            offset = (master_time + delay - times[s.name][1]) if s is not reference else \
                master_time - ref_rx
            writes.append(_write_until_ok(s, Reg.DC_SYSTEM_TIME + 0x10,
                                          struct.pack("<qI", offset, delay)))
        run_jobs(self.transport, writes)
        run_jobs(self.transport, [_write_until_ok(s, Reg.DC_SPEED_COUNTER_START,
                                                  struct.pack("<H", 0x1000)) for s in dc])
        armw = _drift_frame(reference)
        for _ in range(DRIFT_FRAMES):
            self.transport.exchange([armw])

    def wait_dc(self) -> None:
        """Drift compensation until every DC slave's system time difference (0x092C, read
        every ``DC_CHECK_FRAMES`` frames) is under ``dc_threshold_ns``; the cyclic frames
        go on meanwhile.  :class:`DcSyncError` after ``dc_timeout_s``, naming the slave
        furthest off and its last difference."""
        dc, reference = self._dc_slaves()
        if reference is None or not self.dc_threshold_ns:
            return
        threshold = self.dc_threshold_ns
        armw = _drift_frame(reference)
        tick = self._tick if self._cycling else None
        start = self.transport.clock.monotonic()
        frames = 0
        while True:
            diffs = self.read_dc_differences(dc)
            off = {n: d for n, d in diffs.items() if d is None or abs(d) >= threshold}
            if not off:
                self._event("dc", f"DC: every system time difference under {threshold} ns "
                            f"after {frames} drift frames, "
                            f"{(self.transport.clock.monotonic() - start) * 1000:.0f} ms (largest "
                            f"{max(abs(d or 0) for d in diffs.values())} ns)")
                return
            if self.transport.clock.monotonic() - start > self.dc_timeout_s:
                name = max(off, key=lambda n: float("inf") if off[n] is None
                           else abs(off[n] or 0))
                worst = off[name]
                what = ("did not answer the read of its system time difference (0x092C)"
                        if worst is None else f"system time difference (0x092C) is "
                        f"{worst} ns")
                others = len(off) - 1
                raise DcSyncError(
                    f"DC did not converge: {what}, threshold {threshold} ns, after "
                    f"{self.dc_timeout_s:g} s and {frames} drift frames"
                    + (f"; {others} more DC slaves over the threshold" if others else ""),
                    name, diffs)
            for _ in range(DC_CHECK_FRAMES):
                self.transport.exchange([armw])
                if tick is not None:
                    tick()
            frames += DC_CHECK_FRAMES

    def read_dc_differences(self, slaves: list[SlavePlan] | None = None
                            ) -> dict[str, int | None]:
        """System time difference (0x092C, ns, signed: negative when the slave's copy is
        behind the reference) of each DC slave; ``None`` for one that did not answer."""
        if slaves is None:
            slaves = self._dc_slaves()[0]
        reads = [Datagram.physical(Cmd.FPRD, s.phys_addr, Reg.DC_SYSTEM_TIME_DIFFERENCE, 4)
                 for s in slaves]
        out: dict[str, int | None] = {s.name: None for s in slaves}
        at = 0
        for frame in pack(reads):
            got = self.transport.exchange(frame)
            back: list[Datagram | None] = list(got) if got else [None] * len(frame)
            for answer, s in zip(back, slaves[at:at + len(frame)]):
                if answer is not None and answer.wkc == 1:
                    raw, = struct.unpack("<I", answer.data)
                    out[s.name] = -(raw & 0x7FFF_FFFF) if raw & 0x8000_0000 else raw
            at += len(frame)
        return out

    def dc_rejoin_job(self, slave: SlavePlan) -> Step[None]:
        """A DC slave that was powered off and on lost its system time offset and delay:
        set them again from another DC slave's system time (the reference clock, or any
        other DC slave when the reference itself came back), read in the same frame as the
        slave's own, with the delay :meth:`setup_dc` measured; the cyclic drift
        compensation then keeps it on time.  A slave that kept its power is set the same
        way, from the offset and delay it still has."""
        dc, reference = self._dc_slaves()
        online = self.supervisor.health if self.supervisor is not None else {}
        sources = [s for s in ([reference] if reference is not None else []) + dc
                   if s.name != slave.name and (s.name not in online or online[s.name].online)]
        if not sources:
            return
        source = sources[0]
        delay = self.dc_delays.get(slave.name, 0)
        failed = ApplyError("cannot read the DC system times", slave.name)
        # The slave's 0x0910, its offset 0x0920 and delay 0x0928 (0 after a power cycle; a
        # slave that kept power keeps its old ones) in one read of 28 bytes.
        got = yield from until_answered(
            [Datagram.physical(Cmd.FPRD, source.phys_addr, Reg.DC_SYSTEM_TIME, 8),
             Datagram.physical(Cmd.FPRD, slave.phys_addr, Reg.DC_SYSTEM_TIME, 28)],
            monotonic() + TIMEOUT_COMMAND, failed)
        theirs, = struct.unpack("<Q", got[0].data)
        own, old_offset, old_delay = struct.unpack_from("<Q8xqI", got[1].data)
        # A read of 0x0910 gives the local copy of system time less the delay, the time when
        # the frame passed the reference clock (ESC Section I, Table 30): the source's read
        # is the reference's time then, the slave's is its local time + old offset - old
        # delay.  Its new system time must be the reference's, ``delay`` later.
        offset = old_offset - old_delay + theirs + delay - own
        if old_delay == delay and abs(offset - old_offset) < DC_THRESHOLD_NS:
            # It kept power and time: leave it alone, since writing 0x0930 would make its loop
            # learn its quartz's speed again (thousands of samples, microseconds off meanwhile).
            return
        yield from _write_until_ok(slave, Reg.DC_SYSTEM_TIME + 0x10,
                                   struct.pack("<qI", offset, delay))
        yield from _write_until_ok(slave, Reg.DC_SPEED_COUNTER_START, struct.pack("<H", 0x1000))

    def dc_wait_job(self, slave: SlavePlan) -> Step[None]:
        """Until the slave's system time difference (0x092C) is under the threshold, at most
        the DC timeout.  The job sends a drift frame every round of its own (the cyclic
        frames may carry none), and trusts 0x092C only after ``DC_SETTLE_SAMPLES`` of them:
        :meth:`dc_rejoin_job` reset the time control loop, whose mean starts again from the
        first samples and would show a slave far off as close.  It also waits until the
        difference no longer grows, as it does while the loop's learned speed is still off."""
        if not self.dc_threshold_ns:
            return
        _, reference = self._dc_slaves()
        deadline = monotonic() + self.dc_timeout_s
        read = Datagram.physical(Cmd.FPRD, slave.phys_addr, Reg.DC_SYSTEM_TIME_DIFFERENCE, 4)
        drift = [_drift_frame(reference)] if reference is not None else []
        last: int | None = None
        samples = 0
        while True:
            back = yield drift + [read]
            if back is not None:
                samples += len(drift)
                if back[-1].wkc == 1:
                    before = last
                    raw, = struct.unpack("<I", back[-1].data)
                    last = raw & 0x7FFF_FFFF
                    # Under the threshold and no longer moving away: a loop whose learned
                    # speed is still wrong shows a difference that grows through it.
                    settled = not drift or (samples >= DC_SETTLE_SAMPLES and before is not None
                                            and last <= before)
                    if last < self.dc_threshold_ns and settled:
                        return
            if monotonic() > deadline:
                raise DcSyncError(f"DC did not converge: system time difference (0x092C) "
                                  f"{last} ns, threshold {self.dc_threshold_ns} ns, after "
                                  f"{self.dc_timeout_s:g} s", slave.name, {slave.name: last})

    def _broadcast_write(self, ado: int, data: bytes) -> None:
        deadline = self.transport.clock.monotonic() + TIMEOUT_COMMAND
        while self.transport.exchange([Datagram.physical(Cmd.BWR, 0, ado, data)]) is None:
            if self.transport.clock.monotonic() > deadline:
                raise ApplyError("no frame came back for the DC receive-time latch")


def check_dc_wait(threshold_ns: int, timeout_s: float) -> None:
    """The convergence wait's settings as a user gives them (0 ns: no wait)."""
    if not 0 <= threshold_ns <= 0x7FFF_FFFF:
        raise ValueError(f"the DC threshold must be 0..{0x7FFF_FFFF} ns (0x092C holds 31 "
                         f"bits), not {threshold_ns}")
    if not timeout_s > 0:
        raise ValueError(f"the DC timeout must be more than 0 s, not {timeout_s}")


def _drift_frame(reference: SlavePlan) -> Datagram:
    """ARMW of the system time: the reference clock reads it, every later slave's time
    control loop compares it with its own (docs/protocol-notes.md §8)."""
    return Datagram.physical(Cmd.ARMW, -reference.position & 0xFFFF, Reg.DC_SYSTEM_TIME, 8)


def _read_receive_times(slave: SlavePlan,
                        out: dict[str, tuple[tuple[int, int, int, int], int]]) -> Job:
    ports = Datagram.physical(Cmd.FPRD, slave.phys_addr, Reg.DC_RECEIVE_TIME_PORT0, 16)
    unit = Datagram.physical(Cmd.FPRD, slave.phys_addr, 0x0918, 8)
    got = yield from until_answered([ports, unit], monotonic() + TIMEOUT_COMMAND,
                                    ApplyError("cannot read the DC receive times", slave.name))
    p0, p1, p2, p3 = struct.unpack("<IIII", got[0].data)
    rx, = struct.unpack("<Q", got[1].data)
    out[slave.name] = ((p0, p1, p2, p3), rx)


def _between(later: int, earlier: int) -> int:
    """Nanoseconds between two 32-bit receive times of one slave."""
    return (later - earlier + (1 << 31)) % (1 << 32) - (1 << 31)


def _read_port_times(slave: SlavePlan, out: dict[str, tuple[int, int, int, int]]) -> Job:
    """The port receive times of a slave the ENI sets no DC for, when its ESC has a DC
    unit (0x0008 bit 2, as SOEM and IgH tell); nothing when not, or without an answer."""
    features = Datagram.physical(Cmd.FPRD, slave.phys_addr, Reg.ESC_FEATURES, 2)
    ports = Datagram.physical(Cmd.FPRD, slave.phys_addr, Reg.DC_RECEIVE_TIME_PORT0, 16)
    for _ in range(3):
        got = yield [features, ports]
        if got is not None and got[0].wkc == 1 and got[1].wkc == 1:
            if struct.unpack("<H", got[0].data)[0] & ESC_FEATURE_DC:
                out[slave.name] = struct.unpack("<IIII", got[1].data)
            return


def propagation_delays(measured: list[SlavePlan], reference: SlavePlan,
                       ports: dict[str, tuple[int, int, int, int]],
                       found: list[FoundSlave] | None) -> dict[str, int]:
    """Each measured slave's propagation delay from the reference clock (ns), from the
    receive times its ports latched (``ports``; ``measured``: the slaves with them, in
    bus order) and, over a tree, where each slave is plugged (``found``, the scan).

    As SOEM does it (``ethercatdc.c`` ``ecx_configdc``; IgH does the same per link,
    ``ec_slave_calc_transmission_delays_rec``): with the nearest measured slave ``a``
    above slave ``s``, the port ``pa`` of ``a`` that leads to it, and ``prev`` the active
    port of ``a`` before ``pa`` in the processing order 0 -> 3 -> 1 -> 2, the frame
    reaches ``s`` after it reaches ``a`` by

        D(s) - D(a) = dt2 + (dt3 - dt1) / 2
        dt2 = t_a(prev) - t_a(0)     the frame's time in a's earlier branches
        dt3 = t_a(pa) - t_a(prev)    the round trip down pa and back
        dt1 = t_s(last) - t_s(0)     s's own subtree, its last active port

    assuming a frame takes as long out as back; the delay is D(s) - D(reference), 0 for
    the slaves before the reference.  On a line (every slave on port 1 of the one
    before) this is half the difference of the loop times port 1 - port 0 of the
    reference and the slave.  A slave with no measured slave above it (a branch below a
    junction without a DC unit) gets that line value too: its branch cannot be measured."""
    def loop(name: str) -> int:                 # port 0 in -> port 1 back
        t = ports[name]
        return _between(t[1], t[0]) if t[1] else 0

    if not measured:
        return {}
    first = measured[0]
    by_position = {s.position: s for s in measured}
    twice: dict[str, int] = {first.name: 0}     # 2 x D, so halves do not add up
    for s in measured[1:]:
        above = _dc_above(s.position, by_position, found)
        if above is None or found is None:
            twice[s.name] = loop(first.name) - loop(s.name)
            continue
        a, pa = above
        active = active_ports(found[a.position].dl_status)
        order = [p for p in CHILD_PORTS if p in active]
        prev = order[order.index(pa) - 1] if pa in order and order.index(pa) else 0
        ta = ports[a.name]
        dt2 = _between(ta[prev], ta[0])
        dt3 = _between(ta[pa], ta[prev])
        own = [p for p in CHILD_PORTS if p in active_ports(found[s.position].dl_status)]
        ts = ports[s.name]
        dt1 = _between(ts[own[-1]], ts[0]) if own else 0
        twice[s.name] = twice[a.name] + 2 * dt2 + dt3 - dt1
    ref = twice.get(reference.name, 0)
    return {s.name: max(0, (twice[s.name] - ref) // 2)
            if s.position > reference.position else 0 for s in measured}


def _dc_above(position: int, dc: dict[int, SlavePlan], found: list[FoundSlave] | None
              ) -> tuple[SlavePlan, int] | None:
    """The nearest DC slave above ``position`` in the tree found, and its port that leads
    down to ``position``; None without one (or without a tree)."""
    if found is None or position >= len(found):
        return None
    child = position
    plug = found[child].plug
    while plug is not None:
        if plug.parent in dc:
            return dc[plug.parent], plug.port
        child = plug.parent
        plug = found[child].plug
    return None


def _slave_state(data: bytes | bytearray) -> SlaveState:
    status, _, code = struct.unpack_from("<HHH", data)
    return SlaveState(status & AL_STATE_MASK, bool(status & AL_STATUS_ERROR), code)


def _read_state(position: int, out: dict[int, SlaveState]) -> Job:
    dg = al_status_read(position)
    for _ in range(UNANSWERED_READS):
        reply = yield [dg]
        if reply is not None and reply[0].wkc == 1:
            out[position] = _slave_state(reply[0].data)
            return


def _await_state(position: int, target: AlState, out: dict[int, SlaveState]) -> Job:
    data = yield from awaited_al_status(al_status_read(position), target, TIMEOUT_STATE)
    if data is not None:
        out[position] = _slave_state(data)


def _write_by_position(position: int, ado: int, data: bytes) -> Job:
    dg = Datagram.physical(Cmd.APWR, -position & 0xFFFF, ado, data)
    for _ in range(5):
        reply = yield [dg]
        if reply is not None and reply[0].wkc == 1:
            return


def _write_until_ok(slave: SlavePlan, ado: int, data: bytes) -> Job:
    dg = Datagram.physical(Cmd.FPWR, slave.phys_addr, ado, data)
    yield from until_answered([dg], monotonic() + TIMEOUT_COMMAND,
                              ApplyError(f"cannot write DC register 0x{ado:04X}", slave.name))
