"""The whole check-vs-apply agreement matrix: every ENI of both
corpora, the example line compiled by ``ecatcfg compile`` and ``--lines`` lines of corpus
devices drawn by seed and compiled the same way (``tests/compiled_lines.py``), unmodified and with every
fault class of ``tests/faults.py`` planted with each seed, ``check`` against ``apply
--virtual``, with the ESI files of both corpora and from the ENI alone.

    python3 bench/agreement.py [--seeds N] [--lines N] [--corpus DIR --corpus-extra DIR] [-v]

Prints one line per case that is neither an agreement nor a documented limit (and with -v
every case), then the figures as a Markdown table for docs/BENCHMARKS.md: cases, agreements,
check-only faults (the image faults no slave sees), each limit, unexplained, and the time
per case.  Exit 1 when a case is unexplained.  The fixed sample of the same matrix runs in
CI (tests/test_agreement.py).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--lines", type=int, default=10,
                    help="lines of corpus devices compiled (line seeds 1..N)")
    ap.add_argument("--only-lines", action="store_true",
                    help="only the compiled lines of corpus devices, not the corpus ENIs")
    ap.add_argument("--corpus", type=Path, default=SHARED / "corpus")
    ap.add_argument("--corpus-extra", type=Path, default=SHARED / "corpus-extra")
    ap.add_argument("--fault", action="append", metavar="NAME",
                    help="only this fault class (repeatable; tests/faults.py), without the "
                         "unmodified files")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT.parent))
    sys.path.insert(0, str(ROOT / "tests"))
    from agreement import LIMITS, Outcome, run_matrix
    from compiled_lines import candidates, line
    from conftest import compile_example
    from faults import FAULTS

    from ecatcfg.esi.cache import IndexCache
    from ecatcfg.esi.library import Library

    enis: dict[str, bytes] = {}
    for root in (args.corpus, args.corpus_extra) if not args.only_lines else ():
        for path in sorted((root / "eni").rglob("*.xml")):
            enis[f"{root.name}/{path.relative_to(root / 'eni').as_posix()}"] = \
                path.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        if not args.only_lines:
            enis["examples (compiled)"] = compile_example(Path(tmp) / "line.xml").read_bytes()
        library = Library([args.corpus / "esi", args.corpus_extra / "esi", ROOT / "examples"
                           / "esi"], cache=IndexCache(Path(tmp) / "cache"),
                          prefer=[args.corpus / "esi" / "drives"])
        pool = candidates(library, tuple(str((root / "esi").resolve())
                                         for root in (args.corpus, args.corpus_extra)))
        lines = 0
        for seed in range(1, args.lines + 1):
            drawn = line(library, pool, seed)
            if drawn is not None:
                enis[drawn.name] = drawn.eni
                lines += 1

        def report(o: Outcome) -> None:
            if args.verbose or not o.explained:
                mark = "ok " if o.explained else "BAD"
                print(f"{mark} {'[' + o.limit + '] ' if o.limit else ''}{o.describe()}",
                      flush=True)

        started = time.perf_counter()
        unknown = sorted(set(args.fault or ()) - set(FAULTS))
        if unknown:
            ap.error(f"--fault {', '.join(unknown)}: not a fault class of tests/faults.py")
        classes = list(args.fault) if args.fault else [None, *FAULTS]
        outcomes = run_matrix(enis, classes, list(range(1, args.seeds + 1)),
                              {False: None, True: library}, report)
        seconds = time.perf_counter() - started
    limits = Counter(o.limit for o in outcomes if o.limit is not None)
    image_only = sum(1 for o in outcomes if o.agree and o.allowed_disagreement)
    unexplained = [o for o in outcomes if not o.explained]
    agree = sum(1 for o in outcomes if o.agree and o.at_line and not o.allowed_disagreement)
    print(f"\n{platform.machine()}, {os.cpu_count()} CPUs, Python {sys.version.split()[0]}; "
          f"{len(enis)} ENIs ({lines} compiled lines of corpus devices), {len(classes)} fault classes, {args.seeds} seed(s), "
          f"with ESI and ENI only")
    print("| what | cases |")
    print("|---|---|")
    print(f"| cases (a fault with no place in a file is not a case) | {len(outcomes)} |")
    print(f"| check errs exactly where apply fails, at the planted line | {agree} |")
    print(f"| check errs, apply runs: a fault of the image no slave sees | {image_only} |")
    for name in LIMITS:
        print(f"| limit `{name}` | {limits.get(name, 0)} |")
    print(f"| unexplained | {len(unexplained)} |")
    print(f"| time | {seconds:.0f} s, {1000 * seconds / max(len(outcomes), 1):.0f} ms a case |")
    return 1 if unexplained else 0


if __name__ == "__main__":
    raise SystemExit(main())
