"""ESI loading benchmark: bare lxml parse vs ecatcfg's index, full model and cached lookup.

Run from the checkout:  python3 bench/esi_load.py [CORPUS_ESI_DIR] [--repeat N]

All three comparisons are measured in the same run against a baseline from the same run,
interleaved (baseline, candidate, baseline, ...) so machine noise hits both; min and median of
N repeats are reported, in CPU time (user + system of the processes: the machine is shared
with other jobs) and in wall time.  Targets:
  1. cold `ecatcfg devices` over the corpus (new process, empty cache)
     within 2.0x of a new process that only parses the same files with lxml;
  2. a full model of every device within 2.0x of bare lxml.etree.parse (in-process):
     every device with every object dictionary read (the reader reads a dictionary when
     it is first asked for, so the bench asks for all of them); shown beside it, the
     model as read before any dictionary is asked for (what a compile pays per file);
  3. a cached library lookup (index from the warm cache + selector) under 50 ms.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from timing import cpu_timed, interleaved, timed

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CORPUS = ROOT.parent / "shared" / "corpus" / "esi"

PARSE_ONLY = """
import sys
from pathlib import Path
from lxml import etree
for p in sorted(Path(sys.argv[1]).rglob('*.xml')):
    etree.parse(str(p))
"""


def files_of(corpus: Path) -> list[Path]:
    return sorted(corpus.rglob("*.xml"))


def row(name: str, b: list[float], c: list[float], target: str) -> str:
    ratio_min = min(c) / min(b)
    ratio_med = statistics.median(c) / statistics.median(b)
    return (f"| {name} | {min(b)*1e3:.0f} / {statistics.median(b)*1e3:.0f} | "
            f"{min(c)*1e3:.0f} / {statistics.median(c)*1e3:.0f} | "
            f"{ratio_min:.2f}x / {ratio_med:.2f}x | {target} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("corpus", nargs="?", type=Path, default=DEFAULT_CORPUS)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    files = files_of(args.corpus)
    size = sum(p.stat().st_size for p in files)

    from lxml import etree

    from ecatcfg.esi import reader
    from ecatcfg.esi.cache import IndexCache
    from ecatcfg.esi.library import Library

    print(f"machine: {platform.node()} {platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, lxml {etree.__version__}")
    print(f"corpus: {len(files)} files, {size / 1e6:.1f} MB ({args.corpus})\n")
    print("| what | baseline ms (min / median) | ecatcfg ms (min / median) | "
          "ratio (min / median) | target |")
    print("|---|---|---|---|---|")

    # 1. cold `ecatcfg devices`, new process, empty cache each time
    with tempfile.TemporaryDirectory() as tmp:
        def cold_devices() -> None:
            cache = tempfile.mkdtemp(dir=tmp)
            subprocess.run([sys.executable, "-m", "ecatcfg", "devices", "--format", "json",
                            str(args.corpus)], check=True, stdout=subprocess.DEVNULL,
                           env={**os.environ, "XDG_CACHE_HOME": cache}, cwd=ROOT)

        def parse_process() -> None:
            subprocess.run([sys.executable, "-c", PARSE_ONLY, str(args.corpus)], check=True)

        for clock, unit in ((cpu_timed, "CPU"), (timed, "wall")):
            b, c = interleaved(parse_process, cold_devices, args.repeat, clock)
            print(row(f"{unit}: cold `ecatcfg devices` (new process, empty cache) vs "
                      "process parsing with lxml", b, c, "<= 2.0x"))

    # 2. full model of every device, in-process
    def bare_parse() -> None:
        for p in files:
            etree.parse(str(p))

    def full_model() -> None:
        for p in files:
            reader.read_file(p).read_dictionaries()

    def without_dictionaries() -> None:
        for p in files:
            reader.read_file(p)

    for clock, unit in ((cpu_timed, "CPU"), (timed, "wall")):
        b, c = interleaved(bare_parse, full_model, args.repeat, clock)
        print(row(f"{unit}: full model of every device, every dictionary read, vs "
                  "`lxml.etree.parse`", b, c, "<= 2.0x"))
        b, c = interleaved(bare_parse, without_dictionaries, args.repeat, clock)
        print(row(f"{unit}: the same before any dictionary is asked for (read on first "
                  "use)", b, c, "-"))

    # 3. cached lookup: warm the cache once, then index-from-cache + find
    with tempfile.TemporaryDirectory() as cache_dir:
        Library([args.corpus], cache=IndexCache(Path(cache_dir)))
        lookups = []
        for _ in range(args.repeat):
            start = time.perf_counter()
            lib = Library([args.corpus], cache=IndexCache(Path(cache_dir)))
            lib.find("EK1100")
            lib.find("0x9a:0x30924")
            lookups.append(time.perf_counter() - start)
        print(f"| cached library lookup (index {len(files)} files from warm cache + 2 "
              f"selectors) | - | {min(lookups)*1e3:.1f} / {statistics.median(lookups)*1e3:.1f}"
              f" | - | < 50 ms |")


if __name__ == "__main__":
    main()
