"""Compile benchmark: a 512-slave line of mixed corpus devices through `ecatcfg compile`.

Run from the checkout:  python3 bench/compile.py [CORPUS_DIR] [--repeat N] [--expect ENI]

The topology cycles through couplers, digital and analog terminals and two CiA 402 drives
(one with DC), 512 slaves in all, so the process data needs three frames.  The corpus has
two differing descriptions of the SOMANET drive: ``--prefer`` takes the vendor's.  Measured
in the same run, interleaved (baseline, candidate, ...), min and median of N, in CPU time
(user + system of the processes: the machine is shared with other jobs) and wall time:

  1. `ecatcfg compile` as a new process, cold (``--no-cache``: index every ESI file, read
     the six that are used, compile, write the ENI) against a new process that only parses
     the same ESI files with lxml and writes an ENI-sized XML tree (the floor for any
     ESI-reading configurator).  Target: at most 1.0 s CPU.
  2. the same compile with a warm index cache.
  3. in-process, the compile step alone (``compile_topology``, devices already loaded) and
     the ENI writer, to show where the time goes.

Before timing, two runs are checked to produce byte-identical ENIs, and with ``--expect``
to be byte-identical to that ENI (one written by the code before a change).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

from timing import cpu_timed, interleaved, ms, ratio, timed

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CORPUS = ROOT.parent / "shared" / "corpus"

# (name prefix, device selector, extra keys) — cycled over the line.
MIX = [
    ("coupler", "EK1100", ""),
    ("di16_", "EL1809", ""),
    ("do8_", "EL2008", ""),
    ("di4_", "EL1004", ""),
    ("do4_", "EL2004", ""),
    ("elmo", '"0x9a:0x30924:0x10420"', ", dc: DC Sync"),
    ("somanet", '"0x22d2:0x201"', ""),
    ("ai", "EL3202", ""),
]

BASELINE = """
import sys
from lxml import etree
trees = [etree.parse(p) for p in sys.argv[2:]]
root = etree.Element("EtherCATConfig")
for tree in trees:                      # an output of the ENI's size, built and serialised
    for el in tree.iter("Entry"):
        e = etree.SubElement(root, "Entry")
        for ch in el:
            etree.SubElement(e, ch.tag).text = ch.text
open(sys.argv[1], "wb").write(etree.tostring(root, pretty_print=True))
"""


def topology(n: int) -> str:
    lines = ["master: {name: bench, cycle_time_us: 1000}", "slaves:"]
    for i in range(n):
        prefix, device, extra = MIX[i % len(MIX)]
        lines.append(f"  - {{name: {prefix}{i}, device: {device}{extra}}}")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("corpus", nargs="?", type=Path, default=DEFAULT_CORPUS)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--slaves", type=int, default=512)
    ap.add_argument("--expect", type=Path, help="an ENI the compile must give byte for byte")
    args = ap.parse_args()
    esi = [args.corpus / "esi" / d for d in ("beckhoff", "drives", "open-stacks")]
    used = [args.corpus / "esi" / p for p in (
        "beckhoff/Beckhoff EK11xx.xml", "beckhoff/Beckhoff EL1xxx.xml",
        "beckhoff/Beckhoff EL2xxx.xml", "beckhoff/Beckhoff EL3xxx.xml",
        "drives/Elmo_ECAT_00010420_V11.xml", "drives/SOMANET_CiA_402.xml")]
    tmp = Path(tempfile.mkdtemp(prefix="ecatcfg-bench-"))
    topo = tmp / "line.yaml"
    topo.write_text(topology(args.slaves))
    esi_args = [a for d in esi for a in ("--esi", str(d))] + [
        "--prefer", str(args.corpus / "esi" / "drives" / "SOMANET_CiA_402.xml")]
    files = sorted(p for d in esi for p in d.rglob("*.xml"))
    print(f"# {args.slaves} slaves; {len(files)} ESI files indexed "
          f"({sum(p.stat().st_size for p in files) / 1e6:.1f} MB), {len(used)} read in full; "
          f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"repeat {args.repeat}")

    def compile_(out: Path, cache: bool) -> None:
        cmd = [sys.executable, "-m", "ecatcfg", "compile", str(topo), *esi_args, "-o",
               str(out)] + ([] if cache else ["--no-cache"])
        subprocess.run(cmd, check=True, capture_output=True)

    a, b = tmp / "a.xml", tmp / "b.xml"
    compile_(a, False)
    compile_(b, True)
    assert a.read_bytes() == b.read_bytes(), "two compiles gave different ENIs"
    print(f"deterministic: yes ({a.stat().st_size / 1e6:.1f} MB ENI, identical bytes)")
    if args.expect is not None:
        assert a.read_bytes() == args.expect.read_bytes(), f"the ENI differs from {args.expect}"
        print(f"identical to {args.expect}: yes")

    def baseline() -> None:
        subprocess.run([sys.executable, "-c", BASELINE, str(tmp / "base.xml"),
                        *map(str, used)], check=True)

    for clock, unit in ((cpu_timed, "CPU"), (timed, "wall")):
        base, cold = interleaved(baseline, lambda: compile_(a, False), args.repeat, clock)
        print(f"cold compile (new process, --no-cache), {unit}: {ms(cold)} ms (min / median); "
              f"lxml parse + write baseline {ms(base)} ms; ratio {ratio(base, cold)}")
        base, warm = interleaved(baseline, lambda: compile_(a, True), args.repeat, clock)
        print(f"warm compile (index cache), {unit}: {ms(warm)} ms; ratio {ratio(base, warm)}")

    sys.path.insert(0, str(ROOT.parent))
    from ecatcfg.compiler import build, topology as topo_mod
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.esi.library import Library
    lib = Library(esi, cache=False,
                  prefer=[args.corpus / "esi" / "drives" / "SOMANET_CiA_402.xml"])
    loaded = topo_mod.load(topo)
    build.compile_topology(loaded, lib)          # loads the device models once
    plans = []
    steps = [cpu_timed(lambda: plans.append(build.compile_topology(loaded, lib).plan))
             for _ in range(args.repeat)]
    writes = [cpu_timed(lambda: eni_writer.to_bytes(plans[0])) for _ in range(args.repeat)]
    print(f"in process, CPU: compile_topology {ms(steps)} ms, ENI writer {ms(writes)} ms")


if __name__ == "__main__":
    main()
