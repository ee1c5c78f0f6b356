"""A network's topology as Graphviz DOT (``ecatcfg graph``): the master, each slave, and
an edge from the port a slave is plugged into (A-D) to the slave's port A.

The nodes come from an ENI (``eni/network_tree.py``: the selected ``PreviousPort``, a line
without it, passive terminals passing their port on) or from a scan of a live line (the
DL statuses, ``runtime/wiring.py``); this module only writes what it is given.
"""

from __future__ import annotations

from ecatcfg.eni.network_tree import MASTER, parents
from ecatcfg.eni.plan import NetworkPlan, PassiveSlave
from ecatcfg.record import record


@record(frozen=True)
class GraphNode:
    key: int                      # unique; MASTER (-1) for the master
    label: str                    # the name shown (a second line after "\n")
    parent: int | None            # the key of the node it is plugged into; None: master
    port: str | None              # the parent's port A-D, when known
    passive: bool = False


def from_plan(plan: NetworkPlan) -> list[GraphNode]:
    """The master and the ENI's slaves (passive ones too) in file order."""
    order = plan.in_file_order()
    nodes = [GraphNode(MASTER, plan.master.name or "master", None, None)]
    for k, (slave, (parent, port)) in enumerate(zip(order, parents(order))):
        if isinstance(slave, PassiveSlave):
            nodes.append(GraphNode(k, f"{slave.name}\npassive", parent, port, True))
        else:
            nodes.append(GraphNode(k, f"{slave.name}\n#{slave.position} "
                                      f"0x{slave.phys_addr:04X}", parent, port))
    return nodes


def slave_label(position: int, type_name: str | None, name: str | None, vendor_id: int,
                product_code: int) -> str:
    """The label of a slave found on a live line: ``#3 EL1004`` over its device name, as
    its SII or ESI names it; the hex identity where neither does."""
    first = f"#{position} {type_name}" if type_name else f"#{position}"
    second = name if name and name != type_name else \
        f"0x{vendor_id:08X}:0x{product_code:08X}" if not type_name else ""
    return f"{first}\n{second}" if second else first


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def dot(nodes: list[GraphNode], title: str) -> str:
    """The DOT text: a top-down digraph, an edge labelled with the parent's port."""
    lines = [f"digraph {_quote(title)} {{", "  rankdir=TB;",
             '  node [shape=box, fontname="Helvetica"];']
    for n in nodes:
        ident = "master" if n.key == MASTER else f"s{n.key}"
        style = ", style=dashed" if n.passive else \
            ", style=filled, fillcolor=lightgrey" if n.key == MASTER else ""
        lines.append(f"  {ident} [label={_quote(n.label)}{style}];")
    for n in nodes:
        if n.key == MASTER:
            continue
        parent = "master" if n.parent is None or n.parent == MASTER else f"s{n.parent}"
        label = f" [taillabel={_quote(n.port)}, headlabel=\"A\"]" if n.port else ""
        lines.append(f"  {parent} -> s{n.key}{label};")
    lines.append("}")
    return "\n".join(lines) + "\n"


__all__ = ["GraphNode", "dot", "from_plan", "slave_label"]
