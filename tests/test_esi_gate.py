"""Compile never builds on an ESI error: a lint error of a rule that changes
what compile writes, inside a Device element the topology uses or a module it plugs, makes
``compile`` (and ``simulate --topology``) exit 1 naming the ESI file and line, the rule and
the slave; ``--allow-esi-errors`` compiles with a warning per finding."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ecatcfg.cli import main
from ecatcfg.compiler import topology
from ecatcfg.compiler.plugged import plugged_devices
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint import RULES, all_rules
from ecatcfg.esi.lint.gate import DOES_NOT_STOP, STOPS_COMPILE

ROOT = Path(__file__).resolve().parent.parent


def _device(type_name: str, product: str, rx_sm: str = "2", bit_len: str = "8",
            slots: str = "") -> str:
    return f"""      <Device Physics="YY">
        <Type ProductCode="{product}" RevisionNo="#x1">{type_name}</Type>
        <Name LcId="1033">{type_name}</Name>
        <GroupType>G</GroupType>
        <Fmmu>Outputs</Fmmu>
        <Fmmu>Inputs</Fmmu>
        <Sm ControlByte="#x26" DefaultSize="128" Enable="1" StartAddress="#x1000">MBoxOut</Sm>
        <Sm ControlByte="#x22" DefaultSize="128" Enable="1" StartAddress="#x1080">MBoxIn</Sm>
        <Sm ControlByte="#x64" Enable="1" StartAddress="#x1100">Outputs</Sm>
        <Sm ControlByte="#x20" Enable="1" StartAddress="#x1180">Inputs</Sm>
{slots}        <RxPdo Fixed="1" Mandatory="1" Sm="{rx_sm}">
          <Index>#x1600</Index><Name>Out</Name>
          <Entry><Index>#x7000</Index><SubIndex>1</SubIndex>
            <BitLen>{bit_len}</BitLen><Name>o</Name><DataType>USINT</DataType></Entry>
        </RxPdo>
        <TxPdo Fixed="1" Mandatory="1" Sm="3">
          <Index>#x1A00</Index><Name>In</Name>
          <Entry><Index>#x6000</Index><SubIndex>1</SubIndex>
            <BitLen>8</BitLen><Name>i</Name><DataType>USINT</DataType></Entry>
        </TxPdo>
        <Mailbox><CoE/></Mailbox>
      </Device>
"""


_MODULES = """    <Modules>
      <Module><Type ModuleIdent="#x11">GOODMOD</Type><Name>good</Name>
        <TxPdo Fixed="1" Sm="3"><Index>#x1A10</Index><Name>M</Name>
          <Entry><Index>#x6010</Index><SubIndex>1</SubIndex>
            <BitLen>8</BitLen><Name>m</Name><DataType>USINT</DataType></Entry></TxPdo>
      </Module>
      <Module><Type ModuleIdent="#x22">BADMOD</Type><Name>bad</Name>
        <TxPdo Fixed="1" Sm="3"><Index>#x1A20</Index><Name>M</Name>
          <Entry><Index>#x6020</Index><SubIndex>1</SubIndex>
            <BitLen>#xZZ</BitLen><Name>m</Name><DataType>USINT</DataType></Entry></TxPdo>
      </Module>
    </Modules>
"""

_SLOTS = """        <Slots>
          <Slot MinInstances="0" MaxInstances="1"><Name>S1</Name>
            <ModuleIdent>#x11</ModuleIdent><ModuleIdent>#x22</ModuleIdent></Slot>
        </Slots>
"""


def _esi(*devices: str, modules: str = "") -> str:
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<EtherCATInfo Version="1.11">
  <Vendor><Id>#x00E0F1</Id><Name>V</Name></Vendor>
  <Descriptions>
    <Groups><Group><Type>G</Type><Name>G</Name></Group></Groups>
    <Devices>
{"".join(devices)}    </Devices>
{modules}  </Descriptions>
</EtherCATInfo>
"""


@pytest.fixture
def esi(tmp_path: Path) -> Path:
    path = tmp_path / "dev.xml"
    path.write_text(_esi(_device("CLEAN", "#x10"),
                         _device("BADNUM", "#x11", bit_len="0x1G"),
                         _device("BADSM", "#x12", rx_sm="5"),
                         _device("MODULAR", "#x13", slots=_SLOTS), modules=_MODULES))
    return path


def _line(path: Path, text: str, after: str = "") -> int:
    """The line of the first ``text`` after the first ``after`` (found in the file, not by
    the code under test)."""
    lines = path.read_text().splitlines()
    start = next(i for i, ln in enumerate(lines) if after in ln) if after else 0
    return next(i for i, ln in enumerate(lines) if i >= start and text in ln) + 1


def _compile(tmp_path: Path, capsys: pytest.CaptureFixture[str], esi: Path, device: str,
             *options: str, modules: str = "") -> tuple[int, str, Path]:
    topo = tmp_path / "t.yaml"
    topo.write_text(f"slaves:\n  - {{name: ok, device: CLEAN}}\n"
                    f"  - {{name: dut, device: {device}{modules}}}\n")
    out = tmp_path / "out.xml"
    code = main(["compile", str(topo), "--esi", str(esi), "-o", str(out), "--no-cache",
                 *options])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err, out


@pytest.mark.parametrize("device, rule, marker", [
    ("BADNUM", "ESI002", "0x1G"),       # was: a 0-bit BIT0 variable
    ("BADSM", "ESI108", 'Sm="5"'),      # was: the PDO silently moved to SM 0
])
def test_an_esi_error_stops_compile_naming_file_line_rule_and_slave(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], esi: Path, device: str,
        rule: str, marker: str) -> None:
    code, err, out = _compile(tmp_path, capsys, esi, device)
    assert code == 1 and not out.exists()
    line = _line(esi, marker, after=f">{device}<")
    assert re.search(rf"t\.yaml:3: slave 'dut': .*dev\.xml:{line}: {rule} ", err), err
    assert "--allow-esi-errors" in err
    assert "slave 'ok'" not in err       # a clean device of the same file is not concerned


@pytest.mark.parametrize("device, rule, marker", [
    ("BADNUM", "ESI002", "0x1G"), ("BADSM", "ESI108", 'Sm="5"')])
def test_allowed_esi_errors_compile_with_a_warning_per_finding(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], esi: Path, device: str,
        rule: str, marker: str) -> None:
    code, err, out = _compile(tmp_path, capsys, esi, device, "--allow-esi-errors")
    assert code == 0 and out.exists()
    line = _line(esi, marker, after=f">{device}<")
    warnings = [w for w in err.splitlines() if w.startswith("warning:") and " ESI" in w]
    assert len(warnings) == 1, err
    assert f"dev.xml:{line}: {rule} " in warnings[0] and "slave 'dut'" in warnings[0]
    assert "(taken as the ESI says it (--allow-esi-errors))" in warnings[0]


def test_errors_of_other_devices_of_the_file_do_not_stop_compile(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], esi: Path) -> None:
    code, err, out = _compile(tmp_path, capsys, esi, "CLEAN")
    assert code == 0 and out.exists(), err
    assert "warning" not in err


def test_an_error_in_a_plugged_module_stops_compile_an_unplugged_one_does_not(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], esi: Path) -> None:
    code, err, out = _compile(tmp_path, capsys, esi, "MODULAR", modules=", modules: {1: GOODMOD}")
    assert code == 0 and "warning" not in err, err
    out.unlink()
    code, err, out = _compile(tmp_path, capsys, esi, "MODULAR", modules=", modules: {1: BADMOD}")
    line = _line(esi, "#xZZ")
    assert code == 1 and not out.exists()
    assert re.search(rf"t\.yaml:3: slave 'dut': .*dev\.xml:{line}: ESI002 ", err), err


def test_simulate_resolves_with_the_same_rule(tmp_path: Path, esi: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    topo = tmp_path / "t.yaml"
    topo.write_text("slaves:\n  - {name: dut, device: BADSM}\n")
    lib = Library([esi], cache=False)
    line = _line(esi, 'Sm="5"', after=">BADSM<")
    with pytest.raises(TopologyError) as exc:
        plugged_devices(topology.load(topo), lib)
    assert f"dev.xml:{line}: ESI108" in str(exc.value)
    [dev] = plugged_devices(topology.load(topo), lib, allow_esi_errors=True)
    assert [w.message.split(": ")[2].split()[0] for w in dev.esi_warnings] == ["ESI108"]
    # The command line: refused before any interface is opened.
    code = main(["simulate", "--topology", str(topo), "--esi", str(esi), "--no-cache",
                 "--iface", "no-such-if0"])
    err = capsys.readouterr().err
    assert code == 1 and "t.yaml:2: slave 'dut': " in err and "ESI108" in err, err


def test_every_error_rule_is_classified_once() -> None:
    errors = {rid for rid, rule in all_rules().items() if rule.severity == "error"}
    assert STOPS_COMPILE | set(DOES_NOT_STOP) == errors
    assert not STOPS_COMPILE & set(DOES_NOT_STOP)


def test_the_lint_docs_say_which_rules_stop_compile() -> None:
    all_rules()
    text = (ROOT / "docs" / "lint.md").read_text()
    rows = re.findall(r"^\| (ESI\d{3}|XSD\d{3}) \| (\w+) \| (yes|no|) \|", text, re.M)
    assert {r[0] for r in rows} == set(RULES)
    for rid, severity, stops in rows:
        assert severity == RULES[rid].severity
        assert stops == ("yes" if rid in STOPS_COMPILE else
                         "no" if rid in DOES_NOT_STOP else ""), rid


def test_a_file_rewritten_at_once_with_the_same_size_is_checked_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], esi: Path) -> None:
    # compile keeps lint's findings per file for the process (a sweep compiles the devices
    # of one file one after another): the key must follow the content (a key of the path
    # fails here; one of size and modification time only where the clock is coarse).
    code, _, _ = _compile(tmp_path, capsys, esi, "BADNUM")
    assert code == 1
    fixed = esi.read_text().replace("<BitLen>0x1G</BitLen>", "<BitLen>0x08</BitLen>")
    assert len(fixed) == esi.stat().st_size
    esi.write_text(fixed)
    code, err, out = _compile(tmp_path, capsys, esi, "BADNUM")
    assert code == 0 and out.exists(), err
