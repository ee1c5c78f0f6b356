"""IgH's ``ethercat xml``: an ``<EtherCATInfoList>`` of one ``<EtherCATInfo>`` per slave, read
as a list of ESI documents by ``devices``, ``lint``, the library, ``compile``, ``check`` and
``apply --virtual --esi``; and a file that is not UTF-8 and declares no encoding.

``tests/fixtures/igh/ethercat-xml-3-slaves.xml`` is our own, written in the shape IgH's
``tool/CommandXml.cpp`` prints (no encoding declared, decimal vendor ``Id`` without a
``Name``, ``#x%08x`` product and revision, SMs with unpadded hex start addresses and no
type text, Fixed/Mandatory PDOs with UINTn/BOOL types, no Name for a slave whose SII has
none).  The expected identities and lines are read from the fixture with lxml, not from the
code under test.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from conftest import FIXTURES
from ecatcfg.esi import reader as esi_reader
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.library import Library

LIST = FIXTURES / "igh" / "ethercat-xml-3-slaves.xml"


def _cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", *args], capture_output=True,
                          text=True, timeout=180, cwd=cwd)


def _expected() -> list[tuple[int, int, int, str, int]]:
    """(vendor, product, revision, type, Device line) per document, read with lxml."""
    root = etree.parse(str(LIST)).getroot()
    out = []
    for doc in root.iterchildren("EtherCATInfo"):
        dev = doc.find("Descriptions/Devices/Device")
        t = dev.find("Type")
        out.append((int(doc.findtext("Vendor/Id")), int(t.get("ProductCode")[2:], 16),
                    int(t.get("RevisionNo")[2:], 16), t.text, dev.sourceline))
    return out


def test_the_fixture_is_in_igh_form():
    data = LIST.read_bytes()
    assert data.startswith(b'<?xml version="1.0" ?>\n<EtherCATInfoList>')
    assert len(_expected()) == 3


def test_devices_lists_every_slave_of_the_list():
    run = _cli("devices", str(LIST), "--format", "json")
    assert run.returncode == 0, run.stderr
    got = [(d["vendor_id"], d["product_code"], d["revision"], d["type"], d["line"])
           for d in json.loads(run.stdout)["devices"]]
    assert got == _expected()


def test_the_library_and_the_model_read_each_document():
    lib = Library([LIST], cache=False)
    for vendor, product, revision, type_name, line in _expected():
        selection = lib.find(f"0x{vendor:x}:0x{product:x}:0x{revision:x}")
        device = lib.device(selection.entry)
        assert (device.vendor.id, device.type_name, device.source.line) == (
            vendor, type_name, line)
    inputs = lib.device(lib.find("EL1008").entry)
    assert [(p.index, p.sm) for p in inputs.pdos] == [(0x1A00, 0), (0x1A01, 0), (0x1A02, 0)]
    assert [(s.start_address, s.control_byte) for s in inputs.sms] == [(0x1000, 0x00)]


def test_each_document_keeps_its_own_vendor(tmp_path):
    data = LIST.read_bytes().replace(b"<Id>2</Id>", b"<Id>#x2</Id>", 1).replace(
        b"<Id>2</Id>", b"<Id>1234</Id>", 1)
    esi = esi_reader.read_bytes(data, "mixed.xml")
    assert [d.vendor.id for d in esi.devices] == [2, 1234, 2]
    path = tmp_path / "mixed.xml"
    path.write_bytes(data)
    lib = Library([path], cache=False)
    assert lib.device(lib.find("0x4d2:0x3f03052").entry).type_name == "EL1008"
    assert [e.vendor_id for e in lib.entries] == [2, 1234, 2]


def test_lint_names_the_usual_defects_and_checks_each_document_against_the_schema(corpus):
    run = _cli("lint", str(LIST), "--format", "json")
    assert "Traceback" not in run.stderr
    findings = json.loads(run.stdout)["findings"]
    rules = {(f["rule"], f["line"]) for f in findings}
    lines = [line for *_, line in _expected()]
    assert ("ESI005", lines[0]) in rules                  # the coupler has no Name
    assert {("ESI210", lines[1]), ("ESI210", lines[2])} <= rules   # no Fmmu
    assert all(f["severity"] != "error" for f in findings)
    schemas = corpus / "schemas" / "esi-1.17"
    run = _cli("lint", str(LIST), "--schema-dir", str(schemas), "--format", "json")
    xsd = [f for f in json.loads(run.stdout)["findings"] if f["rule"] == "XSD001"]
    vendor_lines = [el.sourceline for el in etree.parse(str(LIST)).iterfind(
        "EtherCATInfo/Vendor")]
    assert sorted(f["line"] for f in xsd if "Vendor" in f["message"]) == vendor_lines


def test_compile_check_and_apply_with_the_list(tmp_path):
    topology = tmp_path / "line.yaml"
    topology.write_text("master: {name: igh-line, cycle_time_us: 1000}\nslaves:\n"
                        "  - {name: coupler, device: EK1100}\n"
                        "  - {name: inputs, device: EL1008}\n"
                        "  - {name: outputs, device: EL2008}\n")
    eni = tmp_path / "line.xml"
    run = _cli("compile", str(topology), "--esi", str(LIST), "-o", str(eni))
    assert run.returncode == 0, run.stderr
    slaves = etree.parse(str(eni)).findall("Config/Slave")
    assert [(int(s.findtext("Info/ProductCode"), 0) & 0xFFFFFFFF)
            for s in slaves] == [p for _, p, *_ in _expected()]
    run = _cli("check", str(eni), "--esi", str(LIST))
    assert run.returncode == 0, run.stdout + run.stderr
    run = _cli("apply", str(eni), "--virtual", "--esi", str(LIST), "--simulated-time", "--cycles",
               "3", "--format", "json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert [s["highest_state"] for s in report["slaves"]] == ["OP"] * 3
    assert not [e for e in report["events"] if "emulated from the ENI alone" in e]


# -- not UTF-8, no encoding declared -------------------------------------------------------

def _latin1(declared: bool) -> bytes:
    head = b'<?xml version="1.0" encoding="ISO-8859-1"?>' if declared else \
        b'<?xml version="1.0" ?>'
    return LIST.read_bytes().replace(b'<?xml version="1.0" ?>', head).replace(
        b"Eingang 24V, 3ms", b"Eingang 24V, 3000 \xb5s")


def test_latin1_without_a_declaration_is_refused_at_the_byte_with_the_fix():
    data = _latin1(declared=False)
    at = data.index(b"\xb5")
    with pytest.raises(xmlsafe.XmlError) as caught:
        xmlsafe.parse_bytes(data, "igh.xml")
    err = caught.value
    assert (err.line, err.column) == (data.count(b"\n", 0, at) + 1,
                                      at - data.rfind(b"\n", 0, at))
    assert "0xB5 is not UTF-8" in err.message and "'µ'" in err.message
    assert 'encoding="ISO-8859-1"' in err.message


def test_latin1_with_its_declaration_is_read(tmp_path):
    path = tmp_path / "igh.xml"
    path.write_bytes(_latin1(declared=True))
    names = [d.name for d in esi_reader.read_file(path).devices]
    assert "EL1008 8K. Dig. Eingang 24V, 3000 µs" in names
    run = _cli("devices", str(path), "--format", "json")
    assert run.returncode == 0


def test_devices_names_the_byte_of_an_undeclared_latin1_file(tmp_path):
    path = tmp_path / "igh.xml"
    path.write_bytes(_latin1(declared=False))
    run = _cli("devices", str(path))
    assert "Traceback" not in run.stderr
    assert f"{path}:" in run.stderr and "is not UTF-8" in run.stderr


def test_an_sm_outside_process_memory_is_a_finding_and_stops_compile_by_name(tmp_path):
    """What an SII read back can hold (a SyncManager at 0x0000): lint's ESI203 at the Sm's
    line, and compile names it; no crash."""
    path = tmp_path / "odd.xml"
    path.write_bytes(LIST.read_bytes().replace(b'StartAddress="#x1000"', b'StartAddress="#x0"'))
    line = next(el.sourceline for el in etree.parse(str(path)).iter("Sm")
                if el.get("StartAddress") == "#x0")
    run = _cli("lint", str(path), "--format", "json")
    assert "Traceback" not in run.stderr
    assert ("ESI203", line) in {(f["rule"], f["line"]) for f in json.loads(run.stdout)["findings"]}
    topology = tmp_path / "line.yaml"
    topology.write_text("slaves:\n  - {name: inputs, device: EL1008}\n")
    run = _cli("compile", str(topology), "--esi", str(path), "-o", str(tmp_path / "x.xml"))
    assert run.returncode != 0 and "Traceback" not in run.stderr
    assert f"{path}:{line}: ESI203" in run.stderr


def test_simulate_with_the_list_serves_a_line_that_apply_brings_to_op(veth_netns, tmp_path):
    """``simulate --topology --esi LIST`` on one end of a veth pair in its namespace,
    ``apply`` of the compiled line on the other."""
    rig = veth_netns
    topology = tmp_path / "line.yaml"
    topology.write_text("master: {name: igh-line, cycle_time_us: 1000}\nslaves:\n"
                        "  - {name: coupler, device: EK1100}\n"
                        "  - {name: inputs, device: EL1008}\n"
                        "  - {name: outputs, device: EL2008}\n")
    eni = tmp_path / "line.xml"
    assert _cli("compile", str(topology), "--esi", str(LIST), "-o", str(eni)).returncode == 0
    sim = rig.popen_in(rig.ns_b, [
        sys.executable, "-m", "ecatcfg", "simulate", "--esi", str(LIST), "--topology",
        str(topology), "--iface", rig.if_b, "--duration", "60", "--no-cache"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert sim.stdout is not None
        for line in sim.stdout:
            if line.startswith("ready:"):
                break
        else:
            raise AssertionError(f"simulate ended before ready: {sim.stderr.read()}")
        done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", "apply", str(eni),
                                     "--iface", rig.if_a, "--cycles", "3", "--format",
                                     "json"], timeout=120)
        assert done.returncode == 0, done.stderr
        assert [s["highest_state"] for s in json.loads(done.stdout)["slaves"]] == ["OP"] * 3
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
