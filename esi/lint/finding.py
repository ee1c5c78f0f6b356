"""What lint reports: findings, and the per-file result the output formats read."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ecatcfg.esi.lint.rules import Severity
from ecatcfg.esi.model import format_selector


@dataclass(frozen=True, slots=True)
class DeviceRef:
    """The device a finding belongs to (vendor/product/revision as the file gives them)."""

    vendor_id: int | None
    product_code: int | None
    revision: int | None
    type: str
    line: int

    @property
    def selector(self) -> str:
        return format_selector(self.vendor_id, self.product_code, self.revision)

    def as_json(self) -> dict[str, Any]:
        return {"vendor_id": self.vendor_id, "product_code": self.product_code,
                "revision": self.revision, "type": self.type}


@dataclass(frozen=True, slots=True)
class Finding:
    file: str
    line: int | None
    column: int | None
    rule: str
    severity: Severity
    message: str
    device: DeviceRef | None = None

    def sort_key(self) -> tuple[str, int, int, str, str]:
        return (self.file, self.line or 0, self.column or 0, self.rule, self.message)

    def as_json(self) -> dict[str, Any]:
        return {"file": self.file, "line": self.line, "column": self.column,
                "rule": self.rule, "severity": self.severity, "message": self.message,
                "device": self.device.as_json() if self.device else None}


@dataclass(slots=True)
class FileResult:
    """One linted file: its findings and the devices it describes (for JUnit test cases)."""

    file: str
    findings: list[Finding] = field(default_factory=list)
    devices: list[DeviceRef] = field(default_factory=list)
    # (first line, first line after it) of each Module element, for findings about a module
    # (compile asks which findings lie inside a module a slave plugs).
    module_spans: list[tuple[int, int | None]] = field(default_factory=list)
    schema_checked: bool = False
    schema_missing: str | None = None    # the schema file that would have applied
    seconds: float = 0.0

    @property
    def has_errors(self) -> bool:
        return any(f.severity == "error" for f in self.findings)


def count_by_severity(findings: list[Finding]) -> dict[str, int]:
    counts = {"error": 0, "warning": 0, "info": 0}
    for f in findings:
        counts[f.severity] += 1
    return counts
