"""mypy over the package, as `python -m mypy` runs it in the checkout: `[tool.mypy]` in
pyproject.toml (strict) names the package `ecatcfg` through `.mypy_path/ecatcfg`, a symlink to
the checkout, whatever the checkout folder is called.  Any error fails the test.

mypy keeps its cache in `.mypy_cache` of the checkout (git-ignored): after the first run a
check takes about a second.  The second test shows the check can fail: mypy run with the same
configuration on a small module that misuses the package reports each misuse.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import ROOT


def mypy(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mypy", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def test_the_package_has_no_type_errors():
    out = mypy()
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("Success: no issues found"), out.stdout + out.stderr
    # the whole package, and only the package
    checked = int(out.stdout.split(" in ")[1].split()[0])
    outside = ("tests", "bench", "docs", "build_backend")
    # (a .pyi is a module to mypy too: the compiled cyclic exchange's, runtime/_exchange.pyi)
    modules = [p for p in [*ROOT.rglob("*.py"), *ROOT.rglob("*.pyi")] if not any(
        part in outside or part.startswith(".") for part in p.relative_to(ROOT).parts)]
    assert checked == len(modules), out.stdout


# Each line marked `# E: text` must draw an error whose message contains the text; nothing
# else may.  The records are @record classes (typing.dataclass_transform), the jobs generators.
MISUSE = '''
from ecatcfg.esc import SmConfig
from ecatcfg.eni.plan import InitCmd
from ecatcfg.runtime.master.lockstep import Job, until_answered
from ecatcfg.runtime.wire import Datagram

Datagram(7, 0, 0)                                        # E: Missing positional argument "data"
InitCmd([], "c", 7, 2, adp=1, data=b"\\0\\0", cnt="1")   # E: Argument "cnt" to "InitCmd"
sm = SmConfig(0x1000, 128, 0x26, True)
sm.start = 0x1100                                        # E: is read-only
Datagram(7, 0, 0, b"", wkc=1) == 1                       # E: Non-overlapping equality check


def job(dg: Datagram) -> Job:
    got = yield from until_answered([dg], 1.0, ValueError())
    print(got.wkc)                                       # E: "list[Datagram]" has no attribute
'''


def test_mypy_reports_misuse_of_the_package(tmp_path: Path):
    probe = tmp_path / "probe.py"
    probe.write_text(MISUSE)
    want = {n: line.split("# E: ")[1] for n, line in enumerate(MISUSE.splitlines(), 1)
            if "# E: " in line}
    out = mypy("--config-file", str(ROOT / "pyproject.toml"), str(probe))
    assert out.returncode == 1, out.stdout + out.stderr
    errors = [line for line in out.stdout.splitlines() if ": error: " in line]
    got = {int(line.split(":")[1]): line for line in errors}
    assert set(got) == set(want), out.stdout
    for n, text in want.items():
        assert text in got[n], (text, got[n])
