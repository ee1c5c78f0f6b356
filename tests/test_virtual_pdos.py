"""Virtual PDOs (ETG.2000 ``Pdo@Virtual``): a bridge-style device whose process data are only
PDOs the master maps, compiled with a user mapping (topology ``pdo_mapping``), brought up on
the virtual segment and under SOEM on ``simulate``.

The device is a self-written ESI (``fixtures/ecatcfg-EXB6695-bridge.xml``) of the shape of
an EL6695 description: "IO Outputs" 0x1608 and "IO Inputs" 0x1A08 without entries, with
their SM; an info PDO 0x1A05 whose one entry is its default mapping; no mapping or
assignment objects in the dictionary.  Expected sizes, mapping words and assignment bytes
are written out here by hand from the CoE layout (ETG.1000.6: index << 16 | subindex << 8 |
bit length, little-endian), not taken from the compiler; SOEM reads the slave's PDO
configuration by itself.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from rig import start_simulate

from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState, Transition
from ecatcfg.esi.library import Library
from ecatcfg.esi.reader import read_bytes, read_file
from ecatcfg.runtime.mailbox import SdoAbort
from ecatcfg.runtime.network import Network
from ecatcfg.runtime.segment.objects import ObjectDictionary
from ecatcfg.runtime.segment.syncman import SmKind

FIXTURE = Path(__file__).with_name("fixtures") / "ecatcfg-EXB6695-bridge.xml"

MAPPING = """\
slaves:
  - name: bridge
    device: EXB6695
    pdo_mapping:
      0x1608:
        - {index: 0x7000, subindex: 1, type: UINT, name: Setpoint}
        - {index: 0x7000, subindex: 2, type: BOOL, name: Enable}
        - [0, 0, 7]
        - [0x7000, 3, 32]
      0x1A08:
        - {index: 0x6000, subindex: 1, type: UDINT, name: Counter}
        - [0x10F4, 0, 16]
"""
# The same mapping as CoE words, by hand: 0x7000:01 UINT, 0x7000:02 BOOL, a 7-bit gap,
# 0x7000:03 32 bits; 0x6000:01 UDINT, 0x10F4:00 16 bits.
RX_WORDS = [0x70000110, 0x70000201, 0x00000007, 0x70000320]
TX_WORDS = [0x60000120, 0x10F40010]
RX_BYTES, TX_BYTES = 7, 6          # 56 and 48 bits


def _esi(tmp_path: Path, complete_access: bool) -> Path:
    if complete_access:
        return FIXTURE
    path = tmp_path / "bridge-no-ca.xml"
    path.write_text(FIXTURE.read_text(encoding="utf-8").replace(
        'CompleteAccess="true" ', ""), encoding="utf-8")
    return path


def _compile(text: str, esi: Path) -> NetworkPlan:
    result = build.compile_topology(topology.loads(text, "t.yaml"), Library([esi], cache=False))
    return eni_reader.read_bytes(eni_writer.to_bytes(result.plan), "t.eni.xml")


def _errors(text: str) -> str:
    with pytest.raises(TopologyError) as err:
        build.compile_topology(topology.loads(text, "t.yaml"), Library([FIXTURE], cache=False))
    return str(err.value)


def _pdo_writes(plan: NetworkPlan) -> list[tuple[int, int, bytes, bool]]:
    coe = plan.slaves[0].mailbox.coe_init_cmds
    return [(c.index, c.subindex, c.data, c.complete_access) for c in coe
            if Transition.PS in c.transitions]


# -- compile --------------------------------------------------------------------------------

@pytest.mark.parametrize("complete_access", [True, False])
def test_bridge_compiles_with_a_user_mapping(tmp_path, eni_schema, complete_access):
    esi = _esi(tmp_path, complete_access)
    result = build.compile_topology(topology.loads(MAPPING, "t.yaml"),
                                    Library([esi], cache=False))
    data = eni_writer.to_bytes(result.plan)
    from lxml import etree
    eni_schema.assertValid(etree.fromstring(data))
    plan = eni_reader.read_bytes(data, "t.eni.xml")
    pdos = {p.index: p for p in plan.slaves[0].process_data.pdos}
    assert pdos[0x1608].virtual and pdos[0x1608].sm == 2
    assert pdos[0x1A08].virtual and pdos[0x1A08].sm == 3
    assert pdos[0x1A05].sm is None                   # not mapped, not chosen: not assigned
    assert [(e.index << 16 | e.subindex << 8 | e.bit_len) for e in pdos[0x1608].entries] \
        == RX_WORDS
    assert [e.name for e in pdos[0x1608].entries][:2] == ["Setpoint", "Enable"]
    pd = plan.slaves[0].process_data
    assert [r.bit_length for r in pd.send] == [8 * RX_BYTES]
    assert [r.bit_length for r in pd.recv] == [8 * TX_BYTES]
    rx = b"".join(struct.pack("<I", w) for w in RX_WORDS)
    tx = b"".join(struct.pack("<I", w) for w in TX_WORDS)
    writes = _pdo_writes(plan)
    if complete_access:
        assert writes == [(0x1C12, 0, b"\x00", False), (0x1C13, 0, b"\x00", False),
                          (0x1608, 0, b"\x04\x00" + rx, True),
                          (0x1A08, 0, b"\x02\x00" + tx, True),
                          (0x1C12, 0, b"\x01\x00\x08\x16", True),
                          (0x1C13, 0, b"\x01\x00\x08\x1a", True)]
    else:
        assert (0x1608, 0, b"\x00", False) in writes
        assert [w for w in writes if w[0] == 0x1608 and w[1]] == [
            (0x1608, n, rx[4 * n - 4:4 * n], False) for n in range(1, 5)]
        assert writes[-2:] == [(0x1C13, 1, b"\x08\x1a", False), (0x1C13, 0, b"\x01", False)]
    variables = {v.name: v.bit_size for v in plan.process_image.outputs}
    assert variables["bridge.IO Outputs.Setpoint"] == 16
    assert variables["bridge.IO Outputs.Enable"] == 1


def test_without_a_mapping_the_bridge_has_no_process_data():
    """A real bridge terminal nobody configured has an empty process image: its virtual
    PDOs are not assigned by default (what the ESI's Sm says applies once they are mapped)."""
    plan = _compile("slaves:\n  - name: bridge\n    device: EXB6695\n", FIXTURE)
    assert all(p.sm is None for p in plan.slaves[0].process_data.pdos)
    assert plan.process_image.outputs == [] and plan.process_image.inputs == []


def test_a_virtual_pdo_with_esi_entries_is_assigned_with_them():
    """Entries the ESI gives a virtual PDO are its default mapping: choosing it is enough."""
    plan = _compile("slaves:\n  - name: bridge\n    device: EXB6695\n"
                    "    tx_pdos: [0x1A05]\n", FIXTURE)
    pdo = next(p for p in plan.slaves[0].process_data.pdos if p.index == 0x1A05)
    assert pdo.sm == 3 and [(e.index, e.subindex, e.bit_len) for e in pdo.entries] == [
        (0xF650, 1, 16)]


@pytest.mark.parametrize("slave, message", [
    ("    rx_pdos: [0x1608]\n",
     "t.yaml:4: slave 'bridge': PDO 0x1608 (IO Outputs) is virtual and its ESI gives it no "
     "entries: give its variables in pdo_mapping"),
    ("    pdo_mapping: {0x1A08: [[0x10F4, 0, 8]]}\n",
     "t.yaml:4: slave 'bridge': object 0x10F4:00 is 16 bits, not 8"),
    ("    pdo_mapping: {0x1A08: [{index: 0x10F4, type: DINT}]}\n",
     "object 0x10F4:00 is 16 bits, not 32"),
    ("    pdo_mapping: {0x1A08: [{index: 0x6000, subindex: 1, type: UDINT, bits: 16}]}\n",
     "type UDINT is 32 bits, not 16"),
    ("    pdo_mapping: {0x1A08: [{index: 0x6000, subindex: 1, type: NOTATYPE}]}\n",
     "unknown data type 'NOTATYPE'"),
    ("    pdo_mapping: {0x1A08: [{index: 0x6000, subindex: 1}]}\n", "give 'bits' or 'type'"),
    ("    pdo_mapping: {0x1608: [[0x1000, 0, 32]]}\n",
     "object 0x1000:00 (Device type) cannot be mapped into an RxPDO"),
    ("    pdo_mapping: {0x1608: [[0, 1, 8]]}\n", "a gap (index 0) has subindex 0"),
    ("    pdo_mapping: {0x1608: [{index: 0, bits: 8, name: Spare}]}\n",
     "a gap (index 0) has subindex 0, and neither a type nor a name"),
    ("    pdo_mapping:\n      0x1608: [" + ", ".join(["[0x7000, 1, 8]"] * 255) + "]\n",
     "PDO 0x1608 holds at most 254 entries (a mapping object's count), not 255"),
    ("    pdo_mapping:\n      0x1608: [" + ", ".join(["[0x7000, 1, 8]"] * 129) + "]\n",
     "the PDOs assigned to SM2 need 129 bytes, more than its MaxSize 128"),
    ("    tx_pdos: [0x1A05]\n    pdo_mapping: {0x1A08: [[0x6000, 1, 8]]}\n",
     "PDO 0x1A08 is mapped but not assigned; add it to tx_pdos"),
])
def test_mapping_errors_name_the_line(slave, message):
    text = "slaves:\n  - name: bridge\n    device: EXB6695\n" + slave
    shown = _errors(text)
    # One error, about the spelling the entry was written in (not both of the union's).
    assert message in shown and "errors in the topology" not in shown, shown
    assert shown.split(": ", 1)[0] in ("t.yaml:2", "t.yaml:4", "t.yaml:5"), shown


# -- the emulated dictionary ------------------------------------------------------------------

def test_emulated_bridge_takes_the_masters_mapping():
    """0x1608 / 0x1A08 exist though the ESI dictionary lacks them, empty and writable in
    PREOP; the SMs follow what the master downloads (clear, entries, count or one complete
    access), as a real slave sizes its process data from 0x1C1n and the mapping."""
    od = ObjectDictionary.from_device(read_file(FIXTURE).devices[0])
    assert od.int_value(0x1608, 0) == 0 and od.int_value(0x1A08, 0) == 0
    assert od.int_value(0x1A05, 0) == 1 and od.int_value(0x1A05, 1) == 0xF6500110
    assert od.int_value(0x1C12, 0) == 0 and od.sm_bits(2) == 0     # nothing assigned
    with pytest.raises(SdoAbort) as err:
        od.write(0x1608, 1, struct.pack("<I", RX_WORDS[0]), AlState.SAFEOP)
    assert err.value.code == 0x08000022                 # wrong state: PREOP only
    for n, word in enumerate(RX_WORDS, start=1):
        od.write(0x1608, n, struct.pack("<I", word), AlState.PREOP)
    od.write(0x1608, 0, bytes([len(RX_WORDS)]), AlState.PREOP)
    with pytest.raises(SdoAbort) as err:                # count first set to 0 (ETG.1000.6)
        od.write(0x1608, 1, struct.pack("<I", RX_WORDS[0]), AlState.PREOP)
    assert err.value.code == 0x06010003
    od.write(0x1C12, 1, b"\x08\x16", AlState.PREOP)
    od.write(0x1C12, 0, b"\x01", AlState.PREOP)
    assert od.sm_bits(2) == 8 * RX_BYTES
    od.write(0x1A08, 0, b"\x02\x00" + b"".join(struct.pack("<I", w) for w in TX_WORDS),
             AlState.PREOP, complete_access=True)
    od.write(0x1C13, 0, b"\x01\x00\x08\x1a", AlState.PREOP, complete_access=True)
    assert od.sm_bits(3) == 8 * TX_BYTES


def test_a_configurable_pdos_mapping_still_names_objects():
    """Only a virtual PDO's mapping may name variables the dictionary lacks: a configurable
    (non-virtual) PDO mapping 0x7000:01 of a device without it is refused at SAFEOP."""
    text = FIXTURE.read_text(encoding="utf-8").replace('<RxPdo Sm="2" Virtual="1">',
                                                        '<RxPdo Sm="2">')
    od = ObjectDictionary.from_device(read_bytes(text.encode(), "x.xml").devices[0])
    od.write(0x1608, 1, struct.pack("<I", RX_WORDS[0]), AlState.PREOP)
    od.write(0x1608, 0, b"\x01", AlState.PREOP)
    assert od.int_value(0x1C12, 1) == 0x1608           # assigned by default (Sm="2")
    assert od.sm_bits(2) is None


# -- on the wire ----------------------------------------------------------------------------------

@pytest.mark.parametrize("complete_access", [True, False])
def test_bridge_reaches_op_virtually_and_moves_its_variables(tmp_path, complete_access):
    esi = _esi(tmp_path, complete_access)
    plan = _compile(MAPPING, esi)
    with Network.virtual(plan, esi=[esi], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        slave = net.segment.slaves[0]
        assert slave.od.rx_entries(2) == [(w >> 16, (w >> 8) & 0xFF, w & 0xFF)
                                          for w in RX_WORDS]
        net["bridge.IO Outputs.Setpoint"] = 0x1234
        net["bridge.IO Outputs.Enable"] = True
        net["bridge.IO Outputs.0x7000:03"] = 0xA5A5A5A5
        net.cycle()
        net.cycle()
        assert slave.outputs()[:RX_BYTES] == bytes.fromhex("3412" "01" "a5a5a5a5")
        slave.set_inputs(bytes.fromhex("78563412" "cdab"))
        net.cycle()
        net.cycle()
        assert int(net["bridge.IO Inputs.Counter"]) == 0x12345678
        assert int(net["bridge.IO Inputs.Bridge status"]) == 0xABCD


def test_bridge_reaches_op_from_the_eni_alone():
    """Without the ESI the emulated slave comes from the ENI (runtime/segment/eni_device.py): its
    virtual PDOs get mapping objects that take the ENI's downloads too."""
    plan = _compile(MAPPING, FIXTURE)
    with Network.virtual(plan, esi=None) as net:
        net.up()
        assert net.state == AlState.OP
        assert net.segment.slaves[0].od.sm_bits(2) == 8 * RX_BYTES


def test_internally_configured_bridge_takes_the_sm_length(tmp_path):
    """Without CoE PdoConfig (an EL6690 bridge, a CX's EtherCAT slave) the master cannot
    download a mapping: the ENI carries the variables and the SM lengths, no mapping write,
    and the device takes the length its SM is given (ETG.2100 Pdo@Virtual, "configured
    internally")."""
    esi = tmp_path / "bridge-internal.xml"
    esi.write_text(FIXTURE.read_text(encoding="utf-8").replace('PdoConfig="true" ', ""),
                   encoding="utf-8")
    plan = _compile(MAPPING, esi)
    writes = _pdo_writes(plan)
    assert not any(0x1600 <= w[0] < 0x1C00 for w in writes), writes
    assert writes[-2:] == [(0x1C12, 0, b"\x01\x00\x08\x16", True),
                           (0x1C13, 0, b"\x01\x00\x08\x1a", True)]
    assert [r.bit_length for r in plan.slaves[0].process_data.send] == [8 * RX_BYTES]
    with Network.virtual(plan, esi=[esi], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        slave = net.segment.slaves[0]
        assert [sm.length for kind in (SmKind.OUTPUTS, SmKind.INPUTS)
                for sm in slave.process_sms(kind)] == [RX_BYTES, TX_BYTES]
        net["bridge.IO Outputs.Setpoint"] = 0x4321
        net.cycle()
        net.cycle()
        assert slave.outputs()[:2] == b"\x21\x43"


def test_apply_virtual_cli_reaches_op(tmp_path):
    topo = tmp_path / "bridge.yaml"
    topo.write_text(MAPPING)
    eni = tmp_path / "bridge.eni.xml"
    run = [sys.executable, "-m", "ecatcfg"]
    done = subprocess.run(run + ["compile", str(topo), "--esi", str(FIXTURE), "-o", str(eni),
                                 "--no-cache"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    done = subprocess.run(run + ["apply", str(eni), "--virtual", "--esi", str(FIXTURE),
                                 "--simulated-time", "--cycles", "5", "--no-cache", "--format",
                                 "json"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["ok"] and [s["highest_state"] for s in report["slaves"]] == ["OP"], report
    assert report["cycles"]["wkc_errors"] == 0, report


def test_soem_configures_the_bridge_on_simulate(veth_netns, pysoem_module, tmp_path):
    """SOEM as the independent master: after config_init it downloads the PDO commands of
    our ENI (as a SOEM user maps a bridge's variables in PREOP), then config_map reads
    0x1C12/0x1C13 and the mappings back by itself and sizes the SMs from them."""
    topo = tmp_path / "bridge.yaml"
    topo.write_text(MAPPING)
    plan = _compile(MAPPING, FIXTURE)
    writes = [[0, index, sub, data.hex(), ca] for index, sub, data, ca in _pdo_writes(plan)]
    sim, lines = start_simulate(veth_netns, "--esi", str(FIXTURE), "--topology", str(topo))
    assert lines and lines[-1].startswith("ready: 1 slaves"), "".join(lines) + sim.stderr.read()
    reads = [[0, 0x1C12, 1], [0, 0x1C13, 1], [0, 0x1608, 0], [0, 0x1A08, 2]]
    done = veth_netns.run_in(veth_netns.ns_a, [sys.executable,
                                               str(Path(__file__).with_name("soem_probe.py")),
                                               veth_netns.if_a,
                                               json.dumps({"writes": writes, "outputs": "5a",
                                                           "read": reads})],
                             timeout=120)
    sim.terminate()
    sim.communicate(timeout=10)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["writes"] == ["ok"] * len(writes), report
    assert [tuple(x) for x in report["sizes"]] == [(RX_BYTES, TX_BYTES)], report
    got = [int.from_bytes(bytes.fromhex(h), "little") for h in report["read"]]
    assert got == [0x1608, 0x1A08, len(RX_WORDS), TX_WORDS[1]], report
    assert report["op"] == 8, report
    assert report["wkc"] == report["expected_wkc"], report


# -- real bridge and PC-slave descriptions ----------------------------------------------------

@pytest.mark.parametrize("file, device, rx, tx", [
    ("Beckhoff EL66xx.xml", "EL6695", 0x1608, 0x1A08),       # PdoConfig: mapping downloaded
    ("Beckhoff EL66xx.xml", "EL6692", 0x1600, 0x1A00),
    ("Beckhoff EL66xx.xml", "EL6690", 0x1610, 0x1A10),       # CoE without PdoAssign/Config
    ("Beckhoff CXxxxx.xml", "CX5010 EtherCAT slave", 0x1600, 0x1A00),   # PdoAssign only
    ("Beckhoff FCxxxx.xml", "FC1100 EtherCAT PCI slave card", 0x1600, 0x1A00),
])
def test_real_virtual_pdo_devices_compile_and_reach_op(corpus_extra, eni_schema, file,
                                                       device, rx, tx):
    """Vendor files whose process data are virtual PDOs: each compiles with a user
    mapping into a schema-valid ENI with those variables and reaches OP on its own
    emulation."""
    esi = corpus_extra / "esi" / "dls" / file
    text = (f"slaves:\n  - name: b\n    device: {device}\n    pdo_mapping:\n"
            f"      {rx}: [{{index: 0x7000, subindex: 1, type: UINT, name: Out}}]\n"
            f"      {tx}: [{{index: 0x6000, subindex: 1, type: UDINT, name: In}}]\n")
    result = build.compile_topology(topology.loads(text, "t.yaml"), Library([esi], cache=False))
    data = eni_writer.to_bytes(result.plan)
    from lxml import etree
    eni_schema.assertValid(etree.fromstring(data))
    plan = eni_reader.read_bytes(data, "t.eni.xml")
    outputs = {v.name: v.bit_size for v in plan.process_image.outputs}
    inputs = {v.name: v.bit_size for v in plan.process_image.inputs}
    assert [bits for name, bits in outputs.items() if name.endswith(".Out")] == [16]
    assert [bits for name, bits in inputs.items() if name.endswith(".In")] == [32]
    with Network.virtual(plan, esi=[esi], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
