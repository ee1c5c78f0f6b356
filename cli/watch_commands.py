"""What the user types while ``ecatcfg watch`` runs: ``force NAME VALUE`` (or
``NAME=VALUE``), ``unforce NAME`` (``release``; a shell pattern releases every forced output
it matches), ``quit``, ``help``; with completion of the command words and variable names.

The same commands come from the keyboard of the live table and, line by line, from stdin
in a pipe (``cli/watch_input.py`` reads them).  Values are parsed as ``--force`` parses
them (``runtime/watch.py``, ``output_value``) and range-checked where they are written.
"""

from __future__ import annotations

import fnmatch
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ecatcfg.errors import EcatcfgError

if TYPE_CHECKING:
    from ecatcfg.runtime.watch import Watch

FORCE = ("force", "f")
RELEASE = ("unforce", "u", "release")
QUIT = ("quit", "q", "exit")
HELP = ("help", "h", "?")
WORDS = ("force", "unforce", "release", "quit", "help")
USAGE = ("force NAME VALUE (or NAME=VALUE), unforce NAME|PATTERN, quit; "
         "f, u, q for short; Tab completes")


@dataclass(frozen=True)
class Outcome:
    """What a command did: ``message`` for the status line, ``error`` when it was refused
    (nothing changed), ``quit`` to stop watching."""

    message: str
    error: bool = False
    quit: bool = False


class Commands:
    """Runs typed commands on a :class:`~ecatcfg.runtime.watch.Watch`."""

    def __init__(self, watch: Watch) -> None:
        self.watch = watch
        self.outputs = sorted(watch.outputs)

    def run(self, line: str) -> Outcome | None:
        """The command ``line``; None for an empty line.  A mistake is an error outcome
        naming the command, never an exception."""
        text = line.strip()
        if not text:
            return None
        word, _, rest = text.partition(" ")
        word, rest = word.lower(), rest.strip()
        try:
            if word in FORCE:
                return self._force(rest)
            if word in RELEASE:
                return self._release(rest)
        except EcatcfgError as exc:
            return Outcome(f"{text}: {exc}", error=True)
        if word in QUIT:
            return Outcome("quit", quit=True)
        if word in HELP:
            return Outcome(USAGE)
        return Outcome(f"{text}: unknown command {word!r} ({USAGE})", error=True)

    def _force(self, rest: str) -> Outcome:
        from ecatcfg.runtime.watch import output_value

        name, raw = self._split(rest)
        value = output_value(self.watch.net.plan, name, raw)
        self.watch.force_output(name, value)
        return Outcome(f"forced {name} = {value_text(self.watch.net[name])}")

    def _split(self, rest: str) -> tuple[str, str]:
        """NAME and VALUE of ``NAME VALUE`` or ``NAME=VALUE``: names may hold both spaces
        and ``=``, so the split that leaves a known variable's name wins."""
        known = set(self.watch.net.variables)
        if rest in known:
            raise EcatcfgError(f"no value for {rest!r}: give NAME VALUE or NAME=VALUE")
        splits = [(n.strip(), v) for n, sep, v in (rest.rpartition(" "), rest.rpartition("="))
                  if sep and n.strip()]
        if not splits:
            raise EcatcfgError("give NAME VALUE or NAME=VALUE")
        for name, raw in splits:
            if name in known:
                return name, raw
        return splits[-1] if "=" in rest else splits[0]

    def _release(self, rest: str) -> Outcome:
        if not rest:
            raise EcatcfgError("give the NAME (or a shell pattern) of a forced output")
        if rest in self.watch.forced or not any(c in rest for c in "*?["):
            names = [rest]
        else:
            names = [n for n in self.watch.forced if fnmatch.fnmatchcase(n, rest)]
            if not names:
                raise EcatcfgError("no forced output matches")
        released = [f"{name} = {value_text(self.watch.release(name))}" for name in names]
        return Outcome("released " + ", ".join(released))

    def complete(self, line: str) -> tuple[str, list[str]]:
        """``line`` completed as far as it is unambiguous, and the candidates it stopped
        at (none when it was completed to one)."""
        word, space, rest = line.partition(" ")
        if not space:
            found = [w for w in WORDS if w.startswith(word.lower())]
            if len(found) == 1:
                return found[0] + " ", []
            return line, found
        if word.lower() in FORCE:
            pool = self.outputs
        elif word.lower() in RELEASE:
            pool = sorted(self.watch.forced)
        else:
            return line, []
        prefix = rest.lstrip()
        found = [n for n in pool if n.startswith(prefix)]
        if not found:
            return line, []
        common = os.path.commonprefix(found)
        if len(found) == 1:
            return f"{word} {common} ", []
        return f"{word} {common}", found

    def status(self) -> str:
        """The forced outputs, for the status line."""
        if not self.watch.forced:
            return "forced: none"
        return "forced: " + ", ".join(f"{n} = {value_text(v)}"
                                      for n, v in self.watch.forced.items())


def value_text(value: bool | int | float) -> str:
    """A process variable's value as watch shows it: a bit as 1/0, REAL shortest."""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)
