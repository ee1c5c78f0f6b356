"""Live process data by variable name (``ecatcfg watch``): which variables to show, outputs
forced to a value every cycle (and released again), what changed since the last look, the
status line (:func:`status`) and TwinCAT's diagnostic variables (:class:`InfoData`).

The values are the ENI's process image variables as the :class:`~ecatcfg.runtime.network.
Network` reads and writes them (``net[name]``); drawing them, and reading what the user
types, is the command line's.
"""

from __future__ import annotations

import fnmatch
import re
from typing import Any

from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.eni.words import command_address
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import LOGICAL_CMDS
from ecatcfg.runtime.master.cyclic import CommandCount
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


def status(net: Network) -> dict[str, Any]:
    """What watch's status line shows, from the run so far: the cycles, the slaves in the
    network's state (and each one that is not, with why), each process-data command's
    working counter against the one it expects in the last cycle, lost frames, late cycles
    and the jitter of the cycle period (p50/p99 of its deviation from the median, us)."""
    stats = net.run_stats
    health = net.health
    offline = {name: h.reason or "offline" for name, h in health.items() if not h.online}
    counts = [{"cmd": command_address(c.cmd), "wkc": c.wkc, "expected": c.expected}
              for frame in net.master.cyclic.working_counters() for c in frame
              if c.cmd.cmd in LOGICAL_CMDS and c.expected is not None]
    jitter = stats.jitter() if stats is not None else {"p50": 0.0, "p99": 0.0, "max": 0.0}
    return {"cycles": stats.cycles if stats is not None else 0, "state": net.state.name,
            "online": len(health) - len(offline), "slaves": len(health), "offline": offline,
            "working_counters": counts,
            "lost_frames": stats.lost_frames if stats is not None else 0,
            "late": stats.late if stats is not None else 0,
            "jitter_us": {"p50": round(jitter["p50"], 1), "p99": round(jitter["p99"], 1)}}


def status_text(s: dict[str, Any]) -> str:
    """``cycle 1200 | 5/5 slaves in OP | LRW 0x10000000 wkc 7/7 | lost 0 | late 0 |
    jitter p50 12.0 us p99 85.0 us``; offline slaves named after the count."""
    slaves = f"{s['online']}/{s['slaves']} slaves in {s['state']}"
    if s["offline"]:
        slaves += " (" + ", ".join(f"{n}: {why}" for n, why in s["offline"].items()) + ")"
    counts = [f"{c['cmd']} wkc {'lost' if c['wkc'] < 0 else c['wkc']}/{c['expected']}"
              for c in s["working_counters"]]
    jitter = s["jitter_us"]
    return " | ".join([f"cycle {s['cycles']}", slaves, *counts, f"lost {s['lost_frames']}",
                       f"late {s['late']}",
                       f"jitter p50 {jitter['p50']} us p99 {jitter['p99']} us"])


# TwinCAT's diagnostic variables in the process image of its ENIs (Beckhoff, TwinCAT
# EtherCAT master "Diagnosis": InfoData and WcState).  TwinCAT's master fills them in the
# input image; the slaves never send them, so a master that does not fill them shows 0
# while every slave is in OP.
_SLAVE_STATE = re.compile(r"(?P<slave>.+)\.InfoData\.State$")
_SLAVE_WC_STATE = re.compile(r"(?P<slave>.+)\.WcState\.WcState$")
_FRAME_WC_STATE = re.compile(r"Inputs\.Frm(?P<frame>\d+)WcState$")
# InfoData.State: the AL state in bits 0-3, plus 0x0010 "slave signals error" and 0x0100
# "slave not present" (the same table).
STATE_ERROR = 0x0010
STATE_NOT_PRESENT = 0x0100


class InfoData:
    """The values of TwinCAT's diagnostic variables an ENI names, from what the master
    knows: ``<slave>.InfoData.State`` (its AL state while online; 0x0010 when offline,
    0x0100 when not on the line), ``<slave>.WcState.WcState`` (1 when a command carrying
    the slave's data came back with another working counter in the last cycle),
    ``Inputs.Frm<n>WcState`` (bit k: datagram k of frame n), ``Inputs.SlaveCount`` and
    ``InfoData.CfgSlaveCount``.  Other diagnostic variables (TwinCAT's own ADS data) are
    left as they are."""

    def __init__(self, net: Network) -> None:
        self.net = net
        plan = net.plan
        slaves = sorted((s.name for s in plan.slaves), key=len, reverse=True)
        data: dict[str, list[tuple[str, int]]] = {}     # slave -> (in/out, image byte)
        self.slave_of: dict[str, str] = {}               # diagnostic name -> slave
        self.kind: dict[str, str] = {}
        for direction, variables in (("in", plan.process_image.inputs),
                                     ("out", plan.process_image.outputs)):
            for v in variables:
                for kind, pattern in (("state", _SLAVE_STATE), ("wc", _SLAVE_WC_STATE)):
                    found = pattern.match(v.name)
                    if found and found["slave"] in slaves:
                        self.kind[v.name], self.slave_of[v.name] = kind, found["slave"]
                        break
                else:
                    if _FRAME_WC_STATE.match(v.name):
                        self.kind[v.name] = "frame"
                    elif v.name in ("Inputs.SlaveCount", "InfoData.CfgSlaveCount"):
                        self.kind[v.name] = v.name
                    else:
                        owner = next((s for s in slaves if v.name.startswith(s + ".")), None)
                        if owner is not None:
                            data.setdefault(owner, []).append((direction, v.bit_offs // 8))
        self._data = data

    @property
    def names(self) -> list[str]:
        return list(self.kind)

    def values(self) -> dict[str, int]:
        net = self.net
        health = net.health
        frames = net.master.cyclic.working_counters()
        out: dict[str, int] = {}
        for name, kind in self.kind.items():
            if kind == "state":
                h = health.get(self.slave_of[name])
                out[name] = (int(net.state) if h is None or h.online else
                             STATE_NOT_PRESENT if h.reason == "not on the line"
                             else STATE_ERROR)
            elif kind == "wc":
                out[name] = int(any(not c.ok for frame in frames for c in frame
                                    if self._serves(c, self.slave_of[name])))
            elif kind == "frame":
                n = int(_FRAME_WC_STATE.match(name)["frame"])   # type: ignore[index]
                out[name] = sum(1 << k for k, c in enumerate(frames[n] if n < len(frames)
                                                             else []) if not c.ok)
            elif kind == "Inputs.SlaveCount":
                out[name] = sum(1 for h in health.values() if h.online)
            else:
                out[name] = len(net.plan.slaves)
        return out

    def _serves(self, c: CommandCount, slave: str) -> bool:
        """Whether command ``c`` carries any of ``slave``'s process data."""
        if c.cmd.cmd not in LOGICAL_CMDS:
            return False
        n = c.cmd.length
        return any(c.in_at <= at < c.in_at + n if d == "in" else c.out_at <= at < c.out_at + n
                   for d, at in self._data.get(slave, []))


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
        self.info = InfoData(net)
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
        """Each variable's value: the process image's, but TwinCAT's diagnostic variables
        computed from what the master knows (:class:`InfoData`)."""
        computed = self.info.values() if self.info.names else {}
        return {name: computed[name] if name in computed else self.net[name]
                for name in self.names}

    def changes(self) -> dict[str, Value]:
        """The variables whose value, or whether they are forced, differs from the last
        call's (all on the first)."""
        now = {n: (v, n in self.forced) for n, v in self.values().items()}
        changed = {n: v for n, (v, f) in now.items() if self._last.get(n) != (v, f)}
        self._last = now
        return changed
