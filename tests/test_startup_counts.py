"""Start-up kept fast by counts that cannot flake: the frames to OP on fixed lines,
the modules ``apply`` imports on its success path and the memory a cycle allocates must not
grow beyond tests/startup_budget.toml.  None of them depends on the host's speed or load:
the line answers inside ``send`` on a simulated clock (tests/startup_counts.py), an import
happens or not, tracemalloc counts bytes.  A change that needs more moves the budget in its
own commit with its reason; times stay in bench/ (bench/startup.py)."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import pytest

import startup_counts as counts

BUDGET = tomllib.loads((Path(__file__).parent / "startup_budget.toml").read_text())


@pytest.mark.parametrize("line", list(BUDGET["frames_to_op"]))
def test_frames_to_op_within_budget(line: str) -> None:
    n, _, dc = line.partition(" ")
    got = counts.frames_to_op(int(n), dc == "dc")
    budget = BUDGET["frames_to_op"][line]
    assert got["total"] <= budget, (
        f"{got['total']} frames to OP on the {line} line, budget {budget} "
        f"(tests/startup_budget.toml); per step: {got}")


def test_frame_counts_do_not_depend_on_the_host(monkeypatch: pytest.MonkeyPatch) -> None:
    """The same line twice gives the same count, step by step, also when the host stalls
    the test for longer than a reply's timeout (20 ms) while the master waits for each of
    the first 40 replies: nothing in the count is paced by the host's clock (a count that
    moved with the load would make the budget flaky)."""
    import time
    calm = counts.frames_to_op(8, True)
    assert counts.frames_to_op(8, True) == calm
    recv = counts.SimLink.recv
    stalled: set[int] = set()

    def stalling(self: counts.SimLink, timeout: float | None = None) -> bytes | None:
        if self.frames <= 40 and self.frames not in stalled:
            stalled.add(self.frames)
            time.sleep(0.025)           # the host away; the reply not yet seen
            return None
        return recv(self, timeout)
    monkeypatch.setattr(counts.SimLink, "recv", stalling)
    assert counts.frames_to_op(8, True) == calm
    assert len(stalled) == 40


def test_the_frame_budget_sees_one_more_frame_per_slave(monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    """The guard is not blind: one more round per slave chain (a read of each slave's AL
    status before its InitCmds of every transition) exceeds the budget."""
    from ecatcfg.esc import Cmd, Reg
    from ecatcfg.runtime.master import bringup
    from ecatcfg.runtime.wire import Datagram
    job = bringup.slave_transition_job

    def with_extra_read(slave, *args, **kwargs):            # type: ignore[no-untyped-def]
        yield [Datagram.physical(Cmd.APRD, -slave.position & 0xFFFF, Reg.AL_STATUS, 2)]
        yield from job(slave, *args, **kwargs)
    monkeypatch.setattr(bringup, "slave_transition_job", with_extra_read)
    got = counts.frames_to_op(8, False)
    assert got["total"] > BUDGET["frames_to_op"]["8"]


@pytest.fixture(scope="module")
def success_imports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[str]]:
    """What ``apply`` imports on the 8-slave line (a coupler, I/O terminals and two CiA 402
    drives with CoE InitCmds), the second run: its plan then comes from the cache."""
    from ecatcfg.eni import writer
    folder = tmp_path_factory.mktemp("imports")
    plan, _ = counts.compile_line(8, False)
    eni = folder / "line8.eni.xml"
    eni.write_bytes(writer.to_bytes(plan))
    env = counts.env_for(folder / "cache")
    cold = counts.apply_imports(eni, folder / "cold.json", env)
    warm = counts.apply_imports(eni, folder / "warm.json", env)
    for run in (cold, warm):
        assert run["code"] == 0 and run["report"]["ok"], run["stderr"][-3000:]
    return {"cold": cold["modules"], "warm": warm["modules"]}


def test_the_success_path_imports_only_the_budgeted_modules(
        success_imports: dict[str, list[str]]) -> None:
    warm = success_imports["warm"]
    budget = BUDGET["imports"]
    ours = {m for m in warm if m.startswith("ecatcfg")}
    assert ours <= set(budget["ecatcfg"]), sorted(ours - set(budget["ecatcfg"]))
    # Everything else is the standard library's or a third party's, each on its list.
    # A budgeted standard-library package covers its submodules (typing.io of typing).
    others = {m for m in set(warm) - ours if m.split(".")[0] not in budget["stdlib"]}
    assert others <= set(budget["third_party"]), sorted(others - set(budget["third_party"]))
    assert set(budget["stdlib"]) <= set(sys.stdlib_module_names)


def test_what_only_a_refusal_needs_is_not_imported_on_a_cold_start(
        success_imports: dict[str, list[str]]) -> None:
    """The first apply of an ENI parses it (lxml, eni/reader.py), but it still imports
    nothing that only explains a refusal or completes a partial ENI."""
    cold = set(success_imports["cold"])
    for name in ("ecatcfg.runtime.master.diagnose", "ecatcfg.esi.library", "ecatcfg.esi.model",
                 "ecatcfg.eni.derive", "ecatcfg.runtime.segment"):
        assert name not in cold
    assert "ecatcfg.eni.reader" in cold and "lxml.etree" in cold        # it did parse


@pytest.mark.parametrize("line", ["8", "64 dc"])
def test_allocations_per_cycle_within_budget(line: str) -> None:
    n, _, dc = line.partition(" ")
    got = counts.cycle_allocations_alone(int(n), dc == "dc")
    assert got["misses"] == 0           # every reply replayed: the master measured alone
    for what in ("peak", "retained"):
        budget = BUDGET["allocations"][f"{line} {what}"]
        assert got[what] <= budget, (f"{line} line: {what} {got[what]} bytes per cycle, "
                                     f"budget {budget} (tests/startup_budget.toml)")


def test_the_allocation_budget_sees_a_leak_and_a_copy(monkeypatch: pytest.MonkeyPatch) -> None:
    """The guard is not blind: a cycle that keeps one small object (a leak) or copies its
    frame's datagrams into a list exceeds the budget."""
    from ecatcfg.runtime.master import bringup
    kept: list[object] = []
    cycle = bringup.Master.cycle

    def leaking(self: bringup.Master) -> bool:
        kept.append((len(kept),))
        return cycle(self)
    monkeypatch.setattr(bringup.Master, "cycle", leaking)
    got = counts.cycle_allocations(8, False)
    assert got["retained"] > BUDGET["allocations"]["8 retained"]

    # A cycle that decodes its reply into Datagram objects (the configuration path's way)
    # instead of matching it in place (runtime/master/cyclic.py).
    from ecatcfg.runtime import wire
    from ecatcfg.runtime.master.transport import Transport
    exchange = Transport.exchange_prepared

    def decoding(self: Transport, prepared, reply, timeout=None):  # type: ignore[no-untyped-def]
        size = exchange(self, prepared, reply, timeout)
        wire.decode(bytes(reply[:size]))
        return size
    monkeypatch.undo()
    monkeypatch.setattr(Transport, "exchange_prepared", decoding)
    got = counts.cycle_allocations(8, False)
    assert got["peak"] > BUDGET["allocations"]["8 peak"]
