"""Lint files: parse safely, validate against the schema, read the model, run the rules.

``lint_paths`` spreads files over worker processes (``jobs``); each worker keeps its compiled
schemas and referenced module libraries for all the files it gets.  A file that cannot be
parsed is a finding (ESI001) at the parser's line, never an exception.
"""

from __future__ import annotations

import bisect
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from lxml import etree

from ecatcfg.esi import reader, xmlsafe
from ecatcfg.esi.library import expand_paths
from ecatcfg.esi.lint.across import add_duplicate_findings
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.finding import DeviceRef, FileResult, Finding
from ecatcfg.esi.lint.rules import RULES, iter_checks
from ecatcfg.esi.lint.schema import SchemaSet
from ecatcfg.esi.model import EsiFile
from ecatcfg.esi.reader import ElementSpans
from ecatcfg.fileio import read_input


@dataclass(frozen=True, slots=True)
class LintOptions:
    active: frozenset[str]               # rule ids in effect
    schema_dir: Path | None = None


@dataclass(frozen=True, slots=True)
class Target:
    path: Path
    shown: str                           # as the user named it (joined inside folders)
    named_directly: bool


def collect(paths: list[str]) -> list[Target]:
    """The files to lint; raises UsageError for a path that does not exist."""
    targets: list[Target] = []
    for given in paths:
        targets.extend(Target(p, shown, direct) for p, shown, direct in expand_paths(given))
    return targets


# -- one file -------------------------------------------------------------------------------

_schemas: SchemaSet | None = None


def _schema_set(options: LintOptions) -> SchemaSet | None:
    global _schemas
    if options.schema_dir is None:
        return None
    if _schemas is None or _schemas.folder != options.schema_dir:
        _schemas = SchemaSet(options.schema_dir)
    return _schemas


class _Emitter:
    """Turns hits into findings for one file, keeping only the active rules."""

    def __init__(self, shown: str, active: frozenset[str]) -> None:
        self.shown = shown
        self.active = active
        self.findings: list[Finding] = []

    def add(self, rule_id: str, line: int | None, column: int | None, message: str,
            device: DeviceRef | None = None) -> None:
        if rule_id in self.active:
            self.findings.append(Finding(self.shown, line or None, column, rule_id,
                                         RULES[rule_id].severity, message, device))


def lint_file(target: Target, options: LintOptions, others: list[Path],
              known: tuple[EsiFile, ElementSpans] | None = None,
              devices: frozenset[int] | None = None) -> FileResult | None:
    """Lint one file; ``None`` for a non-ESI XML file met inside a folder (skipped).
    ``known``: the file's model and element spans, already read from the same content
    (the rules only read them), instead of parsing and reading the file again (unless a
    schema is to be validated: that needs the tree).  ``devices``: check only the Device
    elements starting at these lines (and every module): what compile's gate asks of the
    devices a topology uses; the findings of those devices are the ones a whole-file lint
    gives them, as long as no module of the file is in use (a module's InitCmds are
    checked against the dictionaries of every device of its file that takes it)."""
    start = time.perf_counter()
    result = FileResult(target.shown)
    out = _Emitter(target.shown, options.active)
    if known is not None and options.schema_dir is None:
        esi, where = known
        return _checked(target, options, others, result, out, start, esi, where, None,
                        devices)
    try:
        data = read_input(target.path, target.shown)
        tree = xmlsafe.parse_bytes(data, target.shown, strip=False)
    except (OSError, xmlsafe.XmlError) as exc:
        if isinstance(exc, OSError):
            out.add("ESI001", None, None, f"cannot read: {exc.strerror}")
        else:
            out.add("ESI001", exc.line, exc.column, exc.message)
        return _done(result, out, start)

    root_name = etree.QName(tree.getroot()).localname
    if root_name not in reader.ROOTS:
        if not target.named_directly:
            return None
        out.add("ESI001", tree.getroot().sourceline, None,
                f"root element is <{root_name}>, expected <EtherCATInfo>, <EtherCATModule> or "
                "<EtherCATInfoList>: not an ESI file")
        return _done(result, out, start)

    schema_errors = None
    schemas = _schema_set(options)
    if schemas is not None:
        schema_errors = schemas.validate(tree)
        result.schema_checked = schema_errors is not None
        if schema_errors is None:
            result.schema_missing = str(schemas.path_for(root_name))

    xmlsafe.strip_namespaces(tree)
    return _checked(target, options, others, result, out, start,
                    reader.read_tree(tree, target.shown), reader.spans_of(tree), schema_errors,
                    devices)


def _checked(target: Target, options: LintOptions, others: list[Path], result: FileResult,
             out: _Emitter, start: float, esi: EsiFile, where: ElementSpans,
             schema_errors: list[tuple[int, int | None, str]] | None,
             only: frozenset[int] | None = None) -> FileResult:
    """The rules run over a file's model, findings tied to its Device elements (``only``:
    the devices at these lines, see ``lint_file``)."""
    spans = where.devices
    if only is not None:
        # The others need not have been read (``Library.loaded``), nor their dictionaries
        # (``EsiFile.problems`` reads only the view's): a topology uses one or two devices
        # of a family file of a hundred.  A Device's span starts at its line.
        span_at = {first: (first, end) for first, end in spans}
        esi = replace(esi, devices=[d for d in esi.devices if d.source.line in only])
        spans = [span_at[d.source.line] for d in esi.devices]
    result.module_spans = where.modules
    devices = [DeviceRef(d.vendor.id, d.product_code, d.revision, d.type_name, d.source.line)
               for d in esi.devices]
    result.devices = devices
    starts = [line for line, _ in spans]

    def device_at(line: int | None) -> DeviceRef | None:
        if not line or len(spans) != len(devices):
            return None
        i = bisect.bisect_right(starts, line) - 1
        if i < 0:
            return None
        end = spans[i][1]
        return devices[i] if end is None or line < end else None

    for line, column, message in schema_errors or ():
        out.add("XSD001", line, column, message, device_at(line))

    ctx = FileContext(esi, _resolved(target.path), others)
    for rule in iter_checks(options.active):
        if rule.file_check is not None:
            for hit in rule.file_check(ctx):
                out.add(rule.id, hit.source.line, hit.column, hit.message,
                        device_at(hit.source.line))
        if rule.device_check is not None:
            for dev, ref in zip(esi.devices, devices):
                for hit in rule.device_check(dev, ctx):
                    out.add(rule.id, hit.source.line, hit.column, hit.message, ref)
    return _done(result, out, start)


def _done(result: FileResult, out: _Emitter, start: float) -> FileResult:
    result.findings = sorted(out.findings, key=Finding.sort_key)
    result.seconds = time.perf_counter() - start
    return result


# -- many files -----------------------------------------------------------------------------

def default_jobs() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                           # not on Linux
        return os.cpu_count() or 1


def lint_paths(targets: list[Target], options: LintOptions, jobs: int | None = None,
               progress: Callable[[int, int], None] | None = None) -> list[FileResult]:
    """Lint ``targets`` (in parallel when ``jobs`` > 1); results in the targets' order,
    skipped non-ESI files left out."""
    jobs = jobs or default_jobs()
    others = [_resolved(t.path) for t in targets]
    results: list[FileResult | None] = [None] * len(targets)
    done = 0
    if jobs == 1 or len(targets) < 2:
        for i, target in enumerate(targets):
            results[i] = lint_file(target, options, others)
            done += 1
            if progress:
                progress(done, len(targets))
    else:
        # Only here: the compile gate lints one file at a time, in the compiling process.
        from concurrent.futures import ProcessPoolExecutor, as_completed

        schemas = _schema_set(options)
        if schemas is not None:        # compile once here; forked workers inherit them
            for root in reader.ROOTS:
                schemas.schema_for(root)
        # Biggest files first, so no worker is left with a 3 MB file at the end.
        order = sorted(range(len(targets)), key=lambda i: -_size(targets[i].path))
        with ProcessPoolExecutor(max_workers=min(jobs, len(targets))) as pool:
            futures = {pool.submit(lint_file, targets[i], options, others): i for i in order}
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                done += 1
                if progress:
                    progress(done, len(targets))
    add_duplicate_findings([(t.path, r) for t, r in zip(targets, results) if r is not None],
                           options.active)
    return [r for r in results if r is not None]


def _resolved(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError):         # a symlink loop: reading it fails later, as ESI001
        return path.absolute()


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
