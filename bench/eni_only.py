"""Emulating slaves from the ENI alone: what building the virtual segment costs without ESI
files, against the same line built from the ESI devices.

Run from the checkout:  python3 bench/eni_only.py [--slaves N] [--repeat R]

The ENI is the example devices compiled into a line of N slaves (every fourth a CiA 402
drive with CoE InitCmds), read once into a plan.  Three timings, interleaved with the
baseline (bare ``lxml.etree.fromstring`` of the ENI bytes) so machine noise hits all:
building the segment from the ESI devices (library loaded once, as ``Network.virtual``
does per run, without its cache: the ESI parse is included), and from the ENI alone
(``runtime/segment/eni_device.py``, SII images and dictionaries included).  min / median of R.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

from eni_read import line_eni
from timing import interleaved, ms, ratio

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--slaves", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    from lxml import etree

    from ecatcfg.eni import reader
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate
    from ecatcfg.runtime.segment.virtual import VirtualSegment

    data = line_eni(args.slaves)
    plan = reader.read_bytes(data, "line.xml")

    def base() -> object:
        return etree.fromstring(data)

    def from_esi() -> object:
        library = Library([ROOT / "examples" / "esi"], cache=False)
        return emulate.segment(emulate.specs_from_eni(plan, library, "line.xml"))

    def from_eni() -> VirtualSegment:
        return emulate.segment(emulate.specs_from_eni(plan, None, "line.xml"))

    assert all(s.eni_only for s in from_eni().slaves)
    esi_b, esi_c = interleaved(base, from_esi, args.repeat)
    eni_b, eni_c = interleaved(base, from_eni, args.repeat)
    print(f"{platform.machine()}, {os.cpu_count()} CPUs, Python {sys.version.split()[0]}; "
          f"{args.slaves} slaves, {len(data) / 1e6:.2f} MB ENI, repeat {args.repeat}, "
          "min / median ms")
    print("| what | time | vs bare parse |")
    print("|---|---|---|")
    print(f"| bare lxml parse of the ENI (baseline) | {ms(esi_b)} | |")
    print(f"| segment from the ESI files (parse included) | {ms(esi_c)} | "
          f"{ratio(esi_b, esi_c)} |")
    print(f"| segment from the ENI alone | {ms(eni_c)} | {ratio(eni_b, eni_c)} |")


if __name__ == "__main__":
    main()
