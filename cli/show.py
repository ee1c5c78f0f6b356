"""``ecatcfg show``: one ESI device, or an ENI's network, in words.

    ecatcfg show ESI... --device SELECTOR [--objects] [--format text|json]
    ecatcfg show ENI [--format text|json]

What is shown comes from ``esi/show.py`` and ``eni/show.py``; this module only formats it
(bold headings on a terminal through rich, plain text in a pipe).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from ecatcfg.eni.show import EniView


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("show", help="show an ESI device or an ENI's network",
                       description="Show one device of ESI files (--device), or an ENI's "
                                   "slaves, process image, cyclic frames and InitCmds in "
                                   "words.  Works on any tool's ENI.")
    p.add_argument("paths", nargs="+", metavar="FILE",
                   help="one ENI file, or ESI files and folders with --device")
    p.add_argument("--device", metavar="SELECTOR",
                   help="the ESI device: Type name or VENDOR:PRODUCT[:REVISION]")
    p.add_argument("--objects", action="store_true",
                   help="with --device: the object dictionary, access per state")
    p.add_argument("--prefer", action="append", default=[], metavar="PATH",
                   help="with --device: the ESI file whose description wins where several "
                        "describe the device differently")
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index and ENI plan caches")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.cli.inputs import require_eni
    from ecatcfg.errors import UsageError

    if args.device is not None:
        return _show_esi(args)
    if len(args.paths) != 1:
        raise UsageError("show takes one ENI file (or ESI files with --device)")
    require_eni(args.paths[0], esi_hint="name the device with --device")
    return _show_eni(args)


def _show_esi(args: argparse.Namespace) -> int:
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esi import show
    from ecatcfg.esi.library import Library

    lib = Library(args.paths, cache=not args.no_cache, prefer=args.prefer)
    if lib.problems:
        for problem in lib.problems:
            print(f"error: {problem}", file=sys.stderr)
        raise EcatcfgError(f"{len(lib.problems)} ESI file problem(s)")
    selection = lib.find(args.device)
    if selection.note:
        print(f"note: {selection.note}", file=sys.stderr)
    device = lib.device(selection.entry)
    result = show.with_modules(show.summary(device, args.objects),
                               list(lib.modules_for(selection.entry).values()))
    if args.format == "json":
        json.dump(result, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        _esi_text(result, _Out(sys.stdout))
    return 0


def _show_eni(args: argparse.Namespace) -> int:
    from ecatcfg.eni import show
    from ecatcfg.eni.cache import PlanCache, read_file
    from ecatcfg.eni.reader import read_file as read_uncached

    path = args.paths[0]
    plan = read_uncached(path) if args.no_cache else read_file(path, cache=PlanCache())
    view = show.summary(plan, path)
    if args.format == "json":
        json.dump(show.as_json(view), sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        _eni_text(view, _Out(sys.stdout))
    return 0


class _Out:
    """Plain lines; headings in bold through rich when the output is a terminal."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.console: Any = None
        if stream.isatty():
            from rich.console import Console
            self.console = Console(file=stream, highlight=False)

    def heading(self, text: str) -> None:
        if self.console is not None:
            self.console.print(text, style="bold", markup=False)
        else:
            self.stream.write(text + "\n")

    def line(self, text: str) -> None:
        self.stream.write(text + "\n")


def _hex(value: int | None, digits: int = 4) -> str:
    return "-" if value is None else f"0x{value:0{digits}X}"


def _flags(p: dict[str, Any]) -> str:
    names = [n for n in ("fixed", "mandatory", "virtual") if p[n]]
    if p["default"]:
        names.append(f"default sm {p['sm']}")
    if p["excludes"]:
        names.append("excludes " + " ".join(_hex(x) for x in p["excludes"]))
    return f" [{', '.join(names)}]" if names else ""


def _pdo_lines(out: _Out, pdos: list[dict[str, Any]], indent: str = "  ") -> None:
    for p in pdos:
        out.line(f"{indent}{_hex(p['index'])} {p['name']!r} {p['bit_length']} bit{_flags(p)}")
        for e in p["entries"]:
            where = e["entry"] or "gap"
            out.line(f"{indent}  {where:<10} {e['bit_len'] or 0:>3} bit  "
                     f"{e['type'] or '-':<8} {e['name']}")


def _esi_text(r: dict[str, Any], out: _Out) -> None:
    out.heading(f"{r['type']}  {r['selector']}  {r['name']}")
    out.line(f"  vendor {r['vendor']!r}, {r['file']}:{r['line']}")
    mbx = r["mailbox"]
    out.line("  mailbox: " + (", ".join(mbx["protocols"]) or "none" if mbx else "none"))
    if mbx and mbx["coe"]:
        out.line("  CoE: " + ", ".join(k for k, v in mbx["coe"].items() if v))
    out.heading("SyncManagers")
    for sm in r["sms"]:
        out.line(f"  sm {sm['number']} {sm['type'] or '-':<8} start {_hex(sm['start'])} "
                 f"size {sm['default_size'] if sm['default_size'] is not None else '-'} ctrl {_hex(sm['control'], 2)} enable {sm['enable']}")
    for title, key in (("RxPDOs (outputs)", "rx_pdos"), ("TxPDOs (inputs)", "tx_pdos")):
        out.heading(title)
        _pdo_lines(out, r[key])
    if r["dc_opmodes"]:
        out.heading("DC OpModes")
        for m in r["dc_opmodes"]:
            out.line(f"  {m['name']:<12} AssignActivate {_hex(m['assign_activate'])}  "
                     f"{m['desc'] or ''}")
    if r["slots"]:
        out.heading("Slots")
        for s in r["slots"]:
            out.line(f"  {s['name']!r} {s['min']}..{s['max']}: "
                     f"{' '.join([_hex(i, 8) for i in s['modules']] + s['module_classes'])} "
                     f"(default {_hex(s['default'], 8)})"
                     + (f", slot group {s['slot_group']}" if s.get("slot_group") is not None
                        else ""))
    if r.get("modules"):
        out.heading("Modules")
        for m in r["modules"]:
            out.line(f"  {_hex(m['ident'], 8)} {m['type']} {m['name']!r}")
            _pdo_lines(out, m["rx_pdos"] + m["tx_pdos"], "    ")
    if "objects" in r:
        out.heading("Objects (access PreOp/SafeOp/Op, PDO mapping)")
        for o in r["objects"]:
            out.line(f"  {_hex(o['index'])} {o['name']!r} {o['type']}")
            for e in o["entries"]:
                acc = "/".join(e["access"].values()) if e["access"] else "-"
                out.line(f"    :{e['subindex'] or 0:02X} {e['name']!r} {e['type']} "
                         f"{acc}{' map ' + e['pdo_mapping'] if e['pdo_mapping'] else ''}")


def _eni_text(view: EniView, out: _Out) -> None:
    out.heading(f"{view.file}: {len(view.slaves)} slaves")
    for s in view.slaves:
        where = "passive" if s.passive else f"#{s.position} @{s.phys_addr}"
        behind = f" behind {s.parent!r}" + (f" port {s.port}" if s.port else "") \
            if s.parent else ""
        out.line(f"  {where:<10} {s.name!r} 0x{s.vendor_id:08X}:0x{s.product_code:08X}:"
                 f"0x{s.revision:08X}{behind}")
    out.heading(f"Process image: {view.inputs_size} bytes in, {view.outputs_size} out")
    for v in view.variables:
        out.line(f"  {v.direction:<3} {v.offset:>8} {v.bit_size:>4} bit "
                 f"{v.data_type or '-':<6} {v.name}")
    out.heading("Cyclic frames")
    for k, f in enumerate(view.frames):
        out.line(f"  frame {k}" + (f" (cycle {f.cycle_time_us} us)" if f.cycle_time_us
                                   else ""))
        for c in f.commands:
            wkc = "-" if c.wkc is None else str(c.wkc)
            address = f"0x{c.addr:08X}" if c.addr is not None else \
                f"{c.adp or 0}:0x{c.ado or 0:04X}"
            out.line(f"    {c.cmd:<4} {address:<12} len {c.length:<5} wkc {wkc:<3} "
                     f"{'/'.join(c.states)}")
            for copy_line in c.copies:      # after a valid receive, before the next send
                out.line(f"      {copy_line}")
    if view.unsupported:
        out.heading("Not applied by ecatcfg (apply refuses them unless --skip-unsupported)")
        for u in view.unsupported:
            out.line(f"  {repr(u.slave) + ': ' if u.slave else ''}{u.element}: {u.describe()}")
    if view.ignored:
        out.heading("Ignored: metadata ecatcfg does not read there (it changes nothing sent)")
        for u in view.ignored:
            out.line(f"  {repr(u.slave) + ': ' if u.slave else ''}{u.element}: {u.describe()}")
    out.heading("InitCmds")
    if view.master_init_cmds:
        out.line("  master")
        for t, words in view.master_init_cmds.items():
            for w in words:
                out.line(f"    {t}  {w}")
    for s in view.slaves:
        if not s.init_cmds:
            continue
        out.line(f"  {s.name!r}")
        for t, words in s.init_cmds.items():
            for w in words:
                out.line(f"    {t}  {w}")
