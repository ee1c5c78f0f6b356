"""``ecatcfg graph``: the topology of an ENI or of a live line as Graphviz DOT (SVG with
``dot``)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ecatcfg.eni.graph import GraphNode
    from ecatcfg.esi.library import Library


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "graph", help="the topology of an ENI or a live line as Graphviz DOT or SVG",
        description="Draw the master and the slaves, an edge from the port a slave is "
                    "plugged into (A-D) to the slave: from an ENI (PreviousPort), or with "
                    "--iface from the slaves on the line (their DL statuses, as scan "
                    "reads them), each named by its SII's order number and device name, "
                    "or by the ESI device of its identity with --esi.  Prints DOT, or "
                    "writes FILE with -o: FILE.svg is drawn by Graphviz 'dot', any other "
                    "name gets the DOT text.",
        epilog="Exit 1 when the ENI cannot be read, no frame comes back, or -o FILE.svg "
               "is asked for without 'dot' installed.")
    p.add_argument("eni", nargs="?", metavar="ENI", help="the ENI file (or --iface)")
    p.add_argument("--iface", metavar="IF", help="draw the live line on this interface")
    p.add_argument("-o", "--output", metavar="FILE", help="write DOT or (FILE.svg) SVG here")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="text: DOT; json: the nodes and edges")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="with --iface: ESI file or folder (repeatable) naming each slave by "
                        "the device of its SII identity (without it, by the name in its "
                        "SII)")
    p.add_argument("--no-cache", action="store_true",
                   help="do not use the ENI plan cache or the ESI index cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ecatcfg.cli.paths import output_file
    from ecatcfg.eni import graph
    from ecatcfg.errors import UsageError

    if (args.eni is None) == (args.iface is None):
        raise UsageError("give an ENI file or --iface IF (one of them)")
    if args.esi and args.iface is None:
        raise UsageError("--esi names the slaves of a live line: give it with --iface "
                         "(an ENI names its slaves itself)")
    out = output_file(args.output) if args.output else None
    if args.eni is not None:
        if not Path(args.eni).exists():
            raise UsageError(f"{args.eni}: no such file")
        from ecatcfg.eni.cache import PlanCache, read_file
        from ecatcfg.eni.reader import read_file as read_uncached
        plan = read_uncached(args.eni) if args.no_cache else read_file(args.eni,
                                                                        cache=PlanCache())
        nodes = graph.from_plan(plan)
        title = plan.master.name or Path(args.eni).name
    else:
        library = None
        if args.esi:
            import sys

            from ecatcfg.esi.library import Library
            library = Library(args.esi, cache=not args.no_cache)
            for problem in library.problems:
                print(f"warning: {problem}", file=sys.stderr)
        nodes = _live(args.iface, library)
        title = args.iface
    if args.format == "json":
        text = json.dumps({"title": title, "nodes": [
            {"key": n.key, "label": n.label, "parent": n.parent, "port": n.port,
             "passive": n.passive} for n in nodes]}, indent=2) + "\n"
    else:
        text = graph.dot(nodes, title)
    if out is None:
        print(text, end="")
        return 0
    from ecatcfg.fileio import write_atomic
    if out.suffix.lower() == ".svg" and args.format == "text":
        write_atomic(out, _svg(text))
    else:
        write_atomic(out, text.encode())
    return 0


def _live(iface: str, library: Library | None) -> list[GraphNode]:
    from ecatcfg.cli.identity import slave_identities
    from ecatcfg.eni.graph import GraphNode, slave_label
    from ecatcfg.eni.network_tree import MASTER
    from ecatcfg.esc import PORT_LETTERS
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master.scan import scan
    from ecatcfg.runtime.master.transport import Transport

    with RawLink(iface) as link:
        transport = Transport(link)
        found = scan(transport)
        who = slave_identities(transport, [s.position for s in found], library,
                               sii_names=True, found=found)
    nodes = [GraphNode(MASTER, "master", None, None)]
    for s in found:
        ident = who[s.position]
        nodes.append(GraphNode(s.position, slave_label(s.position, ident.type, ident.name,
                                                       s.vendor_id, s.product_code),
                               s.plug.parent if s.plug is not None else None,
                               PORT_LETTERS[s.plug.port] if s.plug is not None else None))
    return nodes


def _svg(text: str) -> bytes:
    """The DOT drawn by Graphviz ``dot -Tsvg``."""
    import shutil
    import subprocess

    from ecatcfg.errors import EcatcfgError

    tool = shutil.which("dot")
    if tool is None:
        raise EcatcfgError("an SVG needs Graphviz 'dot', which is not installed; write "
                           "the DOT text instead (-o FILE.dot) and draw it elsewhere")
    done = subprocess.run([tool, "-Tsvg"], input=text.encode(), capture_output=True,
                          timeout=60)
    if done.returncode != 0:
        raise EcatcfgError(f"dot -Tsvg failed: {done.stderr.decode(errors='replace')}")
    return done.stdout
