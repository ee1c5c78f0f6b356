"""Typed SDO values: a user's ``value`` encoded little-endian by the object's data type.

CoE transfers data little-endian (ETG.1000.6); integers are range-checked against their type
so ``value: 300`` for a USINT is an error at the topology line, not a surprise on the bus.
"""

from __future__ import annotations

import re
import struct

from ecatcfg.esi import datatypes

_SIGNED = {"SINT", "INT", "INT24", "DINT", "INT40", "INT48", "INT56", "LINT"}
_FLOATS = {"REAL": "<f", "LREAL": "<d"}
_STRING = re.compile(r"^W?STRING(?:\((\d+)\))?$")


class SdoValueError(ValueError):
    """A value that does not fit its type (message says why)."""


def encode(value: int | float | str, type_name: str, bit_size: int | None = None) -> bytes:
    """The wire bytes of ``value`` as ``type_name`` (a base type; records are not values)."""
    base = datatypes.canonical(type_name)
    if base is None:
        raise SdoValueError(f"type {type_name!r} is not a base type; give 'data' as hex bytes")
    if base in _FLOATS:
        try:
            # YAML 1.1 reads 1e-3 (no dot) as a string: accept numbers written that way.
            number = float(value)
            return struct.pack(_FLOATS[base], number)
        except ValueError:
            raise SdoValueError(f"{value!r} is not a number for {base}") from None
        except OverflowError:
            raise SdoValueError(f"{value} is outside the range of {base}") from None
    m = _STRING.match(base)
    if m:
        if not isinstance(value, str):
            raise SdoValueError(f"{base} takes a string value")
        codec = "utf-16-le" if base.startswith("W") else "latin-1"
        try:
            data = value.encode(codec, errors="strict")
        except UnicodeEncodeError as exc:
            raise SdoValueError(f"{value!r} has a character {base} cannot hold "
                                f"({exc.object[exc.start]!r}); give 'data' as hex "
                                "bytes") from None
        limit = (bit_size or 0) // 8 or (int(m.group(1)) if m.group(1) else 0)
        if limit and len(data) > limit:
            raise SdoValueError(f"{value!r} is {len(data)} bytes, more than {base} "
                              f"holds ({limit})")
        return data
    size = datatypes.bit_size(base) or bit_size
    if size is None or base.startswith("ARRAY"):
        raise SdoValueError(f"type {base} has no fixed size; give 'data' as hex bytes")
    if isinstance(value, float):
        if not value.is_integer():
            raise SdoValueError(f"{value} is not an integer ({base})")
        value = int(value)
    if isinstance(value, str):
        try:
            value = int(value, 0)
        except ValueError:
            raise SdoValueError(f"{value!r} is not an integer ({base})") from None
    signed = base in _SIGNED
    lo, hi = ((-(1 << (size - 1)), (1 << (size - 1)) - 1) if signed else (0, (1 << size) - 1))
    if not lo <= value <= hi:
        raise SdoValueError(f"value {value} is outside {base} ({lo}..{hi})")
    return (value & ((1 << size) - 1)).to_bytes((size + 7) // 8, "little")
