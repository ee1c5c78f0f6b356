"""The ESI defects of the devices a topology uses that change what compile writes.

``ecatcfg lint`` finds them (``esi/lint/gate.py`` says which rules stop compile); here
they are tied to the slaves whose Device element, or a module it plugs, holds them.  A
finding elsewhere in the file (another device, an unused module) does not concern the
topology.  Compile refuses a slave with such a finding, unless the user allows ESI errors
(``--allow-esi-errors``): then each is a warning.
"""

from __future__ import annotations

from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint.finding import Finding
from ecatcfg.esi.lint.gate import file_findings, inside


def slave_findings(s: ResolvedSlave, library: Library) -> list[Finding]:
    """The findings that stop compile inside the slave's Device element or its modules."""
    paths = {lf.shown: lf.path for lf in library.files}
    others = list(paths.values())
    found: list[Finding] = []
    dev = s.device
    if dev.source.file in paths:
        result = file_findings(paths[dev.source.file], dev.source.file, others)
        found += [f for f in result.findings
                  if f.device is not None and f.device.line == dev.source.line]
    seen = set()
    for plugged in s.modules:
        src = plugged.module.source
        if src in seen or src.file not in paths:
            continue
        seen.add(src)
        result = file_findings(paths[src.file], src.file, others)
        found += [f for f in result.findings if inside(f, src.line, result.module_spans)]
    return sorted(set(found), key=Finding.sort_key)


def slave_errors(loaded: LoadedTopology, s: ResolvedSlave, library: Library,
                 allowed: bool = False) -> list[EcatcfgError]:
    """One error per finding of the slave, at its topology line, naming the ESI file:line
    and the rule as lint would (``allowed``: worded as the warning it then is)."""
    why = ("taken as the ESI says it (--allow-esi-errors)" if allowed else
           "an ESI error that changes what compile writes; `ecatcfg lint` explains it, "
           "--allow-esi-errors compiles anyway")
    return [loaded.error(f"slave {s.name!r}: {f.file}:{f.line or '?'}: {f.rule} {f.message} "
                         f"({why})", "slaves", s.index)
            for f in slave_findings(s, library)]


def esi_errors(loaded: LoadedTopology, resolved: list[ResolvedSlave], library: Library,
               allowed: bool = False) -> list[EcatcfgError]:
    """The errors (``allowed``: warnings) of every slave, in bus order."""
    return [e for s in resolved for e in slave_errors(loaded, s, library, allowed)]
