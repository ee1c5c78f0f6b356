"""The ESC error counters (0x0300-0x0313): how the emulated ESCs count a lossy port
(ESC Section I "Errors and forwarded errors": the first ESC to receive a frame with an
error counts an invalid frame on that port and marks it, every later reception counts a
forwarded RX error; the ESCs from the error on discard their register operations; the
master loses the frame), how they clear, and ``ecatcfg counters`` over veth against
``ecatcfg simulate --faults``.

The expected counts are written out here from that rule for a known line, not computed by
the segment's code.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import rig
from lxml import etree

from ecatcfg.esc import Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import Faults, LossyPort, VirtualSegment

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
LINE = ["EX1100", "EX1004", "EX1004", "EX2008"]
A, B = 0, 1


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def build(lib: Library, *lossy: LossyPort) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                    for i, s in enumerate(LINE)], Faults(lossy=lossy))


def counters(seg: VirtualSegment, position: int) -> dict[str, int]:
    m = seg.slaves[position].mem
    out = {}
    for n, letter in enumerate("ABCD"):
        out.update({f"{letter}.invalid": m[0x0300 + 2 * n], f"{letter}.rx": m[0x0301 + 2 * n],
                    f"{letter}.forwarded": m[0x0308 + n], f"{letter}.lost": m[0x0310 + n]})
    return {k: v for k, v in out.items() if v}


def alias_frame(value: int) -> bytes:
    # BWR of the station alias (0x0012): a plain register every slave that commits the
    # frame takes.
    return wire.encode([wire.Datagram.physical(Cmd.BWR, 0, 0x0012, value.to_bytes(2, "little"))])


def aliases(seg: VirtualSegment) -> list[int]:
    return [int.from_bytes(s.mem[0x0012:0x0014], "little") for s in seg.slaves]


def test_a_frame_spoilt_on_its_way_out_is_counted_forwarded_and_not_committed(lib):
    seg = build(lib, LossyPort("s2", A, 1.0))
    assert seg.process_lossy(alias_frame(0x0707)) is None           # the master loses it
    # Slave 2 saw the error first on port A; slave 3 received it marked on A, and on the
    # way back slaves 2, 1, 0 received it marked on B.
    assert counters(seg, 2) == {"A.invalid": 1, "B.forwarded": 1}
    assert counters(seg, 3) == {"A.forwarded": 1}
    assert counters(seg, 1) == {"B.forwarded": 1} == counters(seg, 0)
    # Slaves 0 and 1 processed the frame before the error; 2 and 3 discard it.
    assert aliases(seg) == [0x0707, 0x0707, 0, 0]


def test_a_frame_spoilt_on_its_way_back_was_committed_by_every_slave(lib):
    seg = build(lib, LossyPort(1, B, 1.0))
    for _ in range(3):
        assert seg.process_lossy(alias_frame(0x0101)) is None
    assert counters(seg, 1) == {"B.invalid": 3}
    assert counters(seg, 0) == {"B.forwarded": 3}
    assert counters(seg, 2) == {} == counters(seg, 3)
    assert aliases(seg) == [0x0101] * 4


def test_counters_stop_at_255_and_clear_by_group(lib):
    seg = build(lib, LossyPort(3, A, 1.0))
    for _ in range(300):
        seg.process_lossy(alias_frame(1))
    assert counters(seg, 3) == {"A.invalid": 255}
    seg.remove_cable(3)                 # both ends of the cable lose their link
    assert counters(seg, 2)["B.lost"] == 1
    assert seg.wired[3].mem[0x0310] == 1
    seg.restore_cable("s3")
    # A write to any of 0x0300-0x030C clears those; the lost link counters stay until one
    # of 0x0310-0x0313 is written.
    slave2 = seg.slaves[2]
    slave2.write(0x0309, b"\x00")
    assert counters(seg, 2) == {"B.lost": 1}
    slave2.write(0x0313, b"\x00")
    assert counters(seg, 2) == {}
    assert counters(seg, 3) == {"A.invalid": 255, "A.lost": 1}


def test_without_lossy_ports_frames_come_back(lib):
    seg = build(lib)
    back = seg.process_lossy(alias_frame(9))
    assert back is not None and wire.decode(back).datagrams[0].wkc == len(LINE)


# -- over veth ---------------------------------------------------------------------------------

def ecatcfg_in(r, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    done = r.run_in(r.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface", r.if_a],
                    timeout=timeout, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def test_counters_over_veth_against_simulate_with_a_lossy_port(veth_netns):
    sim, lines = rig.start_simulate(veth_netns, "--esi", str(ESI), "--topology",
                                    str(ROOT / "examples" / "topology.yaml"),
                                    "--faults", "sensors:A:0.3", "--seed", "7")
    try:
        assert lines and lines[-1].startswith("ready:"), lines
        # Some traffic first, so that frames have crossed the lossy port (each has a 0.3
        # chance of a CRC error there; commands send again what was lost).
        for _ in range(3):
            assert ecatcfg_in(veth_netns, "states").returncode == 0
        first = ecatcfg_in(veth_netns, "counters", "--format", "json")
        assert first.returncode == 0, first.stderr
        rows = json.loads(first.stdout)["slaves"]
        assert len(rows) == 5
        sensors = rows[2]
        # Only the ports each ESC has (0x0007): the ESI's Physics gives one letter per
        # port (read here with lxml), "YY" two MII ports, so A and B and no C or D.
        physics = {d.get("Physics") for f in ESI.glob("*.xml")
                   for d in etree.parse(str(f)).iter("Device")}
        assert physics == {"YY"}
        assert [sorted(r["ports"]) for r in rows] == [["A", "B"]] * 5
        assert sensors["ports"]["A"]["invalid_frames"] > 0
        assert sensors["first_errors"] == ["A"]
        # Behind the bad port the errors arrive marked; before it, only on the way back.
        assert rows[3]["ports"]["A"]["forwarded_rx_errors"] > 0
        assert rows[3]["ports"]["A"]["invalid_frames"] == 0
        assert rows[1]["ports"]["B"]["forwarded_rx_errors"] > 0
        assert [r["first_errors"] for r in rows] == [[], [], ["A"], [], []]

        text = ecatcfg_in(veth_netns, "counters", "--slave", "2", "--clear")
        assert text.returncode == 0, text.stderr
        assert [line.split()[1] for line in text.stdout.splitlines()[1:3]] == ["A", "B"]
        assert not any(line.split()[:2] in (["2", "C"], ["2", "D"])
                       for line in text.stdout.splitlines())
        assert ("slave 2 port A received frames with errors first: check the cable and "
                "connectors into that port") in text.stdout
        assert "counters cleared" in text.stdout

        watch = ecatcfg_in(veth_netns, "counters", "--slave", "2", "--watch", "--clear",
                           "--interval", "0.1", "--rounds", "10", "--format", "json")
        assert watch.returncode == 0, watch.stderr
        rounds = [json.loads(line) for line in watch.stdout.splitlines()]
        assert [r["round"] for r in rounds] == list(range(10))
        changed = [c for r in rounds[1:] for c in r["changes"]]
        # Each read of the watch crosses the lossy port too: its invalid frame counter
        # grows from 0 (cleared at the start).
        invalid = [c for c in changed if c["counter"] == "A.invalid_frames"]
        assert invalid and invalid[0]["old"] == 0
        assert all(c["new"] > c["old"] for c in invalid)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(10)


def test_only_the_ports_the_port_descriptor_names_are_listed():
    """0x0007 (ESC Section II): two bits per port, 0 not implemented, 1 not configured,
    2 E-bus, 3 MII.  A 2-port E-bus terminal (0x0A), a 3-port junction (0x3F), an ESC with
    port C not configured (0x1F)."""
    from ecatcfg.runtime.master.counters import SlaveCounters
    block = bytes(range(1, 0x15))
    two = SlaveCounters.from_block(0, block, 0b00_00_10_10)
    assert [letter for letter, _ in two.present_ports()] == ["A", "B"]
    assert sorted({k.split(".")[0] for k in two.flat() if "." in k}) == ["A", "B"]
    assert [letter for letter, _ in SlaveCounters.from_block(0, block, 0b00_11_11_11)
            .present_ports()] == ["A", "B", "C"]
    assert [letter for letter, _ in SlaveCounters.from_block(0, block, 0b00_01_11_11)
            .present_ports()] == ["A", "B"]
    # port B's counters are the block's bytes 0x02/0x03, 0x09 and 0x11 (+1 from range(1))
    assert two.ports[1] == {"invalid_frames": 3, "rx_errors": 4, "forwarded_rx_errors": 10,
                            "lost_links": 18}


def test_simulate_faults_usage(tmp_path):
    for spec, message in (("sensors:E:0.1", "SLAVE:PORT:P"), ("sensors:A:1.5", "SLAVE:PORT:P"),
                          ("sensors:0.1", "SLAVE:PORT:P"), ("nobody:A:0.1", "nobody")):
        done = subprocess.run([sys.executable, "-m", "ecatcfg", "simulate", "--esi", str(ESI),
                               "--topology", str(ROOT / "examples" / "topology.yaml"),
                               "--iface", "lo", "--duration", "0.1", "--faults", spec,
                               "--no-cache"], capture_output=True, text=True, cwd=ROOT,
                              timeout=60)
        assert done.returncode in (1, 2), (spec, done.stderr)
        assert message in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_the_receptions_of_a_frame_in_a_tree():
    from ecatcfg.runtime.wiring import Plug, Wiring
    # 0 has 1 on port D (3) and 2 on port B (1); 3 is on port B of 1.  Ports in the order
    # A, D, B, C: out to 1 and 3, back through 1's B and 0's D, out to 2, back through 0's B.
    tree = Wiring([None, Plug(0, 3), Plug(0, 1), Plug(1, 1)])
    assert tree.receptions(()) == [(0, 0), (1, 0), (3, 0), (1, 1), (0, 3), (2, 0), (0, 1)]
    assert tree.receptions({1}) == [(0, 0), (2, 0), (0, 1)]
