"""``{"findings": [...], "summary": {...}}`` as the command-line contract defines it
(``docs/architecture.md``)."""

from __future__ import annotations

import json
from typing import TextIO

from ecatcfg.esi.lint.finding import FileResult, count_by_severity
from ecatcfg.esi.lint.rules import Rule


def write(results: list[FileResult], rules: dict[str, Rule], out: TextIO) -> None:
    findings = [f for r in results for f in r.findings]
    counts = count_by_severity(findings)
    by_rule: dict[str, int] = {}
    for f in findings:
        by_rule[f.rule] = by_rule.get(f.rule, 0) + 1
    doc = {
        "findings": [f.as_json() for f in findings],
        "summary": {
            "files": len(results),
            "files_with_errors": sum(1 for r in results if r.has_errors),
            "errors": counts["error"], "warnings": counts["warning"], "infos": counts["info"],
            "by_rule": dict(sorted(by_rule.items())),
            "schema_checked": sum(1 for r in results if r.schema_checked),
        },
    }
    json.dump(doc, out, indent=1)
    out.write("\n")
