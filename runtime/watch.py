"""Live process data by variable name (``ecatcfg watch``): which variables to show, outputs
forced to a value every cycle (and released again), and what changed since the last look.

The values are the ENI's process image variables as the :class:`~ecatcfg.runtime.network.
Network` reads and writes them (``net[name]``); drawing them, and reading what the user
types, is the command line's.
"""

from __future__ import annotations

import fnmatch

from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.errors import EcatcfgError
from ecatcfg.runtime.network import Network

Value = bool | int | float


def parse_force(plan: NetworkPlan, text: str) -> tuple[str, Value]:
    """``NAME=VALUE`` -> (output variable, value for its type), as :func:`output_value`.
    The last ``=`` separates them, as variable names may contain one."""
    name, sep, raw = text.rpartition("=")
    if not sep or not name:
        raise EcatcfgError(f"--force {text!r}: give NAME=VALUE")
    try:
        return name, output_value(plan, name, raw)
    except EcatcfgError as exc:
        raise EcatcfgError(f"--force {text!r}: {exc}") from None


def output_value(plan: NetworkPlan, name: str, raw: str) -> Value:
    """The value ``raw`` means for output variable ``name``: ``1``/``0``/``true``/``false``
    (``on``/``off``) for a bit, an integer (``0x`` hex allowed) or a number for REAL/LREAL.
    The range of the type is checked where the value is written (``Network[name] = value``).
    An unknown name (with the closest ones) or an input is an error."""
    outputs = {v.name: v for v in plan.process_image.outputs}
    if name not in outputs:
        if name in {v.name for v in plan.process_image.inputs}:
            raise EcatcfgError(f"{name!r} is an input; only outputs can be forced")
        import difflib
        close = difflib.get_close_matches(name, outputs, 3)
        raise EcatcfgError(f"no output variable {name!r} in the ENI"
                           + (f" (did you mean {', '.join(map(repr, close))}?)"
                              if close else ""))
    var = outputs[name]
    kind = (var.data_type or "").upper()
    raw = raw.strip()
    try:
        if kind in ("REAL", "LREAL"):
            return float(raw)
        if var.bit_size == 1 and raw.lower() in ("true", "false", "on", "off"):
            return raw.lower() in ("true", "on")
        return int(raw, 0)
    except ValueError:
        raise EcatcfgError(f"{raw!r} is not a value for {kind or 'this variable'}") from None


class Watch:
    """The variables of ``net`` whose names match one of ``patterns`` (shell patterns; all
    when none), and the outputs in ``forced`` written every cycle (:meth:`force`).

    Not thread-safe: the forcing commands (:meth:`force_output`, :meth:`release`) are meant
    for the thread that calls :meth:`force`, the cycling one (``ecatcfg watch`` runs what
    the user types in the cycle's callback)."""

    def __init__(self, net: Network, patterns: list[str] | None = None,
                 forced: dict[str, Value] | None = None) -> None:
        self.net = net
        self.forced: dict[str, Value] = {}
        names = net.variables
        if patterns:
            names = [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in patterns)]
            if not names:
                raise EcatcfgError(f"no variable of the ENI matches {', '.join(patterns)}")
        self.names = names
        self.outputs = {v.name for v in net.plan.process_image.outputs}
        self._last: dict[str, tuple[Value, bool]] = {}
        # What each forced output held before it was forced: nothing else writes the
        # outputs while watch runs, so releasing one puts this back.
        self._before: dict[str, Value] = {}
        for name, value in (forced or {}).items():   # range checked before the line is up
            self.force_output(name, value)

    def force_output(self, name: str, value: Value) -> None:
        """Write ``value`` to output ``name`` now and every cycle from here on; a value out of
        the type's range, or a name that is not an output, is an error and forces nothing."""
        before = self.net[name]
        self.net[name] = value                       # the type's range is checked here
        self._before.setdefault(name, before)
        self.forced[name] = value

    def release(self, name: str) -> Value:
        """Stop forcing ``name`` and put back the value it held before it was forced (which
        is returned)."""
        if name not in self.forced:
            raise EcatcfgError(f"{name!r} is not forced"
                               + (f" (forced: {', '.join(map(repr, self.forced))})"
                                  if self.forced else ""))
        del self.forced[name]
        before = self._before.pop(name)
        self.net[name] = before
        return before

    def force(self) -> None:
        for name, value in self.forced.items():
            self.net[name] = value

    def values(self) -> dict[str, Value]:
        return {name: self.net[name] for name in self.names}

    def changes(self) -> dict[str, Value]:
        """The variables whose value, or whether they are forced, differs from the last
        call's (all on the first)."""
        now = {n: (v, n in self.forced) for n, v in self.values().items()}
        changed = {n: v for n, (v, f) in now.items() if self._last.get(n) != (v, f)}
        self._last = now
        return changed
