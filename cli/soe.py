"""``ecatcfg soe read|write``: one SoE transfer with one drive, no ENI needed."""

from __future__ import annotations

import argparse
from typing import Any

ELEMENTS = ("attribute", "name", "value")      # the flags are runtime/soe.py's ELEMENT_*

EPILOG = ("IDN as drive manuals write it (S-0-0001, P-0-0010) or as a 16-bit number "
          "(32778, 0x800A).  VALUE is hexadecimal bytes in wire order (d007, hex:d007), or "
          "a number encoded by --type (UINT, UDINT, INT, DINT, ...).  "
          "Use it on a line no other master is driving: the slave is brought to PREOP "
          "(mailbox from its SII) if it is below PREOP, and stays there.  "
          "Exit 1 on an SoE error reply (code and name on stderr), a refused state or no "
          "answer.")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_line, add_timeout

    p = sub.add_parser(
        "soe", help="read or write one IDN of a drive over SoE (servo drive profile)",
        description="One SoE transfer with drive --drive of the slave at position --slave "
                    "(0 = the first after the master): 'read' reads IDN and prints it, "
                    "'write' writes VALUE to it.",
        epilog=EPILOG)
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for action, text in (("read", "read an element of IDN and print it"),
                         ("write", "write VALUE to IDN")):
        a = actions.add_parser(action, help=text, description=f"SoE {action}: {text}.",
                               epilog=EPILOG)
        add_line(a)
        a.add_argument("--drive", type=int, default=0, metavar="N",
                       help="drive number behind the slave, 0..7 (default 0)")
        a.add_argument("idn", metavar="IDN", help="S-0-0001, P-0-0010 or a number")
        if action == "write":
            a.add_argument("value", metavar="VALUE",
                           help="hex bytes (d007) or a number with --type")
        else:
            a.add_argument("--element", choices=ELEMENTS, default="value",
                           help="what to read: the value (default), the attribute word or "
                                "the name")
        a.add_argument("--type", metavar="T",
                       help="data type to decode (read) or encode (write) the value with")
        add_timeout(a, 3.0)
        a.add_argument("--format", choices=["text", "json"], default="text")
        a.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json

    from ecatcfg.esi.idn import idn_text
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import soe_tool
    from ecatcfg.runtime.master.sdo_tool import SlaveMailbox
    from ecatcfg.runtime.master.transport import Transport
    from ecatcfg.runtime.soe import ELEMENT_ATTRIBUTE, ELEMENT_NAME, ELEMENT_VALUE

    flags = {"attribute": ELEMENT_ATTRIBUTE, "name": ELEMENT_NAME, "value": ELEMENT_VALUE}
    idn, type_name = _checked(args)
    data = _write_data(args.value, type_name) if args.action == "write" else None
    element = "value" if data is not None else args.element
    info = SlaveMailbox(args.slave)
    with RawLink(args.iface) as link:
        result = soe_tool.soe_transfer(Transport(link), args.slave, idn, data,
                                       drive_no=args.drive, elements=flags[element],
                                       timeout=args.timeout, info=info)
    out: dict[str, Any] = {"slave": args.slave, "station_address": info.station_address,
                           "drive": args.drive, "idn": idn, "idn_text": idn_text(idn),
                           "action": args.action, "element": element,
                           "al_status_before": info.state_before,
                           "mailbox_configured": info.configured}
    shown = result if data is None else data
    out.update(size=len(shown), hex=shown.hex())
    if data is None:
        out.update(_decoded(result, element, type_name))
    where = f"{idn_text(idn)} (drive {args.drive})"
    if args.format == "json":
        print(json.dumps(out, indent=2))
    elif data is None:
        text = " ".join(f"{b:02x}" for b in result) or "(no data)"
        print(f"{where} {element} = {text}  ({len(result)} byte"
              f"{'s' if len(result) != 1 else ''})")
        for key in ("value", "name", "attribute"):
            if key in out:
                print(f"{type_name or key}: {out[key]}")
    else:
        print(f"{where} <- {' '.join(f'{b:02x}' for b in data)}  ({len(data)} byte"
              f"{'s' if len(data) != 1 else ''}): done")
    return 0


def _decoded(result: bytes, element: str, type_name: str | None) -> dict[str, Any]:
    """The read data in words: a typed value, the name's text, the attribute's fields."""
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.runtime.soe import (ATTR_COMMAND, ATTR_LIST, ATTR_TYPE_SHIFT, ATTR_WP_OP,
                                     ATTR_WP_PREOP, ATTR_WP_SAFEOP, attribute_element_size,
                                     decode_list)
    if element == "name":
        try:
            text, _maximum = decode_list(result)
        except ValueError as exc:
            raise EcatcfgError(f"the name is not a Sercos string: {exc}") from None
        return {"name": text.decode("latin-1")}
    if element == "attribute":
        if len(result) != 4:
            raise EcatcfgError(f"an attribute is 4 bytes, the drive sent {len(result)}")
        word = int.from_bytes(result, "little")
        return {"attribute": {
            "word": f"0x{word:08X}", "element_size": attribute_element_size(word),
            "list": bool(word & ATTR_LIST), "command": bool(word & ATTR_COMMAND),
            "data_type": word >> ATTR_TYPE_SHIFT & 0x7,
            "write_protected": [s for s, bit in (("PREOP", ATTR_WP_PREOP),
                                                 ("SAFEOP", ATTR_WP_SAFEOP),
                                                 ("OP", ATTR_WP_OP)) if word & bit]}}
    if type_name:
        from ecatcfg.esi import datatypes
        try:
            return {"type": type_name, "value": datatypes.decode(result, type_name)}
        except ValueError as exc:
            raise EcatcfgError(f"cannot decode {result.hex()} as {type_name}: {exc}") from None
    return {}


def _checked(args: argparse.Namespace) -> tuple[int, str | None]:
    """The IDN and base type of the command line, checked (exit 2) before a link opens."""
    from ecatcfg.errors import UsageError
    from ecatcfg.esi.idn import MAX_DRIVE, parse_idn

    try:
        idn = parse_idn(args.idn, numbers=True)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not 0 <= args.drive <= MAX_DRIVE:
        raise UsageError(f"--drive {args.drive}: the SoE header numbers drives 0..{MAX_DRIVE}")
    type_name = None
    if args.type:
        from ecatcfg.esi import datatypes
        type_name = datatypes.canonical(args.type)
        if type_name is None:
            raise UsageError(f"--type {args.type}: not a base data type (UINT, UDINT, INT, "
                             "DINT, ...)")
    return idn, type_name


def _write_data(value: str, type_name: str | None) -> bytes:
    """The bytes a write sends: VALUE encoded as ``--type``, else hex bytes."""
    import re

    from ecatcfg.errors import UsageError

    if type_name is not None:
        from ecatcfg.esi.datatypes import ValueTypeError, encode
        try:
            data = encode(value, type_name)
        except ValueTypeError as exc:
            raise UsageError(f"VALUE {value!r}: {exc}") from None
    else:
        digits = re.sub(r"[\s_]", "", value[4:] if value.lower().startswith("hex:") else value)
        if not digits or not re.fullmatch(r"(?:[0-9A-Fa-f]{2})+", digits):
            raise UsageError(f"VALUE {value!r}: hexadecimal bytes (d007), or a number with "
                             "--type")
        data = bytes.fromhex(digits)
    if not data:
        raise UsageError("nothing to write: VALUE encodes to 0 bytes")
    return data
