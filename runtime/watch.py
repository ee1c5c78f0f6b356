"""Live process data by variable name (``ecatcfg watch``): which variables to show, outputs
forced to a value every cycle, and what changed since the last look.

The values are the ENI's process image variables as the :class:`~ecatcfg.runtime.network.
Network` reads and writes them (``net[name]``); drawing them is the command line's.
"""

from __future__ import annotations

import fnmatch

from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.errors import EcatcfgError
from ecatcfg.runtime.network import Network

Value = bool | int | float


def parse_force(plan: NetworkPlan, text: str) -> tuple[str, Value]:
    """``NAME=VALUE`` -> (output variable, value for its type): ``1``/``0``/``true``/
    ``false`` for a bit, an integer (``0x`` hex allowed) or a number for REAL/LREAL.  The
    last ``=`` separates them, as variable names may contain one."""
    name, sep, raw = text.rpartition("=")
    if not sep or not name:
        raise EcatcfgError(f"--force {text!r}: give NAME=VALUE")
    outputs = {v.name: v for v in plan.process_image.outputs}
    if name not in outputs:
        if name in {v.name for v in plan.process_image.inputs}:
            raise EcatcfgError(f"--force {text!r}: {name!r} is an input; only outputs can "
                               "be forced")
        import difflib
        close = difflib.get_close_matches(name, outputs, 3)
        raise EcatcfgError(f"--force {text!r}: no output variable {name!r} in the ENI"
                           + (f" (did you mean {', '.join(map(repr, close))}?)"
                              if close else ""))
    var = outputs[name]
    kind = (var.data_type or "").upper()
    raw = raw.strip()
    value: Value
    try:
        if kind in ("REAL", "LREAL"):
            value = float(raw)
        elif var.bit_size == 1 and raw.lower() in ("true", "false", "on", "off"):
            value = raw.lower() in ("true", "on")
        else:
            value = int(raw, 0)
    except ValueError:
        raise EcatcfgError(f"--force {text!r}: {raw!r} is not a value for "
                           f"{kind or 'this variable'}") from None
    return name, value


class Watch:
    """The variables of ``net`` whose names match one of ``patterns`` (shell patterns; all
    when none), and the outputs in ``forced`` written every cycle (:meth:`force`)."""

    def __init__(self, net: Network, patterns: list[str] | None = None,
                 forced: dict[str, Value] | None = None) -> None:
        self.net = net
        self.forced = dict(forced or {})
        names = net.variables
        if patterns:
            names = [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in patterns)]
            if not names:
                raise EcatcfgError(f"no variable of the ENI matches {', '.join(patterns)}")
        self.names = names
        self.outputs = {v.name for v in net.plan.process_image.outputs}
        self._last: dict[str, Value] = {}
        for name, value in self.forced.items():      # range checked before the line is up
            net[name] = value

    def force(self) -> None:
        for name, value in self.forced.items():
            self.net[name] = value

    def values(self) -> dict[str, Value]:
        return {name: self.net[name] for name in self.names}

    def changes(self) -> dict[str, Value]:
        """The variables whose value differs from the last call's (all on the first)."""
        now = self.values()
        changed = {n: v for n, v in now.items() if self._last.get(n) != v or n not in self._last}
        self._last = now
        return changed
