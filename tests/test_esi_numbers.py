"""ESI numbers a field cannot hold: a number wider than the field, a negative
size, an object larger than an SDO can carry.  Each is an error at its file and line where
the ESI is read, never a traceback later (str() of a 4000-digit number, struct.error of a
negative length, a dictionary of 2**40 bits).  The inputs are the example drive's ESI with
one value changed; the expected line is found in the changed text, not by the reader."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

import fuzzing
from ecatcfg.cli import main
from ecatcfg.esi import reader
from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, emulated_slave

DRIVE = fuzzing.ESI_DIR / "ecatcfg-EXD402-drive.xml"
TOPOLOGY = 'master: {name: m}\nslaves:\n  - {name: d, device: "0xE0000ECA:0x7201"}\n'
HUGE = "#x" + "F" * 4000                       # 16000 bits: str() of it raises in Python


def changed(old: str, new: str) -> tuple[str, int]:
    """The drive's ESI with the first ``old`` replaced by ``new``, and that line."""
    text = DRIVE.read_text(encoding="utf-8")
    at = text.index(old)
    return text[:at] + new + text[at + len(old):], text.count("\n", 0, at) + 1


def esi_dir(tmp_path: Path, text: str) -> Path:
    (tmp_path / "esi").mkdir()
    (tmp_path / "esi" / "drive.xml").write_text(text, encoding="utf-8")
    return tmp_path / "esi"


CASES = [   # (what is changed, into what, the field as the message names it)
    ("<BitLen>16</BitLen>", f"<BitLen>{HUGE}</BitLen>", "Entry/BitLen"),
    ("<SafeopOpTimeout>10000<", f"<SafeopOpTimeout>{HUGE}<", "SafeopOpTimeout"),
    ('DefaultSize="6"', f'DefaultSize="{HUGE}"', "Sm/@DefaultSize"),
    ("<Id>#xE0000ECA</Id>", f"<Id>{HUGE}</Id>", "Vendor/Id"),
    ("<BitLen>16</BitLen>", "<BitLen>-1</BitLen>", "Entry/BitLen"),
    ("<BitLen>16</BitLen>", "<BitLen>-16</BitLen>", "Entry/BitLen"),
    ('DefaultSize="6"', 'DefaultSize="-6"', "Sm/@DefaultSize"),
    ("<BitLen>16</BitLen>", "<BitLen>65536</BitLen>", "Entry/BitLen"),  # 256.. is ESI113
]


@pytest.mark.parametrize("old, new, field", CASES, ids=[f"{c[2]}={c[1][-20:]}" for c in CASES])
def test_number_the_field_cannot_hold_is_a_located_read_problem(old, new, field):
    text, line = changed(old, new)
    esi = reader.read_bytes(text.encode(), "drive.xml")
    found = [p for p in esi.problems if p.source.line == line and field in p.message]
    assert found and "does not fit" in found[0].message, esi.problems
    assert len(found[0].message) < 200                     # the number is shown cut


@pytest.mark.parametrize("old, new, field", CASES, ids=[f"{c[2]}={c[1][-20:]}" for c in CASES])
def test_lint_and_compile_of_such_a_number_exit_without_traceback(tmp_path, capsys, old, new,
                                                                  field):
    text, line = changed(old, new)
    esi = esi_dir(tmp_path, text)
    shown = str(esi / "drive.xml")
    assert main(["lint", "--format", "json", shown]) in (0, 1)
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    assert any(f.get("line") == line and "does not fit" in f.get("message", "")
               for f in json.loads(out)["findings"]), out[:2000]
    topo = tmp_path / "t.yaml"
    topo.write_text(TOPOLOGY)
    code = main(["compile", str(topo), "--esi", str(esi), "-o", str(tmp_path / "o.xml")])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if field in ("Entry/BitLen", "Vendor/Id"):   # changes what is written: compile stops
        assert code == 1 and f"{shown}:{line}" in err, err
    code = main(["sii", "build", shown, "--device", "0xE0000ECA:0x7201", "-o", str(tmp_path / "o.bin")])
    assert code in (0, 1) and "Traceback" not in capsys.readouterr().err


# -- the emulated object dictionary -------------------------------------------------------

DICTIONARY_CASES = [
    ("<BitSize>144</BitSize>", f"<BitSize>{1 << 40}</BitSize>", "DataType/BitSize"),
    ("<BitSize>144</BitSize>", f"<BitSize>{1 << 70}</BitSize>", "DataType/BitSize"),
    ("<BitSize>32</BitSize><BitOffs>16", f"<BitSize>{1 << 48}</BitSize><BitOffs>16",
     "SubItem/BitSize"),
    ("<SubIdx>1</SubIdx>", "<SubIdx>#x7FFFFFFF</SubIdx>", "SubItem/SubIdx"),
    ("<Elements>4</Elements>", "<Elements>#x7FFFFFFF</Elements>", "ArrayInfo/Elements"),
    ("<Elements>4</Elements>", "<Elements>-4</Elements>", "ArrayInfo/Elements"),
    # Within 65535 bytes, but more elements than subindices (0x1600's array part, LBound 1).
    ("<Elements>4</Elements>", "<Elements>54956</Elements>", "CoE array"),
]


@pytest.mark.parametrize("old, new, field", DICTIONARY_CASES,
                         ids=[f"{c[2]}={c[1][-24:]}" for c in DICTIONARY_CASES])
def test_object_larger_than_an_sdo_carries_is_refused_where_read(tmp_path, old, new, field):
    text, line = changed(old, new)
    lib = Library([str(esi_dir(tmp_path, text))], cache=False)
    (entry,) = lib.entries
    device = lib.device(entry)
    problems = [p for p in reader.read_bytes(text.encode(), "drive.xml").problems
                if p.source.line == line and field in p.message]
    assert problems and "not fit" in problems[0].message
    start = time.monotonic()
    slave = emulated_slave(SlaveSpec(device))              # no MemoryError, no minutes
    assert time.monotonic() - start < 5
    assert slave.od is not None and 0x1018 in slave.od


def test_record_array_part_with_more_elements_than_subindices(tmp_path):
    # DT1C12ARR (LBound 1, the array part of 0x1C12) made a value array of 300 elements:
    # the record's SubItem without SubIdx would stand for subindices 1..300.
    text, _ = changed("<ArrayInfo><LBound>1</LBound><Elements>2</Elements>",
                      "<ArrayInfo><LBound>0</LBound><Elements>300</Elements>")
    line = text.count("\n", 0, text.index("<Type>DT1C12ARR</Type>")) + 1
    problems = [p for p in reader.read_bytes(text.encode(), "drive.xml").problems
                if p.source.line == line]
    assert problems and "300 elements" in problems[0].message
    lib = Library([str(esi_dir(tmp_path, text))], cache=False)
    od = emulated_slave(SlaveSpec(lib.device(lib.entries[0]))).od
    assert od is not None and max(od[0x1C12].entries) <= 255


def test_object_size_bound_takes_the_largest_vendor_objects():
    # 64008 bytes, the size of Beckhoff EK10xx's largest ARRAY object, is still read.
    text, line = changed("<BitSize>144</BitSize>", f"<BitSize>{64008 * 8}</BitSize>")
    esi = reader.read_bytes(text.encode(), "drive.xml")
    assert not [p for p in esi.problems if p.source.line == line]


# The dictionary's and the PDO entries' numbers and hexBinary are read inline when they are
# spelled the common way (a short decimal, hex digits in pairs); every other spelling must
# read as anywhere else: the same value, or a ReadProblem at its line.  The expected values
# are written out here, from the ETG.2000 HexDecValue and xs:hexBinary syntax.
def _dt1018(esi, i=1):
    return esi.devices[0].dictionary.data_types["DT1018"].sub_items[i]


def _info_1018(esi):
    return dict(esi.devices[0].dictionary.objects[0x1018].info.sub_items)["Vendor ID"]


def _entry(esi):
    return esi.devices[0].rx_pdos[0].entries[0]


SUB = "<SubIdx>1</SubIdx><Name>Vendor ID</Name>"
SIZE = "<BitSize>32</BitSize><BitOffs>16</BitOffs>"
DATA = "<DefaultData>CA0E00E0</DefaultData>"
ENTRY = "<SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Controlword</Name>"
SPELLINGS = [   # (what is changed, into what, the field read back, its value, the problem)
    (SUB, "<SubIdx>#x01</SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex, 1, None),
    (SUB, "<SubIdx> 1 </SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex, 1, None),
    (SUB, "<SubIdx>001</SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex, 1, None),
    (SUB, "<SubIdx>255</SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex, 255,
     None),
    (SUB, "<SubIdx>256</SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex, None,
     "SubItem/SubIdx: 0x100 does not fit 8 bits (0..255)"),
    (SUB, "<SubIdx>\u0661</SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex,
     None, "SubItem/SubIdx: not a number"),                    # an Arabic-Indic one
    (SUB, "<SubIdx></SubIdx><Name>Vendor ID</Name>", lambda e: _dt1018(e).subindex, None,
     None),                                                   # empty: as if not given
    (SIZE, "<BitSize>#x20</BitSize><BitOffs>16</BitOffs>", lambda e: _dt1018(e).bit_size, 32,
     None),
    (SIZE, "<BitSize>524280</BitSize><BitOffs>16</BitOffs>", lambda e: _dt1018(e).bit_size,
     524280, None),
    (SIZE, "<BitSize>524281</BitSize><BitOffs>16</BitOffs>", lambda e: _dt1018(e).bit_size,
     None, "SubItem/BitSize: 0x7fff9 does not fit"),
    (SIZE, "<BitSize>32</BitSize><BitOffs>0x10</BitOffs>", lambda e: _dt1018(e).bit_offset,
     16, None),
    (SIZE, "<BitSize>32</BitSize><BitOffs>1 6</BitOffs>", lambda e: _dt1018(e).bit_offset,
     None, "SubItem/BitOffs: not a number"),
    (DATA, "<DefaultData>CA 0E 00 E0</DefaultData>", lambda e: _info_1018(e).default_data,
     b"\xca\x0e\x00\xe0", None),
    (DATA, "<DefaultData>C A0E00E0</DefaultData>", lambda e: _info_1018(e).default_data,
     b"\xca\x0e\x00\xe0", None),
    (DATA, "<DefaultData>\n  CA0E00E0\n</DefaultData>", lambda e: _info_1018(e).default_data,
     b"\xca\x0e\x00\xe0", None),
    (DATA, "<DefaultData>CA0E00E</DefaultData>", lambda e: _info_1018(e).default_data, None,
     "Info/DefaultData: not hex bytes: 'CA0E00E' (odd number of digits)"),
    (DATA, "<DefaultData>CA0E00EG</DefaultData>", lambda e: _info_1018(e).default_data, None,
     "Info/DefaultData: not hex bytes"),
    (DATA, "<DefaultData></DefaultData>", lambda e: _info_1018(e).default_data, b"", None),
    (ENTRY, "<SubIndex>#x0</SubIndex><BitLen>16</BitLen><Name>Controlword</Name>",
     lambda e: _entry(e).subindex, 0, None),
    (ENTRY, "<SubIndex>300</SubIndex><BitLen>16</BitLen><Name>Controlword</Name>",
     lambda e: _entry(e).subindex, None, "Entry/SubIndex: 0x12c does not fit 8 bits"),
    (ENTRY, "<SubIndex>0</SubIndex><BitLen>65535</BitLen><Name>Controlword</Name>",
     lambda e: _entry(e).bit_len, 65535, None),
    (ENTRY, "<SubIndex>0</SubIndex><BitLen>99999</BitLen><Name>Controlword</Name>",
     lambda e: _entry(e).bit_len, None, "Entry/BitLen: 0x1869f does not fit 16 bits"),
    (ENTRY, "<SubIndex>0</SubIndex><BitLen>1_6</BitLen><Name>Controlword</Name>",
     lambda e: _entry(e).bit_len, None, "Entry/BitLen: not a number"),
]


@pytest.mark.parametrize("old, new, field, value, problem", SPELLINGS,
                         ids=[repr(c[1][:40]) for c in SPELLINGS])
def test_each_spelling_reads_as_the_syntax_says(old, new, field, value, problem):
    text, line = changed(old, new)
    esi = reader.read_bytes(text.encode(), "drive.xml")
    assert field(esi) == value
    found = [p.message for p in esi.problems if p.source.line == line]
    if problem is None:
        assert found == []
    else:
        assert len(found) == 1 and found[0].startswith(problem), found


ACCESS = '<Access WriteRestrictions="PreOp">rw</Access>'


@pytest.mark.parametrize("new, value, read, write, problem", [
    ("<Access>RW</Access>", "rw", {"PreOp", "SafeOp", "Op"}, {"PreOp", "SafeOp", "Op"}, None),
    ('<Access ReadRestrictions="PreOp_SafeOp"> ro </Access>', "ro", {"PreOp", "SafeOp"},
     {"PreOp", "SafeOp", "Op"}, None),
    ('<Access WriteRestrictions="preop_Boot">rw</Access>', "rw", {"PreOp", "SafeOp", "Op"},
     {"PreOp"}, "Access/@WriteRestrictions: unknown state 'Boot' in 'preop_Boot'"),
], ids=["no restriction", "read restricted", "unknown state"])
def test_access_restrictions_read_as_written(new, value, read, write, problem):
    text, line = changed(ACCESS, new)                     # DT1600's subindex 0 (line 60)
    esi = reader.read_bytes(text.encode(), "drive.xml")
    access = esi.devices[0].dictionary.data_types["DT1600"].sub_items[0].flags.access
    assert (access.value, access.read_states, access.write_states) == (value, read, write)
    found = [p.message for p in esi.problems if p.source.line == line]
    assert found == ([] if problem is None else [problem])
