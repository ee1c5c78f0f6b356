"""An ENI's network as a tree to draw: which slave each one is plugged into, through which
port, and where each sits in a drawing.

Where a slave is plugged comes from ``Slave/PreviousPort`` (ETG.2100: the port of the
slave before it and that slave's ``PhysAddr``; of several, the ``Selected`` one); an ENI
without ``PreviousPort`` describes a line, each slave behind the one listed before it.
Passive terminals (no ESC: no ``PhysAddr``, so nothing can name one as its previous slave)
pass the E-bus on: TwinCAT writes both the passive terminal and the slave after it behind
the same port of the same slave, and the slave listed later is behind the passive one.

The drawing is a tree in the frame's order: each ESC forwards a frame through its ports in
the order A, D, B, C (``esc.PORT_PROCESSING_ORDER``), so children are walked in that order
and the rows are the slaves depth first, the master on top.  A slave with one child
continues straight down; a slave with several (a junction, a coupler with an Ethernet out)
opens one indented branch per port, as a file tree does.
"""

from __future__ import annotations

from ecatcfg.eni.plan import NetworkPlan, PassiveSlave, PreviousPort, SlavePlan
from ecatcfg.esc import PORT_LETTERS, PORT_PROCESSING_ORDER
from ecatcfg.record import record

MASTER = -1                                  # the parent of the first slave(s)

# Drawing units (px): a row per slave, an indent per branch level.
ROW = 38
BOX_W, BOX_H = 96, 24
INDENT = 40
MARGIN = 12
TRUNK = 14                                   # the down line leaves a box this far from its left
CHAR_W = 7.2                                 # estimated width of a label character


@record
class TreeNode:
    index: int                               # in NetworkPlan.in_file_order(); MASTER
    name: str
    passive: bool
    position: int | None
    phys_addr: int | None
    parent: int | None                       # index of the parent; None for the master
    port: str | None                         # the parent's port (A-D) when the ENI says
    row: int = 0
    column: int = 0

    @property
    def x(self) -> int:
        return MARGIN + self.column * INDENT

    @property
    def y(self) -> int:
        return MARGIN + self.row * ROW


@record
class Link:
    parent: int
    child: int
    port: str | None
    path: str                                # SVG path data, parent box -> child box
    label_x: float
    label_y: float


@record
class Drawing:
    nodes: list[TreeNode]                    # master first, then the rows in order
    links: list[Link]
    width: int
    height: int


def previous_port(ports: list[PreviousPort]) -> PreviousPort | None:
    """The PreviousPort a slave is behind: the selected one of several (ETG.2100
    ``PreviousPort/@Selected``), else the first."""
    return next((p for p in ports if p.selected), ports[0] if ports else None)


def parents(order: list[SlavePlan | PassiveSlave]) -> list[tuple[int, str | None]]:
    """Each slave's parent (an index into ``order``, or :data:`MASTER`) and port."""
    by_addr = {s.phys_addr: k for k, s in enumerate(order) if isinstance(s, SlavePlan)}
    out: list[tuple[int, str | None]] = []
    last_on: dict[tuple[int, str], int] = {}        # (parent, port) -> slave there last
    for k, slave in enumerate(order):
        prev = previous_port(slave.previous_ports)
        if prev is None or prev.phys_addr is None:
            parent = k - 1 if k else MASTER
            port = prev.port if prev is not None else None
        else:
            parent = by_addr.get(prev.phys_addr, MASTER)
            port = prev.port
        if port is not None and parent != MASTER:
            there = last_on.get((parent, port))
            if there is not None and isinstance(order[there], PassiveSlave):
                last_on[(parent, port)] = k
                parent, port = there, None
            else:
                last_on[(parent, port)] = k
        out.append((parent, port))
    return out


def _port_rank(port: str | None) -> int:
    if port is not None and port in PORT_LETTERS:
        return PORT_PROCESSING_ORDER.index(PORT_LETTERS.index(port))
    return len(PORT_PROCESSING_ORDER)


def layout(plan: NetworkPlan) -> Drawing:
    order = plan.in_file_order()
    links = parents(order)
    master = TreeNode(MASTER, plan.master.name, False, None, None, None, None)
    nodes = {MASTER: master}
    for k, s in enumerate(order):
        passive = isinstance(s, PassiveSlave)
        nodes[k] = TreeNode(k, s.name, passive,
                            None if isinstance(s, PassiveSlave) else s.position,
                            None if isinstance(s, PassiveSlave) else s.phys_addr,
                            links[k][0], links[k][1])
    children: dict[int, list[int]] = {n: [] for n in nodes}
    for k, (parent, _) in enumerate(links):
        children[parent].append(k)
    rows: list[TreeNode] = []
    seen: set[int] = set()

    def walk(index: int, column: int) -> None:
        # Iterative on the line (one child: same column) so a long line does not recurse.
        while True:
            node = nodes[index]
            seen.add(index)
            node.row, node.column = len(rows), column
            rows.append(node)
            kids = sorted((c for c in children[index] if c not in seen),
                          key=lambda c: (_port_rank(nodes[c].port), c))
            if len(kids) == 1:
                index = kids[0]
                continue
            for kid in kids:
                walk(kid, column + 1)
            return

    walk(MASTER, 0)
    # A PreviousPort that names a slave behind this one makes a loop the walk never enters:
    # such slaves hang off the master, so none is left out of the drawing.
    for k in range(len(order)):
        if k not in seen:
            nodes[k].parent, nodes[k].port = MASTER, None
            walk(k, 1)
    return Drawing(rows, [_link(nodes[n.parent], n) for n in rows if n.parent is not None],
                   _width(rows), MARGIN * 2 + len(rows) * ROW)


def _link(parent: TreeNode, child: TreeNode) -> Link:
    x = parent.x + TRUNK
    top = parent.y + BOX_H
    mid = child.y + BOX_H / 2
    if child.column == parent.column:           # straight down the line
        return Link(parent.index, child.index, child.port, f"M{x},{top} V{child.y}",
                    x + 5, child.y - 2)
    # A branch: down the parent's trunk, then across to the child's box.
    return Link(parent.index, child.index, child.port, f"M{x},{top} V{mid} H{child.x}",
                x + 4, mid - 4)


def _width(rows: list[TreeNode]) -> int:
    right = max(n.x + BOX_W + 8 + CHAR_W * (len(n.name) + 2) for n in rows)
    return int(right) + MARGIN
