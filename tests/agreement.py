"""The check/apply agreement: ``check`` reports an error if and only if ``apply --virtual`` of
the same file fails, with the ESI files (the slaves emulated from their devices) and without
(every slave emulated from the ENI alone).  Both run in this process: ``check_eni`` and
``Network.virtual`` on an in-memory segment, each given the same :class:`Library`.

A case is (ENI, fault class or None, seed); its verdict is ``agree`` or a disagreement, which
is allowed only where the fault class says a slave takes it (``faults.Fault.slave_refuses``
False, or "esi" without ESI): a fault in the master's process image that no slave can see
(docs/show-diff-check.md, "What apply cannot see").
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from faults import FAULTS, plant

from ecatcfg.eni.check import check_eni
from ecatcfg.eni.check.network import UNSUPPORTED
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library

CYCLES = 30
UNSUPPORTED_WORDS = "apply does not do"     # how apply refuses a part it does not do


def _dictionary_gap(o: Outcome) -> bool:
    return (o.with_esi and not o.check_says and any(" ENI301 " in w for w in o.check_warnings)
            and any(code in str(o.apply_failure) for code in ("0x06020000", "0x06090011")))


# The disagreements that are limits, not bugs: (does it apply to the outcome, the reason).
# docs/show-diff-check.md, "check and apply --virtual", names each with its reason.
LIMITS: dict[str, tuple[Callable[[Outcome], bool], str]] = {
    "esi-dictionary": (_dictionary_gap, """
        A CoE InitCmd writes an object the device's ESI dictionary does not list: check warns
        (ENI301; vendors' dictionaries are partial, the real slave's decides), the slave
        emulated from that ESI has only the ESI's objects and aborts the download."""),
}


@dataclass(frozen=True)
class Outcome:
    eni: str
    fault: str | None
    seed: int
    with_esi: bool
    check_errors: list[str]          # "line: RULE message"
    check_unsupported: list[str]     # ENI003: parts apply does not do (warnings)
    check_warnings: list[str]        # every other warning
    apply_failure: str | None
    expected_lines: frozenset[int] = frozenset()
    firmware: bool = True            # the planted slave has firmware (a mailbox)
    device: bool = False             # the planted slave was emulated from its ESI device

    @property
    def check_says(self) -> bool:
        """An error, or a part apply refuses to do (ENI003 is a warning: the file is not
        wrong, ecatcfg does not do it; apply refuses it unless --skip-unsupported)."""
        return bool(self.check_errors or self.check_unsupported)

    @property
    def apply_says(self) -> bool:
        return self.apply_failure is not None

    @property
    def allowed_disagreement(self) -> bool:
        """check errs where apply passes because no slave refuses this fault class."""
        if self.fault is None or not self.check_says or self.apply_says:
            return False
        refuses = FAULTS[self.fault].slave_refuses
        return (refuses is False or (refuses == "esi" and not self.device)
                or (refuses == "firmware" and not self.firmware))

    @property
    def must_err(self) -> bool:
        """check must report this planted fault at its line: every class a slave refuses,
        every fault of the image, and those only the ESI tells where the slave refused.  A
        file apply refuses as a whole (ENI003: encrypted FMMUs) is not judged further."""
        if self.fault is None or (self.check_unsupported and self.apply_says
                                  and UNSUPPORTED_WORDS in str(self.apply_failure)):
            return False
        refuses = FAULTS[self.fault].slave_refuses
        return refuses != "esi" or (self.device and self.apply_says)

    @property
    def limit(self) -> str | None:
        """The documented limit (LIMITS) that explains a disagreement, if one does."""
        if self.agree:
            return None
        for name, (applies, _) in LIMITS.items():
            if applies(self):
                return name
        return None

    @property
    def agree(self) -> bool:
        return self.check_says == self.apply_says or self.allowed_disagreement

    @property
    def explained(self) -> bool:
        """Agrees, with the planted fault's error at its line, or is a documented limit."""
        return (self.agree and self.at_line) or self.limit is not None

    @property
    def at_line(self) -> bool:
        """A planted fault check must report is an error at one of its elements' lines."""
        return not self.must_err or any(e.split(":", 1)[0] in {str(n) for n in
                                                               self.expected_lines}
                                        for e in self.check_errors)

    def describe(self) -> str:
        what = f"{self.eni} [{self.fault or 'unmodified'} seed {self.seed}, " \
               f"{'with ESI' if self.with_esi else 'ENI only'}]"
        return (f"{what}: check {'errors' if self.check_says else 'clean'}"
                f"{' (' + '; '.join(self.check_errors[:3]) + ')' if self.check_errors else ''}"
                f", apply {'fails: ' + str(self.apply_failure) if self.apply_says else 'reaches OP'}"
                + (f"; expected an error at line {', '.join(map(str, sorted(self.expected_lines)))}"
                   if not self.at_line else ""))


# How apply fails when the host, not the file, is slow: the in-memory segment answers
# in a thread, and a loaded machine can miss a frame's deadline on a long line.
HOST_TIMING = "no frame came back"


def apply_failure(path: Path, library: Library | None) -> str | None:
    """How ``apply --virtual`` of the file fails (None: it reached OP, cycled without a
    working-counter error, and every slave was still in OP after the cycles, as ``apply``
    reads them before the way down).  A failure of the host's timing is tried once more."""
    failure = _apply_once(path, library)
    if failure is not None and HOST_TIMING in failure:
        failure = _apply_once(path, library)
    return failure


def _apply_once(path: Path, library: Library | None) -> str | None:
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.runtime import Network
    try:
        net = Network.virtual(path, library, recovery=False)
    except EcatcfgError as exc:
        return str(exc).splitlines()[0]
    try:
        net.up(AlState.OP)
        net.run(CYCLES)
        stats = net.run_stats
        if stats is not None and stats.wkc_errors:
            return f"{stats.wkc_errors} working-counter error(s) in {stats.cycles} cycles"
        # What `apply` does after the cycles (cli/apply.py): a slave that left OP while
        # the line ran (an SM watchdog run out between two cycles) fails the run.
        net.master.check_kept(net.master.read_states())
        return None
    except EcatcfgError as exc:
        return " ".join(str(exc).split())
    finally:
        net.close()


def _has_device(library: Library, identity: tuple[int, int, int]) -> bool:
    """Whether the library holds the device of this exact identity (Network.virtual
    emulates the slave from it; otherwise from the ENI alone)."""
    from ecatcfg.errors import EcatcfgError
    vendor, product, revision = identity
    try:
        library.find(f"0x{vendor:x}:0x{product:x}:0x{revision:x}")
    except EcatcfgError:
        return False
    return True


def run_case(data: bytes, eni: str, fault: str | None, seed: int,
             library: Library | None, work: Path) -> Outcome | None:
    """One case; None when the fault has no place in this file."""
    from faults import lines_of
    expected: frozenset[int] = frozenset()
    firmware = device = True
    if fault is not None:
        planted = plant(data, fault, seed)
        if planted is None:
            return None
        data, where = planted
        expected, firmware = frozenset(lines_of(data, where)), where.firmware
        device = library is not None and where.identity is not None \
            and _has_device(library, where.identity)
    path = work / "case.xml"
    path.write_bytes(data)
    result = check_eni(path, library, use_cache=False, shown="case.xml")
    errors = [f"{f.line}: {f.rule} {f.message}" for f in result.findings
              if f.severity == "error"]
    unsupported = [f"{f.line}: {f.rule} {f.message}" for f in result.findings
                   if f.rule == UNSUPPORTED]
    warnings = [f"{f.line}: {f.rule} {f.message}" for f in result.findings
                if f.severity != "error" and f.rule != UNSUPPORTED]
    failure = apply_failure(path, library)
    return Outcome(eni, fault, seed, library is not None, errors, unsupported, warnings,
                   failure, expected, firmware, device)


def run_matrix(enis: dict[str, bytes], faults: list[str | None], seeds: list[int],
               libraries: dict[bool, Library | None],
               report: Callable[[Outcome], None] | None = None) -> list[Outcome]:
    """Every (ENI, fault, seed) case with and without ESI (the keys of ``libraries``);
    ``report`` is told each outcome as it is known."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for eni, data in enis.items():
            for fault in faults:
                for seed in (seeds if fault is not None else [0]):
                    for with_esi, library in libraries.items():
                        case = run_case(data, eni, fault, seed, library, Path(tmp))
                        if case is not None:
                            out.append(case)
                            if report is not None:
                                report(case)
    return out
