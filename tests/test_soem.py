"""SOEM (pysoem), a master nobody here wrote, configures the virtual segment and runs it in OP.

Each test builds a veth pair between two private network namespaces: the segment answers on
one end, SOEM (``tests/soem_probe.py``, a process of its own) drives the other.  What SOEM
reports is compared with the ESI files: identities, the process image size of the ESI's
default PDO assignment, states, and process data in both directions.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from rig import serving, start_simulate

from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment

PROBE = Path(__file__).with_name("soem_probe.py")
ROOT = Path(__file__).resolve().parent.parent

EK1100 = "0x2:0x44c2c52:0x120000"
EL2008 = "0x2:0x7d83052:0x120000"
EL1809 = "0x2:0x7113052:0x120000"
ELMO = "0x9a:0x30924:0x10420"
SOES = "0x1337:0x4d2"


@pytest.fixture(scope="module")
def corpus_lib(corpus: Path) -> Library:
    return Library([corpus / "esi"], cache=False)


def build(lib: Library, selectors: list[str]) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                    for i, s in enumerate(selectors)])


def soem(rig, options: dict | None = None, timeout: float = 120) -> dict:
    done = rig.run_in(rig.ns_a, [sys.executable, str(PROBE), rig.if_a,
                                 json.dumps(options or {})], timeout=timeout)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def default_bytes(seg: VirtualSegment) -> list[tuple[int, int]]:
    """(output bytes, input bytes) per slave from the ESI default PDO assignment, the way
    SOEM sizes each SyncManager: whole bytes per SM, bits summed over its PDOs."""
    sizes = []
    for s in seg.slaves:
        dev = s.device
        out = inp = 0
        for sm in dev.sms:
            if sm.virtual or sm.type not in ("Outputs", "Inputs"):
                continue
            bits = sum(e.bit_len or 0 for p in dev.rx_pdos + dev.tx_pdos
                       if p.sm == sm.number and not p.virtual for e in p.entries)
            if sm.type == "Outputs":
                out += bits
            else:
                inp += bits
        sizes.append(((out + 7) // 8, (inp + 7) // 8))
    return sizes


def check_identity(report: dict, seg: VirtualSegment) -> None:
    assert report["found"] == len(seg.slaves)
    found = [(s["vendor"], s["product"], s["revision"]) for s in report["slaves"]]
    assert found == [(s.device.vendor.id, s.device.product_code, s.device.revision)
                     for s in seg.slaves]


def test_beckhoff_io_and_elmo_drive_reach_op(veth_netns, pysoem_module, corpus_lib):
    seg = build(corpus_lib, [EK1100, EL2008, EL1809, ELMO])
    inputs = {2: b"\x34\x12"}
    with serving(veth_netns, seg):
        for pos, data in inputs.items():
            seg.slaves[pos].set_inputs(data)
        report = soem(veth_netns, {"outputs": "a5"})
    check_identity(report, seg)
    sizes = default_bytes(seg)
    assert [tuple(x) for x in report["sizes"]] == sizes
    assert report["iomap"] == sum(o + i for o, i in sizes)
    assert report["safeop"] == 4 and report["op"] == 8, report
    assert report["wkc"] == report["expected_wkc"]
    assert seg.slaves[1].outputs() == b"\x00"          # SOEM took the line down to INIT
    assert report["inputs"][2] == "3412"


def test_outputs_reach_the_slaves_in_op(veth_netns, pysoem_module, corpus_lib):
    seg = build(corpus_lib, [EK1100, EL2008, EL1809])
    seen: list[bytes] = []
    with serving(veth_netns, seg):
        original = seg.slaves[1].outputs_written

        def record(now: float | None = None) -> None:
            original(now)
            if seg.slaves[1].state == 8:
                seen.append(seg.slaves[1].outputs())
        seg.slaves[1].outputs_written = record
        report = soem(veth_netns, {"outputs": "c3", "cycles": 5})
    assert report["op"] == 8
    assert b"\xc3" in seen


def test_soes_demo_slave(veth_netns, pysoem_module, corpus_lib):
    seg = build(corpus_lib, [SOES])
    with serving(veth_netns, seg):
        report = soem(veth_netns, {"outputs": "01"})
    check_identity(report, seg)
    assert [tuple(x) for x in report["sizes"]] == default_bytes(seg)
    assert report["op"] == 8, report


def test_wrong_pdo_assignment_is_refused_like_a_real_slave(veth_netns, pysoem_module,
                                                            corpus_lib):
    # SOEM sizes SM3 for the default assignment, then assigns only the first TxPDO:
    # the slave refuses SAFEOP with 0x001E (invalid input configuration), as SOES does.
    seg = build(corpus_lib, [ELMO])
    tx_default = [p.index for p in seg.slaves[0].device.tx_pdos if p.sm == 3]
    with serving(veth_netns, seg):
        report = soem(veth_netns, {"assign": {"slave": 0, "index": 0x1C13,
                                              "pdos": tx_default[:1] + [0x1A03]}})
    assert report["back_to_preop"] == 2 and report["assign"] == "written", report
    assert report["safeop"] != 4
    state, code = report["al"][0]
    assert (state & 0x0F, state & 0x10, code) == (2, 0x10, 0x001E)


def mixed_line(n: int) -> list[str]:
    pattern = [EK1100, EL2008, EL1809, "EL1004", "EL2004", "EL3202", ELMO, SOES]
    return [pattern[i % len(pattern)] for i in range(n)]


def test_64_slave_mixed_segment(veth_netns, pysoem_module, corpus_lib):
    seg = build(corpus_lib, mixed_line(64))
    with serving(veth_netns, seg):
        report = soem(veth_netns, {"outputs": "0f"}, timeout=180)
    check_identity(report, seg)
    sizes = default_bytes(seg)
    assert [tuple(x) for x in report["sizes"]] == sizes
    assert report["iomap"] == sum(o + i for o, i in sizes)
    assert report["op"] == 8, report["al_op"]
    # The working counter of SOEM's LRW by the ESC rule: +2 per slave with outputs, +1 per
    # slave with inputs.  (SOEM's own expected_wkc leaves out slaves whose inputs are
    # only bits, e.g. EL1004: measured 71 expected against this rule's count.)
    want = sum(2 * (o > 0) + (i > 0) for o, i in sizes)
    assert report["wkc"] == want
    assert report["expected_wkc"] <= want


def test_simulate_command_serves_soem(veth_netns, pysoem_module, corpus, tmp_path):
    topo = tmp_path / "line.yaml"
    topo.write_text("slaves:\n"
                    f"  - {{name: coupler, device: '{EK1100}'}}\n"
                    f"  - {{name: out, device: '{EL2008}'}}\n"
                    f"  - {{name: in, device: '{EL1809}'}}\n"
                    f"  - {{name: drive, device: '{ELMO}'}}\n")
    sim, lines = start_simulate(veth_netns, "--esi", str(corpus / "esi"), "--topology",
                                str(topo))
    assert lines and lines[-1].strip() == f"ready: 4 slaves on {veth_netns.if_b}", \
        "".join(lines) + sim.stderr.read()
    report = soem(veth_netns, {"outputs": "5a"})
    assert report["op"] == 8, report
    sim.terminate()
    out, _ = sim.communicate(timeout=10)
    assert "slave 3 (drive): OP" in out
    assert sim.returncode == 0 and "stopped after" in out
