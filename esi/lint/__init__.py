"""``ecatcfg lint``: the ETG.2000 schema check plus semantic rules for ESI files.

    from ecatcfg.esi.lint import LintOptions, collect, lint_paths, select_rules
    results = lint_paths(collect(["devices/"]), LintOptions(select_rules(None, None)))

Rules live in ``checks/`` (one module per topic) and register themselves in ``rules.RULES``;
output formats are writers in ``formats/``.
"""

from ecatcfg.esi.lint.finding import DeviceRef, FileResult, Finding
from ecatcfg.esi.lint.rules import RULES, Rule, all_rules, select_rules
from ecatcfg.esi.lint.runner import LintOptions, Target, collect, lint_file, lint_paths

__all__ = ["DeviceRef", "FileResult", "Finding", "LintOptions", "RULES", "Rule", "Target",
           "all_rules", "collect", "lint_file", "lint_paths", "select_rules"]
