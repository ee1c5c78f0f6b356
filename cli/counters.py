"""``ecatcfg counters``: the ESC error counters of every slave and port, once or watched."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ecatcfg.runtime.master.counters import SlaveCounters


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "counters", help="the ESC error counters (0x0300-0x0313) per slave and port",
        description="Read each slave's error counters by position: per port A-D invalid "
                    "frames (an error this ESC saw first), RX errors, forwarded RX errors "
                    "(seen first by an earlier ESC) and lost links; per slave ECAT "
                    "processing unit and PDI errors.  The port that counts invalid frames "
                    "is where a cable or connector is bad.  --watch reads them again every "
                    "--interval and prints what changed.",
        epilog="Exit 1 when no frame comes back or a slave does not answer.")
    p.add_argument("--iface", required=True, metavar="IF",
                   help="network interface of the EtherCAT line")
    p.add_argument("--slave", type=int, metavar="POS",
                   help="only the slave at this position (0 = first); default all")
    p.add_argument("--clear", action="store_true",
                   help="clear the counters after reading them (with --watch: at the start)")
    p.add_argument("--watch", action="store_true",
                   help="read again every --interval and print the counters that changed")
    p.add_argument("--interval", type=float, default=1.0, metavar="S",
                   help="seconds between reads with --watch (default 1)")
    p.add_argument("--rounds", type=int, metavar="N",
                   help="with --watch: stop after N reads (default: until Ctrl-C)")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="json: one object; with --watch one object per line per read")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json
    import time

    from ecatcfg.errors import UsageError
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import counters
    from ecatcfg.runtime.master.al_tool import positions_on_line
    from ecatcfg.runtime.master.transport import Transport

    if args.slave is not None and args.slave < 0:
        raise UsageError(f"--slave {args.slave}: positions count from 0")
    if args.interval <= 0:
        raise UsageError(f"--interval {args.interval}: must be positive")
    if args.rounds is not None and (args.rounds < 1 or not args.watch):
        raise UsageError("--rounds N takes N >= 1 and goes with --watch")
    with RawLink(args.iface) as link:
        transport = Transport(link)
        positions = positions_on_line(transport, args.slave)
        first = counters.read_counters(transport, positions, clear=args.clear)
        if not args.watch:
            if args.format == "json":
                print(json.dumps({"slaves": [_row(c) for c in first],
                                  "cleared": args.clear}, indent=2))
            else:
                _print_table(first, args.clear)
            return 0
        last = [counters.SlaveCounters.from_block(c.position, bytes(counters.BLOCK))
                for c in first] if args.clear else first
        if args.format == "text":
            _print_table(first, args.clear)
        else:
            print(json.dumps({"round": 0, "slaves": [_row(c) for c in first],
                              "cleared": args.clear}), flush=True)
        done = 1
        while args.rounds is None or done < args.rounds:
            time.sleep(args.interval)
            now = counters.read_counters(transport, positions)
            changed = counters.changes(last, now)
            if args.format == "json":
                print(json.dumps({"round": done, "changes": [
                    {"position": p, "counter": k, "old": old, "new": new}
                    for p, k, old, new in changed]}), flush=True)
            else:
                stamp = time.strftime("%H:%M:%S")
                for p, k, old, new in changed:
                    print(f"{stamp}  slave {p} {k}: {old} -> {new}", flush=True)
            last = now
            done += 1
    return 0


def _row(c: SlaveCounters) -> dict[str, Any]:
    return {"position": c.position,
            "ports": dict(c.present_ports()),
            "processing_unit_errors": c.processing_unit_errors, "pdi_errors": c.pdi_errors,
            "first_errors": c.first_errors()}


def _print_table(found: list[SlaveCounters], cleared: bool) -> None:
    print(f"{'pos':>3} port {'invalid':>7} {'rx err':>7} {'forward':>7} {'lost':>5}   "
          "processing unit, PDI errors")
    for c in found:
        for n, (letter, p) in enumerate(c.present_ports()):
            tail = f"   {c.processing_unit_errors}, {c.pdi_errors}" if n == 0 else ""
            print(f"{c.position:>3} {letter:>4} {p['invalid_frames']:>7} "
                  f"{p['rx_errors']:>7} {p['forwarded_rx_errors']:>7} {p['lost_links']:>5}"
                  + tail)
    for c in found:
        for port in c.first_errors():
            print(f"slave {c.position} port {port} received frames with errors first: "
                  "check the cable and connectors into that port")
    if cleared:
        print("counters cleared")
