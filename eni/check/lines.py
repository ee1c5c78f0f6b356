"""Where in the ENI file a part of the plan is: the lines check's findings name.

The plan holds what the file says, not where; as ``eni/source.py`` does for one command on
an error path, the file is parsed again and the plan's lists are matched with the elements
in file order (the reader keeps ``Config/Slave``, each slave's ``InitCmds/InitCmd`` and
``Mailbox/CoE/InitCmds/InitCmd``, ``Cyclic/Frame/Cmd`` in that order).  Where the counts do
not match (elements the reader refused), the slave's own line is given instead.
"""

from __future__ import annotations

from pathlib import Path

from lxml import etree

from ecatcfg.eni.plan import NetworkPlan, SlavePlan
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.values import parse_int
from ecatcfg.fileio import read_input


class EniLines:
    """Lines of a plan's slaves, their commands and the cyclic commands in its file."""

    def __init__(self, path: Path, shown: str, plan: NetworkPlan) -> None:
        root = xmlsafe.parse_bytes(read_input(path, shown), shown).getroot()
        config = root.find("Config")
        elements = [] if config is None else list(config.iterchildren("Slave"))
        ordered = plan.in_file_order()
        self._slaves: dict[int, etree._Element] = {}
        if len(elements) == len(ordered):
            self._slaves = {id(s): e for s, e in zip(ordered, elements)
                            if isinstance(s, SlavePlan)}
        self._cyclic = [] if config is None else list(config.iterchildren("Cyclic"))
        self.config_line: int | None = None if config is None else config.sourceline

    def slave(self, slave: SlavePlan) -> int | None:
        element = self._slaves.get(id(slave))
        return None if element is None else element.sourceline

    def child(self, slave: SlavePlan, where: str) -> int | None:
        """The line of ``where`` (a path below the slave element), else the slave's."""
        element = self._slaves.get(id(slave))
        found = None if element is None else element.find(where)
        return found.sourceline if found is not None else self.slave(slave)

    def pdo_entry(self, slave: SlavePlan, direction: str, pdo: int, position: int
                  ) -> int | None:
        """The line of the ``position``-th ``Entry`` of ``ProcessData``'s PDO ``pdo`` of
        ``direction`` ("rx": RxPdo, "tx": TxPdo), else of that PDO, else of ``ProcessData``."""
        element = self._slaves.get(id(slave))
        tag = "RxPdo" if direction == "rx" else "TxPdo"
        for desc in [] if element is None else element.iterfind(f"ProcessData/{tag}"):
            try:
                index = parse_int((desc.findtext("Index") or "").strip())
            except ValueError:
                continue
            if index == pdo:
                entries = list(desc.iterchildren("Entry"))
                return (entries[position] if position < len(entries) else desc).sourceline
        return self.child(slave, "ProcessData")

    def listed(self, slave: SlavePlan, where: str, index: int, count: int) -> int | None:
        """The line of the ``index``-th of ``count`` ``InitCmd`` elements in ``where``."""
        element = self._slaves.get(id(slave))
        parent = None if element is None else element.find(where)
        items = [] if parent is None else list(parent.iterchildren("InitCmd"))
        if len(items) != count:
            return self.slave(slave)
        return items[index].sourceline

    def cyclic_cmd(self, cyclic: int, frame: int, cmd: int) -> int | None:
        """The line of ``Cyclic[cyclic]/Frame[frame]/Cmd[cmd]``."""
        try:
            frame_el = list(self._cyclic[cyclic].iterchildren("Frame"))[frame]
            return list(frame_el.iterchildren("Cmd"))[cmd].sourceline
        except IndexError:
            return self.config_line

    def copy_info(self, cyclic: int, frame: int, cmd: int, copy: int,
                  kept: int) -> int | None:
        """The line of that command's ``CopyInfos/CopyInfo[copy]``, else the command's.
        The reader leaves out copies it refuses: ``copy`` counts among the ``kept`` ones,
        so the line is found only while the file has as many."""
        try:
            frame_el = list(self._cyclic[cyclic].iterchildren("Frame"))[frame]
            cmd_el = list(frame_el.iterchildren("Cmd"))[cmd]
        except IndexError:
            return self.config_line
        copies = list(cmd_el.iterfind("CopyInfos/CopyInfo"))
        return copies[copy].sourceline if len(copies) == kept else cmd_el.sourceline

    def frame(self, cyclic: int, frame: int) -> int | None:
        try:
            return list(self._cyclic[cyclic].iterchildren("Frame"))[frame].sourceline
        except IndexError:
            return self.config_line
