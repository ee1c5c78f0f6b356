"""What a check function is given: the plan, where its parts are, and where findings go."""

from __future__ import annotations

from dataclasses import dataclass, field

from ecatcfg.eni.check.lines import EniLines
from ecatcfg.eni.check.rules import RULES
from ecatcfg.eni.plan import NetworkPlan, SlavePlan
from ecatcfg.esi.lint.finding import DeviceRef, Finding


@dataclass(slots=True)
class CheckContext:
    shown: str                       # the ENI as messages name it
    plan: NetworkPlan
    lines: EniLines
    active: frozenset[str]           # the rule ids in effect
    findings: list[Finding] = field(default_factory=list)
    devices: dict[int, DeviceRef] = field(default_factory=dict)

    def device_ref(self, slave: SlavePlan) -> DeviceRef:
        ref = self.devices.get(id(slave))
        if ref is None:
            ref = self.devices[id(slave)] = DeviceRef(
                slave.vendor_id, slave.product_code, slave.revision, slave.name,
                self.lines.slave(slave) or 0)
        return ref

    def add(self, rule: str, line: int | None, message: str,
            slave: SlavePlan | None = None) -> None:
        if rule not in self.active:
            return
        where = f"slave {slave.name!r}: " if slave is not None else ""
        self.findings.append(Finding(self.shown, line, None, rule, RULES[rule].severity,
                                     where + message,
                                     self.device_ref(slave) if slave is not None else None))
