"""``ecatcfg diff``: two ENIs (ours, EC-Engineer's, TwinCAT's) or two topologies compared by
what they make the master do.  The edits below are made with lxml on real files; expected
offsets and values are read from the edited XML, not from our reader."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
from lxml import etree

from conftest import write
from ecatcfg.cli import main

ELMO_ESI = "esi/drives/Elmo_ECAT_00010420_V11.xml"
ELMO_ENI = "eni/rocos-ethercat/eni.xml"               # EC-Engineer
MEGA_ENI = "eni/jn-ec-master/mega_master_eni.xml"     # TwinCAT
DRIVE = "Slave_1001 [Elmo Drive ]"

ELMO = f"""
master: {{name: rocos, cycle_time_us: 1000}}
slaves:
  - name: "{DRIVE}"
    device: "0x9a:0x30924:0x10420"
    rx_pdos: [0x160A, 0x160B, 0x160C, 0x160F, 0x161C]
    tx_pdos: [0x1A0A, 0x1A0E, 0x1A11, 0x1A13, 0x1A1D]
    dc: DC Sync
    sdos:
      - {{index: 0x6060, value: 8}}
      - {{index: 0x60C2, subindex: 1, value: 1}}
"""

MEGA = """
master: {name: mega, layout: lrd_lwr}
slaves:
  - {name: "Term 1 (EK1100)", device: "2:0x044c2c52:0x00120000"}
  - {name: "Term 2 (EL2008)", device: "2:0x07d83052:0x00120000"}
  - {name: "Term 4 (EL1809)", device: "2:0x07113052:0x00120000", station_address: 1004}
"""


def _diff(capsys, a: Path, b: Path) -> tuple[int, list[dict]]:
    code = main(["diff", str(a), str(b), "--format", "json"])
    out = json.loads(capsys.readouterr().out)
    assert out["equal"] == (code == 0) and out["kind"] in ("eni", "topology")
    return code, out["changes"]


def _compile(tmp_path: Path, capsys, text: str, esi: Path) -> Path:
    eni = tmp_path / "ours.xml"
    assert main(["compile", str(write(tmp_path, "t.yaml", text)), "--esi", str(esi),
                 "-o", str(eni)]) == 0
    capsys.readouterr()
    return eni


def _tree(path: Path) -> etree._ElementTree:
    return etree.parse(str(path))


def _save(tree: etree._ElementTree, path: Path) -> Path:
    tree.write(str(path), xml_declaration=True, encoding="utf-8")
    return path


def test_compiled_elmo_against_ec_engineer_has_only_the_watchdogs(tmp_path, capsys, corpus):
    """The same drive, PDOs, DC mode and SDOs compiled by us: the one real difference is the
    three watchdog writes EC-Engineer adds for drives (we write none without the
    topology's ``watchdog:``; the ESI gives no values)."""
    ours = _compile(tmp_path, capsys, ELMO, corpus / ELMO_ESI)
    code, changes = _diff(capsys, corpus / ELMO_ENI, ours)
    assert code == 1
    assert sorted((c["kind"], c["slave"], c["transition"], c["what"], c["old"])
                  for c in changes) == [
        ("initcmd-removed", DRIVE, "IP", "0x0400", "set watchdog divider 2498 (100000 ns)"),
        ("initcmd-removed", DRIVE, "IP", "0x0410",
         "set PDI watchdog 1000 (100 ms at the default divider)"),
        ("initcmd-removed", DRIVE, "IP", "0x0420",
         "set SM watchdog 10000 (1000 ms at the default divider)"),
    ]


def test_compiled_beckhoff_line_against_twincat_names_each_difference(tmp_path, capsys,
                                                                      corpus):
    """TwinCAT's file has an EL4002 we cannot compile (its ESI revision is not in the
    corpus), I->B/B->I commands for terminals without a bootstrap mailbox, a frame-shaped
    process image with its own diagnostic variables, a renamed variable, BIT for one-bit
    variables and no cycle time: each shows as its own difference, nothing else does."""
    ours = _compile(tmp_path, capsys, MEGA, corpus / "esi/beckhoff")
    code, changes = _diff(capsys, corpus / MEGA_ENI, ours)
    assert code == 1
    ref = _tree(corpus / MEGA_ENI)
    theirs = {v.findtext("Name"): int(v.findtext("BitOffs"))
              for v in ref.iter("Variable")}
    ours_vars = {v.findtext("Name"): int(v.findtext("BitOffs"))
                 for v in _tree(ours).iter("Variable")}
    kinds: dict[str, list[dict]] = {}
    for c in changes:
        kinds.setdefault(c["kind"], []).append(c)
    assert set(kinds) == {"slave-removed", "slave-moved", "initcmd-removed",
                          "initcmd-changed", "variable-removed", "variable-added",
                          "image-moved", "cycle-time", "frames"}
    assert [(c["slave"]) for c in kinds["slave-removed"]] == ["Term 3 (EL4002)"]
    assert [(c["slave"], c["old"], c["new"]) for c in kinds["slave-moved"]] == [
        ("Term 4 (EL1809)", "position 3", "position 2")]
    # Boot transitions only: the terminals have no bootstrap mailbox.
    assert {c["transition"] for c in kinds["initcmd-removed"]} == {"IB", "BI"}
    # The EL2008's output FMMU: after the EL4002 in TwinCAT's window, at its start in ours.
    assert [(c["slave"], c["what"]) for c in kinds["initcmd-changed"]] == [
        ("Term 2 (EL2008)", "fmmu 0")]
    assert "0x01000004.0" in kinds["initcmd-changed"][0]["old"]
    # Variables: every one of TwinCAT's that we lack, the renamed ones, and every moved
    # one with TwinCAT's and our offsets as the files give them.
    removed = {c["what"].split(" ", 1)[1] for c in kinds["variable-removed"]}
    assert removed == set(theirs) - set(ours_vars)
    added = {c["what"].split(" ", 1)[1] for c in kinds["variable-added"]}
    assert added == set(ours_vars) - set(theirs) == {
        "Term 4 (EL1809).Channel 1.Input", "Term 2 (EL2008).Channel 1.Output"}
    # Every variable both files have sits at another place, each direction shifted as one
    # (TwinCAT's frame-shaped image against our compact one): one line per direction, with
    # the count and the shift the files give, instead of 22 variable-moved lines.
    shifts = {}
    for direction, tag in (("in", "Inputs"), ("out", "Outputs")):
        def offsets(tree: etree._ElementTree) -> dict[str, int]:
            return {v.findtext("Name"): int(v.findtext("BitOffs"))
                    for v in tree.iterfind(f".//ProcessImage/{tag}/Variable")}
        a, b = offsets(ref), offsets(_tree(ours))
        moved = {(b[n] - a[n]) for n in set(a) & set(b)}
        assert len(moved) == 1 and 0 not in moved
        shifts[direction] = (len(set(a) & set(b)), moved.pop())
    assert sum(n for n, _ in shifts.values()) == 22
    assert [(c["what"], c["new"]) for c in kinds["image-moved"]] == [
        (f"{d}: all {n} variables", f"moved by -{-bits // 8} bytes")
        for d, (n, bits) in shifts.items()]
    assert [(c["old"], c["new"]) for c in kinds["cycle-time"]] == [("none", "1000")]


def test_a_shifted_image_is_one_line_and_the_real_moves_follow(tmp_path, capsys, corpus):
    """The whole output image moved by 56 bytes (another tool's image base), and one of its
    variables by 2 bytes more: one ``image-moved`` line for all but one, then that one with
    both offsets.  Then one slave's inputs moved together: one ``variables-moved`` line."""
    tree = _tree(corpus / MEGA_ENI)
    size = tree.find(".//ProcessImage/Outputs/ByteSize")
    size.text = str(int(size.text) + 58)              # room for the moved variables
    outputs = tree.findall(".//ProcessImage/Outputs/Variable")
    for v in outputs:
        v.find("BitOffs").text = str(int(v.findtext("BitOffs")) + 56 * 8)
    odd = outputs[1]
    old = int(odd.findtext("BitOffs")) - 56 * 8
    odd.find("BitOffs").text = str(old + 58 * 8)
    code, changes = _diff(capsys, corpus / MEGA_ENI, _save(tree, tmp_path / "shifted.xml"))
    assert code == 1
    assert changes == [
        {"kind": "image-moved", "slave": None, "transition": None,
         "what": f"out: {len(outputs) - 1} of {len(outputs)} variables", "old": None,
         "new": "moved by +56 bytes"},
        {"kind": "variable-moved", "slave": None, "transition": None,
         "what": f"out {odd.findtext('Name')}", "old": f"{old // 8}.{old % 8}",
         "new": f"{old // 8 + 58}.{old % 8}"}]
    # One slave's inputs, each moved by 3 bits: the slave's line, nothing else.
    tree = _tree(corpus / MEGA_ENI)
    slave = "Term 4 (EL1809)"
    mine = [v for v in tree.iterfind(".//ProcessImage/Inputs/Variable")
            if v.findtext("Name").startswith(slave + ".")]
    assert len(mine) >= 2
    for v in mine:
        v.find("BitOffs").text = str(int(v.findtext("BitOffs")) + 3)
    code, changes = _diff(capsys, corpus / MEGA_ENI, _save(tree, tmp_path / "slave.xml"))
    assert changes == [{"kind": "variables-moved", "slave": slave, "transition": None,
                        "what": f"in: all {len(mine)} variables", "old": None,
                        "new": "moved by +3 bits"}]


def test_an_identical_copy_and_a_reworded_one_are_equal(tmp_path, capsys, corpus):
    """Comments and the order of a transition's register commands are not differences."""
    copy_path = _save(_tree(corpus / ELMO_ENI), tmp_path / "copy.xml")
    assert _diff(capsys, corpus / ELMO_ENI, copy_path) == (0, [])
    tree = _tree(corpus / ELMO_ENI)
    for comment in tree.iter("Comment"):
        comment.text = "changed by hand"
    init_cmds = tree.find(".//Slave/InitCmds")
    second = init_cmds[1]
    init_cmds.remove(second)
    init_cmds.insert(0, second)
    assert _diff(capsys, corpus / ELMO_ENI, _save(tree, tmp_path / "reworded.xml")) == (0, [])
    assert main(["diff", str(corpus / ELMO_ENI), str(copy_path)]) == 0
    assert capsys.readouterr().out == "no differences\n"


def test_a_moved_variable_is_found_with_both_offsets(tmp_path, capsys, corpus):
    tree = _tree(corpus / ELMO_ENI)
    var = tree.find(".//ProcessImage/Outputs/Variable[2]")
    name, old = var.findtext("Name"), int(var.findtext("BitOffs"))
    var.find("BitOffs").text = str(old + 24)
    code, changes = _diff(capsys, corpus / ELMO_ENI, _save(tree, tmp_path / "moved.xml"))
    assert code == 1
    assert changes == [{"kind": "variable-moved", "slave": None, "transition": None,
                        "what": f"out {name}", "old": f"{old // 8}.{old % 8}",
                        "new": f"{(old + 24) // 8}.{(old + 24) % 8}"}]


def test_a_changed_sdo_is_found_in_words(tmp_path, capsys, corpus):
    tree = _tree(corpus / ELMO_ENI)
    cmd = next(c for c in tree.iter("InitCmd") if c.findtext("Index") == str(0x6060))
    assert cmd.findtext("Data") == "08"
    cmd.find("Data").text = "09"
    code, changes = _diff(capsys, corpus / ELMO_ENI, _save(tree, tmp_path / "sdo.xml"))
    assert code == 1
    assert changes == [{"kind": "initcmd-changed", "slave": DRIVE, "transition": "PS",
                        "what": "0x6060:00", "old": "SDO 0x6060:00 = 8",
                        "new": "SDO 0x6060:00 = 9"}]
    main(["diff", str(corpus / ELMO_ENI), str(tmp_path / "sdo.xml")])
    assert "initcmd-changed  'Slave_1001 [Elmo Drive ]' PS: 0x6060:00: SDO 0x6060:00 = 8 " \
           "-> SDO 0x6060:00 = 9" in capsys.readouterr().out


def _pdo_assignment_as_complete_access(corpus: Path, keep_clear: bool,
                                       pdos: list[int]) -> etree._ElementTree:
    """The EC-Engineer file with its subindex-by-subindex 0x1C12 assignment replaced by one
    CompleteAccess download of ``pdos`` (count, pad byte, entries; ETG.1000.6), after the
    clearing of 0x1C12:00 (EC-Engineer's way) or without it (TwinCAT's)."""
    tree = _tree(corpus / ELMO_ENI)
    cmds = [c for c in tree.iter("InitCmd") if c.findtext("Index") == str(0x1C12)]
    clear, writes = cmds[0], cmds[1:]
    assert (clear.findtext("SubIndex"), clear.findtext("Data")) == ("0", "00")
    ca = copy.deepcopy(writes[-1])
    ca.set("CompleteAccess", "1")
    ca.find("SubIndex").text = "0"
    ca.find("Data").text = bytes([len(pdos), 0]).hex() + "".join(
        p.to_bytes(2, "little").hex() for p in pdos)
    writes[-1].addnext(ca)
    for c in writes + ([] if keep_clear else [clear]):
        c.getparent().remove(c)
    return tree


@pytest.mark.parametrize("keep_clear", [True, False], ids=["ec-engineer", "twincat"])
def test_complete_access_spelling_of_the_same_assignment_is_no_difference(
        tmp_path, capsys, corpus, keep_clear):
    reference = _tree(corpus / ELMO_ENI)
    pdos = [int.from_bytes(bytes.fromhex(c.findtext("Data")), "little")
            for c in reference.iter("InitCmd")
            if c.findtext("Index") == str(0x1C12) and c.findtext("SubIndex") != "0"]
    assert len(pdos) == 5
    tree = _pdo_assignment_as_complete_access(corpus, keep_clear, pdos)
    assert _diff(capsys, corpus / ELMO_ENI, _save(tree, tmp_path / "ca.xml")) == (0, [])


def test_a_complete_access_assignment_of_other_pdos_is_a_difference(tmp_path, capsys,
                                                                    corpus):
    tree = _pdo_assignment_as_complete_access(corpus, True, [0x160A, 0x160B])
    code, changes = _diff(capsys, corpus / ELMO_ENI, _save(tree, tmp_path / "ca.xml"))
    assert code == 1
    assert changes == [{
        "kind": "initcmd-changed", "slave": DRIVE, "transition": "PS", "what": "0x1C12",
        "old": "SDO 0x1C12 = 5: 0x160A, 0x160B, 0x160C, 0x160F, 0x161C",
        "new": "SDO 0x1C12 = 2: 0x160A, 0x160B"}]


def test_slaves_removed_moved_and_identity(tmp_path, capsys, corpus):
    tree = _tree(corpus / MEGA_ENI)
    config = tree.find("Config")
    slaves = config.findall("Slave")
    config.remove(slaves[2])                               # the EL4002
    slaves[3].find("Info/ProductCode").text = "#x07113053"
    assert slaves[3].findtext("Info/AutoIncAddr") == str(0x10000 - 3)
    slaves[3].find("Info/AutoIncAddr").text = str(0x10000 - 2)      # one place up
    code, changes = _diff(capsys, corpus / MEGA_ENI, _save(tree, tmp_path / "edited.xml"))
    assert code == 1
    found = [(c["kind"], c["slave"], c["old"], c["new"]) for c in changes
             if c["kind"] in ("slave-removed", "slave-moved", "identity")]
    assert found == [
        ("slave-removed", "Term 3 (EL4002)", "position 2", None),
        ("slave-moved", "Term 4 (EL1809)", "position 3", "position 2"),
        ("identity", "Term 4 (EL1809)", "0x00000002:0x07113052:0x00120000",
         "0x00000002:0x07113053:0x00120000")]


TOPOLOGY = """
# a line
master: {name: m, cycle_time_us: 1000}
slaves:
  - name: coupler
    device: EK1100
  - name: out
    device: "2:0x07d83052"
    rx_pdos: [0x1600, 0x1601]
    sdos: [{index: 0x8000, subindex: 1, value: 1}]
"""

SAME_TOPOLOGY = """
slaves:
  - {device: EK1100, name: coupler}   # same, other spelling and order
  - {name: out, rx_pdos: [5632, "#x1601"], device: "2:0x07d83052",
     sdos: [{subindex: 1, index: 32768, value: 1}]}
master: {cycle_time_us: 1000, name: m}
"""

OTHER_TOPOLOGY = """
master: {name: m, cycle_time_us: 2000}
slaves:
  - name: out
    device: "2:0x07d83052"
    rx_pdos: [0x1600]
    sdos: [{index: 0x8000, subindex: 1, value: 2}]
  - name: coupler
    device: EK1110
"""


def test_topologies(tmp_path, capsys):
    a = write(tmp_path, "a.yaml", TOPOLOGY)
    assert _diff(capsys, a, write(tmp_path, "same.yaml", SAME_TOPOLOGY)) == (0, [])
    code, changes = _diff(capsys, a, write(tmp_path, "other.yaml", OTHER_TOPOLOGY))
    assert code == 1
    assert sorted((c["kind"], c["slave"], c["what"], c["old"], c["new"])
                  for c in changes) == [
        ("identity", "coupler", "device", "EK1100", "EK1110"),
        ("master-setting", None, "cycle_time_us", "1000", "2000"),
        ("slave-moved", "coupler", "place", "position 0", "position 1"),
        ("slave-moved", "out", "place", "position 1", "position 0"),
        ("slave-setting", "out", "rx_pdos", "[0x1600, 0x1601]", "[0x1600]"),
        ("slave-setting", "out", "sdos", "[{index: 0x8000, subindex: 1, value: 1, transition: PS, "
         "complete_access: false}]", "[{index: 0x8000, subindex: 1, value: 2, transition: PS, "
         "complete_access: false}]")]


def test_inputs_of_different_kinds_are_a_usage_error(tmp_path, capsys, corpus):
    a = write(tmp_path, "a.yaml", TOPOLOGY)
    assert main(["diff", str(a), str(corpus / ELMO_ENI)]) == 2
    assert "two ENIs or two topologies" in capsys.readouterr().err
    bad = write(tmp_path, "bad.xml", "<?xml version='1.0'?>\n<Other/>")
    assert main(["diff", str(bad), str(bad)]) == 1
    assert f"{bad}:1: root element <Other>" in capsys.readouterr().err


def test_two_exports_of_one_drive_at_1_and_4_ms(capsys, corpus):
    """Two exports of one Yaskawa drive from another tool, at 1 ms and 4 ms: the cycle time
    in 0x09A0 and in DC/CycleTime0, the interpolation period 0x60C2:01, and one change the
    corpus notes do not list: the 4 ms file also clears the DC activation (0x0980) in I->P.
    The values are read here from both files."""
    folder = corpus / "eni/acontis-ecmaster-demo-motion"
    a, b = folder / "Yaskawa_SGDV_1ms.xml", folder / "Yaskawa_SGDV_4ms.xml"
    code, changes = _diff(capsys, a, b)
    assert code == 1

    def read(path: Path) -> tuple[int, int, int, list[list[str]]]:
        slave = _tree(path).find("Config/Slave")
        sync0 = next(int.from_bytes(bytes.fromhex(ic.findtext("Data"))[:4], "little")
                     for ic in slave.find("InitCmds") if ic.findtext("Ado") == str(0x09A0))
        period = next(int(ic.findtext("Data"), 16) for ic in slave.iter("InitCmd")
                      if (ic.findtext("Index"), ic.findtext("SubIndex")) == (str(0x60C2), "1"))
        clears = [[t.text for t in ic.findall("Transition")] for ic in slave.find("InitCmds")
                  if ic.findtext("Ado") == str(0x0980) and ic.findtext("Data") == "0000"]
        return sync0, period, int(slave.findtext("DC/CycleTime0")), clears

    (sync_a, period_a, dc_a, clears_a), (sync_b, period_b, dc_b, clears_b) = read(a), read(b)
    assert (sync_a, sync_b, dc_a, dc_b) == (1_000_000, 4_000_000, 1_000_000, 4_000_000)
    assert ["IP"] == [t for c in clears_b for t in c if t not in {x for c in clears_a
                                                                  for x in c}]
    drive = "Drive 1 (SGDV-E1 CoE Drive)"
    assert sorted((c["kind"], c["transition"], c["what"], c["old"], c["new"])
                  for c in changes) == sorted([
        ("initcmd-added", "IP", "0x0980", None, "clear DC activation"),
        ("initcmd-changed", "PS", "0x09A0", f"set SYNC0 cycle {sync_a} ns, SYNC1 cycle 0 ns",
         f"set SYNC0 cycle {sync_b} ns, SYNC1 cycle 0 ns"),
        ("initcmd-changed", "PS", "0x60C2:01", f"SDO 0x60C2:01 = {period_a}",
         f"SDO 0x60C2:01 = {period_b}"),
        ("dc", None, "DC", f"reference clock, cycle {dc_a} ns, shift 0 ns",
         f"reference clock, cycle {dc_b} ns, shift 0 ns")])
    assert {c["slave"] for c in changes} == {drive}


VOE = ("<VoE><InitCmds>" + "".join(
    f"<InitCmd><Transition>PS</Transition><Comment>VoE {i}</Comment><Timeout>1000</Timeout>"
    "<Data>0100</Data></InitCmd>" for i in range(2)) + "</InitCmds></VoE>")


def test_parts_apply_does_not_do_are_compared_and_shown(tmp_path, capsys, corpus):
    """VoE InitCmds (which apply refuses unless told to skip them) added to a drive: diff
    names them, and show lists them with their line, rather than passing over them."""
    tree = _tree(corpus / ELMO_ENI)
    tree.find(".//Slave/Mailbox").append(etree.fromstring(VOE))
    edited = _save(tree, tmp_path / "voe.xml")
    line = _tree(edited).find(".//Slave/Mailbox/VoE").sourceline
    code, changes = _diff(capsys, corpus / ELMO_ENI, edited)
    assert code == 1
    assert changes == [{"kind": "unsupported-added", "slave": DRIVE, "transition": None,
                        "what": "Slave/Mailbox/VoE: VoE InitCmds (vendor-specific mailbox "
                                "messages)",
                        "old": None,
                        "new": "2 command(s)"}]
    assert main(["show", str(edited), "--format", "json", "--no-cache"]) == 0
    assert json.loads(capsys.readouterr().out)["unsupported"] == [
        {"slave": DRIVE, "element": "Slave/Mailbox/VoE",
         "what": "VoE InitCmds (vendor-specific mailbox messages)",
         "line": line, "commands": 2}]
    assert main(["show", str(edited), "--no-cache"]) == 0
    assert f"VoE InitCmds (vendor-specific mailbox messages) (2 commands) at line {line}" \
        in capsys.readouterr().out


def test_the_masters_own_init_cmds_are_compared(tmp_path, capsys, corpus):
    tree = _tree(corpus / ELMO_ENI)
    cmd = next(c for c in tree.find("Config/Master/InitCmds")
               if c.findtext("Ado") == str(0x0200))
    old = cmd.findtext("Data")
    cmd.find("Data").text = "0000"
    code, changes = _diff(capsys, corpus / ELMO_ENI, _save(tree, tmp_path / "master.xml"))
    assert code == 1
    value = int.from_bytes(bytes.fromhex(old), "little")
    assert changes == [{"kind": "initcmd-changed", "slave": None, "transition": "IP",
                        "what": "master 0x0200",
                        "old": f"set ECAT event mask = 0x{value:04X}",
                        "new": "set ECAT event mask = 0x0000"}]


def test_topologies_with_esi_compare_the_devices_selected(tmp_path, capsys):
    """Two spellings of one device are a difference as written, none with --esi (the
    selectors resolved as the compiler resolves them); an unknown one is an error at its
    line."""
    from conftest import EXAMPLES
    a = write(tmp_path, "a.yaml", "slaves:\n  - {name: axis, device: EXD-402}\n")
    b = write(tmp_path, "b.yaml", 'slaves:\n  - {name: axis, device: "0xE0000ECA:0x7201"}\n')
    code, changes = _diff(capsys, a, b)
    assert (code, [(c["kind"], c["what"]) for c in changes]) == (1, [("identity", "device")])
    esi = ["--esi", str(EXAMPLES / "esi")]
    assert main(["diff", str(a), str(b), *esi]) == 0
    assert capsys.readouterr().out == "no differences\n"
    c = write(tmp_path, "c.yaml", "slaves:\n  - {name: axis, device: EX1004}\n")
    assert main(["diff", str(a), str(c), *esi, "--format", "json"]) == 1
    assert [(ch["old"], ch["new"]) for ch in json.loads(capsys.readouterr().out)["changes"]] \
        == [("EXD-402 (0xe0000eca:0x7201:0x20000)", "EX1004 (0xe0000eca:0x2004:0x10000)")]
    bad = write(tmp_path, "bad.yaml", "slaves:\n  - name: axis\n    device: NOPE\n")
    assert main(["diff", str(a), str(bad), *esi]) == 1
    err = capsys.readouterr().err
    assert f"{bad}:3: " in err and "NOPE" in err and "Traceback" not in err
