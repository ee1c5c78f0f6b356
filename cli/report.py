"""What ``ecatcfg apply`` (and ``demo``) show: progress per transition, a final table per
slave, cycle statistics; or one JSON document for scripts.

Drawn with rich on a terminal; rich falls back to plain text when the output is a pipe.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import IO, TYPE_CHECKING, Any

from ecatcfg.eni.plan import NetworkPlan, SlavePlan, Unsupported
from ecatcfg.esc import AlState, al_status_name

from ecatcfg.errors import EcatcfgError

if TYPE_CHECKING:                   # rich and the runtime are imported where they are used
    from rich.console import Console

    from ecatcfg.eni.derive import Derived

    from ecatcfg.runtime.master.bringup import Event
    from ecatcfg.runtime.master.reached import SlaveState
    from ecatcfg.runtime.network import Network
    from ecatcfg.runtime.master.replay import SlaveProgress
    from ecatcfg.runtime.master.scan import FoundSlave

_LOG_WIDTH = 1000          # columns for a pipe or a file: wide enough that nothing wraps
_TRANSITION_TEXT = {"II": "INIT -> INIT", "IP": "INIT -> PREOP", "PS": "PREOP -> SAFEOP",
                    "SO": "SAFEOP -> OP", "OS": "OP -> SAFEOP", "SP": "SAFEOP -> PREOP",
                    "PI": "PREOP -> INIT"}


class _PlainConsole:
    """The part of rich's Console the JSON mode uses."""

    def __init__(self, file: IO[str]) -> None:
        self.file = file

    def print(self, text: str, **_: object) -> None:
        print(text, file=self.file, flush=True)


def slave_count(plan: NetworkPlan) -> str:
    """"5 slaves" or, with passive terminals, "7 slaves: 5 with an ESC, 2 passive"."""
    active, passive = len(plan.slaves), len(plan.passive)
    if not passive:
        return f"{active} slave{'s' if active != 1 else ''}"
    return (f"{active + passive} slaves: {active} with an ESC, {passive} passive (no ESC, "
            "not on the wire)")


class ApplyReport:
    def __init__(self, plan: NetworkPlan, eni: str, json_output: bool = False) -> None:
        self.plan = plan
        self.eni = eni
        self.json_output = json_output
        self.console: _PlainConsole | Console
        if json_output:
            # Progress goes to stderr, so stdout stays one document; no rich (18 ms import).
            self.console = _PlainConsole(sys.stderr)
        else:
            from rich.console import Console
            self.console = Console(highlight=False)
            if not self.console.is_terminal:
                # A pipe or a file (a service's journal): rich would wrap at 80 columns and
                # split table rows and the statistics line; a log keeps each line whole.
                self.console = Console(highlight=False, width=_LOG_WIDTH, soft_wrap=True)
        self.events: list[str] = []
        self.rows: list[dict[str, Any]] = []
        self.summary: dict[str, Any] = {}
        self.skipped_parts: list[dict[str, Any]] = []
        self.ignored_parts: list[dict[str, Any]] = []
        self.derived_parts: list[dict[str, Any]] = []
        # On simulated time (apply --virtual --simulated-time): (what ended, its ns).
        self.marks: list[tuple[str, int]] = []
        self._host_start = 0.0

    def mark(self, what: str, net: Network) -> None:
        """On simulated time: the simulated instant ``what`` ended at (``"start"`` first),
        for the timings the run would take on a real line; nothing on the wall clock."""
        from ecatcfg.runtime.clock import SimClock
        clock = net.clock
        if isinstance(clock, SimClock):
            if not self.marks:
                import time
                self._host_start = time.perf_counter()
            self.marks.append((what, clock.ns))

    def simulated_time(self) -> dict[str, float] | None:
        """ms of simulated time each part of the run took, ``total``, and the host's
        seconds for all of it; None on the wall clock."""
        if len(self.marks) < 2:
            return None
        import time
        out = {what: round((t - before) / 1e6, 3)
               for (_, before), (what, t) in zip(self.marks, self.marks[1:])}
        out["total"] = round((self.marks[-1][1] - self.marks[0][1]) / 1e6, 3)
        out["host_s"] = round(time.perf_counter() - self._host_start, 3)
        return out

    def derived(self, derived: list[Derived]) -> None:
        """The set-up derived for a partial ENI (``eni/derive.py``): a line each, and the
        JSON's ``derived``."""
        self.derived_parts = [{"slave": d.slave or None, "what": d.text} for d in derived]
        for d in derived:
            self.note(f"slave {d.slave!r}: {d.text}" if d.slave else
                      f"master: no InitCmds in the ENI: {d.text}")

    def skipped(self, parts: list[Unsupported]) -> None:
        """The parts of the ENI run without (``--skip-unsupported``), for the JSON."""
        self.skipped_parts = [{"slave": p.slave, "element": p.element, "what": p.what,
                               "line": p.line, "commands": p.commands} for p in parts]

    def ignored(self, parts: list[Unsupported]) -> None:
        """Unknown metadata the reader left out (``NetworkPlan.ignored``), for the JSON;
        the Network warns of each (an ``ignored`` event, printed on stderr)."""
        self.ignored_parts = [{"slave": p.slave, "element": p.element, "what": p.what,
                               "line": p.line} for p in parts]

    def event(self, event: Event) -> None:
        if event.kind in ("skipped", "ignored"):    # a warning: stderr, whatever the format
            self.events.append(event.text)
            print(event.text, file=sys.stderr, flush=True)
            return
        text = event.text
        if event.kind == "transition":      # other events may name slaves like "SO"
            for code, words in _TRANSITION_TEXT.items():
                text = text.replace(f"{code}: {code} ...", f"{words} ...").replace(
                    f"{code}: ", f"{words}: ")
        self.events.append(text)
        self.console.print(text)

    def note(self, text: str) -> None:
        self.events.append(text)
        self.console.print(text)

    def cycling(self, cycles: int | None) -> None:
        self.note(f"cycling ({cycles} cycles)" if cycles else "cycling until Ctrl-C")

    def cycle_callback(self, net: Network,
                       each: Callable[[], None] | None = None) -> Callable[[Network], None]:
        """Called after every bus cycle: ``each`` (the service watchdog's ping)."""
        if each is None:
            return lambda _net: None
        ping = each
        return lambda _net: ping()

    def final_states(self, states: list[SlaveState | None],
                     progress: dict[str, SlaveProgress], *,
                     highest: list[SlaveState | None] | None = None,
                     scanned: list[FoundSlave] | None = None,
                     line: NetworkPlan | None = None) -> None:
        """``states``: the state now (after the way down) of the slave at each auto-increment
        position; ``highest``: read before the way down.  ``scanned``: what the scan found.
        ``line``: the ENI as the line was run (``Master.line``: without the hot-connect
        groups that were not there, the slaves behind them moved up); the ENI by default.
        When the line does not match it (a moved slave, a pulled cable), position N is
        not the ENI's slave N: a slave gets the state of the slave found where the ENI has
        it (paired as verify pairs them) only if it passed verification; "not found" for a
        missing slave, "not verified" for one that differs from the ENI, "absent
        (hot-connect group)" for a slave of a group that was not there."""
        from ecatcfg.runtime.master.scan import paired, verify
        self.rows = []
        line = line or self.plan
        slaves = sorted(self.plan.slaves, key=lambda s: s.position)
        where_on_line = {s.name: s.position for s in line.slaves}
        highest = states if highest is None else highest
        at: dict[int, int] = {p: p for p in where_on_line.values()}
        problems: dict[int, str] = {}
        if scanned is not None:
            mismatches = verify(line, scanned, accept_newer_revision=True)
            if mismatches:
                problems = {m.position: ("not found" if m.problem.startswith("missing")
                                         else "not verified")
                            for m in mismatches if m.expected != "-"}
                at = paired(line, scanned)
        for slave in slaves:
            pos = where_on_line.get(slave.name)
            where = "absent (hot-connect group)" if pos is None else problems.get(pos)
            k = at.get(pos) if pos is not None else None
            if k is None and where is None:
                where = "not found"
            st = states[k] if where is None and k is not None and k < len(states) else None
            top = highest[k] if where is None and k is not None and k < len(highest) else None
            # The AL status code read before the way down: why a slave refused a state
            # (the way down acknowledges the error).
            code = top.code if top and top.code else st.code if st else None
            row = {"position": slave.position, "name": slave.name, "passive": False,
                   "address": slave.phys_addr,
                   "state": where or (st.name if st else "no answer"),
                   "highest_state": where or (top.name if top else "no answer"),
                   "al_status_code": code,
                   "al_status": al_status_name(code) if code else None,
                   "last_command": progress[slave.name].last_command}
            self.rows.append(row)
        self._passive_rows()

    def _passive_rows(self) -> None:
        """The ENI's slaves without an ESC (passive terminals), each after the slave with an
        ESC the file lists before it: never addressed, no state, no position."""
        for p in sorted(self.plan.passive, key=lambda p: p.after, reverse=True):
            before = self.plan.slaves[p.after - 1].name if p.after else None
            k = next((i + 1 for i, r in enumerate(self.rows) if r["name"] == before), 0)
            while k < len(self.rows) and self.rows[k]["passive"]:
                k += 1              # after the passive ones the file lists before it
            self.rows.insert(k, {"position": None, "name": p.name, "passive": True,
                                 "address": None, "state": "passive", "highest_state":
                                 "passive", "al_status_code": None, "al_status": None,
                                 "last_command": None})

    def finish(self, net: Network, failure: EcatcfgError | None, target: AlState) -> None:
        # The cycles that ran (net.run, or net.cycle() after reset_stats()), not the ones
        # run while the slaves changed state.
        from ecatcfg.runtime.master.cyclic import CycleStats
        stats = net.run_stats or CycleStats()
        counters = net.master.transport.counters
        jitter = stats.jitter()
        self.summary = {
            "eni": self.eni, "target": target.name, "ok": failure is None,
            "error": str(failure) if failure else None,
            "slaves": self.rows,
            "slave_count": {"active": len(self.plan.slaves),
                            "passive": len(self.plan.passive)},
            "cycles": {"count": stats.cycles, "lost_frames": stats.lost_frames,
                       "wkc_errors": stats.wkc_errors,
                       "wkc_error_commands": stats.wkc_error_cmds,
                       "jitter_us": {k: round(v, 1) for k, v in jitter.items()}},
            "frames": {"sent": counters.frames_sent, "lost": counters.frames_lost},
            "refused": [],
            # Why slaves refused, as read from them (runtime/master/diagnose.py).
            "causes": list(getattr(failure, "causes", [])),
            "derived": self.derived_parts,
            "skipped": self.skipped_parts,
            "ignored": self.ignored_parts,
        }
        simulated = self.simulated_time()
        if simulated is not None:
            self.summary["simulated_time_ms"] = simulated
        by_slave = {c["slave"]: c["cause"] for c in self.summary["causes"]}
        for row in self.rows:
            row["cause"] = by_slave.get(row["name"])
        segment = getattr(net, "segment", None)         # set by Network.virtual only
        if segment is not None:
            # Which device each virtual slave behaves as: its ESI, or the ENI alone.
            for row in self.rows:
                if row["passive"]:
                    row["emulated_from"] = None     # no ESC: nothing to emulate
                    row["esi"] = row["esi_choice"] = None
            active = [row for row in self.rows if not row["passive"]]
            sources = getattr(net, "esi_sources", None) or [(None, None)] * len(active)
            for row, slave, (esi, why) in zip(active, segment.slaves, sources):
                row["emulated_from"] = "eni" if slave.eni_only is not None else "esi"
                # The ESI file and why that one, where several describe the identity.
                row["esi"], row["esi_choice"] = esi, why
        if self.json_output:
            if failure:
                print(f"ecatcfg apply: {failure}", file=sys.stderr)
            return
        from rich.table import Table

        console = self.console
        assert not isinstance(console, _PlainConsole)      # the JSON mode returned above
        table = Table(title=f"{self.eni}: slaves")
        for col in ("pos", "name", "addr", "state", "highest", "AL status", "last InitCmd"):
            table.add_column(col)
        for r in self.rows:
            code = r["al_status_code"]
            if r["passive"]:
                table.add_row("-", r["name"], "-", "passive (no ESC)", "-", "-", "-")
                continue
            table.add_row(str(r["position"]), r["name"], str(r["address"]), r["state"],
                          r["highest_state"],
                          f"0x{code:04X} {r['al_status']}" if code else "-",
                          r["last_command"] or "-")
        console.print(table)
        if self.plan.passive:
            console.print(slave_count(self.plan))
        if stats.cycles:
            console.print(
                f"{stats.cycles} cycles, {stats.lost_frames} lost frames, "
                f"{stats.wkc_errors} working-counter errors; cycle jitter p50 "
                f"{jitter['p50']:.0f} us, p99 {jitter['p99']:.0f} us, max "
                f"{jitter['max']:.0f} us")
        if simulated is not None:
            parts = ", ".join(f"{what} {ms:.1f} ms" for what, ms in simulated.items()
                              if what not in ("total", "host_s"))
            console.print(f"simulated time: {simulated['total']:.1f} ms ({parts}) in "
                          f"{simulated['host_s']:.2f} s of host time")
        if failure:
            # escape: the message names the InitCmd as "[comment]", which is not markup.
            from rich.markup import escape
            console.print(f"[bold red]failed:[/] {escape(str(failure))}", markup=True)

    def as_json(self) -> dict[str, Any]:
        return dict(self.summary, events=self.events)


def refusal_json(eni: str, target: int, error: EcatcfgError,
                 plan: NetworkPlan | None) -> dict[str, Any]:
    """The JSON document of a run that did not start (an ENI refused or unreadable, a wrong
    option): the keys of a run's document, nothing run, the error, and ``refused``: the
    parts that made apply refuse the ENI, each with its slave, element, line and what
    (``[]`` when the error is not about parts of the ENI)."""
    from ecatcfg.eni.contents import UnsupportedEniError
    from ecatcfg.eni.derive import DeriveError
    from ecatcfg.runtime.master.bringup import IncompleteEniError
    refused: list[dict[str, Any]] = []
    if isinstance(error, UnsupportedEniError):
        refused = [{"slave": p.slave, "element": p.element, "what": p.what, "line": p.line,
                    "commands": p.commands} for p in error.parts]
    elif isinstance(error, IncompleteEniError):
        refused = [{"slave": name, "element": "Slave/InitCmds", "what": text, "line": None,
                    "commands": 0} for name, text in error.missing.items()]
    elif isinstance(error, DeriveError):
        refused = [{"slave": name, "element": "Slave/InitCmds", "what": text, "line": None,
                    "commands": 0} for name, text in error.problems.items()]
    slaves = [{"position": s.position, "name": s.name, "passive": False,
               "address": s.phys_addr, "state": "not started", "highest_state": "not started",
               "al_status_code": None, "al_status": None, "last_command": "", "cause": None}
              if isinstance(s, SlavePlan) else
              {"position": None, "name": s.name, "passive": True, "address": None,
               "state": "passive", "highest_state": "passive", "al_status_code": None,
               "al_status": None, "last_command": "", "cause": None}
              for s in plan.in_file_order()] if plan else []
    return {"eni": eni, "target": AlState(target).name, "ok": False, "error": str(error),
            "refused": refused, "causes": [], "slaves": slaves,
            "slave_count": {"active": len(plan.slaves) if plan else 0,
                            "passive": len(plan.passive) if plan else 0},
            "cycles": {"count": 0, "lost_frames": 0, "wkc_errors": 0,
                       "wkc_error_commands": {}, "jitter_us": {}},
            "frames": {"sent": 0, "lost": 0}, "derived": [], "skipped": [], "ignored": [],
            "events": []}
