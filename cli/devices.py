"""``ecatcfg devices PATH... [--format text|json]``: list the devices in ESI files/folders."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from ecatcfg.esi.index import DeviceEntry
    from ecatcfg.esi.library import Library


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("devices", help="list the devices in ESI files and folders",
                       description="List every device in the given ESI files and folders "
                                   "(searched recursively for *.xml).")
    p.add_argument("paths", nargs="+", metavar="PATH", help="ESI file or folder")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--allow-empty", action="store_true",
                   help="exit 0 when the paths hold no ESI file (default: exit 2)")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the index cache ($XDG_CACHE_HOME/ecatcfg)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.cli.inputs import no_esi_files
    from ecatcfg.errors import UsageError
    from ecatcfg.esi.library import Library

    lib = Library(args.paths, cache=not args.no_cache)
    if not lib.files and not lib.problems and not args.allow_empty:
        raise UsageError(no_esi_files(args.paths))
    report(lib, args.format, sys.stdout)
    return 1 if lib.problems else 0


def report(lib: Library, fmt: str, out: TextIO) -> None:
    """Print the listing; problems and warnings go to stderr, naming file and line."""
    for problem in lib.problems:
        print(f"error: {problem}", file=sys.stderr)
    for lf, ref in lib.unresolved_references():
        print(f"warning: {lf.shown}: InfoReference {ref!r}: module library not found among "
              "the given paths", file=sys.stderr)
    duplicates = _duplicates(lib)
    if fmt == "json":
        json.dump({"devices": [e.as_json() for e in lib.entries],
                   "duplicates": [d.as_json() for d in duplicates],
                   "errors": [{"file": p.file, "line": p.line, "message": p.message}
                              for p in lib.problems]}, out, indent=1)
        out.write("\n")
        return
    rows = [(_selector(e), e.type, e.name,
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
    if duplicates:
        differ = sum(1 for d in duplicates if d.differing)
        out.write(f"{len(duplicates)} identities described more than once ({differ} "
                  "differently: compile and apply refuse them unless told which file):\n")
    for d in duplicates:
        first = d.entries[0]
        where = ", ".join(f"{e.file}:{e.line}" for e in d.entries)
        out.write(f"  {'DIFFERENT' if d.differing else 'same'}  {_selector(first)} "
                  f"({first.type}): {where}\n")
        for e, items in d.differing:
            out.write(f"    {e.file}:{e.line} vs {first.file}:{first.line}: "
                      f"{', '.join(items)}\n")


@dataclass(frozen=True, slots=True)
class _Duplicate:
    """One identity that several Device elements describe, and how they differ."""

    entries: list[DeviceEntry]
    differing: list[tuple[DeviceEntry, list[str]]]   # against the first; empty: the same

    def as_json(self) -> dict[str, Any]:
        first = self.entries[0]
        return {"vendor_id": first.vendor_id, "product_code": first.product_code,
                "revision": first.revision, "type": first.type, "same": not self.differing,
                "sources": [{"file": e.file, "line": e.line} for e in self.entries],
                "differences": [{"file": e.file, "line": e.line, "items": items}
                                for e, items in self.differing]}


def _duplicates(lib: Library) -> list[_Duplicate]:
    return [_Duplicate(group, lib.differing(group)) for group in lib.duplicates()]


def _selector(e: DeviceEntry) -> str:
    return f"{_hex(e.vendor_id)}:{_hex(e.product_code)}:{_hex(e.revision)}"


def _hex(value: int | None) -> str:
    return "?" if value is None else f"0x{value:x}"
