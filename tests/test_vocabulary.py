"""The whole vocabulary of ETG's formats is handled, and metadata never stops a network.

Names are collected here, independently of the code: every element and attribute declared
in the ETG schemas (ESI 1.14 and 1.17, ENI 1.3; parsed with lxml) and every one used in an
ESI or ENI file of both corpora.  Each must have a word in ``esi/vocabulary.py`` (read into
a model, metadata that cannot change what is sent, or refused by name).  Then both sides of
the rule, on our compiled example line given the words with lxml: unknown metadata is a
warning (text and JSON) and apply reaches OP; an unknown word that may change what is sent
is refused with its file, line and slave, and ``--skip-unsupported`` still sends the
InitCmd that carries it.  ``AdaptAutomatically`` on InitCmds is accepted wherever it is.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from conftest import CORPUS, CORPUS_EXTRA, EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esi import vocabulary
from ecatcfg.esi.library import Library

XS = "{http://www.w3.org/2001/XMLSchema}"
ESI = EXAMPLES / "esi"
DRIVE = "axis1"


def schema_words(schemas: Path) -> dict[str, set[str]]:
    """``name`` / ``@name`` -> the schema files that declare it."""
    found: dict[str, set[str]] = {}
    for xsd in sorted(schemas.rglob("*.xsd")):
        tree = etree.parse(str(xsd))
        for kind, prefix in (("element", ""), ("attribute", "@")):
            for node in tree.iter(XS + kind):
                if node.get("name"):
                    found.setdefault(prefix + node.get("name"), set()).add(
                        str(xsd.relative_to(schemas)))
    return found


def document_words(folders: list[Path]) -> dict[str, set[str]]:
    """``name`` / ``@name`` -> the ESI and ENI files (of ``folders``) that use it."""
    found: dict[str, set[str]] = {}
    parser = etree.XMLParser(huge_tree=True, recover=True, resolve_entities=False)
    for folder in folders:
        for path in sorted(folder.rglob("*")):
            if not path.is_file() or path.suffix.lower() not in (".xml", ".esi"):
                continue
            root = etree.parse(str(path), parser).getroot()
            if root is None:
                continue
            for el in root.iter():
                if not isinstance(el.tag, str):
                    continue
                found.setdefault(etree.QName(el).localname, set()).add(path.name)
                for name in el.attrib:
                    found.setdefault("@" + etree.QName(name).localname, set()).add(path.name)
    return found


def unhandled(seen: dict[str, set[str]], words: dict[str, object]) -> dict[str, list[str]]:
    return {name: sorted(where)[:3] for name, where in seen.items() if name not in words}


@pytest.fixture(scope="module")
def seen(corpus: Path, corpus_extra: Path) -> dict[str, set[str]]:
    words = schema_words(corpus / "schemas")
    assert {"@CheckRevisionNo", "Validate", "InitCmd", "@AdaptAutomatically"} <= set(words)
    for name, where in document_words([corpus / "eni", corpus / "esi", corpus_extra / "eni",
                                       corpus_extra / "esi"]).items():
        words.setdefault(name, set()).update(where)
    return words


def test_every_word_of_the_schemas_and_the_corpora_is_handled(seen):
    assert len(seen) > 550
    assert unhandled(seen, vocabulary.WORDS) == {}


@pytest.mark.parametrize("name", ["@AdaptAutomatically", "@Type", "@CompleteAccess",
                                  "Validate", "DisplayName", "VoE", "SlotGroupData"])
def test_removing_one_handled_word_fails_the_check(seen, name):
    """What the test above would say if one word were taken out of the table."""
    if name not in seen:
        pytest.fail(f"{name} is in no schema or corpus file")
    words = dict(vocabulary.WORDS)
    del words[name]
    assert list(unhandled(seen, words)) == [name]


def test_the_kinds_of_the_words_the_issue_names():
    assert vocabulary.kind_of("AdaptAutomatically", attribute=True) == "metadata"
    assert vocabulary.kind_of("Type", attribute=True) == "read"
    assert vocabulary.kind_of("CompleteAccess", attribute=True) == "read"
    assert vocabulary.kind_of("DisplayName") == "metadata"
    assert vocabulary.kind_of("VoE") == "refused"
    assert vocabulary.kind_of("NotAWord") is None


# -- both sides of the rule, on the example line ------------------------------------------

@pytest.fixture(scope="module")
def example_eni() -> bytes:
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([ESI], cache=False)).plan
    return eni_writer.to_bytes(plan)


def _write(tree: etree._ElementTree, path: Path) -> Path:
    path.write_bytes(etree.tostring(tree, xml_declaration=True, encoding="UTF-8",
                                    pretty_print=True))
    return path


def _apply(eni: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(ESI), "--simulated-time", "--cycles", "3", *args],
                          capture_output=True, text=True, timeout=180)


def _line(path: Path, xpath: str) -> int:
    return etree.parse(str(path)).xpath(xpath)[0].sourceline


def test_metadata_is_a_warning_and_apply_reaches_op(example_eni, tmp_path):
    """A tool's metadata where the list does not name it, and AdaptAutomatically on a
    register and a CoE InitCmd (TwinCAT): warnings in text and JSON, nothing refused."""
    tree = etree.ElementTree(etree.fromstring(example_eni))
    drive = tree.xpath(f"//Slave[Info/Name='{DRIVE}']")[0]
    drive.find("Info").append(etree.fromstring("<DisplayName>Axis 1 (X)</DisplayName>"))
    drive.find("InitCmds/InitCmd").set("Guid", "{1234}")
    drive.find("InitCmds/InitCmd").set("AdaptAutomatically", "true")
    coe = drive.find("Mailbox/CoE/InitCmds/InitCmd")
    coe.set("AdaptAutomatically", "true")
    eni = _write(tree, tmp_path / "meta.xml")
    plan = eni_reader.read_file(eni)
    assert plan.unsupported == []
    assert sorted((p.element, p.slave) for p in plan.ignored) == [
        ("Slave/Info/DisplayName", DRIVE), ("Slave/InitCmds/InitCmd/@Guid", DRIVE)]
    run = _apply(eni, "--format", "json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert {s["highest_state"] for s in report["slaves"]} == {"OP"}
    display = _line(eni, f"//Slave[Info/Name='{DRIVE}']/Info/DisplayName")
    assert f"warning: {eni}:{display}: slave '{DRIVE}': ignored <DisplayName>" in run.stderr
    assert {(i["element"], i["line"]) for i in report["ignored"]} == {
        ("Slave/Info/DisplayName", display),
        ("Slave/InitCmds/InitCmd/@Guid",
         _line(eni, f"//Slave[Info/Name='{DRIVE}']/InitCmds/InitCmd[1]"))}


def test_an_unknown_word_that_may_change_what_is_sent_is_refused_and_skipping_keeps_the_cmd(
        example_eni, tmp_path):
    tree = etree.ElementTree(etree.fromstring(example_eni))
    drive = tree.xpath(f"//Slave[Info/Name='{DRIVE}']")[0]
    first = drive.find("InitCmds/InitCmd")
    first.set("RepeatUntil", "3")
    eni = _write(tree, tmp_path / "unknown.xml")
    line = _line(eni, f"//Slave[Info/Name='{DRIVE}']/InitCmds/InitCmd[1]")
    plan = eni_reader.read_file(eni)
    [part] = plan.unsupported
    assert (part.element, part.line, part.slave) == (
        "Slave/InitCmds/InitCmd/@RepeatUntil", line, DRIVE)
    assert plan.ignored == []
    refused = _apply(eni)
    assert refused.returncode == 1
    assert f"{eni}:{line}: slave '{DRIVE}': the attribute RepeatUntil='3'" in refused.stderr
    # Skipping skips the attribute, never the command: the plan has all the InitCmds.
    plain = eni_reader.read_bytes(example_eni, "plain.xml")
    assert len(plan.slave(DRIVE).init_cmds) == len(plain.slave(DRIVE).init_cmds)
    assert plan.slave(DRIVE).init_cmds[0] == plain.slave(DRIVE).init_cmds[0]
    skipped = _apply(eni, "--skip-unsupported", "--format", "json")
    assert skipped.returncode == 0, skipped.stderr
    assert {s["highest_state"] for s in json.loads(skipped.stdout)["slaves"]} == {"OP"}


def test_complete_access_outside_a_coe_transfer_is_refused_when_true(example_eni):
    tree = etree.ElementTree(etree.fromstring(example_eni))
    cmd = tree.xpath(f"//Slave[Info/Name='{DRIVE}']/InitCmds/InitCmd")[0]
    cmd.set("CompleteAccess", "0")
    assert eni_reader.read_bytes(etree.tostring(tree), "x.xml").unsupported == []
    cmd.set("CompleteAccess", "1")
    [part] = eni_reader.read_bytes(etree.tostring(tree), "x.xml").unsupported
    assert part.element.endswith("/@CompleteAccess") and "only a CoE SDO" in part.what


def _spelled_by(modules: list[str]) -> tuple[set[str], set[str]]:
    """The names the readers' code spells: every word of a string constant, and the
    constant heads of f-strings followed by a number (``f"Sm{number}"``)."""
    import ast
    import re
    root = Path(vocabulary.__file__).resolve().parent.parent
    words, heads = set(), set()
    for module in modules:
        for node in ast.walk(ast.parse((root / module).read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                words.update(w for w in re.split(r"[^A-Za-z0-9_]+", node.value) if w)
            elif isinstance(node, ast.JoinedStr) and len(node.values) >= 2 and \
                    isinstance(node.values[0], ast.Constant):
                heads.add(str(node.values[0].value).rsplit("/", 1)[-1])
    return words, heads


def test_a_word_read_into_a_model_is_one_the_readers_look_up():
    """``read`` is a claim about the code: the ENI reader's list or the ESI reader looks
    the name up (it is spelled in their source)."""
    words, heads = _spelled_by(["eni/reader.py", "eni/contents.py", "eni/compare.py",
                                "esi/reader.py", "esi/index.py", "esi/slots.py"])
    not_spelled = [name for name, (kind, _) in vocabulary.WORDS.items() if kind == "read"
                   and name.lstrip("@") not in words
                   and not any(name.startswith(h) and name[len(h):].isdigit() for h in heads)]
    assert not_spelled == []


def test_the_network_api_warns_of_ignored_metadata(example_eni, tmp_path):
    import warnings

    from ecatcfg.esc import AlState
    from ecatcfg.runtime import Network
    from ecatcfg.runtime.network import IgnoredMetadataWarning
    tree = etree.ElementTree(etree.fromstring(example_eni))
    tree.xpath(f"//Slave[Info/Name='{DRIVE}']/Info")[0].append(
        etree.fromstring("<Tool>TwinCAT 3.1</Tool>"))
    eni = _write(tree, tmp_path / "tool.xml")
    line = _line(eni, f"//Slave[Info/Name='{DRIVE}']/Info/Tool")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with Network.virtual(eni, esi=[ESI], esi_cache=False) as net:
            net.up()
            assert net.state == AlState.OP
    [warning] = [w for w in caught if issubclass(w.category, IgnoredMetadataWarning)]
    assert str(warning.message).startswith(f"{eni}:{line}: slave '{DRIVE}': ignored <Tool>")
    events = []
    with Network.virtual(eni, esi=[ESI], esi_cache=False, on_event=events.append):
        pass
    assert [e.kind for e in events].count("ignored") == 1


def test_a_twincat_export_with_adapt_automatically_on_coe_initcmds_reaches_op(corpus_extra):
    """A real TwinCAT export (corpus-extra pmec-wec-bench) writes AdaptAutomatically on CoE
    InitCmds (0x1C32:02, 0x10F3:05): read as written, nothing refused, and it runs."""
    eni = corpus_extra / "eni" / "pmec-wec-bench" / "DriveAndDUTAndPAAndLoadXML.xml"
    marked = etree.parse(str(eni)).xpath("//CoE/InitCmds/InitCmd[@AdaptAutomatically]")
    assert {(int(c.findtext("Index")), int(c.findtext("SubIndex"))) for c in marked} == {
        (0x1C32, 2), (0x10F3, 5)}
    plan = eni_reader.read_file(eni)
    assert plan.unsupported == []
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                          "--simulated-time", "--cycles", "3", "--format", "json"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    states = {s["highest_state"] for s in json.loads(run.stdout)["slaves"]}
    assert states == {"OP", "passive"}


def test_an_unknown_child_of_validate_is_refused_and_metadata_in_it_is_a_warning(example_eni):
    """A Validate is a check: a Type written as an element would change it if it meant
    anything; a comment in it would not."""
    tree = etree.ElementTree(etree.fromstring(example_eni))
    validate = tree.xpath("//Slave/InitCmds/InitCmd/Validate")[0]
    validate.append(etree.fromstring("<Type>EQ_OR_G</Type>"))
    plan = eni_reader.read_bytes(etree.tostring(tree), "x.xml")
    assert [p.element.rsplit("/", 2)[-2:] for p in plan.unsupported] == [["Validate", "Type"]]
    validate.remove(validate[-1])
    validate.append(etree.fromstring("<Comment>EC-Engineer</Comment>"))
    plan = eni_reader.read_bytes(etree.tostring(tree), "x.xml")
    assert plan.unsupported == [] and len(plan.ignored) == 1


def test_use_lrd_lwr_stops_an_lrw_layout_and_runs_with_lrd_lwr(tmp_path):
    """ETG.2000 ``Type@UseLrdLwr``: the device takes process data by LRD and LWR only (the
    corpora's Beckhoff EL2002 rev 0x270B0000 and Murrelektronik Impact67 say so); an LRW
    layout would send it one.  Our IgH list fixture's EL2008 given the attribute."""
    from conftest import FIXTURES
    esi = tmp_path / "list.xml"
    esi.write_bytes((FIXTURES / "igh" / "ethercat-xml-3-slaves.xml").read_bytes().replace(
        b'RevisionNo="#x00100000">EL2008', b'RevisionNo="#x00100000" UseLrdLwr="1">EL2008'))
    slaves = ("slaves:\n  - {name: coupler, device: EK1100}\n"
              "  - {name: inputs, device: EL1008}\n  - {name: outputs, device: EL2008}\n")
    lrw = tmp_path / "lrw.yaml"
    lrw.write_text("master: {name: l, cycle_time_us: 1000}\n" + slaves)
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(lrw), "--esi",
                          str(esi), "-o", str(tmp_path / "x.xml")], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 1
    assert f"{lrw}:5: slave 'outputs': its ESI says UseLrdLwr" in run.stderr
    split = tmp_path / "split.yaml"
    split.write_text("master: {name: l, cycle_time_us: 1000, layout: lrd_lwr}\n" + slaves)
    eni = tmp_path / "line.xml"
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(split), "--esi",
                          str(esi), "-o", str(eni)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    cmds = {int(c.findtext("Cmd")) for c in etree.parse(str(eni)).iterfind(
        "Config/Cyclic/Frame/Cmd")}
    assert 12 not in cmds and {10, 11} <= cmds          # LRD, LWR; no LRW (ETG.1000.4)
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                          "--esi", str(esi), "--simulated-time", "--cycles", "3", "--format",
                          "json"],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr
    assert [s["highest_state"] for s in json.loads(run.stdout)["slaves"]] == ["OP"] * 3


def test_show_lists_ignored_metadata(example_eni, tmp_path):
    tree = etree.ElementTree(etree.fromstring(example_eni))
    tree.xpath(f"//Slave[Info/Name='{DRIVE}']/Info")[0].append(
        etree.fromstring("<Description>the first axis</Description>"))
    eni = _write(tree, tmp_path / "desc.xml")
    line = _line(eni, f"//Slave[Info/Name='{DRIVE}']/Info/Description")
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "show", str(eni), "--format",
                          "json"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    [item] = json.loads(run.stdout)["ignored"]
    assert (item["slave"], item["element"], item["line"]) == (
        DRIVE, "Slave/Info/Description", line)
    text = subprocess.run([sys.executable, "-m", "ecatcfg", "show", str(eni)],
                          capture_output=True, text=True, timeout=120).stdout
    assert "Slave/Info/Description" in text.split("Ignored:", 1)[1]
