"""The pysoem export against SOEM itself, over every corpus ENI.

Run from the checkout, as root (network namespaces, AF_PACKET):
    python3 bench/export_agreement.py [--esi] [--sample N] [ENI ...]

For each ENI of both corpora (``eni/`` of the folders named by ``ECATCFG_CORPUS`` and
``ECATCFG_CORPUS_EXTRA``, as for the tests), or the ENIs given: ``ecatcfg export --format
pysoem``, the ENI's slaves emulated as ``ecatcfg simulate --eni`` builds them (from the ENI
alone; with ``--esi`` from the corpora's ESI files where they hold the device) over a veth
pair, and pysoem with the exported module (``tests/export_agreement.py``, the harness the
CI sample of ``tests/test_export_agreement.py`` runs):

- every variable of the module's table against the FMMUs SOEM programmed (byte, bit,
  IOmap byte);
- 5 input patterns set in the emulated slaves read back by name (every bit of each slave
  with fewer than 8 bits, ``--sample`` variables of each other slave), the same for outputs
  written by name.

Each ENI ends as ``agree``, ``disagree`` (listed), ``refused`` (the export names what it
cannot carry), ``partial`` (the emulation kept a slave below OP: the places of every
variable and the data of the slaves in SAFEOP/OP are compared, the reason is printed),
``no-op`` (pysoem with the module did not map the line: the module's error is printed) or
``error`` (the harness failed: printed).  A ``no-op`` or ``error`` is run again, up to
``--tries`` runs (never a disagreement): on a loaded machine the emulated line, a Python
process, sometimes answers a mailbox or EEPROM read after SOEM stopped waiting, and SOEM
takes the timeout as data; the last run's outcome counts, ``retried`` says how many ENIs
needed more than one.  Prints a
line per ENI, the totals, and the totals as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from conftest import CORPORA  # noqa: E402
from export_agreement import agree_in_ci  # noqa: E402
from rig import veth_pair  # noqa: E402


def enis() -> list[Path]:
    return [p for root in CORPORA.values() for p in sorted((root / "eni").rglob("*.xml"))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("eni", nargs="*", type=Path)
    parser.add_argument("--esi", action="store_true",
                        help="emulate from the corpora's ESI files where they hold the device")
    parser.add_argument("--tries", type=int, default=3,
                        help="runs of an ENI that pysoem did not map (default 3)")
    parser.add_argument("--sample", type=int, default=4,
                        help="variables checked per slave with 8 bits or more (default 4)")
    args = parser.parse_args()
    library = None
    if args.esi:
        from ecatcfg.esi.library import Library
        library = Library([root / "esi" for root in CORPORA.values()], cache=False)
    files = args.eni or enis()
    totals: Counter[str] = Counter()
    places = bits_read = bits_written = 0
    disagreements: list[str] = []
    started = time.monotonic()
    for eni in files:
        t0 = time.monotonic()
        with veth_pair("agree") as rig, tempfile.TemporaryDirectory() as tmp:
            try:
                r = agree_in_ci(rig, eni, Path(tmp), library, args.sample, args.tries)
            except Exception as exc:            # reported, the run goes on
                totals["error"] += 1
                print(f"error     {eni}: {type(exc).__name__}: {exc}", flush=True)
                continue
        totals[r.outcome] += 1
        totals["retried"] += r.retried > 0
        places += r.places
        bits_read += r.bits_read
        bits_written += r.bits_written
        disagreements += [f"{eni}: {d}" for d in r.disagreements]
        print(f"{r.outcome:9} {eni} ({r.variables} variables, {r.bits_read} bits read, "
              f"{r.bits_written} written, {time.monotonic() - t0:.1f} s"
              f"{f', run {r.retried + 1}' if r.retried else ''})"
              + (f": {r.detail}" if r.detail else ""), flush=True)
        for d in r.disagreements[:20]:
            print(f"          {d}")
    took = time.monotonic() - started
    summary = {"enis": len(files), **totals, "places_compared": places,
               "bits_read": bits_read, "bits_written": bits_written,
               "disagreements": len(disagreements), "seconds": round(took, 1)}
    print(json.dumps(summary))
    return 1 if disagreements or totals["error"] else 0


if __name__ == "__main__":
    sys.exit(main())
