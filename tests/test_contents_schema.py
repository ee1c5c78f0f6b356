"""The whole ENI format, not the corpus: every element and attribute of the ETG.2100 schema
(``EtherCATConfig.xsd`` 1.3, parsed here with lxml, following named types, groups and refs)
has a part in ``eni/contents.py`` (read, accepted with a reason, or refused by name), and
appears in a test input: ``tests/fixtures/eni-every-element.xml``, written by hand, which
validates against the schema and is read by the reader.  What real exporters write beyond
the schema (both corpora) is listed too, or refused by name: none of it is unknown.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from lxml import etree

import prereq
from conftest import CORPUS, FIXTURES
from ecatcfg.eni import contents
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni.plan import CopyInfo
from ecatcfg.esc import Transition

XS = "{http://www.w3.org/2001/XMLSchema}"
EVERY = FIXTURES / "eni-every-element.xml"
CORPUS_EXTRA = Path(os.environ.get("ECATCFG_CORPUS_EXTRA", CORPUS.parent / "corpus-extra"))


def _local(name: str | None) -> str | None:
    return name.split(":")[-1] if name else name


def schema_paths(xsd: Path) -> set[tuple[str, ...]]:
    """Every (element path) and (element path + ``@attribute``) the schema allows, from the
    root element down, as tuples of names: ``("EtherCATConfig", "Config", "Slave", "@HotPlug")``
    would be one if the schema had it."""
    root = etree.parse(str(xsd)).getroot()
    named = {kind: {t.get("name"): t for t in root.iterchildren(XS + kind)}
             for kind in ("complexType", "group", "attributeGroup", "element")}
    found: set[tuple[str, ...]] = set()

    def element(el: etree._Element, path: tuple[str, ...], types: frozenset[str]) -> None:
        found.add(path)
        type_name = _local(el.get("type"))
        if type_name in named["complexType"] and type_name not in types:
            content(named["complexType"][type_name], path, types | {type_name})
        content(el, path, types)

    def content(node: etree._Element, path: tuple[str, ...], types: frozenset[str]) -> None:
        for child in node.iterchildren(XS + "*"):
            kind = etree.QName(child).localname
            if kind == "element":
                ref = _local(child.get("ref"))
                target = named["element"][ref] if ref else child
                element(target, path + (target.get("name"),), types)
            elif kind == "attribute":
                found.add(path + ("@" + (child.get("name") or _local(child.get("ref"))),))
            elif kind in ("group", "attributeGroup") and child.get("ref"):
                content(named[kind][_local(child.get("ref"))], path, types)
            elif kind in ("extension", "restriction"):
                base = _local(child.get("base"))
                if base in named["complexType"] and base not in types:
                    content(named["complexType"][base], path, types | {base})
                content(child, path, types)
            elif kind in ("sequence", "choice", "all", "complexType", "complexContent",
                          "simpleContent", "group", "attributeGroup"):
                content(child, path, types)

    for name, el in named["element"].items():
        element(el, (name,), frozenset())
    return found


def document_paths(path: Path) -> set[tuple[str, ...]]:
    found: set[tuple[str, ...]] = set()

    def walk(el: etree._Element, at: tuple[str, ...]) -> None:
        found.add(at)
        found.update(at + ("@" + etree.QName(a).localname,) for a in el.attrib)
        for child in el:
            if isinstance(child.tag, str):
                walk(child, at + (etree.QName(child).localname,))

    root = etree.parse(str(path), etree.XMLParser(huge_tree=True)).getroot()
    walk(root, ("EtherCATConfig",))      # EncryptedEtherCATConfig holds the same tree
    return found


@pytest.fixture(scope="module")
def xsd(corpus: Path) -> Path:
    path = corpus / "schemas" / "eni-1.3" / "EtherCATConfig.xsd"
    if not path.is_file():
        prereq.missing(str(path), "not found", prereq.CORPUS)
    return path


@pytest.fixture(scope="module")
def corpus_extra() -> Path:
    if not (CORPUS_EXTRA / "eni").is_dir():
        prereq.missing(f"the extra corpus at {CORPUS_EXTRA}",
                       "not found (set ECATCFG_CORPUS_EXTRA to its folder)", prereq.CORPUS)
    return CORPUS_EXTRA


def test_the_schema_walk_finds_what_the_schema_says(xsd):
    """The parser is checked on names the schema file spells out in different ways: a
    named complexType (ECatCmdType), an attribute of an anonymous type, a choice."""
    paths = schema_paths(xsd)
    assert ("EtherCATConfig", "@Version") in paths
    assert ("EtherCATConfig", "Config", "Master", "InitCmds", "InitCmd", "Validate",
            "DataMask") in paths
    assert ("EtherCATConfig", "Config", "Slave", "PreviousPort", "@Selected") in paths
    assert ("EtherCATConfig", "Config", "Cyclic", "Frame", "Cmd", "Addr") in paths
    assert ("EtherCATConfig", "Config", "Slave", "ProcessData", "TxPdo", "Entry",
            "DataType", "@SwapData") in paths
    assert len(paths) > 300


def test_every_schema_element_and_attribute_has_its_part(xsd):
    """Read, accepted with a reason, or refused by name: nothing the format allows is left
    to chance.  Deleting one entry of ``contents.CONTENTS`` makes this fail."""
    missing = sorted("/".join(p) for p in schema_paths(xsd)
                     if len(p) > 1 and contents.covering(list(p[1:])) is None)
    assert missing == []


def test_every_schema_element_and_attribute_is_in_a_test_input(xsd):
    assert sorted("/".join(p) for p in schema_paths(xsd) - document_paths(EVERY)) == []


def test_the_every_element_file_is_valid(eni_schema):
    assert eni_schema.validate(etree.parse(str(EVERY))), eni_schema.error_log


def test_the_reader_reads_it_and_names_what_apply_refuses():
    plan = eni_reader.read_file(EVERY)
    assert [s.name for s in plan.slaves] == ["Coupler", "Drive"]
    assert plan.version == "1.3"
    drive = plan.slaves[1]
    [coe] = drive.mailbox.coe_init_cmds
    assert (coe.index, coe.complete_access, coe.fixed) == (0x1C13, True, True)
    assert drive.mailbox.data_link_layer is True
    [soe] = drive.mailbox.soe_init_cmds
    assert (soe.transitions, soe.op_code, soe.drive_no, soe.idn, soe.elements, soe.data) == (
        [Transition.PS], 3, 0, 32, 0x40, bytes([0x0B, 0]))
    assert [(p.element, p.slave, p.commands) for p in plan.unsupported] == [
        ("Slave/Mailbox/AoE/InitCmds", "Drive", 1),
        ("Slave/Mailbox/VoE", "Drive", 1),
        ("FoE/InitCmds/InitCmd", "Drive", 1)]       # in BI: apply does not go to BOOT
    # CopyInfos are read, their #x10 (HexDecValue) as a number.
    assert plan.cyclic[0].frames[0].cmds[0].copy_infos == [CopyInfo(16, 0, 8)]


def _unknown(path: Path) -> list[str]:
    plan = eni_reader.read_file(path)
    return [f"{p.element} line {p.line}: {p.what}" for p in plan.unsupported
            if "ecatcfg does not know" in p.what]


def test_what_exporters_write_beyond_the_schema_is_listed(corpus, corpus_extra):
    """Every element and attribute in a real export (both corpora) has its part: nothing
    in them is refused as unknown."""
    enis = sorted((corpus / "eni").rglob("*.xml")) + sorted((corpus_extra / "eni").rglob("*.xml"))
    assert len(enis) > 20
    unknown = {str(path): found for path in enis if (found := _unknown(path))}
    assert unknown == {}
    beyond: set[str] = set()
    for path in enis:
        for p in document_paths(path):
            if len(p) > 2 and p[1] == "Config" and contents.covering(list(p[1:])) is None:
                beyond.add("/".join(p))
    assert sorted(beyond) == []


@pytest.mark.parametrize("fragment, element", [
    ('<Info Extra="1"/>', "Slave/Info/@Extra"),
    ("<Mailbox RepeatCount='1'/>", "Slave/Mailbox/@RepeatCount")])
def test_an_unknown_attribute_is_refused_by_name(fragment, element):
    """An attribute nobody listed may change what the master does: refused, with its line
    and slave."""
    root = etree.parse(str(EVERY)).getroot()
    slave = root.find("Config/Slave[2]")
    tag = etree.fromstring(fragment).tag
    for name, value in etree.fromstring(fragment).attrib.items():
        slave.find(tag).set(name, value)
    data = etree.tostring(root)
    plan = eni_reader.read_bytes(data, "x.xml")
    line = etree.fromstring(data).find(f"Config/Slave[2]/{tag}").sourceline
    [part] = [p for p in plan.unsupported if p.element == element]
    assert (part.slave, part.line) == ("Drive", line)
    assert "which ecatcfg does not know" in part.what


def test_an_esi_style_adapt_automatically_on_coe_data_is_accepted():
    """ETG.2000's ``Data AdaptAutomatically`` on a CoE InitCmd speaks to the configurator
    (adapt the data to the PDO configuration); an ENI holds the adapted data."""
    root = etree.parse(str(EVERY)).getroot()
    data = root.find("Config/Slave[2]/Mailbox/CoE/InitCmds/InitCmd/Data")
    data.set("AdaptAutomatically", "true")
    before = [(p.element, p.what) for p in eni_reader.read_file(EVERY).unsupported]
    after = eni_reader.read_bytes(etree.tostring(root), "x.xml").unsupported
    assert [(p.element, p.what) for p in after] == before
    data.set("Extra", "true")            # the attribute is listed, not any attribute
    refused = eni_reader.read_bytes(etree.tostring(root), "x.xml").unsupported
    assert ("Slave/Mailbox/CoE/InitCmds/InitCmd/Data/@Extra",
            "the attribute Extra='true' of <Data>, which ecatcfg does not know") in [
        (p.element, p.what) for p in refused]
