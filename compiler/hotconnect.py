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
word 4 at power-on) and/or its explicit device ID (an ID switch): auto-increment commands
where the head is when every slave is present, validated against the values the topology
gives.  Where the ID is, the ESI says: ``Info/IdentificationAdo`` (a register or memory
address that shows it; the EK1101's switch at 0x1000) or ``Info/IdentificationReg134``
(ETG.1020 "Requesting ID": AL control bit 5 makes the slave show it in AL status code
0x0134, with AL status bit 5).
"""

from __future__ import annotations

import struct

from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.eni.plan import HotConnectPlan, InitCmd, Validate
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AL_ID_REQUEST, AL_STATUS_ID, AlState, Cmd, Reg

# How long the master re-reads the alias when it does not match yet (ms): the ESC loads it
# from the EEPROM just after power-on, so a head that has just appeared may still show 0.
IDENTIFY_TIMEOUT = 100


def groups(loaded: LoadedTopology, resolved: list[ResolvedSlave]
           ) -> tuple[dict[int, HotConnectPlan], list[EcatcfgError]]:
    """The group of every head, by bus position, and the errors (each at its head's line).

    ``resolved`` is the whole network in bus order (``resolved[n].position == n``)."""
    heads = {s.position for s in resolved if s.cfg.hot_connect}
    errors: list[EcatcfgError] = []
    identify: dict[int, list[InitCmd]] = {}
    for s in resolved:
        if s.cfg.hot_connect:
            cmds = _identify_cmds(loaded, s, errors)
            if cmds:
                identify[s.position] = cmds
        elif s.cfg.device_id is not None:
            errors.append(loaded.error(
                f"slave {s.name!r}: 'device_id' identifies the head of a hot-connect group, "
                "and this slave is none (add hot_connect: true)", "slaves", s.index,
                "device_id"))
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
        if head in identify:
            result[head] = HotConnectPlan(count, identify[head])
    return result, sorted(errors, key=lambda e: e.line or 0)     # in file order


def _identify_cmds(loaded: LoadedTopology, s: ResolvedSlave,
                   errors: list[EcatcfgError]) -> list[InitCmd]:
    """The head's IdentifyCmds: its alias, then its device ID; errors when it has neither
    or the ESI does not say where the ID is."""
    cfg, info = s.cfg, s.device.info
    if cfg.alias is None and cfg.device_id is None:
        errors.append(loaded.error(
            f"slave {s.name!r}: a hot-connect group's head needs 'alias' (the station alias, "
            "register 0x0012) or 'device_id' (its ID switch) for the master to recognise it "
            "by", "slaves", s.index, "hot_connect"))
        return []
    cmds = [] if cfg.alias is None else [identify_by_alias(s.position, cfg.alias)]
    if cfg.device_id is None:
        return cmds
    if info is not None and info.identification_ado is not None:
        return cmds + [identify_at(s.position, info.identification_ado, cfg.device_id)]
    if info is not None and info.identification_reg134:
        return cmds + identify_by_request(s.position, cfg.device_id)
    errors.append(loaded.error(
        f"slave {s.name!r}: the ESI of {s.device.type_name} does not say the device has an "
        "ID (Info/IdentificationAdo or IdentificationReg134); identify it by 'alias'",
        "slaves", s.index, "device_id"))
    return []


def _validate16(value: int) -> Validate:
    return Validate(struct.pack("<H", value), b"\xff\xff", IDENTIFY_TIMEOUT)


def identify_by_alias(position: int, alias: int) -> InitCmd:
    """APRD of the station alias (0x0012, 2 bytes) at the head's auto-increment address,
    one slave answering (working counter 1), validated against ``alias``."""
    return InitCmd([], "identify hot-connect group head: station alias", Cmd.APRD, 2,
                   adp=(-position) & 0xFFFF, ado=Reg.STATION_ALIAS, cnt=1,
                   validate=_validate16(alias))


def identify_at(position: int, ado: int, device_id: int) -> InitCmd:
    """APRD of the 16 bits at the ESI's ``IdentificationAdo``, validated against the ID."""
    return InitCmd([], "identify hot-connect group head: device ID", Cmd.APRD, 2,
                   adp=(-position) & 0xFFFF, ado=ado, cnt=1, validate=_validate16(device_id))


def identify_by_request(position: int, device_id: int) -> list[InitCmd]:
    """ETG.1020 "Requesting ID": APWR of AL control = INIT with the ID request bit (a head
    that has just appeared is in INIT), then APRD of AL status to AL status code (0x0130,
    6 bytes) until AL status bit 5 shows the ID is loaded and 0x0134 holds it."""
    adp = (-position) & 0xFFFF
    expected = bytes([AL_STATUS_ID, 0, 0, 0]) + struct.pack("<H", device_id)
    return [
        InitCmd([], "identify hot-connect group head: request device ID", Cmd.APWR, 2,
                adp=adp, ado=Reg.AL_CONTROL, data=struct.pack("<H", AlState.INIT | AL_ID_REQUEST),
                cnt=1),
        InitCmd([], "identify hot-connect group head: device ID", Cmd.APRD, 6, adp=adp,
                ado=Reg.AL_STATUS, cnt=1,
                validate=Validate(expected, bytes([AL_STATUS_ID, 0, 0, 0, 0xFF, 0xFF]),
                                  IDENTIFY_TIMEOUT)),
    ]


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
