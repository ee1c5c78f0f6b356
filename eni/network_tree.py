"""An ENI's network as a tree to draw: which slave each one is plugged into, through which
port, and where each sits in a drawing.

Where a slave is plugged comes from ``Slave/PreviousPort`` (ETG.2100: the port of the
slave before it and that slave's ``PhysAddr``; of several, the ``Selected`` one); an ENI
without ``PreviousPort`` describes a line, each slave behind the one listed before it.
Passive terminals (no ESC: no ``PhysAddr``, so nothing can name one as its previous slave)
pass the E-bus on: TwinCAT writes both the passive terminal and the slave after it behind
the same port of the same slave, and the slave listed later is behind the passive one.

The drawing is laid out as the plant is built.  Slaves joined by the E-bus (the parent's
port is a ``K`` in its ``Physics``, ETG.2100 ``Info/Physics``: one letter per port A-D; a
passive terminal sits on the E-bus) stand side by side in a row, as terminals on a DIN rail
beside their coupler; a long rail wraps onto further rows, indented.  What leaves a rail
over Ethernet (a coupler's or a junction's ``Y`` port) is drawn below the rail, indented,
one branch after another in the frame's order (ports A, D, B, C:
``esc.PORT_PROCESSING_ORDER``); the last branch out of the rail's first box (a coupler's
Ethernet out to the next coupler, the next drive of a line) continues straight down in the
same column, so a long line does not drift right.
"""

from __future__ import annotations

from ecatcfg.eni.plan import NetworkPlan, PassiveSlave, PreviousPort, SlavePlan
from ecatcfg.esc import PORT_LETTERS, PORT_PROCESSING_ORDER
from ecatcfg.record import record

MASTER = -1                                  # the parent of the first slave(s)

# Drawing units (px).  A box holds three lines: name, device type, position/address/vendor.
BOX_W, BOX_H = 172, 50
GAP_X = 22                                   # between boxes on a rail (the port letter)
GAP_Y = 24                                   # between rows
INDENT = 40                                  # a branch, and a rail's wrapped rows
MARGIN = 12
TRUNK = 14                                   # a branch's line runs this far right of a rail
RAIL_MAX = 6                                 # boxes per row of a rail before it wraps
LINE_CHARS = 25                              # characters of a box's 11 px lines


@record
class TreeNode:
    index: int                               # in NetworkPlan.in_file_order(); MASTER
    name: str
    passive: bool
    position: int | None
    phys_addr: int | None
    parent: int | None                       # index of the parent; None for the master
    port: str | None                         # the parent's port (A-D) when the ENI says
    x: int = 0
    y: int = 0
    ebus: bool = False                       # joined to its parent by the E-bus


@record
class Link:
    parent: int
    child: int
    port: str | None
    path: str                                # SVG path data, parent box -> child box
    label_x: float
    label_y: float
    ebus: bool = False


@record
class Drawing:
    nodes: list[TreeNode]                    # master first, then in drawing order
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


def _on_ebus(order: list[SlavePlan | PassiveSlave], parent: int, child: int,
             port: str | None) -> bool:
    """Whether ``child`` hangs on ``parent``'s E-bus: the parent's port is ``K`` in its
    Physics; without a port (a line, or behind a passive terminal) the child's own port A
    says, and a passive terminal (no ESC: an E-bus terminal) is on the E-bus."""
    if parent == MASTER:
        return False
    up, down = order[parent], order[child]
    if isinstance(down, PassiveSlave):
        return True
    if port is not None and port in PORT_LETTERS and isinstance(up, SlavePlan):
        physics = up.physics or ""
        k = PORT_LETTERS.index(port)
        if k < len(physics):
            return physics[k] == "K"
    return (down.physics or "Y")[:1] == "K"


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
                            links[k][0], links[k][1],
                            ebus=_on_ebus(order, links[k][0], k, links[k][1]))
    children: dict[int, list[int]] = {n: [] for n in nodes}
    for k, (parent, _) in enumerate(links):
        children[parent].append(k)
    for kids in children.values():
        kids.sort(key=lambda c: (_port_rank(nodes[c].port), c))
    drawn: list[TreeNode] = []
    paths: list[Link] = []
    seen: set[int] = set()

    def rail_of(first: int) -> tuple[list[int], list[int]]:
        """The rail ``first`` starts (it, then E-bus neighbours) and its Ethernet branches
        (in the order of the rail, each member's in port order)."""
        rail, branches = [first], []
        later: list[list[int]] = []           # ports the frame takes after the rail's
        seen.add(first)
        k = 0
        while k < len(rail):
            kids = [c for c in children[rail[k]] if c not in seen]
            ebus = [c for c in kids if nodes[c].ebus]
            on = ebus[0] if ebus else None    # the rail goes on; a second E-bus out branches
            before = kids if on is None else kids[:kids.index(on)]
            after = [] if on is None else kids[kids.index(on) + 1:]
            branches += before
            later.append(after)
            seen.update(kids)
            if on is not None:
                rail.append(on)
            k += 1
        # The frame comes back along the rail: a port after the E-bus one (a coupler's
        # Ethernet out, C after B) is taken once everything behind the rail is done.
        for after in reversed(later):
            branches += after
        return rail, branches

    def place(first: int, x: int, y: int) -> tuple[int, int]:
        """Draw the rail from ``first`` at (x, y) and everything behind it; the bottom
        and the right edge it took."""
        rail, branches = rail_of(first)
        right = x
        rows = 0
        for k, index in enumerate(rail):
            node = nodes[index]
            row, col = divmod(k, RAIL_MAX)
            node.x = x + (INDENT if row else 0) + col * (BOX_W + GAP_X)
            node.y = y + row * (BOX_H + GAP_Y)
            right = max(right, node.x + BOX_W)
            rows = row + 1
            drawn.append(node)
            if k:
                paths.append(_rail_link(nodes[rail[k - 1]], node, wrapped=col == 0))
        bottom = y + rows * BOX_H + (rows - 1) * GAP_Y
        for n, index in enumerate(branches):
            node = nodes[index]
            # The last branch out of the rail's first box (a coupler's Ethernet out, the
            # next drive of a line) goes on in the same column: the line continues.
            straight = n == len(branches) - 1 and node.parent == first
            bx = x if straight else x + INDENT
            top = bottom + GAP_Y
            end, far = place(index, bx, top)
            paths.append(_branch_link(nodes[node.parent if node.parent is not None
                                            else MASTER], node, x + TRUNK, straight))
            bottom, right = end, max(right, far)
        return bottom, right

    master.x, master.y = MARGIN, MARGIN
    drawn.append(master)
    bottom, right = MARGIN + BOX_H, MARGIN + BOX_W
    first = list(children[MASTER])
    seen.update(first)
    straight = len(first) == 1
    for c in first:
        seen.discard(c)
        end, far = place(c, MARGIN if straight else MARGIN + INDENT, bottom + GAP_Y)
        paths.append(_branch_link(master, nodes[c], MARGIN + TRUNK, straight))
        bottom, right = end, max(right, far)
    # A PreviousPort that names a slave behind this one makes a loop the walk never enters:
    # such slaves hang off the master, so none is left out of the drawing.
    for k in range(len(order)):
        if k not in seen:
            nodes[k].parent, nodes[k].port, nodes[k].ebus = MASTER, None, False
            end, far = place(k, MARGIN + INDENT, bottom + GAP_Y)
            paths.append(_branch_link(master, nodes[k], MARGIN + TRUNK, False))
            bottom, right = end, max(right, far)
    return Drawing(drawn, paths, _width(drawn, right), bottom + MARGIN)


def _rail_link(left: TreeNode, right: TreeNode, wrapped: bool) -> Link:
    """E-bus neighbours: right edge to left edge; onto a wrapped row: down from the
    bottom edge, along the gap, into the top edge."""
    mid = left.y + BOX_H / 2
    if not wrapped:
        return Link(left.index, right.index, right.port,
                    f"M{left.x + BOX_W},{mid} H{right.x}", left.x + BOX_W + 6, mid - 4, True)
    lane = left.y + BOX_H + GAP_Y / 2
    sx, ex = left.x + BOX_W / 2, right.x + BOX_W / 2
    return Link(left.index, right.index, right.port,
                f"M{sx},{left.y + BOX_H} V{lane} H{ex} V{right.y}", sx + 4, lane - 3, True)


def _branch_link(parent: TreeNode, child: TreeNode, trunk: float, straight: bool) -> Link:
    """Over Ethernet, below: down from the parent's bottom edge to the lane under its row,
    along to the rail's trunk, down to the child (its top edge when it is straight below,
    else across into its left edge)."""
    bottom = parent.y + BOX_H
    start = trunk if parent.x + TRUNK == trunk else parent.x + BOX_W / 2
    mid = child.y + BOX_H / 2
    head = f"M{start},{bottom}"
    if start != trunk:
        lane = bottom + GAP_Y / 2
        head += f" V{lane} H{trunk}"
    if straight and child.x <= trunk <= child.x + BOX_W:
        return Link(parent.index, child.index, child.port, f"{head} V{child.y}",
                    trunk + 5, child.y - 3)
    return Link(parent.index, child.index, child.port, f"{head} V{mid} H{child.x}",
                trunk + 4, mid - 4)


def _width(nodes: list[TreeNode], right: int) -> int:
    return max([right] + [n.x + BOX_W for n in nodes]) + MARGIN
