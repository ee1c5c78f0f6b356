"""``ecatcfg sdo read|write``: one SDO transfer with one slave, no ENI needed."""

from __future__ import annotations

import argparse
from typing import Any

EPILOG = ("INDEX:SUB is hexadecimal, '0x' optional: 0x1018:01, 0x6060:0, 1C12:0.  "
          "VALUE is encoded by --type (USINT, UINT, UDINT, SINT, INT, DINT, LINT, ULINT, REAL, "
          "LREAL, BOOL, STRING, ...); 'hex:0a00' gives the bytes in wire order instead.  "
          "Use it on a line no other master is driving: the slave is brought to PREOP "
          "(mailbox from its SII) if it is below PREOP, and stays there.  "
          "Exit 1 on an SDO abort (code and name on stderr), a refused state or no answer.")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_line, add_timeout

    p = sub.add_parser(
        "sdo", help="read or write one CoE object of one slave (SDO upload/download)",
        description="One SDO transfer with the slave at position --slave (0 = the first "
                    "after the master): 'read' uploads INDEX:SUB and prints it, 'write' "
                    "downloads VALUE to it.",
        epilog=EPILOG)
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for action, text in (("read", "upload INDEX:SUB and print it"),
                         ("write", "download VALUE to INDEX:SUB")):
        a = actions.add_parser(action, help=text, description=f"SDO {action}: {text}.",
                               epilog=EPILOG)
        add_line(a)
        a.add_argument("address", metavar="INDEX:SUB", help="object, e.g. 0x1018:01")
        if action == "write":
            a.add_argument("value", metavar="VALUE",
                           help="the value (encoded by --type) or hex:BYTES")
        a.add_argument("--type", metavar="T",
                       help="data type to decode (read) or encode (write) the value with"
                            + ("; required unless VALUE is hex:BYTES" if action == "write"
                               else ""))
        a.add_argument("--complete-access", action="store_true",
                       help="the whole object from SUB (0 or 1) on, in one transfer")
        add_timeout(a, 3.0)
        a.add_argument("--format", choices=["text", "json"], default="text")
        a.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import sdo_tool
    from ecatcfg.runtime.master.transport import Transport

    index, sub, type_name = _checked(args)
    data = _write_data(args.value, type_name) if args.action == "write" else None
    info = sdo_tool.SlaveMailbox(args.slave)
    with RawLink(args.iface) as link:
        result = sdo_tool.sdo_transfer(Transport(link), args.slave, index, sub, data,
                                       args.complete_access, timeout=args.timeout,
                                       info=info)
    where = f"0x{index:04X}:{sub:02X}"
    out: dict[str, Any] = {"slave": args.slave, "station_address": info.station_address,
                 "index": index, "subindex": sub, "complete_access": args.complete_access,
                 "action": args.action, "al_status_before": info.state_before,
                 "mailbox_configured": info.configured}
    decoded_error = None
    if data is None:                                    # a read
        out.update(size=len(result), hex=result.hex())
        if type_name:
            from ecatcfg.esi import datatypes
            out["type"] = type_name
            try:
                out["value"] = datatypes.decode(result, type_name)
            except ValueError as exc:
                decoded_error = f"{where}: cannot decode as {type_name}: {exc}"
    else:
        out.update(size=len(data), hex=data.hex())
    if args.format == "json":
        if decoded_error:
            out["error"] = decoded_error
        print(json.dumps(out, indent=2))
    else:
        _print_text(where, data, result, out, type_name)
    if decoded_error:
        print(f"ecatcfg sdo: {decoded_error}", file=sys.stderr)
        return 1
    return 0


def _checked(args: argparse.Namespace) -> tuple[int, int, str | None]:
    """The object address, subindex and base type of the command line, checked (exit 2)
    before a link is opened."""
    from ecatcfg.errors import UsageError
    from ecatcfg.runtime.master import sdo_tool

    try:
        index, sub = sdo_tool.parse_address(args.address)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.complete_access and sub > 1:
        raise UsageError(f"--complete-access reads or writes from subindex 0 or 1, not "
                         f"0x{sub:02X}")
    type_name = None
    if args.type:
        from ecatcfg.esi import datatypes
        type_name = datatypes.canonical(args.type)
        if type_name is None:
            raise UsageError(f"--type {args.type}: not a base data type (USINT, UINT, UDINT, "
                             "SINT, INT, DINT, REAL, STRING, ...)")
    return index, sub, type_name


def _write_data(value: str, type_name: str | None) -> bytes:
    """The bytes a write sends: ``hex:`` bytes as given, else VALUE encoded as
    ``--type``."""
    import re

    from ecatcfg.errors import UsageError

    if value.lower().startswith("hex:"):
        digits = re.sub(r"[\s_]", "", value[4:])
        if not digits or not re.fullmatch(r"(?:[0-9A-Fa-f]{2})+", digits):
            raise UsageError(f"{value!r}: hex: takes whole bytes, e.g. hex:0a00")
        data = bytes.fromhex(digits)
    else:
        if type_name is None:
            raise UsageError("write needs --type to encode VALUE (or give the bytes as "
                             "hex:0a00)")
        from ecatcfg.esi.datatypes import ValueTypeError, encode
        try:
            data = encode(value, type_name)
        except ValueTypeError as exc:
            raise UsageError(f"VALUE {value!r}: {exc}") from None
    if not data:
        raise UsageError("nothing to write: VALUE encodes to 0 bytes")
    return data


def _print_text(where: str, data: bytes | None, result: bytes, out: dict[str, Any],
                type_name: str | None) -> None:
    if data is None:
        shown = " ".join(f"{b:02x}" for b in result) or "(no data)"
        print(f"{where} = {shown}  ({len(result)} byte{'s' if len(result) != 1 else ''})")
        if "value" in out:
            value = out["value"]
            extra = (f" (0x{value & ((1 << 8 * len(result)) - 1):0{2 * len(result)}X})"
                     if isinstance(value, int) and not isinstance(value, bool) else "")
            print(f"{type_name}: {value!r}{extra}" if isinstance(value, str)
                  else f"{type_name}: {value}{extra}")
    else:
        print(f"{where} <- {' '.join(f'{b:02x}' for b in data)}  ({len(data)} "
              f"byte{'s' if len(data) != 1 else ''}): done")
