"""Every device on its own emulation: every device of every ESI file of both corpora,
compiled alone, checked against the ETG.2100 schema and brought up to OP on a virtual
segment built from its own ESI.

Run from the checkout (no root):
    python3 bench/sweep_devices.py [--corpus DIR] [--corpus-extra DIR] [--jobs N]
                                   [--limit N] [--only SUBSTRING] [--json FILE]

The work per device is ``tests/sweep.py`` (``Worker.run``), the same code the CI
sample (``tests/test_sweep_devices.py``) runs: a one-slave topology selecting the device by
vendor, product and revision, compiled in-process with the library API against a library of
its file (and the module libraries it references), the ENI validated with
``EtherCATConfig.xsd``, read back and brought up to OP and down to INIT on
``Network.virtual``.  ``ecatcfg lint`` (all rules, with the ESI schema) runs over both
corpora first; every device that does not reach OP must have a lint error, else it is
listed as unexplained.

Prints the figures of docs/BENCHMARKS.md ("Every device on its own emulation"): devices,
OP, outcomes by category with the lint rules that explain them, time per stage, per-device
median and the wall time; ``--json`` writes every device's result.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import statistics
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT.parent))
sys.path.insert(0, str(ROOT / "tests"))

import sweep  # noqa: E402

_worker: sweep.Worker | None = None


def _init(corpora: dict[str, Path]) -> None:
    global _worker
    _worker = sweep.Worker(corpora)


def _run(case: sweep.Case) -> sweep.Result:
    assert _worker is not None
    return _worker.run(case)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus")))
    p.add_argument("--corpus-extra", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS_EXTRA", ROOT.parent / "shared" / "corpus-extra")))
    p.add_argument("--jobs", type=int, default=2, help="worker processes (at most 2 here)")
    p.add_argument("--limit", type=int, help="only the first N devices (sorted by key)")
    p.add_argument("--only", help="only devices whose key or Type contains this")
    p.add_argument("--json", type=Path, help="write every device's result here")
    args = p.parse_args()

    corpora = {"corpus": args.corpus}
    if args.corpus_extra.is_dir():
        corpora["corpus-extra"] = args.corpus_extra
    wall = time.perf_counter()
    todo = sweep.cases(corpora)
    if args.only:
        todo = [c for c in todo if args.only in c.key or args.only in c.type]
    if args.limit:
        todo = todo[:args.limit]
    t = time.perf_counter()
    files = {(c.corpus, c.file) for c in todo}
    errors = sweep.lint_errors(corpora, files, jobs=args.jobs)
    lint_s = time.perf_counter() - t
    print(f"# {len(todo)} devices in {len(files)} files; {platform.machine()}, "
          f"{os.cpu_count()} CPUs, Python {platform.python_version()}, {args.jobs} jobs; "
          f"lint {lint_s:.1f} s", flush=True)
    results: list[sweep.Result] = []
    with multiprocessing.get_context("fork").Pool(args.jobs, _init, (corpora,)) as pool:
        for i, r in enumerate(pool.imap(_run, todo, chunksize=1)):
            r.lint_errors = sweep.errors_for(todo[i], errors)
            results.append(r)
            if r.outcome not in ("op", "passive"):
                print(f"{r.outcome:14} {r.key} ({r.type}): {r.message[:200]}", flush=True)
            if (i + 1) % 100 == 0:
                print(f"# {i + 1}/{len(todo)} in {time.perf_counter() - wall:.0f} s",
                      flush=True)
    wall_s = time.perf_counter() - wall
    s = sweep.summary(results)
    print()
    print(f"| devices | OP | passive (no ESC) | refused | schema-invalid | not emulated | apply failed | crash "
          f"| unexplained | wall s | per device median ms |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    o = s["outcomes"]
    print(f"| {s['devices']} | {s['op']} | {s['passive']} | {o.get('refused', 0)} "
          f"| {o.get('schema-invalid', 0)} | {o.get('not-emulated', 0)} "
          f"| {o.get('apply-failed', 0)} | {o.get('crash', 0)} | {len(s['unexplained'])} "
          f"| {wall_s:.0f} | {s['seconds']['per_device_median'] * 1000:.0f} |")
    print()
    print("time per stage, summed over devices (s): " + ", ".join(
        f"{k} {v}" for k, v in s["seconds"]["stages"].items()) + f"; lint {lint_s:.1f}")
    print()
    print("| outcome | category | devices | lint errors that explain them | unexplained |")
    print("|---|---|---|---|---|")
    for outcome in ("refused", "schema-invalid", "not-emulated", "apply-failed", "crash"):
        cats: dict[str, list[sweep.Result]] = {}
        for r in results:
            if r.outcome == outcome:
                cats.setdefault(r.category, []).append(r)
        for cat, rs in sorted(cats.items(), key=lambda kv: -len(kv[1])):
            rules = Counter(e.split()[0] for r in rs for e in set(
                x.split()[0] for x in r.lint_errors))
            print(f"| {outcome} | {cat} | {len(rs)} | "
                  + ", ".join(f"{k} ×{v}" for k, v in rules.most_common(4))
                  + f" | {sum(not r.explained for r in rs)} |")
    if args.json:
        args.json.write_text(json.dumps({"summary": s, "wall_s": round(wall_s, 1),
                                         "lint_s": round(lint_s, 1),
                                         "results": [r.as_json() for r in results]},
                                        indent=1))
    median = statistics.median([sum(r.seconds.values()) for r in results]) if results else 0
    print(f"\n# wall {wall_s:.0f} s, per device median {median * 1000:.0f} ms", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
