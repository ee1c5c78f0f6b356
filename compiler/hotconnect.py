"""Hot-connect groups (ETG.2100 ``Config/Slave/HotConnect``) from the topology's heads.

A slave with ``hot_connect: true`` heads a group: itself and every slave behind it, that is
every slave whose way to the master passes through it (the rest of a line; in a tree, its
branches through junction ports), except the slaves behind another head further down,
which form that head's group.  The ENI counts a group as its head and the slaves that
follow it in the file (``GroupMemberCnt``), and the file lists the slaves in bus order
(depth first, ports in processing order, ``compiler/wiring.py``), so a head's branch is one
run of slaves; its group is that run up to the first nested group, which must therefore
come after all of the group's own slaves.  When the wiring puts a nested group in the
middle (a junction's port processed before a port the group goes on through) that is an
error: the group could not be written as a count.

The master recognises the head by its station alias (ESC register 0x0012, loaded from SII
word 4 at power-on): one auto-increment read where the head is when every slave is present,
validated against the alias the topology gives.
"""

from __future__ import annotations

import struct

from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.eni.plan import HotConnectPlan, InitCmd, Validate
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import Cmd, Reg

# How long the master re-reads the alias when it does not match yet (ms): the ESC loads it
# from the EEPROM just after power-on, so a head that has just appeared may still show 0.
IDENTIFY_TIMEOUT = 100


def groups(loaded: LoadedTopology, resolved: list[ResolvedSlave]
           ) -> tuple[dict[int, HotConnectPlan], list[EcatcfgError]]:
    """The group of every head, by bus position, and the errors (each at its head's line).

    ``resolved`` is the whole network in bus order (``resolved[n].position == n``)."""
    heads = {s.position for s in resolved if s.cfg.hot_connect}
    errors: list[EcatcfgError] = []
    for s in resolved:
        if s.cfg.hot_connect and s.cfg.alias is None:
            errors.append(loaded.error(
                f"slave {s.name!r}: a hot-connect group's head needs 'alias', the station "
                "alias (register 0x0012) the master recognises it by", "slaves", s.index,
                "hot_connect"))
    if not heads:
        return {}, errors
    owner: list[int | None] = []             # by bus position: the head of its group
    for s in resolved:                       # a parent comes before its children
        if s.position in heads:
            owner.append(s.position)
        else:
            owner.append(None if s.parent is None else owner[s.parent])
    result: dict[int, HotConnectPlan] = {}
    for head in sorted(heads):
        members = [n for n, o in enumerate(owner) if o == head]
        count = len(members)
        if members != list(range(head, head + count)):
            errors.append(_gap_error(loaded, resolved, owner, head, members))
            continue
        s = resolved[head]
        if s.cfg.alias is not None:
            result[head] = HotConnectPlan(count, [identify_by_alias(s.position, s.cfg.alias)])
    return result, sorted(errors, key=lambda e: e.line or 0)     # in file order


def identify_by_alias(position: int, alias: int) -> InitCmd:
    """APRD of the station alias (0x0012, 2 bytes) at the head's auto-increment address,
    one slave answering (working counter 1), validated against ``alias``."""
    return InitCmd([], "identify hot-connect group head: station alias", Cmd.APRD, 2,
                   adp=(-position) & 0xFFFF, ado=Reg.STATION_ALIAS, cnt=1,
                   validate=Validate(struct.pack("<H", alias), b"\xff\xff", IDENTIFY_TIMEOUT))


def _gap_error(loaded: LoadedTopology, resolved: list[ResolvedSlave], owner: list[int | None],
               head: int, members: list[int]) -> EcatcfgError:
    """The first slave of another group inside ``head``'s run, and the member after it."""
    gap = next(n for n in range(head, members[-1]) if owner[n] != head)
    after = next(n for n in members if n > gap)
    s, nested, member = resolved[head], resolved[owner[gap] or gap], resolved[after]
    return loaded.error(
        f"slave {s.name!r}: its hot-connect group is not one run of slaves in bus order: "
        f"the group of {nested.name!r} comes between it and its member {member.name!r}; a "
        "group is written as its head and a count of the slaves that follow, so plug the "
        f"nested group on a port the frame passes after {member.name!r} (ports in the order "
        "D, B, C), or make it no group of its own", "slaves", s.index, "hot_connect")
