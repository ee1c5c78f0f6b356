"""ETG.2000 / CoE base data type names: their bit sizes and the spellings that mean the same.

ESI files name types in IEC 61131 style (``UINT``, ``UDINT``, ``STRING(12)``,
``ARRAY [0..3] OF BYTE``); some generators use the CoE (ETG.1000.6) spellings (``UNSIGNED16``,
``INTEGER32``, ``BOOLEAN``) or the short C-like ones (``UINT16``).  A dictionary's own
``DataType`` elements add record and array types by name (``DT1018``).
"""

from __future__ import annotations

import re

# Canonical IEC name -> bit size (None: variable length).
BASE_TYPES: dict[str, int | None] = {
    "BOOL": 1, "BIT": 1,
    **{f"BIT{n}": n for n in range(1, 9)},
    "BITARR8": 8, "BITARR16": 16, "BITARR32": 32,
    "BYTE": 8, "WORD": 16, "DWORD": 32, "LWORD": 64,
    "SINT": 8, "INT": 16, "INT24": 24, "DINT": 32, "INT40": 40, "INT48": 48, "INT56": 56,
    "LINT": 64,
    "USINT": 8, "UINT": 16, "UINT24": 24, "UDINT": 32, "UINT40": 40, "UINT48": 48,
    "UINT56": 56, "ULINT": 64,
    "REAL": 32, "LREAL": 64,
    "TIME_OF_DAY": 48, "TIME_DIFFERENCE": 48, "TIME": 32, "DATE": 32, "DT": 64,
    "GUID": 128,
    "STRING": None, "WSTRING": None, "OCTET_STRING": None, "UNICODE_STRING": None,
    "DOMAIN": None,
}

# Other spellings of the same types (CoE names, C-like names).
ALIASES: dict[str, str] = {
    "BOOLEAN": "BOOL",
    "INTEGER8": "SINT", "INTEGER16": "INT", "INTEGER24": "INT24", "INTEGER32": "DINT",
    "INTEGER40": "INT40", "INTEGER48": "INT48", "INTEGER56": "INT56", "INTEGER64": "LINT",
    "UNSIGNED8": "USINT", "UNSIGNED16": "UINT", "UNSIGNED24": "UINT24",
    "UNSIGNED32": "UDINT", "UNSIGNED40": "UINT40", "UNSIGNED48": "UINT48",
    "UNSIGNED56": "UINT56", "UNSIGNED64": "ULINT",
    "INT8": "SINT", "INT16": "INT", "INT32": "DINT", "INT64": "LINT",
    "UINT8": "USINT", "UINT16": "UINT", "UINT32": "UDINT", "UINT64": "ULINT",
    "REAL32": "REAL", "REAL64": "LREAL", "FLOAT": "REAL", "DOUBLE": "LREAL",
    "VISIBLE_STRING": "STRING",
}

_STRING = re.compile(r"^(W?STRING)\s*\(\s*(\d+)\s*\)$", re.IGNORECASE)
_ARRAY = re.compile(r"^ARRAY\s*\[\s*(-?\d+)\s*\.\.\s*(-?\d+)\s*\]\s*OF\s+(.+)$", re.IGNORECASE)


def canonical(name: str) -> str | None:
    """The canonical spelling of a base type name, or ``None`` if it is not a base type.

    ``STRING(n)`` and ``ARRAY [a..b] OF T`` (T a base type) count as base types and are
    returned normalised (``STRING(12)``, ``ARRAY [0..3] OF USINT``).
    """
    key = name.strip().upper()
    bounds = []
    m = _ARRAY.match(key)
    if m:                       # an array of a base type; arrays of arrays are not base types
        bounds = [int(m.group(1)), int(m.group(2))]
        key = m.group(3).strip()
    key = ALIASES.get(key, key)
    if key not in BASE_TYPES:
        m = _STRING.match(key)
        if not m:
            return None
        key = f"{m.group(1).upper()}({int(m.group(2))})"
    return f"ARRAY [{bounds[0]}..{bounds[1]}] OF {key}" if bounds else key


def bit_size(name: str) -> int | None:
    """Bit size of a base type (``None`` if variable-length or not a base type)."""
    key = canonical(name)
    if key is None:
        return None
    if key in BASE_TYPES:
        return BASE_TYPES[key]
    m = _STRING.match(key)
    if m:
        return int(m.group(2)) * (16 if m.group(1) == "WSTRING" else 8)
    m = _ARRAY.match(key)
    if m:
        element = bit_size(m.group(3))      # canonical() allows only a base element type
        count = int(m.group(2)) - int(m.group(1)) + 1
        return element * count if element is not None and count > 0 else None
    return None
