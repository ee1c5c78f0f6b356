"""``ecatcfg apply``: bring a network up from an ENI (ours, TwinCAT's, EC-Engineer's)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable

    from ecatcfg.cli.report import ApplyReport
    from ecatcfg.eni.derive import Derived
    from ecatcfg.eni.plan import NetworkPlan
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esc import AlState
    from ecatcfg.runtime.master.bringup import Event
    from ecatcfg.runtime.network import Network
    from ecatcfg.runtime.master.realtime import RealtimeOptions
    from ecatcfg.runtime.service import Notifier

STATES = {"init": 1, "preop": 2, "safeop": 4, "op": 8}


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_prefer

    p = sub.add_parser(
        "apply", help="bring a network up from an ENI over raw Ethernet",
        description="Check that the slaves on the line are the ones the ENI describes (no "
                    "configuration write before that), replay its InitCmds transition by "
                    "transition, then run its cyclic frames.  After --cycles N (default: "
                    "until Ctrl-C) the slaves go back to INIT unless --stay.")
    p.add_argument("eni", metavar="ENI", help="ENI file (ETG.2100 XML)")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--iface", metavar="IF", help="network interface of the EtherCAT line")
    target.add_argument("--virtual", action="store_true",
                        help="a virtual segment emulating the ENI's slaves: from their ESI "
                             "files (--esi), else from the ENI alone")
    p.add_argument("--simulated-time", action="store_true",
                   help="with --virtual: run master and slaves on simulated time, the "
                        "slaves taking the time real ones take (the fitted timing model, "
                        "docs/timing.md): as fast as the host can, the same frames on every "
                        "run, and the simulated time each step would take on a real line "
                        "reported; needs --cycles when cycling")
    p.add_argument("--esi", action="append", metavar="PATH",
                   help="ESI file or folder; repeatable.  With --virtual the slaves are "
                        "emulated from them (a slave whose device is not there from the ENI "
                        "alone); on a line and in the virtual case, a refusal's cause is "
                        "compared with the device found by its identity (a DC refusal: its "
                        "DC op modes and minimum cycle time).  Nothing is configured from "
                        "them")
    add_prefer(p)
    p.add_argument("--state", choices=list(STATES), default="op",
                   help="state to bring the slaves to (default: op)")
    p.add_argument("--cycles", type=int, metavar="N",
                   help="run N bus cycles, then stop (default: until Ctrl-C)")
    p.add_argument("--stay", action="store_true",
                   help="leave the slaves in the state reached instead of going to INIT")
    p.add_argument("--accept-newer-revision", action="store_true",
                   help="accept a slave whose revision is newer than the ENI's")
    p.add_argument("--dc-threshold", type=int, default=None, metavar="NS",
                   help="before SAFEOP->OP, drift compensation until every DC slave's system "
                        "time difference (0x092C) is under NS nanoseconds (default 1000; "
                        "0: no wait)")
    p.add_argument("--dc-timeout", type=float, default=None, metavar="S",
                   help="give up the DC wait after S seconds with an error naming the slave "
                        "(default 5)")
    p.add_argument("--pcap", metavar="FILE", help="record every frame as pcapng")
    rt = p.add_argument_group(
        "real-time options for the cycling thread (docs/runtime.md, \"Real-time options\"); "
        "a refused one is an error (exit 1) saying how to grant it")
    rt.add_argument("--rt-priority", type=int, metavar="N",
                    help="cycle under SCHED_FIFO at priority N (1-99); needs root, "
                         "CAP_SYS_NICE or an RLIMIT_RTPRIO of N (ulimit -r, LimitRTPRIO=)")
    rt.add_argument("--lock-memory", action="store_true",
                    help="lock the process's memory (mlockall) so no cycle waits for a page "
                         "fault; needs root, CAP_IPC_LOCK or RLIMIT_MEMLOCK (ulimit -l, "
                         "LimitMEMLOCK=)")
    rt.add_argument("--cpu", metavar="LIST",
                    help="run the cycling thread only on these CPUs, e.g. 1 or 2-3 (best an "
                         "isolated one: isolcpus=)")
    rt.add_argument("--busy-wait", type=int, metavar="US", default=0,
                    help="wake US microseconds before each period boundary and spin to it "
                         "(less wake-up jitter for that much CPU time per cycle; default 0)")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("--skip-unsupported", action="store_true",
                   help="apply an ENI that asks for what apply does not do (AoE or VoE "
                        "InitCmds, SoE requests other than writes, FoE requests other than "
                        "reads, copies outside the process image ...: see docs/runtime.md) "
                        "without those parts, with one warning per slave; by default it is "
                        "refused before anything is sent")
    p.add_argument("--no-cache", action="store_true",
                   help="parse the ENI (and the ESI files of --esi) even if cached "
                        "in $XDG_CACHE_HOME/ecatcfg")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """The run, and with ``--format json`` always one JSON document on stdout: also when
    the ENI is refused or cannot be read, or the command line is wrong (the error then
    goes to stderr as well, with the usual exit code)."""
    from ecatcfg.errors import EcatcfgError
    ctx = _Run()
    try:
        return _run(args, ctx)
    except EcatcfgError as exc:
        if args.format == "json" and not ctx.printed:
            import json

            from ecatcfg.cli.report import refusal_json
            print(json.dumps(refusal_json(args.eni, STATES[args.state], exc, ctx.plan),
                             indent=2), flush=True)
        raise


class _Run:
    """What the JSON of a refused run can say: the plan, once read; whether the run's own
    document was printed."""

    def __init__(self) -> None:
        self.plan: NetworkPlan | None = None
        self.printed = False


def _run(args: argparse.Namespace, ctx: _Run) -> int:
    import json

    from ecatcfg.cli.report import ApplyReport
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.runtime.service import Notifier

    dc_threshold, dc_timeout, realtime = _checked_options(args)
    plan, derived, target = _plan(args, ctx)
    report = ApplyReport(plan, args.eni, json_output=args.format == "json")
    report.derived(derived)
    report.skipped(plan.unsupported)
    report.ignored(plan.ignored)
    notify = Notifier.from_env()

    def on_event(event: Event) -> None:
        notify.watchdog()               # a step that reports progress is alive
        report.event(event)
    net = _network(args, plan, on_event, dc_threshold, dc_timeout)
    report.mark("start", net)
    guard = _SignalGuard(net, report, notify)
    failure: EcatcfgError | None = None
    with guard:                         # also while the summary is printed
        try:
            try:
                try:
                    _up_and_cycle(net, plan, target, args, report, notify, realtime, guard)
                finally:
                    # No bytecode here checks for signals: from this store on, a signal
                    # can no longer interrupt, whatever ends the run.
                    guard.down = True
            except EcatcfgError as exc:
                failure = exc
            except KeyboardInterrupt as exc:   # Ctrl-C, or SIGTERM/SIGHUP (_SignalGuard)
                report.note(f"stopped by {exc.args[0]}" if exc.args else "interrupted")
            if guard.stop_asked:               # a signal while cycling: the loop has ended
                report.note(f"stopped by {guard.stop_asked}")
            down_failure = _down(net, plan, args, report, notify, target)
            failure = failure or down_failure     # the first error is the run's
        finally:
            net.close()
            notify.close()
        report.finish(net, failure, target)
        if args.format == "json":
            print(json.dumps(report.as_json(), indent=2), flush=True)
            ctx.printed = True
    return 1 if failure else 0


def _checked_options(args: argparse.Namespace
                     ) -> tuple[int, float, RealtimeOptions | None]:
    """The options checked before anything is read or sent (exit 2): the DC wait's
    threshold and timeout, the real-time options (tried once and undone), the pcap file."""
    from pathlib import Path

    from ecatcfg.cli.paths import output_file
    from ecatcfg.errors import UsageError
    from ecatcfg.runtime.master.bringup import DC_THRESHOLD_NS, DC_TIMEOUT_S, check_dc_wait

    if not Path(args.eni).exists():
        raise UsageError(f"{args.eni}: no such file")
    if args.prefer and not args.esi:
        raise UsageError("--prefer ranks files of --esi: give them with --esi")
    if args.cycles is not None and args.cycles < 0:
        raise UsageError(f"--cycles {args.cycles}: must be 0 or more")
    if args.simulated_time and not args.virtual:
        raise UsageError("--simulated-time is a mode of the virtual segment: give --virtual")
    if args.simulated_time and args.cycles is None and STATES[args.state] >= 4:   # SAFEOP and OP cycle
        raise UsageError("--simulated-time: give --cycles N (simulated time runs as fast as "
                         "the host can: cycling until Ctrl-C would never pause)")
    if args.simulated_time and (args.rt_priority is not None or args.lock_memory
                                or args.cpu is not None or args.busy_wait):
        raise UsageError("--simulated-time: the real-time options pace a real line's "
                         "cycles; simulated time has no host timing to improve")
    dc_threshold: int = DC_THRESHOLD_NS if args.dc_threshold is None else args.dc_threshold
    dc_timeout: float = DC_TIMEOUT_S if args.dc_timeout is None else args.dc_timeout
    try:
        check_dc_wait(dc_threshold, dc_timeout)
    except ValueError as exc:
        option = "--dc-threshold" if "threshold" in str(exc) else "--dc-timeout"
        raise UsageError(f"{option}: {exc}") from None
    realtime = _realtime_options(args)
    if realtime is not None:
        # Try them once here, undone at once: a refusal is reported before a frame is sent
        # (the cycling thread applies them again for the run).
        from ecatcfg.runtime.master.realtime import apply as apply_realtime
        apply_realtime(realtime)()
    if args.pcap:
        output_file(args.pcap, stdout=False)
    return dc_threshold, dc_timeout, realtime


def _plan(args: argparse.Namespace, ctx: _Run) -> tuple[NetworkPlan, list[Derived], AlState]:
    """The ENI's plan (through the plan cache unless --no-cache), refused if it holds what
    apply does not do (unless --skip-unsupported), completed where it is partial, and
    checked to request every state up to the target, all before a link is opened."""
    from ecatcfg.eni import cache as eni_cache
    from ecatcfg.esc import AlState
    from ecatcfg.runtime.master.bringup import check_requests

    if args.no_cache:
        from ecatcfg.eni import reader as eni_reader
        plan = eni_reader.read_file(args.eni)
    else:
        plan = eni_cache.read_file(args.eni)
    target = AlState(STATES[args.state])
    ctx.plan = plan
    if plan.unsupported and not args.skip_unsupported:
        from ecatcfg.eni.contents import refuse
        refuse(plan, args.eni)              # before a link is opened or a frame sent
    # A partial ENI: the standard set-up of slaves without register InitCmds (the
    # derivation imported only then: tests/test_startup_counts.py).
    derived: list[Derived] = []
    if plan.partial_slaves():
        from ecatcfg.eni.derive import complete
        plan, derived = complete(plan, args.eni)
    check_requests(plan, target, args.eni)
    return plan, derived, target


def _network(args: argparse.Namespace, plan: NetworkPlan, on_event: Callable[[Event], None],
             dc_threshold: int, dc_timeout: float) -> Network:
    """The network on --iface, or on a virtual segment with --virtual."""
    from ecatcfg.runtime.network import Network

    if args.virtual:
        clock = timing = None
        if args.simulated_time:
            from ecatcfg.runtime.clock import SimClock
            from ecatcfg.runtime.segment.timing import Timing
            clock, timing = SimClock(), Timing()
        return Network.virtual(plan, args.esi, esi_prefer=args.prefer, pcap=args.pcap,
                               on_event=on_event, clock=clock, timing=timing,
                               esi_cache=not args.no_cache, skip_unsupported=True,
                               eni_name=args.eni,
                               dc_threshold_ns=dc_threshold, dc_timeout_s=dc_timeout)
    from ecatcfg.runtime.link import RawLink
    return Network(plan, RawLink(args.iface), pcap=args.pcap, on_event=on_event,
                   skip_unsupported=True, eni_name=args.eni, esi=args.esi,
                   esi_prefer=args.prefer, esi_cache=not args.no_cache,
                   dc_threshold_ns=dc_threshold, dc_timeout_s=dc_timeout)


def _up_and_cycle(net: Network, plan: NetworkPlan, target: AlState,
                  args: argparse.Namespace, report: ApplyReport, notify: Notifier,
                  realtime: RealtimeOptions | None, guard: _SignalGuard) -> None:
    """Bring the line up to ``target`` and, in SAFEOP or OP, cycle it (--cycles)."""
    from ecatcfg.esc import AlState

    undo = prepare_cycling(net, realtime) if target >= AlState.SAFEOP and args.cycles != 0 \
        else None
    try:
        _up_and_run(net, plan, target, args, report, notify, realtime, guard)
    finally:
        if undo is not None:
            undo()              # what prepare_cycling did, whether the run cycled or not


def _up_and_run(net: Network, plan: NetworkPlan, target: AlState,
                args: argparse.Namespace, report: ApplyReport, notify: Notifier,
                realtime: RealtimeOptions | None, guard: _SignalGuard) -> None:
    """The start-up, then the cycles of a SAFEOP or OP target."""
    from ecatcfg.esc import AlState

    net.up(target, accept_newer_revision=args.accept_newer_revision)
    report.mark(f"start-up to {target.name}", net)
    # The stop timeout a service manager needs (docs/runtime.md).
    up = len(net.master.slaves)
    status = (f"{up} slaves in {target.name}" + (
        f" ({len(plan.slaves) - up} in hot-connect groups not on the line)"
        if up < len(plan.slaves) else "")
        + (f", {len(plan.passive)} passive" if plan.passive else "")
        + f"; way down at most {net.master.down_bound():.0f} s")
    if target >= AlState.SAFEOP and args.cycles != 0:
        report.cycling(args.cycles)
        notify.ready(status.replace(";", ", cycling;", 1))
        net.run(args.cycles, guard.cycle_callback(report.cycle_callback(net, notify.watchdog)),
                realtime=realtime, read_states=True)
        report.mark(f"{args.cycles} cycles", net)
    else:
        notify.ready(status)


def prepare_cycling(net: Network, realtime: RealtimeOptions | None = None
                    ) -> Callable[[], None]:
    """Do before the slaves are in OP what the first cycles would otherwise wait for: a
    slave whose outputs stop for longer than its SM watchdog (100 ms by default) drops to
    SAFEOP+ERR.  Returns the function that undoes it, for the end of the run.

    - Import the supervisor of slaves that drop out (``runtime/master/recovery.py``), which
      the first cycle imports (a module compiled from source, where no bytecode is
      written, on a busy host: tens of ms).
    - With real-time options, the run freezes the heap before its first cycle
      (``gc.collect()`` and ``gc.freeze()``, ``Network._loop``); a full collection of a
      large heap (an application that imports ecatcfg, the test runner) takes tens to
      hundreds of ms.  Collected and frozen here, the run's own collection only scans what
      is new since; undone: the heap unfrozen (the run does it too, a run that never
      cycled did not).
    - With ``--lock-memory``, the process's memory is locked here (``mlockall`` pins
      every page it has: hundreds of ms for a large process on a busy host), not at the
      run's start between OP and the first cycle; undone: unlocked (the run's own undo
      unlocks it too)."""
    steps: list[Callable[[], object]] = []
    if net.master.recovery:
        import ecatcfg.runtime.master.recovery  # noqa: F401
    if realtime is not None:
        import gc

        from ecatcfg.runtime.master import realtime as rt  # the run's first step
        if realtime.lock_memory:
            steps.append(rt.lock_memory())
        gc.collect()
        gc.freeze()
        steps.append(gc.unfreeze)

    def undo() -> None:
        for step in reversed(steps):
            step()
    return undo


def _down(net: Network, plan: NetworkPlan, args: argparse.Namespace, report: ApplyReport,
          notify: Notifier, target: AlState) -> EcatcfgError | None:
    """Back to INIT unless --stay, and the slaves' final states in the report; the first
    error found here: a slave that left the state the line ran in, or the way down's."""
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esc import AlState

    failure: EcatcfgError | None = None
    highest = net.master.read_states()
    if net.state == target > AlState.INIT:
        # The line reached its target and ran there: a slave that left it while it ran
        # (an SM watchdog run out between two cycles) fails the run, as the transition's
        # own read-back would have.  Judged on the states read right after the last cycle
        # (Network.states_after_run): by now, on a busy host, outputs stopped longer than
        # a watchdog may have taken a slave to SAFEOP+ERR after the cycles, as they
        # should.  (A run stopped on the way up has slaves between states.)
        try:
            net.master.check_kept(net.states_after_run or highest)
        except EcatcfgError as exc:
            failure = exc
    if not args.stay and net.state > AlState.INIT:
        notify.stopping(f"bringing {len(plan.slaves)} slaves down to INIT")
        try:
            net.down()
        except EcatcfgError as exc:
            failure = failure or exc
        report.final_states(net.master.read_states(), net.master.progress,
                            highest=highest, scanned=net.master.scanned,
                            line=net.master.line)
        report.mark("way down", net)
    else:
        notify.stopping("leaving the slaves as they are")
        report.final_states(highest, net.master.progress, highest=highest,
                            scanned=net.master.scanned, line=net.master.line)
        report.mark("states read", net)
    return failure


def _realtime_options(args: argparse.Namespace) -> RealtimeOptions | None:
    """The --rt-priority/--lock-memory/--cpu/--busy-wait options, checked (exit 2 for a
    value out of range); None without any."""
    if args.rt_priority is None and not args.lock_memory and args.cpu is None \
            and not args.busy_wait:
        return None
    from ecatcfg.errors import UsageError
    from ecatcfg.runtime.master import realtime
    try:
        cpus = realtime.parse_cpus(args.cpu) if args.cpu is not None else None
        return realtime.options(args.rt_priority, args.lock_memory, cpus, args.busy_wait)
    except UsageError as exc:
        flag = ("--cpu" if "CPU" in exc.message else "--busy-wait" if "busy" in exc.message
                else "--rt-priority")
        raise UsageError(f"{flag}: {exc.message}") from None


class _SignalGuard:
    """SIGINT, SIGTERM and SIGHUP during ``apply``: the first one stops the run like Ctrl-C
    (a KeyboardInterrupt naming the signal), so the slaves are brought down and the summary
    printed.  Once the way down has begun, a further signal does not abandon the slaves: it
    says how long the way down can still take (Master.down_bound); a third signal in all
    exits at once (exit 1), naming the state each slave was last brought to.

    While the line cycles, the first signal raises nothing: it only asks the cycle loop to
    end after the cycle under way (``stop_asked``, read by the loop's callback).  An
    exception thrown at an arbitrary bytecode can land between a lock's acquire and the
    ``try`` that releases it, in the master or in a virtual segment's queues (CPython runs
    signal handlers between any two bytecodes, bpo-29988), and the way down then waits on
    that lock for ever."""

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self, net: Network, report: ApplyReport, notify: Notifier) -> None:
        self.net = net
        self.report = report
        self.notify = notify
        self.count = 0
        self.down = False               # True once the way down has begun: no interrupt
        self.cycling = False            # in Network.run: ask the loop to end, raise nothing
        self.stop_asked: str | None = None   # the signal that asked it
        self.saved: dict[int, Any] = {}

    def cycle_callback(self, inner: Callable[[Network], None]) -> Callable[[Network], None]:
        """``inner``, run after every cycle, and the end of the run once a signal asked
        for it; the guard counts as cycling for as long as the loop calls it."""
        self.cycling = True

        def callback(net: Network) -> None:
            inner(net)
            if self.stop_asked is not None:
                self.down = True        # from here on no signal interrupts
                net.stop()
        return callback

    def __enter__(self) -> _SignalGuard:
        import signal
        import threading
        if threading.current_thread() is not threading.main_thread():
            return self                 # only the main thread may set signal handlers
        for name in self.SIGNALS:
            number = getattr(signal, name)
            self.saved[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        import signal
        for number, handler in self.saved.items():
            signal.signal(number, handler)

    def _handle(self, number: int, _frame: object) -> None:
        import os
        import signal
        import sys
        name = signal.Signals(number).name
        self.count += 1
        if not self.down:
            if self.cycling:
                if self.stop_asked is None:
                    self.stop_asked = name      # the loop ends after this cycle
                    return
            else:
                self.down = True
                raise KeyboardInterrupt(name)
        master = self.net.master
        if self.count >= 3:
            where = ", ".join(s.name for s in master.slaves)
            print(f"ecatcfg apply: {name} (third signal): exiting at once; the slaves were "
                  f"left on the way down, last brought to {master.state.name}: {where}",
                  file=sys.stderr, flush=True)
            self.notify.send(STATUS=f"abandoned with the slaves in {master.state.name}")
            os._exit(1)
        print(f"ecatcfg apply: {name}: finishing the way down (at most "
              f"{master.down_bound():.0f} s from {master.state.name}); a third signal exits "
              f"at once and leaves the slaves as they are", file=sys.stderr, flush=True)
