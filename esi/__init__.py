"""ESI (ETG.2000) side: reader, device model, device library; later lint rules and SII.

Typical use::

    from ecatcfg.esi import Library
    lib = Library(["vendor-esi/"])
    device = lib.device("EK1100")             # or "0x2:0x44c2c52:0x110000"
    for pdo in device.tx_pdos: ...
"""

from ecatcfg.esi.library import Library, Selection, SelectorError
from ecatcfg.esi.model import Device, EsiFile, Module, Pdo, PdoEntry, SyncManager
from ecatcfg.esi.reader import read_file

__all__ = ["Device", "EsiFile", "Library", "Module", "Pdo", "PdoEntry", "Selection",
           "SelectorError", "SyncManager", "read_file"]
