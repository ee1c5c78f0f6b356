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
from conftest import EXAMPLES, device_xml, esi_xml
from lxml import etree

from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

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
        f"t.yaml:{line}: slave 'outputs': a hot-connect group's head needs 'alias' (the "
        "station alias, register 0x0012) or 'device_id' (its ID switch) for the master to "
        "recognise it by"]


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


# -- identification by device ID ----------------------------------------------------------

def _cmds(data: bytes, name: str) -> list[dict]:
    """Every IdentifyCmd of slave ``name``, its fields as written."""
    [slave] = etree.fromstring(data).xpath(f"//Slave[Info/Name='{name}']")
    return [{c.tag: c.text for c in cmd.iter() if len(c) == 0 and c.tag != "Comment"}
            for cmd in slave.xpath("HotConnect/IdentifyCmd")]


def test_an_ek1101_is_identified_by_its_id_switch_at_the_esis_address(corpus, eni_schema):
    """Beckhoff EK11xx.xml gives the EK1101 ``<IdentificationAdo>#x1000</IdentificationAdo>``:
    the ID switch is read there; alias and ID both given: both are checked."""
    text = ("slaves:\n  - {name: c, device: EK1100}\n"
            "  - {name: head, device: EK1101, parent: c, port: C, hot_connect: true,\n"
            "     device_id: 0x42, alias: 7}\n")
    data = _compile(text, _lib(corpus / "esi" / "beckhoff"))
    assert eni_schema.validate(etree.fromstring(data)), eni_schema.error_log
    assert _cmds(data, "head") == [
        {"Cmd": "1", "Adp": "65535", "Ado": "18", "DataLength": "2", "Cnt": "1",
         "Data": "0700", "DataMask": "ffff", "Timeout": "100"},
        {"Cmd": "1", "Adp": "65535", "Ado": "4096", "DataLength": "2", "Cnt": "1",
         "Data": "4200", "DataMask": "ffff", "Timeout": "100"}]


def _reg134_lib(tmp_path) -> Library:
    head = device_xml("FXH", "#x21").replace(
        "<GroupType>", "<Info><IdentificationReg134>1</IdentificationReg134></Info><GroupType>")
    (tmp_path / "fx.xml").write_text(esi_xml(device_xml("FXC", "#x20"), head,
                                             device_xml("FXP", "#x22")))
    return _lib(tmp_path)


def test_a_head_with_the_id_in_0x0134_is_asked_for_it(tmp_path, eni_schema):
    """IdentificationReg134: write AL control 0x0021 (INIT + request, ETG.1020), then read
    AL status .. AL status code (6 bytes) for bit 5 and the ID."""
    text = ("slaves:\n  - {name: c, device: FXC}\n"
            "  - {name: head, device: FXH, hot_connect: true, device_id: 513}\n"
            "  - {name: tail, device: FXP}\n")
    data = _compile(text, _reg134_lib(tmp_path))
    assert eni_schema.validate(etree.fromstring(data)), eni_schema.error_log
    assert _cmds(data, "head") == [
        {"Cmd": "2", "Adp": "65535", "Ado": "288", "Data": "2100", "Cnt": "1"},
        {"Cmd": "1", "Adp": "65535", "Ado": "304", "DataLength": "6", "Cnt": "1",
         "Data": "200000000102", "DataMask": "20000000ffff", "Timeout": "100"}]
    assert int(etree.fromstring(data).xpath(
        "string(//Slave[Info/Name='head']/HotConnect/GroupMemberCnt)")) == 2


def test_the_identify_cmds_pass_on_the_emulated_devices_and_fail_on_others(tmp_path):
    """The commands as compiled, sent to emulated slaves with the alias and ID the topology
    names: they validate; a device with another ID or alias fails them."""
    lib = _reg134_lib(tmp_path)
    text = ("slaves:\n  - {name: c, device: FXC}\n"
            "  - {name: head, device: FXH, hot_connect: true, device_id: 513, alias: 9}\n")
    plan = build.compile_topology(topology.loads(text, "t.yaml"), lib).plan
    cmds = plan.slave("head").hot_connect.identify_cmds
    assert len(cmds) == 3

    def passes(alias: int, device_id: int) -> bool:
        seg = segment([SlaveSpec(lib.device(lib.find(t).entry), n, alias=a)
                       for t, n, a in (("FXC", "c", 0), ("FXH", "head", alias))])
        seg.slaves[1].device_id = device_id
        ok = True
        for cmd in cmds:
            [got] = wire.decode(seg.process(wire.encode([wire.Datagram.physical(
                cmd.cmd, cmd.adp, cmd.ado, cmd.payload)]))).datagrams
            ok &= got.wkc == cmd.cnt
            if cmd.validate is not None:
                mask = cmd.validate.mask or bytes([0xFF] * len(got.data))
                ok &= bytes(a & m for a, m in zip(got.data, mask)) == bytes(
                    a & m for a, m in zip(cmd.validate.data, mask))
        return ok

    assert passes(9, 513)
    assert not passes(9, 514) and not passes(8, 513)
    assert cmds[0].cmd == Cmd.APRD


@pytest.mark.parametrize("extra, key, words", [
    ("device_id: 5", "device_id", "does not say the device has an ID"),
])
def test_device_id_where_the_esi_has_none_is_an_error(extra, key, words):
    text = HOT_TREE.read_text().replace("    alias: 12\n", f"    {extra}\n")
    line = _line_of(text, extra)
    [error] = _errors(text)
    assert error.startswith(f"t.yaml:{line}: slave 'outputs': the ESI of EXB2018 ") and \
        words in error


def test_device_id_without_a_group_is_an_error():
    text = HOT_TREE.read_text().replace(
        "  - name: inputs\n", "  - name: inputs\n    device_id: 3\n")
    line = _line_of(text, "device_id: 3")
    assert _errors(text) == [
        f"t.yaml:{line}: slave 'inputs': 'device_id' identifies the head of a hot-connect "
        "group, and this slave is none (add hot_connect: true)"]


def _coupler_and_head(port: str):
    """The example line cut to its coupler and the lamps terminal, the lamps a hot-connect
    group of one plugged (ENI ``PreviousPort``) into the coupler's ``port``."""
    from ecatcfg.eni.plan import HotConnectPlan, PreviousPort
    from ecatcfg.record import replace
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  _lib(EXAMPLES / "esi")).plan
    coupler = next(s for s in plan.slaves if s.name == "coupler")
    lamps = next(s for s in plan.slaves if s.name == "lamps")
    lamps = replace(lamps, hot_connect=HotConnectPlan(1, []),
                    previous_ports=[PreviousPort(port, coupler.phys_addr)])
    return replace(plan, slaves=[coupler, lamps]), coupler, lamps


@pytest.mark.parametrize("plugged", [2, 1], ids=["its-port", "another-port"])
def test_a_head_is_its_group_only_on_the_enis_port_of_its_parent(plugged):
    """In a tree, the group is there when its head pairs port by port: the lamps terminal
    found on the coupler's port C, where the ENI puts it, is the group; found on port B,
    with the same identity and passing the same IdentifyCmds, it is not (it is on another
    branch of the tree), so the group counts as absent."""
    from ecatcfg.runtime.master.hotconnect import present_groups
    from ecatcfg.runtime.master.scan import FoundSlave
    from ecatcfg.runtime.wiring import Plug
    plan, coupler, lamps = _coupler_and_head("C")
    found = [FoundSlave(0, coupler.vendor_id, coupler.product_code, coupler.revision, 0),
             FoundSlave(1, lamps.vendor_id, lamps.product_code, lamps.revision, 0,
                        plug=Plug(0, plugged))]
    identified = {("lamps", 1): True}          # its IdentifyCmds pass where it is
    assert present_groups(plan, found, identified) == ({"lamps"} if plugged == 2 else set())


def test_a_slave_behind_an_absent_group_is_plugged_where_the_group_was():
    """The example line as a tree whose every slave names the one before it in a single
    ``PreviousPort`` (port B, no ``Selected`` attribute: one entry, as TwinCAT writes it),
    the lamps terminal a hot-connect group of one.  With the group absent, the line as it
    is (``as_found``) has the drive plugged into port B of the sensors terminal, where the
    lamps were: walking up from the lamps to the first slave present, through entries
    none of which is selected."""
    import itertools

    from ecatcfg.eni.plan import HotConnectPlan, PreviousPort
    from ecatcfg.record import replace
    from ecatcfg.runtime.master.hotconnect import as_found
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  _lib(EXAMPLES / "esi")).plan
    ordered = sorted(plan.slaves, key=lambda s: s.position)
    chained = [ordered[0]] + [replace(s, previous_ports=[PreviousPort("B", before.phys_addr)])
                              for before, s in itertools.pairwise(ordered)]
    chained = [replace(s, hot_connect=HotConnectPlan(1, [])) if s.name == "lamps" else s
               for s in chained]
    sensors = next(s for s in chained if s.name == "sensors")
    present = {s.name for s in chained} - {"lamps"}
    line = as_found(replace(plan, slaves=chained), present)
    assert [s.name for s in line.slaves] == ["coupler", "buttons", "sensors", "axis1"]
    drive = next(s for s in line.slaves if s.name == "axis1")
    assert [(p.port, p.phys_addr, p.selected) for p in drive.previous_ports] == [
        ("B", sensors.phys_addr, True)]


def test_without_the_first_slaves_group_every_slave_moves_up_one_position():
    """The coupler a hot-connect group of one and absent: every slave present sits one
    position further up (auto-increment addresses 0, -1, -2, -3), and the drift
    compensation's ARMW, addressed by position to the drive (the reference clock), moves
    with it."""
    from ecatcfg.eni.plan import HotConnectPlan
    from ecatcfg.record import replace
    from ecatcfg.runtime.master.hotconnect import as_found
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  _lib(EXAMPLES / "esi")).plan
    plan = replace(plan, slaves=[replace(s, hot_connect=HotConnectPlan(1, []))
                                 if s.name == "coupler" else s for s in plan.slaves])
    line = as_found(plan, {s.name for s in plan.slaves} - {"coupler"})
    assert [(s.name, s.auto_inc_addr) for s in line.slaves] == [
        ("buttons", 0), ("sensors", 0xFFFF), ("lamps", 0xFFFE), ("axis1", 0xFFFD)]
    [armw] = [c for f in line.cyclic[0].frames for c in f.cmds if c.cmd == Cmd.ARMW]
    assert armw.adp == 0xFFFD
