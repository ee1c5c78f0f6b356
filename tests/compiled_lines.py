"""Lines of corpus devices compiled by ``compile``: the third kind of ENI of the check-vs-apply
agreement (tests/test_agreement.py, bench/agreement.py), beside the corpus' own ENIs and
the example line.

A line is drawn by ``random.Random(seed)`` from every device of the ESI files given
(both corpora): a file, then one of its devices (so that one vendor's many files of
terminals do not make every line theirs), selected by ``VENDOR:PRODUCT:REVISION`` as a
user writes it in a topology, in bus order, each plugged into the slave before it (the
topology's default wiring).  A device is kept when the line compiles with it
(``compiler.build.compile_topology``, what ``ecatcfg compile`` runs, then ``eni.writer``);
a device compile refuses (its port does not fit the slave before it, an ESI error that
stops compile) is drawn again.  A slot that needs a module and names no default gets the
first it takes (as in the device sweep, tests/sweep.py).  A device with DC OpModes runs
one of them, drawn, half of the time (else the topology's default, DC off).  Devices whose
identity the library cannot resolve to one description (the same identity in several
files, none preferred) are not drawn: compile would refuse every line with them.

Only identities, modules and OpModes are chosen: what compile writes is the
code under test, and ``check`` and ``apply --virtual`` judge it from the written file.
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.index import DeviceEntry
from ecatcfg.esi.library import Library

# Devices per line, and how many draws a line may take before it is given up as shorter.
SLAVES = 4
DRAWS = 40


@dataclass(frozen=True)
class CompiledLine:
    seed: int
    devices: tuple[str, ...]      # the selectors, in bus order
    topology: str                 # the topology compiled (JSON, a YAML subset)
    eni: bytes

    @property
    def name(self) -> str:
        return f"compiled line seed {self.seed} ({', '.join(self.devices)})"


def _selector(e: DeviceEntry) -> str:
    return f"0x{e.vendor_id:x}:0x{e.product_code:x}:0x{e.revision:x}"


def candidates(library: Library, corpus_roots: tuple[str, ...]) -> list[DeviceEntry]:
    """Every device of the files below ``corpus_roots`` (absolute folder paths) that a
    selector by identity reaches: it has vendor, product and revision, and ``find`` gives
    this very description (not another file's, not a refusal for duplicates).  Paths are
    compared resolved: ``../shared`` may be a symbolic link."""
    out = []
    for e in library.entries:
        if e.vendor_id is None or e.product_code is None or e.revision is None \
                or not str(Path(e.file).resolve()).startswith(corpus_roots):
            continue
        try:
            found = library.find(_selector(e)).entry
        except EcatcfgError:
            continue
        if (found.file, found.ordinal) == (e.file, e.ordinal):
            out.append(e)
    return out


def compile_line(library: Library, slaves: list[dict[str, Any]]) -> bytes:
    """The ENI ``compile`` writes for a line of ``slaves`` (topology entries), 1 ms cycle."""
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer as eni_writer
    text = json.dumps({"master": {"name": "corpus-line", "cycle_time_us": 1000},
                       "slaves": slaves}, indent=1)
    compiled = build.compile_topology(topology.loads(text, "line.yaml"), library)
    return eni_writer.to_bytes(compiled.plan, generator="ecatcfg compile")


def _modules(library: Library, e: DeviceEntry) -> dict[int, list[int]]:
    """The modules a slot needs and names no default for: the first it takes (as the
    device sweep does, tests/sweep.py), else compile refuses the device whatever the line."""
    from sweep import _required_modules
    return _required_modules(library.device(e), library.modules_for(e))


def line(library: Library, pool: list[DeviceEntry], seed: int,
         slaves: int = SLAVES) -> CompiledLine | None:
    """The line of ``seed``: up to ``slaves`` devices drawn from ``pool`` that compile one
    after another; None when not even one did in ``DRAWS`` draws."""
    rng = random.Random(f"compiled-line:{seed}")
    files: dict[str, list[DeviceEntry]] = {}
    for d in pool:
        files.setdefault(d.file, []).append(d)
    names = sorted(files)
    chosen: list[dict[str, Any]] = []
    eni = b""
    for _ in range(DRAWS):
        if len(chosen) == slaves:
            break
        e = rng.choice(files[rng.choice(names)])
        slave: dict[str, Any] = {"name": f"slave{len(chosen) + 1}", "device": _selector(e)}
        if e.dc_opmodes and rng.random() < 0.5:
            slave["dc"] = rng.choice(e.dc_opmodes)     # one of its OpModes, by name
        try:
            modules = _modules(library, e)
            if modules:
                slave["modules"] = {str(k): v for k, v in modules.items()}
            eni = compile_line(library, [*chosen, slave])
        except EcatcfgError:
            continue
        chosen.append(slave)
    if not chosen:
        return None
    text = json.dumps({"slaves": chosen})
    return CompiledLine(seed, tuple(s["device"] for s in chosen), text, eni)
