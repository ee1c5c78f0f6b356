"""Reading ``ecatcfg watch``'s commands (``cli/watch_commands.py``) without holding up the
bus cycle: stdin is polled with ``select`` from the cycle's callback, never read blocking.

- :class:`Keyboard`: the live table's terminal.  stdin goes to cbreak mode (no line
  buffering, no echo; signals stay on, so Ctrl-C still interrupts) and the line being typed
  is drawn by the table.  The saved mode is put back when the block ends, by ``q``, by the
  end of ``--cycles``, by Ctrl-C, SIGTERM or SIGHUP (which ask the cycle loop to end:
  ``cli/watch.py`` ``StopOnSignal``) or by an exception; SIGCONT (after Ctrl-Z) puts
  cbreak mode back, as the shell restores its own mode on a stop.
- :class:`Lines`: stdin in a pipe, a file, or a terminal whose output is not the table:
  one command per line; a refused one is said on stderr with its line number.
"""

from __future__ import annotations

import codecs
import os
import re
import select
import sys
from collections.abc import Callable
from types import FrameType
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from ecatcfg.cli.watch_commands import Commands, Outcome

# Escape sequences of cursor and function keys (ECMA-48 CSI and SS3): ignored, not typed.
_ESCAPE = re.compile(r"\x1b(\[[0-?]*[ -/]*[@-~]|O.|.?)", re.S)
_ERASE = ("\x7f", "\b")
_KILL_LINE = "\x15"                     # Ctrl-U


def foreground(fd: int) -> bool:
    """Whether this process may read (and set the mode of) terminal ``fd``: a background
    job that does is stopped by SIGTTIN/SIGTTOU."""
    try:
        return os.tcgetpgrp(fd) == os.getpgrp()
    except OSError:
        return False


def _readable(fd: int) -> bool:
    try:
        ready, _, _ = select.select([fd], [], [], 0)
    except (OSError, ValueError):
        return False
    return bool(ready)


class Keyboard:
    """Keys typed on the terminal ``fd`` while the table refreshes: printable keys edit the
    line, Backspace and Ctrl-U erase, Tab completes, Enter runs it; ``q`` on an empty line
    quits at once."""

    def __init__(self, fd: int, commands: Commands) -> None:
        self.fd = fd
        self.commands = commands
        self.line = ""
        self.candidates: list[str] = []
        self.last: Outcome | None = None
        self.quit = False
        self.ended = False
        self._decoder = codecs.getincrementaldecoder("utf-8")("replace")
        self._saved: list[Any] | None = None
        self._handlers: dict[int, Any] = {}

    def __enter__(self) -> Keyboard:
        import signal
        import termios
        import tty

        self._saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd, termios.TCSANOW)
        # SIGCONT (``fg`` after Ctrl-Z): the shell put the terminal back in line mode.
        # SIGINT, SIGTERM and SIGHUP end the watch through ``StopOnSignal``.
        self._handlers[signal.SIGCONT] = signal.signal(signal.SIGCONT, self._signal)
        return self

    def __exit__(self, *exc: object) -> None:
        import signal
        import termios

        for number, handler in self._handlers.items():
            signal.signal(number, handler)
        self._handlers.clear()
        if self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None

    def _signal(self, number: int, _frame: FrameType | None) -> None:
        import signal
        import termios
        import tty

        if number == signal.SIGCONT and self._saved is not None and foreground(self.fd):
            tty.setcbreak(self.fd, termios.TCSANOW)

    def poll(self) -> bool:
        """Take the keys typed since the last call; True when the line or the status
        changed (the table should be drawn again)."""
        if self.ended or not _readable(self.fd):
            return False
        try:
            data = os.read(self.fd, 1024)
        except OSError:
            data = b""
        if not data:                            # hung up: nothing more will be typed
            self.ended = True
            return False
        text = _ESCAPE.sub("", self._decoder.decode(data))
        for key in text:
            if self.quit:
                break
            self._key(key)
        return True

    def _key(self, key: str) -> None:
        if key in ("\r", "\n"):
            line, self.line, self.candidates = self.line, "", []
            outcome = self.commands.run(line)
            if outcome is not None:
                self.last = outcome
                self.quit = outcome.quit
        elif key == "\t":
            self.line, self.candidates = self.commands.complete(self.line)
        elif key in _ERASE:
            self.line = self.line[:-1]
        elif key == _KILL_LINE:
            self.line = ""
        elif key in "qQ" and not self.line:
            self.quit = True
        elif key.isprintable():
            self.line += key


class Lines:
    """Commands read line by line from ``fd`` (a pipe, a file, a terminal in line mode);
    a refused one is said on ``errors`` as ``stdin line N: ...`` and counted in
    :attr:`refused`; ``after`` is called after each command that was run (the lines of
    what it changed are printed before the next command runs, so commands that come
    together each leave their trace).  End of input ends the reading, not the watch."""

    def __init__(self, fd: int, commands: Commands, errors: TextIO = sys.stderr) -> None:
        self.after: Callable[[], None] | None = None
        self.fd = fd
        self.commands = commands
        self.errors = errors
        self.quit = False
        self.refused = 0
        self.number = 0
        self._pending = b""
        try:
            os.fstat(fd)
            self.ended = False
            self.terminal = os.isatty(fd)
        except OSError:
            self.ended, self.terminal = True, False     # no stdin at all

    def __enter__(self) -> Lines:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def poll(self) -> bool:
        """Run the complete lines that came since the last call; True when one changed
        something."""
        if self.ended or self.quit or not _readable(self.fd):
            return False
        if self.terminal and not foreground(self.fd):
            return False                        # a background job: typed for the shell
        try:
            data = os.read(self.fd, 65536)
        except OSError:
            data = b""
        if not data:
            self.ended = True
            data = b"\n" if self._pending else b""
        *lines, self._pending = (self._pending + data).split(b"\n")
        changed = False
        for raw in lines:
            self.number += 1
            outcome = self.commands.run(raw.decode(errors="replace"))
            if outcome is None:
                continue
            changed = True
            if outcome.error:
                self.refused += 1
                print(f"ecatcfg watch: stdin line {self.number}: {outcome.message}",
                      file=self.errors, flush=True)
            elif self.after is not None:
                self.after()
            if outcome.quit:
                self.quit = True
                break
        return changed
