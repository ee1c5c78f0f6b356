"""Hot-connect groups from the topology (``hot_connect: true`` on a head): the compiler writes
ETG.2100 ``HotConnect`` elements that validate against the ETG schema, with the member count
and the head's identification command the topology text gives.

Expected values are written by hand from the topology files and the wiring rule (depth
first, ports A, D, B, C; auto-increment address = -position as 16 bits), and read from the
ENI with XPath; schema verdicts come from the ETG.2100 schema.
"""

from __future__ import annotations

import json
import subprocess
import sys

import jsonschema
import pytest
from conftest import EXAMPLES
from lxml import etree

from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esi.library import Library

TREE_ESI = [EXAMPLES / "tree" / "esi", EXAMPLES / "esi"]
HOT_TREE = EXAMPLES / "tree" / "hotconnect.yaml"


def _lib(*folders) -> Library:
    return Library(list(folders) or TREE_ESI, cache=False)


def _compile(text: str, lib: Library) -> bytes:
    return eni_writer.to_bytes(build.compile_topology(topology.loads(text, "t.yaml"), lib).plan)


def groups_in(data: bytes) -> dict[str, dict]:
    """Every HotConnect of the ENI by its slave's name, read with XPath."""
    out = {}
    for slave in etree.fromstring(data).xpath("/EtherCATConfig/Config/Slave[HotConnect]"):
        [cmd] = slave.xpath("HotConnect/IdentifyCmd")
        out[slave.findtext("Info/Name")] = {
            "count": int(slave.findtext("HotConnect/GroupMemberCnt")),
            "cmd": int(cmd.findtext("Cmd")), "adp": int(cmd.findtext("Adp")),
            "ado": int(cmd.findtext("Ado")), "length": int(cmd.findtext("DataLength")),
            "cnt": int(cmd.findtext("Cnt")), "transitions": cmd.findall("Transition"),
            "validate": (cmd.findtext("Validate/Data"), cmd.findtext("Validate/DataMask")),
            "timeout": int(cmd.findtext("Validate/Timeout")),
        }
    return out


def _identify(count: int, position: int, alias_hex: str) -> dict:
    """What the topology asks for: APRD (1) of 0x0012 (18), 2 bytes, one slave answering,
    at auto-increment address -position, validated against the alias (little-endian)."""
    return {"count": count, "cmd": 1, "adp": (-position) & 0xFFFF, "ado": 18, "length": 2,
            "cnt": 1, "transitions": [], "validate": (alias_hex, "ffff"), "timeout": 100}


def test_example_tree_groups(eni_schema, tmp_path):
    """examples/tree/hotconnect.yaml: bus order coupler 0, inputs 1, junction 2, axis1 3,
    axis2 4, outputs 5, axis3 6.  junction (alias 10) takes axis1 (port D) and axis2
    (port B); outputs (port C, alias 12) and axis3 (alias 3) are groups of one."""
    out = tmp_path / "hc.xml"
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(HOT_TREE),
                          *sum((["--esi", str(p)] for p in TREE_ESI), []), "-o", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    data = out.read_bytes()
    assert eni_schema.validate(etree.fromstring(data)), eni_schema.error_log
    assert groups_in(data) == {"junction": _identify(3, 2, "0a00"),
                               "outputs": _identify(1, 5, "0c00"),
                               "axis3": _identify(1, 6, "0300")}
    names = [n.text for n in etree.fromstring(data).xpath("//Slave/Info/Name")]
    assert names == ["coupler", "inputs", "junction", "axis1", "axis2", "outputs", "axis3"]
    # Read back: the same plan.
    plan = eni_reader.read_bytes(data, "hc.xml")
    assert eni_reader.read_bytes(eni_writer.to_bytes(plan), "again.xml") == plan
    assert plan.slave("junction").hot_connect.member_count == 3


def test_a_head_in_a_line_takes_the_rest_of_the_line(eni_schema):
    """examples/topology.yaml is a line of five: coupler, buttons, sensors, lamps, axis1."""
    text = (EXAMPLES / "topology.yaml").read_text().replace(
        "  - name: sensors\n", "  - name: sensors\n    hot_connect: true\n    alias: 0x77\n")
    data = _compile(text, _lib(EXAMPLES / "esi"))
    assert eni_schema.validate(etree.fromstring(data)), eni_schema.error_log
    assert groups_in(data) == {"sensors": _identify(3, 2, "7700")}


def test_a_nested_head_in_a_line_ends_the_outer_group():
    text = (EXAMPLES / "topology.yaml").read_text().replace(
        "  - name: buttons\n", "  - name: buttons\n    hot_connect: true\n    alias: 2\n"
    ).replace("  - name: lamps\n", "  - name: lamps\n    hot_connect: true\n    alias: 4\n")
    data = _compile(text, _lib(EXAMPLES / "esi"))
    assert groups_in(data) == {"buttons": _identify(2, 1, "0200"),
                               "lamps": _identify(2, 3, "0400")}


def _errors(text: str) -> list[str]:
    with pytest.raises(TopologyError) as info:
        build.compile_topology(topology.loads(text, "t.yaml"), _lib())
    return [str(p) for p in info.value.problems]


def _line_of(text: str, needle: str, after: str = "") -> int:
    start = text.index(after) if after else 0
    return text[:text.index(needle, start)].count("\n") + 1


def test_a_head_without_alias_is_an_error_at_its_line():
    text = HOT_TREE.read_text().replace("    alias: 12\n", "")
    line = _line_of(text, "hot_connect: true", "name: outputs")
    assert _errors(text) == [
        f"t.yaml:{line}: slave 'outputs': a hot-connect group's head needs 'alias', the "
        "station alias (register 0x0012) the master recognises it by"]


def test_a_nested_group_inside_a_group_is_refused():
    """axis1 on the junction's port D is passed before axis2 on port B: as a group of its
    own it would split the junction's group in two."""
    text = HOT_TREE.read_text().replace(
        "  - name: axis1\n    device: EXD-402\n",
        "  - name: axis1\n    device: EXD-402\n    hot_connect: true\n    alias: 31\n")
    line = _line_of(text, "hot_connect: true", "name: junction")
    [error] = _errors(text)
    assert error.startswith(
        f"t.yaml:{line}: slave 'junction': its hot-connect group is not one run of slaves in "
        "bus order: the group of 'axis1' comes between it and its member 'axis2'")


def test_topology_schema_has_hot_connect(tmp_path):
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "schema", "topology"],
                         capture_output=True, text=True, timeout=60)
    schema = json.loads(run.stdout)
    prop = schema["$defs"]["Slave"]["properties"]["hot_connect"]
    assert prop["type"] == "boolean" and prop["default"] is False
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"slaves": [{"name": "a", "device": "X", "hot_connect": "yes"}]},
                            schema)
