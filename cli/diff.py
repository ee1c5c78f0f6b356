"""``ecatcfg diff A B [--format text|json]``: what differs between two ENIs (any tool's, in
any combination) or two topology files, as ``eni/diff.py`` and ``compiler/topology_diff.py``
find it; exit 0 when equal, 1 when different."""

from __future__ import annotations

import argparse
import json
import sys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("diff", help="compare two ENIs or two topologies",
                       description="Compare two ENI files (ours, TwinCAT's, EC-Engineer's) or "
                                   "two topology files by what they make the master do: "
                                   "slaves, PDO assignment and mapping, process-image "
                                   "offsets, InitCmds in words, DC and cycle time.  Comments, "
                                   "element order and a tool's spelling of the same "
                                   "commands are not differences.",
                       epilog="Exit codes: 0 equal, 1 different (or an input error), 2 usage "
                              "error or missing path.")
    p.add_argument("old", metavar="A", help="ENI or topology file (the old one)")
    p.add_argument("new", metavar="B", help="ENI or topology file of the same kind (the new one)")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="topologies: ESI files or folders to resolve each slave's device "
                        "selector with, so two spellings of one device are no difference")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.cli.inputs import kind
    from ecatcfg.eni.diff import Change
    from ecatcfg.errors import UsageError

    ka, kb = kind(args.old), kind(args.new)
    if ka != kb or ka == "esi":
        raise UsageError(f"diff compares two ENIs or two topologies, not {ka} {args.old} "
                         f"and {kb} {args.new}")
    changes: list[Change]
    if ka == "eni":
        from ecatcfg.eni.diff import diff
        from ecatcfg.eni.reader import read_file
        changes = diff(read_file(args.old), read_file(args.new))
    else:
        from ecatcfg.compiler import topology
        from ecatcfg.compiler.topology_diff import diff as topology_diff
        library = None
        if args.esi:
            from ecatcfg.esi.library import Library
            library = Library(args.esi, cache=not args.no_cache)
        changes = topology_diff(topology.load(args.old), topology.load(args.new), library)
    if args.format == "json":
        json.dump({"a": args.old, "b": args.new, "kind": ka, "equal": not changes,
                   "changes": [c.as_json() for c in changes]}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        for c in changes:
            print(c.describe())
        print(f"{len(changes)} difference{'s' if len(changes) != 1 else ''}"
              if changes else "no differences")
    return 1 if changes else 0
