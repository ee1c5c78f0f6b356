"""Compile the topologies of real ENI exports and compare with what TwinCAT / EC-Engineer wrote.

The reference ENIs are read with plain lxml here (not our ENI reader), so the comparison does
not depend on code under test.  What is compared, per slave: the SyncManager InitCmd data
bytes (comment, transitions, register, data), FMMU length / type / bit ranges / physical
start (not the logical address: it depends on the other slaves), and the CoE InitCmds
(index, subindex, data, CompleteAccess) for PDO assignment and user SDOs; for the Elmo file
also the LRW working counter and the process-data sizes.

Deliberate differences (asserted, so a change shows up):
* EC-Engineer writes the watchdog divider, PDI and SM watchdog in I→P for the Elmo drive;
  the ESI gives no values for them, so without the topology's ``watchdog:`` we write none
  (``tests/test_topology_settings.py`` compiles the same drive with it and gets the
  export's commands).
* EC-Engineer's cyclic frame also carries NOP 0x0900 and APWR 0x0910 (bus shift); ours has
  only the ARMW (the runtime adds what its DC mode needs), so the image is smaller.
* TwinCAT writes I→B / B→I commands also for terminals without a bootstrap mailbox; we
  write boot transitions only for slaves that have one.
* TwinCAT's EL2008 output FMMU starts at 0x01000004 because the EL4002 (its ESI revision is
  not in the corpus) sits before it in that window.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import write
from ecatcfg.compiler import build, topology
from ecatcfg.esc import FmmuConfig
from ecatcfg.esi.library import Library


def _ref_slaves(path: Path):
    from lxml import etree
    return {s.findtext("Info/Name"): s for s in etree.parse(str(path)).iter("Slave")}


def _reg_cmds(slave_el, lo: int, hi: int) -> list[tuple]:
    out = []
    for ic in slave_el.find("InitCmds"):
        ado = int(ic.findtext("Ado"))
        if lo <= ado < hi:
            data = ic.findtext("Data") or "00" * int(ic.findtext("DataLength"))
            out.append((ic.findtext("Comment"), tuple(t.text for t in ic.findall("Transition")),
                        ado, data))
    return out


def _our_cmds(slave, lo: int, hi: int) -> list[tuple]:
    return [(c.comment, tuple(t.value for t in c.transitions), int(c.ado), c.payload.hex())
            for c in slave.init_cmds if c.ado is not None and lo <= c.ado < hi]


def _by_transition(cmds: list[tuple]) -> dict[str, list[tuple]]:
    """Each transition's commands in execution (file) order."""
    out: dict[str, list[tuple]] = {}
    for comment, transitions, ado, data in cmds:
        for t in transitions:
            out.setdefault(t, []).append((comment, ado, data))
    return out


def _fmmus(cmds: list[tuple]) -> list[tuple]:
    """(comment, transitions, length, start bit, stop bit, physical start, type, active)."""
    out = []
    for comment, transitions, _, data in cmds:
        f = FmmuConfig.from_bytes(bytes.fromhex(data))
        out.append((comment, transitions, f.length, f.logical_start_bit, f.logical_stop_bit,
                    f.physical_start, f.physical_start_bit, f.type, f.active))
    return out


def _ref_coe(slave_el) -> list[tuple]:
    return [(int(ic.findtext("Index")), int(ic.findtext("SubIndex")), ic.findtext("Data"),
             ic.get("CompleteAccess") in ("1", "true"), ic.findtext("Comment"))
            for ic in slave_el.findall("Mailbox/CoE/InitCmds/InitCmd")]


def _compile(tmp_path: Path, text: str, esi: list[Path]):
    path = write(tmp_path, "ref.yaml", text)
    return build.compile_topology(topology.load(path), Library(esi, cache=False)).plan


ELMO = """
master: {name: rocos, cycle_time_us: 1000}
slaves:
  - name: "Slave_1001 [Elmo Drive ]"
    device: "0x9a:0x30924:0x10420"
    rx_pdos: [0x160A, 0x160B, 0x160C, 0x160F, 0x161C]
    tx_pdos: [0x1A0A, 0x1A0E, 0x1A11, 0x1A13, 0x1A1D]
    dc: DC Sync
    sdos:
      - {index: 0x6060, value: 8}
      - {index: 0x60C2, subindex: 1, value: 1}
"""


def test_elmo_gold_matches_ec_engineer(tmp_path, corpus):
    ref = _ref_slaves(corpus / "eni/rocos-ethercat/eni.xml")["Slave_1001 [Elmo Drive ]"]
    plan = _compile(tmp_path, ELMO, [corpus / "esi/drives/Elmo_ECAT_00010420_V11.xml"])
    ours = plan.slaves[0]
    # SyncManagers: mailbox, bootstrap, process data, clears: identical bytes and comments.
    assert _our_cmds(ours, 0x800, 0x900) == _reg_cmds(ref, 0x800, 0x900)
    assert _fmmus(_our_cmds(ours, 0x600, 0x700)) == _fmmus(_reg_cmds(ref, 0x600, 0x700))
    # DC registers (cycle, start placeholder, activation, latch, clears).
    assert _by_transition(_our_cmds(ours, 0x980, 0x9B0)) == \
        _by_transition(_reg_cmds(ref, 0x980, 0x9B0))
    # Every transition's register commands, in execution order, with the same bytes, except
    # the watchdog writes EC-Engineer adds for drives (none without the topology's
    # ``watchdog:``: the ESI gives no watchdog values).
    watchdogs = {"set watchdog divider", "set PDI watchdog", "set SM watchdog"}
    ref_all = [c for c in _reg_cmds(ref, 0, 0x10000) if c[0] not in watchdogs]
    assert _by_transition(_our_cmds(ours, 0, 0x10000)) == _by_transition(ref_all)
    assert len(ref_all) == len(_reg_cmds(ref, 0, 0x10000)) - 3
    # CoE: assignment, clearing the unassigned configurable PDOs, and the user's SDOs (the
    # user's 0x60C2:01 = 1 replaces the ESI's = 2 under the ESI's comment "Cycle time").
    coe = [(c.index, c.subindex, c.data.hex(), c.complete_access, c.comment)
           for c in ours.mailbox.coe_init_cmds]
    assert coe == _ref_coe(ref)
    assert ours.mailbox.poll_time == int(ref.findtext("Mailbox/Recv/PollTime"))
    # Working counter and process-data sizes.
    lrw = next(c for f in plan.cyclic[0].frames for c in f.cmds if c.cmd == 12)
    from lxml import etree
    ref_lrw = next(c for c in etree.parse(str(corpus / "eni/rocos-ethercat/eni.xml"))
                   .iter("Cmd") if c.findtext("Cmd") == "12")
    assert (lrw.length, lrw.cnt) == (int(ref_lrw.findtext("DataLength")),
                                     int(ref_lrw.findtext("Cnt")))
    assert ours.process_data.send[0].bit_length == int(ref.findtext("ProcessData/Send/BitLength"))
    assert ours.process_data.recv[0].bit_length == int(ref.findtext("ProcessData/Recv/BitLength"))
    assert (ours.dc.cycle_time0, ours.dc.shift_time) == (
        int(ref.findtext("DC/CycleTime0")), int(ref.findtext("DC/ShiftTime")))
    # Deliberate: no NOP / bus-shift APWR in our frame (see the module docstring).
    assert [c.cmd for c in plan.cyclic[0].frames[0].cmds] == [13, 12, 7]


MEGA = """
master: {name: mega, layout: lrd_lwr}
slaves:
  - {name: "Term 1 (EK1100)", device: "2:0x044c2c52:0x00120000"}
  - {name: "Term 2 (EL2008)", device: "2:0x07d83052:0x00120000"}
  - {name: "Term 4 (EL1809)", device: "2:0x07113052:0x00120000", station_address: 1004}
"""


@pytest.mark.parametrize("name", ["Term 1 (EK1100)", "Term 2 (EL2008)", "Term 4 (EL1809)"])
def test_beckhoff_terminals_match_twincat(tmp_path, corpus, name):
    ref = _ref_slaves(corpus / "eni/jn-ec-master/mega_master_eni.xml")[name]
    plan = _compile(tmp_path, MEGA, [corpus / "esi/beckhoff"])
    ours = plan.slave(name)
    assert _our_cmds(ours, 0x800, 0x900) == _reg_cmds(ref, 0x800, 0x900)
    assert _fmmus(_our_cmds(ours, 0x600, 0x700)) == _fmmus(_reg_cmds(ref, 0x600, 0x700))
    assert ours.mailbox is None and ref.find("Mailbox") is None
    # Every transition's commands, FMMUs aside (compared above without the logical address).
    # Deliberate: TwinCAT also writes I->B / B->I for these terminals, which have no
    # bootstrap mailbox; we write boot transitions only for slaves that have one.
    ours_by = _by_transition([c for c in _our_cmds(ours, 0, 0x10000)
                              if not 0x600 <= c[2] < 0x700])
    ref_by = _by_transition([c for c in _reg_cmds(ref, 0, 0x10000)
                             if not 0x600 <= c[2] < 0x700])
    assert set(ref_by) - set(ours_by) == {"IB", "BI"}
    assert ours_by == {t: v for t, v in ref_by.items() if t not in ("IB", "BI")}
    # Identity checks read the same SII words and expect the same values.
    ident = [(c.ado, c.payload.hex(), c.validate.data.hex() if c.validate else None)
             for c in ours.init_cmds if c.comment in ("check vendor id", "check product code")]
    ref_ident = [(int(ic.findtext("Ado")), ic.findtext("Data"), ic.findtext("Validate/Data"))
                 for ic in ref.find("InitCmds")
                 if ic.findtext("Comment") in ("check vendor id", "check product code")]
    assert ident == ref_ident


def test_beckhoff_logical_windows_and_wkc(tmp_path, corpus):
    plan = _compile(tmp_path, MEGA, [corpus / "esi/beckhoff"])
    cmds = {c.cmd: c for c in plan.cyclic[0].frames[0].cmds}
    # TwinCAT: LWR at 0x01000000 (Cnt 2 with the EL4002 we cannot compile), LRD at
    # 0x01000800 with Cnt 1 and 2 bytes (EL1809), BRD AL status Cnt = slave count.
    assert (cmds[11].addr, cmds[11].cnt, cmds[11].length) == (0x01000000, 1, 1)
    assert (cmds[10].addr, cmds[10].cnt, cmds[10].length) == (0x01000800, 1, 2)
    assert cmds[7].cnt == 3
    el2008 = FmmuConfig.from_bytes(next(c for c in plan.slave("Term 2 (EL2008)").init_cmds
                                        if c.comment == "set fmmu 0 (outputs)").payload)
    assert el2008.logical_start == 0x01000000      # TwinCAT: 0x01000004, after the EL4002


GEN_DAQ = """
master: {name: navfac, cycle_time_us: 1000}
slaves:
  - {name: "Box 1 (GEN Series DAQ System)", device: "0x11d:0xd01:0x2"}
"""


def test_an_esi_that_lists_the_mailbox_state_fmmu_first_numbers_it_first(tmp_path,
                                                                         corpus_extra):
    """The HBM GEN Series DAQ's ESI lists its FMMUs as MBoxState, Outputs, Inputs: TwinCAT
    (the NAVFACOSWECS export) sets FMMU 0 to the mailbox-state bit in I->P and FMMUs 1 and
    2 to the process data in P->S, and clears them in that order; so do we (the process
    data's FMMU lengths depend on the PDOs the export assigned, not compared)."""
    ref = _ref_slaves(corpus_extra / "eni/pmec-foswec2/NAVFACOSWECSxml.xml")[
        "Box 1 (GEN Series DAQ System)"]
    plan = _compile(tmp_path, GEN_DAQ, [corpus_extra / "esi/hbm/20260505_NAVFACOSWECS.xml"])
    ours = plan.slave("Box 1 (GEN Series DAQ System)")

    def shape(cmds: list[tuple]) -> list[tuple]:
        return [(comment, tuple(t for t in transitions if t not in ("IB", "BI")), ado)
                for comment, transitions, ado, _ in cmds]
    assert shape(_our_cmds(ours, 0x600, 0x700)) == shape(_reg_cmds(ref, 0x600, 0x700))
    [mine] = [d for c, _, _, d in _our_cmds(ours, 0x600, 0x700) if "mailbox state" in c]
    [theirs] = [d for c, _, _, d in _reg_cmds(ref, 0x600, 0x700) if "mailbox state" in c]
    assert mine == theirs == "00000009010000000d08000101000000"
