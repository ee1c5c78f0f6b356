"""The index cache: a second run does not reparse, and it is never stale."""

import os

import pytest

from conftest import device_xml, esi_xml, write
from ecatcfg.esi import index, library
from ecatcfg.esi.cache import IndexCache
from ecatcfg.esi.library import Library


@pytest.fixture
def parses(monkeypatch):
    calls = []
    real = index.summarize

    def counting(tree, file):
        calls.append(file)
        return real(tree, file)

    monkeypatch.setattr(library, "summarize", counting)
    return calls


def test_second_run_does_not_reparse(tmp_path, parses):
    esi = write(tmp_path, "a.xml", esi_xml(device_xml("A")))
    cache = IndexCache(tmp_path / "cache")
    assert Library([esi], cache=cache).entries[0].type == "A"
    assert Library([esi], cache=IndexCache(tmp_path / "cache")).entries[0].type == "A"
    assert len(parses) == 1


def test_default_cache_dir_follows_xdg(tmp_path, monkeypatch, parses):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    esi = write(tmp_path, "a.xml", esi_xml())
    Library([esi])
    Library([esi])
    assert len(parses) == 1
    assert any((tmp_path / "xdg" / "ecatcfg").rglob("stat.json"))


def test_same_size_same_mtime_rewrite_is_seen(tmp_path, parses):
    """Content changes that keep size and mtime (cp -p, restore tools) still reindex."""
    esi = write(tmp_path, "a.xml", esi_xml(device_xml("AAAA")))
    st = os.stat(esi)
    Library([esi], cache=IndexCache(tmp_path / "c"))
    esi.write_text(esi_xml(device_xml("BBBB")))
    os.utime(esi, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(esi).st_size == st.st_size and os.stat(esi).st_mtime_ns == st.st_mtime_ns
    assert Library([esi], cache=IndexCache(tmp_path / "c")).entries[0].type == "BBBB"
    assert len(parses) == 2


def test_touched_but_unchanged_file_reuses_summary_by_hash(tmp_path, parses):
    esi = write(tmp_path, "a.xml", esi_xml())
    Library([esi], cache=IndexCache(tmp_path / "c"))
    os.utime(esi, ns=(1, 1))
    Library([esi], cache=IndexCache(tmp_path / "c"))
    assert len(parses) == 1


def test_corrupt_or_deleted_cache_is_harmless(tmp_path, parses):
    esi = write(tmp_path, "a.xml", esi_xml())
    Library([esi], cache=IndexCache(tmp_path / "c"))
    for f in (tmp_path / "c").rglob("*.json"):
        f.write_text("{not json")
    assert Library([esi], cache=IndexCache(tmp_path / "c")).entries[0].type == "FX1"
    import shutil
    shutil.rmtree(tmp_path / "c")
    assert Library([esi], cache=IndexCache(tmp_path / "c")).entries[0].type == "FX1"
    assert len(parses) == 3


def test_unwritable_cache_only_costs_speed(tmp_path):
    blocker = write(tmp_path, "c", "a file where the cache folder should be")
    esi = write(tmp_path, "a.xml", esi_xml())
    assert Library([esi], cache=IndexCache(blocker)).entries[0].type == "FX1"
