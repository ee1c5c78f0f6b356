"""``ecatcfg check``: an ENI checked against itself and the ESI files of its devices.

:func:`check_eni` returns lint's :class:`~ecatcfg.esi.lint.finding.FileResult`, so the
command writes it with lint's output formats; the rules are in :mod:`.rules`."""

from __future__ import annotations

from ecatcfg.eni.check.rules import all_rules
from ecatcfg.eni.check.run import check_eni

__all__ = ["all_rules", "check_eni"]
