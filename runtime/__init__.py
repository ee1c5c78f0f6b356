"""The runtime: wire codec, links, the master that applies an ENI, the virtual segment.

The master: :mod:`ecatcfg.runtime.master` (verify, replay, DC, cyclic) under ``network.py``
(the application's :class:`Network`); the slaves: :mod:`ecatcfg.runtime.segment` (emulated
ESCs on a line, built from ESI files or an ENI).  The two never import each other; only
``network.py`` (``Network.virtual``), the command line, tests and benches put them on one
link.  Both sides share ``wire.py`` (frames and datagrams), ``mailbox.py`` (mailbox, CoE,
SDO), ``ecatcfg/eoe.py`` (EoE), ``link.py``, ``wiring.py`` and ``pcap.py``.

The runtime consumes ENIs (:mod:`ecatcfg.eni`), never the compiler's objects, and never
imports :mod:`ecatcfg.compiler` (``docs/architecture.md``).  Nothing here is imported by
``ecatcfg --help`` or ``ecatcfg devices``; ``Network`` (and the
:class:`BackgroundRun` of its ``run(background=True)``) is loaded on first use.
"""

from __future__ import annotations

from typing import Any

__all__ = ["BackgroundRun", "Network"]


def __getattr__(name: str) -> Any:
    if name in ("Network", "BackgroundRun"):
        from ecatcfg.runtime import network
        return getattr(network, name)
    raise AttributeError(f"module 'ecatcfg.runtime' has no attribute {name!r}")
