"""``ecatcfg compile``: the example line, the NetworkPlan's rules, and bad topologies."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest

from conftest import EXAMPLES, write
from ecatcfg.cli import main
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.esc import Cmd, FmmuConfig, FmmuType, SmConfig
from ecatcfg.esi.library import Library

ESI = EXAMPLES / "esi"


def compile_text(tmp_path: Path, text: str, esi: list[Path] | None = None) -> build.CompileResult:
    path = write(tmp_path, "t.yaml", text)
    return build.compile_topology(topology.load(path), Library(esi or [ESI], cache=False))


def example_plan() -> NetworkPlan:
    return build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([ESI], cache=False)).plan


def cmds(plan: NetworkPlan, slave: str, comment: str):
    return [c for c in plan.slave(slave).init_cmds if c.comment == comment]


# -- the example line -----------------------------------------------------------------------

def test_example_compiles_to_a_schema_valid_deterministic_eni(tmp_path, eni_schema, capsys):
    from lxml import etree
    out1, out2, header = tmp_path / "a.xml", tmp_path / "b.xml", tmp_path / "line.h"
    args = ["compile", str(EXAMPLES / "topology.yaml"), "--esi", str(ESI)]
    assert main(args + ["-o", str(out1), "--header", str(header)]) == 0
    assert main(args + ["-o", str(out2)]) == 0
    assert out1.read_bytes() == out2.read_bytes()
    doc = etree.parse(str(out1))
    assert eni_schema.validate(doc), eni_schema.error_log
    assert "wrote" in capsys.readouterr().out
    assert b"#define ECAT_IN_AXIS1" in header.read_bytes()
    # Only the two outputs and the header were written: no temporary files left behind.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.xml", "b.xml", "line.h"]


def test_reading_our_eni_back_gives_the_same_plan():
    plan = example_plan()
    assert eni_reader.read_bytes(eni_writer.to_bytes(plan), "x.xml") == plan


def test_json_topology_is_accepted(tmp_path):
    data = {"master": {"name": "j"}, "slaves": [{"name": "c", "device": "EX1100"},
                                                {"name": "d", "device": "EX1004"}]}
    plan = compile_text(tmp_path, json.dumps(data)).plan
    assert [s.name for s in plan.slaves] == ["c", "d"]


def test_addresses_and_positions(tmp_path):
    plan = compile_text(tmp_path, """
slaves:
  - {name: a, device: EX1100}
  - {name: b, device: EX1004, station_address: 2000, alias: 7}
  - {name: c, device: EX1004}
""").plan
    assert [(s.phys_addr, s.auto_inc_addr) for s in plan.slaves] == [
        (1001, 0), (2000, 0xFFFF), (1003, 0xFFFE)]
    addr = cmds(plan, "b", "set physical address")[0]
    assert (addr.cmd, addr.adp, addr.ado, addr.data) == (Cmd.APWR, 0xFFFF, 0x10, b"\xd0\x07")
    alias = cmds(plan, "b", "check station alias")[0]
    assert (alias.cmd, alias.ado, alias.validate.data) == (Cmd.APRD, 0x12, b"\x07\x00")
    # After the address is set, commands use it (FPxx).
    assert all(c.adp == 2000 for c in cmds(plan, "b", "set fmmu 0 (inputs)"))


def test_bit_terminals_share_a_byte_and_wkc_counts_directions():
    plan = example_plan()
    f_buttons = FmmuConfig.from_bytes(cmds(plan, "buttons", "set fmmu 0 (inputs)")[0].payload)
    f_sensors = FmmuConfig.from_bytes(cmds(plan, "sensors", "set fmmu 0 (inputs)")[0].payload)
    assert f_buttons.logical_start == f_sensors.logical_start
    assert (f_buttons.logical_start_bit, f_buttons.logical_stop_bit) == (0, 3)
    assert (f_sensors.logical_start_bit, f_sensors.logical_stop_bit) == (4, 7)
    assert f_sensors.type == FmmuType.READ and f_sensors.length == 1
    lamps = FmmuConfig.from_bytes(cmds(plan, "lamps", "set fmmu 0 (outputs)")[0].payload)
    assert lamps.type == FmmuType.WRITE and lamps.logical_start == f_buttons.logical_start + 1
    [frame] = plan.cyclic[0].frames
    lrw = next(c for c in frame.cmds if c.cmd == Cmd.LRW)
    # buttons +1, sensors +1, lamps +2, axis1 +3
    assert lrw.cnt == 7
    brd = next(c for c in frame.cmds if c.cmd == Cmd.BRD)
    assert (brd.ado, brd.cnt) == (0x130, 5)
    names = [v.name for v in plan.process_image.inputs]
    assert names[:2] == ["buttons.Channel 1.Input", "buttons.Channel 2.Input"]
    assert [v.bit_offs for v in plan.process_image.inputs[:8]] == list(range(8))


def test_sm_lengths_follow_the_assigned_pdos_and_oponly_sms_wait_for_op():
    plan = example_plan()
    sm2 = SmConfig.from_bytes(cmds(plan, "axis1", "set sm 2 (outputs)")[0].payload)
    sm3 = SmConfig.from_bytes(cmds(plan, "axis1", "set sm 3 (inputs)")[0].payload)
    assert (sm2.start, sm2.length, sm2.control, sm2.enable) == (0x1100, 6, 0x64, True)
    assert sm3.length == 6 + 10           # 0x1A00 (6 bytes) + the remapped 0x1A01 (10)
    [lamps_sm] = cmds(plan, "lamps", "set sm 0 (outputs)")
    assert [t.value for t in lamps_sm.transitions] == ["SO"]
    assert cmds(plan, "lamps", "clear output sm")[0].transitions[0].value == "OS"


def test_pdo_assignment_and_mapping_coe_commands():
    plan = example_plan()
    coe = [(c.comment, c.index, c.subindex, c.data.hex(), c.complete_access)
           for c in plan.slave("axis1").mailbox.coe_init_cmds]
    assert coe[:8] == [
        ("clear sm pdos (0x1C12)", 0x1C12, 0, "00", False),
        ("clear sm pdos (0x1C13)", 0x1C13, 0, "00", False),
        ("clear pdo 0x1600 entries", 0x1600, 0, "00", False),       # configurable, unassigned
        ("download pdo 0x1601 entries", 0x1601, 0, "0200100040602000ff60", True),
        ("download pdo 0x1A00 entries", 0x1A00, 0, "02001000416020006460", True),
        ("download pdo 0x1A01 entries", 0x1A01, 0, "0300100041602000646020006c60", True),
        ("download pdo 0x1C12 index", 0x1C12, 0, "01000116", True),
        ("download pdo 0x1C13 index", 0x1C13, 0, "0200001a011a", True),
    ]
    # The user's 0x6060 replaces the ESI's InitCmd in place, under the ESI's comment.
    assert coe[8] == ("Modes of operation", 0x6060, 0, "09", False)
    assert coe[9:] == [("Interpolation time period: Time period units", 0x60C2, 1, "01", False),
                       ("Interpolation time period: Time period index", 0x60C2, 2, "fd", False)]


def test_dc_registers_from_the_opmode():
    plan = example_plan()
    axis = plan.slave("axis1")
    assert (axis.dc.reference_clock, axis.dc.cycle_time0) == (True, 1_000_000)
    by = {c.comment: c for c in axis.init_cmds}
    assert by["set DC cycle time"].data == struct.pack("<II", 1_000_000, 0)
    assert by["set DC start time"].data == bytes(8)
    assert by["set DC activation"].data == b"\x00\x03"          # AssignActivate #x0300
    frame = plan.cyclic[0].frames[0]
    armw = next(c for c in frame.cmds if c.cmd == Cmd.ARMW)
    assert (armw.adp, armw.ado) == (0xFFFC, 0x910)              # axis1 is position 4


def test_transition_order_of_a_mailbox_slave():
    plan = example_plan()
    ip = [c.comment for c in plan.slave("axis1").init_cmds if any(t.value == "IP"
                                                                  for t in c.transitions)]
    assert ip == [
        "set device state to INIT", "check device state for INIT", "assign EEPROM to ECAT",
        "check vendor id", "check vendor id", "check product code", "check product code",
        "set physical address", "clear sm 0/1 (mailbox out/in)", "set sm 0 (mailbox out)",
        "set sm 1 (mailbox in)", "clear DC activation", "clear sms",
        "set fmmu 2 (mailbox state)", "assign EEPROM to PDI", "set device state to PREOP",
        "check device state for PREOP", "assign EEPROM back to ECAT"]
    ps = [c.comment for c in plan.slave("axis1").init_cmds if [t.value for t in c.transitions]
          == ["PS"]]
    assert ps == ["set DC cycle time", "set DC start time", "set DC activation",
                  "set DC latch cfg", "set sm 2 (outputs)", "set sm 3 (inputs)",
                  "set fmmu 0 (outputs)", "set fmmu 1 (inputs)",
                  "set device state to SAFEOP", "check device state for SAFEOP"]


def test_layout_lrd_lwr_windows(tmp_path):
    plan = compile_text(tmp_path, """
master: {layout: lrd_lwr}
slaves:
  - {name: c, device: EX1100}
  - {name: i, device: EX1004}
  - {name: o, device: EX2008}
  - {name: d, device: EXD-402}
""").plan
    frame = plan.cyclic[0].frames[0]
    lwr = next(c for c in frame.cmds if c.cmd == Cmd.LWR)
    lrd = next(c for c in frame.cmds if c.cmd == Cmd.LRD and c.addr != 0x09000000)
    assert (lwr.addr, lwr.length, lwr.cnt) == (0x01000000, 1 + 6, 2)
    assert (lrd.addr, lrd.length, lrd.cnt) == (0x01000800, 1 + 6, 2)
    # Image regions of different commands never overlap.
    spans = sorted((c.input_offs, c.input_offs + c.length) for c in frame.cmds)
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))


def test_frames_split_at_the_ethernet_limit(tmp_path):
    drives = "\n".join(f"  - {{name: d{i}, device: EXD-402, tx_pdos: [0x1A00, 0x1A01]}}"
                       for i in range(150))
    plan = compile_text(tmp_path, f"slaves:\n{drives}\n").plan
    frames = plan.cyclic[0].frames
    assert len(frames) == 2
    for frame in frames:
        size = 2 + sum(12 + c.length for c in frame.cmds)
        assert size <= 1500
    lrws = [c for f in frames for c in f.cmds if c.cmd == Cmd.LRW]
    assert sum(c.cnt for c in lrws) == 150 * 3
    assert sum(c.length for c in lrws) == 150 * 12         # max(6 out, 12 in) per drive
    # consecutive logical windows, each slave whole in one datagram
    assert lrws[1].addr == lrws[0].addr + lrws[0].length
    assert all(c.length % 12 == 0 for c in lrws)


def test_ebus_current_warning(tmp_path):
    terminals = "\n".join(f"  - {{name: t{i}, device: EX1004}}" for i in range(23))
    result = compile_text(tmp_path, f"slaves:\n  - {{name: c, device: EX1100}}\n{terminals}\n")
    [warning] = result.warnings
    assert warning.line == 2 + 23 and "2070 mA" in warning.message and "2000 mA" in warning.message
    result = compile_text(tmp_path, "slaves:\n  - {name: c, device: EX1100}\n"
                                    + "\n".join(terminals.splitlines()[:22]) + "\n")
    assert result.warnings == []


def test_ebus_current_follows_the_ebus_not_the_bus_order(tmp_path):
    """A junction in the first coupler's row sends the frame through its Ethernet port D
    (a second coupler and its row) before its E-bus port C goes on with the first row
    (ESC port order A, D, B, C).  The terminals on port C draw from the first coupler:
    900 mA of inputs + 220 mA of the junction + 110 mA per output exceed its 2000 mA at
    the 9th output (2110 mA).  Summed in bus order, they were charged to the second
    coupler, which feeds only its own 5 inputs, and no warning came."""
    tree = EXAMPLES / "tree" / "esi"
    rows = ["slaves:", "  - {name: c1, device: EXB1100}"]
    rows += [f"  - {{name: in{i}, device: EXB1018}}" for i in range(10)]
    rows += ["  - {name: junction, device: EXB1122}",
             "  - {name: c2, device: EXB1100, parent: junction, port: D}"]
    rows += [f"  - {{name: u{i}, device: EXB1018}}" for i in range(5)]
    rows += ["  - {name: out0, device: EXB2018, parent: junction, port: C}"]
    rows += [f"  - {{name: out{i}, device: EXB2018}}" for i in range(1, 12)]
    result = compile_text(tmp_path, "\n".join(rows) + "\n", [tree])
    order = [s.name for s in result.plan.slaves]
    assert order.index("u4") < order.index("out0")     # the branch comes first on the wire
    [warning] = result.warnings
    assert warning.line == 1 + rows.index("  - {name: out8, device: EXB2018}")
    assert "E-bus of 'c1'" in warning.message and "2110 mA" in warning.message
    assert "up to slave 'out8'" in warning.message and "2000 mA" in warning.message


def test_schema_command_prints_the_topology_schema(capsys):
    assert main(["schema", "topology"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["title"] == "ecatcfg topology"
    assert set(schema["properties"]) == {"master", "slaves"}
    import jsonschema
    jsonschema.validate({"slaves": [{"name": "x", "device": "EX1100", "rx_pdos": [5632]}]},
                        schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"slaves": [{"name": "x", "devise": "EX1100"}]}, schema)


# -- bad topologies: exit 1, the topology line, and no output --------------------------------

BAD = [
    ("unknown device", "  - {name: x, device: EX1005}\n", 3, "closest: EX1100, EX1008, EX1004"),
    ("revision", "  - {name: x, device: '0xE0000ECA:0x2004:0x99'}\n", 3,
     "revision 0x99 of 0xe0000eca:0x2004 (EX1004) is not in the library"),
    ("unknown PDO", "  - {name: x, device: EXD-402,\n     rx_pdos: [0x1605]}\n", 4,
     "has no RxPdo 0x1605"),
    ("excluded", "  - {name: x, device: EXD-402,\n     rx_pdos: [0x1600, 0x1601]}\n", 4,
     "excludes 0x1601"),
    ("mandatory", "  - {name: x, device: EXD-402,\n     tx_pdos: [0x1A01]}\n", 4,
     "mandatory PDO 0x1A00"),
    ("not mappable", "  - name: x\n    device: EXD-402\n    pdo_mapping:\n"
                     "      0x1600: [[0x6040, 0, 16], [0x6041, 0, 16]]\n", 6,
     "0x6041:00 (Statusword) cannot be mapped into an RxPDO"),
    ("fixed PDO", "  - name: x\n    device: EX1004\n    pdo_mapping: {0x1A00: [[0x6000, 1, 1]]}\n",
     5, "does not support PDO mapping"),
    ("value range", "  - name: x\n    device: EXD-402\n    sdos:\n"
                    "      - {index: 0x6060, value: 300}\n", 6, "outside SINT (-128..127)"),
    ("read-only", "  - name: x\n    device: EXD-402\n    sdos:\n"
                  "      - {index: 0x6041, value: 1}\n", 6, "is not writable in PreOp"),
    ("no object", "  - name: x\n    device: EXD-402\n    sdos:\n"
                  "      - {index: 0x2000, value: 1}\n", 6, "object 0x2000 is not in"),
    ("dc mode", "  - {name: x, device: EXD-402,\n     dc: Sync}\n", 4,
     "no DC op mode 'Sync'; EXD-402 has DC, FreeRun"),
    ("unknown key", "  - {name: x, device: EX1004, rxpdos: [1]}\n", 3, "unknown key"),
    ("duplicate address", "  - {name: x, device: EX1004}\n"
                          "  - {name: y, device: EX1004, station_address: 1001}\n", 4,
     "station address 1001 is also the address of slave 'x'"),
    ("modules on a plain device", "  - {name: x, device: EX1004,\n     modules: {1: 5}}\n", 4,
     "not a modular device"),
    ("not YAML", "  - {name: x, device: [}\n", 3, "not valid YAML"),
]


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_topology(tmp_path, capsys, case):
    _, slaves, line, text = case
    topo = write(tmp_path, "bad.yaml", "master: {name: m}\nslaves:\n" + slaves)
    out = tmp_path / "out.xml"
    assert main(["compile", str(topo), "--esi", str(ESI), "-o", str(out),
                 "--header", str(tmp_path / "out.h")]) == 1
    err = capsys.readouterr().err
    assert f"{topo}:{line}:" in err, err
    assert text in err, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml"]


def test_all_errors_are_reported_together(tmp_path):
    with pytest.raises(TopologyError) as info:
        compile_text(tmp_path, "slaves:\n  - {name: a, device: EX9}\n"
                               "  - {name: b, device: EX1004, rx_pdos: [0x1600]}\n")
    assert [p.line for p in info.value.problems] == [2, 3]


def test_existing_output_survives_an_error(tmp_path):
    out = write(tmp_path, "out.xml", "old")
    topo = write(tmp_path, "bad.yaml", "slaves:\n  - {name: a, device: EX9}\n")
    assert main(["compile", str(topo), "--esi", str(ESI), "-o", str(out)]) == 1
    assert out.read_text() == "old"


def test_yaml_alias_bomb_is_refused(tmp_path, capsys):
    bomb = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
        for p, c in zip("abcdefg", "bcdefgh")) + "slaves: [*h]\n"
    topo = write(tmp_path, "bomb.yaml", bomb)
    assert main(["compile", str(topo), "--esi", str(ESI), "-o", str(tmp_path / "o")]) == 1
    assert "more than" in capsys.readouterr().err


def test_usage_errors(tmp_path, capsys):
    assert main(["compile", str(tmp_path / "missing.yaml"), "--esi", str(ESI),
                 "-o", str(tmp_path / "o.xml")]) == 2
    topo = EXAMPLES / "topology.yaml"
    assert main(["compile", str(topo), "--esi", str(ESI),
                 "-o", str(tmp_path / "no" / "o.xml")]) == 2
    assert main(["compile", str(topo), "--esi", str(tmp_path / "nothing"),
                 "-o", str(tmp_path / "o.xml")]) == 2


# -- modular devices ------------------------------------------------------------------------

MODULES = """<?xml version="1.0"?>
<EtherCATModule Version="1.12"><Vendor><Id>#xE0000ECA</Id><Name>V</Name></Vendor><Modules>
<Module><Type ModuleIdent="#x1111">M-DI</Type><Name>DI module</Name>
<TxPdo Fixed="1" Sm="3"><Index DependOnSlot="1">#x1A00</Index><Name>In</Name>
<Entry><Index DependOnSlot="1">#x6000</Index><SubIndex>1</SubIndex><BitLen>8</BitLen>
<Name>DI</Name><DataType>USINT</DataType></Entry></TxPdo></Module>
<Module><Type ModuleIdent="#x2222">M-AO</Type><Name>AO module</Name>
<RxPdo Fixed="1" Sm="2"><Index DependOnSlot="1">#x1600</Index><Name>Out</Name>
<Entry><Index DependOnSlot="1">#x7000</Index><SubIndex>1</SubIndex><BitLen>16</BitLen>
<Name>AO</Name><DataType>INT</DataType></Entry></RxPdo></Module>
</Modules></EtherCATModule>
"""
COUPLER_BODY = (
    '<Fmmu>Outputs</Fmmu><Fmmu>Inputs</Fmmu>'
    '<Sm ControlByte="#x26" DefaultSize="128" Enable="1" StartAddress="#x1000">MBoxOut</Sm>'
    '<Sm ControlByte="#x22" DefaultSize="128" Enable="1" StartAddress="#x1080">MBoxIn</Sm>'
    '<Sm ControlByte="#x64" Enable="1" StartAddress="#x1100">Outputs</Sm>'
    '<Sm ControlByte="#x20" Enable="1" StartAddress="#x1180">Inputs</Sm>'
    '<Slots SlotIndexIncrement="#x10" SlotPdoIncrement="1">'
    '<Slot><Name>S1</Name><ModuleIdent>#x1111</ModuleIdent></Slot>'
    '<Slot><Name>S2</Name><ModuleIdent Default="1">#x2222</ModuleIdent></Slot></Slots>')


@pytest.fixture
def modular(tmp_path) -> Path:
    from conftest import device_xml, esi_xml
    folder = tmp_path / "esi"
    folder.mkdir()
    write(folder, "coupler.xml", esi_xml(device_xml("MX-1", body=COUPLER_BODY)).replace(
        "<Vendor>", "<InfoReference>mods.xml</InfoReference><Vendor>"))
    write(folder, "mods.xml", MODULES)
    return folder


def test_modules_shift_pdos_and_objects_by_slot(tmp_path, modular):
    plan = compile_text(tmp_path, "slaves:\n  - {name: m, device: MX-1, modules: {1: 0x1111}}\n",
                        [modular]).plan
    pdos = {p.index: p for p in plan.slaves[0].process_data.pdos}
    # slot 1: no offset; slot 2 (its default module 0x2222): PDO +1, objects +0x10
    assert pdos[0x1A00].entries[0].index == 0x6000 and pdos[0x1A00].sm == 3
    assert pdos[0x1601].entries[0].index == 0x7010 and pdos[0x1601].sm == 2
    names = {v.name for v in plan.process_image.inputs + plan.process_image.outputs}
    assert names == {"m.Module 1 (DI module).In.DI", "m.Module 2 (AO module).Out.AO"}


def test_module_that_does_not_fit_its_slot(tmp_path, modular, capsys):
    topo = write(tmp_path, "t.yaml", "slaves:\n  - name: m\n    device: MX-1\n"
                                     "    modules: {1: 0x2222, 3: 0x1111}\n")
    assert main(["compile", str(topo), "--esi", str(modular), "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert f"{topo}:4: slave 'm': module 0x00002222 (M-AO) does not fit slot 1 (S1)" in err
    assert "slot 3 does not exist; MX-1 has 2 slots" in err
    assert not (tmp_path / "o").exists()


def test_etg2001_modular_drive(tmp_path, corpus):
    plan = compile_text(tmp_path, "slaves:\n  - {name: d, device: Drive1, "
                                  "modules: {1: 0x100, 2: 0x200}}\n",
                        [corpus / "esi/modular/ETG2001_ModulesSlots_CiA402.xml"]).plan
    d = plan.slaves[0]
    assigned = {p.index: [hex(e.index) for e in p.entries] for p in d.process_data.pdos
                if p.sm is not None}
    # SlotPdoIncrement 16, SlotIndexIncrement 0x800: axis 2 maps 0x68xx objects.
    assert assigned == {0x1600: ["0x607a", "0x6040"], 0x1A00: ["0x6064", "0x6041"],
                        0x1610: ["0x68ff", "0x6840"], 0x1A10: ["0x686c", "0x6841"]}
    coe = [(c.index, c.subindex, c.data.hex()) for c in d.mailbox.coe_init_cmds]
    assert coe[-2:] == [(0x1C12, 0, "020000161016"), (0x1C13, 0, "0200001a101a")]
