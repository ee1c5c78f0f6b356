"""Slaves without an ESC (passive terminals: end caps, potential feeds), end to end.

TwinCAT lists them in an ENI as a ``Slave`` whose ``Info`` has a name and an identity but no
``PhysAddr``/``AutoIncAddr`` (the group ETG.2100 documents as "slave device has EtherCAT
Slave Controller"), an empty ``ProcessData`` and a ``PreviousPort``.  The ENIs here are the
compiled example with such slaves written in by hand (``with_passive``, plain lxml), one
between active slaves and one after the last.  References independent of the code under
test: the ETG.2100 schema, SOEM (pysoem) as a second master on ``simulate --eni``, the
element counts read from the XML with XPath, and Beckhoff's ESI of its EL9xxx terminals.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import EXAMPLES, FIXTURES, compile_example
from lxml import etree
from rig import start_simulate
from test_soem import soem

from ecatcfg.compiler import topology
from ecatcfg.compiler.build import compile_topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import PassiveSlave, SlavePlan
from ecatcfg.eni.reader import EniReadError
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network

PASSIVE_ESI = FIXTURES / "ecatcfg-EX9xxx-passive.xml"
APPLY_TIMEOUT = 120


def _passive_xml(name: str, product: int, previous: int | None) -> etree._Element:
    """A passive terminal as TwinCAT writes it (``Selected="true"``, an empty
    ``ProcessData``; VendorId 2 is Beckhoff's)."""
    port = ("" if previous is None else
            f'\n<PreviousPort Selected="true">\n<Port>B</Port>\n<PhysAddr>{previous}'
            "</PhysAddr>\n</PreviousPort>")
    return etree.fromstring(
        f"<Slave>\n<Info>\n<Name>{name}</Name>\n<VendorId>2</VendorId>\n"
        f"<ProductCode>{product}</ProductCode>\n<RevisionNo>0</RevisionNo>\n"
        f"<SerialNo>0</SerialNo>\n</Info>\n<ProcessData/>{port}\n</Slave>")


def with_passive(eni: Path, out: Path) -> Path:
    """``eni`` with a passive slave after its second slave and one after its last."""
    tree = etree.parse(str(eni))
    slaves = tree.getroot().findall("Config/Slave")
    second, last = slaves[1], slaves[-1]
    second.addnext(_passive_xml("Term 3 (EL9100)", 0,
                                int(second.findtext("Info/PhysAddr"))))
    last.addnext(_passive_xml("Term 9 (EL9011)", 0, int(last.findtext("Info/PhysAddr"))))
    tree.write(str(out), xml_declaration=True, encoding="UTF-8")
    return out


def xml_slaves(path: Path) -> tuple[list[etree._Element], list[etree._Element]]:
    """(with an ESC, without) as the XML has them."""
    config = etree.parse(str(path)).getroot().find("Config")
    every = config.findall("Slave")
    return ([s for s in every if s.find("Info/PhysAddr") is not None],
            [s for s in every if s.find("Info/PhysAddr") is None])


@pytest.fixture(scope="module")
def example_eni(tmp_path_factory) -> Path:
    return compile_example(tmp_path_factory.mktemp("example") / "example.eni.xml")


@pytest.fixture()
def passive_eni(example_eni, tmp_path) -> Path:
    return with_passive(example_eni, tmp_path / "passive.eni.xml")


# -- reading and writing --------------------------------------------------------------------

def test_reader_keeps_passive_slaves_apart_in_file_order(passive_eni, example_eni):
    plan = eni_reader.read_file(passive_eni)
    plain = eni_reader.read_file(example_eni)
    # The slaves with an ESC are exactly those of the ENI without the passive ones.
    assert plan.slaves == plain.slaves
    assert [(p.name, p.after) for p in plan.passive] == [
        ("Term 3 (EL9100)", 2), ("Term 9 (EL9011)", len(plain.slaves))]
    order = [s.name for s in plan.in_file_order()]
    assert order == [s.findtext("Info/Name")
                     for s in etree.parse(str(passive_eni)).getroot().iter("Slave")]
    assert plan.passive[0].previous_ports[0].phys_addr == plain.slaves[1].phys_addr
    assert plan.passive[0].process_data


def test_round_trip_is_equal_and_valid(passive_eni, eni_schema, tmp_path):
    plan = eni_reader.read_file(passive_eni)
    written = tmp_path / "again.xml"
    eni_writer.write(plan, written)
    assert eni_reader.read_file(written) == plan
    doc = etree.parse(str(written))
    assert eni_schema.validate(doc), eni_schema.error_log
    active, passive = xml_slaves(written)
    assert len(active) == len(plan.slaves) and len(passive) == 2
    for el in passive:
        assert [c.tag for c in el.find("Info")] == ["Name", "VendorId", "ProductCode",
                                                    "RevisionNo", "SerialNo"]
        assert el.find("ProcessData") is not None and len(el.find("ProcessData")) == 0


def test_the_plan_cache_keeps_passive_slaves(passive_eni, tmp_path):
    """``apply`` reads through the plan cache: a stored plan with passive slaves loads
    (its unpickler builds plan classes only) and equals the parsed one."""
    from ecatcfg.eni import cache as eni_cache
    store = eni_cache.PlanCache(tmp_path / "cache")
    first = eni_cache.read_file(passive_eni, cache=store)
    assert len(list((tmp_path / "cache").rglob("*.pickle"))) == 1
    again = eni_cache.read_file(passive_eni, cache=store)
    assert again == first == eni_reader.read_file(passive_eni)
    assert again is not first and len(again.passive) == 2


def test_passive_slaves_in_every_place_round_trip():
    """First, two in a row, last: ``after`` and the order among equals survive."""
    from ecatcfg.eni.plan import MasterPlan, NetworkPlan
    active = [SlavePlan(name=f"a{k}", phys_addr=1001 + k, auto_inc_addr=-k & 0xFFFF,
                        vendor_id=1, product_code=2, revision=3) for k in range(2)]
    passive = [PassiveSlave(name=n, after=a, vendor_id=2, product_code=0, revision=0,
                            process_data=pd)
               for n, a, pd in (("p0", 0, True), ("p1", 1, False), ("p2", 1, True),
                                ("p3", 2, True))]
    plan = NetworkPlan(master=MasterPlan("m"), slaves=active, passive=passive)
    assert [s.name for s in plan.in_file_order()] == ["p0", "a0", "p1", "p2", "a1", "p3"]
    assert eni_reader.read_bytes(eni_writer.to_bytes(plan), "mem") == plan


def _edit_passive(passive_eni: Path, tmp_path: Path, xml: str, where: str = "") -> Path:
    """The ENI with ``xml`` appended to the first passive slave (or its ``Info``)."""
    tree = etree.parse(str(passive_eni))
    el = next(s for s in tree.getroot().iter("Slave") if s.find("Info/PhysAddr") is None)
    target = el.find(where) if where else el
    target.append(etree.fromstring(xml))
    out = tmp_path / "edited.xml"
    tree.write(str(out))
    return out


def _line_of(path: Path, text: str, after: str = "Term 3 (EL9100)") -> int:
    """The line of the first ``text`` after the line that holds ``after``."""
    lines = path.read_text().splitlines()
    start = next(n for n, line in enumerate(lines, 1) if after in line)
    return next(n for n, line in enumerate(lines, 1) if n > start and text in line)


@pytest.mark.parametrize("xml, tag, what", [
    ("<Mailbox><Send><Start>4096</Start><Length>128</Length></Send><Recv><Start>4224"
     "</Start><Length>128</Length></Recv></Mailbox>", "<Mailbox>", "a mailbox"),
    ("<InitCmds><InitCmd><Transition>IP</Transition><Cmd>2</Cmd><Adp>0</Adp><Ado>288</Ado>"
     "<Data>0200</Data></InitCmd></InitCmds>", "<InitCmd>", "InitCmds"),
    ("<DC><ReferenceClock>1</ReferenceClock><CycleTime0>1000000</CycleTime0></DC>", "<DC>",
     "distributed clocks"),
    ("<HotConnect><GroupMemberCnt>1</GroupMemberCnt></HotConnect>", "<HotConnect>",
     "a hot-connect group"),
])
def test_what_needs_an_esc_is_refused_at_its_line(passive_eni, tmp_path, xml, tag, what):
    eni = _edit_passive(passive_eni, tmp_path, xml)
    with pytest.raises(EniReadError) as exc:
        eni_reader.read_file(eni)
    err = exc.value
    assert err.file == str(eni)
    assert err.line == _line_of(eni, tag)
    assert "'Term 3 (EL9100)'" in str(err) and what in str(err)


@pytest.mark.parametrize("xml", [
    "<Sm2><Type>Outputs</Type><StartAddress>4352</StartAddress><ControlByte>100"
    "</ControlByte><Enable>1</Enable></Sm2>",
    "<Send><BitStart>0</BitStart><BitLength>8</BitLength></Send>",
    "<RxPdo><Index>#x1600</Index><Name>x</Name></RxPdo>",
])
def test_process_data_of_a_passive_slave_is_refused(passive_eni, tmp_path, xml):
    eni = _edit_passive(passive_eni, tmp_path, xml, "ProcessData")
    with pytest.raises(EniReadError) as exc:
        eni_reader.read_file(eni)
    tag = etree.fromstring(xml).tag
    assert exc.value.line == _line_of(eni, f"<{tag}>")
    assert "process data" in str(exc.value)


@pytest.mark.parametrize("tag, value, message", [
    ("PhysAddr", "1010", "has <PhysAddr> but no <AutoIncAddr>"),
    ("AutoIncAddr", "-7", "has <AutoIncAddr> but no <PhysAddr>"),
    ("Physics", "KK", "has <Physics> but no <PhysAddr> and <AutoIncAddr>"),
])
def test_half_an_address_is_an_error_at_info(passive_eni, tmp_path, tag, value, message):
    tree = etree.parse(str(passive_eni))
    info = next(s for s in tree.getroot().iter("Slave")
                if s.find("Info/PhysAddr") is None).find("Info")
    new = etree.SubElement(info, tag)
    new.text = value
    info.insert(1, new)
    out = tmp_path / "half.xml"
    tree.write(str(out))
    with pytest.raises(EniReadError, match=message) as exc:
        eni_reader.read_file(out)
    # The line of that Info: the one after the passive slave's <Slave>.
    text = out.read_text().splitlines()
    name_line = next(n for n, line in enumerate(text, 1) if "Term 3 (EL9100)" in line)
    assert exc.value.line == name_line - 1


def test_a_passive_slave_inside_a_hot_connect_group_is_refused(tmp_path):
    """GroupMemberCnt 3 from ``a0``: is the passive ``p`` between ``a1`` and ``a2`` one
    of the three?  ETG.2100 does not say; the reader refuses rather than guess."""
    from ecatcfg.eni.plan import HotConnectPlan, InitCmd, MasterPlan, NetworkPlan
    identify = InitCmd(transitions=[], comment="alias", cmd=4, length=2, adp=0, ado=0x12,
                       data=b"\x07\x00")
    active = [SlavePlan(name=f"a{k}", phys_addr=1001 + k, auto_inc_addr=-k & 0xFFFF,
                        vendor_id=1, product_code=2, revision=3) for k in range(4)]
    active[0].hot_connect = HotConnectPlan(3, [identify])
    inside = NetworkPlan(master=MasterPlan("m"), slaves=active, passive=[
        PassiveSlave(name="p", after=2, vendor_id=2, product_code=0, revision=0)])
    data = eni_writer.to_bytes(inside)
    with pytest.raises(EniReadError, match="inside the hot-connect group of 'a0'") as exc:
        eni_reader.read_bytes(data, "inside.xml")
    lines = data.decode().splitlines()
    assert exc.value.line == next(n for n, line in enumerate(lines, 1)
                                  if "<Name>p</Name>" in line) - 2
    after = NetworkPlan(master=MasterPlan("m"), slaves=active, passive=[
        PassiveSlave(name="p", after=3, vendor_id=2, product_code=0, revision=0)])
    assert eni_reader.read_bytes(eni_writer.to_bytes(after), "after.xml") == after


# -- apply --virtual and simulate --eni -------------------------------------------------------

def _apply_virtual(eni: Path, *args: str) -> tuple[int, dict, str]:
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--format", "json", "--simulated-time", "--cycles", "20", "--no-cache",
                           *args],
                          capture_output=True, text=True, timeout=APPLY_TIMEOUT)
    return done.returncode, json.loads(done.stdout), done.stderr


def _check_op(report: dict, eni: Path) -> None:
    active, passive = xml_slaves(eni)
    rows = report["slaves"]
    assert [r["name"] for r in rows] == [s.findtext("Info/Name") for s in
                                         etree.parse(str(eni)).getroot().iter("Slave")]
    on_wire = [r for r in rows if not r["passive"]]
    assert [r["name"] for r in on_wire] == [s.findtext("Info/Name") for s in active]
    assert [r["position"] for r in on_wire] == list(range(len(active)))
    assert [r["address"] for r in on_wire] == [int(s.findtext("Info/PhysAddr"))
                                               for s in active]
    assert all(r["highest_state"] == "OP" for r in on_wire), rows
    off = [r for r in rows if r["passive"]]
    assert [r["name"] for r in off] == [s.findtext("Info/Name") for s in passive]
    assert all(r["position"] is None and r["address"] is None and r["state"] == "passive"
               and r.get("emulated_from", None) is None for r in off)
    assert report["slave_count"] == {"active": len(active), "passive": len(passive)}
    assert report["cycles"]["wkc_errors"] == 0


def test_apply_virtual_reaches_op_past_passive_slaves(passive_eni):
    rc, report, err = _apply_virtual(passive_eni)
    assert rc == 0, err
    assert report["ok"], report["error"]
    _check_op(report, passive_eni)
    assert any("2 passive slaves without an ESC not on the wire" in e
               for e in report["events"]), report["events"]


def test_apply_virtual_with_esi_does_not_emulate_passive_devices(tmp_path):
    """The compiled topology with the passive fixture devices, applied with the same ESI
    files: the passive devices are in the library but not on the segment."""
    eni = _compile_passive_topology(tmp_path)
    rc, report, err = _apply_virtual(eni, "--esi", str(EXAMPLES / "esi"),
                                     "--esi", str(PASSIVE_ESI))
    assert rc == 0, err
    _check_op(report, eni)
    assert {r["emulated_from"] for r in report["slaves"] if not r["passive"]} == {"esi"}


def test_apply_text_marks_passive_slaves(passive_eni):
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(passive_eni),
                           "--virtual", "--simulated-time", "--cycles", "5", "--no-cache"],
                          capture_output=True, text=True, timeout=APPLY_TIMEOUT)
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if "Term 9 (EL9011)" in line]
    assert len(rows) == 1 and "passive (no ESC)" in rows[0]
    assert "7 slaves: 5 with an ESC, 2 passive (no ESC, not on the wire)" in done.stdout


def test_network_api_never_sees_a_passive_slave(passive_eni):
    plan = eni_reader.read_file(passive_eni)
    with Network.virtual(plan) as net:
        net.up(AlState.OP)
        assert [s.name for s in net.master.slaves] == [s.name for s in plan.slaves]
        assert set(net.health) == {s.name for s in plan.slaves}
        assert net.cycle()
        with pytest.raises(EcatcfgError, match="'Term 9 \\(EL9011\\)' is a passive slave"):
            net.online("Term 9 (EL9011)")
        assert len(net.segment.slaves) == len(plan.slaves)


def _soem_on_simulate(rig, eni: Path) -> tuple[dict, list[str]]:
    sim, lines = start_simulate(rig, "--eni", str(eni))
    assert lines and lines[-1].startswith("ready:"), "".join(lines) + sim.stderr.read()
    report = soem(rig, {"outputs": "5a", "cycles": 20})
    sim.terminate()
    sim.communicate(timeout=10)
    return report, lines


def test_soem_on_simulate_finds_only_the_active_slaves(veth_netns, pysoem_module,
                                                       passive_eni, example_eni):
    """SOEM finds the five slaves with an ESC, brings them to OP, and reads the working
    counter of its LRW by the ESC rule (+2 per slave with outputs, +1 per slave with
    inputs, ETG.1000.4), the same as on the ENI without the passive slaves: they add
    nothing to it.  (SOEM's own expected_wkc leaves out slaves whose inputs are only bits,
    as tests/test_soem.py measured; here the EX1004s.)"""
    report, lines = _soem_on_simulate(veth_netns, passive_eni)
    assert lines[-1].startswith("ready: 5 slaves on")
    assert "(2 passive not emulated)" in lines[-1]
    assert sum("passive: no ESC, not emulated" in line for line in lines) == 2
    plain, _ = _soem_on_simulate(veth_netns, example_eni)
    active, _ = xml_slaves(passive_eni)
    assert report["found"] == len(active)
    assert [(s["vendor"], s["product"], s["revision"]) for s in report["slaves"]] == [
        tuple(int(s.findtext(f"Info/{t}")) & 0xFFFFFFFF
              for t in ("VendorId", "ProductCode", "RevisionNo")) for s in active]
    assert report["safeop"] == 4 and report["op"] == 8, report
    assert report["sizes"] == plain["sizes"]
    assert report["wkc"] == sum(2 * (o > 0) + (i > 0) for o, i in report["sizes"])
    assert report["wkc"] == plain["wkc"] and report["expected_wkc"] == plain["expected_wkc"]


# -- the compiler -----------------------------------------------------------------------------

TOPOLOGY = """\
master: {name: passive-line, cycle_time_us: 1000}
slaves:
  - {name: coupler, device: EX1100}
  - {name: buttons, device: EX1004}
  - {name: feed, device: EX9100}
  - {name: lamps, device: EX2008}
  - {name: sensors, device: EX1004}
  - {name: cap, device: EX9011}
"""


def _library() -> Library:
    return Library([EXAMPLES / "esi", PASSIVE_ESI], cache=False)


def _compile_passive_topology(tmp_path: Path, text: str = TOPOLOGY) -> Path:
    topo = tmp_path / "line.yaml"
    topo.write_text(text)
    eni = tmp_path / "line.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo),
                           "--esi", str(EXAMPLES / "esi"), "--esi", str(PASSIVE_ESI),
                           "-o", str(eni), "--no-cache"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    assert "4 slaves and 2 passive" in done.stdout
    return eni


def test_fixture_devices_are_passive_and_the_examples_are_not():
    lib = _library()
    kinds = {e.type: lib.device(e).passive for e in lib.entries}
    assert kinds["EX9100"] and kinds["EX9011"]
    assert not any(v for k, v in kinds.items() if not k.startswith("EX9"))


ODD_ESI = """<?xml version="1.0" encoding="UTF-8"?>
<EtherCATInfo Version="1.17">
  <Vendor><Id>#xE0000ECA</Id><Name>ecatcfg Example Devices</Name></Vendor>
  <Descriptions>
    <Groups><Group><Type>X</Type><Name>x</Name></Group></Groups>
    <Devices>
      <Device Physics="YY">
        <Type ProductCode="#x7001" RevisionNo="#x1">EXJ7001</Type>
        <Name>an ESC and nothing else described: a junction</Name>
        <GroupType>X</GroupType>
      </Device>
      <Device Physics="KK">
        <Type>EXB7002</Type>
        <Name>SyncManagers but no identity: a broken ESI</Name>
        <GroupType>X</GroupType>
        <Sm ControlByte="#x64" Enable="1" StartAddress="#x1100">Outputs</Sm>
      </Device>
    </Devices>
  </Descriptions>
</EtherCATInfo>
"""


def test_passive_needs_both_no_product_code_and_no_esc(tmp_path):
    """A ProductCode says an ESC answers with it (even with nothing else described); an
    ESI without a ProductCode that describes SyncManagers is broken, not passive, and
    compiling it stays an error."""
    esi = tmp_path / "odd.xml"
    esi.write_text(ODD_ESI)
    lib = Library([esi], cache=False)
    kinds = {e.type: lib.device(e).passive for e in lib.entries}
    assert kinds == {"EXJ7001": False, "EXB7002": False}
    topo = tmp_path / "odd.yaml"
    topo.write_text("slaves:\n  - {name: j, device: EXJ7001}\n  - {name: b, device: EXB7002}\n")
    with pytest.raises(TopologyError) as exc:
        compile_topology(topology.load(str(topo)), lib)
    [problem] = exc.value.problems
    assert problem.line == 3 and "has no readable identity" in problem.message


def test_beckhoff_passive_terminals_are_passive(corpus_extra):
    """Beckhoff's own ESI: the EL9011 end terminal and EL9100 potential feed have no ESC;
    the EL9110 (a potential feed with diagnostics) and the EL9410 (E-bus refresh) do."""
    lib = Library([corpus_extra / "esi" / "dls" / "Beckhoff EL9xxx.xml"], cache=False)
    kinds = {e.type: lib.device(e).passive for e in lib.entries}
    assert kinds["EL9011"] and kinds["EL9100"] and kinds["EL9400"]
    assert not kinds["EL9110"] and not kinds["EL9410"]


def test_compiler_writes_passive_slaves_without_positions(tmp_path, eni_schema):
    eni = _compile_passive_topology(tmp_path)
    assert eni_schema.validate(etree.parse(str(eni))), eni_schema.error_log
    active, passive = xml_slaves(eni)
    assert [s.findtext("Info/Name") for s in active] == ["coupler", "buttons", "lamps",
                                                         "sensors"]
    assert [int(s.findtext("Info/AutoIncAddr")) & 0xFFFF for s in active] == [
        0, 0xFFFF, 0xFFFE, 0xFFFD]
    assert [int(s.findtext("Info/PhysAddr")) for s in active] == [1001, 1002, 1003, 1004]
    assert [s.findtext("Info/Name") for s in passive] == ["feed", "cap"]
    for el in passive:
        assert el.find("Info/PhysAddr") is None and el.find("Info/AutoIncAddr") is None
        assert el.find("Info/Physics") is None and el.find("InitCmds") is None
        assert int(el.findtext("Info/VendorId")) & 0xFFFFFFFF == 0xE0000ECA
        assert el.findtext("Info/ProductCode") == "0"
        assert len(el.find("ProcessData")) == 0
    # PreviousPort of a passive slave and of the slave after it: the slave with an ESC
    # before them, port B.
    order = [s.findtext("Info/Name") for s in etree.parse(str(eni)).getroot().iter("Slave")]
    assert order == ["coupler", "buttons", "feed", "lamps", "sensors", "cap"]
    ports = {s.findtext("Info/Name"): (s.findtext("PreviousPort/Port"),
                                       s.findtext("PreviousPort/PhysAddr"))
             for s in etree.parse(str(eni)).getroot().iter("Slave")}
    assert ports["feed"] == ports["lamps"] == ("B", "1002")
    assert ports["cap"] == ("B", "1004")


def test_compiled_passive_slaves_apply_to_op(tmp_path):
    eni = _compile_passive_topology(tmp_path)
    rc, report, err = _apply_virtual(eni)
    assert rc == 0, err
    _check_op(report, eni)


def _topology_error(tmp_path: Path, text: str) -> TopologyError:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(TopologyError) as exc:
        compile_topology(topology.load(str(path)), _library())
    return exc.value


@pytest.mark.parametrize("extra, key", [
    ("station_address: 1010", "station_address"),
    ("sdos: [{index: 0x8000, value: 1}]", "sdos"),
    ("parent: coupler", "parent"),
])
def test_what_needs_an_esc_is_a_topology_error(tmp_path, extra, key):
    text = TOPOLOGY.replace("{name: feed, device: EX9100}",
                            f"{{name: feed, device: EX9100, {extra}}}")
    err = _topology_error(tmp_path, text)
    [problem] = err.problems
    assert problem.line == 5 and f"'{key}' must go" in problem.message
    assert "passive terminal without an ESC" in problem.message


@pytest.mark.parametrize("old, new, line, first", [
    ("{name: cap, device: EX9011}", "{name: feed, device: EX9011}", 8, 5),
    ("{name: sensors, device: EX1004}", "{name: feed, device: EX1004}", 7, 5),
    ("{name: lamps, device: EX2008}", "{name: buttons, device: EX2008}", 6, 4),
])
def test_slave_names_are_unique_with_passive_ones_among_them(tmp_path, old, new, line,
                                                              first):
    [problem] = _topology_error(tmp_path, TOPOLOGY.replace(old, new)).problems
    assert problem.line == line
    assert f"is already used by the slave at line {first}" in problem.message


def test_a_slave_plugged_into_a_passive_one_is_an_error(tmp_path):
    text = TOPOLOGY.replace("{name: lamps, device: EX2008}",
                            "{name: lamps, device: EX2008, parent: feed}")
    [problem] = _topology_error(tmp_path, text).problems
    assert problem.line == 6 and "its parent 'feed' is a passive terminal" in problem.message


def test_errors_of_active_slaves_keep_their_lines(tmp_path):
    """The active slaves are compiled without the passive ones: their errors still name
    their own lines in the user's file."""
    text = TOPOLOGY.replace("{name: sensors, device: EX1004}",
                            "{name: sensors, device: EX1004, dc: NoSuchMode}")
    [problem] = _topology_error(tmp_path, text).problems
    assert problem.line == 7 and "'sensors'" in problem.message


def test_a_passive_slave_inside_a_compiled_hot_connect_group_is_an_error(tmp_path):
    text = TOPOLOGY.replace("{name: buttons, device: EX1004}",
                            "{name: buttons, device: EX1004, hot_connect: true, alias: 7}")
    [problem] = _topology_error(tmp_path, text).problems
    assert problem.line == 5 and "inside the hot-connect group of 'buttons'" in problem.message


def test_a_passive_power_feed_counts_in_the_ebus_budget(tmp_path):
    """23 EX1004 (90 mA each) draw 2070 mA from the coupler's 2000: a warning at the 23rd,
    its own line although a passive slave before it is not compiled with it.  A passive
    EX9400 (-2000 mA, like Beckhoff's EL9400) after the 12th feeds the rest: none."""
    lib = _library()

    def warnings(feed_after: int | None) -> list[EcatcfgError]:
        rows = ["slaves:", "  - {name: c, device: EX1100}", "  - {name: cap0, device: EX9100}"]
        for i in range(23):
            rows.append(f"  - {{name: t{i}, device: EX1004}}")
            if i == feed_after:
                rows.append("  - {name: feed, device: EX9400}")
        path = tmp_path / "ebus.yaml"
        path.write_text("\n".join(rows) + "\n")
        return compile_topology(topology.load(str(path)), lib).warnings

    [warning] = warnings(None)
    assert warning.line == 3 + 23 and "2070 mA" in warning.message
    assert warnings(11) == []


def test_a_tree_with_hot_connect_groups_and_passive_terminals(tmp_path, eni_schema):
    """examples/tree/hotconnect.yaml with a potential feed after ``inputs`` (just before
    the junction's group) and an end cap after ``outputs`` (a group of its own): the
    compiled ENI validates, the tree is verified port by port without them, both groups
    are left out while the junction's cable is out and join when it is back; the passive
    devices of the ESI library are never emulated."""
    import time

    text = (EXAMPLES / "tree" / "hotconnect.yaml").read_text()
    text = text.replace("  - name: junction\n",
                        "  - {name: feed, device: EX9100}\n  - name: junction\n")
    text = text.replace("  - name: axis3\n", "  - {name: cap, device: EX9011}\n"
                                             "  - name: axis3\n")
    path = tmp_path / "hc.yaml"
    path.write_text(text)
    esi = [EXAMPLES / "tree" / "esi", EXAMPLES / "esi", PASSIVE_ESI]
    built = compile_topology(topology.load(str(path)), Library(esi, cache=False)).plan
    data = eni_writer.to_bytes(built)
    assert eni_schema.validate(etree.fromstring(data).getroottree()), eni_schema.error_log
    plan = eni_reader.read_bytes(data, "hc.eni.xml")
    assert [s.name for s in plan.in_file_order()] == [
        "coupler", "inputs", "feed", "junction", "axis1", "axis2", "outputs", "cap", "axis3"]
    assert [s.position for s in plan.slaves] == list(range(7))
    with Network.virtual(plan, esi=esi) as net:
        seg = net.segment
        assert [s.name for s in seg.slaves] == [s.name for s in plan.slaves]
        seg.remove_cable("junction")
        net.up()
        assert [(s.name, s.state) for s in seg.slaves if s.state == AlState.OP] == [
            ("coupler", AlState.OP), ("inputs", AlState.OP), ("axis3", AlState.OP)]
        seg.restore_cable("junction")
        start = time.monotonic()
        while not all(h.online for h in net.health.values()):
            assert time.monotonic() - start < 20, net.health
            net.cycle()
            time.sleep(0.0005)
        assert set(net.health) == {s.name for s in plan.slaves}
        assert all(s.state == AlState.OP for s in seg.slaves)
        assert [s.station_address for s in seg.slaves] == list(range(1001, 1008))
