"""Build a wheel, install it into a fresh venv and run the CLI from there.

This is what catches missing package data (the examples and templates must be inside the
wheel) and generic top-level modules leaking into site-packages.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import venv
import zipfile

from conftest import ROOT
from ecatcfg.cli import main


SUBPACKAGES = ("cli", "esi", "esi.lint", "esi.lint.checks", "esi.lint.formats", "eni",
               "compiler", "runtime", "templates", "examples")
NOT_PACKAGES = ("tests", "bench", "docs", "build_backend")
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
        "ecatcfg-demo"))
    return src, sorted(p.relative_to(src) for p in src.rglob("*") if "__pycache__" not in p.parts)


def listing(src) -> list:
    return sorted(p.relative_to(src) for p in src.rglob("*") if "__pycache__" not in p.parts)


def test_wheel_installs_and_runs(tmp_path):
    # Build from a clean copy, so that nothing from the checkout's own installs hides a
    # missing file, and check that the build leaves nothing behind in the source folder
    # (no build/ with a stale copy of the sources, no egg-info).
    src, before = clean_copy(tmp_path)
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist),
                    str(src)], check=True, capture_output=True)
    assert listing(src) == before, set(listing(src)) - set(before)
    wheel, = dist.glob("ecatcfg-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"ecatcfg"}, top
    assert "ecatcfg/examples/esi/ecatcfg-EXD402-drive.xml" in names
    assert "ecatcfg/examples/topology.yaml" in names
    assert "ecatcfg/examples/ecatcfg-apply.service" in names     # the systemd unit
    assert "ecatcfg/examples/tree/esi/ecatcfg-EXB-branching.xml" in names
    assert "ecatcfg/templates/process_image.h.j2" in names
    assert "ecatcfg/templates/__init__.py" in names
    assert not any(n.startswith("ecatcfg/tests/") or n.startswith("ecatcfg/bench/")
                   for n in names)

    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(wheel)], check=True,
                   capture_output=True, env=VENV_ENV)
    exe = env_dir / "bin" / "ecatcfg"
    run = lambda *a, cwd=ROOT: subprocess.run([str(exe), *a], capture_output=True, text=True,
                                              cwd=cwd, env=VENV_ENV)
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


def test_editable_install_imports_only_real_subpackages_and_leaves_no_litter(tmp_path):
    """``pip install -e .`` maps ``ecatcfg`` onto the source folder, where tests/, bench/ and
    docs/ sit beside the subpackages: they must not import as namespace packages, and the
    install must leave no egg-info behind."""
    src, before = clean_copy(tmp_path)
    env_dir = tmp_path / "venv"
    # the dependencies come from this interpreter's site-packages; the venv's own editable
    # finder for the copy comes first
    venv.create(env_dir, with_pip=True, system_site_packages=True)
    py = env_dir / "bin" / "python"
    out = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "-e", str(src)],
                         capture_output=True, text=True, env=VENV_ENV)
    assert out.returncode == 0, out.stderr
    assert listing(src) == before, set(listing(src)) - set(before)
    where = subprocess.run([str(py), "-c", CHECK_IMPORTS], capture_output=True, text=True,
                           cwd=tmp_path, env=VENV_ENV)
    assert where.returncode == 0, where.stdout + where.stderr
    assert where.stdout.strip() == str(src / "__init__.py")
