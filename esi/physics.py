"""ESC ports and their kinds from an ESI ``Device/@Physics``: one letter per port 0-3.

ETG.2000 allows ``Y`` (100BASE-TX Ethernet), ``H`` (Ethernet with fast hot-connect),
``K`` (E-bus, LVDS) and a blank (no port): an EK1100 is ``YKY``, an EK1122 ``KYKY``, a
terminal ``KK``, a drive ``YY``.  ``F`` (100BASE-FX) and ``E`` (E-bus) are read as well, as
the SII builder reads them.  Two ports can only be joined by a cable of one kind.  The ENI
(ETG.2100 ``PhysicsType``) allows ``Y``, ``K``, ``B`` and a blank only, so an ESI ``H`` is
written there as the Ethernet port it is.
"""

from __future__ import annotations

from typing import Literal

PortKind = Literal["Ethernet", "E-bus"]

ETHERNET: PortKind = "Ethernet"
EBUS: PortKind = "E-bus"
MAX_PORTS = 4
# A device without Physics (ETG.2000 requires it): two Ethernet ports, in and out.
DEFAULT_PHYSICS = "YY"
_KINDS: dict[str, PortKind] = {"Y": ETHERNET, "H": ETHERNET, "F": ETHERNET,
                               "K": EBUS, "E": EBUS}
_ENI_LETTER: dict[PortKind, str] = {ETHERNET: "Y", EBUS: "K"}


def port_kinds(physics: str | None) -> list[PortKind | None]:
    """The kind of ESC ports 0-3 (None: the port does not exist)."""
    letters = (physics or "")[:MAX_PORTS].upper()
    return [_KINDS.get(letters[n]) if n < len(letters) else None for n in range(MAX_PORTS)]


def eni_physics(physics: str) -> str:
    """``Slave/Info/Physics`` of the ENI for an ESI ``Physics``: ``KHKH`` -> ``KYKY``."""
    kinds = port_kinds(physics)
    return "".join(_ENI_LETTER[k] if k else " " for k in kinds[:len(physics[:MAX_PORTS])])
