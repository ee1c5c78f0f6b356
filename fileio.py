"""File output shared by every writer (nothing is ever left half-written) and the cache folder."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def cache_dir() -> Path:
    """Where ecatcfg keeps its caches: ``$XDG_CACHE_HOME/ecatcfg``, else ``~/.cache/ecatcfg``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ecatcfg"


def write_atomic(path: str | Path, data: bytes, mode: int | None = None) -> None:
    """Write ``data`` so readers see the old file or the new one, never a torn one.

    The temporary file lives beside the target (same file system, so the rename is atomic)
    and is removed again if anything fails.  ``mode``: the new file's permissions (default:
    those of the file it replaces, or what a plain ``open()`` would give).
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp makes the file 0600; give it the mode a plain open() would (or keep the
        # mode of the file it replaces).
        if mode is None:
            try:
                mode = path.stat().st_mode & 0o7777
            except FileNotFoundError:
                mode = 0o666 & ~_umask()
        os.chmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
