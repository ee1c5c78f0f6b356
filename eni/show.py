"""What ``ecatcfg show ENI`` shows: an ENI's network as a reader wants it, from any tool's file.

:func:`summary` turns a :class:`NetworkPlan` into plain objects (JSON-ready through
:func:`as_json`): the slaves with identity, position, parent and port (passive terminals
marked), the process image's variables at ``byte.bit``, the cyclic frames with each
command's expected working counter, and each slave's InitCmds per transition in words
(:mod:`ecatcfg.eni.words`), in the order ``apply`` sends them (:mod:`ecatcfg.eni.sequence`).
The command line only formats it.
"""

from __future__ import annotations

from typing import Any

from ecatcfg.eni.network_tree import previous_port
from ecatcfg.eni.plan import NetworkPlan, PassiveSlave, SlavePlan, Unsupported, Variable
from ecatcfg.eni.sequence import transition_sequence
from ecatcfg.eni.words import (coe_words, command_name, copy_words, eoe_words, foe_words,
                               init_cmd_words, soe_words)
from ecatcfg.esc import Transition
from ecatcfg.record import field, record


@record
class SlaveView:
    name: str
    position: int | None                     # None: passive (no ESC, no position)
    phys_addr: int | None
    vendor_id: int
    product_code: int
    revision: int
    passive: bool = False
    parent: str | None = None
    port: str | None = None                  # the parent's port (A-D) when the ENI says
    init_cmds: dict[str, list[str]] = field(default_factory=dict)


@record
class VariableView:
    name: str
    direction: str                           # "in" / "out"
    bit_offs: int
    bit_size: int
    data_type: str | None

    @property
    def offset(self) -> str:
        """``byte.bit`` in the process image."""
        return f"{self.bit_offs // 8}.{self.bit_offs % 8}"


@record
class CommandView:
    cmd: str
    adp: int | None                          # physical: position or station address ...
    ado: int | None                          # ... and register
    addr: int | None                         # logical address
    length: int
    wkc: int | None                          # expected working counter (ENI Cnt)
    states: list[str]
    copies: list[str] = field(default_factory=list)   # its CopyInfos in words, file order


@record
class FrameView:
    cycle_time_us: int | None
    commands: list[CommandView]


@record
class EniView:
    file: str
    slaves: list[SlaveView]
    inputs_size: int
    outputs_size: int
    variables: list[VariableView]
    frames: list[FrameView]
    # What the reader kept but apply does not do (``eni/contents.py``): named, never
    # dropped from what is shown.
    unsupported: list[Unsupported] = field(default_factory=list)
    master_init_cmds: dict[str, list[str]] = field(default_factory=dict)
    # Unknown metadata the reader left out (``NetworkPlan.ignored``): shown, not applied.
    ignored: list[Unsupported] = field(default_factory=list)


def master_words(plan: NetworkPlan) -> dict[str, list[str]]:
    """The master's own InitCmds (``Config/Master/InitCmds``) per transition, in words."""
    out: dict[str, list[str]] = {t.value: [] for t in Transition}
    for cmd in plan.master.init_cmds:
        for t in cmd.transitions:
            out[t.value].append(init_cmd_words(cmd))
    return {t: words for t, words in out.items() if words}


def transition_words(slave: SlavePlan) -> dict[str, list[str]]:
    """Each transition's InitCmds in words, in the order ``apply`` sends them
    (``eni/sequence.py``, the one definition both use): the register commands up to the
    state request, the CoE, SoE, EoE and FoE commands, then the request and the rest; the
    disabled mailbox commands where they would stand, marked so.  Transitions in the order
    of ``esc.Transition``."""
    out: dict[str, list[str]] = {}
    for t in Transition:
        sequence = transition_sequence(slave, t, with_disabled=True)
        words = [init_cmd_words(c) for c in sequence.before]
        words += [coe_words(c) for c in sequence.coe] + [soe_words(c) for c in sequence.soe]
        words += [eoe_words(c) for c in sequence.eoe] + [foe_words(c) for c in sequence.foe]
        words += [init_cmd_words(c) for c in sequence.after]
        if words:
            out[t.value] = words
    return out


def _parent(plan: NetworkPlan, index: int, slave: SlavePlan | PassiveSlave,
            order: list[SlavePlan | PassiveSlave]) -> tuple[str | None, str | None]:
    by_addr = {s.phys_addr: s.name for s in plan.slaves}
    prev = previous_port(slave.previous_ports)
    if prev is not None and prev.phys_addr is not None:
        return by_addr.get(prev.phys_addr), prev.port
    # Without PreviousPort an ENI describes a line: behind the slave before it.
    return (order[index - 1].name if index else None), None


def summary(plan: NetworkPlan, file: str) -> EniView:
    order = plan.in_file_order()
    slaves = []
    for k, s in enumerate(order):
        parent, port = _parent(plan, k, s, order)
        if isinstance(s, PassiveSlave):
            slaves.append(SlaveView(s.name, None, None, s.vendor_id, s.product_code,
                                    s.revision, True, parent, port))
        else:
            slaves.append(SlaveView(s.name, s.position, s.phys_addr, s.vendor_id,
                                    s.product_code, s.revision, False, parent, port,
                                    transition_words(s)))
    image = plan.process_image
    variables = [_variable(v, "in") for v in image.inputs] + \
        [_variable(v, "out") for v in image.outputs]
    frames = [FrameView(c.cycle_time, [
        CommandView(command_name(cmd.cmd), cmd.adp, cmd.ado, cmd.addr, cmd.length, cmd.cnt,
                    list(cmd.states), [copy_words(copy, image.inputs, image.outputs)
                                       for copy in cmd.copy_infos]) for cmd in f.cmds])
        for c in plan.cyclic for f in c.frames]
    return EniView(file, slaves, image.inputs_size, image.outputs_size, variables, frames,
                   list(plan.unsupported), master_words(plan), list(plan.ignored))


def _variable(v: Variable, direction: str) -> VariableView:
    return VariableView(v.name, direction, v.bit_offs, v.bit_size, v.data_type)


def as_json(view: EniView) -> dict[str, Any]:
    """The ``show ENI --format json`` shape (docs/show-diff-check.md)."""
    return {
        "file": view.file,
        "master_init_cmds": view.master_init_cmds,
        "slaves": [{"name": s.name, "position": s.position, "phys_addr": s.phys_addr,
                    "vendor_id": s.vendor_id, "product_code": s.product_code,
                    "revision": s.revision, "passive": s.passive, "parent": s.parent,
                    "port": s.port, "init_cmds": s.init_cmds} for s in view.slaves],
        "process_image": {
            "inputs_size": view.inputs_size, "outputs_size": view.outputs_size,
            "variables": [{"name": v.name, "direction": v.direction, "offset": v.offset,
                           "bit_offs": v.bit_offs, "bit_size": v.bit_size,
                           "type": v.data_type} for v in view.variables]},
        "frames": [{"cycle_time_us": f.cycle_time_us,
                    "commands": [{"cmd": c.cmd, "adp": c.adp, "ado": c.ado, "addr": c.addr,
                                  "length": c.length,
                                  "wkc": c.wkc, "states": c.states, "copies": c.copies}
                                 for c in f.commands]}
                   for f in view.frames],
        "unsupported": [{"slave": u.slave, "element": u.element, "what": u.what,
                         "line": u.line, "commands": u.commands} for u in view.unsupported],
        "ignored": [{"slave": u.slave, "element": u.element, "what": u.what, "line": u.line}
                    for u in view.ignored],
    }
