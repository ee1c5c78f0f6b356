"""SoE identification numbers (IDNs): their notation, the few standard ones ecatcfg types.

SoE (Servo drive profile over EtherCAT, ETG.1000.6 §5.8, the drive profile of IEC
61800-7-204/-304, Sercos's parameter model) addresses a drive parameter by a 16-bit IDN:

- bit 15: 0 = S (standard, the profile's own parameters), 1 = P (product specific);
- bits 14:12: the parameter set, 0..7;
- bits 11:0: the data block number, 0..4095.

Drive tools, IgH's ``ecrt_slave_config_idn`` and LinuxCNC's lcec write an IDN as
``S-0-0001`` / ``P-0-0010``: S or P, the set, the number in four decimal digits.  ESI and
ENI files write the 16-bit number itself (``<IDN>32778</IDN>`` is P-0-0010).

A drive behind an SoE slave is one of up to 8 (the SoE header's 3-bit drive number;
ESI ``Mailbox/SoE/InitCmd@Chn``, ENI ``DriveNo``).

:data:`STANDARD_IDNS` types the values of a handful of S parameters that start-up lists
write, so that a topology may give them as numbers.  Their sizes and units are those of
the public IDN descriptions of drives that implement them (Beckhoff's AX5000 IDN
reference: S-0-0001 and S-0-0002 are 16-bit unsigned microseconds, S-0-0015 the 16-bit
telegram type, S-0-0032 a 16-bit operation mode word, S-0-0099 the 16-bit procedure
command that resets the class 1 diagnostic).  Any other IDN takes a ``type`` or raw bytes.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from ecatcfg.esc import Transition

P_BIT = 0x8000                 # bit 15: product-specific parameter
SET_SHIFT, SET_MASK = 12, 0x7  # bits 14:12: parameter set
NUMBER_MASK = 0x0FFF           # bits 11:0: data block number
MAX_DRIVE = 7                  # the SoE header's drive number has 3 bits (ETG.1000.6 §5.8)
WRITE_REQUEST = 3              # SoE OpCode "write request" (ETG.1000.6 Table: SoE OpCodes)
VALUE_ELEMENT = 0x40           # element flags: bit 6, the value (operation data)

# The IDN lists a drive keeps of its own parameters (IEC 61800-7-204; the AX5000 IDN
# reference): all its IDNs, those it needs before SAFEOP (communication phase 2 -> 3 is
# PREOP -> SAFEOP), and those of the latter found missing or invalid at the switch.
IDN_LIST_ALL = 17              # S-0-0017, IDN-list of all operation data
IDN_LIST_CP2 = 18              # S-0-0018, IDN-list of operation data for CP2
IDN_LIST_INVALID_CP2 = 21      # S-0-0021, IDN-list of invalid operation data for CP2

# The notation as a regular expression without flags, so that the topology's JSON schema
# (compiler/topology.py) takes the same text.
NOTATION_PATTERN = r"^\s*([SPsp])\s*-\s*([0-7])\s*-\s*([0-9]{1,4})\s*$"
_NOTATION = re.compile(NOTATION_PATTERN)


class StandardIdn(NamedTuple):
    name: str
    type: str                  # an esi/datatypes base type: how a value is encoded
    unit: str = ""


# Keyed by the 16-bit IDN (S-0-0032 is 32): the number in the notation is decimal.
STANDARD_IDNS: dict[int, StandardIdn] = {
    1: StandardIdn("NC cycle time (TNcyc)", "UINT", "µs"),
    2: StandardIdn("Communication cycle time (tScyc)", "UINT", "µs"),
    15: StandardIdn("Telegram type parameter", "UINT"),
    32: StandardIdn("Primary operation mode", "UINT"),
    99: StandardIdn("Reset class 1 diagnostic", "UINT"),
}


def idn_text(idn: int) -> str:
    """``S-0-0001`` for 1, ``P-0-0010`` for 32778 (0x800A)."""
    if not 0 <= idn <= 0xFFFF:
        raise ValueError(f"IDN {idn} is not a 16-bit number")
    kind = "P" if idn & P_BIT else "S"
    return f"{kind}-{idn >> SET_SHIFT & SET_MASK}-{idn & NUMBER_MASK:04d}"


def parse_idn(text: str, *, numbers: bool = False) -> int:
    """The 16-bit IDN of ``S-0-1002`` / ``P-0-0015`` (any case, 1 to 4 digits); with
    ``numbers``, also of a number as ESI and ENI files write it (``32778``, ``0x800A``,
    ``#x800A``: the command line takes both).  Raises ``ValueError`` naming the notation
    for anything else, and for a number above 4095."""
    m = _NOTATION.match(text)
    if m is None:
        raw = text.strip()
        value = None
        if numbers:
            try:
                value = int(raw[2:], 16) if raw[:2].lower() in ("0x", "#x") else int(raw, 10)
            except ValueError:
                pass
        if value is None:
            raise ValueError(f"{text!r} is not an IDN: write S-<set>-<number> or "
                             "P-<set>-<number>, e.g. S-0-0001, P-0-0010"
                             + (", or a 16-bit number" if numbers else ""))
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"IDN {raw}: not a 16-bit number")
        return value
    number = int(m.group(3))
    if number > NUMBER_MASK:
        raise ValueError(f"{text!r}: an IDN's number is 0..{NUMBER_MASK}")
    kind = P_BIT if m.group(1).upper() == "P" else 0
    return kind | int(m.group(2)) << SET_SHIFT | number


def standard(idn: int) -> StandardIdn | None:
    """What :data:`STANDARD_IDNS` says of ``idn`` (S parameters of set 0 only)."""
    return STANDARD_IDNS.get(idn)


# -- transitions ---------------------------------------------------------------------------

# The transitions an ENI's SoE InitCmd may name (ETG.2100 EtherCATConfig.xsd,
# Mailbox/SoE/InitCmds/InitCmd/Transition): those in which the mailbox works and the drive
# is past INIT->PREOP.
ENI_TRANSITIONS: tuple[Transition, ...] = (Transition.PS, Transition.SO, Transition.SP,
                                           Transition.OP, Transition.OS)


def eni_transition(esi: str) -> Transition | None:
    """The ENI transition of an ESI SoE InitCmd's ``Transition`` (ETG.2000 allows IP, PS,
    SO, SP, OP, OS), ``None`` for one no ENI can carry.

    IP becomes PS.  ETG.2000 lets a drive's file ask for an SoE write in INIT->PREOP (the
    AX5000's firmware 2.10 files write P-0-0010 there), but the mailbox works only once the
    slave is in PREOP (ETG.1000.6), and ETG.2100 gives SoE InitCmds no IP.  TwinCAT's
    start-up list sends such "I->P" writes to the drive in PREOP, before the "P->S" ones
    (the AX5206 traffic users of SOEM describe: P-0-0010 first, then S-0-0001, S-0-0002,
    S-0-0032, all in PREOP).  PS is that moment in the ENI: in PREOP, before SAFEOP is
    requested; the compiler puts these commands first among the PS ones.  What differs is
    a master that stops in PREOP: it does not send them."""
    if esi == Transition.IP.value:
        return Transition.PS
    try:
        transition = Transition(esi)
    except ValueError:
        return None
    return transition if transition in ENI_TRANSITIONS else None
