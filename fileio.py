"""The one way ecatcfg reads a user's input file and writes an output, and the cache folder.

Inputs (:func:`read_input`): only a regular file, and only up to :data:`MAX_INPUT_BYTES`.
A device node, a FIFO or a pipe (``/dev/zero``, ``<(yes)``) has no end to wait for; read
whole, it grows memory until the OOM killer ends the run.  Every ESI, ENI, topology, timing
model or SII image goes through here, so every command refuses it the same way (exit 2).

Outputs (:func:`write_atomic`, :class:`OutputFile`): a regular file (or a new path) is
written beside its final name and renamed over it, so readers see the old file or the new
one, never a torn one.  A character device or a FIFO is written directly, never renamed
over: renaming a temporary file over ``/dev/null`` replaces the machine's ``/dev/null`` with
a regular file for every other program.  ``-`` is standard output.  Anything else (a folder,
a block device, a socket) is refused.
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path
from typing import BinaryIO, Literal

from ecatcfg.errors import UsageError

# The largest real ESI we know is a few MB and a 1,000-slave ENI some tens of MB; a file
# past this bound is not an EtherCAT description, and parsing it would take gigabytes.
MAX_INPUT_BYTES = 256 << 20

STDOUT = "-"                # as an output path: standard output


def cache_dir() -> Path:
    """Where ecatcfg keeps its caches: ``$XDG_CACHE_HOME/ecatcfg``, else ``~/.cache/ecatcfg``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ecatcfg"


def file_type(st: os.stat_result) -> str:
    """What a path that is not a regular file is, in words, for a message."""
    mode = st.st_mode
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO or pipe"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _not_regular(shown: str, st: os.stat_result) -> UsageError:
    return UsageError(f"{shown}: is {file_type(st)}, not a regular file; ecatcfg reads its "
                      "inputs only from regular files")


def check_input(path: str | Path, shown_as: str | None = None) -> None:
    """Refuse ``path`` before any work if it exists but is not a regular file (a missing
    path is left to the reader, which names it in its own words)."""
    try:
        st = os.stat(path)
    except OSError:
        return
    if not stat.S_ISREG(st.st_mode):
        raise _not_regular(shown_as or str(path), st)


def read_input(path: str | Path, shown_as: str | None = None,
               limit: int = MAX_INPUT_BYTES) -> bytes:
    """The whole content of the regular file ``path``.

    A path that is not a regular file, or a file larger than ``limit`` bytes, is refused
    with a :class:`UsageError` naming ``shown_as`` (the path as the user gave it), before
    anything is read: a FIFO is not even opened for long (``O_NONBLOCK``: opening one
    without a writer would wait for ever).  Other failures (missing file, no permission)
    raise ``OSError`` for the caller to word.
    """
    shown = shown_as or str(path)
    with _open_regular(path, shown) as f:
        if os.fstat(f.fileno()).st_size > limit:
            raise _too_large(shown, limit)
        data = f.read(limit + 1)            # a file still growing stops at the bound too
    if len(data) > limit:
        raise _too_large(shown, limit)
    return data


def read_head(path: str | Path, shown_as: str | None = None, size: int = 65536) -> bytes:
    """The first ``size`` bytes of the regular file ``path`` (what kind of file it is),
    refused as :func:`read_input` refuses."""
    with _open_regular(path, shown_as or str(path)) as f:
        return f.read(size)


def _open_regular(path: str | Path, shown: str) -> BinaryIO:
    """``path`` opened for reading if it is a regular file, else a :class:`UsageError`."""
    check_input(path, shown)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOCTTY", 0))
    f = os.fdopen(fd, "rb")
    st = os.fstat(fd)                       # the file opened, not the name checked before
    if not stat.S_ISREG(st.st_mode):
        f.close()
        raise _not_regular(shown, st)
    return f


def _too_large(shown: str, limit: int) -> UsageError:
    return UsageError(f"{shown}: larger than {limit >> 20} MiB, more than any EtherCAT "
                      "description; not read")


def output_kind(path: str | Path) -> Literal["stdout", "stream", "file"]:
    """How an output goes to ``path``: ``stdout`` (``-``), ``stream`` (a character device or
    FIFO: written directly) or ``file`` (a regular file or a new path: written atomically).
    Anything else is refused with a :class:`UsageError`."""
    if str(path) == STDOUT:
        return "stdout"
    try:
        st = os.stat(path)
    except OSError:                         # a new file (a bad folder fails when written)
        return "file"
    if stat.S_ISREG(st.st_mode):
        return "file"
    if stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode):
        return "stream"
    raise UsageError(f"{path}: is {file_type(st)}, not a file to write (ecatcfg writes "
                     "regular files, character devices, FIFOs and '-' for standard output)")


class OutputFile:
    """A file being written to ``path``: ``file`` takes the bytes, :meth:`commit` publishes
    them (the rename of a regular file), :meth:`discard` drops them (a device node or FIFO
    has had what was written).  ``name`` is what ``file`` writes to (the temporary file, or
    ``path`` itself), for a writer that opens its file by name.  ``replace``: always a new
    file renamed over ``path``, whatever is there (a cache's own files, where a FIFO or a
    device node is damage to replace, not a place to write to).  ``mode``: a new regular
    file's permissions (default: those of the file it replaces, or what a plain ``open()``
    would give).  Standard output is not an ``OutputFile`` (:func:`write_atomic` writes
    it)."""

    def __init__(self, path: str | Path, mode: int | None = None, *,
                 replace: bool = False) -> None:
        self.path = Path(path)
        self._replace = replace
        kind = "file" if replace else output_kind(path)
        if kind == "stdout":
            raise UsageError(f"{path}: standard output cannot take this output")
        self._tmp: str | None = None
        if kind == "stream":
            # No O_CREAT: if the node went away since the check, nothing is created.
            fd = os.open(path, os.O_WRONLY | os.O_CLOEXEC | getattr(os, "O_NOCTTY", 0))
            self.file: BinaryIO = os.fdopen(fd, "wb")
            self.name = str(path)
            return
        # Imported here: tempfile brings shutil and its compressors, which a run that
        # writes nothing (apply with its plan in the cache) need not load.
        import tempfile
        fd, self._tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.",
                                         suffix=".tmp")
        self.name = self._tmp
        try:
            # mkstemp makes the file 0600; give it the mode a plain open() would (or keep
            # the mode of the file it replaces).
            if mode is None:
                try:
                    mode = self.path.stat().st_mode & 0o7777
                except FileNotFoundError:
                    mode = 0o666 & ~_umask()
            os.chmod(fd, mode)
            self.file = os.fdopen(fd, "wb")
        except BaseException:
            os.close(fd)
            os.unlink(self._tmp)
            raise

    def commit(self) -> None:
        try:
            self.file.close()
            if self._tmp is not None:
                if not self._replace and output_kind(self.path) != "file":
                    # Became a device node or FIFO while we wrote: never rename over it.
                    raise UsageError(f"{self.path}: is no longer a regular file; not "
                                     "replaced")
                os.replace(self._tmp, self.path)
                self._tmp = None
        except BaseException:
            self.discard()
            raise

    def discard(self) -> None:
        self.file.close()
        if self._tmp is not None:
            try:
                os.unlink(self._tmp)
            except OSError:
                pass
            self._tmp = None


def write_atomic(path: str | Path, data: bytes, mode: int | None = None, *,
                 replace: bool = False) -> None:
    """Write ``data`` to ``path`` (see :class:`OutputFile`): a regular file so that readers
    see the old file or the new one, never a torn one; a character device or FIFO directly;
    ``-`` to standard output.  ``replace``: always renamed over (a cache's own files)."""
    if not replace and output_kind(path) == "stdout":
        sys.stdout.flush()
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
        return
    out = OutputFile(path, mode, replace=replace)
    try:
        out.file.write(data)
    except BaseException:
        out.discard()
        raise
    out.commit()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
