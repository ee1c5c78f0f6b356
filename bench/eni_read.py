"""ENI reading benchmark: bare lxml parse vs ecatcfg's reader, and what its check of every
element against the list of what an ENI may contain (``eni/contents.py``) costs.

Run from the checkout:  python3 bench/eni_read.py [--slaves N] [--repeat R]

The ENI is the example devices compiled into a line of N slaves (every fourth a CiA 402
drive with CoE InitCmds), written by ecatcfg.  In-process, interleaved with the baseline
(bare ``lxml.etree.fromstring`` of the same bytes) so machine noise hits both; min / median
of R repeats.  This is the price of a plan-cache miss: ``apply`` reads a cached plan
without parsing (``bench/startup.py``).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

from timing import interleaved, ms, ratio

ROOT = Path(__file__).resolve().parent.parent


def line_eni(n: int) -> bytes:
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer
    from ecatcfg.esi.library import Library

    kinds = ["EXD-402" if i % 4 == 0 else "EX2008" if i % 2 else "EX1008" for i in range(n)]
    text = "slaves:\n" + "".join(f"  - {{name: s{i}, device: {k}}}\n"
                                 for i, k in enumerate(kinds))
    plan = build.compile_topology(topology.loads(text, "line.yaml"),
                                  Library([ROOT / "examples" / "esi"], cache=False)).plan
    return writer.to_bytes(plan)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--slaves", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=30)
    args = ap.parse_args()
    from lxml import etree

    from ecatcfg.eni import contents, reader

    data = line_eni(args.slaves)
    config = etree.fromstring(data).find("Config")
    assert config is not None and contents.audit(config) == []

    def base() -> object:
        return etree.fromstring(data)

    read_b, read_c = interleaved(base, lambda: reader.read_bytes(data, "line.xml"),
                                 args.repeat)
    audit_b, audit_c = interleaved(base, lambda: contents.audit(config), args.repeat)
    print(f"{platform.machine()}, {os.cpu_count()} CPUs, Python {sys.version.split()[0]}; "
          f"{args.slaves} slaves, {len(data) / 1e6:.2f} MB, repeat {args.repeat}, "
          "min / median ms")
    print("| what | time | vs bare parse |")
    print("|---|---|---|")
    print(f"| bare lxml parse (baseline) | {ms(read_b)} | |")
    print(f"| reader: parse, plan, check | {ms(read_c)} | {ratio(read_b, read_c)} |")
    print(f"| the check alone (contents.audit) | {ms(audit_c)} | {ratio(audit_b, audit_c)} |")


if __name__ == "__main__":
    main()
