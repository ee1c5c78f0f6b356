"""Branched networks on the runtime side: the virtual segment as a tree, scan and verify of
the tree, DC propagation delays over it.

Expectations are worked out by hand from the wiring rule (a frame enters port 0 and each
ESC takes its open ports in the order 0 -> 3 -> 1 -> 2, ETG.1000.4; SOEM ``ethercatdc.c``,
IgH ``slave.c``) and from the delay model of ``runtime/segment/dc_clock.py``: P on the way from
port 0 through the processing unit to the first open port, F from a port the frame comes
back on to the next one (or out of port 0), C per cable, P to turn round in a slave with
no open downstream port.

The tree used throughout, six DC drives (given to the segment in this order)::

    t0 --D--> t1 --B--> t2
    t0 --B--> t3 --B--> t5
    t0 --C--> t4

Bus order: t0, t1, t2 (port D first), t3, t5 (port B), t4 (port C).
"""

from __future__ import annotations

import dataclasses
import struct

import pytest
from rig import start_simulate

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.esc import Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.segment.dc_clock import (CABLE_DELAY_NS, FORWARDING_DELAY_NS,
                                              PROCESSING_DELAY_NS, DcModel)
from ecatcfg.runtime.wiring import Plug

ESI = EXAMPLES / "esi"
DRIVE = '"0xE0000ECA:0x7201"'
P, F, C = PROCESSING_DELAY_NS, FORWARDING_DELAY_NS, CABLE_DELAY_NS
# A master assumes a frame takes as long out as back; the model does not (P out, F back),
# so a delay may be off by (P - F) / 2 where half a hop is guessed; plus 2 ns: the ports
# latch in their own clock (quartz within ±100 ppm over a few us, rounded to the ns).
TOLERANCE = (P - F) // 2 + 2
A, B_, C_, D = 0, 1, 2, 3                     # ESC ports by ENI letter
TREE = [None, Plug(0, D), Plug(1, B_), Plug(0, B_), Plug(0, C_), Plug(3, B_)]
BUS_ORDER = ["t0", "t1", "t2", "t3", "t5", "t4"]
# When a frame sent at 0 reaches each port (None: no frame there), by hand from the model:
# t0 sends it down D at P; t1 (P + C) down its B at 2P + C, t2 (2P + 2C) turns it round
# (P) and it is back at t1's B at 3P + 3C, out of t1's A at 3P + 3C + F, at t0's D at
# 3P + 4C + F; t0 forwards it down B (F): t3 at 3P + 5C + 2F ...
HAND_TIMES = {
    "t0": (0, 5 * P + 8 * C + 3 * F, 6 * P + 10 * C + 4 * F, 3 * P + 4 * C + F),
    "t1": (P + C, 3 * P + 3 * C, None, None),
    "t2": (2 * P + 2 * C, None, None, None),
    "t3": (3 * P + 5 * C + 2 * F, 5 * P + 7 * C + 2 * F, None, None),
    "t5": (4 * P + 6 * C + 2 * F, None, None, None),
    "t4": (5 * P + 9 * C + 4 * F, None, None, None),
}
LINK = 0x0010                                 # DL status: link on port n = LINK << n
OPEN = 0x0200                                 # loop open, communication: OPEN << 2n
CLOSED = 0x0100                               # loop closed: CLOSED << 2n


def dl_status(*linked: int) -> int:
    """DL status bits 4-15 with links on the ports given (by hand from ESC Section II)."""
    value = 0
    for port in range(4):
        value |= (LINK << port | OPEN << 2 * port) if port in linked else CLOSED << 2 * port
    return value


@pytest.fixture(scope="module")
def drives():
    topo = "master: {name: tree, cycle_time_us: 1000}\nslaves:\n" + "".join(
        f"  - {{name: t{i}, device: {DRIVE}, dc: DC}}\n" for i in range(6))
    library = Library([ESI], cache=False)
    plan = build.compile_topology(topology.loads(topo, "tree.yaml"), library).plan
    return plan, library


class SimClock:
    def __init__(self) -> None:
        self.t = 1_000_000_000_000

    def __call__(self) -> int:
        return self.t


def tree_segment(drives, clock=None, dc=None):
    plan, library = drives
    specs = [dataclasses.replace(s, plug=plug) for s, plug in
             zip(emulate.specs_from_eni(plan, library, "tree"), TREE)]
    return emulate.segment(specs, clock_ns=clock,
                           dc=dc or DcModel(drift_ppm=0.0, start_spread_ns=0))


def send(segment, *datagrams):
    return wire.decode(segment.process(wire.encode(list(datagrams)))).datagrams


def aprd(segment, position: int, ado: int, n: int):
    got, = send(segment, wire.Datagram.physical(Cmd.APRD, -position & 0xFFFF, ado, n))
    return got


# -- the segment --------------------------------------------------------------------------

def test_bus_order_follows_the_ports_processing_order(drives):
    segment = tree_segment(drives)
    assert [s.name for s in segment.slaves] == BUS_ORDER
    assert [s.position for s in segment.slaves] == list(range(6))
    # Auto-increment reaches them in that order; a broadcast counts each once.
    for pos, name in enumerate(BUS_ORDER):
        got = aprd(segment, pos, 0x0110, 2)
        assert got.wkc == 1
    brd, = send(segment, wire.Datagram.physical(Cmd.BRD, 0, 0x0130, 2))
    assert brd.wkc == 6


def test_dl_status_shows_the_ports_with_a_link(drives):
    segment = tree_segment(drives)
    want = {"t0": dl_status(A, B_, C_, D), "t1": dl_status(A, B_), "t2": dl_status(A),
            "t3": dl_status(A, B_), "t5": dl_status(A), "t4": dl_status(A)}
    got = {name: struct.unpack("<H", aprd(segment, pos, 0x0110, 2).data)[0] & 0xFFF0
           for pos, name in enumerate(BUS_ORDER)}
    assert got == want


def test_receive_times_latch_per_port_with_the_hop_delays(drives):
    clock = SimClock()
    segment = tree_segment(drives, clock)           # clocks start at 0 now, no drift
    clock.t += 5_000
    send(segment, wire.Datagram.physical(Cmd.BWR, 0, 0x0900, bytes(4)))
    got = {s.name: struct.unpack_from("<4I", s.mem, 0x0900) for s in segment.slaves}
    want = {name: tuple(0 if t is None else 5_000 + t for t in times)
            for name, times in HAND_TIMES.items()}
    assert got == want


def test_a_removed_cable_takes_the_slaves_behind_it_out_of_the_frame(drives):
    segment = tree_segment(drives)
    gone = segment.remove_cable("t3")
    assert sorted(s.name for s in gone) == ["t3", "t5"]
    assert [s.name for s in segment.slaves] == ["t0", "t1", "t2", "t4"]
    brd, = send(segment, wire.Datagram.physical(Cmd.BRD, 0, 0x0130, 2))
    assert brd.wkc == 4
    assert aprd(segment, 3, 0x0110, 2).wkc == 1                     # t4 moved up to 3
    assert aprd(segment, 4, 0x0110, 2).wkc == 0
    t0 = struct.unpack("<H", aprd(segment, 0, 0x0110, 2).data)[0] & 0xFFF0
    assert t0 == dl_status(A, C_, D)                                # port B: no link
    segment.restore_cable("t3")
    assert [s.name for s in segment.slaves] == BUS_ORDER


def test_a_line_is_the_default_wiring(drives):
    plan, library = drives
    segment = emulate.segment(emulate.specs_from_eni(plan, library, "line"))
    assert [s.name for s in segment.slaves] == [f"t{i}" for i in range(6)]
    assert segment.wiring.is_line


def test_plugging_errors_name_the_slaves(drives):
    plan, library = drives
    specs = emulate.specs_from_eni(plan, library, "tree")
    two = [specs[0], dataclasses.replace(specs[1], plug=Plug(0, D)),
           dataclasses.replace(specs[2], plug=Plug(0, D))]
    with pytest.raises(ValueError, match="both plugged into port 3 of slave 0.*'t2'"):
        emulate.segment(two)
    with pytest.raises(ValueError, match="port 0 faces the master"):
        emulate.segment([specs[0], dataclasses.replace(specs[1], plug=Plug(0, 0))])


# -- an ENI of a tree: apply, scan, verify, DC --------------------------------------------

# The same shape with the names in bus order, as an ENI lists them (PreviousPort: the
# port letter and PhysAddr of the parent).
ENI_TREE = {"t1": ("t0", "D"), "t2": ("t1", "B"), "t3": ("t0", "B"), "t4": ("t3", "B"),
            "t5": ("t0", "C")}
ENI_ARRIVAL = {"t0": 0, "t1": P + C, "t2": 2 * P + 2 * C, "t3": 3 * P + 5 * C + 2 * F,
               "t4": 4 * P + 6 * C + 2 * F, "t5": 5 * P + 9 * C + 4 * F}


def tree_eni(drives, tree=ENI_TREE, no_dc=()):
    """The compiled line of six drives with its PreviousPort entries rewritten to ``tree``
    and no DC settings for the slaves ``no_dc`` (the XML, read back by the ENI reader)."""
    from lxml import etree

    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.eni import writer as eni_writer
    plan, _ = drives
    root = etree.fromstring(eni_writer.to_bytes(plan))
    address = {s.findtext("Info/Name"): s.findtext("Info/PhysAddr")
               for s in root.iter("Slave")}
    for slave in root.iter("Slave"):
        name = slave.findtext("Info/Name")
        if name in no_dc:
            slave.remove(slave.find("DC"))
        if name in tree:
            parent, letter = tree[name]
            slave.find("PreviousPort/Port").text = letter
            slave.find("PreviousPort/PhysAddr").text = address[parent]
    return eni_reader.read_bytes(etree.tostring(root), "tree.eni.xml")


class SimLink:
    """The master's end of a segment that answers at once, each frame 60 us of simulated
    time (as in test_dc.py)."""

    def __init__(self, segment, clock: SimClock) -> None:
        self.segment, self.clock = segment, clock
        self.replies: list[bytes] = []
        self.sent: list[bytes] = []

    def send(self, frame: bytes) -> None:
        self.clock.t += 60_000
        self.sent.append(bytes(frame))
        self.replies.append(bytes(self.segment.process(frame)))

    def recv(self, timeout: float | None = None) -> bytes | None:
        return self.replies.pop(0) if self.replies else None

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        pass


def on_segment(drives, plan, plugs=None, cut=(), dc=None):
    """A Master for ``plan`` on a segment of its slaves plugged as the ENI says, or as
    ``plugs`` (name -> (parent name, letter)) says, with the cables into ``cut`` removed."""
    from ecatcfg.runtime.master.bringup import Master
    _, library = drives
    specs = emulate.specs_from_eni(plan, library, "tree")
    if plugs is not None:
        index = {s.name: k for k, s in enumerate(specs)}
        specs = [dataclasses.replace(s, plug=None if s.name not in plugs else Plug(
            index[plugs[s.name][0]], "ABCD".index(plugs[s.name][1]))) for s in specs]
    clock = SimClock()
    segment = emulate.segment(specs, clock_ns=clock,
                              dc=dc or DcModel(drift_ppm=0.0, start_spread_ns=0))
    for name in cut:
        segment.remove_cable(name)
    link = SimLink(segment, clock)
    return Master(plan, link, dc_threshold_ns=0), segment, link


def test_the_eni_tree_is_emulated_and_scanned_back(drives):
    plan = tree_eni(drives)
    from ecatcfg.runtime.wiring import eni_plugs
    names = [s.name for s in sorted(plan.slaves, key=lambda s: s.position)]
    assert [(names[p.parent], "ABCD"[p.port]) if p else None
            for p in eni_plugs(sorted(plan.slaves, key=lambda s: s.position), "x")] == \
        [None] + [ENI_TREE[n] for n in names[1:]]
    master, segment, _ = on_segment(drives, plan)
    assert [s.name for s in segment.slaves] == names              # the ENI's bus order
    found = master.scan_and_verify()
    assert [(names[f.plug.parent], "ABCD"[f.plug.port]) if f.plug else None
            for f in found] == [None] + [ENI_TREE[n] for n in names[1:]]


def test_a_tree_eni_reaches_op_on_the_virtual_segment(drives):
    from ecatcfg.esc import AlState
    from ecatcfg.runtime import Network
    with Network.virtual(tree_eni(drives), esi=[ESI]) as net:
        assert not net.segment.wiring.is_line
        net.up()
        assert net.state == AlState.OP
        assert all(net.cycle() for _ in range(5))
        assert [s.state for s in net.segment.slaves] == [AlState.OP] * 6


def _verify_error(master, link):
    from ecatcfg.runtime.master.bringup import VerifyError
    with pytest.raises(VerifyError) as err:
        master.scan_and_verify()
    written = {d.ado for f in link.sent for d in wire.decode(f).datagrams
               if d.cmd in (Cmd.APWR, Cmd.FPWR, Cmd.BWR)}
    assert all(0x0500 <= ado < 0x0510 for ado in written), written     # nothing configured
    return err.value


def test_a_slave_in_another_junction_port_is_a_mismatch_with_both_places(drives):
    plan = tree_eni(drives)
    moved = dict(ENI_TREE, t5=("t1", "C"))              # t0's port C -> t1's port C
    master, segment, link = on_segment(drives, plan, moved)
    assert [s.name for s in segment.slaves] == ["t0", "t1", "t2", "t5", "t3", "t4"]
    err = _verify_error(master, link)
    assert [(m.position, m.problem) for m in err.mismatches] == [
        (5, "plugged into another port (found at position 3)")]
    m = err.mismatches[0]
    assert m.expected.startswith("t5 (") and m.expected.endswith(" behind t0 port C")
    assert m.found.endswith(" behind t1 port C")
    assert "t5" in str(err) and "behind t1 port C" in str(err)


def test_a_cable_removed_in_a_branch_names_the_slaves_behind_it(drives):
    plan = tree_eni(drives)
    master, segment, link = on_segment(drives, plan, cut=["t3"])
    err = _verify_error(master, link)
    assert [(m.position, m.expected.split()[0], m.found) for m in err.mismatches] == [
        (3, "t3", "-"), (4, "t4", "-")]
    assert err.mismatches[0].problem == ("missing slave (no slave on port B of t0: cable "
                                         "or slave missing)")
    assert err.mismatches[1].problem == "missing slave"


def test_dc_delays_on_the_tree_equal_the_model(drives):
    """The delays the master writes (0x0928) against the model's: slave s's port 0 sees
    the frame ENI_ARRIVAL[s] after the reference t0 does (by hand, module docstring).  The
    master assumes a frame takes as long out as back, which the model does not: TOLERANCE."""
    from ecatcfg.esc import AlState
    plan = tree_eni(drives)
    master, segment, _ = on_segment(drives, plan, dc=DcModel(drift_ppm=50.0, seed=3))
    master.scan_and_verify()
    master.bring_up(AlState.SAFEOP)
    written = {s.name: struct.unpack_from("<I", s.mem, 0x0928)[0] for s in segment.slaves}
    off = {n: written[n] - ENI_ARRIVAL[n] for n in written}
    assert all(abs(d) <= TOLERANCE for d in off.values()), off
    assert written["t0"] == 0
    # Branches the frame takes later are further away than a line's position suggests:
    # t5 (position 5, third branch) is more than 5 hops of P + C away.
    assert written["t5"] > 5 * (P + C) + TOLERANCE


# -- SOEM, a master nobody here wrote, on `ecatcfg simulate` of the tree ------------------

def _simulate(rig, eni, *extra):
    return start_simulate(rig, "--esi", str(ESI), "--eni", str(eni), *extra)


def _soem(rig, options):
    from test_soem import soem
    return soem(rig, options)


def test_dc_delays_through_a_junction_the_eni_sets_no_dc_for(drives):
    """t0 without DC in the ENI (a junction as TwinCAT writes it): t1 is the reference,
    and the branches on t0's ports B and C are measured with t0's receive times (its ESC
    has a DC unit, 0x0008 bit 2).  Without them t3, t4 and t5 would have no measured slave
    above them.  The reference's estimate and the slave's are each off by up to
    (P - F) / 2 (one guessed half-hop on each path): the tolerance is twice TOLERANCE."""
    from ecatcfg.esc import AlState
    plan = tree_eni(drives, no_dc=["t0"])
    master, segment, _ = on_segment(drives, plan, dc=DcModel(drift_ppm=50.0, seed=5))
    master.scan_and_verify()
    master.bring_up(AlState.SAFEOP)
    written = {s.name: struct.unpack_from("<I", s.mem, 0x0928)[0] for s in segment.slaves
               if s.name != "t0"}
    want = {n: ENI_ARRIVAL[n] - ENI_ARRIVAL["t1"] for n in written}
    off = {n: written[n] - want[n] for n in written}
    assert all(abs(d) <= 2 * TOLERANCE for d in off.values()), (off, written)
    assert written["t1"] == 0


def test_soem_reads_the_tree_from_simulate(veth_netns, pysoem_module, drives, tmp_path):
    """pysoem does not expose SOEM's parent and port of a slave, but its config_dc works
    them out from the DL statuses (ethercatconfig.c, ethercatdc.c) and writes a delay
    computed along them: delays that agree with the model's arrival times (within the
    tolerance of the symmetric-link assumption, test_dc_delays_on_the_tree_equal_the_model)
    show SOEM found each slave on the parent and port the ENI names."""
    from ecatcfg.eni import writer as eni_writer
    eni = tmp_path / "tree.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(tree_eni(drives)))
    sim, lines = _simulate(veth_netns, eni)
    try:
        assert lines and lines[-1].strip() == f"ready: 6 slaves on {veth_netns.if_b}", \
            "".join(lines)
        report = _soem(veth_netns, {"dc": True, "outputs": "5a"})
    finally:
        sim.terminate()
        out, err = sim.communicate(timeout=10)
    assert report["found"] == 6, report
    assert report["dc"] is True
    names = ["t0", "t1", "t2", "t3", "t4", "t5"]
    off = {n: d - ENI_ARRIVAL[n] for n, d in zip(names, report["delays"])}
    assert all(abs(d) <= TOLERANCE for d in off.values()), (off, report["delays"])
    assert report["op"] == 8 and report["wkc"] == report["expected_wkc"], report
    assert "slave 5 (t5): OP" in out, out + err
    # Our master on the same tree, with the clocks simulate has (DcModel()): the same
    # delays as SOEM's, up to the ns the drifting latches round to.
    from ecatcfg.esc import AlState
    master, segment, _ = on_segment(drives, tree_eni(drives), dc=DcModel())
    master.scan_and_verify()
    master.bring_up(AlState.SAFEOP)
    ours = [struct.unpack_from("<I", s.mem, 0x0928)[0] for s in segment.slaves]
    assert all(abs(a - b) <= 2 for a, b in zip(ours, report["delays"])), \
        (ours, report["delays"])


def test_soem_sees_a_removed_cable(veth_netns, pysoem_module, drives, tmp_path):
    from ecatcfg.eni import writer as eni_writer
    eni = tmp_path / "tree.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(tree_eni(drives)))
    sim, lines = _simulate(veth_netns, eni, "--cut", "t3")
    try:
        assert lines and lines[-1].strip() == f"ready: 4 slaves on {veth_netns.if_b}", \
            "".join(lines)
        assert any("cable into t3 removed: t3, t4 not on the frame" in line
                   for line in lines), "".join(lines)
        report = _soem(veth_netns, {})
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    assert report["found"] == 4, report
    assert report["op"] == 8, report


# -- ecatcfg scan and apply on a tree -----------------------------------------------------

def _ecatcfg_in(rig, *argv):
    import sys
    from pathlib import Path
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface", rig.if_a],
                      timeout=60, cwd=Path(__file__).resolve().parent.parent)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def test_scan_writes_parent_and_port_where_the_tree_branches(veth_netns, drives, tmp_path):
    """By hand from ENI_TREE: t2 and t4 sit on port B of the slave before them (a drive,
    Physics YY: no port D the default plugging would take first), so only t1, t3 and t5
    name their parent and port."""
    import json

    from rig import serving
    _, library = drives
    segment = emulate.segment(emulate.specs_from_eni(tree_eni(drives), library, "tree"))
    out = tmp_path / "found.yaml"
    with serving(veth_netns, segment):
        done = _ecatcfg_in(veth_netns, "scan", "--esi", str(ESI), "--topology-out", str(out),
                           "--format", "json", "--no-cache")
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)["slaves"]
    assert [(r["parent_position"], r["port"]) for r in rows] == [
        (None, None), (0, "D"), (1, "B"), (0, "B"), (3, "B"), (0, "C")]
    plugs = [line.split("device:")[1].split("}")[0] for line in out.read_text().splitlines()
             if line.startswith("  - ")]
    assert [p.split(",", 1)[1].strip() if "," in p else "" for p in plugs] == [
        "", "parent: exd_402_1, port: D", "", "parent: exd_402_1, port: B", "",
        "parent: exd_402_1, port: C"], out.read_text()


def test_apply_names_the_slaves_behind_a_removed_cable(veth_netns, drives, tmp_path):
    """apply against simulate --cut: exit 1 before any configuration, naming the missing
    slaves with where the ENI has them."""
    import json

    from ecatcfg.eni import writer as eni_writer
    eni = tmp_path / "tree.eni.xml"
    eni.write_bytes(eni_writer.to_bytes(tree_eni(drives)))
    sim, lines = _simulate(veth_netns, eni, "--cut", "t3")
    try:
        assert lines and lines[-1].startswith("ready: 4 slaves"), "".join(lines)
        done = _ecatcfg_in(veth_netns, "apply", str(eni), "--format", "json")
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    assert done.returncode == 1, done.stdout + done.stderr
    table = json.loads(done.stdout)["error"]
    assert "nothing was configured" in table
    row3 = next(line for line in table.splitlines() if line.strip().startswith("3  t3 ("))
    assert "behind t0 port B" in row3 and "missing slave (no slave on port B of t0" in row3
    row4 = next(line for line in table.splitlines() if line.strip().startswith("4  t4 ("))
    assert "behind t3 port B" in row4 and "missing slave" in row4
    # The final table names the ENI's slaves, not auto-increment positions: t5 is found at
    # position 3 (t3 and t4 are gone), so its state is the one read there.
    slaves = {r["name"]: r for r in json.loads(done.stdout)["slaves"]}
    assert slaves["t3"]["state"] == slaves["t4"]["state"] == "not found", slaves
    assert all(slaves[n]["state"] == slaves[n]["highest_state"] == "INIT"
               for n in ("t0", "t1", "t2", "t5")), slaves


def test_a_previous_port_that_cannot_be_wired_is_an_error_naming_the_slave(drives):
    from ecatcfg.errors import EcatcfgError
    _, library = drives
    for tree, says in (
            (dict(ENI_TREE, t4=("t3", "A")), "slave 't4': PreviousPort 'A' of PhysAddr "
                                             "1004: the port is not B, C or D"),
            (dict(ENI_TREE, t5=("t1", "B")), "slaves 2 and 5 are both plugged into port 1 "
                                             "of slave 1")):
        with pytest.raises(EcatcfgError) as err:
            emulate.specs_from_eni(tree_eni(drives, tree), library, "tree.eni.xml")
        assert says in str(err.value) and str(err.value).startswith("tree.eni.xml: ")


def test_the_tree_from_dl_statuses_by_hand():
    """DL statuses written by hand (ESC Section II 0x0110; SOEM counts a port active when
    bits 9+2n, 8+2n read 1, 0): a junction with all four ports, a slave with ports A and
    B on its port D, an end on that one's B, an end on the junction's B, an end on its C.
    The frame takes D before B before C."""
    from ecatcfg.runtime.wiring import active_ports, plugs_from_dl_status
    statuses = [dl_status(A, B_, C_, D) | 0x1, dl_status(A, B_) | 0x3, dl_status(A),
                dl_status(A), dl_status(A)]
    assert active_ports(statuses[0]) == [0, 1, 2, 3]
    assert active_ports(0x5A31) == [0, 1]                 # a real EK1100 between two slaves
    assert plugs_from_dl_status(statuses) == [None, Plug(0, D), Plug(1, B_), Plug(0, B_),
                                              Plug(0, C_)]
    # A line: two slaves with ports A and B open (an EK1100 reads 0x5A31, an EL2828 0x5A33
    # in ethercrab-rs/ethercrab tests/replay-dc.pcapng), then an end with port A only.
    assert plugs_from_dl_status([0x5A31, 0x5A33, 0x5633]) == [None, Plug(0, 1), Plug(1, 1)]
    # More slaves than the open ports leave room for: the rest get no place.
    assert plugs_from_dl_status([0x5633, 0x5633]) == [None, None]


# -- the compiler's worked example on `simulate --topology` --------------------------------

TREE_TOPOLOGY = ESI.parent / "tree" / "tree.yaml"
TREE_ESI = [ESI.parent / "tree" / "esi", ESI]


def _slaves_of(eni: bytes) -> list[tuple]:
    """What an ENI says of each slave that a scan can know: identity, addresses, Physics,
    PreviousPort (read with lxml)."""
    from lxml import etree
    out = []
    for el in etree.fromstring(eni).iter("Slave"):
        info = el.find("Info")
        out.append(tuple(info.findtext(k) for k in ("VendorId", "ProductCode", "RevisionNo",
                                                     "PhysAddr", "AutoIncAddr", "Physics"))
                   + tuple((p.findtext("Port"), p.findtext("PhysAddr"))
                           for p in el.findall("PreviousPort")))
    return out


def test_the_example_tree_on_simulate_apply_soem_and_scan(veth_netns, pysoem_module, tmp_path):
    """examples/tree/tree.yaml served by `simulate --topology`: apply reaches OP, SOEM
    finds the 7 slaves and reaches OP, and the topology the scan writes compiles to an ENI
    whose slaves (identity, addresses, Physics, PreviousPort) are the example's: what the
    scan cannot know are the names, DC settings and the master's name and cycle time."""
    from ecatcfg.eni import writer as eni_writer
    lib = Library(TREE_ESI, cache=False)
    eni = tmp_path / "tree.eni.xml"
    original = eni_writer.to_bytes(build.compile_topology(topology.load(TREE_TOPOLOGY),
                                                          lib).plan)
    eni.write_bytes(original)
    esi = [a for p in TREE_ESI for a in ("--esi", str(p))]
    sim, lines = start_simulate(veth_netns, *esi, "--topology", str(TREE_TOPOLOGY))
    try:
        assert lines and lines[-1].startswith("ready: 7 slaves"), "".join(lines)
        applied = _ecatcfg_in(veth_netns, "apply", str(eni), "--cycles", "20")
        found = tmp_path / "found.yaml"
        scanned = _ecatcfg_in(veth_netns, "scan", *esi, "--topology-out", str(found),
                              "--no-cache")
        report = _soem(veth_netns, {"outputs": "5a"})
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    assert applied.returncode == 0, applied.stdout + applied.stderr
    assert scanned.returncode == 0, scanned.stderr
    assert report["found"] == 7 and report["op"] == 8, report
    again = eni_writer.to_bytes(build.compile_topology(topology.load(found), lib).plan)
    assert _slaves_of(again) == _slaves_of(original)
    assert [len(s) for s in _slaves_of(original)] == [6] + [7] * 6     # PreviousPort each
