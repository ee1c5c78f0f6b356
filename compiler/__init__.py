"""The compiler: a topology file plus ESI devices into a :class:`~ecatcfg.eni.plan.NetworkPlan`.

- :mod:`~ecatcfg.compiler.topology`: the topology file (YAML, checked by its JSON Schema);
- :mod:`~ecatcfg.compiler.resolve`: each slave's device, modules, PDO choice, DC and SDOs,
  every mistake pointing at its topology line;
- :mod:`~ecatcfg.compiler.layout`: the process image, FMMUs, frames and working counters;
- :mod:`~ecatcfg.compiler.initcmds`, :mod:`~ecatcfg.compiler.pdocmds`: the InitCmds;
- :mod:`~ecatcfg.compiler.build`: the driver (:func:`~ecatcfg.compiler.build.compile_topology`);
- :mod:`~ecatcfg.compiler.header`: the C header of the process image.

The plan is written as an ENI by :mod:`ecatcfg.eni.writer`; the compiler never imports the
runtime.  ``compile_topology`` is loaded lazily from here.
"""

from __future__ import annotations

from typing import Any

__all__ = ["compile_topology"]


def __getattr__(name: str) -> Any:
    if name == "compile_topology":
        from ecatcfg.compiler.build import compile_topology
        return compile_topology
    raise AttributeError(f"module 'ecatcfg.compiler' has no attribute {name!r}")
