"""Branched networks in the compiler: ``parent``/``port`` in the topology, the default
plugging by port kind, auto-increment order along the frame's path, ``PreviousPort`` and
``Physics`` in the ENI, and the errors of a wiring that cannot be.

Expectations are written by hand from the wiring rule (``trees.py``: the tree and its own
depth-first walk over ports A, D, B, C) and read back from the ENI with lxml; schema
verdicts come from the ETG.2100 schema.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import trees
from conftest import EXAMPLES, ESI_TEMPLATE, device_xml, write
from lxml import etree

from ecatcfg.cli import main
from ecatcfg.compiler import build, topology
from ecatcfg.compiler.plugged import plugged_devices
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esi.library import Library

TREE_ESI = [EXAMPLES / "tree" / "esi", EXAMPLES / "esi"]


@pytest.fixture(scope="module")
def tree_lib(corpus: Path) -> Library:
    esi = corpus / "esi"
    return Library([esi / "beckhoff", esi / "modular", esi / "drives"], cache=False)


def example_lib() -> Library:
    return Library(TREE_ESI, cache=False)


def compiled(text: str, lib: Library) -> tuple[build.CompileResult, bytes]:
    result = build.compile_topology(topology.loads(text, "t.yaml"), lib)
    return result, eni_writer.to_bytes(result.plan)


def eni_slaves(data: bytes) -> list[dict]:
    """Name, addresses, Physics and PreviousPort of every ENI slave, read with lxml."""
    out = []
    for el in etree.fromstring(data).iter("Slave"):
        info = el.find("Info")
        ports = [(p.get("Selected"), p.findtext("Port"), int(p.findtext("PhysAddr")))
                 for p in el.findall("PreviousPort")]
        out.append({"name": info.findtext("Name"), "phys": int(info.findtext("PhysAddr")),
                    "auto": int(info.findtext("AutoIncAddr")),
                    "physics": info.findtext("Physics"), "previous": ports})
    return out


def errors_of(text: str, lib: Library) -> list[str]:
    with pytest.raises(TopologyError) as exc:
        build.compile_topology(topology.loads(text, "t.yaml"), lib)
    return [str(p) for p in exc.value.problems]


# -- the acceptance network ----------------------------------------------------------------

def test_acceptance_tree_compiles_to_a_valid_eni_in_frame_order(tree_lib, eni_schema):
    assert trees.bus_order(trees.ACCEPTANCE_TREE) == trees.ACCEPTANCE_ORDER
    result, data = compiled(trees.ACCEPTANCE, tree_lib)
    assert eni_schema.validate(etree.ElementTree(etree.fromstring(data))), \
        eni_schema.error_log
    slaves = eni_slaves(data)
    order = trees.bus_order(trees.ACCEPTANCE_TREE)
    assert [s["name"] for s in slaves] == order
    # Positions 0, -1, -2, ... and station addresses 1001, 1002, ... along the frame.
    assert [s["auto"] for s in slaves] == [(-n) & 0xFFFF for n in range(len(order))]
    phys = {name: 1001 + n for n, name in enumerate(order)}
    assert [s["phys"] for s in slaves] == [phys[name] for name in order]
    for s in slaves:
        up = trees.ACCEPTANCE_TREE[s["name"]]
        want = [] if up is None else [("1", up[1], phys[up[0]])]
        assert s["previous"] == want, s["name"]
    assert [s["physics"] for s in slaves] == ["YKY", "KYKY", "YY", "YY", "KK", "KK", "YY"]
    assert not result.notes or all("order" not in n for n in result.notes), result.notes
    # The process image follows the bus order too: the station's data after the terminals'.
    recv = {s.name: s.process_data.recv[0].bit_start for s in result.plan.slaves
            if s.process_data and s.process_data.recv}
    assert recv["axis1"] < recv["axis2"] < recv["inputs"] < recv["station"]
    assert eni_reader.read_bytes(data, "t.eni.xml") == result.plan


def test_the_same_wiring_listed_in_another_order_gives_the_same_eni(tree_lib):
    result, data = compiled(trees.ACCEPTANCE, tree_lib)
    shuffled, data2 = compiled(trees.ACCEPTANCE_SHUFFLED, tree_lib)
    assert data2 == data
    note, = [n for n in shuffled.notes if "another order" in n]
    assert "bus order: " + ", ".join(trees.ACCEPTANCE_ORDER) in note, note


def test_plugged_devices_give_parent_position_and_port(tree_lib):
    devices = plugged_devices(topology.loads(trees.ACCEPTANCE_SHUFFLED, "t.yaml"), tree_lib)
    order = trees.bus_order(trees.ACCEPTANCE_TREE)
    assert [d.name for d in devices] == order
    got = {d.name: None if d.parent is None else (devices[d.parent].name,
                                                 "ABCD"[d.parent_port])
           for d in devices}
    assert got == trees.ACCEPTANCE_TREE
    assert all(d.parent is None or d.parent < n for n, d in enumerate(devices))
    assert devices[order.index("station")].device.type_name == "UR20-FBC-EC"


# -- default plugging ------------------------------------------------------------------------

def test_a_line_that_can_be_wired_as_written_keeps_its_order_without_a_note():
    text = ("slaves:\n  - {name: c, device: EXB1100}\n  - {name: t1, device: EXB1018}\n"
            "  - {name: t2, device: EXB2018}\n  - {name: t3, device: EXB1018}\n"
            "  - {name: d1, device: EXD-402}\n  - {name: d2, device: EXD-402}\n")
    result, data = compiled(text, example_lib())
    slaves = eni_slaves(data)
    assert [s["name"] for s in slaves] == ["c", "t1", "t2", "t3", "d1", "d2"]
    # Each E-bus terminal follows the terminal before it; the drive after the row lands on
    # the coupler's free Ethernet port C, the next drive on that drive's port B.
    assert [s["previous"] for s in slaves] == [
        [], [("1", "B", 1001)], [("1", "B", 1002)], [("1", "B", 1003)], [("1", "C", 1001)],
        [("1", "B", 1005)]]
    assert result.notes == []


def test_default_plugging_that_changes_the_order_says_so_and_the_eni_follows_the_wiring():
    # Written as a line: c, d1, t1.  But the E-bus terminal t1 can only go onto the
    # coupler's E-bus port B, which the frame passes before port C, where d1 sits.
    text = ("slaves:\n  - {name: c, device: EXB1100}\n  - {name: d1, device: EXD-402}\n"
            "  - {name: t1, device: EXB1018}\n")
    result, data = compiled(text, example_lib())
    slaves = eni_slaves(data)
    assert [(s["name"], s["auto"], s["phys"], s["previous"]) for s in slaves] == [
        ("c", 0, 1001, []), ("t1", 0xFFFF, 1002, [("1", "B", 1001)]),
        ("d1", 0xFFFE, 1003, [("1", "C", 1001)])]
    note, = result.notes
    assert "'t1' on port B of 'c' (default plugging)" in note
    assert note.endswith("bus order: c, t1, d1"), note


def test_junction_ports_are_taken_in_frame_order_d_b_c():
    text = ("slaves:\n  - {name: c, device: EXB1100}\n  - {name: j, device: EXB1122}\n"
            "  - {name: d1, device: EXD-402}\n  - {name: d2, device: EXD-402, parent: j}\n"
            "  - {name: t, device: EXB1018}\n")
    result, data = compiled(text, example_lib())
    prev = {s["name"]: s["previous"] for s in eni_slaves(data)}
    assert prev == {"c": [], "j": [("1", "B", 1001)], "d1": [("1", "D", 1002)],
                    "d2": [("1", "B", 1002)], "t": [("1", "C", 1002)]}
    assert result.notes == []


def test_example_tree_is_the_worked_example_of_the_docs(eni_schema, esi_schema):
    esi = EXAMPLES / "tree" / "esi" / "ecatcfg-EXB-branching.xml"
    assert esi_schema.validate(etree.parse(str(esi))), esi_schema.error_log
    loaded = topology.load(EXAMPLES / "tree" / "tree.yaml")
    result = build.compile_topology(loaded, example_lib())
    data = eni_writer.to_bytes(result.plan)
    assert eni_schema.validate(etree.ElementTree(etree.fromstring(data))), \
        eni_schema.error_log
    tree = {"coupler": None, "inputs": ("coupler", "B"), "junction": ("inputs", "B"),
            "axis1": ("junction", "D"), "axis2": ("junction", "B"),
            "outputs": ("junction", "C"), "axis3": ("coupler", "C")}
    order = trees.bus_order(tree)
    slaves = eni_slaves(data)
    assert [s["name"] for s in slaves] == order == [s.name for s in
                                                    loaded.topology.slaves]
    phys = {s["name"]: s["phys"] for s in slaves}
    assert {s["name"]: s["previous"] for s in slaves} == {
        name: [] if up is None else [("1", up[1], phys[up[0]])] for name, up in tree.items()}
    assert result.notes == []
    docs = (EXAMPLES.parent / "docs" / "compile.md").read_text()
    assert "examples/tree/tree.yaml" in docs and "PreviousPort" in docs


# -- ENI Physics -------------------------------------------------------------------------------

def test_fast_hot_connect_ports_are_written_as_ethernet_in_the_eni(tmp_path, eni_schema):
    """An EK1122-0080's Physics is KHKH (H: Ethernet with fast hot-connect, ETG.2000); the
    ENI schema allows Y, K, B and a blank only."""
    junction = device_xml("FX1122", "#x1122").replace('Physics="YY"', 'Physics="KHKH"')
    coupler = device_xml("FX1100", "#x1100").replace('Physics="YY"', 'Physics="YKY"')
    drive = device_xml("FXD", "#x0D")
    write(tmp_path, "fx.xml", ESI_TEMPLATE.format(encoding="UTF-8", vendor="#x0ECA",
                                                  devices="\n".join([coupler, junction, drive])))
    text = ("slaves:\n  - {name: c, device: FX1100}\n  - {name: j, device: FX1122}\n"
            "  - {name: d, device: FXD}\n")
    _, data = compiled(text, Library([tmp_path], cache=False))
    slaves = eni_slaves(data)
    assert [s["physics"] for s in slaves] == ["YKY", "KYKY", "YY"]
    assert slaves[2]["previous"] == [("1", "D", 1002)]      # H is an Ethernet port
    assert eni_schema.validate(etree.ElementTree(etree.fromstring(data))), \
        eni_schema.error_log
    # The schema is what refuses the ESI's letters as they are.
    raw = data.replace(b"<Physics>KYKY</Physics>", b"<Physics>KHKH</Physics>")
    assert raw != data and not eni_schema.validate(etree.ElementTree(etree.fromstring(raw)))


# -- errors --------------------------------------------------------------------------------

HEAD = "slaves:\n  - {name: c, device: EXB1100}\n"          # ports A Y, B K, C Y


@pytest.mark.parametrize("lines, line, message", [
    (["  - {name: d, device: EXD-402, parent: c, port: D}"], 3,
     "slave 'd': port D does not exist on 'c' (ports A Ethernet, B E-bus, C Ethernet)"),
    (["  - {name: d, device: EXD-402, parent: c, port: A}"], 3,
     "slave 'd': port A of 'c' is its port toward the master"),
    (["  - {name: d, device: EXD-402, parent: c, port: C}",
      "  - {name: e, device: EXD-402, parent: c, port: C}"], 4,
     "slave 'e': port C of 'c' is already used by slave 'd' (line 3); two slaves cannot "
     "share a port"),
    (["  - {name: d, device: EXD-402, parent: c, port: B}"], 3,
     "slave 'd': its port A is Ethernet but port B of 'c' is E-bus"),
    (["  - {name: t, device: EXB1018, parent: c, port: C}"], 3,
     "slave 't': its port A is E-bus but port C of 'c' is Ethernet"),
    (["  - {name: d, device: EXD-402, parent: x}"], 3,
     "slave 'd': parent 'x' is not a slave of this topology"),
    (["  - {name: d, device: EXD-402, parent: d}"], 3,
     "slave 'd': it cannot be plugged into itself"),
    (["  - {name: d, device: EXD-402, parent: e, port: B}",
      "  - {name: e, device: EXD-402, parent: d, port: B}"], 3,
     "slave 'd': slaves 'd', 'e' form a cycle"),
    (["  - {name: t, device: EXB1018}", "  - {name: u, device: EXB1018, parent: c}"], 4,
     "slave 'u': 'c' (ports A Ethernet, B E-bus, C Ethernet) has no free E-bus port"),
    (["  - {name: d, device: EXD-402, parent: c}", "  - {name: t, device: EXB1018}",
      "  - {name: u, device: EXB1018}", "  - {name: j, device: EXB1122, parent: d, port: B}"],
     6,
     "slave 'j': its port A is E-bus but port B of 'd' is Ethernet"),
    (["  - {name: d, device: EXD-402, port: B}"], 3,
     "'port' needs 'parent'"),
    (["  - {name: d, device: EXD-402, parent: c, port: E}"], 3,
     "a port is A, B, C or D (ESC ports 0-3), not 'E'"),
])
def test_wiring_errors_name_the_topology_line(lines, line, message):
    problems = errors_of(HEAD + "\n".join(lines) + "\n", example_lib())
    assert any(p.startswith(f"t.yaml:{line}: ") and message in p for p in problems), problems


def test_a_slave_no_earlier_slave_can_take_is_an_error_at_its_line():
    text = "slaves:\n  - {name: t, device: EXB1018}\n  - {name: d, device: EXD-402}\n"
    problem, = errors_of(text, example_lib())
    assert problem.startswith("t.yaml:3: slave 'd': no slave before it has a free Ethernet "
                              "port for its port A (Ethernet)"), problem


def test_first_slave_cannot_have_a_parent():
    text = "slaves:\n  - {name: d, device: EXD-402, parent: e}\n  - {name: e, device: EXD-402}\n"
    problems = errors_of(text, example_lib())
    assert any(p.startswith("t.yaml:2: slave 'd': the first slave is the one the master is "
                            "plugged into") for p in problems), problems


def test_schema_describes_parent_and_port(tmp_path, capsys):
    import jsonschema
    assert main(["schema", "topology"]) == 0
    schema = json.loads(capsys.readouterr().out)
    slave = schema["$defs"]["Slave"]["properties"]
    assert {"parent", "port"} <= set(slave)
    ok = {"slaves": [{"name": "c", "device": "EK1100"},
                     {"name": "d", "device": "X", "parent": "c", "port": "C"},
                     {"name": "e", "device": "X", "parent": "c", "port": 1}]}
    jsonschema.validate(ok, schema)
    for bad in ("E", "b", 4, -1):
        wrong = {"slaves": [{"name": "c", "device": "X", "parent": "c", "port": bad}]}
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(wrong, schema)
