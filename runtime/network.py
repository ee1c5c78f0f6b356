"""The application's view of a running network: open an ENI, bring it up, use its variables.

::

    from ecatcfg.runtime import Network

    # Network("line.eni.xml", RawLink("eth1")) on hardware; here a virtual segment:
    with Network.virtual("line.eni.xml", esi=["esi/"]) as net:
        net.up()                                                   # scan, verify, INIT -> OP
        for _ in range(1000):
            net["lamps.Channel 1-8.Output 1"] = True
            net.cycle()                                            # one bus cycle
            print(net["buttons.Channel 1.Input"])

Variables are the ENI's process image names (``<slave>.<pdo>.<entry>``) with their IEC
types: BOOL/BIT as ``bool``, integers as ``int``, REAL/LREAL as ``float``.  ``run()``
cycles at the ENI's cycle time, on the caller's thread or a thread of its own (then it
returns a :class:`BackgroundRun` to join or stop), calling ``callback(network)`` after
every cycle.
"""

from __future__ import annotations

import gc
import struct
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Literal, overload

from ecatcfg.eni.plan import NetworkPlan, Variable
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState
from ecatcfg.record import record
from ecatcfg.runtime.clock import WALL, clock_of
from ecatcfg.runtime.master.bringup import (DC_THRESHOLD_NS, DC_TIMEOUT_S, Event, Master,
                                            check_requests)
from ecatcfg.runtime.master.replay import ApplyError

if TYPE_CHECKING:                   # imported where used: `import ecatcfg.runtime` stays light
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.clock import Clock
    from ecatcfg.runtime.master.cyclic import CycleStats
    from ecatcfg.runtime.segment.dc_clock import DcModel
    from ecatcfg.runtime.link import Link
    from ecatcfg.runtime.pcap import PcapRecorder
    from ecatcfg.runtime.master.realtime import RealtimeOptions
    from ecatcfg.runtime.master.reached import SlaveState
    from ecatcfg.runtime.master.recovery import SlaveHealth
    from ecatcfg.runtime.segment.virtual import Faults, VirtualSegment
    from ecatcfg.runtime.segment.timing import Timing

_FLOATS = {"REAL": "<f", "LREAL": "<d"}
_SIGNED = {"SINT", "INT", "DINT", "LINT", "INT24", "INT40", "INT48", "INT56"}


@record(frozen=True)
class _Var:
    variable: Variable
    output: bool

    @property
    def type(self) -> str:
        return (self.variable.data_type or "").upper()


class Network:
    """An ENI running on a link (see the module docstring)."""

    segment: VirtualSegment     # the emulated slaves, set by Network.virtual only
    # Network.virtual only: the ESI file each emulated slave's device is from (None: the
    # ENI alone), and why, where several files describe its identity differently.
    esi_sources: list[tuple[str | None, str | None]]

    def __init__(self, eni: NetworkPlan | str | Path, link: Link, *,
                 pcap: str | Path | None = None,
                 on_event: Callable[[Event], None] | None = None,
                 skip_unsupported: bool = False, eni_name: str | None = None,
                 dc_threshold_ns: int = DC_THRESHOLD_NS, dc_timeout_s: float = DC_TIMEOUT_S,
                 recovery: bool = True,
                 esi: list[str | Path] | Library | None = None,
                 esi_prefer: list[str | Path] | None = None, esi_cache: bool = True,
                 _closers: Iterable[Callable[[], None]] = ()) -> None:
        """``skip_unsupported``: run an ENI that asks for what this master does not do
        (``eni/contents.py``: AoE and VoE InitCmds, SoE requests other than writes, FoE
        requests other than reads, copies outside the process image ...) without
        those parts, with one warning per slave (an ``Event("skipped", ...)`` to
        ``on_event``, else a :class:`SkippedConfigWarning`); by default such an ENI raises
        :class:`~ecatcfg.eni.contents.UnsupportedEniError` here, before any frame is sent.
        ``eni_name`` names the file in those messages (default: the path given).
        ``dc_threshold_ns``, ``dc_timeout_s``: before SAFEOP->OP, :meth:`up` sends drift
        compensation until every DC slave's system time difference (0x092C) is under the
        threshold (0: no wait), and raises :class:`~ecatcfg.runtime.master.bringup.DcSyncError`
        naming the slave furthest off after the timeout.  ``recovery``: while cycling,
        bring back slaves that drop out (``runtime/master/recovery.py``, :attr:`health`); when
        false, a slave that drops out only makes :meth:`cycle` return ``False``.
        ``esi``, ``esi_prefer``: ESI files or folders (or a :class:`Library`), used only to
        explain refusals: the cause of a DC refusal is compared with the device's DC op
        modes and minimum cycle time (``runtime/master/diagnose.py``), the device found by
        the slave's identity; without them the cause says what the slave holds.
        ``esi_cache``: the ESI files' index through the cache (``Library``'s ``cache``)."""
        try:
            if not isinstance(eni, NetworkPlan):
                from ecatcfg.eni import reader as eni_reader
                eni_name = eni_name or str(eni)
                eni = eni_reader.read_file(eni)
            _check_supported(eni, eni_name, skip_unsupported, on_event)
            _warn_ignored(eni, eni_name, on_event)
            eni = _completed(eni, eni_name, on_event)
            library = _library(esi, esi_prefer, esi_cache)
            if library is not None:
                # Among ESI files that describe an identity differently, a cause is
                # compared with the one the ENI's slaves agree with (eni/evidence.py).
                from ecatcfg.eni.evidence import evidence_by_identity
                by_identity = evidence_by_identity(eni, eni_name or "the ENI")
                library = library.guided(lambda v, p, r: by_identity.get((v, p, r)))
        except BaseException:
            link.close()                    # the Network owns the link from the start
            raise
        self.plan = eni
        self.eni_name = eni_name            # the ENI file, for the lines of refused InitCmds
        self.link = link                    # the Network's from here on: close() closes it
        self.recorder: PcapRecorder | None = None
        if pcap is not None:
            from ecatcfg.runtime.pcap import PcapRecorder
            # A simulated wire's frames are recorded at its simulated times.
            self.recorder = PcapRecorder(pcap, clock_of(link))
        self.master = Master(eni, link, recorder=self.recorder, on_event=on_event,
                             dc_threshold_ns=dc_threshold_ns, dc_timeout_s=dc_timeout_s,
                             recovery=recovery, esi=library)
        self._vars = {v.name: _Var(v, False) for v in eni.process_image.inputs}
        self._vars.update({v.name: _Var(v, True) for v in eni.process_image.outputs})
        # Which slave each variable belongs to: its name starts with the slave's name and a
        # dot (the longest such name, as slave names may contain dots).
        names = sorted((s.name for s in eni.slaves), key=len, reverse=True)
        self._owner = {v: next((n for n in names if v.startswith(n + ".")), None)
                       for v in self._vars}
        self._closers = list(_closers)
        self.run_stats: CycleStats | None = None
        # Each slave's AL state right after the last run(read_states=True) (None: not
        # asked for, the run ended below SAFEOP, or the read failed): see _states_now.
        self.states_after_run: list[SlaveState | None] | None = None
        self._run: BackgroundRun | None = None     # the last run(background=True)
        self._stop = threading.Event()
        self._lock = threading.Lock()

    @classmethod
    def virtual(cls, eni: NetworkPlan | str | Path,
                esi: list[str | Path] | Library | None = None, *,
                faults: Faults | None = None, esi_cache: bool = True,
                esi_prefer: list[str | Path] | None = None,
                pcap: str | Path | None = None,
                on_event: Callable[[Event], None] | None = None,
                skip_unsupported: bool = False, eni_name: str | None = None,
                timing: Timing | None = None, dc: DcModel | None = None,
                dc_threshold_ns: int = DC_THRESHOLD_NS,
                dc_timeout_s: float = DC_TIMEOUT_S, recovery: bool = True,
                clock: Clock | None = None) -> Network:
        """The ENI on a virtual segment that emulates its slaves from the ESI files
        (``esi_cache``: through the ESI index cache), or from a :class:`Library` already
        built (a caller that brings up many ENIs from one library reads its files once).  A slave whose device the files do not
        hold, and every slave without ``esi``, is emulated from the ENI alone
        (``runtime/segment/eni_device.py``); each such slave is an ``Event("emulated", ...)`` to
        ``on_event`` and has ``eni_only`` set in ``net.segment.slaves``.
        ``skip_unsupported``, ``eni_name``, the DC wait and ``recovery`` as for the
        constructor.
        ``timing``: slaves that take the time real ones do (``runtime/segment/timing.py``, e.g.
        ``Timing()`` for the table); instantaneous slaves by default.  ``dc``: the emulated
        clocks and line timing (``runtime/segment/dc_clock.py``; seeded ±100 ppm drift by
        default).  ``esi_prefer``: the ESI files or folders whose description wins where
        several describe one device differently (``Library``'s ``prefer``); without it the
        description that agrees with the ENI's slave is taken, said in an
        ``Event("esi", ...)``, and where none or several agree the device is an error
        naming the files and what differs.
        ``clock``: a :class:`~ecatcfg.runtime.clock.SimClock` runs master and segment on
        simulated time, in the caller's thread (``runtime/simwire.py``): the same calls
        give the same frames at the same times, whatever the host does, and waiting costs
        no host time (:attr:`clock` says how long things took).  By default the segment
        lives on the wall clock and answers each frame in the thread that sends it, at
        once (``SynchronousLink``): the master's pacing alone reads real time, and a frame
        is lost only when ``faults`` drop it."""
        from ecatcfg.eni import reader as eni_reader
        from ecatcfg.runtime.clock import SimClock
        from ecatcfg.runtime.segment import emulate

        shown = eni_name or (str(eni) if not isinstance(eni, NetworkPlan) else "the ENI")
        plan = eni if isinstance(eni, NetworkPlan) else eni_reader.read_file(eni)
        if not skip_unsupported:            # refuse before building the segment
            _check_supported(plan, eni_name or (None if isinstance(eni, NetworkPlan)
                                                else str(eni)), False, None)
        # The slaves of a partial ENI are emulated as configured by its derived set-up.
        plan = _completed(plan, eni_name or (None if isinstance(eni, NetworkPlan)
                                             else str(eni)), on_event)
        library = _library(esi, esi_prefer, esi_cache)
        specs = emulate.specs_from_eni(plan, library, shown)
        segment = emulate.segment(specs, faults, timing, dc=dc,
                                  clock_ns=clock.monotonic_ns if clock is not None else None)
        if on_event is not None:
            for spec, slave in zip(specs, segment.slaves):
                if spec.esi_choice is not None:
                    on_event(Event("esi", f"slave {slave.name!r} (position {slave.position})"
                                          f": {spec.esi_choice}"))
            for slave in segment.slaves:
                if slave.eni_only is not None:
                    on_event(Event("emulated", f"slave {slave.name!r} (position "
                                               f"{slave.position}): emulated from the ENI "
                                               f"alone ({slave.eni_only})"))
        closers: list[Callable[[], None]] = []
        link: Link
        if isinstance(clock, SimClock):
            from ecatcfg.runtime.simwire import SimulatedLink
            link = SimulatedLink(clock, segment)
        else:
            # The slaves answer in the master's thread, on the wall clock: a segment served
            # on a thread of its own answers when the host schedules it, and a busy host
            # made the master count frames lost that no wire lost (runtime/simwire.py).
            from ecatcfg.runtime.simwire import SynchronousLink
            link = SynchronousLink(segment) if clock is None else SynchronousLink(segment,
                                                                                  clock=clock)

        net = cls(plan, link, pcap=pcap, on_event=on_event, skip_unsupported=skip_unsupported,
                  eni_name=eni_name or (None if isinstance(eni, NetworkPlan) else str(eni)),
                  dc_threshold_ns=dc_threshold_ns, dc_timeout_s=dc_timeout_s,
                  recovery=recovery, esi=library, _closers=closers)
        net.segment = segment
        net.esi_sources = [(None if spec.eni_only is not None else
                            f"{spec.device.source.file}:{spec.device.source.line}",
                            spec.esi_choice) for spec in specs]
        return net

    # -- state ------------------------------------------------------------------------------

    @property
    def clock(self) -> Clock:
        """The time the master runs on: the wall clock on a real line, the
        :class:`~ecatcfg.runtime.clock.SimClock` of a simulated one."""
        return self.master.transport.clock

    @property
    def state(self) -> AlState:
        return self.master.state

    def up(self, state: AlState = AlState.OP, *, accept_newer_revision: bool = False) -> None:
        """Scan and verify the line, then bring it to ``state`` (default OP).  An ENI that
        has no command requesting a state on the way is refused before anything is sent
        (:class:`~ecatcfg.runtime.master.bringup.IncompleteEniError`); a slave not read back in a
        transition's target state is a :class:`~ecatcfg.runtime.master.bringup.NotReachedError`
        (``runtime/master/reached.py``); an InitCmd a slave refuses is an :class:`ApplyError`
        naming the ENI file and the command's line."""
        check_requests(self.plan, state, self.eni_name)
        try:
            self.master.scan_and_verify(accept_newer_revision)
            self.master.bring_up(state)
        except ApplyError as exc:
            self._locate(exc)
            self._explain(exc)
            raise

    def down(self, state: AlState = AlState.INIT) -> None:
        self.stop()
        try:
            self.master.bring_down(state)
        except ApplyError as exc:
            self._locate(exc)
            raise

    def _explain(self, exc: ApplyError) -> None:
        """Read from the slaves why they refused (``runtime/master/diagnose.py``) and add
        the cause to the error: a slave whose identity is not the ENI's, a slave that
        refused a state with an AL status code."""
        from ecatcfg.runtime.master.bringup import NotReachedError, VerifyError
        from ecatcfg.runtime.master.diagnose import (Context, bus_cycle, explain,
                                                     identity_cause)
        master = self.master
        transport = master.transport
        if isinstance(exc, VerifyError):
            from ecatcfg.runtime.master.scan import paired
            scanned = master.scanned or []
            pairs = paired(master.line, scanned)
            for m in exc.mismatches:
                at = pairs.get(m.position)
                if not m.problem.startswith(("other device", "other revision")) or at is None:
                    continue
                found = scanned[at]
                lines = identity_cause(m, found.identity)
                name = next((s.name for s in master.line.slaves if s.position == m.position),
                            None)
                exc.add_cause(name, {"position": found.position, "al_status_code": None,
                                     "cause": lines, "vendor_id": found.vendor_id,
                                     "product_code": found.product_code,
                                     "revision": found.revision}, "; ".join(lines))
            return
        if isinstance(exc, NotReachedError):
            states = master.read_states()
            refused = [(s, st.code) for s, st in zip(master.slaves, states)
                       if st is not None and st.error]
        elif exc.al_code and exc.slave is not None:
            refused = [(s, exc.al_code) for s in master.slaves if s.name == exc.slave]
        elif exc.al_code in (0, None) and exc.slave is not None:
            # A refusal whose code the ENI's state check did not read (None: it reads
            # 0x0130 alone) or read as 0 (a broadcast whose answer is another slave's):
            # the codes are read now, as for slaves that did not reach their state.
            states = master.read_states()
            refused = [(s, st.code) for s, st in zip(master.slaves, states)
                       if st is not None and st.error and st.code]
        else:
            return
        for slave, code in refused:
            context = Context(slave=slave, channel=master.mailboxes.get(slave.name),
                              bus_cycle_ns=bus_cycle(self.plan), esi=master.esi)
            try:
                cause = explain(transport, slave.position, code, context=context)
            except ApplyError as failed:        # the line itself stopped answering
                exc.add_cause(slave.name, {"position": slave.position,
                                           "al_status_code": code,
                                           "cause": [f"not read: {failed.message}"]},
                              f"not read: {failed.message}")
                continue
            exc.add_cause(slave.name, cause.as_json(), cause.text())

    def _locate(self, exc: ApplyError) -> None:
        """Name the file and line of the InitCmd that failed (``eni/source.py``)."""
        if exc.init_cmd is None or exc.file is not None or self.eni_name is None:
            return
        from ecatcfg.eni.source import init_cmd_line
        exc.file = self.eni_name
        exc.line = init_cmd_line(self.eni_name, self.plan, exc.init_cmd)

    # -- process data -----------------------------------------------------------------------

    @property
    def variables(self) -> list[str]:
        return list(self._vars)

    def cycle(self) -> bool:
        """One bus cycle; ``True`` if every working counter was as the ENI expects."""
        with self._lock:
            return self.master.cycle()

    # -- slaves that drop out ----------------------------------------------------------------

    @property
    def health(self) -> dict[str, SlaveHealth]:
        """Each slave's health while the network cycles in SAFEOP or OP (``online``, why
        not, attempts to bring it back: ``runtime/master/recovery.py``); every slave online
        before that.  Changes are also events (``offline``, ``online``, ``retry``,
        ``refused``) to ``on_event``."""
        supervisor = self.master.supervisor
        if supervisor is not None:
            return dict(supervisor.health)
        from ecatcfg.runtime.master.recovery import SlaveHealth
        present = {s.name: s.position for s in self.master.slaves}
        return {s.name: SlaveHealth(s.name, present.get(s.name, s.position),
                                    online=s.name in present,
                                    reason="" if s.name in present else "not on the line")
                for s in self.plan.slaves}

    def online(self, slave: str) -> bool:
        """Whether ``slave`` (its ENI name) is in the network's state and exchanging data."""
        try:
            return self.health[slave].online
        except KeyError:
            if any(p.name == slave for p in self.plan.passive):
                raise EcatcfgError(f"slave {slave!r} is a passive slave (no ESC): it is "
                                   "never on the wire") from None
            raise EcatcfgError(f"no slave {slave!r} in the ENI") from None

    def valid(self, name: str) -> bool:
        """Whether the process variable ``name`` holds what its slave sent this cycle: an
        input of a slave that is offline is cleared to 0 and not valid."""
        var = self._var(name)
        slave = self._owner.get(name)
        return var.output or slave is None or self.online(slave)

    def recover(self, slave: str) -> None:
        """Try again to bring back a slave the network gave up on (after
        ``recovery.MAX_ATTEMPTS`` failed attempts)."""
        self.online(slave)                      # names the slave if it does not exist
        if self.master.supervisor is not None:
            self.master.supervisor.recover(slave)

    def __getitem__(self, name: str) -> bool | int | float:
        var = self._var(name)
        image = self.master.cyclic.outputs if var.output else self.master.cyclic.inputs
        return _decode(image, var)

    def __setitem__(self, name: str, value: bool | int | float) -> None:
        var = self._var(name)
        if not var.output:
            raise EcatcfgError(f"{name!r} is an input; only outputs can be set")
        with self._lock:
            _encode(self.master.cyclic.outputs, var, value)

    def _var(self, name: str) -> _Var:
        try:
            return self._vars[name]
        except KeyError:
            import difflib
            close = difflib.get_close_matches(name, self._vars, 3)
            raise EcatcfgError(f"no process variable {name!r}" + (
                f"; did you mean {', '.join(map(repr, close))}?" if close else "")) from None

    @overload
    def run(self, cycles: int | None = None,
            callback: Callable[[Network], None] | None = None, *,
            background: Literal[False] = False,
            realtime: RealtimeOptions | None = None, read_states: bool = False) -> None: ...

    @overload
    def run(self, cycles: int | None = None,
            callback: Callable[[Network], None] | None = None, *,
            background: Literal[True], realtime: RealtimeOptions | None = None,
            read_states: bool = False) -> BackgroundRun: ...

    def run(self, cycles: int | None = None, callback: Callable[[Network], None] | None = None,
            *, background: bool = False, realtime: RealtimeOptions | None = None,
            read_states: bool = False) -> BackgroundRun | None:
        """Cycle at the ENI's cycle time (``cycles`` times, or until :meth:`stop`), calling
        ``callback(network)`` after every cycle (on the cycling thread; what it returns is
        not used; an exception it raises ends the run).  ``background``: cycle on a thread
        of its own and return a :class:`BackgroundRun` at once (``join``, ``stop``,
        ``done``, ``error``); otherwise return when the run ends.  ``realtime``: the
        options of ``runtime/master/realtime.py`` (SCHED_FIFO, mlockall, CPU affinity,
        busy-wait), applied to the cycling thread for the run and undone after it; a
        refusal raises :class:`~ecatcfg.runtime.master.realtime.RealtimeError` here, before the
        first cycle.  ``read_states``: read every slave's AL state right after the last
        cycle, on the cycling thread, into :attr:`states_after_run` (one frame more)."""
        if self._run is not None and not self._run.done:
            raise EcatcfgError("the network is already cycling on its own thread: "
                               "stop() or join() that run first")
        self._stop.clear()
        if not background:
            self._loop(cycles, callback, realtime, read_states=read_states)
            return None
        started = threading.Event()
        refused: list[BaseException] = []
        run = BackgroundRun(self._stop)

        def cycling() -> None:
            try:
                self._loop(cycles, callback, realtime, started, refused, read_states)
            except BaseException as exc:        # the application's to see: join(), error
                run._error = exc

        run._thread = threading.Thread(target=cycling, daemon=True, name="ecat-cycle")
        run._thread.start()
        started.wait()
        if refused:
            run._thread.join()
            raise refused[0]
        self._run = run
        return run

    def reset_stats(self) -> CycleStats:
        """Count cycles from here on in :attr:`run_stats` (apart from the cycles run while
        the slaves change state); :meth:`run` does this itself."""
        from ecatcfg.runtime.master.cyclic import CycleStats
        self.run_stats = self.master.cyclic.stats = CycleStats()
        self.master.cyclic.restart_periods()
        return self.run_stats

    def _loop(self, cycles: int | None, callback: Callable[[Network], None] | None,
              realtime: RealtimeOptions | None = None, started: threading.Event | None = None,
              refused: list[BaseException] | None = None, read_states: bool = False) -> None:
        from ecatcfg.runtime.master.cyclic import CycleStats
        restore: Callable[[], None] | None = None
        try:
            if realtime is not None:
                from ecatcfg.runtime.master import realtime as rt
                restore = rt.apply(realtime)
        except BaseException as exc:
            if refused is None:
                raise
            refused.append(exc)
            return
        finally:
            if started is not None:
                started.set()
        frozen = realtime is not None
        if frozen:
            # Everything allocated so far goes to the permanent generation: a collection
            # the callback's garbage triggers then scans only what is new (docs/runtime.md).
            gc.collect()
            gc.freeze()
        try:
            self.reset_stats()          # the statistics of this run
            period = self.master.cyclic.cycle_time_us / 1e6
            margin = realtime.busy_wait_us / 1e6 if realtime is not None else 0.0
            timer = self.master.transport.clock
            clock, sleep = timer.monotonic, timer.sleep
            if timer is not WALL:
                margin = 0.0            # nothing to gain from spinning on simulated time
            next_at = clock()
            done = 0
            while not self._stop.is_set() and (cycles is None or done < cycles):
                self.cycle()
                done += 1
                if callback is not None:
                    callback(self)
                next_at += period
                now = clock()
                if now >= next_at:
                    next_at = now               # late: do not try to catch up
                    self.master.cyclic.stats.late += 1
                    continue
                # An absolute deadline: sleep to it, or to ``margin`` before it and spin on
                # the clock to it, so neither the cycle's time nor a late wake-up adds up.
                if next_at - now > margin:
                    sleep(next_at - now - margin)
                if margin:
                    # sleep(0) lets go of the GIL on every turn: another thread of the
                    # process (a virtual segment, the application's) wanting it would
                    # otherwise wait out the 5 ms switch interval, and the cycle after it.
                    while clock() < next_at:
                        sleep(0)
        finally:
            self.states_after_run = self._states_now() if read_states else None
            if frozen:
                gc.unfreeze()
            if restore is not None:
                restore()
            self.master.cyclic.stats = CycleStats()

    def _states_now(self) -> list[SlaveState | None] | None:
        """The slaves' AL states read right after a run's last cycle, in the cycling thread
        with the run's real-time settings still in force: whether a slave left the state
        while the line ran (cli/apply, ``Master.check_kept``) must not depend on how long
        the host takes to get back to the caller, since outputs that stop for longer than
        a slave's SM watchdog (100 ms by default) take it to SAFEOP+ERR, as they should
        once the cycles have ended.  None below SAFEOP, or when the read fails (the run's
        own error, if any, is the one raised)."""
        if self.master.state < AlState.SAFEOP:
            return None
        try:
            return self.master.read_states()
        except (EcatcfgError, OSError):
            return None

    def stop(self) -> None:
        """End :meth:`run` after the cycle under way; a run on its own thread is waited
        for (its error stays in its :class:`BackgroundRun`)."""
        self._stop.set()
        if self._run is not None:
            self._run.stop()

    def close(self) -> None:
        """Stop cycling, finish the pcap and close the link (a raw socket is released)."""
        self.stop()
        closers, self._closers = self._closers, []
        try:
            if self.recorder is not None:
                self.recorder.close()
            for close in closers:
                close()
        finally:
            self.link.close()

    def __enter__(self) -> Network:
        return self

    def __exit__(self, *exc: object) -> None:
        """Leaving the block stops a run on its own thread (after the cycle under way),
        brings the line back to INIT, also after an error (whose exception then wins over
        one from the way down), and raises the error of a run on its own thread that
        failed and was not joined: a failed run is never lost silently."""
        try:
            failed = None
            if self._run is not None:
                self._run.stop()        # no cycle of it between the way down's frames
                failed = self._run.unreported()
            if self.master.state > AlState.INIT:
                try:
                    self.down()
                except EcatcfgError:
                    if exc[0] is None and failed is None:
                        raise
            if failed is not None and exc[0] is None:
                raise failed
        finally:
            self.close()


class BackgroundRun:
    """A :meth:`Network.run` on a thread of its own (``background=True``).

    ``done``: the run has ended (its cycles run, stopped, or failed); ``error``: the
    exception that ended it, else ``None``; ``join(timeout)`` waits for the end and
    re-raises that exception; ``stop()`` ends the run after the cycle under way and waits
    for it.  Leaving the Network's ``with`` block stops it too."""

    def __init__(self, stop_event: threading.Event) -> None:
        self._stop_event = stop_event
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._reported = False

    @property
    def done(self) -> bool:
        return self._thread is None or not self._thread.is_alive()

    @property
    def error(self) -> BaseException | None:
        """The exception that ended the run (the callback's, a link's ...), else None."""
        return self._error if self.done else None

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the run to end (at most ``timeout`` s); ``True`` when it has.  An error
        that ended it is raised here."""
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        if self.done and self._error is not None:
            self._reported = True
            raise self._error
        return self.done

    def stop(self) -> None:
        """End the run after the cycle under way and wait for it (from the callback, on
        the cycling thread itself: only ask it to end)."""
        self._stop_event.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()

    def unreported(self) -> BaseException | None:
        """The error of an ended run that no join() has raised yet."""
        return None if self._reported or not self.done else self._error

    def __repr__(self) -> str:
        what = ("failed: " + repr(self._error) if self.done and self._error is not None
                else "done" if self.done else "cycling")
        return f"<BackgroundRun {what}>"


class SkippedConfigWarning(UserWarning):
    """Parts of an ENI a Network runs without (``skip_unsupported=True``)."""


def _completed(plan: NetworkPlan, name: str | None,
               on_event: Callable[[Event], None] | None) -> NetworkPlan:
    """``plan`` with the standard set-up of the slaves a partial ENI gives no register
    InitCmds (``eni/derive.py``), each one said as an ``Event("derived", ...)``; raises
    :class:`~ecatcfg.eni.derive.DeriveError` when it cannot be derived.  The derivation
    is imported only for a partial ENI."""
    if not plan.partial_slaves():
        return plan
    from ecatcfg.eni.derive import complete
    done, derived = complete(plan, name)
    if on_event is not None:
        for d in derived:
            on_event(Event("derived", f"slave {d.slave!r}: {d.text}" if d.slave else
                           f"master: no InitCmds in the ENI: {d.text}", d.slave or None))
    return done


def _library(esi: list[str | Path] | Library | None, prefer: list[str | Path] | None,
             cache: bool = True) -> Library | None:
    """The ESI library of ``esi`` (files or folders, or a library already built).  Imported
    only when files are given: the library (lxml, the ESI reader and model) explains
    refusals, and a start-up that goes well never needs it (tests/test_startup_counts.py)."""
    if not isinstance(esi, (list, tuple)):
        return esi                          # None, or a library already built
    if not esi:
        return None
    from ecatcfg.esi.library import Library
    return Library([str(p) for p in esi], cache=cache, prefer=list(prefer or []))


class IgnoredMetadataWarning(UserWarning):
    """Unknown metadata of an ENI (a name, a tool's data: ``esi/vocabulary.py``) that the
    reader left out; it cannot change what is sent."""


def _warn_ignored(plan: NetworkPlan, name: str | None,
                  on_event: Callable[[Event], None] | None) -> None:
    """A warning per piece of ignored metadata: an ``Event("ignored", ...)`` to
    ``on_event``, else an :class:`IgnoredMetadataWarning`."""
    if not plan.ignored:
        return
    from ecatcfg.eni import contents
    for text in contents.ignored_warnings(plan, name):
        if on_event is not None:
            on_event(Event("ignored", f"warning: {text}"))
        else:
            import warnings
            warnings.warn(text, IgnoredMetadataWarning, stacklevel=3)


def _check_supported(plan: NetworkPlan, name: str | None, skip: bool,
                     on_event: Callable[[Event], None] | None) -> None:
    """Refuse a plan with unsupported parts, or warn once per slave about skipping them."""
    if not plan.unsupported:
        return
    from ecatcfg.eni import contents
    if not skip:
        contents.refuse(plan, name)
    for text in contents.skip_warnings(plan, name):
        if on_event is not None:
            on_event(Event("skipped", f"warning: {text}"))
        else:
            import warnings
            warnings.warn(text, SkippedConfigWarning, stacklevel=3)


def _bits(var: _Var) -> tuple[int, int]:
    return var.variable.bit_offs, var.variable.bit_size


def _decode(image: bytearray, var: _Var) -> bool | int | float:
    offs, size = _bits(var)
    first, last = offs // 8, (offs + size - 1) // 8
    raw = int.from_bytes(image[first:last + 1], "little") >> offs % 8 & ((1 << size) - 1)
    kind = var.type
    if size == 1 and kind in ("BOOL", "BIT", ""):
        return bool(raw)
    if kind in _FLOATS:
        value: float = struct.unpack(_FLOATS[kind], raw.to_bytes(size // 8, "little"))[0]
        return value
    if kind in _SIGNED and raw >> size - 1:
        return raw - (1 << size)
    return raw


def _encode(image: bytearray, var: _Var, value: bool | int | float) -> None:
    offs, size = _bits(var)
    kind = var.type
    if kind in _FLOATS:
        raw = int.from_bytes(struct.pack(_FLOATS[kind], float(value)), "little")
    else:
        number = int(value)
        lo = -(1 << size - 1) if kind in _SIGNED else 0
        hi = (1 << size - 1) - 1 if kind in _SIGNED else (1 << size) - 1
        if not lo <= number <= hi:
            raise EcatcfgError(f"{var.variable.name!r}: {value} is outside {kind or 'the'} "
                               f"range {lo}..{hi}")
        raw = number & ((1 << size) - 1)
    first, last = offs // 8, (offs + size - 1) // 8
    chunk = int.from_bytes(image[first:last + 1], "little")
    mask = ((1 << size) - 1) << offs % 8
    chunk = chunk & ~mask | raw << offs % 8
    image[first:last + 1] = chunk.to_bytes(last - first + 1, "little")
