"""The ``Network`` API as docs/runtime.md ("The `Network` API") documents it, on the virtual
segment: ``run(background=True)`` and its :class:`BackgroundRun` (``join``, ``stop``,
``done``, ``error``; leaving the ``with`` block stops it), the callback's signature, a
summary when ``run_stats`` is printed and a named ``state``."""

from __future__ import annotations

import re
import statistics
import threading
import time

import pytest

from conftest import EXAMPLES
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState
from ecatcfg.runtime import BackgroundRun, Network

ESI = EXAMPLES / "esi"



def cycling_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "ecat-cycle"]


class Boom(RuntimeError):
    pass


def test_a_background_run_is_joined_after_its_cycles(example_plan):
    seen: list[object] = []
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        run = net.run(cycles=200, callback=seen.append, background=True)
        assert isinstance(run, BackgroundRun)
        assert run.join(timeout=30) is True
        assert run.done and run.error is None
        assert net.run_stats is not None and net.run_stats.cycles == 200
        # The callback gets the Network itself, once per cycle (the documented signature).
        assert len(seen) == 200 and all(n is net for n in seen)
        assert net.state == AlState.OP
    assert not cycling_threads()


def test_join_with_a_timeout_returns_while_the_run_goes_on_and_stop_ends_it(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        run = net.run(background=True)                  # until stopped
        assert run.join(timeout=0.2) is False and not run.done
        with pytest.raises(EcatcfgError, match="already cycling"):
            net.run(cycles=1, background=True)
        run.stop()
        assert run.done and run.error is None and not cycling_threads()
        counted = net.run_stats.cycles
        assert counted > 0
        assert net.cycle()                          # the network is the caller's again
        again = net.run(cycles=3, background=True)  # and can run anew
        assert again.join(10) and net.run_stats.cycles == 3


def test_the_error_of_a_failed_run_is_raised_by_join(example_plan):
    def callback(n: Network) -> None:
        if n.run_stats is not None and n.run_stats.cycles == 5:
            raise Boom("cycle 5")

    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        run = net.run(cycles=100, callback=callback, background=True)
        with pytest.raises(Boom, match="cycle 5"):
            run.join(timeout=30)
        assert run.done and isinstance(run.error, Boom)
        assert net.run_stats.cycles == 5
    # Joined: leaving the block does not raise it again; the slaves went down.
    assert [s.state for s in net.segment.slaves] == [AlState.INIT] * 5


def test_a_failed_run_nobody_joined_is_raised_when_the_block_ends(example_plan):
    def callback(n: Network) -> None:
        raise Boom("first cycle")

    with pytest.raises(Boom, match="first cycle"):
        with Network.virtual(example_plan, esi=[ESI]) as net:
            net.up()
            run = net.run(cycles=100, callback=callback, background=True)
            deadline = time.monotonic() + 10
            while not run.done and time.monotonic() < deadline:
                time.sleep(0.01)
    assert [s.state for s in net.segment.slaves] == [AlState.INIT] * 5


def test_leaving_the_block_stops_a_run_still_going(example_plan):
    # Was: the way down raced the cycling thread and the run was cut after a cycle.
    seen: list[AlState] = []
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        run = net.run(callback=lambda n: seen.append(n.state), background=True)  # no end
        time.sleep(0.05)
    assert run.done and run.error is None and not cycling_threads()
    # The run ended before the way down began: no cycle of it ran in a lower state.
    assert seen and set(seen) == {AlState.OP}, sorted(set(seen))
    assert net.run_stats is not None and net.run_stats.cycles > 0
    assert [s.state for s in net.segment.slaves] == [AlState.INIT] * 5


def test_the_runtime_md_example_runs_its_cycles(example_plan):
    # docs/runtime.md's example with the virtual segment in place of RawLink("eth1"):
    # the 1000 cycles asked for are run before the block ends.
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        net["lamps.Channel 1-8.Output 1"] = True
        net.cycle()
        run = net.run(cycles=1000, callback=lambda n: None, background=True)
        run.join()
        assert net.run_stats.cycles == 1000 and net.run_stats.lost_frames == 0
        assert net.segment.slaves[3].outputs() == b"\x01"


def test_printed_run_stats_are_a_summary(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        net.run(cycles=50)
        stats = net.run_stats
        text = str(stats)
        assert repr(stats) == text and len(text) < 300, text
        assert "50 cycles" in text and "0 lost frames" in text, text
        found = re.search(r"period min/median/max ([\d.]+)/([\d.]+)/([\d.]+) us over the "
                          r"last (\d+)", text)
        assert found, text
        periods = stats.periods_us
        assert int(found[4]) == len(periods) == 49          # periods between 50 cycles
        for shown, value in zip(found.groups()[:3], (min(periods),
                                                     statistics.median(periods),
                                                     max(periods))):
            assert float(shown) == pytest.approx(value, abs=0.051)


def test_late_cycles_are_counted(example_plan):
    # A callback longer than the ENI's cycle time: every cycle ends after the next one's
    # deadline.
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        period = net.master.cyclic.cycle_time_us / 1e6
        net.run(cycles=10, callback=lambda n: n.clock.sleep(2 * period))
        assert net.run_stats.late == 10
        assert "10 late" in str(net.run_stats)


def test_the_state_prints_its_name(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        assert str(net.state) == "INIT"
        net.up()
        assert (str(net.state), f"{net.state}") == ("OP", "OP")
        assert net.state == 8 and int(net.state) == 8 and isinstance(net.state, AlState)
        assert f"{net.state:d}" == "8"
