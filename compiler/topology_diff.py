"""``ecatcfg diff`` of two topology files: the slaves and settings the user changed.

Two topologies are compared as the validated model (``compiler/topology.py``) the compiler
reads, not as YAML text: comments, key order, quoting and number spellings (``0x1600``,
``"#x1600"``, ``5632``) are not differences.  Slaves are matched by name; a slave is
added, removed or moved (its place in the file is its bus order on a line), and every
other key that differs (device, PDOs, mapping, modules, SDOs, SoE, DC, EoE, watchdog,
parent, port, ...) is one change naming the key, as are the master's keys (cycle time, layout).
The changes are :class:`ecatcfg.eni.diff.Change` records, as for ENIs.
"""

from __future__ import annotations

import json
from typing import Any

from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.eni.diff import Change
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.idn import idn_text
from ecatcfg.esi.library import Library, SelectorError
from ecatcfg.esi.model import format_selector


def _resolved(library: Library, loaded: LoadedTopology, k: int, selector: str) -> str:
    """The exact selector of the device ``selector`` names, as the compiler resolves it."""
    try:
        e = library.find(selector).entry
    except SelectorError as exc:
        raise EcatcfgError(exc.message, loaded.file,
                           loaded.line("slaves", k, "device")) from None
    return format_selector(e.vendor_id, e.product_code, e.revision)


# Keys whose numbers are object or PDO indices: shown in hex, as topologies write them.
_INDEX_KEYS = frozenset({"index", "rx_pdos", "tx_pdos"})


def _spell(value: Any, hex_numbers: bool = False) -> str:
    """A key's value in YAML flow style (``[{index: 0x8000, value: 1}]``), indices in hex;
    keys not set are left out of a mapping, and a key not set is ``none``."""
    if value is None:
        return "none"
    if isinstance(value, bool) or not isinstance(value, (int, list, dict)):
        return json.dumps(value) if not isinstance(value, str) else value
    if isinstance(value, int):
        return f"0x{value:04X}" if hex_numbers else str(value)
    if isinstance(value, list):
        return "[" + ", ".join(_spell(v, hex_numbers) for v in value) + "]"
    return "{" + ", ".join(
        f"{_spell_key(k, hex_numbers)}: "
        + (idn_text(v) if k == "idn" and isinstance(v, int) else
           _spell(v, hex_numbers or k in _INDEX_KEYS))
        for k, v in value.items() if v is not None) + "}"


def _spell_mapping(value: Any) -> str:
    """``pdo_mapping``: PDO index -> entries, each ``[index, subindex, bits]`` (or a mapping
    with those keys); only the indices in hex."""
    if not isinstance(value, dict):
        return _spell(value)
    def entry(e: Any) -> str:
        if isinstance(e, list) and len(e) == 3 and all(isinstance(x, int) for x in e):
            return f"[0x{e[0]:04X}, {e[1]}, {e[2]}]"
        if isinstance(e, dict):
            return "{" + ", ".join(f"{k}: " + (f"0x{v:04X}" if k == "index" else _spell(v))
                                   for k, v in e.items() if v is not None) + "}"
        return _spell(e)
    return "{" + ", ".join(f"{_spell_key(k, True)}: [" + ", ".join(entry(e) for e in v) + "]"
                           for k, v in value.items()) + "}"


def _spell_key(key: str, hex_numbers: bool) -> str:
    return f"0x{int(key):04X}" if hex_numbers and key.isdigit() else key


def _keys(model: Any) -> dict[str, Any]:
    """Every key with its value, defaults filled in (a default written out is no change)."""
    return dict(model.model_dump(mode="json"))


def diff(a: LoadedTopology, b: LoadedTopology,
         library: Library | None = None) -> list[Change]:
    """The changes from ``a`` to ``b``.  With ``library``, each slave's ``device`` is
    compared as the exact device it selects (``VENDOR:PRODUCT:REVISION``), so two spellings
    of one device (``EXD-402``, ``0xE0000ECA:0x7201``) are no difference; a selector the
    library cannot resolve is an error at its line."""
    out: list[Change] = []
    ma, mb = _keys(a.topology.master), _keys(b.topology.master)
    for key in sorted(set(ma) | set(mb)):
        if ma.get(key) != mb.get(key):
            out.append(Change("master-setting", None, key, _spell(ma.get(key)),
                              _spell(mb.get(key))))
    old = {s.name: (k, s) for k, s in enumerate(a.topology.slaves)}
    new = {s.name: (k, s) for k, s in enumerate(b.topology.slaves)}
    for name, (k, s) in old.items():
        if name not in new:
            out.append(Change("slave-removed", name, s.device, old=f"position {k}"))
    for name, (k, s) in new.items():
        if name not in old:
            out.append(Change("slave-added", name, s.device, new=f"position {k}"))
            continue
        j, o = old[name]
        if j != k:
            out.append(Change("slave-moved", name, "place", f"position {j}",
                              f"position {k}"))
        ko, kn = _keys(o), _keys(s)
        if library is not None:
            old_device = _resolved(library, a, j, o.device)
            new_device = _resolved(library, b, k, s.device)
            del ko["device"], kn["device"]
            if old_device != new_device:
                out.append(Change("identity", name, "device", f"{o.device} ({old_device})",
                                  f"{s.device} ({new_device})"))
        for key in sorted(set(ko) | set(kn)):
            if key != "name" and ko.get(key) != kn.get(key):
                kind = "identity" if key in ("device", "esi") else "slave-setting"
                spell = _spell_mapping if key == "pdo_mapping" else (
                    lambda v: _spell(v, key in _INDEX_KEYS))
                out.append(Change(kind, name, key, spell(ko.get(key)), spell(kn.get(key))))
    return out
