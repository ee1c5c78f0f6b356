"""Where in its ENI file a part of a plan was written: the line of a slave's InitCmd, or of
a slave-to-slave copy.

The plan holds what the file says, not where (reading our own output back gives an equal
plan, whatever its layout), so a command the runtime finds refused is located afterwards,
by reading the file again: the reader keeps a slave's register InitCmds
(``Slave/InitCmds``) and its mailbox InitCmds (``Slave/Mailbox/CoE|EoE|SoE|FoE/InitCmds``)
in file order, so the n-th command of a list is the n-th ``InitCmd`` element of the slave's
element.  Only used on an error path; the file is parsed as the reader parses it
(``esi/xmlsafe.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ecatcfg.eni.plan import (CoeInitCmd, CopyInfo, EoeInitCmd, FoeInitCmd, InitCmd,
                             NetworkPlan, SoeInitCmd)
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi import xmlsafe
from ecatcfg.fileio import read_input


def init_cmd_line(path: str | Path, plan: NetworkPlan,
                  cmd: InitCmd | CoeInitCmd | EoeInitCmd | SoeInitCmd | FoeInitCmd
                  ) -> int | None:
    """The line of the ``InitCmd`` element that ``cmd`` (an object of ``plan``, read from
    ``path``) comes from; ``None`` when it is not a slave's command or the file no longer
    matches the plan (changed since, or commands the reader left out as refused)."""
    for number, slave in enumerate(plan.slaves):
        lists: list[tuple[str, Sequence[InitCmd | CoeInitCmd | EoeInitCmd | SoeInitCmd
                                        | FoeInitCmd]]] = [
            ("InitCmds", slave.init_cmds)]
        if slave.mailbox is not None:
            lists += [("Mailbox/CoE/InitCmds", slave.mailbox.coe_init_cmds),
                      ("Mailbox/EoE/InitCmds", slave.mailbox.eoe_init_cmds),
                      ("Mailbox/SoE/InitCmds", slave.mailbox.soe_init_cmds),
                      ("Mailbox/FoE/InitCmds", slave.mailbox.foe_init_cmds)]
        for where, cmds in lists:
            index = next((i for i, c in enumerate(cmds) if c is cmd), None)
            if index is not None:
                return _element_line(path, number, where, index, len(cmds))
    return None


def _element_line(path: str | Path, slave: int, where: str, index: int,
                  count: int) -> int | None:
    try:
        root = xmlsafe.parse_bytes(read_input(path), str(path)).getroot()
    except (OSError, EcatcfgError):
        return None
    config = root.find("Config")
    slaves = [] if config is None else list(config.iterchildren("Slave"))
    if slave >= len(slaves):
        return None
    parent = slaves[slave].find(where)
    elements = [] if parent is None else list(parent.iterchildren("InitCmd"))
    if len(elements) != count:
        return None
    line: int | None = elements[index].sourceline
    return line


def copy_info_line(path: str | Path, plan: NetworkPlan, copy: CopyInfo) -> int | None:
    """The line of the ``CopyInfo`` element ``copy`` (of ``plan``, read from ``path``) comes
    from: the reader keeps every ``Cyclic/Frame/Cmd/CopyInfos/CopyInfo`` in file order;
    ``None`` when the file no longer matches (or the reader left some out as refused)."""
    copies = [c for cyc in plan.cyclic for f in cyc.frames for cmd in f.cmds
              for c in cmd.copy_infos]
    index = next((i for i, c in enumerate(copies) if c is copy), None)
    try:
        root = xmlsafe.parse_bytes(read_input(path), str(path)).getroot()
    except (OSError, EcatcfgError):
        return None
    elements = list(root.iterfind("Config/Cyclic/Frame/Cmd/CopyInfos/CopyInfo"))
    if index is None or len(elements) != len(copies):
        return None
    line: int | None = elements[index].sourceline
    return line
