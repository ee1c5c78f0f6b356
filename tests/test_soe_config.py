"""SoE on the configuration side: the ESI's Mailbox/SoE InitCmds and the topology's ``soe:``
compiled into the ENI's Mailbox/SoE/InitCmds, read back, shown, compared, checked and
exported.

The references are not ecatcfg's own: the ETG.2100 schema judges every ENI, the expected
commands are written here by hand from the self-written drive (tests/fixtures/esi/
soe_drive.xml) and its comments, gcc builds the SOEM export against SOEM's own sources,
and every SoE device of the corpora is compiled against its vendor's file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from conftest import FIXTURES, write
from test_export_soem_c import build as build_c
from test_export_soem_c import soem_sources  # noqa: F401  (a fixture: gcc and SOEM's sources)
from ecatcfg.cli import main
from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan, SoeInitCmd
from ecatcfg.eni.words import soe_words
from ecatcfg.esc import Transition
from ecatcfg.esi.idn import idn_text, parse_idn
from ecatcfg.esi.library import Library
from ecatcfg.esi.reader import read_file as read_esi

ESI = FIXTURES / "esi"
DRIVE = ESI / "soe_drive.xml"
PS, SO = Transition.PS, Transition.SO

TOPOLOGY = """\
master: {name: soe-line, cycle_time_us: 1000}
slaves:
  - name: axes
    device: TSD-2 SoE
"""
SOE_KEYS = """\
    soe:
      - {idn: S-0-0001, value: 2000}
      - {idn: P-0-0015, data: "0a00", transition: SO, drive: 1}
      - {idn: S-0-0032, value: 2, drive: 1, comment: position mode}
"""

# The fixture's InitCmds as an ENI carries them, written from its file: the two IP writes
# of P-0-0010 first in PS, then the PS writes in file order, then the SO one.
FROM_ESI = [
    SoeInitCmd([PS], "Feature flags", 0x800A, bytes.fromhex("fe7f000000000000"), drive_no=0),
    SoeInitCmd([PS], "Feature flags", 0x800A, bytes.fromhex("fe7f000000000000"), drive_no=1),
    SoeInitCmd([PS], "NC cycle time", 1, bytes([0xE8, 0x03]), drive_no=0),
    SoeInitCmd([PS], "Communication cycle time", 2, bytes([0xE8, 0x03]), drive_no=0),
    SoeInitCmd([PS], "Primary operation mode", 32, bytes([0x0B, 0]), drive_no=0),
    SoeInitCmd([PS], "Primary operation mode", 32, bytes([0x0B, 0]), drive_no=1),
    SoeInitCmd([SO], "Drive-specific setting", 0x8064, bytes([1, 0, 0, 0]), drive_no=1),
]


def compile_text(tmp_path: Path, text: str, esi: Path = ESI) -> NetworkPlan:
    topo = write(tmp_path, "t.yaml", text)
    return build.compile_topology(topology.load(topo), Library([esi], cache=False)).plan


def compile_errors(tmp_path: Path, text: str, esi: Path = ESI) -> list[str]:
    with pytest.raises(TopologyError) as caught:
        compile_text(tmp_path, text, esi)
    return [str(p) for p in caught.value.problems]


def soe_cmds(plan: NetworkPlan) -> list[SoeInitCmd]:
    [slave] = plan.slaves
    assert slave.mailbox is not None
    return slave.mailbox.soe_init_cmds


# -- IDN notation ---------------------------------------------------------------------------

@pytest.mark.parametrize("text, idn", [("S-0-0001", 1), ("P-0-0010", 0x800A),
                                        ("s-0-1002", 1002), ("P-7-4095", 0xFFFF),
                                        ("S-1-0032", 0x1020)])
def test_idn_notation(text: str, idn: int) -> None:
    assert parse_idn(text) == idn
    assert idn_text(idn) == text.upper()


@pytest.mark.parametrize("text", ["S-8-0001", "P-0-4096", "X-0-0001", "32778", "S-0-"])
def test_not_an_idn(text: str) -> None:
    with pytest.raises(ValueError, match="IDN"):
        parse_idn(text)


# -- the compiler -----------------------------------------------------------------------------

def test_the_esi_soe_init_cmds_reach_the_eni(tmp_path: Path, eni_schema) -> None:
    plan = compile_text(tmp_path, TOPOLOGY)
    assert soe_cmds(plan) == FROM_ESI
    [slave] = plan.slaves
    assert slave.mailbox is not None and slave.mailbox.protocols == ["SoE"]
    assert slave.mailbox.coe_init_cmds == []
    eni = write(tmp_path, "eni.xml", eni_writer.to_bytes(plan))
    tree = etree.parse(str(eni))
    assert eni_schema.validate(tree), eni_schema.error_log
    assert len(tree.findall(".//Mailbox/SoE/InitCmds/InitCmd")) == 7
    assert eni_reader.read_file(eni) == plan           # the file holds all of it


def test_topology_entries_replace_and_add(tmp_path: Path, eni_schema) -> None:
    plan = compile_text(tmp_path, TOPOLOGY + SOE_KEYS)
    expected = list(FROM_ESI)
    # S-0-0001 of drive 0 in PS: replaced in place, the ESI's comment kept; S-0-0032 of
    # drive 1 likewise; P-0-0015 of drive 1 in SO: added after the ESI's.
    expected[2] = SoeInitCmd([PS], "NC cycle time", 1, bytes([0xD0, 0x07]), drive_no=0)
    expected[5] = SoeInitCmd([PS], "Primary operation mode", 32, bytes([2, 0]), drive_no=1)
    expected.append(SoeInitCmd([SO], "write P-0-0015", 0x800F, bytes([0x0A, 0]), drive_no=1))
    assert soe_cmds(plan) == expected
    eni = write(tmp_path, "eni.xml", eni_writer.to_bytes(plan))
    assert eni_schema.validate(etree.parse(str(eni))), eni_schema.error_log


def test_data_with_spaces_and_a_type_that_matches_the_idns(tmp_path: Path) -> None:
    """'data' is hex bytes with spaces anywhere (the topology's check takes them out);
    'type' for an IDN ecatcfg types is accepted when it has the IDN's size (S-0-0002:
    UINT, 16 bits), and the value is encoded by it (1000 = 0x03E8, little endian)."""
    plan = compile_text(tmp_path, TOPOLOGY + "    soe:\n"
                        '      - {idn: P-0-0015, data: "0 a 0 0", transition: SO}\n'
                        "      - {idn: S-0-0002, value: 1000, type: UINT}\n")
    found = {(c.idn, c.drive_no, tuple(c.transitions)): c.data for c in soe_cmds(plan)}
    assert found[(0x800F, 0, (SO,))] == bytes([0x0A, 0x00])
    assert found[(2, 0, (PS,))] == bytes([0xE8, 0x03])


def test_an_entry_in_another_transition_is_added_not_replaced(tmp_path: Path) -> None:
    plan = compile_text(tmp_path, TOPOLOGY + "    soe:\n"
                        "      - {idn: S-0-0032, value: 8, transition: SO}\n")
    cmds = soe_cmds(plan)
    assert cmds[:7] == FROM_ESI
    assert cmds[7] == SoeInitCmd([SO], "S-0-0032 Primary operation mode", 32, bytes([8, 0]))


def test_an_esi_write_in_two_transitions_is_split_by_a_topology_entry(tmp_path: Path) -> None:
    text = DRIVE.read_text().replace(
        "<Transition>SO</Transition>", "<Transition>PS</Transition><Transition>SO</Transition>")
    folder = tmp_path / "esi"
    folder.mkdir()
    write(folder, "drive.xml", text)
    plan = compile_text(tmp_path, TOPOLOGY + "    soe:\n"
                        "      - {idn: P-0-0100, drive: 1, data: '02000000', transition: SO}\n",
                        folder)
    assert soe_cmds(plan)[6:] == [
        SoeInitCmd([PS], "Drive-specific setting", 0x8064, bytes([1, 0, 0, 0]), drive_no=1),
        SoeInitCmd([SO], "Drive-specific setting", 0x8064, bytes([2, 0, 0, 0]), drive_no=1)]


def test_topology_errors_name_their_lines(tmp_path: Path) -> None:
    text = TOPOLOGY + """\
    soe:
      - {idn: S-0-0001, value: 70000}
      - {idn: S-0-0033, value: 1}
      - {idn: S-0-0032, value: 1, drive: 2}
      - {idn: S-0-0032, value: 1, transition: IP}
      - {idn: S-0-0001, value: 1, type: UDINT}
      - {idn: P-0-0010, data: "0100", type: UINT}
"""
    topo = tmp_path / "t.yaml"
    assert compile_errors(tmp_path, text) == [
        f"{topo}:6: slave 'axes': S-0-0001 (drive 0): value 70000 is outside UINT (0..65535)",
        f"{topo}:7: slave 'axes': S-0-0033 (drive 0) is not among the IDNs ecatcfg knows "
        "the type of (S-0-0001, S-0-0002, S-0-0015, S-0-0032, S-0-0099); give 'type' (e.g. "
        "UINT) or 'data'",
        f"{topo}:8: slave 'axes': S-0-0032 (drive 2): TSD-2 SoE has 2 drives (ESI SoE "
        "ChannelCount), numbered from 0",
        f"{topo}:9: slave 'axes': S-0-0032 (drive 0): an SoE write cannot run in transition "
        "IP (ETG.2100 allows PS, SO, SP, OP, OS; PS reaches the drive in PREOP)",
        f"{topo}:10: slave 'axes': S-0-0001 (drive 0) (NC cycle time (TNcyc)) is 16 bits "
        "(UINT), but 'type' UDINT is 32 bits",
    ]


def test_the_entry_itself_is_checked_at_its_line(tmp_path: Path) -> None:
    text = TOPOLOGY + """\
    soe:
      - {idn: S-9-0001, value: 1}
      - {idn: S-0-0001}
      - {idn: S-0-0001, value: 1, drive: 8}
"""
    errors = compile_errors(tmp_path, text)
    topo = tmp_path / "t.yaml"
    assert len(errors) == 3
    assert errors[0].startswith(f"{topo}:6: slaves.0.soe.0.idn") and "S-9-0001" in errors[0]
    assert errors[1].startswith(f"{topo}:7: slaves.0.soe.1") and \
        "exactly one of 'value' and 'data'" in errors[1]
    assert errors[2].startswith(f"{topo}:8: slaves.0.soe.2.drive")


def test_soe_on_a_device_without_soe(tmp_path: Path) -> None:
    from conftest import EXAMPLES
    text = """\
slaves:
  - name: axis1
    device: EXD-402
    soe:
      - {idn: S-0-0001, value: 1000}
"""
    [error] = compile_errors(tmp_path, text, EXAMPLES / "esi")
    assert error.startswith(f"{tmp_path / 't.yaml'}:5: slave 'axis1': EXD-402 has no SoE "
                            "mailbox (its ESI, ")
    assert error.endswith("lists CoE, FoE), so S-0-0001 (drive 0) cannot be written")


@pytest.mark.parametrize("change, says", [
    (("<IDN>1</IDN>\n              <Data>e803</Data>", "<IDN>1</IDN>"),
     "writes S-0-0001 but has no Data"),
    (('<InitCmd Chn="1">\n              <Transition>SO', '<InitCmd Chn="2">\n'
      "              <Transition>SO"),
     "writes P-0-0100 of drive 2 (Chn), but the device has 2 drives (ChannelCount)"),
    (("<Transition>SO</Transition>", "<Transition>II</Transition>"),
     "writes P-0-0100 in transition II: an SoE write needs the mailbox"),
    (("<Transition>SO</Transition>", ""),
     "writes P-0-0100 in transition (none): an SoE write needs the mailbox"),
])
def test_an_esi_init_cmd_no_eni_can_carry_stops_compile(tmp_path: Path, change, says) -> None:
    old, new = change
    text = DRIVE.read_text()
    assert old in text
    folder = tmp_path / "esi"
    folder.mkdir()
    drive = write(folder, "drive.xml", text.replace(old, new))
    line = next(n for n, (a, b) in enumerate(zip(text.splitlines(),
                                                 drive.read_text().splitlines()), 1) if a != b)
    errors = compile_errors(tmp_path, TOPOLOGY, folder)
    mine = [e for e in errors if "the SoE InitCmd at" in e]
    assert len(mine) == 1, errors
    # The command's line in the ESI: the InitCmd element the change is in or below.
    cmd_line = max(n for n, t in enumerate(text.splitlines(), 1)
                   if "<InitCmd" in t and n <= line)
    assert f"the SoE InitCmd at {drive}:{cmd_line} {says}" in mine[0]


def test_an_esi_ip_write_later_in_the_file_still_goes_first(tmp_path: Path) -> None:
    """Drive 0's IP write of P-0-0010 moved to the end of the file: the IP writes still
    open PS (esi/idn.py eni_transition), in their file order among themselves."""
    block = ('            <InitCmd Chn="0">\n              <Transition>IP</Transition>\n'
             "              <IDN>32778</IDN>\n              <Data>fe7f000000000000</Data>\n"
             "              <Comment>Feature flags</Comment>\n            </InitCmd>\n")
    last = "<Comment>Drive-specific setting</Comment>\n            </InitCmd>\n"
    text = DRIVE.read_text()
    assert block in text and last in text
    folder = tmp_path / "esi"
    folder.mkdir()
    write(folder, "drive.xml", text.replace(block, "", 1).replace(last, last + block, 1))
    assert soe_cmds(compile_text(tmp_path, TOPOLOGY, folder)) == \
        [FROM_ESI[1], FROM_ESI[0], *FROM_ESI[2:]]


def test_a_type_of_unknown_size_for_a_known_idn_is_an_error_at_its_type(tmp_path: Path) -> None:
    text = TOPOLOGY + ("    soe:\n      - idn: S-0-0001\n        value: 5\n"
                       "        type: NOSUCHTYPE\n")
    [error] = compile_errors(tmp_path, text)
    line = text.splitlines().index("        type: NOSUCHTYPE") + 1
    assert error.endswith(f"t.yaml:{line}: slave 'axes': S-0-0001 (drive 0) (NC cycle time "
                          "(TNcyc)) is 16 bits (UINT), but 'type' NOSUCHTYPE is of unknown "
                          "bits"), error


def test_lint_stops_nothing_the_resolver_does_not(tmp_path: Path) -> None:
    """ESI216 and ESI217 find the same defects the resolver refuses."""
    from ecatcfg.esi.lint import LintOptions, Target, lint_file, select_rules
    text = DRIVE.read_text().replace('<InitCmd Chn="1">\n              <Transition>SO',
                                     '<InitCmd Chn="5">\n              <Transition>SO')
    path = write(tmp_path, "drive.xml", text.replace("<Data>e803</Data>", "", 1))
    result = lint_file(Target(path, str(path), True), LintOptions(select_rules(None, None)), [])
    assert result is not None
    assert sorted(f.rule for f in result.findings) == ["ESI216", "ESI217"]


def test_the_read_esi_keeps_the_channels(tmp_path: Path) -> None:
    [device] = read_esi(DRIVE).devices
    assert device.mailbox is not None and device.mailbox.soe is not None
    assert device.mailbox.soe.drives == 2
    assert [c.channel for c in device.mailbox.soe.init_cmds] == [0, 1, 0, 0, 0, 1, 1]


# -- the ENI: writer, reader, apply's list -------------------------------------------------

def _eni(tmp_path: Path, text: str = TOPOLOGY + SOE_KEYS) -> Path:
    return write(tmp_path, "eni.xml", eni_writer.to_bytes(compile_text(tmp_path, text)))


def test_the_element_order_is_the_schemas(tmp_path: Path) -> None:
    cmd = etree.parse(str(_eni(tmp_path))).find(".//Mailbox/SoE/InitCmds/InitCmd")
    assert [c.tag for c in cmd] == ["Transition", "Comment", "Timeout", "OpCode", "DriveNo",
                                    "IDN", "Elements", "Attribute", "Data"]
    assert [c.text for c in cmd] == ["PS", "Feature flags", "0", "3", "0", "32778", "64", "0",
                                     "fe7f000000000000"]
    mailbox = cmd.getparent().getparent().getparent()
    assert [c.tag for c in mailbox] == ["Send", "Recv", "Protocol", "SoE"]


def test_every_field_survives_a_round_trip(tmp_path: Path, eni_schema) -> None:
    plan = compile_text(tmp_path, TOPOLOGY)
    [slave] = plan.slaves
    assert slave.mailbox is not None
    slave.mailbox.soe_init_cmds = [
        SoeInitCmd([PS, Transition.OP], "", 0xFFFF, b"", op_code=3, drive_no=7,
                   elements=0x40, attribute=0xFFFFFFFF, timeout=2500, disabled=True,
                   fixed=True),
        SoeInitCmd([Transition.SP, Transition.OS], "x", 0, b"\x01", attribute=0x00020000)]
    data = eni_writer.to_bytes(plan)
    assert eni_schema.validate(etree.fromstring(data).getroottree()), eni_schema.error_log
    assert eni_reader.read_bytes(data, "eni.xml") == plan


@pytest.mark.parametrize("field, value, says", [
    ("DriveNo", "8", "DriveNo"), ("IDN", "65536", "IDN"), ("Elements", "256", "Elements"),
    ("Attribute", "4294967296", "Attribute")])
def test_a_field_out_of_range_is_an_error_at_its_line(tmp_path: Path, field: str, value: str,
                                                      says: str) -> None:
    eni = _eni(tmp_path)
    tree = etree.parse(str(eni))
    el = tree.find(f".//Mailbox/SoE/InitCmds/InitCmd/{field}")
    el.text = value
    tree.write(str(eni))
    line = etree.parse(str(eni)).find(f".//Mailbox/SoE/InitCmds/InitCmd/{field}").sourceline
    with pytest.raises(eni_reader.EniReadError) as caught:
        eni_reader.read_file(eni)
    assert caught.value.line == line and says in str(caught.value)


def test_only_write_requests_are_read_another_opcode_is_refused_by_name(tmp_path: Path) -> None:
    eni = _eni(tmp_path)
    tree = etree.parse(str(eni))
    cmds = tree.findall(".//Mailbox/SoE/InitCmds/InitCmd")
    cmds[2].find("OpCode").text = "1"             # a read request
    tree.write(str(eni))
    op_line = etree.parse(str(eni)).findall(".//Mailbox/SoE/InitCmds/InitCmd")[2] \
        .find("OpCode").sourceline
    plan = eni_reader.read_file(eni)
    [part] = plan.unsupported
    assert (part.element, part.slave, part.line, part.commands) == (
        "SoE/InitCmds/InitCmd", "axes", op_line, 1)
    assert part.what == "an SoE request with OpCode 1 (apply sends write requests, OpCode " \
        "3, only)"
    # Left out of the plan, so that a skipping apply does not send it.
    assert len(soe_cmds(plan)) == 7 and all(c.op_code == 3 for c in soe_cmds(plan))
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(ESI), "--simulated-time", "--cycles", "1"],
                           capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert f"{eni}:{op_line}: slave 'axes': an SoE request with OpCode 1" in done.stderr
    assert "nothing was written to the bus" in done.stderr


def test_an_soe_write_where_no_mailbox_answers_is_refused(tmp_path: Path) -> None:
    eni = _eni(tmp_path)
    tree = etree.parse(str(eni))
    tree.find(".//Mailbox/SoE/InitCmds/InitCmd/Transition").text = "II"
    tree.write(str(eni))
    [part] = eni_reader.read_file(eni).unsupported
    assert part.what.startswith("a SoE InitCmd in transition II (INIT->INIT): ")


def test_soe_init_cmds_are_not_refused_by_apply(tmp_path: Path) -> None:
    assert eni_reader.read_file(_eni(tmp_path)).unsupported == []


# -- show, diff, check, report ------------------------------------------------------------

def test_words() -> None:
    assert soe_words(SoeInitCmd([PS], "", 1, bytes([0xD0, 0x07]))) == \
        "SoE write S-0-0001 (drive 0) = d0 07"
    assert soe_words(SoeInitCmd([PS], "", 0x800A, b"\x01", drive_no=1, disabled=True)) == \
        "SoE write P-0-0010 (drive 1) = 01 (disabled)"
    assert soe_words(SoeInitCmd([PS], "", 32, b"", op_code=1, elements=0x08)) == \
        "SoE OpCode 1 S-0-0032 (drive 0) elements 0x08"


def test_show_lists_them_per_transition(tmp_path: Path, capsys) -> None:
    eni = _eni(tmp_path)
    assert main(["show", str(eni), "--no-cache", "--format", "json"]) == 0
    [slave] = json.loads(capsys.readouterr().out)["slaves"]
    words = json.dumps(slave)
    for text in ("SoE write P-0-0010 (drive 1) = fe 7f 00 00 00 00 00 00",
                 "SoE write S-0-0001 (drive 0) = d0 07",
                 "SoE write P-0-0015 (drive 1) = 0a 00"):
        assert text in words
    assert main(["show", str(eni), "--no-cache"]) == 0
    out = capsys.readouterr().out
    assert "    SO  SoE write P-0-0100 (drive 1) = 01 00 00 00\n" \
           "    SO  SoE write P-0-0015 (drive 1) = 0a 00\n" in out


def test_diff_compares_them(tmp_path: Path, capsys) -> None:
    a = _eni(tmp_path)
    b_dir = tmp_path / "b"
    b_dir.mkdir()
    b = _eni(b_dir, TOPOLOGY + SOE_KEYS.replace("value: 2000", "value: 4000")
             .replace('      - {idn: P-0-0015, data: "0a00", transition: SO, drive: 1}\n', ""))
    assert main(["diff", str(a), str(b), "--format", "json", "--no-cache"]) == 1
    changes = json.loads(capsys.readouterr().out)["changes"]
    assert [(c["kind"], c["transition"], c["what"], c["old"], c["new"]) for c in changes] == [
        ("initcmd-changed", "PS", "SoE S-0-0001 (drive 0)",
         "SoE write S-0-0001 (drive 0) = d0 07", "SoE write S-0-0001 (drive 0) = a0 0f"),
        ("initcmd-removed", "SO", "SoE P-0-0015 (drive 1)",
         "SoE write P-0-0015 (drive 1) = 0a 00", None)]


def test_check_finds_nothing_in_a_compiled_drive_and_a_drive_it_lacks(tmp_path: Path) -> None:
    from ecatcfg.eni.check import check_eni
    eni = _eni(tmp_path)
    assert check_eni(eni, Library([ESI], cache=False), use_cache=False).findings == []
    tree = etree.parse(str(eni))
    tree.findall(".//Mailbox/SoE/InitCmds/InitCmd/DriveNo")[1].text = "3"
    tree.write(str(eni))
    found = check_eni(eni, Library([ESI], cache=False), use_cache=False).findings
    device_line = next(n for n, text in enumerate(DRIVE.read_text().splitlines(), 1)
                       if "<Device " in text)
    assert [(f.rule, f.message) for f in found] == [
        ("ENI502", "slave 'axes': SoE write P-0-0010 (drive 3) = fe 7f 00 00 00 00 00 00: "
         f"the device has 2 drive(s), numbered from 0 (ChannelCount, {DRIVE}:{device_line})")]


def test_the_report_lists_them(tmp_path: Path) -> None:
    eni = _eni(tmp_path)
    page = tmp_path / "report.html"
    assert main(["report", str(eni), "-o", str(page), "--no-cache"]) == 0
    text = page.read_text()
    assert "SoE write S-0-0032 (drive 1) = 02 00" in text


# -- export -----------------------------------------------------------------------------------

def _ps_only(tmp_path: Path) -> Path:
    """The compiled drive without its SO writes: what a PREOP hook can make."""
    eni = _eni(tmp_path)
    tree = etree.parse(str(eni))
    for cmd in tree.xpath('//Mailbox/SoE/InitCmds/InitCmd[Transition="SO"]'):
        cmd.getparent().remove(cmd)
    tree.write(str(eni))
    return eni


def test_pysoem_export_refuses_soe_by_slave_and_command(tmp_path: Path) -> None:
    eni = _ps_only(tmp_path)
    line = etree.parse(str(eni)).find(".//Mailbox/SoE/InitCmds/InitCmd").sourceline
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "pysoem", "-o", str(tmp_path / "setup.py"), "--no-cache"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert f"{eni}:{line}: slave 0 ('axes'): SoE write P-0-0010 (drive 0) = fe 7f 00 00 00 " \
           "00 00 00: pysoem has no SoE call (6 SoE write(s) in all)" in done.stderr
    assert not (tmp_path / "setup.py").exists()


def test_an_soe_write_after_safeop_cannot_be_exported(tmp_path: Path) -> None:
    eni = _eni(tmp_path)
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "soem-c", "-o", str(tmp_path / "setup.c"), "--no-cache"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "slave 0 ('axes'): SoE write P-0-0100 (drive 1) = 01 00 00 00 in SO" in done.stderr


def test_soem_export_makes_them_with_ecx_soewrite(
        tmp_path: Path, soem_sources: Path) -> None:  # noqa: F811
    """gcc builds it (-Werror) with SOEM's own sources: ecx_SoEwrite's signature is SOEM's."""
    eni = _ps_only(tmp_path)
    source = tmp_path / "setup.c"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "soem-c", "-o", str(source), "--no-cache"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    text = source.read_text()
    calls = [line.strip()[len("if ("):] for line in text.splitlines()
             if line.strip().startswith("if (ecatcfg_soe(")]
    assert calls[0] == ('ecatcfg_soe(context, slave, 0, 0x40, 32778, sizeof data, data, '
                        '"SoE write P-0-0010 (drive 0) = fe 7f 00 00 00 00 00 00", error))')
    assert [c.split(", ")[2:5] for c in calls] == [
        ["0", "0x40", "32778"], ["1", "0x40", "32778"], ["0", "0x40", "1"],
        ["0", "0x40", "2"], ["0", "0x40", "32"], ["1", "0x40", "32"]]
    assert "static const uint8 data[] = { 0xD0, 0x07 };" in text
    build_c(soem_sources, source)


# -- every SoE device of the corpora --------------------------------------------------------

def _soe_devices(folder: Path) -> list[tuple[Path, object]]:
    out = []
    for path in sorted((folder / "esi").rglob("*.xml")):
        if b"<SoE" not in path.read_bytes():
            continue
        for device in read_esi(path).devices:
            soe = device.mailbox.soe if device.mailbox else None
            if soe is not None and soe.init_cmds:
                out.append((path, device))
    return out


def test_every_soe_device_of_the_corpora_compiles_with_its_init_cmds(
        tmp_path: Path, corpus: Path, corpus_extra: Path, eni_schema) -> None:
    found = _soe_devices(corpus) + _soe_devices(corpus_extra)
    # corpus-extra's Beckhoff AX5xxx.xml: 147 AX5000 devices with SoE InitCmds.
    assert len(found) >= 140
    for n, (path, device) in enumerate(found):
        folder = tmp_path / str(n)
        folder.mkdir()
        sel = f"0x{device.vendor.id:X}:0x{device.product_code:X}:0x{device.revision:X}"
        topo = write(folder, "t.yaml", f"slaves:\n  - name: drive\n    device: '{sel}'\n")
        plan = build.compile_topology(topology.load(topo),
                                      Library([path], cache=False)).plan
        esi_cmds = device.mailbox.soe.init_cmds
        cmds = soe_cmds(plan)
        # Every command of the file, IP ones first as PS, each with its IDN, drive, data.
        ip = [c for c in esi_cmds if "IP" in c.transitions]
        rest = [c for c in esi_cmds if "IP" not in c.transitions]
        assert [(c.idn, c.channel, c.data) for c in ip + rest] == \
            [(c.idn, c.drive_no, c.data) for c in cmds], (path.name, device.type_name)
        assert all(set(c.transitions) <= {PS, SO, Transition.SP, Transition.OP,
                                          Transition.OS} for c in cmds)
        data = eni_writer.to_bytes(plan)
        tree = etree.fromstring(data).getroottree()
        assert eni_schema.validate(tree), (device.type_name, eni_schema.error_log)
        assert len(tree.findall(".//Mailbox/SoE/InitCmds/InitCmd")) == len(esi_cmds)


def test_a_modules_soe_init_cmds_are_an_error_not_left_out(tmp_path: Path) -> None:
    """ETG.2000 gives a module's Mailbox CoE only; a file that gives one SoE InitCmds anyway
    (the reader takes a module's Mailbox as a device's) stops compile at the slave."""
    from conftest import EXAMPLES
    source = (EXAMPLES / "station" / "esi" / "ecatcfg-EXM-station.xml").read_text()
    old = "        </TxPdo>\n      </Module>"
    assert old in source
    soe = ("        </TxPdo>\n        <Mailbox><SoE><InitCmd><Transition>PS</Transition>"
           "<IDN>1</IDN><Data>e803</Data></InitCmd></SoE></Mailbox>\n      </Module>")
    folder = tmp_path / "esi"
    folder.mkdir()
    write(folder, "station.xml", source.replace(old, soe, 1))
    errors = compile_errors(tmp_path, "slaves:\n  - name: station\n    device: EXM100\n"
                            "    modules:\n      1: [EXM-4DI]\n", folder)
    assert [e for e in errors if "has SoE InitCmds" in e and
            "which ETG.2000 gives devices only; ecatcfg would not send them" in e
            and f"{tmp_path / 't.yaml'}:4:" in e], errors
