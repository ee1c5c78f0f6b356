"""Lint findings across the files of one run: one identity described by several files.

Each file is linted on its own (``runner.lint_file``, in worker processes); this pass then
looks at the devices of all of them, and for every vendor/product/revision that Device
elements of more than one file share, compares the descriptions (``esi/duplicates.py``, the
comparison ``compile`` and ``apply`` make): ESI007 (info) when they are the same, ESI008
(error) when they differ, saying what.  Each file of such a group gets the finding at its
Device element, naming the others.  Repeats inside one file are ESI004's.
Only files with a shared identity are parsed again.
"""

from __future__ import annotations

from pathlib import Path, PureWindowsPath

from ecatcfg.esi import xmlsafe
from ecatcfg.esi.duplicates import Description, describe, device_elements, differences
from ecatcfg.esi.lint.finding import DeviceRef, FileResult, Finding
from ecatcfg.esi.lint.rules import RULES

ACROSS = ("ESI007", "ESI008")          # the rules this pass reports
Member = tuple[int, int]                 # (index of the file's result, ordinal of the Device)


def add_duplicate_findings(results: list[tuple[Path, FileResult]],
                           active: frozenset[str]) -> None:
    """Append ESI007/ESI008 findings to ``results`` (path of each file, its result)."""
    if "ESI007" not in active and "ESI008" not in active:
        return
    groups: dict[tuple[int | None, int, int | None], list[Member]] = {}
    for i, (_, result) in enumerate(results):
        for ordinal, ref in enumerate(result.devices):
            if ref.product_code is not None:
                groups.setdefault((ref.vendor_id, ref.product_code, ref.revision),
                                  []).append((i, ordinal))
    shared = [g for g in groups.values() if len({i for i, _ in g}) > 1]
    if not shared:
        return
    descriptions = _describe(results, {i for g in shared for i, _ in g})
    for group in shared:
        for member in group:
            _report(results, descriptions, member, group, active)
    for _, result in results:
        result.findings.sort(key=Finding.sort_key)


def _describe(results: list[tuple[Path, FileResult]], files: set[int]
              ) -> dict[Member, Description]:
    found: dict[Member, Description] = {}
    for i in sorted(files):
        path, result = results[i]
        try:
            tree = xmlsafe.parse_file(path, result.file)
        except xmlsafe.XmlError:         # read once already; gone since: nothing to compare
            continue
        for ordinal, el in enumerate(device_elements(tree)):
            found[(i, ordinal)] = describe(el)
    return found


def _report(results: list[tuple[Path, FileResult]], descriptions: dict[Member, Description],
            member: Member, group: list[Member], active: frozenset[str]) -> None:
    mine = descriptions.get(member)
    if mine is None:
        return
    i, ordinal = member
    result = results[i][1]
    ref = result.devices[ordinal]
    others = [m for m in group if m[0] != i and m in descriptions]
    same = [m for m in others if descriptions[m].digest == mine.digest]
    differ = [m for m in others if descriptions[m].digest != mine.digest]
    if differ and "ESI008" in active:
        said = "; ".join(
            f"{_where(results, m)}: " + ", ".join(differences(
                mine, descriptions[m], _short(results, member), _short(results, m)))
            for m in differ)
        _add(result, "ESI008", ref, f"{ref.type!r} {ref.selector} is described differently "
             f"by {said}")
    if same and "ESI007" in active:
        _add(result, "ESI007", ref, f"{ref.type!r} {ref.selector} is described the same by "
             + ", ".join(_where(results, m) for m in same))


def _add(result: FileResult, rule: str, ref: DeviceRef, message: str) -> None:
    result.findings.append(Finding(result.file, ref.line or None, None, rule,
                                   RULES[rule].severity, message, ref))


def _where(results: list[tuple[Path, FileResult]], m: Member) -> str:
    result = results[m[0]][1]
    return f"{result.file}:{result.devices[m[1]].line}"


def _short(results: list[tuple[Path, FileResult]], m: Member) -> str:
    result = results[m[0]][1]
    return f"{PureWindowsPath(result.file).name}:{result.devices[m[1]].line}"
