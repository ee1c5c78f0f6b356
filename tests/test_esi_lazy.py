"""What the reader leaves for later is the same as what it reads at once: a Profile's object
dictionary read on first use, a library file's Device elements read when a device is asked
for, and the lint gate checking only the devices a topology uses.

References independent of the reader: the Object and Device elements lxml finds in the file,
the lines of the fixtures' defects found in their text, and a whole-file lint."""

from __future__ import annotations

import threading
from pathlib import Path

from lxml import etree

from conftest import device_xml, esi_xml, write
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.cache import content_digest
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint.gate import STOPS_COMPILE, file_findings
from ecatcfg.esi.lint.runner import LintOptions, Target, lint_file
from ecatcfg.esi.reader import device_elements, read_bytes, read_file

# An object dictionary with a number the reader cannot take (an ESI002 that stops compile)
# and an element ETG.2000 does not define there (ESI006), each on a line of its own.
_BAD_DICTIONARY = """<Mailbox><CoE/></Mailbox><Profile><ProfileNo>5001</ProfileNo><Dictionary>
<DataTypes><DataType><Name>USINT</Name>
<BitSize>#xZZ</BitSize></DataType></DataTypes>
<Objects><Object><Index>#x2000</Index><Name>a</Name><Type>USINT</Type><BitSize>8</BitSize>
<Bogus/>
</Object><Object><Index>#x2001</Index><Name>b</Name><Type>USINT</Type><BitSize>8</BitSize>
</Object></Objects></Dictionary></Profile>"""
_GOOD_DICTIONARY = """<Mailbox><CoE/></Mailbox><Profile><Dictionary><Objects><Object>
<Index>#x3000</Index><Name>c</Name><Type>USINT</Type><BitSize>8</BitSize></Object>
</Objects></Dictionary></Profile>"""


def _text() -> str:
    return esi_xml(device_xml("GOOD", "#x10", body=_GOOD_DICTIONARY),
                   device_xml("BAD", "#x11", body=_BAD_DICTIONARY))


def _line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


def _number(text: str) -> int:
    text = text.strip()
    return int(text[2:], 16) if text[:2].lower() in ("#x", "0x") else int(text)


def test_a_corpus_dictionary_is_read_on_first_use_object_for_object(corpus):
    path = corpus / "esi" / "beckhoff" / "Beckhoff EL3xxx.xml"
    esi = read_file(path)
    profiles = [p for d in esi.devices for p in d.profiles]
    assert profiles and all(p.dictionary_pending for p in profiles)
    elements = device_elements(xmlsafe.parse_file(path).getroot())
    assert len(elements) == len(esi.devices)
    for dev, el in zip(esi.devices, elements):
        written = {_number(i.text or "") for i in
                   el.iterfind("Profile/Dictionary/Objects/Object/Index")}
        dic = dev.dictionary
        assert dic is not None and set(dic.objects) == written, dev.type_name
        assert {o.source.line for o in dic.objects.values()} <= {
            i.getparent().sourceline for i in
            el.iterfind("Profile/Dictionary/Objects/Object/Index")}
    assert not any(p.dictionary_pending for p in profiles)


def test_problems_of_a_dictionary_not_read_yet_are_the_files(tmp_path):
    text = _text()
    esi = read_bytes(text.encode(), "f.xml")
    assert all(p.dictionary_pending for d in esi.devices for p in d.profiles)
    bad = _line_of(text, "#xZZ")
    assert [(p.source.line, p.kind) for p in esi.problems] == [(bad, "number")]
    assert [(i.source.line, i.tag, i.parent) for i in esi.ignored] == [
        (_line_of(text, "<Bogus/>"), "Bogus", "Object")]
    # Read once: asking again, or for the dictionary itself, adds nothing.
    assert esi.devices[1].dictionary is not None
    assert len(esi.problems) == 1 and len(esi.ignored) == 1
    assert sorted(esi.devices[1].dictionary.objects) == [0x2000, 0x2001]


def test_two_threads_asking_for_one_dictionary_read_it_once(tmp_path):
    esi = read_bytes(_text().encode(), "f.xml")
    profile = esi.devices[1].profiles[0]
    start = threading.Barrier(4)
    got = []

    def ask() -> None:
        start.wait()
        got.append(profile.dictionary)

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 4 and all(d is got[0] for d in got) and got[0] is not None
    assert len(esi.problems) == 1


def test_the_library_reads_only_the_devices_asked_for(corpus):
    path = corpus / "esi" / "beckhoff" / "Beckhoff EL2xxx.xml"
    lib = Library([path], cache=False)
    entry = lib.find("EL2008").entry
    dev = lib.device(entry)
    digest = content_digest(path.read_bytes())
    partial, spans = lib.loaded(path.resolve(), digest, frozenset({dev.source.line}))
    assert partial.devices == [dev]
    elements = device_elements(xmlsafe.parse_file(path).getroot())
    assert dev.source.line == elements[entry.ordinal].sourceline
    assert [first for first, _ in spans.devices] == [el.sourceline for el in elements]
    # The whole file: every Device, in file order, the one read before kept as it was.
    whole = lib.load(lib.files[0])
    assert [d.source.line for d in whole.devices] == [el.sourceline for el in elements]
    assert whole.devices[entry.ordinal] is dev
    assert whole == read_file(path, lib.files[0].shown)


def test_two_threads_asking_the_library_for_one_device_get_one_model(tmp_path):
    path = write(tmp_path, "f.xml", _text())
    lib = Library([path], cache=False)
    start = threading.Barrier(4)
    got = []

    def ask() -> None:
        start.wait()
        got.append(lib.device(lib.entries[1]))

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 4 and all(d is got[0] for d in got)
    whole = lib.load(lib.files[0])
    assert [d.type_name for d in whole.devices] == ["GOOD", "BAD"]
    assert whole.devices[1] is got[0] and len(whole.problems) == 1


def _gate_and_lint(path: Path) -> tuple[Library, list]:
    lib = Library([path], cache=False)
    whole = lint_file(Target(path, lib.files[0].shown, True), LintOptions(STOPS_COMPILE), [])
    assert whole is not None
    return lib, whole.findings


def test_the_gate_on_used_devices_finds_what_lint_of_the_whole_file_finds(tmp_path):
    """Per device: the gate, checking that device alone from the library's partial model,
    gives exactly the whole-file lint's findings inside it (the fixture's ESI002 is in the
    dictionary of the second device)."""
    path = write(tmp_path, "f.xml", _text())
    lib, whole = _gate_and_lint(path)
    bad = _line_of(_text(), "#xZZ")
    assert [(f.rule, f.device.line if f.device else None) for f in whole
            if f.line == bad] == [("ESI002", lib.device(lib.entries[1]).source.line)]
    for entry in lib.entries:
        dev = lib.device(entry)
        lines = frozenset({dev.source.line})
        got = file_findings(path.resolve(), lib.files[0].shown, [], lib.loaded, lines)
        mine = [f for f in got.findings if f.device is not None and f.device.line in lines]
        assert mine == [f for f in whole if f.device is not None and f.device.line in lines]
    assert lib.device(lib.entries[1]).dictionary is not None


def test_the_gate_on_used_devices_agrees_with_lint_over_corpus_files(corpus, corpus_extra):
    for path in (corpus / "esi" / "beckhoff" / "Beckhoff EL3xxx.xml",
                 corpus_extra / "esi" / "pollen" / "Orbita3d.xml"):
        lib, whole = _gate_and_lint(path)
        assert whole or path.name == "Beckhoff EL3xxx.xml"
        for entry in lib.entries[::7] + lib.entries[-1:]:
            lines = frozenset({lib.device(entry).source.line})
            got = file_findings(path.resolve(), lib.files[0].shown, [], lib.loaded, lines)
            assert [f for f in got.findings if f.device and f.device.line in lines] == \
                [f for f in whole if f.device and f.device.line in lines], entry


def test_a_list_of_documents_is_read_whole(tmp_path):
    text = ('<?xml version="1.0"?><EtherCATInfoList>'
            + esi_xml(device_xml("A", "#x10")).split("?>", 1)[1]
            + esi_xml(device_xml("B", "#x11")).split("?>", 1)[1] + "</EtherCATInfoList>")
    path = write(tmp_path, "list.xml", text)
    lib = Library([path], cache=False)
    assert [lib.device(e).type_name for e in lib.entries] == ["A", "B"]
    assert lib.load(lib.files[0]) == read_file(path, lib.files[0].shown)
    assert etree.fromstring(text.encode()).tag == "EtherCATInfoList"


_INIT_MODULE = """    <Modules>
      <Module><Type ModuleIdent="#x33">INITMOD</Type><Name>m</Name>
        <Mailbox><CoE><InitCmd><Transition>PS</Transition><Index>#x8000</Index>
          <SubIndex>0</SubIndex><Data>01020304</Data></InitCmd></CoE></Mailbox>
      </Module>
    </Modules>
"""
_INIT_SLOTS = """        <Slots>
          <Slot MinInstances="0" MaxInstances="1"><Name>S1</Name>
            <ModuleIdent>#x33</ModuleIdent></Slot>
        </Slots>
"""
_UINT_OBJECT = """        <Profile><Dictionary><Objects><Object><Index>#x8000</Index><Name>u</Name>
          <Type>UINT</Type><BitSize>16</BitSize></Object></Objects></Dictionary></Profile>
"""


def test_a_plugged_module_is_checked_against_every_device_of_its_file(tmp_path, capsys):
    """A module's InitCmd is checked against the dictionary of each device of its file that
    takes it (ESI304): here only an unused device says 0x8000 is a UINT, so the gate must
    check the whole file when the topology plugs one of its modules."""
    from ecatcfg.cli import main
    from test_esi_gate import _device, _esi
    text = _esi(_device("STATION", "#x10", slots=_INIT_SLOTS),
                _device("OTHER", "#x11", slots=_INIT_SLOTS + _UINT_OBJECT),
                modules=_INIT_MODULE)
    path = write(tmp_path, "dev.xml", text)
    topo = write(tmp_path, "t.yaml", "slaves:\n  - {name: dut, device: STATION, "
                 "modules: {1: INITMOD}}\n")
    out = tmp_path / "out.xml"
    code = main(["compile", str(topo), "--esi", str(path), "-o", str(out), "--no-cache"])
    err = capsys.readouterr().err
    line = _line_of(text, "<CoE><InitCmd>")
    assert code == 1 and f"dev.xml:{line}: ESI304 " in err, err
