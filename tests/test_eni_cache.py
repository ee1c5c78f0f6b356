"""The parsed-ENI cache (``eni/cache.py``): a hit gives the plan the reader gives, a
changed file is never served stale, and nothing it loads can be anything but a plan."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import pytest

from conftest import FifoUnblock
from ecatcfg.eni import cache as eni_cache
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni.cache import PlanCache
from ecatcfg.eni.writer import to_bytes
from ecatcfg.errors import EcatcfgError
from test_eni_io import rich_plan


@pytest.fixture
def parses(monkeypatch):
    """The files the reader really parsed."""
    calls = []
    real = eni_reader.read_bytes

    def counting(data, shown_as):
        calls.append(shown_as)
        return real(data, shown_as)

    monkeypatch.setattr(eni_reader, "read_bytes", counting)
    return calls


def _eni(tmp_path: Path, name: str = "net.eni.xml", plan=None) -> Path:
    path = tmp_path / name
    path.write_bytes(to_bytes(plan or rich_plan()))
    return path


def _entries(cache: PlanCache) -> list[Path]:
    return sorted(cache.dir.glob("*.pickle"))


def test_a_hit_gives_the_readers_plan_without_parsing(tmp_path, parses):
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    first = eni_cache.read_file(eni, cache=cache)
    second = eni_cache.read_file(eni, cache=PlanCache(tmp_path / "cache"))
    assert first == second == eni_reader.read_file(eni) == rich_plan()
    assert second is not first
    assert parses == [str(eni), str(eni)]              # the cached read parsed nothing
    assert len(_entries(cache)) == 1
    assert (cache.dir.stat().st_mode & 0o777) == 0o700
    assert (_entries(cache)[0].stat().st_mode & 0o777) == 0o600


def test_a_changed_file_is_read_again(tmp_path, parses):
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    eni_cache.read_file(eni, cache=cache)
    plan = rich_plan()
    plan.slaves[0].name = "Coupler 2"
    eni.write_bytes(to_bytes(plan))
    assert eni_cache.read_file(eni, cache=cache).slaves[0].name == "Coupler 2"
    assert len(parses) == 2


def test_same_key_other_bytes_is_a_miss(tmp_path, parses):
    """The key only names an entry: the stored ENI bytes must equal the file's."""
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    data = eni.read_bytes()
    eni_cache.read_file(eni, cache=cache)
    forged = data[:-2] + b"?" + data[-1:]              # same length; pretend the CRC matched
    assert cache.get(cache.key(data), forged) is None
    assert cache.get(cache.key(data), data) == rich_plan()


def test_a_new_reader_source_changes_every_key(tmp_path, monkeypatch):
    cache = PlanCache(tmp_path / "cache")
    before = cache.key(b"<EtherCATConfig/>")
    monkeypatch.setattr(eni_cache, "FORMAT_VERSION", eni_cache.FORMAT_VERSION + 1)
    assert cache.key(b"<EtherCATConfig/>") != before
    # Every source the key covers is really read (a typo would silently cover nothing).
    root = Path(eni_cache.__file__).parent.parent
    assert all((root / name).is_file() for name in eni_cache._FINGERPRINTED)
    assert "esi/xmlsafe.py" in eni_cache._FINGERPRINTED


def test_every_module_the_reader_reads_with_is_in_the_key():
    """What the reader decides with (bounds such as an SoE drive number's, what is refused,
    the plan's classes) lives in the modules it imports, at module level or inside a
    function, and in theirs: each one's source is in the key, so a change to any is a miss.
    Only ``errors.py`` is left out: its exception types say where a file is wrong, not
    what a plan holds."""
    import ast

    root = Path(eni_cache.__file__).parent.parent
    todo, seen = ["eni/reader.py"], set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for node in ast.walk(ast.parse((root / name).read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and \
                    node.module.startswith("ecatcfg."):
                base = node.module.removeprefix("ecatcfg.").replace(".", "/")
                for path in [f"{base}.py"] + [f"{base}/{a.name}.py" for a in node.names]:
                    if (root / path).is_file():       # a module, or one of a package's
                        todo.append(path)
    assert seen - {"errors.py"} <= set(eni_cache._FINGERPRINTED), \
        sorted(seen - {"errors.py"} - set(eni_cache._FINGERPRINTED))


def test_an_install_without_sources_still_caches(tmp_path, monkeypatch, parses):
    """Only .pyc files installed: the key falls back to the version, apply still works."""
    monkeypatch.setattr(eni_cache, "_FINGERPRINTED", ("compiler/no_such_file.py",))
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    assert eni_cache.read_file(eni, cache=cache) == eni_cache.read_file(eni, cache=cache)
    assert len(parses) == 1


def test_a_read_only_cache_still_serves_its_plans(tmp_path, monkeypatch, parses):
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    eni_cache.read_file(eni, cache=cache)

    def read_only(*_args, **_kwargs):
        raise OSError(30, "Read-only file system")
    monkeypatch.setattr(eni_cache.os, "utime", read_only)
    assert eni_cache.read_file(eni, cache=cache) == rich_plan()
    assert len(parses) == 1


def test_errors_are_not_cached(tmp_path, parses):
    bad = tmp_path / "bad.eni.xml"
    bad.write_bytes(b"<EtherCATConfig><Config>")
    cache = PlanCache(tmp_path / "cache")
    for _ in range(2):
        with pytest.raises(EcatcfgError, match="bad.eni.xml:1:"):
            eni_cache.read_file(bad, cache=cache)
    assert len(parses) == 2 and _entries(cache) == []
    with pytest.raises(eni_reader.EniReadError, match="cannot read"):
        eni_cache.read_file(tmp_path / "missing.xml", cache=cache)


def test_damaged_or_foreign_entries_are_misses(tmp_path, parses):
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    eni_cache.read_file(eni, cache=cache)
    entry = _entries(cache)[0]
    entry.write_bytes(entry.read_bytes()[:100])                       # truncated
    assert eni_cache.read_file(eni, cache=cache) == rich_plan()
    # A pickle that would call something other than a plan class is refused unrun.
    entry = _entries(cache)[0]
    entry.write_bytes(pickle.dumps((eni.read_bytes(), os.system)))
    assert eni_cache.read_file(eni, cache=cache) == rich_plan()
    assert len(parses) == 3


def test_a_folder_others_can_write_is_not_used(tmp_path, parses):
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    eni_cache.read_file(eni, cache=cache)
    os.chmod(cache.dir, 0o777)
    eni_cache.read_file(eni, cache=cache)
    assert len(parses) == 2                           # not loaded from there
    os.chmod(cache.dir, 0o700)
    entry = _entries(cache)[0]
    os.chmod(entry, 0o666)
    eni_cache.read_file(eni, cache=cache)
    assert len(parses) == 3


def test_only_the_newest_entries_are_kept(tmp_path, monkeypatch):
    monkeypatch.setattr(eni_cache, "KEEP", 3)
    cache = PlanCache(tmp_path / "cache")
    for n in range(5):
        plan = rich_plan()
        plan.master.name = f"master {n}"
        path = _eni(tmp_path, f"{n}.eni.xml", plan)
        eni_cache.read_file(path, cache=cache)
        os.utime(_newest(cache), ns=(n * 10**9, n * 10**9))     # distinct, ordered mtimes
    kept = {eni_cache.read_file(tmp_path / f"{n}.eni.xml", cache=cache).master.name
            for n in (2, 3, 4)}
    assert len(_entries(cache)) == 3 and kept == {"master 2", "master 3", "master 4"}


def _newest(cache: PlanCache) -> Path:
    return max(_entries(cache), key=lambda p: p.stat().st_mtime_ns)


def test_an_unwritable_cache_only_costs_speed(tmp_path, parses):
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the folder would go")
    eni = _eni(tmp_path)
    assert eni_cache.read_file(eni, cache=PlanCache(blocker)) == rich_plan()


def test_default_folder_follows_xdg(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    eni_cache.read_file(_eni(tmp_path))
    assert list((tmp_path / "xdg" / "ecatcfg").glob("eni-plan-v*/*.pickle"))


@pytest.mark.parametrize("damage", ["fifo", "folder"])
def test_an_entry_that_is_not_a_regular_file_is_a_miss_and_replaced(tmp_path, parses, damage):
    """A FIFO in an entry's place is neither waited on when read (it has no writer) nor
    written into when the entry is stored again: the new entry is renamed over it."""
    eni, cache = _eni(tmp_path), PlanCache(tmp_path / "cache")
    eni_cache.read_file(eni, cache=cache)
    entry = _entries(cache)[0]
    entry.unlink()
    if damage == "fifo":
        os.mkfifo(entry, 0o600)
    else:
        entry.mkdir(0o700)
    with FifoUnblock(entry) as unblock:
        assert eni_cache.read_file(eni, cache=cache) == rich_plan()
    assert not unblock.needed, "the cache waited on the FIFO"
    assert len(parses) == 2
    if damage == "fifo":                    # replaced by a good entry: the next read hits
        assert entry.is_file()
        assert eni_cache.read_file(eni, cache=cache) == rich_plan()
        assert len(parses) == 2

