"""How an InitCmd's read is compared with its ``Validate`` (ETG.2100 ``Validate``, with the
``Type`` attribute real exporters write): the compare types of ETG.2000's identity check
(``EtherCATInfo.xsd``, ``Device/Type@CheckRevisionNo``: NONE, EQ, EQ_OR_G, LW_EQ,
LW_EQ_HW_EQ_OR_G, HW_EQ, HW_EQ_LW_EQ_OR_G).

The read and the expected data are masked (``DataMask``, all ones without one) and taken as
little-endian unsigned numbers, as the ESC and the SII hold them; ``LW`` is the low word
(the first two bytes read), ``HW`` the rest (the next two for a 32-bit revision).  EC-Engineer
checks a revision with ``<Validate Type="EQ_OR_G">``: a slave of a newer revision passes.

:func:`revision_check` finds the ENI's own check of a slave's revision (an EEPROM read of
SII word 0x000C, ETG.2010), so that the master's identity check (``runtime/master/scan.py``)
compares the revision the way the ENI asks.
"""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.eni.plan import InitCmd, SlavePlan, Validate
from ecatcfg.esc import REGISTER_READS, REGISTER_WRITES, SII_REVISION, Reg

_WORD = 0xFFFF


def _lw(v: int) -> int:
    return v & _WORD


def _hw(v: int) -> int:
    return v >> 16


# got, want -> passes
COMPARES: dict[str, Callable[[int, int], bool]] = {
    "NONE": lambda got, want: True,
    "EQ": lambda got, want: got == want,
    "EQ_OR_G": lambda got, want: got >= want,
    "LW_EQ": lambda got, want: _lw(got) == _lw(want),
    "HW_EQ": lambda got, want: _hw(got) == _hw(want),
    "LW_EQ_HW_EQ_OR_G": lambda got, want: _lw(got) == _lw(want) and _hw(got) >= _hw(want),
    "HW_EQ_LW_EQ_OR_G": lambda got, want: _hw(got) == _hw(want) and _lw(got) >= _lw(want),
}
DEFAULT = "EQ"
NAMES = ", ".join(COMPARES)


def compare_type(text: str) -> str | None:
    """The compare type spelled ``text`` (case and blanks as exporters write them), or
    ``None`` when it is none of :data:`COMPARES`."""
    name = text.strip().upper()
    return name if name in COMPARES else None


def compared(kind: str | None) -> str:
    """How a compare type reads before the expected value in messages and ``show``:
    ``>= `` for EQ_OR_G, ``LW_EQ `` for the word-wise types, nothing for equal."""
    return "" if kind is None or kind == "EQ" else ">= " if kind == "EQ_OR_G" else f"{kind} "


def passes(got: int, want: int, kind: str | None) -> bool:
    """``got`` compared with ``want`` as ``kind`` says (``EQ`` when ``None``)."""
    return COMPARES[kind or DEFAULT](got, want)


def matches(data: bytes | bytearray, validate: Validate) -> bool:
    """Whether the read ``data`` satisfies ``validate``: byte for byte under the mask for
    ``EQ``, as numbers for the other types."""
    want = validate.data
    n = len(want)
    mask = (validate.mask or b"")[:n].ljust(n, b"\xff")
    got_masked = bytes(g & m for g, m in zip(bytes(data[:n]).ljust(n, b"\0"), mask))
    want_masked = bytes(w & m for w, m in zip(want, mask))
    if len(data) < n:
        return False
    return passes(int.from_bytes(got_masked, "little"), int.from_bytes(want_masked, "little"),
                  validate.compare)


def _eeprom_address(cmd: InitCmd) -> int | None:
    """The SII word address an EEPROM read request writes (0x0502: control, then the
    address, ETG.1000.4 EEPROM interface), ``None`` for any other command."""
    data = cmd.data or b""
    if cmd.cmd in REGISTER_WRITES and cmd.ado == Reg.EEPROM_CONTROL and len(data) >= 4:
        return int.from_bytes(data[2:4], "little")
    return None


def revision_check(slave: SlavePlan) -> Callable[[int, int], bool] | None:
    """How the ENI's own InitCmds compare the slave's revision (SII words 0x000C-0x000D,
    read through 0x0508 after an EEPROM read request): ``(found, want) -> passes``; ``None``
    when its InitCmds do not check the revision with a compare type.  A check of one word
    (EC-Engineer: "check revision number (lo word)") compares that word; the word it does
    not check must be equal."""
    words: dict[int, str] = {}
    address: int | None = None
    whole: str | None = None
    for cmd in slave.init_cmds:
        at = _eeprom_address(cmd)
        if at is not None:
            address = at
            continue
        v = cmd.validate
        if cmd.cmd in REGISTER_READS and cmd.ado == Reg.EEPROM_DATA and v is not None \
                and address in (SII_REVISION, SII_REVISION + 1) and v.compare is not None:
            if address == SII_REVISION and len(v.data) >= 4:
                whole = v.compare
            else:
                words[address - SII_REVISION] = v.compare
    if whole is not None:
        kind = whole
        return lambda found, want: passes(found, want, kind)
    if not words:
        return None
    low, high = words.get(0, DEFAULT), words.get(1, DEFAULT)
    return lambda found, want: (passes(found & _WORD, want & _WORD, low)
                                and passes(found >> 16, want >> 16, high))
