"""Parsed ENIs on disk, so a machine that applies the same ENI at every start parses it once.

Reading an ENI is lxml's import (about 10 ms), its parse and a Python walk over every
InitCmd: about 4 ms for one slave and 44 ms for 64 (1812 InitCmds), against about 1 and
6 ms to load the pickled plan, which needs no lxml.
``ecatcfg apply`` reads through this cache (docs/BENCHMARKS.md, "Startup").

Layout under ``$XDG_CACHE_HOME/ecatcfg`` (default ``~/.cache/ecatcfg``)::

    eni-plan-v<N>/<key>.pickle      (ENI bytes, NetworkPlan read from them)

Never stale: an entry is used only if its ENI bytes equal the file's, byte for byte, and
the key also covers ecatcfg's version, the source of the reader, the plan model and the
safe XML parser, and lxml's version, so a changed ecatcfg or lxml is a miss.  (The key is a CRC-32 with the length: it only names the entry; hashlib would
cost 3 ms of OpenSSL start-up.)  Only plans that read without error are stored; errors are
reported fresh on every run.  Loading builds nothing but plan classes (the unpickler
refuses any other), and only from a folder of the current user that nobody else can write
to (created 0700).  Safe to delete at any time; writes are atomic, and an unreadable entry
is a miss.  The newest ``KEEP`` entries are kept.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import stat
import zlib
from pathlib import Path

from ecatcfg import __version__
from ecatcfg.eni import plan as plan_model
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import Transition
from ecatcfg.fileio import cache_dir, read_input, write_atomic

FORMAT_VERSION = 1
KEEP = 32                                   # entries; the oldest go when a new one is written
# A change to any of these changes every key (contents.py: what is refused; eoe.py: which
# EoE data decodes; esc.py: the Transition values; xmlsafe.py:
# how the XML is parsed and its namespaces stripped; values.py: number and boolean syntax;
# idn.py: an SoE drive number's bounds and the OpCode apply sends; fileio.py: which
# files are read at all; record.py: how the
# plan's classes are built).  Every module the reader imports is here but errors.py
# (tests/test_eni_cache.py).
_FINGERPRINTED = ("eni/reader.py", "eni/contents.py", "eni/plan.py", "eni/compare.py",
                  "eoe.py", "esc.py", "fileio.py", "esi/xmlsafe.py", "esi/values.py",
                  "esi/idn.py", "esi/vocabulary.py", "record.py")


def _fingerprint() -> int:
    """The reader's code: its source and the plan's (in an install without sources, the
    version alone), and lxml's ``__init__.py``, which names its version (read, not
    imported: a cache hit does without lxml)."""
    sources = [Path(__file__).parent.parent / name for name in _FINGERPRINTED]
    lxml = importlib.util.find_spec("lxml")
    if lxml is not None and lxml.origin:
        sources.append(Path(lxml.origin))
    crc = zlib.crc32(f"{FORMAT_VERSION} {__version__}".encode())
    for path in sources:
        try:
            crc = zlib.crc32(path.read_bytes(), crc)
        except OSError:                     # only .pyc files installed
            pass
    return crc


class _PlanUnpickler(pickle.Unpickler):
    """Builds plan objects and nothing else: a pickle naming any other class is refused."""

    def find_class(self, module: str, name: str) -> type:
        found = getattr(plan_model, name, None) if module == plan_model.__name__ else None
        if isinstance(found, type) and hasattr(found, "__record_fields__"):
            return found
        if (module, name) == (Transition.__module__, "Transition"):
            return Transition
        raise pickle.UnpicklingError(f"{module}.{name} is not part of a plan")


class PlanCache:
    def __init__(self, root: Path | None = None) -> None:
        self.dir = (root or cache_dir()) / f"eni-plan-v{FORMAT_VERSION}"

    def key(self, data: bytes) -> str:
        return f"{_fingerprint():08x}-{len(data):x}-{zlib.crc32(data):08x}"

    def get(self, key: str, data: bytes) -> NetworkPlan | None:
        """The plan stored under ``key`` for exactly the ENI bytes ``data``."""
        path = self.dir / f"{key}.pickle"
        if not self._trusted_dir():
            return None
        try:
            # O_NONBLOCK: a FIFO in the cache's place is not waited on; only a regular file
            # of ours is read.
            with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC),
                           "rb") as f:
                st = os.fstat(f.fileno())
                if (not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid()
                        or st.st_mode & 0o022):
                    return None
                stored, plan = _PlanUnpickler(f).load()
        except FileNotFoundError:
            return None
        # A damaged entry can fail to unpickle in many ways (UnpicklingError, EOFError,
        # TypeError, ValueError, ...); every one of them only means "parse again".
        except Exception:                   # noqa: BLE001
            return None
        if stored != data or not isinstance(plan, NetworkPlan):
            return None
        try:
            os.utime(path)                  # most recently used: kept longest
        except OSError:                     # a read-only cache still serves its plans
            pass
        return plan

    def put(self, key: str, data: bytes, plan: NetworkPlan) -> None:
        # A cache that cannot be written (read-only home, full disk) only costs speed.
        try:
            self.dir.mkdir(mode=0o700, parents=True, exist_ok=True)
            if not self._trusted_dir():
                return
            write_atomic(self.dir / f"{key}.pickle",
                         pickle.dumps((data, plan), protocol=pickle.HIGHEST_PROTOCOL),
                         mode=0o600, replace=True)
            self._prune()
        except OSError:
            pass

    def _trusted_dir(self) -> bool:
        try:
            st = os.stat(self.dir)
        except OSError:
            return False
        return (stat.S_ISDIR(st.st_mode) and st.st_uid == os.geteuid()
                and not st.st_mode & 0o022)

    def _prune(self) -> None:
        entries = sorted(self.dir.glob("*.pickle"), key=lambda p: p.stat().st_mtime_ns)
        for old in entries[:-KEEP]:
            old.unlink(missing_ok=True)


def read_file(path: str | Path, shown_as: str | None = None,
              cache: PlanCache | None = None) -> NetworkPlan:
    """:func:`ecatcfg.eni.reader.read_file` through ``cache`` (the default one if
    ``None``).  lxml and the reader are imported only on a miss."""
    name = shown_as or str(path)
    try:
        data = read_input(path, name)
    except OSError as exc:
        from ecatcfg.eni.reader import EniReadError
        raise EniReadError(f"cannot read: {exc.strerror}", name) from None
    cache = cache or PlanCache()
    key = cache.key(data)
    plan = cache.get(key, data)
    if plan is None:
        from ecatcfg.eni import reader as eni_reader
        plan = eni_reader.read_bytes(data, name)
        cache.put(key, data, plan)
    return plan
