"""The ``check`` rules: every rule's id, severity, summary and explanation.

``ecatcfg check`` reports in ``lint``'s formats, so a rule is lint's
:class:`~ecatcfg.esi.lint.rules.Rule` (without a check function: the checks of an ENI are
in :mod:`ecatcfg.eni.check.network` and :mod:`ecatcfg.eni.check.devices`).  The rules are
kept in their own registry, apart from lint's: lint's ``--list-rules`` and the compile gate
(``esi/lint/gate.py``) are about ESI files.  Ids are grouped by topic: ENI0xx the devices
of the slaves, ENI1xx SyncManagers, FMMUs, frames and working counters, ENI2xx PDOs,
ENI3xx CoE InitCmds, ENI4xx DC, ENI5xx mailbox against the ESI; ENI11x the slave-to-slave
copies (CopyInfos).
"""

from __future__ import annotations

import textwrap

from ecatcfg.esi.lint.rules import Rule, Severity

RULES: dict[str, Rule] = {}


def declare(rule_id: str, severity: Severity, summary: str, explain: str) -> str:
    """Register a rule; returns its id (the check modules name their rules by it)."""
    if rule_id in RULES:
        raise RuntimeError(f"check rule {rule_id} declared twice")
    RULES[rule_id] = Rule(rule_id, severity, summary, textwrap.dedent(explain).strip())
    return rule_id


UNREADABLE = declare("ENI004", "error", "the ENI cannot be read", """
    The file is not an ENI the reader takes (eni/reader.py): not well-formed XML, a value
    that is not a number, a command without its address, a cyclic frame whose datagrams
    take more than the 1500 bytes of an Ethernet payload (at most 1486 data bytes in one
    datagram; ETG.1000.4), ...  The message names the line; nothing else is checked.""")
