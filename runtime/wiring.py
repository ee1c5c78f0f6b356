"""How the slaves of a virtual segment are cabled: a tree, with a line as the common case.

Every slave is plugged with its port 0 into a port (1-3) of a parent slave, the first one
into the master.  A frame enters the first slave's port 0 and each ESC passes it on
through its open ports in the processing order 0 -> 3 -> 1 -> 2 (ETG.1000.4; SOEM
``ethercatdc.c`` "order of ports is 0 - 3 - 1 - 2", IgH ``slave.c`` ``next_table``): the
frame is processed once, where it enters on port 0, then goes down the subtree on port 3,
comes back, goes down port 1, and so on.  A port with nothing plugged, or whose cable is
removed, closes its loop, so the frame turns round there.  The order in which the frame
meets the slaves, depth first, is their auto-increment order.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

from ecatcfg.esc import PORT_LETTERS, PORT_PROCESSING_ORDER
from ecatcfg.record import record

if TYPE_CHECKING:
    from ecatcfg.eni.plan import SlavePlan

# The downstream ports (not port 0, which faces the master), in the order the frame takes
# them; ``PORT_LETTERS`` names ESC ports 0-3 as ENI PreviousPort and topologies do.
CHILD_PORTS = tuple(p for p in PORT_PROCESSING_ORDER if p != 0)


@record(frozen=True)
class Plug:
    """Where a slave's port 0 is plugged: ``port`` (1-3) of slave ``parent`` (an index
    into the segment's list of slaves)."""

    parent: int
    port: int


class Wiring:
    """The cables of ``n`` slaves: ``plugs[k]`` is where slave k is plugged, None for the
    one slave plugged into the master."""

    def __init__(self, plugs: Sequence[Plug | None]) -> None:
        self.plugs = list(plugs)
        n = len(self.plugs)
        self.children: list[dict[int, int]] = [{} for _ in range(n)]
        roots = [k for k, p in enumerate(self.plugs) if p is None]
        if n and len(roots) != 1:
            raise ValueError(f"exactly one slave is plugged into the master, not "
                             f"{len(roots)} (slaves {roots})")
        self.root = roots[0] if roots else -1
        for k, p in enumerate(self.plugs):
            if p is None:
                continue
            if not 0 <= p.parent < n or p.parent == k:
                raise ValueError(f"slave {k}: parent {p.parent} is not another slave")
            if p.port not in CHILD_PORTS:
                raise ValueError(f"slave {k}: port {p.port} of slave {p.parent} is not a "
                                 f"downstream port (1-3; port 0 faces the master)")
            taken = self.children[p.parent].get(p.port)
            if taken is not None:
                raise ValueError(f"slaves {taken} and {k} are both plugged into port "
                                 f"{p.port} of slave {p.parent}")
            self.children[p.parent][p.port] = k
        if n and len(self.order(())) != n:
            raise ValueError("the plugging has a cycle: some slaves do not reach the master")

    @classmethod
    def line(cls, n: int) -> Wiring:
        """Each slave in port 1 of the one before: a line."""
        return cls([None] + [Plug(k - 1, 1) for k in range(1, n)])

    @property
    def is_line(self) -> bool:
        return all(p is None or p == Plug(k - 1, 1) for k, p in enumerate(self.plugs))

    def order(self, cut: Iterable[int]) -> list[int]:
        """The slaves a frame reaches, in the order it reaches them, when the cables into
        the slaves ``cut`` are removed (those slaves and everything behind them are gone)."""
        if self.root < 0:
            return []
        gone = set(cut)
        out: list[int] = []
        stack = [self.root]
        while stack:
            k = stack.pop()
            if k in gone:
                continue
            out.append(k)
            ports = self.children[k]
            # Pushed in reverse, so port 3's subtree is walked first, then 1, then 2.
            stack.extend(ports[p] for p in reversed(CHILD_PORTS) if p in ports)
        return out

    def receptions(self, cut: Iterable[int]) -> list[tuple[int, int]]:
        """Every (slave, port) a frame is received on, in the order it happens: port 0 on
        its way out (where the slave processes it), then each port with a slave behind it
        as the frame comes back from that subtree (ports in the processing order 0, 3, 1,
        2).  A port without a cable in place closes its loop: nothing is received there."""
        if self.root < 0:
            return []
        gone = set(cut)
        out: list[tuple[int, int]] = []

        def visit(k: int) -> None:
            out.append((k, 0))
            for port in CHILD_PORTS:
                child = self.children[k].get(port)
                if child is not None and child not in gone:
                    visit(child)
                    out.append((k, port))

        if self.root not in gone:
            visit(self.root)
        return out

    def links(self, k: int, cut: Iterable[int]) -> tuple[bool, bool, bool, bool]:
        """Which of slave k's ports have a link partner: port 0 unless its own cable is
        removed, another port when a slave is plugged into it through a cable in place."""
        gone = set(cut)
        ports = self.children[k]
        return (k not in gone, 1 in ports and ports[1] not in gone,
                2 in ports and ports[2] not in gone, 3 in ports and ports[3] not in gone)


def eni_plugs(slaves: list[SlavePlan], shown: str) -> list[Plug | None]:
    """Where each slave (in position order) is plugged, from its ENI ``PreviousPort``:
    the port letter (A-D = ESC port 0-3) of the slave with that ``PhysAddr``; the selected
    entry when there are several (hot-connect alternatives), else the first.  A slave
    without one (hand-written ENIs, the first slave) follows the slave before it on port
    B (port 1), the first slave the master.  A PreviousPort that names no earlier slave
    or no downstream port is an error naming the slave."""
    from ecatcfg.errors import EcatcfgError

    by_address = {s.phys_addr: k for k, s in enumerate(slaves)}
    plugs: list[Plug | None] = []
    for k, s in enumerate(slaves):
        ports = s.previous_ports
        chosen = next((p for p in ports if p.selected), ports[0] if ports else None)
        if k == 0 or chosen is None:
            plugs.append(None if k == 0 else Plug(k - 1, 1))
            continue
        letter = chosen.port.strip().upper()
        port = PORT_LETTERS.find(letter) if len(letter) == 1 else -1
        parent = k - 1 if chosen.phys_addr is None else by_address.get(chosen.phys_addr, -1)
        where = f"{shown}: slave {s.name!r}: PreviousPort {chosen.port!r}" + (
            f" of PhysAddr {chosen.phys_addr}" if chosen.phys_addr is not None else "")
        if port < 1:
            raise EcatcfgError(f"{where}: the port is not B, C or D (a downstream port)")
        if not 0 <= parent < k:
            raise EcatcfgError(f"{where}: no slave before it has that address")
        plugs.append(Plug(parent, port))
    return plugs


def active_ports(dl_status: int) -> list[int]:
    """The ports DL status (0x0110) shows with the loop open and communication established
    (bits 8+2n, 9+2n = 0, 1; SOEM ``ecx_config_init``)."""
    return [port for port in range(4) if dl_status >> 8 + 2 * port & 3 == 2]


def plugs_from_dl_status(statuses: Sequence[int]) -> list[Plug | None]:
    """Where each slave found (in bus order) is plugged, from the DL status of every one:
    the frame enters each slave on port 0 and takes its active ports in the processing
    order, so the slave after a junction's port-3 subtree is on its port 1, and so on (the
    facts IgH links its slaves with, ``ec_master_calc_topology_rec``).  A slave the active
    ports leave no place for (DL status contradicts the count) gets None, like the first."""
    plugs: list[Plug | None] = [None] * len(statuses)
    if not statuses:
        return plugs
    following = 1
    # Depth first, as the frame goes: per slave on the stack, its active ports still to walk.
    stack = [(0, [p for p in CHILD_PORTS if p in active_ports(statuses[0])])]
    while stack and following < len(statuses):
        k, ports = stack[-1]
        if not ports:
            stack.pop()
            continue
        child = following
        following += 1
        plugs[child] = Plug(k, ports.pop(0))
        stack.append((child, [p for p in CHILD_PORTS if p in active_ports(statuses[child])]))
    return plugs
