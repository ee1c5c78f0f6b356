"""``ecatcfg states``: show or request the AL states of the slaves on a line."""

from __future__ import annotations

import argparse
from typing import Any

STATES = ("init", "preop", "boot", "safeop", "op")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_iface, add_slave, add_timeout

    p = sub.add_parser(
        "states", help="show or request the AL states of the slaves on a line",
        description="Without STATE: each slave's AL status (0x0130) and AL status code "
                    "(0x0134).  With STATE: write it to AL control (0x0120) of every slave "
                    "(or the one at --slave), acknowledging an error indication, and wait "
                    "until each is in it or refuses it.  Slaves are addressed by position; "
                    "no ENI is needed.  Each slave is shown with the identity in its SII "
                    "(vendor:product:revision) and, with --esi, its device type.",
        epilog="Exit 1 when a slave refuses the state (its AL status code is shown) or "
               "does not reach it within --timeout, or no frame comes back.")
    add_iface(p)
    add_slave(p, required=False)
    p.add_argument("state", nargs="?", type=str.lower, choices=STATES, metavar="STATE",
                   help="request this state: init, preop, boot, safeop or op")
    add_timeout(p, 5.0, "each slave to reach STATE")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (repeatable): name each slave by the device "
                        "of its SII identity")
    p.add_argument("--no-cache", action="store_true",
                   help="read the ESI files without the index cache")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json

    from ecatcfg.cli.identity import slave_identities
    from ecatcfg.esc import AlState, al_state_name, al_status_name
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import al_tool
    from ecatcfg.runtime.master.transport import Transport

    target = AlState[args.state.upper()] if args.state else None
    library = None
    if args.esi:
        import sys

        from ecatcfg.esi.library import Library
        library = Library(args.esi, cache=not args.no_cache)
        for problem in library.problems:
            print(f"warning: {problem}", file=sys.stderr)
    with RawLink(args.iface) as link:
        transport = Transport(link)
        positions = al_tool.positions_on_line(transport, args.slave)
        # Read before a request: the SII is read over the EEPROM interface, which a
        # slave's PDI may take over in the states above INIT.
        who = slave_identities(transport, positions, library)
        if target is None:
            found = al_tool.read_states(transport, positions)
        else:
            found = al_tool.request_state(transport, positions, target, args.timeout)
    rows: list[dict[str, Any]] = [{
        "position": s.position, "al_status": s.al_status, "state": al_state_name(s.state),
        "error": s.error, "al_status_code": s.code, "al_status_text": al_status_name(s.code),
        "requested": s.requested.name if s.requested is not None else None,
        "reached": s.reached if s.requested is not None else None,
        "timed_out": s.timed_out,
        **(who[s.position].as_json() if s.position in who else {"identity": None})}
        for s in found]
    if args.format == "json":
        print(json.dumps({"slaves": rows, "count": len(rows)}, indent=2))
    else:
        for s in found:
            ident = who[s.position].text() if s.position in who else "(SII not read)"
            line = f"{s.position:>3}  {ident}  {s.text()}"
            if s.requested is not None and not s.reached:
                line += (f"  (requested {s.requested.name}: "
                         + ("not reached in time" if s.timed_out else "refused") + ")")
            print(line)
    return 0 if target is None or all(s.reached for s in found) else 1
