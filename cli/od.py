"""``ecatcfg od``: a slave's object dictionary as the slave describes it (SDO Information),
optionally compared with its ESI dictionary."""

from __future__ import annotations

import argparse
from typing import Any

EPILOG = ("Use it on a line no other master is driving: the slave is brought to PREOP "
          "(mailbox from its SII) if it is below PREOP, and stays there.  With --esi the "
          "device is found by the identity in the slave's SII, and every object missing on "
          "the slave or differing in data type, bit length or access is listed (objects "
          "only the slave has are listed apart and do not fail); types are compared by "
          "their ETG.1020 meaning, access by the states it allows, and communication "
          "entries an ESI types otherwise than ETG.1000.6 are noted as the ESI's "
          "(ESI).  With --values each entry's value is uploaded and shown beside it "
          "(CoE-Online); write one with 'ecatcfg sdo write'.  Exit 1 on "
          "an SDO information error of the list or an object, no answer, or (with --esi) a "
          "difference.")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_line, add_timeout

    p = sub.add_parser(
        "od", help="upload a slave's object dictionary (SDO Information), compare with "
                   "its ESI",
        description="The object dictionary of the slave at position --slave (0 = the "
                    "first after the master), uploaded with SDO Information (ETG.1000.6): "
                    "the list of all objects, each object's description (object code, "
                    "data type, max subindex, name) and each entry's (data type, bit "
                    "length, access per state, PDO mapping, name).",
        epilog=EPILOG)
    add_line(p)
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (searched recursively) to compare with; "
                        "repeatable")
    p.add_argument("--values", action="store_true",
                   help="upload each entry's value too (a record or array with one complete "
                        "access where the slave takes it) and show it beside the entry; "
                        "write a value with 'ecatcfg sdo write'")
    add_timeout(p, 3.0)
    p.add_argument("--pcap", metavar="FILE",
                   help="record every frame sent and received as pcapng (Wireshark)")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from ecatcfg.cli.identity import esi_device
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import od_tool
    from ecatcfg.runtime.master.transport import Transport

    lib = None
    if args.esi:
        from ecatcfg.esi.library import Library
        lib = Library(args.esi, cache=not args.no_cache)
        for problem in lib.problems:
            print(f"warning: {problem}", file=sys.stderr)
    recorder = None
    if args.pcap:
        from ecatcfg.cli.paths import output_file
        from ecatcfg.runtime.pcap import PcapRecorder
        output_file(args.pcap, stdout=False)
        recorder = PcapRecorder(args.pcap)
    device = None
    esi_where = None
    try:
        with RawLink(args.iface) as link:
            transport = Transport(link, recorder=recorder)
            if lib is not None:
                device, esi_where = esi_device(lib, transport, args.slave)
            # The ESI's CoE@CompleteAccess, where it is at hand, says whether to try it.
            coe = device.mailbox.coe if device is not None and device.mailbox else None
            objects = od_tool.upload_dictionary(
                transport, args.slave, timeout=args.timeout, values=args.values,
                complete_access=coe is None or coe.complete_access)
    finally:
        if recorder is not None:
            recorder.close()
    differences: list[str] | None = None
    extras: list[str] = []
    notes: list[str] = []
    if device is not None:
        found = od_tool.compare_with_esi(objects, device)
        differences, extras, notes = found.differences, found.extras, found.esi_notes
    if args.format == "json":
        out: dict[str, Any] = {"slave": args.slave, "objects": od_tool.as_json(objects)}
        if differences is not None:
            out.update(esi=esi_where, differences=differences, extras=extras,
                       esi_notes=notes)
        print(json.dumps(out, indent=2))
    else:
        _print_text(objects, args.values)
        if differences is not None:
            print(f"compared with {esi_where}: "
                  + ("no differences" if not differences
                     else f"{len(differences)} difference"
                          f"{'s' if len(differences) != 1 else ''}"))
            for line in differences:
                print(f"  {line}")
            for line in extras:
                print(f"  (more) {line}")
            for line in notes:
                print(f"  (ESI) {line}")
    return 1 if differences else 0


def _print_text(objects: Any, values: bool) -> None:
    from ecatcfg.esi.datatypes import coe_type_name
    from ecatcfg.runtime.mailbox import OBJECT_CODE_NAMES, abort_name
    from ecatcfg.runtime.master.od_tool import access_short, value_text

    print(f"{len(objects)} object{'s' if len(objects) != 1 else ''}")
    for obj in objects:
        d = obj.description
        kind = OBJECT_CODE_NAMES.get(d.object_code, str(d.object_code))
        print(f"0x{d.index:04X}  {kind:6} {d.name}")
        for e in obj.entries.values():
            pdo = "".join(c for c, bit in (("R", 0x40), ("T", 0x80)) if e.access & bit)
            value = ""
            if e.subindex in obj.values:
                value = f" = {value_text(e, obj.values[e.subindex])}"
            elif e.subindex in obj.value_aborts:
                code = obj.value_aborts[e.subindex]
                value = f" = (upload aborted 0x{code:08X} {abort_name(code)})"
            print(f"  :{e.subindex:02X}  {coe_type_name(e.data_type):12} "
                  f"{e.bit_length:>4} bit  {access_short(e.access):12} {pdo:2} {e.name}"
                  f"{value}")
        for sub, code in obj.missing.items():
            print(f"  :{sub:02X}  (SDO information error 0x{code:08X})")
    if values:
        print("write a value with: ecatcfg sdo write --iface IF --slave POS INDEX:SUB VALUE")
