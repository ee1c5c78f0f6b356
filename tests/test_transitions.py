"""Every transition ETG.2100 lists (``TransitionType``: II, IP, PP, PO, PS, PI, SS, SP, SO, SI,
OS, OP, OI, IB, BI) for register, CoE and EoE InitCmds: each is on the wire where
``esc.TRANSITION_RULES`` says, or never (a path apply does not take), or refused by name
(transition, line, slave) before anything is sent.

The line is one self-written EoE and CoE slave (its ESI below), compiled, then given one
InitCmd of each kind with the transition under test through lxml.  ``ecatcfg apply
--virtual --pcap`` runs it up to OP and down to INIT; tshark, an independent dissector,
reads the capture.  The windows come from the slave's own AL-control requests on the wire
(INIT, PREOP, SAFEOP, OP up, then SAFEOP, PREOP, INIT down), not from the master's code.
"""

from __future__ import annotations

import functools
import subprocess
import sys
import time
from pathlib import Path

import pytest
from lxml import etree

from conftest import MAILBOX_PD_SMS, device_xml, esi_xml
from rig import tshark_fields
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import TRANSITION_RULES, AlState, Transition
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.master import bringup as master

ESI = esi_xml(device_xml("FX-EOE", "#x20",
                         body=MAILBOX_PD_SMS + "<Mailbox><EoE/><CoE/></Mailbox>"))

AL_CONTROL = 0x0120
SM2 = 0x0810
TEST_ADO = 0x1F00               # process RAM outside every SyncManager: any ESC takes it
SDO_INDEX = 0x1018              # identity object: an upload every CoE slave answers
# EoE set IP parameter request, gateway 10.0.0.2 alone (compact layout after the EoE
# header; ETG.1000.6 §5.7, SOEM ecx_EOEsetIp): type 2, flags 0x08, the address.
EOE_DATA = "02000000" "08000000" "0200000a"
KINDS = ("register", "CoE", "EoE")


def _register_data(transition: Transition) -> str:
    return transition.value.encode().hex()       # "II" -> 4949: which command it is


@pytest.fixture(scope="module")
def line(tmp_path_factory) -> tuple[Path, bytes]:
    folder = tmp_path_factory.mktemp("transitions")
    esi = folder / "fx.xml"
    esi.write_text(ESI)
    plan = build.compile_topology(
        topology.loads("slaves:\n  - {name: s0, device: FX-EOE}\n", "t.yaml"),
        Library([esi], cache=False)).plan
    return esi, eni_writer.to_bytes(plan)


def _with_commands(eni: bytes, transition: Transition, kinds: tuple[str, ...]) -> bytes:
    """The line with one InitCmd per kind in ``transition``; the register one goes right
    before the slave's request of the transition's target state, if it has one."""
    root = etree.fromstring(eni)
    slave = root.find("Config/Slave")
    t = transition.value
    if "register" in kinds:
        cmd = etree.fromstring(
            f"<InitCmd><Transition>{t}</Transition><Comment>test {t}</Comment><Cmd>2</Cmd>"
            f"<Adp>0</Adp><Ado>{TEST_ADO}</Ado><Data>{_register_data(transition)}</Data>"
            "<Cnt>1</Cnt><Retries>3</Retries></InitCmd>")
        cmds = slave.find("InitCmds")
        request = next((c for c in cmds if c.findtext("Transition") == t
                        and c.findtext("Ado") == str(AL_CONTROL)
                        and c.findtext("Cmd") in ("2", "5")
                        and int(c.findtext("Data", "00")[:2], 16) & 0x0F
                        == transition.target), None)
        if request is not None:
            request.addprevious(cmd)
        else:
            cmds.append(cmd)
    mailbox = slave.find("Mailbox")
    bodies = {"CoE": f"<Ccs>2</Ccs><Index>#x{SDO_INDEX:04x}</Index><SubIndex>1</SubIndex>",
              "EoE": f"<Data>{EOE_DATA}</Data>"}
    for kind, body in bodies.items():
        if kind not in kinds:
            continue
        protocol = mailbox.find(kind)
        if protocol is None:
            protocol = etree.SubElement(mailbox, kind)
        cmds = protocol.find("InitCmds")
        if cmds is None:
            cmds = etree.SubElement(protocol, "InitCmds")
        cmds.append(etree.fromstring(
            f"<InitCmd><Transition>{t}</Transition><Comment>{kind.lower()} {t}</Comment>"
            f"<Timeout>2000</Timeout>{body}</InitCmd>"))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _apply(eni: Path, esi: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(esi), "--simulated-time", "--cycles", "3", *args],
                          capture_output=True, text=True, timeout=120)


@functools.cache
def _folder(base: Path) -> Path:
    folder = base / "transitions-wire"
    folder.mkdir()
    return folder


def _runs_folder(factory: pytest.TempPathFactory) -> Path:
    return _folder(factory.getbasetemp())


def _runnable(transition: Transition) -> tuple[str, ...]:
    return KINDS if TRANSITION_RULES[transition].mailbox else ("register",)


@functools.cache
def _wire(transition: Transition, folder: Path, esi: Path, eni: bytes) -> list[tuple[str, int]]:
    """Apply the line with every kind the transition can hold; the capture as a list of
    events in wire order: ("state", requested state), ("register", 0), ("CoE", 0),
    ("EoE", 0), ("sm2", 0), ("scan", 0) for an SII data read."""
    path = folder / f"{transition.value}.xml"
    path.write_bytes(_with_commands(eni, transition, _runnable(transition)))
    pcap = folder / f"{transition.value}.pcap"
    done = _apply(path, esi, "--pcap", str(pcap))
    assert done.returncode == 0, done.stdout + done.stderr
    fields = ["eth.src", "ecat.cmd", "ecat.ado", "ecat.data", "ecat.reg.alctrl.ctrl",
              "ecat_mailbox.coe.sdoidx", "ecat_mailbox.eoe.type"]
    events: list[tuple[str, int]] = []
    for packet in tshark_fields(pcap, fields):
        if int(packet["eth.src"][0][:2], 16) & 0x02:
            continue        # the frame back from the line: the first ESC set this bit
        cmds, ados, data = packet["ecat.cmd"], packet["ecat.ado"], packet["ecat.data"]
        rows = zip(cmds, ados, data) if len(data) == len(ados) else (
            (c, a, "") for c, a in zip(cmds, ados))
        # tshark shows an AL control value as the register, not as datagram data.
        requested = iter(packet["ecat.reg.alctrl.ctrl"])
        for cmd, ado, value in rows:
            writes = int(cmd, 16) in (0x02, 0x05, 0x08)          # APWR, FPWR, BWR
            if int(ado, 16) == AL_CONTROL:
                state = next(requested)
                if writes:
                    events.append(("state", int(state, 16) & 0x0F))
            elif writes and int(ado, 16) == TEST_ADO:
                events.append(("register", int(value, 16)))
            elif writes and int(ado, 16) == SM2:
                events.append(("sm2", 0))
            elif int(ado, 16) == 0x0508:
                events.append(("scan", 0))
        if f"0x{SDO_INDEX:04x}" in packet["ecat_mailbox.coe.sdoidx"]:
            events.append(("CoE", 0))
        if "2" in packet["ecat_mailbox.eoe.type"]:                # set IP parameter request
            events.append(("EoE", 0))
    return events


# Where each transition's commands must be, as (after, before) anchors on the wire: the
# n-th state request (0: INIT of INIT->PREOP, 1 PREOP, 2 SAFEOP, 3 OP, 4 SAFEOP, 5 PREOP,
# 6 INIT on the way down), "scan" the last SII read before the first request, "sm2" the
# first SM2 write in PREOP (the first PREOP->SAFEOP register command of the slave).
WINDOWS: dict[tuple[Transition, str], tuple[object, object]] = {
    (Transition.II, "register"): ("scan", 0),
    (Transition.IP, "register"): (0, 1),
    (Transition.IP, "mailbox"): (1, "sm2"),      # once the slave is in PREOP
    (Transition.PS, "register"): (1, 2),
    (Transition.PS, "mailbox"): ("sm2", 2),
    (Transition.SO, "register"): (2, 3),
    (Transition.SO, "mailbox"): (2, 3),
    (Transition.OS, "register"): (3, 4),
    (Transition.OS, "mailbox"): (3, 4),
    (Transition.SP, "register"): (4, 5),
    (Transition.SP, "mailbox"): (4, 5),
    (Transition.PI, "register"): (5, 6),
    (Transition.PI, "mailbox"): (5, 6),
}


def _index(events: list[tuple[str, int]], anchor: object) -> int:
    requests = [i for i, (kind, _) in enumerate(events) if kind == "state"]
    if isinstance(anchor, int):
        return requests[anchor]
    if anchor == "scan":
        return max(i for i, (kind, _) in enumerate(events[:requests[0]]) if kind == "scan")
    return next(i for i, (kind, _) in enumerate(events) if kind == anchor and i > requests[1])


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("transition", list(Transition), ids=[t.value for t in Transition])
def test_each_transition_runs_where_the_rule_says_or_is_refused(
        transition, kind, line, tmp_path_factory, tshark_path):
    esi, eni = line
    rule = TRANSITION_RULES[transition]
    if kind != "register" and not rule.mailbox:
        path = tmp_path_factory.mktemp("refused") / "line.xml"
        path.write_bytes(_with_commands(eni, transition, (kind,)))
        tag = etree.parse(str(path)).find(f"Config/Slave/Mailbox/{kind}/InitCmds")
        expected_line = tag[-1].find("Transition").sourceline
        done = _apply(path, esi)
        assert done.returncode == 1
        assert (f"{path}:{expected_line}: slave 's0': a {kind} InitCmd in transition "
                f"{transition.value} ({transition.source.name}->{transition.target.name})"
                ) in done.stderr
        assert "nothing was written to the bus" in done.stderr
        return
    events = _wire(transition, _runs_folder(tmp_path_factory), esi, eni)
    requests = [state for kind_, state in events if kind_ == "state"]
    assert requests == [AlState.INIT, AlState.PREOP, AlState.SAFEOP, AlState.OP,
                        AlState.SAFEOP, AlState.PREOP, AlState.INIT]
    sent = [i for i, (k, value) in enumerate(events) if k == kind and (
        kind != "register" or value == int(_register_data(transition), 16))]
    if not rule.sent:
        assert sent == [], f"{transition.value} is never taken, yet its command was sent"
        return
    assert sent, f"the {kind} command of {transition.value} is not on the wire"
    after, before = WINDOWS[transition, "register" if kind == "register" else "mailbox"]
    assert _index(events, after) < sent[0] and sent[-1] < _index(events, before), (
        transition.value, kind, events)


def test_the_refused_mailbox_commands_are_left_out_of_the_plan(line):
    """With --skip-unsupported the reader's plan holds no CoE/EoE command of II, IB or BI
    (nothing would send it), and the register ones stay."""
    _, eni = line
    for transition in (Transition.II, Transition.IB, Transition.BI):
        plan = eni_reader.read_bytes(_with_commands(eni, transition, KINDS), "x.xml")
        [slave] = plan.slaves
        assert not [c for c in slave.mailbox.coe_init_cmds if transition in c.transitions]
        assert not [c for c in slave.mailbox.eoe_init_cmds if transition in c.transitions]
        assert [c.comment for c in slave.init_cmds if transition in c.transitions][-1] == \
            f"test {transition.value}"
        assert sorted(p.element for p in plan.unsupported) == [
            "CoE/InitCmds/InitCmd", "EoE/InitCmds/InitCmd"]


def test_a_disabled_mailbox_command_in_ii_is_no_loss(line):
    _, eni = line
    root = etree.fromstring(_with_commands(eni, Transition.II, ("CoE",)))
    etree.SubElement(root.find("Config/Slave/Mailbox/CoE/InitCmds/InitCmd[last()]"),
                     "Disabled").text = "1"
    assert eni_reader.read_bytes(etree.tostring(root), "x.xml").unsupported == []


def test_the_masters_steps_are_the_rules_steps():
    """``runtime/master/bringup.py`` walks UP and DOWN; the rules name exactly those (and II) as
    sent, and every transition has a rule."""
    assert set(TRANSITION_RULES) == set(Transition)
    walked = set(master.UP) | {t for steps in master.DOWN.values() for t in steps}
    assert {t for t, r in TRANSITION_RULES.items() if r.sent} == walked | {Transition.II}
    for transition in Transition:
        rule = TRANSITION_RULES[transition]
        assert rule.sent or rule.why, transition
        # Neither INIT nor BOOT has a mailbox a CoE or EoE command could use (ETG.1000.6);
        # the way into or out of them has one at the other end.
        assert rule.mailbox == (not {transition.source, transition.target}
                                <= {AlState.INIT, AlState.BOOT}), transition


def test_the_docs_table_is_the_rules():
    """docs/runtime.md shows exactly ``esc.TRANSITION_RULES``, row by row."""
    doc = (Path(__file__).resolve().parent.parent / "docs" / "runtime.md").read_text()
    rows = [f"| `{t.value}` {t.source.name}→{t.target.name} | {r.sent or 'never'} | {r.why}"
            f"{'' if r.mailbox else '; a mailbox command here is refused'} |"
            for t, r in TRANSITION_RULES.items()]
    table = [line.strip() for line in doc.splitlines()
             if line.strip().startswith("| `") and "→" in line.split("|")[1]]
    assert table == rows


def test_a_slave_brought_back_runs_its_ii_commands_again(line):
    """A slave that lost power comes back in INIT; the master asks it for INIT and brings
    it up again: its INIT->INIT commands run again before INIT->PREOP (the register the II
    command writes is cleared by the power cycle and written again)."""
    esi, _ = line
    built = build.compile_topology(topology.loads(
        "slaves:\n  - {name: s0, device: FX-EOE}\n  - {name: s1, device: FX-EOE}\n", "t.yaml"),
        Library([esi], cache=False)).plan
    root = etree.fromstring(eni_writer.to_bytes(built))
    root.find("Config/Slave[2]/InitCmds").append(etree.fromstring(
        f"<InitCmd><Transition>II</Transition><Comment>test II</Comment><Cmd>2</Cmd>"
        f"<Adp>{0xFFFF}</Adp><Ado>{TEST_ADO}</Ado><Data>4949</Data><Cnt>1</Cnt></InitCmd>"))
    plan = eni_reader.read_bytes(etree.tostring(root), "x.xml")
    with Network.virtual(plan, esi=[esi]) as net:
        net.up()
        slave = net.segment.slaves[1]
        assert slave.read(TEST_ADO, 2) == b"II"
        net.segment.remove_cable("s1")
        slave.power_cycle()
        assert slave.read(TEST_ADO, 2) == bytes(2)
        for _ in range(5):
            net.cycle()
        assert not net.online("s1")
        net.segment.restore_cable("s1")
        end = time.monotonic() + 5
        while not net.online("s1"):
            assert time.monotonic() < end, "s1 not back after 5 s"
            net.cycle()
            time.sleep(0.001)
        assert slave.state == AlState.OP
        assert slave.read(TEST_ADO, 2) == b"II"


def test_the_masters_ii_commands_run_after_the_scan_before_init_to_preop(line, tmp_path,
                                                                       tshark_path):
    """The master's own InitCmds of II (before and after the slaves' ones) are sent in
    the same place: after the scan, before the first INIT->PREOP command."""
    esi, eni = line
    root = etree.fromstring(eni)
    cmds = root.find("Config/Master/InitCmds")
    # The first write of INIT->PREOP (the scan before only reads).
    first_ip = next(c for c in cmds if c.findtext("Transition") == "IP"
                    and c.findtext("Cmd") == "8")
    for before, data in (("true", "4242"), ("false", "4141")):
        cmds.append(etree.fromstring(
            f"<InitCmd><Transition>II</Transition><BeforeSlave>{before}</BeforeSlave>"
            f"<Comment>master II</Comment><Cmd>8</Cmd><Adp>0</Adp><Ado>{TEST_ADO + 2}</Ado>"
            f"<Data>{data}</Data><Cnt>1</Cnt></InitCmd>"))
    path, pcap = tmp_path / "master.xml", tmp_path / "master.pcap"
    path.write_bytes(etree.tostring(root))
    done = _apply(path, esi, "--pcap", str(pcap))
    assert done.returncode == 0, done.stderr
    sent: list[tuple[int, str]] = []
    for packet in tshark_fields(pcap, ["eth.src", "ecat.cmd", "ecat.ado", "ecat.data"]):
        if int(packet["eth.src"][0][:2], 16) & 0x02:
            continue
        data = packet["ecat.data"]
        if len(data) != len(packet["ecat.ado"]):
            data = [""] * len(packet["ecat.ado"])     # reads show no data: no alignment
        sent += [(int(ado, 16), value) for ado, value in zip(packet["ecat.ado"], data)]
    ours = [i for i, (ado, _) in enumerate(sent) if ado == TEST_ADO + 2]
    assert [sent[i][1] for i in ours] == ["4242", "4141"]
    scan = max(i for i, (ado, _) in enumerate(sent[:ours[0]]) if ado == 0x0508)
    ip = next(i for i, (ado, _) in enumerate(sent) if ado == int(first_ip.findtext("Ado")))
    assert scan < ours[0] and ours[-1] < ip
