"""Selectors and module-library resolution on self-written fixtures."""

import pytest

from conftest import EXAMPLES, device_xml, esi_xml, write
from ecatcfg.errors import UsageError
from ecatcfg.esi import Library, SelectorError
from ecatcfg.esi.library import parse_selector


@pytest.fixture
def lib(tmp_path):
    write(tmp_path, "a.xml", esi_xml(device_xml("Drive ", "#x10", "#x1"),
                                     device_xml("Drive ", "#x10", "#x3"),
                                     device_xml("Drive ", "#x10", "#x2"),
                                     device_xml("Twin", "#x20", "#x1")))
    sub = tmp_path / "sub"
    sub.mkdir()
    write(sub, "b.xml", esi_xml(device_xml("Twin", "#x21", "#x1"), vendor="#x00E0F1"))
    return Library([tmp_path], cache=False)


def test_selector_syntax():
    assert parse_selector("0x9a:0x30924:0x10420") == (0x9A, 0x30924, 0x10420)
    assert parse_selector("154:199972") == (154, 199972, None)
    assert parse_selector("EK1100") is None and parse_selector("a:b") is None


def test_exact_revision(lib):
    sel = lib.find("0xe0f1:0x10:0x2")
    assert (sel.entry.revision, sel.note) == (2, None)


def test_omitted_revision_takes_highest_and_says_so(lib, tmp_path):
    sel = lib.find("0xE0F1:16")
    assert sel.entry.revision == 3
    # The note names the file and line of the Device element taken (its third in a.xml).
    line = (tmp_path / "a.xml").read_text().splitlines().index(
        device_xml("Drive ", "#x10", "#x3")) + 1
    assert sel.note == (f"no revision given; took 0xe0f1:0x10:0x3 ({tmp_path / 'a.xml'}:{line}), "
                        "the highest of 0x1, 0x2, 0x3")


def test_missing_revision_lists_the_available_ones(lib):
    with pytest.raises(SelectorError, match=r"revision 0x9 of 0xe0f1:0x10 \(Drive\) is not in "
                       r"the library; available: 0xe0f1:0x10:0x1, 0xe0f1:0x10:0x2, 0xe0f1:0x10:0x3"):
        lib.find("0xe0f1:0x10:9")


def test_type_name_is_trimmed_and_takes_highest(lib):
    sel = lib.find("  Drive")
    assert sel.entry.revision == 3 and "highest" in sel.note


def test_ambiguous_name_lists_selectors(lib):
    with pytest.raises(SelectorError) as err:
        lib.find("Twin")
    msg = str(err.value)
    assert "matches 2 products" in msg and "0xe0f1:0x20:0x1" in msg and "0xe0f1:0x21:0x1" in msg
    assert "sub/b.xml" in msg


def test_unknown_name_suggests_close_matches(lib):
    with pytest.raises(SelectorError, match="closest: Drive"):
        lib.find("Driv")


def test_unknown_product(lib):
    with pytest.raises(SelectorError, match=r"no device 0xe0f1:0x99:\? in the library"):
        lib.find("0xe0f1:0x99")


def test_device_model_is_loaded_on_demand(lib):
    dev = lib.device("0xe0f1:0x10:0x2")
    assert dev.revision == 2 and dev.vendor.id == 0xE0F1


def test_missing_path_is_a_usage_error(tmp_path):
    with pytest.raises(UsageError, match="no such file or folder"):
        Library([tmp_path / "nope"], cache=False)


def test_non_esi_xml_in_a_folder_is_skipped_but_named_file_is_an_error(tmp_path):
    write(tmp_path, "eni.xml", "<EtherCATConfig/>")
    write(tmp_path, "dev.xml", esi_xml())
    lib = Library([tmp_path], cache=False)
    assert len(lib.entries) == 1 and lib.problems == [] and lib.skipped
    lib = Library([tmp_path / "eni.xml"], cache=False)
    assert "root element is <EtherCATConfig>" in str(lib.problems[0])


MODULE_LIB = """<?xml version="1.0"?>
<EtherCATModule Version="1.12"><Vendor><Id>#x00E0F1</Id><Name>V</Name></Vendor><Modules>
<Module><Type ModuleIdent="#x1111" ModuleClass="DI">M-DI</Type><Name>DI module</Name>
<TxPdo Fixed="1" Sm="3"><Index DependOnSlot="1">#x1A00</Index><Name>In</Name>
<Entry><Index DependOnSlot="1">#x6000</Index><SubIndex>1</SubIndex><BitLen>1</BitLen>
<Name>DI1</Name><DataType>BOOL</DataType></Entry></TxPdo></Module></Modules></EtherCATModule>
"""


def test_info_reference_resolved_beside_the_file_or_warned(tmp_path):
    slots = ('<Slots SlotIndexIncrement="16" SlotPdoIncrement="1"><Slot MinInstances="1" '
             'MaxInstances="8"><ModuleIdent Default="1">#x1111</ModuleIdent></Slot></Slots>')
    xml = esi_xml(device_xml("Coupler", body=slots)).replace(
        "<Vendor>", "<InfoReference>Mods\\lib.xml</InfoReference><Vendor>")
    write(tmp_path, "coupler.xml", xml)
    lib = Library([tmp_path], cache=False)
    assert [ref for _, ref in lib.unresolved_references()] == ["Mods\\lib.xml"]
    assert lib.entries[0].modules == 0
    write(tmp_path, "lib.xml", MODULE_LIB)            # beside it, not in Mods\
    lib = Library([tmp_path], cache=False)
    assert lib.unresolved_references() == []
    entry = lib.find("Coupler").entry
    assert entry.slots == 1 and entry.modules == 1
    module = lib.modules_for(entry)[0x1111]
    assert module.tx_pdos[0].depend_on_slot and module.tx_pdos[0].entries[0].depend_on_slot
    assert lib.device(entry).slots.slots[0].default_ident == 0x1111


def test_examples_are_a_valid_library():
    lib = Library([EXAMPLES], cache=False)
    assert {e.type for e in lib.entries} == {"EX1100", "EX1004", "EX1008", "EX2008", "EXD-402",
                                              "EXM100", "EXB1100", "EXB1122", "EXB1018",
                                              "EXB2018"}
    assert lib.problems == []


def test_examples_validate_against_the_etg_schema(esi_schema):
    from lxml import etree
    paths = sorted(EXAMPLES.glob("esi/*.xml"))
    assert len(paths) == 3
    for path in paths:
        assert esi_schema.validate(etree.parse(str(path))), esi_schema.error_log


def test_bad_vendor_id_in_a_module_library_is_reported(tmp_path):
    write(tmp_path, "lib.xml", MODULE_LIB.replace("<Id>#x00E0F1</Id>", "<Id>#xQQ</Id>"))
    lib = Library([tmp_path], cache=False)
    problem, = lib.problems
    assert problem.file.endswith("lib.xml") and problem.line == 2
    assert "Vendor/Id" in problem.message and "#xQQ" in problem.message
