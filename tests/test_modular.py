"""Modular stations: a row of modules in one multi-instance slot (Weidmueller UR20, UTRIO
UC20), axis modules (Copley XE2), the module ident lists 0xF030/0xF050 and the virtual
station.

Expectations come from the vendors' files read here with lxml (module idents, PDO and entry
indices, names, the Slots increments), the ETG.2100 schema and SOEM, not from ecatcfg's
reader or compiler.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path

import pytest
from rig import serve_in_memory, start_simulate
from lxml import etree

from conftest import EXAMPLES

from ecatcfg.compiler import build, topology
from ecatcfg.compiler.plugged import plugged_devices
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.network import Network
from ecatcfg.runtime.master.replay import ApplyError

# 12 modules of 9 kinds (digital in/out, relay, analog in/out, counter, RTD).
UR20 = ["UR20-4DI-P", "UR20-8DI-P-3W", "UR20-16DI-P", "UR20-4DO-P", "UR20-8DO-P",
        "UR20-16DO-P", "UR20-4AI-UI-16", "UR20-4AO-UI-16", "UR20-4RO-CO-255", "UR20-2CNT-100",
        "UR20-4AI-RTD-DIAG", "UR20-4DI-P"]
UTRIO = ["UC20-8DI-NP", "UC20-16DI-NP", "UC20-16DO-P", "UC20-8DO-P", "UC20-4AI-U",
         "UC20-4AO-U", "UC20-4RTD", "UC20-8DI-NP"]


def _hex(text: str | None) -> int:
    text = (text or "").strip()
    return int(text[2:], 16) if text[:2] in ("#x", "0x") else int(text)


def vendor_modules(path: Path) -> dict[str, etree._Element]:
    root = etree.parse(str(path)).getroot()
    return {m.findtext("Type").strip(): m for m in root.iter("Module")}


def station(name: str, device: str, modules: list[str] | dict, slot: int = 1) -> str:
    mods = modules if isinstance(modules, dict) else {slot: modules}
    body = ", ".join(f"{n}: [{', '.join(repr(x) for x in v)}]" for n, v in mods.items())
    return f"slaves:\n  - name: {name}\n    device: {device}\n    modules: {{{body}}}\n"


def compile_station(text: str, lib: Library) -> NetworkPlan:
    plan = build.compile_topology(topology.loads(text, "t.yaml"), lib).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "t.eni.xml")


@pytest.fixture(scope="module")
def modular_lib(corpus: Path) -> Library:
    return Library([corpus / "esi" / "modular", corpus / "esi" / "drives"], cache=False)


def _expected_variables(modules: list[str], vendor: dict[str, etree._Element], slave: str,
                        pdo_inc: int, index_inc: int) -> dict[str, tuple[int, int, int]]:
    """Variable name -> (PDO index, entry index, subindex) for every module channel, from
    the vendor file: position P moves DependOnSlot indices by (P - 1) x the increment."""
    want = {}
    for pos, type_name in enumerate(modules, start=1):
        m = vendor[type_name]
        label = f"Module {pos} ({m.findtext('Name').strip()})"
        for pdo in m.findall("TxPdo") + m.findall("RxPdo"):
            idx = pdo.find("Index")
            pdo_index = _hex(idx.text) + (pos - 1) * pdo_inc * (idx.get("DependOnSlot")
                                                                  in ("1", "true"))
            for e in pdo.findall("Entry"):
                ei = e.find("Index")
                if _hex(ei.text) == 0:
                    continue
                index = _hex(ei.text) + (pos - 1) * index_inc * (ei.get("DependOnSlot")
                                                                 in ("1", "true"))
                name = f"{slave}.{label}.{pdo.findtext('Name').strip()}." \
                       f"{e.findtext('Name').strip()}"
                want[name] = (pdo_index, index, _hex(e.findtext("SubIndex")))
    return want


def _slots_increments(path: Path, type_name: str) -> tuple[int, int]:
    root = etree.parse(str(path)).getroot()
    dev = next(d for d in root.iter("Device") if d.findtext("Type").strip() == type_name)
    slots = dev.find("Slots")
    return _hex(slots.get("SlotPdoIncrement")), _hex(slots.get("SlotIndexIncrement"))


# -- compile ----------------------------------------------------------------------------------

def test_ur20_station_compiles_with_a_variable_per_module_channel(corpus, modular_lib,
                                                                   eni_schema):
    io_file = corpus / "esi/modular/Weidmueller_UR20_IO.xml"
    vendor = vendor_modules(io_file)
    assert len(set(UR20)) >= 6 and len(UR20) == 12
    pdo_inc, index_inc = _slots_increments(corpus / "esi/modular/Weidmueller_UR20_FBC.xml",
                                           "UR20-FBC-EC")
    assert (pdo_inc, index_inc) == (1, 16)
    result = build.compile_topology(topology.loads(station("io", "UR20-FBC-EC", UR20),
                                                   "t.yaml"), modular_lib)
    data = eni_writer.to_bytes(result.plan)
    assert eni_schema.validate(etree.ElementTree(etree.fromstring(data))), eni_schema.error_log
    plan = eni_reader.read_bytes(data, "t.eni.xml")
    variables = {v.name for v in plan.process_image.inputs + plan.process_image.outputs}
    want = _expected_variables(UR20, vendor, "io", pdo_inc, index_inc)
    assert len(want) == 96            # counted in the vendor file: 4+8+16+4+8+16+...
    assert set(want) <= variables, sorted(set(want) - variables)[:5]
    # The ENI's PDOs carry each module's position in their indices and names.
    pdos = {p.index: p for p in plan.slaves[0].process_data.pdos}
    for name, (pdo_index, index, sub) in want.items():
        pdo = pdos[pdo_index]
        assert name.startswith(f"io.{pdo.name}."), (name, pdo.name)
        assert (index, sub) in {(e.index, e.subindex) for e in pdo.entries}
        assert pdo.sm in (2, 3)
    # The configured module ident list: the idents of the vendor file, by position, first
    # in PREOP->SAFEOP (CompleteAccess: count, pad byte, one UDINT per module).
    idents = [_hex(vendor[t].find("Type").get("ModuleIdent")) for t in UR20]
    coe = plan.slaves[0].mailbox.coe_init_cmds
    assert (coe[0].index, coe[0].subindex, coe[0].complete_access) == (0xF030, 0, True)
    assert coe[0].data == bytes([12, 0]) + b"".join(i.to_bytes(4, "little") for i in idents)
    assert [t.value for t in coe[0].transitions] == ["PS"]


@pytest.mark.parametrize("modules, message, line", [
    ([], "slot 1 (Terminals) needs at least 1 module; the topology plugs none", 2),
    (["UR20-4DI-P"] * 65,
     "slot 1 (Terminals) takes at most 64 modules; the topology plugs 65", 5),
    (["UR20-4DO-P", "UR20-4DI-Q"], "no module 'UR20-4DI-Q' in the library of UR20-FBC-EC; "
                                   "did you mean UR20-4DI-P", 7),
    (["UR20-4DO-P", "0x12345678"], "no module 0x12345678 in the library", 7),
])
def test_ur20_module_errors_name_the_line(modular_lib, modules, message, line):
    text = "slaves:\n  - name: io\n    device: UR20-FBC-EC\n"
    if modules:
        text += "    modules:\n      1:\n" + "".join(f"        - {m}\n" for m in modules)
    with pytest.raises(TopologyError) as exc:
        build.compile_topology(topology.loads(text, "t.yaml"), modular_lib)
    assert message in str(exc.value)
    assert str(exc.value.problems[0]).startswith(f"t.yaml:{line}:"), str(exc.value)


def test_module_that_does_not_fit_and_too_many_in_a_single_slot(modular_lib):
    # Copley XE2: two axis slots, each one module of four idents; the UR20's DI is none.
    text = station("d", "XE2", {1: [0x91F84], 2: [0x10B00100, 0x10B00200]})
    with pytest.raises(TopologyError) as exc:
        build.compile_topology(topology.loads(text, "t.yaml"), modular_lib)
    errors = [str(e) for e in exc.value.problems]
    assert any("no module 0x00091F84 in the library of XE2" in e for e in errors), errors
    assert any("slot 2 (Axis B) takes at most 1 module; the topology plugs 2" in e
               for e in errors), errors


def test_missing_module_library_is_named(corpus, tmp_path):
    lib = Library([corpus / "esi/modular/Weidmueller_UR20_FBC.xml"], cache=False)
    with pytest.raises(TopologyError) as exc:
        build.compile_topology(topology.loads(station("io", "UR20-FBC-EC", ["UR20-4DI-P"]),
                                              "t.yaml"), lib)
    assert "UR20-IO-Modules\\Weidmueller_UR20_IO.xml (InfoReference in the ESI of " \
           "UR20-FBC-EC) is not loaded; pass its folder with --esi" in str(exc.value)


# -- apply on the virtual segment ---------------------------------------------------------------

def _entry_offsets(entries: list[tuple[int, int, int]]) -> dict[tuple[int, int], tuple[int, int]]:
    """(index, subindex) -> (bit offset, bits) in an SM, from the slave's own assignment."""
    out, bit = {}, 0
    for index, sub, bits in entries:
        if index:
            out[(index, sub)] = (bit, bits)
        bit += bits
    return out


def _bits(data: bytes, offset: int, bits: int) -> int:
    return (int.from_bytes(data, "little") >> offset) & ((1 << bits) - 1)


def check_process_data_moves(net: Network, plan: NetworkPlan, name: str) -> set[str]:
    """Every module variable both ways, checked against the emulated slave's own view of its
    SMs (its 0x1C12/0x1C13 and mapping objects); returns the module labels exercised."""
    slave = next(s for s in net.segment.slaves if s.name == name)
    sp = plan.slave(name)
    where = {f"{name}.{p.name}.{e.name}": (e.index, e.subindex)
             for p in sp.process_data.pdos if p.sm is not None for e in p.entries if e.index}
    outs = _entry_offsets(slave.od.rx_entries(2))
    ins = _entry_offsets(slave.od.tx_entries(3))
    rng = random.Random(17)
    written = {}
    for v in plan.process_image.outputs:
        if v.name in where and ".Module " in v.name:
            value = rng.randrange(1 << min(v.bit_size, 15)) | 1 if v.bit_size > 1 else True
            net[v.name] = value
            written[v.name] = int(value)
    net.cycle()
    net.cycle()
    for var, value in written.items():
        bit, bits = outs[where[var]]
        assert _bits(slave.outputs(), bit, bits) == value, var
    size = sum(b for _, _, b in slave.od.tx_entries(3)) // 8 + 1
    data = bytes(rng.randrange(256) for _ in range(size))
    slave.set_inputs(data)
    net.cycle()
    net.cycle()
    labels = set()
    for v in plan.process_image.inputs:
        if v.name in where and ".Module " in v.name:
            bit, bits = ins[where[v.name]]
            got = net[v.name]
            assert int(got) & ((1 << bits) - 1) == _bits(data, bit, bits), v.name
            labels.add(v.name.split(".")[1])
    return labels | {v.split(".")[1] for v in written}


def test_ur20_station_reaches_op_and_every_module_moves_data(corpus, modular_lib):
    plan = compile_station(station("io", "UR20-FBC-EC", UR20), modular_lib)
    with Network.virtual(plan, esi=[corpus / "esi/modular"], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        station_slave = net.segment.slaves[0]
        assert station_slave.od.int_value(0xF050, 0) == 12
        labels = check_process_data_moves(net, plan, "io")
    assert len(labels) == 12, labels        # every module position carried data


def test_swapped_module_fails_before_safeop_with_a_table(corpus, modular_lib):
    plan = compile_station(station("io", "UR20-FBC-EC", UR20), modular_lib)
    plugged = list(UR20)
    plugged[4] = "UR20-4DO-P"               # an 8DO-P configured, a 4DO-P found
    loaded = topology.loads(station("io", "UR20-FBC-EC", plugged), "real.yaml")
    seg = emulate.segment([emulate.SlaveSpec(d.device, d.name)
                           for d in plugged_devices(loaded, modular_lib)])
    link, close = serve_in_memory(seg)
    with Network(plan, link, _closers=[close]) as net:
        with pytest.raises(ApplyError) as exc:
            net.up()
        assert seg.slaves[0].state == AlState.PREOP
    text = str(exc.value)
    assert "slave 'io'" in text and "plugged modules differ" in text
    row = next(line for line in text.splitlines() if line.strip().startswith("5 "))
    assert "0x01022FC8" in row and "UR20-8DO-P" in row and "0x01012FA0" in row \
        and row.endswith("<<")
    assert sum(line.endswith("<<") for line in text.splitlines()) == 1


def test_apply_virtual_cli_reaches_op_for_the_ur20_station(corpus, modular_lib, tmp_path):
    eni = tmp_path / "s.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(compile_station(station("io", "UR20-FBC-EC", UR20),
                                                        modular_lib)))
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(corpus / "esi/modular"), "--simulated-time", "--cycles",
                           "5", "--no-cache"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr + done.stdout
    assert "PREOP -> SAFEOP: SAFEOP" in done.stdout + done.stderr


@pytest.mark.parametrize("text", [
    # Copley XE2: two axes, slot 2 left to its default module (ModuleIdent Default="1").
    "slaves:\n  - name: d\n    device: XE2\n    modules: {1: 0x10B00200}\n",
    station("u", "UC20-RTU-EC-A", UTRIO),
], ids=["copley-xe2", "utrio-8"])
def test_copley_and_utrio_reach_op_virtually(corpus, modular_lib, text):
    result = build.compile_topology(topology.loads(text, "t.yaml"), modular_lib)
    plan = eni_reader.read_bytes(eni_writer.to_bytes(result.plan), "t.eni.xml")
    name = plan.slaves[0].name
    with Network.virtual(plan, esi=[corpus / "esi/modular", corpus / "esi/drives"],
                         esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        labels = check_process_data_moves(net, plan, name)
    if name == "d":
        assert any("slot 2 (Axis B): no module given, plugged its default" in n
                   for n in result.notes), result.notes
        assert labels == {"Module 1 (Cyclic velocity Mode)", "Module 2 (Cyclic position Mode)"}
        # Axis B's PDOs and objects one SlotPdoIncrement (64) and SlotIndexIncrement
        # (0x800) further than axis A's (the vendor file's Slots).
        pdos = {p.index for p in plan.slaves[0].process_data.pdos if p.sm is not None}
        assert {0x1700 + 64, 0x1B00 + 64} <= pdos
    else:
        assert len(labels) == 8, labels
        vendor = vendor_modules(corpus / "esi/modular/UTRIO-UC20-RTU-EC-A_20251104.xml")
        idents = [_hex(vendor[t].find("Type").get("ModuleIdent")) for t in UTRIO]
        f030 = plan.slaves[0].mailbox.coe_init_cmds[0]
        assert f030.index == 0xF030 and f030.data[2:] == b"".join(
            i.to_bytes(4, "little") for i in idents)


# -- SOEM ---------------------------------------------------------------------------------------

def test_soem_reaches_op_on_simulate_of_the_ur20_station(veth_netns, pysoem_module, corpus,
                                                         modular_lib, tmp_path):
    """SOEM reads the station's PDO assignment and mappings over CoE: they are what our ENI
    lists, so its process image has our ENI's sizes."""
    topo = tmp_path / "station.yaml"
    topo.write_text(station("io", "UR20-FBC-EC", UR20))
    plan = compile_station(topo.read_text(), modular_lib)
    sm_pdos = {sm: [p.index for p in plan.slaves[0].process_data.pdos if p.sm == sm]
               for sm in (2, 3)}
    pdos = plan.slaves[0].process_data.pdos
    sizes = [(sum(e.bit_len for p in pdos if p.sm == sm for e in p.entries) + 7) // 8
             for sm in (2, 3)]
    sim, lines = start_simulate(veth_netns, "--esi", str(corpus / "esi/modular"),
                                "--topology", str(topo))
    assert lines and lines[-1].startswith("ready: 1 slaves"), "".join(lines) + sim.stderr.read()
    reads = [[0, 0x1C12, 0], [0, 0x1C13, 0]]
    reads += [[0, 0x1C12, n] for n in range(1, len(sm_pdos[2]) + 1)]
    reads += [[0, 0x1C13, n] for n in range(1, len(sm_pdos[3]) + 1)]
    reads += [[0, 0xF050, n] for n in range(0, 13)]
    done = veth_netns.run_in(veth_netns.ns_a, [sys.executable,
                                               str(Path(__file__).with_name("soem_probe.py")),
                                               veth_netns.if_a,
                                               json.dumps({"outputs": "01", "read": reads})],
                             timeout=120)
    sim.terminate()
    sim.communicate(timeout=10)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["op"] == 8, report
    assert [tuple(x) for x in report["sizes"]] == [tuple(sizes)]
    got = [int.from_bytes(bytes.fromhex(h), "little") for h in report["read"]]
    n2, n3 = len(sm_pdos[2]), len(sm_pdos[3])
    assert got[:2] == [n2, n3]
    assert got[2:2 + n2] == sm_pdos[2] and got[2 + n2:2 + n2 + n3] == sm_pdos[3]
    vendor = vendor_modules(corpus / "esi/modular/Weidmueller_UR20_IO.xml")
    assert got[2 + n2 + n3:] == [12] + [_hex(vendor[t].find("Type").get("ModuleIdent"))
                                        for t in UR20]


# -- OverwrittenByModule and default modules ---------------------------------------------------

FIXTURE = Path(__file__).with_name("fixtures") / "ecatcfg-EXS-overwritten-pdo.xml"


@pytest.mark.parametrize("modules, bits, default",
                         [("", 16, True), ("{1: EXS-APP-32}", 32, False)])
def test_module_pdo_replaces_the_overwritten_device_pdo(modules, bits, default):
    text = "slaves:\n  - name: s\n    device: EXS6900\n" + (
        f"    modules: {modules}\n" if modules else "")
    result = build.compile_topology(topology.loads(text, "t.yaml"), Library([FIXTURE],
                                                                             cache=False))
    plan = eni_reader.read_bytes(eni_writer.to_bytes(result.plan), "t.eni.xml")
    rx = [p for p in plan.slaves[0].process_data.pdos if p.direction == "rx"]
    # One 0x1600, the module's: the device's placeholder (8 bits) is gone.
    assert [(p.index, [e.bit_len for e in p.entries]) for p in rx] == [(0x1600, [bits])]
    assign = [c for c in plan.slaves[0].mailbox.coe_init_cmds if c.index == 0x1C12]
    assert [c.data for c in assign if c.subindex == 1] == [b"\x00\x16"]
    assert not any(c.subindex == 2 for c in assign)
    noted = any("slot 1 (Application): no module given, plugged its default EXS-APP-16"
                in n for n in result.notes)
    assert noted == default, result.notes
    with Network.virtual(plan, esi=[FIXTURE], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        check_process_data_moves(net, plan, "s")


def test_example_station_is_the_worked_example_of_the_docs(esi_schema):
    """docs/compile.md's table for examples/station/station.yaml; its ESI and the fixture's
    are valid ETG.2000."""
    esi = EXAMPLES / "station" / "esi"
    for f in (esi / "ecatcfg-EXM-station.xml", FIXTURE):
        assert esi_schema.validate(etree.parse(str(f))), (f, esi_schema.error_log)
    loaded = topology.load(EXAMPLES / "station" / "station.yaml")
    plan = build.compile_topology(loaded, Library([esi], cache=False)).plan
    pdos = [(p.index, p.name, p.entries[0].index) for p in plan.slaves[0].process_data.pdos]
    assert pdos == [(0x1AFF, "Station status", 0xF100),
                    (0x1A00, "Module 1 (4 digital inputs).Inputs", 0x6000),
                    (0x1601, "Module 2 (4 digital outputs).Outputs", 0x7010),
                    (0x1A02, "Module 3 (2 analog inputs).Inputs", 0x6020),
                    (0x1A03, "Module 4 (4 digital inputs).Inputs", 0x6030)]
    f030 = plan.slaves[0].mailbox.coe_init_cmds[0]
    assert (f030.index, f030.complete_access) == (0xF030, True)
    assert f030.data == bytes.fromhex("0400" "014de100" "024de100" "034de100" "014de100")
    with Network.virtual(plan, esi=[esi], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        assert len(check_process_data_moves(net, plan, "station")) == 4


def test_station_without_a_detected_list_is_not_checked(corpus, modular_lib):
    plan = compile_station(station("io", "UR20-FBC-EC", UR20[:3]), modular_lib)
    with Network.virtual(plan, esi=[corpus / "esi/modular"], esi_cache=False) as net:
        del net.segment.slaves[0].od.objects[0xF050]       # firmware without 0xF050
        net.up()
        assert net.state == AlState.OP


# -- the 0xF050 check on the example station (self-written, no corpus) -----------------------

STATION_ESI = EXAMPLES / "station" / "esi"
CONFIGURED = ["EXM-4DI", "EXM-4DO"]


def example_station(modules: list[str]) -> str:
    return station("station", "EXM100", modules)


def test_an_extra_module_after_the_configured_ones_fails_before_safeop():
    """The ENI configures two modules; the station has a third plugged after them.  Its
    0xF050 lists three positions: position 3 differs (nothing configured, the module's
    ident found), so apply stops in PREOP with that row marked, as it would for a module
    swapped (the station's process image no longer fits the ENI's)."""
    lib = Library([STATION_ESI], cache=False)
    plan = compile_station(example_station(CONFIGURED), lib)
    plugged = CONFIGURED + ["EXM-2AI"]
    loaded = topology.loads(example_station(plugged), "real.yaml")
    seg = emulate.segment([emulate.SlaveSpec(d.device, d.name)
                           for d in plugged_devices(loaded, lib)])
    assert seg.slaves[0].od.int_value(0xF050, 0) == 3
    link, close = serve_in_memory(seg)
    with Network(plan, link, _closers=[close]) as net:
        with pytest.raises(ApplyError) as exc:
            net.up()
        assert seg.slaves[0].state == AlState.PREOP
    text = str(exc.value)
    assert "slave 'station'" in text and "plugged modules differ" in text, text
    vendor = vendor_modules(STATION_ESI / "ecatcfg-EXM-station.xml")
    extra = _hex(vendor["EXM-2AI"].find("Type").get("ModuleIdent"))
    marked = [line.split() for line in text.splitlines() if line.endswith("<<")]
    assert marked == [["3", "(none)", f"0x{extra:08X}", "<<"]], text


@pytest.mark.parametrize("code", [0x08000022, 0x06010001])
def test_another_abort_of_the_0xf050_upload_is_an_error_naming_the_slave(code):
    """Only "object does not exist" (0x06020000) says a station has no detected module
    list and cannot be checked; any other abort of its upload (here: not in this state,
    0x08000022; a write-only object, 0x06010001) is an error naming the slave and the
    check, and the station stays in PREOP."""
    lib = Library([STATION_ESI], cache=False)
    plan = compile_station(example_station(CONFIGURED), lib)
    with Network.virtual(plan, esi=[STATION_ESI], esi_cache=False) as net:
        net.segment.slaves[0].od.inject_abort(0xF050, 0, code)
        with pytest.raises(ApplyError) as exc:
            net.up()
        assert net.segment.slaves[0].state == AlState.PREOP
    assert exc.value.abort_code == code
    text = str(exc.value)
    assert text.startswith("slave 'station' [check detected modules (0xF050)]: ") \
        and f"0x{code:08X}" in text, text


def test_a_station_without_0xf050_is_not_checked_by_its_abort_code():
    """The same station answering the upload with 0x06020000 (object does not exist, as a
    firmware without 0xF050 does) goes on to OP unchecked."""
    lib = Library([STATION_ESI], cache=False)
    plan = compile_station(example_station(CONFIGURED), lib)
    with Network.virtual(plan, esi=[STATION_ESI], esi_cache=False) as net:
        net.segment.slaves[0].od.inject_abort(0xF050, 0, 0x06020000)
        net.up()
        assert net.state == AlState.OP
