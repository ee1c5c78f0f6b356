"""``ecatcfg watch``: live process data by variable name, outputs forced by name."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ecatcfg.cli.watch_commands import Commands
    from ecatcfg.cli.watch_input import Keyboard
    from ecatcfg.runtime.watch import Value, Watch


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "watch", help="live process data by variable name, forcing outputs",
        description="Bring the network of an ENI up to OP and show its process data by "
                    "variable name while it cycles: on a terminal a table refreshed in "
                    "place, in a pipe one line per variable that changed (all of them "
                    "first).  --force writes an output variable every cycle.  While it "
                    "runs, commands typed on the terminal (or read from stdin line by "
                    "line in a pipe) force and release outputs: 'force NAME VALUE' (or "
                    "NAME=VALUE, 'f' for short), 'unforce NAME' ('u'; a shell pattern "
                    "releases all it matches), 'quit' ('q'); Tab completes names.",
        epilog="Variable names are the ENI's (ecatcfg show ENI lists them).  Ctrl-C stops "
               "and brings the line back to INIT.  Exit 1 when a slave refuses a state or "
               "the ENI is wrong; 2 for usage errors (an unknown variable, a value out of "
               "range), also when a command read from stdin was refused.")
    p.add_argument("eni", metavar="ENI", help="ENI file (ETG.2100 XML)")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--iface", metavar="IF", help="network interface of the EtherCAT line")
    target.add_argument("--virtual", action="store_true",
                        help="on a virtual segment emulating the ENI's slaves")
    p.add_argument("--esi", action="append", metavar="PATH",
                   help="with --virtual: ESI files or folders the slaves are emulated from")
    p.add_argument("--force", action="append", default=[], metavar="NAME=VALUE",
                   help="write output NAME every cycle (1/0/true/false, integers, 0x hex, "
                        "numbers for REAL); repeatable")
    p.add_argument("--match", action="append", default=[], metavar="PATTERN",
                   help="show only the variables matching this shell pattern (e.g. "
                        "'axis1.*'); repeatable")
    p.add_argument("--interval", type=float, default=0.2, metavar="S",
                   help="seconds between refreshes (default 0.2)")
    p.add_argument("--cycles", type=int, metavar="N",
                   help="run N bus cycles, then stop (default: until Ctrl-C)")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="json: one JSON object per change, {t, name, value, output, forced}")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache and the ENI plan cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import os
    import sys
    import time

    from ecatcfg.cli import EXIT_USAGE
    from ecatcfg.cli.apply import prepare_cycling
    from ecatcfg.cli.watch_commands import Commands
    from ecatcfg.cli.watch_input import Keyboard, Lines, foreground
    from ecatcfg.eni import cache as eni_cache
    from ecatcfg.errors import EcatcfgError, UsageError
    from ecatcfg.runtime.network import Network
    from ecatcfg.runtime.watch import Watch, parse_force

    if args.interval <= 0:
        raise UsageError(f"--interval {args.interval}: must be positive")
    if args.cycles is not None and args.cycles < 1:
        raise UsageError(f"--cycles {args.cycles}: must be 1 or more")
    if args.esi and not args.virtual:
        raise UsageError("--esi goes with --virtual (the devices to emulate)")
    if args.no_cache:
        from ecatcfg.eni import reader as eni_reader
        plan = eni_reader.read_file(args.eni)
    else:
        plan = eni_cache.read_file(args.eni)
    forced: dict[str, Value] = {}
    for text in args.force:
        try:
            name, value = parse_force(plan, text)
        except EcatcfgError as exc:
            raise UsageError(str(exc)) from None
        forced[name] = value

    if args.virtual:
        net = Network.virtual(plan, args.esi, esi_cache=not args.no_cache,
                              eni_name=args.eni)
    else:
        from ecatcfg.runtime.link import RawLink
        net = Network(plan, RawLink(args.iface), eni_name=args.eni)
    live = args.format == "text" and sys.stdout.isatty()
    with net:
        try:
            watch = Watch(net, args.match or None, forced)
        except EcatcfgError as exc:
            raise UsageError(str(exc)) from None
        commands = Commands(watch)
        stdin = _stdin_fd()
        keyboard = live and stdin is not None and os.isatty(stdin) and foreground(stdin)
        if stdin is not None and os.isatty(stdin) and not foreground(stdin):
            # A job in a background process group (under `timeout`, or started with `&`)
            # may not read the terminal: say so instead of ignoring every key.
            print("note: the terminal's keys cannot be read: watch runs in a background "
                  "process group (under timeout, use timeout --foreground); typed "
                  "commands are not seen, --force still works", file=sys.stderr, flush=True)
            stdin = None
        reader: Keyboard | Lines = (Keyboard(stdin, commands) if keyboard and stdin is not None
                                    else Lines(-1 if stdin is None else stdin, commands))
        prepare_cycling(net)
        net.up()
        start = time.monotonic()
        show: _Live | _Lines = (
            _Live(watch, commands, reader if isinstance(reader, Keyboard) else None)
            if live else _Lines(watch, args.format == "json", start))
        if isinstance(reader, Lines):
            reader.after = show.refresh
        due = [0.0, 0.0]                        # next refresh, next look at stdin

        stop = StopOnSignal()

        def each_cycle(_net: Network) -> None:
            if stop.asked:
                net.stop()
                return
            watch.force()
            now = time.monotonic()
            typed = False
            if now >= due[1]:
                due[1] = now + KEY_POLL_S
                typed = reader.poll()
                if reader.quit:
                    net.stop()
            if now >= due[0] or typed:
                due[0] = now + args.interval
                show.refresh()

        try:
            with reader, show, stop:
                net.run(args.cycles, each_cycle)
                show.refresh()
                show.final_status()
        except KeyboardInterrupt:
            pass
    if isinstance(reader, Lines) and reader.refused:
        return EXIT_USAGE
    return 0


class StopOnSignal:
    """SIGINT, SIGTERM and SIGHUP while the watch cycles: the first one only asks the cycle
    loop to end after the cycle under way (``asked``, read by the loop's callback), so the
    slaves are brought down and the terminal put back.  Nothing is raised into the loop:
    an exception at an arbitrary bytecode can land between a lock's acquire and the ``try``
    that releases it, and the way down then waits on that lock for ever (CPython runs
    signal handlers between any two bytecodes, bpo-29988; ``apply`` does the same).  A
    second signal interrupts at once, for a loop that no longer comes round."""

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self) -> None:
        self.asked: str | None = None
        self._saved: dict[int, Any] = {}

    def __enter__(self) -> StopOnSignal:
        import signal
        import threading
        if threading.current_thread() is threading.main_thread():
            for name in self.SIGNALS:
                number = getattr(signal, name)
                self._saved[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        import signal
        for number, handler in self._saved.items():
            signal.signal(number, handler)
        self._saved.clear()

    def _handle(self, number: int, _frame: object) -> None:
        import signal
        name = signal.Signals(number).name
        if self.asked is not None:
            raise KeyboardInterrupt(name)
        self.asked = name


# How often a pipe gets the status line (a terminal has it on screen all the time).
STATUS_EVERY_S = 5.0

# How often stdin is looked at: often enough that typing shows at once, seldom enough that
# a 1 kHz cycle does not make a system call per cycle for it.
KEY_POLL_S = 0.02


def _stdin_fd() -> int | None:
    import sys
    try:
        return sys.stdin.fileno() if sys.stdin is not None else None
    except (OSError, ValueError):       # closed, or replaced by an object without a file
        return None


class _Lines:
    """Plain lines (or JSON lines): each variable whose value, or whether it is forced,
    changed since the last refresh."""

    def __init__(self, watch: Watch, as_json: bool, start: float) -> None:
        self.watch = watch
        self.as_json = as_json
        self.start = start
        self.next_status = start + STATUS_EVERY_S

    def __enter__(self) -> _Lines:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def refresh(self) -> None:
        import json
        import time

        from ecatcfg.cli.watch_commands import value_text

        t = round(time.monotonic() - self.start, 3)
        for name, value in self.watch.changes().items():
            output = name in self.watch.outputs
            forced = name in self.watch.forced
            if self.as_json:
                print(json.dumps({"t": t, "name": name, "value": value, "output": output,
                                  "forced": forced}), flush=True)
            else:
                print(f"{t:9.3f}  {'out' if output else 'in '}  {name} = {value_text(value)}"
                      f"{' (forced)' if forced else ''}", flush=True)
        if time.monotonic() >= self.next_status:
            self.next_status = time.monotonic() + STATUS_EVERY_S
            self.final_status()

    def final_status(self) -> None:
        """The status line (states, working counters, lost frames, jitter, cycles): every
        STATUS_EVERY_S seconds and at the end; in JSON an object ``{"t", "status"}``."""
        import json
        import time

        from ecatcfg.runtime.watch import status, status_text

        t = round(time.monotonic() - self.start, 3)
        now = status(self.watch.net)
        if self.as_json:
            print(json.dumps({"t": t, "status": now}), flush=True)
        else:
            print(f"{t:9.3f}  status: {status_text(now)}", flush=True)


class _Live:
    """A table refreshed in place on the terminal (rich), under the line being typed and a
    status line (what is forced, what the last command did).  They come first: rich crops
    a table taller than the terminal at its bottom."""

    def __init__(self, watch: Watch, commands: Commands, keyboard: Keyboard | None) -> None:
        from rich.live import Live

        self.watch = watch
        self.commands = commands
        self.keyboard = keyboard
        self.live = Live(self._view(), auto_refresh=False)

    def __enter__(self) -> _Live:
        self.live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.live.__exit__(*exc)

    def refresh(self) -> None:
        self.live.update(self._view(), refresh=True)

    def final_status(self) -> None:
        return None             # the live table's status line is already on screen

    def _view(self) -> Any:
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        from ecatcfg.cli.watch_commands import USAGE, value_text
        from ecatcfg.runtime.watch import status, status_text

        table = Table("variable", "dir", "value")
        for name, value in self.watch.values().items():
            direction = "out" if name in self.watch.outputs else "in"
            shown = value_text(value) + (" (forced)" if name in self.watch.forced else "")
            table.add_row(name, direction, shown)
        lines = [Text(status_text(status(self.watch.net)), style="cyan"),
                 Text(self.commands.status())]
        keys = self.keyboard
        if keys is not None:
            last = keys.last
            if keys.candidates:
                lines.append(Text("  ".join(keys.candidates), style="dim"))
            elif last is not None:
                lines.append(Text(("error: " if last.error else "") + last.message,
                                  style="red" if last.error else "green"))
            lines.insert(0, Text(f"> {keys.line}", style="bold")
                         if keys.line else Text(f"> ({USAGE})", style="dim"))
        return Group(*lines, table)
