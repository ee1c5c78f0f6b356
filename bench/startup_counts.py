"""Where ``apply``'s start-up goes, step by step, in counts and in-process times: the
breakdown of docs/BENCHMARKS.md ("Start-up in counts").

    python3 bench/startup_counts.py [--lines 1,8,64,64dc] [-n 5] [--checkout PATH ...]

Per line (tests/startup_counts.py: the fixed lines of the example devices, compiled in
memory; the line emulated in this process, answering inside ``send`` on a simulated clock):
per step of ``Network.up()`` to OP (scan, II, IP, read-backs, DC set-up, PS, SO, as the
master's events mark them) the frames, the function calls made in ecatcfg's code other
than the emulated line's (one run under ``sys.setprofile``: a count, load-independent) and
the time (min of ``-n`` runs, ``time.perf_counter``, the emulation's own time taken out;
the machine's load shows in it); and
before it the plan from the cache (``eni/cache.py``, min of ``-n``) and the check that every
state is requested (``check_requests``, which apply runs twice).  Not here: the raw
socket's open and close (bench/startup.py times them on veth).
Imports: ``apply ENI --iface`` as the console script runs it, the raw socket replaced by a
socket pair to an emulated line in another process (``startup_counts.apply_imports``), with
``-X importtime``: the modules it imports and the sum of their own import times (min over
``-n`` runs per module).

``--checkout PATH``: the same for another checkout of the package (a folder whose
``ecatcfg`` is the package, e.g. made with ``git worktree add``), each in its own
process, so that the figures of two commits come from one run.  Benchmarks are not tests:
nothing is asserted (the guards are tests/test_startup_counts.py).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import startup_counts as counts  # noqa: E402  (from tests/, as the path above allows)

SEGMENT_FILES = ("/segment/", "/runtime/virtual.py", "/runtime/slave.py", "/runtime/emulate.py",
                 "/runtime/syncman.py", "/runtime/dc_clock.py", "/runtime/mailbox_server.py",
                 "/runtime/sdo_server.py", "/runtime/objects.py", "/runtime/esc_chips.py",
                 "/runtime/eni_device.py", "/runtime/al_checks.py")


def one_line(n: int, dc: bool, runs: int) -> dict[str, object]:
    """Steps of one line in this process: {step: [frames, calls, ms]}."""
    from ecatcfg.eni import cache as eni_cache
    from ecatcfg.eni import writer
    from ecatcfg.esc import AlState
    plan, library = counts.compile_line(n, dc)
    bringup, _ = counts._modules()
    out: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        eni = Path(tmp) / "line.eni.xml"
        eni.write_bytes(writer.to_bytes(plan))
        os.environ["XDG_CACHE_HOME"] = tmp
        eni_cache.read_file(eni)                    # stores the plan
        best = min(_timed(lambda: eni_cache.read_file(eni)) for _ in range(runs))
        out["plan from the cache"] = [0, 0, best]
    check = getattr(bringup, "check_requests", None)
    if check is not None:
        out["check_requests"] = [0, _calls(lambda: check(plan, AlState.OP)),
                                 min(_timed(lambda: check(plan, AlState.OP))
                                     for _ in range(runs))]
    for k in range(runs + 1):
        profile = k == runs                         # the last run counts calls
        marks: list[tuple[str, tuple[float, ...]]] = []
        calls = [0]
        net, link, _, undo = counts.simulated_network(plan, library)

        def on_event(event: Any, marks: list[Any] = marks, link: Any = link,
                     calls: list[int] = calls) -> None:
            marks.append((event.text, (link.frames, calls[0],
                                       time.perf_counter() - link.busy_s)))
        net.master.on_event = on_event
        if profile:
            sys.setprofile(_counter(calls))
        try:
            net.up(AlState.OP)
            end = (link.frames, calls[0], time.perf_counter() - link.busy_s)
        finally:
            sys.setprofile(None)
            undo()
        net.close()
        steps = counts.steps(marks, end)
        for name, (frames, n_calls, seconds) in steps.items():
            row = out.setdefault(name, [frames, 0, float("inf")])
            if profile:
                row[1] = n_calls
            else:
                row[2] = min(row[2], seconds * 1e3)
    return out


def _timed(fn) -> float:                          # type: ignore[no-untyped-def]
    t = time.perf_counter()
    fn()
    return (time.perf_counter() - t) * 1e3


def _counter(calls: list[int]):                   # type: ignore[no-untyped-def]
    def count(frame, event, arg):                 # type: ignore[no-untyped-def]
        if event in ("call", "c_call"):
            name = frame.f_code.co_filename
            if "ecatcfg" in name and not any(s in name for s in SEGMENT_FILES):
                calls[0] += 1
    return count


def _calls(fn) -> int:                            # type: ignore[no-untyped-def]
    calls = [0]
    sys.setprofile(_counter(calls))
    try:
        fn()
    finally:
        sys.setprofile(None)
    return calls[0]


def imports(n: int, runs: int) -> dict[str, object]:
    """The modules of apply's process on the line and the sum of their own import times."""
    from ecatcfg.eni import writer
    plan, _ = counts.compile_line(n, False)
    with tempfile.TemporaryDirectory() as tmp:
        eni = Path(tmp) / "line.eni.xml"
        eni.write_bytes(writer.to_bytes(plan))
        env = counts.env_for(Path(tmp) / "cache")
        master = dict(env, PYTHONPROFILEIMPORTTIME="1")
        best: dict[str, int] = {}
        for k in range(runs + 1):
            run = counts.apply_imports(eni, Path(tmp) / "m.json", env, master)
            if k == 0:
                continue                            # the first run stores the plan
            for name, us in _self_times(run["stderr"], run["modules"]).items():
                best[name] = min(best.get(name, 1 << 60), us)
    mods = run["modules"]
    ours = [m for m in mods if m.startswith("ecatcfg")]
    return {"modules": len(mods), "ecatcfg": len(ours), "third party": counts.third_party(mods),
            "ms": round(sum(best.values()) / 1e3, 1),
            "ecatcfg ms": round(sum(v for k, v in best.items()
                                    if k.startswith("ecatcfg")) / 1e3, 1),
            "largest": sorted(best.items(), key=lambda kv: -kv[1])[:8],
            "frames": run["report"]["frames"]}


def _self_times(stderr: str, modules: list[str]) -> dict[str, int]:
    wanted = set(modules)
    out: dict[str, int] = {}
    for line in stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+\d+ \|\s*(\S+)", line)
        if m and m.group(2) in wanted:
            out[m.group(2)] = int(m.group(1))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--lines", default="1,8,64,64dc")
    p.add_argument("-n", type=int, default=5)
    p.add_argument("--checkout", action="append", default=[])
    p.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    here = {"package": str(Path(__import__("ecatcfg").__file__).parent)}
    lines = [x for x in args.lines.split(",") if x]
    for spec in lines:
        n, dc = int(spec.rstrip("dc")), spec.endswith("dc")
        here[spec] = one_line(n, dc, args.n)
    here["imports"] = imports(8, args.n)
    if args.json:
        print(json.dumps(here))
        return
    results = {"this checkout": here}
    for path in args.checkout:
        done = subprocess.run(
            [sys.executable, __file__, "--json", "--lines", args.lines, "-n", str(args.n)],
            capture_output=True, text=True, check=True,
            env=dict(os.environ, PYTHONPATH=path))
        results[path] = json.loads(done.stdout)
    print(table(results, lines))


def table(results: dict[str, dict[str, object]], lines: list[str]) -> str:
    """Markdown: per line, the steps with frames / calls / ms of each checkout; imports."""
    names = list(results)
    out = []
    for line in lines:
        out.append(f"\nline {line}: frames / function calls / ms (min)\n")
        out.append("| step | " + " | ".join(names) + " |")
        out.append("|---|" + "---|" * len(names))
        steps: list[str] = []
        for r in results.values():
            steps += [s for s in r[line] if s not in steps]      # type: ignore[attr-defined]
        total = {n: [0.0, 0.0, 0.0] for n in names}
        for step in steps:
            cells = []
            for n in names:
                row = results[n][line].get(step)                 # type: ignore[attr-defined]
                if row is None:
                    cells.append("-")
                    continue
                total[n] = [a + b for a, b in zip(total[n], row)]
                cells.append(f"{row[0]:.0f} / {row[1]:.0f} / {row[2]:.1f}")
            out.append(f"| {step} | " + " | ".join(cells) + " |")
        out.append("| total | " + " | ".join(f"{t[0]:.0f} / {t[1]:.0f} / {t[2]:.1f}"
                                              for t in total.values()) + " |")
    out.append("\nimports of apply --iface (8-slave line, plan in the cache)\n")
    for n in names:
        imp = results[n]["imports"]
        out.append(f"- {n}: {json.dumps(imp)}")
    return "\n".join(out)


if __name__ == "__main__":
    main()
