"""The layers of the package (docs/architecture.md): esi at the bottom, eni above it, the
compiler and the runtime above those and never importing each other, cli on top.

import-linter checks the contract in pyproject.toml over every import statement, relative
and inside functions included.  The second test shows the check can fail: the same contract
over a copy of the package in which the runtime imports the compiler is broken.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

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
    assert "1 kept, 0 broken" in out.stdout, out.stdout


def test_a_runtime_module_importing_the_compiler_breaks_the_contract(tmp_path):
    copy = tmp_path / "ecatcfg"
    # symlinks=True: .mypy_path/ecatcfg links to the checkout itself (pyproject.toml, mypy)
    shutil.copytree(ROOT, copy, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", "tests", "bench", "docs", "__pycache__", "*_cache", "*.egg-info"))
    scan = copy / "runtime" / "master" / "scan.py"
    # a relative import inside a function, the kind a grep for "ecatcfg.compiler" misses
    scan.write_text(scan.read_text() + "\n\ndef _sneak():\n    from ...compiler import build\n"
                    "    return build\n")
    out = lint_imports(tmp_path)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "ecatcfg.runtime.master.scan -> ecatcfg.compiler.build" in out.stdout, out.stdout


def test_public_names_import_from_their_homes():
    """The plan model, the ENI reader/writer/cache and the SDO value codec live in ``eni/``
    and ``esi/datatypes.py``; the compiler's old re-export modules are gone (README, "What
    moved"), so nothing imports a second path to them."""
    import importlib

    import pytest

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
