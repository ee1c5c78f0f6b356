"""Never lose configuration silently: ENI parts apply does not do are refused (file, line,
slave, element, commands lost) before anything is sent, or skipped with one warning per
slave when the user says so; everything real exporters write is accepted.

The ENIs here are our example line compiled, then given the section under test with lxml,
or corpus ENIs given it the same way; the expected lines come from lxml's ``sourceline`` of
the element the test inserted, the expected counts from the test's own inserts.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import contents
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.contents import UnsupportedEniError
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.link import MemoryLink
from ecatcfg.runtime.network import SkippedConfigWarning

ESI = EXAMPLES / "esi"
DRIVE = "axis1"                     # the example's slave with a mailbox (CoE)


@pytest.fixture(scope="module")
def example_eni() -> bytes:
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([ESI], cache=False)).plan
    return eni_writer.to_bytes(plan)


def _mailbox_cmds(tag: str, n: int, disabled: int = 0) -> str:
    """``n`` InitCmds of a mailbox protocol (ETG.2100 MailboxCmdType), ``disabled`` of them
    with Disabled=1; SoE gets its own fields (OpCode, DriveNo, IDN ...)."""
    cmds = []
    for i in range(n):
        extra = ("<OpCode>3</OpCode><DriveNo>0</DriveNo><IDN>32</IDN><Elements>64</Elements>"
                 "<Attribute>0</Attribute>" if tag == "SoE" else "")
        off = "<Disabled>1</Disabled>" if i < disabled else ""
        cmds.append(f"<InitCmd><Transition>PS</Transition><Comment>{tag} {i}</Comment>"
                    f"<Timeout>1000</Timeout>{extra}<Data>0100</Data>{off}</InitCmd>")
    return f"<{tag}><InitCmds>{''.join(cmds)}</InitCmds></{tag}>"


HOT_CONNECT = ("<HotConnect><GroupMemberCnt>1</GroupMemberCnt><IdentifyCmd><Cmd>4</Cmd>"
               "<Adp>1005</Adp><Ado>18</Ado><DataLength>2</DataLength></IdentifyCmd>"
               "</HotConnect>")


def _insert(eni: bytes, xpath: str, fragment: str, tmp_path: Path,
            name: str = "line.xml") -> tuple[Path, int]:
    """``eni`` with ``fragment`` appended to the element at ``xpath``; the file and the
    inserted element's line in it."""
    tree = etree.ElementTree(etree.fromstring(eni))
    parent = tree.xpath(xpath)[0]
    parent.append(etree.fromstring(fragment))
    path = tmp_path / name
    path.write_bytes(etree.tostring(tree, xml_declaration=True, encoding="UTF-8",
                                    pretty_print=True))
    tag = etree.fromstring(fragment).tag
    line = etree.parse(str(path)).xpath(f"{xpath}/{tag}")[0].sourceline
    return path, line


def _apply(eni: Path, *args: str, esi: Path = ESI) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(esi), "--simulated-time", "--cycles", "3", *args],
                          capture_output=True, text=True, timeout=120)


SLAVE_MAILBOX = f"//Slave[Info/Name='{DRIVE}']/Mailbox"

CASES = {   # name: (where, fragment, element path, what the message says, commands lost)
    "AoE": (SLAVE_MAILBOX, _mailbox_cmds("AoE", 1), "Slave/Mailbox/AoE/InitCmds",
            "AoE InitCmds", 1),
    "VoE": (SLAVE_MAILBOX, _mailbox_cmds("VoE", 4), "Slave/Mailbox/VoE", "VoE InitCmds", 4),
    "unknown protocol": (SLAVE_MAILBOX, _mailbox_cmds("XoE", 2), "Slave/Mailbox/XoE",
                         "XoE InitCmds (a mailbox protocol ecatcfg does not know)", 2),
}


@pytest.mark.parametrize("case", list(CASES))
def test_refused_before_anything_is_sent_then_skipped_with_a_warning(case, example_eni,
                                                                     tmp_path):
    where, fragment, element, what, lost = CASES[case]
    eni, line = _insert(example_eni, where, fragment, tmp_path)
    pcap = tmp_path / "run.pcapng"
    refused = _apply(eni, "--pcap", str(pcap))
    assert refused.returncode == 1, refused.stdout + refused.stderr
    err = refused.stderr
    assert "Traceback" not in err
    assert f"{eni}:{line}: slave '{DRIVE}': {what}" in err, err
    assert f"[{element}]" in err
    if lost:
        assert f": {lost} command{'s' if lost > 1 else ''} would be lost" in err
    else:
        assert "would be lost" not in err
    assert "nothing was written to the bus" in err and "--skip-unsupported" in err
    assert not pcap.exists()                  # no link opened, not one frame

    done = _apply(eni, "--skip-unsupported", "--format", "json")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["ok"] and all(s["highest_state"] == "OP" and s["state"] == "INIT"
                                for s in report["slaves"])
    warnings_ = [w for w in done.stderr.splitlines() if w.startswith("warning:")]
    assert len(warnings_) == 1, done.stderr               # one per slave: one slave here
    assert f"slave '{DRIVE}': skipped {what}" in warnings_[0]
    assert f"at line {line}" in warnings_[0]
    assert report["skipped"] == [{"slave": DRIVE, "element": element,
                                  "what": report["skipped"][0]["what"], "line": line,
                                  "commands": lost}]


def test_several_parts_are_all_named_and_warned_once_per_slave(example_eni, tmp_path):
    first, _ = _insert(example_eni, SLAVE_MAILBOX, _mailbox_cmds("VoE", 2), tmp_path, "a.xml")
    second, _ = _insert(first.read_bytes(), SLAVE_MAILBOX, _mailbox_cmds("FoE", 1), tmp_path,
                        "b.xml")
    eni, _ = _insert(second.read_bytes(), "//Slave[Info/Name='lamps']",
                     "<Redundancy>1</Redundancy>", tmp_path, "c.xml")
    refused = _apply(eni)
    assert refused.returncode == 1
    assert "asks for 3 things" in refused.stderr
    assert len(re.findall(r"^  .*c\.xml:\d+: slave ", refused.stderr, re.M)) == 3
    done = _apply(eni, "--skip-unsupported")
    assert done.returncode == 0, done.stderr
    lines = [w for w in done.stderr.splitlines() if w.startswith("warning:")]
    assert len(lines) == 2                                  # axis1 and lamps
    drive = next(w for w in lines if f"'{DRIVE}'" in w)
    assert "VoE InitCmds" in drive and "FoE InitCmd: <Data> of 2 bytes" in drive


def test_network_api_refuses_and_skips(example_eni, tmp_path):
    eni, line = _insert(example_eni, SLAVE_MAILBOX, _mailbox_cmds("VoE", 3), tmp_path)
    with pytest.raises(UnsupportedEniError) as caught:
        Network.virtual(eni, esi=[ESI])
    [part] = caught.value.parts
    assert (part.slave, part.element, part.line, part.commands) == (
        DRIVE, "Slave/Mailbox/VoE", line, 3)
    # The constructor refuses too, and closes the link it was given (it owns it).
    ours, theirs = MemoryLink.pair()
    with pytest.raises(UnsupportedEniError):
        Network(eni, ours)
    assert ours._closed                    # (private: MemoryLink has no public flag)
    theirs.close()

    with warnings.catch_warnings(record=True) as caught_warnings:
        warnings.simplefilter("always")
        with Network.virtual(eni, esi=[ESI], skip_unsupported=True) as net:
            net.up()
            assert net.state == AlState.OP
    skipped = [w for w in caught_warnings if issubclass(w.category, SkippedConfigWarning)]
    assert len(skipped) == 1 and f"slave '{DRIVE}'" in str(skipped[0].message)

    events = []
    with Network.virtual(eni, esi=[ESI], skip_unsupported=True,
                         on_event=events.append) as net:
        net.up(AlState.PREOP)
    assert [e.kind for e in events].count("skipped") == 1


ACCEPTED = {   # name: (where, fragment): nothing lost, so nothing to refuse
    "copy infos": ("//Cyclic/Frame/Cmd[1]",
                   "<CopyInfos><CopyInfo><SrcBitOffs>0</SrcBitOffs><DstBitOffs>8</DstBitOffs>"
                   "<BitSize>1</BitSize></CopyInfo></CopyInfos>"),
    "empty FoE": (SLAVE_MAILBOX, "<FoE/>"),
    "SoE with disabled commands only": (SLAVE_MAILBOX, _mailbox_cmds("SoE", 2, disabled=2)),
    "AoE NetId": (SLAVE_MAILBOX, "<AoE><NetId>1.1.1.1.3.234</NetId></AoE>"),
    "identification off": (f"//Slave[Info/Name='{DRIVE}']/Info",
                           '<Identification Value="0" EnableIdentification="False">'
                           "<Ado>#x0012</Ado></Identification>"),
    "master EoE switch": ("//Config/Master",
                          "<EoE><MaxPorts>2</MaxPorts><MaxFrames>120</MaxFrames>"
                          "<MaxMACs>100</MaxMACs></EoE>"),
    # A hot-connect group is read (the plan's SlavePlan.hot_connect), no longer refused.
    "hot-connect group": (f"//Slave[Info/Name='{DRIVE}']", HOT_CONNECT),
    "vendor data outside Config": ("/EtherCATConfig",
                                   "<ElmoSpecialResources><ElmoDC/></ElmoSpecialResources>"),
}


@pytest.mark.parametrize("case", list(ACCEPTED))
def test_accepted_parts_are_not_refused(case, example_eni, tmp_path):
    where, fragment = ACCEPTED[case]
    eni, _ = _insert(example_eni, where, fragment, tmp_path)
    assert eni_reader.read_file(eni).unsupported == []


REFUSED_SETTINGS = {   # name: (where, fragment, element, words in the message)
    "identification on": (f"//Slave[Info/Name='{DRIVE}']/Info",
                          '<Identification Value="7" EnableIdentification="True">'
                          "<Ado>#x0012</Ado></Identification>", "Slave/Info/Identification",
                          "explicit device identification"),
    "unknown slave element": (f"//Slave[Info/Name='{DRIVE}']", "<Redundancy>1</Redundancy>",
                              "Slave/Redundancy", "<Redundancy>, an element ecatcfg does "
                              "not know"),
    "unknown InitCmd field": (f"//Slave[Info/Name='{DRIVE}']/InitCmds/InitCmd[1]",
                              "<Repeat>5</Repeat>", "Slave/InitCmds/InitCmd/Repeat",
                              "<Repeat>"),
    "copy outside the image": ("//Cyclic/Frame/Cmd[1]",
                               "<CopyInfos><CopyInfo><SrcBitOffs>0</SrcBitOffs><DstBitOffs>"
                               "#x10000</DstBitOffs><BitSize>1</BitSize></CopyInfo>"
                               "</CopyInfos>", "Cyclic/Frame/Cmd/CopyInfos/CopyInfo",
                               "a slave-to-slave copy outside the process image (copy 1 bit: "
                               "input bit 0 (byte 0.0) -> output bit 65536 (byte 8192.0)"),
    "master clock as DC reference": ("//Config/Master",
                                     "<DC><ReferenceClock>0</ReferenceClock><Type>1</Type>"
                                     "<MasterTimeAsRef>1</MasterTimeAsRef></DC>", "Master/DC",
                                     "the master's clock as the DC reference"),
    "redundancy NIC": ("//Config/Master", "<RNIC>eth2</RNIC>", "Master/RNIC",
                       "<RNIC> is not empty"),
}


@pytest.mark.parametrize("case", list(REFUSED_SETTINGS))
def test_settings_apply_does_not_do_are_recorded(case, example_eni, tmp_path):
    where, fragment, element, words = REFUSED_SETTINGS[case]
    eni, line = _insert(example_eni, where, fragment, tmp_path)
    [part] = eni_reader.read_file(eni).unsupported
    assert (part.element, part.line, part.commands) == (element, line, 0)
    assert words in part.what
    assert part.slave == (None if element.startswith(("Master", "Cyclic")) else DRIVE)


def test_hot_connect_group_is_read_and_its_commands_checked_field_by_field(example_eni,
                                                                          tmp_path):
    """A HotConnect group is read into the plan; an IdentifyCmd field the reader does not
    know is refused like one in an InitCmd."""
    first, _ = _insert(example_eni, f"//Slave[Info/Name='{DRIVE}']", HOT_CONNECT, tmp_path,
                       "a.xml")
    plan = eni_reader.read_file(first)
    group = plan.slave(DRIVE).hot_connect
    assert plan.unsupported == [] and group is not None
    [cmd] = group.identify_cmds
    assert (group.member_count, cmd.cmd, cmd.adp, cmd.ado, cmd.length) == (1, 4, 1005, 18, 2)
    eni, line = _insert(first.read_bytes(), f"//Slave[Info/Name='{DRIVE}']/HotConnect/"
                        "IdentifyCmd", "<Repeat>5</Repeat>", tmp_path, "b.xml")
    [part] = eni_reader.read_file(eni).unsupported
    assert (part.element, part.line, part.slave) == (
        "Slave/HotConnect/IdentifyCmd/Repeat", line, DRIVE)


def test_hot_plug_attribute_and_frame_factor(example_eni, tmp_path):
    tree = etree.fromstring(example_eni)
    tree.xpath(f"//Slave[Info/Name='{DRIVE}']")[0].set("HotPlug", "1")
    tree.xpath("//Cyclic/Frame")[0].set("CycleTimeFactor", "4")
    plan = eni_reader.read_bytes(etree.tostring(tree), "x.xml")
    assert sorted((p.element, p.slave) for p in plan.unsupported) == [
        ("Cyclic/Frame/@CycleTimeFactor", None), ("Slave/@HotPlug", DRIVE)]
    # The values Elmo Application Studio writes when the feature is off are accepted.
    tree.xpath(f"//Slave[Info/Name='{DRIVE}']")[0].set("HotPlug", "0")
    tree.xpath("//Cyclic/Frame")[0].set("CycleTimeFactor", "0")
    assert eni_reader.read_bytes(etree.tostring(tree), "x.xml").unsupported == []


def test_cyclic_tasks_with_different_cycle_times(example_eni, tmp_path):
    tree = etree.fromstring(example_eni)
    config = tree.find("Config")
    cyclic = config.find("Cyclic")
    for c in config.iterchildren("Cyclic"):
        for old in c.iterchildren("CycleTime"):
            c.remove(old)
    etree.SubElement(cyclic, "CycleTime").text = "1000"
    second = etree.fromstring("<Cyclic><CycleTime>4000</CycleTime></Cyclic>")
    second.append(etree.fromstring(etree.tostring(cyclic.find("Frame"))))
    cyclic.addnext(second)
    [part] = eni_reader.read_bytes(etree.tostring(tree), "x.xml").unsupported
    assert part.element == "Cyclic" and "1000, 4000" in part.what


# The example line's one process-data command is the LRW of logical 0x10000000, 18 bytes
# (the compiled ENI's Cyclic/Frame/Cmd); the lamps' output FMMU 0 is moved over its edges.
LRW_START, LRW_SIZE = 0x10000000, 18


@pytest.mark.parametrize("start, length, covered", [
    (LRW_START, LRW_SIZE, True),                       # the whole window, edge to edge
    (LRW_START + LRW_SIZE - 1, 1, True),               # its last byte
    (LRW_START + LRW_SIZE - 1, 2, False),              # one byte past its end
    (LRW_START - 1, 2, False),                         # one byte before its start
    (LRW_START - 1, LRW_SIZE + 2, False),              # all of it and a byte on each side
    (LRW_START + LRW_SIZE, 1, False),                  # just after it
], ids=["exact", "last-byte", "past-end", "before-start", "both-sides", "after"])
def test_an_fmmu_only_partly_in_a_cyclic_window_is_refused(start, length, covered,
                                                           example_eni):
    """An FMMU maps its whole logical range (ETG.1000.4 FMMU: logical start address and
    length); the bytes a cyclic command does not carry are exchanged with nobody, so a
    setting that only partly overlaps the LRW is refused at its InitCmd's line, as one
    that maps nothing the commands carry; one inside the window, to its edges, is read."""
    tree = etree.fromstring(example_eni)
    [cmd] = tree.xpath("//Cyclic/Frame/Cmd[Cmd='12']")
    assert (int(cmd.findtext("Addr")), int(cmd.findtext("DataLength"))) == (LRW_START,
                                                                           LRW_SIZE)
    [init] = tree.xpath("//Slave[Info/Name='lamps']/InitCmds/InitCmd"
                        "[Comment='set fmmu 0 (outputs)']")
    # Logical start (32 bits) and length (16 bits) lead the FMMU record (ETG.1000.4
    # 0x0600 + 16n); the rest (bits, physical address 0x0F00, write, active) stays.
    record = bytearray.fromhex(init.findtext("Data"))
    assert record[10:13] == b"\x00\x02\x01"
    record[0:6] = struct.pack("<IH", start, length)
    init.find("Data").text = record.hex()
    data = etree.tostring(tree, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    line = etree.fromstring(data).xpath("//Slave[Info/Name='lamps']/InitCmds/InitCmd"
                                        "[Comment='set fmmu 0 (outputs)']")[0].sourceline
    plan = eni_reader.read_bytes(data, "line.xml")
    kept = [c for c in plan.slave("lamps").init_cmds if c.comment == "set fmmu 0 (outputs)"]
    if covered:
        assert plan.unsupported == [] and len(kept) == 1
        return
    [part] = plan.unsupported
    assert (part.slave, part.element, part.line, part.commands) == (
        "lamps", "Slave/InitCmds/InitCmd", line, 1)
    assert part.what == (f"FMMU 0 setting that maps logical 0x{start:08X}+{length}, which "
                         "no cyclic command covers")
    assert kept == []                   # left out of the plan: a skipping apply never writes it


def test_refused_from_the_plan_cache_too(example_eni, tmp_path):
    """A cached plan keeps its unsupported parts: the second run is refused as well."""
    eni, line = _insert(example_eni, SLAVE_MAILBOX, _mailbox_cmds("VoE", 1), tmp_path)
    for _ in range(2):
        refused = _apply(eni)
        assert refused.returncode == 1 and f"{eni}:{line}:" in refused.stderr


def test_docs_table_is_the_readers_list():
    """docs/runtime.md shows exactly the reader's list (eni/contents.py), row by row."""
    doc = (Path(__file__).resolve().parent.parent / "docs" / "runtime.md").read_text()
    rows = [f"| `{element}` | {kind} | {text} |" for element, kind, text in contents.table()]
    section = doc.split("## What an ENI may contain", 1)[1].split("\n## ", 1)[0]
    table = [line for line in section.splitlines() if line.startswith("| `")]
    assert table == rows


def test_every_context_the_list_descends_into_is_listed():
    for context, parts in contents.CONTENTS.items():
        for tag, part in parts.items():
            assert part.within is None or part.within in contents.CONTENTS, (context, tag)
            assert part.kind != "refused" or part.within is None


# -- the corpus ------------------------------------------------------------------------------

def test_every_corpus_eni_is_accepted_as_it_is(corpus):
    """All but the Murrelektronik export: an EncryptedEtherCATConfig whose two process-data
    FMMU InitCmds are not clear text (see the next test)."""
    enis = sorted((corpus / "eni").rglob("*.xml"))
    assert len(enis) >= 10
    for eni in enis:
        plan = eni_reader.read_file(eni)
        if eni.parent.name == "murrelektronik-variox":
            assert [(p.slave, p.element, p.commands) for p in plan.unsupported] == [
                ("Slave_1002 [54632]", "Slave/InitCmds/InitCmd", 1)] * 2
            assert all("encrypted" in p.what for p in plan.unsupported)
        else:
            assert plan.unsupported == [], (eni.name, plan.unsupported)


def test_encrypted_fmmu_settings_are_refused_and_never_written(corpus, tmp_path):
    """The VarioX export's FMMU 0/1 data read as a mapping of logical 0xEB030B5F, while its
    only process-data command is the LRW at 0x10000000 and its SM2 lies at 0x17D8.  The
    clear FMMU 0 these settings stand for, from the file's own ProcessData (SM2 0x17D8,
    164 bytes of outputs at logical 0x10000000), differs from the bytes in the file in
    every 4-byte group: the data is encrypted, not a mapping."""
    eni = corpus / "eni" / "murrelektronik-variox" / "eni.xml"
    text = eni.read_text(encoding="iso-8859-1")
    stored = bytes.fromhex(text.split("set fmmu 0 (outputs)]]></Comment>")[1]
                           .split("<Data>")[1].split("</Data>")[0])
    clear = struct.pack("<IHBBHBBB3x", 0x10000000, 164, 0, 7, 0x17D8, 0, 2, 1)
    assert all(stored[i:i + 4] != clear[i:i + 4] for i in range(0, 16, 4))
    plan = eni_reader.read_file(eni)
    fmmu_writes = [c for s in plan.slaves for c in s.init_cmds
                   if c.ado is not None and 0x0600 <= c.ado < 0x0700 and c.data and any(c.data)]
    # Only the mailbox-state FMMU (clear text) stays in the plan: skipping never writes them.
    assert [c.comment for c in fmmu_writes] == ["set fmmu 2 (mailbox state)"]
    run = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                          "--simulated-time", "--cycles", "1"], capture_output=True, text=True,
                          timeout=60)
    assert run.returncode == 1
    assert "slave 'Slave_1002 [54632]': FMMU 0 setting that maps logical 0xEB030B5F" in \
        run.stderr and "nothing was written to the bus" in run.stderr


def test_corpus_eni_with_voe_added_is_refused(corpus, tmp_path):
    """eni1.xml (Elmo Application Studio) with a VoE section added to its drive."""
    source = (corpus / "eni" / "rocos-ethercat" / "eni1.xml").read_bytes()
    eni, line = _insert(source, "//Slave[Info/Name='Elmo Drive']/Mailbox",
                        _mailbox_cmds("VoE", 2), tmp_path)
    refused = _apply(eni, esi=corpus / "esi")
    assert refused.returncode == 1
    assert f"{eni}:{line}: slave 'Elmo Drive': VoE InitCmds" in refused.stderr
    assert ": 2 commands would be lost" in refused.stderr
    done = _apply(eni, "--skip-unsupported", esi=corpus / "esi")
    assert done.returncode == 0, done.stderr
    assert "warning:" in done.stderr and "slave 'Elmo Drive': skipped VoE" in done.stderr


def test_simulate_eni_names_what_it_ignores(veth_netns, example_eni, tmp_path):
    """simulate is not the master: it emulates the slaves of an ENI apply would refuse,
    and says which parts it ignores."""
    eni, line = _insert(example_eni, SLAVE_MAILBOX, _mailbox_cmds("VoE", 3), tmp_path)
    done = veth_netns.run_in(veth_netns.ns_b, [
        sys.executable, "-m", "ecatcfg", "simulate", "--iface", veth_netns.if_b,
        "--no-cache", "--esi", str(ESI), "--eni", str(eni), "--duration", "0.3"],
        timeout=60)
    assert done.returncode == 0, done.stderr
    assert "ready: 5 slaves" in done.stdout
    [note] = [n for n in done.stderr.splitlines() if n.startswith("note:")]
    assert f"{eni}:{line}: slave '{DRIVE}': VoE InitCmds" in note
    assert "3 commands would be lost" in note
