"""One identity, several ESI descriptions (docs/compile.md, "Which ESI file describes a
device"): identical ones are one device, differing ones are an error at the topology line
naming each file and what differs, unless the topology names the file (``esi:``) or the
command ranks the files (``--prefer``).  ``devices`` lists them, lint reports them across the
files it is given.  Self-written pairs; the corpus at the end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from conftest import esi_xml, write
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.duplicates import Description, describe, device_elements, differences
from ecatcfg.esi.library import DuplicateError, EsiChoiceError, Library


def ecatcfg(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120)


def _entry(index: int, sub: int, bits: int, type_: str, name: str = "e") -> str:
    return (f"<Entry><Index>#x{index:04X}</Index><SubIndex>{sub}</SubIndex>"
            f"<BitLen>{bits}</BitLen><Name>{name}</Name><DataType>{type_}</DataType></Entry>")


def io_device(inputs: str, name: str = "IO8 name", type_name: str = "IO8",
              sms: int = 2, product: str = "#x1234", extra: str = "") -> str:
    """A mailbox-less I/O device: one output byte (RxPdo 0x1600), inputs as given (TxPdo
    0x1A00 entries)."""
    sm = ('<Sm ControlByte="#x64" Enable="1" StartAddress="#x0F00">Outputs</Sm>'
          '<Sm ControlByte="#x20" Enable="1" StartAddress="#x1000">Inputs</Sm>')
    if sms == 4:
        sm = ('<Sm ControlByte="#x26" DefaultSize="128" Enable="1" StartAddress="#x1800">'
              'MBoxOut</Sm><Sm ControlByte="#x22" DefaultSize="128" Enable="1" '
              'StartAddress="#x1880">MBoxIn</Sm>' + sm.replace("#x0F00", "#x1100")
              .replace("#x1000", "#x1180"))
    out_sm, in_sm = (0, 1) if sms == 2 else (2, 3)
    return (f'      <Device Physics="KK"><Type ProductCode="{product}" RevisionNo="#x00010000">'
            f'{type_name}</Type><Name LcId="1033">{name}</Name><GroupType>G</GroupType>'
            f'<Fmmu>Outputs</Fmmu><Fmmu>Inputs</Fmmu>{sm}'
            f'<RxPdo Fixed="1" Mandatory="1" Sm="{out_sm}"><Index>#x1600</Index><Name>Out'
            f'</Name>{_entry(0x7000, 1, 8, "USINT")}</RxPdo>'
            f'<TxPdo Fixed="1" Mandatory="1" Sm="{in_sm}"><Index>#x1A00</Index><Name>In</Name>'
            f'{inputs}</TxPdo>{extra}</Device>')


ONE_INPUT = _entry(0x6000, 1, 8, "USINT", "Input")
TWO_INPUTS = ONE_INPUT + _entry(0x6000, 2, 16, "UINT", "Counter")

TOPOLOGY = """\
slaves:
  - name: io
    device: IO8
"""


@pytest.fixture
def pair(tmp_path: Path) -> Path:
    """esi/a.xml and esi/b.xml: IO8 0xE0F1:0x1234:0x10000 with 1 and with 2 input entries."""
    (tmp_path / "esi").mkdir()
    write(tmp_path / "esi", "a.xml", esi_xml(io_device(ONE_INPUT)))
    write(tmp_path / "esi", "b.xml", esi_xml(io_device(TWO_INPUTS)))
    return tmp_path


def _device_line(path: Path) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1)
                if "<Device " in line)


def _input_entries(eni: Path) -> int:
    """TxPdo entries of the compiled slave, read from the ENI with lxml."""
    root = etree.parse(str(eni)).getroot()
    return len(root.findall("Config/Slave/ProcessData/TxPdo/Entry"))


# -- compile ---------------------------------------------------------------------------------

def test_differing_pair_is_an_error_at_the_topology_line_naming_both_files(pair: Path):
    topo = write(pair, "t.yaml", TOPOLOGY)
    done = ecatcfg("compile", topo, "--esi", pair / "esi", "-o", pair / "out.xml",
                   "--no-cache")
    assert done.returncode == 1, done.stderr
    a, b = pair / "esi" / "a.xml", pair / "esi" / "b.xml"
    # At the slave's device line (3), naming both files with their Device lines, and what
    # differs: b has a second entry in TxPdo 0x1A00.
    assert f"{topo}:3: slave 'io': " in done.stderr
    assert f"{a}:{_device_line(a)}" in done.stderr and f"{b}:{_device_line(b)}" in done.stderr
    assert "TxPdo 0x1A00 entries differ" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (pair / "out.xml").exists()


def test_esi_names_the_file_and_it_compiles(pair: Path, eni_schema):
    for esi, entries in (("esi/b.xml", 2), ("a.xml", 1)):   # a path, a library file's name
        topo = write(pair, "t.yaml", TOPOLOGY + f"    esi: {esi}\n")
        out = pair / "out.xml"
        done = ecatcfg("compile", topo, "--esi", pair / "esi", "-o", out, "--no-cache")
        assert done.returncode == 0, done.stderr
        assert _input_entries(out) == entries
        assert eni_schema.validate(etree.parse(str(out))), eni_schema.error_log


def test_esi_relative_to_the_topology_file_not_the_working_directory(pair: Path, tmp_path):
    sub = pair / "plant"
    sub.mkdir()
    topo = write(sub, "t.yaml", TOPOLOGY + "    esi: ../esi/b.xml\n")
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    done = ecatcfg("compile", topo, "--esi", pair / "esi", "-o", pair / "out.xml",
                   "--no-cache", cwd=elsewhere)
    assert done.returncode == 0, done.stderr
    assert _input_entries(pair / "out.xml") == 2


def test_esi_that_does_not_describe_the_device_is_an_error_at_its_line(pair: Path):
    write(pair / "esi", "other.xml", esi_xml(io_device(ONE_INPUT, type_name="IO9",
                                                       product="#x999")))
    for esi, said in (("other.xml", "does not describe 'IO8'"),
                      ("missing.xml", "is not one of the library's 3 files")):
        topo = write(pair, "t.yaml", TOPOLOGY + f"    esi: {esi}\n")
        done = ecatcfg("compile", topo, "--esi", pair / "esi", "-o", pair / "out.xml",
                       "--no-cache")
        assert done.returncode == 1
        assert f"{topo}:4: slave 'io': esi: " in done.stderr and said in done.stderr, \
            done.stderr


def test_identical_duplicates_are_silent(tmp_path: Path):
    """The same device written differently: other names, comments, number and boolean
    spellings, white space, attribute order; compile takes it without a word."""
    (tmp_path / "esi").mkdir()
    write(tmp_path / "esi", "a.xml", esi_xml(io_device(TWO_INPUTS)))
    other = (io_device(TWO_INPUTS, name="IO8 other download")
             .replace("<Index>#x1A00</Index>", "<!-- inputs --><Index> 6656 </Index>")
             .replace('Fixed="1" Mandatory="1"', 'Mandatory="true" Fixed="true"')
             .replace("<Name>Counter</Name>", "<Name>Zähler</Name>")
             .replace("<GroupType>G</GroupType>", "<GroupType>Other</GroupType>"
                      "<URL>http://example.invalid/io8</URL>"))
    write(tmp_path / "esi", "b.xml", esi_xml(other))
    topo = write(tmp_path, "t.yaml", TOPOLOGY)
    done = ecatcfg("compile", topo, "--esi", tmp_path / "esi", "-o", tmp_path / "out.xml",
                   "--no-cache")
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert _input_entries(tmp_path / "out.xml") == 2


def test_prefer_takes_the_ranked_file_with_a_note(pair: Path):
    topo = write(pair, "t.yaml", TOPOLOGY)
    b = pair / "esi" / "b.xml"
    done = ecatcfg("compile", topo, "--esi", pair / "esi", "--prefer", b, "-o",
                   pair / "out.xml", "--no-cache")
    assert done.returncode == 0, done.stderr
    assert _input_entries(pair / "out.xml") == 2
    assert f"took {b}:{_device_line(b)} (--prefer {b})" in done.stderr
    assert "note: slave 'io'" in done.stderr and "TxPdo 0x1A00 entries differ" in done.stderr
    # A --prefer path outside the library is a usage error.
    done = ecatcfg("compile", topo, "--esi", pair / "esi", "--prefer", pair / "t.yaml", "-o",
                   pair / "out.xml", "--no-cache")
    assert done.returncode == 2 and "no ESI file of the library is there" in done.stderr


def test_prefer_of_a_folder_with_both_differing_files_still_refuses(pair: Path):
    lib = Library([pair / "esi"], cache=False, prefer=[pair / "esi"])
    with pytest.raises(DuplicateError):
        lib.find("IO8")


def test_a_selector_without_revision_takes_the_highest_and_names_its_file(tmp_path: Path):
    write(tmp_path, "old.xml", esi_xml(io_device(ONE_INPUT).replace("#x00010000",
                                                                      "#x270B0000")))
    write(tmp_path, "new.xml", esi_xml(io_device(ONE_INPUT)))
    sel = Library([tmp_path], cache=False).find("0xE0F1:0x1234")
    assert sel.entry.revision == 0x270B0000
    assert f"({tmp_path / 'old.xml'}:{_device_line(tmp_path / 'old.xml')})" in str(sel.note)


# -- what differs ----------------------------------------------------------------------------

def _describe(text: str, tmp_path: Path, name: str) -> Description:
    tree = xmlsafe.parse_bytes(text.encode(), name)
    return describe(device_elements(tree)[0])


def test_differences_name_sms_pdos_and_dictionary_objects(tmp_path: Path):
    dictionary = ("<Profile><Dictionary><DataTypes><DataType><Name>USINT</Name><BitSize>8"
                  "</BitSize></DataType></DataTypes><Objects>{}</Objects></Dictionary>"
                  "</Profile>")
    obj = ("<Object><Index>#x{:04X}</Index><Name>o</Name><Type>USINT</Type><BitSize>8"
           "</BitSize></Object>")
    a = _describe(esi_xml(io_device(ONE_INPUT, sms=4, extra=dictionary.format(
        obj.format(0x8000) + obj.format(0x1000)))), tmp_path, "a.xml")
    b = _describe(esi_xml(io_device(TWO_INPUTS, sms=2, extra=dictionary.format(
        obj.format(0x1000)))), tmp_path, "b.xml")
    found = differences(a, b, "A", "B", limit=10) 
    assert "Sm count 4 vs 2" in found
    assert "TxPdo 0x1A00 entries differ" in found
    assert "dictionary: object 0x8000 only in A" in found
    # The DC op mode's name is what a topology chooses: it counts; a PDO's name does not.
    dc = ('<Dc><OpMode><Name>{}</Name><Desc>d</Desc><AssignActivate>#x300</AssignActivate>'
          '</OpMode></Dc>')
    c = _describe(esi_xml(io_device(ONE_INPUT, extra=dc.format("DC"))), tmp_path, "c.xml")
    d = _describe(esi_xml(io_device(ONE_INPUT, extra=dc.format("DC-Sync"))
                          .replace("<Name>In</Name>", "<Name>Inputs</Name>")
                          .replace("<Desc>d</Desc>", "<Desc>other text</Desc>")),
                  tmp_path, "d.xml")
    assert differences(c, d, "C", "D") == ["Dc/OpMode/Name differs"]


# -- devices, lint, apply --------------------------------------------------------------------

def test_devices_lists_duplicates_with_their_files(pair: Path):
    write(pair / "esi", "c.xml", esi_xml(io_device(TWO_INPUTS, name="a copy of b")))
    done = ecatcfg("devices", pair / "esi", "--no-cache")
    assert done.returncode == 0, done.stderr
    a, b, c = (f"{pair / 'esi' / n}:{_device_line(pair / 'esi' / n)}"
               for n in ("a.xml", "b.xml", "c.xml"))
    assert f"DIFFERENT  0xe0f1:0x1234:0x10000 (IO8): {a}, {b}, {c}" in done.stdout
    assert f"{b} vs {a}: TxPdo 0x1A00 entries differ" in done.stdout
    data = json.loads(ecatcfg("devices", pair / "esi", "--format", "json",
                              "--no-cache").stdout)
    [dup] = data["duplicates"]
    assert dup["same"] is False and [s["file"] for s in dup["sources"]] == [
        str(pair / "esi" / n) for n in ("a.xml", "b.xml", "c.xml")]
    assert [d["file"] for d in dup["differences"]] == [str(pair / "esi" / "b.xml"),
                                                        str(pair / "esi" / "c.xml")]
    # b and c alone: the same device, one line.
    done = ecatcfg("devices", pair / "esi" / "b.xml", pair / "esi" / "c.xml", "--no-cache")
    assert f"same  0xe0f1:0x1234:0x10000 (IO8): {b}, {c}" in done.stdout


def test_lint_reports_differing_and_identical_duplicates_across_files(pair: Path):
    write(pair / "esi", "c.xml", esi_xml(io_device(TWO_INPUTS, name="a copy of b")))
    done = ecatcfg("lint", pair / "esi", "--format", "json", "--select", "ESI007,ESI008")
    assert done.returncode == 1, done.stderr
    found = {(Path(f["file"]).name, f["rule"], f["line"]) for f in
             json.loads(done.stdout)["findings"]}
    line = _device_line(pair / "esi" / "a.xml")
    assert found == {("a.xml", "ESI008", line), ("b.xml", "ESI008", line),
                     ("c.xml", "ESI008", line), ("b.xml", "ESI007", line),
                     ("c.xml", "ESI007", line)}
    # The identical pair alone: info only, exit 0.
    done = ecatcfg("lint", pair / "esi" / "b.xml", pair / "esi" / "c.xml")
    assert done.returncode == 0 and "info ESI007" in done.stdout, done.stdout


def test_apply_virtual_takes_the_description_the_eni_has_unless_preferred(pair: Path):
    """The ENI compiled with b.xml has b's two input entries: of the differing pair, b
    agrees with it and is taken, said with both files (tests/test_same_identity.py has
    the rules); an ENI that neither fits is refused naming both."""
    topo = write(pair, "t.yaml", TOPOLOGY + "    esi: b.xml\n")
    eni = pair / "out.xml"
    assert ecatcfg("compile", topo, "--esi", pair / "esi", "-o", eni,
                   "--no-cache").returncode == 0
    done = ecatcfg("apply", eni, "--virtual", "--esi", pair / "esi", "--simulated-time",
                   "--cycles", "3", "--no-cache")
    assert done.returncode == 0, done.stderr
    b, a = pair / "esi" / "b.xml", pair / "esi" / "a.xml"
    words = " ".join((done.stdout + done.stderr).split())
    assert f"took {b}:{_device_line(b)}: the only description that agrees" in words
    assert f"{a}:{_device_line(a)}: TxPdo 0x1A00 entries differ from the ENI's" in words
    eni.write_text(eni.read_text().replace("<BitLen>16</BitLen>", "<BitLen>32</BitLen>"))
    done = ecatcfg("apply", eni, "--virtual", "--esi", pair / "esi", "--simulated-time",
                   "--cycles", "3", "--no-cache")
    assert done.returncode == 1
    assert "a.xml" in done.stderr and "b.xml" in done.stderr and "Traceback" not in done.stderr
    assert "none agrees with the ENI's slave 'io'" in " ".join(done.stderr.split())
    done = ecatcfg("apply", eni, "--virtual", "--esi", pair / "esi", "--prefer",
                   pair / "esi" / "b.xml", "--simulated-time", "--cycles", "3", "--no-cache")
    assert done.returncode == 0, done.stderr + done.stdout


# -- the corpus ------------------------------------------------------------------------------

def test_real_files_of_one_identity_with_different_pdos_are_refused(corpus_extra: Path):
    """Two vendor files of one identity (0xF3F:1:1): their RxPdo 0x1600 entries differ
    (read here with lxml), so a selector naming it is refused, naming both."""
    folder = corpus_extra / "esi" / "pollen"
    a, b = folder / "Orbita2d.xml", folder / "Orbita3d.xml"

    def entries(path: Path) -> list[str]:
        root = etree.parse(str(path)).getroot()
        pdo = next(p for p in root.iter("RxPdo") if p.findtext("Index") in ("#x1600",))
        return [etree.tostring(e.find("Index")) for e in pdo.iter("Entry")]

    assert entries(a) != entries(b)
    lib = Library([a, b], cache=False)
    with pytest.raises(DuplicateError, match="RxPdo 0x1600 entries differ") as err:
        lib.find("0xf3f:1:1")
    assert str(a) in str(err.value) and str(b) in str(err.value)
    assert lib.find("Orbita3d", within=lib.file_named("Orbita3d.xml")).entry.file == str(b)
    with pytest.raises(EsiChoiceError):
        lib.find("Orbita3d", within=lib.file_named("Orbita2d.xml"))


def test_real_copies_of_one_download_are_one_device(corpus: Path, corpus_extra: Path):
    files = [corpus / "esi" / "beckhoff" / "Beckhoff EK11xx.xml",
             corpus_extra / "esi" / "ethercat-esi" / "Beckhoff_EK11xx.xml"]
    lib = Library(files, cache=False)
    sel = lib.find("0x2:0x44c2c52:0x110000")
    assert sel.entry.file == str(files[0]) and sel.note is None and sel.preferred is None


def test_two_device_elements_of_one_file(tmp_path: Path):
    """The rule inside one file too: the same description twice is one device, two different
    ones are refused (lint's ESI004 reports both)."""
    write(tmp_path, "same.xml", esi_xml(io_device(ONE_INPUT), io_device(ONE_INPUT, name="x")))
    assert Library([tmp_path / "same.xml"], cache=False).find("IO8").entry.ordinal == 0
    write(tmp_path, "differ.xml", esi_xml(io_device(ONE_INPUT), io_device(TWO_INPUTS)))
    with pytest.raises(DuplicateError, match="by 2 Device elements of one file"):
        Library([tmp_path / "differ.xml"], cache=False).find("IO8")
