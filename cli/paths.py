"""Checks of the files a command will write, made before it does any work (a failure after
the bus was touched or an output written would leave half a job behind)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TextIO

from ecatcfg.errors import UsageError
from ecatcfg.fileio import STDOUT, output_kind


def output_file(text: str | Path, stdout: bool = True) -> Path:
    """``text`` as a file to write: ``-`` (standard output, unless ``stdout`` is false), a
    character device or FIFO (written directly), or a regular file or new path whose folder
    exists (usage errors naming it; see ``fileio.output_kind``)."""
    path = Path(text)
    if str(text) == STDOUT:
        if not stdout:
            raise UsageError(f"{text}: this output cannot go to standard output")
        return path
    if path.is_dir():
        raise UsageError(f"{text}: is a folder, not a file to write")
    if output_kind(path) == "file":
        folder = path.resolve().parent
        if not folder.is_dir():
            raise UsageError(f"{text}: folder {str(path.parent)!r} does not exist")
    return path


def messages(*outputs: str | Path | None) -> TextIO:
    """Where a command's own summary goes: standard error when one of ``outputs`` is
    standard output (which then holds the output alone), else standard output."""
    return sys.stderr if any(o is not None and str(o) == STDOUT for o in outputs) \
        else sys.stdout
