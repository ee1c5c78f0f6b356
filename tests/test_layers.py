"""The layers of the package (docs/architecture.md): esi at the bottom, eni above it, the
compiler and the runtime above those and never importing each other, cli on top; inside the
runtime, the master and the virtual segment never import each other and the shared codec
imports neither.

import-linter checks the contracts in pyproject.toml over every import statement, relative
and inside functions included.  The other tests show the check can fail: the same contracts
over a copy of the package in which the runtime imports the compiler, the master the
segment, the segment the master or the codec the master are broken.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT


def lint_imports(package_parent: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    if package_parent is not None:          # import ``ecatcfg`` from there, not the checkout
        env["PYTHONPATH"] = str(package_parent)
    return subprocess.run(
        [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command;"
         " sys.exit(lint_imports_command())", "--config", str(ROOT / "pyproject.toml"),
         "--no-cache"], capture_output=True, text=True, env=env, timeout=300)


def test_layers_are_kept():
    out = lint_imports()
    assert out.returncode == 0, out.stdout + out.stderr
    assert "2 kept, 0 broken" in out.stdout, out.stdout


def _copy_with(tmp_path: Path, module: str, sneak: str) -> Path:
    """A copy of the package in which ``module`` (a path below the checkout) gains a
    function with the import statement ``sneak``; the folder to import it from."""
    copy = tmp_path / "ecatcfg"
    # symlinks=True: .mypy_path/ecatcfg links to the checkout itself (pyproject.toml, mypy)
    shutil.copytree(ROOT, copy, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", "tests", "bench", "docs", "__pycache__", "*_cache", "*.egg-info"))
    path = copy / module
    path.write_text(path.read_text() + f"\n\ndef _sneak():\n    {sneak}\n    return None\n")
    return tmp_path


# Relative imports inside a function: the kind a grep for "ecatcfg.compiler" misses.
@pytest.mark.parametrize("module, sneak, contract, line", [
    ("runtime/master/scan.py", "from ...compiler import build",
     "esi < eni < compiler | runtime < examples < cli BROKEN",
     "ecatcfg.runtime.master.scan -> ecatcfg.compiler.build"),
    ("runtime/master/sdo_client.py", "from ..segment import sdo_server",
     "runtime: codec < master | segment < network < watch BROKEN",
     "ecatcfg.runtime.master.sdo_client -> ecatcfg.runtime.segment.sdo_server"),
    ("runtime/segment/slave.py", "from ecatcfg.runtime.master.replay import ApplyError",
     "runtime: codec < master | segment < network < watch BROKEN",
     "ecatcfg.runtime.segment.slave -> ecatcfg.runtime.master.replay"),
    ("runtime/mailbox.py", "from .master import sdo_client",
     "runtime: codec < master | segment < network < watch BROKEN",
     "ecatcfg.runtime.mailbox -> ecatcfg.runtime.master.sdo_client"),
], ids=["runtime-to-compiler", "master-to-segment", "segment-to-master", "codec-to-master"])
def test_an_import_across_the_layers_breaks_a_contract(tmp_path, module, sneak, contract,
                                                        line):
    out = lint_imports(_copy_with(tmp_path, module, sneak))
    assert out.returncode == 1, out.stdout + out.stderr
    assert contract in out.stdout and "1 kept, 1 broken" in out.stdout, out.stdout
    assert line in out.stdout, out.stdout


def test_public_names_import_from_their_homes():
    """The plan model, the ENI reader/writer/cache and the SDO value codec live in ``eni/``
    and ``esi/datatypes.py``; the compiler's old re-export modules are gone (README, "What
    moved"), so nothing imports a second path to them."""
    import importlib

    from ecatcfg.compiler import compile_topology
    from ecatcfg.compiler.build import compile_topology as build_compile
    from ecatcfg.esi import Library, library
    from ecatcfg.runtime import Network
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.network import Network as network_class

    assert compile_topology is build_compile and Library is library.Library
    assert Network is network_class and RawLink.__module__ == "ecatcfg.runtime.link"
    for gone in ("plan", "eni_reader", "eni_writer", "eni_cache", "sdo"):
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module(f"ecatcfg.compiler.{gone}")
