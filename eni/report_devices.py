"""What the report says of each slave's device, and which check rules ran for it.

The device type comes from the ENI where it says (``Slave/Info/ProductRevision``, ETG.2100:
TwinCAT writes the order number, e.g. ``EK1100-0000-0018``), else from the ESI device of
the slave's identity when ``--esi`` gives one (its ``Type``), else it is left out.  The
vendor is the ESI's ``Vendor/Name`` for the slave's vendor id when an ESI of that vendor
is given, else the id.  The plan (``eni/reader.py``) does not keep ``ProductRevision``: it
is read here from the file with lxml, per ``Config/Slave`` in file order (the order of
``NetworkPlan.in_file_order()``, passive terminals included).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ecatcfg.eni.plan import NetworkPlan, SlavePlan
from ecatcfg.record import record

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library


@record
class DeviceLabel:
    type: str                                 # "" when neither the ENI nor an ESI says
    vendor: str                               # the ESI's name, else "vendor 0x2"
    esi: str | None                           # "file:line" of the ESI device, with --esi


@record
class CheckCoverage:
    """Which of ``check``'s rules ran: the network rules always; the device rules for the
    slaves whose identity (vendor, product, revision) an ESI given describes."""

    slaves: int                               # with an ESC: the device rules are per slave
    esi_given: bool
    checked: list[str]                        # "name (type, ESI file:line)" checked
    unchecked: list[str]                      # ... and those without an ESI

    def sentence(self) -> str:
        if not self.esi_given:
            return (f"network rules ran; device rules skipped: no ESI given (--esi), so "
                    f"none of the {self.slaves} slaves was checked against its device")
        if not self.unchecked:
            return (f"network rules ran; device rules ran for all {self.slaves} slaves "
                    "(each against its ESI device)")
        return (f"network rules ran; device rules ran for {len(self.checked)} of "
                f"{self.slaves} slaves; skipped: no ESI for {len(self.unchecked)} of "
                f"{self.slaves} slaves")


def product_revisions(path: str | Path) -> list[str]:
    """``Info/ProductRevision`` of each ``Config/Slave`` in file order ("" where absent)."""
    from ecatcfg.esi import xmlsafe
    root = xmlsafe.parse_bytes(Path(path).read_bytes(), str(path)).getroot()
    return [(s.findtext("Info/ProductRevision") or "").strip()
            for s in root.iterfind("Config/Slave")]


def _vendor_names(library: Library | None) -> dict[int, str]:
    if library is None:
        return {}
    return {f.summary.vendor_id: f.summary.vendor_name for f in library.files
            if f.summary.vendor_id is not None and f.summary.vendor_name}


def labels(plan: NetworkPlan, revisions: list[str],
           library: Library | None) -> list[DeviceLabel]:
    """A label per slave of ``plan.in_file_order()``."""
    vendors = _vendor_names(library)
    out = []
    order = plan.in_file_order()
    for k, s in enumerate(order):
        kind = revisions[k] if k < len(revisions) and len(revisions) == len(order) else ""
        esi = None
        if library is not None:
            entry, _, _ = library.entry_for_identity(s.vendor_id, s.product_code, s.revision)
            if entry is not None:
                kind = kind or entry.type
                esi = f"{entry.file}:{entry.line}"
        vendor = vendors.get(s.vendor_id) or f"vendor 0x{s.vendor_id:X}"
        out.append(DeviceLabel(kind, vendor, esi))
    return out


def coverage(plan: NetworkPlan, found: list[DeviceLabel] | None,
             esi_given: bool) -> CheckCoverage:
    """``found``: the labels of :func:`labels` (a slave has an ESI device when its
    ``esi`` is set), for ``plan.in_file_order()``."""
    order = plan.in_file_order()
    esi = [lab.esi if esi_given and lab is not None else None
           for lab in (found or [])] + [None] * len(order)
    active = [(s, esi[k]) for k, s in enumerate(order) if isinstance(s, SlavePlan)]
    labels_by = dict(enumerate(found or []))
    checked = [f"{s.name} ({labels_by[k].type}, {esi[k]})" for k, s in enumerate(order)
               if isinstance(s, SlavePlan) and esi[k] is not None]
    unchecked = [s.name for s, where in active if where is None]
    return CheckCoverage(len(active), esi_given, checked, unchecked)

