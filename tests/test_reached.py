"""Results that are true (``runtime/reached.py``): apply and the Network report a state only
when every slave reads back in it, refuse an ENI that cannot take its slaves there (a partial
ENI) before anything is sent, and ``apply --format json`` prints one JSON document whatever
happens.

The ENIs are the example topology compiled by ecatcfg, then cut the way the files seen in
the field are: no register InitCmds for the slaves (a partial export), no "check device
state" commands (so only the read-back can tell that a slave refused), no state request
beyond PREOP.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.eni import reader as eni_reader
from ecatcfg.esc import AlState, Transition
from ecatcfg.runtime.master import IncompleteEniError, NotReachedError
from ecatcfg.runtime.network import Network

TIMEOUT = 90


@pytest.fixture(scope="module")
def compiled(tmp_path_factory: pytest.TempPathFactory) -> Path:
    eni = tmp_path_factory.mktemp("reached") / "example.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile",
                           str(EXAMPLES / "topology.yaml"), "--esi", str(EXAMPLES / "esi"),
                           "-o", str(eni), "--no-cache"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    return eni


def cut(src: Path, dst: Path, drop: Callable[[str, str], bool]) -> Path:
    """``src`` without the slave InitCmds for which ``drop(slave name, comment)`` holds."""
    tree = etree.parse(str(src))
    for slave in tree.iterfind("Config/Slave"):
        name = slave.findtext("Info/Name")
        for cmd in list(slave.iterfind("InitCmds/InitCmd")):
            if drop(name, cmd.findtext("Comment", "")):
                cmd.getparent().remove(cmd)
    tree.write(str(dst))
    return dst


def apply_json(eni: Path, *args: str) -> tuple[int, dict, str]:
    """``apply --virtual --format json``: stdout must be exactly one JSON document."""
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(EXAMPLES / "esi"), "--format", "json", "--cycles", "5",
                           *args], capture_output=True, text=True, timeout=TIMEOUT)
    return done.returncode, json.loads(done.stdout), done.stderr


def partial(compiled: Path, tmp_path: Path) -> Path:
    """Mailbox, process data and CoE InitCmds only, as some IDEs export."""
    return cut(compiled, tmp_path / "partial.xml", lambda name, comment: True)


# -- a partial ENI is refused before anything is sent ------------------------------------------

def test_partial_eni_is_refused_naming_every_slave(compiled, tmp_path):
    eni = partial(compiled, tmp_path)
    rc, report, err = apply_json(eni)
    assert rc == 1
    assert report["ok"] is False
    names = [s.name for s in eni_reader.read_file(eni).slaves]
    assert [r["slave"] for r in report["refused"]] == names
    for part in report["refused"]:
        assert part["what"] == ("no InitCmd requests PREOP (INIT -> PREOP), SAFEOP (PREOP -> "
                                "SAFEOP), OP (SAFEOP -> OP); no register InitCmds at all")
    assert report["frames"]["sent"] == 0 and report["cycles"]["count"] == 0
    assert [r["state"] for r in report["slaves"]] == ["not started"] * len(names)
    assert "partial export" in report["error"] and "nothing was sent" in report["error"]
    assert f"{eni}: the ENI cannot take its slaves to OP" in err      # and on stderr


def test_partial_eni_through_the_network_api_sends_nothing(compiled, tmp_path):
    plan = eni_reader.read_file(partial(compiled, tmp_path))
    with Network.virtual(plan, [EXAMPLES / "esi"]) as net:
        with pytest.raises(IncompleteEniError) as caught:
            net.up()
        assert net.master.transport.counters.frames_sent == 0
        assert all(s.al_status & 0x0F == AlState.INIT for s in net.segment.slaves)
    assert set(caught.value.missing) == {s.name for s in plan.slaves}


def test_requests_up_to_the_target_only(compiled, tmp_path):
    """Without the SAFEOP and OP requests the ENI still takes the line to PREOP."""
    eni = cut(compiled, tmp_path / "to-preop.xml", lambda name, comment: comment in (
        "set device state to SAFEOP", "set device state to OP"))
    rc, report, err = apply_json(eni, "--state", "preop")
    assert rc == 0, err
    assert {r["highest_state"] for r in report["slaves"]} == {"PREOP"}
    rc, report, _ = apply_json(eni)
    assert rc == 1 and report["frames"]["sent"] == 0
    assert {r["what"] for r in report["refused"]} == {
        "no InitCmd requests SAFEOP (PREOP -> SAFEOP), OP (SAFEOP -> OP)"}


def test_a_master_broadcast_requests_the_state_for_every_slave(compiled, tmp_path):
    """ETG.2100 lets the master's InitCmds broadcast the state request (BWR 0x0120), here
    after the slaves' commands; the read-back then finds them in PREOP."""
    eni = cut(compiled, tmp_path / "broadcast.xml", lambda name, comment: comment in (
        "set device state to PREOP", "check device state for PREOP"))
    tree = etree.parse(str(eni))
    cmds = tree.find("Config/Master/InitCmds")
    cmds.append(etree.fromstring(
        "<InitCmd><Transition>IP</Transition><BeforeSlave>0</BeforeSlave>"
        "<Comment>set all to PREOP</Comment><Cmd>8</Cmd><Adp>0</Adp><Ado>288</Ado>"
        "<Data>0200</Data></InitCmd>"))
    tree.write(str(eni))
    plan = eni_reader.read_file(eni)
    assert not any(c.comment == "set device state to PREOP" and Transition.IP in c.transitions
                   for s in plan.slaves for c in s.init_cmds)
    rc, report, err = apply_json(eni, "--state", "preop")
    assert rc == 0, err
    assert {r["highest_state"] for r in report["slaves"]} == {"PREOP"}


# -- the read-back: a slave that refused is never reported as there -----------------------------

def unchecked(compiled: Path, tmp_path: Path) -> Path:
    """No "check device state" commands, and the drive (axis1) without its process-data
    SyncManagers: it refuses SAFEOP (0x001D) and only the read-back can tell."""
    return cut(compiled, tmp_path / "unchecked.xml", lambda name, comment: (
        comment.startswith("check device state")
        or (name == "axis1" and comment.startswith(("set sm 2", "set sm 3")))))


def test_a_slave_that_refused_fails_the_run(compiled, tmp_path):
    rc, report, err = apply_json(unchecked(compiled, tmp_path))
    assert rc == 1 and report["ok"] is False
    assert report["error"].startswith("after PS (SAFEOP requested), 1 slave not in SAFEOP")
    assert ("slave 'axis1' (position 4) is in PREOP+ERR, not SAFEOP, AL status code 0x001D "
            "(invalid output configuration)") in report["error"]
    axis = next(r for r in report["slaves"] if r["name"] == "axis1")
    assert (axis["highest_state"], axis["al_status_code"]) == ("PREOP+ERR", 0x001D)
    assert report["cycles"]["count"] == 0            # no cycling reported for a failed run


def test_the_network_api_raises_not_reached(compiled, tmp_path):
    with Network.virtual(unchecked(compiled, tmp_path), [EXAMPLES / "esi"]) as net:
        with pytest.raises(NotReachedError) as caught:
            net.up()
        assert caught.value.transition == Transition.PS
        assert net.state == AlState.SAFEOP                # requested: the way down covers it
    assert caught.value.lines == [
        "slave 'axis1' (position 4) is in PREOP+ERR, not SAFEOP, AL status code 0x001D "
        "(invalid output configuration)"]


# -- --format json: one document, whatever happens --------------------------------------------

def test_json_for_an_unreadable_eni(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<EtherCATConfig><Config>\n<Slave>\n</Config>")
    rc, report, err = apply_json(bad)
    assert rc == 1 and report["ok"] is False and report["slaves"] == []
    assert report["error"].startswith(f"{bad}:") and report["error"] in err


def test_json_for_a_missing_file_is_a_usage_error(tmp_path):
    rc, report, err = apply_json(tmp_path / "none.xml")
    assert rc == 2 and report["ok"] is False
    assert report["error"] == f"{tmp_path / 'none.xml'}: no such file"


def test_json_for_an_unsupported_part(compiled, tmp_path):
    tree = etree.parse(str(compiled))
    [mailbox] = tree.xpath("Config/Slave[Info/Name='axis1']/Mailbox")
    mailbox.append(etree.fromstring(
        "<SoE><InitCmds><InitCmd><Transition>PS</Transition><Comment>x</Comment>"
        "<Timeout>100</Timeout><OpCode>3</OpCode><DriveNo>0</DriveNo><IDN>32</IDN>"
        "<Elements>64</Elements><Attribute>0</Attribute><Data>0100</Data></InitCmd>"
        "</InitCmds></SoE>"))
    eni = tmp_path / "soe.xml"
    tree.write(str(eni))
    rc, report, _ = apply_json(eni)
    assert rc == 1 and report["frames"]["sent"] == 0
    [part] = report["refused"]
    assert (part["slave"], part["element"], part["commands"]) == (
        "axis1", "Slave/Mailbox/SoE", 1)
    assert part["line"] == etree.parse(str(eni)).xpath(
        "Config/Slave[Info/Name='axis1']/Mailbox/SoE")[0].sourceline
