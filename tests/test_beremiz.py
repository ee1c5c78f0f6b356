"""Beremiz's EtherLab-plugin file (a Beremiz project's config.xml) compiled as the topology
it describes, then applied on the virtual segment emulating its devices from their ESI.

References independent of the code under test: the two real plugin files and the ESI files
beside them (corpus-extra beremiz-tests), read with plain XPath; what Beremiz's generator
does with them (etherlab/EthercatCFileGenerator.py: each start-up SDO downloaded as the
integer its Data spells, in the size of the ESI's object, little-endian as EC_WRITE_U16 and
its kind write it; the slave addressed alias:position with alias Info/AutoIncAddr,
position Info/PhysAddr).  As an ENI these files are refused (tests/test_eni_only.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from ecatcfg.compiler import beremiz, build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network


def _folder(corpus_extra: Path) -> Path:
    return corpus_extra / "eni" / "beremiz-tests"


def _library(corpus: Path, corpus_extra: Path) -> list[Path]:
    return [corpus / "esi", corpus_extra / "esi" / "beremiz-tests"]


def _object_bytes(esi: Path, index: int) -> int:
    """The byte size of object ``index`` (subindex 0 of a variable) in the ESI, by XPath."""
    [obj] = [o for o in etree.parse(str(esi)).iter("Object")
             if int(o.findtext("Index").replace("#x", "0x"), 0) == index]
    return int(obj.findtext("BitSize")) // 8


@pytest.mark.parametrize("name", ["wago_higen", "wago_sanyo"])
def test_the_plugin_file_compiles_and_reaches_op(corpus, corpus_extra, tmp_path, name):
    path = _folder(corpus_extra) / name / "config.xml"
    root = etree.parse(str(path)).getroot()
    slaves = sorted(root.iterfind("Config/Slave"), key=lambda s: int(s.findtext("Info/PhysAddr")))
    loaded = topology.load(path)
    esi = _library(corpus, corpus_extra)
    compiled = build.compile_topology(loaded, Library(esi, cache=False))
    eni = tmp_path / "compiled.xml"
    eni.write_bytes(eni_writer.to_bytes(compiled.plan, generator="test"))
    plan = eni_reader.read_file(eni)
    # Slaves in Beremiz's position order, by identity; the alias Beremiz addresses a slave
    # with (AutoIncAddr) is checked at 0x0012 where it is not 0.
    assert [(s.name, s.vendor_id, s.product_code, s.revision) for s in plan.slaves] == [
        (s.findtext("Info/Name"), int(s.findtext("Info/VendorId")),
         int(s.findtext("Info/ProductCode")), int(s.findtext("Info/RevisionNo")))
        for s in slaves]
    aliases = [int(s.findtext("Info/AutoIncAddr")) for s in slaves]
    for slave, alias in zip(plan.slaves, aliases):
        checks = [c for c in slave.init_cmds if c.ado == 0x0012 and c.validate is not None]
        assert [int.from_bytes(c.validate.data[:2], "little") for c in checks] == \
            ([alias] if alias else [])
    net = Network.virtual(eni, esi)
    try:
        net.up(AlState.OP)
        net.run(20)
        assert net.master.state == AlState.OP
        # Each start-up SDO holds the value its Data spells, in the ESI object's size.
        for el, emulated in zip(slaves, net.segment.slaves):
            for cmd in el.iterfind("Mailbox/CoE/InitCmds/InitCmd"):
                index = int(cmd.findtext("Index"))
                size = _object_bytes(corpus_extra / "esi" / "beremiz-tests" /
                                     "Higen_EDA7000_CoE_ver16_with_variablePDO_rv3.xml", index)
                want = int(cmd.findtext("Data"), 16).to_bytes(size, "little")
                assert emulated.od[index][int(cmd.findtext("SubIndex"))].value == want
        net.down()
    finally:
        net.close()


def test_the_higen_sdos_are_beremiz_values(corpus_extra):
    """0x60E0 (positive torque limit) "05DC" is 1500, i.e. 150.0 %: bytes DC 05 on the
    wire, as Beremiz's EC_WRITE_U16 writes it (not 05 DC, the text's byte order)."""
    text = beremiz.plugin_topology(
        (_folder(corpus_extra) / "wago_higen" / "config.xml").read_bytes(), "higen")
    assert text is not None
    [drive] = [s for s in json.loads(text)["slaves"] if "sdos" in s]
    assert [(s["index"], s["subindex"], s["value"], s["transition"]) for s in drive["sdos"]] \
        == [(0x2025, 0, 7, "PS"), (0x60E0, 0, 1500, "PS"), (0x60E1, 0, 1500, "PS")]


def test_an_eni_is_not_a_plugin_file(corpus):
    eni = corpus / "eni" / "jn-ec-master" / "mega_master_eni.xml"
    assert beremiz.plugin_topology(eni.read_bytes(), str(eni)) is None
    with pytest.raises(EcatcfgError) as refused:
        topology.load(eni)
    assert "not a topology" in str(refused.value)


def test_a_plugin_file_with_a_bad_value_is_a_located_error(corpus_extra, tmp_path):
    path = _folder(corpus_extra) / "wago_higen" / "config.xml"
    bad = tmp_path / "config.xml"
    bad.write_bytes(path.read_bytes().replace(b"<Data>05DC</Data>", b"<Data>5,1</Data>", 1))
    line = next(n for n, text in enumerate(bad.read_text().splitlines(), 1) if "5,1" in text)
    with pytest.raises(EcatcfgError) as refused:
        topology.load(bad)
    err = refused.value
    assert (err.file, err.message) == (str(bad), "slave 'EDA7000 CoE Drive': start-up SDO "
                                                 "value '5,1' is not a hex number")
    assert line - 8 <= err.line <= line


def test_compile_on_the_command_line(corpus, corpus_extra, tmp_path):
    out = tmp_path / "higen.xml"
    done = subprocess.run(
        [sys.executable, "-m", "ecatcfg", "compile",
         str(_folder(corpus_extra) / "wago_higen" / "config.xml"),
         *[a for p in _library(corpus, corpus_extra) for a in ("--esi", str(p))],
         "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("wrote ") and "4 slaves" in done.stdout
    assert len(eni_reader.read_file(out).slaves) == 4
