"""Each lint rule against its own failing and passing fixture (tests/lint_fixtures.py)."""

from __future__ import annotations

import re

from pathlib import Path

import pytest

from ecatcfg.esi.lint import LintOptions, Target, all_rules, lint_file, select_rules
from ecatcfg.esi.lint.across import ACROSS
from ecatcfg.esi.lint.runner import lint_paths
from lint_fixtures import CASES, Case, marked_line

ALL = select_rules(None, None)


def _lint(tmp_path: Path, case: Case, text: str):
    for name, content in case.files:
        extra = tmp_path / name
        extra.parent.mkdir(parents=True, exist_ok=True)
        extra.write_text(content)
    path = tmp_path / f"{case.rule}.xml"
    path.write_text(text)
    if case.rule in ACROSS:         # found by the pass over all the files of one run
        extra = [Target(tmp_path / name, str(tmp_path / name), True) for name, _ in case.files]
        return lint_paths([Target(path, str(path), True)] + extra, LintOptions(ALL), 1)[0]
    result = lint_file(Target(path, str(path), True), LintOptions(ALL), [])
    assert result is not None
    return result


def test_every_rule_has_fixtures():
    rules = all_rules()
    covered = {c.rule for c in CASES}
    semantic = {rid for rid in rules if rid != "XSD001"}
    assert semantic == covered, f"rules without fixtures: {sorted(semantic - covered)}"
    assert len(semantic) >= 25
    assert len(covered) == len(CASES), "one case per rule"


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.rule)
def test_failing_fixture_reports_the_rule_at_the_marked_line(tmp_path, case):
    result = _lint(tmp_path, case, case.failing)
    hits = [f for f in result.findings if f.rule == case.rule]
    assert hits, f"{case.rule} not reported; got {[(f.rule, f.message) for f in result.findings]}"
    assert marked_line(case.failing) in {f.line for f in hits}, \
        [(f.line, f.message) for f in hits]
    assert all(f.severity == all_rules()[case.rule].severity for f in hits)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.rule)
def test_passing_fixture_has_no_findings(tmp_path, case):
    result = _lint(tmp_path, case, case.passing)
    assert result.findings == []


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.rule)
def test_passing_fixture_is_schema_valid(tmp_path, case, corpus):
    from lxml import etree
    folder = corpus / "schemas" / "esi-1.17"
    texts = [case.passing] + [content for _, content in case.files]
    for text in texts:
        tree = etree.fromstring(text.encode()).getroottree()
        schema = etree.XMLSchema(etree.parse(str(folder / f"{tree.getroot().tag}.xsd")))
        assert schema.validate(tree), [str(e) for e in schema.error_log][:5]


def test_rules_have_summary_and_explanation():
    for rule in all_rules().values():
        assert rule.severity in ("error", "warning", "info")
        assert rule.summary and "\n" not in rule.summary and len(rule.summary) < 80, rule.id
        assert len(rule.explanation) > 80, rule.id


def test_select_and_ignore_take_ids_and_prefixes():
    assert select_rules(["ESI1"], None) == {r for r in all_rules() if r.startswith("ESI1")}
    assert "ESI101" not in select_rules(None, ["esi101"])
    assert select_rules(["ESI2"], ["ESI20"]) == {r for r in all_rules() if r.startswith("ESI21")}
    with pytest.raises(ValueError, match="ESI999"):
        select_rules(["ESI999"], None)


def test_docs_list_every_rule():
    from conftest import ROOT
    doc = (ROOT / "docs" / "lint.md").read_text()
    # The third column ("stops compile") is checked by test_esi_gate.py.
    for rule in all_rules().values():
        assert re.search(rf"^\| {rule.id} \| {rule.severity} \| (yes|no|) \| "
                         rf"{re.escape(rule.summary)} \|$", doc, re.M), rule.id


# -- cases found in review: each failed before its fix ----------------------------------------

from lint_fixtures import MAILBOX, PROFILE, drive, entry, esi, rx  # noqa: E402


def _findings(tmp_path: Path, text: str) -> list:
    path = tmp_path / "case.xml"
    path.write_text(text)
    return lint_file(Target(path, str(path), True), LintOptions(ALL), []).findings


def test_complete_access_init_cmd_judged_by_the_subindices_it_writes(tmp_path):
    def ca(sub: int, transition: str = "PS") -> str:
        return esi(drive(mailbox=MAILBOX.replace(
            "<InitCmd><Transition>PS</Transition><Index>#x8000</Index><SubIndex>0</SubIndex>"
            "<Data>0100</Data>",
            f'<InitCmd CompleteAccess="1"><Transition>{transition}</Transition><Index>#x7010'
            f"</Index><SubIndex>{sub}</SubIndex><Data>0100000000</Data>")))
    # 0x7010:00 is ro, :01 rw: a CompleteAccess write from 0 or 1 changes :01 and is fine
    assert _findings(tmp_path, ca(1)) == []
    assert _findings(tmp_path, ca(0)) == []
    ro = esi(drive(profile=PROFILE.replace(
        "<Type>DINT</Type><BitSize>32</BitSize><BitOffs>16</BitOffs><Flags><Access>rw",
        "<Type>DINT</Type><BitSize>32</BitSize><BitOffs>16</BitOffs><Flags><Access>ro"),
        mailbox=MAILBOX.replace("<InitCmd>", '<InitCmd CompleteAccess="1">').replace(
            "#x8000", "#x7010")))
    assert {f.rule for f in _findings(tmp_path, ro)} == {"ESI302"}


def test_objects_of_a_second_profile_count(tmp_path):
    second = PROFILE.replace("<Profile>", '<Profile Channel="2">').replace(
        "#x6000", "#x6800").replace("#x7000", "#x7800").replace("#x7010", "#x7810").replace(
        "#x8000", "#x8800")
    text = esi(drive(profile=PROFILE + "\n" + second,
                     rx=rx(entry=entry("#x7800", 0, 16, "UINT"))))
    assert _findings(tmp_path, text) == []


def test_every_repeated_identity_is_reported(tmp_path):
    text = esi(drive(), drive(type_name="B"), drive(type_name="C"))
    assert [f.message.split("'")[1] for f in _findings(tmp_path, text)
            if f.rule == "ESI004"] == ["B", "C"]


@pytest.mark.parametrize("control, rule", [("#x68", "ESI207"), ("#x65", "ESI207"),
                                           ("#x66", "ESI206")])
def test_reserved_control_byte_bits(tmp_path, control, rule):
    text = esi(drive(sm2=f'<Sm ControlByte="{control}" DefaultSize="2" Enable="1" '
                         'StartAddress="#x1100">Outputs</Sm>'))
    hits = [f for f in _findings(tmp_path, text) if f.rule in ("ESI206", "ESI207")]
    assert [f.rule for f in hits] == [rule]
    if control == "#x68":
        assert "reserved" in hits[0].message


def test_nested_array_type_is_unknown_not_a_crash(tmp_path):
    deep = "ARRAY [0..1] OF " * 5000 + "BYTE"
    text = esi(drive(rx=rx(entry=entry("#x7000", 0, 16, deep))))
    assert "ESI303" in {f.rule for f in _findings(tmp_path, text)}


def test_thousands_of_sync_managers_are_cheap(tmp_path):
    # 3000 identical SMs overlap pairwise: a pairwise pass would report ~4.5 million
    # overlaps.  Beyond the ESC's 16 SMs only ESI211 reports, and the pairwise rules skip.
    sms = "\n".join('<Sm ControlByte="#x64" DefaultSize="2" Enable="1" '
                    'StartAddress="#x1100">Outputs</Sm>' for _ in range(3000))
    found = _findings(tmp_path, esi(drive(sm2=sms)))
    assert "ESI211" in {f.rule for f in found}
    assert not {"ESI201", "ESI202"} & {f.rule for f in found}     # no pairwise flood
    assert len(found) < 10
