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


def upload_requests(frame: bytes, sm0_start: int) -> list[tuple[int, int]]:
    """The (index, subindex) of each CoE SDO upload request a master frame writes into a
    mailbox at ``sm0_start``: mailbox type 3 (CoE), CoE service 2 (SDO request), command
    specifier 0x40 (initiate upload; ETG.1000.6)."""
    from ecatcfg.esc import Cmd
    from ecatcfg.runtime.wire import decode
    out = []
    for dg in decode(frame).datagrams:
        data = dg.data
        if dg.cmd == Cmd.FPWR and dg.address >> 16 == sm0_start and len(data) >= 12 \
                and data[5] & 0x0F == 3 and data[7] >> 4 == 2 and data[8] == 0x40:
            out.append((int.from_bytes(data[9:11], "little"), data[11]))
    return out


def has_logical(frame: bytes) -> bool:
    """Whether the frame carries process data (LRD, LWR, LRW: the cyclic frames)."""
    from ecatcfg.esc import LOGICAL_CMDS
    from ecatcfg.runtime.wire import decode
    return any(dg.cmd in LOGICAL_CMDS for dg in decode(frame).datagrams)


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
        net.clock.sleep(0.4)            # no cycles: the outputs stop
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
        # Without an ENI the slave is named by the identity in its SII (the EXD-402's).
        assert ("slave 4 (0xe0000eca:0x00007201:0x00020000): INIT, not OP\n"
                "  no error flag (AL status code 0x0000)") in done.stdout
    finally:
        proc.send_signal(2)
        proc.wait(10)


# -- a refusal while the network cycles (runtime/master/recovery.py) ---------------------------

def test_a_refusal_during_recovery_carries_its_cause_and_the_cycle_goes_on(plan):
    """The drive is powered off and on while the line cycles in OP, and the master's
    configuration of it has meanwhile lost a byte of SM2: the recovery configures it again
    from INIT, it refuses SAFEOP with 0x001D, and the retry event and ``health`` carry the
    cause line.  The diagnosis runs as the attempt does, one round per cycle: the cycles
    between the refusal and the event are many (a diagnosis that blocked the cycle would
    take none), and in every cycle the lamps got the pattern sent."""
    events = []
    with Network.virtual(plan, esi=[ESI], on_event=events.append) as net:
        net.up()
        patched(net.master.plan, "axis1", "set sm 2 (outputs)", 2, 5)
        drive = next(s for s in net.segment.slaves if s.name == "axis1")
        lamps = next(s for s in net.segment.slaves if s.name == "lamps")
        sm0 = drive.device.sms[0].start_address
        # The master's frames in order: "cyclic", or the objects of the uploads they carry.
        wire: list[object] = []

        def record(frame: bytes, sent: bool) -> None:
            if sent:
                wire.extend(upload_requests(frame, sm0))
                if has_logical(frame):
                    wire.append("cyclic")
        net.master.transport.recorder = record
        drive.power_cycle()                 # registers gone: configured again from INIT
        wrong: list[int] = []
        cycles = 0
        deadline = time.monotonic() + 10
        while not any(e.kind == "retry" and e.slave == "axis1" for e in events):
            assert time.monotonic() < deadline, [e.text for e in events]
            cycles += 1
            pattern = cycles % 256
            for k in range(8):
                net[f"lamps.Channel 1-8.Output {k + 1}"] = bool(pattern >> k & 1)
            net.cycle()
            if lamps.outputs() != bytes([pattern]):
                wrong.append(cycles)
            time.sleep(0.0005)
        [retry] = [e for e in events if e.kind == "retry"]
        assert "0x001D" in retry.text
        assert ("cause: 0x001D invalid output configuration: SM2 length 5 bytes (0x0812), but "
                "the PDO assignment the slave holds (0x1C12 = 0x1601) gives 6 bytes"
                ) in retry.text, retry.text
        assert net.health["axis1"].cause[0].startswith("SM2 length 5 bytes (0x0812)")
        # The diagnosis's uploads, from 0x1C12:00 to the last, went out between cycles: a
        # diagnosis that held the cycle up would send them all with no cyclic frame between.
        first = wire.index((0x1C12, 0))
        last = max(i for i, w in enumerate(wire) if w != "cyclic")
        assert wire[first:last].count("cyclic") >= 5, wire[first:last + 1]
        assert wrong == [], wrong


# -- a DC refusal against the device's ESI --------------------------------------------------

# The ETG.1020 SyncManager output parameter object with its minimum cycle time (subindex 5)
# 500 µs (0x0007A120), added to the example drive as a Beckhoff ESI gives it.
SM_PARAM_TYPES = """
              <DataType>
                <Name>DT1C32</Name>
                <BitSize>80</BitSize>
                <SubItem><SubIdx>0</SubIdx><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>1</SubIdx><Name>Sync mode</Name><Type>UINT</Type><BitSize>16</BitSize><BitOffs>16</BitOffs><Flags><Access>rw</Access></Flags></SubItem>
                <SubItem><SubIdx>5</SubIdx><Name>Minimum cycle time</Name><Type>UDINT</Type><BitSize>32</BitSize><BitOffs>48</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
              </DataType>
"""
SM_PARAM_OBJECT = """
              <Object>
                <Index>#x1C32</Index><Name>SM output parameter</Name><Type>DT1C32</Type><BitSize>80</BitSize>
                <Info>
                  <SubItem><Name>SubIndex 000</Name><Info><DefaultData>05</DefaultData></Info></SubItem>
                  <SubItem><Name>Sync mode</Name><Info><DefaultData>0200</DefaultData></Info></SubItem>
                  <SubItem><Name>Minimum cycle time</Name><Info><DefaultData>20a10700</DefaultData></Info></SubItem>
                </Info>
                <Flags><Access>ro</Access><Category>o</Category></Flags>
              </Object>
"""


@pytest.fixture
def slow_drive_esi(tmp_path):
    """The example ESI files, the drive's with 0x1C32:05 = 500 µs."""
    import shutil
    folder = tmp_path / "esi"
    folder.mkdir()
    for esi in ESI.glob("*.xml"):
        shutil.copy(esi, folder)
    drive = folder / "ecatcfg-EXD402-drive.xml"
    text = drive.read_text()
    text = text.replace("<DataTypes>", "<DataTypes>" + SM_PARAM_TYPES, 1)
    text = text.replace("<Objects>", "<Objects>" + SM_PARAM_OBJECT, 1)
    drive.write_text(text)
    return folder


def cycle_250us(plan):
    """The example line at a 250 µs bus cycle: the drive's SYNC0 every cycle (its op mode
    'DC', CycleTimeSync0 Factor 1), 0x09A0 = 250000 ns."""
    cmd = next(c for c in plan.slave("axis1").init_cmds if c.comment == "set DC cycle time")
    data = bytearray(cmd.payload)
    struct.pack_into("<I", data, 0, 250_000)
    cmd.data = bytes(data)
    plan.slave("axis1").dc.cycle_time0 = 250_000
    for cyclic in plan.cyclic:
        cyclic.cycle_time = 250
    return plan


def test_0x0035_compares_the_sync0_cycle_with_the_devices_minimum_and_op_mode(
        plan, slow_drive_esi):
    """A drive whose dictionary says 0x1C32:05 = 500 µs refuses a 250 µs SYNC0 cycle with
    0x0035, as firmware on the Slave Stack Code does; the cause names the cycle, the
    minimum the slave holds, and, from its ESI, the minimum and the op mode 'DC'."""
    from ecatcfg.esi.library import Library
    with Network.virtual(cycle_250us(plan), esi=[slow_drive_esi], esi_cache=False) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
        # doctor without the ENI: the device found by the identity in the drive's SII; the
        # op mode's cycle is not known without the ENI's bus cycle.
        _, findings = doctor(net.master.transport, AlState.OP, None,
                             Library([slow_drive_esi], cache=False))
    [drive] = [f for f in findings if f.cause is not None]
    assert drive.position == 4 and drive.cause.code == 0x0035
    assert drive.cause.lines[1] == ("the SYNC0 cycle 250 µs, the device allows ≥ 500 µs (the "
                                    "slave's minimum cycle time 0x1C32:05 = 500000 ns)")
    assert drive.cause.lines[2].startswith("the device's ESI gives a minimum cycle time "
                                           "500 µs")
    assert drive.cause.lines[3].endswith("): SYNC0 every bus cycle")
    assert err.value.al_code == 0x0035
    [cause] = err.value.causes
    lines = cause["cause"]
    assert lines[0].startswith("SYNC activation 0x0981 = 0x03, SYNC0 cycle time 0x09A0 = "
                               "250000 ns")
    assert lines[1] == "the ENI's SYNC0 cycle time is 250000 ns"
    assert lines[2] == ("the SYNC0 cycle 250 µs, the device allows ≥ 500 µs (the slave's "
                        "minimum cycle time 0x1C32:05 = 500000 ns)")
    drive = slow_drive_esi / "ecatcfg-EXD402-drive.xml"
    assert lines[3].startswith("the device's ESI gives a minimum cycle time 500 µs (ESI "
                               f"0x1C32:05 default, {drive}:")
    assert lines[4].startswith("DC OpMode 'DC' (AssignActivate 0x0300, ")
    assert lines[4].endswith("): SYNC0 every bus cycle = 250 µs")
    dc = cause["dc"]
    assert (dc["sync0_cycle_ns"], dc["min_cycle_ns"], dc["esi"]["min_cycle_ns"]) == (
        250_000, 500_000, 500_000)
    assert dc["esi"]["op_modes"] == [{"name": "DC", "assign_activate": 0x0300, "factor": 1,
                                      "fixed_ns": None, "cycle_ns": 250_000}]


def test_0x0035_without_esi_says_what_the_slave_holds_and_that_esi_says_more(
        plan, slow_drive_esi):
    """The same line emulated from the ESI, the master given none: the cause has the
    registers, the minimum the slave reports over CoE, and the hint."""
    from rig import serve_in_memory

    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate
    plan = cycle_250us(plan)
    segment = emulate.segment(emulate.specs_from_eni(
        plan, Library([slow_drive_esi], cache=False), "x"))
    link, close = serve_in_memory(segment)
    with Network(plan, link, _closers=[close]) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
    [cause] = err.value.causes
    assert cause["cause"][2] == ("the SYNC0 cycle 250 µs, the device allows ≥ 500 µs (the "
                                 "slave's minimum cycle time 0x1C32:05 = 500000 ns)")
    assert cause["cause"][3].startswith("with --esi, the cycle would be compared with the "
                                        "device's DC op modes")
    assert "esi" not in cause["dc"]


def test_the_emulated_drive_takes_a_sync0_cycle_at_its_minimum(plan, slow_drive_esi):
    """500 µs, the minimum its dictionary gives, is accepted (the check is "shorter than")."""
    plan = cycle_250us(plan)
    cmd = next(c for c in plan.slave("axis1").init_cmds if c.comment == "set DC cycle time")
    data = bytearray(cmd.payload)
    struct.pack_into("<I", data, 0, 500_000)
    cmd.data = bytes(data)
    with Network.virtual(plan, esi=[slow_drive_esi], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP


# -- one mailbox per diagnosis ----------------------------------------------------------------

def test_a_diagnosis_prepares_the_mailbox_once_for_all_its_uploads(plan):
    """``doctor`` without an ENI reads the drive's CoE objects through a mailbox it finds
    from the SII (words 0x0018-0x001C) and its SyncManagers: that is done once per
    diagnosis, not once per upload.  Counted on the wire: the SII read commands (a write
    of the read command 0x0100 to 0x0502) against the SDO upload requests (CoE SDO
    service, command specifier 2: "initiate upload")."""
    from ecatcfg.esc import (EEPROM_CMD_READ, SII_MAILBOX_PROTOCOLS, SII_STD_MAILBOX, Cmd,
                             Reg)
    from ecatcfg.runtime.wire import decode
    with Network.virtual(patched(plan, "axis1", "set sm 2 (outputs)", 2, 5),
                         esi=[ESI]) as net:
        with pytest.raises(ApplyError):
            net.up()
        transport = net.master.transport
        sii_reads: list[int] = []
        uploads: list[tuple[int, int]] = []
        sm0 = next(s for s in net.segment.slaves if s.name == "axis1").device.sms[0]

        def record(frame: bytes, sent: bool) -> None:
            if not sent:
                return
            uploads.extend(upload_requests(frame, sm0.start_address))
            for dg in decode(frame).datagrams:
                if dg.cmd in (Cmd.APWR, Cmd.FPWR) and dg.address >> 16 == Reg.EEPROM_CONTROL \
                        and int.from_bytes(dg.data[:2], "little") & EEPROM_CMD_READ \
                        and SII_STD_MAILBOX <= int.from_bytes(dg.data[2:6], "little") \
                        <= SII_MAILBOX_PROTOCOLS:
                    # The reads of the mailbox words (the SyncManager and PDO categories
                    # the 0x001D cause compares with are read once, from word 0x0040 on).
                    sii_reads.append(dg.address)
        transport.recorder = record
        count, findings = doctor(transport, AlState.OP)
    [axis] = [f for f in findings if f.cause is not None and f.cause.code == 0x001D]
    assert "0x1C12 = 0x1601" in axis.cause.lines[0]
    # 0x1C12:00, 0x1C12:01, 0x1601:00..02, 0x10F3:02 (the drive has none: an abort).
    assert len(uploads) >= 6, uploads
    assert 1 <= len(sii_reads) <= 3, sii_reads


def test_apply_and_doctor_compare_with_the_esi_over_veth(veth_netns, plan, slow_drive_esi,
                                                         tmp_path):
    """``apply --iface --esi`` and ``doctor --esi`` as processes against ``simulate`` of the
    drive whose 0x1C32:05 is 500 µs: apply of the 250 µs ENI is refused with 0x0035 and
    its cause has the ESI's view; after it (``--stay``: the drive keeps PREOP+ERR and
    0x09A0 = 250 µs), doctor with the line's 1000 µs ENI finds the op mode's cycle is
    not the one the drive holds."""
    from rig import start_simulate

    from ecatcfg.eni import writer as eni_writer
    good = tmp_path / "line.eni.xml"
    good.write_bytes(eni_writer.to_bytes(plan))
    bad = tmp_path / "fast.eni.xml"
    bad.write_bytes(eni_writer.to_bytes(cycle_250us(copy.deepcopy(plan))))
    proc, _ = start_simulate(veth_netns, "--esi", str(slow_drive_esi), "--eni", str(good))
    try:
        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "apply", str(bad), "--iface", veth_netns.if_a,
            "--esi", str(slow_drive_esi), "--stay", "--no-cache", "--format", "json"],
            timeout=60, cwd=ROOT)
        assert "Traceback" not in done.stderr, done.stderr
        assert done.returncode == 1
        [cause] = json.loads(done.stdout)["causes"]
        assert cause["slave"] == "axis1" and cause["al_status_code"] == 0x0035
        assert "the SYNC0 cycle 250 µs, the device allows ≥ 500 µs" in cause["cause"][2]
        assert cause["dc"]["esi"]["min_cycle_ns"] == 500_000
        assert cause["dc"]["esi"]["op_modes"][0]["cycle_ns"] == 250_000

        done = veth_netns.run_in(veth_netns.ns_a, [
            sys.executable, "-m", "ecatcfg", "doctor", str(good), "--iface",
            veth_netns.if_a, "--esi", str(slow_drive_esi), "--no-cache"],
            timeout=60, cwd=ROOT)
        assert "Traceback" not in done.stderr, done.stderr
        assert done.returncode == 1
        assert "slave 4 (axis1): PREOP+ERR, not OP" in done.stdout, done.stdout
        assert "the ENI's SYNC0 cycle time is 1000000 ns" in done.stdout
        assert "SYNC0 every bus cycle = 1000 µs, not 250 µs" in done.stdout, done.stdout
    finally:
        proc.send_signal(2)
        proc.wait(10)


def test_a_slave_that_leaves_op_with_a_code_while_cycling_is_reported_with_its_cause(plan):
    """No cycle for 0.3 s: the lamps terminal's SM watchdog (100 ms) expires and it falls to
    SAFEOP+ERR 0x001B.  Once the line cycles again the supervisor takes it offline and its
    offline event carries the cause (the watchdog registers), read between the cycles;
    then it is brought back."""
    events = []
    with Network.virtual(plan, esi=[ESI], on_event=events.append) as net:
        net.up()
        net.clock.sleep(0.3)
        deadline = net.clock.monotonic() + 5
        while not any(e.slave == "lamps" and e.kind == "online" for e in events):
            assert net.clock.monotonic() < deadline, [e.text for e in events]
            net.cycle()
            net.clock.sleep(0.001)
        lamps = [e for e in events if e.slave == "lamps"]
        assert [e.kind for e in lamps] == ["offline", "online"], [e.text for e in lamps]
        text = lamps[0].text
        assert "fell to SAFEOP+ERR, AL status code 0x001B" in text, text
        assert ("cause: 0x001B sync manager watchdog: no process data for 100 ms: outputs "
                "stopped arriving for longer than the SM watchdog time (0x0420 = 1000 x "
                "100 µs, 0x0400 = 2498)") in text, text
        assert net.health["lamps"].cause == []          # back online: nothing to say


def test_esi_files_for_the_causes_are_read_without_the_cache_when_told(plan, tmp_path,
                                                                       monkeypatch):
    """``apply --no-cache --esi`` on a line: the ESI files the causes compare with are
    indexed afresh, with no cache entry written; with the cache, they leave one."""
    from ecatcfg.runtime.link import MemoryLink

    for cached in (False, True):
        home = tmp_path / f"xdg-{cached}"
        monkeypatch.setenv("XDG_CACHE_HOME", str(home))
        Network(plan, MemoryLink(), esi=[ESI], esi_cache=cached).close()
        entries = list((home / "ecatcfg").glob("esi-index-*/*")) if home.exists() else []
        assert bool(entries) == cached, entries


# -- the process-data cause on bit-sized PDOs and inactive FMMUs --------------------------------

def test_0x001e_of_bit_sized_pdos_rounds_their_bits_up_to_whole_bytes(plan):
    """The 4-input terminal 'buttons' (EX1004, examples/esi: four fixed TxPDOs of one BOOL
    bit each, no CoE) with its SM0 set to 2 bytes: 4 bits take 1 byte of the SM (ETG.2010:
    an SM is (bits + 7) / 8 bytes long), so the slave's SII PDOs give 1 byte, not 0 and
    not 'no data'."""
    exc = refusal(patched(plan, "buttons", "set sm 0 (inputs)", 2, 2))
    assert exc.al_code == 0x001E
    [cause] = exc.causes
    assert cause["slave"] == "buttons"
    assert any("SM0 length 2 bytes (0x0802), but the fixed PDOs of the slave's SII "
               "(0x1A00, 0x1A01, 0x1A02, 0x1A03) gives 1 bytes" in line
               for line in cause["cause"]), cause["cause"]
    [sm] = cause["sync_managers"]
    assert (sm["sm"], sm["length"], sm["assigned_bytes"]) == (0, 2, 1)
    assert "sm-length" in cause["rules"]


def test_0x001e_an_fmmu_written_but_not_activated_maps_nothing(plan):
    """The terminal's FMMU 0 written with everything but its activate byte (0x060C = 0,
    ESC datasheet Section II: an FMMU maps only when activated): the slave refuses SAFEOP
    for its inputs, and the cause says no read FMMU maps SM0, not that all agrees."""
    exc = refusal(patched(plan, "buttons", "set fmmu 0 (inputs)", 12, 0))
    assert exc.al_code == 0x001E
    [cause] = exc.causes
    assert cause["slave"] == "buttons"
    assert cause["cause"] == ["no read FMMU maps all of SM0 (0x1000, 1 bytes; FMMUs at 0x0600)"]
    assert cause["rules"] == ["no-fmmu"]
    [sm] = cause["sync_managers"]
    assert sm["fmmu_covers"] is False


# -- 0x0045: an SoE drive's missing IDNs (S-0-0021), read in this process ---------------------

SOE_TOPOLOGY = """\
master: {name: soe-line, cycle_time_us: 1000}
slaves:
  - {name: axes, device: TSD-2 SoE}
"""


def test_0x0045_lists_every_idn_the_drive_misses(tmp_path):
    """The two-axis SoE drive of tests/fixtures/esi/soe_drive.xml with two of drive 0's PS
    writes (S-0-0002, S-0-0032) taken out of its ENI: it refuses SAFEOP with 0x0045 and
    lists both in drive 0's S-0-0021 (the AX5000's IDN list of invalid operation data);
    drive 1 lists none, and the drive after the last (SoE error 0x800A, no such drive)
    ends the reading without a word."""
    from conftest import FIXTURES, write
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import reader as eni_reader, writer as eni_writer
    from ecatcfg.esi.library import Library
    esi = FIXTURES / "esi" / "soe_drive.xml"
    compiled = build.compile_topology(topology.load(write(tmp_path, "t.yaml", SOE_TOPOLOGY)),
                                      Library([esi], cache=False)).plan
    plan = eni_reader.read_bytes(eni_writer.to_bytes(compiled), "soe.xml")
    mailbox = plan.slave("axes").mailbox
    mailbox.soe_init_cmds = [c for c in mailbox.soe_init_cmds
                             if (c.drive_no, c.idn) not in ((0, 2), (0, 32))]
    with Network.virtual(plan, esi=[esi]) as net:
        with pytest.raises(ApplyError) as err:
            net.up()
    assert err.value.al_code == 0x0045
    [cause] = err.value.causes
    assert cause["slave"] == "axes"
    assert cause["cause"] == ["S-0-0021 of drive 0 lists S-0-0002, S-0-0032: IDNs the drive "
                              "needs before SAFEOP that are missing or invalid"]
    assert cause["soe_invalid_idns"] == {0: ["S-0-0002", "S-0-0032"], 1: []}
    assert cause["rules"] == ["soe-idns"]


# -- doctor, the command, in this process over an in-memory line -------------------------------

def test_doctor_reports_each_slave_and_the_one_that_is_not_the_enis(plan, tmp_path,
                                                                    monkeypatch, capsys):
    """``ecatcfg doctor ENI --iface X`` run in this process, its raw socket replaced by an
    in-memory wire to the emulated example line (just powered on: every slave in INIT).
    The ENI expects another product code at the lamps' place: that finding says what the
    lamps' SII holds; every finding is in the JSON with its state and identity lines, and
    the text names each slave with no error flag."""
    from rig import serve_in_memory

    from ecatcfg.cli import main
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime import link as links
    from ecatcfg.runtime.segment import emulate
    wrong = copy.deepcopy(plan)
    wrong.slave("lamps").product_code = 0x00003009
    eni = tmp_path / "wrong.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(wrong))
    closers = []

    def memory_line(iface: str, *args, **kwargs):
        assert iface == "memory0"
        segment = emulate.segment(emulate.specs_from_eni(plan, Library([ESI], cache=False),
                                                         "x"))
        master_end, close = serve_in_memory(segment)
        closers.append(close)
        return master_end
    monkeypatch.setattr(links, "RawLink", memory_line)
    try:
        assert main(["doctor", str(eni), "--iface", "memory0", "--format", "json"]) == 1
        out = json.loads(capsys.readouterr().out)
        assert (out["slaves"], out["ok"]) == (5, False)
        found = {f["name"]: f for f in out["findings"]}
        assert [(f["name"], f["state"]) for f in out["findings"]] == [
            (n, "INIT") for n in ("coupler", "buttons", "sensors", "lamps", "axis1")]
        assert [found[n]["identity"] for n in ("coupler", "buttons", "sensors", "axis1")] == [
            None] * 4
        [lamps] = found["lamps"]["identity"]
        assert lamps.startswith("position 3: the slave's SII holds vendor ID 0xE0000ECA "
                                "(word 0x0008), product code 0x00003008 (word 0x000A)")
        assert main(["doctor", str(eni), "--iface", "memory0"]) == 1
        text = capsys.readouterr().out
        assert ("slave 0 (coupler): INIT, not OP\n  no error flag (AL status code 0x0000): "
                "nothing refused OP; no request for it reached the slave\n") in text
        assert f"slave 3 (lamps): INIT, not OP\n  identity: {lamps}\n" in text
    finally:
        for close in closers:
            close()


def test_0x0016_names_the_mailbox_sm_against_the_sii(plan):
    """The drive's SM1 (mailbox in) written 0x20 bytes long, below the 34 its ESI's MinSize
    allows (its SII's standard mailbox, words 0x1A-0x1B: 0x1080, 128 bytes): it refuses
    PREOP with 0x0016, and the cause gives both SMs as read and the SII's areas.  (64 bytes
    would be taken: MinSize..MaxSize, esi/model.py SyncManager.takes_mailbox_length.)"""
    exc = refusal(patched(plan, "axis1", "set sm 1 (mailbox in)", 2, 0x20))
    assert exc.al_code == 0x0016
    [cause] = exc.causes
    assert cause["cause"] == ["SM1 (0x0808) 0x1080, 32 bytes, the SII's mailbox send area is "
                              "0x1080, 128 bytes (SII word 0x001A)"]
    assert cause["mailbox_sms"] == [
        {"sm": 0, "start": 0x1000, "length": 128, "control": 0x26, "enabled": True,
         "sii_start": 0x1000, "sii_length": 128},
        {"sm": 1, "start": 0x1080, "length": 32, "control": 0x22, "enabled": True,
         "sii_start": 0x1080, "sii_length": 128}]
    assert cause["rules"] == ["mailbox-sm"]


def test_registers_a_lost_frame_took_are_read_again(plan):
    """Half the frames lost on the wire (seeded, half of them after the slaves processed
    them): the diagnosis's register reads (AL status, SM0/SM1, FMMU 0) ask again for what
    did not come back, until the command timeout, and read what a loss-free line reads."""
    from ecatcfg.runtime.master.diagnose import read_registers
    from ecatcfg.runtime.segment.virtual import Faults
    spans = [(0x0130, 6), (0x0800, 16), (0x0600, 16)]
    with Network.virtual(plan, esi=[ESI]) as net:
        want = read_registers(net.master.transport, 4, spans)
    assert set(want) == {0x0130, 0x0800, 0x0600}
    lost = 0
    for seed in range(6):
        with Network.virtual(plan, esi=[ESI], faults=Faults(drop=0.5, seed=seed)) as net:
            counters = net.master.transport.counters
            before = counters.frames_lost
            assert read_registers(net.master.transport, 4, spans) == want, seed
            lost += counters.frames_lost - before
    assert lost > 0                   # the seeds lose frames of these reads


def test_0x0011_of_a_slave_that_left_the_line_says_what_was_not_read(plan):
    """An invalid state change (0x0011) to explain for the drive, which has just been
    unplugged: AL control and AL status get no working counter by the command timeout, and
    the cause says so (not a state machine verdict on registers nobody read); with the
    drive plugged back (still in OP, as it kept power), the same explanation reads both."""
    from ecatcfg.runtime.master.diagnose import explain
    with Network.virtual(plan, esi=[ESI], recovery=False) as net:
        net.up()
        net.segment.remove_cable("axis1")
        gone = explain(net.master.transport, 4, 0x0011)
        assert (gone.code, gone.lines) == (0x0011, [
            "AL control and status (0x0120, 0x0130) not read"])
        assert "requested_state" not in gone.fields
        net.segment.restore_cable("axis1")
        back = explain(net.master.transport, 4, 0x0011)
        assert back.lines[0].startswith("AL control 0x0120 asks for "), back.lines
        assert back.fields["requested_state"] == "OP"
