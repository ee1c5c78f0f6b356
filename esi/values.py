"""Value syntax of ETG.2000 files: HexDecValue numbers, booleans and hexBinary.

Vendor files write numbers as ``#x1A00`` (the ETG form), ``0x1A00`` or decimal, and booleans
as ``1/0/true/false``; the schema's HexDecValue pattern is ``[+-]?[0-9]{1,}|#x[0-9|a-f|A-F]{1,}``
but real files use all three.  These functions raise ``ValueError`` with a message meant for
a person; the reader adds file and line.
"""

from __future__ import annotations

import re

# [0-9] and [0-9A-Fa-f] are ASCII-only in Python's re: no Arabic-Indic digits, no "1_000"
# (both of which int() alone would accept).  Surrounding white space and a sign are tolerated
# (ENI exporters write negative numbers in decimal; a sign before hex digits costs nothing).
# The value is not range-checked here: each reader checks it against the field it fills
# (an absurd ByteSize is a lint finding of its own).  Only the length is bounded, below the
# 4300 digits beyond which int() refuses a string.
_NUMBER = re.compile(
    r"\s*([+-]?)(?:([0-9]{1,4000})|(?:#x|#X|0x|0X)([0-9A-Fa-f]{1,4000}))\s*\Z")

_BOOLEANS = {"1": True, "true": True, "0": False, "false": False}


def parse_int(text: str) -> int:
    """A HexDecValue: ``#x1A00``, ``0x1A00`` or decimal (optionally signed).  The one number
    syntax of the project: the ESI reader, the ENI reader and the topology file use it."""
    if len(text) <= 20 and text.isascii() and text.isdigit():   # "8", "16", "1033": fast
        return int(text)
    m = _NUMBER.match(text)
    if m is None:
        raise ValueError(f"not a number: {text!r} (expected #x1A00, 0x1A00 or decimal)")
    sign, dec, hexa = m.groups()
    value = int(dec) if dec is not None else int(hexa, 16)
    return -value if sign == "-" else value


def parse_bool(text: str) -> bool:
    """An xs:boolean as vendors write it: ``1``, ``0``, ``true``, ``false`` (any case)."""
    value = _BOOLEANS.get(text.strip().lower())
    if value is not None:
        return value
    raise ValueError(f"not a boolean: {text!r} (expected 1, 0, true or false)")


def parse_hex_bytes(text: str) -> bytes:
    """An xs:hexBinary, bytes in file order; white space between digits is tolerated."""
    s = "".join(text.split())
    try:
        return bytes.fromhex(s)
    except ValueError:
        raise ValueError(f"not hex bytes: {text[:40]!r}"
                         + (" (odd number of digits)" if len(s) % 2 else "")) from None


def format_hex(value: int, width: int = 0) -> str:
    """``0x``-prefixed hex the way selectors and messages print numbers."""
    return f"0x{value:0{width}x}" if width else f"0x{value:x}"
