"""``check_eni``: the findings of every check rule in effect for one ENI file."""

from __future__ import annotations

import time
from pathlib import Path

from ecatcfg.eni import cache, reader
from ecatcfg.eni.check import copies, dc, devices, fmmus, network, pdo_state
from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.lines import EniLines
from ecatcfg.eni.check.rules import RULES, UNREADABLE
from ecatcfg.eni.evidence import evidence_by_identity
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.lint.finding import FileResult, Finding
from ecatcfg.esi.lint.rules import Rule
from ecatcfg.esi.library import Library


def all_rules() -> dict[str, Rule]:
    """Every check rule: the check modules imported above have declared theirs."""
    return RULES


def check_eni(path: str | Path, library: Library | None, active: frozenset[str] | None = None,
              shown: str | None = None, use_cache: bool = True,
              notes: list[str] | None = None) -> FileResult:
    """Check the ENI at ``path`` against itself and, with a ``library``, against the ESI
    devices of its slaves.  ``active``: the rule ids to report (default: every rule).
    A file the reader refuses is one ENI004 finding at the line the reader names.
    Where several ESI files describe a slave's identity differently, the one that agrees
    with the ENI's slaves of that identity is checked against (``eni/evidence.py``); each
    such choice is said in ``notes``."""
    started = time.perf_counter()
    path = Path(path)
    shown = shown if shown is not None else str(path)
    active = frozenset(all_rules()) if active is None else active
    try:
        plan = cache.read_file(path, shown) if use_cache else reader.read_file(path, shown)
    except EcatcfgError as exc:
        found = [Finding(shown, exc.line, exc.column, UNREADABLE, RULES[UNREADABLE].severity,
                         exc.message)] if UNREADABLE in active else []
        return FileResult(shown, found, seconds=time.perf_counter() - started)
    ctx = CheckContext(shown, plan, EniLines(path, shown, plan), active)
    network.check(ctx)
    copies.check(ctx)
    pdo_state.check(ctx)
    fmmus.check(ctx)
    dc.check(ctx)
    if library is not None:
        by_identity = evidence_by_identity(plan, shown)
        guided = library.guided(lambda v, p, r: by_identity.get((v, p, r)))
        devices.check(ctx, guided)
        if notes is not None:
            notes += [f"{shown}: {n}" for n in dict.fromkeys(guided.decisions)]
    ctx.findings.sort(key=lambda f: f.sort_key())
    return FileResult(shown, ctx.findings, [ctx.device_ref(s) for s in plan.slaves],
                      seconds=time.perf_counter() - started)
