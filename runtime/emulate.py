"""Emulated slaves from ESI devices: what ``ecatcfg simulate`` and the tests put on a line.

Each device gets its SII image (``esi/sii.py``) and, when the ESI declares CoE, a runtime
object dictionary with an SDO server (``runtime/objects.py``, ``runtime/sdo_server.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.esi import sii
from ecatcfg.esi.coe import has_coe
from ecatcfg.esi.model import Device
from ecatcfg.runtime.segment import Faults, VirtualSegment
from ecatcfg.runtime.slave import EmulatedSlave


@dataclass(frozen=True, slots=True)
class SlaveSpec:
    """One slave of a virtual line: its device and how it is told apart."""

    device: Device
    name: str = ""
    serial: int = 0
    alias: int = 0


def emulated_slave(spec: SlaveSpec) -> EmulatedSlave:
    dev = spec.device
    od = server = None
    if has_coe(dev):
        from ecatcfg.runtime.objects import ObjectDictionary
        from ecatcfg.runtime.sdo_server import SdoServer
        od = ObjectDictionary.from_device(dev)
        out = next((s for s in dev.sms if s.type == "MBoxOut"), None)
        inp = next((s for s in dev.sms if s.type == "MBoxIn"), None)
        server = SdoServer(od, (out.default_size if out else None) or 128,
                           (inp.default_size if inp else None) or 128)
    image = sii.build(dev, serial=spec.serial, alias=spec.alias)
    return EmulatedSlave(dev, image, name=spec.name, od=od, sdo_server=server)


def segment(specs: list[SlaveSpec], faults: Faults | None = None) -> VirtualSegment:
    """A line of emulated slaves in the order given."""
    return VirtualSegment([emulated_slave(s) for s in specs], faults)


def specs_from_topology(loaded, library) -> list[SlaveSpec]:
    """The slaves of a topology file (``compiler/topology.py``), each with its ESI device.
    An unknown device is an error at the slave's line."""
    from ecatcfg.errors import EcatcfgError

    specs, errors = [], []
    for i, cfg in enumerate(loaded.topology.slaves):
        try:
            device = library.device(library.find(cfg.device).entry)
        except EcatcfgError as exc:
            errors.append(loaded.error(f"slave {cfg.name!r}: {exc.message}", "slaves", i,
                                       "device"))
            continue
        if cfg.modules:
            errors.append(loaded.error(f"slave {cfg.name!r}: modules are not emulated yet; "
                                       "the virtual segment runs devices without slots",
                                       "slaves", i, "modules"))
            continue
        specs.append(SlaveSpec(device, cfg.name, alias=cfg.alias or 0))
    if errors:
        raise EcatcfgError("\n".join(str(e) for e in errors))
    return specs


def specs_from_eni(plan, library, shown: str) -> list[SlaveSpec]:
    """The slaves an ENI describes (identity and order); their behaviour comes from the
    ESI devices with exactly that vendor, product and revision."""
    from ecatcfg.errors import EcatcfgError

    specs, missing = [], []
    for s in sorted(plan.slaves, key=lambda s: s.position):
        selector = f"0x{s.vendor_id:x}:0x{s.product_code:x}:0x{s.revision:x}"
        try:
            device = library.device(library.find(selector).entry)
        except EcatcfgError as exc:
            missing.append(f"slave {s.name!r} (position {s.position}): {exc.message}")
            continue
        specs.append(SlaveSpec(device, s.name, serial=s.serial_no))
    if missing:
        raise EcatcfgError(f"{shown}: no ESI for " + "; ".join(missing))
    return specs
