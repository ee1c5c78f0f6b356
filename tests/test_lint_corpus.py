"""``ecatcfg lint`` over the real vendor files of the corpus, with the ETG schema.

XSD001 runs lxml's XMLSchema (libxml2); the schema verdict and every error line are
cross-checked with an independent validator, the ``xmlschema`` package (``xsd_reference.py``
runs it), and every place where the two disagree is explained by a rule written here.
"""

from __future__ import annotations

import json
import re
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
    # EL2252 revision 0x00110000 describes RxPdo 0x1602 twice: a virtual "DC Sync Activate"
    # on a virtual SM and a real "Reserved" on SM 2 (the next revision moves it to 0x1604).
    ("beckhoff/Beckhoff EL2xxx.xml", "ESI102"): [52909],
    # One identity (0x22D2:0x201:0x0A000002), two descriptions: siitool's test copy of the
    # SOMANET drive has another dictionary (61 objects fewer; 0x1000's DefaultData among the
    # 15 objects that differ) and another SM 0 than Synapticon's file.
    ("drives/SOMANET_CiA_402.xml", "ESI008"): [16],
    ("open-stacks/siitool/Somanet_CiA402-single.xml", "ESI008"): [22],
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


# -- cross-check with an independent validator ------------------------------------------------

# xmlschema's error counts over the corpus with the 1.17 schemas (the corpus manifest records
# them for xmlschema 4.3: "schema-1.17 errors"); every other file has none.
XMLSCHEMA_ERRORS = {
    "beckhoff/Beckhoff CUxxxx.xml": 4,
    "drives/Copley_XE2_4.60.xml": 4,
    "modular/UTRIO-UC20-RTU-EC-A_20251104.xml": 789,
    "open-stacks/kickcat-xmc4800-relax/xmc4800.xml": 2,
}


@pytest.fixture(scope="module")
def reference(corpus) -> dict[str, list[dict]]:
    """xmlschema's errors per file (relative to corpus/esi), in two processes: validating
    the corpus costs it about 15 s of CPU, most of it in the four large Beckhoff files."""
    files = sorted((corpus / "esi").rglob("*.xml"), key=lambda p: -p.stat().st_size)
    groups: list[list[Path]] = [[], []]
    for path in files:                          # largest first, to the lighter group
        min(groups, key=lambda g: sum(p.stat().st_size for p in g)).append(path)
    script = Path(__file__).with_name("xsd_reference.py")
    procs = [subprocess.Popen([sys.executable, str(script), str(corpus / "schemas/esi-1.17"),
                               *map(str, group)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for group in groups]
    out: dict[str, list[dict]] = {}
    for proc in procs:
        stdout, stderr = proc.communicate(timeout=600)
        assert proc.returncode == 0, stderr
        for line in stdout.splitlines():
            result = json.loads(line)
            out[str(Path(result["file"]).relative_to(corpus / "esi"))] = result["errors"]
    assert len(out) == len(files) == 29
    return out


def _xsd001(corpus: Path, corpus_lint: dict) -> dict[str, list[dict]]:
    found: dict[str, list[dict]] = {}
    for f in corpus_lint["findings"]:
        if f["rule"] == "XSD001":
            found.setdefault(str(Path(f["file"]).relative_to(corpus / "esi")), []).append(f)
    return found


def _lint_kind(message: str) -> tuple[str, str | None]:
    """What a libxml2 message (as lint words it) reports, in xmlschema's terms."""
    m = re.match(r"Element '([^']+)': not expected here", message)
    if m:
        return "unexpected", m.group(1)
    m = re.match(r"Element '([^']+)': Missing child element", message)
    if m:
        return "incomplete", m.group(1)
    if "is not a valid value of" in message:
        return "value", None
    m = re.search(r"No match found for key-sequence \['([^']*)'\]", message)
    if m:
        return "keyref", m.group(1)
    if "Not all fields of key identity-constraint" in message:
        return "keyfield", None
    return "other", message


def test_schema_verdict_and_counts_agree_with_xmlschema(corpus, corpus_lint, reference):
    """Per file: lint finds XSD001 errors exactly where xmlschema rejects the file, and
    xmlschema's counts are those the corpus manifest records."""
    lint = _xsd001(corpus, corpus_lint)
    assert {name: len(errors) for name, errors in reference.items() if errors} == \
        XMLSCHEMA_ERRORS
    assert {name for name, errors in reference.items() if errors} == set(lint)
    # Where neither validator skips anything, the counts are equal too (UTRIO: below).
    assert {name: len(lint[name]) for name in XMLSCHEMA_ERRORS} == {
        **XMLSCHEMA_ERRORS, "modular/UTRIO-UC20-RTU-EC-A_20251104.xml": 741}


def test_every_schema_finding_is_an_error_xmlschema_reports(corpus, corpus_lint, reference):
    """Each XSD001 finding names a defect xmlschema reports at the same line:

    * "not expected here": xmlschema's "unexpected child" of that tag, which it reports on
      the parent whose content it checks; the rejected child is on the finding's line;
    * "missing child element(s)": xmlschema's "content ... is not complete" of that element;
    * a value that is not of its simple type: xmlschema's "invalid value" on that element;
    * "no match for key-sequence [V] of keyref": xmlschema reports a missing key value once,
      on the element holding the key, "(N times)": the N findings with value V lie inside
      that element;
    * "not all fields of key ... evaluate to a node": the element lacks the key's field
      (its Name); xmlschema reports the same defect as the element's content, rejected at
      that line.
    """
    lint = _xsd001(corpus, corpus_lint)
    tally: Counter = Counter()
    for name, findings in lint.items():
        ref = reference[name]
        unexplained = []
        keyrefs: Counter = Counter()
        for f in findings:
            kind, detail = _lint_kind(f["message"])
            line = f["line"]
            tally[kind] += 1
            if kind == "unexpected":
                ok = any(e["kind"] == "unexpected" and e["tag"] == detail and e["line"] == line
                         and not e["after_rejection"] for e in ref)
            elif kind == "incomplete":
                ok = any(e["kind"] == "incomplete" and e["tag"] == detail and e["line"] == line
                         for e in ref)
            elif kind == "value":
                ok = any(e["kind"] == "value" and e["line"] == line for e in ref)
            elif kind == "keyref":
                owners = [i for i, e in enumerate(ref) if e["kind"] == "keyref"
                          and e["value"] == detail and e["span"][0] <= line <= e["span"][1]]
                ok = len(owners) == 1
                if ok:
                    keyrefs[owners[0]] += 1
            elif kind == "keyfield":
                ok = any(e["kind"] == "unexpected" and e["parent_line"] == line for e in ref)
            else:
                ok = False
            if not ok:
                unexplained.append((line, f["message"]))
        assert unexplained == [], name
        # Each of xmlschema's keyref errors accounts for exactly its "N times" findings.
        assert keyrefs == {i: e["times"] for i, e in enumerate(ref) if e["kind"] == "keyref"}
    assert tally == {"unexpected": 627, "incomplete": 4, "value": 2, "keyref": 26,
                     "keyfield": 92}


def test_every_xmlschema_error_is_a_schema_finding_or_skipped_by_libxml2(corpus, corpus_lint,
                                                                        reference):
    """Each xmlschema error is reported by lint as well, except where libxml2 does not look:
    after a child that an element's content model rejects, libxml2 validates neither that
    child nor the children after it (nor anything below them); xmlschema goes on and finds
    more there (UTRIO: 64 LcId attributes on Comment elements after a misplaced Name, 92
    Flags whose content follows a rejected BitSize)."""
    lint = _xsd001(corpus, corpus_lint)
    skipped: Counter = Counter()
    for name, errors in reference.items():
        at = Counter((f["line"], _lint_kind(f["message"])[0]) for f in lint.get(name, []))
        kinds = {kind for _, kind in at}
        unexplained = []
        for e in errors:
            if e["after_rejection"]:
                skipped[e["kind"]] += 1
                continue
            if e["kind"] == "keyref":
                seen = sum(n for (line, kind), n in at.items()
                           if kind == "keyref" and e["span"][0] <= line <= e["span"][1])
                ok = seen >= e["times"]
            else:
                ok = (e["line"], e["kind"]) in at and e["kind"] in kinds
            if not ok:
                unexplained.append((e["line"], e["reason"]))
        assert unexplained == [], name
    assert skipped == {"attribute": 64, "unexpected": 92}
