"""What ``ecatcfg show ESI --device SELECTOR`` shows: one device as a configurator sees it.

:func:`summary` turns a :class:`Device` into JSON-ready objects: identity, mailbox and
protocols, SyncManagers, PDOs with their entries (``index:sub``, bit length, type, name), the
ETG.2000 PDO flags (Fixed, Mandatory, Virtual, Exclude: the PDOs it cannot be assigned
with, its alternatives), whether a PDO is assigned by default (it names a SyncManager,
``Pdo/@Sm``), the DC OpModes, slots and modules, and with ``objects`` the object dictionary
with each entry's access per AL state and PDO-mapping flag.  The command line only formats.
"""

from __future__ import annotations

from typing import Any

from ecatcfg.esi.coe import device_dictionary
from ecatcfg.esi.model import STATES, Device, Dictionary, DictObject, Module, ObjectFlags, Pdo


def pdo(p: Pdo) -> dict[str, Any]:
    return {
        "direction": p.direction, "index": p.index, "name": p.name,
        "sm": p.sm, "default": p.sm is not None,
        "fixed": p.fixed, "mandatory": p.mandatory, "virtual": p.virtual,
        "excludes": list(p.excludes),
        "bit_length": p.bit_length,
        "entries": [{"index": e.index, "subindex": e.subindex,
                     "entry": None if not e.index else
                     f"0x{e.index:04X}:{e.subindex or 0:02X}",
                     "bit_len": e.bit_len, "type": e.data_type, "name": e.name}
                    for e in p.entries],
    }


def _module(m: Module) -> dict[str, Any]:
    return {"ident": m.ident, "type": m.type_name, "name": m.name,
            "rx_pdos": [pdo(p) for p in m.rx_pdos], "tx_pdos": [pdo(p) for p in m.tx_pdos]}


def access(flags: ObjectFlags | None) -> dict[str, str] | None:
    """Per AL state (ETG.2000 ``Flags/Access`` with its ``Read/WriteRestrictions``):
    ``rw``, ``ro``, ``wo`` or ``-``."""
    if flags is None or flags.access is None:
        return None
    a = flags.access
    return {state: ("r" if a.readable_in(state) else "") + ("w" if a.writable_in(state)
                                                           else "") or "-"
            for state in STATES}


def _rights(text: str) -> str:
    return {"r": "ro", "w": "wo"}.get(text, text)


def _entry(subindex: int | None, name: str, type_name: str, bit_size: int | None,
           flags: ObjectFlags | None) -> dict[str, Any]:
    rights = access(flags)
    return {"subindex": subindex, "name": name, "type": type_name, "bit_size": bit_size,
            "access": None if rights is None else {st: _rights(r) for st, r in
                                                   rights.items()},
            "pdo_mapping": flags.pdo_mapping if flags else None}


def objects(dic: Dictionary) -> list[dict[str, Any]]:
    """Each object with its entries (a simple object: subindex 0 alone), the access of
    each per AL state and its PDO-mapping flag (a SubItem without Flags takes its
    object's, as ``esi/coe.py`` reads them)."""
    out = []
    for index in sorted(i for i in dic.objects if i is not None):
        obj: DictObject = dic.objects[index]
        entries = []
        for s in dic.sub_items(obj):
            flags = s.flags or obj.flags
            arr = dic.data_types.get(s.type) if s.subindex is None else None
            if arr is not None and arr.array_info:
                # A record's array part as one SubItem without SubIdx (ETG.2000): its
                # elements are subindices LBound .. LBound + Elements - 1.
                info = arr.array_info[0]
                size = arr.bit_size // info.elements if arr.bit_size else None
                entries += [_entry(k, f"{s.name} {k}", arr.base_type or "", size, flags)
                            for k in range(info.lbound, info.lbound + info.elements)]
            else:
                entries.append(_entry(s.subindex, s.name, s.type, s.bit_size, flags))
        entries = entries or [_entry(0, obj.name, obj.type, obj.bit_size, obj.flags)]
        out.append({"index": index, "name": obj.name, "type": obj.type,
                    "entries": entries})
    return out


def summary(dev: Device, with_objects: bool = False) -> dict[str, Any]:
    """The ``show ESI --format json`` shape (docs/show-diff-check.md)."""
    mbx = dev.mailbox
    coe = mbx.coe if mbx else None
    result: dict[str, Any] = {
        "file": dev.source.file, "line": dev.source.line,
        "vendor_id": dev.vendor.id, "product_code": dev.product_code,
        "revision": dev.revision, "selector": dev.selector,
        "type": dev.type_name, "name": dev.name, "vendor": dev.vendor.name,
        "mailbox": None if mbx is None else {
            "protocols": list(mbx.protocols),
            "coe": None if coe is None else {
                "sdo_info": coe.sdo_info, "pdo_assign": coe.pdo_assign,
                "pdo_config": coe.pdo_config, "complete_access": coe.complete_access,
                "segmented_sdo": coe.segmented_sdo}},
        "sms": [{"number": sm.number, "type": sm.type, "start": sm.start_address,
                 "default_size": sm.default_size, "control": sm.control_byte,
                 "enable": sm.enable, "virtual": sm.virtual, "op_only": sm.op_only}
                for sm in dev.sms],
        "rx_pdos": [pdo(p) for p in dev.rx_pdos],
        "tx_pdos": [pdo(p) for p in dev.tx_pdos],
        "dc_opmodes": [] if dev.dc is None else [
            {"name": m.name, "desc": m.desc, "assign_activate": m.assign_activate,
             "cycle_time_sync0": m.cycle_time_sync0,
             "cycle_time_sync0_factor": m.cycle_time_sync0_factor,
             "shift_time_sync0": m.shift_time_sync0,
             "cycle_time_sync1": m.cycle_time_sync1,
             "cycle_time_sync1_factor": m.cycle_time_sync1_factor}
            for m in dev.dc.opmodes],
        "slots": [] if dev.slots is None else [
            {"name": s.name, "min": s.min_instances, "max": s.max_instances,
             "modules": list(s.module_idents), "module_classes": list(s.module_classes),
             "default": s.default_ident, "slot_group": s.slot_group}
            for s in dev.slots.slots],
    }
    if with_objects:
        dic = device_dictionary(dev)
        result["objects"] = [] if dic is None else objects(dic)
    return result


def with_modules(result: dict[str, Any], modules: list[Module]) -> dict[str, Any]:
    """Add the modules the library has for the device's slots."""
    result["modules"] = [_module(m) for m in modules]
    return result
