"""``file:line[:col]: severity ID message``, coloured on a terminal, and a summary line.

The column is printed where the finding has one: the XML parser's (ESI001) and libxml2's
schema errors (XSD001); lxml gives an element its line only (``sourceline``), so the rules
that look at elements name the line of the start tag (docs/lint.md, "Output")."""

from __future__ import annotations

from typing import TextIO

from ecatcfg.errors import location
from ecatcfg.esi.lint.finding import FileResult, count_by_severity
from ecatcfg.esi.lint.rules import Rule

_COLOUR = {"error": "\033[1;31m", "warning": "\033[33m", "info": "\033[36m"}
_DIM, _BOLD, _RESET = "\033[2m", "\033[1m", "\033[0m"


def write(results: list[FileResult], rules: dict[str, Rule], out: TextIO,
          colour: bool = False) -> None:
    findings = [f for r in results for f in r.findings]
    for f in findings:
        where = location(f.file, f.line, f.column) or f.file
        if colour:
            out.write(f"{_BOLD}{where}{_RESET}: {_COLOUR[f.severity]}{f.severity}{_RESET} "
                      f"{_DIM}{f.rule}{_RESET} {f.message}\n")
        else:
            out.write(f"{where}: {f.severity} {f.rule} {f.message}\n")
    out.write(summary_line(results) + "\n")


def summary_line(results: list[FileResult]) -> str:
    counts = count_by_severity([f for r in results for f in r.findings])
    files = len(results)
    with_errors = sum(1 for r in results if r.has_errors)
    return (f"{files} file{'s' if files != 1 else ''} checked: {counts['error']} errors, "
            f"{counts['warning']} warnings, {counts['info']} infos"
            + (f" ({with_errors} file{'s' if with_errors != 1 else ''} with errors)"
               if with_errors else ""))
