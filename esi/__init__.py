"""ESI (ETG.2000) side, the bottom layer of the package (``docs/architecture.md``).

The reader (``reader.py``, over ``xmlsafe.py``) into the device model (``model.py``); value
syntax (``values.py``), typed data values (``datatypes.py``), CoE facts of a device
(``coe.py``) and modules in slots (``slots.py``); the device library with its index and
cache (``library.py``, ``index.py``, ``cache.py``); SII images (``sii.py``); ``ecatcfg lint``
(``lint/``).  Nothing here imports the ENI model, the compiler or the runtime.

Typical use::

    from ecatcfg.esi import Library
    lib = Library(["vendor-esi/"])
    device = lib.device("EK1100")             # or "0x2:0x44c2c52:0x110000"
    for pdo in device.tx_pdos: ...
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

# Loaded on first use: importing a submodule (the ENI reader needs only ``xmlsafe``) must
# not pay for the library, reader and model (35 ms, measured for `ecatcfg apply`).
_EXPORTS = {"Library": "library", "Selection": "library", "SelectorError": "library",
            "Device": "model", "EsiFile": "model", "Module": "model", "Pdo": "model",
            "PdoEntry": "model", "SyncManager": "model", "read_file": "reader"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ecatcfg.esi' has no attribute {name!r}")
    return getattr(import_module(f"ecatcfg.esi.{module}"), name)
