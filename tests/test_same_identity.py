"""Same-identity ESI files chosen by evidence (docs/compile.md, "Which ESI file describes a
device"): where several files describe one vendor, product and revision differently and the
user has not chosen, the description that agrees with what the ENI says of the slave (its
PDOs, SyncManagers, mailbox) is taken, and said; where none or several agree, the command
stops naming the files and what differs.

Self-written files (tests/fixtures/same-identity: four descriptions of EXD4400 with four
PDO sets, and a partial ENI of one of them); which file the ENI fits is worked out here
from the XML with lxml, not by the code under test.  Then the HBM GEN DAQ of corpus-extra
and its three ENIs, paired as the corpus MANIFEST says.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from conftest import FIXTURES
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni.evidence import EniSlaveEvidence
from ecatcfg.esc import AlState
from ecatcfg.esi.evidence import SiiEvidence
from ecatcfg.esi.library import DuplicateError, Library
from ecatcfg.esi.sii import build, decode
from ecatcfg.runtime import Network

HERE = FIXTURES / "same-identity"
ESIS = sorted(p for p in HERE.glob("*.xml") if p.name != "eni.xml")
SELECTOR = "0xE0000ECA:0x4400:0x10000"


def ecatcfg(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def _number(text: str) -> int:
    text = text.strip()
    return int(text[2:], 16) if text[:2] in ("#x", "#X") else int(text, 0)


def _pdo_set(element: etree._Element) -> set[tuple[str, int, tuple[tuple[int, int, int], ...]]]:
    """Each RxPdo/TxPdo under ``element``: kind, index and entries (index, subindex, bits)."""
    return {(p.tag, _number(p.findtext("Index")),
             tuple((_number(e.findtext("Index")), _number(e.findtext("SubIndex")),
                    _number(e.findtext("BitLen"))) for e in p.iterfind("Entry")))
            for p in element if p.tag in ("RxPdo", "TxPdo")}


def _device(path: Path) -> etree._Element:
    [device] = etree.parse(str(path)).xpath("//Descriptions/Devices/Device")
    return device


def _where(path: Path, shown: str | None = None) -> str:
    return f"{shown or path}:{_device(path).sourceline}"


def _fitting(eni: Path) -> list[Path]:
    """The fixture ESIs whose PDO set is the ENI's slave's, by lxml."""
    [pd] = etree.parse(str(eni)).xpath("//Config/Slave/ProcessData")
    return [p for p in ESIS if _pdo_set(_device(p)) == _pdo_set(pd)]


def test_the_fixtures_are_four_descriptions_of_one_identity_that_one_eni_fits():
    """The premise, from the XML alone: four files, one identity, four PDO sets, and the
    ENI's PDO set is exactly one of them."""
    assert len(ESIS) == 4
    identities = {(_device(p).find("Type").get("ProductCode"),
                   _device(p).find("Type").get("RevisionNo")) for p in ESIS}
    assert len(identities) == 1
    assert len({frozenset(_pdo_set(_device(p))) for p in ESIS}) == 4
    assert [p.name for p in _fitting(HERE / "eni.xml")] == ["vendor-build-2.xml"]


def test_apply_virtual_reaches_op_with_the_description_the_eni_agrees_with():
    [right] = _fitting(HERE / "eni.xml")
    run = ecatcfg("apply", HERE / "eni.xml", "--virtual", "--esi", HERE, "--simulated-time",
                  "--cycles", "3", "--format", "json", "--no-cache")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    [row] = report["slaves"]
    assert row["highest_state"] == "OP" and row["emulated_from"] == "esi"
    assert row["esi"] == _where(right, str(HERE / right.name))
    why = row["esi_choice"]
    assert f"took {_where(right)}: the only description that agrees with the ENI's slave " \
           f"'Box 1 (EXD4400)' ({HERE / 'eni.xml'})" in why
    for other in ESIS:
        if other != right:
            assert f"{_where(other)}: " in why      # each other file, with what disagrees
    # vendor-build-1.xml has TxPdo 0x1A00 alone: it lacks the ENI's 0x1A01.
    assert f"{_where(HERE / 'vendor-build-1.xml')}: the ENI's TxPdo 0x1A01 not in it" in why
    assert any(why in e for e in report["events"])
    # The text output says it too.
    text = ecatcfg("apply", HERE / "eni.xml", "--virtual", "--esi", HERE, "--simulated-time",
                   "--cycles", "3", "--no-cache")
    assert text.returncode == 0, text.stderr
    words = " ".join((text.stdout + text.stderr).split())
    assert f"took {_where(right)}: the only description that agrees with" in words


def test_network_virtual_says_the_choice_in_an_event():
    events = []
    net = Network.virtual(HERE / "eni.xml", [HERE], esi_cache=False, on_event=events.append)
    try:
        net.up(AlState.OP)
        net.run(10)
        assert net.master.state == AlState.OP
        net.down()
    finally:
        net.close()
    [said] = [e.text for e in events if e.kind == "esi"]
    assert said.startswith("slave 'Box 1 (EXD4400)' (position 0): 0xe0000eca:0x4400:0x10000 "
                           "(EXD4400) is described differently by 4 ESI files; took "
                           f"{_where(HERE / 'vendor-build-2.xml')}")
    [(esi, why)] = net.esi_sources
    assert esi == _where(HERE / "vendor-build-2.xml") and why is not None and why in said
    # What a refusal's cause is compared with (runtime/master/diagnose.py looks the
    # device up by the identity the slave reports): the same file, by the ENI's evidence.
    exact, _, note = net.master.esi.entry_for_identity(0xE0000ECA, 0x4400, 0x10000)
    assert exact is not None and exact.file == str(HERE / "vendor-build-2.xml")
    assert note == why


def _variant(tmp_path: Path, change) -> Path:
    """The fixture ENI with one change made by lxml."""
    tree = etree.parse(str(HERE / "eni.xml"))
    change(tree.getroot())
    out = tmp_path / "eni.xml"
    tree.write(str(out), xml_declaration=True, encoding="UTF-8")
    return out


def _renumber_counter_pdo(root: etree._Element) -> None:
    [index] = root.xpath("//TxPdo[Index='#x1a01']/Index")
    index.text = "#x1a03"
    [assigned] = root.xpath("//Sm3/Pdo[text()='#x1a01']")
    assigned.text = "#x1a03"


def test_an_eni_no_description_fits_is_refused_naming_the_differences(tmp_path: Path):
    eni = _variant(tmp_path, _renumber_counter_pdo)
    assert _fitting(eni) == []
    run = ecatcfg("apply", eni, "--virtual", "--esi", HERE, "--simulated-time", "--cycles", "3",
                  "--no-cache")
    assert run.returncode == 1
    err = " ".join(run.stderr.split())
    assert f"{eni}: slave 'Box 1 (EXD4400)': 0xe0000eca:0x4400:0x10000 (EXD4400) is " \
           "described differently by 4 ESI files: " in err, err
    assert f"none agrees with the ENI's slave 'Box 1 (EXD4400)' ({eni})" in err
    for f in ESIS:
        assert f"{_where(f)}: the ENI's TxPdo 0x1A03 not in it" in err
    assert "--prefer FILE_OR_FOLDER" in err and "Traceback" not in err
    # --prefer still decides (the user's choice), and the note says it does not agree.
    right = HERE / "vendor-build-2.xml"
    chosen = ecatcfg("apply", eni, "--virtual", "--esi", HERE, "--prefer", right,
                     "--simulated-time", "--cycles", "3", "--no-cache", "--format", "json")
    assert chosen.returncode == 0, chosen.stderr
    [row] = json.loads(chosen.stdout)["slaves"]
    assert row["highest_state"] == "OP" and row["esi"] == _where(right)
    assert f"(--prefer {right})" in row["esi_choice"]
    assert row["esi_choice"].endswith(
        f"; it does not agree with the ENI's slave 'Box 1 (EXD4400)' ({eni}): the ENI's "
        "TxPdo 0x1A03 not in it, PDO 0x1A01 (assigned to SM3 by default) not in the ENI")


@pytest.mark.parametrize("change, said", [
    (lambda r: setattr(r.find(".//Mailbox/Send/Start"), "text", "#x1800"),
     "Mailbox/Send start 0x1800, SM0's 0x1000"),
    (lambda r: setattr(r.find(".//Mailbox/Recv/Length"), "text", "64"),
     "Mailbox/Recv length 64, SM1 takes 128"),
    (lambda r: r.find(".//Mailbox").append(etree.fromstring("<Protocol>FoE</Protocol>")),
     "the ENI's mailbox protocol FoE not among its CoE"),
    (lambda r: setattr(r.find(".//Sm3/StartAddress"), "text", "#x1400"),
     "SM3 is Inputs at 0x1180, the ENI's Inputs at 0x1400"),
    (lambda r: setattr(r.find(".//TxPdo/Entry/BitLen"), "text", "16"),
     "TxPdo 0x1A00 entries differ from the ENI's"),
    (lambda r: r.find(".//Sm3").remove(r.find(".//Sm3/Pdo[2]")),
     "PDO 0x1A01 assigned to SM3 by default, not by the ENI (which writes no 0x1C13)"),
], ids=["mailbox-start", "mailbox-length", "protocol", "sm-start", "entries", "assignment"])
def test_each_part_of_the_evidence_tells(tmp_path: Path, change, said):
    """What makes the one fitting description disagree: each rule of eni/evidence.py."""
    eni = _variant(tmp_path, change)
    [slave] = eni_reader.read_file(eni).slaves
    lib = Library([HERE], cache=False)
    right = next(e for e in lib.entries if e.file.endswith("vendor-build-2.xml"))
    assert EniSlaveEvidence(slave, str(eni)).disagreements(lib.device(right)) == [said]
    unchanged = eni_reader.read_file(HERE / "eni.xml").slaves[0]
    assert EniSlaveEvidence(unchanged, "eni.xml").disagreements(lib.device(right)) == []


def test_several_descriptions_that_agree_ask_naming_what_would_decide(tmp_path: Path):
    """A fifth file with vendor-build-2's PDOs but DC op modes: the ENI (no DC) does not
    tell the two apart; the error names both and what differs between them."""
    folder = tmp_path / "esi"
    folder.mkdir()
    for f in ESIS:
        (folder / f.name).write_bytes(f.read_bytes())
    text = (HERE / "vendor-build-2.xml").read_text()
    dc = ("<Dc><OpMode><Name>DcSync</Name><Desc>DC</Desc><AssignActivate>#x300"
          "</AssignActivate></OpMode></Dc>\n        <Eeprom>")
    (folder / "with-dc.xml").write_text(text.replace("<Eeprom>", dc, 1))
    lib = Library([folder], cache=False)
    [slave] = eni_reader.read_file(HERE / "eni.xml").slaves
    with pytest.raises(DuplicateError) as asked:
        lib.find(SELECTOR, evidence=EniSlaveEvidence(slave, "eni.xml"))
    text = asked.value.message
    a, b = folder / "vendor-build-2.xml", folder / "with-dc.xml"
    assert (f"2 of them agree with the ENI's slave 'Box 1 (EXD4400)' (eni.xml): "
            f"{_where(a)}, {_where(b)}, which differ in what it does not say "
            f"({_where(b)} vs {_where(a)}: ") in text, text
    assert "Dc" in text.split("which differ in what it does not say")[1]


def test_check_uses_the_chosen_description():
    """check --esi: the note says which file; the device rules run against it (project-b's
    Mandatory TxPdo 0x1A02 would be reported as not assigned)."""
    run = ecatcfg("check", HERE / "eni.xml", "--esi", HERE, "--no-cache", "--format", "json")
    findings = json.loads(run.stdout)
    rules = {f["rule"] for f in _findings(findings)}
    assert "ENI002" not in rules and "ENI201" not in rules, findings
    assert f"took {_where(HERE / 'vendor-build-2.xml')}: the only description that agrees" \
        in " ".join(run.stderr.split())
    wrong = ecatcfg("check", HERE / "eni.xml", "--esi", HERE, "--no-cache", "--format",
                    "json", "--prefer", HERE / "project-b.xml")
    messages = [f["message"] for f in _findings(json.loads(wrong.stdout))]
    assert any("TxPdo 0x1A02" in m and "Mandatory" in m and "project-b.xml" in m
               for m in messages), messages


def test_report_says_which_description_its_check_took(tmp_path: Path):
    run = ecatcfg("report", HERE / "eni.xml", "--esi", HERE, "--no-cache", "-o",
                  tmp_path / "r.html")
    assert run.returncode == 0, run.stderr
    assert f"ecatcfg report: note: {HERE / 'eni.xml'}: 0xe0000eca:0x4400:0x10000 (EXD4400) " \
           "is described differently by 4 ESI files; took " \
           f"{_where(HERE / 'vendor-build-2.xml')}" in " ".join(run.stderr.split())


def test_simulate_eni_emulates_the_description_the_eni_agrees_with(veth_netns):
    """``simulate --eni --esi``: the note names the file and why; the slave list says the
    slave is emulated from its ESI."""
    from rig import start_simulate

    sim, lines = start_simulate(veth_netns, "--eni", str(HERE / "eni.xml"), "--esi",
                                str(HERE), duration=3)
    assert lines and lines[-1].startswith("ready:"), "".join(lines)
    _, err = sim.communicate(timeout=30)
    words = " ".join(err.split())
    assert "note: slave 'Box 1 (EXD4400)': 0xe0000eca:0x4400:0x10000 (EXD4400) is " \
           f"described differently by 4 ESI files; took {_where(HERE / 'vendor-build-2.xml')}" \
           ": the only description that agrees with the ENI's slave" in words, err


# -- a live line: the slave's SII ------------------------------------------------------------

def test_each_fixture_description_agrees_with_its_own_sii_alone():
    """The SII a device built from each file carries (what the emulated slave's EEPROM
    holds) agrees with that file and with no other: the PDO categories differ."""
    lib = Library([HERE], cache=False)
    for f in ESIS:
        mine = lib.device(next(e for e in lib.entries if e.file == str(f)))
        evidence = SiiEvidence(decode(build(mine)), "slave 0")
        fits = [e.file for e in lib.entries if not evidence.disagreements(lib.device(e))]
        assert fits == [str(f)]
        chosen = lib.find(SELECTOR, evidence=evidence)
        assert chosen.entry.file == str(f)
        assert "the only description that agrees with the SII of slave 0" in chosen.preferred


def test_scan_chooses_by_the_sii_read_from_the_slave(veth_netns):
    """``scan --esi`` on a line whose slave carries project-a.xml's SII: the scan reads
    the EEPROM and names project-a.xml, saying why; the other files are named with what
    their SII would have that the slave's has not."""
    from rig import serving

    from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

    lib = Library([HERE], cache=False)
    project_a = HERE / "project-a.xml"
    device = lib.device(lib.find(SELECTOR, within=lib.file_named(str(project_a))).entry)
    with serving(veth_netns, segment([SlaveSpec(device, "daq")])):
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "scan", "--esi", str(HERE), "--format", "json",
            "--no-cache", "--iface", veth_netns.if_a], timeout=60)
    assert done.returncode == 0, done.stderr
    [row] = json.loads(done.stdout)["slaves"]
    assert row["file"] == str(project_a) and row["line"] == _device(project_a).sourceline
    assert row["exact"]
    assert f"took {_where(project_a)}: the only description that agrees with the SII of " \
           "slave 0" in row["note"]
    # vendor-build-2.xml has TxPdo 0x1A01, which the slave's SII has not.
    assert f"{_where(HERE / 'vendor-build-2.xml')}: TxPdo 0x1A01 not in the slave's SII" \
        in row["note"]


def test_doctor_explains_a_refusal_with_the_description_the_sii_agrees_with(veth_netns):
    """``doctor --esi``: a slave of project-a.xml's SII refuses SAFEOP with 0x0030 (invalid
    DC SYNC configuration); the cause is compared with the ESI device: project-a.xml,
    named with why."""
    from rig import serving

    from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

    lib = Library([HERE], cache=False)
    project_a = HERE / "project-a.xml"
    device = lib.device(lib.find(SELECTOR, within=lib.file_named(str(project_a))).entry)
    seg = segment([SlaveSpec(device, "daq")])
    seg.slaves[0]._set_state(AlState.PREOP, 0x0030)      # the firmware's own decision
    with serving(veth_netns, seg):
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "doctor", "--esi", str(HERE), "--state",
            "safeop", "--no-cache", "--format", "json", "--iface", veth_netns.if_a],
            timeout=60)
    assert "Traceback" not in done.stderr, done.stderr
    [finding] = json.loads(done.stdout)["findings"]
    where = finding["dc"]["esi"]["device"]
    assert where.startswith(f"{_where(project_a)}; 0xe0000eca:0x4400:0x10000 (EXD4400) is "
                            f"described differently by 4 ESI files; took {_where(project_a)}"
                            ": the only description that agrees with the SII of slave 0"), \
        where


def _findings(report: dict) -> list[dict]:
    return list(report["findings"])


# -- the corpus: HBM GEN DAQ, four files, three ENIs --------------------------------------

@pytest.mark.parametrize("eni, paired", [
    ("pmec-foswec2/NAVFACOSWECSxml.xml", "20260505_NAVFACOSWECS.xml"),
    ("pmec-lupa/LUPAxml.xml", "mCDR_ESI.xml"),
    ("pmec-wec-bench/DriveAndDUTAndPAAndLoadXML.xml", "20260305_mCDR.xml"),
    ("pmec-wec-bench/Pendulum2XML.xml", None),
])
def test_the_gen_daq_description_each_corpus_eni_agrees_with(corpus_extra: Path, eni: str,
                                                           paired: str | None):
    """The pairing of corpus-extra's MANIFEST ("GEN DAQ exact and PDO-identical"; for
    Pendulum2XML "none has this PDO set"), and the TxPdo sets compared with lxml."""
    path = corpus_extra / "eni" / eni
    hbm = corpus_extra / "esi" / "hbm"
    [xml_slave] = etree.parse(str(path)).xpath("//Config/Slave[Info/ProductCode='3329']")
    same = [f.name for f in sorted(hbm.glob("*.xml"))
            if _pdo_set(_device(f)) == _pdo_set(xml_slave.find("ProcessData"))]
    assert same == ([paired] if paired else [])
    [slave] = [s for s in eni_reader.read_file(path).slaves if s.product_code == 0xD01]
    lib = Library([hbm], cache=False)
    evidence = EniSlaveEvidence(slave, str(path))
    if paired is None:
        with pytest.raises(DuplicateError, match="none agrees with the ENI's slave"):
            lib.find("0x11D:0xD01:2", evidence=evidence)
        return
    chosen = lib.find("0x11D:0xD01:2", evidence=evidence)
    assert Path(chosen.entry.file).name == paired
    assert chosen.preferred is not None and "the only description that agrees" in \
        chosen.preferred
