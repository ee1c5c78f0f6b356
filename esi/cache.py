"""On-disk cache of file summaries, so a second run does not reparse unchanged ESI files.

Layout under ``$XDG_CACHE_HOME/ecatcfg`` (default ``~/.cache/ecatcfg``)::

    esi-index-v<N>/stat.json        {absolute path: [dev, ino, size, mtime_ns, ctime_ns, digest]}
    esi-index-v<N>/<digest>.json    the FileSummary of a file with that content (BLAKE2b-128)

Never stale: a summary is keyed by the file's content hash.  The stat record only saves
re-hashing: when device, inode, size, mtime *and* ctime are all unchanged the file has not
been written (ctime moves on every write and cannot be set back by ``touch``/``utime``; the
same test git's index relies on).  Anything else re-hashes the bytes, and a hash seen before
(a fresh checkout, a copy) reuses its summary without parsing.
Safe to delete at any time; every write is atomic (temp file + rename), and an unreadable or
foreign cache file is treated as absent.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

from ecatcfg.errors import UsageError
from ecatcfg.esi.index import SUMMARY_VERSION, FileSummary
from ecatcfg.fileio import cache_dir as default_cache_dir
from ecatcfg.fileio import read_input, write_atomic


_DIGEST = re.compile(r"[0-9a-f]{32}")       # content_digest's: BLAKE2b-128 in hex


def content_digest(data: bytes) -> str:
    return hashlib.blake2b(data, digest_size=16).hexdigest()


def stat_key(st: os.stat_result) -> list[int]:
    return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]


class IndexCache:
    def __init__(self, root: Path | None = None) -> None:
        self.dir = (root or default_cache_dir()) / f"esi-index-v{SUMMARY_VERSION}"
        self._stat: dict[str, list[Any]] | None = None
        self._stat_dirty = False

    # -- stat records ---------------------------------------------------------------------

    def _stats(self) -> dict[str, list[Any]]:
        if self._stat is None:
            data = _read_json(self.dir / "stat.json")
            self._stat = data if isinstance(data, dict) else {}
        return self._stat

    def known_digest(self, path: Path, st: os.stat_result) -> str | None:
        """The content digest recorded for ``path`` if the file is provably unchanged."""
        rec = self._stats().get(str(path))
        if isinstance(rec, list) and len(rec) == 6 and rec[:5] == stat_key(st) \
                and isinstance(rec[5], str) and _DIGEST.fullmatch(rec[5]):
            return rec[5]
        return None

    def remember(self, path: Path, st: os.stat_result, digest: str) -> None:
        self._stats()[str(path)] = stat_key(st) + [digest]
        self._stat_dirty = True

    # -- summaries ------------------------------------------------------------------------

    def get(self, digest: str) -> FileSummary | None:
        if not _DIGEST.fullmatch(digest):       # a damaged stat record: never a path
            return None
        try:
            return FileSummary.from_json(_read_json(self.dir / f"{digest}.json"))
        except ValueError:      # damaged, or written by another summary layout: summarized
            return None         # again, and put() replaces it

    def put(self, digest: str, summary: FileSummary) -> None:
        self._write(self.dir / f"{digest}.json", summary.to_json())

    def flush(self) -> None:
        if self._stat_dirty and self._stat is not None:
            self._write(self.dir / "stat.json", self._stat)
            self._stat_dirty = False

    def _write(self, path: Path, data: Any) -> None:
        # A cache that cannot be written (read-only home, full disk) only costs speed.
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            write_atomic(path, json.dumps(data, separators=(",", ":")).encode(), replace=True)
        except OSError:
            pass


def _read_json(path: Path) -> Any:
    try:
        return json.loads(read_input(path))
    except (OSError, ValueError, UsageError):    # UsageError: not a regular file
        return None
