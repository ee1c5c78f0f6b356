"""Each figure of a timing file sets its own time and no other, up to the 10-minute bound;
a device with the CiA 402 control and status words in its PDOs is a drive even when its ESI
names no profile 402 (runtime/segment/timing.py: the kinds and the overrides)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import EXAMPLES
from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment import timing
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

DRIVE_ESI = EXAMPLES / "esi" / "ecatcfg-EXD402-drive.xml"


def _load(tmp_path: Path, raw: object) -> timing.Timing:
    path = tmp_path / "timing.json"
    path.write_text(json.dumps(raw), encoding="utf-8")
    return timing.load(path)


@pytest.mark.parametrize("key, field, ms, ns", [
    ("eeprom_read_ms", "eeprom_read_ns", 1.25, 1_250_000),
    ("eeprom_write_ms", "eeprom_write_ns", 4, 4_000_000),
    ("mailbox_reply_ms", "mailbox_reply_ns", 0.5, 500_000),
])
def test_each_figure_sets_its_own_time_and_no_other(tmp_path, key, field, ms, ns):
    model = _load(tmp_path, {"firmware": {key: ms}})
    firmware = model.kinds["firmware"]
    assert getattr(firmware, field) == ns
    table = timing.TABLE["firmware"]
    for other in ("eeprom_read_ns", "eeprom_write_ns", "mailbox_reply_ns", "state_change_ns"):
        if other != field:
            assert getattr(firmware, other) == getattr(table, other), other


def test_ten_minutes_is_the_longest_time_accepted(tmp_path):
    model = _load(tmp_path, {"drive": {"eeprom_write_ms": 600_000}})
    assert model.kinds["drive"].eeprom_write_ns == 600_000 * 1_000_000
    with pytest.raises(EcatcfgError, match=r"timing.json: 'drive': eeprom_write_ms: "
                                           r"600000.5 is not a time in ms \(0 to 600000\)"):
        _load(tmp_path, {"drive": {"eeprom_write_ms": 600_000.5}})


def test_an_unknown_figure_is_refused_with_the_figures_there_are(tmp_path):
    with pytest.raises(EcatcfgError) as exc:
        _load(tmp_path, {"esc": {"eeprom_read": 1}})
    assert str(exc.value).endswith(
        "'esc': unknown key 'eeprom_read' (mailbox_reply_ms, reply_start_ms, "
        "eeprom_read_ms, eeprom_write_ms, state_change_ms)")


def _kind_without_profile_402(tmp_path: Path, words: bool) -> str:
    """The example drive with its profile renumbered (5001, a modular device profile), and
    with or without 0x6040/0x6041 in its PDOs (renamed to 0x2040/0x2041 objects)."""
    text = DRIVE_ESI.read_text(encoding="utf-8")
    assert "<ProfileNo>402</ProfileNo>" in text
    text = text.replace("<ProfileNo>402</ProfileNo>", "<ProfileNo>5001</ProfileNo>")
    if not words:
        text = text.replace("#x6040", "#x2040").replace("#x6041", "#x2041")
    path = tmp_path / ("words" if words else "none") / DRIVE_ESI.name
    path.parent.mkdir()
    path.write_text(text, encoding="utf-8")
    lib = Library([path.parent], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry))])
    return timing.kind_of(seg.slaves[0])


def test_the_control_and_status_words_make_a_drive_without_its_profile(tmp_path):
    assert _kind_without_profile_402(tmp_path, words=True) == "drive"
    assert _kind_without_profile_402(tmp_path, words=False) == "firmware"
