"""A topology's devices as they sit in the network: what a virtual segment emulates
(``ecatcfg simulate --topology``), after the checks a compile makes.

Above :mod:`~ecatcfg.compiler.resolve`, :mod:`~ecatcfg.compiler.passive` and
:mod:`~ecatcfg.compiler.esi_errors`: it uses all three, and the last two use the first.
"""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.compiler.esi_errors import FileGate, slave_errors
from ecatcfg.compiler.passive import split
from ecatcfg.compiler.resolve import resolve_all
from ecatcfg.compiler.topology import LoadedTopology, TopologyError
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.library import Library
from ecatcfg.esi.model import Device
from ecatcfg.esi.slots import with_modules


@dataclass(frozen=True, slots=True)
class PluggedDevice:
    """A topology slave's device as it sits in the network: with the PDOs and dictionaries
    of the modules the topology plugs into its slots (what a virtual segment emulates), and
    where it is plugged: the bus position of its parent and the parent's ESC port (0-3;
    ``None`` for the first slave, which the master is plugged into, through its port 0)."""

    name: str
    device: Device
    alias: int = 0
    parent: int | None = None
    parent_port: int | None = None
    # ESI errors that change what compile writes, let through by ``allow_esi_errors``.
    esi_warnings: tuple[EcatcfgError, ...] = ()


def plugged_devices(loaded: LoadedTopology, library: Library,
                    allow_esi_errors: bool = False) -> list[PluggedDevice]:
    """The devices of a topology's slaves in bus order (auto-increment positions 0, 1, ...:
    the frame's path through the tree), after the same checks as a compile (an unknown
    device, a module that does not fit its slot, a port that cannot be plugged is an error at
    its line).  A slave's ``parent`` is an index into this list, always a smaller one.
    Passive terminals (no ESC, ``compiler/passive.py``) are not in it: nothing to emulate.
    An ESI error that would stop a compile (``compiler/esi_errors.py``) stops this too,
    or with ``allow_esi_errors`` is in the device's ``esi_warnings``."""
    parts = split(loaded, library)
    resolved, errors, _ = resolve_all(parts.active, library)
    errors = parts.errors + errors
    gate = FileGate(library, resolved)
    defects = [slave_errors(parts.active, r, library, allow_esi_errors, gate) for r in resolved]
    if not allow_esi_errors:
        errors += [e for found in defects for e in found]
    if errors:
        raise TopologyError(errors)
    return [PluggedDevice(r.name, with_modules(r.device, r.modules), r.cfg.alias or 0,
                          r.parent, r.parent_port,
                          tuple(found) if allow_esi_errors else ())
            for r, found in zip(resolved, defects)]
