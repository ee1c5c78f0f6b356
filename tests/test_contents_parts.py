"""What the ENI reader says of parts ``apply`` does not do or does not read
(``eni/contents.py``), in the words, lines and slaves a user gets: the example line compiled
in this process, one element or attribute added by hand, read back.  The expected lines
come from lxml's ``sourceline`` of the element added, the texts from ETG.2100's meaning of
the element (the Disabled flag, the SoE OpCode, the FoE OpCode, the cyclic task's
CycleTime)."""

from __future__ import annotations

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import contents
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esi.library import Library

DRIVE = "//Slave[Info/Name='axis1']"


@pytest.fixture(scope="module")
def example_eni() -> bytes:
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([EXAMPLES / "esi"], cache=False)).plan
    return eni_writer.to_bytes(plan)


def read(root: etree._Element) -> tuple[NetworkPlan, etree._Element]:
    """The plan of ``root`` written and read back, and the tree as the reader saw it
    (its lines)."""
    data = etree.tostring(root)
    return eni_reader.read_bytes(data, "line.xml"), etree.fromstring(data)


def added(example_eni: bytes, where: str, fragment: str) -> tuple[NetworkPlan, int]:
    """The plan with ``fragment`` appended to the element at ``where``, and the line of
    the fragment's first element."""
    root = etree.fromstring(example_eni)
    root.xpath(where)[0].append(etree.fromstring(fragment))
    plan, tree = read(root)
    return plan, tree.xpath(where)[0][-1].sourceline


def _mailbox(protocol: str, inner: str) -> str:
    return f"<{protocol}><InitCmds>{inner}</InitCmds></{protocol}>"


def _coe_cmd(transition: str, disabled: str = "") -> str:
    return (f"<InitCmd><Transition>{transition}</Transition>{disabled}<Timeout>0</Timeout>"
            "<Ccs>1</Ccs><Index>24672</Index><SubIndex>0</SubIndex><Data>09</Data></InitCmd>")


def test_a_disabled_mailbox_command_in_a_transition_without_mailbox_is_no_loss(example_eni):
    """A CoE InitCmd in INIT->INIT (no mailbox there, ETG.1000.6) is refused: no master
    can run it.  Disabled (``<Disabled>1</Disabled>``, ETG.2100: not sent), it asks
    nothing of the master and the ENI reads without a word."""
    root = etree.fromstring(example_eni)
    cmds = root.xpath(f"{DRIVE}/Mailbox/CoE/InitCmds")[0]
    cmds.append(etree.fromstring(_coe_cmd("II")))
    plan, tree = read(root)
    [part] = plan.unsupported
    assert (part.element, part.slave, part.commands) == ("CoE/InitCmds/InitCmd", "axis1", 1)
    assert part.what.startswith("a CoE InitCmd in transition II (INIT->INIT)")
    assert part.line == tree.xpath(f"{DRIVE}/Mailbox/CoE/InitCmds/InitCmd")[-1][0].sourceline
    cmds[-1].insert(1, etree.fromstring("<Disabled>1</Disabled>"))
    plan, _ = read(root)
    assert plan.unsupported == []


def test_an_soe_command_that_is_no_write_request_is_refused_at_its_opcode(example_eni):
    """An SoE InitCmd with OpCode 1 (a read request; apply sends write requests, OpCode 3,
    ETG.1000.6): refused as one command of the drive, at its OpCode's line, under the
    element it is."""
    cmd = ("<InitCmd><Transition>PS</Transition><Timeout>0</Timeout><OpCode>1</OpCode>"
           "<DriveNo>0</DriveNo><IDN>32</IDN><Elements>64</Elements><Attribute>0</Attribute>"
           "<Data>0100</Data></InitCmd>")
    root = etree.fromstring(example_eni)
    mailbox = root.xpath(f"{DRIVE}/Mailbox")[0]
    mailbox.append(etree.fromstring(_mailbox("SoE", cmd)))
    plan, tree = read(root)
    [part] = [p for p in plan.unsupported if "OpCode" in p.what]
    assert part.element == "SoE/InitCmds/InitCmd"
    assert part.what == ("an SoE request with OpCode 1 (apply sends write requests, "
                         "OpCode 3, only)")
    assert (part.slave, part.commands) == ("axis1", 1)
    assert part.line == tree.xpath(f"{DRIVE}/Mailbox/SoE/InitCmds/InitCmd/OpCode")[0].sourceline


def test_an_foe_write_request_is_refused_by_the_slaves_name(example_eni):
    """FoE InitCmd Data starting with OpCode 2 (write request, ETG.1000.6 FoE): an ENI has
    no place for the file's contents; refused as a command of the drive, named as the ENI
    names it (Info/Name), not by a line."""
    cmd = ("<InitCmd><Transition>PS</Transition><Timeout>0</Timeout>"
           "<Data>0200000000006669726d</Data></InitCmd>")
    root = etree.fromstring(example_eni)
    root.xpath(f"{DRIVE}/Mailbox")[0].append(etree.fromstring(_mailbox("FoE", cmd)))
    plan, _ = read(root)
    [part] = [p for p in plan.unsupported if p.element == "FoE/InitCmds/InitCmd"]
    assert part.slave == "axis1"
    assert part.what.startswith("FoE InitCmd: a write request")


def test_an_unknown_protocols_commands_are_counted_without_comments(example_eni):
    """A protocol no ETG.2100 version has, with one InitCmd and a comment inside its
    InitCmds (as a hand-edited file has): one command would be lost, not two."""
    inner = ("<!-- written by hand -->"
             "<InitCmd><Transition>PS</Transition><Data>0100</Data></InitCmd>")
    plan, line = added(example_eni, f"{DRIVE}/Mailbox", _mailbox("XoE", inner))
    [part] = plan.unsupported
    assert (part.element, part.line, part.slave, part.commands) == (
        "Slave/Mailbox/XoE", line, "axis1", 1)
    message = pytest.raises(contents.UnsupportedEniError, contents.refuse, plan,
                            "line.xml").value.message
    assert (f"line.xml:{line}: slave 'axis1': XoE InitCmds (a mailbox protocol ecatcfg does "
            "not know) [Slave/Mailbox/XoE]: 1 command would be lost\n") in message


def test_cyclic_tasks_of_different_cycle_times_are_refused_at_the_first(example_eni):
    """Two Cyclic elements with CycleTime 1000 and 2000 µs (two tasks, ETG.2100): apply
    runs one cycle; refused at the first Cyclic's line."""
    root = etree.fromstring(example_eni)
    config = root.find("Config")
    first = config.find("Cyclic")
    second = etree.fromstring(etree.tostring(first))
    second.find("CycleTime").text = "2000"
    first.addnext(second)
    plan, tree = read(root)
    [part] = [p for p in plan.unsupported if p.element == "Cyclic"]
    assert part.what.startswith("cyclic tasks with different cycle times (1000, 2000 µs)")
    assert part.line == tree.find("Config/Cyclic").sourceline


def test_metadata_attributes_are_ignored_with_what_they_are(example_eni):
    """An attribute ecatcfg does not read that cannot change what is sent (``MinCycleTime``
    on a Slave, a description of the hardware): read, with a warning that names it, its
    value, its element and what kind of word it is, at its line and slave."""
    root = etree.fromstring(example_eni)
    root.xpath(DRIVE)[0].set("MinCycleTime", "1000")
    plan, tree = read(root)
    assert plan.unsupported == []
    [warning] = contents.ignored_warnings(plan, "line.xml")
    assert warning == (
        f"line.xml:{tree.xpath(DRIVE)[0].sourceline}: slave 'axis1': ignored the attribute "
        "MinCycleTime='1000' of <Slave>, which ecatcfg does not read here: a description "
        "of the hardware or its limits; the master reads the slave itself (ESC registers, "
        "SII) and the ENI or topology says what to configure [Slave/@MinCycleTime]")


def test_complete_access_on_a_register_command_is_refused(example_eni):
    """``CompleteAccess`` belongs to a CoE SDO transfer (ETG.1000.6); on a register InitCmd
    (``Slave/InitCmds/InitCmd``) and true it asks for what no register command is:
    refused at the command's line.  False there is an ordinary access."""
    root = etree.fromstring(example_eni)
    cmd = root.xpath(f"{DRIVE}/InitCmds/InitCmd")[0]
    cmd.set("CompleteAccess", "true")
    plan, tree = read(root)
    [part] = plan.unsupported
    assert part.what == ("complete access on <InitCmd> (<InitCmd CompleteAccess='true'>): "
                         "only a CoE SDO transfer can be one")
    assert (part.slave, part.line) == ("axis1",
                                       tree.xpath(f"{DRIVE}/InitCmds/InitCmd")[0].sourceline)
    cmd.set("CompleteAccess", "false")
    plan, _ = read(root)
    assert plan.unsupported == []


def test_a_cyclic_command_without_data_or_length_is_an_error_not_a_crash(example_eni):
    """A logical cyclic Cmd with neither Data nor DataLength (the schema wants one): the
    reader refuses the file naming the line, the FMMU check does not crash on it."""
    from ecatcfg.errors import EcatcfgError
    root = etree.fromstring(example_eni)
    cmd = root.find("Config/Cyclic/Frame/Cmd")
    for tag in ("Data", "DataLength"):
        for el in cmd.findall(tag):
            cmd.remove(el)
    with pytest.raises(EcatcfgError) as caught:
        read(root)
    assert caught.value.line is not None


def test_a_metadata_element_is_ignored_and_an_unknown_one_of_the_master_refused(example_eni):
    """``ExcludedPdo`` in a Slave (a configurator's hint; what it decided is in the ENI's
    PDOs): read with a warning at its line, nothing refused.  An element no format has in
    ``Config/Master``: refused as the master's, each line of the refusal indented under
    its heading."""
    root = etree.fromstring(example_eni)
    root.xpath(DRIVE)[0].append(etree.fromstring("<ExcludedPdo>#x1600</ExcludedPdo>"))
    root.find("Config/Master").append(etree.fromstring("<Frobnicate>1</Frobnicate>"))
    plan, tree = read(root)
    [warning] = contents.ignored_warnings(plan, "line.xml")
    line = tree.xpath(f"{DRIVE}/ExcludedPdo")[0].sourceline
    assert warning.startswith(f"line.xml:{line}: slave 'axis1': ignored <ExcludedPdo>, which "
                              "ecatcfg does not read here: a hint to the configurator")
    [part] = plan.unsupported
    message = pytest.raises(contents.UnsupportedEniError, contents.refuse, plan,
                            "line.xml").value.message
    master = tree.find("Config/Master/Frobnicate").sourceline
    assert message == (
        "the ENI asks for 1 thing apply does not do; nothing was written to the bus:\n"
        f"  line.xml:{master}: the master: <Frobnicate>, an element ecatcfg does not know "
        "[Master/Frobnicate]\n" + contents.SKIP_HINT)


def test_an_foe_read_request_in_init_to_init_is_refused(example_eni):
    """An FoE read request (OpCode 1) in INIT->INIT: the slave has no mailbox there
    (ETG.1000.6), so no master can run it; refused like a CoE command there."""
    cmd = ("<InitCmd><Transition>II</Transition><Timeout>0</Timeout>"
           "<Data>0100000000006669726d</Data></InitCmd>")
    root = etree.fromstring(example_eni)
    root.xpath(f"{DRIVE}/Mailbox")[0].append(etree.fromstring(_mailbox("FoE", cmd)))
    plan, _ = read(root)
    [part] = plan.unsupported
    assert (part.element, part.slave, part.commands) == ("FoE/InitCmds/InitCmd", "axis1", 1)
    assert part.what.startswith("a FoE InitCmd in transition II (INIT->INIT)")
