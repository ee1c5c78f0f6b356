"""``ecatcfg devices PATH... [--format text|json]``: list the devices in ESI files/folders."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("devices", help="list the devices in ESI files and folders",
                       description="List every device in the given ESI files and folders "
                                   "(searched recursively for *.xml).")
    p.add_argument("paths", nargs="+", metavar="PATH", help="ESI file or folder")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the index cache ($XDG_CACHE_HOME/ecatcfg)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.esi.library import Library

    lib = Library(args.paths, cache=not args.no_cache)
    report(lib, args.format, sys.stdout)
    return 1 if lib.problems else 0


def report(lib: Library, fmt: str, out: TextIO) -> None:
    """Print the listing; problems and warnings go to stderr, naming file and line."""
    for problem in lib.problems:
        print(f"error: {problem}", file=sys.stderr)
    for lf, ref in lib.unresolved_references():
        print(f"warning: {lf.shown}: InfoReference {ref!r}: module library not found among "
              "the given paths", file=sys.stderr)
    if fmt == "json":
        json.dump({"devices": [e.as_json() for e in lib.entries],
                   "errors": [{"file": p.file, "line": p.line, "message": p.message}
                              for p in lib.problems]}, out, indent=1)
        out.write("\n")
        return
    rows = [(f"{_hex(e.vendor_id)}:{_hex(e.product_code)}:{_hex(e.revision)}", e.type, e.name,
             f"{e.rx_pdos}/{e.tx_pdos}", ",".join(e.mailbox) or "-",
             ",".join(e.dc_opmodes) or "-",
             f"{e.slots}/{e.modules}" if e.slots or e.modules else "-", f"{e.file}:{e.line}")
            for e in lib.entries]
    header = ("SELECTOR", "TYPE", "NAME", "RX/TX", "MAILBOX", "DC", "SLOTS/MODS", "SOURCE")
    widths = [min(max(len(r[i]) for r in rows + [header]), 40) for i in range(len(header) - 1)]
    for row in [header] + rows:
        cells = [c if len(c) <= w else c[:w - 1] + "…" for c, w in zip(row, widths)]
        out.write("  ".join(c.ljust(w) for c, w in zip(cells, widths)) + "  " + row[-1] + "\n")
    out.write(f"{len(lib.entries)} devices in {len(lib.files)} files\n")


def _hex(value: int | None) -> str:
    return "?" if value is None else f"0x{value:x}"
