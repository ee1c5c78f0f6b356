"""Passive terminals in a topology: slaves whose ESI device has no ESC (``Device.passive``).

An end cap or a potential feed is part of the line as it is built, so the ENI lists it
(as TwinCAT does: a ``Slave`` whose ``Info`` has no ``PhysAddr``/``AutoIncAddr``, an empty
``ProcessData`` and a ``PreviousPort``; ETG.2100 makes the address group optional for
exactly this), but it answers no frame.  So it takes no bus position and no station
address: the compiler lays out and wires the slaves with an ESC alone (:func:`split` gives
a topology without the passive ones, its lines still pointing into the user's file), and
the passive ones go into the plan beside them (:func:`place`).

What would ask something of a slave without an ESC (PDOs, SDOs, DC, an alias, a station
address, a hot-connect group, a place in a tree) is an error at its topology line.
"""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.compiler.topology import LoadedTopology, Path_, Slave
from ecatcfg.eni.plan import NetworkPlan, PassiveSlave, PreviousPort
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import PORT_LETTERS
from ecatcfg.esi.library import Library, SelectorError
from ecatcfg.esi.model import Device

# Topology keys that configure an ESC, with what they ask for.
_NEEDS_ESC = {"station_address": "a station address", "alias": "a station alias",
              "device_id": "a device ID", "hot_connect": "a hot-connect group",
              "rx_pdos": "PDOs", "tx_pdos": "PDOs", "pdo_mapping": "a PDO mapping",
              "modules": "modules", "sdos": "SDOs", "dc": "distributed clocks",
              "parent": "a place in a tree", "port": "a place in a tree",
              "eoe": "EoE IP parameters", "watchdog": "watchdogs"}
# The port a passive terminal's PreviousPort names on the slave before it: port B (ESC
# port 1), where a line of terminals continues (TwinCAT writes the next terminal's
# PreviousPort the same way, with the PhysAddr of the slave with an ESC before it).
_LINE_PORT = 1


@dataclass(slots=True)
class PassiveEntry:
    index: int                      # place in the topology file
    cfg: Slave
    device: Device
    previous: int | None            # file index of the slave with an ESC before it


@dataclass(slots=True)
class Split:
    active: LoadedTopology          # the slaves with an ESC; errors still at the file's lines
    passive: list[PassiveEntry]
    errors: list[EcatcfgError]
    file_index: list[int]           # file index of each slave of ``active``


def in_line(active: list[tuple[str, Device, int]],
            passive: list[PassiveEntry]) -> list[tuple[str, Device, int]]:
    """``(name, device, file index)`` of the slaves with an ESC (in bus order) with the
    passive ones put after the slave with an ESC the file lists before them: the line as
    it is built, for what passive terminals take part in (the E-bus current budget)."""
    out = list(active)
    placed: set[int] = set()
    for p in passive:
        k = next((i + 1 for i, a in enumerate(out) if a[2] == p.previous), 0)
        while k < len(out) and out[k][2] in placed:
            k += 1                  # after the passive ones the file lists before it
        out.insert(k, (p.cfg.name, p.device, p.index))
        placed.add(p.index)
    return out


def _device(cfg: Slave, library: Library, loaded: LoadedTopology) -> Device | None:
    """The slave's device when its selector names one; None otherwise (the compile of the
    active slaves reports the selector's error at its line)."""
    from ecatcfg.compiler.resolve import select
    try:
        return library.device(select(cfg, library, loaded).entry)
    except SelectorError:
        return None


def split(loaded: LoadedTopology, library: Library) -> Split:
    """The topology without its passive slaves, and those slaves."""
    slaves = loaded.topology.slaves
    passive: list[PassiveEntry] = []
    active: list[int] = []
    errors: list[EcatcfgError] = []
    for index, cfg in enumerate(slaves):
        device = _device(cfg, library, loaded)
        if device is None or not device.passive:
            active.append(index)
            continue
        passive.append(PassiveEntry(index, cfg, device, active[-1] if active else None))
        for key, what in _NEEDS_ESC.items():
            if getattr(cfg, key) not in (None, False, [], {}):
                errors.append(loaded.error(
                    f"slave {cfg.name!r}: {device.type_name} ({device.source}) is a passive "
                    f"terminal without an ESC (no ProductCode, no SyncManagers in its ESI): "
                    f"it cannot have {what}; '{key}' must go", "slaves", index, key))
    if not passive:
        return Split(loaded, [], errors, list(range(len(slaves))))
    # Names are unique among all slaves; the compile of the slaves with an ESC checks
    # those among themselves, this the ones a passive slave takes part in.
    names: dict[str, int] = {}
    passive_at = {p.index for p in passive}
    for index, cfg in enumerate(slaves):
        first = names.setdefault(cfg.name, index)
        if first != index and (index in passive_at or first in passive_at):
            errors.append(loaded.error(f"slave name {cfg.name!r} is already used by the "
                                       f"slave at line {loaded.line('slaves', first)}",
                                       "slaves", index, "name"))
    passive_names = {p.cfg.name: p for p in passive}
    kept = {index: slaves[index] for index in active}
    for index in active:
        parent = slaves[index].parent
        if parent is not None and parent in passive_names:
            p = passive_names[parent]
            errors.append(loaded.error(
                f"slave {slaves[index].name!r}: its parent {parent!r} is a passive terminal "
                f"({p.device.type_name}, no ESC): name the slave with an ESC before it",
                "slaves", index, "parent"))
            # Said once: the wiring of the rest would only add "not a slave" for it.
            kept[index] = slaves[index].model_copy(update={"parent": None, "port": None})
    if not active:
        errors.append(loaded.error("every slave is a passive terminal (no ESC): there is "
                                   "nothing for a master to configure", "slaves"))
        return Split(loaded, passive, errors, [])
    new_index = {old: new for new, old in enumerate(active)}
    lines: dict[Path_, int] = {}
    for path, line in loaded.lines.items():
        if len(path) >= 2 and path[0] == "slaves" and isinstance(path[1], int):
            if path[1] in new_index:
                lines[("slaves", new_index[path[1]], *path[2:])] = line
        else:
            lines[path] = line
    topology = loaded.topology.model_copy(update={"slaves": [kept[i] for i in active]})
    return Split(LoadedTopology(topology, loaded.file, lines), passive, errors, active)


def place(plan: NetworkPlan, passive: list[PassiveEntry],
          loaded: LoadedTopology) -> list[EcatcfgError]:
    """Put the passive slaves into ``plan`` (compiled without them): each after the
    slave with an ESC the topology lists before it, in bus order; the errors of a passive
    slave inside a hot-connect group (the ENI reader refuses it: ETG.2100 does not say
    whether ``GroupMemberCnt`` counts it)."""
    by_name = {s.name: s for s in plan.slaves}
    order = sorted(plan.slaves, key=lambda s: s.position)
    placed: list[PassiveSlave] = []
    errors: list[EcatcfgError] = []
    for p in passive:
        before = None if p.previous is None else by_name[loaded.topology.slaves[p.previous].name]
        after = 0 if before is None else before.position + 1
        dev = p.device
        placed.append(PassiveSlave(
            name=p.cfg.name, after=after, vendor_id=dev.vendor.id or 0,
            product_code=dev.product_code or 0, revision=dev.revision or 0,
            previous_ports=[] if before is None else [
                PreviousPort(PORT_LETTERS[_LINE_PORT], before.phys_addr, True)]))
        for k, head in enumerate(order):
            group = head.hot_connect
            if group is not None and k < after <= k + group.member_count - 1:
                errors.append(loaded.error(
                    f"slave {p.cfg.name!r}: a passive terminal inside the hot-connect group "
                    f"of {head.name!r}; whether the ENI's GroupMemberCnt counts it is not "
                    "defined (ETG.2100), so list it after the group's last slave",
                    "slaves", p.index))
    plan.passive = sorted(placed, key=lambda p: p.after)      # stable: file order kept
    return errors
