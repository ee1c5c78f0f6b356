"""Hot-connect groups (ETG.2100 ``Config/Slave/HotConnect``): parts of the line that may be
absent at start-up and come and go while the rest runs.

A group is its head and the slaves after it in the ENI's order, ``GroupMemberCnt`` in all
(``eni/plan.py`` :class:`HotConnectPlan`).  At start-up the master decides for each group
whether it is there: its head must be found where the ENI's order puts it (in a line: the
next slave found; in a tree: on the ENI's port of its parent) with the head's identity, and
the group's ``IdentifyCmd`` commands (a read of the station alias 0x0012 or of the ID
register 0x0134 with a ``Validate``) must succeed at that position.  A group that is not
there is left out: the other slaves move up in the auto-increment order, so their plans are
moved with them (:func:`at_position`, :func:`as_found`), and the rest is verified
and brought up as usual.  While the network cycles, the supervisor
(``runtime/master/recovery.py``) looks for the absent groups where they would be, identifies the
head and brings the group up.

The ENI's slave order is the bus order of the complete line (auto-increment addresses), so
a slave's position on the line as it is is the number of slaves present before it in that
order (:func:`positions`).
"""

from __future__ import annotations

from collections.abc import Iterable

from ecatcfg.eni.plan import CyclicCmd, InitCmd, NetworkPlan, SlavePlan
from ecatcfg.esc import AUTO_INCREMENT_CMDS
from ecatcfg.record import replace
from ecatcfg.runtime.master.lockstep import Job
from ecatcfg.runtime.master.replay import ApplyError, init_cmd_job
from ecatcfg.runtime.master.scan import FoundSlave, paired



def slaves(n: int) -> str:
    """"1 slave", "3 slaves": a group's size in a message."""
    return f"{n} slave" + ("" if n == 1 else "s")


def groups(slaves: Iterable[SlavePlan]) -> dict[str, list[SlavePlan]]:
    """Each group's head name and its members (the head first), in bus order."""
    ordered = sorted(slaves, key=lambda s: s.position)
    out: dict[str, list[SlavePlan]] = {}
    for k, s in enumerate(ordered):
        if s.hot_connect is not None:
            out[s.name] = ordered[k:k + s.hot_connect.member_count]
    return out


def positions(slaves: Iterable[SlavePlan], present: set[str]) -> dict[str, int]:
    """Where each slave is (or would be, if it came now) when the slaves named in
    ``present`` are on the line: the number of present slaves before it in bus order."""
    out: dict[str, int] = {}
    before = 0
    for s in sorted(slaves, key=lambda s: s.position):
        out[s.name] = before
        before += s.name in present
    return out


def moved(cmds: list[InitCmd], old: int, new: int) -> list[InitCmd]:
    """``cmds`` with the auto-increment commands addressed to ``old`` sent to ``new``."""
    if old == new:
        return cmds
    return [replace(c, adp=new) if c.cmd in AUTO_INCREMENT_CMDS and c.adp == old else c
            for c in cmds]


def at_position(slave: SlavePlan, position: int) -> SlavePlan:
    """The slave's plan for when it sits at ``position``: its auto-increment address and
    the auto-increment commands among its InitCmds (and IdentifyCmds) moved there."""
    adp = -position & 0xFFFF
    if adp == slave.auto_inc_addr:
        return slave
    group = slave.hot_connect
    if group is not None:
        group = replace(group, identify_cmds=moved(group.identify_cmds, slave.auto_inc_addr,
                                                   adp))
    return replace(slave, auto_inc_addr=adp, hot_connect=group,
                   init_cmds=moved(slave.init_cmds, slave.auto_inc_addr, adp))


def identify_job(head: SlavePlan, position: int, out: dict[tuple[str, int], bool]) -> Job:
    """The group's IdentifyCmds sent to ``position``: ``out[(head, position)]`` is whether
    every one got its working counter and its Validate data."""
    group = at_position(head, position).hot_connect
    assert group is not None
    ok = True
    try:
        for cmd in group.identify_cmds:
            yield from init_cmd_job(cmd, head.name)
    except ApplyError:
        ok = False
    out[(head.name, position)] = ok


def candidates(plan: NetworkPlan, found: list[FoundSlave]) -> list[tuple[SlavePlan, int]]:
    """(head, position) pairs worth identifying: a found slave with the head's vendor and
    product code."""
    heads = [s for s in plan.slaves if s.hot_connect is not None]
    return [(h, f.position) for h in heads for f in found
            if (f.vendor_id, f.product_code) == (h.vendor_id, h.product_code)]


def present_groups(plan: NetworkPlan, found: list[FoundSlave],
                   identified: dict[tuple[str, int], bool]) -> set[str]:
    """The heads of the groups that are on the line.  In a line: walking the ENI's slaves
    and the slaves found side by side, a group is there when the next slave found is its
    head (identity and IdentifyCmds), and skipped otherwise.  With ``PreviousPort`` (a
    tree): a group is there when its head pairs port by port with an identified slave, in
    the line without the groups before it in bus order that are not there (a head plugged
    behind an absent group sits where that group was: :func:`as_found`)."""
    ordered = sorted(plan.slaves, key=lambda s: s.position)
    heads = groups(ordered)
    tree = any(s.previous_ports for s in ordered[1:]) and all(
        f.plug is not None for f in found[1:])
    if tree:
        # Heads in bus order: where a head is plugged depends only on the slaves before
        # it, so the groups found absent so far are all that moves it.
        on_line = {s.name for s in ordered}
        for h, members in heads.items():
            pairs = paired(as_found(plan, on_line), found)
            at = pairs.get(positions(ordered, on_line)[h], -1)
            if not identified.get((h, at), False):
                on_line -= {m.name for m in members}
        return {h for h in heads if h in on_line}
    present: set[str] = set()
    f = 0
    k = 0
    while k < len(ordered):
        s = ordered[k]
        if s.name in heads:
            if identified.get((s.name, f), False):
                present.add(s.name)
            else:
                k += len(heads[s.name])
                continue
        f += 1
        k += 1
    return present


def absent_slaves(plan: NetworkPlan, present_heads: set[str]) -> dict[str, str]:
    """The slaves of the groups that are not there, with their head's name."""
    return {m.name: head for head, members in groups(plan.slaves).items()
            if head not in present_heads for m in members}



def as_found(plan: NetworkPlan, present: set[str]) -> NetworkPlan:
    """The plan of the line as it is when only the slaves named in ``present`` are on it:
    those slaves at their positions (:func:`positions`), and the cyclic commands that
    address a slave by position (the drift compensation's ARMW to the reference clock)
    moved with it."""
    where = positions(plan.slaves, present)
    if all(where[s.name] == s.position for s in plan.slaves if s.name in present):
        return replace(plan, slaves=[_reconnected(s, plan, present) for s in plan.slaves
                                     if s.name in present])
    adps = {s.auto_inc_addr: -where[s.name] & 0xFFFF for s in plan.slaves
            if s.name in present}

    def move(c: CyclicCmd) -> CyclicCmd:
        if c.cmd in AUTO_INCREMENT_CMDS and c.adp in adps:
            return replace(c, adp=adps[c.adp])
        return c

    return replace(
        plan, slaves=[at_position(_reconnected(s, plan, present), where[s.name])
                      for s in plan.slaves if s.name in present],
        cyclic=[replace(cyc, frames=[replace(f, cmds=[move(c) for c in f.cmds])
                                     for f in cyc.frames]) for cyc in plan.cyclic])


def _reconnected(slave: SlavePlan, plan: NetworkPlan, present: set[str]) -> SlavePlan:
    """The slave's ``PreviousPort`` on the line without the absent groups: the ENI's
    hot-connect alternative (another ``PreviousPort`` entry) that names a slave present,
    else, through the absent slaves, the port the first of them is plugged into (a group
    left out of a line: the next slave is where the group was)."""
    ports = slave.previous_ports
    chosen = next((p for p in ports if p.selected), ports[0] if ports else None)
    by_address = {s.phys_addr: s for s in plan.slaves}
    if chosen is None or chosen.phys_addr not in by_address or \
            by_address[chosen.phys_addr].name in present:
        return slave
    other = next((p for p in ports if p.phys_addr in by_address
                  and by_address[p.phys_addr].name in present), None)
    if other is None:
        parent = by_address[chosen.phys_addr]
        while parent.name not in present and parent.previous_ports:
            up = next((p for p in parent.previous_ports if p.selected),
                      parent.previous_ports[0])
            if up.phys_addr not in by_address:
                break
            other, parent = up, by_address[up.phys_addr]
        if other is None or parent.name not in present:
            return replace(slave, previous_ports=[])
    return replace(slave, previous_ports=[replace(other, selected=True)])
