"""Who a slave on a live line is, for the online commands that work without an ENI
(``states``, ``doctor``, ``graph --iface``, ``scan``, ``od``, ``pdos``): the identity in its
SII (vendor, product, revision) and a device name, from the ESI files given (the library's
entry of that identity: its Type and Name; where several files describe it differently,
the one its SII agrees with) or, where asked, from the SII itself (GENERAL: order number
and name strings, as TwinCAT shows a slave it has no ESI for)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ecatcfg.esi.evidence import SiiEvidence
    from ecatcfg.esi.index import DeviceEntry
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.master.scan import FoundSlave
    from ecatcfg.runtime.master.transport import Transport


@dataclass(slots=True)
class SlaveIdentity:
    position: int
    vendor_id: int
    product_code: int
    revision: int
    type: str | None = None          # ESI Type, or the SII's order number
    name: str | None = None          # ESI Name, or the SII's device name
    source: str | None = None        # "ESI FILE:LINE" or "SII"
    note: str | None = None          # e.g. the ESI has another revision

    @property
    def selector(self) -> str:
        """``0xVVVVVVVV:0xPPPPPPPP:0xRRRRRRRR``: what ``--esi``/``devices`` take."""
        return f"0x{self.vendor_id:08x}:0x{self.product_code:08x}:0x{self.revision:08x}"

    def text(self) -> str:
        return self.selector + (f" {self.type}" if self.type else "")

    def as_json(self) -> dict[str, Any]:
        return {"vendor_id": self.vendor_id, "product_code": self.product_code,
                "revision": self.revision, "type": self.type, "name": self.name,
                "name_from": self.source, "name_note": self.note}


def slave_identities(transport: Transport, positions: list[int],
                     library: Library | None = None, *, sii_names: bool = False,
                     found: list[FoundSlave] | None = None) -> dict[int, SlaveIdentity]:
    """The identity of each slave in ``positions`` (one whose SII does not answer is left
    out), named from ``library`` where it has the identity (the exact revision, else
    another of the product, said in ``note``), else from the SII's GENERAL category when
    ``sii_names``.  ``found``: a scan already made (its identities are used)."""
    from ecatcfg.runtime.master.scan import identities

    known = {s.position: s for s in found} if found is not None else \
        identities(transport, positions)
    out = {p: SlaveIdentity(p, s.vendor_id, s.product_code, s.revision)
           for p, s in known.items() if p in positions}
    if library is not None:
        for ident in out.values():
            exact, other, note = library.entry_for_identity(
                ident.vendor_id, ident.product_code, ident.revision)
            entry = exact or other
            if entry is not None:
                ident.type, ident.name = entry.type.strip(), entry.name.strip()
                ident.source, ident.note = f"ESI {entry.file}:{entry.line}", note
    unnamed = [p for p, ident in out.items() if ident.type is None and ident.name is None]
    if sii_names and unnamed:
        from ecatcfg.esi.sii import SiiError, decode
        from ecatcfg.runtime.master.scan import sii_heads

        for position, head in sii_heads(transport, unnamed).items():
            try:
                general = decode(head, source=f"slave {position}").general
            except SiiError:
                continue                 # a damaged SII: the identity alone
            if general is not None:
                ident = out[position]
                ident.type, ident.name, ident.source = general.order, general.name, "SII"
    return out


def esi_entry(lib: Library, s: FoundSlave, transport: Transport
               ) -> tuple[DeviceEntry | None, DeviceEntry | None, str | None]:
    """The library's entry of a found slave (``Library.entry_for_identity``).  Where
    several ESI files describe its identity differently, its SII is read from its EEPROM
    and the description that agrees with it is taken (``esi/evidence.py``), said in the
    note; one that cannot be read leaves the choice to the files' order, said too."""
    evidence = None
    if lib.differs(s.vendor_id, s.product_code, s.revision):
        evidence, why = sii_evidence(transport, s.position)
        if evidence is None:
            exact, other, note = lib.entry_for_identity(s.vendor_id, s.product_code,
                                                        s.revision)
            return exact, other, f"several ESI files describe it differently; {why}"
    return lib.entry_for_identity(s.vendor_id, s.product_code, s.revision, evidence)


def sii_evidence(transport: Transport, position: int) -> tuple[SiiEvidence | None, str]:
    """The SII of the slave at ``position``, read from its EEPROM, as evidence; else None
    and why not."""
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esi.evidence import SiiEvidence
    from ecatcfg.esi.sii import decode
    from ecatcfg.runtime.master.eeprom import Eeprom

    shown = f"slave {position}"
    try:
        image = decode(Eeprom(transport, position).read(), source=shown)
    except EcatcfgError as exc:
        return None, f"its SII could not be read to choose ({exc.message})"
    return SiiEvidence(image, shown), ""


def esi_device(lib: Library, transport: Transport, position: int) -> tuple[Any, str]:
    """The ESI device of the slave at ``position``, by the identity in its SII."""
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.runtime.master.scan import scan

    found = [s for s in scan(transport) if s.position == position]
    if not found:
        raise EcatcfgError(f"no slave at position {position}")
    s = found[0]
    exact, other, note = esi_entry(lib, s, transport)
    entry = exact or other
    if entry is None:
        raise EcatcfgError(f"slave {position} (vendor 0x{s.vendor_id:08x}, product "
                           f"0x{s.product_code:08x}, revision 0x{s.revision:08x}): no "
                           "device of that identity in the ESI files given")
    where = f"{entry.file}:{entry.line} ({entry.type.strip()})"
    if note:
        where += f"; {note}"
    return lib.device(entry), where
