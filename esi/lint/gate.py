"""Which lint errors stop ``compile``: the ESI defects that change what the compiler writes.

Every error-severity rule is classified here, once (``tests/test_esi_gate.py`` fails on a
new error rule that is in neither set, and on docs/lint.md's "stops compile" column
disagreeing).  A rule stops compile when the compiler would otherwise write an ENI that
is wrong for the device: a value it could not read and replaced by a default (ESI002), a
PDO, SyncManager, mailbox, DC or InitCmd description that contradicts itself or the ESC
so that the slave refuses what the ENI tells the master to write (ESI101, ESI109, ESI201,
ESI207, ESI304 ...).  It does not when the finding is descriptive, is already refused by
the library or the resolver with its own message, or concerns what compile does not
read (EEPROM, the XML schema: see docs/lint.md "Which lint errors stop compile").
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from ecatcfg.esi.cache import content_digest
from ecatcfg.esi.lint.finding import FileResult, Finding
from ecatcfg.esi.lint.runner import LintOptions, Target, lint_file
from ecatcfg.esi.model import EsiFile
from ecatcfg.esi.reader import ElementSpans
from ecatcfg.fileio import read_input

STOPS_COMPILE: frozenset[str] = frozenset({
    "ESI002",                   # a number left unset: the compiler writes a default instead
    "ESI101", "ESI105", "ESI108", "ESI109", "ESI111", "ESI112", "ESI113",
    "ESI114",                   # the PDOs written are not what the device can take
    "ESI201", "ESI203", "ESI204", "ESI205", "ESI207", "ESI208", "ESI209", "ESI211",
    "ESI213",                   # the SM/FMMU/mailbox registers written are refused or wrong
    "ESI304",                   # an InitCmd's data the slave refuses: it does not fit
    "ESI402", "ESI403", "ESI404",   # the DC registers written do not make the SYNC signals
    "ESI603", "ESI605",         # a module ident that names two modules; 0xF030 unwritable
})

# Error rules that do not stop compile, and why (docs/lint.md gives the same reasons).
DOES_NOT_STOP: dict[str, str] = {
    "ESI001": "an unreadable file: the library refuses it before compile starts",
    "ESI004": "two devices with one identity in a file: the library takes them as one "
              "device when they are the same, else refuses the selector",
    "ESI008": "files that differ for one identity: the library refuses or --prefer chooses",
    "ESI302": "an InitCmd of a read-only object: the resolver refuses it with its own "
              "message",
    "ESI102": "two PDOs with one index: the resolver refuses them with its own message, "
              "--allow-esi-errors or not (an ENI names a PDO by its index)",
    "ESI214": "an EoE InitCmd: the resolver refuses the device with its own message",
    "ESI216": "an SoE InitCmd without IDN or Data: the resolver refuses the device with its "
              "own message",
    "ESI217": "an SoE InitCmd for a drive the device does not have: the resolver refuses "
              "the device with its own message",
    "ESI301": "an object the ESI's dictionary does not list: ESI dictionaries are often "
              "partial, and the real slave's dictionary decides",
    "ESI303": "an unknown data type name: the ENI carries the name as written, sizes come "
              "from BitLen",
    "ESI501": "Eeprom/ConfigData: compile does not read the EEPROM part",
    "ESI503": "Eeprom/ByteSize: compile does not read the EEPROM part",
    "ESI601": "a slot's unknown module ident: the resolver refuses plugging it",
    "ESI602": "a missing module library: the library and the resolver refuse it",
    "ESI604": "a DependOnSlotGroup index in a slot of no group: the resolver refuses that "
              "module there with its own message",
    "XSD001": "compile validates no schema; the schema errors that change a value compile "
              "reads are ESI002 and the other rules here",
}


_cache: dict[tuple[Path, str, str, frozenset[int] | None], FileResult] = {}
_CACHE_FILES = 64       # a long-running process (a fuzz campaign) must not grow without end


def file_findings(path: Path, shown: str, others: list[Path],
                  loaded: Callable[[Path, str, frozenset[int] | None],
                                   tuple[EsiFile, ElementSpans] | None] | None
                  = None, devices: frozenset[int] | None = None) -> FileResult:
    """The findings of the rules that stop compile in one ESI file, linted once per
    process while its content is unchanged (a sweep compiles the devices of one file one
    after another).  Keyed by a digest of the content, not the modification time, whose
    granularity (a clock tick) lets a file rewritten at once with the same size look
    unchanged.  ``loaded(path, digest)``: the model and element spans already read from
    that very content (``Library.loaded``), which lint then takes instead of parsing and
    reading the file again.  ``devices``: only the Device elements at these lines are
    checked (``lint_file``), the others' findings are left out."""
    try:
        digest = content_digest(read_input(path, shown))
    except OSError:
        digest = ""                         # lint reports the unreadable file (ESI001)
    key = (path, shown, digest, devices)
    found = _cache.get(key)
    if found is None:
        # Named directly, a file is never skipped (``None`` is for non-ESI files in folders).
        if len(_cache) >= _CACHE_FILES:
            del _cache[next(iter(_cache))]          # the oldest
        known = loaded(path, digest, devices) if loaded is not None and digest else None
        found = _cache[key] = lint_file(Target(path, shown, True), LintOptions(STOPS_COMPILE),
                                        others, known, devices) or FileResult(shown)
    return found


def inside(finding: Finding, start: int, span: list[tuple[int, int | None]]) -> bool:
    """Whether ``finding`` lies in the element of ``span`` that starts at line ``start``."""
    if finding.line is None:
        return False
    for first, end in span:
        if first == start:
            return first <= finding.line and (end is None or finding.line < end)
    return False
