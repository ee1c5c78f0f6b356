"""``ecatcfg scan`` and ``ecatcfg sdo`` against emulated lines.

Runtime cases build a veth pair between two private network namespaces: the virtual segment
answers on one end (in this process, or ``ecatcfg simulate`` in a process of its own), the
command under test runs in the other namespace as a process of its own, as a user would run
it.  What the commands report is compared with the ESI files they were emulated from.
In-memory cases (no namespaces needed) drive ``runtime/master/sdo_tool.py`` over a lossy
:class:`MemoryLink` and check the parts that need no wire (INDEX:SUB, values, usage errors).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from rig import serving

from ecatcfg.esi import datatypes
from ecatcfg.compiler import topology
from ecatcfg.esi.library import Library
from ecatcfg.runtime.master import sdo_tool
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.link import MemoryLink
from ecatcfg.runtime.segment.virtual import Faults, VirtualSegment
from ecatcfg.runtime.master.transport import Transport

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
VENDOR = 0xE0000ECA
LINE = ["EX1100", "EX1004", "EX1004", "EX2008", "EXD-402"]
DRIVE = 4                                   # position of the EXD-402 in LINE


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def build(lib: Library, selectors: list[str], faults: Faults | None = None) -> VirtualSegment:
    # Distinct serial numbers: the scan must report each slave's own.
    return segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}", serial=0x100 + i)
                    for i, s in enumerate(selectors)], faults)


def ecatcfg_in(rig, *argv: str, timeout: float = 30) -> subprocess.CompletedProcess:
    """``python -m ecatcfg ARGV --iface va`` run inside namespace A."""
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface", rig.if_a],
                      timeout=timeout, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def sdo(rig, action: str, slave: int, *argv: str) -> subprocess.CompletedProcess:
    return ecatcfg_in(rig, "sdo", action, "--slave", str(slave), *argv)


def sdo_json(rig, action: str, slave: int, *argv: str) -> dict:
    done = sdo(rig, action, slave, *argv, "--format", "json")
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def ecatcfg(*argv: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "ecatcfg", *argv], capture_output=True,
                          text=True, cwd=cwd, timeout=60)
    assert "Traceback" not in done.stderr, done.stderr
    return done


# -- scan ------------------------------------------------------------------------------------

def test_scan_lists_the_line_and_writes_a_topology_that_compiles(veth_netns, lib, tmp_path):
    seg = build(lib, LINE)
    topo = tmp_path / "found.yaml"
    with serving(veth_netns, seg):
        done = ecatcfg_in(veth_netns, "scan", "--esi", str(ESI), "--format", "json",
                          "--topology-out", str(topo))
        text = ecatcfg_in(veth_netns, "scan", "--esi", str(ESI))
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["count"] == len(LINE)
    rows = report["slaves"]
    assert [r["position"] for r in rows] == list(range(len(LINE)))
    for row, s in zip(rows, seg.slaves):
        dev = s.device
        assert (row["vendor_id"], row["product_code"], row["revision"]) == \
            (dev.vendor.id, dev.product_code, dev.revision)
        assert row["serial_no"] == 0x100 + s.position
        assert row["type"] == dev.type_name.strip() and row["exact"]
        assert row["name"] and row["name"].startswith(dev.type_name.strip())
    names = [r["topology_name"] for r in rows]
    assert names == ["ex1100_1", "ex1004_1", "ex1004_2", "ex2008_1", "exd_402_1"]

    assert text.returncode == 0, text.stderr
    assert f"{len(LINE)} slaves on {veth_netns.if_a}" in text.stdout
    assert "EX1004 4-channel digital input" in text.stdout
    assert "0xe0000eca 0x00007201 0x00020000 0x00000104  3:B      EXD-402" in text.stdout

    loaded = topology.load(topo)
    assert [s.name for s in loaded.topology.slaves] == names
    assert [lib.find(s.device).entry.type for s in loaded.topology.slaves] == LINE
    eni = tmp_path / "found.eni.xml"
    compiled = ecatcfg("compile", str(topo), "--esi", str(ESI), "-o", str(eni))
    assert compiled.returncode == 0, compiled.stderr
    assert eni.read_bytes().startswith(b"<?xml")


def test_scan_without_esi_files_and_unknown_devices(veth_netns, lib, tmp_path):
    seg = build(lib, ["EX1100", "EXD-402"])
    topo = tmp_path / "t.yaml"
    only_io = ESI / "ecatcfg-EXxxxx-digital-io.xml"
    with serving(veth_netns, seg):
        bare = ecatcfg_in(veth_netns, "scan", "--format", "json")
        partial = ecatcfg_in(veth_netns, "scan", "--esi", str(only_io), "--topology-out",
                             str(topo))
    assert bare.returncode == 0, bare.stderr
    rows = json.loads(bare.stdout)["slaves"]
    assert [(r["product_code"], r["type"], r["topology_name"]) for r in rows] == \
        [(0x1001, None, "slave_1"), (0x7201, None, "slave_2")]
    assert partial.returncode == 0, partial.stderr
    assert [s.name for s in topology.load(topo).topology.slaves] == ["slave_1", "slave_2"]
    # Without the ESI files the devices cannot be resolved: compile says which one.
    failed = ecatcfg("compile", str(topo), "--esi", str(only_io), "-o", str(tmp_path / "x"))
    assert failed.returncode == 1 and "0xe0000eca:0x1001" in failed.stderr


def test_scan_with_no_answer_exits_1(veth_netns):
    done = ecatcfg_in(veth_netns, "scan")          # nothing serves the other end
    assert done.returncode == 1
    assert "no frame came back" in done.stderr


# -- sdo --------------------------------------------------------------------------------------

def test_sdo_read_write_and_aborts(veth_netns, lib):
    seg = build(lib, LINE)
    drive = seg.slaves[DRIVE]
    with serving(veth_netns, seg):
        first = sdo_json(veth_netns, "read", DRIVE, "0x1018:01", "--type", "UDINT")
        assert drive.state == 2                                 # brought to PREOP
        text = sdo(veth_netns, "read", DRIVE, "1018:1", "--type", "UDINT")
        wrote = sdo(veth_netns, "write", DRIVE, "0x6060:00", "8", "--type", "SINT")
        back8 = sdo_json(veth_netns, "read", DRIVE, "0x6060:0", "--type", "SINT")
        sdo(veth_netns, "write", DRIVE, "0x6060:00", "-3", "--type", "SINT")
        back_neg = sdo_json(veth_netns, "read", DRIVE, "0x6060:00", "--type", "SINT")
        raw = sdo(veth_netns, "write", DRIVE, "0x60C2:01", "hex:05")
        back_raw = sdo_json(veth_netns, "read", DRIVE, "0x60C2:01")
        whole = sdo_json(veth_netns, "read", DRIVE, "0x1018:00", "--complete-access")
        read_only = sdo(veth_netns, "write", DRIVE, "0x1018:01", "1", "--type", "UDINT")
        missing = sdo(veth_netns, "read", DRIVE, "0x2000:00")
        no_coe = sdo(veth_netns, "read", 1, "0x1018:01")
        no_slave = sdo(veth_netns, "read", 9, "0x1018:01")
        state_after = drive.state

    assert first["value"] == VENDOR and first["hex"] == "ca0e00e0"
    assert first["mailbox_configured"] is True and first["al_status_before"] == 1
    assert text.returncode == 0 and "ca 0e 00 e0" in text.stdout
    assert "UDINT: 3758100170 (0xE0000ECA)" in text.stdout
    assert wrote.returncode == 0, wrote.stderr
    assert back8["value"] == 8 and back8["hex"] == "08"
    assert back8["mailbox_configured"] is False                # PREOP already: SMs reused
    assert back_neg["value"] == -3 and back_neg["hex"] == "fd"
    assert raw.returncode == 0 and back_raw["hex"] == "05"
    # Complete access from SI 0: SI 0 padded to 16 bits, then the four UDINTs.
    assert bytes.fromhex(whole["hex"])[:14] == bytes.fromhex(
        "0400" "ca0e00e0" "01720000" "00000200")
    assert whole["size"] == 18
    assert (read_only.returncode, missing.returncode) == (1, 1)
    assert "0x06010002" in read_only.stderr and "read-only" in read_only.stderr
    assert "0x06020000" in missing.stderr and "does not exist" in missing.stderr
    assert no_coe.returncode == 1 and "does not support CoE" in no_coe.stderr
    assert no_slave.returncode == 1 and "no slave at position 9" in no_slave.stderr
    assert state_after == 2                                     # left in PREOP


def test_sdo_reports_a_refused_preop(veth_netns, lib):
    seg = build(lib, ["EX1100", "EXD-402"])
    seg.slaves[1].refuse["IP"] = 0x0016
    with serving(veth_netns, seg):
        done = sdo(veth_netns, "read", 1, "0x1018:01")
    assert done.returncode == 1
    assert "refused PREOP" in done.stderr and "0x0016" in done.stderr
    assert "invalid mailbox configuration (PREOP)" in done.stderr


def test_simulate_command_serves_scan_and_sdo(veth_netns, tmp_path):
    """The example topology under ``ecatcfg simulate``, all three commands processes."""
    sim = veth_netns.popen_in(veth_netns.ns_b, [
        sys.executable, "-m", "ecatcfg", "simulate", "--esi", str(ESI), "--topology",
        str(ROOT / "examples" / "topology.yaml"), "--iface", veth_netns.if_b,
        "--duration", "60", "--no-cache"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, cwd=ROOT)
    lines = []
    for line in sim.stdout:
        lines.append(line)
        if line.startswith("ready:"):
            break
    assert lines and lines[-1].strip() == f"ready: 5 slaves on {veth_netns.if_b}", \
        "".join(lines) + sim.stderr.read()
    scan = ecatcfg_in(veth_netns, "scan", "--esi", str(ESI), "--format", "json")
    period = sdo_json(veth_netns, "read", 4, "0x60C2:02", "--type", "SINT")
    sim.terminate()
    out, _ = sim.communicate(timeout=10)
    assert scan.returncode == 0, scan.stderr
    assert [r["type"] for r in json.loads(scan.stdout)["slaves"]] == \
        ["EX1100", "EX1004", "EX1004", "EX2008", "EXD-402"]
    assert period["value"] == -3                  # the ESI default (FD): 10^-3 s
    assert "slave 4 (axis1): PREOP" in out
    assert sim.returncode == 0


def test_corpus_devices(veth_netns, corpus):
    """Real vendor files: a Beckhoff coupler and terminal, an Elmo drive with CoE."""
    lib = Library([corpus / "esi"], cache=False)
    selectors = ["0x2:0x44c2c52:0x120000", "0x2:0x7d83052:0x120000", "0x9a:0x30924:0x10420"]
    seg = segment([SlaveSpec(lib.device(lib.find(s).entry)) for s in selectors])
    with serving(veth_netns, seg):
        scan = ecatcfg_in(veth_netns, "scan", "--esi", str(corpus / "esi"), "--format",
                          "json")
        vendor = sdo_json(veth_netns, "read", 2, "0x1018:01", "--type", "UDINT")
        product = sdo_json(veth_netns, "read", 2, "0x1018:02", "--type", "UDINT")
    assert scan.returncode == 0, scan.stderr
    rows = json.loads(scan.stdout)["slaves"]
    assert [r["type"] for r in rows] == [s.device.type_name.strip() for s in seg.slaves]
    assert all(r["exact"] for r in rows)
    assert (vendor["value"], product["value"]) == (0x9A, 0x30924)


# -- without a wire ----------------------------------------------------------------------------

@contextmanager
def memory_line(seg: VirtualSegment) -> Iterator[Transport]:
    ours, theirs = MemoryLink.pair()
    stop = threading.Event()
    thread = threading.Thread(target=seg.serve, args=(theirs,), kwargs={"stop": stop},
                              daemon=True)
    thread.start()
    try:
        yield Transport(ours)
    finally:
        stop.set()
        thread.join(5)


def test_transfers_survive_lost_frames_and_stale_mailbox_messages(lib):
    # Lost frames make the master write requests twice (a lost reply to an SM0 write that
    # arrived) and ask for repeats: old answers left in SM1 must not be taken for new ones.
    seg = build(lib, ["EX1100", "EXD-402"], Faults(drop=0.15, seed=0))
    info = sdo_tool.SlaveMailbox(1)
    with memory_line(seg) as t:
        for i in range(12):
            sdo_tool.sdo_transfer(t, 1, 0x6060, 0, bytes([i % 10]))
            assert sdo_tool.sdo_transfer(t, 1, 0x6060, 0) == bytes([i % 10])
            whole = sdo_tool.sdo_transfer(t, 1, 0x1018, 0, complete_access=True, info=info)
            assert whole[2:6] == VENDOR.to_bytes(4, "little")
        assert t.counters.frames_lost > 0


def test_a_message_left_in_sm1_is_taken_out_first(lib):
    from ecatcfg.runtime.mailbox import encode_upload_request, pad_to
    from ecatcfg.runtime.master.replay import MailboxChannel
    from ecatcfg.runtime.master.lockstep import run_jobs
    from ecatcfg.eni.plan import MailboxArea, MailboxPlan

    seg = build(lib, ["EXD-402"])
    with memory_line(seg) as t:
        assert sdo_tool.sdo_transfer(t, 0, 0x6060, 0) == b"\x08"
        # Another client asks for 0x1000 and goes away without reading the answer.
        channel = MailboxChannel(0x1001, MailboxPlan(MailboxArea(0x1000, 128),
                                                     MailboxArea(0x1080, 128)))
        run_jobs(t, [channel.send(pad_to(encode_upload_request(0x1000, 0, 5), 128),
                                  float("inf"), None, "test")])
        info = sdo_tool.SlaveMailbox(0)
        assert sdo_tool.sdo_transfer(t, 0, 0x1018, 1, info=info) == \
            VENDOR.to_bytes(4, "little")
        assert info.stale_messages == 1 and not info.configured


def test_sdo_usage_errors_exit_2_before_touching_the_wire():
    cases = [
        (["read", "0x1018"], "INDEX:SUB"),
        (["read", "0x10180:1"], "INDEX:SUB"),
        (["write", "0x6060:0", "8"], "needs --type"),
        (["write", "0x6060:0", "8", "--type", "DT1018"], "not a base data type"),
        (["write", "0x6060:0", "300", "--type", "USINT"], "outside USINT"),
        (["write", "0x6060:0", "hex:0g"], "whole bytes"),
        (["read", "0x1018:2", "--complete-access"], "subindex 0 or 1"),
        (["read", "0x1018:1", "--slave", "-1"], "count from 0"),
    ]
    for argv, message in cases:
        extra = [] if "--slave" in argv else ["--slave", "0"]
        done = ecatcfg("sdo", *argv, *extra, "--iface", "no-such-if0")
        assert done.returncode == 2, (argv, done.stderr)
        assert message in done.stderr, (argv, done.stderr)


def test_scan_and_sdo_name_a_missing_interface():
    for argv in (["scan"], ["sdo", "read", "--slave", "0", "0x1018:1"]):
        done = ecatcfg(*argv, "--iface", "no-such-if0")
        assert done.returncode == 2 and "no-such-if0" in done.stderr, done.stderr


@pytest.mark.parametrize("text, expected", [
    ("0x1018:01", (0x1018, 1)), ("1018:1", (0x1018, 1)), ("0x6060:0", (0x6060, 0)),
    ("#x1C12:0A", (0x1C12, 10)), (" 0x60c2 : 2 ", (0x60C2, 2)),
])
def test_parse_address(text, expected):
    assert sdo_tool.parse_address(text) == expected


@pytest.mark.parametrize("value, type_name", [
    (200, "USINT"), (-100, "SINT"), (65535, "UINT"), (-2, "INT"), (0xE0000ECA, "UDINT"),
    (-123456, "DINT"), (-(1 << 63), "LINT"), (0x123456, "UINT24"), (1.5, "REAL"),
    (-0.25, "LREAL"), ("EXD-402", "STRING"), (1, "BOOL"),
])
def test_decode_inverts_encode(value, type_name):
    data = datatypes.encode(value, type_name)
    assert datatypes.decode(data, type_name) == value


def test_decode_refuses_what_does_not_fit():
    with pytest.raises(ValueError, match="4 bytes came back; UINT has 2"):
        datatypes.decode(b"\x01\x02\x03\x04", "UINT")
    with pytest.raises(ValueError, match="not a base data type"):
        datatypes.decode(b"\x01", "DT1018")
    assert datatypes.decode(b"abc\x00\x00", "STRING") == "abc"
