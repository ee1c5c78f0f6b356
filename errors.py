"""The error types every subcommand turns into a one-line message and an exit code.

A user mistake (bad file, unknown device, wrong flag value) raises a subclass of
:class:`EcatcfgError`; the CLI prints ``str(error)`` and exits 1 without a traceback.
Anything else escaping to the CLI is a bug in ecatcfg and keeps its traceback.
"""

from __future__ import annotations


class EcatcfgError(Exception):
    """An error in the user's input, with the place it comes from when known."""

    exit_code = 1

    def __init__(self, message: str, file: str | None = None, line: int | None = None,
                 column: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.column = column

    def __str__(self) -> str:
        where = location(self.file, self.line, self.column)
        return f"{where}: {self.message}" if where else self.message


class UsageError(EcatcfgError):
    """Wrong command-line use or a path that does not exist (exit code 2)."""

    exit_code = 2


def location(file: str | None, line: int | None = None, column: int | None = None) -> str:
    """``file:line:column`` with the parts that are known."""
    if not file:
        return ""
    parts = [file]
    if line:
        parts.append(str(line))
        if column:
            parts.append(str(column))
    return ":".join(parts)
