"""Every error of a topology at once, in line order; "did you mean" for a misspelt key; an
XML file (an ENI, an ESI) given as a topology named for what it is."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import EXAMPLES, write
from ecatcfg.cli import main
from ecatcfg.compiler import topology
from ecatcfg.compiler.topology import TopologyError

ESI = EXAMPLES / "esi"

# An unknown key in the master, one in a slave, one in an SDO; between them a device the
# library lacks, a PDO, a DC mode and an object the example drive does not have.
MIXED = """\
master: {name: m, cycle_tme_us: 1000}
slaves:
  - name: coupler
    device: EX1100
    aliass: 5
  - name: io
    device: NOPE9999
  - name: axis1
    device: EXD-402
    rx_pdos: [0x1699]
    dc: NODC
    sdos:
      - {index: 0x6060, value: 9, transitoin: PS}
      - {index: 0x7777, value: 1}
"""


def compile_cli(tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]) -> list[str]:
    topo = write(tmp_path, "t.yaml", text)
    out = tmp_path / "out.xml"
    assert main(["compile", str(topo), "--esi", str(ESI), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert not out.exists()
    return [line.strip() for line in err.splitlines()[1:]]


def test_unknown_keys_come_with_the_errors_of_the_rest_in_line_order(tmp_path, capsys):
    lines = compile_cli(tmp_path, MIXED, capsys)
    topo = tmp_path / "t.yaml"
    assert lines == [
        f"{topo}:1: master.cycle_tme_us: unknown key; did you mean 'cycle_time_us'?",
        f"{topo}:5: slaves.0.aliass: unknown key; did you mean 'alias'?",
        f"{topo}:7: slave 'io': no device with Type name 'NOPE9999' in the library "
        "(5 devices in 3 files)",
        f"{topo}:10: slave 'axis1': EXD-402 has no RxPdo 0x1699; it has 0x1600, 0x1601",
        f"{topo}:11: slave 'axis1': no DC op mode 'NODC'; EXD-402 has DC, FreeRun",
        f"{topo}:13: slaves.2.sdos.0.transitoin: unknown key; did you mean 'transition'?",
        f"{topo}:14: slave 'axis1': object 0x7777 is not in the dictionary of EXD-402",
    ]


def test_unknown_keys_alone_are_still_an_error(tmp_path, capsys):
    topo = write(tmp_path, "u.yaml", "slaves:\n  - {name: a, device: EX1004, rxpdos: [1]}\n")
    out = tmp_path / "o.xml"
    assert main(["compile", str(topo), "--esi", str(ESI), "-o", str(out)]) == 1
    assert capsys.readouterr().err.strip() == (
        f"ecatcfg compile: {topo}:2: slaves.0.rxpdos: unknown key; did you mean 'rx_pdos'?")
    assert not out.exists()


def test_a_check_that_needs_the_misspelt_key_is_reported_with_it(tmp_path, capsys):
    # 'valeu' for 'value': the SDO then has neither value nor data; both are said.
    lines = compile_cli(tmp_path, "slaves:\n  - name: a\n    device: EXD-402\n    sdos:\n"
                                  "      - {index: 0x6060, valeu: 9}\n", capsys)
    topo = tmp_path / "t.yaml"
    assert lines == [f"{topo}:5: slaves.0.sdos.0.valeu: unknown key; did you mean 'value'?",
                     f"{topo}:5: slaves.0.sdos.0: Value error, give exactly one of 'value' "
                     "and 'data'"]


def test_other_model_errors_are_not_compiled_but_listed_with_the_unknown_keys(tmp_path,
                                                                              capsys):
    # A mistyped value has no meaning to resolve: the device error of slave b is not
    # looked for, but every error the model finds is listed.
    lines = compile_cli(tmp_path, "master: {cycle_time_us: fast}\nslaves:\n"
                                  "  - {name: a, device: EX1004, prot: B}\n"
                                  "  - {name: b, device: NOPE}\n", capsys)
    topo = tmp_path / "t.yaml"
    assert [line.split(": ")[0] for line in lines] == [f"{topo}:1", f"{topo}:3"]
    assert "did you mean 'port'?" in lines[1]
    assert not any("NOPE" in line for line in lines)


@pytest.mark.parametrize("key, at, suggestion", [
    ("layuot: lrw", "master", "layout"),
    ("watchdog: {qqq: 100}", "master.watchdog", None),     # nothing close: no guess
    ("watchdog: {sm_msec: 100}", "master.watchdog", "sm_ms"),
])
def test_did_you_mean_in_the_master(tmp_path, key, at, suggestion):
    path = write(tmp_path, "t.yaml", f"master:\n  {key}\nslaves:\n  - {{name: a, device: X}}\n")
    with pytest.raises(TopologyError) as info:
        topology.load(path)
    message = info.value.problems[0].message
    assert message.startswith(f"{at}.")
    assert message.endswith(f"; did you mean {suggestion!r}?" if suggestion else
                            "unknown key"), message


@pytest.mark.parametrize("slave, suggestion", [
    ("{name: a, device: X, eoe: {subnetmask: 255.0.0.0}}", "subnet_mask"),
    ("{name: a, device: X, pdo_mapping: {0x1600: [{index: 0x7000, bits: 8, nmae: n}]}}",
     "name"),
    ("{name: a, device: X, sdos: [{index: 1, value: 1, complete_acess: true}]}",
     "complete_access"),
    ("{name: a, device: X, hotconnect: true}", "hot_connect"),
    ("{name: a, device: X, xyz: 1}", None),
])
def test_did_you_mean_in_a_slave(tmp_path, slave, suggestion):
    path = write(tmp_path, "t.yaml", f"slaves:\n  - {slave}\n")
    with pytest.raises(TopologyError) as info:
        topology.load(path)
    [problem] = info.value.problems
    assert problem.line == 2
    assert ("; did you mean" in problem.message) == (suggestion is not None), problem.message
    if suggestion:
        assert problem.message.endswith(f"; did you mean {suggestion!r}?")


def test_the_library_api_never_drops_an_unknown_key(tmp_path):
    # Only the caller that reports them (topology.checked) reads past unknown keys.
    path = write(tmp_path, "t.yaml", "slaves:\n  - {name: a, device: EX1004, rxpdos: [1]}\n")
    with pytest.raises(TopologyError):
        topology.load(path)
    loaded = topology.load(path, unknown_keys="defer")
    assert [p.line for p in loaded.unknown] == [2]
    with pytest.raises(TopologyError) as info:
        topology.checked(loaded, lambda: "compiled")
    assert "rxpdos: unknown key" in str(info.value)


# -- XML given as a topology ----------------------------------------------------------------

@pytest.mark.parametrize("text, line, what", [
    (b'<?xml version="1.0" encoding="ISO-8859-1"?>\n<!-- made by hand -->\n'
     b'<EtherCATConfig Version="1.3">\n<Config/>\n</EtherCATConfig>\n', 3,
     "this is an ENI (network configuration): XML with root element <EtherCATConfig>"),
    (b'\xef\xbb\xbf<EtherCATInfo>\n  <Vendor><Name>M\xfcller</Name></Vendor>\n'
     b'</EtherCATInfo>\n', 1,
     "this is an ESI (device description): XML with root element <EtherCATInfo>"),
    ('<?xml version="1.0" encoding="UTF-16"?>\r\n<EtherCATConfig/>'.encode("utf-16"), 2,
     "this is an ENI (network configuration): XML with root element <EtherCATConfig>"),
    (b"\n\n  <!DOCTYPE html>\n<html><body>x</body></html>\n", 4,
     "this is XML with root element <html>"),
])
def test_xml_is_named_by_its_root_element(tmp_path, capsys, text, line, what):
    topo = write(tmp_path, "network.xml", text)
    assert main(["compile", str(topo), "--esi", str(ESI), "-o", str(tmp_path / "o")]) == 1
    assert capsys.readouterr().err.strip() == (
        f"ecatcfg compile: {topo}:{line}: {what}, not a topology (YAML or JSON)")


def test_real_eni_and_esi_given_as_topology(tmp_path, corpus, capsys):
    eni = corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml"
    esi = corpus / "esi" / "beckhoff" / "Beckhoff EL1xxx.xml"
    for path, kind in ((eni, "an ENI"), (esi, "an ESI")):
        assert main(["compile", str(path), "--esi", str(ESI), "-o",
                     str(tmp_path / "o.xml")]) == 1
        err = capsys.readouterr().err
        assert f"this is {kind} (" in err and "not a topology" in err, err
    assert not (tmp_path / "o.xml").exists()


def test_our_own_eni_given_back_to_compile(tmp_path, capsys):
    eni = tmp_path / "line.xml"
    assert main(["compile", str(EXAMPLES / "topology.yaml"), "--esi", str(ESI),
                 "-o", str(eni)]) == 0
    capsys.readouterr()
    assert main(["compile", str(eni), "--esi", str(ESI), "-o", str(tmp_path / "o.xml")]) == 1
    assert "this is an ENI (network configuration)" in capsys.readouterr().err


def test_yaml_that_merely_mentions_xml_is_a_topology(tmp_path):
    path = write(tmp_path, "t.yaml", "# <EtherCATConfig> is what compile writes\n"
                                     "slaves:\n  - {name: '<a>', device: EX1004}\n")
    assert topology.load(path).topology.slaves[0].name == "<a>"


def test_an_unknown_key_deep_in_a_mapping_entry_is_left_out_and_the_rest_compiled(tmp_path,
                                                                                  capsys):
    lines = compile_cli(tmp_path, "slaves:\n  - name: a\n    device: EXD-402\n"
                                  "    tx_pdos: [0x1A00, 0x1A01]\n    pdo_mapping:\n"
                                  "      0x1A01: [{index: 0x6041, bits: 16, nmae: x}]\n"
                                  "  - {name: b, device: NOPE}\n", capsys)
    topo = tmp_path / "t.yaml"
    assert [line.split(": ", 1)[0] for line in lines] == [f"{topo}:6", f"{topo}:7"]
    assert lines[0].endswith(".0.nmae: unknown key; did you mean 'name'?"), lines
    assert "'NOPE'" in lines[1]
