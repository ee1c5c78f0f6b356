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
# Only the length is bounded here, below the 4300 digits beyond which int() refuses a string;
# the value is bounded by parse_int's ``lo``/``hi``: by default to what 64 bits hold (no
# ETG.2000 or ETG.2100 number field is wider: ULINT/LINT are the widest CoE integers), and
# by the readers to what their field holds (esi/reader.py).  A wider number left in the
# model would make every later str(), f-string or json.dump of it raise (Python's
# 4300-digit limit for int -> decimal str).
_NUMBER = re.compile(
    r"\s*([+-]?)(?:([0-9]{1,4000})|(?:#x|#X|0x|0X)([0-9A-Fa-f]{1,4000}))\s*\Z")

INT64_MIN = -(1 << 63)
UINT64_MAX = (1 << 64) - 1
# Beyond every number the syntax can spell (4,000 hex digits): as ``lo``/``hi``, a reader
# that checks the field's own range afterwards, with its own words, gets any number.
SPELLABLE = 1 << 16000

_BOOLEANS = {"1": True, "true": True, "0": False, "false": False}


def parse_int(text: str, lo: int = INT64_MIN, hi: int = UINT64_MAX) -> int:
    """A HexDecValue: ``#x1A00``, ``0x1A00`` or decimal (optionally signed), in ``lo..hi``
    (by default what 64 bits hold, signed or not).  The one number syntax of the project:
    the ESI reader, the ENI reader and the topology file use it."""
    if len(text) <= 18 and text.isascii() and text.isdigit():   # "8", "16", "1033": fast
        value = int(text)
    else:
        m = _NUMBER.match(text)
        if m is None:
            raise ValueError(f"not a number: {text[:40]!r} (expected #x1A00, 0x1A00 or "
                             "decimal)")
        sign, dec, hexa = m.groups()
        value = int(dec) if dec is not None else int(hexa, 16)
        if sign == "-":
            value = -value
    if lo <= value <= hi:
        return value
    raise ValueError(f"{shown_number(value)} does not fit {range_text(lo, hi)}")


def shown_number(value: int) -> str:
    """A number for a message, whatever its size: in hex (no digit limit, unlike decimal),
    cut in the middle beyond 64 bits."""
    digits = f"{abs(value):x}"
    if len(digits) > 16:
        digits = f"{digits[:8]}...{digits[-4:]} ({len(digits)} hex digits)"
    return f"{'-' if value < 0 else ''}0x{digits}"


def range_text(lo: int, hi: int) -> str:
    """``0..65535 (16 bits)``: a range as messages name it."""
    if lo == INT64_MIN and hi == UINT64_MAX:
        return "64 bits"
    if lo == 0 and hi & (hi + 1) == 0:
        return f"{hi.bit_length()} bits (0..{hi})"
    return f"{lo}..{hi}"


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
