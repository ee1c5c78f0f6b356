"""The suite on a busy machine: is it red only when the code is wrong?

Run from the checkout:  python3 bench/loaded_host.py [--runs 3] [--hogs 4] [-- PYTEST_ARGS...]

A user's machine is rarely idle: a build, a browser, another test run.  A test that fails
because the host was busy for a few tens of milliseconds teaches everyone to rerun instead of
read.  This script starts ``--hogs`` CPU hogs (``while True: pass`` processes, twice the cores
of the project's 2-core machine by default) *before* the first run, runs the whole suite
``--runs`` times in a row while they spin, and kills them after the last run.  It prints one
line per run (passed, failed, expected failures, wall time, load average), the node ids
of every failure and the end of each failure's report (from pytest's JUnit XML report of
the run; ``--reports DIR`` keeps those files); the exit status is 1 when any run had a
failure.

The suite's own settings apply (pytest's configuration in pyproject.toml); extra pytest
arguments follow ``--``.  Nothing here changes what a test expects: a failure under load is
a finding, to be fixed in the test (simulated time, a tolerance that measures) or the code.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HOG = "while True: pass"
# pytest's last line: "N failed, M passed, K xfailed in 700.12s (0:11:40)"
_COUNT = re.compile(r"(\d+) (passed|failed|xfailed|errors?|skipped|xpassed)")


def start_hogs(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(n)]


def stop_hogs(hogs: list[subprocess.Popen[bytes]]) -> None:
    for p in hogs:
        p.send_signal(signal.SIGKILL)
    for p in hogs:
        p.wait()


def one_run(pytest_args: list[str], junit: Path) -> tuple[dict[str, int], list[str], float,
                                                         str]:
    """The suite once: (counts by outcome, failed node ids, wall seconds, pytest's last line).
    pytest's JUnit XML report goes to ``junit``: it keeps each failure's whole text."""
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-rfE", f"--junitxml={junit}", *pytest_args], cwd=ROOT,
                          capture_output=True, text=True,
                          # pytest cuts the summary's reasons to the terminal's width
                          env=dict(os.environ, COLUMNS="400"))
    wall = time.monotonic() - t0
    lines = proc.stdout.strip().splitlines()
    summary = lines[-1] if lines else proc.stderr.strip()[-200:]
    counts: dict[str, int] = {}
    for n, what in _COUNT.findall(summary):
        counts["errors" if what.startswith("error") else what] = int(n)
    # The node id and pytest's one-line reason ("FAILED id - AssertionError: ..."), cut
    # to a line: what the host did, or the code, is then readable from the report alone.
    failed = [line.split(" ", 1)[1][:300] for line in lines
              if line.startswith(("FAILED ", "ERROR "))]
    if proc.returncode not in (0, 1) and not counts:
        counts["errors"] = 1       # pytest itself could not run: a usage or collection error
        failed.append(f"pytest exited {proc.returncode}: {summary}")
    return counts, failed, wall, summary


def failure_texts(junit: Path, tail: int = 60) -> list[str]:
    """The last ``tail`` lines of each failed or erroring test's report in a JUnit XML file
    of pytest (what the one-line reason leaves out: apply's stderr, the values compared)."""
    from lxml import etree
    if not junit.is_file():
        return []
    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=True)
    out = []
    for case in etree.parse(str(junit), parser).iter("testcase"):
        for bad in [*case.iterfind("failure"), *case.iterfind("error")]:
            lines = (bad.text or bad.get("message") or "").splitlines()[-tail:]
            out.append(f"{case.get('classname')}::{case.get('name')}\n" + "\n".join(
                "    " + line for line in lines))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--hogs", type=int, default=2 * (os.cpu_count() or 2))
    ap.add_argument("--reports", type=Path, default=None, metavar="DIR",
                    help="keep pytest's JUnit XML report of each run here (default: a "
                         "temporary folder, removed at the end)")
    ap.add_argument("pytest_args", nargs="*", help="after --: passed to pytest")
    args = ap.parse_args()
    reports = args.reports or Path(tempfile.mkdtemp(prefix="loaded-host-"))
    reports.mkdir(parents=True, exist_ok=True)
    print(f"# {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; "
          f"{args.hogs} CPU hogs from before the first run to after the last")
    hogs = start_hogs(args.hogs)
    bad = 0
    try:
        time.sleep(1.0)       # the hogs are spinning before the suite starts
        for run in range(1, args.runs + 1):
            junit = reports / f"run-{run}.xml"
            counts, failed, wall, summary = one_run(args.pytest_args, junit)
            load = os.getloadavg()[0]
            print(f"run {run}: {summary}  [wall {wall:.0f} s, load average {load:.1f}]",
                  flush=True)
            for reason in failed:
                print(f"  failed: {reason}", flush=True)
            for text in failure_texts(junit):
                print(f"  --- {text}", flush=True)
            bad += counts.get("failed", 0) + counts.get("errors", 0)
    finally:
        stop_hogs(hogs)
        if args.reports is None:
            shutil.rmtree(reports, ignore_errors=True)
    print(f"# {bad} failure(s) in {args.runs} run(s) under load")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
