"""Module ident lists only where the ESI asks, and no CoE download the dictionary refuses.

A modular device's configured module ident list (0xF030, ETG.5001) is downloaded only when
its ESI says ``Slots@DownloadModuleIdentList``, never because the dictionary has the object;
a download the dictionary declares read-only in the state it runs in is never written (the
ESI's own InitCmds, the module ident list, PDO assignment, user SDOs); a module's own CoE
InitCmds are written after the device's and linted like them.

The fixture (tests/fixtures/ecatcfg-EXK-coupler.xml) is self-written; expectations (module
idents, lines, data) are read from it with lxml, the emulated slave answers as its
dictionary says, and the ETG.2000 schema checks the fixture.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from conftest import FIXTURES
from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.esi.lint import LintOptions, Target, lint_file, select_rules
from ecatcfg.runtime.network import Network
from ecatcfg.runtime.master.replay import ApplyError
from lint_fixtures import drive, esi, init_cmd, marked_line

COUPLER = FIXTURES / "ecatcfg-EXK-coupler.xml"
MODULES = ["EXK-4DI", "EXK-2AO", "EXK-4DI"]
TOPOLOGY = ("slaves:\n  - name: io\n    device: EXK1100\n    modules: {1: [" +
            ", ".join(MODULES) + "]}\n")


def coupler(tmp_path: Path, *, ask: bool, access: str = "rw",
            transition: str | None = None, room: int = 4) -> Path:
    """The fixture with ``DownloadModuleIdentList`` (``ask``), every subindex of 0xF030 of
    ``access``, ``DownloadModuleListTransition`` when given, and ``room`` positions in the
    module ident lists (the fixture has 4)."""
    text = COUPLER.read_text(encoding="utf-8")
    text = text.replace("<Elements>4</Elements>", f"<Elements>{room}</Elements>").replace(
        '<BitSize>128</BitSize>', f"<BitSize>{32 * room}</BitSize>").replace(
        "<BitSize>144</BitSize>", f"<BitSize>{16 + 32 * room}</BitSize>")
    if ask:
        extra = f' DownloadModuleListTransition="{transition}"' if transition else ""
        text = text.replace("<Slots ", f'<Slots DownloadModuleIdentList="true"{extra} ')
    start = text.index("<Name>DTF030</Name>")
    end = text.index("</DataType>", start)
    text = text[:start] + text[start:end].replace("<Access>rw</Access>",
                                                  f"<Access>{access}</Access>") + text[end:]
    path = tmp_path / f"coupler-{ask}-{access}-{transition}-{room}.xml"
    path.write_text(text, encoding="utf-8")
    return path


def compile_with(esi_path: Path, text: str = TOPOLOGY, allow_esi_errors: bool = False
                 ) -> NetworkPlan:
    plan = build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library([esi_path], cache=False), allow_esi_errors).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "t.eni.xml")


def idents_of(path: Path, names: list[str]) -> list[int]:
    """The ModuleIdent of each named module, read from the file with lxml."""
    root = etree.parse(str(path)).getroot()
    by_name = {m.findtext("Type").strip(): int(m.find("Type").get("ModuleIdent")[2:], 16)
               for m in root.iter("Module")}
    return [by_name[n] for n in names]


def line_of(path: Path, xpath: str) -> int:
    return etree.parse(str(path)).getroot().xpath(xpath)[0].sourceline


def f030(plan: NetworkPlan) -> list:
    return [c for c in plan.slaves[0].mailbox.coe_init_cmds if c.index == 0xF030]


def two_single_slots(tmp_path: Path) -> Path:
    """The fixture asking for the ident list, its one slot for a row of modules replaced by
    two slots of one module each, both optional and without a default module (as a drive
    with two axis slots, either of which may stay empty)."""
    text = coupler(tmp_path, ask=True).read_text(encoding="utf-8")
    start = text.index("<Slot ")
    end = text.index("</Slot>", start) + len("</Slot>")
    classes = "".join(re.findall(r"<ModuleClass>.*?</ModuleClass>", text[start:end]))
    slots = "".join(f'<Slot MinInstances="0" MaxInstances="1"><Name LcId="1033">{name}'
                    f"</Name>{classes}</Slot>" for name in ("Left", "Right"))
    path = tmp_path / "coupler-two-slots.xml"
    path.write_text(text[:start] + slots + text[end:], encoding="utf-8")
    return path


def test_fixture_is_valid_etg2000(esi_schema, tmp_path):
    for path in (COUPLER, coupler(tmp_path, ask=True, access="ro", transition="IP"),
                 two_single_slots(tmp_path)):
        assert esi_schema.validate(etree.parse(str(path))), esi_schema.error_log


def test_a_dictionary_with_0xf030_but_no_attribute_gets_no_ident_list(tmp_path):
    path = coupler(tmp_path, ask=False)
    plan = compile_with(path)
    assert f030(plan) == []
    with Network.virtual(plan, esi=[path], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        # Nothing downloaded it: the emulated station's list holds no ident.
        od = net.segment.slaves[0].od
        assert [od.int_value(0xF030, n) for n in range(1, len(MODULES) + 1)] \
            == [0] * len(MODULES)


@pytest.mark.parametrize("transition", [None, "IP"])
def test_the_attribute_gets_the_ident_list_in_its_transition(tmp_path, transition):
    path = coupler(tmp_path, ask=True, transition=transition)
    plan = compile_with(path)
    cmds = f030(plan)
    idents = idents_of(COUPLER, MODULES)
    assert [(c.subindex, c.complete_access, [t.value for t in c.transitions]) for c in cmds] \
        == [(0, True, [transition or "PS"])]
    assert cmds[0].data == bytes([len(idents), 0]) + b"".join(
        i.to_bytes(4, "little") for i in idents)
    with Network.virtual(plan, esi=[path], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        od = net.segment.slaves[0].od
        assert [od.int_value(0xF030, n) for n in range(len(idents) + 1)] \
            == [len(idents)] + idents


def test_a_read_only_ident_list_without_the_attribute_is_not_written(tmp_path):
    path = coupler(tmp_path, ask=False, access="ro")
    plan = compile_with(path)
    assert f030(plan) == []
    with Network.virtual(plan, esi=[path], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP


def test_a_read_only_ident_list_asked_for_is_a_compile_error_naming_the_esi_line(tmp_path):
    path = coupler(tmp_path, ask=True, access="ro")
    with pytest.raises(TopologyError) as err:
        compile_with(path)
    text = str(err.value)
    slots_line = line_of(path, "//Device/Slots")
    assert f"{path}:{slots_line}" in text and "t.yaml:4" in text, text
    assert "0xF030:00" in text and "PreOp" in text and "PS" in text and "'ro'" in text
    # The command line: exit 1, the message, no traceback, no ENI written.
    topo = tmp_path / "t.yaml"
    topo.write_text(TOPOLOGY)
    out = tmp_path / "out.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(path), "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 1 and "0xF030:00" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and not out.exists()


@pytest.mark.parametrize("room", [4, 2])
def test_a_station_whose_esi_declares_0xf030_read_only_refuses_the_download(tmp_path, room):
    """An ENI that downloads 0xF030 (compiled for a station that takes it, as a tool that
    writes it whenever the dictionary has it would) applied to a station whose ESI declares
    it read-only: abort 0x06010002, and the station stays below SAFEOP, as a BK1120-style
    coupler does; also when more modules are plugged than the ESI lists positions."""
    plan = compile_with(coupler(tmp_path, ask=True))
    assert f030(plan)
    read_only = coupler(tmp_path, ask=True, access="ro", room=room)
    with Network.virtual(plan, esi=[read_only], esi_cache=False) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
        assert net.segment.slaves[0].state == AlState.PREOP
    assert err.value.abort_code == 0x06010002, str(err.value)
    assert "0xF030" in str(err.value)


def test_module_init_cmds_follow_the_devices_with_moved_indices(tmp_path):
    path = coupler(tmp_path, ask=True)
    plan = compile_with(path)
    coe = plan.slaves[0].mailbox.coe_init_cmds
    root = etree.parse(str(COUPLER)).getroot()
    module = next(m for m in root.iter("Module") if m.findtext("Type") == "EXK-2AO")
    cmd = module.find("Mailbox/CoE/InitCmd")
    # EXK-2AO sits at position 2: its DependOnSlot 0x8000 moves by SlotIndexIncrement once.
    step = int(root.find(".//Slots").get("SlotIndexIncrement"))
    want = (int(cmd.findtext("Index")[2:], 16) + step, int(cmd.findtext("SubIndex")),
            bytes.fromhex(cmd.findtext("Data")))
    got = [(c.index, c.subindex, c.data) for c in coe if c.index & 0xF000 == 0x8000]
    assert got == [want]
    assert coe.index(f030(plan)[0]) < next(i for i, c in enumerate(coe) if c.index == want[0])
    with Network.virtual(plan, esi=[path], esi_cache=False) as net:
        net.up()
        assert net.segment.slaves[0].od.int_value(want[0], want[1]) \
            == int.from_bytes(want[2], "little")


def test_an_empty_single_slot_keeps_its_position(tmp_path):
    """Slot 1 takes one module and is left empty (it has no default); slot 2 takes EXK-2AO.
    An empty single slot is still a position (docs/compile.md: 0xF030 holds one UDINT per
    position, 0 for an empty slot), so the module is at position 2: its PDO and object
    indices move once by the Slots increments, and the ident list is [0, its ident].
    Counted at position 1, its PDO, objects and InitCmd would be those of slot 1, and the
    station would compare another list.  Expected values are read from the fixture."""
    path = two_single_slots(tmp_path)
    plan = compile_with(path, "slaves:\n  - name: io\n    device: EXK1100\n"
                              "    modules: {2: [EXK-2AO]}\n")
    root = etree.parse(str(path)).getroot()
    slots = root.find(".//Slots")
    pdo_step = int(slots.get("SlotPdoIncrement"))
    index_step = int(slots.get("SlotIndexIncrement"))
    module = next(m for m in root.iter("Module") if m.findtext("Type") == "EXK-2AO")
    ident = int(module.find("Type").get("ModuleIdent")[2:], 16)
    position = 2
    rx = module.find("RxPdo")
    want_pdo = int(rx.findtext("Index")[2:], 16) + (position - 1) * pdo_step
    want_entries = [(int(e.findtext("Index")[2:], 16) + (position - 1) * index_step,
                     int(e.findtext("SubIndex"))) for e in rx.iter("Entry")]
    init = module.find("Mailbox/CoE/InitCmd")
    want_init = (int(init.findtext("Index")[2:], 16) + (position - 1) * index_step,
                 int(init.findtext("SubIndex")), bytes.fromhex(init.findtext("Data")))
    slave = plan.slaves[0]
    pdos = [p for p in slave.process_data.pdos if p.direction == "rx"]
    assert [(p.index, [(e.index, e.subindex) for e in p.entries]) for p in pdos] == [
        (want_pdo, want_entries)], pdos
    assert pdos[0].name.startswith(f"Module {position} (")
    assert f030(plan)[0].data == bytes([2, 0]) + bytes(4) + ident.to_bytes(4, "little")
    coe = slave.mailbox.coe_init_cmds
    assert [(c.index, c.subindex, c.data) for c in coe
            if c.index & 0xF000 == 0x8000] == [want_init]
    # The station emulated from the ENI has the module in slot 2: it takes the InitCmd,
    # passes the 0xF050 check and exchanges the module's outputs.
    with Network.virtual(plan, esi=[path], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        od = net.segment.slaves[0].od
        assert [od.int_value(0xF050, n) for n in range(3)] == [2, 0, ident]
        assert od.int_value(want_init[0], want_init[1]) \
            == int.from_bytes(want_init[2], "little")


def _lint(path: Path, rules: str) -> list:
    result = lint_file(Target(path, str(path), True), LintOptions(select_rules([rules], None)),
                       [])
    assert result is not None
    return result.findings


def test_lint_flags_a_module_init_cmd_whose_data_does_not_fit():
    findings = _lint(COUPLER, "ESI3")
    root = etree.parse(str(COUPLER)).getroot()
    bad = next(m for m in root.iter("Module") if m.findtext("Type") == "EXK-2AO-BAD")
    line = bad.find("Mailbox/CoE/InitCmd").sourceline
    assert [(f.rule, f.line) for f in findings] == [("ESI304", line)], findings
    assert "EXK-2AO-BAD" in findings[0].message and "4 byte(s)" in findings[0].message


def test_the_module_init_cmd_lint_flags_fails_apply(tmp_path):
    """What ESI304 warns of: the station refuses the download at PREOP->SAFEOP.  So compile
    refuses the plugged module's InitCmd at its line (docs/lint.md "Which lint errors stop
    compile"); let through, the station refuses it."""
    path = coupler(tmp_path, ask=True)
    text = TOPOLOGY.replace("EXK-2AO", "EXK-2AO-BAD")
    with pytest.raises(TopologyError) as refused:
        compile_with(path, text)
    bad = etree.parse(str(path)).getroot().xpath(
        "//Module[Type='EXK-2AO-BAD']/Mailbox/CoE/InitCmd")[0]
    assert f"{path.name}:{bad.sourceline}: ESI304 " in str(refused.value)
    plan = compile_with(path, text, allow_esi_errors=True)
    with Network.virtual(plan, esi=[path], esi_cache=False) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
        assert net.segment.slaves[0].state == AlState.PREOP
    assert err.value.abort_code == 0x06070010, str(err.value)


def test_lint_flags_an_ident_list_asked_for_but_read_only(tmp_path):
    read_only = coupler(tmp_path, ask=True, access="ro")
    hits = _lint(read_only, "ESI605")
    assert [(f.rule, f.line) for f in hits] == [("ESI605", line_of(read_only, "//Slots"))]
    assert _lint(coupler(tmp_path, ask=True), "ESI605") == []
    assert _lint(coupler(tmp_path, ask=False, access="ro"), "ESI605") == []


# -- the general rule: no CoE download the dictionary refuses in that state ----------------

def _compile_text(tmp_path: Path, esi_text: str, slave: str = "") -> NetworkPlan:
    path = tmp_path / "d.xml"
    path.write_text(esi_text)
    return compile_with(path, "slaves:\n  - name: d\n    device: FX1\n" + slave)


def test_an_esi_init_cmd_the_dictionary_refuses_is_an_error_at_its_line(tmp_path):
    text = esi(drive(mailbox=init_cmd("#x8000", "0100", "SO", mark=True)))
    with pytest.raises(TopologyError) as err:
        _compile_text(tmp_path, text)
    message = str(err.value)
    assert f"d.xml:{marked_line(text)}" in message and "0x8000:00" in message, message
    assert "SafeOp" in message and "SO" in message
    _compile_text(tmp_path, esi(drive(mailbox=init_cmd("#x8000", "0100", "PS"))))


def test_a_user_sdo_given_as_data_is_checked_too(tmp_path):
    with pytest.raises(TopologyError) as err:
        _compile_text(tmp_path, esi(drive()),
                      "    sdos:\n      - {index: 0x6000, subindex: 0, data: '0100'}\n")
    assert "t.yaml:5" in str(err.value) and "0x6000:00" in str(err.value), str(err.value)


def _read_only_rx_assignment() -> str:
    """The reference drive (lint_fixtures.py), its dictionary with the assignment objects:
    0x1C12 read-only (its one RxPDO is always assigned), 0x1C13 writable in PREOP."""
    from lint_fixtures import PROFILE, RXPDO

    def assign(index: str, access: str) -> str:
        return (f"<Object><Index>{index}</Index><Name>SM assign</Name><Type>DT{index[2:]}"
                f"</Type><BitSize>32</BitSize><Flags><Access>{access}</Access></Flags>"
                "</Object>")

    def dtype(index: str, access: str) -> str:
        return (f"<DataType><Name>DT{index[2:]}</Name><BitSize>32</BitSize>"
                "<SubItem><SubIdx>0</SubIdx><Name>Count</Name><Type>USINT</Type><BitSize>8"
                f"</BitSize><BitOffs>0</BitOffs><Flags>{access}</Flags>"
                "</SubItem><SubItem><SubIdx>1</SubIdx><Name>PDO 1</Name><Type>UINT</Type>"
                f"<BitSize>16</BitSize><BitOffs>16</BitOffs><Flags>{access}"
                "</Flags></SubItem></DataType>")

    profile = PROFILE.replace("</DataTypes>", dtype("#x1C12", "<Access>ro</Access>") + dtype(
        "#x1C13", '<Access WriteRestrictions="PreOp">rw</Access>') + "</DataTypes>").replace(
        "</Objects>", assign("#x1C12", "ro") + assign("#x1C13", "rw") + "</Objects>")
    rx2 = ('<RxPdo><Index>#x1601</Index><Name>More</Name><Entry><Index>#x7000</Index>'
           "<SubIndex>0</SubIndex><BitLen>16</BitLen><Name>O</Name><DataType>UINT</DataType>"
           "</Entry></RxPdo>")
    return esi(drive(profile=profile, rx=RXPDO + rx2, dc=""))


def test_a_read_only_pdo_assignment_is_kept_as_the_slave_has_it(tmp_path):
    text = _read_only_rx_assignment()
    plan = _compile_text(tmp_path, text)
    written = {c.index for c in plan.slaves[0].mailbox.coe_init_cmds}
    assert 0x1C12 not in written and 0x1C13 in written, written
    with Network.virtual(plan, esi=[tmp_path / "d.xml"], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
    with pytest.raises(TopologyError) as err:
        _compile_text(tmp_path, text, "    rx_pdos: [0x1600, 0x1601]\n")
    assert "t.yaml:4" in str(err.value) and "0x1C12" in str(err.value), str(err.value)


# -- what a download writes: strings written shorter, CompleteAccess from subindex 1 -------

def _string_and_record_profile() -> str:
    """The reference drive's dictionary with a STRING(8) 0x8010 and a record 0x8020 whose
    entries start at subindex 4 (as Beckhoff's IO-Link settings 0x80n0 do)."""
    from lint_fixtures import PROFILE
    return PROFILE.replace("</DataTypes>", (
        "<DataType><Name>STRING(8)</Name><BitSize>64</BitSize></DataType>"
        "<DataType><Name>DT8020</Name><BitSize>48</BitSize>"
        "<SubItem><SubIdx>0</SubIdx><Name>Count</Name><Type>USINT</Type><BitSize>8</BitSize>"
        "<BitOffs>0</BitOffs><Flags><Access>ro</Access></Flags></SubItem>"
        "<SubItem><SubIdx>4</SubIdx><Name>Id</Name><Type>DINT</Type><BitSize>32</BitSize>"
        "<BitOffs>16</BitOffs><Flags><Access>rw</Access></Flags></SubItem></DataType>"
        "</DataTypes>")).replace("</Objects>", (
            "<Object><Index>#x8010</Index><Name>Name</Name><Type>STRING(8)</Type><BitSize>64"
            "</BitSize><Flags><Access>rw</Access></Flags></Object>"
            "<Object><Index>#x8020</Index><Name>Settings</Name><Type>DT8020</Type><BitSize>48"
            "</BitSize></Object></Objects>"))


@pytest.mark.parametrize("index, data, complete, rule", [
    ("#x8010", "414243", False, None),                  # a string written shorter: fits
    ("#x8010", "414243444546474849", False, "ESI304"),  # longer than STRING(8)
    ("#x8010", "", False, "ESI304"),                    # empty
    ("#x8000", "01000000", False, "ESI304"),            # a UINT given four bytes
    ("#x8020", "00000000", True, None),                 # whole record from subindex 1
])
def test_what_a_download_writes(tmp_path, index, data, complete, rule):
    attrs = ' CompleteAccess="1"' if complete else ""
    cmd = (f"<InitCmd{attrs}><Transition>PS</Transition>"
           f"<Index>{index}</Index><SubIndex>{1 if complete else 0}</SubIndex>"
           f"<Data>{data}</Data></InitCmd>")
    path = tmp_path / "d.xml"
    path.write_text(esi(drive(profile=_string_and_record_profile(), mailbox=(
        f'<Mailbox><CoE SdoInfo="1" PdoAssign="1" CompleteAccess="1">{cmd}</CoE></Mailbox>'))))
    assert [f.rule for f in _lint(path, "ESI3")] == ([rule] if rule else [])


def test_the_emulated_slave_takes_what_lint_lets_through(tmp_path):
    """The same length rule answers on the wire: a shorter string is taken (the rest NULs),
    a longer one refused with 0x06070012, a number of the wrong size with 0x06070010."""
    from ecatcfg.runtime.segment import emulate
    from ecatcfg.runtime.mailbox import SdoAbort
    path = tmp_path / "d.xml"
    path.write_text(esi(drive(profile=_string_and_record_profile())))
    device = Library([path], cache=False)
    od = emulate.emulated_slave(emulate.SlaveSpec(device.device(device.entries[0]), "d")).od
    assert od is not None
    od.write(0x8010, 0, b"ABC", AlState.PREOP)
    assert od.read(0x8010, 0, AlState.PREOP) == b"ABC" + bytes(5)
    for index, data, code in ((0x8010, b"ABCDEFGHI", 0x06070012), (0x8000, bytes(4), 0x06070010)):
        with pytest.raises(SdoAbort) as err:
            od.write(index, 0, data, AlState.PREOP)
        assert err.value.code == code


def test_lint_of_the_real_module_library_flags_the_strings_that_do_not_fit(corpus):
    """Weidmüller's UR20 module library: every module InitCmd that writes more bytes than
    its module's dictionary gives the subitem (read here with lxml) is ESI304, at its line;
    no other InitCmd is flagged (a name shorter than its STRING(25) fits)."""
    path = corpus / "esi/modular/Weidmueller_UR20_IO.xml"
    root = etree.parse(str(path)).getroot()
    want, total = set(), 0
    for module in root.iter("Module"):
        types = {d.findtext("Name"): d for d in module.iter("DataType")}
        objects = {o.findtext("Index").lower(): o for o in module.iter("Object")}
        for cmd in module.iterfind("Mailbox/CoE/InitCmd"):
            total += 1
            obj = objects[cmd.findtext("Index").lower()]
            item = next(i for i in types[obj.findtext("Type")].iter("SubItem")
                        if i.findtext("SubIdx") == cmd.findtext("SubIndex"))
            if len(bytes.fromhex(cmd.findtext("Data"))) > int(item.findtext("BitSize")) // 8:
                want.add(cmd.sourceline)
    findings = _lint(path, "ESI3")
    assert {f.line for f in findings if f.rule == "ESI304"} == want
    assert {f.rule for f in findings} <= {"ESI304"}
    assert (total, len(want)) == (164, 3)           # the figure docs/lint.md gives
