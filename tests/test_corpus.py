"""Every real vendor file in ../shared/corpus/esi loads, and what we count agrees with an
independent XPath count done here on the raw XML."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from ecatcfg.esi import Library, read_file


def corpus_files(corpus: Path) -> list[Path]:
    return sorted(p for p in (corpus / "esi").rglob("*") if p.suffix.lower() == ".xml")


def xpath_counts(path: Path) -> list[tuple[int, int, int, int]]:
    tree = etree.parse(str(path))
    devices = tree.xpath("/*[local-name()='EtherCATInfo']/*[local-name()='Descriptions']"
                         "/*[local-name()='Devices']/*[local-name()='Device']")
    return [(int(d.xpath("count(*[local-name()='RxPdo'])")),
             int(d.xpath("count(*[local-name()='TxPdo'])")),
             int(d.xpath("count(*[local-name()='RxPdo']/*[local-name()='Entry'])")),
             int(d.xpath("count(*[local-name()='TxPdo']/*[local-name()='Entry'])")))
            for d in devices]


def test_corpus_has_the_files_the_issue_names(corpus):
    files = corpus_files(corpus)
    assert len(files) == 29
    names = {p.name for p in files}
    assert {"Weidmueller_UR20_FBC.xml", "Weidmueller_UR20_IO.xml", "Beckhoff EL2xxx.xml"} <= names


def test_every_corpus_file_loads_into_the_model_with_matching_counts(corpus):
    total = 0
    for path in corpus_files(corpus):
        esi = read_file(path)
        assert [p for p in esi.problems if p.severity == "error"] == [], path
        expected = xpath_counts(path)
        got = [(len(d.rx_pdos), len(d.tx_pdos), sum(len(p.entries) for p in d.rx_pdos),
                sum(len(p.entries) for p in d.tx_pdos)) for d in esi.devices]
        assert got == expected, path.name
        for d in esi.devices:
            assert d.product_code is not None and d.revision is not None, d.source
            assert d.vendor.id is not None
        total += len(esi.devices)
    assert total == 363      # MANIFEST.md's Device entries, summed


def test_devices_json_over_the_corpus_matches_xpath(corpus, tmp_path):
    out = subprocess.run([sys.executable, "-m", "ecatcfg", "devices", "--format", "json",
                          str(corpus / "esi")], capture_output=True, text=True, check=True)
    listed = json.loads(out.stdout)["devices"]
    by_file: dict[str, list[tuple[int, int, int, int]]] = {}
    for d in listed:
        assert isinstance(d["vendor_id"], int) and isinstance(d["line"], int)
        by_file.setdefault(d["file"], []).append(
            (d["rx_pdos"], d["tx_pdos"], d["rx_entries"], d["tx_entries"]))
    for path in corpus_files(corpus):
        shown = str(corpus / "esi" / path.relative_to(corpus / "esi"))
        assert by_file.get(shown, []) == xpath_counts(path), path.name


def test_modular_coupler_finds_its_module_library_by_file_name(corpus):
    lib = Library([corpus / "esi" / "modular"], cache=False)
    entry = lib.find("UR20-FBC-EC").entry
    # The reference is the Windows path UR20-IO-Modules\Weidmueller_UR20_IO.xml; the file
    # lies beside the coupler's file instead.
    lf = lib._file(entry.file)
    assert lf.summary.info_references == ["UR20-IO-Modules\\Weidmueller_UR20_IO.xml"]
    modules = lib.modules_for(entry)
    ur20_io = etree.parse(str(corpus / "esi/modular/Weidmueller_UR20_IO.xml"))
    own = etree.parse(str(corpus / "esi/modular/Weidmueller_UR20_FBC.xml"))
    assert len(modules) == len(ur20_io.xpath("//Module")) + len(own.xpath("//Modules/Module"))
    assert entry.modules == len(modules) and entry.slots == 1
    dev = lib.device(entry)
    assert dev.slots.slot_index_increment == 16 and dev.slots.slot_pdo_increment == 1
    assert lib.unresolved_references() == []


def test_modules_and_slots_of_a_drive(corpus):
    esi = read_file(corpus / "esi/drives/Copley_XE2_4.60.xml")
    dev, = esi.devices
    assert len(dev.slots.slots) == 2 and dev.slots.slot_index_increment == 0x800
    assert dev.slots.slots[0].default_ident == 0x10B00100
    assert dev.slots.slots[0].module_idents[:2] == [0x10B00100, 0x10B00200]
    assert {m.ident for m in esi.modules} >= {0x10B00100, 0x10B00200}
    # the known bad hexBinary "2" is a warning with its line, not a failure
    assert any("DefaultData" in p.message and p.source.line > 0 for p in esi.problems)


def test_type_name_with_trailing_space_matching_two_products_lists_them(corpus):
    from ecatcfg.esi import SelectorError
    lib = Library([corpus / "esi/drives"], cache=False)
    with pytest.raises(SelectorError) as err:
        lib.find("Elmo Drive")          # the file writes "Elmo Drive " (trailing space)
    msg = str(err.value)
    assert "matches 2 products" in msg
    for selector in ("0x9a:0x30924:0x10420", "0x9a:0x30925:0x10420", "0x9a:0x30924:0x1"):
        assert selector in msg
    assert lib.device(lib.find("0x9a:0x30924").entry).revision == 0x10420


def test_dictionary_of_a_real_drive(corpus):
    path = corpus / "esi/drives/Elmo_ECAT_00010420_V11.xml"
    devices = read_file(path).devices
    tree = etree.parse(str(path))
    for dev, el in zip(devices, tree.xpath("//Devices/Device"), strict=True):
        indices = {int(o.findtext("Index").replace("#x", ""), 16)
                   for o in el.xpath("Profile/Dictionary/Objects/Object")}
        assert set(dev.dictionary.objects) == indices
    gold = devices[-1]
    assert gold.dictionary.objects[0x6040].flags.pdo_mapping in ("R", "RT", "TR")
    assert gold.dictionary.objects[0x6041].flags.access.value == "ro"
