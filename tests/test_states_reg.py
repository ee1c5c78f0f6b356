"""``ecatcfg states`` and ``ecatcfg reg`` against an emulated line over veth.

The virtual segment answers in namespace B (in this process); each command runs in
namespace A as a process of its own.  What the commands show and do is compared with the
emulated ESCs' own registers and AL state machine, read in this process.
"""

from __future__ import annotations

import json
import signal
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from rig import serving

from ecatcfg.esc import AlState, AlStatusCode
from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
LINE = ["EX1100", "EX1004", "EXD-402"]
DRIVE = 2                       # the EXD-402: a mailbox device


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def build(lib: Library) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                    for i, s in enumerate(LINE)])


def ecatcfg_in(rig, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface", rig.if_a],
                      timeout=timeout, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def as_json(done: subprocess.CompletedProcess) -> dict:
    return json.loads(done.stdout)


# -- states ----------------------------------------------------------------------------------

def test_states_shows_requests_and_acknowledges_a_refusal(veth_netns, lib):
    seg = build(lib)
    with serving(veth_netns, seg):
        shown = ecatcfg_in(veth_netns, "states", "--format", "json")
        assert shown.returncode == 0, shown.stderr
        assert [r["state"] for r in as_json(shown)["slaves"]] == ["INIT"] * len(LINE)

        # PREOP without SM0/SM1 set up: the drive's firmware refuses it (no mailbox), the
        # others go.
        up = ecatcfg_in(veth_netns, "states", "preop", "--format", "json")
        assert up.returncode == 1
        rows = as_json(up)["slaves"]
        assert [r["reached"] for r in rows] == [True, True, False]
        drive = rows[DRIVE]
        assert drive["error"] and drive["al_status_code"] == AlStatusCode.INVALID_MAILBOX
        assert drive["al_status_code"] == seg.slaves[DRIVE].status_code
        assert seg.slaves[DRIVE].error
        assert [s.state for s in seg.slaves] == [AlState.PREOP, AlState.PREOP, AlState.INIT]
        text = ecatcfg_in(veth_netns, "states", "--slave", str(DRIVE))
        # The drive is shown by the identity in its SII (its ESI's Vendor/Id, ProductCode
        # and RevisionNo: E0000ECA, 7201, 00020000).
        assert text.stdout.strip() == ("2  0xe0000eca:0x00007201:0x00020000  INIT+ERR 0x0016 "
                                       "invalid mailbox configuration (PREOP)")

        # INIT of the drive alone, acknowledging its error: the flag goes.
        back = ecatcfg_in(veth_netns, "states", "--slave", str(DRIVE), "INIT")
        assert back.returncode == 0, back.stdout + back.stderr
        assert back.stdout.strip() == "2  0xe0000eca:0x00007201:0x00020000  INIT"
        assert not seg.slaves[DRIVE].error and seg.slaves[DRIVE].state == AlState.INIT
        assert seg.slaves[0].state == AlState.PREOP          # the others were left alone


def test_states_usage_and_positions(veth_netns, lib):
    with serving(veth_netns, build(lib)):
        missing = ecatcfg_in(veth_netns, "states", "--slave", "7")
    assert missing.returncode == 1
    assert "no slave at position 7: the line has 3 slaves (positions 0..2)" in missing.stderr
    bad = subprocess.run([sys.executable, "-m", "ecatcfg", "states", "--iface", "lo",
                          "running"], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "invalid choice" in bad.stderr


# -- reg ---------------------------------------------------------------------------------------

def reg(rig, action: str, slave: int, *argv: str) -> dict:
    done = ecatcfg_in(rig, "reg", action, "--slave", str(slave), *argv, "--format", "json")
    assert done.returncode == 0, done.stderr
    return as_json(done)


def named(report: dict) -> dict[str, dict]:
    return {r["name"]: r for r in report["registers"]}


def test_reg_reads_and_decodes_al_dl_and_sm_registers(veth_netns, lib):
    seg = build(lib)
    with serving(veth_netns, seg):
        ecatcfg_in(veth_netns, "states", "--slave", str(DRIVE), "preop")   # refused: 0x0016
        al = named(reg(veth_netns, "read", DRIVE, "0x0130:6"))
        # SM0 of the drive: start 0x1000, 128 bytes, mailbox out (0x26), enabled; written
        # as the ESC's 8 register bytes in wire order.
        image = struct.pack("<HHBBBB", 0x1000, 128, 0x26, 0, 1, 0)
        sm = reg(veth_netns, "write", DRIVE, "0x0800", "hex:" + image.hex())
        station = reg(veth_netns, "write", 0, "0x0010", "0x1234")
        readonly = reg(veth_netns, "write", DRIVE, "0x0130", "0x0008")
        dl_first = named(reg(veth_netns, "read", 0, "0x0110"))["DL status"]["fields"]
        dl_last = named(reg(veth_netns, "read", DRIVE, "110:2"))["DL status"]["fields"]
        text = ecatcfg_in(veth_netns, "reg", "read", "--slave", str(DRIVE), "0x0130:6")
        unknown = ecatcfg_in(veth_netns, "reg", "read", "--slave", "0", "0x0131")
        absent = ecatcfg_in(veth_netns, "reg", "read", "--slave", "9", "0x0130")

    drive = seg.slaves[DRIVE]
    assert al["AL status"]["value"] == drive.al_status == 0x11
    assert al["AL status"]["fields"] == {"state": "INIT", "error": True, "id_loaded": False}
    assert al["AL status code"]["value"] == 0x0016 == drive.status_code
    assert "0x0134 AL status code = 0x0016: text invalid mailbox configuration (PREOP)" \
        in text.stdout

    assert sm["hex"] == image.hex() and bytes(drive.mem[0x0800:0x0808]) == image
    fields = named(sm)["SM0"]["fields"]
    assert (fields["start"], fields["length"], fields["mode"], fields["direction"],
            fields["enable"]) == (0x1000, 128, "mailbox", "ECAT writes", True)
    assert drive.sms[0].start == 0x1000 and drive.sms[0].length == 128

    assert seg.slaves[0].station_address == 0x1234
    assert named(station)["configured station address"]["value"] == 0x1234
    # AL status is read-only for ECAT: the write is taken, the value stays.
    assert readonly["written"] == "0800" and readonly["hex"] == "1100"

    # A line: the first slave has communication on A (the master) and B (the next);
    # the last one on A only, its port B loop closed.
    assert dl_first["port_A"]["communication"] and dl_first["port_B"]["communication"]
    assert dl_last["port_A"]["communication"] and not dl_last["port_B"]["communication"]
    assert dl_last["port_B"]["loop"] == "closed" and dl_first["port_B"]["loop"] == "open"
    assert dl_first["pdi_operational"] is (seg.slaves[0].mem[0x0110] & 1 == 1)

    assert unknown.returncode == 2 and "give its length (ADDR:LEN)" in unknown.stderr
    assert absent.returncode == 1 and "no slave at position 9" in absent.stderr


def test_reg_usage_errors():
    for argv, message in ((["read", "0x10000"], "not ADDR[:LEN]"),
                          (["write", "0x0010", "0x12345"], "does not fit 2 bytes"),
                          (["write", "0x0F00:2", "hex:01"], "is 1 bytes, LEN says 2"),
                          (["read", "0xFFFF:2"], "runs past 0xFFFF")):
        done = subprocess.run([sys.executable, "-m", "ecatcfg", "reg", argv[0], "--iface",
                               "lo", "--slave", "0", *argv[1:]], capture_output=True,
                              text=True, cwd=ROOT)
        assert done.returncode == 2, (argv, done.stderr)
        assert message in done.stderr and "Traceback" not in done.stderr


def test_reg_decodes_fmmu_sm_and_dc_registers_apply_wrote(veth_netns, tmp_path):
    """After ``apply`` to SAFEOP the drive holds the FMMUs, SyncManagers and DC settings of
    its ENI; ``reg`` shows them field by field, compared with the ENI read with lxml."""
    from lxml import etree

    from rig import start_simulate

    eni = tmp_path / "line.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", "examples/topology.yaml",
                           "--esi", "examples/esi", "-o", str(eni)], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    axis = etree.parse(str(eni)).getroot().findall("Config/Slave")[4]
    written: dict[int, bytes] = {}
    for cmd in axis.findall("InitCmds/InitCmd"):          # the register commands
        transitions = [t.text for t in cmd.findall("Transition")]
        if "PS" in transitions or "IP" in transitions:
            data = cmd.findtext("Data")
            if data and int(cmd.findtext("Ado", "0")) in range(0x0600, 0x0A00):
                written[int(cmd.findtext("Ado"))] = bytes.fromhex(data)
    cycle0 = int(axis.findtext("DC/CycleTime0"))

    sim, lines = start_simulate(veth_netns, "--esi", str(ESI), "--topology",
                                str(ROOT / "examples" / "topology.yaml"))
    try:
        assert lines and lines[-1].startswith("ready:"), lines
        up = ecatcfg_in(veth_netns, "apply", str(eni), "--state", "safeop", "--cycles", "0",
                        "--stay")
        assert up.returncode == 0, up.stdout + up.stderr
        fmmus = named(reg(veth_netns, "read", 4, "0x0600:32"))
        sms = named(reg(veth_netns, "read", 4, "0x0800:32"))
        dc = named(reg(veth_netns, "read", 4, "0x0980:2")) | named(
            reg(veth_netns, "read", 4, "0x09A0:8"))
        al = named(reg(veth_netns, "read", 4, "0x0130"))
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(10)
    assert al["AL status"]["fields"]["state"] == "SAFEOP"
    for n in range(2):
        image = written[0x0600 + 16 * n]
        start, length, sbit, ebit, phys, pbit, kind, active = struct.unpack_from(
            "<IHBBHBBB", image)
        f = fmmus[f"FMMU{n}"]["fields"]
        assert (f["logical_start"], f["length"], f["logical_start_bit"],
                f["logical_stop_bit"], f["physical_start"], f["physical_start_bit"],
                f["active"]) == (start, length, sbit, ebit, phys, pbit, bool(active))
        assert f["type"] == {1: "READ", 2: "WRITE", 3: "READ_WRITE"}[kind]
    for n in range(4):
        image = written.get(0x0800 + 8 * n)
        if image is None:
            continue
        start, length, control = struct.unpack_from("<HHB", image)
        f = sms[f"SM{n}"]["fields"]
        assert (f["start"], f["length"], f["control"], f["enable"]) == \
            (start, length, control, bool(image[6] & 1))
        assert f["mode"] == ("mailbox" if control & 3 == 2 else "buffered")
    activation = written[0x0980][1]
    assert dc["DC activation"]["fields"] == {"cyclic_operation": bool(activation & 1),
                                              "sync0": bool(activation & 2),
                                              "sync1": bool(activation & 4)}
    assert dc["DC activation"]["fields"]["sync0"]
    assert dc["DC SYNC0 cycle time"]["value"] == cycle0


def test_reg_write_beside_a_cycling_master_is_refused_unless_forced(veth_netns, tmp_path):
    """``apply`` cycling the line in namespace A, and ``reg write`` on the same interface:
    its frames come back through that interface while reg sends nothing, so the write is
    refused (exit 2, naming the interface) and the register keeps its value; ``--force``
    writes with a warning.  Once apply has stopped, the same write goes through without a
    word."""
    import time

    from rig import start_simulate

    eni = tmp_path / "line.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", "examples/topology.yaml",
                           "--esi", "examples/esi", "-o", str(eni)], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    sim, lines = start_simulate(veth_netns, "--esi", str(ESI), "--topology",
                                str(ROOT / "examples" / "topology.yaml"))
    apply = veth_netns.popen_in(veth_netns.ns_a, [sys.executable, "-m", "ecatcfg", "apply",
                                                  str(eni), "--iface", veth_netns.if_a],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=ROOT)
    try:
        assert lines and lines[-1].startswith("ready:"), lines
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:          # until apply cycles in OP
            if reg(veth_netns, "read", 1, "0x0130")["registers"][0]["fields"][
                    "state"] == "OP":
                break
            time.sleep(0.2)
        refused = ecatcfg_in(veth_netns, "reg", "write", "--slave", "1", "0x0012", "0x0007")
        assert refused.returncode == 2, refused.stdout + refused.stderr
        assert f"another master is running the line on {veth_netns.if_a}" in refused.stderr
        assert reg(veth_netns, "read", 1, "0x0012")["registers"][0]["value"] == 0
        forced = ecatcfg_in(veth_netns, "reg", "write", "--slave", "1", "0x0012", "0x0007",
                            "--force", "--format", "json")
        assert forced.returncode == 0, forced.stderr
        assert "warning: another master is running the line" in forced.stderr
        assert as_json(forced)["hex"] == "0700"
    finally:
        apply.send_signal(signal.SIGINT)
        apply.communicate(timeout=60)
    try:
        quiet = ecatcfg_in(veth_netns, "reg", "write", "--slave", "1", "0x0012", "0x0008")
        assert quiet.returncode == 0 and "another master" not in quiet.stderr, quiet.stderr
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(10)
