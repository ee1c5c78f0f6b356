"""No import cycles between the package's modules (docs/architecture.md, "How the layers are
checked").

The graph is read from the sources with ``ast``, not from import-linter: every ``import`` and
``from ... import`` statement, absolute or relative, at module level, inside a function or
under ``if TYPE_CHECKING`` (a cycle of type-only imports still ties two modules together).
``from package import name`` is an edge to the submodule when ``name`` is one, else to the
package.  Importing a submodule also runs its packages' ``__init__``; those implicit edges are
left out, as Python and import-linter do: a package that loads a submodule lazily is no cycle.

One cycle is allowed: the lint rule registry (``esi/lint/rules.py``) imports its check
modules so that they register, and each check module imports the registry's decorator.
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

from conftest import ROOT

PACKAGE = "ecatcfg"
NOT_THE_PACKAGE = {"tests", "bench", "docs", "build_backend", ".mypy_path"}
REGISTRY = "ecatcfg.esi.lint.rules"
REGISTERED = "ecatcfg.esi.lint.checks"


def module_files(root: Path) -> dict[str, Path]:
    """Every module of the package in the checkout ``root``, by dotted name."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] in NOT_THE_PACKAGE or any(p.startswith(".") for p in rel.parts):
            continue
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join([PACKAGE, *parts])] = path
    return out


def imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that ``name`` (at ``path``) imports, anywhere in its body."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            for alias in node.names:
                sub = f"{source}.{alias.name}"
                out.add(sub if sub in modules else source)
    return {m for m in out if m in modules and m != name}


def import_graph(root: Path) -> dict[str, set[str]]:
    modules = module_files(root)
    return {name: imported(name, path, modules) for name, path in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(component)
    return found


def forbidden_cycles(root: Path) -> list[list[str]]:
    """The cycles other than the rule registry's own."""
    def allowed(component: set[str]) -> bool:
        return all(m == REGISTRY or m == REGISTERED or m.startswith(REGISTERED + ".")
                   for m in component)
    return [sorted(c) for c in cycles(import_graph(root)) if not allowed(c)]


def test_the_graph_sees_every_kind_of_import():
    graph = import_graph(ROOT)
    # module level, absolute
    assert "ecatcfg.runtime.wire" in graph["ecatcfg.runtime.master.transport"]
    # relative (``from ..errors import``)
    assert "ecatcfg.errors" in graph["ecatcfg.runtime.link"]
    # inside a function (the Network loads the virtual segment when asked for one)
    assert "ecatcfg.runtime.segment.virtual" in graph["ecatcfg.runtime.network"]
    # ``from package import submodule``
    assert "ecatcfg.runtime.master.hotconnect" in graph["ecatcfg.runtime.master.bringup"]
    # the registry's cycle is there, and is the one allowed
    assert any(REGISTRY in c for c in cycles(graph))


def test_no_import_cycles():
    assert forbidden_cycles(ROOT) == []


def test_a_cycle_through_an_import_inside_a_function_is_found(tmp_path):
    copy = tmp_path / "ecatcfg"
    shutil.copytree(ROOT, copy, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", *NOT_THE_PACKAGE, "__pycache__", "*_cache", "*.egg-info"))
    wire = copy / "runtime" / "wire.py"
    # the codec reaching up into the master, relative and late: transport imports wire
    wire.write_text(wire.read_text() + "\n\ndef _sneak():\n"
                    "    from .master import transport\n    return transport\n")
    assert forbidden_cycles(copy) == [["ecatcfg.runtime.master.transport",
                                       "ecatcfg.runtime.wire"]]
