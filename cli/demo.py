"""``ecatcfg demo``: the main job on the embedded default (the README's first command).

Until the compiler and the runtime exist this lists the example devices that ship inside the
package; later it compiles the example topology and applies it to a virtual segment.
"""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on the embedded example",
                       description="Show what ecatcfg does on the example files shipped "
                                   "inside the package; needs no arguments and no hardware.")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.cli.devices import report
    from ecatcfg.esi.library import Library
    from ecatcfg.examples import example_dir

    folder = example_dir()
    if args.format == "text":
        print(f"Example ESI files shipped with ecatcfg ({folder}):\n")
    lib = Library([folder])
    report(lib, args.format, sys.stdout)
    return 1 if lib.problems else 0
