"""Each lint rule against its own failing and passing fixture (tests/lint_fixtures.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ecatcfg.esi.lint import LintOptions, Target, all_rules, lint_file, select_rules
from lint_fixtures import CASES, Case, marked_line

ALL = select_rules(None, None)


def _lint(tmp_path: Path, case: Case, text: str):
    for name, content in case.files:
        extra = tmp_path / name
        extra.parent.mkdir(parents=True, exist_ok=True)
        extra.write_text(content)
    path = tmp_path / f"{case.rule}.xml"
    path.write_text(text)
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
    for rule in all_rules().values():
        assert f"| {rule.id} | {rule.severity} | {rule.summary} |" in doc, rule.id
