"""Where each slave is plugged, and the bus order that follows: the topology as a tree.

A slave names its parent and the parent's port (``parent: j1, port: D``) or takes the
default plugging: the nearest slave before it in the file (walking back) that has a free
port of the kind of its own port 0, the parent's ports taken in processing order
(3, 1, 2; port 0 leads toward the master).  So an E-bus terminal follows the terminal before
it, and a drive listed after a row of terminals lands on the coupler's free Ethernet port;
a line that can be wired as written keeps its order.

Auto-increment positions follow the frame: it enters port 0 of the first slave and every
ESC forwards it through its ports in the order 0 -> 3 -> 1 -> 2, so the slaves are numbered
depth-first, a parent's branches in that order (``esc.PORT_PROCESSING_ORDER``).

Every mistake is an error at the slave's topology line: an unknown parent, a port that does
not exist or leads toward the master, a port two slaves are plugged into, ports of
different kinds (E-bus and Ethernet) joined, a cycle, a slave no earlier slave has a free
port for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import PORT_LETTERS, PORT_PROCESSING_ORDER
from ecatcfg.esi.physics import PortKind, port_kinds

# The ports a slave can take children on, in the order the frame leaves through them.
DOWNSTREAM_PORTS = tuple(p for p in PORT_PROCESSING_ORDER if p != 0)
# Slaves listed by name in a note before "and N more".
NOTE_NAMES = 24


@dataclass(slots=True)
class Wiring:
    """The tree, by file index (the slave's place in the topology's ``slaves`` list)."""

    parent: list[int | None]                 # file index of the parent; None: the first slave
    port: list[int | None]                   # the parent's port 0-3 it is plugged into
    order: list[int]                         # file indices in bus order
    notes: list[str] = field(default_factory=list)
    _positions: dict[int, int] = field(init=False, default_factory=dict)

    def __post_init__(self) -> None:
        self._positions = {i: n for n, i in enumerate(self.order)}

    def position(self, index: int) -> int:
        """The bus position (auto-increment order) of the slave at file index ``index``."""
        return self._positions[index]


@dataclass(slots=True)
class _State:
    loaded: LoadedTopology
    kinds: list[list[PortKind | None] | None]     # None: the device is unknown (already an error)
    parent: list[int | None]
    port: list[int | None]
    used: dict[tuple[int, int], int] = field(default_factory=dict)   # (parent, port) -> child
    errors: list[EcatcfgError] = field(default_factory=list)

    def name(self, i: int) -> str:
        return self.loaded.topology.slaves[i].name

    def error(self, message: str, i: int, key: str | None = None) -> None:
        path: tuple[str | int, ...] = ("slaves", i) + ((key,) if key else ())
        self.errors.append(self.loaded.error(f"slave {self.name(i)!r}: {message}", *path))

    def describe(self, i: int) -> str:
        kinds = self.kinds[i]
        ports = ", ".join(f"{PORT_LETTERS[n]} {k}" for n, k in enumerate(kinds or []) if k)
        return f"{self.name(i)!r} (ports {ports or 'none'})"

    def plug(self, child: int, parent: int, port: int) -> None:
        self.parent[child], self.port[child] = parent, port
        self.used[(parent, port)] = child


def wire(loaded: LoadedTopology, physics: list[str | None]) -> tuple[Wiring, list[EcatcfgError]]:
    """The tree of a topology whose slaves have the ESI ``Physics`` given (None: the device
    was not found, an error reported elsewhere; its plugging is not checked).  With errors,
    the returned wiring keeps the file's order."""
    slaves = loaded.topology.slaves
    n = len(slaves)
    st = _State(loaded, [port_kinds(p) if p is not None else None for p in physics],
                [None] * n, [None] * n)
    names: dict[str, int] = {}
    for i, s in enumerate(slaves):
        names.setdefault(s.name, i)
    # Named ports first, so that a port the user names is never taken by a guess; then in
    # file order the slaves that name only their parent or nothing take the free ports.
    for i, s in enumerate(slaves):
        if s.parent is not None and s.port is not None:
            _plug_named(st, i, names)
    for i, s in enumerate(slaves):
        if s.parent is not None and s.port is None:
            _plug_named(st, i, names)
        elif s.parent is None and i > 0:
            _plug_default(st, i)
    cycles = _cycles(st)
    if st.errors or cycles or None in st.kinds:
        errors = sorted(st.errors + cycles, key=lambda e: e.line or 0)    # in file order
        return Wiring(list(st.parent), list(st.port), list(range(n))), errors
    order = _bus_order(st, n)
    wiring = Wiring(st.parent, st.port, order)
    if order != list(range(n)):
        wiring.notes.append(_order_note(st, order))
    return wiring, []


def _plug_named(st: _State, i: int, names: dict[str, int]) -> None:
    cfg = st.loaded.topology.slaves[i]
    assert cfg.parent is not None
    if i == 0:
        st.error("the first slave is the one the master is plugged into; it has no parent "
                 "(list the slave it names before it)", i, "parent")
        return
    parent = names.get(cfg.parent)
    if parent is None:
        st.error(f"parent {cfg.parent!r} is not a slave of this topology", i, "parent")
        return
    if parent == i:
        st.error("it cannot be plugged into itself", i, "parent")
        return
    mine, theirs = st.kinds[i], st.kinds[parent]
    if mine is None or theirs is None:
        return                                  # an unknown device: already an error
    port = cfg.port
    if port is None:
        free = [p for p in DOWNSTREAM_PORTS if (parent, p) not in st.used
                and theirs[p] is not None and theirs[p] == mine[0]]
        if not free:
            st.error(f"{st.describe(parent)} has no free {mine[0]} port for its port A "
                     f"({mine[0]}); name the port", i, "parent")
            return
        st.plug(i, parent, free[0])
        return
    letter = PORT_LETTERS[port]
    if port == 0:
        st.error(f"port A of {cfg.parent!r} is its port toward the master; plug it into "
                 "one of its other ports", i, "port")
    elif theirs[port] is None:
        st.error(f"port {letter} does not exist on {st.describe(parent)}", i, "port")
    elif (parent, port) in st.used:
        other = st.used[(parent, port)]
        st.error(f"port {letter} of {cfg.parent!r} is already used by slave "
                 f"{st.name(other)!r} (line {st.loaded.line('slaves', other)}); two slaves "
                 "cannot share a port", i, "port")
    elif mine[0] is not None and theirs[port] != mine[0]:
        st.error(f"its port A is {mine[0]} but port {letter} of {cfg.parent!r} is "
                 f"{theirs[port]}; an {mine[0]} port cannot be plugged into an "
                 f"{theirs[port]} port", i, "port")
    else:
        st.plug(i, parent, port)


def _plug_default(st: _State, i: int) -> None:
    mine = st.kinds[i]
    if mine is None:
        return
    kind = mine[0]
    for j in range(i - 1, -1, -1):
        theirs = st.kinds[j]
        if theirs is None:
            return                              # an unknown device: already an error
        for port in DOWNSTREAM_PORTS:
            if theirs[port] is not None and theirs[port] == kind and (j, port) not in st.used:
                st.plug(i, j, port)
                return
    st.error(f"no slave before it has a free {kind or 'usable'} port for its port A"
             f"{f' ({kind})' if kind else ''}; name its parent and port, or list it after "
             "the slave it is plugged into", i)


def _cycles(st: _State) -> list[EcatcfgError]:
    """Slaves whose parents lead back to themselves never reach the master."""
    errors = []
    done: set[int] = set()
    for start in range(len(st.parent)):
        path: list[int] = []
        seen: set[int] = set()
        i: int | None = start
        while i is not None and i not in done and i not in seen:
            seen.add(i)
            path.append(i)
            i = st.parent[i]
        if i is not None and i in seen:
            loop = path[path.index(i):]
            first = min(loop)
            names = ", ".join(repr(st.name(x)) for x in sorted(loop))
            errors.append(st.loaded.error(
                f"slave {st.name(first)!r}: slaves {names} form a cycle (each is plugged "
                "behind the next); one of them must be plugged toward the master",
                "slaves", first, "parent"))
        done.update(path)
    return errors


def _bus_order(st: _State, n: int) -> list[int]:
    """Depth first from the first slave, each slave's ports in processing order."""
    children: dict[int, list[int]] = {}
    for child in range(1, n):
        parent = st.parent[child]
        if parent is not None:
            children.setdefault(parent, []).append(child)
    rank = {p: r for r, p in enumerate(PORT_PROCESSING_ORDER)}
    order: list[int] = []
    stack = [0]
    while stack:                        # iterative: a line of thousands is deep
        i = stack.pop()
        order.append(i)
        below = sorted(children.get(i, []), key=lambda c: rank[st.port[c] or 0])
        stack.extend(reversed(below))
    return order


def _order_note(st: _State, order: list[int]) -> str:
    moved = [i for n, i in enumerate(order) if n != i]
    cfgs = st.loaded.topology.slaves
    where = []
    for i in moved[:NOTE_NAMES]:
        parent, port = st.parent[i], st.port[i]
        assert parent is not None and port is not None
        how = "" if cfgs[i].parent is not None else " (default plugging)"
        where.append(f"{st.name(i)!r} on port {PORT_LETTERS[port]} of "
                     f"{st.name(parent)!r}{how}")
    more = f" and {len(moved) - NOTE_NAMES} more" if len(moved) > NOTE_NAMES else ""
    shown = ", ".join(st.name(i) for i in order[:NOTE_NAMES * 2])
    rest = f", ... ({len(order)} slaves)" if len(order) > NOTE_NAMES * 2 else ""
    return ("the wiring puts slaves in another order than the file lists them: "
            + "; ".join(where) + more + f"; bus order: {shown}{rest}")
