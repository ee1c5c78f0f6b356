"""The long fuzz campaign: every target of ``tests/fuzzing.py`` for a while, counting outcomes.

Run from the checkout (nothing else needed; no root):
    python3 bench/fuzz.py [--minutes M | --seconds S] [--targets a,b] [--seed N] [--chunk K]

Each target runs for the given time in chunks of ``--chunk`` inputs; chunk i is a hypothesis
run seeded with ``seed + i`` (so the campaign is repeatable input for input, given the same
time per chunk), generating inputs from the same strategies as the test suite's bounded
campaign (``tests/test_fuzz.py``).  Every input's outcome is counted: accepted, rejected
(ecatcfg's own located error), crash (any other exception, an error without a location or a
broken invariant of the emulated ESC) or hang (more than 5 s).  A chunk that finds a defect
is shrunk by hypothesis to a minimal input, which is printed, and the campaign goes on with
the next chunk; inputs tried while shrinking are counted as inputs too.

Prints one line per target as it finishes and a markdown table at the end (the figures in
docs/BENCHMARKS.md, "Fuzzing").  A benchmark, not a test: nothing is asserted, the exit code
is 1 when a defect was found.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import os
import platform
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=None, help="time per target")
    p.add_argument("--minutes", type=float, default=2.0, help="time per target (default 2)")
    p.add_argument("--targets", default="", help="comma-separated target names (default all)")
    p.add_argument("--seed", type=int, default=1, help="seed of the first chunk")
    p.add_argument("--chunk", type=int, default=500, help="inputs per hypothesis run")
    args = p.parse_args()
    seconds = args.seconds if args.seconds is not None else args.minutes * 60

    sys.path.insert(0, str(ROOT.parent))
    sys.path.insert(0, str(ROOT / "tests"))
    import hypothesis
    from hypothesis import HealthCheck, Phase, given, settings

    import fuzzing

    names = [n for n in args.targets.split(",") if n] or list(fuzzing.TARGETS)
    unknown = [n for n in names if n not in fuzzing.TARGETS]
    if unknown:
        p.error(f"unknown target(s) {', '.join(unknown)}; known: {', '.join(fuzzing.TARGETS)}")

    rows = []
    defects: list[str] = []
    for name in names:
        target = fuzzing.TARGETS[name]
        counts: collections.Counter[str] = collections.Counter()
        found = 0
        start = time.monotonic()
        chunk = 0
        strategy = target.strategy()
        while time.monotonic() - start < seconds:
            @hypothesis.seed(args.seed + chunk)
            @settings(max_examples=args.chunk, database=None, deadline=None,
                      suppress_health_check=list(HealthCheck), report_multiple_bugs=False,
                      phases=(Phase.generate, Phase.shrink), print_blob=False)
            @given(strategy)
            def check(value):
                try:
                    counts[fuzzing.run(target, value)] += 1
                except fuzzing.Hang:
                    counts["hang"] += 1
                    raise
                except BaseException:
                    counts["crash"] += 1
                    raise

            try:
                check()
            except Exception as exc:     # hypothesis re-raises the shrunk failure
                found += 1
                notes = "\n".join(getattr(exc, "__notes__", []))
                text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
                defects.append(f"{name} (chunk seed {args.seed + chunk}): {text}\n{notes}")
                print(f"  DEFECT in {name}: {text[:300]}\n{notes[:2000]}", flush=True)
            chunk += 1
        took = time.monotonic() - start
        inputs = sum(counts.values())
        row = (name, inputs, counts["accepted"], counts["rejected"], found,
               counts["hang"], took, inputs / took if took else 0.0)
        rows.append((row, target.what))
        print(f"{name:14} {inputs:8} inputs  accepted {counts['accepted']:7}  rejected "
              f"{counts['rejected']:7}  defects {found}  (crashing inputs {counts['crash']}, "
              f"hangs {counts['hang']})  {took:.0f} s, {row[-1]:.0f}/s", flush=True)

    when = datetime.date.today().isoformat()
    print(f"\nMachine: {platform.machine()}, {os.cpu_count()} CPUs, {platform.platform()}, "
          f"Python {platform.python_version()}, hypothesis {hypothesis.__version__}; {when}; "
          f"{seconds:.0f} s per target, chunks of {args.chunk}, seeds from {args.seed}.\n")
    print("| target | inputs | accepted | rejected (located error) | crashes | hangs | "
          "inputs/s | what |")
    print("|---|---|---|---|---|---|---|---|")
    total = 0
    for (name, inputs, acc, rej, found, hangs, took, rate), what in rows:
        total += inputs
        print(f"| {name} | {inputs} | {acc} | {rej} | {found} | {hangs} | {rate:.0f} | {what} |")
    print(f"\n{total} inputs in all; {len(defects)} defect(s).")
    for d in defects:
        print("\n" + d)
    return 1 if defects else 0


if __name__ == "__main__":
    sys.exit(main())
