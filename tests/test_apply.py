"""Acceptance tests of ``ecatcfg apply`` (docs/runtime.md).

The master (``ecatcfg apply`` as a process, or the Network API in-process) runs in one private
network namespace, the slaves it configures (``ecatcfg simulate`` as a process, or a virtual
segment served in-process) in another, joined by a veth pair (``tests/rig.py``).  What is
checked:

1. compiled ENIs reach OP over the veth pair: Beckhoff EK1100 + EL2008 + EL1809, the Elmo Gold
   drive with its PDO assignment over CoE, a 64-slave mixed line; outputs written by variable
   name reach the emulated slaves and their inputs come back;
2. a foreign ENI (EC-Engineer, ``corpus/eni/rocos-ethercat/eni.xml``) reaches OP;
3. tshark finds no malformed packet in the pcap of every run, and the SDO requests it decodes
   carry the index, subindex and data of the ENI's CoE InitCmds (see :func:`check_pcap`);
4. with 5 % of the frames lost, apply reaches OP in at least 99 of 100 runs and never runs
   past its timeouts (in-process over an in-memory link), plus one run over the veth pair;
5. a slave that refuses SAFEOP gives ApplyError / exit 1 naming it and its AL status code;
6. two swapped slaves give exit 1 with the expected/found table, before any configuration
   write (checked in the pcap and in the emulated slaves);
7. ``ecatcfg apply --virtual`` of the example topology reaches OP (no root, no rig).
"""

from __future__ import annotations

import json
import os
import queue
import re
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from rig import serving

from conftest import EXAMPLES, compile_example
from rig import require_tshark, tshark_malformed
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState, Cmd, Transition
from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.clock import SimClock
from ecatcfg.runtime.network import Network
from ecatcfg.runtime.master.replay import (TIMEOUT_COMMAND, TIMEOUT_MAILBOX, ApplyError,
                                           command_timeout)
from ecatcfg.runtime.master.scan import EEPROM_TIMEOUT
from ecatcfg.runtime.segment.virtual import Faults
from ecatcfg.runtime.simwire import SimulatedLink

EK1100 = "0x2:0x44c2c52:0x120000"
EL2008 = "0x2:0x7d83052:0x120000"
EL1809 = "0x2:0x7113052:0x120000"
ELMO = "0x9a:0x30924:0x10420"
SOES = "0x1337:0x4d2"
MIXED = [EK1100, EL2008, EL1809, "EL1004", "EL2004", "EL3202", ELMO, SOES]
FAULT_LINE = [EK1100] + [EL2008] * 3 + [EL1809] * 3 + [ELMO]

APPLY_TIMEOUT = 90          # s: a hung `ecatcfg apply` process is killed after this
READY_TIMEOUT = 60          # s: `ecatcfg simulate` must say "ready:" within this
CYCLES = 50

_WRITES = {Cmd.APWR, Cmd.FPWR, Cmd.BWR, Cmd.APRW, Cmd.FPRW, Cmd.BRW, Cmd.ARMW, Cmd.FRMW,
           Cmd.LWR, Cmd.LRW}


# --------------------------------------------------------------------------- building blocks

@pytest.fixture(scope="module")
def corpus_esi(corpus: Path) -> Path:
    return corpus / "esi"


@pytest.fixture(scope="module")
def corpus_lib(corpus_esi: Path) -> Library:
    return Library([corpus_esi], cache=False)


def topology_text(kinds: list[str], names: list[str] | None = None) -> str:
    names = names or [f"s{i}" for i in range(len(kinds))]
    return "slaves:\n" + "".join(f"  - {{name: '{n}', device: '{k}'}}\n"
                                 for n, k in zip(names, kinds))


def compile_line(lib: Library, kinds: list[str], names: list[str] | None = None
                 ) -> tuple[NetworkPlan, bytes]:
    """The ENI of a line, in-process; the plan is read back from the written bytes (what
    ``ecatcfg apply`` reads)."""
    plan = build.compile_topology(topology.loads(topology_text(kinds, names), "line.yaml"),
                                  lib).plan
    data = eni_writer.to_bytes(plan)
    return eni_reader.read_bytes(data, "line.eni.xml"), data


def write_line(tmp_path: Path, lib: Library, kinds: list[str],
               names: list[str] | None = None) -> tuple[Path, Path, NetworkPlan]:
    """(topology file, ENI file, plan) of a line."""
    topo = tmp_path / "line.yaml"
    topo.write_text(topology_text(kinds, names))
    plan, data = compile_line(lib, kinds, names)
    eni = tmp_path / "line.eni.xml"
    eni.write_bytes(data)
    return topo, eni, plan


def specs_for(lib: Library, kinds: list[str], names: list[str] | None = None,
              plan: NetworkPlan | None = None):
    """The emulated slaves of ``kinds``; plugged as ``plan``'s PreviousPort entries say
    (the compiler puts a drive after a row of terminals on the coupler's Ethernet port)
    when given, else in a line."""
    from dataclasses import replace

    from ecatcfg.runtime.wiring import eni_plugs
    names = names or [f"s{i}" for i in range(len(kinds))]
    specs = [emulate.SlaveSpec(lib.device(lib.find(k).entry), n) for k, n in zip(kinds, names)]
    if plan is None:
        return specs
    plugs = eni_plugs(sorted(plan.slaves, key=lambda s: s.position), "the ENI")
    return [replace(spec, plug=plug) for spec, plug in zip(specs, plugs)]


class Simulator:
    """``ecatcfg simulate`` running in namespace B; its stdout is drained by a thread."""

    def __init__(self, rig, args: list[str], stderr_path: Path) -> None:
        self._err = open(stderr_path, "w+")
        self.proc = rig.popen_in(rig.ns_b, [
            sys.executable, "-m", "ecatcfg", "simulate", "--iface", rig.if_b, "--no-cache",
            *args], stdout=subprocess.PIPE, stderr=self._err, text=True)
        self.lines: list[str] = []
        self._ready: queue.Queue[bool] = queue.Queue()
        threading.Thread(target=self._drain, daemon=True, name="simulate-out").start()

    def _drain(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)
            if line.startswith("ready:"):
                self._ready.put(True)
        self._ready.put(False)

    def wait_ready(self, n: int) -> None:
        try:
            ready = self._ready.get(timeout=READY_TIMEOUT)
        except queue.Empty:
            ready = False
        if not ready:
            self._err.seek(0)
            pytest.fail("ecatcfg simulate did not get ready:\n" + "".join(self.lines)
                        + self._err.read())
        assert self.lines[-1].strip().endswith(f"{n} slaves on vb"), self.lines[-1]

    def stop(self) -> str:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        finally:
            self._err.close()
        return "".join(self.lines)


def simulate(rig, tmp_path: Path, args: list[str], n: int) -> Simulator:
    sim = Simulator(rig, args, tmp_path / "simulate.err")
    sim.wait_ready(n)
    return sim


def apply_cli(rig, eni: Path, *args: str) -> subprocess.CompletedProcess:
    """``ecatcfg apply ENI --iface va ARGS`` in namespace A (killed after APPLY_TIMEOUT)."""
    return rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", "apply", str(eni),
                                 "--iface", rig.if_a, *args], timeout=APPLY_TIMEOUT)


def apply_json(rig, eni: Path, pcap: Path, *args: str) -> dict:
    done = apply_cli(rig, eni, "--format", "json", "--pcap", str(pcap),
                     "--cycles", str(CYCLES), *args)
    try:
        report = json.loads(done.stdout)
    except json.JSONDecodeError:
        pytest.fail(f"exit {done.returncode}, no JSON report:\n{done.stdout}\n{done.stderr}")
    assert done.returncode == 0, report.get("error") or done.stderr
    return report


def check_reached_op(report: dict, plan: NetworkPlan) -> None:
    assert report["ok"] is True and report["error"] is None, report["error"]
    assert report["target"] == "OP"
    names = [s.name for s in sorted(plan.slaves, key=lambda s: s.position)]
    assert [r["name"] for r in report["slaves"]] == names
    bad = [(r["name"], r["highest_state"], r["al_status_code"]) for r in report["slaves"]
           if r["highest_state"] != "OP" or r["state"] != "INIT"]
    assert not bad, bad
    cycles = report["cycles"]
    assert cycles["count"] == CYCLES
    assert cycles["wkc_errors"] == 0, cycles["wkc_error_commands"]
    # A lost frame is not a working-counter error, but on a quiet veth pair there are few.
    assert cycles["lost_frames"] <= CYCLES // 10, cycles


# --------------------------------------------------------------------------- pcap checks

def _walk(tree, key: str):
    """The first value of ``key`` anywhere in a tshark JSON tree, or None."""
    if isinstance(tree, dict):
        if key in tree:
            value = tree[key]
            return value[0] if isinstance(value, list) else value
        items = tree.values()
    elif isinstance(tree, list):
        items = tree
    else:
        return None
    for item in items:
        found = _walk(item, key)
        if found is not None:
            return found
    return None


def _datagram_trees(ecat) -> Iterator[dict]:
    """The per-datagram subtrees of tshark's ``ecat`` layer (``--no-duplicate-keys``: two
    datagrams with the same summary line become a list under one key)."""
    for key, value in ecat.items():
        if not key.startswith("EtherCAT datagram"):
            continue
        for tree in value if isinstance(value, list) else [value]:
            yield tree


SDO_FIELDS = ("counter", "sdoreq", "expedited", "complete", "sdoidx", "sdosub", "sdodata",
              "sdolength", "dsoldata")


def sdo_requests(pcap: Path) -> dict[int, list[dict]]:
    """The SDO requests the master sent (outbound frames only: pcapng direction flag 2), as
    tshark decodes them, per station address: ``{adp: [{field: text}, ...]}`` in order."""
    tshark = require_tshark()
    cmd = [tshark, "-n", "-r", str(pcap), "-T", "json", "--no-duplicate-keys", "-Y",
           "frame.packet_flags_direction == 2 && ecat_mailbox.coe.sdoreq"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out: dict[int, list[dict]] = {}
    for packet in json.loads(proc.stdout or "[]"):
        layers = packet["_source"]["layers"]
        for ecat in layers["ecat"] if isinstance(layers["ecat"], list) else [layers["ecat"]]:
            for dg in _datagram_trees(ecat):
                mbx = dg.get("ecat_mailbox")
                if mbx is None or _walk(mbx, "ecat_mailbox.coe.sdoreq") is None:
                    continue
                adp = int(_walk(dg, "ecat.adp"), 16)
                fields = {
                    "frame": int(_walk(layers["frame"], "frame.number")),
                    "counter": _walk(mbx, "ecat_mailbox.counter"),
                    "sdoreq": _walk(mbx, "ecat_mailbox.coe.sdoreq"),
                    "expedited": _walk(mbx, "ecat_mailbox.coe.sdoccsid.expedited"),
                    "complete": _walk(mbx, "ecat_mailbox.coe.sdoccsid.complete"),
                    "sdoidx": _walk(mbx, "ecat_mailbox.coe.sdoidx"),
                    "sdosub": _walk(mbx, "ecat_mailbox.coe.sdosub"),
                    "sdodata": _walk(mbx, "ecat_mailbox.coe.sdodata"),
                    "sdolength": _walk(mbx, "ecat_mailbox.coe.sdolength"),
                    "dsoldata": _walk(mbx, "ecat_mailbox.coe.dsoldata"),
                }
                out.setdefault(adp, []).append(fields)
    return out


def _collapse_resends(requests: list[dict]) -> list[dict]:
    """A request whose frame is sent again (lost frame, or SM0 still full) is the same
    mailbox message with the same counter: keep one."""
    kept: list[dict] = []
    for r in requests:
        key = tuple(r[f] for f in SDO_FIELDS)
        if kept and tuple(kept[-1][f] for f in SDO_FIELDS) == key:
            continue
        kept.append(r)
    return kept


RUN_ORDER = [Transition.IP, Transition.PS, Transition.SO, Transition.OS, Transition.SP,
             Transition.PI]


def expected_sdo_downloads(plan: NetworkPlan, transitions=RUN_ORDER) -> dict[int, list]:
    """Per station address, the CoE InitCmds the master must send, in the order it runs
    them: transition by transition, file order within one."""
    out = {}
    for s in plan.slaves:
        if s.mailbox is None:
            continue
        cmds = [c for t in transitions for c in s.mailbox.coe_init_cmds
                if t in c.transitions and not c.disabled]
        if cmds:
            out[s.phys_addr] = cmds
    return out


def check_sdo_requests(pcap: Path, plan: NetworkPlan) -> int:
    """The SDO requests tshark decodes against the ENI's CoE InitCmds, slave by slave and in
    order.  Compared: SDO index and subindex always, and the command specifier (1 =
    download); for an expedited transfer (data <= 4 bytes, no CompleteAccess) tshark's
    ``sdodata`` (a uint32) against the InitCmd data read as a little-endian integer; for a
    normal transfer (CompleteAccess, or more than 4 bytes) the CompleteAccess flag, the
    size in the request (``sdolength``) and the data bytes (``dsoldata``).  Returns the
    number of requests compared."""
    seen = {adp: _collapse_resends(reqs) for adp, reqs in sdo_requests(pcap).items()}
    want = expected_sdo_downloads(plan)
    assert set(seen) == set(want), (f"SDO requests to stations {sorted(seen)}, the ENI has "
                                    f"CoE InitCmds for {sorted(want)}")
    compared = 0
    for adp, cmds in want.items():
        got = seen[adp]
        shown = [(r["sdoidx"], r["sdosub"], r["sdodata"] or r["dsoldata"]) for r in got]
        assert len(got) == len(cmds), (adp, shown, [(hex(c.index), c.subindex) for c in cmds])
        for r, c in zip(got, cmds):
            what = f"station {adp}, frame {r['frame']}, InitCmd {c.comment!r}"
            assert int(r["sdoreq"]) == c.ccs, what
            assert (int(r["sdoidx"], 16), int(r["sdosub"], 16)) == (c.index, c.subindex), what
            data = c.data or b""
            if c.ccs != 1:
                continue
            if len(data) <= 4 and not c.complete_access:
                assert r["expedited"] == "1", f"{what}: not expedited"
                assert int(r["sdodata"], 16) == int.from_bytes(data, "little"), (
                    f"{what}: data {r['sdodata']}, InitCmd {data.hex()}")
            elif r["expedited"] == "1":               # CompleteAccess of <= 4 bytes
                assert r["complete"] == "1", what
                assert int(r["sdodata"], 16) == int.from_bytes(data, "little"), what
            else:
                assert r["complete"] == ("1" if c.complete_access else "0"), what
                assert int(r["sdolength"], 16) == len(data), what
                assert (r["dsoldata"] or "").replace(":", "") == data.hex(), (
                    f"{what}: data {r['dsoldata']}, InitCmd {data.hex()}")
            compared += 1
    return compared


def check_pcap(pcap: Path, plan: NetworkPlan) -> int:
    """Test 3 on one run's capture: nothing malformed, SDO requests = CoE InitCmds."""
    assert pcap.is_file() and pcap.stat().st_size > 0
    assert tshark_malformed(pcap) == []
    return check_sdo_requests(pcap, plan)


# --------------------------------------------------------------------------- 1 + 3: veth runs

LINES = {
    "beckhoff-io": [EK1100, EL2008, EL1809],
    "elmo-drive": [ELMO],
    "mixed-64": [MIXED[i % len(MIXED)] for i in range(64)],
}


@pytest.mark.parametrize("line", list(LINES))
def test_cli_apply_over_veth_reaches_op(line, veth_netns, tshark_path, corpus_esi,
                                        corpus_lib, tmp_path):
    kinds = LINES[line]
    topo, eni, plan = write_line(tmp_path, corpus_lib, kinds)
    sim = simulate(veth_netns, tmp_path, ["--esi", str(corpus_esi), "--topology", str(topo)],
                   len(kinds))
    pcap = tmp_path / "apply.pcapng"
    report = apply_json(veth_netns, eni, pcap)
    check_reached_op(report, plan)
    out = sim.stop()
    assert f"slave {len(kinds) - 1} (s{len(kinds) - 1}): OP" in out
    compared = check_pcap(pcap, plan)
    if ELMO in kinds:               # the drive's PDO assignment went over CoE
        per_drive = len(expected_sdo_downloads(plan)[plan.slaves[kinds.index(ELMO)].phys_addr])
        assert per_drive >= 10 and compared == per_drive * kinds.count(ELMO)


def test_process_data_over_veth(veth_netns, corpus_lib):
    """Outputs set by variable name in OP reach the emulated slaves; inputs come back."""
    kinds = [EK1100, EL2008, EL1809, ELMO]
    names = ["coupler", "out", "in", "drive"]
    plan, _ = compile_line(corpus_lib, kinds, names)
    seg = emulate.segment(specs_for(corpus_lib, kinds, names, plan))
    with serving(veth_netns, seg):
        with Network(plan, veth_netns.socket_in(veth_netns.ns_a)) as net:
            net.up()
            assert net.state == AlState.OP
            assert [s.state for s in seg.slaves] == [AlState.OP] * 4
            net["out.Channel 1.Output"] = True
            net["out.Channel 8.Output"] = True
            net["drive.Outputs.Target Position"] = -123456
            net["drive.Outputs.Digital Outputs"] = 0x00010002
            net["drive.Outputs.Control word"] = 0x000F
            assert net.cycle()
            assert seg.slaves[1].outputs() == b"\x81"
            assert seg.slaves[3].outputs() == struct.pack("<iIH", -123456, 0x00010002, 0x0F)
            seg.slaves[2].set_inputs(b"\x05\x80")            # channels 1, 3 and 16
            seg.slaves[3].set_inputs(struct.pack("<iiH", 98765, -2, 0x1237))
            assert net.cycle() and net.cycle()
            assert [net[f"in.Channel {c}.Input"] for c in range(1, 17)] == [
                c in (1, 3, 16) for c in range(1, 17)]
            assert net["drive.Inputs.Position actual value"] == 98765
            assert net["drive.Inputs.Digital Inputs"] == -2
            assert net["drive.Inputs.Status word"] == 0x1237
            net["out.Channel 8.Output"] = False
            assert net.cycle()
            assert seg.slaves[1].outputs() == b"\x01"
    assert [s.state for s in seg.slaves] == [AlState.INIT] * 4


# --------------------------------------------------------------------------- 2: foreign ENI

def test_ec_engineer_eni_reaches_op(veth_netns, tshark_path, corpus, tmp_path):
    eni = corpus / "eni" / "rocos-ethercat" / "eni.xml"
    plan = eni_reader.read_file(eni)
    sim = simulate(veth_netns, tmp_path, ["--esi", str(corpus / "esi" / "drives"),
                                          "--eni", str(eni)], 1)
    pcap = tmp_path / "rocos.pcapng"
    report = apply_json(veth_netns, eni, pcap)
    check_reached_op(report, plan)
    assert "slave 0 (Slave_1001 [Elmo Drive ]): OP" in sim.stop()
    assert check_pcap(pcap, plan) == 20            # 6 clear + 12 assignment + 2 user SDOs


# --------------------------------------------------------------------------- 4: lost frames

def _virtual(plan: NetworkPlan, specs, faults: Faults) -> Network:
    """What ``Network.virtual(clock=SimClock())`` builds (the segment behind a simulated
    wire: a lost frame costs its timeout in simulated time, and a busy host cannot make a
    reply late or a watchdog expire), with the ESI devices resolved once for all runs
    instead of parsing the ESI files again for each of them."""
    clock = SimClock()
    seg = emulate.segment(specs, faults, clock_ns=clock.monotonic_ns)
    net = Network(plan, SimulatedLink(clock, seg))
    net.segment = seg
    return net


def _longest_timeout(plan: NetworkPlan) -> float:
    """The longest single wait the runtime documents for this ENI: any InitCmd's timeout
    (its own, or replay.py's defaults), an SDO transfer, the SII reading of the scan."""
    cmds = list(plan.master.init_cmds) + [c for s in plan.slaves for c in s.init_cmds]
    coe = [c.timeout / 1000 for s in plan.slaves if s.mailbox
           for c in s.mailbox.coe_init_cmds if c.timeout]
    return max([command_timeout(c) for c in cmds] + coe
               + [TIMEOUT_MAILBOX, TIMEOUT_COMMAND, EEPROM_TIMEOUT])


def _within(seconds: float, fn: Callable[[], object]) -> tuple[str, object, float]:
    """``fn()`` on a daemon thread: ("ok", result, s) / ("error", exception, s), or
    ("hung", None, s) when it has not returned after ``seconds``."""
    out: dict = {}

    def body() -> None:
        try:
            out["ok"] = fn()
        except BaseException as exc:          # handed back to the test
            out["error"] = exc

    start = time.monotonic()
    thread = threading.Thread(target=body, daemon=True, name="fault-run")
    thread.start()
    thread.join(seconds)
    took = time.monotonic() - start
    if thread.is_alive():
        return "hung", None, took
    kind = "ok" if "ok" in out else "error"
    return kind, out[kind], took


def test_lost_frames_100_runs_in_process(corpus_lib):
    plan, _ = compile_line(corpus_lib, FAULT_LINE)
    specs = specs_for(corpus_lib, FAULT_LINE, plan=plan)
    limit = _longest_timeout(plan) + 2.0

    def one(seed: int) -> list[AlState]:
        net = _virtual(plan, specs, Faults(drop=0.05, seed=seed))
        begin = net.clock.monotonic()
        try:
            net.up()
            states = [s.state for s in net.segment.slaves]
            for _ in range(5):
                net.cycle()
            net.down()
            simulated[seed] = net.clock.monotonic() - begin
            return states
        finally:
            net.close()

    simulated: dict[int, float] = {}

    results = []
    for seed in range(1, 101):
        results.append((seed, *_within(limit + 10, lambda: one(seed))))
    durations = [took for *_, took in results]
    hung = [seed for seed, kind, _, _ in results if kind == "hung"]
    assert not hung, f"runs that did not end within {limit + 10:.0f} s: seeds {hung}"
    other = [(seed, repr(v)) for seed, kind, v, _ in results
             if kind == "error" and not isinstance(v, ApplyError)]
    assert not other, other
    reached = [seed for seed, kind, v, _ in results if kind == "ok" and v == [AlState.OP] * 8]
    failed = [(seed, str(v)) for seed, kind, v, _ in results if kind == "error"]
    assert len(reached) == 100, failed      # deterministic: no host stall to excuse
    # The time a run would take on a real line: its simulated time.
    too_long = [(seed, round(took, 2)) for seed, took in simulated.items() if took > limit]
    assert not too_long, f"longer than the longest timeout {limit - 2:g} s + 2 s: {too_long}"
    print(f"\n100 runs with 5% lost frames: {len(reached)} reached OP, failures {failed}; "
          f"simulated run time max {max(simulated.values()):.2f} s, host time max "
          f"{max(durations):.2f} s, limit {limit:.1f} s")


def test_lost_frames_over_veth(veth_netns, tshark_path, corpus_esi, corpus_lib, tmp_path):
    topo, eni, plan = write_line(tmp_path, corpus_lib, FAULT_LINE)
    sim = simulate(veth_netns, tmp_path, ["--esi", str(corpus_esi), "--topology", str(topo),
                                          "--drop", "0.05", "--seed", "1"], 8)
    pcap = tmp_path / "drop.pcapng"
    start = time.monotonic()
    done = apply_cli(veth_netns, eni, "--format", "json", "--pcap", str(pcap), "--cycles",
                     str(CYCLES))
    took = time.monotonic() - start
    sim.stop()
    report = json.loads(done.stdout)
    assert done.returncode == 0 and report["ok"], report["error"]
    assert [(r["highest_state"], r["state"]) for r in report["slaves"]] == [("OP", "INIT")] * 8
    assert report["frames"]["lost"] > 0            # the faults did happen
    assert took < _longest_timeout(plan) + 10
    assert tshark_malformed(pcap) == []
    check_sdo_requests(pcap, plan)


# --------------------------------------------------------------------------- 5: refused state

def test_refused_safeop_names_slave_and_code(corpus_lib, corpus_esi):
    kinds = [EK1100, EL2008, EL1809, ELMO]
    plan, _ = compile_line(corpus_lib, kinds, ["coupler", "out", "in", "drive"])
    with Network.virtual(plan, esi=[corpus_esi / "beckhoff",
                                    corpus_esi / "drives" / "Elmo_ECAT_00010420_V11.xml"]) \
            as net:
        net.segment.slaves[3].refuse["PS"] = 0x001E
        with pytest.raises(ApplyError) as err:
            net.up()
        assert net.segment.slaves[3].error and net.segment.slaves[3].status_code == 0x001E
    text = str(err.value)
    assert "slave 'drive'" in text and "0x001E" in text, text
    assert "check device state for SAFEOP" in text, text
    assert err.value.slave == "drive" and err.value.al_code == 0x001E
    assert "timed out" not in text, "a refused state is final: no waiting out the timeout"


def test_refused_safeop_exit_1_from_the_cli(corpus_lib, corpus_esi, tmp_path, monkeypatch,
                                            capsys):
    """The same through ``ecatcfg apply --virtual`` (in-process, to inject the refusal)."""
    from ecatcfg.cli import main

    _, eni, _ = write_line(tmp_path, corpus_lib, [EK1100, EL2008, EL1809],
                           ["coupler", "out", "in"])
    real = Network.virtual.__func__

    def refusing(cls, *args, **kwargs):
        net = real(cls, *args, **kwargs)
        net.segment.slaves[2].refuse["PS"] = 0x001E
        return net

    monkeypatch.setattr(Network, "virtual", classmethod(refusing))
    rc = main(["apply", str(eni), "--virtual", "--esi", str(corpus_esi / "beckhoff"),
               "--format", "json", "--cycles", "5"])
    out, err = capsys.readouterr()
    assert rc == 1
    report = json.loads(out)
    assert report["ok"] is False
    assert "slave 'in'" in report["error"] and "0x001E" in report["error"], report["error"]
    row = next(r for r in report["slaves"] if r["name"] == "in")
    assert row["al_status_code"] == 0x001E and row["highest_state"].endswith("+ERR"), row
    assert row["state"] == "INIT", row                  # after the way down
    # The ENI file and the line of the refused InitCmd lead the message (eni/source.py).
    assert re.search(rf"ecatcfg apply: {re.escape(str(eni))}:\d+: slave 'in' ", err), err
    assert "0x001E" in err


# --------------------------------------------------------------------------- 6: swapped slaves

def test_swapped_slaves_exit_1_before_any_configuration(veth_netns, corpus_lib, tmp_path):
    from scapy.utils import rdpcap

    from ecatcfg.runtime import wire

    _, eni, plan = write_line(tmp_path, corpus_lib, [EK1100, EL2008, EL1809],
                              ["coupler", "out", "in"])
    seg = emulate.segment(specs_for(corpus_lib, [EK1100, EL1809, EL2008],
                                    ["coupler", "in", "out"]))
    pcap = tmp_path / "swapped.pcapng"
    with serving(veth_netns, seg):
        done = apply_cli(veth_netns, eni, "--format", "json", "--pcap", str(pcap))
    assert done.returncode == 1, done.stderr
    report = json.loads(done.stdout)
    error = report["error"]
    assert "do not match the ENI; nothing was configured" in error, error
    assert "expected (ENI)" in error and "found" in error
    rows = {int(line.split()[0]): line for line in error.splitlines()[2:]
            if not line.lstrip().startswith("cause")}
    assert sorted(rows) == [1, 2], error
    # Under the table, where each slave holds the identity read (its SII words).
    assert [c["slave"] for c in report["causes"]] == ["out", "in"]
    assert "product code 0x07113052 (word 0x000A)" in report["causes"][0]["cause"][0]
    assert "out (0x2:0x7d83052:0x120000)" in rows[1] and "0x2:0x7113052:0x120000" in rows[1]
    assert "in (0x2:0x7113052:0x120000)" in rows[2] and "0x2:0x7d83052:0x120000" in rows[2]
    assert "swapped" in rows[1] and "swapped" in rows[2]
    assert "ecatcfg apply:" in done.stderr and "swapped" in done.stderr
    # Nothing but the SII interface registers was written.
    writes = []
    for packet in rdpcap(str(pcap)):
        if getattr(packet, "direction", 2) != 2 or bytes(packet)[12:14] != b"\x88\xa4":
            continue
        for dg in wire.decode(bytes(packet)).datagrams:
            if dg.cmd in _WRITES:
                writes.append((Cmd(dg.cmd).name, dg.adp, dg.ado, len(dg.data)))
    assert writes, "the scan writes the SII control register"
    outside = [w for w in writes if w[0] in ("LWR", "LRW")
               or not (0x0500 <= w[2] and w[2] + w[3] <= 0x0510)]
    assert not outside, outside
    assert [s.state for s in seg.slaves] == [AlState.INIT] * 3
    assert [s.station_address for s in seg.slaves] == [0, 0, 0]


# --------------------------------------------------------------------------- 7: --virtual

def _apply_virtual(eni: Path, *args: str, env: dict | None = None) -> tuple[int, dict, str]:
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(EXAMPLES / "esi"), "--simulated-time", "--format",
                           "json", *args],
                          capture_output=True, text=True, timeout=APPLY_TIMEOUT, env=env)
    return done.returncode, json.loads(done.stdout), done.stderr


def test_apply_with_a_cached_plan_is_the_same_apply(tmp_path):
    """The first apply stores the parsed ENI (eni/cache.py), the next one starts
    from it; --no-cache parses again.  All three configure the same slaves the same way."""
    eni = compile_example(tmp_path / "example.eni.xml")
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "xdg"))
    reports = []
    for args in ((), (), ("--no-cache",)):
        rc, report, err = _apply_virtual(eni, "--cycles", "0", *args, env=env)
        assert rc == 0, err
        reports.append(report)
        if not reports[1:]:
            assert len(list((tmp_path / "xdg").rglob("*.pickle"))) == 1
    assert reports[0]["slaves"] == reports[1]["slaves"] == reports[2]["slaves"]
    assert [r["slaves"][-1]["highest_state"] for r in reports] == ["OP"] * 3
    assert [r["slaves"][-1]["state"] for r in reports] == ["INIT"] * 3
    transitions = [[e.split(" in ")[0] for e in r["events"] if " -> " in e] for r in reports]
    assert transitions[0] == transitions[1] == transitions[2]


def test_virtual_apply_of_the_example_reaches_op(tmp_path):
    eni = compile_example(tmp_path / "example.eni.xml")
    rc, report, err = _apply_virtual(eni, "--cycles", str(CYCLES))
    assert rc == 0, err
    check_reached_op(report, eni_reader.read_file(eni))
    assert report["events"][-1].startswith("PREOP -> INIT: INIT")


def test_virtual_apply_pcap_of_the_example(tshark_path, tmp_path):
    eni = compile_example(tmp_path / "example.eni.xml")
    pcap = tmp_path / "example.pcapng"
    rc, report, err = _apply_virtual(eni, "--cycles", "5", "--pcap", str(pcap))
    assert rc == 0 and report["ok"], err
    # The drive's mappings and assignments go with CompleteAccess (normal transfers).
    assert check_pcap(pcap, eni_reader.read_file(eni)) == 11


def test_a_slave_that_leaves_op_while_the_line_runs_fails_apply(tmp_path: Path) -> None:
    """An SM watchdog of one base tick (0x0420 = 1: 100 µs at the default divider) set in
    PS on the drive, which has firmware: the watchdog runs out between two cycles and the
    drive drops to SAFEOP+ERR 0x001B, while the emulated ESC still counts the writes, so
    every working counter adds up.  apply reads the states after the cycles and fails
    naming the slave and the code, as `check` (ENI121) says it would; it used to exit 0."""
    import copy

    from lxml import etree
    eni = compile_example(tmp_path / "line.eni.xml")
    tree = etree.parse(str(eni))
    axis = tree.xpath("Config/Slave[Info/Name='axis1']")[0]
    template = next(c for c in axis.iterfind("InitCmds/InitCmd")
                    if c.findtext("Cmd") == str(int(Cmd.FPWR)) and
                    [t.text for t in c.iterfind("Transition")] == ["PS"])
    cmd = copy.deepcopy(template)
    cmd.find("Comment").text = "set SM watchdog"
    cmd.find("Ado").text = str(0x0420)
    cmd.find("Data").text = "0100"
    template.addnext(cmd)
    tree.write(str(eni))
    assert subprocess.run([sys.executable, "-m", "ecatcfg", "check", str(eni)],
                          capture_output=True, text=True, timeout=60).returncode == 1
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--esi", str(EXAMPLES / "esi"), "--simulated-time", "--cycles",
                           "50", "--format", "json"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 1, done.stdout + done.stderr
    error = json.loads(done.stdout)["error"]
    assert "left it" in error and "'axis1'" in error and "0x001B" in error, error
