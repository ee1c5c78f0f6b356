"""Value syntax of ETG.2000 files: HexDecValue numbers, booleans and hexBinary.

Vendor files write numbers as ``#x1A00`` (the ETG form), ``0x1A00`` or decimal, and booleans
as ``1/0/true/false``; the schema's HexDecValue pattern is ``[+-]?[0-9]{1,}|#x[0-9|a-f|A-F]{1,}``
but real files use all three.  These functions raise ``ValueError`` with a message meant for
a person; the reader adds file and line.
"""

from __future__ import annotations

import re

# [0-9] and [0-9A-Fa-f] are ASCII-only in Python's re: no Arabic-Indic digits, no "1_000"
# (both of which int() alone would accept).  Surrounding white space is tolerated.
_DEC = re.compile(r"\s*([+-]?[0-9]+)\s*\Z")
_HEX = re.compile(r"\s*(?:#x|#X|0x|0X)([0-9A-Fa-f]+)\s*\Z")

_TRUE = frozenset(("1", "true"))
_FALSE = frozenset(("0", "false"))


def parse_int(text: str) -> int:
    """A HexDecValue: ``#x1A00``, ``0x1A00`` or decimal (optionally signed)."""
    if text.isascii() and text.isdigit():      # the common "8", "16", "1033": no regex
        return int(text)
    m = _DEC.match(text)
    if m is not None:
        return int(m.group(1))
    m = _HEX.match(text)
    if m is not None:
        return int(m.group(1), 16)
    raise ValueError(f"not a number: {text!r} (expected #x1A00, 0x1A00 or decimal)")


def parse_bool(text: str) -> bool:
    """An xs:boolean as vendors write it: ``1``, ``0``, ``true``, ``false`` (any case)."""
    s = text.strip().lower()
    if s in _TRUE:
        return True
    if s in _FALSE:
        return False
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
