"""``ecatcfg export --format pysoem``: the module it writes, used by pysoem (SOEM, a master
nobody here wrote) as its docstring says, configures ``ecatcfg simulate`` over a veth pair.

The line is the shipped example (examples/): a drive with a chosen RxPDO/TxPDO set, a
remapped TxPDO, DC and start-up SDOs.  What SOEM sizes per slave is compared with the ENI's
ProcessData Send/Recv bit lengths as the file gives them (read with lxml here, not through
the plan the export uses), and the start-up SDO is read back from the slave.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import EXAMPLES, compile_example
from lxml import etree
from rig import start_simulate

PROBE = Path(__file__).with_name("export_probe.py")


def export(eni: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "pysoem", "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=60)


def send_recv_bits(eni: Path) -> list[tuple[int, int]]:
    """Each slave's (Send, Recv) BitLength sums from the ENI's ProcessData."""
    root = etree.parse(str(eni)).getroot()
    return [(sum(int(x) for x in s.xpath("ProcessData/Send/BitLength/text()")),
             sum(int(x) for x in s.xpath("ProcessData/Recv/BitLength/text()")))
            for s in root.iterfind("Config/Slave")]


@pytest.fixture(scope="module")
def example_eni(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_example(tmp_path_factory.mktemp("export") / "line.eni.xml")


def probe(rig, module: Path, options: dict) -> dict:
    done = rig.run_in(rig.ns_a, [sys.executable, str(PROBE), rig.if_a, str(module),
                                 json.dumps(options)], timeout=180)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_pysoem_with_the_exported_hooks_reaches_op(veth_netns, pysoem_module, example_eni,
                                                   tmp_path):
    module = tmp_path / "line_setup.py"
    done = export(example_eni, module)
    assert done.returncode == 0, done.stderr
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(EXAMPLES / "topology.yaml"))
    assert lines and lines[-1].startswith("ready: 5 slaves"), "".join(lines)
    report = probe(veth_netns, module, {"cycles": 50, "read": [[4, 0x6060, 0],
                                                               [4, 0x1C12, 1]]})
    assert report["found"] == 5
    assert report.get("safeop") == 4 and report.get("op") == 8, report
    bits = send_recv_bits(example_eni)
    # Every cycle's working counter by the ESC rule (ETG.1000.4): SOEM's one LRW adds 2 per
    # slave with outputs, 1 per slave with inputs.  (SOEM's own expected_wkc leaves out
    # slaves whose inputs are only bits: test_soem.py.)
    assert report["wkcs"] == [sum(2 * (o > 0) + (i > 0) for o, i in bits)]
    assert [tuple(s) for s in report["sizes"]] == [((o + 7) // 8, (i + 7) // 8)
                                                   for o, i in bits]
    assert bits[4] == (48, 128)              # the drive: 0x1601 out, 0x1A00 + 0x1A01 in
    assert report["read"] == ["09", "0116"]  # modes of operation 9 (CSV); RxPDO 0x1601
    assert report["dc"][4] == ["03", f"{1_000_000:08x}"]     # the drive: SYNC0 every 1 ms
    assert {tuple(d) for d in report["dc"][:4]} == {("00", "00000000")}


def test_a_different_line_is_refused_by_setup(veth_netns, pysoem_module, example_eni,
                                              tmp_path):
    module = tmp_path / "line_setup.py"
    assert export(example_eni, module).returncode == 0
    topo = tmp_path / "short.yaml"
    topo.write_text("slaves:\n  - {name: coupler, device: EX1100}\n"
                    "  - {name: lamps, device: EX2008}\n  - {name: buttons, device: EX1004}\n"
                    "  - {name: b2, device: EX1004}\n  - {name: b3, device: EX1004}\n")
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(topo))
    assert lines and lines[-1].startswith("ready: 5 slaves"), "".join(lines)
    report = probe(veth_netns, module, {})
    assert report["setup_error"] == (
        "slave 1 (buttons): line.eni.xml wants 0xE0000ECA:0x00002004:0x00010000, "
        "found 0xE0000ECA:0x00003008:0x00010000")
    assert "iomap" not in report


def test_the_export_is_deterministic_and_says_where_it_came_from(example_eni, tmp_path):
    import hashlib
    first, second = tmp_path / "a.py", tmp_path / "b.py"
    assert export(example_eni, first).returncode == 0
    assert export(example_eni, second).returncode == 0
    assert first.read_bytes() == second.read_bytes()
    text = first.read_text()
    digest = hashlib.sha256(example_eni.read_bytes()).hexdigest()
    version = subprocess.run([sys.executable, "-m", "ecatcfg", "--version"],
                             capture_output=True, text=True, timeout=30).stdout.split()[1]
    assert f"ENI_SHA256 = '{digest}'" in text
    assert "ENI_NAME = 'line.eni.xml'" in text
    assert f"ECATCFG_VERSION = '{version}'" in text
    compile(text, str(first), "exec")        # valid Python


def test_a_coe_command_after_safeop_is_refused_by_file_line_and_slave(example_eni,
                                                                      tmp_path):
    """The start-up SDO moved to SAFEOP->OP: pysoem has no hook there; refused by the line
    of its InitCmd, nothing written."""
    from lxml import etree
    tree = etree.parse(str(example_eni))
    cmd = tree.xpath("//CoE/InitCmds/InitCmd[Index='24672']")[0]
    cmd.find("Transition").text = "SO"
    eni = tmp_path / "so.xml"
    tree.write(str(eni), xml_declaration=True, encoding="utf-8")
    line = etree.parse(str(eni)).xpath("//CoE/InitCmds/InitCmd[Index='24672']")[0].sourceline
    out = tmp_path / "so.py"
    done = export(eni, out)
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith(f"ecatcfg export: {eni}:{line}: slave 4 ('axis1'): "
                                  f"SDO 0x6060:00 = 9 in SO"), done.stderr
    assert not out.exists()


def test_a_coe_command_repeated_after_safeop_is_refused_not_exported_once(example_eni,
                                                                          tmp_path):
    """The start-up SDO written in PS and again in SO (ETG.2100 allows several
    Transition elements): the hook would make the PS write and lose the SO one."""
    from lxml import etree
    tree = etree.parse(str(example_eni))
    cmd = tree.xpath("//CoE/InitCmds/InitCmd[Index='24672']")[0]
    cmd.find("Transition").addnext(etree.fromstring("<Transition>SO</Transition>"))
    eni = tmp_path / "ps-so.xml"
    tree.write(str(eni), xml_declaration=True, encoding="utf-8")
    out = tmp_path / "ps-so.py"
    done = export(eni, out)
    assert done.returncode == 1, done.stderr
    assert "slave 4 ('axis1'): SDO 0x6060:00 = 9 in PS/SO (SO too)" in done.stderr, \
        done.stderr
    assert not out.exists()


ELMO_TOPOLOGY = """
master: {name: rocos, cycle_time_us: 1000}
slaves:
  - name: drive
    device: "0x9a:0x30924:0x10420"
    rx_pdos: [0x160A, 0x160B, 0x160C, 0x160F, 0x161C]
    tx_pdos: [0x1A0A, 0x1A0E, 0x1A11, 0x1A13, 0x1A1D]
    dc: DC Sync
    sdos:
      - {index: 0x6060, value: 8}
      - {index: 0x60C2, subindex: 1, value: 1}
"""


def test_ec_engineer_elmo_eni_gives_what_our_eni_gives(veth_netns, pysoem_module, corpus,
                                                       tmp_path):
    """The Elmo drive of an EC-Engineer export in the corpus and our ENI compiled from a
    topology with the same PDOs, DC mode and SDOs: pysoem with either module gets the same
    sizes, working counters, PDO assignment and SDO values from the emulated drive."""
    topo = tmp_path / "elmo.yaml"
    topo.write_text(ELMO_TOPOLOGY)
    ours = tmp_path / "ours.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(corpus / "esi" / "drives"), "-o", str(ours), "--no-cache"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    theirs = corpus / "eni" / "rocos-ethercat" / "eni.xml"
    read = [[0, 0x1C12, 0], [0, 0x1C12, 1], [0, 0x1C12, 5], [0, 0x1C13, 0],
            [0, 0x1C13, 5], [0, 0x6060, 0], [0, 0x60C2, 1]]
    reports = []
    for eni in (theirs, ours):
        module = tmp_path / f"{eni.stem}_setup.py"
        done = export(eni, module)
        assert done.returncode == 0, done.stderr
        sim, lines = start_simulate(veth_netns, "--esi", str(corpus / "esi" / "drives"),
                                    "--topology", str(topo))
        assert lines and lines[-1].startswith("ready: 1 slaves"), "".join(lines)
        report = probe(veth_netns, module, {"cycles": 50, "read": read})
        sim.terminate()
        sim.communicate(timeout=20)
        assert report.get("safeop") == 4 and report.get("op") == 8, report
        bits = send_recv_bits(eni)
        assert [tuple(s) for s in report["sizes"]] == [((o + 7) // 8, (i + 7) // 8)
                                                       for o, i in bits]
        reports.append({k: report[k] for k in ("sizes", "wkcs", "read", "iomap", "dc")})
    assert reports[0] == reports[1]
    assert reports[0]["read"][:3] == ["05", "0a16", "1c16"]
    assert reports[0]["read"][5:] == ["08", "01"]
    assert reports[0]["dc"] == [["03", f"{1_000_000:08x}"]]    # SYNC0 every 1 ms


def test_a_refused_sdo_raises_with_slave_object_and_abort_code(veth_netns, pysoem_module,
                                                               example_eni, tmp_path):
    """The start-up SDO moved to an object the drive does not have: the emulated drive
    aborts (0x06020000, ETG.1000.6 Table 41: object does not exist) and the module's
    config_map raises naming the slave, the object and the code, before any SAFEOP."""
    tree = etree.parse(str(example_eni))
    cmd = tree.xpath("//CoE/InitCmds/InitCmd[Index='24672']")[0]
    cmd.find("Index").text = str(0x2FFF)
    eni = tmp_path / "refused.xml"
    tree.write(str(eni), xml_declaration=True, encoding="utf-8")
    module = tmp_path / "refused_setup.py"
    assert export(eni, module).returncode == 0
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(EXAMPLES / "topology.yaml"))
    assert lines and lines[-1].startswith("ready: 5 slaves"), "".join(lines)
    report = probe(veth_netns, module, {})
    assert report["map_error"] == ("slave 4 (axis1): SDO 0x2FFF:00 = 9: refused, abort "
                                   "code 0x06020000"), report
    assert "safeop" not in report


def test_soem_sizes_unlike_the_eni_s_raise_after_config_map(veth_netns, pysoem_module,
                                                            example_eni, tmp_path):
    """An ENI that gives the 4-input terminal 16 bits (ProcessData Recv) where the slave
    maps 4: after config_map the module compares len(slave.input) with the ENI and
    raises."""
    tree = etree.parse(str(example_eni))
    recv = tree.xpath("//Config/Slave[Info/Name='buttons']/ProcessData/Recv/BitLength")[0]
    recv.text = "16"
    eni = tmp_path / "sizes.xml"
    tree.write(str(eni), xml_declaration=True, encoding="utf-8")
    module = tmp_path / "sizes_setup.py"
    done = export(eni, module)
    assert done.returncode == 0, done.stderr
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(EXAMPLES / "topology.yaml"))
    assert lines and lines[-1].startswith("ready: 5 slaves"), "".join(lines)
    report = probe(veth_netns, module, {})
    assert report["map_error"] == ("slave 1 (buttons): SOEM mapped 0 output and 1 input "
                                   "byte(s), sizes.xml has 0 and 2 (0 and 16 bits)"), report
