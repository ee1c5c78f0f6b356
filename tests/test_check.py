"""``ecatcfg check``: an ENI against itself and the ESI files of its devices.

Each rule fires on a self-written defective ENI: the example line compiled by ``ecatcfg
compile`` (clean: no finding at all), with one defect put in by lxml, the expected message
written out here by hand.  The real ENIs of both corpora and the ENIs the compiler writes
from them have no error finding except the defects named here, and the EC-Engineer ENI
that writes the read-only 0x1C12:00 is judged against its device's exact-revision ESI,
whose access rights the test reads itself.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from lxml import etree

from conftest import EXAMPLES, ROOT, compile_example, corpus_eni, corpus_enis

from ecatcfg.eni.check import all_rules, check_eni
from ecatcfg.esi.lint.finding import FileResult
from ecatcfg.esi.library import Library

Root = etree._Element


def check(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "check", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def example_eni(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_example(tmp_path_factory.mktemp("check") / "line.xml")


@pytest.fixture(scope="module")
def examples() -> Library:
    return Library([EXAMPLES / "esi"], cache=False)


def _slave(root: Root, name: str) -> Root:
    found: Root = root.xpath(f"Config/Slave[normalize-space(Info/Name)='{name}']")[0]
    return found


def _init_cmd(slave: Root, comment: str) -> Root:
    found: Root = slave.xpath(f"InitCmds/InitCmd[Comment='{comment}']")[0]
    return found


def _defective(tmp_path: Path, eni: Path, defect: Callable[[Root], None]) -> Path:
    tree = etree.parse(str(eni))
    defect(tree.getroot())
    out = tmp_path / "defective.xml"
    tree.write(str(out), xml_declaration=True, encoding="UTF-8")
    return out


def _rules(result: FileResult) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for f in result.findings:
        found.setdefault(f.rule, []).append(f.message)
    return found


def test_the_compiled_example_is_clean(example_eni: Path, examples: Library) -> None:
    result = check_eni(example_eni, examples)
    assert result.findings == []
    assert [d.type for d in result.devices] == ["coupler", "buttons", "sensors", "lamps",
                                                "axis1"]


def _sm2_length_8(root: Root) -> None:
    # axis1's outputs: 0x1601 = controlword + target velocity, 6 bytes; set 8.
    cmd = _init_cmd(_slave(root, "axis1"), "set sm 2 (outputs)")
    cmd.find("Data").text = "0011080064000100"


def _sm3_never_set(root: Root) -> None:
    # axis1 inputs: 0x1A00 (6 bytes) and 0x1A01 remapped to 2 + 4 + 4 bytes.
    axis = _slave(root, "axis1")
    cmd = _init_cmd(axis, "set sm 3 (inputs)")
    cmd.getparent().remove(cmd)


def _lamps_fmmu_inactive(root: Root) -> None:
    cmd = _init_cmd(_slave(root, "lamps"), "set fmmu 0 (outputs)")
    data = bytearray.fromhex(cmd.find("Data").text)
    data[12] = 0                                       # FMMU +0x0C: activate
    cmd.find("Data").text = data.hex()


def _sensors_over_buttons(root: Root) -> None:
    buttons = _slave(root, "buttons").find("ProcessData/Recv/BitStart").text
    _slave(root, "sensors").find("ProcessData/Recv/BitStart").text = buttons


def _big_frame(root: Root) -> None:
    frame = root.find("Config/Cyclic/Frame")
    cmd = etree.SubElement(frame, "Cmd")
    for tag, text in (("State", "OP"), ("Cmd", "10"), ("Addr", "536870912"),
                      ("DataLength", "1480"), ("InputOffs", "100"), ("OutputOffs", "100")):
        etree.SubElement(cmd, tag).text = text


def _lrw_cnt_plus_one(root: Root) -> None:
    cnt = root.xpath("Config/Cyclic/Frame/Cmd[Cmd='12']/Cnt")[0]
    cnt.text = str(int(cnt.text) + 1)


def _mailbox_send_64(root: Root) -> None:
    _slave(root, "axis1").find("Mailbox/Send/Length").text = "64"


def _mandatory_1a00_unassigned(root: Root) -> None:
    sm3 = _slave(root, "axis1").find("ProcessData/Sm3")
    sm3.remove(sm3.xpath("Pdo[text()='#x1a00' or text()='6656']")[0])


def _excluded_pair(root: Root) -> None:
    etree.SubElement(_slave(root, "axis1").find("ProcessData/Sm2"), "Pdo").text = "#x1600"


def _fixed_remapped(root: Root) -> None:
    pdo = _slave(root, "buttons").xpath("ProcessData/TxPdo[Index='#x1a00']")[0]
    pdo.find("Entry/Index").text = "#x6001"


def _rx_object_in_txpdo(root: Root) -> None:
    pdo = _slave(root, "axis1").xpath("ProcessData/TxPdo[Index='#x1a01']")[0]
    entry = pdo.find("Entry[Index='#x606c']")
    entry.find("Index").text = "#x60ff"               # PdoMapping R: target velocity


def _coe_cmd(index: int, subindex: int, data: str, transition: str = "PS"
             ) -> Callable[[Root], None]:
    def add(root: Root) -> None:
        cmds = _slave(root, "axis1").find("Mailbox/CoE/InitCmds")
        cmd = etree.SubElement(cmds, "InitCmd")
        for tag, text in (("Transition", transition), ("Comment", "test"), ("Timeout", "0"),
                          ("Ccs", "1"), ("Index", str(index)), ("SubIndex", str(subindex)),
                          ("Data", data)):
            etree.SubElement(cmd, tag).text = text
    return add


def _soe_cmd(transition: str = "PS", drive: int = 0, listed: bool = False
             ) -> Callable[[Root], None]:
    """An SoE write of S-0-0032 added to axis1 (a CoE drive): ``listed`` adds SoE to its
    Mailbox/Protocol list too."""
    def add(root: Root) -> None:
        mailbox = _slave(root, "axis1").find("Mailbox")
        if listed:
            mailbox.find("Protocol").addnext(etree.fromstring("<Protocol>SoE</Protocol>"))
        soe = etree.fromstring(
            f"<SoE><InitCmds><InitCmd><Transition>{transition}</Transition><Timeout>0"
            f"</Timeout><OpCode>3</OpCode><DriveNo>{drive}</DriveNo><IDN>32</IDN>"
            "<Elements>64</Elements><Attribute>0</Attribute><Data>0b00</Data></InitCmd>"
            "</InitCmds></SoE>")
        mailbox.find("CoE").addnext(soe)
    return add


def _coe_not_listed(root: Root) -> None:
    """axis1's Mailbox/Protocol says EoE only, though its CoE InitCmds set its PDOs up."""
    protocol = _slave(root, "axis1").find("Mailbox/Protocol")
    assert protocol.text == "CoE"
    protocol.text = "EoE"


def _assign_activate_0700(root: Root) -> None:
    _init_cmd(_slave(root, "axis1"), "set DC activation").find("Data").text = "0007"


def _foe_on_lamps(root: Root) -> None:
    """An FoE read request InitCmd (OpCode 1, password 0, "cal.bin") for the EX2008, whose
    ESI has no mailbox at all."""
    lamps = _slave(root, "lamps")
    data = "0100" + "00000000" + b"cal.bin".hex()
    mailbox = etree.fromstring(
        "<Mailbox><Send><Start>4096</Start><Length>128</Length></Send><Recv><Start>4224"
        "</Start><Length>128</Length></Recv><FoE><InitCmds><InitCmd><Transition>PS"
        f"</Transition><Comment>calibration</Comment><Timeout>0</Timeout><Data>{data}"
        "</Data></InitCmd></InitCmds></FoE></Mailbox>")
    lamps.find("ProcessData").addnext(mailbox)


def _mailbox_512(root: Root) -> None:
    axis = _slave(root, "axis1")
    axis.find("Mailbox/Send/Length").text = "512"
    cmd = _init_cmd(axis, "set sm 0 (mailbox out)")
    data = bytearray.fromhex(cmd.find("Data").text)
    data[2:4] = (512).to_bytes(2, "little")
    cmd.find("Data").text = data.hex()


def _unreadable_fmmu(root: Root) -> None:
    # A logical address no cyclic command covers, as EC-Engineer's encrypted settings read.
    cmd = _init_cmd(_slave(root, "lamps"), "set fmmu 0 (outputs)")
    data = bytearray.fromhex(cmd.find("Data").text)
    data[0:4] = (0xEB030B5F).to_bytes(4, "little")
    cmd.find("Data").text = data.hex()


def _encrypted_fmmu(root: Root) -> None:
    """As EC-Engineer writes an encrypted configuration: the root is
    EncryptedEtherCATConfig, the FMMU's logical address unreadable."""
    _unreadable_fmmu(root)
    root.tag = "EncryptedEtherCATConfig"


def _ca_data(slave: str, comment: str, data: str) -> Callable[[Root], None]:
    """The Data of one of ``slave``'s CoE InitCmds (by its Comment) replaced."""
    def change(root: Root) -> None:
        [cmd] = _slave(root, slave).xpath(f"Mailbox/CoE/InitCmds/InitCmd[Comment='{comment}']")
        cmd.find("Data").text = data
    change.__name__ = f"_{comment.replace(' ', '_')}"
    return change


# axis1's CompleteAccess downloads: 0x1C13 = 2: 0x1A00, 0x1A01 with a count of 1; 0x1C12 =
# 1: 0x16FF (no such PDO); 0x1A01's third entry 0x606C:00 with 16 bits instead of 32.
_1c13_count_1 = _ca_data("axis1", "download pdo 0x1C13 index", "0100001a011a")
_1c12_16ff = _ca_data("axis1", "download pdo 0x1C12 index", "0100ff16")
_1a01_606c_16_bit = _ca_data("axis1", "download pdo 0x1A01 entries",
                             "0300100041602000646010006c60")


def _register(slave: str, comment: str, change: Callable[[bytearray], None]
              ) -> Callable[[Root], None]:
    def apply(root: Root) -> None:
        cmd = _init_cmd(_slave(root, slave), comment)
        data = bytearray.fromhex(cmd.find("Data").text)
        change(data)
        cmd.find("Data").text = data.hex()
    apply.__name__ = f"_{slave}_{comment.replace(' ', '_')}"
    return apply


def _set(offset: int, value: int) -> Callable[[bytearray], None]:
    def change(data: bytearray) -> None:
        data[offset] = value
    return change


# The sensors' inputs are bits 4..7 of input byte 0 (FMMU 0: logical 0x10000000.4 to bit
# 7): an end bit 5 leaves bits 6..7 out.  axis1's inputs start at input bit 16 (its read
# FMMU at logical 0x10000002.0): a start bit 4 leaves bits 16..19 out.  axis1's SM2
# control byte 0x64 (buffered, the master writes) made 0x60 (the master reads).
_sensors_end_bit_5 = _register("sensors", "set fmmu 0 (inputs)", _set(7, 5))
_axis1_start_bit_4 = _register("axis1", "set fmmu 1 (inputs)", _set(6, 4))
_axis1_sm2_read = _register("axis1", "set sm 2 (outputs)", _set(4, 0x60))


def _axis1_sm3_from_the_esi(root: Root) -> None:
    """ProcessData names no PDO of SM3 (no Pdo in Sm3, no TxPdo); SM3 is set to 20 bytes,
    the PDOs 0x1C13 holds (0x1A00 from the ESI: 6 bytes, 0x1A01 as downloaded: 10) take 16."""
    axis = _slave(root, "axis1")
    pd = axis.find("ProcessData")
    for el in pd.xpath("Sm3/Pdo | TxPdo"):
        el.getparent().remove(el)
    cmd = _init_cmd(axis, "set sm 3 (inputs)")
    data = bytearray.fromhex(cmd.find("Data").text)
    data[2:4] = (20).to_bytes(2, "little")
    cmd.find("Data").text = data.hex()


def _axis1_watchdog_1(root: Root) -> None:
    """An InitCmd that sets axis1's SM watchdog (0x0420) to 1 unit: 100 µs with the divider
    after reset (0x09C2: 2500 × 40 ns), under the example's 1000 µs cycle; its SM2 control
    byte 0x64 has the watchdog on (bit 6)."""
    before = _init_cmd(_slave(root, "axis1"), "set sm 2 (outputs)")
    cmd = etree.fromstring(
        "<InitCmd><Transition>IP</Transition><Comment>set SM watchdog</Comment>"
        "<Requires>cycle</Requires><Cmd>5</Cmd><Adp>1005</Adp><Ado>1056</Ado>"
        "<Data>0100</Data><Retries>3</Retries></InitCmd>")
    before.addprevious(cmd)


def _axis1_sync0_cycle_0(root: Root) -> None:
    """axis1's InitCmd that writes the SYNC0 cycle (0x09A0) writes 0; the DC element still
    says 1 ms and the activation (0x0981 = 0x03) switches SYNC0 on."""
    _init_cmd(_slave(root, "axis1"), "set DC cycle time").find("Data").text = "00" * 8


def _axis1_without_mailbox(root: Root) -> None:
    axis = _slave(root, "axis1")
    axis.remove(axis.find("Mailbox"))
    for comment in ("set sm 0 (mailbox out)", "set sm 1 (mailbox in)",
                    "set sm 0 (bootstrap out)", "set sm 1 (bootstrap in)"):
        cmd = _init_cmd(axis, comment)
        cmd.getparent().remove(cmd)


def _copies(cmd: str, *copies: tuple[int, int, int]) -> Callable[[Root], None]:
    """CopyInfos (source bit, destination bit, bits) on the cyclic command ``cmd``."""
    def add(root: Root) -> None:
        parent = etree.SubElement(root.xpath(f"Config/Cyclic/Frame/Cmd[Cmd='{cmd}']")[0],
                                  "CopyInfos")
        for src, dst, bits in copies:
            info = etree.SubElement(parent, "CopyInfo")
            for tag, value in (("SrcBitOffs", src), ("DstBitOffs", dst), ("BitSize", bits)):
                etree.SubElement(info, tag).text = str(value)
    return add


# The example's images are 25 bytes; the LRW's data is input/output bytes 0..17, the
# sensors' inputs bits 4..7, the lamps' outputs bits 8..15.
_copy_past_inputs = _copies("12", (8 * 25, 8, 1))
_copy_from_al_status = _copies("7", (4, 8, 4))          # BRD 0x0130: input bytes 23..24
_copy_to_no_slave = _copies("12", (4, 0, 4))
_copies_overlap = _copies("12", (4, 8, 4), (0, 10, 4))


def _revision_9(root: Root) -> None:
    _slave(root, "lamps").find("Info/RevisionNo").text = "9"


def _axis1_state_bit_1(root: Root) -> None:
    """The line's one drive polled through MailboxStates (Count 1) at bit 1."""
    _slave(root, "axis1").find("Mailbox/Recv/StatusBitAddr").text = "1"


# rule, defect, words the message must hold (written here, not taken from the code)
DEFECTS: list[tuple[str, Callable[[Root], None], list[str]]] = [
    ("ENI001", _revision_9, ["lamps", "revision 0x9", "available"]),
    ("ENI003", _encrypted_fmmu, ["FMMU 0", "0xEB030B5F", "encrypted"]),
    ("ENI108", _unreadable_fmmu, ["lamps", "FMMU 0", "0xEB030B5F", "no cyclic command"]),
    ("ENI109", _sensors_end_bit_5, ["sensors", "ProcessData/Recv bit(s) 6..7 (2 of 4)",
                                    "no read FMMU", "to bit 5"]),
    ("ENI109", _axis1_start_bit_4, ["axis1", "ProcessData/Recv bit(s) 16..19 (4 of 128)",
                                    "logical 0x10000002.4"]),
    ("ENI110", _axis1_sm2_read, ["axis1", "SM2 (Outputs) is set with control byte 0x60",
                                 "the master reads it", "0x001D"]),
    ("ENI121", _axis1_watchdog_1,
     ["axis1", "SM watchdog 100 µs (1 × 100000 ns)", "the cycle 1000 µs", "0x001B"]),
    ("ENI122", _axis1_state_bit_1, ["axis1", "StatusBitAddr 1 lies outside "
                                             "Master/MailboxStates", "Count 1"]),
    ("ENI404", _axis1_sync0_cycle_0, ["axis1", "AssignActivate 0x0300", "0x09A0 is written 0",
                                      "0x0035"]),
    ("ENI120", _mailbox_512, ["axis1", "SM0 (0x1000..0x11FF) reaches into SM1 "
                                       "(0x1080..0x10FF)"]),
    ("ENI205", _1c13_count_1, ["0x1C13 holds 1 PDO(s) after PS (0x1A00)",
                               "ProcessData/Sm3 assigns 2 (0x1A00, 0x1A01)",
                               "SM3 is set to 16 byte(s)", "take 6", "0x001E"]),
    ("ENI205", _1c12_16ff, ["0x1C12 holds 1 PDO(s) after PS (0x16FF)", "assigns 1 (0x1601)",
                            "describes no PDO 0x16FF"]),
    ("ENI206", _1a01_606c_16_bit, ["0x1A01:03 maps 0x606C:00 16 bit after PS",
                                   "TxPdo 0x1A01 has 0x606C:00 32 bit there",
                                   "64 bit(s) where the ENI lays out 80"]),
    ("ENI207", _1c13_count_1, ["CompleteAccess download of 0x1C13 sets the count to 1 "
                               "and carries 2 entries"]),
    ("ENI208", _axis1_sm3_from_the_esi, ["0x1C13 holds 2 PDO(s) after PS (0x1A00, 0x1A01)",
                                         "16 byte(s); SM3 is set to 20"]),
    ("ENI504", _axis1_without_mailbox, ["axis1", "the ENI sets up no mailbox, the device "
                                                 "has one (SM0", "0x0016"]),
    ("ENI101", _sm2_length_8, ["SM2 (Outputs) is set to 8 byte(s)", "0x1601", "take 6"]),
    ("ENI101", _sm3_never_set, ["SM3 (Inputs) has PDOs of 16 byte(s)", "no InitCmd"]),
    ("ENI102", _lamps_fmmu_inactive, ["lamps", "SM0 (Outputs, 0x0F00", "no write FMMU"]),
    ("ENI103", _sensors_over_buttons, ["sensors", "Recv (inputs)", "buttons"]),
    ("ENI004", _big_frame, ["<Frame> of 5 commands", "1500"]),
    ("ENI104", _lrw_cnt_plus_one, ["LRW 0x10000000", "expects working counter 8", "give 7"]),
    ("ENI105", _mailbox_send_64, ["Mailbox/Send is 0x1000, 64 byte(s)", "SM0", "128"]),
    ("ENI106", _soe_cmd(), ["1 SoE InitCmd(s)", "Mailbox/Protocol lists CoE"]),
    ("ENI106", _coe_not_listed, ["CoE InitCmd(s), but Mailbox/Protocol lists EoE"]),
    ("ENI107", _soe_cmd("IP", listed=True), ["SoE write S-0-0032 (drive 0) = 0b 00 in IP",
                                             "PS, SO, SP, OP, OS"]),
    ("ENI111", _copy_past_inputs, ["outside the process image", "input bit 200 (byte 25.0)",
                                   "25 input and 25 output bytes"]),
    ("ENI112", _copy_from_al_status, ["CopyInfo 1 of cyclic BRD", "not in the command's "
                                      "input data (bits 184..199)"]),
    ("ENI113", _copy_to_no_slave, ["4 of its 4 output bits (the first: bit 0) are no "
                                   "slave's outputs"]),
    ("ENI114", _copies_overlap, ["CopyInfo 2 of cyclic LRW", "overwrites output bits 10..11 "
                                 "of CopyInfo 1 at line"]),
    ("ENI201", _mandatory_1a00_unassigned, ["TxPdo 0x1A00", "Mandatory", "not assigned"]),
    ("ENI202", _excluded_pair, ["0x1600 and 0x1601", "excludes"]),
    ("ENI203", _fixed_remapped, ["buttons", "PDO 0x1A00 is Fixed"]),
    ("ENI204", _rx_object_in_txpdo, ["0x60FF:00", "TxPDO", "'R'"]),
    ("ENI301", _coe_cmd(0x2000, 0, "01"), ["0x2000:00", "no such object"]),
    ("ENI302", _coe_cmd(0x1018, 1, "01000000"), ["0x1018:01", "read-only", "'ro'"]),
    ("ENI302", _coe_cmd(0x1C12, 0, "00", "SO"), ["0x1C12:00", "SO, in SafeOp",
                                                 "not writable then", "PreOp"]),
    ("ENI303", _coe_cmd(0x6060, 0, "0900"), ["2 byte(s) to 0x6060:00", "SINT of 1"]),
    ("ENI401", _assign_activate_0700, ["AssignActivate 0x0700", "DC 0x0300"]),
    ("ENI501", _mailbox_512, ["Mailbox/Send", "length 512", "34..256"]),
    ("ENI502", _soe_cmd(listed=True), ["SoE write S-0-0032 (drive 0)", "no SoE mailbox"]),
    ("ENI503", _foe_on_lamps, ["FoE InitCmd 'calibration'", "lists no FoE"]),
]


@pytest.mark.parametrize("rule, defect, words", DEFECTS,
                         ids=[f"{r}-{d.__name__.strip('_') if d.__name__ != 'add' else i}"
                              for i, (r, d, _) in enumerate(DEFECTS)])
def test_a_defect_fires_its_rule(tmp_path: Path, example_eni: Path, examples: Library,
                                 rule: str, defect: Callable[[Root], None],
                                 words: list[str]) -> None:
    result = check_eni(_defective(tmp_path, example_eni, defect), examples, use_cache=False)
    found = _rules(result)
    assert rule in found, found
    assert any(all(w in m for w in words) for m in found[rule]), found[rule]
    severity = all_rules()[rule].severity
    assert any(f.severity == severity for f in result.findings if f.rule == rule)


def test_copy_checks_at_the_edges_of_a_command_and_of_another_copy(
        tmp_path: Path, example_eni: Path, examples: Library) -> None:
    """A copy whose source starts in the LRW's input data (bits 0..143) and ends past it is
    ENI112 at its own line; two copies whose destinations only touch (bits 12..15, then
    8..11) overlap nowhere: no ENI114."""
    path = _defective(tmp_path, example_eni, _copies("12", (140, 8, 8)))
    result = check_eni(path, examples, use_cache=False)
    [info] = etree.parse(str(path)).xpath("//CopyInfo")      # lxml's own line count
    assert [(f.rule, f.line) for f in result.findings] == [("ENI112", info.sourceline)]
    assert "input data (bits 0..143)" in result.findings[0].message
    touching = _defective(tmp_path, example_eni, _copies("12", (0, 12, 4), (4, 8, 4)))
    assert check_eni(touching, examples, use_cache=False).findings == []
    # The other order (the later copy starts where the earlier ends), and a source that
    # ends exactly with the LRW's data (bits 136..143): nothing to report.
    edge = _defective(tmp_path, example_eni, _copies("12", (4, 8, 4), (0, 12, 4),
                                                      (136, 16, 8)))
    assert check_eni(edge, examples, use_cache=False).findings == []


def test_copy_findings_are_at_their_copy_info_lines(tmp_path: Path, example_eni: Path,
                                                    examples: Library) -> None:
    """ENI111, ENI112 (a command that writes only: the LRW as an LWR) and ENI114 each at
    the line of its CopyInfo (for ENI114 the later one), as lxml counts it."""
    def as_lwr(root: Root) -> None:
        lrw = root.xpath("Config/Cyclic/Frame/Cmd[Cmd='12']")[0]
        lrw.find("Cmd").text, lrw.find("Cnt").text = "11", "2"
        _copies("11", (4, 8, 4))(root)

    for rule, defect, index in (("ENI111", _copy_past_inputs, 0), ("ENI112", as_lwr, 0),
                                ("ENI114", _copies_overlap, 1)):
        path = _defective(tmp_path, example_eni, defect)
        info = etree.parse(str(path)).xpath("//CopyInfo")[index]
        found = [(f.line, f.message) for f in check_eni(path, examples, use_cache=False)
                 .findings if f.rule == rule]
        assert [line for line, _ in found] == [info.sourceline], (rule, found)
        if rule == "ENI112":
            assert "the command reads no input data" in found[0][1]


def test_a_copy_in_a_frame_shaped_image_is_checked_in_that_image(tmp_path: Path,
                                                                  corpus: Path) -> None:
    """TwinCAT's frame-shaped image (docs/eni-exports.md §4): the EL1809's inputs at
    BitOffs 448 = 8·(the LRD's InputOffs 46 + 10).  A copy of its channels 3-6 to the
    EL2008's channels 4-7 is in the LRD's data counted in that image: no copy finding."""
    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.eni.plan import CopyInfo
    from ecatcfg.esc import Cmd
    plan = eni_reader.read_file(corpus / "eni" / "jn-ec-master" / "mega_master_eni.xml")
    inputs = {v.name: v.bit_offs for v in plan.process_image.inputs}
    outputs = {v.name: v.bit_offs for v in plan.process_image.outputs}
    [lrd] = [c for cyc in plan.cyclic for f in cyc.frames for c in f.cmds if c.cmd == Cmd.LRD
             and c.cnt == 1]
    lrd.copy_infos = [CopyInfo(inputs["Term 4 (EL1809).Channel 3.Input"],
                               outputs["Term 2 (EL2008).Channel 4.Output"], 4)]
    path = tmp_path / "mega-copies.xml"
    path.write_bytes(eni_writer.to_bytes(plan))
    result = check_eni(path, Library([corpus / "esi" / "beckhoff"], cache=False),
                       use_cache=False)
    assert [f for f in result.findings if f.rule in ("ENI111", "ENI112", "ENI113",
                                                      "ENI114")] == []


@pytest.mark.parametrize("cmd, cnt", [(11, 2), (10, 3)])
def test_working_counters_of_lwr_and_lrd(tmp_path: Path, example_eni: Path,
                                         examples: Library, cmd: int, cnt: int) -> None:
    """The example's LRW (Cnt 7: lamps write 2, axis1 write and read 3, buttons and sensors
    read 1 each) as an LWR counts the two writers once each, as an LRD the three readers
    (ETG.1000.4); the other count is an ENI104 finding."""
    def as_cmd(expected: int) -> Callable[[Root], None]:
        def change(root: Root) -> None:
            lrw = root.xpath("Config/Cyclic/Frame/Cmd[Cmd='12']")[0]
            lrw.find("Cmd").text = str(cmd)
            lrw.find("Cnt").text = str(expected)
        return change

    right = check_eni(_defective(tmp_path, example_eni, as_cmd(cnt)), examples,
                      use_cache=False)
    assert right.findings == []
    wrong = check_eni(_defective(tmp_path, example_eni, as_cmd(7)), examples,
                      use_cache=False)
    assert [(f.rule, f"give {cnt}" in f.message) for f in wrong.findings] == [("ENI104", True)]


def test_a_copy_from_one_slaves_inputs_to_anothers_outputs_is_clean(
        tmp_path: Path, example_eni: Path, examples: Library) -> None:
    """The sensors' four input bits to lamps 3..6: in the LRW's data, received by a slave."""
    result = check_eni(_defective(tmp_path, example_eni, _copies("12", (4, 10, 4))),
                       examples, use_cache=False)
    assert result.findings == []


def test_every_rule_has_a_defect() -> None:
    covered = {r for r, _, _ in DEFECTS} | {"ENI002", "ENI402", "ENI403"}   # tested below
    assert covered == set(all_rules())


def _drive_copy(folder: Path, old: str, new: str) -> None:
    """The example ESI files in ``folder``, the drive's with ``old`` replaced by ``new``."""
    shutil.copytree(EXAMPLES / "esi", folder)
    drive = folder / "ecatcfg-EXD402-drive.xml"
    text = drive.read_text()
    assert old in text
    drive.write_text(text.replace(old, new))


def test_an_exclude_given_on_one_pdo_only_is_enough(tmp_path: Path,
                                                     example_eni: Path) -> None:
    # 0x1601 excludes 0x1600; 0x1600 no longer says so.
    _drive_copy(tmp_path / "esi", "<Exclude>#x1601</Exclude>", "")
    bad = _defective(tmp_path, example_eni, _excluded_pair)
    found = _rules(check_eni(bad, Library([tmp_path / "esi"], cache=False), use_cache=False))
    assert [m for m in found["ENI202"] if "0x1600 and 0x1601" in m and
            "(PDO 0x1601) excludes 0x1600" in m]


def test_a_fixed_sync0_cycle_other_than_the_enis_warns(tmp_path: Path,
                                                       example_eni: Path) -> None:
    _drive_copy(tmp_path / "esi", '<CycleTimeSync0 Factor="1">0</CycleTimeSync0>',
                "<CycleTimeSync0>500000</CycleTimeSync0>")
    result = check_eni(example_eni, Library([tmp_path / "esi"], cache=False))
    found = _rules(result)
    assert list(found) == ["ENI402"]
    assert "CycleTime0 is 1000000 ns" in found["ENI402"][0]
    assert "gives 500000 ns" in found["ENI402"][0]


def test_a_sync0_cycle_below_the_devices_minimum_is_an_error(tmp_path: Path,
                                                             example_eni: Path) -> None:
    """The drive's dictionary says 0x1C32:05 = 500 µs (as Beckhoff files give it): the
    example's 1 ms SYNC0 is fine; with a minimum of 2 ms (0x001E8480) it is refused."""
    from test_diagnose import SM_PARAM_OBJECT, SM_PARAM_TYPES
    for minimum, expected in (("20a10700", []), ("80841e00", ["ENI403"])):
        shutil.rmtree(tmp_path / "esi", ignore_errors=True)
        _drive_copy(tmp_path / "esi", "<DataTypes>", "<DataTypes>" + SM_PARAM_TYPES)
        _drive_copy_more(tmp_path / "esi", "<Objects>", "<Objects>" + SM_PARAM_OBJECT.replace(
            "20a10700", minimum))
        found = _rules(check_eni(example_eni, Library([tmp_path / "esi"], cache=False),
                                 use_cache=False))
        assert list(found) == expected, found
    [message] = found["ENI403"]
    assert "the SYNC0 cycle the InitCmds write (0x09A0) is 1000 µs with SYNC0 on" in message
    assert "minimum cycle time 2000 µs (ESI 0x1C32:05 default" in message
    assert "0x0035" in message


def _drive_copy_more(folder: Path, old: str, new: str) -> None:
    drive = folder / "ecatcfg-EXD402-drive.xml"
    text = drive.read_text()
    assert old in text
    drive.write_text(text.replace(old, new, 1))


def test_differing_descriptions_of_a_slave_are_named(tmp_path: Path,
                                                     example_eni: Path) -> None:
    other = tmp_path / "other"
    other.mkdir()
    text = (EXAMPLES / "esi" / "ecatcfg-EXD402-drive.xml").read_text()
    (other / "drive-v2.xml").write_text(text.replace("<Exclude>#x1601</Exclude>", "", 1))
    result = check_eni(example_eni, Library([EXAMPLES / "esi", other], cache=False))
    found = _rules(result)
    assert list(found) == ["ENI002"]
    assert "ecatcfg-EXD402-drive.xml" in found["ENI002"][0]
    assert "drive-v2.xml" in found["ENI002"][0]
    # --prefer settles it: the slave is checked against the preferred file.
    chosen = Library([EXAMPLES / "esi", other], cache=False, prefer=[other])
    assert check_eni(example_eni, chosen).findings == []


def test_every_description_of_a_duplicate_identity_is_checked(tmp_path: Path,
                                                               example_eni: Path) -> None:
    """Two ESI files describe the drive differently (the copy's DC OpMode activates
    0x0700, not 0x0300): ENI002 is an error (apply refuses the device as well), and the
    device rules still run against both descriptions: a finding both give (the InitCmd that
    writes the read-only 0x1018:01) is one line, the one only the copy gives (the ENI's
    AssignActivate 0x0300 is none of its own) is named in ENI002 with its line and file,
    never switched off."""
    other = tmp_path / "other"
    other.mkdir()
    text = (EXAMPLES / "esi" / "ecatcfg-EXD402-drive.xml").read_text()
    assert text.count("<AssignActivate>#x0300</AssignActivate>") == 1
    (other / "drive-v2.xml").write_text(text.replace("<AssignActivate>#x0300",
                                                     "<AssignActivate>#x0700"))
    path = _defective(tmp_path, example_eni, _coe_cmd(0x1018, 1, "01000000"))
    result = check_eni(path, Library([EXAMPLES / "esi", other], cache=False), use_cache=False)
    found = _rules(result)
    assert sorted(found) == ["ENI002", "ENI302"], found
    assert len(found["ENI302"]) == 1 and "0x1018:01" in found["ENI302"][0]
    [activation] = etree.parse(str(path)).xpath(
        "Config/Slave[normalize-space(Info/Name)='axis1']/InitCmds/InitCmd"
        "[Comment='set DC activation']")
    [duplicate] = found["ENI002"]
    assert (f"the device rules differ by description: ENI401 at line "
            f"{activation.sourceline} only with drive-v2.xml") in duplicate, duplicate
    assert [f.severity for f in result.findings if f.rule == "ENI002"] == ["error"]


# -- the command line -----------------------------------------------------------------------

def test_cli_formats_and_exit_codes(tmp_path: Path, example_eni: Path) -> None:
    bad = _defective(tmp_path, example_eni, _sm2_length_8)
    done = check(str(bad), "--esi", str(EXAMPLES / "esi"), "--format", "json")
    assert done.returncode == 1, done.stderr
    doc = json.loads(done.stdout)
    # The longer SM2 is ENI101; its last 2 bytes lie past the FMMU's 6: ENI102.
    assert [f["rule"] for f in doc["findings"]] == ["ENI101", "ENI102"]
    finding = doc["findings"][0]
    assert finding["severity"] == "error"
    assert finding["file"] == str(bad)
    # The line is the Sm2 element of axis1, found here with lxml.
    tree = etree.parse(str(bad))
    assert finding["line"] == _slave(tree.getroot(), "axis1").find("ProcessData/Sm2").sourceline
    assert finding["device"] == {"vendor_id": 0xE0000ECA, "product_code": 0x7201,
                                 "revision": 0x20000, "type": "axis1"}
    assert doc["summary"]["errors"] == 2

    ok = check(str(example_eni), "--esi", str(EXAMPLES / "esi"))
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.strip() == "1 file checked: 0 errors, 0 warnings, 0 infos"

    junit = check(str(bad), "--esi", str(EXAMPLES / "esi"), "--format", "junit")
    suites = etree.fromstring(junit.stdout.encode())
    failed = [c.get("name") for c in suites.iter("testcase") if c.find("failure") is not None]
    assert len(failed) == 1 and failed[0].startswith("axis1 ")

    sarif = json.loads(check(str(bad), "--esi", str(EXAMPLES / "esi"), "--format",
                             "sarif").stdout)
    assert sarif["runs"][0]["tool"]["driver"]["name"] == "ecatcfg check"
    assert [(r["ruleId"], r["level"]) for r in sarif["runs"][0]["results"]] == [
        ("ENI101", "error"), ("ENI102", "error")]

    ignored = check(str(bad), "--esi", str(EXAMPLES / "esi"), "--ignore", "ENI1")
    assert ignored.returncode == 0, ignored.stdout


def test_cli_explain_list_and_usage_errors(tmp_path: Path) -> None:
    explained = check("--explain", "eni302")
    assert explained.returncode == 0
    assert explained.stdout.startswith("ENI302 (error): ")
    assert "0x06010002" in explained.stdout
    listed = check("--list-rules").stdout.splitlines()
    assert [line.split()[0] for line in listed] == sorted(all_rules())
    assert check("--explain", "ESI101").returncode == 2
    assert check(str(tmp_path / "missing.xml")).returncode == 2
    assert check().returncode == 2
    broken = tmp_path / "broken.xml"
    broken.write_text("<EtherCATConfig>\n<Config><Slave>")
    done = check(str(broken))
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert done.stdout.startswith(f"{broken}:2") and " error ENI004 " in done.stdout


# -- real files -----------------------------------------------------------------------------

# The real defects the sweep finds, by ENI: (rule, words of the message) each.  The
# EC-Engineer export for a Synapticon SOMANET (0x22D2:0x201 revision 0x0A000002) remaps
# PDOs and the PDO assignment that the exact-revision ESI (corpus esi/drives) marks
# read-only and Fixed: the slave answers those downloads with abort 0x06010002.
REAL_DEFECTS: dict[str, set[tuple[str, str]]] = {
    # A Beremiz test ENI that lists the slaves only: no Mailbox for the Sanyo Denki RS2
    # drive, whose ESI has SM0/SM1 mailboxes (MBoxOut at 0x1800): apply --virtual --esi of
    # the file stops in INIT+ERR 0x0016, as the agreement test shows.
    "corpus-extra/beremiz-tests/wago_sanyo/config.xml": {
        ("ENI504", "the ENI sets up no mailbox, the device has one (SM0, ")},
    # The other Beremiz file gives every slave mailbox areas of start 0 and length 0 (its
    # plugin's placeholders): the HIGEN drive's ESI (same folder) has SM0/SM1 at
    # 0x1800/0x1C00 of 32..512 bytes; apply --virtual --esi refuses the file earlier, for
    # its CoE writes in INIT->INIT (tests/test_eni_only.py).
    "corpus-extra/beremiz-tests/wago_higen/config.xml": {
        ("ENI501", "'EDA7000 CoE Drive': Mailbox/Send: length 0, the ESI allows 32..512"),
        ("ENI501", "'EDA7000 CoE Drive': Mailbox/Recv: length 0, the ESI allows 32..512")},
    # One finding per object, not per subindex (26 lines before, several the
    # same finding twice).
    "corpus-extra/rocos-ecm-history/eni_sea.xml": {
        ("ENI302", "write 0x1C12:00, 0x1C12:01, read-only"),
        ("ENI302", "write 0x1C13:00, 0x1C13:01, read-only"),
        ("ENI302", "write " + ", ".join(f"0x1600:{s:02X}" for s in range(8)) + ", read-only"),
        ("ENI302", "write " + ", ".join(f"0x1A00:{s:02X}" for s in range(8)) + ", read-only"),
        ("ENI203", "PDO 0x1600 is Fixed"), ("ENI203", "PDO 0x1A00 is Fixed"),
    },
    # The HBM GEN Series DAQ is described differently by four ESI files of corpus-extra
    # esi/hbm.  For three pmec ENIs the ENI's PDOs pick one of them (the MANIFEST names
    # it), and check uses that one; this ENI's PDO set is in none of the four (the
    # MANIFEST: "none has this PDO set"): apply refuses the device until --prefer chooses,
    # and so does check (the device rules ran against each description).
    "corpus-extra/pmec-wec-bench/Pendulum2XML.xml": {
        ("ENI002", "0x11d:0xd01:0x2 (GEN Series DAQ System) is described differently by 4 "
                   "ESI files")},
}


@pytest.fixture(scope="module")
def corpora_library(corpus: Path, corpus_extra: Path) -> Library:
    # The vendor's download before the open-stack copy of the SOMANET file (a trimmed
    # description of the same identity, corpus esi/open-stacks/siitool).
    return Library([corpus / "esi", corpus_extra / "esi"], cache=False,
                   prefer=[corpus / "esi" / "drives"])


@pytest.mark.parametrize("eni", corpus_enis())
def test_corpus_enis_have_no_error_but_the_named_defects(
        request: pytest.FixtureRequest, eni: str, corpora_library: Library) -> None:
    result = check_eni(corpus_eni(request, eni), corpora_library, use_cache=False)
    errors = [f for f in result.findings if f.severity == "error"]
    expected = REAL_DEFECTS.get(eni, set())
    for f in errors:
        assert any(rule == f.rule and words in f.message for rule, words in expected), \
            f"{f.rule} {f.message}"
    for rule, words in expected:
        assert any(rule == f.rule and words in f.message for f in errors), (rule, words)


def test_the_read_only_1c12_write_is_what_the_esi_says(corpus: Path,
                                                        corpus_extra: Path) -> None:
    esi = corpus / "esi" / "drives" / "SOMANET_CiA_402.xml"
    eni = corpus_extra / "eni" / "rocos-ecm-history" / "eni_sea.xml"
    # Independently: the ENI writes 0x1C12:00 in PS, and the device of its identity in the
    # ESI gives 0x1C12's type a subindex 0 with Access ro.
    eni_root = etree.parse(str(eni)).getroot()
    info = eni_root.find("Config/Slave/Info")
    identity = (int(info.findtext("VendorId")), int(info.findtext("ProductCode")),
                int(info.findtext("RevisionNo")))
    writes = [c for c in eni_root.iterfind("Config/Slave/Mailbox/CoE/InitCmds/InitCmd")
              if c.findtext("Index") == str(0x1C12) and c.findtext("SubIndex") == "0"]
    assert writes and {c.findtext("Transition") for c in writes} == {"PS"}
    esi_root = etree.parse(str(esi)).getroot()
    [device] = [d for d in esi_root.iter("Device")
                if int(d.find("Type").get("ProductCode").replace("#x", ""), 16) == identity[1]
                and int(d.find("Type").get("RevisionNo").replace("#x", ""), 16) == identity[2]]
    [obj] = [o for o in device.iter("Object") if o.findtext("Index").lower() == "#x1c12"]
    [dtype] = [t for t in device.iter("DataType") if t.findtext("Name") == obj.findtext("Type")]
    [sub0] = [s for s in dtype.iter("SubItem") if s.findtext("SubIdx") == "0"]
    assert sub0.findtext("Flags/Access") == "ro"

    done = check(str(eni), "--esi", str(esi), "--format", "json", "--select", "ENI302")
    assert done.returncode == 1
    messages = [f["message"] for f in json.loads(done.stdout)["findings"]]
    assert any("0x1C12:00" in m and "read-only" in m for m in messages)


# -- what the compiler writes from the corpus -------------------------------------------------

# Every 6th device of both corpora (sorted, tests/sweep.py), and the devices named below;
# ECATCFG_CHECK_EVERY=1 compiles and checks every device (about 1,500: a few minutes).
EVERY = int(os.environ.get("ECATCFG_CHECK_EVERY", "6"))

# The real defects of ENIs compiled from corpus devices, by device key: (rule, words).
# None at present: the two this sweep found (an EL2252 revision whose ESI describes PDO
# 0x1602 twice, written twice into the ENI; IgH's dump of a UR20 coupler whose untyped
# SyncManagers got none of its Mandatory PDOs) are compile's refusal and a compiled ENI
# now, each checked below.
COMPILED_DEFECTS: dict[str, set[tuple[str, str]]] = {}


def test_enis_compiled_from_the_corpus_have_no_error_but_the_named_defects(
        tmp_path: Path, corpus: Path, corpus_extra: Path) -> None:
    import sweep

    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer
    from ecatcfg.errors import EcatcfgError

    corpora = {"corpus": corpus, "corpus-extra": corpus_extra}
    every = sweep.cases(corpora)
    chosen = sweep.sample(every, EVERY) + [c for c in every if c.key in COMPILED_DEFECTS
                                           and c not in every[::EVERY]]
    worker = sweep.Worker(corpora)
    checked, unexpected, seen = 0, [], set()
    for case in chosen:
        lib = worker.library(case)
        if lib.problems:
            continue
        [entry] = [e for e in lib.entries if e.ordinal == case.ordinal
                   and e.file == lib.files[0].shown]
        device = lib.device(entry)
        if device.passive:
            continue
        slave: dict[str, object] = {"name": "dut", "device": case.selector}
        needed = sweep._required_modules(device, lib.modules_for(entry))
        if needed:
            slave["modules"] = needed
        try:
            if lib.find(case.selector).entry.ordinal != case.ordinal:
                continue                      # another Device element has this identity
            plan = build.compile_topology(topology.loads(
                json.dumps({"master": {"name": "m"}, "slaves": [slave]}), "t.yaml"), lib).plan
        except EcatcfgError:
            continue                          # compile refuses it (test_sweep_devices)
        eni = tmp_path / "compiled.xml"
        eni.write_bytes(writer.to_bytes(plan))
        checked += 1
        expected = COMPILED_DEFECTS.get(case.key, set())
        for f in check_eni(eni, lib, use_cache=False).findings:
            if f.severity != "error":
                continue
            named = {(r, w) for r, w in expected if r == f.rule and w in f.message}
            seen |= named
            if not named:
                unexpected.append(f"{case.key}: {f.rule} {f.message}")
    assert checked >= 1400 // EVERY
    assert unexpected == []
    assert seen == set().union(*COMPILED_DEFECTS.values())


def test_the_el2252_revision_describing_0x1602_twice_is_refused_at_both_lines(
        corpus: Path, tmp_path: Path) -> None:
    from ecatcfg.compiler import build, topology
    from ecatcfg.compiler.topology import TopologyError
    from ecatcfg.eni import writer
    from ecatcfg.esi.library import Library as Lib

    esi = corpus / "esi" / "beckhoff" / "Beckhoff EL2xxx.xml"
    # Independently: the device's RxPdo elements of index 0x1602, by lxml.
    root = etree.parse(str(esi)).getroot()
    [device] = [d for d in root.iter("Device") if d.findtext("Type") == "EL2252"
                and d.find("Type").get("RevisionNo") == "#x00110000"]
    twice = [p for p in device.iterfind("RxPdo") if p.findtext("Index").lower() == "#x1602"]
    assert [p.get("Virtual") for p in twice] == ["true", None]
    lib = Lib([esi], cache=False)
    text = json.dumps({"master": {"name": "m"},
                       "slaves": [{"name": "dut", "device": "0x2:0x8cc3052:0x110000"}]})
    with pytest.raises(TopologyError) as exc:
        build.compile_topology(topology.loads(text, "t.json"), lib, allow_esi_errors=True)
    message = str(exc.value)
    assert "EL2252 describes PDO 0x1602 twice" in message
    assert all(f"{esi}:{p.sourceline}" in message for p in twice)
    # The next revision gives the real PDO its own index: compiled, the check finds nothing.
    text = text.replace("0x110000", "0x120000")
    eni = tmp_path / "el2252.xml"
    eni.write_bytes(writer.to_bytes(
        build.compile_topology(topology.loads(text, "t.json"), lib).plan))
    assert [f for f in check_eni(eni, lib, use_cache=False).findings
            if f.severity == "error"] == []


def test_the_igh_dump_of_a_ur20_gets_its_mandatory_pdos(corpus_extra: Path,
                                                         tmp_path: Path) -> None:
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer
    from ecatcfg.esi.library import Library as Lib

    esi = corpus_extra / "esi" / "ethercat-esi" / "Weidmueller_UR20_FBC_from_IgH.xml"
    # Independently: the Sm elements have no text, and the Mandatory PDOs name SM 2 and 3.
    root = etree.parse(str(esi)).getroot()
    assert [(sm.text or "").strip() for sm in root.iter("Sm")] == ["", "", "", ""]
    wanted = {sm: [int(p.findtext("Index").replace("#x", ""), 16) for p in root.iter(tag)
                   if p.get("Mandatory") == "1" and p.get("Sm") == str(sm)]
              for sm, tag in ((2, "RxPdo"), (3, "TxPdo"))}
    assert len(wanted[2]) == len(wanted[3]) == 5
    lib = Lib([esi], cache=False)
    text = json.dumps({"master": {"name": "m"},
                       "slaves": [{"name": "dut", "device": "UR20-FBC-EC"}]})
    eni = tmp_path / "ur20.xml"
    eni.write_bytes(writer.to_bytes(
        build.compile_topology(topology.loads(text, "t.json"), lib).plan))
    pd = etree.parse(str(eni)).getroot().find("Config/Slave/ProcessData")
    for sm, kind in ((2, "Outputs"), (3, "Inputs")):
        el = pd.find(f"Sm{sm}")
        assert el.findtext("Type") == kind
        assert sorted(int(x.text) for x in el.iterfind("Pdo")) == sorted(wanted[sm])
    assert [f for f in check_eni(eni, lib, use_cache=False).findings
            if f.severity == "error"] == []


def test_a_copy_after_one_the_reader_left_out_is_not_given_the_left_out_ones_line(
        tmp_path: Path, example_eni: Path, examples: Library) -> None:
    """The first CopyInfo lies outside the images (ENI111, at its own line) and leaves the
    plan; the second, kept, writes bits no slave receives (ENI113).  Counted among the
    kept copies the second is the first: its finding names the command's line, never the
    line of the copy that was left out."""
    tree = etree.parse(str(example_eni))
    _copies("12", (8 * 25, 8, 1), (4, 0, 4))(tree.getroot())
    etree.indent(tree)                        # each CopyInfo on lines of its own
    eni = tmp_path / "copies.xml"
    tree.write(str(eni), xml_declaration=True, encoding="UTF-8")
    tree = etree.parse(str(eni))
    lrw = tree.getroot().xpath("Config/Cyclic/Frame/Cmd[Cmd='12']")[0]
    outside, kept = lrw.iterfind("CopyInfos/CopyInfo")
    result = check_eni(eni, examples, use_cache=False)
    lines = {f.rule: f.line for f in result.findings}
    assert lines["ENI111"] == outside.sourceline
    assert lines["ENI113"] in (kept.sourceline, lrw.sourceline)
