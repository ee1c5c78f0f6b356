"""The emulator-vs-diagnosis agreement, whole: every corpus ENI, with and without the corpora's ESI files,
unchanged and with every fault the seeded generator plants (``tests/diagnosis_agreement.py``),
brought up on the in-memory virtual segment; every refusal of an emulated slave must be
diagnosed with the same AL status code and the rule the emulator applied, and never with
"the slave's firmware checks more".

Run from the checkout:  python3 bench/diagnosis_agreement.py [--seed N] [--limit K]

``--limit``: at most K faults per ENI (default: all).  Prints one line per disagreement,
then the figures docs/BENCHMARKS.md keeps: cases, refusals per rule, disagreements, time.
Exit status 1 when any case disagrees.  ENIs the runtime refuses to run (a file it cannot
read, ESI files that describe one device differently) are counted and named, not run.
"""

from __future__ import annotations

import argparse
import collections
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
CORPORA = {"corpus": Path(os.environ.get("ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus")),
           "corpus-extra": Path(os.environ.get("ECATCFG_CORPUS_EXTRA",
                                               ROOT.parent / "shared" / "corpus-extra"))}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=39)
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    import warnings
    warnings.simplefilter("ignore")      # each skipped part of an ENI, once per case
    from diagnosis_agreement import faults, run_case

    from ecatcfg.eni import reader
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esi.library import Library

    folders = [str(root / "esi") for root in CORPORA.values()]
    library = Library(folders, prefer=[str(CORPORA["corpus"] / "esi" / "drives"),
                                       folders[0]])
    enis = sorted(p for root in CORPORA.values() for p in (root / "eni").rglob("*.xml"))
    cases = refusals = 0
    per_rule: collections.Counter[str] = collections.Counter()
    bad: list[str] = []
    skipped: list[str] = []
    start = time.monotonic()
    for path in enis:
        name = f"{path.parent.parent.name}/{path.parent.name}/{path.name}"
        try:
            plan = reader.read_file(path)
        except EcatcfgError as exc:
            skipped.append(f"{name}: {exc.message.splitlines()[0][:120]}")
            continue
        planted = faults(plan, args.seed)[:args.limit]
        began, before = time.monotonic(), (cases, refusals, len(bad))
        for with_esi in (True, False):
            lib = library if with_esi else None
            mode = "esi" if with_esi else "eni-only"
            for label, changed in [("unchanged", plan)] + [
                    (f"{f.name} {f.slave} ({f.what})", f.plan) for f in planted]:
                try:
                    outcome = run_case(f"{name} [{mode}] {label}", plan, changed, lib)
                except EcatcfgError as exc:
                    skipped.append(f"{name} [{mode}] {label}: "
                                   f"{exc.message.splitlines()[0][:120]}")
                    break               # the ENI itself does not run this way
                cases += 1
                refusals += len(outcome.refusals)
                per_rule.update(f"0x{code:04X} {rule}" for _, code, rule in outcome.refusals)
                bad += outcome.disagreements
        print(f"{name}: {cases - before[0]} cases, {refusals - before[1]} refusals, "
              f"{len(bad) - before[2]} disagreements, {time.monotonic() - began:.1f} s",
              flush=True)
    elapsed = time.monotonic() - start
    for line in bad:
        print("DISAGREE", line)
    for line in skipped:
        print("not run:", line)
    print(f"\nmachine: {platform.machine()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}; seed {args.seed}")
    print(f"{len(enis)} ENIs, {cases} cases, {refusals} refusals, {len(bad)} disagreements, "
          f"{len(skipped)} not run, {elapsed:.1f} s")
    for rule, n in sorted(per_rule.items()):
        print(f"  {rule}: {n}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
