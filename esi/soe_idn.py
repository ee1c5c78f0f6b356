"""SoE IDNs (identification numbers of a drive's parameters) as numbers and as text.

An IDN is 16 bits (IEC 61800-7-204 / Sercos; ETG.1000.6 5.8 carries it in the SoE header):
bit 15 says a standard (``S``, 0) or product-specific (``P``, 1) parameter, bits 14:12 the
parameter set (0..7), bits 11:0 the data block number (0..4095).  People write it
``S-0-0001`` (the NC cycle time) or ``P-0-0010`` (0x800A), the way drive manuals and
TwinCAT show them; ESI and ENI files write the 16-bit number in decimal.

Both ends need this: the compiler reads IDNs from a topology (``soe:`` entries) and the
runtime from the command line (``ecatcfg soe``) and names them in messages, so it lives
beside the device model (below both), like EoE's codec beside ``esc.py``.
"""

from __future__ import annotations

import re

IDN_PRODUCT = 0x8000            # bit 15: P (product-specific) rather than S (standard)
IDN_SET_SHIFT = 12              # bits 14:12: parameter set
IDN_SET_MASK = 0x7000
IDN_NUMBER_MASK = 0x0FFF        # bits 11:0: data block number

_TEXT = re.compile(r"^\s*([SP])\s*-\s*([0-7])\s*-\s*([0-9]{1,4})\s*$", re.IGNORECASE)


def format_idn(idn: int) -> str:
    """``S-0-0001``, ``P-0-0010``: the text of a 16-bit IDN."""
    if not 0 <= idn <= 0xFFFF:
        raise ValueError(f"IDN {idn} is not a 16-bit number")
    kind = "P" if idn & IDN_PRODUCT else "S"
    return f"{kind}-{(idn & IDN_SET_MASK) >> IDN_SET_SHIFT}-{idn & IDN_NUMBER_MASK:04d}"


def parse_idn(text: str) -> int:
    """The 16-bit IDN of ``S-0-0001`` / ``P-0-0010`` (S or P, the parameter set 0..7, the
    number 0..4095), or of a number as ESI and ENI files write it (``32778``, ``0x800A``,
    ``#x800A``)."""
    m = _TEXT.match(text)
    if m:
        number = int(m.group(3))
        if number > IDN_NUMBER_MASK:
            raise ValueError(f"IDN {text.strip()!r}: the data block number is 0..4095")
        return ((IDN_PRODUCT if m.group(1).upper() == "P" else 0)
                | int(m.group(2)) << IDN_SET_SHIFT | number)
    raw = text.strip()
    try:
        value = int(raw[2:], 16) if raw[:2].lower() in ("0x", "#x") else int(raw, 10)
    except ValueError:
        raise ValueError(f"{text!r} is not an IDN (S-0-0001, P-0-0010 or a 16-bit "
                         "number)") from None
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"IDN {raw}: not a 16-bit number")
    return value
