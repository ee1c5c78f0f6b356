"""The master side in memory (no root needed): the Network API, typed process variables,
the lockstep replay, failures that name the slave and command, timeouts, the mailbox repeat,
and the two ENI conventions for process image offsets."""

from __future__ import annotations

import struct
import subprocess
import sys
import threading
import time

import pytest
from rig import serve_in_memory

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import InitCmd, Validate
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState, Cmd, Transition
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.master.cyclic import CyclicFrames
from ecatcfg.runtime.link import MemoryLink
from ecatcfg.runtime.master.lockstep import run_jobs
from ecatcfg.runtime.master.bringup import Master, VerifyError
from ecatcfg.runtime.master.replay import ApplyError, init_cmd_job
from ecatcfg.runtime.segment.virtual import Faults
from ecatcfg.runtime.master.transport import Transport

ESI = EXAMPLES / "esi"



def line_plan(kinds: list[str]):
    text = "slaves:\n" + "".join(f"  - {{name: s{i}, device: {k}}}\n"
                                 for i, k in enumerate(kinds))
    plan = build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library([ESI], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "t.eni.xml")


def test_process_data_both_ways(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        assert net.state == AlState.OP
        assert [s.state for s in net.segment.slaves] == [AlState.OP] * 5
        net["lamps.Channel 1-8.Output 3"] = True
        net["axis1.RxPDO 2 (CSV).Target velocity"] = -123456
        net.cycle()
        lamps, drive = net.segment.slaves[3], net.segment.slaves[4]
        assert lamps.outputs() == b"\x04"
        # RxPDO 2 (CSV): control word (16 bit), then the target velocity (DINT).
        assert struct.unpack_from("<i", drive.outputs(), 2)[0] == -123456
        net.segment.slaves[2].set_inputs(b"\x09")         # sensors: channels 1 and 4
        drive.set_inputs(struct.pack("<Hi", 0x1237, -5))
        net.cycle()
        net.cycle()
        assert [net[f"sensors.Channel {c}.Input"] for c in (1, 2, 3, 4)] == [
            True, False, False, True]
        assert net["axis1.TxPDO 1 (CSP).Statusword"] == 0x1237
        assert net["axis1.TxPDO 1 (CSP).Position actual value"] == -5
    # Leaving the block took the line down.
    assert [s.state for s in net.segment.slaves] == [AlState.INIT] * 5


def test_variables_are_typed_and_checked(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        with pytest.raises(EcatcfgError, match="outside DINT range"):
            net["axis1.RxPDO 2 (CSV).Target velocity"] = 1 << 31
        with pytest.raises(EcatcfgError, match="is an input"):
            net["buttons.Channel 1.Input"] = True
        with pytest.raises(EcatcfgError, match="did you mean 'lamps.Channel 1-8.Output 1'"):
            net["lamps.Channel 1-8.Output1"]
        assert net["lamps.Channel 1-8.Output 1"] is False


def test_cycles_run_on_their_own_thread(example_plan):
    seen = []
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        net.run(cycles=20, callback=lambda n: seen.append(n.state), background=True)
        deadline = time.monotonic() + 5
        while len(seen) < 20 and time.monotonic() < deadline:
            time.sleep(0.01)
        net.stop()
        assert len(seen) == 20 and net.run_stats.wkc_errors == 0
        assert net.run_stats.lost_frames == 0


def test_commands_of_different_slaves_share_frames():
    plan = line_plan(["EX1100"] + ["EX1004", "EX2008"] * 20)
    with Network.virtual(plan, esi=[ESI]) as net:
        counters = net.master.transport.counters
        net.master.scan_and_verify()
        before = counters.frames_sent
        net.master.run_transition(Transition.IP)
        longest = max(sum(Transition.IP in c.transitions for c in s.init_cmds)
                      for s in plan.slaves)
        master = sum(Transition.IP in c.transitions for c in plan.master.init_cmds)
        # One round per command of the longest chain (41 slaves' commands share frames).
        assert counters.frames_sent - before <= longest + master + 2


def test_refused_state_names_slave_command_and_code(example_plan):
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.segment.slaves[4].refuse["PS"] = 0x001E
        with pytest.raises(ApplyError) as err:
            net.up()
    text = str(err.value)
    # The error flag is final: no waiting out the state timeout (the message would say so).
    assert "timed out" not in text
    assert "slave 'axis1'" in text and "check device state for SAFEOP" in text
    assert "0x001E (invalid input configuration)" in text
    assert err.value.al_code == 0x001E


def test_a_failed_init_cmd_is_named_with_its_file_and_line(example_plan, tmp_path):
    """The ENI read from a file: the refused state names the file and the line of the
    failing InitCmd, found here with plain XPath; a plan given in memory names none."""
    from lxml import etree
    path = tmp_path / "line.xml"
    eni_writer.write(example_plan, path)
    with Network.virtual(path, esi=[ESI]) as net:
        net.segment.slaves[4].refuse["PS"] = 0x001E
        with pytest.raises(ApplyError) as err:
            net.up()
    slave = etree.parse(str(path)).xpath("/EtherCATConfig/Config/Slave")[4]
    [check] = slave.xpath("InitCmds/InitCmd[Comment='check device state for SAFEOP']"
                          "[Transition='PS']")
    assert check.sourceline > 100                   # the writer puts one element a line
    assert str(err.value).startswith(f"{path}:{check.sourceline}: slave 'axis1' [check "
                                     "device state for SAFEOP]: ")
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.segment.slaves[4].refuse["PS"] = 0x001E
        with pytest.raises(ApplyError) as err:
            net.up()
    assert str(err.value).startswith("slave 'axis1' [check device state for SAFEOP]: ")


def test_swapped_slaves_stop_before_any_configuration():
    plan = line_plan(["EX1100", "EX1004", "EX2008"])
    swapped = line_plan(["EX1100", "EX2008", "EX1004"])
    from ecatcfg.runtime.segment import emulate
    lib = Library([ESI], cache=False)
    seg = emulate.segment(emulate.specs_from_eni(swapped, lib, "x"))
    a, b = MemoryLink.pair()
    stop = threading.Event()
    thread = threading.Thread(target=seg.serve, args=(b,), kwargs={"stop": stop}, daemon=True)
    thread.start()
    written = []
    master = Master(plan, a, recorder=lambda f, sent: written.append(f) if sent else None)
    try:
        with pytest.raises(EcatcfgError, match="other device .*swapped") as err:
            master.scan_and_verify()
    finally:
        stop.set()
        thread.join(2)
    assert "nothing was configured" in str(err.value)
    from ecatcfg.runtime import wire
    targets = {(d.cmd, d.ado) for f in written for d in wire.decode(f).datagrams
               if d.cmd in (Cmd.APWR, Cmd.FPWR, Cmd.BWR)}
    assert all(0x0500 <= ado < 0x0510 for _, ado in targets), targets
    assert [s.station_address for s in seg.slaves] == [0, 0, 0]


def test_a_silent_line_fails_within_the_timeout():
    a, _b = MemoryLink.pair()                   # nobody answers
    transport = Transport(a, timeout=0.005)
    cmd = InitCmd([Transition.IP], "check device state for PREOP", Cmd.APRD, 2, adp=0,
                  ado=0x0130, validate=Validate(b"\x02\x00", timeout=200))
    start = time.monotonic()
    with pytest.raises(ApplyError, match=r"\[check device state for PREOP\]: no reply"):
        run_jobs(transport, [init_cmd_job(cmd, "s0")])
    # The 200 ms timeout fires: not before, and (10x margin for a loaded machine) not never.
    assert 0.2 <= time.monotonic() - start < 2.0


def test_bring_up_survives_heavy_frame_loss(example_plan):
    # 20 % of frames lost, half of them after the slave processed them.
    for seed in range(5):
        with Network.virtual(example_plan, esi=[ESI], faults=Faults(drop=0.2, seed=seed)) \
                as net:
            net.up()
            assert net.state == AlState.OP
            assert [s.state for s in net.segment.slaves] == [AlState.OP] * 5


def _sm0_requests(frames, sm0):
    """(index, subindex) of every CoE request written into SM0 at ``sm0``, in order."""
    from ecatcfg.runtime.mailbox import decode
    out = []
    for f in frames:
        for d in wire.decode(f).datagrams:
            if d.cmd == Cmd.FPWR and d.ado == sm0:
                content = decode(bytes(d.data))[1]
                out.append((content.index, content.subindex))
    return out


def _losing(segment, pick):
    """``segment.process`` that drops the first reply ``pick(datagrams)`` chooses (another
    datagram index: the master takes it for a lost frame); the dropped datagrams in the
    list it returns."""
    process = segment.process
    lost = []

    def lossy(frame):
        back = process(frame)
        datagrams = wire.decode(back).datagrams
        if not lost and pick(datagrams):
            lost.append(datagrams)
            back[17] ^= 0xFF
        return back
    segment.process = lossy
    return lost


def test_a_lost_mailbox_answer_is_recovered_with_the_repeat_request(example_plan):
    """The reply to the SM1 read that took the drive's last answer of PS out of the mailbox
    (no request went ahead of it) is lost on the way back: the answer is gone from SM1, and
    only the repeat toggle (ETG.1000.4 mailbox repeat) gets it posted again."""
    from ecatcfg.runtime.mailbox import decode
    mailbox = example_plan.slaves[4].mailbox
    last = [c for c in mailbox.coe_init_cmds if Transition.PS in c.transitions][-1]
    with Network.virtual(example_plan, esi=[ESI]) as net:
        segment = net.segment

        def last_answer(datagrams):
            reads = [d for d in datagrams if d.cmd == Cmd.FPRD and d.ado == mailbox.recv.start
                     and d.wkc == 1]
            if not reads:
                return False
            answer = decode(bytes(reads[0].data))[1]
            return (answer.index, answer.subindex) == (last.index, last.subindex)
        lost = _losing(segment, last_answer)
        sent: list[bytes] = []
        net.master.transport.recorder = lambda f, out: sent.append(f) if out else None
        net.up()
        assert lost and net.state == AlState.OP
        assert [s.state for s in segment.slaves] == [AlState.OP] * 5
    repeats = [d for f in sent for d in wire.decode(f).datagrams
               if d.cmd == Cmd.FPWR and d.ado == 0x080E]
    assert len(repeats) == 1
    # Nothing was sent twice: the repeat brought the answer back.
    ps = [c for c in mailbox.coe_init_cmds if Transition.PS in c.transitions]
    assert _sm0_requests(sent, mailbox.send.start) == [(c.index, c.subindex) for c in ps]


def _assert_assigned(drive):
    """The example drive's PDO assignment as its PS InitCmds write it (complete access:
    0x1C12 = 1 x 0x1601, 0x1C13 = 2 x 0x1A00, 0x1A01) and its mode of operation."""
    assert [drive.od.int_value(0x1C12, k) for k in range(2)] == [1, 0x1601]
    assert [drive.od.int_value(0x1C13, k) for k in range(3)] == [2, 0x1A00, 0x1A01]
    assert drive.od.int_value(0x6060) == 9


def test_start_up_sdos_go_one_frame_each(example_plan):
    """Each CoE InitCmd's request goes in the frame that reads the answer to the one
    before, behind that read (the ESC processes datagrams in order: the read can only
    return the earlier answer): the drive's 11 PS SDOs in 12 frames, not 22."""
    mailbox = example_plan.slaves[4].mailbox
    ps = [c for c in mailbox.coe_init_cmds if Transition.PS in c.transitions]
    with Network.virtual(example_plan, esi=[ESI]) as net:
        sent: list[bytes] = []
        net.master.transport.recorder = lambda f, out: sent.append(f) if out else None
        net.up()
        assert net.state == AlState.OP
        _assert_assigned(net.segment.slaves[4])
    shapes = [[(d.cmd, d.ado) for d in wire.decode(f).datagrams
               if d.cmd in (Cmd.FPRD, Cmd.FPWR)
               and d.ado in (mailbox.send.start, mailbox.recv.start)] for f in sent]
    shapes = [s for s in shapes if s]
    read, write = (Cmd.FPRD, mailbox.recv.start), (Cmd.FPWR, mailbox.send.start)
    assert shapes == [[write]] + [[read, write]] * (len(ps) - 1) + [[read]]
    assert _sm0_requests(sent, mailbox.send.start) == [(c.index, c.subindex) for c in ps]


def test_an_answer_lost_with_the_next_request_in_the_slave_runs_the_list_again(
        example_plan):
    """The frame that read the drive's first answer of PS and wrote its second request is
    lost on the way back: the answer is gone, the second request is in the slave, and
    its answer is the next in SM1 (a repeat would post that one again).  Whether the
    first command took is unknown, so the drive's PS list runs again from its start, one
    request at a time, without a repeat request; the drive ends configured as the ENI
    says."""
    mailbox = example_plan.slaves[4].mailbox
    ps = [(c.index, c.subindex) for c in mailbox.coe_init_cmds
          if Transition.PS in c.transitions]
    with Network.virtual(example_plan, esi=[ESI]) as net:
        segment = net.segment

        def answer_and_request(datagrams):
            return any(d.cmd == Cmd.FPRD and d.ado == mailbox.recv.start and d.wkc == 1
                       for d in datagrams) and any(
                d.cmd == Cmd.FPWR and d.ado == mailbox.send.start and d.wkc == 1
                for d in datagrams)
        lost = _losing(segment, answer_and_request)
        sent: list[bytes] = []
        net.master.transport.recorder = lambda f, out: sent.append(f) if out else None
        net.up()
        assert lost and net.state == AlState.OP
        _assert_assigned(segment.slaves[4])
    assert not [d for f in sent for d in wire.decode(f).datagrams
                if d.cmd == Cmd.FPWR and d.ado == 0x080E]
    assert _sm0_requests(sent, mailbox.send.start) == ps[:2] + ps


@pytest.mark.parametrize("cut", [2, 7])
def test_a_cyclic_reply_shorter_than_its_frame_is_a_lost_frame(example_plan, cut):
    """A reply that comes back ``cut`` bytes short (here the last datagram's working counter,
    or that and part of its data) is not the frame sent: a slave never shortens a datagram
    (ETG.1000.4: it forwards every byte), so the frame is lost for this cycle.  Nothing of
    it reaches the input image, though its first bytes carry a new button, and the rest is
    not read from the last cycle's reply either; the next whole reply brings the button."""
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        cyclic = net.master.cyclic
        assert net.cycle() and net["buttons.Channel 1.Input"] is False
        before, lost = bytes(cyclic.inputs), cyclic.stats.lost_frames
        net.segment.slaves[1].set_inputs(b"\x01")                 # buttons: channel 1
        process = net.segment.process
        net.segment.process = lambda frame: process(frame)[:-cut]
        try:
            assert net.cycle() is False
        finally:
            net.segment.process = process
        assert cyclic.stats.lost_frames == lost + 1
        assert bytes(cyclic.inputs) == before
        assert net["buttons.Channel 1.Input"] is False
        assert [s.wkc for s in cyclic.frames[0]] == [-1] * len(cyclic.frames[0])
        assert net.cycle() and net["buttons.Channel 1.Input"] is True


def test_twincat_offsets_are_frame_shaped(corpus):
    """TwinCAT writes the datagram header's position in the frame; the data sits 10 bytes
    later, where its variables' bit offsets point (docs/eni-exports.md §4)."""
    plan = eni_reader.read_file(corpus / "eni/jn-ec-master/mega_master_eni.xml")
    frames = CyclicFrames(plan)
    lwr = next(s for s in frames.frames[0] if s.cmd.cmd == Cmd.LWR)
    assert (lwr.cmd.output_offs, lwr.out_at) == (29, 39)
    el4002 = next(v for v in plan.process_image.outputs if "EL4002" in v.name)
    assert el4002.bit_offs == lwr.out_at * 8
    ours = CyclicFrames(line_plan(["EX1100", "EX2008"]))
    assert all(s.in_at == s.cmd.input_offs for s in ours.frames[0])


def test_example_program_runs():
    done = subprocess.run([sys.executable, "-m", "ecatcfg.examples.toggle"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 6
    assert lines[0].startswith("cycle 1: lamp 1 on   button 1 pressed")
    assert "outputs 0x01" in lines[0] and "outputs 0x00" in lines[1]
    assert "button 1 pressed" in lines[3]


@pytest.mark.parametrize("slave", [
    "{name: d, device: Drive1, modules: {1: 0x100, 2: 0x200}}",      # Copley XE2: 2 axes
    "{name: c, device: 'UR20-FBC-EC', modules: {1: 0x91f84}}",       # Weidmueller + 4DI
], ids=["copley", "ur20"])
@pytest.mark.parametrize("source", ["topology", "eni"])
def test_modular_devices_are_emulated_with_their_modules(corpus, slave, source):
    """simulate --topology plugs the topology's modules; simulate --eni takes the modules
    from the ENI (its 0xF030 list, else accepting what its startup SDOs write) and the PDOs
    it lists.  Either way the compiled ENI brings the slave to OP."""
    from ecatcfg.compiler.plugged import plugged_devices
    from ecatcfg.runtime.segment import emulate
    lib = Library([corpus / "esi"], cache=False)
    loaded = topology.loads(f"slaves:\n  - {slave}\n", "t.yaml")
    plan = eni_reader.read_bytes(eni_writer.to_bytes(
        build.compile_topology(loaded, lib).plan), "t.eni.xml")
    specs = ([emulate.SlaveSpec(d.device, d.name) for d in plugged_devices(loaded, lib)]
             if source == "topology" else emulate.specs_from_eni(plan, lib, "t.eni.xml"))
    device = specs[0].device
    assigned = sorted(p.index for p in device.rx_pdos + device.tx_pdos if p.sm is not None)
    assert assigned == sorted(p.index for p in plan.slaves[0].process_data.pdos
                              if p.sm is not None)
    link, close = serve_in_memory(emulate.segment(specs))
    with Network(plan, link, _closers=[close]) as net:
        net.up()
        assert net.state == AlState.OP and net.cycle()


def test_a_refused_sdo_is_named_and_the_answer_to_the_request_ahead_is_taken(example_plan):
    """An SDO the drive refuses (an object it does not have) in the middle of its PS list:
    the request after it went ahead, in the frame that read the abort, so the drive has
    taken it too; the transition fails naming the refused command, and the answer to the
    request ahead is read and dropped: nothing is left in SM1 for a later reader to take
    for its own answer."""
    import copy
    from ecatcfg.runtime.master.replay import ApplyError
    plan = copy.deepcopy(example_plan)
    mailbox = plan.slaves[4].mailbox
    cmds = mailbox.coe_init_cmds
    missing = copy.deepcopy(next(c for c in cmds if c.index == 0x6060))
    missing.index, missing.comment = 0x5FFE, "no such object"
    at = cmds.index(next(c for c in cmds if c.index == 0x1C12 and c.data == b"\x00")) + 1
    cmds.insert(at, missing)
    after = cmds[at + 1]
    with Network.virtual(plan, esi=[ESI]) as net:
        sent: list[bytes] = []
        net.master.transport.recorder = lambda f, out: sent.append(f) if out else None
        with pytest.raises(ApplyError, match=r"\[no such object\]: SDO abort 0x06020000") \
                as refused:
            net.up()
        assert refused.value.init_cmd is missing
        drive = net.segment.slaves[4]
        assert drive.state == AlState.PREOP
        assert not drive.mem[0x080D] & 0x08     # SM1 status (0x0805 + 8): not full
        assert not drive.mailbox_queue
    requests = _sm0_requests(sent, mailbox.send.start)
    assert requests[-2:] == [(missing.index, missing.subindex), (after.index, after.subindex)]


def test_mailbox_counters_go_on_across_transitions():
    # 15 mailbox messages in PS (counters 1..7, 1..7, 1), then one in SO: a master that
    # restarts at 1 there sends a counter equal to the last one, which the slave drops as
    # a repeat (ETG.1000.4; SOES mbxincnt).  The SO SDO must still arrive.
    import copy
    text = ("slaves:\n  - {name: coupler, device: EX1100}\n  - name: axis1\n"
            "    device: '0xE0000ECA:0x7201'\n    sdos:\n"
            + "".join(f"      - {{index: 0x{i:04X}, value: 0, transition: PS}}\n"
                      for i in (0x607A, 0x60FF, 0x6040))
            + "      - {index: 0x60C2, subindex: 1, value: 1}\n"
              "      - {index: 0x60C2, subindex: 2, value: -3}\n"
              "      - {index: 0x6060, value: 9, transition: SO}\n")
    plan = build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library([ESI], cache=False)).plan
    cmds = plan.slaves[1].mailbox.coe_init_cmds
    cmds.insert(len(cmds) - 1, copy.deepcopy(next(c for c in cmds if c.index == 0x60C2)))
    assert [c.transitions for c in cmds].count([Transition.PS]) == 15
    with Network.virtual(plan, esi=[ESI]) as net:
        net.up()
        assert net.segment.slaves[1].od.int_value(0x6060) == 9


def test_going_down_acknowledges_errors(example_plan):
    # An SM-watchdog fault leaves slaves in SAFEOP+ERR 0x001B; requests without the
    # acknowledge are ignored, so the way down must acknowledge first.
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        net.run(cycles=5)
        time.sleep(0.3)                       # no cycles for longer than the 100 ms watchdog
        for s in net.segment.slaves:
            s.check_watchdog(time.monotonic())
        assert any(s.error and s.status_code == 0x001B for s in net.segment.slaves)
        net.down()
        assert net.state == AlState.INIT
        assert [(s.state, s.error) for s in net.segment.slaves] == [(AlState.INIT, False)] * 5


def test_close_closes_the_link_it_was_given(example_plan):
    """The Network owns its link: closing it releases the socket (RawLink) or the
    in-memory end, also when the caller handed the link in."""
    from ecatcfg.runtime.segment import emulate
    from ecatcfg.runtime.link import LinkError
    lib = Library([ESI], cache=False)
    link, close = serve_in_memory(emulate.segment(emulate.specs_from_eni(example_plan, lib, "x")))
    with Network(example_plan, link, _closers=[close]) as net:
        net.up()
        assert net.state == AlState.OP
    with pytest.raises(LinkError, match="closed"):
        link.send(bytes(60))
    net.close()                                   # a second close is harmless


# -- working counters above the expected one ------------------------------------------------

def test_two_slaves_answering_one_address_fail_the_command_at_once():
    """The ENI's Cnt is the working counter a command must return (ETG.2100 InitCmd/Cnt).
    Two slaves with one station address (an ENI that gives two slaves the same address)
    answer an FPRD together: working counter 2 where the file says 1.  Resending cannot
    change that; it is an error naming the slave and the command, never a success."""
    from ecatcfg.runtime.segment import emulate
    plan = line_plan(["EX1100", "EX1004", "EX2008"])
    link, close = serve_in_memory(emulate.segment(emulate.specs_from_eni(plan, Library([ESI],
                                                                              cache=False), "x")))
    transport = Transport(link)
    try:
        for pos in (1, 2):                           # both get station address 1002
            run_jobs(transport, [init_cmd_job(InitCmd(
                [Transition.IP], "set station address", Cmd.APWR, 2, adp=-pos & 0xFFFF,
                ado=0x0010, data=struct.pack("<H", 1002), cnt=1), f"s{pos}")])
        check = InitCmd([Transition.IP], "check device state for INIT", Cmd.FPRD, 2,
                        adp=1002, ado=0x0130, cnt=1, retries=3)
        sent = transport.counters.frames_sent
        with pytest.raises(ApplyError) as err:
            run_jobs(transport, [init_cmd_job(check, "s1")])
        assert transport.counters.frames_sent - sent == 1      # no retries: they cannot help
    finally:
        close()
    assert str(err.value).startswith(
        "slave 's1' [check device state for INIT]: working counter 2, expected 1")
    assert "more slaves answered" in str(err.value)


def test_a_cyclic_working_counter_above_the_expected_one_is_a_bad_cycle(example_plan):
    """A slave that should not answer the process-data LRW does (here the coupler, given
    an FMMU over the first byte of the window): the working counter exceeds the ENI's Cnt,
    the cycle is bad and the command is counted, as for a counter that is too low."""
    from ecatcfg.esc import FmmuConfig, FmmuType, fmmu_register
    lrw = next(c for f in example_plan.cyclic[0].frames for c in f.cmds if c.cmd == Cmd.LRW)
    assert lrw.cnt == 7
    with Network.virtual(example_plan, esi=[ESI]) as net:
        net.up()
        assert net.cycle() and net.master.cyclic.stats.wkc_errors == 0
        coupler = net.segment.slaves[0]
        assert coupler.fmmus == []
        fmmu = FmmuConfig(lrw.addr, 1, 0, 7, 0x1000, 0, FmmuType.READ)
        assert coupler.write(fmmu_register(0), fmmu.to_bytes())
        back = wire.decode(net.segment.process(wire.encode(
            [wire.datagram_for(lrw, bytes(lrw.length))]))).datagrams[0]
        assert back.wkc == 8                          # the emulated line counts it
        assert net.cycle() is False
        stats = net.master.cyclic.stats
        assert stats.wkc_errors == 1 and stats.wkc_error_cmds == {lrw.comment: 1}


# -- the line check -------------------------------------------------------------------------

def _verify_on(eni_plan, line, accept_newer_revision: bool = False
               ) -> tuple[VerifyError, list[bytes]]:
    """Scan and verify ``eni_plan`` against a virtual line of ``line``'s slaves; the
    VerifyError it must raise and the frames the master sent."""
    from ecatcfg.runtime.segment import emulate
    seg = emulate.segment(emulate.specs_from_eni(line, Library([ESI], cache=False), "x")
                          if line is not None else [])
    link, close = serve_in_memory(seg)
    sent: list[bytes] = []
    master = Master(eni_plan, link, recorder=lambda f, out: sent.append(f) if out else None)
    try:
        with pytest.raises(VerifyError) as err:
            master.scan_and_verify(accept_newer_revision)
    finally:
        close()
    written = {d.ado for f in sent for d in wire.decode(f).datagrams
               if d.cmd in (Cmd.APWR, Cmd.FPWR, Cmd.BWR)}
    assert all(0x0500 <= ado < 0x0510 for ado in written), written   # nothing configured
    assert "nothing was configured" in str(err.value)
    return err.value, sent


def _with_revision(plan, position: int, revision: int):
    from lxml import etree
    root = etree.fromstring(eni_writer.to_bytes(plan))
    root.findall("Config/Slave")[position].find("Info/RevisionNo").text = str(revision)
    return eni_reader.read_bytes(etree.tostring(root), "r.eni.xml")


def test_a_missing_slave_at_the_end_of_the_line_is_reported():
    eni = line_plan(["EX1100", "EX1004", "EX2008"])
    err, _ = _verify_on(eni, line_plan(["EX1100", "EX1004"]))
    assert [(m.position, m.found, m.problem) for m in err.mismatches] == [
        (2, "-", "missing slave")]
    assert err.mismatches[0].expected.startswith("s2 (0xe0000eca:0x3008:")
    assert "    2  s2 (0xe0000eca:0x3008:0x10000)" in str(err)


def test_an_empty_line_reports_every_slave_missing():
    """The frame comes back with working counter 0 from the BRD: no slave at all.  Each
    slave of the ENI is reported missing, by position; nothing crashes."""
    eni = line_plan(["EX1100", "EX1004", "EX2008"])
    err, _ = _verify_on(eni, None)
    assert [(m.position, m.found, m.problem) for m in err.mismatches] == [
        (0, "-", "missing slave"), (1, "-", "missing slave"), (2, "-", "missing slave")]


def test_an_extra_slave_at_the_end_of_the_line_is_reported():
    err, _ = _verify_on(line_plan(["EX1100", "EX1004"]),
                        line_plan(["EX1100", "EX1004", "EX2008"]))
    assert [(m.position, m.expected, m.problem) for m in err.mismatches] == [
        (2, "-", "extra slave")]
    assert err.mismatches[0].found == "0xe0000eca:0x3008:0x10000"


def test_another_revision_is_reported_and_a_newer_one_taken_only_on_request():
    line = line_plan(["EX1100", "EX1004", "EX2008"])
    revision = line.slaves[1].revision
    assert revision == 0x10000
    # The ENI wants a newer revision than the slave has: a mismatch, even when newer
    # revisions are accepted.
    newer = _with_revision(line, 1, revision + 1)
    for accept in (False, True):
        err, _ = _verify_on(newer, line, accept_newer_revision=accept)
        assert [(m.position, m.problem) for m in err.mismatches] == [(1, "other revision")]
        assert err.mismatches[0].found == "0xe0000eca:0x2004:0x10000"
    # The slave is newer than the ENI says: a mismatch unless the caller accepts it.
    older = _with_revision(line, 1, revision - 1)
    err, _ = _verify_on(older, line)
    assert [(m.position, m.problem) for m in err.mismatches] == [
        (1, "other revision (newer: --accept-newer-revision takes it)")]
    from ecatcfg.runtime.segment import emulate
    link, close = serve_in_memory(emulate.segment(emulate.specs_from_eni(
        line, Library([ESI], cache=False), "x")))
    try:
        found = Master(older, link).scan_and_verify(accept_newer_revision=True)
    finally:
        close()
    assert [f.revision for f in found] == [revision] * 3


def test_the_enis_bus_shift_write_is_left_out_and_its_other_cyclic_writes_are_sent(
        example_plan):
    """EC-Engineer's cyclic frame carries an APWR of 0x0910 to the reference clock (bus
    shift: the master's own time, zeros in the file); this master follows the reference
    clock instead (ARMW), so that write is not sent, while a cyclic register write of
    another register (an FPWR of a user RAM word of the drive, OP only) is: the drive's
    word holds it after the cycles, and no frame carries the 0x0910 write."""
    import copy

    from ecatcfg.eni.plan import CyclicCmd
    from ecatcfg.esc import Reg
    plan = copy.deepcopy(example_plan)
    drive = plan.slave("axis1")
    word = b"\x5a\xa5"
    frame = plan.cyclic[0].frames[0]
    frame.cmds += [
        CyclicCmd(["SAFEOP", "OP"], "bus shift", Cmd.APWR, 8, adp=drive.auto_inc_addr,
                  ado=Reg.DC_SYSTEM_TIME, data=bytes(8), cnt=1),
        CyclicCmd(["OP"], "a user RAM word", Cmd.FPWR, 2, adp=drive.phys_addr, ado=0x0F80,
                  data=word, cnt=1)]
    cyclic = CyclicFrames(plan)
    sent = [(s.cmd.cmd, s.cmd.ado) for slots in cyclic.frames for s in slots]
    assert (Cmd.APWR, Reg.DC_SYSTEM_TIME) not in sent and (Cmd.FPWR, 0x0F80) in sent
    with Network.virtual(plan) as net:
        net.up()
        assert all(net.cycle() for _ in range(5))
        axis1 = next(s for s in net.segment.slaves if s.name == "axis1")
        assert bytes(axis1.mem[0x0F80:0x0F82]) == word


def test_the_cycle_periods_jitter_is_their_deviation_from_the_median():
    """``CycleStats.jitter`` (watch's status line, ``report``): the periods 1000, 1000,
    1010, 990, 1000, 1030 us have the median 1000 us and the deviations 0, 0, 0, 10, 10,
    30 us: p50 is the middle one, 10 us (the upper of the two middle ones, as the list
    has an even length), p99 and max the largest, 30 us.  A single period has no jitter."""
    from ecatcfg.runtime.master.cyclic import CycleStats
    stats = CycleStats()
    stats.add_period(1000.0)
    assert stats.jitter() == {"p50": 0.0, "p99": 0.0, "max": 0.0}
    two = CycleStats()                         # two periods: each 5 us from their median
    two.add_period(1000.0)
    two.add_period(1010.0)
    assert two.jitter() == {"p50": 5.0, "p99": 5.0, "max": 5.0}
    for us in (1000.0, 1010.0, 990.0, 1000.0, 1030.0):
        stats.add_period(us)
    assert stats.jitter() == {"p50": 10.0, "p99": 30.0, "max": 30.0}
    many = CycleStats()                        # 200 periods: p99 is the 199th deviation
    for k in range(199):
        many.add_period(1000.0 + k)
    many.add_period(3000.0)                    # one late cycle
    # median (1099 + 1100) / 2 = 1099.5; deviations sorted: 0.5, 0.5, 1.5, 1.5, ... 98.5,
    # 98.5 (indices 0-197), 99.5 (1000 us), 1900.5 (the late one)
    assert many.jitter() == {"p50": 50.5, "p99": 99.5, "max": 1900.5}


def test_the_working_counters_are_the_last_cycles_against_the_enis(example_plan):
    """``working_counters`` (watch's status line): after a cycle of the example line in OP
    the process-data LRW brought back the working counter the ENI's ``Cnt`` says, at the
    ENI's image offsets; with the drive unplugged, 3 less (its outputs count 2, its
    inputs 1: ETG.1000.4 LRW).  The AL status BRD's output offset is moved from its input
    offset (the schema lets them differ; the exporters write them equal), so that each
    offset is seen to be its own."""
    import copy
    plan = copy.deepcopy(example_plan)
    [lrw] = [c for frame in plan.cyclic[0].frames for c in frame.cmds if c.cmd == Cmd.LRW]
    [brd] = [c for frame in plan.cyclic[0].frames for c in frame.cmds if c.cmd == Cmd.BRD]
    brd.output_offs = brd.input_offs + 2
    with Network.virtual(plan, recovery=False) as net:
        net.up()
        assert net.cycle()
        [status] = [c for frame in net.master.cyclic.working_counters() for c in frame
                    if c.cmd.cmd == Cmd.BRD]
        assert (status.wkc, status.in_at, status.out_at) == (
            brd.cnt, brd.input_offs, brd.input_offs + 2)
        [count] = [c for frame in net.master.cyclic.working_counters() for c in frame
                   if c.cmd.cmd == Cmd.LRW]
        assert (count.wkc, count.expected, count.ok) == (lrw.cnt, lrw.cnt, True)
        assert (count.in_at, count.out_at) == (lrw.input_offs, lrw.output_offs)
        net.segment.remove_cable("axis1")
        assert not net.cycle()
        [count] = [c for frame in net.master.cyclic.working_counters() for c in frame
                   if c.cmd.cmd == Cmd.LRW]
        assert (count.wkc, count.expected, count.ok) == (lrw.cnt - 3, lrw.cnt, False)
        net.segment.restore_cable("axis1")


def test_a_reply_with_the_circulating_bit_set_is_still_the_cycles(example_plan):
    """A slave may set a datagram's circulating bit (ETG.1000.4: the frame passed a closed
    port 0); the reply is still the frame sent, so the cycle takes its working counters and
    inputs.  A reply whose datagram came back with another length is not this frame: the
    cycle fails and its inputs are not taken."""
    with Network.virtual(example_plan, recovery=False) as net:
        net.up()
        seg = net.segment
        answer = seg.answer
        change = {"flags": wire.CIRCULATING}

        def marked(frame):
            back, late = answer(frame)
            if back is not None and frame[wire.FRAME_HEADER_END + 0] == Cmd.ARMW:
                pos, _ = wire.datagram_offsets(back)[-1]          # the BRD of AL status
                flags, = struct.unpack_from("<H", back, pos + 6)
                struct.pack_into("<H", back, pos + 6, flags ^ change["flags"])
            return back, late
        seg.answer = marked
        buttons = next(s for s in seg.slaves if s.name == "buttons")
        buttons.set_inputs(b"\x05")
        assert all(net.cycle() for _ in range(3))
        assert [net[f"buttons.Channel {k}.Input"] for k in range(1, 5)] == [
            True, False, True, False]
        change["flags"] = 1                   # 2 bytes of AL status said to be 3
        buttons.set_inputs(b"\x0a")
        assert not any(net.cycle() for _ in range(3))
        assert net.master.cyclic.stats.lost_frames >= 3
        assert [net[f"buttons.Channel {k}.Input"] for k in range(1, 5)] == [
            True, False, True, False]
