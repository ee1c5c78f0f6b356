"""The ESI defects of the devices a topology uses that change what compile writes.

``ecatcfg lint`` finds them (``esi/lint/gate.py`` says which rules stop compile); here
they are tied to the slaves whose Device element, or a module it plugs, holds them.  A
finding elsewhere in the file (another device, an unused module) does not concern the
topology.  Compile refuses a slave with such a finding, unless the user allows ESI errors
(``--allow-esi-errors``): then each is a warning.
"""

from __future__ import annotations

from collections.abc import Iterable

from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint.finding import FileResult, Finding
from ecatcfg.esi.lint.gate import file_findings, inside


class FileGate:
    """The gate's findings of each library file, asked once per file for one topology.

    ``file_findings`` reads and hashes the whole file on every call, to see a file changed
    under a long-running process; 512 slaves of one 3 MB Beckhoff family file asked it 512
    times (1.5 GB hashed, most of a cold compile's time).  One topology is compiled from
    one reading of its files, so each is asked once here.

    ``used``: the slaves of the topology.  A file is then checked only in the Device
    elements they use (lint's rules for the others would read dictionaries compile never
    looks at: a Beckhoff family file holds up to 124 devices), unless they plug one of its
    modules (a module's InitCmds are checked against every device of its file)."""

    def __init__(self, library: Library, used: Iterable[ResolvedSlave] = ()) -> None:
        self.library = library
        self.paths = {lf.shown: lf.path for lf in library.files}
        self.others = list(self.paths.values())
        self.results: dict[str, FileResult] = {}
        lines: dict[str, set[int]] = {}
        whole: set[str] = set()
        for s in used:
            lines.setdefault(s.device.source.file, set()).add(s.device.source.line)
            whole.update(p.module.source.file for p in s.modules)
        self.devices = {file: frozenset(found) for file, found in lines.items()
                        if file not in whole}

    def findings(self, shown: str) -> FileResult:
        found = self.results.get(shown)
        if found is None:
            found = self.results[shown] = file_findings(self.paths[shown], shown, self.others,
                                                        self.library.loaded,
                                                        self.devices.get(shown))
        return found


def slave_findings(s: ResolvedSlave, library: Library,
                   gate: FileGate | None = None) -> list[Finding]:
    """The findings that stop compile inside the slave's Device element or its modules
    (``gate``: shared by the slaves of one topology)."""
    gate = gate or FileGate(library, [s])
    paths = gate.paths
    found: list[Finding] = []
    dev = s.device
    if dev.source.file in paths:
        result = gate.findings(dev.source.file)
        found += [f for f in result.findings
                  if f.device is not None and f.device.line == dev.source.line]
    seen = set()
    for plugged in s.modules:
        src = plugged.module.source
        if src in seen or src.file not in paths:
            continue
        seen.add(src)
        result = gate.findings(src.file)
        found += [f for f in result.findings if inside(f, src.line, result.module_spans)]
    return sorted(set(found), key=Finding.sort_key)


def slave_errors(loaded: LoadedTopology, s: ResolvedSlave, library: Library,
                 allowed: bool = False, gate: FileGate | None = None) -> list[EcatcfgError]:
    """One error per finding of the slave, at its topology line, naming the ESI file:line
    and the rule as lint would (``allowed``: worded as the warning it then is)."""
    why = ("taken as the ESI says it (--allow-esi-errors)" if allowed else
           "an ESI error that changes what compile writes; `ecatcfg lint` explains it, "
           "--allow-esi-errors compiles anyway")
    return [loaded.error(f"slave {s.name!r}: {f.file}:{f.line or '?'}: {f.rule} {f.message} "
                         f"({why})", "slaves", s.index)
            for f in slave_findings(s, library, gate)]


def esi_errors(loaded: LoadedTopology, resolved: list[ResolvedSlave], library: Library,
               allowed: bool = False) -> list[EcatcfgError]:
    """The errors (``allowed``: warnings) of every slave, in bus order."""
    gate = FileGate(library, resolved)
    return [e for s in resolved for e in slave_errors(loaded, s, library, allowed, gate)]
