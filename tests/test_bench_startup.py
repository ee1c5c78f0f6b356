"""bench/startup.py reports a master's run that did not reach OP as failed, with what the
master said, and takes its figures over the runs that did (a failed SOEM run has no
config_map time to take)."""

from __future__ import annotations

import sys
from types import ModuleType

import pytest

from conftest import ROOT

SOEM_ERROR = "ConfigMapError: [PacketError(3, 3)]"


@pytest.fixture
def startup(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(ROOT / "bench"))      # its own imports: timing, ...
    monkeypatch.delitem(sys.modules, "startup", raising=False)
    import startup as module
    return module


def apply_run(startup: ModuleType, wall: float) -> object:
    return startup.Run(wall, 500, {
        "ok": True, "frames": {"sent": 400, "lost": 0}, "cycles": {"count": 1},
        "slaves": [{}] * 8,
        "events": ["INIT -> PREOP: ok in 20 ms, 100 frames",
                   "PREOP -> SAFEOP: ok in 200 ms, 200 frames",
                   "SAFEOP -> OP: ok in 100 ms, 99 frames"]},
        [(0.1, "scanning the line"), (0.4, "SAFEOP -> OP: ok")])


def soem_ok(startup: ModuleType, wall: float) -> object:
    return startup.Run(wall, 1800, {"import_s": 0.01, "found": 8, "init_s": 0.04,
                                    "assign_s": 0.2, "iomap": 96, "map_s": 0.3,
                                    "safeop_s": 0.4, "op_s": 0.5, "states": [8],
                                    "op": True})


def soem_failed(startup: ModuleType) -> object:
    # What the SOEM script prints when config_map raises: no map_s, no op.
    return startup.Run(0.3, 900, {"import_s": 0.01, "found": 8, "init_s": 0.04,
                                  "assign_s": 0.2, "error": SOEM_ERROR})


def test_a_failed_soem_run_is_reported_and_left_out_of_the_figures(startup, capsys):
    runs = {"apply": [apply_run(startup, 0.45)], "apply cold": [apply_run(startup, 0.5)],
            "SOEM": [soem_failed(startup), soem_ok(startup, 0.6)]}
    startup.report_line("402x8", runs, {}, startup.Minimum(scan=63), 1)
    out = capsys.readouterr().out
    assert f"SOEM run 1 FAILED (not in OP): {SOEM_ERROR}" in out
    assert "SOEM 1 of 2" in out and "apply 1 of 1" in out
    assert "SOEM 600 / 600" in out                    # the run that reached OP only


def test_no_figures_when_every_soem_run_failed(startup, capsys):
    runs = {"apply": [apply_run(startup, 0.45)], "apply cold": [apply_run(startup, 0.5)],
            "SOEM": [soem_failed(startup)]}
    startup.report_line("402x8", runs, {}, startup.Minimum(scan=63), 1)
    startup.summary({("402x8", "free"): {"runs": runs}},
                    {"402x8": (None, None, None, None, startup.Minimum(scan=63), 1)})
    out = capsys.readouterr().out
    assert "SOEM run 1 FAILED" in out and "SOEM 0 of 1" in out
    assert "| 402x8 | free | no figures" in out
