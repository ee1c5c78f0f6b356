"""``ecatcfg simulate --input NAME=VALUE`` and ``--control``: a line of the virtual segment
changed while a master runs it, from a terminal or a script.

``--control`` reads one command a line from standard input (a pipe, a FIFO, a terminal) and
answers each with one line on standard output, ``ok: ...`` or ``error: ...``:

- ``set NAME VALUE`` (or ``NAME=VALUE``): hold an input of an emulated slave at a value;
- ``release NAME``: stop holding it (the input keeps its last value);
- ``cut SLAVE``: pull the cable into the slave's port 0 (it and the slaves behind it leave
  the frame); ``plug SLAVE``: put it back;
- ``power SLAVE`` or ``power all``: switch a slave (or the line) off and on;
- ``inputs [SLAVE]``: list the input names; ``help``.

Commands take effect between two frames (the segment's tick, every 2 ms), never in the
middle of one.  A slave is named as in the table simulate prints (or by its bus position
with every cable in place).
"""

from __future__ import annotations

import queue
import sys
import threading
from typing import TextIO

from ecatcfg.runtime.segment.inputs import find_input, input_entries
from ecatcfg.runtime.segment.slave import EmulatedSlave
from ecatcfg.runtime.segment.virtual import VirtualSegment

HELP = ("commands: set NAME VALUE | NAME=VALUE | release NAME | cut SLAVE | plug SLAVE | "
        "power SLAVE|all | inputs [SLAVE] | help")


def hold(seg: VirtualSegment, assignment: str) -> str:
    """``NAME=VALUE``: the input held; what was done, in words.  ValueError otherwise."""
    name, sep, value = assignment.rpartition("=")
    if not sep or not name.strip():
        raise ValueError(f"{assignment}: NAME=VALUE, e.g. 'buttons.Channel 1.Input=1'")
    entry = find_input(seg, name.strip())
    number = entry.parse(value)
    entry.hold(number)
    return f"{entry.name} = {number}"


class Control:
    """Commands from ``source`` (read by a thread of its own), run by :meth:`tick` in the
    segment's loop."""

    def __init__(self, seg: VirtualSegment, source: TextIO = sys.stdin,
                 out: TextIO = sys.stdout) -> None:
        self.seg, self.out = seg, out
        self.lines: queue.Queue[str] = queue.Queue()
        self.reader = threading.Thread(target=self._read, args=(source,), daemon=True,
                                       name="simulate-control")
        self.reader.start()

    def _read(self, source: TextIO) -> None:
        for line in source:
            self.lines.put(line)

    def tick(self) -> None:
        """Run the commands that arrived, then put every held input in place again (a
        master that remapped the PDOs or a power cycle moved or cleared them)."""
        while True:
            try:
                line = self.lines.get_nowait()
            except queue.Empty:
                break
            if line.strip() and not line.lstrip().startswith("#"):
                self._answer(line.strip())
        for s in self.seg.wired:
            s.apply_held_inputs()

    def _answer(self, line: str) -> None:
        try:
            text = "ok: " + self.run(line)
        except ValueError as exc:
            text = f"error: {exc}"
        print(text, file=self.out, flush=True)

    def run(self, line: str) -> str:
        """One command; what it did, in words (ValueError: why not)."""
        word, _, rest = line.partition(" ")
        rest = rest.strip()
        if word == "set":
            name, _, value = rest.rpartition(" ")
            return hold(self.seg, f"{name}={value}")
        if "=" in line and word not in ("release", "cut", "plug", "power", "inputs"):
            return hold(self.seg, line)
        if word == "release":
            entry = find_input(self.seg, rest)
            entry.release()
            return f"{entry.name} released"
        if word == "cut":
            gone = self.seg.remove_cable(self._slave(rest))
            return f"cable into {rest} removed: {', '.join(s.name for s in gone)} off the frame"
        if word == "plug":
            self.seg.restore_cable(self._slave(rest))
            return f"cable into {rest} back"
        if word == "power":
            targets = list(self.seg.wired) if rest == "all" else [self._slave(rest)]
            for s in targets:
                self.seg.power_cycle(s)
            return f"{len(targets)} slave{'s' * (len(targets) != 1)} switched off and on"
        if word == "inputs":
            names = sorted(n for n, e in input_entries(self.seg).items()
                           if not rest or e.slave.name == rest)
            return f"{len(names)} inputs: " + "; ".join(names)
        if word == "help":
            return HELP
        raise ValueError(f"{line!r}: unknown command; {HELP}")

    def _slave(self, name: str) -> EmulatedSlave:
        # Every slave, on the frame or not (a cut cable's): ``wired`` holds them all.
        for s in self.seg.wired:
            if s.name == name:
                return s
        if name.isdigit():
            for s in self.seg.wired:
                if s.position == int(name):
                    return s
        raise ValueError(f"{name or '(none)'}: no slave of that name or position (the slaves "
                         f"are {', '.join(s.name for s in self.seg.wired)})")


__all__ = ["Control", "HELP", "hold"]
