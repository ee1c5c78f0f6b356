"""``ecatcfg pdos``: the PDO assignment and mapping a slave holds now, read over CoE."""

from __future__ import annotations

import argparse
from typing import Any


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_line, add_timeout

    p = sub.add_parser(
        "pdos", help="the PDO assignment and mapping a slave holds now (CoE)",
        description="The PDO assignment (0x1C10 + SM) of each process-data SyncManager of "
                    "the slave at position --slave (0 = the first after the master), as "
                    "0x1C00 gives their types, and the mapping of each PDO assigned, read "
                    "with SDO uploads.  With --esi the PDOs and entries are named from the "
                    "device's ESI (found by the identity in the slave's SII).",
        epilog="Use it on a line no other master is driving: a slave below PREOP is "
               "brought to PREOP (mailbox from its SII) and stays there; one in PREOP, "
               "SAFEOP or OP is read in that state.  Exit 1 on an SDO abort or no answer.")
    add_line(p)
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (searched recursively) to name PDOs and entries; "
                        "repeatable")
    add_timeout(p, 3.0)
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from ecatcfg.cli.identity import esi_device
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import pdo_tool
    from ecatcfg.runtime.master.transport import Transport

    lib = None
    if args.esi:
        from ecatcfg.esi.library import Library
        lib = Library(args.esi, cache=not args.no_cache)
        for problem in lib.problems:
            print(f"warning: {problem}", file=sys.stderr)
    device = None
    with RawLink(args.iface) as link:
        transport = Transport(link)
        if lib is not None:
            device, _where = esi_device(lib, transport, args.slave)
        held = pdo_tool.read_pdos(transport, args.slave, timeout=args.timeout)
    names = _Names(device)
    if args.format == "json":
        print(json.dumps({"slave": args.slave, "sync_managers": [
            {"sm": a.sm, "type": "outputs" if a.sm_type == pdo_tool.OUTPUTS else "inputs",
             "assign_index": a.assign_index, "bit_length": a.bit_length,
             "pdos": [{"index": p.index, "name": names.pdo(p.index),
                       "bit_length": p.bit_length,
                       "entries": [{"index": e.index, "subindex": e.subindex,
                                    "bit_length": e.bit_length,
                                    "name": names.entry(e.index, e.subindex)}
                                   for e in p.entries]}
                      for p in a.pdos]}
            for a in held]}, indent=2))
        return 0
    for a in held:
        kind = "outputs" if a.sm_type == pdo_tool.OUTPUTS else "inputs"
        pdos = ", ".join(f"0x{p.index:04X}" for p in a.pdos) or "none"
        print(f"SM{a.sm} {kind}: 0x{a.assign_index:04X} = {pdos}  ({a.bit_length} bits)")
        for p in a.pdos:
            name = names.pdo(p.index)
            print(f"  0x{p.index:04X}{'  ' + name if name else ''}  ({p.bit_length} bits)")
            for e in p.entries:
                what = "gap" if e.index == 0 else f"0x{e.index:04X}:{e.subindex:02X}"
                ename = names.entry(e.index, e.subindex)
                print(f"    {what:9} {e.bit_length:>3} bit{'  ' + ename if ename else ''}")
    return 0


class _Names:
    """PDO and entry names from the ESI device, where it has them."""

    def __init__(self, device: Any) -> None:
        self.pdos: dict[int, str] = {}
        self.entries: dict[tuple[int, int], str] = {}
        if device is None:
            return
        from ecatcfg.esi.coe import device_dictionary
        from ecatcfg.esi.model import pick_name

        for pdo in device.pdos:
            if pdo.index is not None:
                self.pdos.setdefault(pdo.index, pdo.name)
            for entry in pdo.entries:
                if entry.index:
                    self.entries.setdefault((entry.index, entry.subindex or 0), entry.name)
        dic = device_dictionary(device)
        if dic is not None:
            for index, obj in dic.objects.items():
                self.entries.setdefault((index, 0), pick_name(obj.names))

    def pdo(self, index: int) -> str | None:
        return self.pdos.get(index)

    def entry(self, index: int, subindex: int) -> str | None:
        return self.entries.get((index, subindex)) if index else None
