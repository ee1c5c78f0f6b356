"""Capture conformance: replay every capture of both corpora against the virtual segment
and print the per-capture table of docs/conformance.md.

Run from the checkout (no root):
    python3 bench/conformance.py [--corpus DIR] [--corpus-extra DIR] [--differences N]

For each wire capture in the corpora (``pcap/`` and its subfolders) the harness in
``tests/conformance.py`` identifies the slaves from the capture's SII reads (a revision the
capture does not read from the corpus SII dumps that agree with it), builds the same line
from the ESI files of both corpora, sends the master's frames through the emulated line in
memory and classifies each returned datagram as equal, equal by rule, known limit or
different.  Prints a markdown table and, per capture, the first N differences.  Captures
of the extra corpus are named with the prefix ``corpus-extra/``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--corpus", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus")))
    p.add_argument("--corpus-extra", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS_EXTRA", ROOT.parent / "shared" / "corpus-extra")))
    p.add_argument("--differences", type=int, default=5, help="differences listed per capture")
    args = p.parse_args()
    sys.path.insert(0, str(ROOT.parent))
    sys.path.insert(0, str(ROOT / "tests"))
    import conformance

    from ecatcfg.esi.library import Library

    corpora = [(args.corpus, "")] + ([(args.corpus_extra, "corpus-extra/")]
                                     if args.corpus_extra.is_dir() else [])
    library = Library([root / "esi" for root, _ in corpora])
    dumps = conformance.sii_dumps(args.corpus / "sii")
    reports = [conformance.replay(path, library,
                                  prefix + str(path.relative_to(root / "pcap")), dumps)
               for root, prefix in corpora for path in conformance.captures(root)]
    print(conformance.table(reports))
    for r in reports:
        if r.differences:
            print(f"\n{r.name}: {len(r.differences)} differences, first {args.differences}:")
            for d in r.differences[:args.differences]:
                print(f"  {d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
