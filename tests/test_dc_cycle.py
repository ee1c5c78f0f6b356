"""What an ESI says of the SYNC0 cycle (``esi/dc_cycle.py``), read from real vendor files
and checked against the same files read with lxml by the test: the minimum cycle time of
the SyncManager parameter objects (0x1C32:05 / 0x1C33:05 "Minimum cycle time",
``DefaultData`` little-endian, ETG.1020) and each SYNC0 op mode's ``CycleTimeSync0`` with
its ``Factor`` (ETG.2000)."""

from __future__ import annotations

import pytest
from lxml import etree

from ecatcfg.esi.dc_cycle import min_cycle_time, sync0_rules, sync_cycle
from ecatcfg.esi.library import Library


def _int(text: str) -> int:
    text = text.strip()
    return int(text[2:], 16) if text.startswith("#x") else int(text)


def _devices(path):  # type: ignore[no-untyped-def]
    """(Device element line, Device element) of a file, read with lxml."""
    tree = etree.parse(str(path))
    return {d.sourceline: d for d in tree.iter("Device")}


def _expected_min(device: etree._Element) -> int | None:
    values = []
    for obj in device.iter("Object"):
        index = obj.findtext("Index")
        if index is None or _int(index) not in (0x1C32, 0x1C33):
            continue
        for item in obj.findall("Info/SubItem"):
            if (item.findtext("Name") or "").strip().lower() == "minimum cycle time":
                data = item.findtext("Info/DefaultData")
                if data:
                    values.append(int.from_bytes(bytes.fromhex(data.strip()), "little"))
    values = [v for v in values if v]
    return max(values) if values else None


@pytest.mark.parametrize("name", ["beckhoff/Beckhoff EL1xxx.xml",
                                  "beckhoff/Beckhoff EL7xxx.xml",
                                  "drives/C5-E-2-21.xml"])
def test_min_cycle_time_and_sync0_op_modes_as_the_files_give_them(corpus, name):
    path = corpus / "esi" / name
    lib = Library([path], cache=False)
    elements = _devices(path)
    with_min = with_rules = 0
    for entry in lib.entries:
        element = elements[entry.line]
        device = lib.device(entry)
        found = min_cycle_time(device)
        expected = _expected_min(element)
        assert (found.ns if found else None) == expected, (entry.type, found, expected)
        with_min += expected is not None
        want = []
        for mode in element.findall("Dc/OpMode"):
            activate = mode.findtext("AssignActivate")
            if activate is None or _int(activate) & 0x0300 != 0x0300:
                continue
            cycle = mode.find("CycleTimeSync0")
            factor = int(cycle.get("Factor")) if cycle is not None and cycle.get("Factor") \
                else 0
            value = _int(cycle.text) if cycle is not None and cycle.text else 0
            want.append((mode.findtext("Name"), factor or None,
                         None if factor else (value or None)))
        got = [(r.mode, r.factor, r.fixed_ns) for r in sync0_rules(device)]
        assert got == want, entry.type
        with_rules += bool(want)
    assert with_min + with_rules > 0          # the file says something of it


def test_a_factor_multiplies_or_divides_the_bus_cycle_and_a_value_is_fixed():
    assert sync_cycle(0, 1, 1_000_000) == 1_000_000
    assert sync_cycle(0, 4, 250_000) == 1_000_000
    assert sync_cycle(0, -8, 1_000_000) == 125_000          # EL3702-style oversampling
    assert sync_cycle(250_000, None, 1_000_000) == 250_000
    assert sync_cycle(250_000, 0, 1_000_000) == 250_000
    assert sync_cycle(0, None, 1_000_000) is None
