"""The ``ecatcfg`` console script: one small module per subcommand.

Each subcommand module defines ``add_parser(subparsers)`` and ``run(args) -> int`` and imports
its heavy dependencies (lxml, the runtime, scapy) inside ``run``: building the parser for
``ecatcfg --help`` must stay cheap.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import NoReturn

from ecatcfg import __version__
from ecatcfg.errors import EcatcfgError

# Subcommands in the order --help lists them (module names in ecatcfg.cli, but see MODULES).
SUBCOMMANDS = ("devices", "lint", "check", "schema", "compile", "show", "diff", "report",
               "export", "demo", "apply", "simulate", "sii", "scan", "sdo", "od", "pdos", "watch",
               "states", "reg", "counters", "graph", "doctor", "alias",
               "soe", "foe")
# A subcommand whose module is not named after it: cli/report.py is apply's progress and
# tables, older than the `report` command.
MODULES = {"report": "network_report"}

EXIT_OK, EXIT_INPUT, EXIT_USAGE = 0, 1, 2


class _Version(argparse.Action):
    """``--version``: the package's version, and whether the cyclic frames go through the
    compiled exchange or the pure-Python fallback (an install built without a C compiler,
    or ``ECATCFG_PURE_PYTHON=1``: docs/architecture.md).  The runtime's link module is
    imported only when asked, not by every command's parser."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> NoReturn:
        from ecatcfg.runtime.link import cyclic_exchange_path
        print(f"ecatcfg {__version__}\ncyclic exchange: {cyclic_exchange_path()}")
        parser.exit()


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:     # argparse's own exit code is already 2
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or with ``only`` the one subcommand about to run.

    Each subcommand module costs its import and its ``add_parser``; ``ecatcfg apply`` at
    startup should not pay about 12 ms for the other nine (bench/startup.py).
    """
    parser = _Parser(
        prog="ecatcfg",
        description="EtherCAT configuration compiler and network configurator: "
                    "vendor ESI files + a topology -> ENI; ENI -> a running network.",
        epilog="Exit codes: 0 success, 1 the input has errors, 2 usage error or missing path.")
    parser.add_argument("--version", action=_Version, nargs=0,
                        help="show the version and the cyclic exchange in use, and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in (only,) if only else SUBCOMMANDS:
        module = importlib.import_module(f"ecatcfg.cli.{MODULES.get(name, name)}")
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # A known subcommand first: its parser alone gives the same parse, usage and --help.
    parser = build_parser(argv[0] if argv and argv[0] in SUBCOMMANDS else None)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        code: int = args.run(args)
        return code
    except EcatcfgError as exc:
        print(f"ecatcfg {args.command}: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:        # `ecatcfg devices ... | head`
        sys.stderr.close()
        return EXIT_OK


def console() -> None:
    """The console script and ``python -m ecatcfg``: :func:`main`, then a fast exit.

    Every subcommand has closed its files and sockets by the time it returns, so the
    interpreter's teardown (module and object clean-up, 9-25 ms, more with a big plan) is
    pure delay for a command a startup script waits on.  ``os._exit`` skips it after the
    standard streams are flushed; no part of ecatcfg registers atexit handlers.
    """
    code = main()
    for stream in (sys.stdout, sys.stderr):
        # `ecatcfg devices ... | head`: main may have closed stderr after a broken pipe,
        # and a stream whose reader is gone cannot take the rest; either way, nothing
        # more can be said, and the exit code stays main's.
        try:
            if stream is not None and not stream.closed:
                stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
