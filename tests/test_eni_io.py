"""ENI writer and reader: our own files round-trip exactly and validate against the 2011
ETG.2100 schema; every real ENI of both corpora (../shared/corpus/eni and
../shared/corpus-extra/eni) reads, with counts that agree with an
independent XPath count on the raw XML; bad input is a one-line EcatcfgError."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
from lxml import etree

from conftest import corpus_eni, corpus_enis

from ecatcfg.eni.reader import EniReadError, read_bytes, read_file
from ecatcfg.eni.writer import to_bytes, write
from ecatcfg.eni.plan import (
    BitRange,
    CoeInitCmd,
    Cyclic,
    CyclicCmd,
    DcPlan,
    Frame,
    HotConnectPlan,
    InitCmd,
    MailboxArea,
    MailboxPlan,
    MasterPlan,
    NetworkPlan,
    PdoDesc,
    PdoEntryDesc,
    PreviousPort,
    ProcessData,
    ProcessImage,
    SlavePlan,
    SmSettings,
    Validate,
    Variable,
)
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import Transition as T

# --- a small, rich plan built by hand -------------------------------------------------------


def _master() -> MasterPlan:
    return MasterPlan(
        name="ecatcfg master",
        source=bytes.fromhex("020000000001"),
        mailbox_states=(0x09000000, 1),
        init_cmds=[
            InitCmd([T.IP], "read slave count", cmd=7, length=2, adp=0, ado=0x0130,
                    data=b"\x00\x00", retries=0, requires="cycle", before_slave=True),
            InitCmd([T.IP, T.PI, T.BI, T.SI, T.OI], "clear fmmu", cmd=8, length=256, adp=0,
                    ado=0x0600, retries=3, requires="cycle", before_slave=True),
            InitCmd([T.IP], "en/disable second physical address", cmd=8, length=1, adp=0,
                    ado=0x0103, data=b"\x00", retries=3, requires="cycle", before_slave=False),
        ])


def _coupler() -> SlavePlan:
    return SlavePlan(
        name="Term 1 (EK1100)", phys_addr=1001, auto_inc_addr=0, vendor_id=0xE0000ECA,
        product_code=0x044C2C52, revision=0x80120000, serial_no=0xFFFFFFFF, physics="YYY",
        init_cmds=[
            InitCmd([T.IP], "set physical address", cmd=2, length=2, adp=0, ado=0x0010,
                    data=bytes.fromhex("e903"), cnt=1, retries=3),
            InitCmd([T.IP], "check device state for PREOP", cmd=4, length=6, adp=1001,
                    ado=0x0130, data=bytes(6), cnt=1, retries=3, requires="cycle",
                    validate=Validate(bytes.fromhex("020000000000"),
                                      bytes.fromhex("1f0000000000"), 10000)),
            InitCmd([T.IP], "check vendor id", cmd=1, length=4, adp=0, ado=0x0508,
                    data=bytes(4), validate=Validate(bytes.fromhex("02000000"), None, 100)),
        ])


def _drive() -> SlavePlan:
    pdos = [
        PdoDesc("rx", 0x1600, "Outputs", sm=2, fixed=True, mandatory=True,
                excludes=[0x1601], entries=[
                    PdoEntryDesc(0x6040, 0, 16, "Control word", "UINT"),
                    PdoEntryDesc(0, 0, 8),                                  # padding
                    PdoEntryDesc(0x607A, 0, 32, "Target position", "DINT")]),
        PdoDesc("tx", 0x1A00, "Inputs", sm=3, entries=[
            PdoEntryDesc(0x6041, 0, 16, "Status word", "UINT")]),
        PdoDesc("rx", 0x1601, "Alt outputs", virtual=True, excludes=[0x1600]),
    ]
    sms = [SmSettings(2, "Outputs", 0x1100, 0x64, True, pdos=[0x1600], min_size=0,
                      max_size=32, default_size=32, virtual=False, watchdog=1),
           SmSettings(3, "Inputs", 0x1180, 0x20, True, pdos=[0x1A00], default_size=32)]
    mailbox = MailboxPlan(
        send=MailboxArea(0x1800, 140), recv=MailboxArea(0x1900, 140),
        protocols=["CoE", "FoE"], status_bit_addr=1,
        bootstrap_send=MailboxArea(0x1000, 244), bootstrap_recv=MailboxArea(0x10F4, 244),
        coe_init_cmds=[
            CoeInitCmd([T.PS], "download pdo 0x1C12 index", 0x1C12, 0,
                       bytes.fromhex("0100 0016"), complete_access=True, fixed=True),
            CoeInitCmd([T.PS, T.SO], "Op mode", 0x6060, 0, b"\x08", timeout=3000),
            CoeInitCmd([T.PS], "", 0x2000, 1, b"", ccs=1, disabled=True),
        ],
        coe_profiles=[(402, None), (5001, "extra")],
        data_link_layer=True)
    return SlavePlan(
        name="Drive 1 <α & β>", phys_addr=1002, auto_inc_addr=0xFFFF, vendor_id=0x9A,
        product_code=0x00030924, revision=0x00010420, serial_no=12345,
        process_data=ProcessData(send=[BitRange(0, 56)], recv=[BitRange(0, 16)], sms=sms,
                                 pdos=pdos),
        mailbox=mailbox,
        init_cmds=[
            InitCmd([T.PS], "set sm 2 (outputs)", cmd=5, length=8, adp=1002, ado=0x0810,
                    data=bytes.fromhex("00110e0064000100"), cnt=1, retries=3),
            InitCmd([T.PS], "set dc start time", cmd=5, length=8, adp=1002, ado=0x0990,
                    requires="cycle"),
        ],
        dc=DcPlan(reference_clock=True, cycle_time0=1_000_000, cycle_time1=0, shift_time=0),
        previous_ports=[PreviousPort("B", 1001, True), PreviousPort("C", None, False),
                        PreviousPort("D")],
        # A group of one, recognised by its station alias 0x0012 = 7 at position 1.
        hot_connect=HotConnectPlan(1, [
            InitCmd([], "check station alias", cmd=1, length=2, adp=0xFFFF, ado=0x0012,
                    cnt=1, validate=Validate(b"\x07\x00", b"\xff\xff", 100))]))


def _cyclic() -> list[Cyclic]:
    frame = Frame(comment="frame 0", cmds=[
        CyclicCmd(["PREOP", "SAFEOP", "OP"], "DC; ARMW; System Time Register", cmd=13,
                  length=4, adp=0, ado=0x0910, input_offs=16, output_offs=16),
        CyclicCmd(["SAFEOP", "OP"], "PD; LRW;", cmd=12, length=7, addr=0x10000000, cnt=3,
                  input_offs=30, output_offs=30),
        CyclicCmd(["OP"], "", cmd=8, length=2, ado=0x0120, data=b"\x08\x00"),
    ])
    second = Frame([CyclicCmd(["SAFEOP"], "", cmd=7, length=2, adp=0, ado=0x0130, cnt=2)])
    return [Cyclic(frames=[frame], cycle_time=1000, comment="task 1"), Cyclic(frames=[second])]


def rich_plan() -> NetworkPlan:
    image = ProcessImage(
        inputs_size=2, outputs_size=7,
        inputs=[Variable("Drive 1.Inputs.Status word", 16, 0, "UINT")],
        outputs=[Variable("Drive 1.Outputs.Control word", 16, 0, "UINT", comment=""),
                 Variable("Drive 1.Outputs.Target position", 32, 24, "DINT", "pos")])
    return NetworkPlan(master=_master(), slaves=[_coupler(), _drive()], cyclic=_cyclic(),
                       process_image=image)


# --- our own files --------------------------------------------------------------------------


def test_round_trip_gives_an_equal_plan():
    plan = rich_plan()
    assert read_bytes(to_bytes(plan), "ours.xml") == plan
    assert read_bytes(to_bytes(plan, generator="ecatcfg 1.0"), "ours.xml") == plan


def test_output_is_deterministic_and_spelled_like_the_real_files():
    data = to_bytes(rich_plan(), generator="ecatcfg 1.0")
    assert data == to_bytes(copy.deepcopy(rich_plan()), generator="ecatcfg 1.0")
    text = data.decode("utf-8")
    assert text.startswith('<?xml version="1.0" encoding="UTF-8"?>\n'
                           "<!-- Created with ecatcfg 1.0 -->\n<EtherCATConfig ")
    assert 'Version="1.3"' in text and 'xsi:noNamespaceSchemaLocation="EtherCATConfig.xsd"' in text
    assert "\n  <Config>\n    <Master>\n" in text                 # 2-space indentation
    assert "<Ado>304</Ado>" in text and "<Data>00110e0064000100</Data>" in text
    assert "<DataLength>256</DataLength>" in text and "<Index>#x1a00</Index>" in text
    assert "<BeforeSlave>1</BeforeSlave>" in text and "true" not in text
    assert "<Name>Drive 1 &lt;α &amp; β&gt;</Name>" in text and "CDATA" not in text
    assert "<Addr>268435456</Addr>" in text
    # uint32 values beyond xs:int in their signed spelling; read back unsigned.
    assert "<VendorId>-536867126</VendorId>" in text and "<SerialNo>-1</SerialNo>" in text


def test_init_cmd_timeout_is_not_written():
    plan = rich_plan()
    plan.slaves[0].init_cmds[0].timeout = 4321
    text = to_bytes(plan).decode()
    assert "<Timeout>4321</Timeout>" not in text
    assert read_bytes(to_bytes(plan), "x").slaves[0].init_cmds[0].timeout is None


def test_comment_cannot_be_broken_by_the_generator_name():
    data = to_bytes(rich_plan(), generator="x -- y --->")
    etree.fromstring(data)                                    # still well-formed


def test_write_and_read_file(tmp_path: Path):
    path = tmp_path / "net.xml"
    write(rich_plan(), path)
    assert read_file(path) == rich_plan()
    assert [p.name for p in tmp_path.iterdir()] == ["net.xml"]


def test_written_file_validates_against_the_2011_schema(eni_schema):
    for generator in (None, "ecatcfg"):
        doc = etree.fromstring(to_bytes(rich_plan(), generator))
        assert eni_schema.validate(doc), eni_schema.error_log


def test_minimal_plan_validates(eni_schema):
    plan = NetworkPlan(master=MasterPlan(name="m"))
    doc = etree.fromstring(to_bytes(plan))
    assert eni_schema.validate(doc), eni_schema.error_log
    assert read_bytes(to_bytes(plan), "x") == plan


def test_sync_managers_are_written_in_schema_order():
    plan = rich_plan()
    plan.slaves[1].process_data.sms.reverse()
    assert [sm.number for sm in read_bytes(to_bytes(plan), "x").slaves[1].process_data.sms] \
        == [2, 3]


@pytest.mark.parametrize("change, message", [
    (lambda p: setattr(p.master.init_cmds[0], "addr", 5), "both"),
    (lambda p: setattr(p.master.init_cmds[0], "ado", None), "needs Ado"),
    (lambda p: setattr(p.master.init_cmds[0], "length", 3), "length"),
    (lambda p: setattr(p.slaves[1].mailbox, "bootstrap_recv", None), "BootStrap"),
    (lambda p: p.slaves[1].process_data.sms.append(SmSettings(2, "Outputs", 0, 0, True)),
     "Sm0..Sm3"),
    (lambda p: p.cyclic[1].frames[0].cmds.clear(), "Frame"),
    (lambda p: p.cyclic[1].frames.clear(), "Cyclic"),
    (lambda p: setattr(p.slaves[0], "vendor_id", -1), "32-bit"),
    (lambda p: setattr(p.cyclic[0].frames[0].cmds[1], "addr", 1 << 32), "32-bit"),
])
def test_plans_the_schema_cannot_express_are_refused(change, message):
    plan = rich_plan()
    change(plan)
    with pytest.raises(ValueError, match=message):
        to_bytes(plan)


# --- the real files -------------------------------------------------------------------------


def _config(path: Path) -> etree._Element:
    root = etree.parse(str(path)).getroot()
    return root.find("Config")


def xpath_facts(path: Path) -> dict:
    """What the raw XML says, counted with plain XPath (independent of the reader)."""
    config = _config(path)
    # A slave without PhysAddr and AutoIncAddr and without anything only an ESC has
    # (mailbox, InitCmds, process data, DC) has no ESC (a passive end cap, as TwinCAT writes
    # the EL9011): counted apart.  One with a mailbox but no address (SOEM's hand-written
    # sample) is an ESC slave at its order in the file, as SOEM's converter
    # (scripts/eniconv.py) places it, numbered as compile numbers station addresses.
    esc = ("Info/PhysAddr or Info/AutoIncAddr or Mailbox or InitCmds/* or ProcessData/* "
           "or DC or HotConnect")
    slaves = config.xpath(f"Slave[{esc}]")
    return {
        "master_cmds": int(config.xpath("count(Master/InitCmds/InitCmd)")),
        "passive": int(config.xpath(f"count(Slave[not({esc})])")),
        "slaves": [(int(s.xpath("string(Info/PhysAddr)") or 1001 + n),
                    int(s.xpath("string(Info/VendorId)")),
                    int(s.xpath("string(Info/ProductCode)"), 0),
                    int(s.xpath("count(InitCmds/InitCmd)")),
                    int(s.xpath("count(Mailbox/CoE/InitCmds/InitCmd)")),
                    int(s.xpath("count(ProcessData/RxPdo | ProcessData/TxPdo)")))
                   for n, s in enumerate(slaves)],
        "cyclic_cmds": int(config.xpath("count(Cyclic/Frame/Cmd)")),
        "variables": int(config.xpath("count(ProcessImage/*/Variable)")),
    }


def plan_facts(plan: NetworkPlan) -> dict:
    """The plan's counts; InitCmds it leaves out as refused (encrypted FMMU settings, CoE
    writes in INIT->INIT) are counted from ``unsupported``, so every command of the file is
    accounted for."""
    def dropped(name: str, element: str = "Slave/InitCmds/InitCmd") -> int:
        return sum(p.commands for p in plan.unsupported
                   if p.slave == name and p.element == element)

    return {
        "master_cmds": len(plan.master.init_cmds),
        "passive": len(plan.passive),
        "slaves": [(s.phys_addr, s.vendor_id, s.product_code,
                    len(s.init_cmds) + dropped(s.name),
                    (len(s.mailbox.coe_init_cmds) if s.mailbox else 0)
                    + dropped(s.name, "CoE/InitCmds/InitCmd"),
                    len(s.process_data.pdos) if s.process_data else 0)
                   for s in plan.slaves],
        "cyclic_cmds": sum(len(f.cmds) for c in plan.cyclic for f in c.frames),
        "variables": len(plan.process_image.inputs) + len(plan.process_image.outputs),
    }


def test_corpus_has_the_eni_files(corpus, corpus_extra):
    names = set(corpus_enis())
    assert len([n for n in names if n.startswith("corpus/")]) == 10
    assert {"corpus/rocos-ethercat/eni.xml", "corpus/rocos-ethercat/eni1.xml",
            "corpus/jn-ec-master/mega_master_eni.xml",
            "corpus/murrelektronik-variox/eni.xml"} <= names
    # corpus-extra's MANIFEST.md: 16 ENIs from 5 repositories' folders, and 17 more from 10
    # folders of 8 repositories (its section of files added 2026-11-29).
    extra = {n.split("/")[1] for n in names if n.startswith("corpus-extra/")}
    assert len([n for n in names if n.startswith("corpus-extra/")]) == 33
    assert extra == {"hydra", "altinay-networkdata", "altinay-moobot", "rocos-ecm-history",
                     "marcelgehrig-ethercattest", "pmec-wec-bench", "pmec-fostwin",
                     "pmec-lupa", "pmec-foswec2", "pmec-linear-actuator", "minzesun-speedgoat",
                     "marcelgehrig-ectest", "beremiz-tests", "soem-sample"}
    assert {"corpus-extra/hydra/hydra_wholebody_20160108_DC.xml",
            "corpus-extra/rocos-ecm-history/eni_sea.xml"} <= names


@pytest.mark.parametrize("eni", corpus_enis())
def test_every_corpus_eni_reads_with_matching_counts(request, eni, eni_schema):
    path = corpus_eni(request, eni)
    plan = read_file(path)
    assert plan_facts(plan) == xpath_facts(path), path
    assert plan.slaves, path
    # Re-written, every real file validates and reads back the same (InitCmd timeouts
    # are the one thing the 2011 schema cannot carry).
    data = to_bytes(plan)
    assert eni_schema.validate(etree.fromstring(data)), (path, eni_schema.error_log)
    for cmd in [*plan.master.init_cmds, *(c for s in plan.slaves for c in s.init_cmds)]:
        cmd.timeout = None
    plan.unsupported = []           # the writer writes what the plan holds, nothing refused
    assert read_bytes(data, "rewritten.xml") == plan, path


def test_ec_engineer_file_values(corpus):
    plan = read_file(corpus / "eni" / "rocos-ethercat" / "eni.xml")
    drive = plan.slaves[0]
    assert (drive.phys_addr, drive.auto_inc_addr, drive.vendor_id) == (1001, 0, 154)
    sm2 = next(c for c in drive.init_cmds if c.comment == "set sm 2 (outputs)")
    assert (sm2.data.hex(), sm2.cmd, sm2.adp, sm2.ado, sm2.transitions) == (
        "00110e0064000100", 5, 1001, 0x0810, [T.PS])
    lrw = next(c for c in plan.cyclic[0].frames[0].cmds if c.cmd == 12)
    assert (lrw.addr, lrw.length, lrw.cnt, lrw.data, lrw.states) == (
        268435456, 14, 3, None, ["SAFEOP", "OP"])
    assert plan.cyclic[0].cycle_time == 1000
    assert plan.process_image.inputs_size == 28
    assert plan.master.init_cmds[0].before_slave is True
    clear_fmmu = next(c for c in plan.master.init_cmds if c.comment == "clear fmmu")
    assert (clear_fmmu.data, clear_fmmu.length, clear_fmmu.payload) == (None, 256, bytes(256))
    assert plan.master.destination == b"\xff" * 6 and plan.master.ether_type == b"\xa4\x88"
    assert drive.dc == DcPlan(True, 1_000_000, 0, 0)
    tx = next(p for p in drive.process_data.pdos if p.index == 0x1A00)
    assert (tx.direction, tx.fixed, tx.excludes[0], tx.entries[2].index) == (
        "tx", True, 0x1A01, 0x6041)


def test_twincat_file_values(corpus):
    plan = read_file(corpus / "eni" / "jn-ec-master" / "mega_master_eni.xml")
    el2008 = plan.slave("Term 2 (EL2008)")
    assert el2008.auto_inc_addr == 65535 and el2008.position == 1
    so = next(c for c in el2008.init_cmds if c.comment == "set sm 0 (outputs)")
    assert (so.data.hex(), so.transitions, so.retries) == ("000f010044000100", [T.SO], 3)
    assert plan.master.init_cmds[0].before_slave is True                 # "true"
    assert plan.master.mailbox_states == (0x09000000, 1)
    init = next(c for c in el2008.init_cmds
                if c.comment == "set device state to INIT" and T.IP in c.transitions)
    assert init.timeout == 3000
    assert el2008.previous_ports == [PreviousPort("B", 1001, True)]   # Selected="true"
    assert plan.process_image.inputs_size == 1536


def test_encrypted_root_with_clear_body(corpus):
    plan = read_file(corpus / "eni" / "murrelektronik-variox" / "eni.xml")
    assert plan.version == "1.3" and len(plan.slaves) == 2
    coupler = plan.slaves[0]
    assert coupler.process_data == ProcessData()               # <ProcessData />
    assert coupler.dc is None                                  # PotentialReferenceClock only


def test_elmo_application_studio_dialect(corpus):
    plan = read_file(corpus / "eni" / "rocos-ethercat" / "eni1.xml")
    assert plan.version is None
    drive = plan.slaves[0]
    assert (drive.name, drive.phys_addr, drive.physics) == ("Elmo Drive", 1001, "YY")
    assert drive.mailbox.protocols == ["EoE", "FoE", "CoE"]
    assert [c.complete_access for c in drive.mailbox.coe_init_cmds] == [True, True, False, False]
    assert drive.mailbox.coe_init_cmds[0].data.hex() == "05000a1a0e1a111a131a1d1a"
    assert drive.mailbox.coe_init_cmds[0].timeout == 10000
    assert [c.addr for c in plan.cyclic[0].frames[0].cmds] == [0x11000, 0x12000]


def test_complete_access_and_status_bit(corpus):
    plan = read_file(corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml")
    slave = plan.slaves[1]
    assert slave.mailbox.status_bit_addr == 1 and slave.mailbox.data_link_layer is True
    cmd = next(c for c in slave.mailbox.coe_init_cmds if c.comment == "download pdo 0x1C12 index")
    assert (cmd.complete_access, cmd.fixed, cmd.data.hex()) == (True, True, "020000160116")


# --- tolerance and bad input ----------------------------------------------------------------

_SMALL = """<?xml version="1.0"?>
<EtherCATConfig Version="1.3">
  <Config>
    <Master><Info><Name>m</Name><Destination>ffffffffffff</Destination>
      <Source>000000000000</Source></Info></Master>
    <Slave>
      <Info><Name>s</Name><PhysAddr>{phys}</PhysAddr><AutoIncAddr>-1</AutoIncAddr>
        <Physics>YY</Physics><VendorId>#x9a</VendorId><ProductCode>0x10</ProductCode>
        <RevisionNo>1</RevisionNo><SerialNo>0</SerialNo></Info>
      <InitCmds>
        <InitCmd><Transition>{transition}</Transition><Cmd>{cmd}</Cmd><Adp>0</Adp>
          <Ado>16</Ado><Data>E903</Data><Timeout>100</Timeout><Unknown/></InitCmd>
      </InitCmds>
      <HotConnect><GroupMemberCnt>1</GroupMemberCnt><IdentifyCmd><Cmd>1</Cmd><Adp>-1</Adp>
        <Ado>#x12</Ado><DataLength>2</DataLength></IdentifyCmd></HotConnect>
    </Slave>
  </Config>
</EtherCATConfig>
"""


def small(phys: str = "1001", transition: str = "IP", cmd: str = "2") -> bytes:
    return _SMALL.format(phys=phys, transition=transition, cmd=cmd).encode()


def test_tolerant_reading_of_numbers_and_unknown_elements():
    plan = read_bytes(small(), "small.xml")
    slave = plan.slaves[0]
    assert (slave.auto_inc_addr, slave.vendor_id, slave.product_code) == (0xFFFF, 0x9A, 0x10)
    assert slave.init_cmds[0].data == b"\xe9\x03" and slave.init_cmds[0].timeout == 100
    assert plan.master.ether_type == b"\xa4\x88" and plan.process_image == ProcessImage()
    group = slave.hot_connect
    assert group is not None and group.member_count == 1
    assert [(c.cmd, c.adp, c.ado, c.length) for c in group.identify_cmds] == [
        (1, 0xFFFF, 0x12, 2)]


@pytest.mark.parametrize("data, line, words", [
    (small(phys="abc"), 7, "PhysAddr"),
    (small(phys="12abc"), 7, "not a number"),
    (small(phys="9" * 5000), 7, "not a number"),
    (small().replace(b"<Slave>", b'<Slave><Mailbox DataLinkLayer="yes"><Send><Start>1</Start>'
                     b"<Length>1</Length></Send><Recv><Start>1</Start><Length>1</Length>"
                     b"</Recv></Mailbox>"), 6, "DataLinkLayer"),
    (small(cmd="LWR"), 11, "<Cmd>"),
    (small(transition="XY"), 11, "unknown transition"),
    (small().replace(b"<PhysAddr>1001</PhysAddr>", b""), 7, "PhysAddr"),
    (small().replace(b"E903", b"E90"), 12, "hex"),
    (small().replace(b"<Ado>16</Ado>", b""), 11, "neither <Ado> nor <Addr>"),
    (small()[:300], None, "not well-formed"),
    (b'<?xml version="1.0"?>\n<EtherCATInfo Version="1.17"/>\n', 2, "root element"),
    (b'<?xml version="1.0"?>\n<EtherCATConfig/>\n', 2, "<Config>"),
    (b'<?xml version="1.0"?>\n<!DOCTYPE x [\n<!ENTITY e "boom">\n]>\n'
     b"<EtherCATConfig><Config/></EtherCATConfig>\n", 3, "entity"),
])
def test_bad_input_is_a_located_error(data: bytes, line: int | None, words: str):
    with pytest.raises(EcatcfgError) as info:
        read_bytes(data, "bad.xml")
    error = info.value
    assert error.file == "bad.xml" and words in error.message
    if line is not None:
        assert error.line == line
    else:
        assert error.line
    assert str(error).startswith("bad.xml:")


def _group_eni(counts: dict[int, str], identify: str = "<IdentifyCmd><Cmd>1</Cmd>"
               "<Ado>18</Ado><DataLength>2</DataLength></IdentifyCmd>") -> bytes:
    """Three slaves; slave ``i`` in ``counts`` heads a group with that GroupMemberCnt."""
    slaves = []
    for i in range(3):
        group = (f"<HotConnect><GroupMemberCnt>{counts[i]}</GroupMemberCnt>{identify}"
                 "</HotConnect>" if i in counts else "")
        slaves.append(
            f"<Slave><Info><Name>s{i}</Name><PhysAddr>{1001 + i}</PhysAddr>"
            f"<AutoIncAddr>{-i}</AutoIncAddr><VendorId>2</VendorId><ProductCode>3"
            f"</ProductCode><RevisionNo>0</RevisionNo></Info>\n{group}</Slave>\n")
    return ("<EtherCATConfig><Config><Master><Info><Name>m</Name></Info></Master>\n"
            + "".join(slaves) + "</Config></EtherCATConfig>\n").encode()


def _line_of(data: bytes, xpath: str) -> int:
    return etree.fromstring(data).xpath(xpath)[0].sourceline


@pytest.mark.parametrize("counts, identify, at, words", [
    ({1: "0"}, None, "//Slave[2]/HotConnect/GroupMemberCnt", "at least its head"),
    ({1: "-3"}, None, "//Slave[2]/HotConnect/GroupMemberCnt", "at least its head"),
    ({1: "3"}, None, "//Slave[2]/HotConnect/GroupMemberCnt",
     "only 2 slaves from the group's head 's1'"),
    ({2: "2"}, None, "//Slave[3]/HotConnect/GroupMemberCnt", "only 1 slave from"),
    ({1: "two"}, None, "//Slave[2]/HotConnect/GroupMemberCnt", "not a number"),
    ({0: "2", 1: "1"}, None, "//Slave[2]/HotConnect/GroupMemberCnt",
     "already in the group of 's0'"),
    ({1: "1"}, "", "//Slave[2]/HotConnect", "no <IdentifyCmd>"),
    ({1: "1"}, "<IdentifyCmd><Cmd>1</Cmd><DataLength>2</DataLength></IdentifyCmd>",
     "//Slave[2]/HotConnect/IdentifyCmd", "neither <Ado> nor <Addr>"),
    ({1: "1"}, "<IdentifyCmd><Cmd>1</Cmd><Ado>18</Ado><Data>0g</Data></IdentifyCmd>",
     "//Slave[2]/HotConnect/IdentifyCmd/Data", "hex"),
])
def test_bad_hot_connect_group_is_a_located_error(counts, identify, at, words):
    data = _group_eni(counts) if identify is None else _group_eni(counts, identify)
    with pytest.raises(EniReadError) as info:
        read_bytes(data, "groups.xml")
    assert words in info.value.message, info.value.message
    assert (info.value.file, info.value.line) == ("groups.xml", _line_of(data, at))


def test_hot_connect_groups_that_fit_are_read():
    """Two groups side by side, the second up to the last slave."""
    plan = read_bytes(_group_eni({0: "1", 1: "2"}), "groups.xml")
    assert [s.hot_connect.member_count if s.hot_connect else None for s in plan.slaves] == [
        1, 2, None]


def test_a_group_without_identify_cmds_is_not_written():
    plan = rich_plan()
    plan.slaves[1].hot_connect.identify_cmds.clear()
    with pytest.raises(ValueError, match="IdentifyCmd"):
        to_bytes(plan)


def test_hot_connect_is_written_where_the_schema_puts_it():
    """After PreviousPort, before DC (ETG.2100 ``Config/Slave``); the values as written."""
    drive = etree.fromstring(to_bytes(rich_plan())).xpath("//Slave[2]")[0]
    tags = [child.tag for child in drive]
    assert tags.index("HotConnect") == tags.index("DC") - 1
    assert tags[tags.index("HotConnect") - 1] == "PreviousPort"
    cmd = drive.find("HotConnect/IdentifyCmd")
    assert drive.findtext("HotConnect/GroupMemberCnt") == "1"
    assert [(c.tag, c.text) for c in cmd if len(c) == 0] == [
        ("Comment", "check station alias"), ("Cmd", "1"), ("Adp", "65535"), ("Ado", "18"),
        ("DataLength", "2"), ("Cnt", "1")]
    assert [(c.tag, c.text) for c in cmd.find("Validate")] == [
        ("Data", "0700"), ("DataMask", "ffff"), ("Timeout", "100")]


def test_reader_errors_are_eni_read_errors():
    with pytest.raises(EniReadError):
        read_bytes(small(phys="abc"), "bad.xml")


def test_missing_file_is_an_error(tmp_path: Path):
    with pytest.raises(EniReadError, match="cannot read"):
        read_file(tmp_path / "nope.xml", shown_as="nope.xml")


# -- slaves an ENI gives no address ------------------------------------------------------------

def _unaddressed(first_info: str = "", recv: str = "Recv") -> bytes:
    """Two slaves with a mailbox and CoE writes but no PhysAddr/AutoIncAddr (the shape of
    SOEM's hand-written sample ENI), an end cap between them; ``first_info`` goes into the
    first slave's Info."""
    def slave(name: str, product: str, info: str = "") -> str:
        return (f"<Slave><Info><Name>{name}</Name>{info}<VendorId>1</VendorId>"
                f"<ProductCode>{product}</ProductCode><RevisionNo>0</RevisionNo></Info>"
                "<Mailbox><Send><Start>0x1000</Start><Length>128</Length></Send>"
                f"<{recv}><Start>0x1100</Start><Length>128</Length></{recv}>"
                "<Protocol>CoE</Protocol><CoE><InitCmds><InitCmd><Transition>PS</Transition>"
                "<Ccs>1</Ccs><Index>0x1c13</Index><SubIndex>0</SubIndex><Data>00</Data>"
                "</InitCmd></InitCmds></CoE></Mailbox></Slave>")
    return ('<?xml version="1.0"?>\n<EtherCATConfig Version="1.3"><Config><Master><Info>'
            "<Name>m</Name></Info></Master>"
            + slave("A", "0x1234", first_info)
            + "<Slave><Info><Name>end cap</Name><VendorId>2</VendorId>"
              "<ProductCode>590557264</ProductCode><RevisionNo>0</RevisionNo></Info></Slave>"
            + slave("B", "0x10055aa") + "</Config></EtherCATConfig>\n").encode()


def test_slaves_with_a_mailbox_but_no_address_are_placed_by_their_order():
    """SOEM's ENI converter (scripts/eniconv.py) takes a Slave without AutoIncAddr as the
    n-th slave of the line, n its order in the file; the end cap, with nothing an ESC has,
    stays passive.  Station addresses count from 1001 as compile numbers them."""
    plan = read_bytes(_unaddressed(), "soem.xml")
    assert [(s.name, s.position, s.auto_inc_addr, s.phys_addr, s.product_code)
            for s in plan.slaves] == [("A", 0, 0, 1001, 0x1234),
                                      ("B", 1, 0xFFFF, 1002, 0x10055AA)]
    assert [(p.name, p.after) for p in plan.passive] == [("end cap", 1)]
    assert [(c.index, c.data) for c in plan.slaves[1].mailbox.coe_init_cmds] == [
        (0x1C13, b"\x00")]


def test_receive_is_read_as_the_mailbox_recv_area():
    """SOEM's sample spells SM1's area ``<Receive>``; ETG.2100 ``<Recv>``."""
    plan = read_bytes(_unaddressed(recv="Receive"), "soem.xml")
    assert [s.mailbox.recv.start for s in plan.slaves] == [0x1100, 0x1100]
    both = _unaddressed().replace(b"</Recv>", b"</Recv><Receive><Start>1</Start>"
                                  b"<Length>1</Length></Receive>", 1)
    with pytest.raises(EniReadError) as info:
        read_bytes(both, "both.xml")
    assert "<Mailbox> has both <Recv> and <Receive>" in str(info.value)


def test_a_slave_without_address_beside_addressed_ones_is_a_located_error():
    """Beside slaves that give their address, the order in the file need not be a slave's
    place (a gap, a passive slave): refused at the part that needs the ESC."""
    data = _unaddressed().replace(
        b"<Name>B</Name>", b"<Name>B</Name><PhysAddr>1002</PhysAddr><AutoIncAddr>-1</AutoIncAddr>"
        b"<Physics>YY</Physics>")
    with pytest.raises(EniReadError) as info:
        read_bytes(data, "mixed.xml")
    assert info.value.line == _line_of(data, "//Slave[1]/Mailbox")
    assert "slave 'A' has no <PhysAddr> and <AutoIncAddr> but has <Mailbox>" in str(info.value)
    assert "its place on the line cannot be told" in str(info.value)

