"""Lint benchmark: `ecatcfg lint` over the corpus with the ETG schema vs bare lxml work.

Run from the checkout:  python3 bench/lint.py [CORPUS_DIR] [--repeat N]

Measured in the same run, interleaved (baseline, candidate, ...), min and median of N:
  1. `ecatcfg lint CORPUS/esi --schema-dir ... --format json` as a new process (default
     --jobs = CPU count), against a new process that only parses every file with lxml and
     validates it with XMLSchema (the floor for any schema-checking linter).  Target:
     under 10 s on this 2-core machine.
  2. the same lint with --jobs 1, to show what the parallel run buys.
  3. per file, for the largest files: `lint_file` (parse + schema + model + all rules) against
     lxml parse + XMLSchema validate of the same file, in-process.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
from pathlib import Path

from timing import interleaved, ms, ratio

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CORPUS = ROOT.parent / "shared" / "corpus"

PARSE_AND_VALIDATE = """
import sys
from pathlib import Path
from lxml import etree
schemas = {}
for p in sorted(Path(sys.argv[1]).rglob('*.xml')):
    tree = etree.parse(str(p))
    root = etree.QName(tree.getroot()).localname
    if root not in schemas:
        schemas[root] = etree.XMLSchema(etree.parse(str(Path(sys.argv[2]) / (root + '.xsd'))))
    schemas[root].validate(tree)
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("corpus", nargs="?", type=Path, default=DEFAULT_CORPUS)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    esi_dir, schemas = args.corpus / "esi", args.corpus / "schemas" / "esi-1.17"
    files = sorted(esi_dir.rglob("*.xml"))
    size = sum(p.stat().st_size for p in files)
    print(f"# {len(files)} files, {size / 1e6:.1f} MB; {platform.machine()}, "
          f"{os.cpu_count()} CPUs, Python {platform.python_version()}, repeat {args.repeat}")

    def baseline() -> None:
        subprocess.run([sys.executable, "-c", PARSE_AND_VALIDATE, str(esi_dir), str(schemas)],
                       check=True)

    def lint(jobs: str | None) -> None:
        cmd = [sys.executable, "-m", "ecatcfg", "lint", str(esi_dir), "--schema-dir",
               str(schemas), "--format", "json", "--no-config"]
        if jobs:
            cmd += ["--jobs", jobs]
        subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, check=False)

    print("| what | baseline ms (min / median) | ecatcfg ms (min / median) | ratio |")
    print("|---|---|---|---|")
    b, c = interleaved(baseline, lambda: lint(None), args.repeat)
    print(f"| `ecatcfg lint` corpus + schema, default --jobs, new process | {ms(b)} | {ms(c)} "
          f"| {ratio(b, c)} |")
    b, c = interleaved(baseline, lambda: lint("1"), args.repeat)
    print(f"| `ecatcfg lint` corpus + schema, --jobs 1, new process | {ms(b)} | {ms(c)} "
          f"| {ratio(b, c)} |")

    sys.path.insert(0, str(ROOT.parent))
    from lxml import etree
    from ecatcfg.esi.lint import LintOptions, Target, lint_file, select_rules
    options = LintOptions(select_rules(None, None), schemas)
    compiled = {r: etree.XMLSchema(etree.parse(str(schemas / f"{r}.xsd")))
                for r in ("EtherCATInfo", "EtherCATModule")}
    lint_file(Target(files[0], str(files[0]), True), options, [])   # compile schemas once
    print()
    print("| file | MB | parse + validate ms (min / median) | lint_file ms (min / median) "
          "| ratio |")
    print("|---|---|---|---|---|")
    for path in sorted(files, key=lambda p: -p.stat().st_size)[:4]:
        def base() -> None:
            tree = etree.parse(str(path))
            compiled[etree.QName(tree.getroot()).localname].validate(tree)
        b, c = interleaved(base, lambda: lint_file(Target(path, str(path), True), options, []),
                           args.repeat)
        print(f"| {path.name} | {path.stat().st_size / 1e6:.1f} | {ms(b)} | {ms(c)} "
              f"| {ratio(b, c)} |")


if __name__ == "__main__":
    main()
