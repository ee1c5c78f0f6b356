"""Slot groups (ETG.2000 ``Slots/SlotGroupData``, ``Slot/@SlotGroup``,
``Index@DependOnSlotGroup``, ``SlotGroupPdoIncrement``, ``SlotGroupIndexIncrement``):
compiled, linted and emulated from the ESI with the same indices.

The rule, from the ETG schemas' own words (the ENI schema's annotations of
``Index@DependOnSlotGroup``: the index "will be adapted depend on the slot group number and
the SlotGroupIndexIncrement value in the Slots-part of the device description"; the ESI
schema puts both increments on ``Slots`` and on ``Slot``): an index marked
``DependOnSlotGroup`` moves by the slot group number x the group increment, one marked
``DependOnSlot`` by (position - 1) x the slot increment, one marked both by both.

The fixture ``fixtures/ecatcfg-EXG-slot-groups.xml`` (self-written, two slot groups) and the
indices below were worked out by hand from that rule:

    Slots: SlotPdoIncrement 1, SlotIndexIncrement 0x10,
           SlotGroupPdoIncrement 0x20, SlotGroupIndexIncrement 0x800
    slot 1 "Axis A", group 1, position 1: slot offsets 0 / 0, group offsets 0x20 / 0x800
    slot 2 "Axis B", group 2, position 2: slot offsets 1 / 0x10, group offsets 0x40 / 0x1000
    slot 3 "Axis B option", group 2 with its own SlotGroupIndexIncrement 0x400, position 3:
           slot offsets 2 / 0x20, group offsets 0x40 / 0x800

    EXG-AXIS  RxPdo 0x1600 (DependOnSlot)        -> 0x1600, 0x1601
              its Exclude 0x1700 (DependOnSlotGroup, its own mark) -> 0x1720, 0x1740
              entry 0x5840 (DependOnSlotGroup)   -> 0x6040, 0x6840
              RxPdo 0x1700 (DependOnSlotGroup, no Sm: not assigned) -> 0x1720, 0x1740
              its Exclude 0x1600 (DependOnSlot)  -> 0x1600, 0x1601
              TxPdo 0x1A00 (DependOnSlotGroup)   -> 0x1A20, 0x1A40
              entry 0x5841 (DependOnSlotGroup)   -> 0x6041, 0x6841
              entry 0x5000 (DependOnSlot)        -> 0x5000, 0x5010
              entry 0x2000 (fixed)               -> 0x2000, 0x2000
              InitCmd 0x5860 (DependOnSlotGroup) -> 0x6060, 0x6860
    EXG-OPTION TxPdo 0x1A00 (both)               -> 0x1A00 + 2 + 0x40  = 0x1A42
              entry 0x5100 (both)                -> 0x5100 + 0x20 + 0x800 = 0x5920
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint import LintOptions, Target, lint_file, select_rules
from ecatcfg.esi.reader import read_file as read_esi
from ecatcfg.runtime.network import Network

FIXTURE = Path(__file__).with_name("fixtures") / "ecatcfg-EXG-slot-groups.xml"
WITH_OPTION = "slaves:\n  - name: s\n    device: EXG8200\n    modules: {3: [EXG-OPTION]}\n"

# (PDO index, its Excludes, its entries' indices) in ESI order, module by module, from the
# table above.
PDOS = [(0x1600, [0x1720], [0x6040]), (0x1720, [0x1600], [0x6040]),
        (0x1A20, [], [0x6041, 0x5000, 0x2000]),
        (0x1601, [0x1740], [0x6840]), (0x1740, [0x1601], [0x6840]),
        (0x1A40, [], [0x6841, 0x5010, 0x2000]), (0x1A42, [], [0x5920])]


def _hex(text: str | None) -> int:
    text = (text or "").strip()
    return int(text[2:], 16) if text[:2] in ("#x", "0x") else int(text)


def _eni(esi: Path, text: str = WITH_OPTION) -> bytes:
    result = build.compile_topology(topology.loads(text, "t.yaml"),
                                    Library([esi], cache=False))
    return eni_writer.to_bytes(result.plan)


def test_the_fixture_is_valid_etg2000(esi_schema):
    assert esi_schema.validate(etree.parse(str(FIXTURE))), esi_schema.error_log


def test_the_reader_keeps_the_group_data():
    esi = read_esi(FIXTURE)
    [dev] = esi.devices
    assert dev.slots is not None
    assert [(g.number, g.name) for g in dev.slots.groups] == [(1, "Axis A"), (2, "Axis B")]
    assert [s.slot_group for s in dev.slots.slots] == [1, 2, 2]
    assert (dev.slots.slot_group_pdo_increment, dev.slots.slot_group_index_increment) \
        == (0x20, 0x800)
    assert [s.slot_group_index_increment for s in dev.slots.slots] == [None, None, 0x400]
    text = FIXTURE.read_text(encoding="utf-8").splitlines()
    assert "SlotGroupData" in text[dev.slots.groups[1].source.line - 1]


def test_compile_moves_the_indices_by_slot_group():
    """The ENI's PDO list, assignment and InitCmds, read with lxml, are the hand-computed
    indices of the module docstring."""
    eni = etree.fromstring(_eni(FIXTURE))
    pdos = [(_hex(p.findtext("Index")), [_hex(x.text) for x in p.iter("Exclude")],
             [_hex(e.findtext("Index")) for e in p.iter("Entry")])
            for p in eni.iter("RxPdo", "TxPdo")]
    assert pdos == PDOS
    coe = [(_hex(c.findtext("Index")), _hex(c.findtext("SubIndex")), c.findtext("Data"))
           for c in eni.iterfind(".//Mailbox/CoE/InitCmds/InitCmd")]
    assign = [int.from_bytes(bytes.fromhex(d or ""), "little") for i, s, d in coe
              if i in (0x1C12, 0x1C13) and s]
    assert assign == [0x1600, 0x1601, 0x1A20, 0x1A40, 0x1A42]
    modes = [(i, d) for i, s, d in coe if i & 0xFF == 0x60 and i >= 0x5000]
    assert modes == [(0x6060, "08"), (0x6860, "08")]


def test_the_emulation_from_the_esi_has_the_moved_objects_and_reaches_op(tmp_path):
    """The virtual segment builds the station from the ESI and the ENI's module ident list
    (0xF030): its dictionary holds the objects where the table puts them, not at the
    modules' base indices, and the InitCmds of both axes found their objects."""
    eni = tmp_path / "eni.xml"
    eni.write_bytes(_eni(FIXTURE))
    with Network.virtual(eni, esi=[FIXTURE], esi_cache=False) as net:
        slave = net.segment.slaves[0]
        assert slave.eni_only is None
        net.up(AlState.OP)
        assert net.state == AlState.OP
        od = slave.od
        assert {0x6040, 0x6041, 0x6060, 0x6840, 0x6841, 0x6860, 0x5000, 0x5010} <= \
            set(od.objects)
        assert not {0x5840, 0x5841, 0x5860} & set(od.objects)
        assert (od.int_value(0x6060, 0), od.int_value(0x6860, 0)) == (8, 8)
        assert [e[0] for e in od.tx_entries(3)] == [0x6041, 0x5000, 0x2000, 0x6841, 0x5010,
                                                    0x2000, 0x5920]


def _without_group(tmp_path: Path) -> tuple[Path, int]:
    """The fixture with slot 1 in no slot group; the line of its module's first
    DependOnSlotGroup index."""
    text = FIXTURE.read_text(encoding="utf-8").replace(
        '<Slot MinInstances="1" MaxInstances="1" SlotGroup="1">',
        '<Slot MinInstances="1" MaxInstances="1">')
    assert text != FIXTURE.read_text(encoding="utf-8")
    esi = tmp_path / "ungrouped.xml"
    esi.write_text(text, encoding="utf-8")
    line = next(n for n, ln in enumerate(text.splitlines(), start=1)
                if 'DependOnSlotGroup="1">#x5840' in ln)
    return esi, line


def test_a_group_index_in_a_slot_of_no_group_is_an_error_naming_file_and_line(tmp_path):
    esi, line = _without_group(tmp_path)
    with pytest.raises(TopologyError) as err:
        _eni(esi, "slaves:\n  - name: s\n    device: EXG8200\n")
    message = str(err.value)
    assert f"{esi}:{line}" in message and "slot 1 (Axis A)" in message, message
    assert "DependOnSlotGroup" in message


def _lint(path: Path) -> list[tuple[str, str, int]]:
    result = lint_file(Target(path, str(path), True), LintOptions(select_rules(None, None)),
                       [])
    assert result is not None
    return [(f.rule, f.severity, f.line) for f in result.findings]


def test_lint_reports_the_ungrouped_slot_and_nothing_on_the_fixture(tmp_path):
    assert _lint(FIXTURE) == []
    esi, _ = _without_group(tmp_path)
    slot_line = next(n for n, ln in enumerate(esi.read_text().splitlines(), start=1)
                     if "<Slot " in ln)
    assert ("ESI604", "error", slot_line) in _lint(esi)


def test_a_slot_group_without_its_number_is_a_read_error_at_its_line(tmp_path):
    text = FIXTURE.read_text(encoding="utf-8").replace('<SlotGroupData SlotGroup="2">',
                                                       "<SlotGroupData>")
    esi = tmp_path / "nonumber.xml"
    esi.write_text(text, encoding="utf-8")
    line = next(n for n, ln in enumerate(text.splitlines(), start=1)
                if "<SlotGroupData>" in ln)
    problems = read_esi(esi).problems
    assert [(p.source.line, p.severity) for p in problems] == [(line, "error")]


def test_compile_cli_writes_the_group_indices(tmp_path):
    """The same through ``ecatcfg compile`` (what a user runs)."""
    topo = tmp_path / "t.yaml"
    topo.write_text(WITH_OPTION)
    out = tmp_path / "out.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(FIXTURE), "-o", str(out)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    eni = etree.parse(str(out)).getroot()
    assert [_hex(p.findtext("Index")) for p in eni.iter("RxPdo", "TxPdo")] == \
        [i for i, _, _ in PDOS]


# -- the corpus devices with slot groups -------------------------------------------------------

def test_every_corpus_device_with_slot_groups_reaches_op_on_its_own_emulation(
        corpus: Path, corpus_extra: Path):
    """Every device of both corpora whose Slots put a slot in a slot group (Beckhoff's
    EL6900/EL6930 TwinSAFE logic terminals, EP1908, ELX31xx/ELX4181, EL67xx, BK1150: 31
    when written), compiled alone with its default modules and brought to OP on the
    virtual segment built from its ESI (``tests/sweep.py``, as the device sweep does)."""
    import sweep

    corpora = {"corpus": corpus, "corpus-extra": corpus_extra}
    worker = sweep.Worker(corpora)
    grouped = []
    for case in sweep.cases(corpora):
        if not case.slots:
            continue
        lib = worker.library(case)
        [entry] = [e for e in lib.entries if e.ordinal == case.ordinal
                   and e.file == lib.files[0].shown]
        dev = lib.device(entry)
        if dev.slots is not None and any(s.slot_group is not None for s in dev.slots.slots):
            grouped.append(case)
    assert len(grouped) >= 31
    assert {"EL6900", "EL6930", "EP1908"} <= {c.type for c in grouped}
    results = [worker.run(c) for c in grouped]
    bad = [f"{r.key} ({r.type}): {r.outcome}: {r.message}" for r in results
           if r.outcome != "op"]
    assert not bad, "\n".join(bad)


def test_show_gives_each_slot_its_group():
    import json
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "show", str(FIXTURE), "--device",
                           "EXG8200", "--format", "json"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)
    slots = etree.parse(str(FIXTURE)).getroot().iter("Slot")
    assert [s["slot_group"] for s in shown["slots"]] == [_hex(s.get("SlotGroup")) for s in slots]


def test_an_index_moved_out_of_its_range_is_an_error_naming_the_esi_line(tmp_path):
    """Slot group 60 moves the axis TxPDO 0x1A00 by 60 x 0x20 to 0x2180, past the TxPDO
    mappings 0x1A00-0x1BFF, and the InitCmd 0x5860 by 60 x 0x800 to 0x23860, past 16 bits
    (ETG.1000.6): errors at the ESI lines, never an ENI with those indices."""
    text = FIXTURE.read_text(encoding="utf-8").replace(
        '<Slot MinInstances="1" MaxInstances="1" SlotGroup="2">',
        '<Slot MinInstances="1" MaxInstances="1" SlotGroup="60">')
    esi = tmp_path / "far.xml"
    esi.write_text(text, encoding="utf-8")
    lines = text.splitlines()
    tx = next(n for n, ln in enumerate(lines, start=1) if "<TxPdo" in ln)
    init = next(n for n, ln in enumerate(lines, start=1) if "<InitCmd>" in ln)
    with pytest.raises(TopologyError) as err:
        _eni(esi, "slaves:\n  - name: s\n    device: EXG8200\n")
    message = str(err.value)
    assert f"TxPdo 0x1A00 at {esi}:{tx} is 0x2180 in slot 2" in message, message
    assert f"InitCmd of Module 2 (Axis) at {esi}:{init}" in message and "0x23860" in message
