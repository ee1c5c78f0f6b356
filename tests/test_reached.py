"""Results that are true (``runtime/master/reached.py``, ``eni/derive.py``): apply and the Network
report a state only when every slave reads back in it; a partial ENI (no register InitCmds)
is completed with the standard set-up, or refused before anything is sent when that cannot
be derived, as is an ENI that requests no state on the way; ``apply --format json`` prints
one JSON document whatever happens.

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

from conftest import EXAMPLES, compile_example
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni.derive import complete
from ecatcfg.eni.plan import SlavePlan
from ecatcfg.esc import AlState, Cmd, Reg, Transition
from ecatcfg.runtime.master.bringup import Event, NotReachedError
from ecatcfg.runtime.network import Network

TIMEOUT = 90


@pytest.fixture(scope="module")
def compiled(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_example(tmp_path_factory.mktemp("reached") / "example.eni.xml")


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
                           "--esi", str(EXAMPLES / "esi"), "--format", "json", "--simulated-time",
                           "--cycles", "5",
                           *args], capture_output=True, text=True, timeout=TIMEOUT)
    return done.returncode, json.loads(done.stdout), done.stderr


def partial(src: Path, dst: Path, keep_master: bool = False) -> Path:
    """Mailbox, process data and CoE InitCmds only, as some IDEs export: no register
    InitCmds of the slaves (nor of the master, unless ``keep_master``)."""
    cut(src, dst, lambda name, comment: True)
    if not keep_master:
        tree = etree.parse(str(dst))
        cmds = tree.find("Config/Master/InitCmds")
        cmds.getparent().remove(cmds)
        tree.write(str(dst))
    return dst


# Register writes that make the set-up: station address, AL control, SyncManagers, FMMUs.
_SETUP = (Reg.STATION_ADDRESS, Reg.AL_CONTROL)


def setup_writes(slave: SlavePlan) -> set[tuple]:
    """The slave's register writes of the set-up, in the transitions apply runs, as
    (transitions, register, data): what must be equal whoever wrote the ENI."""
    out = set()
    for c in slave.init_cmds:
        runs = tuple(t for t in c.transitions if t in (Transition.IP, Transition.PS,
                                                        Transition.SO))
        if c.cmd in (Cmd.APWR, Cmd.FPWR) and runs and c.ado is not None and (
                c.ado in _SETUP or 0x0600 <= c.ado < 0x0A00):
            out.add((runs, c.ado, c.payload))
    return out


# -- a partial ENI: the standard set-up derived, equal to a full export's -----------------

def test_partial_eni_reaches_op_with_the_derived_setup(compiled, tmp_path):
    eni = partial(compiled, tmp_path / "partial.xml")
    rc, report, err = apply_json(eni)
    assert rc == 0, err
    names = [s.name for s in eni_reader.read_file(eni).slaves]
    assert [d["slave"] for d in report["derived"]] == [*names, None]     # None: the master
    assert all(d["what"].startswith("no register InitCmds in the ENI: derived the standard "
                                    "set-up") for d in report["derived"][:-1])
    assert {r["highest_state"] for r in report["slaves"]} == {"OP"}
    assert report["cycles"]["count"] == 5


def test_derived_setup_equals_the_compiled_export(compiled, tmp_path):
    """The same devices compiled from their ESI files (a full export) and derived from the
    partial ENI write the same SyncManagers, FMMUs, station addresses and state requests,
    but for what only an ESI says: the lamps' EX2008 enables its outputs SM only in OP
    (ESI OpOnly), the derived set-up from PREOP->SAFEOP on."""
    full = eni_reader.read_file(compiled)
    done, _ = complete(eni_reader.read_file(partial(compiled, tmp_path / "p.xml")))
    assert [c.comment for c in done.master.init_cmds] == \
        [c.comment for c in full.master.init_cmds]
    for ours, theirs in zip(done.slaves, full.slaves):
        if ours.name == "lamps":
            sm0 = (Reg.SM0, bytes.fromhex("000f010044000100"))
            assert ((Transition.SO,), *sm0) in setup_writes(theirs)
            assert ((Transition.PS,), *sm0) in setup_writes(ours)
            assert setup_writes(ours) - {((Transition.PS,), *sm0)} == \
                setup_writes(theirs) - {((Transition.SO,), *sm0)}
        else:
            assert setup_writes(ours) == setup_writes(theirs), ours.name
            assert ours.init_cmds == theirs.init_cmds, ours.name


def test_derived_setup_equals_twincats(corpus, tmp_path):
    """An independent reference: TwinCAT's export of EK1100, EL2008, EL4002 (mailbox,
    bootstrap, mailbox-state FMMU) and EL1809, cut to a partial ENI, derived again: every
    SyncManager, FMMU, station address and state request is TwinCAT's, but the EL2008's
    OpOnly outputs SM (TwinCAT: set in SAFEOP->OP)."""
    src = corpus / "eni" / "jn-ec-master" / "mega_master_eni.xml"
    full = eni_reader.read_file(src)
    done, derived = complete(eni_reader.read_file(partial(src, tmp_path / "p.xml",
                                                          keep_master=True)))
    assert [d.slave for d in derived] == [s.name for s in full.slaves]
    for ours, theirs in zip(done.slaves, full.slaves):
        mine, twincat = setup_writes(ours), setup_writes(theirs)
        if ours.name == "Term 2 (EL2008)":
            sm0 = (Reg.SM0, bytes.fromhex("000f010044000100"))
            assert mine - twincat == {((Transition.PS,), *sm0)}
            assert twincat - mine == {((Transition.SO,), *sm0)}
        else:
            assert mine == twincat, ours.name
    fmmus = [c for c in done.slave("Term 3 (EL4002)").init_cmds if c.ado == Reg.FMMU0 + 16]
    assert fmmus[0].payload.hex() == "00000009010000000d08000101000000"    # mailbox state


def test_partial_eni_through_the_network_api(compiled, tmp_path):
    plan = eni_reader.read_file(partial(compiled, tmp_path / "partial.xml"))
    events: list[Event] = []
    with Network.virtual(plan, [EXAMPLES / "esi"], on_event=events.append) as net:
        net.up()
        assert net.state == AlState.OP
        assert all(s.al_status & 0x0F == AlState.OP for s in net.segment.slaves)
    assert [e.slave for e in events if e.kind == "derived"] == \
        [*(s.name for s in plan.slaves), None]
    assert not plan.slaves[0].init_cmds              # the caller's plan is left as it was


def test_a_partial_eni_that_cannot_be_derived_is_refused(compiled, tmp_path):
    """Without the cyclic command that carries the drive's data, where its FMMUs map to
    is not in the file: refused, naming the slave and what is missing."""
    eni = partial(compiled, tmp_path / "partial.xml")
    tree = etree.parse(str(eni))
    for cmd in tree.iterfind("Config/Cyclic/Frame/Cmd"):
        if cmd.findtext("Cmd") in ("10", "11", "12"):           # LRD, LWR, LRW
            cmd.getparent().remove(cmd)
    tree.write(str(eni))
    rc, report, err = apply_json(eni)
    assert rc == 1 and report["frames"]["sent"] == 0
    refused = {r["slave"]: r["what"] for r in report["refused"]}
    assert refused["axis1"].startswith("no cyclic command carries the bits")
    assert set(refused) == {"buttons", "sensors", "lamps", "axis1"}     # not the coupler
    assert "cannot be derived" in err


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
        "<VoE><InitCmds><InitCmd><Transition>PS</Transition><Comment>x</Comment>"
        "<Timeout>100</Timeout><Data>0100</Data></InitCmd></InitCmds></VoE>"))
    eni = tmp_path / "voe.xml"
    tree.write(str(eni))
    rc, report, _ = apply_json(eni)
    assert rc == 1 and report["frames"]["sent"] == 0
    [part] = report["refused"]
    assert (part["slave"], part["element"], part["commands"]) == (
        "axis1", "Slave/Mailbox/VoE", 1)
    assert part["line"] == etree.parse(str(eni)).xpath(
        "Config/Slave[Info/Name='axis1']/Mailbox/VoE")[0].sourceline


# -- survivors of the mutation pass: each a fault a user would meet --------------------------

def test_a_slave_read_back_in_the_target_state_with_its_error_flag_set_has_not_reached_it():
    """AL status 0x14 (SAFEOP with the error flag, ETG.1000.6 "AL status"): the slave is in
    SAFEOP but refused something (here 0x001B); read back after a SAFEOP request, it has
    not reached SAFEOP, as with 0x0130 = 0x12 it would not."""
    from ecatcfg.runtime.master.reached import SlaveState, not_reached
    slave = SlavePlan("drive", 1001, 0, 0x9A, 0x30924, 0x10420)
    assert not_reached([slave], [SlaveState(AlState.SAFEOP, False, 0)], AlState.SAFEOP) == []
    [line] = not_reached([slave], [SlaveState(AlState.SAFEOP, True, 0x001B)], AlState.SAFEOP)
    assert line.startswith("slave 'drive' (position 0) is in SAFEOP+ERR, not SAFEOP")
    assert "0x001B" in line


def test_a_partial_eni_with_sync1_activates_sync0_and_sync1(compiled, tmp_path):
    """Slave/DC with a CycleTime1 (SYNC1 running): the derived activation is 0x0700
    (cyclic unit, SYNC0 and SYNC1: 0x0981 bits 0-2, ETG.1000.4), not 0x0300."""
    eni = partial(compiled, tmp_path / "partial.xml")
    tree = etree.parse(str(eni))
    [dc] = [s.find("DC") for s in tree.iterfind("Config/Slave") if s.find("DC") is not None]
    assert dc.findtext("CycleTime0")
    cycle1 = dc.find("CycleTime1")
    if cycle1 is None:
        cycle1 = etree.SubElement(dc, "CycleTime1")
        dc.insert(list(dc).index(dc.find("CycleTime0")) + 1, cycle1)
    cycle1.text = "500000"
    tree.write(str(eni))
    done, _ = complete(eni_reader.read_file(eni))
    drive = next(s for s in done.slaves if s.dc is not None and s.dc.cycle_time0)
    activation = [c.payload for c in drive.init_cmds
                  if c.ado == Reg.DC_CYCLIC_UNIT_CONTROL and any(c.payload)]
    assert activation == [bytes.fromhex("0007")], activation


def test_an_sm_whose_pdos_are_partly_described_cannot_be_derived(compiled, tmp_path):
    """ProcessData/Sm3 of the drive assigns two PDOs and only one is described: its length
    is not known (DefaultSize is the default assignment's, not this one's), so the set-up
    cannot be derived: refused naming the SM, not a wrong length written."""
    eni = partial(compiled, tmp_path / "partial.xml")
    tree = etree.parse(str(eni))
    drive = next(s for s in tree.iterfind("Config/Slave") if s.findtext("Info/Name") == "axis1")
    sm3 = drive.find("ProcessData/Sm3")
    assigned = [p.text for p in sm3.iterfind("Pdo")]
    assert len(assigned) >= 2
    def number(text: str) -> int:
        text = text.strip()
        return int(text[2:], 16) if text.lower().startswith("#x") else int(text)
    dropped = [tx for tx in drive.iterfind("ProcessData/TxPdo")
               if number(tx.findtext("Index")) == number(assigned[-1])]
    assert len(dropped) == 1
    dropped[0].getparent().remove(dropped[0])
    tree.write(str(eni))
    rc, report, err = apply_json(eni)
    assert rc == 1 and report["frames"]["sent"] == 0
    refused = {r["slave"]: r["what"] for r in report["refused"]}
    assert refused["axis1"].startswith("ProcessData/Sm3 assigns PDOs that are not all "
                                       "described"), refused


# -- the wait for a slave on its way (reached.awaited_al_status) ---------------------------------

FRAME_NS = 100_000          # each round of the wait: a frame's round trip, 0.1 ms


def wait_for_state(shown: Callable[[float], tuple[int, int] | None], target: int = 0x02,
                   timeout: float = 5.0) -> tuple[bytes | None, float, int]:
    """Run the wait against a slave whose AL status, ``shown(seconds since the start)``, is
    (AL status, AL status code), or None for no answer; on simulated time, a round trip per
    read.  Returns what the wait returned, the seconds it took and the reads it sent."""
    import struct

    from ecatcfg.runtime.clock import SimClock, using
    from ecatcfg.runtime.master.reached import al_status_read, awaited_al_status
    clock = SimClock()
    start = clock.monotonic()
    reads = 0
    with using(clock):
        step = awaited_al_status(al_status_read(3), target, timeout)
        request = next(step)
        while True:
            clock.advance(FRAME_NS)
            reply = None
            if request:
                reads += 1
                [read] = request
                assert (read.cmd, read.adp, read.ado, len(read.data)) == \
                    (Cmd.APRD, -3 & 0xFFFF, Reg.AL_STATUS, 6)
                now = shown(clock.monotonic() - start)
                if now is not None:
                    read.data, read.wkc = struct.pack("<HHH", now[0], 0, now[1]), 1
                reply = [read]
            try:
                request = step.send(reply)
            except StopIteration as done:
                return done.value, clock.monotonic() - start, reads


def test_the_wait_ends_when_the_slave_gets_there():
    got, took, reads = wait_for_state(lambda t: (0x01, 0) if t < 0.030 else (0x02, 0))
    assert got[:2] == b"\x02\x00" and 0.030 <= took < 0.035
    # Three reads at once, then one a millisecond: not a frame per round trip.
    assert reads < 40


def test_a_refusal_ends_the_wait_after_the_error_flag_held_20_ms():
    got, took, _ = wait_for_state(lambda t: (0x11, 0x0016))
    assert got == bytes([0x11, 0, 0, 0, 0x16, 0]) and 0.020 <= took < 0.025


def test_an_error_flag_that_clears_is_no_refusal():
    # The flag of an error being acknowledged, gone after 10 ms; the state after 40 ms.
    got, took, _ = wait_for_state(
        lambda t: (0x11, 0x0016) if t < 0.010 else (0x01, 0) if t < 0.040 else (0x02, 0))
    assert got[:2] == b"\x02\x00" and 0.040 <= took < 0.045


def test_a_slave_that_stays_is_given_up_at_the_timeout():
    got, took, _ = wait_for_state(lambda t: (0x01, 0), timeout=2.0)
    assert got[:2] == b"\x01\x00" and 2.0 <= took < 2.01


def test_a_slave_that_never_answers_is_given_up_after_five_reads():
    got, took, reads = wait_for_state(lambda t: None)
    assert got is None and reads == 5


def test_the_error_flag_must_hold_20_ms_each_time_it_shows():
    # Shown 10 ms, cleared, then shown for good from 30 ms: a refusal at 50 ms, not at 30.
    got, took, _ = wait_for_state(
        lambda t: (0x11, 0x0016) if t < 0.010 or t >= 0.030 else (0x01, 0))
    assert got[0] == 0x11 and 0.050 <= took < 0.055
