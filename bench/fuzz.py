"""The long fuzz campaign: targets of ``tests/fuzzing.py`` for a while, counting outcomes and
the distinct failures among them.

Run from the checkout (nothing else needed; no root):
    python3 bench/fuzz.py [--minutes M | --seconds S] [--targets a,b] [--mutations k,l]
                          [--seed N] [--chunk K] [--stop-at-first] [--shrink]

Each target runs for the given time in chunks of ``--chunk`` inputs; chunk i is a hypothesis
run seeded with ``seed + i`` (so the campaign is repeatable input for input, given the same
time per chunk), generating inputs from the same strategies as the test suite's bounded
campaign (``tests/test_fuzz.py``), or with ``--mutations`` only edits of those kinds
(``fuzzing.MUTATION_KINDS``: ``huge-numbers``, ``negative-sizes``, ``huge-counts``,
``boundaries``, ``repeated-elements``, ``registers``; only the targets that take one of
them run).  Every input's outcome is counted: accepted, rejected (ecatcfg's own located
error), crash (any other exception, an error without a location or a broken invariant of
the emulated ESC) or hang (more than 5 s).

A crash does not stop the campaign: each is filed under its *signature*, the exception type
and the innermost frame of ecatcfg's own code it came from (``ValueError @
esi/sii.py:_strings``; for the harness's own findings the kind of finding), so one campaign
shows every class it meets, with the input number and the time of its first hit and how
many inputs hit it.  Hypothesis would stop a run at its first failure and shrink it
towards the simplest input, so in a mix the class with the simplest input hides the
others.  ``--stop-at-first`` ends a target at its first crash (the time to find a class);
``--shrink`` shrinks the first input of each signature to a minimal one (a hypothesis run of
that chunk again, failing only on that signature), printed as ``Mutant(...)``.

Prints one line per target as it finishes, a markdown table at the end (the figures in
docs/BENCHMARKS.md, "Fuzzing") and one per signature.  A benchmark, not a test: nothing is
asserted, the exit code is 1 when a crash or hang was found.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import os
import platform
import re
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Found:
    """A failure signature and where the campaign met it first."""

    target: str
    signature: str
    message: str
    first_input: int        # 1-based, counted over the target's whole campaign
    first_seconds: float
    chunk_seed: int
    example: str            # repr of the first input (a Mutant names seed and edits)
    hits: int = 1
    shrunk: str = ""


def signature(exc: BaseException) -> tuple[str, str]:
    """``(signature, message)`` of a failure: the exception type and the innermost frame in
    ecatcfg's own code (not the harness in tests/, not the standard library)."""
    import fuzzing
    message = " ".join(str(exc).split())[:160]
    if isinstance(exc, fuzzing.Hang):
        kind = "Hang"
    elif isinstance(exc, fuzzing.Defect):
        # The harness's own findings: an error without a location, a broken invariant.
        # Their text says which; numbers and names in it vary from input to input.
        kind = "Defect: " + re.sub(r"'[^']*'|\d+", "_", message.split(":")[0])[:60]
        cause = exc.__cause__
        if cause is None:
            return kind, message
        exc = cause
    else:
        kind = type(exc).__name__
    package = ROOT.resolve()
    where = ""
    for frame in traceback.extract_tb(exc.__traceback__):
        if frame.filename.startswith("<"):      # code made at run time (record.py's __init__)
            continue
        path = Path(frame.filename).resolve()
        if path.is_relative_to(package) and not any(
                path.is_relative_to(package / d) for d in ("tests", "bench")):
            # A hang is interrupted wherever its loop happens to be: named by module only.
            where = str(path.relative_to(package)) + ("" if kind == "Hang" else
                                                       f":{frame.name}")
    return f"{kind} @ {where or '?'}", message


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=None, help="time per target")
    p.add_argument("--minutes", type=float, default=2.0, help="time per target (default 2)")
    p.add_argument("--targets", default="", help="comma-separated target names (default all)")
    p.add_argument("--mutations", default="",
                   help="comma-separated mutation kinds (default: each target's own mix)")
    p.add_argument("--seed", type=int, default=1, help="seed of the first chunk")
    p.add_argument("--chunk", type=int, default=500, help="inputs per hypothesis run")
    p.add_argument("--stop-at-first", action="store_true",
                   help="end a target at its first crash or hang")
    p.add_argument("--shrink", action="store_true",
                   help="shrink the first input of each signature to a minimal one")
    args = p.parse_args()
    seconds = args.seconds if args.seconds is not None else args.minutes * 60

    sys.path.insert(0, str(ROOT.parent))
    sys.path.insert(0, str(ROOT / "tests"))
    import hypothesis
    from hypothesis import HealthCheck, Phase, given, settings

    import fuzzing

    kinds = frozenset(k for k in args.mutations.split(",") if k) or None
    if kinds and kinds - set(fuzzing.MUTATION_KINDS):
        p.error(f"unknown mutation kind(s) {', '.join(sorted(kinds - set(fuzzing.MUTATION_KINDS)))}"
                f"; known: {', '.join(fuzzing.MUTATION_KINDS)}")
    names = [n for n in args.targets.split(",") if n]
    unknown = [n for n in names if n not in fuzzing.TARGETS]
    if unknown:
        p.error(f"unknown target(s) {', '.join(unknown)}; known: {', '.join(fuzzing.TARGETS)}")
    if kinds:
        takes = [n for n in names or fuzzing.TARGETS if kinds & set(fuzzing.TARGETS[n].kinds)]
        if names and takes != names:
            p.error(f"{', '.join(sorted(set(names) - set(takes)))} take(s) none of "
                    f"{', '.join(sorted(kinds))}")
        names = takes
    names = names or list(fuzzing.TARGETS)

    def hypothesis_run(strategy: Any, chunk_seed: int, test: Any, shrink: bool,
                       examples: int = args.chunk) -> None:
        phases = (Phase.generate, Phase.shrink) if shrink else (Phase.generate,)

        @hypothesis.seed(chunk_seed)
        @settings(max_examples=examples, database=None, deadline=None,
                  suppress_health_check=list(HealthCheck), report_multiple_bugs=False,
                  phases=phases, print_blob=False)
        @given(strategy)
        def check(value: Any) -> None:
            test(value)

        check()

    rows = []
    found: dict[tuple[str, str], Found] = {}
    for name in names:
        target = fuzzing.TARGETS[name]
        own = kinds & set(target.kinds) if kinds else None
        strategy = target.strategy(frozenset(own) if own else None)
        counts: collections.Counter[str] = collections.Counter()

        def warm_up(value: Any) -> None:
            # Neither timed nor counted: the first input of a target imports the modules
            # and builds the seeds (an ENI compiled, a line brought up: seconds on a busy
            # machine), which the watchdog would take for a hang of that input.
            try:
                target.call(value)
            except Exception:
                pass

        hypothesis_run(strategy, args.seed, warm_up, shrink=False, examples=3)
        start = time.monotonic()
        chunk = 0
        stop = False
        while time.monotonic() - start < seconds and not stop:
            chunk_seed = args.seed + chunk

            def test(value: Any) -> None:
                nonlocal stop
                if stop or time.monotonic() - start >= seconds:
                    return                      # the rest of the chunk: not run, not counted
                try:
                    counts[fuzzing.run(target, value)] += 1
                    return
                except Exception as exc:
                    failure: BaseException = exc
                counts["hang" if isinstance(failure, fuzzing.Hang) else "crash"] += 1
                sig, message = signature(failure)
                key = (name, sig)
                if key in found:
                    found[key].hits += 1
                    return
                n = sum(counts.values())
                found[key] = Found(name, sig, message, n, time.monotonic() - start,
                                   chunk_seed, repr(value))
                print(f"  {name}: new {sig} at input {n} ({time.monotonic() - start:.1f} s): "
                      f"{message[:120]}\n    {repr(value)[:300]}", flush=True)
                stop = args.stop_at_first

            hypothesis_run(strategy, chunk_seed, test, shrink=False)
            chunk += 1
        took = time.monotonic() - start
        inputs = sum(counts.values())
        mine = [f for f in found.values() if f.target == name]
        rows.append((name, inputs, counts, len(mine), took, target.what))
        print(f"{name:14} {inputs:8} inputs  accepted {counts['accepted']:7}  rejected "
              f"{counts['rejected']:7}  crashes {counts['crash']}  hangs {counts['hang']}  "
              f"signatures {len(mine)}  {took:.0f} s, {inputs / took if took else 0:.0f}/s",
              flush=True)

    if args.shrink:
        for f in found.values():
            target = fuzzing.TARGETS[f.target]
            own = kinds & set(target.kinds) if kinds else None

            def only(value: Any, f: Found = f, target: Any = target) -> None:
                try:
                    fuzzing.run(target, value)
                except Exception as exc:
                    if signature(exc)[0] == f.signature:
                        raise
            try:
                hypothesis_run(target.strategy(frozenset(own) if own else None),
                               f.chunk_seed, only, shrink=True)
                f.shrunk = "(not met again)"
            except Exception as exc:
                # hypothesis's note: "Falsifying example: check(value=Mutant(...))".
                notes = " ".join(" ".join(getattr(exc, "__notes__", [])).split())
                f.shrunk = notes.removeprefix("Falsifying example: ")[:600] or "?"

    when = datetime.date.today().isoformat()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\nMachine: {platform.machine()}, {os.cpu_count()} CPUs, {platform.platform()}, "
          f"Python {platform.python_version()}, hypothesis {hypothesis.__version__}; {when}; "
          f"load average {load:.1f} at the end; {seconds:.0f} s per target, chunks of "
          f"{args.chunk}, seeds from {args.seed}"
          + (f", mutations {','.join(sorted(kinds))}" if kinds else "") + ".\n")
    print("| target | inputs | accepted | rejected (located error) | crashing inputs | hangs | "
          "signatures | inputs/s | what |")
    print("|---|---|---|---|---|---|---|---|---|")
    total = 0
    for name, inputs, counts, sigs, took, what in rows:
        total += inputs
        print(f"| {name} | {inputs} | {counts['accepted']} | {counts['rejected']} | "
              f"{counts['crash']} | {counts['hang']} | {sigs} | "
              f"{inputs / took if took else 0:.0f} | {what} |")
    print(f"\n{total} inputs in all; {len(found)} signature(s).")
    if found:
        print("\n| target | signature | first at input | after s | inputs hit | message | "
              "first input |")
        print("|---|---|---|---|---|---|---|")
        for f in found.values():
            shown = f.example if len(f.example) <= 200 else f.example[:200] + "..."
            print(f"| {f.target} | {f.signature} | {f.first_input} | {f.first_seconds:.1f} | "
                  f"{f.hits} | {f.message[:100]} | `{shown}` |")
            if f.shrunk:
                print(f"|  | shrunk (chunk seed {f.chunk_seed}) | | | | | {f.shrunk} |")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
