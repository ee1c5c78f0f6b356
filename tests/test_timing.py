"""Slaves that take time (runtime/segment/timing.py): mailbox replies, state changes and
EEPROM reads become visible only after the table's times, on a simulated clock in memory;
our master and SOEM still bring a realistic line to OP.

The expected figures are the table's (docs/timing.md: measured in captures of real slaves by
bench/capture_timing.py), the register values those of the captures: a busy EEPROM reads
0x8140 (busy, read command, 8-byte reads), then 0x0040 (ethercrab-rs/ethercrab
tests/replay-ek1100-el2828-el2889.pcapng).
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import pytest
from rig import serving

from conftest import EXAMPLES
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import AlState, Cmd, SmConfig, sm_register
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network, wire
from ecatcfg.runtime.segment import timing
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment
from ecatcfg.runtime.segment.timing import Timing
from ecatcfg.runtime.wire import Datagram

ESI = EXAMPLES / "esi"
MS = 1_000_000
# An SDO upload request of 0x1018:01 (ETG.1000.6), padded to the 128-byte mailbox.
SDO_UPLOAD_1018_01 = bytes.fromhex("0a00000000" "13" "0020" "40181001" "00000000")


class Clock:
    """Simulated time (ns) that only moves when a test moves it."""

    def __init__(self) -> None:
        self.now = 1_000 * MS

    def __call__(self) -> int:
        return self.now

    def advance(self, ns: int) -> None:
        self.now += ns


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def line(lib: Library, *types: str, clock: Clock, model: Timing | None = None
         ) -> VirtualSegment:
    seg = segment([SlaveSpec(lib.device(lib.find(t).entry), f"{t}-{i}")
                   for i, t in enumerate(types)])
    return VirtualSegment(seg.slaves, clock_ns=clock, timing=model or Timing())


def run(seg: VirtualSegment, *dgs: Datagram) -> list[Datagram]:
    return wire.decode(seg.process(wire.encode(list(dgs)))).datagrams


def fp(cmd: Cmd, ado: int, data: bytes | int, addr: int = 0x1001) -> Datagram:
    return Datagram.physical(cmd, addr, ado, data)


def addressed(seg: VirtualSegment) -> None:
    [d] = run(seg, Datagram.physical(Cmd.APWR, 0, 0x0010, struct.pack("<H", 0x1001)))
    assert d.wkc == 1


def al_status(seg: VirtualSegment) -> int:
    [d] = run(seg, fp(Cmd.FPRD, 0x0130, 2))
    value: int = struct.unpack("<H", d.data)[0]
    return value


def to_preop(seg: VirtualSegment, clock: Clock) -> None:
    run(seg, fp(Cmd.FPWR, sm_register(0), SmConfig(0x1000, 128, 0x26, True).to_bytes()),
        fp(Cmd.FPWR, sm_register(1), SmConfig(0x1080, 128, 0x22, True).to_bytes()),
        fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.PREOP)))
    clock.advance(timing.TABLE["drive"].transition_ns("IP"))
    assert al_status(seg) == AlState.PREOP


# -- the table and the kinds ------------------------------------------------------------------

def test_devices_map_to_kinds(lib, corpus):
    clock = Clock()
    seg = line(lib, "EX1100", "EX1004", "EXD-402", clock=clock)
    assert [s.timing.kind for s in seg.slaves] == ["firmware", "firmware", "drive"]
    # An EK1100 is an ESC in device emulation (its SII word 0, as the real one's dump):
    # no firmware, no state-change time.
    corpus_lib = Library([corpus / "esi" / "beckhoff" / "Beckhoff EK11xx.xml"], cache=False)
    ek = segment([SlaveSpec(corpus_lib.device(corpus_lib.find("EK1100").entry))])
    assert timing.kind_of(ek.slaves[0]) == "esc"
    assert timing.TABLE["esc"].state_change_ns == {}


def test_off_by_default(lib):
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry))])
    assert seg.slaves[0].timing is None
    addressed(seg)
    run(seg, fp(Cmd.FPWR, 0x0502, struct.pack("<HI", 0x0100, 8)))
    [d] = run(seg, fp(Cmd.FPRD, 0x0502, 2))
    assert d.data == struct.pack("<H", 0x0040)      # done at once


# -- EEPROM ------------------------------------------------------------------------------------

def test_eeprom_is_busy_while_reading(lib):
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    slave = seg.slaves[0]
    run(seg, fp(Cmd.FPWR, 0x0508, bytes(8)))        # read-only to the master: stays 0
    run(seg, fp(Cmd.FPWR, 0x0502, struct.pack("<HI", 0x0100, 8)))   # read word 8
    read_ns = timing.TABLE["drive"].eeprom_read_ns
    assert read_ns == 690_000
    clock.advance(read_ns - 1_000)
    [status, data] = run(seg, fp(Cmd.FPRD, 0x0502, 2), fp(Cmd.FPRD, 0x0508, 8))
    assert status.data == struct.pack("<H", 0x8140)              # busy, as a real ESC
    assert data.data != bytes(slave.eeprom[16:24])
    # A command written while busy is ignored (the address stays word 8).
    run(seg, fp(Cmd.FPWR, 0x0502, struct.pack("<HI", 0x0100, 0)))
    clock.advance(1_000)
    [status, data] = run(seg, fp(Cmd.FPRD, 0x0502, 2), fp(Cmd.FPRD, 0x0508, 8))
    assert status.data == struct.pack("<H", 0x0040)
    assert data.data == bytes(slave.eeprom[16:24])               # vendor id, product code


# -- state changes -----------------------------------------------------------------------------

def test_al_status_keeps_the_old_state_until_the_transition_time(lib):
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    drive = timing.TABLE["drive"]
    run(seg, fp(Cmd.FPWR, sm_register(0), SmConfig(0x1000, 128, 0x26, True).to_bytes()),
        fp(Cmd.FPWR, sm_register(1), SmConfig(0x1080, 128, 0x22, True).to_bytes()),
        fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.PREOP)))
    clock.advance(drive.transition_ns("IP") - 1)
    assert al_status(seg) == AlState.INIT
    # Writing the same request again does not start the transition over.
    run(seg, fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.PREOP)))
    clock.advance(1)
    assert al_status(seg) == AlState.PREOP


def test_a_new_request_replaces_the_transition_in_progress(lib):
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    to_preop(seg, clock)
    run(seg, fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.INIT)))
    clock.advance(MS)
    [d] = run(seg, Datagram.physical(Cmd.BRD, 0, 0x0130, 2))
    assert d.data[0] == AlState.PREOP                # PI takes 3 ms, broadcast or not
    run(seg, fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.PREOP)))   # stay after all
    clock.advance(timing.TABLE["drive"].transition_ns("PI"))
    assert al_status(seg) == AlState.PREOP and not seg.slaves[0].busy


# -- mailbox -----------------------------------------------------------------------------------

def test_mailbox_reply_is_not_readable_before_its_latency(lib):
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    to_preop(seg, clock)
    latency = timing.TABLE["drive"].mailbox_reply_ns
    [d] = run(seg, fp(Cmd.FPWR, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    assert d.wkc == 1
    clock.advance(latency - 1)
    [status, reply] = run(seg, fp(Cmd.FPRD, 0x080D, 1), fp(Cmd.FPRD, 0x1080, 128))
    assert status.data[0] & 0x08 == 0 and reply.wkc == 0          # SM1 empty
    clock.advance(1)
    [status] = run(seg, fp(Cmd.FPRD, 0x080D, 1))
    assert status.data[0] & 0x08                                   # mailbox full
    [reply] = run(seg, fp(Cmd.FPRD, 0x1080, 128))
    assert reply.wkc == 1 and reply.data[8] == 0x43 and reply.data[9:12] == b"\x18\x10\x01"


def test_the_read_event_clears_when_the_firmware_starts_its_reply(lib):
    """After the master read a reply, SM1's status shows the read event (0x02) until the
    firmware writes the first byte of its next reply (0x00), then full (0x09) when the
    last is written: the sequence of the real EL6910 (ethercrab-rs/ethercrab
    tests/replay-mailbox-el6910.pcapng: 0x02 for about 1.16 ms, 0x00 for about 0.6 ms).
    Without a reply start (the drive kind's table) it stays 0x02 until the reply."""
    for start_ms, expected in ((1, [0x02, 0x00, 0x09]), (None, [0x02, 0x02, 0x09])):
        clock = Clock()
        figures = {"mailbox_reply_ms": 2} | ({"reply_start_ms": start_ms} if start_ms else {})
        seg = line(lib, "EXD-402", clock=clock, model=timing.overridden({"drive": figures}))
        addressed(seg)
        to_preop(seg, clock)
        request = SDO_UPLOAD_1018_01.ljust(128, b"\0")
        run(seg, fp(Cmd.FPWR, 0x1000, request))
        clock.advance(2 * MS)
        [reply] = run(seg, fp(Cmd.FPRD, 0x1080, 128))
        assert reply.wkc == 1
        again = request[:5] + bytes((0x23,)) + request[6:]       # the next mailbox counter
        [d] = run(seg, fp(Cmd.FPWR, 0x1000, again))
        assert d.wkc == 1
        seen = []
        for step in (MS - 1, 1, MS):
            clock.advance(step)
            [status] = run(seg, fp(Cmd.FPRD, 0x080D, 1))
            seen.append(status.data[0])
        assert seen == expected, start_ms


def test_figures_for_a_kind_replace_its_devices_own():
    """The EL6910 has its own measured figures (DEVICES) unless the user gives figures for
    its kind, `firmware`: they are then meant for every firmware device."""
    assert timing.EL6910 in Timing().devices
    assert timing.EL6910 in timing.overridden({"drive": {"mailbox_reply_ms": 5}}).devices
    assert timing.overridden({"firmware": {"mailbox_reply_ms": 5}}).devices == {}


def test_the_firmware_answers_one_request_at_a_time(lib):
    """A second request written while the firmware still works on the first (a master that
    sends the next request ahead of reading the answer) is answered a whole latency after
    the first answer, not in parallel with it: one firmware, one mailbox handler."""
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    to_preop(seg, clock)
    latency = timing.TABLE["drive"].mailbox_reply_ns
    first = SDO_UPLOAD_1018_01.ljust(128, b"\0")
    second = bytearray(first)
    second[5] = 0x23                                  # counter 2
    second[11] = 0x02                                 # 0x1018:02
    [d] = run(seg, fp(Cmd.FPWR, 0x1000, first))
    assert d.wkc == 1
    clock.advance(latency // 2)
    [d] = run(seg, fp(Cmd.FPWR, 0x1000, bytes(second)))
    assert d.wkc == 1                                 # SM0 taken: the firmware read it
    clock.advance(latency // 2 + 1)
    [reply] = run(seg, fp(Cmd.FPRD, 0x1080, 128))
    assert reply.wkc == 1 and reply.data[9:12] == b"\x18\x10\x01"
    clock.advance(latency - 2)                        # the second's latency not yet over
    [reply] = run(seg, fp(Cmd.FPRD, 0x1080, 128))
    assert reply.wkc == 0
    clock.advance(1)
    [reply] = run(seg, fp(Cmd.FPRD, 0x1080, 128))
    assert reply.wkc == 1 and reply.data[9:12] == b"\x18\x10\x02"


def test_a_request_written_again_is_answered_once(lib):
    """SOEM sends a frame again when no answer came back within 2 ms (ecx_srconfirm, up to
    three sends of an SM0 write): the same bytes, so the same mailbox counter.  The slave
    takes each copy into SM0 and its firmware drops the copies as repeats (ETG.1000.6
    counter; SOES ``mbxincnt``): one reply after the latency, and SM1 stays empty after it
    is read.  A second reply would be read as the answer to the master's next request."""
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    to_preop(seg, clock)
    latency = timing.TABLE["drive"].mailbox_reply_ns
    request = fp(Cmd.FPWR, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0"))
    for _ in range(3):
        [d] = run(seg, request)
        assert d.wkc == 1                              # SM0 taken: the firmware read it
        clock.advance(2 * MS)
    [status, reply] = run(seg, fp(Cmd.FPRD, 0x080D, 1), fp(Cmd.FPRD, 0x1080, 128))
    assert status.data[0] & 0x08 and reply.wkc == 1 and reply.data[9:12] == b"\x18\x10\x01"
    clock.advance(latency * 4)
    [status, again] = run(seg, fp(Cmd.FPRD, 0x080D, 1), fp(Cmd.FPRD, 0x1080, 128))
    assert status.data[0] & 0x08 == 0 and again.wkc == 0          # nothing more in SM1


def test_a_lost_reply_is_posted_again_on_a_repeat_request(lib):
    """The frame that read SM1 is lost on its way back (the slave emptied SM1, SOEM saw no
    working counter): SOEM toggles the repeat request (0x080E bit 1), waits for the
    acknowledge (0x080F bit 1) and reads the same reply again (ETG.1000.4 mailbox
    repeat)."""
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock)
    addressed(seg)
    to_preop(seg, clock)
    run(seg, fp(Cmd.FPWR, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    clock.advance(timing.TABLE["drive"].mailbox_reply_ns)
    [first] = run(seg, fp(Cmd.FPRD, 0x1080, 128))                    # lost on the way back
    assert first.wkc == 1
    [sm1] = run(seg, fp(Cmd.FPRD, 0x080D, 2))
    assert sm1.data[0] & 0x08 == 0
    toggled = bytes([sm1.data[0], sm1.data[1] ^ 0x02])
    run(seg, fp(Cmd.FPWR, 0x080D, toggled))
    [ack, status] = run(seg, fp(Cmd.FPRD, 0x080F, 1), fp(Cmd.FPRD, 0x080D, 1))
    assert ack.data[0] & 0x02 and status.data[0] & 0x08
    [again] = run(seg, fp(Cmd.FPRD, 0x1080, 128))
    assert again.wkc == 1 and again.data == first.data


def test_replies_in_progress_are_dropped_when_the_mailbox_stops(lib):
    # A reply slower than PI (the table's drive answers faster than it leaves PREOP), so
    # that it is still in progress when the slave reaches INIT.
    model = timing.overridden({"drive": {"mailbox_reply_ms": 10, "state_change_ms":
                                         {"IP": 1, "PI": 2}}})
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock, model=model)
    addressed(seg)
    run(seg, fp(Cmd.FPWR, sm_register(0), SmConfig(0x1000, 128, 0x26, True).to_bytes()),
        fp(Cmd.FPWR, sm_register(1), SmConfig(0x1080, 128, 0x22, True).to_bytes()),
        fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.PREOP)))
    clock.advance(MS)
    assert al_status(seg) == AlState.PREOP
    run(seg, fp(Cmd.FPWR, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")),
        fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.INIT)))
    clock.advance(MS)
    assert al_status(seg) == AlState.PREOP and seg.slaves[0]._replies   # in progress
    clock.advance(MS)
    assert al_status(seg) == AlState.INIT
    clock.advance(10 * MS)
    assert not seg.slaves[0].busy and not seg.slaves[0].mailbox_queue
    [status] = run(seg, fp(Cmd.FPRD, 0x080D, 1))
    assert status.data[0] & 0x08 == 0               # and never shows in SM1


# -- overrides ---------------------------------------------------------------------------------

def test_overrides_merge_over_the_table(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"drive": {"mailbox_reply_ms": 2, "state_change_ms":
                                          {"PS": 300}}}))
    model = timing.load(path)
    drive = model.kinds["drive"]
    assert drive.mailbox_reply_ns == 2 * MS and drive.transition_ns("PS") == 300 * MS
    assert drive.transition_ns("SO") == timing.TABLE["drive"].transition_ns("SO")
    assert model.kinds["firmware"] == timing.TABLE["firmware"]


def test_an_override_of_0_ms_means_at_once(lib, tmp_path):
    """0 ms is a time like any other (at once), not "no override": every figure of the
    drive set to 0 replaces the table's, and the drive answers, changes state and reads
    its EEPROM without the clock moving."""
    path = tmp_path / "zero.json"
    path.write_text(json.dumps({"drive": {
        "mailbox_reply_ms": 0, "eeprom_read_ms": 0, "eeprom_write_ms": 0.0,
        "state_change_ms": {t: 0 for t in timing.TRANSITIONS}}}))
    model = timing.load(path)
    zero = model.kinds["drive"]
    assert (zero.mailbox_reply_ns, zero.eeprom_read_ns, zero.eeprom_write_ns) == (0, 0, 0)
    assert zero.state_change_ns == {t: 0 for t in timing.TRANSITIONS}
    table = timing.TABLE["drive"]
    assert table.mailbox_reply_ns and table.eeprom_read_ns and table.transition_ns("IP")
    clock = Clock()
    seg = line(lib, "EXD-402", clock=clock, model=model)
    addressed(seg)
    run(seg, fp(Cmd.FPWR, sm_register(0), SmConfig(0x1000, 128, 0x26, True).to_bytes()),
        fp(Cmd.FPWR, sm_register(1), SmConfig(0x1080, 128, 0x22, True).to_bytes()),
        fp(Cmd.FPWR, 0x0120, struct.pack("<H", AlState.PREOP)))
    assert al_status(seg) == AlState.PREOP
    run(seg, fp(Cmd.FPWR, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    [status, reply] = run(seg, fp(Cmd.FPRD, 0x080D, 1), fp(Cmd.FPRD, 0x1080, 128))
    assert status.data[0] & 0x08 and reply.wkc == 1 and reply.data[9:12] == b"\x18\x10\x01"
    run(seg, fp(Cmd.FPWR, 0x0502, struct.pack("<HI", 0x0100, 8)))      # read word 8
    [status, data] = run(seg, fp(Cmd.FPRD, 0x0502, 2), fp(Cmd.FPRD, 0x0508, 8))
    assert status.data == struct.pack("<H", 0x0040)
    assert data.data == bytes(seg.slaves[0].eeprom[16:24])


@pytest.mark.parametrize("raw, message", [
    ({"servo": {}}, "'servo': no such device kind"),
    ({"drive": {"latency": 1}}, "unknown key 'latency'"),
    ({"drive": {"mailbox_reply_ms": -1}}, "-1 is not a time in ms"),
    ({"drive": {"state_change_ms": {"XY": 1}}}, "no transition 'XY'"),
    ([1], "expected an object of device kinds"),
])
def test_bad_overrides_name_the_file_and_the_figure(tmp_path, raw, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(raw))
    with pytest.raises(EcatcfgError, match="bad.json") as exc:
        timing.load(path)
    assert message in str(exc.value)


# -- masters on a realistic line ---------------------------------------------------------------

def drives_plan(n: int):
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.eni import writer as eni_writer
    text = "slaves:\n" + "".join(f"  - {{name: axis{i}, device: EXD-402}}\n"
                                 for i in range(n))
    plan = build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library([ESI], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "t.eni.xml")


def test_our_master_reaches_op_on_realistic_drives():
    """Eight drives with the table's times: apply's timeouts fit them.  The drives' PS and
    SO take 100 ms each, so the line cannot be in OP sooner (a lower bound only)."""
    plan = drives_plan(8)
    with Network.virtual(plan, esi=[ESI], timing=Timing()) as net:
        start = net.clock.monotonic()
        net.up()
        took = net.clock.monotonic() - start
        assert [s.state for s in net.segment.slaves] == [AlState.OP] * 8
        assert all(s.timing is not None and s.timing.kind == "drive"
                   for s in net.segment.slaves)
    drive = timing.TABLE["drive"]
    assert took >= (drive.transition_ns("PS") + drive.transition_ns("SO")) / 1e9


def test_soem_reaches_op_on_simulate_realistic(veth_netns, pysoem_module, lib):
    from test_soem import PROBE, check_identity
    seg = segment([SlaveSpec(lib.device(lib.find(t).entry), f"s{i}")
                   for i, t in enumerate(["EX1100", "EX1004", "EXD-402", "EXD-402"])],
                  timing=Timing())
    with serving(veth_netns, seg):
        done = veth_netns.run_in(veth_netns.ns_a, [sys.executable, str(PROBE),
                                                   veth_netns.if_a, "{}"], timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    check_identity(report, seg)
    assert report["safeop"] == 4 and report["op"] == 8, report


def test_simulate_timing_file_errors(tmp_path):
    import subprocess
    bad = tmp_path / "t.json"
    bad.write_text("{\"drive\": {\"eeprom_read_ms\": \"x\"}}")
    argv = [sys.executable, "-m", "ecatcfg", "simulate", "--esi", str(ESI), "--topology",
            str(EXAMPLES / "topology.yaml"), "--iface", "none0", "--no-cache"]
    done = subprocess.run(argv + ["--timing", str(bad)], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).parent)
    assert done.returncode == 1 and "t.json: 'drive': eeprom_read_ms" in done.stderr
    done = subprocess.run(argv + ["--timing", str(tmp_path / "none.json")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "none.json: no such file" in done.stderr


def test_eeprom_write_cycle_refuses_commands_until_done(lib):
    """After a word write the EEPROM writes internally for ~3.5 ms: a command in that time
    reads back 0x2040 (bit 13, no acknowledge) and does nothing, as the EK1100 of
    ethercrab-rs/ethercrab tests/replay-ek1100-alias-address.pcapng answers a write 1.2-3.2
    ms after the previous one; from 3.7 ms on the write is taken."""
    clock = Clock()
    seg = line(lib, "EX1004", clock=clock)
    slave = seg.slaves[0]
    ms = 1_000_000

    def command(data: bytes, word: int, cmd: int) -> int:
        slave.write(0x0508, data)
        slave.write(0x0502, struct.pack("<HI", cmd, word))
        slave.settle()
        return struct.unpack_from("<H", slave.mem, 0x0502)[0]

    assert command(b"\xcd\xab", 4, 0x0201) & 0x2000 == 0
    clock.advance(2 * ms)
    assert command(b"\x52\x00", 7, 0x0201) == 0x2040          # refused: still writing
    assert slave.eeprom[14:16] != b"\x52\x00"
    clock.advance(2 * ms)
    assert command(b"\x52\x00", 7, 0x0201) & 0x2000 == 0       # 4 ms after: taken
    assert slave.eeprom[14:16] == b"\x52\x00" and slave.eeprom[8:10] == b"\xcd\xab"
