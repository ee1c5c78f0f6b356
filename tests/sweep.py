"""Every device on its own emulation: compile one device alone, check the ENI against the
ETG.2100 schema, bring it up on a virtual segment built from the same ESI, and say why not.

For one device (one ``Descriptions/Devices/Device`` of an ESI file, every revision its own)
``Worker.run``

1. writes a one-slave topology that selects it by ``VENDOR:PRODUCT:REVISION`` (its Type
   name when the file gives no numbers) and compiles it with the library API
   (``compiler.build.compile_topology``, what ``ecatcfg compile`` runs) against a library of
   that file alone plus the module libraries its ``InfoReference`` names, so another file
   with the same identity cannot stand in for it; with its default modules, and where a
   slot needs a module and names no default, the first module it takes;
2. writes the ENI (``eni.writer``) and validates it against ``EtherCATConfig.xsd``;
3. reads it back (``eni.reader``) and brings it up to OP on ``Network.virtual`` with the
   same library, the way ``ecatcfg apply --virtual --esi FILE`` does (the partial-ENI
   completion, the request check, the unsupported-content skip), then back to INIT;
4. classifies the result: ``op``; ``passive`` (a terminal without an ESC: nothing to
   configure, and compile rightly refuses a line of passive terminals alone); ``refused``
   (compile said no: the message, grouped into a category; an ESI error of a rule that
   stops compile, ``esi/lint/gate.py``, is such a refusal); ``schema-invalid``; ``not-emulated`` (the segment fell back to the ENI alone:
   the ESI did not reach the emulator); ``apply-failed`` (an error naming the slave and
   command, or the state it was left in); ``crash`` (an exception that is no
   ``EcatcfgError``: a bug by definition).

``lint_errors`` gives, per device, the error findings ``ecatcfg lint`` reports inside its
Device element; the sweep requires every refusal and every failure to be
explained by one.  ``bench/sweep_devices.py`` runs every device of both corpora;
``tests/test_sweep_devices.py`` a fixed sample of them.
"""

from __future__ import annotations

import json
import re
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ecatcfg.errors import EcatcfgError

CONFIG_XSD = Path("schemas") / "eni-1.3" / "EtherCATConfig.xsd"
ESI_XSD_DIR = Path("schemas") / "esi-1.17"


@dataclass(frozen=True, slots=True)
class Case:
    """One device of one ESI file."""

    corpus: str                # "corpus" or "corpus-extra"
    file: str                  # below the corpus' esi/ folder, posix
    ordinal: int               # position among the file's Device elements
    line: int                  # of the Device element
    type: str
    vendor_id: int | None
    product_code: int | None
    revision: int | None
    has_coe: bool
    has_dc: bool
    slots: bool
    modules: tuple[str, ...]   # module library files its InfoReferences resolve to (absolute)

    @property
    def key(self) -> str:
        return f"{self.corpus}/{self.file}#{self.ordinal}"

    @property
    def selector(self) -> str:
        if self.vendor_id is None or self.product_code is None:
            return self.type.strip()
        sel = f"0x{self.vendor_id:x}:0x{self.product_code:x}"
        return sel if self.revision is None else f"{sel}:0x{self.revision:x}"


# compile's refusal for an ESI error (compiler/esi_errors.py): "FILE:LINE: RULE message".
_ESI_GATE = re.compile(r"\.xml:\d+: (ESI\d{3}|XSD\d{3}) ")


@dataclass(slots=True)
class Result:
    key: str
    type: str
    selector: str
    # op | passive (no ESC) | refused | schema-invalid | not-emulated | apply-failed | crash
    outcome: str
    message: str = ""
    category: str = ""
    seconds: dict[str, float] = field(default_factory=dict)
    lint_errors: list[str] = field(default_factory=list)

    @property
    def explained(self) -> bool:
        """A device that is not ``op`` (nor a passive terminal) is explained when lint
        reports an error for it; refused for an ESI error that stops compile, when lint
        reports that very rule for it (compile and lint must agree on the finding)."""
        if self.outcome in ("op", "passive"):
            return True
        gate = _ESI_GATE.findall(self.message) if self.outcome == "refused" else []
        reported = {e.split()[0] for e in self.lint_errors}
        return bool(self.lint_errors) and set(gate) <= reported

    def as_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["explained"] = self.explained
        return data


# -- the devices -------------------------------------------------------------------------------

def cases(corpora: dict[str, Path]) -> list[Case]:
    """Every device of every ESI file below each corpus' ``esi/`` folder, sorted by key."""
    from ecatcfg.esi.library import Library

    found: list[Case] = []
    for name, root in corpora.items():
        esi_dir = root / "esi"
        library = Library([esi_dir], cache=True)
        for lf in library.files:
            modules = tuple(sorted(str(t.path) for t in (
                library.resolve_reference(lf, r) for r in lf.summary.info_references) if t))
            rel = lf.path.relative_to(esi_dir.resolve()).as_posix()
            for d in lf.summary.devices:
                found.append(Case(
                    name, rel, d["ordinal"], d["line"], d["type"], lf.summary.vendor_id,
                    d["product_code"], d["revision"], "CoE" in d["mailbox"],
                    bool(d["dc_opmodes"]), bool(d["slots"]), modules))
    return sorted(found, key=lambda c: (c.corpus, c.file, c.ordinal))


def sample(all_cases: list[Case], every: int) -> list[Case]:
    """Every ``every``-th device of the sorted list: a fixed, deterministic sample."""
    return all_cases[::every]


# -- lint ------------------------------------------------------------------------------------

def lint_errors(corpora: dict[str, Path], files: set[tuple[str, str]] | None = None,
                jobs: int | None = None) -> dict[str, list[str]]:
    """``"corpus/file#line"`` of a device (or ``"corpus/file#"`` for findings outside any
    device) -> ``"RULE message"`` of each error lint reports there, with the ETG.2000
    schema.  ``files``: only these (corpus, file) pairs; every file of each corpus is
    still given to lint as a possible module library."""
    from ecatcfg.esi.lint import LintOptions, lint_file, lint_paths, select_rules
    from ecatcfg.esi.lint.runner import collect

    out: dict[str, list[str]] = {}
    for name, root in corpora.items():
        esi_dir = root / "esi"
        schema_dir = _schema_root(corpora) / ESI_XSD_DIR
        options = LintOptions(select_rules(None, None),
                              schema_dir if schema_dir.is_dir() else None)
        targets = collect([str(esi_dir)])
        wanted = [t for t in targets if files is None or
                  (name, t.path.resolve().relative_to(esi_dir.resolve()).as_posix()) in files]
        if files is None:
            results = lint_paths(wanted, options, jobs)
        else:
            others = [t.path.resolve() for t in targets]
            results = [r for r in (lint_file(t, options, others) for t in wanted) if r]
        by_shown = {t.shown: t for t in targets}
        for res in results:
            rel = by_shown[res.file].path.resolve().relative_to(esi_dir.resolve()).as_posix()
            for f in res.findings:
                if f.severity != "error":
                    continue
                where = f"{name}/{rel}#{f.device.line if f.device else ''}"
                out.setdefault(where, []).append(f"{f.rule} {f.message}")
    return out


def errors_for(case: Case, errors: dict[str, list[str]]) -> list[str]:
    """The lint errors inside the case's Device element (not those elsewhere in its file:
    a finding about another device explains nothing about this one)."""
    return errors.get(f"{case.corpus}/{case.file}#{case.line}", [])


def _schema_root(corpora: dict[str, Path]) -> Path:
    """The ETG schemas are kept in the first corpus."""
    return next(iter(corpora.values()))


# -- one device --------------------------------------------------------------------------------

class Worker:
    """Runs cases; keeps the last library (cases of one file come one after another) and the
    compiled ENI schema."""

    def __init__(self, corpora: dict[str, Path]) -> None:
        from lxml import etree
        self.corpora = corpora
        xsd = _schema_root(corpora) / CONFIG_XSD
        self.schema = etree.XMLSchema(etree.parse(str(xsd)))
        self._library: tuple[tuple[str, ...], Any] | None = None

    def library(self, case: Case) -> Any:
        from ecatcfg.esi.library import Library
        paths = (str(self.corpora[case.corpus] / "esi" / case.file),) + case.modules
        if self._library is None or self._library[0] != paths:
            self._library = (paths, Library(list(paths), cache=False))
        return self._library[1]

    def run(self, case: Case) -> Result:
        result = Result(case.key, case.type, case.selector, "crash")
        try:
            self._run(case, result)
        except EcatcfgError as exc:           # placed by _run; here: an unexpected stage
            result.outcome, result.message = "apply-failed", str(exc)
        except Exception:                     # noqa: BLE001  (a bug: kept with its place)
            result.outcome = "crash"
            result.message = traceback.format_exc(limit=-3).strip().splitlines()[-1]
            result.category = _where(traceback.format_exc())
        if result.outcome not in ("op", "passive", "crash"):
            result.category = category(result.message)
        return result

    def _run(self, case: Case, result: Result) -> None:
        from lxml import etree

        from ecatcfg.compiler import build, topology
        from ecatcfg.eni import reader as eni_reader
        from ecatcfg.eni import writer as eni_writer
        from ecatcfg.eni.derive import complete
        from ecatcfg.esc import AlState
        from ecatcfg.runtime.master.bringup import check_requests
        from ecatcfg.runtime.network import Network

        t = time.perf_counter()
        lib = self.library(case)
        if lib.problems:
            result.outcome, result.message = "refused", str(lib.problems[0])
            return
        result.seconds["library"] = _lap(t)
        t = time.perf_counter()
        shown = f"sweep({case.key}).yaml"
        slave: dict[str, Any] = {"name": "dut", "device": case.selector}
        [entry] = [e for e in lib.entries if e.ordinal == case.ordinal
                   and e.file == lib.files[0].shown]
        device = lib.device(entry)
        if device.passive:
            # No ESC: nothing a master configures or brings to OP (compile refuses a line of
            # passive terminals alone, rightly).
            result.outcome, result.message = "passive", "no ESC (passive terminal)"
            return
        needed = _required_modules(device, lib.modules_for(entry))
        if needed:
            slave["modules"] = needed
        master: dict[str, Any] = {"name": "sweep"}
        if device.use_lrd_lwr:
            master["layout"] = "lrd_lwr"      # what the ESI asks for (compile says so)
        text = json.dumps({"master": master, "slaves": [slave]})
        try:
            chosen = lib.find(case.selector).entry
        except EcatcfgError:
            chosen = entry                    # compile says why
        if chosen.ordinal != case.ordinal:
            # Another device of the same file has this identity: a selector cannot reach
            # this one (lint ESI004; which description wins is the identity rules' part).
            result.outcome = "refused"
            result.message = (f"{case.selector} is also the device at line {chosen.line} "
                              "of the same file; the selector takes that one")
            return
        try:
            compiled = build.compile_topology(topology.loads(text, shown), lib)
            eni = eni_writer.to_bytes(compiled.plan, generator="ecatcfg sweep")
        except EcatcfgError as exc:
            result.outcome, result.message = "refused", str(exc)
            result.seconds["compile"] = _lap(t)
            return
        result.seconds["compile"] = _lap(t)
        t = time.perf_counter()
        doc = etree.fromstring(eni)
        valid = self.schema.validate(doc.getroottree())
        result.seconds["schema"] = _lap(t)
        if not valid:
            err = self.schema.error_log.last_error
            result.outcome = "schema-invalid"
            result.message = f"line {err.line}: {err.message}" if err else "invalid"
            return
        t = time.perf_counter()
        name = f"sweep({case.key}).xml"
        plan = eni_reader.read_bytes(eni, name)
        plan, _ = complete(plan, name)
        check_requests(plan, AlState.OP, name)
        net = Network.virtual(plan, lib, skip_unsupported=True, eni_name=name)
        try:
            fallback = [s.eni_only for s in net.segment.slaves if s.eni_only is not None] \
                if net.segment else []
            if fallback:
                result.outcome, result.message = "not-emulated", fallback[0]
                return
            try:
                net.up(AlState.OP)
                states = net.master.read_states()
                net.down()
            except EcatcfgError as exc:
                result.outcome, result.message = "apply-failed", str(exc)
                return
            reached = [s for s in states if s is not None]
            if len(reached) != len(states) or any(s.state != AlState.OP or s.error
                                                  for s in reached):
                result.outcome = "apply-failed"
                result.message = f"read back after OP: {states}"
                return
            result.outcome = "op"
        finally:
            net.close()
            result.seconds["apply"] = _lap(t)


def _required_modules(device: Any, modules: dict[int, Any]) -> dict[int, list[int]]:
    """Slot -> modules for the slots that need a module and name no default one: the first
    module the slot lists (by ident, else the first of the library's modules, in ident
    order, of a class the slot takes), as often as the slot needs it; a device "with its
    default modules" is otherwise not compilable alone."""
    out: dict[int, list[int]] = {}
    if device.slots is None:
        return out
    for number, slot in enumerate(device.slots.slots, start=1):
        low = slot.min_instances or 0
        if not low or slot.default_ident is not None:
            continue
        fits = list(slot.module_idents) or [
            ident for ident, m in sorted(modules.items())
            if m.module_class is not None and m.module_class in slot.module_classes]
        if fits:
            out[number] = [fits[0]] * low
    return out


def _lap(start: float) -> float:
    return round(time.perf_counter() - start, 4)


def _where(tb: str) -> str:
    """The innermost ``ecatcfg`` frame of a traceback: file and function."""
    frames = re.findall(r'File "[^"]*?/((?:[a-z_]+/)*[a-z_]+\.py)", line \d+, in (\w+)', tb)
    inner = [f for f in frames if not f[0].startswith("tests/")]
    return "crash in " + (f"{inner[-1][0]}:{inner[-1][1]}" if inner else "?")


# -- categories --------------------------------------------------------------------------------

_VARIABLE = [
    (re.compile(r"sweep\([^)]*\)\.(?:yaml|xml)(?::\d+)?:?\s*"), ""),
    (re.compile(r"(?:/[\w.+ -]+)+\.xml(?::\d+)?"), "FILE"),
    (re.compile(r"'[^']*'"), "'…'"),
    (re.compile(r"\"[^\"]*\""), "\"…\""),
    (re.compile(r"\b0x[0-9a-fA-F]+(?::[0-9a-fA-F]+)*\b"), "N"),
    (re.compile(r"#x[0-9a-fA-F]+"), "N"),
    (re.compile(r"\b\d+\b"), "N"),
    (re.compile(r"\([^()]*N[^()]*\)"), "(…)"),
    (re.compile(r"(slot N) \([^()]*\)"), r"\1 (…)"),
]


def category(message: str) -> str:
    """A message with its numbers, names and files taken out: one category per kind of
    failure."""
    lines = message.split("\n")
    # "N errors in the topology:" and one error a line: the first error names the kind.
    text = lines[1] if len(lines) > 1 and lines[0].endswith(":") else lines[0]
    for pattern, repl in _VARIABLE:
        text = pattern.sub(repl, text)
    return re.sub(r"\s+", " ", text).strip()[:160]


# -- summary ---------------------------------------------------------------------------------

def summary(results: list[Result]) -> dict[str, Any]:
    import statistics
    by: dict[str, dict[str, list[str]]] = {}
    for r in results:
        if r.outcome not in ("op", "passive"):
            by.setdefault(r.outcome, {}).setdefault(r.category, []).append(r.key)
    per_device = [sum(r.seconds.values()) for r in results]
    stages: dict[str, float] = {}
    for r in results:
        for stage, s in r.seconds.items():
            stages[stage] = stages.get(stage, 0.0) + s
    return {
        "devices": len(results),
        "op": sum(r.outcome == "op" for r in results),
        "passive": sum(r.outcome == "passive" for r in results),
        "outcomes": {o: sum(len(v) for v in cats.values()) for o, cats in by.items()},
        "unexplained": [r.key for r in results if not r.explained],
        "categories": {o: {c: len(keys) for c, keys in sorted(
            cats.items(), key=lambda kv: -len(kv[1]))} for o, cats in by.items()},
        "seconds": {"stages": {k: round(v, 1) for k, v in stages.items()},
                    "per_device_median": round(statistics.median(per_device), 4)
                    if per_device else 0.0},
    }
