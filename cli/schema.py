"""``ecatcfg schema topology``: print the topology JSON Schema (for editor completion)."""

from __future__ import annotations

import argparse
import json
import sys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("schema", help="print a JSON Schema (topology)",
                       description="Print the JSON Schema of a file format, e.g. for editor "
                                   "completion of topology files (YAML language servers read "
                                   "'# yaml-language-server: $schema=FILE').")
    p.add_argument("what", choices=("topology",), help="which schema")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.compiler.topology import json_schema

    json.dump(json_schema(), sys.stdout, indent=2, sort_keys=True)
    sys.stdout.write("\n")
    return 0
