"""The index cache: a second run does not reparse, and it is never stale."""

import os

import pytest

from conftest import FifoUnblock, device_xml, esi_xml, write
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


def _summary_file(cache_dir):
    [found] = [f for f in cache_dir.rglob("*.json") if f.name != "stat.json"]
    return found


@pytest.mark.parametrize("damage", [
    lambda s: s["devices"][0].pop("name"),                      # a record without its name
    lambda s: s["devices"][0].__setitem__("name", 7),           # a value of the wrong type
    lambda s: s["devices"][0].__setitem__("product_code", "16"),
    lambda s: s["devices"][0].__setitem__("rx_pdos", True),     # JSON true is no count
    lambda s: s["devices"][0].__setitem__("mailbox", "CoE"),
    lambda s: s["devices"].__setitem__(0, ["not", "a", "record"]),
    lambda s: s.__setitem__("devices", {}),
    lambda s: s.__setitem__("modules", None),
    lambda s: s.__setitem__("errors", [[1]]),
    lambda s: s.__setitem__("info_references", [3]),
    lambda s: s.pop("vendor_id"),
    lambda s: s.__setitem__("extra", 1),
], ids=["no name", "name int", "product str", "count bool", "mailbox str", "record list",
        "devices dict", "modules null", "error short", "reference int", "no vendor",
        "extra key"])
def test_a_damaged_summary_is_discarded_and_rebuilt(tmp_path, parses, damage):
    """A cache entry that is valid JSON but not a summary (a device record without its
    ``name``, a value of another type) is a miss: the file is summarized again and the entry
    replaced, on this run and the next (it used to be a KeyError in every later run)."""
    import json
    esi = write(tmp_path, "a.xml", esi_xml(device_xml("A", body="<RxPdo><Index>#x1600</Index>"
                                                             "<Name>R</Name></RxPdo>")))
    Library([esi], cache=IndexCache(tmp_path / "c"))
    stored = _summary_file(tmp_path / "c")
    summary = json.loads(stored.read_text())
    damage(summary)
    stored.write_text(json.dumps(summary))
    for _ in range(2):
        entry = Library([esi], cache=IndexCache(tmp_path / "c")).entries[0]
        assert (entry.type, entry.name, entry.product_code, entry.rx_pdos) == \
            ("A", "A name", 0x10, 1)
    assert len(parses) == 2                 # the first run and the one that met the damage
    assert json.loads(stored.read_text())["devices"][0]["name"] == "A name"


def test_a_damaged_stat_record_never_names_another_file(tmp_path, parses):
    """The stat record's digest names the summary file; a damaged one (a path) is a miss."""
    import json
    esi = write(tmp_path, "a.xml", esi_xml(device_xml("A")))
    Library([esi], cache=IndexCache(tmp_path / "c"))
    [stats] = (tmp_path / "c").rglob("stat.json")
    records = json.loads(stats.read_text())
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text(_summary_file(tmp_path / "c").read_text().replace('"A name"',
                                                                         '"planted"'))
    for rec in records.values():
        rec[5] = str(elsewhere.with_suffix(""))
    stats.write_text(json.dumps(records))
    assert Library([esi], cache=IndexCache(tmp_path / "c")).entries[0].name == "A name"
    assert len(parses) == 1                 # the content hash found the good summary again


def test_a_damaged_index_cache_does_not_break_a_command(tmp_path):
    """What a user met: ``ecatcfg devices`` failed with a KeyError traceback on every run
    after one cache entry lost a device's name."""
    import json
    import subprocess
    import sys
    esi = write(tmp_path, "a.xml", esi_xml(device_xml("A")))
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "xdg")}

    def devices():
        return subprocess.run([sys.executable, "-m", "ecatcfg", "devices", str(esi)],
                              capture_output=True, text=True, env=env, timeout=60)
    assert devices().returncode == 0
    stored = _summary_file(tmp_path / "xdg")
    summary = json.loads(stored.read_text())
    del summary["devices"][0]["name"]
    stored.write_text(json.dumps(summary))
    for _ in range(2):
        done = devices()
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
        assert "A name" in done.stdout


def test_a_summary_that_is_a_fifo_is_a_miss_and_replaced(tmp_path, parses):
    """Neither waited on (no writer) nor written into: a new summary is renamed over it."""
    esi = write(tmp_path, "a.xml", esi_xml(device_xml("A")))
    Library([esi], cache=IndexCache(tmp_path / "c"))
    stored = _summary_file(tmp_path / "c")
    stored.unlink()
    os.mkfifo(stored)
    with FifoUnblock(stored) as unblock:
        assert Library([esi], cache=IndexCache(tmp_path / "c")).entries[0].name == "A name"
    assert not unblock.needed, "the cache waited on the FIFO"
    assert stored.is_file()
    assert Library([esi], cache=IndexCache(tmp_path / "c")).entries[0].name == "A name"
    assert len(parses) == 2

