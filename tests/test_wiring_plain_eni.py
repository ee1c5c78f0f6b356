"""An ENI without PreviousPort (a hand-written one) is a line: each slave on port B of the
one before it; a PreviousPort without PhysAddr that names no downstream port is an error
naming the slave and the port alone; an empty segment has no wiring to walk and a cabling
loop is refused as one (runtime/wiring.py)."""

from __future__ import annotations

import pytest

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan, PreviousPort
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.library import Library
from ecatcfg.record import replace
from ecatcfg.runtime.wiring import Plug, Wiring, eni_plugs


@pytest.fixture(scope="module")
def plan() -> NetworkPlan:
    built = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                   Library([EXAMPLES / "esi"], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(built), "example.eni.xml")


def test_slaves_without_previous_port_follow_each_other_on_port_b(plan):
    slaves = [replace(s, previous_ports=[]) for s in sorted(plan.slaves, key=lambda s: s.position)]
    assert len(slaves) == 5
    assert eni_plugs(slaves, "plain.xml") == [None, Plug(0, 1), Plug(1, 1), Plug(2, 1),
                                             Plug(3, 1)]


def test_a_previous_port_a_without_address_is_refused_naming_the_slave(plan):
    slaves = sorted(plan.slaves, key=lambda s: s.position)
    slaves[2] = replace(slaves[2], previous_ports=[PreviousPort("A")])
    with pytest.raises(EcatcfgError) as exc:
        eni_plugs(slaves, "plain.xml")
    assert str(exc.value) == (f"plain.xml: slave {slaves[2].name!r}: PreviousPort 'A': the "
                              "port is not B, C or D (a downstream port)")


def test_an_empty_segment_reaches_no_slave():
    assert Wiring([]).order(()) == []


def test_a_cabling_loop_is_refused():
    # Slave 1 in slave 2 and slave 2 in slave 1: neither reaches the master.
    with pytest.raises(ValueError, match="the plugging has a cycle"):
        Wiring([None, Plug(2, 1), Plug(1, 1)])
