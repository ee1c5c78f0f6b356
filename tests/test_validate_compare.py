"""``<Validate Type="...">``: the compare types of ETG.2000's revision check, on register
InitCmds and on the master's identity check.

The list of types is taken from the ESI schema (``EtherCATInfo.xsd`` 1.14 and 1.17,
``CheckRevisionNo``); the expectations of the compares are worked out by hand.  End to end:
our example line given an EC-Engineer-style revision check (an EEPROM read request of SII
word 0x000C, then a read of 0x0508 validated with a type), its drive replaced on the virtual
segment by one of a higher or a lower revision.
"""

from __future__ import annotations

import dataclasses

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import compare
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import Validate
from ecatcfg.eni.reader import EniReadError
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.master.bringup import VerifyError
from ecatcfg.runtime.master.replay import ApplyError
from ecatcfg.runtime.segment import emulate

XS = "{http://www.w3.org/2001/XMLSchema}"
ESI = EXAMPLES / "esi"
DRIVE = "axis1"


@pytest.mark.parametrize("version", ["esi-1.14", "esi-1.17"])
def test_the_compare_types_are_the_schemas(corpus, version):
    xsd = etree.parse(str(corpus / "schemas" / version / "EtherCATInfo.xsd"))
    [attribute] = xsd.iterfind(f".//{XS}attribute[@name='CheckRevisionNo']")
    values = [e.get("value") for e in attribute.iter(XS + "enumeration")]
    assert sorted(values) == sorted(compare.COMPARES)


REV = 0x0012_0005              # high word 0x0012, low word 0x0005


@pytest.mark.parametrize("kind, got, passes", [
    ("EQ", REV, True), ("EQ", REV + 1, False),
    ("EQ_OR_G", REV, True), ("EQ_OR_G", REV + 1, True), ("EQ_OR_G", 0x0013_0000, True), ("EQ_OR_G", REV - 1, False),
    ("LW_EQ", 0x0099_0005, True), ("LW_EQ", 0x0012_0006, False),
    ("HW_EQ", 0x0012_FFFF, True), ("HW_EQ", 0x0013_0005, False),
    ("LW_EQ_HW_EQ_OR_G", 0x0013_0005, True), ("LW_EQ_HW_EQ_OR_G", 0x0011_0005, False),
    ("LW_EQ_HW_EQ_OR_G", 0x0013_0006, False),
    ("HW_EQ_LW_EQ_OR_G", 0x0012_0009, True), ("HW_EQ_LW_EQ_OR_G", 0x0012_0004, False),
    ("HW_EQ_LW_EQ_OR_G", 0x0013_0009, False),
    ("NONE", 0, True)])
def test_each_type_on_a_32_bit_read(kind, got, passes):
    v = Validate(REV.to_bytes(4, "little"), compare=kind)
    assert compare.matches(got.to_bytes(4, "little"), v) is passes


def test_the_mask_applies_before_the_compare_and_a_short_read_fails():
    # AL status 0x0130: state bits under mask 0x000F; 0x14 (SAFEOP+error) masked is 4.
    v = Validate(bytes([0x02, 0]), bytes([0x0F, 0]), compare="EQ_OR_G")
    assert compare.matches(bytes([0x14, 0]), v)
    assert not compare.matches(bytes([0x11, 0]), v)
    assert not compare.matches(b"\x05", Validate(b"\x04\x00", compare="EQ_OR_G"))


def test_an_unknown_type_is_a_read_error_at_its_line(example_eni):
    tree = _with_revision_check(example_eni, "GREATER")
    data = etree.tostring(tree)
    line = etree.fromstring(data).xpath("//Validate[@Type]")[0].sourceline
    with pytest.raises(EniReadError, match="not a compare type") as caught:
        eni_reader.read_bytes(data, "ec.xml")
    assert caught.value.line == line


# -- end to end ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def example_eni() -> bytes:
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([ESI], cache=False)).plan
    return eni_writer.to_bytes(plan)


def _with_revision_check(eni: bytes, kind: str | None) -> etree._ElementTree:
    """EC-Engineer's "check revision number": an EEPROM read request of SII word 0x000C
    (APWR 0x0502: control 0x0100, address 0x0000000C), then APRD 0x0508 validated against
    the ENI's revision, first in the drive's IP commands."""
    tree = etree.ElementTree(etree.fromstring(eni))
    slave = tree.xpath(f"//Slave[Info/Name='{DRIVE}']")[0]
    adp = slave.findtext("Info/AutoIncAddr")
    revision = int(slave.findtext("Info/RevisionNo"), 0) & 0xFFFFFFFF
    type_attr = "" if kind is None else f' Type="{kind}"'
    cmds = etree.fromstring(
        f"""<x><InitCmd><Transition>IP</Transition><Comment>set eeprom address</Comment>
        <Cmd>2</Cmd><Adp>{adp}</Adp><Ado>1282</Ado><Data>00010c000000</Data><Cnt>1</Cnt>
        <Retries>3</Retries></InitCmd>
        <InitCmd><Transition>IP</Transition><Comment>check revision number</Comment>
        <Requires>cycle</Requires><Cmd>1</Cmd><Adp>{adp}</Adp><Ado>1288</Ado>
        <Data>00000000</Data><Cnt>1</Cnt><Retries>3</Retries>
        <Validate{type_attr}><Data>{revision.to_bytes(4, "little").hex()}</Data>
        <Timeout>500</Timeout></Validate></InitCmd></x>""")
    init_cmds = slave.find("InitCmds")
    for k, cmd in enumerate(cmds):
        init_cmds.insert(k, cmd)
    return tree


def _up_with_drive_revision(eni: bytes, tmp_path, revision_delta: int,
                            accept_newer: bool = False) -> Network:
    path = tmp_path / "ec.xml"
    path.write_bytes(eni)
    plan = eni_reader.read_file(path)
    want = plan.slave(DRIVE).revision
    net = Network.virtual(plan, esi=[ESI], esi_cache=False)
    spec = next(s for s in emulate.specs_from_eni(plan, Library([ESI], cache=False), "x")
                if s.name == DRIVE)
    other = dataclasses.replace(spec, device=dataclasses.replace(
        spec.device, revision=want + revision_delta))
    net.segment.swap(DRIVE, emulate.emulated_slave(other))
    try:
        net.up(accept_newer_revision=accept_newer)
    except BaseException:
        net.close()
        raise
    return net


def test_a_newer_slave_passes_an_eq_or_g_check_and_reaches_op(example_eni, tmp_path):
    eni = etree.tostring(_with_revision_check(example_eni, "EQ_OR_G"))
    plan = eni_reader.read_bytes(eni, "ec.xml")
    [check] = [c for c in plan.slave(DRIVE).init_cmds if c.comment == "check revision number"]
    assert check.validate.compare == "EQ_OR_G"
    with _up_with_drive_revision(eni, tmp_path, +0x10000) as net:
        assert net.state == AlState.OP


def test_an_older_slave_is_refused_by_name(example_eni, tmp_path):
    eni = etree.tostring(_with_revision_check(example_eni, "EQ_OR_G"))
    with pytest.raises(VerifyError, match="other revision \\(the ENI's revision check "
                                          "refuses it\\)"):
        _up_with_drive_revision(eni, tmp_path, -1)


def test_without_a_type_the_replayed_check_wants_the_same_revision(example_eni, tmp_path):
    """The identity check let through (--accept-newer-revision), the InitCmd's equal
    compare still refuses the newer slave, naming the command and what it read."""
    eni = etree.tostring(_with_revision_check(example_eni, None))
    with pytest.raises(ApplyError, match="check revision number") as caught:
        _up_with_drive_revision(eni, tmp_path, +0x10000, accept_newer=True)
    assert "expected" in str(caught.value)


def test_show_and_messages_say_the_compare(example_eni):
    from ecatcfg.eni.words import init_cmd_words
    plan = eni_reader.read_bytes(etree.tostring(_with_revision_check(example_eni, "EQ_OR_G")),
                                 "ec.xml")
    [check] = [c for c in plan.slave(DRIVE).init_cmds if c.comment == "check revision number"]
    revision = plan.slave(DRIVE).revision
    assert init_cmd_words(check) == f"check SII data >= 0x{revision:08X}"


def test_the_type_is_written_back_and_read_again(example_eni):
    """A plan read from an EC-Engineer-style file and written again keeps its compare."""
    plan = eni_reader.read_bytes(etree.tostring(_with_revision_check(example_eni,
                                                                     "HW_EQ_LW_EQ_OR_G")),
                                 "ec.xml")
    again = eni_reader.read_bytes(eni_writer.to_bytes(plan), "again.xml")
    [check] = [c for c in again.slave(DRIVE).init_cmds if c.comment == "check revision number"]
    assert check.validate.compare == "HW_EQ_LW_EQ_OR_G"
    assert again.slave(DRIVE).init_cmds == plan.slave(DRIVE).init_cmds
