"""Checks of the files a command will write, made before it does any work (a failure after
the bus was touched or an output written would leave half a job behind)."""

from __future__ import annotations

from pathlib import Path

from ecatcfg.errors import UsageError


def output_file(text: str | Path) -> Path:
    """``text`` as a file to write: its folder must exist and it must not be a folder
    (usage errors naming it)."""
    path = Path(text)
    folder = path.resolve().parent
    if not folder.is_dir():
        raise UsageError(f"{text}: folder {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise UsageError(f"{text}: is a folder, not a file to write")
    return path
