"""The ``ecatcfg`` console script: one small module per subcommand.

Each subcommand module defines ``add_parser(subparsers)`` and ``run(args) -> int`` and imports
its heavy dependencies (lxml, the runtime, scapy) inside ``run``: building the parser for
``ecatcfg --help`` must stay cheap.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ecatcfg import __version__
from ecatcfg.errors import EcatcfgError

# Subcommands in the order --help lists them (module names in ecatcfg.cli).
SUBCOMMANDS = ("devices", "lint", "schema", "compile", "demo", "apply", "simulate", "sii",
               "scan", "sdo")

EXIT_OK, EXIT_INPUT, EXIT_USAGE = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:     # argparse's own exit code is already 2
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="ecatcfg",
        description="EtherCAT configuration compiler and network configurator: "
                    "vendor ESI files + a topology -> ENI; ENI -> a running network.",
        epilog="Exit codes: 0 success, 1 the input has errors, 2 usage error or missing path.")
    parser.add_argument("--version", action="version", version=f"ecatcfg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"ecatcfg.cli.{name}")
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        return args.run(args)
    except EcatcfgError as exc:
        print(f"ecatcfg {args.command}: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:        # `ecatcfg devices ... | head`
        sys.stderr.close()
        return EXIT_OK
