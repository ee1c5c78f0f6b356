"""Build a wheel, install it into a fresh venv and run the CLI from there.

This is what catches missing package data (the examples and templates must be inside the
wheel), subpackages missing from the wheel (``check``, ``report`` and ``export`` once ended in
ModuleNotFoundError from an installed package while the editable checkout passed)
and generic top-level modules leaking into site-packages.  The wheel is built and installed
once per module; every subcommand then runs from it: its ``--help``, a run of each command
that takes a file, and the suite's end-to-end command-line tests (``tests/installed.py``).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

import rig
from conftest import ROOT
from ecatcfg.cli import SUBCOMMANDS, main


def package_folders(root: Path) -> list[str]:
    """The subpackages a wheel must hold, found from the tree itself (every folder with an
    ``__init__.py`` outside the folders that are not part of the package), so a new
    subpackage is expected without editing a list."""
    found = []
    for init in sorted(root.rglob("__init__.py")):
        rel = init.parent.relative_to(root)
        if rel.parts and rel.parts[0] in NOT_PACKAGES + (".mypy_path",):
            continue
        if any(part.startswith(".") or part == "__pycache__" for part in rel.parts):
            continue
        if rel.parts:
            found.append(".".join(rel.parts))
    return found


NOT_PACKAGES = ("tests", "bench", "docs", "build_backend")
# The optional compiled cyclic exchange (runtime/_exchange.c), as a build names it, and
# whether this machine has the C compiler the build would use (sysconfig's CC).
EXTENSION = Path("runtime") / ("_exchange" + sysconfig.get_config_var("EXT_SUFFIX"))
HAS_COMPILER = shutil.which((sysconfig.get_config_var("CC") or "cc").split()[0]) is not None
SUBPACKAGES = tuple(package_folders(ROOT))

CHECK_IMPORTS = f"""
import importlib
for name in {SUBPACKAGES!r}:
    importlib.import_module("ecatcfg." + name)
for name in {NOT_PACKAGES!r}:
    try:
        importlib.import_module("ecatcfg." + name)
    except ModuleNotFoundError:
        continue
    raise SystemExit("ecatcfg." + name + " imports")
import ecatcfg
print(ecatcfg.__file__)
"""


# The venvs must see their own install only: a PYTHONPATH (a worktree's) would put another
# ecatcfg in front of it.
VENV_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def clean_copy(tmp_path) -> tuple:
    """A copy of the checkout without build products, and a listing of what it holds."""
    src = tmp_path / "src"
    # symlinks=True: .mypy_path/ecatcfg links to the checkout itself (pyproject.toml, mypy)
    shutil.copytree(ROOT, src, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", "build", "dist", "*.egg-info", "__pycache__", "*_cache", ".hypothesis",
        "ecatcfg-demo", "*.so"))
    return src, sorted(p.relative_to(src) for p in src.rglob("*") if "__pycache__" not in p.parts)


def listing(src) -> list:
    return sorted(p.relative_to(src) for p in src.rglob("*") if "__pycache__" not in p.parts)


class Installed:
    """The wheel built from a clean copy of the checkout, installed in a fresh venv."""

    def __init__(self, base: Path) -> None:
        # Build from a clean copy, so that nothing from the checkout's own installs hides a
        # missing file, and check that the build leaves nothing behind in the source folder
        # (no build/ with a stale copy of the sources, no egg-info).
        self.base = base
        src, before = clean_copy(base)
        dist = base / "dist"
        subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                        str(dist), str(src)], check=True, capture_output=True)
        self.litter = set(listing(src)) - set(before)
        self.wheel, = dist.glob("ecatcfg-*.whl")
        self.env_dir = base / "venv"
        venv.create(self.env_dir, with_pip=True)
        self.python = self.env_dir / "bin" / "python"
        subprocess.run([str(self.python), "-m", "pip", "install", "-q", str(self.wheel)],
                       check=True, capture_output=True, env=VENV_ENV)
        self.exe = self.env_dir / "bin" / "ecatcfg"

    def run(self, *args: str | Path, cwd: Path = ROOT,
            timeout: float = 120) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(self.exe), *map(str, args)], capture_output=True,
                              text=True, cwd=cwd, env=VENV_ENV, timeout=timeout)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Installed:
    return Installed(tmp_path_factory.mktemp("wheel"))


def test_wheel_installs_and_runs(installed, tmp_path):
    assert not installed.litter, installed.litter
    wheel, env_dir, py = installed.wheel, installed.env_dir, installed.python
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"ecatcfg"}, top
    # every subpackage of the tree is in the wheel, found without a list kept by hand
    assert {"eni.check", "eni.export", "runtime.master"} <= set(SUBPACKAGES)
    missing = [s for s in SUBPACKAGES if f"ecatcfg/{s.replace('.', '/')}/__init__.py" not in names]
    assert not missing, f"subpackages missing from the wheel: {missing}"
    assert "ecatcfg/examples/esi/ecatcfg-EXD402-drive.xml" in names
    assert "ecatcfg/examples/topology.yaml" in names
    assert "ecatcfg/examples/ecatcfg-apply.service" in names     # the systemd unit
    assert "ecatcfg/examples/tree/esi/ecatcfg-EXB-branching.xml" in names
    assert "ecatcfg/templates/process_image.h.j2" in names
    assert "ecatcfg/templates/__init__.py" in names
    # the compiled cyclic exchange where the build found a C compiler, and --version says
    # which path runs
    assert (f"ecatcfg/{EXTENSION.as_posix()}" in names) is HAS_COMPILER, names
    out = installed.run("--version")
    assert out.returncode == 0 and out.stdout.splitlines()[1] == \
        f"cyclic exchange: {'compiled' if HAS_COMPILER else 'pure Python'}", out.stdout
    assert not any(n.startswith(("ecatcfg/tests/", "ecatcfg/bench/", "ecatcfg/docs/",
                                 "ecatcfg/build_backend/", "ecatcfg/.mypy_path"))
                   for n in names)
    run = lambda *a, cwd=ROOT: installed.run(*a, cwd=cwd)
    out = run("--help")
    assert out.returncode == 0 and "devices" in out.stdout
    out = run("devices", "examples/")
    assert out.returncode == 0 and "EXD-402" in out.stdout, out.stderr
    out = run("lint", "examples/", "--no-config", "--jobs", "2")   # rules load from the wheel
    assert out.returncode == 0 and "0 errors, 0 warnings" in out.stdout, out.stderr
    out = run("demo", cwd=tmp_path)        # the embedded default: package data only
    assert out.returncode == 0 and "LRW (WKC 7)" in out.stdout, out.stderr
    # ... and applied on the virtual segment: every slave in OP, process data both ways.
    # (state and highest state: the demo's table is printed while the slaves are in OP)
    assert "SAFEOP -> OP: OP" in out.stdout and len(re.findall(
        r"│ OP\s+│ OP\s+│", out.stdout)) == 5, out.stdout
    assert "0x0237    7000" in out.stdout and "00000001     11101100" in out.stdout
    assert "PREOP -> INIT: INIT" in out.stdout
    assert (tmp_path / "ecatcfg-demo" / "demo.h").is_file()     # template from the wheel
    out = run("compile", str(ROOT / "examples" / "topology.yaml"), "--esi",
              str(ROOT / "examples" / "esi"), "-o", str(tmp_path / "w.xml"))
    assert out.returncode == 0, out.stderr
    # the installed compiler gives the same bytes as the demo's embedded run, and as the
    # checkout (whose output test_compile validates against the ETG ENI schema)
    wheel_eni = (tmp_path / "w.xml").read_bytes()
    assert wheel_eni == (tmp_path / "ecatcfg-demo" / "demo.eni.xml").read_bytes()
    assert main(["compile", str(ROOT / "examples" / "topology.yaml"), "--esi",
                 str(ROOT / "examples" / "esi"), "-o", str(tmp_path / "c.xml")]) == 0
    assert wheel_eni == (tmp_path / "c.xml").read_bytes()
    # the installed module is the wheel's, not the checkout's, and only its real
    # subpackages import
    where = subprocess.run([str(py), "-c", CHECK_IMPORTS], capture_output=True, text=True,
                           cwd=tmp_path, env=VENV_ENV)
    assert where.returncode == 0, where.stdout + where.stderr
    assert str(env_dir) in where.stdout


def _commands(help_text: str) -> list[str]:
    """The (sub)commands a ``--help`` lists: the entries under the metavar of its
    ``positional arguments`` (argparse indents each by four spaces there)."""
    section = help_text.split("positional arguments:", 1)[-1].split("\n\n", 1)[0]
    return re.findall(r"^    ([a-z][a-z0-9-]*)(?:\s{2,}|$)", section, re.M) \
        if "positional arguments:" in help_text else []


def test_every_subcommand_and_its_subcommands_have_help_from_the_wheel(installed):
    top = installed.run("--help")
    assert top.returncode == 0, top.stderr
    assert _commands(top.stdout) == list(SUBCOMMANDS)       # the wheel offers every command
    helped = []
    for name in SUBCOMMANDS:
        out = installed.run(name, "--help")
        assert out.returncode == 0 and out.stdout.startswith("usage: ecatcfg " + name), (
            name, out.stderr[-2000:])
        helped.append(name)
        for inner in _commands(out.stdout):
            deeper = installed.run(name, inner, "--help")
            assert deeper.returncode == 0 and "usage:" in deeper.stdout, (
                name, inner, deeper.stderr[-2000:])
            helped.append(f"{name} {inner}")
    assert {"sii build", "sii show", "sdo read", "soe write", "foe read"} <= set(helped)


def test_each_command_that_takes_a_file_runs_from_the_wheel(installed, tmp_path):
    """A run of each command that reads a file, from the installed package: what a user
    does first with each; the outputs are checked for what each command writes."""
    esi, topo = ROOT / "examples" / "esi", ROOT / "examples" / "topology.yaml"
    eni, header = tmp_path / "line.eni.xml", tmp_path / "line.h"

    def ok(*args: str | Path, codes: tuple[int, ...] = (0,)) -> str:
        out = installed.run(*args, cwd=tmp_path)
        assert out.returncode in codes and "Traceback" not in out.stderr, (
            args, out.returncode, out.stderr[-3000:])
        return out.stdout

    ok("compile", topo, "--esi", esi, "-o", eni, "--header", header)
    assert eni.read_bytes().startswith(b"<?xml") and b"#define" in header.read_bytes()
    assert "1 file checked: 0 errors" in ok("check", eni, "--esi", esi)
    assert "'coupler' 0xE0000ECA:0x00001001" in ok("show", eni)
    assert ok("diff", eni, eni).strip() == "no differences"
    ok("report", eni, "-o", tmp_path / "line.html")
    assert b"<html" in (tmp_path / "line.html").read_bytes()[:2000].lower()
    formats = re.search(r"--format \{([a-z0-9,-]+)\}", ok("export", "--help")).group(1).split(",")
    assert {"pysoem", "soem-c"} <= set(formats), formats
    exported = []
    for fmt in formats:
        # Each format runs from the wheel; one that cannot express the example (lcec: an
        # entry mapped twice in one slave's PDOs) refuses it by name, exit 1, no traceback.
        out = tmp_path / f"export-{fmt}"
        done = installed.run("export", eni, "--format", fmt, "-o", out, cwd=tmp_path)
        assert "Traceback" not in done.stderr, (fmt, done.stderr[-3000:])
        if done.returncode == 0:
            assert out.stat().st_size > 0, fmt
            exported.append(fmt)
        else:
            assert done.returncode == 1 and str(eni) in done.stderr, (fmt, done.stderr)
    assert {"pysoem", "soem-c"} <= set(exported), exported
    assert ok("graph", eni).startswith('digraph "example-line"')
    ok("graph", eni, "-o", tmp_path / "line.dot")
    assert (tmp_path / "line.dot").read_text().startswith('digraph "example-line"')
    assert "3 files checked: 0 errors" in ok("lint", esi, "--no-config")
    assert "EXD-402" in ok("devices", esi)
    ok("sii", "build", esi, "--device", "EXD-402", "-o", tmp_path / "drive.bin")
    assert "vendor 0xE0000ECA  product 0x00007201" in ok("sii", "show", tmp_path / "drive.bin")
    applied = ok("apply", eni, "--virtual", "--esi", esi, "--cycles", "20")
    assert "SAFEOP -> OP: OP" in applied and "PREOP -> INIT: INIT" in applied, applied


def test_simulate_runs_from_the_wheel_for_a_second(installed, tmp_path):
    """``simulate`` from the installed package answers on an interface (a veth end in a
    namespace of the test's own) and stops by itself after ``--duration``."""
    rig.require_netns()
    with rig.veth_pair("whl") as pair:
        done = pair.run_in(pair.ns_b, [str(installed.exe), "simulate", "--esi",
                                       str(ROOT / "examples" / "esi"), "--topology",
                                       str(ROOT / "examples" / "topology.yaml"), "--iface",
                                       pair.if_b, "--duration", "1", "--no-cache"],
                           timeout=120, cwd=tmp_path, env=VENV_ENV)
    assert done.returncode == 0, done.stderr[-3000:]
    assert any(line.startswith("ready:") for line in done.stdout.splitlines()), done.stdout


# The end-to-end command-line tests of the suite: the command-line contract, the README's
# tour and every example of the README and docs/ (tests/installed.py routes their commands).
E2E_TESTS = ("tests/test_cli.py", "tests/test_readme_tour.py", "tests/test_doc_examples.py")


def test_the_suites_command_line_tests_pass_against_the_wheel(installed):
    env = {**VENV_ENV, "ECATCFG_TEST_PYTHON": str(installed.python)}
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-x", *E2E_TESTS], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=1200)
    tail = done.stdout[-4000:]
    assert done.returncode == 0, tail + done.stderr[-2000:]
    assert re.search(r"\b\d+ passed", tail) and " skipped" not in tail.splitlines()[-1], tail


def test_the_installed_command_is_the_wheels_when_the_tests_run_against_it(installed):
    """``tests/installed.py`` really runs the installed package: its isolated interpreter
    imports the venv's ecatcfg, not the checkout, whatever the environment says."""
    env = {**os.environ, "ECATCFG_TEST_PYTHON": str(installed.python),
           "PYTHONPATH": str(ROOT / ".mypy_path")}
    done = subprocess.run([sys.executable, "-c", "import installed, subprocess; "
                           "print(subprocess.run([*installed.PYTHON, '-c', 'import ecatcfg; "
                           "print(ecatcfg.__file__)'], capture_output=True, text=True).stdout)"],
                          cwd=ROOT / "tests", env=env, capture_output=True, text=True)
    assert str(installed.env_dir) in done.stdout, done.stdout + done.stderr


def venv_with_test_dependencies(env_dir: Path) -> Path:
    """A new venv's python that sees the test dependencies.  They come from the
    site-packages of the interpreter running the tests, which is a venv's when README
    command 2 was run in one (a venv made with system_site_packages sees only the base
    interpreter's: lxml was missing there).  A plain path in a .pth file does not run that
    folder's own .pth files, so the checkout's editable finder stays out; the venv's own
    finder for what is installed into it comes first."""
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    inner = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                           capture_output=True, text=True, check=True).stdout.strip()
    outer = [p for p in sys.path if p.endswith("-packages") and os.path.isdir(p)]
    (Path(inner) / "zz-test-dependencies.pth").write_text("\n".join(outer) + "\n")
    return py


def test_editable_install_imports_only_real_subpackages_and_leaves_no_litter(tmp_path):
    """``pip install -e .`` maps ``ecatcfg`` onto the source folder, where tests/, bench/ and
    docs/ sit beside the subpackages: they must not import as namespace packages, and the
    install must leave no egg-info behind."""
    src, before = clean_copy(tmp_path)
    py = venv_with_test_dependencies(tmp_path / "venv")
    out = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "-e", str(src)],
                         capture_output=True, text=True, env=VENV_ENV)
    assert out.returncode == 0, out.stderr
    # The one exception: the compiled cyclic exchange is built into the source folder,
    # since the editable package *is* that folder (setuptools builds extensions in place
    # for editable installs; docs/architecture.md); nothing else (no .o, no build/).
    assert set(listing(src)) - set(before) == ({EXTENSION} if HAS_COMPILER else set()), \
        set(listing(src)) - set(before)
    assert set(before) <= set(listing(src))
    where = subprocess.run([str(py), "-c", CHECK_IMPORTS], capture_output=True, text=True,
                           cwd=tmp_path, env=VENV_ENV)
    assert where.returncode == 0, where.stdout + where.stderr
    assert where.stdout.strip() == str(src / "__init__.py")


def test_a_build_without_a_c_compiler_installs_and_cycles_in_pure_python(tmp_path):
    """README command 1 on a machine without a C compiler (CC=/bin/false): the build
    leaves the compiled exchange out with a warning instead of failing, the wheel installs,
    ``ecatcfg --version`` reports the pure-Python path, and the demo reaches OP."""
    src, before = clean_copy(tmp_path)
    dist = tmp_path / "dist"
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                            str(dist), str(src)], capture_output=True, text=True,
                           env={**os.environ, "CC": "/bin/false"})
    assert built.returncode == 0, built.stderr
    assert listing(src) == before, set(listing(src)) - set(before)
    wheel, = dist.glob("ecatcfg-*.whl")
    assert not any(n.endswith(".so") for n in zipfile.ZipFile(wheel).namelist())
    py = venv_with_test_dependencies(tmp_path / "venv")
    done = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", str(wheel)],
                          capture_output=True, text=True, env=VENV_ENV)
    assert done.returncode == 0, done.stderr
    exe = py.parent / "ecatcfg"
    out = subprocess.run([str(exe), "--version"], capture_output=True, text=True,
                         env=VENV_ENV, timeout=60)
    assert out.stdout.splitlines()[1] == "cyclic exchange: pure Python", out.stdout + out.stderr
    out = subprocess.run([str(exe), "demo"], capture_output=True, text=True, env=VENV_ENV,
                         cwd=tmp_path, timeout=300)
    assert out.returncode == 0 and "SAFEOP -> OP: OP" in out.stdout, out.stdout + out.stderr
