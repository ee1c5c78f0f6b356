"""What the SOEM and pysoem exports tell a master to do per slave (``eni/export/steps.py``),
checked in the exported pysoem module itself (rendered in this process and run as Python):
the variables' places of a slave with several SyncManagers of one direction, register
commands next to the registers SOEM configures itself, the order of a slave's CoE
downloads and the ENI's register read checks.  Each ENI is the example line (examples/)
compiled, with one element added by hand the way ETG.2100 writes it; the expected values
come from the ENI text and the SOEM rules cited, not from the export."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import compile_example, device_xml, esi_xml, write
from lxml import etree

from ecatcfg.eni.export import pysoem_module
from ecatcfg.eni.export.steps import slave_setups
from ecatcfg.eni.reader import read_file


def module_of(eni: Path) -> tuple[str, dict]:
    """The pysoem module the export writes for ``eni``: its text, and its names as Python
    runs it."""
    setups = slave_setups(read_file(eni), eni)
    pysoem_module.check(setups, str(eni))
    text = pysoem_module.render(setups, eni.name, "0" * 64, "test").decode()
    namespace: dict = {}
    exec(compile(text, str(eni), "exec"), namespace)
    return text, namespace


def hook_lines(text: str, slave: int) -> list[str]:
    """The statements of slave ``slave``'s hook that talk to the slave, in order."""
    body = text.split(f"def _hook_{slave}(master", 1)[1].split("    return hook", 1)[0]
    return [line.strip() for line in body.splitlines()
            if line.strip().startswith(("slave._fpwr", "slave.sdo_write", "_check_register",
                                        "slave.dc_sync"))]


@pytest.fixture(scope="module")
def example_eni(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_example(tmp_path_factory.mktemp("steps") / "line.eni.xml")


def edited(example_eni: Path, tmp_path: Path, slave: str, where: str, xml: str,
           first: bool = False) -> Path:
    """The example ENI with the element ``xml`` added to ``where`` (a path below the
    slave's Config/Slave element), at its end or (``first``) its start."""
    tree = etree.parse(str(example_eni))
    [node] = tree.xpath(f"Config/Slave[Info/Name='{slave}']/{where}")
    element = etree.fromstring(xml)
    if first:
        node.insert(0, element)
    else:
        node.append(element)
    out = tmp_path / "edited.eni.xml"
    tree.write(str(out))
    return out


# -- a slave with two SyncManagers of each direction, the first of a few bits ------------------

_ENTRY = ("<Entry><Index>#x{index:04X}</Index><SubIndex>1</SubIndex><BitLen>{bits}</BitLen>"
          "<Name>{name}</Name><DataType>{type}</DataType></Entry>")


def _pdo(kind: str, sm: int, index: int, entries: list[tuple[int, int, str, str]]) -> str:
    body = "".join(_ENTRY.format(index=i, bits=b, name=n, type=t) for i, b, n, t in entries)
    return (f'<{kind} Fixed="1" Mandatory="1" Sm="{sm}"><Index>#x{index:04X}</Index>'
            f"<Name>P{index:04X}</Name>{body}</{kind}>")


TWO_SM_DEVICE = device_xml("FX22", body=(
    "<Fmmu>Outputs</Fmmu><Fmmu>Outputs</Fmmu><Fmmu>Inputs</Fmmu><Fmmu>Inputs</Fmmu>"
    '<Sm ControlByte="#x44" Enable="1" StartAddress="#x1000">Outputs</Sm>'
    '<Sm ControlByte="#x44" Enable="1" StartAddress="#x1080">Outputs</Sm>'
    '<Sm ControlByte="#x00" Enable="1" StartAddress="#x1100">Inputs</Sm>'
    '<Sm ControlByte="#x00" Enable="1" StartAddress="#x1180">Inputs</Sm>'
    + _pdo("RxPdo", 0, 0x1600, [(0x7000, 1, "Lamp 1", "BOOL"), (0x7001, 1, "Lamp 2", "BOOL"),
                               (0x7002, 1, "Lamp 3", "BOOL")])
    + _pdo("RxPdo", 1, 0x1601, [(0x7010, 16, "Setpoint", "UINT")])
    + _pdo("TxPdo", 2, 0x1A00, [(0x6000, 1, "Key 1", "BOOL"), (0x6001, 1, "Key 2", "BOOL"),
                               (0x6002, 1, "Key 3", "BOOL"), (0x6003, 1, "Key 4", "BOOL"),
                               (0x6004, 1, "Key 5", "BOOL")])
    + _pdo("TxPdo", 3, 0x1A01, [(0x6010, 16, "Reading", "UINT")])))


def test_a_slave_with_two_sms_of_a_few_bits_and_of_whole_bytes(tmp_path):
    """FX22: 3 output bits in SM0 and 16 in SM1, 5 input bits in SM2 and 16 in SM3.  SOEM
    lays out a slave with more than 7 bits byte by byte, each SyncManager's data from a
    whole byte, (bits + 7) / 8 bytes long (SOEM ``ecx_readPDOmap``; eni/export/soem_image.py):
    the 3 bits take byte 0 of the slave's outputs and the setpoint starts at byte 1, the 5
    bits byte 0 of its inputs and the reading byte 1, whatever bit the ENI's own image
    puts them at."""
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.esi.library import Library
    esi = write(tmp_path, "fx22.xml", esi_xml(TWO_SM_DEVICE))
    topo = write(tmp_path, "line.yaml", "master: {name: two, cycle_time_us: 1000}\n"
                 "slaves:\n  - {name: io, device: FX22}\n")
    plan = build.compile_topology(topology.load(topo), Library([esi], cache=False)).plan
    tree = etree.fromstring(eni_writer.to_bytes(plan)).getroottree()
    # Our compiler writes one Send and one Recv per slave, the SMs' bits one after the
    # other; an ENI may give one per SyncManager (ETG.2100 schema: Send and Recv
    # maxOccurs unbounded).  Split so, the image and the FMMUs unchanged.
    for kind, first in (("Send", 3), ("Recv", 5)):
        [whole] = tree.xpath(f"Config/Slave/ProcessData/{kind}")
        start, length = int(whole.findtext("BitStart")), int(whole.findtext("BitLength"))
        assert length == first + 16
        whole.find("BitLength").text = str(first)
        second = etree.fromstring(f"<{kind}><BitStart>{start + first}</BitStart>"
                                  f"<BitLength>16</BitLength></{kind}>")
        whole.addnext(second)
    eni = tmp_path / "line.eni.xml"
    tree.write(str(eni))
    _text, module = module_of(eni)
    places = {name: (v.direction, v.byte, v.bit, v.bit_size)
              for name, v in module["VARIABLES"].items()}
    assert places == {
        "io.P1600.Lamp 1": ("output", 0, 0, 1), "io.P1600.Lamp 2": ("output", 0, 1, 1),
        "io.P1600.Lamp 3": ("output", 0, 2, 1), "io.P1601.Setpoint": ("output", 1, 0, 16),
        "io.P1A00.Key 1": ("input", 0, 0, 1), "io.P1A00.Key 5": ("input", 0, 4, 1),
        "io.P1A00.Key 2": ("input", 0, 1, 1), "io.P1A00.Key 3": ("input", 0, 2, 1),
        "io.P1A00.Key 4": ("input", 0, 3, 1), "io.P1A01.Reading": ("input", 1, 0, 16)}
    # pysoem gives the slave (19 + 7) / 8 = 3 output and (21 + 7) / 8 = 3 input bytes.
    assert module["PROCESS_DATA_BITS"] == [(19, 21)]


# -- register commands next to SOEM's registers --------------------------------------------------

def _register_cmd(transition: str, comment: str, cmd: int, ado: int, data: str,
                  validate: str = "") -> str:
    return (f"<InitCmd><Transition>{transition}</Transition><Comment>{comment}</Comment>"
            f"<Cmd>{cmd}</Cmd><Adp>0</Adp><Ado>{ado}</Ado><Data>{data}</Data>"
            f"{validate}<Retries>3</Retries></InitCmd>")


def test_a_register_write_that_runs_past_soems_registers_is_exported(example_eni, tmp_path):
    """FPWR of 10 bytes at 0x09A0: SYNC0 and SYNC1 cycle times (0x09A0-0x09A7, which SOEM's
    ecx_dcsync0 programs) and the latch control registers 0x09A8/0x09A9 (ESC datasheet
    Section II), which SOEM never writes.  The write is made by the hook, whole: leaving
    it to SOEM would lose the latch settings without a word.  A write wholly inside
    SOEM's registers (0x09A0, 8 bytes) is SOEM's and is not made."""
    eni = edited(example_eni, tmp_path, "lamps", "InitCmds", _register_cmd(
        "PS", "sync cycles and latch control", 5, 0x09A0, "00000000" "00000000" "0103"))
    text, _ = module_of(eni)
    assert "slave._fpwr(0x09A0, bytes.fromhex('00000000000000000103'))" in hook_lines(text, 3)
    inside = edited(example_eni, tmp_path, "lamps", "InitCmds", _register_cmd(
        "PS", "sync cycles", 5, 0x09A0, "00000000" "00000000"))
    text, _ = module_of(inside)
    assert "def _hook_3(" not in text         # the lamps' hook had nothing else to do


def test_a_register_read_check_is_exported_with_its_data_and_mask(example_eni, tmp_path):
    """FPRD of the SM watchdog time 0x0420 with a Validate (ETG.2100: the InitCmd is
    repeated until the data read, under DataMask, is Data): outside SOEM's registers, so
    the hook reads it and raises SetupError when it differs."""
    eni = edited(example_eni, tmp_path, "lamps", "InitCmds", _register_cmd(
        "PS", "check the SM watchdog time", 4, 0x0420, "0000",
        "<Validate><Data>e803</Data><DataMask>ffff</DataMask><Timeout>100</Timeout>"
        "</Validate>"))
    text, _ = module_of(eni)
    [line] = hook_lines(text, 3)
    assert line == ("_check_register(slave, position, 0x0420, 2, bytes.fromhex('e803'), "
                    "bytes.fromhex('ffff'), step)")


# -- the order of a slave's CoE downloads ----------------------------------------------------------

def test_ip_downloads_come_before_ps_downloads_whatever_the_eni_order(example_eni, tmp_path):
    """A CoE download of INIT->PREOP written after the drive's PS downloads in the ENI: the
    hook runs in PREOP before SAFEOP, where the master would have made the IP one first
    (it runs in the earlier transition), so the hook makes it first, then the PS ones in
    ENI order."""
    ip = ("<InitCmd><Transition>IP</Transition><Comment>error reaction</Comment>"
          "<Timeout>0</Timeout><Ccs>1</Ccs><Index>24671</Index><SubIndex>0</SubIndex>"
          "<Data>0100</Data></InitCmd>")          # 0x605F
    eni = edited(example_eni, tmp_path, "axis1", "Mailbox/CoE/InitCmds", ip)
    text, _ = module_of(eni)
    tree = etree.parse(str(eni))
    ps = [(int(c.findtext("Index")), int(c.findtext("SubIndex")))
          for c in tree.xpath("Config/Slave[Info/Name='axis1']/Mailbox/CoE/InitCmds/InitCmd")
          if c.findtext("Transition") == "PS"]
    written = [line for line in hook_lines(text, 4) if line.startswith("slave.sdo_write")]
    order = [(int(line.split("(")[1].split(",")[0], 16), int(line.split(", ")[1]))
             for line in written]
    assert order == [(0x605F, 0), *ps]
    assert written[0] == "slave.sdo_write(0x605F, 0, bytes.fromhex('0100'), False)"


# -- SoE writes and parts apply does not do ----------------------------------------------------

SOE_TOPOLOGY = """\
master: {name: soe-line, cycle_time_us: 1000}
slaves:
  - {name: axes, device: TSD-2 SoE}
"""


def soe_eni(tmp_path: Path, disable_first: bool = False) -> Path:
    """The two-axis SoE drive of tests/fixtures/esi/soe_drive.xml compiled, its SoE
    InitCmds of PREOP->SAFEOP only (a hook runs before SAFEOP: an SO write is refused, a
    test of its own); its first one disabled (``<Disabled>1</Disabled>``) if asked."""
    from conftest import FIXTURES
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.esi.library import Library
    plan = build.compile_topology(topology.load(write(tmp_path, "t.yaml", SOE_TOPOLOGY)),
                                  Library([FIXTURES / "esi" / "soe_drive.xml"],
                                          cache=False)).plan
    tree = etree.fromstring(eni_writer.to_bytes(plan)).getroottree()
    for cmd in tree.xpath("//Mailbox/SoE/InitCmds/InitCmd"):
        if [t.text for t in cmd.iterfind("Transition")] != ["PS"]:
            cmd.getparent().remove(cmd)
    if disable_first:
        first = tree.xpath("//Mailbox/SoE/InitCmds/InitCmd")[0]
        first.insert(1, etree.fromstring("<Disabled>1</Disabled>"))
    eni = tmp_path / "soe.eni.xml"
    tree.write(str(eni))
    return eni


def test_the_c_export_makes_every_enabled_soe_write_after_a_disabled_one(tmp_path):
    """The drive's first SoE InitCmd disabled (not sent by any master, ETG.2100): the SOEM
    C export's hook makes each of the others with ecx_SoEwrite, in ENI order."""
    from ecatcfg.eni.export import soem_c
    eni = soe_eni(tmp_path, disable_first=True)
    cmds = etree.parse(str(eni)).xpath("//Mailbox/SoE/InitCmds/InitCmd")
    enabled = [int(c.findtext("IDN")) for c in cmds if c.find("Disabled") is None]
    assert len(enabled) == len(cmds) - 1 >= 2
    source, _ = soem_c.render(slave_setups(read_file(eni), eni), "soe.h", eni.name, "0" * 64,
                              "test")
    calls = [line for line in source.decode().splitlines() if "ecatcfg_soe(context, slave," in line]
    assert [int(line.split(", ")[4]) for line in calls] == enabled


def test_the_pysoem_export_refuses_soe_writes_at_the_first_ones_line(tmp_path):
    """pysoem has no SoE call: the export refuses the drive's SoE writes, at the line of the
    first InitCmd (lxml's sourceline), naming how many there are."""
    from ecatcfg.eni.export.steps import ExportError
    eni = soe_eni(tmp_path)
    cmds = etree.parse(str(eni)).xpath("//Mailbox/SoE/InitCmds/InitCmd")
    with pytest.raises(ExportError) as caught:
        module_of(eni)
    assert caught.value.line == cmds[0].sourceline
    assert f"pysoem has no SoE call ({len(cmds)} SoE write(s) in all)" in caught.value.message


def test_a_part_apply_does_not_do_is_refused_at_its_line(example_eni, tmp_path):
    """VoE InitCmds in the drive's mailbox (vendor messages apply does not send): the
    export refuses the ENI at the VoE element's line, naming the slave."""
    from ecatcfg.eni.export.steps import ExportError
    voe = ("<VoE><InitCmds><InitCmd><Transition>PS</Transition><Data>0100</Data></InitCmd>"
           "</InitCmds></VoE>")
    eni = edited(example_eni, tmp_path, "axis1", "Mailbox", voe)
    [element] = etree.parse(str(eni)).xpath("//Slave[Info/Name='axis1']/Mailbox/VoE")
    with pytest.raises(ExportError) as caught:
        slave_setups(read_file(eni), eni)
    assert (caught.value.file, caught.value.line) == (str(eni), element.sourceline)
    assert caught.value.message.startswith("slave 'axis1': ")


# -- commands no hook can carry ----------------------------------------------------------------

def _coe(transitions: list[str], ccs: int = 1) -> str:
    return ("<InitCmd>" + "".join(f"<Transition>{t}</Transition>" for t in transitions)
            + f"<Comment>mode</Comment><Timeout>0</Timeout><Ccs>{ccs}</Ccs><Index>24672</Index>"
            "<SubIndex>0</SubIndex><Data>09</Data></InitCmd>")


@pytest.mark.parametrize("transitions, said", [
    (["PS", "SO"], "in PS/SO (SO too)"),             # exported once, its SO repeat lost
    (["SO", "OS"], "in SO/OS"),                      # none of the hook's transitions
])
def test_a_command_outside_the_hooks_transitions_is_refused_by_them(example_eni, tmp_path,
                                                                    transitions, said):
    """A CoE download of 0x6060 the drive gets in SAFEOP->OP (and back): the hooks run in
    PREOP before SAFEOP; the refusal names the transitions the ENI gives it, at its line."""
    from ecatcfg.eni.export.steps import ExportError
    eni = edited(example_eni, tmp_path, "axis1", "Mailbox/CoE/InitCmds", _coe(transitions))
    [cmd] = etree.parse(str(eni)).xpath(
        "//Slave[Info/Name='axis1']/Mailbox/CoE/InitCmds/InitCmd[Comment='mode']")
    with pytest.raises(ExportError) as caught:
        slave_setups(read_file(eni), eni)
    assert caught.value.line == cmd.sourceline
    assert caught.value.message == (f"slave 4 ('axis1'): SDO 0x6060:00 = 9 {said}: the "
                                    "exported hooks run in PREOP before SAFEOP only (IP, PS)")


def test_a_coe_upload_is_refused_at_its_line(example_eni, tmp_path):
    """A CoE InitCmd with Ccs 2 (an upload, ETG.2100): the hooks make downloads only; the
    refusal is at the command's line."""
    from ecatcfg.eni.export.steps import ExportError
    eni = edited(example_eni, tmp_path, "axis1", "Mailbox/CoE/InitCmds", _coe(["PS"], ccs=2))
    [cmd] = etree.parse(str(eni)).xpath(
        "//Slave[Info/Name='axis1']/Mailbox/CoE/InitCmds/InitCmd[Comment='mode']")
    with pytest.raises(ExportError) as caught:
        slave_setups(read_file(eni), eni)
    assert caught.value.line == cmd.sourceline
    assert caught.value.message.endswith(": only SDO downloads are exported")


def test_the_module_says_where_the_enis_inputs_differ_from_soems(example_eni):
    """SOEM lays the example's outputs out first (the lamps' 8 bits at byte 0, axis1's 48
    from byte 1: 7 bytes), then the inputs from byte 7 (buttons and sensors, 4 bits each,
    fill it; axis1's 128 bits, byte-oriented, from byte 8); the ENI's own input image has
    axis1's Recv at bit 16 (byte 2). The module says so for the inputs as for the
    outputs."""
    text, _ = module_of(example_eni)
    recv = etree.parse(str(example_eni)).xpath(
        "//Slave[Info/Name='axis1']/ProcessData/Recv/BitStart/text()")
    assert recv == ["16"]
    assert ("# slave 4 ('axis1'): SOEM puts its 128 input bit(s) at IOmap byte 8 bit 0 "
            "(Istartbit 0); the ENI's input image at byte 2 bit 0: the places here are "
            "SOEM's") in text
