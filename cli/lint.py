"""``ecatcfg lint PATH...``: validate ESI files (ETG.2000 schema + semantic rules) for CI.

Exit 0 when no finding has error severity, 1 when one does (an unparseable file is one),
2 for usage errors and paths that do not exist.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import textwrap
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from ecatcfg.esi.lint.rules import Rule

FORMATS = ("text", "json", "junit", "sarif")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "lint", help="validate ESI files: ETG.2000 schema and semantic rules",
        description="Validate ESI files and folders (searched recursively for *.xml) against "
                    "the ETG.2000 schema (--schema-dir) and ecatcfg's semantic rules.",
        epilog="Rule ids and prefixes (ESI1 = every ESI1xx rule) work in --select/--ignore "
               "and in [tool.ecatcfg.lint] of pyproject.toml; `ecatcfg lint --list-rules` "
               "lists them, `ecatcfg lint --explain ID` explains one.")
    p.add_argument("paths", nargs="*", metavar="PATH", help="ESI file or folder")
    p.add_argument("--schema-dir", metavar="DIR",
                   help="folder with the ETG.2000 XSD set (EtherCATInfo.xsd, "
                        "EtherCATModule.xsd); the schemas are not shipped with ecatcfg")
    p.add_argument("--format", choices=FORMATS, default="text")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="write the report to FILE (atomically) instead of stdout")
    p.add_argument("--select", action="append", metavar="IDS",
                   help="only these rules (comma-separated ids or prefixes; repeatable)")
    p.add_argument("--ignore", action="append", metavar="IDS",
                   help="skip these rules (comma-separated ids or prefixes; repeatable)")
    p.add_argument("--jobs", type=_positive, metavar="N",
                   help="files linted in parallel (default: the number of CPUs)")
    p.add_argument("--config", metavar="PYPROJECT",
                   help="read [tool.ecatcfg.lint] from this file (default: the nearest "
                        "pyproject.toml from the current folder up)")
    p.add_argument("--no-config", action="store_true", help="ignore pyproject.toml")
    p.add_argument("--skip-non-esi", action="store_true",
                   help="skip XML files that are not ESI files even when named directly "
                        "(as pre-commit passes every changed *.xml)")
    p.add_argument("--allow-empty", action="store_true",
                   help="exit 0 when the paths hold no ESI file to check (default: exit 2, "
                        "as a mistyped path would pass silently)")
    p.add_argument("--explain", metavar="ID", help="explain one rule and exit")
    p.add_argument("--list-rules", action="store_true", help="list every rule and exit")
    p.set_defaults(run=run)


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError("must be at least 1")
    return value


def run(args: argparse.Namespace) -> int:
    from ecatcfg.errors import UsageError
    from ecatcfg.esi.lint import config as lint_config
    from ecatcfg.esi.lint.rules import all_rules, select_rules
    from ecatcfg.fileio import check_input

    rules = all_rules()
    if args.explain:
        rule = rules.get(args.explain.strip().upper())
        if rule is None:
            raise UsageError(f"unknown rule {args.explain!r}; `ecatcfg lint --list-rules` "
                             "lists them")
        print(f"{rule.id} ({rule.severity}): {rule.summary}\n")
        print(textwrap.fill(" ".join(rule.explanation.split()), width=88))
        return 0
    if args.list_rules:
        for rule in sorted(rules.values(), key=lambda r: r.id):
            print(f"{rule.id}  {rule.severity:<7}  {rule.summary}")
        return 0
    if not args.paths:
        raise UsageError("give at least one ESI file or folder (or --explain ID)")

    if args.no_config:
        cfg = lint_config.LintConfig()
    else:
        if args.config:
            check_input(args.config, f"--config {args.config}")
        if args.config and not Path(args.config).is_file():
            raise UsageError(f"--config {args.config}: no such file")
        source = Path(args.config) if args.config else lint_config.find_pyproject(Path.cwd())
        cfg = lint_config.load(source)
    select = _ids(args.select) if args.select else cfg.select
    ignore = cfg.ignore + _ids(args.ignore or [])
    try:
        active = select_rules(select, ignore)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not active:
        raise UsageError("no rule left to check: --select/--ignore (with the config file's "
                         f"ignore list {cfg.ignore}) exclude every rule")
    schema_dir = Path(args.schema_dir) if args.schema_dir else cfg.schema_dir
    if schema_dir is not None and not schema_dir.is_dir():
        raise UsageError(f"schema folder {schema_dir}: no such folder")
    if "XSD001" not in active:
        schema_dir = None
    return _lint(args, active, schema_dir, args.jobs or cfg.jobs, rules)


def _lint(args: argparse.Namespace, active: frozenset[str], schema_dir: Path | None,
          jobs: int | None, rules: dict[str, Rule]) -> int:
    from ecatcfg.esi.lint.formats import json as json_format, junit, sarif, text
    from ecatcfg.esi.lint.runner import LintOptions, collect, lint_paths
    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import write_atomic

    targets = collect(args.paths)
    if args.skip_non_esi:
        targets = [replace(t, named_directly=False) for t in targets]
    progress = _ProgressBar(sys.stderr) if sys.stderr.isatty() and len(targets) > 1 else None
    results = lint_paths(targets, LintOptions(active, schema_dir), jobs, progress)
    if progress:
        progress.clear()
    if not results and not args.allow_empty:
        from ecatcfg.cli.inputs import no_esi_files
        raise UsageError(no_esi_files(args.paths))

    if "XSD001" in active and schema_dir is None:
        print("ecatcfg lint: note: no --schema-dir given; the ETG.2000 schema was not checked",
              file=sys.stderr)
    for missing in sorted({r.schema_missing for r in results if r.schema_missing}):
        count = sum(1 for r in results if r.schema_missing == missing)
        print(f"ecatcfg lint: note: {missing} not found; {count} file(s) with that root "
              "element were not schema-checked", file=sys.stderr)

    in_effect = {rid: rules[rid] for rid in sorted(active)}
    buffer = io.StringIO()
    if args.format == "text":
        to_terminal = args.output is None and sys.stdout.isatty()
        text.write(results, in_effect, buffer,
                   colour=to_terminal and "NO_COLOR" not in os.environ)
    else:
        {"json": json_format, "junit": junit, "sarif": sarif}[args.format].write(
            results, in_effect, buffer)
    if args.output:
        try:
            write_atomic(Path(args.output), buffer.getvalue().encode())
        except OSError as exc:
            raise UsageError(f"-o {args.output}: cannot write: {exc.strerror}") from None
    else:
        sys.stdout.write(buffer.getvalue())
    return 1 if any(r.has_errors for r in results) else 0


def _ids(values: list[str]) -> list[str]:
    from ecatcfg.esi.lint.config import split_ids
    return [i for v in values for i in split_ids(v)]


class _ProgressBar:
    """``lint [#####.....] 12/29 files`` on stderr, redrawn in place."""

    WIDTH = 30

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream

    def __call__(self, done: int, total: int) -> None:
        filled = self.WIDTH * done // total
        self.stream.write(f"\rlint [{'#' * filled}{'.' * (self.WIDTH - filled)}] "
                          f"{done}/{total} files")
        self.stream.flush()

    def clear(self) -> None:
        self.stream.write("\r" + " " * (self.WIDTH + 30) + "\r")
        self.stream.flush()
