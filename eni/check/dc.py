"""The SYNC0 a slave's InitCmds start, from the ENI alone: which activation (0x0980/0x0981)
and which SYNC0 cycle (0x09A0) the slave gets, and a SYNC0 started without a cycle.

The slave gets the registers the InitCmds write, not the ``DC`` element's numbers: apply
replays the writes as the file gives them (runtime/master/transition.py), and the DC
element only describes them (ETG.2100 ``DC/CycleTime0``).  Where the file writes no cycle
register, the element's ``CycleTime0`` is the cycle (a master that completes a partial ENI
writes that)."""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.plan import SlavePlan, register_writes_at
from ecatcfg.esc import REGISTER_WRITES, Reg, sync0_running

NO_CYCLE = declare("ENI404", "error", "SYNC0 started without a SYNC0 cycle time", """
    The InitCmds switch SYNC0 on in cyclic operation (AssignActivate 0x0981 bits 0-1) and
    the SYNC0 cycle time they leave in 0x09A0 is 0 (or, without a write of it, the DC
    element's CycleTime0 is).  A cycle time of 0 makes SYNC0 a single pulse (ESC Section
    II, 0x09A0); a slave with firmware checks the cycle before SAFEOP and refuses it with
    AL status code 0x0035 (invalid sync cycle time; the Slave Stack Code's
    StartInputHandler).  A slave without firmware does not check.""")


@dataclass(frozen=True)
class Sync0:
    """The SYNC0 a slave's InitCmds start: the activation word (0x0980 low byte, 0x0981
    high byte) and the command that writes it; the cycle in ns and the position of the
    command that writes it (None: no write, the DC element's CycleTime0)."""

    activation: int
    activation_at: int
    cycle_ns: int
    cycle_at: int | None


def assign_activate(slave: SlavePlan) -> tuple[int, int] | None:
    """The last AssignActivate the InitCmds write that activates SYNC signals (0x0980 with
    0x0981, or 0x0981 alone), with the position of the command."""
    found = None
    for n, cmd in enumerate(slave.init_cmds):
        if cmd.cmd not in REGISTER_WRITES or cmd.ado is None or not cmd.data:
            continue
        data = cmd.data
        if cmd.ado == Reg.DC_CYCLIC_UNIT_CONTROL and len(data) >= 2:
            value = int.from_bytes(data[:2], "little")
        elif cmd.ado == Reg.DC_CYCLIC_UNIT_CONTROL + 1:
            value = data[0] << 8
        else:
            continue
        if value & 0xFF00:                      # a write that activates SYNC signals
            found = (value, n)
    return found


def sync0(slave: SlavePlan) -> Sync0 | None:
    """The SYNC0 the slave runs in cyclic operation, or None when its InitCmds do not
    switch it on."""
    found = assign_activate(slave)
    if found is None or not sync0_running(found[0] >> 8):
        return None
    cycle_ns, cycle_at = (slave.dc.cycle_time0 if slave.dc is not None else 0), None
    for _, record, _, position in register_writes_at(slave, Reg.DC_SYNC0_CYCLE_TIME, 4, 1):
        cycle_ns, cycle_at = int.from_bytes(record, "little"), position
    return Sync0(found[0], found[1], cycle_ns, cycle_at)


def check(ctx: CheckContext) -> None:
    for slave in ctx.plan.slaves:
        running = sync0(slave)
        if running is None or running.cycle_ns:
            continue
        if running.cycle_at is not None:
            line = ctx.lines.listed(slave, "InitCmds", running.cycle_at, len(slave.init_cmds))
            where = "0x09A0 is written 0"
        else:
            line = ctx.lines.child(slave, "DC")
            where = "no write of 0x09A0 and DC CycleTime0 is 0"
        ctx.add(NO_CYCLE, line, f"SYNC0 is switched on (AssignActivate "
                f"0x{running.activation:04X}) and {where}: a slave with firmware refuses "
                "SAFEOP with AL status code 0x0035", slave)
