"""Where compile puts each PDO an ESI describes, and what it refuses rather than lose.

Two shapes ``ecatcfg check`` found in ENIs compiled from corpus devices, each written
here as a small ESI of our own:

- A device describes one PDO index twice, a virtual PDO on a virtual SyncManager and a
  real one (the shape of Beckhoff's EL2252 revision 0x00110000, whose next revision moved
  the real "Reserved" PDO to 0x1604).  An ENI lists a SyncManager's PDOs by index, so
  both cannot be written: compile refuses the device at both ESI lines, even with
  ``--allow-esi-errors``, and lint reports ESI102.
- A device's Sm elements give no type (IgH's ``ethercat xml`` dump of a Weidmueller UR20
  coupler).  The control byte says what the ESC does with each SM (register 0x0804: bits
  3:2 direction, 1:0 mode), so the type is taken from it and the Mandatory PDOs are
  assigned; an SM whose control byte gives no type leaves a Mandatory PDO without a
  SyncManager, which is an error naming the PDO's line, never a silent omission.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import esi_xml, write
from lxml import etree

from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.check import check_eni
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint import LintOptions, Target, lint_file, select_rules
from ecatcfg.esi.model import sm_type_from_control


def _entry(index: int, sub: int, bits: int, dtype: str) -> str:
    return (f"<Entry><Index>#x{index:04x}</Index><SubIndex>{sub}</SubIndex>"
            f"<BitLen>{bits}</BitLen><Name>v{sub}</Name><DataType>{dtype}</DataType></Entry>")


def _compile(esi: Path, device: str, allow: bool = False) -> bytes:
    text = json.dumps({"master": {"name": "m"}, "slaves": [{"name": "dut", "device": device}]})
    result = build.compile_topology(topology.loads(text, "t.json"),
                                    Library([esi], cache=False), allow_esi_errors=allow)
    return eni_writer.to_bytes(result.plan)


def _line(text: str, marker: str) -> int:
    return text[:text.index(marker)].count("\n") + 1


def _lint(esi: Path) -> list[tuple[str, int | None]]:
    result = lint_file(Target(esi, str(esi), True), LintOptions(select_rules(None, None)), [])
    assert result is not None
    return [(f.rule, f.line) for f in result.findings]


# -- one PDO index, two descriptions ------------------------------------------------------------

# Digital outputs at 0x0F00 with DC time stamps: two virtual SMs over the DC activation and
# start-time registers carry virtual PDOs; the "Reserved" PDO reuses the first one's index.
TWICE = (
    '<Device Physics="YY"><Type ProductCode="#x52" RevisionNo="#x1">DO2T</Type>'
    '<Name LcId="1033">DO2T</Name><GroupType>G</GroupType>'
    '<Fmmu Sm="0">Outputs</Fmmu><Fmmu Sm="1">Outputs</Fmmu><Fmmu Sm="2">Outputs</Fmmu>'
    '\n<Sm StartAddress="#x0981" Virtual="true">Outputs</Sm>'
    '\n<Sm StartAddress="#x0990" Virtual="true">Outputs</Sm>'
    '\n<Sm StartAddress="#x0f00" ControlByte="#x44" Enable="1">Outputs</Sm>'
    '\n<RxPdo Fixed="1" Sm="0" Virtual="true"><Index>#x1602</Index><Name>Sync Activate</Name>'
    f'{_entry(0x1D09, 0x81, 8, "USINT")}</RxPdo>'
    '\n<RxPdo Fixed="1" Sm="1" Virtual="true"><Index>#x1603</Index><Name>Sync Start</Name>'
    f'{_entry(0x1D09, 0x90, 64, "ULINT")}</RxPdo>'
    '\n<RxPdo Fixed="1" Sm="2" Mandatory="1"><Index>#x1600</Index><Name>Channel 1</Name>'
    f'{_entry(0x7000, 1, 1, "BOOL")}{_entry(0x7000, 2, 1, "BOOL")}'
    '<Entry><Index>0</Index><BitLen>6</BitLen></Entry></RxPdo>'
    '\n<RxPdo Fixed="1" Sm="2" Mandatory="1"><Index>#x1602</Index><Name>Reserved</Name>'
    '</RxPdo>\n</Device>')


def test_one_index_described_twice_is_refused_at_both_lines(tmp_path: Path) -> None:
    text = esi_xml(TWICE)
    esi = write(tmp_path, "do2t.xml", text)
    virtual, real = _line(text, "<RxPdo Fixed=\"1\" Sm=\"0\""), _line(text, "<Name>Reserved")
    assert virtual != real
    for allow in (False, True):
        with pytest.raises(TopologyError) as exc:
            _compile(esi, "DO2T", allow)
        message = str(exc.value)
        assert "slave 'dut': DO2T describes PDO 0x1602 twice" in message
        assert f"'Sync Activate' (virtual) at {esi}:{virtual}" in message
        assert f"'Reserved' at {esi}:{real}" in message
        assert "Traceback" not in message
    assert ("ESI102", real) in _lint(esi)


def test_the_real_pdo_alone_compiles_and_reads_back(tmp_path: Path) -> None:
    # The same device with the second PDO at its own index (what the vendor's next revision
    # did): compiled, the ENI lists 0x1600 and 0x1604 on SM2, and our reader takes it.
    text = esi_xml(TWICE.replace("<Index>#x1602</Index><Name>Reserved",
                                 "<Index>#x1604</Index><Name>Reserved"))
    esi = write(tmp_path, "do2t.xml", text)
    eni = write(tmp_path, "do2t-eni.xml", _compile(esi, "DO2T"))
    [sm2] = etree.parse(str(eni)).getroot().iterfind("Config/Slave/ProcessData/Sm2")
    assert [int(p.text or "") for p in sm2.iterfind("Pdo")] == [0x1600, 0x1604]
    read_back = eni_reader.read_file(eni).slaves[0].process_data
    assert read_back is not None
    assert sorted(p.index for p in read_back.pdos) == [0x1600, 0x1602, 0x1603, 0x1604]
    assert [f for f in check_eni(eni, Library([esi], cache=False), use_cache=False).findings
            if f.severity == "error"] == []


# -- SyncManagers without a type ----------------------------------------------------------------

def _untyped(sm2_control: str = "#x64", sm3_control: str = "#x20",
             mailbox: str = "") -> str:
    # IgH's dump: Sm elements without text, Enable 0 and DefaultSize 0 on the process-data
    # SMs (sized by the PDOs), Mandatory PDOs naming SM 2 and 3, no Fmmu list.
    return esi_xml(
        '<Device Physics="YY"><Type ProductCode="#x4f" RevisionNo="#x11100">CPL1</Type>'
        '<Name LcId="1033">CPL1</Name><GroupType>G</GroupType>'
        '\n<Sm Enable="1" StartAddress="#x1000" ControlByte="#x26" DefaultSize="128" />'
        '\n<Sm Enable="1" StartAddress="#x1400" ControlByte="#x22" DefaultSize="128" />'
        f'\n<Sm Enable="0" StartAddress="#x1800" ControlByte="{sm2_control}" DefaultSize="0" />'
        f'\n<Sm Enable="0" StartAddress="#x2400" ControlByte="{sm3_control}" DefaultSize="0" />'
        '\n<RxPdo Sm="2" Fixed="1" Mandatory="1"><Index>#x16ff</Index><Name>Control</Name>'
        f'{_entry(0xF200, 1, 16, "UINT")}</RxPdo>'
        '\n<RxPdo Sm="2" Fixed="1" Mandatory="1"><Index>#x1600</Index><Name>Out</Name>'
        f'{_entry(0x7000, 1, 8, "USINT")}</RxPdo>'
        '\n<TxPdo Sm="3" Fixed="1" Mandatory="1"><Index>#x1aff</Index><Name>Status</Name>'
        f'{_entry(0xF100, 1, 16, "UINT")}</TxPdo>'
        '\n<TxPdo Sm="3" Fixed="1" Mandatory="1"><Index>#x1a00</Index><Name>In</Name>'
        f'{_entry(0x6000, 1, 8, "USINT")}</TxPdo>'
        f'{mailbox}\n</Device>')


def test_untyped_syncmanagers_take_the_type_their_control_byte_gives(tmp_path: Path) -> None:
    esi = write(tmp_path, "cpl1.xml", _untyped())
    eni = write(tmp_path, "cpl1-eni.xml", _compile(esi, "CPL1"))
    pd = etree.parse(str(eni)).getroot().find("Config/Slave/ProcessData")
    assert pd is not None
    sm2, sm3 = pd.find("Sm2"), pd.find("Sm3")
    assert sm2 is not None and sm3 is not None
    assert (sm2.findtext("Type"), sm2.findtext("StartAddress"), sm2.findtext("Enable")) == (
        "Outputs", str(0x1800), "1")
    assert (sm3.findtext("Type"), sm3.findtext("StartAddress"), sm3.findtext("Enable")) == (
        "Inputs", str(0x2400), "1")
    # In ESI order, all four Mandatory PDOs.
    assert [int(p.text or "") for p in sm2.iterfind("Pdo")] == [0x16FF, 0x1600]
    assert [int(p.text or "") for p in sm3.iterfind("Pdo")] == [0x1AFF, 0x1A00]
    # 3 bytes each way: the SM lengths in the InitCmds that set SM2 and SM3 (0x0810, 0x0818).
    lengths = {c.findtext("Ado"): bytes.fromhex(c.findtext("Data") or "")[2:4]
               for c in etree.parse(str(eni)).getroot().iterfind("Config/Slave/InitCmds/InitCmd")
               if c.findtext("Ado") in (str(0x0810), str(0x0818))}
    assert lengths == {str(0x0810): b"\x03\x00", str(0x0818): b"\x03\x00"}
    assert [f for f in check_eni(eni, Library([esi], cache=False), use_cache=False).findings
            if f.severity == "error"] == []
    # Lint says which types were taken from control bytes, at each Sm's line.
    found = [line for rule, line in _lint(esi) if rule == "ESI215"]
    text = _untyped()
    assert found == [_line(text, f'StartAddress="#x{a}"') for a in ("1000", "1400", "1800", "2400")]


def test_an_untyped_sm_whose_control_byte_gives_no_type_is_an_error(tmp_path: Path) -> None:
    # Direction bits 3:2 = 10 are reserved: the SM has no type, and the Mandatory PDOs that
    # name it have nowhere to go.
    text = _untyped(sm3_control="#x28")
    esi = write(tmp_path, "cpl1.xml", text)
    with pytest.raises(TopologyError) as exc:
        _compile(esi, "CPL1", allow=True)
    message = str(exc.value)
    for index, name in ((0x1AFF, "Status"), (0x1A00, "In")):
        line = _line(text, f"<Index>#x{index:04x}</Index>")
        assert (f"CPL1 has no Inputs SyncManager for the Mandatory TxPdo 0x{index:04X} ({name}) "
                f"at {esi}:{line}") in message
    sm3 = _line(text, 'StartAddress="#x2400"')
    assert f"names Sm 3 at {esi}:{sm3}" in message
    assert "ControlByte 0x28 gives none" in message
    assert "RxPdo" not in message                      # the outputs are placed


def test_a_mandatory_pdo_without_sm_goes_to_its_directions_sm(tmp_path: Path) -> None:
    text = _untyped().replace('<TxPdo Sm="3" Fixed="1" Mandatory="1"><Index>#x1a00',
                              '<TxPdo Fixed="1" Mandatory="1"><Index>#x1a00')
    esi = write(tmp_path, "cpl1.xml", text)
    [sm3] = etree.fromstring(_compile(esi, "CPL1")).iterfind("Config/Slave/ProcessData/Sm3")
    assert [int(p.text or "") for p in sm3.iterfind("Pdo")] == [0x1AFF, 0x1A00]


# Written from the ESC register description (0x0804: bits 1:0 mode 00 three buffers / 10
# mailbox, bits 3:2 direction 00 master reads / 01 master writes), not from the code.
@pytest.mark.parametrize("control, named, expected", [
    (0x26, False, "MBoxOut"), (0x22, False, "MBoxIn"), (0x64, False, "Outputs"),
    (0x20, False, "Inputs"), (0x44, False, "Outputs"), (0x00, False, "Inputs"),
    (0x22, True, "Inputs"),          # one buffer, but PDOs name it: EL1252-style inputs
    (0x26, True, "Outputs"),
    (0x28, False, None), (0x2C, False, None),       # direction 10, 11: reserved
    (0x21, False, None), (0x63, True, None),        # mode 01, 11: reserved
])
def test_the_type_a_control_byte_gives(control: int, named: bool, expected: str | None) -> None:
    assert sm_type_from_control(control, named) == expected
