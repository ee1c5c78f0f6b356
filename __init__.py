"""ecatcfg: EtherCAT configuration compiler and network configurator.

Two models sit in the middle: the :class:`~ecatcfg.esi.model.Device` (read from vendor ESI
files, ETG.2000) and the :class:`~ecatcfg.eni.plan.NetworkPlan` (what an ENI, ETG.2100, says).
The compiler turns devices and a topology into a plan; the runtime brings a network up from a
plan; ``docs/architecture.md`` shows the layers.  Keep this module light: ``import ecatcfg``
and ``ecatcfg --help`` must not pull in lxml, scapy or the runtime.
"""

from __future__ import annotations

import sys
from importlib.machinery import ModuleSpec, PathFinder
from typing import Sequence

__version__ = "0.1.0"


class _RealSubpackagesOnly:
    """Import only the subpackages that have an ``__init__.py``.

    The repository root is this package's folder, so in an editable install ``tests/``,
    ``bench/`` and ``docs/`` sit where subpackages would, and Python would import them as
    namespace packages (``import ecatcfg.tests`` would succeed).  This finder, first on
    ``sys.meta_path``, refuses a namespace package under ``ecatcfg``; everything else it
    finds the usual way (the same lookup Python does)."""

    @staticmethod
    def find_spec(fullname: str, path: Sequence[str] | None = None,
                  target: object = None) -> ModuleSpec | None:
        if not fullname.startswith(__name__ + ".") or path is None:
            return None
        spec = PathFinder.find_spec(fullname, path)
        if spec is not None and spec.loader is None:       # a namespace package
            raise ModuleNotFoundError(f"No module named {fullname!r}: not a subpackage of "
                                      f"{__name__}", name=fullname)
        return spec


if not any(isinstance(f, type) and f.__name__ == "_RealSubpackagesOnly" for f in sys.meta_path):
    sys.meta_path.insert(0, _RealSubpackagesOnly)
