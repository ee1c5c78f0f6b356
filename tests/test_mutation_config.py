"""bench/mutation.py's map of modules to focused tests names files that exist, covers the
modules the project keeps a mutation score for, and the run works on a copy of the checkout
that mutmut can read (the working tree itself is never mutated)."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path
from types import ModuleType

import pytest

from conftest import ROOT

# The modules docs/BENCHMARKS.md ("Mutation testing") keeps a score for.
SCORED = {"runtime/master/recovery.py", "runtime/master/hotconnect.py",
          "runtime/segment/eni_device.py", "eni/contents.py", "eoe.py",
          "runtime/segment/eoe_server.py", "runtime/master/cyclic.py",
          "runtime/master/modules.py", "runtime/segment/dc_clock.py",
          "runtime/segment/timing.py", "runtime/wiring.py",
          "runtime/soe.py", "runtime/segment/soe_server.py", "runtime/master/soe_client.py",
          "esi/idn.py", "compiler/soe_cmds.py", "runtime/foe.py",
          "runtime/segment/foe_server.py", "runtime/master/foe_client.py",
          "runtime/master/foe_init.py", "eni/check/copies.py", "compiler/copies.py"}


@pytest.fixture
def mutation(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(ROOT / "bench"))
    monkeypatch.delitem(sys.modules, "mutation", raising=False)
    import mutation as module
    return module


def test_every_scored_module_has_focused_tests_that_exist(mutation):
    config = mutation.load_config()
    assert SCORED <= set(config)
    for module, focus in config.items():
        assert (ROOT / module).is_file(), module
        assert focus.tests, module
        for test in focus.tests:
            assert (ROOT / test).is_file() and Path(test).name.startswith("test_"), test


def test_a_module_is_chosen_by_a_unique_part_of_its_path(mutation):
    config = mutation.load_config()
    assert mutation.select(config, ["recovery"]) == ["runtime/master/recovery.py"]
    assert mutation.select(config, ["eoe.py"]) == ["eoe.py"]          # the exact key wins
    with pytest.raises(SystemExit, match="'eoe' names 2 modules"):
        mutation.select(config, ["eoe"])
    with pytest.raises(SystemExit, match="'nothing' names 0 modules"):
        mutation.select(config, ["nothing"])
    assert mutation.select(config, []) == list(config)


def test_the_copy_has_the_checkout_files_and_no_symlink(mutation, tmp_path):
    mutation.copy_checkout(tmp_path)
    assert (tmp_path / "runtime" / "master" / "recovery.py").read_bytes() == \
        (ROOT / "runtime" / "master" / "recovery.py").read_bytes()
    assert (tmp_path / "tests" / "conftest.py").is_file()
    # .mypy_path/ecatcfg is a symlink to the checkout: copied, it would loop.
    assert not (tmp_path / ".mypy_path").exists()
    assert not any(p.is_symlink() for p in tmp_path.rglob("*"))


def test_mutmut_is_told_the_one_module_and_its_tests(mutation, tmp_path):
    focus = mutation.Focus(["tests/test_timing.py"], ["-k", "not fit"])
    mutation.write_mutmut_config(tmp_path, "runtime/segment/timing.py", focus)
    settings = tomllib.loads((tmp_path / "pyproject.toml").read_text())["tool"]["mutmut"]
    assert settings["source_paths"] == ["ecatcfg"]
    assert settings["only_mutate"] == ["ecatcfg/runtime/segment/timing.py"]
    assert settings["also_copy"] == ["ecatcfg"]
    assert settings["pytest_add_cli_args_test_selection"] == ["ecatcfg/tests/test_timing.py"]
    assert settings["pytest_add_cli_args"][-2:] == ["-k", "not fit"]


def test_a_mutant_is_counted_in_its_function_or_method(mutation):
    # mutmut 3 names: x_<function>__mutmut_<n>, xǁ<class>ǁ<method>__mutmut_<n>.
    base = "ecatcfg.runtime.master.cyclic."
    assert mutation.function_of(base + "x__compile__mutmut_12") == "_compile"
    assert mutation.function_of(base + "xǁ_Preparedǁcopy_slave_to_slave__mutmut_3") == \
        "copy_slave_to_slave"
    assert mutation.function_of(base + "xǁCycleStatsǁ__init____mutmut_1") == "__init__"
