"""The branched network of the acceptance, end to end: the coupler, the junction with three
branches (two drives, a line of I/O terminals) and the UR20 station of ``tests/trees.py``,
compiled from the corpus ESI files.

- ``apply --virtual`` (``Network.virtual``) reaches OP and process data moves for every
  slave: every output variable written reaches the emulated slave's outputs, and inputs
  the slave sets (all ones) come back in every input variable;
- over veth, SOEM (pysoem) configures ``simulate --topology`` of the same topology and
  reaches OP with the 7 slaves;
- ``scan --topology-out`` of that segment gives a topology that compiles to the same ENI,
  byte for byte, once the scan is told what it cannot know: the slaves' names (it names
  them by device), the station's modules (in the station's CoE dictionary, which a scan
  that writes only the SII interface does not read), the master's name and cycle time.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from rig import start_simulate
import trees
import yaml

from ecatcfg.compiler import build, topology
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def tree_lib(corpus: Path) -> Library:
    return Library([corpus / "esi"], cache=False)


def compiled(text: str, lib: Library, name: str = "tree.yaml") -> bytes:
    return eni_writer.to_bytes(build.compile_topology(topology.loads(text, name), lib).plan)


def test_the_tree_reaches_op_and_every_slave_moves_data(corpus, tree_lib):
    plan = build.compile_topology(topology.loads(trees.ACCEPTANCE, "tree.yaml"),
                                  tree_lib).plan
    with Network.virtual(plan, esi=[corpus / "esi"], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        slaves = {s.name: s for s in net.segment.slaves}
        assert [s.name for s in net.segment.slaves] == trees.ACCEPTANCE_ORDER
        outputs = [v for v in plan.process_image.outputs if v.data_type not in ("REAL",
                                                                                 "LREAL")]
        inputs = [v for v in plan.process_image.inputs if v.data_type not in ("REAL",
                                                                              "LREAL")]
        moved_out, moved_in = set(), set()
        for name, slave in slaves.items():
            mine = [v for v in outputs if v.name.startswith(f"{name}.")]
            if mine:
                net.cycle()
                assert not any(slave.outputs()), name              # nothing written yet
                for v in mine:
                    net[v.name] = True if v.bit_size == 1 else 1
                net.cycle()
                net.cycle()
                assert any(slave.outputs()), name
                for v in mine:
                    net[v.name] = False if v.bit_size == 1 else 0
                moved_out.add(name)
            theirs = [v for v in inputs if v.name.startswith(f"{name}.")]
            if theirs:
                slave.set_inputs(b"\xff" * 512)
                net.cycle()
                net.cycle()
                for v in theirs:
                    mask = (1 << v.bit_size) - 1
                    assert int(net[v.name]) & mask == mask, v.name
                moved_in.add(name)
    # Which slaves have data in which direction, from the devices: the terminals one way
    # each, the drives and the station both ways, coupler and junction none.
    assert moved_out == {"axis1", "axis2", "outputs", "station"}
    assert moved_in == {"axis1", "axis2", "inputs", "station"}


def _scanned_topology(found: Path) -> str:
    """The scan's topology with what a scan cannot know given back (module docstring)."""
    scanned = yaml.safe_load(found.read_text())
    by_scan = [s["name"] for s in scanned["slaves"]]
    names = dict(zip(by_scan, trees.ACCEPTANCE_ORDER))
    for s in scanned["slaves"]:
        s["name"] = names[s["name"]]
        if "parent" in s:
            s["parent"] = names[s["parent"]]
        if s["name"] == "station":
            s["modules"] = {1: trees.UR20_MODULES}
    scanned["master"] = {"name": "tree", "cycle_time_us": 1000}
    return yaml.safe_dump(scanned, sort_keys=False)


def test_soem_and_scan_on_simulate_of_the_tree(veth_netns, pysoem_module, corpus, tree_lib,
                                                tmp_path):
    from test_soem import soem

    topo = tmp_path / "tree.yaml"
    topo.write_text(trees.ACCEPTANCE)
    original = compiled(trees.ACCEPTANCE, tree_lib)
    sim, lines = start_simulate(veth_netns, "--esi", str(corpus / "esi"), "--topology",
                                str(topo), duration=90)
    try:
        assert lines and lines[-1].startswith("ready: 7 slaves"), "".join(lines)
        found = tmp_path / "found.yaml"
        scan = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "scan", "--iface", veth_netns.if_a, "--esi",
            str(corpus / "esi"), "--topology-out", str(found), "--no-cache"],
            timeout=60, cwd=ROOT)
        report = soem(veth_netns, {"outputs": "5a"})
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    assert scan.returncode == 0, scan.stdout + scan.stderr
    assert report["found"] == 7, report
    assert [(s["vendor"], s["product"]) for s in report["slaves"]][:2] == [
        (0x2, 0x044C2C52), (0x2, 0x04622C52)]
    assert report["safeop"] == 4 and report["op"] == 8, report
    again = compiled(_scanned_topology(found), tree_lib, "found.yaml")
    assert again == original


@pytest.mark.parametrize("change, slave, found", [
    # axis2 moved from the junction's port B to the station's port B.
    ("move", "axis2", "station port B"),
    # The cable into the line of terminals pulled: the terminals are gone.
    ("cut", "inputs", "missing slave"),
])
def test_a_moved_slave_or_a_pulled_cable_stops_apply(veth_netns, corpus, tree_lib, tmp_path,
                                                    change, slave, found):
    """apply (the acceptance ENI) against simulate of a tree wired otherwise: exit 1 before
    any configuration, naming the slave with where the ENI has it and what was found."""
    eni = tmp_path / "tree.eni.xml"
    eni.write_bytes(compiled(trees.ACCEPTANCE, tree_lib))
    text = trees.ACCEPTANCE
    extra: list[str] = []
    if change == "move":
        text = text.replace("parent: junction, port: B}", "parent: station, port: B}")
    else:
        extra = ["--cut", slave]
    topo = tmp_path / "wired.yaml"
    topo.write_text(text)
    sim, lines = start_simulate(veth_netns, "--esi", str(corpus / "esi"), "--topology",
                                str(topo), *extra)
    try:
        assert lines and lines[-1].startswith("ready:"), "".join(lines)
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "apply", str(eni), "--iface", veth_netns.if_a],
            timeout=60, cwd=ROOT)
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    assert done.returncode == 1, done.stdout + done.stderr
    text_out = " ".join((done.stdout + done.stderr).split())
    assert "Traceback" not in text_out
    assert slave in text_out and found in text_out, text_out
    assert "nothing was configured" in text_out, text_out
