"""Every cyclic command whose working counter is not the expected one counts once per cycle,
in the total and under the command's name (runtime/master/cyclic.py ``CycleStats``): what
`apply` reports as working-counter errors."""

from __future__ import annotations

import pytest

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network

ESI = EXAMPLES / "esi"
CYCLES = 5


@pytest.fixture(scope="module")
def plan() -> NetworkPlan:
    built = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                   Library([ESI], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(built), "example.eni.xml")


def test_a_missing_slave_counts_one_error_per_command_and_cycle(plan):
    # Without recovery, so that nothing but the cycle runs while the slaves are away.
    with Network.virtual(plan, esi=[ESI], recovery=False) as net:
        net.up()
        assert net.state == AlState.OP
        assert all(net.cycle() for _ in range(CYCLES))
        stats = net.master.cyclic.stats
        assert (stats.wkc_errors, stats.wkc_error_cmds) == (0, {})
        net.segment.remove_cable("lamps")              # the lamps and the drive behind them
        assert not any(net.cycle() for _ in range(CYCLES))
        assert stats.lost_frames == 0                  # the frames come back, short of WKC
        assert stats.wkc_error_cmds and set(stats.wkc_error_cmds.values()) == {CYCLES}
        assert stats.wkc_errors == CYCLES * len(stats.wkc_error_cmds)
        net.segment.restore_cable("lamps")             # so that the network can go down
