"""CPU per cycle of the C program ``ecatcfg export --format soem-c`` writes, against SOEM's
own example loop (``test/simple_ng/simple_ng.c`` of SOEM's sources), on the same virtual
segment over veth.

Run from the checkout, as root (network namespaces, AF_PACKET):
    python3 bench/soem_c_cycle.py [--rounds 3] [--cycles 10000]

SOEM's sources come from the pysoem source archive of the corpus
(``$ECATCFG_CORPUS/third-party/pysoem-1.1.13.tar.gz``), unpacked into a temporary folder.

Method:
  1. The example line (examples/topology.yaml: coupler, 2 x EX1004, EX2008, a drive with DC)
     compiled to an ENI and exported with ``--format soem-c``; the export and SOEM's
     simple_ng built with ``gcc -O2`` against SOEM's sources (EC_VER2, as pysoem builds
     SOEM).  ``ecatcfg simulate`` of the line serves namespace B.
  2. Each program runs in namespace A to completion; its CPU time (user + system) comes
     from ``wait4``'s resource usage.  The export runs twice per round: with 0 cycles (the
     set-up alone: config_init, ecatcfg_config_map with the start-up writes, SAFEOP, OP,
     INIT) and with
     ``--cycles`` cycles of 1 ms (each waiting up to 50 ms for its frame, so that a late
     reply of the emulated line is not a lost frame; the working-counter errors are
     reported); its CPU per cycle is the difference over the cycles.
     simple_ng runs its fixed 10,000 iterations (send, receive, print a line, sleep 5 ms);
     its CPU per cycle is its CPU less the export's set-up CPU of the round, over 10,000
     (its own set-up is the same SOEM calls without the start-up writes: an estimate, said
     so).
  3. Min and median over ``--rounds`` rounds, printed as a table and as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from virtual_segment import IF_A, IF_B, Bench, stop, wait_for  # noqa: E402

ARCHIVE = "third-party/pysoem-1.1.13.tar.gz"
SIMPLE_NG_ITERATIONS = 10_000              # fixed in simple_ng.c
# How long the export's cycle waits for its frame (SOEM's default, EC_TIMEOUTRET, is
# 2 ms): the emulated slaves are a Python process, late now and then on a shared machine;
# SOEM's receive polls its socket, so a late reply costs CPU in both programs alike.
REPLY_US = "50000"


def cpu_run(ns: str, argv: list[str]) -> tuple[float, str]:
    """``argv`` in ``ns`` to completion: (its CPU seconds, user + system; its stdout)."""
    with tempfile.TemporaryFile() as out:
        proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], stdout=out,
                                stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read().decode(errors="replace")
    if proc.returncode != 0:
        raise RuntimeError(f"{argv[0]} failed ({proc.returncode}): {text[-2000:]}")
    return usage.ru_utime + usage.ru_stime, text


def build(soem: Path, sources: list[Path], program: Path, defines: list[str]) -> None:
    includes = [f"-I{soem / d}" for d in ("soem", "osal", "osal/linux", "oshw/linux")]
    soem_files = [*sorted((soem / "soem").glob("*.c")), soem / "osal/linux/osal.c",
                  *sorted((soem / "oshw/linux").glob("*.c"))]
    subprocess.run(["gcc", "-O2", "-w", "-D_GNU_SOURCE", "-DEC_VER2", *defines, *includes,
                    *map(str, sources), *map(str, soem_files), "-lpthread", "-lrt", "-o",
                    str(program)], check=True, timeout=300)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=10_000)
    ap.add_argument("--corpus", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus")))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        with tarfile.open(args.corpus / ARCHIVE) as archive:
            archive.extractall(tmp, members=[m for m in archive.getmembers()
                                             if "/soem/" in m.name], filter="data")
        soem = next(tmp.glob("pysoem-*/soem"))
        py = [sys.executable, "-m", "ecatcfg"]
        env_root = str(ROOT.parent)
        os.environ["PYTHONPATH"] = env_root + os.pathsep + os.environ.get("PYTHONPATH", "")
        eni, source = tmp / "line.eni.xml", tmp / "line.c"
        subprocess.run([*py, "compile", str(ROOT / "examples/topology.yaml"), "--esi",
                        str(ROOT / "examples/esi"), "-o", str(eni)], check=True, timeout=120)
        subprocess.run([*py, "export", str(eni), "--format", "soem-c", "-o", str(source)],
                       check=True, timeout=120)
        ours, simple_ng = tmp / "line", tmp / "simple_ng"
        build(soem, [source], ours, ["-DECATCFG_MAIN"])
        build(soem, [soem / "test/simple_ng/simple_ng.c"], simple_ng, [])
        bench = Bench()
        try:
            bench.up()
            sim = bench.start(bench.ns_b, [*py, "simulate", "--esi", str(ROOT / "examples/esi"),
                                           "--topology", str(ROOT / "examples/topology.yaml"),
                                           "--iface", IF_B, "--duration", "3600"])
            wait_for(sim, "ready:", 120)
            rows: dict[str, list[float]] = {"export": [], "simple_ng": [], "setup": [],
                                            "wkc_errors": []}
            for k in range(args.rounds):
                setup, _ = cpu_run(bench.ns_a, [str(ours), IF_A, "0"])
                full, out = cpu_run(bench.ns_a, [str(ours), IF_A, str(args.cycles),
                                                 REPLY_US])
                errors = re.search(r"wkc_errors (\d+)", out)
                if errors is None:
                    raise RuntimeError(f"the export did not cycle: {out}")
                rows["wkc_errors"].append(float(errors.group(1)))
                theirs, _ = cpu_run(bench.ns_a, [str(simple_ng), IF_A])
                rows["setup"].append(setup * 1e3)
                rows["export"].append((full - setup) * 1e6 / args.cycles)
                rows["simple_ng"].append((theirs - setup) * 1e6 / SIMPLE_NG_ITERATIONS)
                print(f"round {k}: set-up {setup * 1e3:.1f} ms CPU; per cycle: export "
                      f"{rows['export'][-1]:.2f} us, simple_ng {rows['simple_ng'][-1]:.2f} us; "
                      f"export working-counter errors {rows['wkc_errors'][-1]:.0f}",
                      flush=True)
            stop(sim)
        finally:
            bench.close()
    print("| program | CPU per cycle, min / median (us) |")
    print("|---|---|")
    for name in ("export", "simple_ng"):
        v = rows[name]
        print(f"| {name} | {min(v):.2f} / {statistics.median(v):.2f} |")
    print(f"set-up CPU (ms, min / median): {min(rows['setup']):.1f} / "
          f"{statistics.median(rows['setup']):.1f}")
    print(json.dumps({k: [round(x, 3) for x in v] for k, v in rows.items()}))


if __name__ == "__main__":
    main()
