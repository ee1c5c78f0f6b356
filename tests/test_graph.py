"""``ecatcfg graph``: the topology of an ENI and of a live line as Graphviz DOT and SVG.

The branched network of ``tests/trees.py`` (hand-written parent and port per slave) is
compiled from the corpus ESI files; the DOT ``graph`` writes is read back by Graphviz
itself (``dot -Tjson``), an independent parser, and its edges compared with the
hand-written tree.  The live line is ``ecatcfg simulate`` of the same topology over veth.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import prereq
import pytest
import rig
import trees
from lxml import etree

from ecatcfg.compiler import build, topology
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esi.library import Library

ROOT = Path(__file__).resolve().parent.parent


def ecatcfg(*argv: str) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "ecatcfg", *argv], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert "Traceback" not in done.stderr, done.stderr
    return done


@pytest.fixture(scope="module")
def tree_eni(corpus: Path, tmp_path_factory) -> Path:
    lib = Library([corpus / "esi"], cache=False)
    plan = build.compile_topology(topology.loads(trees.ACCEPTANCE, "tree.yaml"), lib).plan
    path = tmp_path_factory.mktemp("graph") / "tree.eni.xml"
    path.write_bytes(eni_writer.to_bytes(plan))
    return path


def dot_tool() -> str:
    tool = shutil.which("dot")
    if tool is None:
        prereq.missing("Graphviz dot", "not on the PATH (Debian's graphviz)", prereq.TOOLS)
    return tool


def edges_by_graphviz(dot_text: str) -> dict[str, tuple[str, str | None] | None]:
    """Each slave's (parent, port) as Graphviz reads the DOT: node labels' first line are
    the slave names, the master's label is the master's name."""
    done = subprocess.run([dot_tool(), "-Tjson"], input=dot_text, capture_output=True,
                          text=True, timeout=60, check=True)
    graph = json.loads(done.stdout)
    names = {o["_gvid"]: o["label"].split("\\n")[0] for o in graph["objects"]}
    master = next(o["label"] for o in graph["objects"] if o["name"] == "master")
    out: dict[str, tuple[str, str | None] | None] = {}
    for e in graph["edges"]:
        parent, child = names[e["tail"]], names[e["head"]]
        out[child] = None if parent == master else (parent, e.get("taillabel"))
    return out


def test_the_graph_of_an_eni_is_its_tree(tree_eni, tmp_path):
    done = ecatcfg("graph", str(tree_eni), "--no-cache")
    assert done.returncode == 0, done.stderr
    assert edges_by_graphviz(done.stdout) == trees.ACCEPTANCE_TREE

    svg = tmp_path / "tree.svg"
    dot_tool()
    drawn = ecatcfg("graph", str(tree_eni), "-o", str(svg))
    assert drawn.returncode == 0, drawn.stderr
    root = etree.parse(str(svg)).getroot()
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    texts = {t.text for t in root.iter("{http://www.w3.org/2000/svg}text")}
    assert set(trees.ACCEPTANCE_ORDER) <= texts

    as_json = json.loads(ecatcfg("graph", str(tree_eni), "--format", "json").stdout)
    by_name = {n["label"].split("\n")[0]: n for n in as_json["nodes"]}
    assert by_name["axis1"]["port"] == "D"
    assert by_name["axis1"]["parent"] == by_name["junction"]["key"]


def test_graph_usage():
    both = ecatcfg("graph", "x.xml", "--iface", "lo")
    assert both.returncode == 2 and "one of them" in both.stderr
    missing = ecatcfg("graph", "nowhere.eni.xml")
    assert missing.returncode == 2 and "nowhere.eni.xml: no such file" in missing.stderr


def test_the_graph_of_a_live_line(veth_netns, corpus, tmp_path):
    topo = tmp_path / "tree.yaml"
    topo.write_text(trees.ACCEPTANCE)
    sim, lines = rig.start_simulate(veth_netns, "--esi", str(corpus / "esi"), "--topology",
                                    str(topo))
    try:
        assert lines and lines[-1].startswith("ready:"), lines
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "graph", "--iface", veth_netns.if_a,
            "--format", "json"], timeout=60, cwd=ROOT)
        dot = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "graph", "--iface", veth_netns.if_a],
            timeout=60, cwd=ROOT)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(10)
    assert done.returncode == 0, done.stderr
    nodes = json.loads(done.stdout)["nodes"][1:]
    # Positions are the bus order: the names of tests/trees.py in ACCEPTANCE_ORDER.
    name = dict(enumerate(trees.ACCEPTANCE_ORDER))
    got = {name[n["key"]]: None if n["parent"] is None else (name[n["parent"]], n["port"])
           for n in nodes}
    assert got == trees.ACCEPTANCE_TREE
    assert dot.returncode == 0 and dot.stdout.startswith("digraph")
