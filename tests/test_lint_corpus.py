"""``ecatcfg lint`` over the real vendor files in ../shared/corpus/esi, with the ETG schema."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from lxml import etree

from conftest import ROOT

# Vendors whose files TwinCAT accepts: an error finding there is either a real defect of the
# file (listed here, with the reason) or a false positive, i.e. a bug in a rule.
TRUSTED = ("beckhoff", "drives/Elmo", "drives/IS620N", "drives/SV660", "drives/SOMANET",
           "open-stacks/siitool/Somanet", "drives/C5-E")
KNOWN_DEFECTS = {
    # Profile/Dictionary without Objects (the schema requires them) in four CU2508 revisions.
    ("beckhoff/Beckhoff CUxxxx.xml", "XSD001"): [488, 522, 738, 957],
}


@pytest.fixture(scope="module")
def corpus_lint(corpus) -> dict:
    out = subprocess.run(
        [sys.executable, "-m", "ecatcfg", "lint", str(corpus / "esi"), "--format", "json",
         "--schema-dir", str(corpus / "schemas" / "esi-1.17"), "--no-config"],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in out.stderr
    assert out.returncode == 1          # UTRIO, Copley, KickCAT and CUxxxx fail the schema
    assert "not found" not in out.stderr and "not checked" not in out.stderr
    return json.loads(out.stdout)


def _lxml_errors(path: Path, schemas: Path) -> list[int]:
    tree = etree.parse(str(path))
    root = etree.QName(tree.getroot()).localname
    schema = etree.XMLSchema(etree.parse(str(schemas / f"{root}.xsd")))
    schema.validate(tree)
    return [e.line for e in schema.error_log]


def test_schema_findings_match_lxml(corpus, corpus_lint):
    schemas = corpus / "schemas" / "esi-1.17"
    lines = Counter()
    for f in corpus_lint["findings"]:
        if f["rule"] == "XSD001":
            lines[f["file"]] += 1
    files = sorted((corpus / "esi").rglob("*.xml"))
    assert len(files) == 29 and corpus_lint["summary"]["files"] == 29
    rejected = 0
    for path in files:
        expected = _lxml_errors(path, schemas)
        assert lines[str(path)] == len(expected), path.name
        rejected += bool(expected)
    assert rejected == 4


def test_utrio_schema_errors_at_lxml_lines(corpus, corpus_lint):
    path = corpus / "esi" / "modular" / "UTRIO-UC20-RTU-EC-A_20251104.xml"
    ours = sorted(f["line"] for f in corpus_lint["findings"]
                  if f["file"] == str(path) and f["rule"] == "XSD001")
    theirs = sorted(_lxml_errors(path, corpus / "schemas" / "esi-1.17"))
    assert len(ours) == 741
    assert ours == theirs


def test_no_unexplained_errors_on_trusted_vendor_files(corpus, corpus_lint):
    base = str(corpus / "esi") + "/"
    errors: dict[tuple[str, str], list[int]] = {}
    for f in corpus_lint["findings"]:
        rel = f["file"].removeprefix(base)
        if f["severity"] == "error" and rel.startswith(TRUSTED):
            errors.setdefault((rel, f["rule"]), []).append(f["line"])
    assert errors == KNOWN_DEFECTS


def test_every_finding_is_located(corpus_lint):
    for f in corpus_lint["findings"]:
        assert isinstance(f["line"], int) and f["line"] >= 1, f
