"""``ecatcfg check ENI... --esi PATH...``: an ENI checked against itself and the ESI files of
its devices, with findings in ``lint``'s formats (text, json, junit, sarif).

Exit 0 when no finding has error severity, 1 when one does or an ENI cannot be read, 2
for usage errors and paths that do not exist.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
from pathlib import Path

FORMATS = ("text", "json", "junit", "sarif")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_prefer, add_rule_options

    p = sub.add_parser(
        "check", help="check an ENI against itself and the ESI files of its devices",
        description="Check ENI files (ours or any tool's): SyncManagers, FMMUs, frames and "
                    "working counters against the file itself; with --esi, each slave's "
                    "PDOs, CoE InitCmds, DC and mailbox against its device's ESI.",
        epilog="Rule ids and prefixes (ENI3 = every ENI3xx rule) work in --select/--ignore; "
               "`ecatcfg check --list-rules` lists them, `ecatcfg check --explain ID` "
               "explains one.")
    p.add_argument("enis", nargs="*", metavar="ENI", help="ENI file")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (repeatable; folders searched for *.xml)")
    add_prefer(p)
    p.add_argument("--format", choices=FORMATS, default="text")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="write the report to FILE (atomically) instead of stdout")
    add_rule_options(p)
    p.add_argument("--no-cache", action="store_true",
                   help="do not use the ESI index cache and the ENI plan cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.cli.options import rule_help
    from ecatcfg.eni.check import all_rules
    from ecatcfg.errors import UsageError
    from ecatcfg.esi.lint.config import split_ids
    from ecatcfg.esi.lint.rules import select_rules
    from ecatcfg.fileio import check_input

    rules = all_rules()
    if rule_help(args, rules, "check"):
        return 0
    if not args.enis:
        raise UsageError("give at least one ENI file (or --explain ID)")
    for eni in args.enis:
        check_input(eni)                    # a device node or FIFO: refused as such
        if not Path(eni).is_file():
            raise UsageError(f"{eni}: no such file" + (" (a folder: give ENI files)"
                                                        if Path(eni).is_dir() else ""))
    try:
        active = select_rules([i for v in args.select or [] for i in split_ids(v)],
                              [i for v in args.ignore or [] for i in split_ids(v)], rules)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return _check(args, active)


def _check(args: argparse.Namespace, active: frozenset[str]) -> int:
    from ecatcfg.eni.check import all_rules, check_eni
    from ecatcfg.errors import UsageError
    from ecatcfg.esi.library import Library
    from ecatcfg.esi.lint.formats import json as json_format, junit, sarif, text
    from ecatcfg.fileio import write_atomic

    library = None
    if args.esi:
        library = Library(args.esi, cache=not args.no_cache, prefer=args.prefer)
        for problem in library.problems:
            print(f"ecatcfg check: note: {problem} (its devices are not in the library)",
                  file=sys.stderr)
    else:
        print("ecatcfg check: note: no --esi given; the slaves were checked against the "
              "ENI alone", file=sys.stderr)
    notes: list[str] = []
    results = [check_eni(eni, library, active, use_cache=not args.no_cache, notes=notes)
               for eni in args.enis]
    for note in notes:          # which of differing ESI files the ENI's evidence chose
        print(f"ecatcfg check: note: {note}", file=sys.stderr)
    rules = all_rules()
    in_effect = {rid: rules[rid] for rid in sorted(active)}
    buffer = io.StringIO()
    if args.format == "text":
        to_terminal = args.output is None and sys.stdout.isatty()
        text.write(results, in_effect, buffer,
                   colour=to_terminal and "NO_COLOR" not in os.environ)
    elif args.format == "json":
        json_format.write(results, in_effect, buffer)
    elif args.format == "junit":
        junit.write(results, in_effect, buffer, tool="ecatcfg check")
    else:
        sarif.write(results, in_effect, buffer, tool="ecatcfg check", tag="eni")
    if args.output:
        try:
            write_atomic(Path(args.output), buffer.getvalue().encode())
        except OSError as exc:
            raise UsageError(f"-o {args.output}: cannot write: {exc.strerror}") from None
    else:
        sys.stdout.write(buffer.getvalue())
    return 1 if any(r.has_errors for r in results) else 0
