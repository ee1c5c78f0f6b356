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
