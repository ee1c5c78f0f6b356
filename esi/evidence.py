"""Evidence that tells apart ESI descriptions of one identity: does this Device agree with
what is known of the slave?

Several files can describe one vendor, product and revision differently (``esi/duplicates.py``:
a vendor's configuration-specific builds, a project's copy beside the vendor's).  Where the
user has not chosen (``--prefer``, a topology's ``esi:``), the library keeps the candidates
that agree with the evidence at hand (``Library.find(..., evidence=...)``) before it asks:

- an ENI's slave (``eni/evidence.py``): the PDOs it lists, its SyncManagers and mailbox;
- a slave on a line (:class:`SiiEvidence` here): the SII categories read from its EEPROM.

An :class:`Evidence` names itself (``what``: "the ENI's slave 'Term 1' (a.xml)", said in
notes and errors) and lists where a candidate Device disagrees with it, in a few words each
(``TxPdo 0x1A0C (assigned by default) is not in the ENI``): an empty list is agreement.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

from ecatcfg.esi.model import Device
from ecatcfg.esi.sii import SiiError, SiiImage, build, decode


class Evidence(Protocol):
    """What is known of one slave, to compare candidate descriptions with."""

    @property
    def what(self) -> str: ...

    def disagreements(self, device: Device) -> list[str]: ...


def in_brief(items: list[str], limit: int = 4) -> str:
    """At most ``limit`` items of a list of disagreements, the last saying how many more."""
    if len(items) > limit:
        items = items[:limit - 1] + [f"{len(items) - limit + 1} more"]
    return ", ".join(items)


@dataclass(frozen=True, slots=True)
class AllOf:
    """Several pieces of evidence on one identity (two slaves of one ENI with the same
    vendor, product and revision): a candidate must agree with each."""

    parts: tuple[Evidence, ...]

    @property
    def what(self) -> str:
        return " and ".join(p.what for p in self.parts)

    def disagreements(self, device: Device) -> list[str]:
        return [d for p in self.parts for d in p.disagreements(device)]


def all_of(parts: Iterable[Evidence]) -> Evidence | None:
    found = tuple(parts)
    return None if not found else found[0] if len(found) == 1 else AllOf(found)


# -- a slave's SII, read on a line -------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class SiiEvidence:
    """A slave's SII image (read from its EEPROM), compared with the image a candidate ESI
    Device gives (``esi/sii.py``'s ``build``: the one definition of how an ESI becomes SII
    categories; ETG.2010).  Compared: the SYNCM category (start, control byte, enable, type
    per SyncManager; lengths of mailbox SMs), the TXPDO/RXPDO categories (each PDO's index,
    SyncManager and entries: index, subindex, bit length), the standard mailbox words
    (offsets and sizes, protocols) and GENERAL's mailbox details (CoE, FoE, EoE, SoE).
    Names and strings are not: a vendor's tool and ours write them differently."""

    image: SiiImage
    slave: str                      # how messages name the slave: "slave 3 (EL1008)"

    @property
    def what(self) -> str:
        return f"the SII of {self.slave}"

    def disagreements(self, device: Device) -> list[str]:
        try:
            ours = decode(build(device))
        except SiiError as exc:
            return [f"no SII image can be built from it ({exc.message})"]
        return sii_differences(ours, self.image)


def sii_differences(esi: SiiImage, slave: SiiImage) -> list[str]:
    """Where the image built from an ESI (``esi``) and a slave's (``slave``) differ, in the
    categories that change what a master does (see :class:`SiiEvidence`)."""
    out: list[str] = []
    if (esi.std_rx, esi.std_tx) != (slave.std_rx, slave.std_tx):
        out.append(f"standard mailbox (offset, size) out {esi.std_rx} in {esi.std_tx} vs "
                   f"the slave's {slave.std_rx} {slave.std_tx}")
    if esi.protocols != slave.protocols:
        out.append(f"mailbox protocols {'/'.join(esi.protocols) or 'none'} vs the slave's "
                   f"{'/'.join(slave.protocols) or 'none'}")
    g, h = esi.general, slave.general
    if g is not None and h is not None:
        for name in ("coe_details", "foe_details", "eoe_details", "soe_channels"):
            if getattr(g, name) != getattr(h, name):
                out.append(f"GENERAL {name} 0x{getattr(g, name):X} vs the slave's "
                           f"0x{getattr(h, name):X}")
    if len(esi.syncms) != len(slave.syncms):
        out.append(f"{len(esi.syncms)} SyncManagers vs the slave's {len(slave.syncms)}")
    for n, (a, b) in enumerate(zip(esi.syncms, slave.syncms)):
        mailbox = a.type in (1, 2)          # SYNCM type byte: 1 MBoxOut, 2 MBoxIn (ETG.2010)
        if (a.start, a.control, a.enable, a.type) != (b.start, b.control, b.enable, b.type) \
                or (mailbox and a.length != b.length):
            out.append(f"SM{n} differs (start 0x{a.start:04X} vs 0x{b.start:04X}, control "
                       f"0x{a.control:02X} vs 0x{b.control:02X})")
    for kind, mine, theirs in (("TxPdo", esi.txpdos, slave.txpdos),
                               ("RxPdo", esi.rxpdos, slave.rxpdos)):
        a_ = {p.index: p for p in mine}
        b_ = {p.index: p for p in theirs}
        only_esi = [i for i in a_ if i not in b_]
        only_slave = [i for i in b_ if i not in a_]
        if only_esi:
            out.append(f"{kind} {indices_said(only_esi)} not in the slave's SII")
        if only_slave:
            out.append(f"the slave's {kind} {indices_said(only_slave)} not in the ESI")
        changed = [i for i in a_ if i in b_ and (
            a_[i].sm != b_[i].sm or [(e.index, e.subindex, e.bit_len) for e in a_[i].entries]
            != [(e.index, e.subindex, e.bit_len) for e in b_[i].entries])]
        if changed:
            out.append(f"{kind} {indices_said(changed)} entries or SyncManager differ")
    return out


def indices_said(indices: list[int]) -> str:
    """``0x1A00, 0x1A01`` (at most four, then how many more)."""
    shown = ", ".join(f"0x{i:04X}" for i in indices[:4])
    return shown + (f" (+{len(indices) - 4} more)" if len(indices) > 4 else "")
