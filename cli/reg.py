"""``ecatcfg reg read|write``: ESC registers of one slave, with names and fields."""

from __future__ import annotations

import argparse
import re
from typing import Any

EPILOG = ("ADDR is hexadecimal ('0x' optional), LEN decimal bytes: 0x0130:6, 0x0800:16, 110.  "
          "Without LEN the length of the register starting at ADDR (AL status 2, SM 8, "
          "FMMU 16, ...).  DATA: a number (0x.. or decimal) written little-endian over "
          "LEN bytes, or hex:BYTES in wire order.  Known registers (DL status, AL, "
          "counters, watchdogs, FMMUs, SyncManagers, DC) are shown with their fields.  "
          "Exit 1 when the slave does not answer or answers with working counter 0.")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("reg", help="read or write ESC registers of one slave",
                       description="Read (APRD) or write (APWR, then read back) registers "
                                   "of the slave at position --slave; no ENI needed.",
                       epilog=EPILOG)
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for action, text in (("read", "read ADDR[:LEN] and decode it"),
                         ("write", "write DATA at ADDR[:LEN] and read it back")):
        a = actions.add_parser(action, help=text, description=f"reg {action}: {text}.",
                               epilog=EPILOG)
        a.add_argument("--iface", required=True, metavar="IF",
                       help="network interface of the EtherCAT line")
        a.add_argument("--slave", required=True, type=int, metavar="POS",
                       help="position of the slave on the line (0 = first)")
        a.add_argument("address", metavar="ADDR[:LEN]", help="register, e.g. 0x0130:6")
        if action == "write":
            a.add_argument("data", metavar="DATA", help="a number, or hex:BYTES")
        a.add_argument("--format", choices=["text", "json"], default="text")
        a.set_defaults(run=run)


_ADDR = re.compile(r"^\s*(?:0x)?([0-9a-f]{1,4})\s*(?::\s*(\d+))?\s*$", re.IGNORECASE)


def parse_address(text: str, data: str | None) -> tuple[int, int | None]:
    """``0x0130:6`` -> (0x130, 6); the length is None when not given."""
    m = _ADDR.match(text)
    if not m:
        raise ValueError(f"{text!r} is not ADDR[:LEN] (hexadecimal address, decimal "
                         "length: 0x0130:6)")
    return int(m.group(1), 16), int(m.group(2)) if m.group(2) else None


def encode(data: str, length: int | None) -> bytes:
    """DATA as bytes: hex:BYTES as given, a number little-endian over ``length``."""
    if data.lower().startswith("hex:"):
        digits = re.sub(r"[\s_]", "", data[4:])
        if not digits or not re.fullmatch(r"(?:[0-9A-Fa-f]{2})+", digits):
            raise ValueError(f"{data!r}: hex: takes whole bytes, e.g. hex:0200")
        raw = bytes.fromhex(digits)
        if length is not None and len(raw) != length:
            raise ValueError(f"{data!r} is {len(raw)} bytes, LEN says {length}")
        return raw
    try:
        value = int(data, 0)
    except ValueError:
        raise ValueError(f"{data!r} is neither a number nor hex:BYTES") from None
    if length is None:
        raise ValueError("give LEN (ADDR:LEN) to write a number to an unknown register")
    if not 0 <= value < 1 << 8 * length:
        raise ValueError(f"{data} does not fit {length} byte{'s' if length != 1 else ''}")
    return value.to_bytes(length, "little")


def run(args: argparse.Namespace) -> int:
    import json

    from ecatcfg.errors import UsageError
    from ecatcfg.runtime.link import RawLink
    from ecatcfg import registers as register_fields
    from ecatcfg.runtime.master import reg_tool
    from ecatcfg.runtime.master.transport import Transport

    if args.slave < 0:
        raise UsageError(f"--slave {args.slave}: positions count from 0")
    try:
        address, length = parse_address(args.address, None)
        if length is None:
            reg = register_fields.known(address)
            if reg is not None:
                length = reg.size
            elif args.action == "read":
                raise ValueError(f"0x{address:04X} is not the start of a register this "
                                 "tool knows: give its length (ADDR:LEN)")
        data = encode(args.data, length) if args.action == "write" else None
        reg_tool.check_range(address, len(data) if data is not None else length or 0)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    with RawLink(args.iface) as link:
        transport = Transport(link)
        if data is None:
            assert length is not None
            got = reg_tool.read(transport, args.slave, address, length)
        else:
            got = reg_tool.write(transport, args.slave, address, data)
    decoded = register_fields.decode(address, got)
    if args.format == "json":
        out: dict[str, Any] = {
            "slave": args.slave, "action": args.action, "address": address,
            "length": len(got), "hex": got.hex(),
            "written": data.hex() if data is not None else None,
            "registers": [{"address": d.address, "size": d.size, "name": d.name,
                           "value": d.value, "fields": d.fields} for d in decoded]}
        print(json.dumps(out, indent=2))
        return 0
    if data is not None:
        print(f"0x{address:04X} <- {' '.join(f'{b:02x}' for b in data)}")
    print(f"0x{address:04X}:{len(got)} = {' '.join(f'{b:02x}' for b in got)}")
    for d in decoded:
        text = register_fields.fields_text(d.fields)
        print(f"  0x{d.address:04X} {d.name} = 0x{d.value:0{2 * d.size}X}"
              + (f": {text}" if text else ""))
    return 0
