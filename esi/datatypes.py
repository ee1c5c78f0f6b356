"""ETG.2000 / CoE base data types: names, bit sizes, the spellings that mean the same, and how a
value of each type is written on the wire (:func:`encode`, :func:`decode`).

ESI files name types in IEC 61131 style (``UINT``, ``UDINT``, ``STRING(12)``,
``ARRAY [0..3] OF BYTE``); some generators use the CoE (ETG.1000.6) spellings (``UNSIGNED16``,
``INTEGER32``, ``BOOLEAN``) or the short C-like ones (``UINT16``).  A dictionary's own
``DataType`` elements add record and array types by name (``DT1018``).
"""

from __future__ import annotations

import math
import re
import struct

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


def download_fits(type_name: str, size: int, length: int) -> bool:
    """Whether an SDO download of ``length`` bytes fits an object entry of ``type_name``
    that holds ``size`` bytes: a number takes exactly its size (a slave answers another
    length with abort 0x06070010); a visible, unicode or octet string also takes a shorter
    non-empty value, the rest reading as NULs (CANopen strings are as long as written).
    Lint judges ESI InitCmds by it and the emulated slave answers by it
    (runtime/segment/objects.py)."""
    base = canonical(type_name) or type_name.strip().upper()
    if base.startswith(("STRING", "WSTRING", "OCTET_STRING", "UNICODE_STRING")):
        return 0 < length <= size
    return length == size



# CoE data type codes (protocol-notes §6, SOEM ec_datatype; GUID and BITARR8/16/32 from the CoE
# DEFTYPE tables of slave stacks) and the base type names (canonical spelling) written with
# them: the SII PDO entries (esi/sii.py) and SDO Information entry descriptions give them.
COE_TYPE_NAMES: dict[int, str] = {
    0x01: "BOOL", 0x02: "SINT", 0x03: "INT", 0x04: "DINT", 0x05: "USINT", 0x06: "UINT",
    0x07: "UDINT", 0x08: "REAL", 0x09: "STRING", 0x0A: "OCTET_STRING",
    0x0B: "UNICODE_STRING", 0x0C: "TIME_OF_DAY", 0x0D: "TIME_DIFFERENCE", 0x0F: "DOMAIN",
    0x10: "INT24", 0x11: "LREAL", 0x12: "INT40", 0x13: "INT48", 0x14: "INT56", 0x15: "LINT",
    0x16: "UINT24", 0x18: "UINT40", 0x19: "UINT48", 0x1A: "UINT56", 0x1B: "ULINT",
    0x1D: "GUID", 0x2D: "BITARR8", 0x2E: "BITARR16", 0x2F: "BITARR32",
    **{0x2F + n: f"BIT{n}" for n in range(1, 9)},
}
COE_TYPES: dict[str, int] = {
    **{name: code for code, name in COE_TYPE_NAMES.items()},
    "BIT": 0x30, "WSTRING": 0x0B,
    # CoE has BYTE 0x1E, WORD 0x1F and DWORD 0x20, but real images write the unsigned type
    # of the same size (WORD -> 0x06 in the NI 9144 image, BYTE -> 0x05 in the EL2262 one)
    # and SOEM knows only those.
    "BYTE": 0x05, "WORD": 0x06, "DWORD": 0x07,
}


def coe_type(name: str | None) -> int:
    """The CoE data type code of an ESI DataType name; 0 when it has none (records, ...)."""
    if not name:
        return 0
    key = canonical(name)
    if key is None:
        return 0
    if key.startswith("STRING("):
        return COE_TYPES["STRING"]
    if key.startswith("WSTRING("):
        return COE_TYPES["WSTRING"]
    return COE_TYPES.get(key, 0)


def coe_type_name(code: int) -> str:
    """The base type name of a CoE data type code (``0x0007`` -> ``UDINT``), or the code in
    hex for one the table does not name."""
    return COE_TYPE_NAMES.get(code, f"0x{code:04X}")

# -- values on the wire ----------------------------------------------------------------------

_SIGNED = {"SINT", "INT", "INT24", "DINT", "INT40", "INT48", "INT56", "LINT"}
_FLOATS = {"REAL": "<f", "LREAL": "<d"}
_SIZED_STRING = re.compile(r"^W?STRING(?:\((\d+)\))?$")


class ValueTypeError(ValueError):
    """A value that does not fit its type (message says why)."""


def encode(value: int | float | str, type_name: str, bits: int | None = None) -> bytes:
    """The wire bytes of ``value`` as ``type_name`` (a base type; records are not values).

    CoE transfers data little-endian (ETG.1000.6); integers are range-checked against their
    type, so ``value: 300`` for a USINT is an error where the value was given, not a
    surprise on the bus."""
    base = canonical(type_name)
    if base is None:
        raise ValueTypeError(f"type {type_name!r} is not a base type; give 'data' as hex bytes")
    if base in _FLOATS:
        try:
            # YAML 1.1 reads 1e-3 (no dot) as a string: accept numbers written that way.
            number = float(value)
            return struct.pack(_FLOATS[base], number)
        except ValueError:
            raise ValueTypeError(f"{value!r} is not a number for {base}") from None
        except OverflowError:
            raise ValueTypeError(f"{value} is outside the range of {base}") from None
    m = _SIZED_STRING.match(base)
    if m:
        if not isinstance(value, str):
            raise ValueTypeError(f"{base} takes a string value")
        codec = "utf-16-le" if base.startswith("W") else "latin-1"
        try:
            data = value.encode(codec, errors="strict")
        except UnicodeEncodeError as exc:
            raise ValueTypeError(f"{value!r} has a character {base} cannot hold "
                                 f"({exc.object[exc.start]!r}); give 'data' as hex "
                                 "bytes") from None
        limit = (bits or 0) // 8 or (int(m.group(1)) if m.group(1) else 0)
        if limit and len(data) > limit:
            raise ValueTypeError(f"{value!r} is {len(data)} bytes, more than {base} "
                                 f"holds ({limit})")
        return data
    size = bit_size(base) or bits
    if size is None or base.startswith("ARRAY"):
        raise ValueTypeError(f"type {base} has no fixed size; give 'data' as hex bytes")
    if isinstance(value, float):
        if not value.is_integer():
            raise ValueTypeError(f"{value} is not an integer ({base})")
        value = int(value)
    if isinstance(value, str):
        try:
            value = int(value, 0)
        except ValueError:
            raise ValueTypeError(f"{value!r} is not an integer ({base})") from None
    signed = base in _SIGNED
    lo, hi = ((-(1 << (size - 1)), (1 << (size - 1)) - 1) if signed else (0, (1 << size) - 1))
    if not lo <= value <= hi:
        raise ValueTypeError(f"value {value} is outside {base} ({lo}..{hi})")
    return (value & ((1 << size) - 1)).to_bytes((size + 7) // 8, "little")

def decode(data: bytes, type_name: str) -> int | float | str | bool:
    """The value of ``data`` (CoE wire bytes, little-endian) as the base type ``type_name``:
    the inverse of :func:`encode`.  Raises :class:`ValueTypeError` saying why when the bytes
    do not fit the type."""
    base = canonical(type_name)
    if base is None:
        raise ValueTypeError(f"{type_name!r} is not a base data type (USINT, UINT, UDINT, "
                             "SINT, INT, DINT, REAL, STRING, ...)")
    if base.startswith(("STRING", "WSTRING", "UNICODE_STRING")):
        codec = "latin-1" if base.startswith("STRING") else "utf-16-le"
        text = data.decode(codec, errors="replace")
        return text.split("\x00", 1)[0]          # padded with NULs up to the object size
    if base in ("OCTET_STRING", "DOMAIN"):
        return data.hex()
    bits = bit_size(base)
    if bits is None or base.startswith("ARRAY"):
        raise ValueTypeError(f"type {base} has no single value; read it as hex bytes")
    size = (bits + 7) // 8
    if len(data) != size:
        raise ValueTypeError(f"{len(data)} byte{'s' if len(data) != 1 else ''} came back; "
                             f"{base} has {size}")
    if base in _FLOATS:
        value = struct.unpack(_FLOATS[base], data)[0]
        return value if math.isfinite(value) else repr(value)
    number = int.from_bytes(data, "little", signed=base in _SIGNED)
    if bits < 8 * size:                           # BOOL, BITn: the low bits only
        number &= (1 << bits) - 1
    return bool(number) if base in ("BOOL", "BIT") else number
