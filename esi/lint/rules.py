"""The lint rule registry: every rule's id, severity, one-line summary and explanation.

A rule is declared once, next to the code that checks it (``esi/lint/checks/*.py``)::

    @device_rule("ESI101", "error", "PDO index outside the CoE range for its direction",
                 explain=\"\"\"...\"\"\")
    def pdo_index_range(dev: Device, ctx: FileContext) -> Iterator[Hit]:
        yield Hit(pdo.source, "RxPdo 0x1A00 ...")

Rule ids are stable: a CI configuration selects and ignores them by id, SARIF consumers key
their history on them.  Ids are grouped by topic: XSD (schema), ESI0xx file and values,
ESI1xx PDOs, ESI2xx SyncManagers/FMMUs/mailbox, ESI3xx CoE dictionary, ESI4xx DC, ESI5xx
EEPROM, ESI6xx modular devices.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Iterator, Literal, NamedTuple

if TYPE_CHECKING:
    from ecatcfg.esi.lint.context import FileContext
    from ecatcfg.esi.model import Device, Source

Severity = Literal["error", "warning", "info"]
SEVERITIES: tuple[Severity, ...] = ("error", "warning", "info")


class Hit(NamedTuple):
    """What a check reports: where, and the one-line message for this occurrence."""

    source: Source
    message: str
    column: int | None = None


FileCheck = Callable[["FileContext"], Iterator[Hit]]
DeviceCheck = Callable[["Device", "FileContext"], Iterator[Hit]]


@dataclass(frozen=True, slots=True)
class Rule:
    id: str
    severity: Severity
    summary: str                    # one line: what is wrong
    explanation: str                # a paragraph or two: why it matters, how to fix it
    file_check: FileCheck | None = None
    device_check: DeviceCheck | None = None


RULES: dict[str, Rule] = {}


def _register(rule: Rule) -> None:
    if rule.id in RULES:
        raise RuntimeError(f"lint rule {rule.id} declared twice")
    RULES[rule.id] = rule


def declare(rule_id: str, severity: Severity, summary: str, explain: str) -> Rule:
    """A rule produced outside the check functions (the schema step, the reader)."""
    rule = Rule(rule_id, severity, summary, textwrap.dedent(explain).strip())
    _register(rule)
    return rule


def file_rule(rule_id: str, severity: Severity, summary: str, explain: str
              ) -> Callable[[FileCheck], FileCheck]:
    """Declare a rule checked once per file: ``fn(ctx) -> Iterator[Hit]``."""
    def wrap(fn: FileCheck) -> FileCheck:
        _register(Rule(rule_id, severity, summary, textwrap.dedent(explain).strip(),
                       file_check=fn))
        return fn
    return wrap


def device_rule(rule_id: str, severity: Severity, summary: str, explain: str
                ) -> Callable[[DeviceCheck], DeviceCheck]:
    """Declare a rule checked per device: ``fn(device, ctx) -> Iterator[Hit]``."""
    def wrap(fn: DeviceCheck) -> DeviceCheck:
        _register(Rule(rule_id, severity, summary, textwrap.dedent(explain).strip(),
                       device_check=fn))
        return fn
    return wrap


def all_rules() -> dict[str, Rule]:
    """Every rule, loading the check modules on first use."""
    import ecatcfg.esi.lint.checks  # noqa: F401  (registers the rules)
    return RULES


def select_rules(select: list[str] | None, ignore: list[str] | None,
                 registry: dict[str, Rule] | None = None) -> frozenset[str]:
    """The rule ids in effect.  Entries are ids or prefixes (``ESI1`` = every ESI1xx rule).
    ``registry``: the rules to choose from (default lint's; ``check`` has its own).

    Raises ``ValueError`` naming an entry that matches no rule.
    """
    rules = all_rules() if registry is None else registry

    def expand(entries: list[str]) -> set[str]:
        chosen: set[str] = set()
        for entry in entries:
            key = entry.strip().upper()
            if not key:
                continue
            matched = {rid for rid in rules if rid.startswith(key)} if key != "ALL" \
                else set(rules)
            if not matched:
                raise ValueError(f"unknown rule id or prefix {entry!r}")
            chosen |= matched
        return chosen

    active = expand(select) if select else set(rules)
    return frozenset(active - expand(ignore or []))


def iter_checks(active: frozenset[str]) -> Iterator[Rule]:
    for rule in all_rules().values():
        if rule.id in active:
            yield rule
