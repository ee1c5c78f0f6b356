"""The network plan and the ENI format (ETG.2100), in the middle of the house.

- :mod:`~ecatcfg.eni.plan`: the :class:`NetworkPlan`, everything an ENI says as plain objects;
- :mod:`~ecatcfg.eni.reader`: any ENI file (ours, TwinCAT's, EC-Engineer's) into a plan;
- :mod:`~ecatcfg.eni.writer`: a plan into an ENI file (deterministic bytes);
- :mod:`~ecatcfg.eni.cache`: parsed plans kept on disk for ``ecatcfg apply``.

The compiler (:mod:`ecatcfg.compiler`) produces plans and the runtime (:mod:`ecatcfg.runtime`)
consumes them; neither imports the other, and this package imports neither (only
:mod:`ecatcfg.esi` below it and the shared modules at the package root).

Loaded lazily: ``from ecatcfg.eni import NetworkPlan, read_file`` costs nothing until used.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {"NetworkPlan": "plan", "SlavePlan": "plan", "read_file": "reader",
            "read_bytes": "reader", "EniReadError": "reader", "to_bytes": "writer",
            "write": "writer"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ecatcfg.eni' has no attribute {name!r}")
    return getattr(import_module(f"ecatcfg.eni.{module}"), name)
