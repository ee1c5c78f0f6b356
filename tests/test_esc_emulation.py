"""The emulated ESC and the virtual segment, driven with real frames in memory.

Expected values come from ETG.1000.4 as the open masters and slaves implement it (sources
per rule in docs/protocol-notes.md §1-§4): working-counter rules per command, auto-increment
addressing, the AL state machine's refusals and codes, SyncManager mailbox rules, FMMU bit
mapping.
"""

from __future__ import annotations

import struct
import threading

import pytest

from conftest import EXAMPLES
from ecatcfg.esc import AlState, Cmd, FmmuConfig, FmmuType, SmConfig, fmmu_register, sm_register
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.link import MemoryLink
from ecatcfg.runtime.segment.timing import Timing
from ecatcfg.runtime.segment.virtual import Faults, VirtualSegment
from ecatcfg.runtime.wire import Datagram


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([EXAMPLES / "esi"], cache=False)


def line(lib: Library, *types: str, faults: Faults | None = None) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(t).entry), f"{t}-{i}")
                    for i, t in enumerate(types)], faults)


def run(seg: VirtualSegment, *dgs: Datagram) -> list[Datagram]:
    return wire.decode(seg.process(wire.encode(list(dgs)))).datagrams


def ap(cmd: Cmd, pos: int, ado: int, data: bytes | int) -> Datagram:
    return Datagram.physical(cmd, -pos & 0xFFFF, ado, data)


def fp(cmd: Cmd, addr: int, ado: int, data: bytes | int) -> Datagram:
    return Datagram.physical(cmd, addr, ado, data)


def u16(value: int) -> bytes:
    return struct.pack("<H", value)


def address_all(seg: VirtualSegment) -> None:
    for i in range(len(seg.slaves)):
        [d] = run(seg, ap(Cmd.APWR, i, 0x0010, u16(0x1001 + i)))
        assert d.wkc == 1


def request(seg: VirtualSegment, addr: int, state: int) -> tuple[int, int]:
    run(seg, fp(Cmd.FPWR, addr, 0x0120, u16(state)))
    [d] = run(seg, fp(Cmd.FPRD, addr, 0x0130, 6))
    status, _, code = struct.unpack("<HHH", d.data)
    return status, code


# -- addressing and working counters ------------------------------------------------------------

def test_broadcast_read_counts_every_slave(lib):
    seg = line(lib, "EX1100", "EX1004", "EX2008")
    [d] = run(seg, Datagram.physical(Cmd.BRD, 0, 0x0000, 2))
    assert d.wkc == 3 and d.data[0] == 0x11
    # Broadcasts and auto-increment datagrams come back with ADP counted up once per slave.
    assert d.adp == 3


def test_auto_increment_and_configured_addressing(lib):
    seg = line(lib, "EX1100", "EX1004", "EX2008")
    address_all(seg)
    assert [s.station_address for s in seg.slaves] == [0x1001, 0x1002, 0x1003]
    [d] = run(seg, fp(Cmd.FPRD, 0x1002, 0x0010, 2))
    assert (d.wkc, d.data) == (1, u16(0x1002))
    [d] = run(seg, fp(Cmd.FPRD, 0x2222, 0x0010, 2))
    assert d.wkc == 0                                  # nobody has that address
    [d] = run(seg, ap(Cmd.APRD, 5, 0x0000, 1))
    assert d.wkc == 0                                  # position past the end of the line


def test_read_write_commands(lib):
    seg = line(lib, "EX1100", "EX1004")
    address_all(seg)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0420, u16(1234)))
    [d] = run(seg, fp(Cmd.FPRW, 0x1001, 0x0420, u16(4321)))
    assert (d.wkc, d.data) == (3, u16(1234))          # FPRW: +1 read, +2 write
    [d] = run(seg, Datagram.physical(Cmd.BRW, 0, 0x0420, u16(7)))
    assert d.wkc == 6
    # Each slave writes the data as it arrives and ORs its old contents into the frame:
    # the second slave gets (and keeps) the first one's old value too.
    assert d.data == u16(7 | 4321 | 1000)
    assert [s.read(0x0420, 2) for s in seg.slaves] == [u16(7), u16(7 | 4321)]


def test_read_only_registers_stay(lib):
    seg = line(lib, "EX1100")
    run(seg, Datagram.physical(Cmd.BWR, 0, 0x0000, b"\xff" * 16))
    [d] = run(seg, Datagram.physical(Cmd.BRD, 0, 0x0000, 1))
    assert d.data == b"\x11"


def test_sii_through_the_eeprom_interface(lib):
    seg = line(lib, "EX1100", "EXD-402")
    address_all(seg)
    dev = seg.slaves[1].device

    def word_pair(addr: int) -> bytes:
        run(seg, fp(Cmd.FPWR, 0x1002, 0x0502, struct.pack("<HI", 0x0100, addr)))
        [status] = run(seg, fp(Cmd.FPRD, 0x1002, 0x0502, 2))
        assert struct.unpack("<H", status.data)[0] & 0x8000 == 0      # not busy
        [d] = run(seg, fp(Cmd.FPRD, 0x1002, 0x0508, 8))
        return d.data

    assert struct.unpack("<II", word_pair(0x08)) == (dev.vendor.id, dev.product_code)
    assert struct.unpack("<I", word_pair(0x0C)[:4]) == (dev.revision,)
    # 0x0502 bit 6: this ESC reads 8 bytes at a time (SOEM checks it).
    [d] = run(seg, fp(Cmd.FPRD, 0x1002, 0x0502, 2))
    assert struct.unpack("<H", d.data)[0] & 0x0040


# -- AL state machine ---------------------------------------------------------------------------

def test_refused_transition_and_acknowledge(lib):
    seg = line(lib, "EX1004")
    address_all(seg)
    assert request(seg, 0x1001, AlState.SAFEOP) == (AlState.INIT | 0x10, 0x0011)
    # An error must be acknowledged: a plain request is ignored ...
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.INIT | 0x10, 0x0011)
    # ... an acknowledged one goes through and clears the code.
    assert request(seg, 0x1001, AlState.PREOP | 0x10) == (AlState.PREOP, 0)
    assert request(seg, 0x1001, AlState.OP) == (AlState.PREOP | 0x10, 0x0011)
    assert request(seg, 0x1001, 0x07 | 0x10) == (AlState.PREOP | 0x10, 0x0012)   # no such state
    assert request(seg, 0x1001, AlState.INIT) == (AlState.INIT, 0)        # INIT always


def configure_dio(seg: VirtualSegment, addr: int, sm: SmConfig, fmmu: FmmuConfig | None) -> None:
    run(seg, fp(Cmd.FPWR, addr, sm_register(0), sm.to_bytes()))
    if fmmu is not None:
        run(seg, fp(Cmd.FPWR, addr, fmmu_register(0), fmmu.to_bytes()))


@pytest.mark.parametrize("sm, fmmu, code", [
    (SmConfig(0x0F00, 2, 0x44, True), FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE), 0x1D),
    (SmConfig(0x0F00, 1, 0x44, True), None, 0x1D),
    (SmConfig(0x0F00, 1, 0x44, True), FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.READ), 0x1D),
    (SmConfig(0x0F00, 1, 0x20, True), FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE), 0x1D),
    (SmConfig(0x0F00, 1, 0x44, True), FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE), 0),
], ids=["length", "no fmmu", "fmmu direction", "sm direction", "valid"])
def test_safeop_checks_output_configuration(lib, sm, fmmu, code):
    seg = line(lib, "EX2008")
    address_all(seg)
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.PREOP, 0)
    configure_dio(seg, 0x1001, sm, fmmu)
    want = (AlState.PREOP | 0x10, code) if code else (AlState.SAFEOP, 0)
    assert request(seg, 0x1001, AlState.SAFEOP) == want


def test_op_only_sm_may_stay_disabled_until_safeop_to_op(lib):
    seg = line(lib, "EX2008")
    address_all(seg)
    request(seg, 0x1001, AlState.PREOP)
    configure_dio(seg, 0x1001, SmConfig(0x0F00, 1, 0x44, False),
                  FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE))
    assert request(seg, 0x1001, AlState.SAFEOP) == (AlState.SAFEOP, 0)
    assert request(seg, 0x1001, AlState.OP) == (AlState.SAFEOP | 0x10, 0x1D)
    run(seg, fp(Cmd.FPWR, 0x1001, sm_register(0) + 6, b"\x01"))
    assert request(seg, 0x1001, AlState.OP | 0x10) == (AlState.OP, 0)


def test_injected_refusal(lib):
    seg = line(lib, "EX1004")
    seg.slaves[0].refuse["IP"] = 0x0020
    address_all(seg)
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.INIT | 0x10, 0x0020)


def _timed_drive_in_preop(lib: Library) -> tuple[VirtualSegment, list[int]]:
    """The example drive with the fitted firmware timing on a clock the test moves, its
    mailbox SyncManagers as its ESI gives them, in PREOP."""
    now = [0]
    device = lib.device(lib.find("EXD-402").entry)
    seg = segment([SlaveSpec(device, "drive")], timing=Timing(), clock_ns=lambda: now[0])
    address_all(seg)
    for sm in device.sms[:2]:
        config = SmConfig(sm.start_address, sm.default_size, sm.control_byte, True)
        [d] = run(seg, fp(Cmd.FPWR, 0x1001, sm_register(sm.number), config.to_bytes()))
        assert d.wkc == 1
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0120, u16(AlState.PREOP)))
    now[0] += 10**9                      # far longer than any firmware time of the model
    assert al_status(seg) == (AlState.PREOP, 0)
    return seg, now


def al_status(seg: VirtualSegment) -> tuple[int, int]:
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0130, 6))
    status, _, code = struct.unpack("<HHH", d.data)
    return status, code


def clear_mailbox_sms(seg: VirtualSegment) -> None:
    for n in (0, 1):
        [d] = run(seg, fp(Cmd.FPWR, 0x1001, sm_register(n), bytes(8)))
        assert d.wkc == 1


def test_mailbox_sms_cleared_behind_a_request_for_init_are_no_refusal(lib):
    """PREOP -> INIT as some exporters write it: AL control = INIT, then SM0 and SM1
    cleared at once, with no state check between, so the firmware has not taken the
    request yet when the SMs change.  A firmware takes the state request first (SOES runs
    ESC_state() before ESC_sm_act_event() in every pass): the slave reaches INIT without
    an error.  The same SMs cleared in PREOP with no request pending stop its mailbox, and
    it falls back to INIT+ERR 0x0016 (SOES ESC_checkmbx)."""
    seg, now = _timed_drive_in_preop(lib)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0120, u16(AlState.INIT)))
    clear_mailbox_sms(seg)
    assert al_status(seg) == (AlState.PREOP, 0)      # the firmware is still at it
    now[0] += 10**9
    assert al_status(seg) == (AlState.INIT, 0)

    seg, now = _timed_drive_in_preop(lib)
    clear_mailbox_sms(seg)
    now[0] += 10**9
    assert al_status(seg) == (AlState.INIT | 0x10, 0x0016)


# -- process data through FMMUs -----------------------------------------------------------------

def bring_up_dio(seg: VirtualSegment) -> None:
    """Two 4-bit input terminals packed into one logical byte, one output byte after it."""
    address_all(seg)
    layout = {0: (0, 0, 3), 1: (0, 4, 7)}
    for i, s in enumerate(seg.slaves):
        addr = 0x1001 + i
        request(seg, addr, AlState.PREOP)
        if s.device.type_name == "EX1004":
            start, sbit, ebit = layout[i]
            configure_dio(seg, addr, SmConfig(0x1000, 1, 0x00, True),
                          FmmuConfig(start, 1, sbit, ebit, 0x1000, 0, FmmuType.READ))
        else:
            configure_dio(seg, addr, SmConfig(0x0F00, 1, 0x44, True),
                          FmmuConfig(1, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE))
        assert request(seg, addr, AlState.SAFEOP) == (AlState.SAFEOP, 0)


def test_bit_packed_inputs_and_outputs_in_one_lrw(lib):
    seg = line(lib, "EX1004", "EX1004", "EX2008")
    bring_up_dio(seg)
    seg.slaves[0].set_inputs(b"\x05")        # channels 1 and 3
    seg.slaves[1].set_inputs(b"\x0a")        # channels 2 and 4
    [d] = run(seg, Datagram.logical(Cmd.LRW, 0, b"\x00\x3c"))
    assert d.wkc == 1 + 1 + 2                # inputs +1 each, outputs +2
    assert d.data[0] == 0xA5                 # 0x5 in bits 0-3, 0xA in bits 4-7
    assert seg.slaves[2].outputs() == b"\x00"          # still SAFEOP: outputs kept safe
    for addr in (0x1001, 0x1002, 0x1003):
        assert request(seg, addr, AlState.OP) == (AlState.OP, 0)
    [d] = run(seg, Datagram.logical(Cmd.LRW, 0, b"\xff\x3c"))
    assert seg.slaves[2].outputs() == b"\x3c"
    assert d.data[0] == 0xA5                 # unmapped bits would keep 0xff; all are mapped
    [d] = run(seg, Datagram.logical(Cmd.LRD, 0, 2))
    assert (d.wkc, d.data) == (2, b"\xa5\x00")
    [d] = run(seg, Datagram.logical(Cmd.LWR, 1, b"\x81"))
    assert d.wkc == 1 and seg.slaves[2].outputs() == b"\x81"


def test_process_data_before_safeop_gets_no_working_counter(lib):
    seg = line(lib, "EX1004")
    address_all(seg)
    request(seg, 0x1001, AlState.PREOP)
    configure_dio(seg, 0x1001, SmConfig(0x1000, 1, 0x00, True),
                  FmmuConfig(0, 1, 0, 3, 0x1000, 0, FmmuType.READ))
    [d] = run(seg, Datagram.logical(Cmd.LRD, 0, 1))
    assert d.wkc == 0


def test_sm_watchdog_drops_outputs(lib):
    seg = line(lib, "EX2008")
    address_all(seg)
    request(seg, 0x1001, AlState.PREOP)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0420, u16(100)))   # 100 x 100 us = 10 ms
    configure_dio(seg, 0x1001, SmConfig(0x0F00, 1, 0x44, True),
                  FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE))
    request(seg, 0x1001, AlState.SAFEOP)
    request(seg, 0x1001, AlState.OP)
    run(seg, Datagram.logical(Cmd.LWR, 0, b"\x42"))
    slave = seg.slaves[0]
    # Times from the write on (the slave's own record of it), not the host's clock now: a
    # host that holds this test up 10 ms after the write would expire the watchdog early.
    written = slave._last_output_write
    slave.check_watchdog(written + 0.005)
    assert slave.outputs() == b"\x42"
    slave.check_watchdog(written + 0.02)
    assert (slave.state, slave.error, slave.status_code) == (AlState.SAFEOP, True, 0x001B)
    assert slave.outputs() == b"\x00"
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0440, 1))
    assert d.data == b"\x00"                # SM watchdog status: expired


# -- distributed clocks -------------------------------------------------------------------------

def test_armw_distributes_the_reference_time(lib):
    seg = line(lib, "EX1100", "EX1004", "EX2008")
    address_all(seg)
    run(seg, Datagram.physical(Cmd.BWR, 0, 0x0900, 4))
    [d] = run(seg, fp(Cmd.FPRD, 0x1002, 0x0900, 8))
    port0, port1 = struct.unpack("<II", d.data)
    assert port1 > port0                     # the frame came back through port 1 later
    [d] = run(seg, fp(Cmd.FPRD, 0x1003, 0x0904, 4))
    assert d.data == bytes(4)                # the last slave's port 1 is closed
    [d] = run(seg, ap(Cmd.ARMW, 0, 0x0910, 8))
    assert d.wkc == 3                        # one read + two writes
    ref_time = struct.unpack("<Q", d.data)[0]
    # The others' time control loops compared it with their own clocks (no offsets yet:
    # seconds apart) and show the difference in 0x092C; the reference, which read, does
    # not.  The loop slews a clock, it does not set it: the times stay apart.
    [r] = run(seg, fp(Cmd.FPRD, 0x1001, 0x092C, 4))
    assert r.data == bytes(4)
    for addr in (0x1002, 0x1003):
        [diff] = run(seg, fp(Cmd.FPRD, addr, 0x092C, 4))
        assert struct.unpack("<I", diff.data)[0] & 0x7FFF_FFFF > 1000
        [t] = run(seg, fp(Cmd.FPRD, addr, 0x0910, 8))
        assert abs(struct.unpack("<Q", t.data)[0] - ref_time) > 1_000_000


# -- running on a link --------------------------------------------------------------------------

def serve_in_thread(seg: VirtualSegment):
    master, slave_end = MemoryLink.pair()
    stop = threading.Event()
    thread = threading.Thread(target=seg.serve, args=(slave_end,), kwargs={"stop": stop},
                              daemon=True)
    thread.start()
    return master, stop, thread


def replies_with_drop(lib, seed: int) -> list[int]:
    seg = line(lib, "EX1100", faults=Faults(drop=0.3, seed=seed))
    master, stop, thread = serve_in_thread(seg)
    answered = []
    try:
        for i in range(100):
            master.send(wire.encode([Datagram.physical(Cmd.BRD, 0, 0x0000, 2, idx=i)]))
            reply = master.recv(0.05)
            if reply is not None:
                answered.append(wire.decode(reply).datagrams[0].idx)
    finally:
        stop.set()
        thread.join(2)
    return answered


def test_seeded_drop_is_reproducible(lib):
    first = replies_with_drop(lib, seed=7)
    assert 50 <= len(first) <= 90            # about 30 % lost
    assert replies_with_drop(lib, seed=7) == first
    assert replies_with_drop(lib, seed=8) != first


def test_frame_with_bad_lengths_is_returned_unprocessed(lib):
    seg = line(lib, "EX1100")
    frame = bytearray(wire.encode([Datagram.physical(Cmd.BRD, 0, 0, 2)]))
    frame[14] = 0x40                         # EtherCAT header claims 64 bytes
    back = seg.process(bytes(frame))
    assert back[:6] == frame[:6] and back[16:] == frame[16:]


def test_bit_mapping_across_a_byte_boundary(lib):
    # 8 input bits at logical bits 4..11 and 8 output bits at logical bits 12..19: each
    # memory byte meets two frame bytes with different shifts.
    seg = line(lib, "EX1008", "EX2008")
    address_all(seg)
    for addr in (0x1001, 0x1002):
        request(seg, addr, AlState.PREOP)
    configure_dio(seg, 0x1001, SmConfig(0x1000, 1, 0x00, True),
                  FmmuConfig(0, 2, 4, 3, 0x1000, 0, FmmuType.READ))
    configure_dio(seg, 0x1002, SmConfig(0x0F00, 1, 0x44, True),
                  FmmuConfig(1, 2, 4, 3, 0x0F00, 0, FmmuType.WRITE))
    for addr in (0x1001, 0x1002):
        assert request(seg, addr, AlState.SAFEOP) == (AlState.SAFEOP, 0)
        assert request(seg, addr, AlState.OP) == (AlState.OP, 0)
    seg.slaves[0].set_inputs(b"\xc5")
    [d] = run(seg, Datagram.logical(Cmd.LRW, 0, b"\x0f\x70\xf9"))
    assert d.wkc == 3
    # Inputs 0xC5 land in bits 4..11; the frame's other bits stay as sent.
    assert d.data[0] == 0x5F and d.data[1] & 0x0F == 0x0C
    # Outputs are bits 12..19: 0x7 from byte 1's high nibble, 0x9 from byte 2's low one.
    assert seg.slaves[1].outputs() == b"\x97"


# -- the mailbox state a master polls ----------------------------------------------------------

# FMMU images both configurators write (register 0x0600 + 16·n): logical 0x09000000, one bit,
# read from physical 0x080D (SM1 status) bit 0.  TwinCAT: "set fmmu 1 (mailbox state)" in
# jasper-node/jn-ec-master src/tests/fixtures/mega_master_eni.xml; EC-Engineer: "set fmmu 2
# (mailbox state)" in the acontis training-slaves ENI, where the second slave takes logical
# bit 1 (start and stop bit 1) of the same byte.
MAILBOX_STATE_FMMUS = [bytes.fromhex("00000009010000000d08000101000000"),
                       bytes.fromhex("00000009010001010d08000101000000")]
# An SDO upload request of 0x1018:01 (ETG.1000.6): mailbox header (length 10, address 0,
# channel/priority 0, type CoE, counter 1), CoE header (SDO request), initiate upload.
SDO_UPLOAD_1018_01 = bytes.fromhex("0a00000000" "13" "0020" "40181001" "00000000")


def test_sm1_status_bit_0_shows_a_full_mailbox_through_the_mailbox_state_fmmu(lib):
    """ENIs of TwinCAT and EC-Engineer poll one LRD over the mailbox-state FMMUs instead of
    reading every slave's SM1: bit 0 of SM1's status (0x080D; ESC datasheets: "interrupt
    write", buffer completely written) is set while the slave's answer waits in the
    mailbox (bit 3, mailbox full) and cleared when the master has read it."""
    seg = line(lib, "EXD-402", "EXD-402")
    address_all(seg)
    for i, addr in enumerate((0x1001, 0x1002)):
        sm0, sm1 = SmConfig(0x1000, 128, 0x26, True), SmConfig(0x1080, 128, 0x22, True)
        run(seg, fp(Cmd.FPWR, addr, sm_register(0), sm0.to_bytes()),
            fp(Cmd.FPWR, addr, sm_register(1), sm1.to_bytes()),
            fp(Cmd.FPWR, addr, fmmu_register(2), MAILBOX_STATE_FMMUS[i]))
        assert request(seg, addr, AlState.PREOP) == (AlState.PREOP, 0)

    def states() -> tuple[int, int]:
        [d] = run(seg, Datagram.logical(Cmd.LRD, 0x09000000, 1))
        return d.data[0], d.wkc

    def sm1_status(addr: int) -> int:
        [d] = run(seg, fp(Cmd.FPRD, addr, 0x080D, 1))
        return d.data[0]

    assert states() == (0x00, 2) and sm1_status(0x1001) == sm1_status(0x1002) == 0
    [d] = run(seg, fp(Cmd.FPWR, 0x1002, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    assert d.wkc == 1
    assert states() == (0x02, 2)                # the second slave's bit: its answer waits
    assert sm1_status(0x1002) & 0x09 == 0x09 and sm1_status(0x1001) == 0
    run(seg, fp(Cmd.FPWR, 0x1001, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    assert states() == (0x03, 2)
    [answer] = run(seg, fp(Cmd.FPRD, 0x1002, 0x1080, 128))
    assert answer.wkc == 1 and answer.data[5] & 0x0F == 0x03       # a CoE message
    assert answer.data[8] == 0x43 and answer.data[9:12] == b"\x18\x10\x01"  # expedited, 4 B
    assert states() == (0x01, 2) and sm1_status(0x1002) & 0x09 == 0
