"""``ecatcfg scan``: which slaves are on the line, by their SII identity."""

from __future__ import annotations

import argparse
import re
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ecatcfg.esi.evidence import SiiEvidence
    from ecatcfg.esi.index import DeviceEntry
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.master.scan import FoundSlave
    from ecatcfg.runtime.master.transport import Transport
    from ecatcfg.runtime.wiring import Plug


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "scan", help="list the slaves on a line (SII identity, ESI names)",
        description="Count the slaves on the line and read each one's identity (vendor, "
                    "product, revision, serial) from its SII EEPROM and its DL status, "
                    "addressed by position: nothing but the SII interface registers is "
                    "written.  The DL statuses show where each slave is plugged (column "
                    "'behind': parent position and port A-D).  With --esi the devices are "
                    "named from the ESI files; --topology-out writes a topology file for "
                    "the slaves found, with parent and port where the network branches.",
        epilog="Exit 1 when no frame comes back (nothing on the interface, or not an "
               "EtherCAT line).")
    p.add_argument("--iface", required=True, metavar="IF",
                   help="network interface of the EtherCAT line")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (searched recursively) to name the devices; "
                        "repeatable")
    p.add_argument("--topology-out", metavar="FILE",
                   help="write a topology (YAML) for the slaves found")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    p.set_defaults(run=run)


def slave_name(type_name: str | None, used: dict[str, int]) -> str:
    """A unique topology name: the ESI Type lower-cased (runs of other characters become
    '_') and a number counting that type from 1; 'slave' when the device is unknown."""
    base = re.sub(r"[^a-z0-9]+", "_", (type_name or "").strip().lower()).strip("_")
    base = base or "slave"
    used[base] = used.get(base, 0) + 1
    return f"{base}_{used[base]}"


def topology_yaml(rows: list[dict[str, Any]], iface: str) -> str:
    """The topology text for the slaves found (names and exact device selectors), with
    ``parent`` and ``port`` for each slave the DL statuses show plugged elsewhere than
    simply behind the slave before it (see :func:`simply_behind`)."""
    lines = [f"# Written by 'ecatcfg scan --iface {iface}': the slaves found, in bus order.",
             "# Devices are VENDOR:PRODUCT:REVISION from each slave's SII EEPROM; parent and",
             "# port (A-D = ESC ports 0-3) where the DL statuses show a branch.",
             "slaves:"]
    for row in rows:
        shown = " ".join((row["type"] or "").split())
        note = f"  # {shown}" if shown else "  # not in the ESI files given"
        plug = "" if row["simply_behind"] or row["parent"] is None else \
            f", parent: {row['parent']}, port: {row['port']}"
        lines.append(f"  - {{name: {row['topology_name']}, device: \"{row['selector']}\""
                     f"{plug}}}{note}")
    return "\n".join(lines) + "\n"


def simply_behind(plug: Plug | None, position: int, physics: str | None) -> bool:
    """Whether a topology may leave out where a slave is plugged: on port B of the slave
    before it, unless that slave's ESI ``Physics`` (``physics``) has a port D, which the
    default plugging would take first (processing order D, B, C).  An unknown device
    before it is taken for one with two ports, as on a line."""
    return (plug is not None and plug.parent == position - 1 and plug.port == 1
            and (physics is None or len(physics.strip()) <= 3))


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from ecatcfg.cli.paths import output_file

    if args.topology_out:
        output_file(args.topology_out, stdout=False)     # stdout has the table
    lib = None
    if args.esi:
        from ecatcfg.esi.library import Library
        lib = Library(args.esi, cache=not args.no_cache)
        for problem in lib.problems:
            print(f"warning: {problem}", file=sys.stderr)

    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master.scan import scan
    from ecatcfg.runtime.master.transport import Transport
    from ecatcfg.esc import PORT_LETTERS

    with RawLink(args.iface) as link:
        transport = Transport(link)
        found = scan(transport)
        chosen = {s.position: _esi_entry(lib, s, transport) for s in found} \
            if lib is not None else {}

    used: dict[str, int] = {}
    rows: list[dict[str, Any]] = []          # the JSON output's slaves
    physics: list[str | None] = []
    for s in found:
        exact, other, note = chosen.get(s.position, (None, None, None))
        entry = exact or other
        physics.append(lib.device(entry).physics if lib is not None and entry else None)
        parent = rows[s.plug.parent] if s.plug is not None else None
        rows.append({
            "position": s.position, "vendor_id": s.vendor_id,
            "product_code": s.product_code, "revision": s.revision, "serial_no": s.serial_no,
            "type": entry.type.strip() if entry else None,
            "name": entry.name.strip() if entry else None,
            "file": entry.file if entry else None, "line": entry.line if entry else None,
            "exact": exact is not None, "note": note,
            "selector": f"0x{s.vendor_id:x}:0x{s.product_code:x}:0x{s.revision:x}",
            "topology_name": slave_name(entry.type if entry else None, used),
            "dl_status": s.dl_status,
            "parent": parent["topology_name"] if parent is not None else None,
            "parent_position": parent["position"] if parent is not None else None,
            "port": PORT_LETTERS[s.plug.port] if s.plug is not None else None,
            "simply_behind": s.plug is None or simply_behind(
                s.plug, s.position, physics[s.plug.parent]),
        })

    if args.topology_out:
        if not rows:
            from ecatcfg.errors import EcatcfgError
            raise EcatcfgError(f"no slaves answered on {args.iface}: no topology written to "
                               f"{args.topology_out}")
        from ecatcfg.fileio import write_atomic
        write_atomic(args.topology_out, topology_yaml(rows, args.iface).encode())

    if args.format == "json":
        print(json.dumps({"slaves": rows, "count": len(rows),
                          "topology": args.topology_out}, indent=2))
        return 0
    _print_table(rows, args.iface)
    if args.topology_out:
        print(f"topology written to {args.topology_out}")
    return 0


def _esi_entry(lib: Library, s: FoundSlave, transport: Transport
               ) -> tuple[DeviceEntry | None, DeviceEntry | None, str | None]:
    """The library's entry of a found slave (``Library.entry_for_identity``).  Where
    several ESI files describe its identity differently, its SII is read from its EEPROM
    and the description that agrees with it is taken (``esi/evidence.py``), said in the
    note; one that cannot be read leaves the choice to the files' order, said too."""
    evidence = None
    if lib.differs(s.vendor_id, s.product_code, s.revision):
        evidence, why = sii_evidence(transport, s.position)
        if evidence is None:
            exact, other, note = lib.entry_for_identity(s.vendor_id, s.product_code,
                                                        s.revision)
            return exact, other, f"several ESI files describe it differently; {why}"
    return lib.entry_for_identity(s.vendor_id, s.product_code, s.revision, evidence)


def sii_evidence(transport: Transport, position: int) -> tuple[SiiEvidence | None, str]:
    """The SII of the slave at ``position``, read from its EEPROM, as evidence; else None
    and why not."""
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esi.evidence import SiiEvidence
    from ecatcfg.esi.sii import decode
    from ecatcfg.runtime.master.eeprom import Eeprom

    shown = f"slave {position}"
    try:
        image = decode(Eeprom(transport, position).read(), source=shown)
    except EcatcfgError as exc:
        return None, f"its SII could not be read to choose ({exc.message})"
    return SiiEvidence(image, shown), ""


def _print_table(rows: list[dict[str, Any]], iface: str) -> None:
    print(f"{len(rows)} slave{'s' if len(rows) != 1 else ''} on {iface}")
    if rows:
        print(f"{'pos':>3}  {'vendor':10} {'product':10} {'revision':10} {'serial':10}  "
              f"{'behind':8} {'type':14} name")
        for r in rows:
            behind = f"{r['parent_position']}:{r['port']}" if r["parent"] else "master"
            print(f"{r['position']:>3}  0x{r['vendor_id']:08x} 0x{r['product_code']:08x} "
                  f"0x{r['revision']:08x} 0x{r['serial_no']:08x}  {behind:8} "
                  f"{(r['type'] or '-')[:14]:14} {r['name'] or '-'}"
                  + (f"  ({r['note']})" if r["note"] else ""))
