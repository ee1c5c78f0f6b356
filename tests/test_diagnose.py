"""Why a slave refuses a state (``runtime/master/diagnose.py``): each refusal provoked on the
virtual segment by a deliberately wrong ENI, and the cause line checked for the register or
object it names and the values it reads.  The expected values come from the example ESI
files (the drive's RxPDO 0x1601: control word 16 bit + target velocity 32 bit = 6 bytes;
TxPDOs 0x1A00 + the remapped 0x1A01) and the register images the ENI writes, not from the
code under test.  In memory (the Network API) and over veth (``apply`` and ``doctor`` as
processes against an emulated line)."""

from __future__ import annotations

import copy
import json
import struct
import sys
import time

import pytest

from conftest import EXAMPLES, ROOT
from ecatcfg.esc import AlState
from ecatcfg.runtime import Network
from ecatcfg.runtime.master.bringup import VerifyError
from ecatcfg.runtime.master.diagnose import doctor
from ecatcfg.runtime.master.replay import ApplyError

ESI = EXAMPLES / "esi"


@pytest.fixture
def plan(example_plan):
    """The example line's plan, for this test alone to change."""
    return copy.deepcopy(example_plan)


def patched(plan, slave: str, comment: str, offset: int, value: int):
    """``plan`` with the 16-bit value at ``offset`` of ``slave``'s InitCmd ``comment``
    replaced."""
    for cmd in plan.slave(slave).init_cmds:
        if cmd.comment == comment:
            data = bytearray(cmd.payload)
            struct.pack_into("<H", data, offset, value)
            cmd.data = bytes(data)
            return plan
    raise AssertionError(f"no InitCmd {comment!r}")


def refusal(plan) -> ApplyError:
    with Network.virtual(plan, esi=[ESI]) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
    return err.value


def test_0x001d_names_the_sm_length_and_the_assignment_the_slave_holds(plan):
    # SM2 of the drive: 5 bytes instead of the 6 its assigned RxPDO 0x1601 needs.
    exc = refusal(patched(plan, "axis1", "set sm 2 (outputs)", 2, 5))
    assert exc.al_code == 0x001D
    [cause] = exc.causes
    assert cause["slave"] == "axis1" and cause["al_status_code"] == 0x001D
    [line] = cause["cause"]
    assert "SM2 length 5 bytes (0x0812)" in line
    assert "0x1C12 = 0x1601" in line and "gives 6 bytes" in line
    [sm] = cause["sync_managers"]
    assert (sm["sm"], sm["length"], sm["assigned_pdos"], sm["assigned_bytes"]) == (
        2, 5, ["0x1601"], 6)
    assert "cause (axis1): 0x001D invalid output configuration: SM2 length 5" in str(exc)


def test_0x001e_names_the_input_sm_and_its_assignment(plan):
    # SM3 of the drive: TxPDO 0x1A00 (status word + position, 6 bytes) and the remapped
    # 0x1A01 (status word + position + velocity, 10 bytes) = 16 bytes; the ENI says 15.
    exc = refusal(patched(plan, "axis1", "set sm 3 (inputs)", 2, 15))
    assert exc.al_code == 0x001E
    [cause] = exc.causes
    [line] = cause["cause"]
    assert "SM3 length 15 bytes (0x081A)" in line
    assert "0x1C13 = 0x1A00, 0x1A01" in line and "gives 16 bytes" in line


def test_a_slave_read_back_in_error_gets_its_cause_too(plan):
    """An ENI without the drive's own state check for SAFEOP: the refusal is found when
    every slave's AL status is read back after the transition (NotReachedError), and
    the cause is read the same way."""
    from ecatcfg.runtime.master.bringup import NotReachedError
    patched(plan, "axis1", "set sm 2 (outputs)", 2, 5)
    axis = plan.slave("axis1")
    axis.init_cmds = [c for c in axis.init_cmds
                      if c.comment != "check device state for SAFEOP"]
    exc = refusal(plan)
    assert isinstance(exc, NotReachedError)
    [cause] = exc.causes
    assert cause["slave"] == "axis1" and cause["al_status_code"] == 0x001D
    assert "SM2 length 5 bytes (0x0812)" in cause["cause"][0]


# The diagnosis history object (ETG.1020) added to the example drive's dictionary, with one
# message in subindex 6: DiagCode 0x00011234, flags 0x0002, text ID 0x8002, time stamp 1,
# four bytes of parameters.
DIAG_TYPES = """
              <DataType><Name>OCTET_STRING(20)</Name><BitSize>160</BitSize></DataType>
              <DataType>
                <Name>DT10F3</Name>
                <BitSize>224</BitSize>
                <SubItem><SubIdx>0</SubIdx><Name>Number of entries</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>1</SubIdx><Name>Maximum messages</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>16</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>2</SubIdx><Name>Newest message</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>24</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>3</SubIdx><Name>Newest acknowledged message</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>32</BitOffs><Flags><Access>rw</Access></Flags></SubItem>
                <SubItem><SubIdx>4</SubIdx><Name>New messages available</Name><Type>BOOL</Type><BitSize>1</BitSize><BitOffs>40</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>5</SubIdx><Name>Flags</Name><Type>UINT</Type><BitSize>16</BitSize><BitOffs>48</BitOffs><Flags><Access>rw</Access></Flags></SubItem>
                <SubItem><SubIdx>6</SubIdx><Name>Diagnosis message 001</Name><Type>OCTET_STRING(20)</Type><BitSize>160</BitSize><BitOffs>64</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
              </DataType>
"""
DIAG_OBJECT = """
              <Object>
                <Index>#x10F3</Index><Name>Diagnosis history</Name><Type>DT10F3</Type><BitSize>224</BitSize>
                <Info>
                  <SubItem><Name>Number of entries</Name><Info><DefaultData>06</DefaultData></Info></SubItem>
                  <SubItem><Name>Maximum messages</Name><Info><DefaultData>01</DefaultData></Info></SubItem>
                  <SubItem><Name>Newest message</Name><Info><DefaultData>06</DefaultData></Info></SubItem>
                  <SubItem><Name>Newest acknowledged message</Name><Info><DefaultData>00</DefaultData></Info></SubItem>
                  <SubItem><Name>New messages available</Name><Info><DefaultData>01</DefaultData></Info></SubItem>
                  <SubItem><Name>Flags</Name><Info><DefaultData>0000</DefaultData></Info></SubItem>
                  <SubItem><Name>Diagnosis message 001</Name><Info><DefaultData>3412010002000280010000000000000001020304</DefaultData></Info></SubItem>
                </Info>
                <Flags><Access>ro</Access><Category>o</Category></Flags>
              </Object>
"""


def test_the_newest_0x10f3_message_is_said_where_the_slave_has_one(plan, tmp_path):
    import shutil
    for esi in ESI.glob("*.xml"):
        shutil.copy(esi, tmp_path)
    drive = tmp_path / "ecatcfg-EXD402-drive.xml"
    text = drive.read_text()
    text = text.replace("<DataTypes>", "<DataTypes>" + DIAG_TYPES, 1)
    text = text.replace("<Objects>", "<Objects>" + DIAG_OBJECT, 1)
    drive.write_text(text)
    with Network.virtual(patched(plan, "axis1", "set sm 2 (outputs)", 2, 5),
                         esi=[tmp_path], esi_cache=False) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
    [cause] = err.value.causes
    assert cause["cause"][-1] == ("newest diagnosis message 0x10F3:06: code 0x00011234, "
                                  "text ID 0x8002, flags 0x0002")
    assert cause["diagnosis_message"] == {
        "subindex": 6, "diag_code": 0x00011234, "flags": 2, "text_id": 0x8002,
        "time_stamp": 1, "parameters": "01020304"}


def test_0x0035_names_the_sync0_cycle_time_registers(plan):
    axis = plan.slave("axis1")
    axis.init_cmds = [c for c in axis.init_cmds if c.comment != "set DC cycle time"]
    exc = refusal(plan)
    assert exc.al_code == 0x0035
    [cause] = exc.causes
    assert "SYNC activation 0x0981 = 0x03" in cause["cause"][0]
    assert "SYNC0 cycle time 0x09A0 = 0 ns" in cause["cause"][0]
    assert "without a cycle time" in cause["cause"][0]
    # The ENI's cycle (the example line's 1000 µs bus cycle, SYNC0 every cycle).
    assert "the ENI's SYNC0 cycle time is 1000000 ns" in cause["cause"][1]
    assert cause["dc"]["sync0_cycle_ns"] == 0 and cause["dc"]["eni_sync0_cycle_ns"] == 1_000_000


def test_0x001b_names_the_watchdog_time(plan):
    """In OP, outputs that stop for longer than the SM watchdog time (the power-on
    0x0420 = 1000 in the base 0x0400 = 2498: 100 µs, so 100 ms) take the lamps terminal
    (SM watchdog enabled in its ESI) to SAFEOP+ERR 0x001B; ``doctor`` says why."""
    with Network.virtual(plan, esi=[ESI]) as net:
        net.up()
        time.sleep(0.4)                 # no cycles: the outputs stop
        count, findings = doctor(net.master.transport, AlState.OP, plan)
        assert count == 5
        by_name = {f.name: f for f in findings}
        lamps = by_name["lamps"]
        assert lamps.state == "SAFEOP+ERR" and lamps.cause is not None
        assert lamps.cause.code == 0x001B
        [line, *_] = lamps.cause.lines
        assert "no process data for 100 ms" in line
        assert "0x0420 = 1000 x 100 µs" in line and "0x0400 = 2498" in line
        assert "0x0440 = expired" in line
        assert lamps.cause.fields["watchdog"]["time_ms"] == 100


def test_a_wrong_identity_names_the_sii_words(plan):
    """The line is the example's; the ENI expects another product code at the lamps'
    place (EX2008, product code 0x00003008 in its ESI)."""
    from rig import serve_in_memory

    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate
    segment = emulate.segment(emulate.specs_from_eni(plan, Library([ESI], cache=False), "x"))
    link, close = serve_in_memory(segment)
    wrong = copy.deepcopy(plan)
    wrong.slave("lamps").product_code = 0x00003009
    with Network(wrong, link, _closers=[close]) as net:
        with pytest.raises(VerifyError) as err:
            net.up()
    [cause] = err.value.causes
    [line] = cause["cause"]
    assert cause["slave"] == "lamps" and cause["product_code"] == 0x3008
    assert "product code 0x00003008 (word 0x000A)" in line
    assert "vendor ID 0xE0000ECA (word 0x0008)" in line
    assert "the ENI expects lamps (0xe0000eca:0x3009:" in line


# -- over veth: apply and doctor as processes ------------------------------------------------

def test_apply_and_doctor_say_the_cause_over_veth(veth_netns, plan, tmp_path):
    from rig import start_simulate

    from ecatcfg.eni import writer as eni_writer
    good = tmp_path / "line.eni.xml"
    good.write_bytes(eni_writer.to_bytes(plan))
    bad = tmp_path / "bad.eni.xml"
    bad.write_bytes(eni_writer.to_bytes(patched(plan, "axis1",
                                                "set sm 2 (outputs)", 2, 5)))
    proc, _ = start_simulate(veth_netns, "--esi", str(ESI), "--eni", str(good))
    try:
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "apply", str(bad), "--iface", veth_netns.if_a,
            "--format", "json"], timeout=60, cwd=ROOT)
        assert "Traceback" not in done.stderr, done.stderr
        assert done.returncode == 1
        out = json.loads(done.stdout)
        [cause] = out["causes"]
        assert cause["slave"] == "axis1" and cause["al_status_code"] == 0x001D
        assert "0x1C12 = 0x1601" in cause["cause"][0]
        axis = next(r for r in out["slaves"] if r["name"] == "axis1")
        assert axis["cause"] == cause["cause"]

        # After apply took the line down, doctor finds every slave in INIT, not OP.
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "doctor", str(good), "--iface",
            veth_netns.if_a, "--format", "json"], timeout=60, cwd=ROOT)
        assert "Traceback" not in done.stderr, done.stderr
        assert done.returncode == 1
        out = json.loads(done.stdout)
        assert out["slaves"] == 5
        assert [(f["name"], f["state"]) for f in out["findings"]] == [
            (n, "INIT") for n in ("coupler", "buttons", "sensors", "lamps", "axis1")]
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "doctor", "--iface", veth_netns.if_a,
            "--state", "init"], timeout=60, cwd=ROOT)
        assert (done.returncode, done.stdout) == (0, "all 5 slaves in INIT\n"), done.stderr
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "doctor", "--iface", veth_netns.if_a],
            timeout=60, cwd=ROOT)
        assert done.returncode == 1, done.stderr
        assert "slave 4: INIT, not OP\n  no error flag (AL status code 0x0000)" in done.stdout
    finally:
        proc.send_signal(2)
        proc.wait(10)
