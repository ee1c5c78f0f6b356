"""C names and C types for generated code: identifiers from EtherCAT names, text safe in a
C comment, the C type of an IEC base type.  Used by the C header of ``compile --header``
and the SOEM export, so both spell a variable the same way.
"""

from __future__ import annotations

import re
import unicodedata

# IEC type -> (C type of the value, whatever the alignment; what it is).
C_TYPES: dict[str, tuple[str, str]] = {
    "BOOL": ("uint8_t", "bit"), "BIT": ("uint8_t", "bit"),
    **{f"BIT{n}": ("uint8_t", "bits") for n in range(2, 9)},
    "SINT": ("int8_t", "signed"), "INT": ("int16_t", "signed"),
    **dict.fromkeys(["INT24", "DINT"], ("int32_t", "signed")),
    **dict.fromkeys(["INT40", "INT48", "INT56", "LINT"], ("int64_t", "signed")),
    **dict.fromkeys(["USINT", "BYTE", "BITARR8"], ("uint8_t", "unsigned")),
    **dict.fromkeys(["UINT", "WORD", "BITARR16"], ("uint16_t", "unsigned")),
    **dict.fromkeys(["UINT24", "UDINT", "DWORD", "BITARR32"], ("uint32_t", "unsigned")),
    **dict.fromkeys(["UINT40", "UINT48", "UINT56", "ULINT", "LWORD"], ("uint64_t", "unsigned")),
    "REAL": ("float", "float"), "LREAL": ("double", "double"),
}

def identifier(name: str) -> str:
    """``Term 1 (EL1008).Channel 1`` -> ``TERM_1_EL1008_CHANNEL_1``; accents dropped (NFKD),
    other non-alphanumeric runs become ``_``, a leading digit gets ``V_``."""
    chars = ("" if unicodedata.combining(c) else c if c.isascii() and c.isalnum() else "_"
             for c in unicodedata.normalize("NFKD", name))
    ident = re.sub(r"_+", "_", "".join(chars)).strip("_").upper()
    return ident if ident[:1].isalpha() else f"V_{ident}".rstrip("_")


def identifiers(names: list[str]) -> list[str]:
    """Unique identifiers in order: a repeat gets ``_2``, ``_3``... never one another name
    produces by itself."""
    bases = [identifier(n) for n in names]
    reserved, taken, out = set(bases), set[str](), []
    for base in bases:
        ident, n = base, 1
        while ident in taken or (ident != base and ident in reserved):
            n += 1
            ident = f"{base}_{n}"
        taken.add(ident)
        out.append(ident)
    return out



def comment(text: object) -> str:
    """Text safe inside ``/* ... */`` on one line: printable ASCII only (others as
    ``<U+00E4>``), no ``*/`` or ``/*``, no trigraphs, no backslash (line splices)."""
    s = "".join(" " if c in "\t\r\n" else "/" if c == "\\" else c if " " <= c <= "~"
                else f"<U+{ord(c):04X}>" for c in str(text))
    while "*/" in s or "/*" in s or "??" in s:
        s = s.replace("*/", "* /").replace("/*", "/ *").replace("??", "? ?")
    return s
