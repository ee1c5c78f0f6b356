"""ESC device emulation (0x0141 bit 0) and the registers masters read at start-up.

References, none of them computed by the emulator: the Beckhoff ESC register description
(Section II: AL Control 0x0120, AL Status 0x0130, Watchdog Status 0x0440), Beckhoff's
"General notes for setting the watchdog" (the SM watchdog leaves the terminal's state
alone), and the real replies of EK1100, EL1004, EL2828 and EL2889 in EtherCrab's captures
(ethercrab-rs/ethercrab ``dumps/soem-sdinfo-ek1100-el1004.pcapng`` and
``tests/replay-ek1100-el2828-el2889.pcapng``, in the corpus): their master frames are
replayed against the emulated slaves and the replies compared with what the hardware said.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path

import pytest
from scapy.utils import RawPcapNgReader
from conftest import EXAMPLES
from test_esc_emulation import SDO_UPLOAD_1018_01, address_all, fp, request, run, u16

from ecatcfg.esc import AlState, Cmd, FmmuConfig, FmmuType, SmConfig, fmmu_register, sm_register
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment
from ecatcfg.runtime.segment.slave import StateChange
from ecatcfg.runtime.wire import Datagram


@pytest.fixture(scope="module")
def beckhoff(corpus: Path) -> Library:
    return Library([corpus / "esi" / "beckhoff"], cache=False)


def line(lib: Library, *types: str) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(t).entry), f"{t}-{i}")
                    for i, t in enumerate(types)])


def configure(seg: VirtualSegment, addr: int, sm: int, cfg: SmConfig,
              fmmu: FmmuConfig | None = None, fmmu_no: int = 0) -> None:
    [d] = run(seg, fp(Cmd.FPWR, addr, sm_register(sm), cfg.to_bytes()))
    assert d.wkc == 1
    if fmmu is not None:
        [d] = run(seg, fp(Cmd.FPWR, addr, fmmu_register(fmmu_no), fmmu.to_bytes()))
        assert d.wkc == 1


# -- the acceptance: SM lengths the ESI does not give --------------------------------

def test_device_emulation_slaves_reach_op_with_sm_lengths_other_than_the_esis(beckhoff):
    """A master that sizes the EL1809's input SM from its first PDO only (1 byte, the ESI
    says 2) and puts both EL2809 output bytes into SM0 (the ESI: one byte in SM0, one in
    SM1) gets OP: no firmware checks them, the ESC copies AL control into AL status."""
    seg = line(beckhoff, "EK1100", "EL1809", "EL2809")
    assert [s.device_emulation for s in seg.slaves] == [True, True, True]
    changes: list[StateChange] = []
    seg.on_state_change = changes.append
    address_all(seg)
    configure(seg, 0x1002, 0, SmConfig(0x1000, 1, 0x00, True),
              FmmuConfig(0, 1, 0, 7, 0x1000, 0, FmmuType.READ))
    configure(seg, 0x1003, 0, SmConfig(0x0F00, 2, 0x44, True),
              FmmuConfig(1, 2, 0, 7, 0x0F00, 0, FmmuType.WRITE))
    configure(seg, 0x1003, 1, SmConfig(0x0F01, 0, 0x44, False))
    for addr in (0x1001, 0x1002, 0x1003):
        for state in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
            assert request(seg, addr, state) == (state, 0)
    seg.slaves[1].set_inputs(b"\x5a\xff")            # only the first byte is configured
    [d] = run(seg, Datagram.logical(Cmd.LRW, 0, b"\x00\x81\x42"))
    assert d.wkc == 1 + 2                             # inputs +1, outputs +2
    assert d.data[0] == 0x5A
    assert seg.slaves[2].outputs() == b"\x81\x42"
    # simulate's log notes the lengths once, when each slave enters SAFEOP.
    notes = {(c.name, c.state): c.note for c in changes if c.note}
    assert notes == {
        ("EL1809-1", AlState.SAFEOP): "SM lengths in bytes differ from the ESI: SM0 1 (ESI 2)",
        ("EL2809-2", AlState.SAFEOP):
            "SM lengths in bytes differ from the ESI: SM0 2 (ESI 1), SM1 0 (ESI 1)"}


def test_a_firmware_refuses_the_same_sizing_with_its_code(beckhoff):
    """The same sizing against a CoE slave (EL3202: SM3 from its first TxPDO only, 4 bytes
    where the default assignment needs 8): its firmware refuses SAFEOP with 0x001E (SOES
    ESC_checkSM23), and takes the ESI's length."""
    seg = line(beckhoff, "EL3202")
    dev = seg.slaves[0]
    assert not dev.device_emulation
    address_all(seg)
    configure(seg, 0x1001, 0, SmConfig(0x1000, 128, 0x26, True))
    configure(seg, 0x1001, 1, SmConfig(0x1080, 128, 0x22, True))
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.PREOP, 0)
    configure(seg, 0x1001, 3, SmConfig(0x1180, 4, 0x20, True),
              FmmuConfig(0, 4, 0, 7, 0x1180, 0, FmmuType.READ))
    assert request(seg, 0x1001, AlState.SAFEOP) == (AlState.PREOP | 0x10, 0x001E)
    configure(seg, 0x1001, 3, SmConfig(0x1180, 8, 0x20, True),
              FmmuConfig(0, 8, 0, 7, 0x1180, 0, FmmuType.READ))
    assert request(seg, 0x1001, AlState.SAFEOP | 0x10) == (AlState.SAFEOP, 0)


# -- AL control mirrored into AL status ----------------------------------------------------

def test_al_control_is_copied_into_al_status(beckhoff):
    """Every value as written, whatever the state before (ESC Section II, 0x0120 note): the
    acknowledge bit becomes the error flag, BOOT and values that are no state are shown
    too, the status code is left alone.  With no firmware to switch SMs off, the ESC serves
    its FMMUs in any state, as a real EL2828 and EL2889 count an LRW in PREOP
    (ethercrab-rs/ethercrab tests/replay-dc.pcapng)."""
    seg = line(beckhoff, "EL1004")
    address_all(seg)
    assert request(seg, 0x1001, 0x0011) == (0x0011, 0)
    assert request(seg, 0x1001, AlState.OP) == (AlState.OP, 0)         # INIT -> OP at once
    assert request(seg, 0x1001, AlState.BOOT) == (AlState.BOOT, 0)
    assert request(seg, 0x1001, 0x0024) == (0x0024, 0)                 # identification bit
    configure(seg, 0x1001, 0, SmConfig(0x1000, 1, 0x00, True),
              FmmuConfig(0, 1, 0, 3, 0x1000, 0, FmmuType.READ))
    assert request(seg, 0x1001, 0x0005) == (0x0005, 0)                 # no such state
    assert seg.slaves[0].state is None
    [d] = run(seg, Datagram.logical(Cmd.LRD, 0, 1))
    assert d.wkc == 1
    assert request(seg, 0x1001, AlState.SAFEOP) == (AlState.SAFEOP, 0)
    [d] = run(seg, Datagram.logical(Cmd.LRD, 0, 1))
    assert d.wkc == 1
    # A one-byte write (SOEM's BWR of 0x11) copies the whole register.
    run(seg, Datagram.physical(Cmd.BWR, 0, 0x0120, b"\x12"))
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0130, 6))
    assert struct.unpack("<HHH", d.data) == (0x0012, 0, 0)


def test_injected_refusal_still_applies_with_device_emulation(beckhoff):
    seg = line(beckhoff, "EL1809")
    seg.slaves[0].refuse["IP"] = 0x0020
    address_all(seg)
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.INIT | 0x10, 0x0020)


# -- the SM watchdog -----------------------------------------------------------------------

def _op_with_watchdog(seg: VirtualSegment) -> None:
    address_all(seg)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0420, u16(100)))   # 100 x 100 us = 10 ms
    configure(seg, 0x1001, 0, SmConfig(0x0F00, 1, 0x44, True),
              FmmuConfig(0, 1, 0, 7, 0x0F00, 0, FmmuType.WRITE))
    for state in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        request(seg, 0x1001, state)
    run(seg, Datagram.logical(Cmd.LWR, 0, b"\x42"))


def test_sm_watchdog_with_device_emulation_keeps_op_and_clears_outputs(beckhoff):
    """No firmware to change AL status: the state stays OP, the ESC clears 0x0440 bit 0,
    counts the expiry in 0x0442 and resets the digital outputs; the next output write
    re-triggers it."""
    seg = line(beckhoff, "EL2008")
    slave = seg.slaves[0]
    _op_with_watchdog(seg)
    slave.check_watchdog(time.monotonic())
    assert slave.outputs() == b"\x42"
    slave.check_watchdog(time.monotonic() + 0.02)
    slave.check_watchdog(time.monotonic() + 0.04)                 # expires once
    assert (slave.state, slave.error, slave.status_code) == (AlState.OP, False, 0)
    assert slave.outputs() == b"\x00"
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0440, 4))
    assert d.data == b"\x00\x00\x01\x00"                         # expired, counted once
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0130, 6))
    assert struct.unpack("<HHH", d.data) == (AlState.OP, 0, 0)
    run(seg, Datagram.logical(Cmd.LWR, 0, b"\x24"))
    assert slave.outputs() == b"\x24"
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0440, 1))
    assert d.data == b"\x01"
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0443, b"\x00"))             # a write clears the counters
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0442, 2))
    assert d.data == b"\x00\x00"


def test_sm_watchdog_with_firmware_drops_to_safeop_with_0x001b(beckhoff):
    """EL7342, a CoE terminal (ConfigData byte 1 = 0, a microcontroller): its firmware takes
    SAFEOP+ERR 0x001B when the outputs stop (SOES ecat_slv.c)."""
    seg = line(beckhoff, "EL7342")
    slave = seg.slaves[0]
    assert not slave.device_emulation
    address_all(seg)
    configure(seg, 0x1001, 0, SmConfig(0x1000, 128, 0x26, True))
    configure(seg, 0x1001, 1, SmConfig(0x1080, 128, 0x22, True))
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.PREOP, 0)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0420, u16(100)))
    configure(seg, 0x1001, 2, SmConfig(0x1100, 16, 0x64, True),
              FmmuConfig(0, 16, 0, 7, 0x1100, 0, FmmuType.WRITE), 0)
    configure(seg, 0x1001, 3, SmConfig(0x1200, 16, 0x20, True),
              FmmuConfig(16, 16, 0, 7, 0x1200, 0, FmmuType.READ), 1)
    assert request(seg, 0x1001, AlState.SAFEOP) == (AlState.SAFEOP, 0)
    assert request(seg, 0x1001, AlState.OP) == (AlState.OP, 0)
    run(seg, Datagram.logical(Cmd.LWR, 0, b"\x01" * 16))
    slave.check_watchdog(time.monotonic() + 0.02)
    assert (slave.state, slave.error, slave.status_code) == (AlState.SAFEOP, True, 0x001B)
    assert slave.outputs() == bytes(16)


def test_sm_watchdog_shorter_than_the_segments_loop_expires_between_two_writes(beckhoff):
    """A watchdog of 1 unit (100 µs) under a 1 ms cycle: the ESC's watchdog runs out between
    two output writes whenever they come, not when the segment's loop looks (every 2 ms,
    ``check_watchdog``, not called here).  The slave's clock is the test's own: 50 µs
    between writes keeps OP, 1 ms drops the EL7342's firmware to SAFEOP+ERR 0x001B."""
    now = [10**12]
    seg = segment([SlaveSpec(beckhoff.device(beckhoff.find("EL7342").entry), "EL7342-0")],
                  clock_ns=lambda: now[0])
    slave = seg.slaves[0]
    address_all(seg)
    configure(seg, 0x1001, 0, SmConfig(0x1000, 128, 0x26, True))
    configure(seg, 0x1001, 1, SmConfig(0x1080, 128, 0x22, True))
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.PREOP, 0)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x0420, u16(1)))
    configure(seg, 0x1001, 2, SmConfig(0x1100, 16, 0x64, True),
              FmmuConfig(0, 16, 0, 7, 0x1100, 0, FmmuType.WRITE), 0)
    configure(seg, 0x1001, 3, SmConfig(0x1200, 16, 0x20, True),
              FmmuConfig(16, 16, 0, 7, 0x1200, 0, FmmuType.READ), 1)
    assert request(seg, 0x1001, AlState.SAFEOP) == (AlState.SAFEOP, 0)
    assert request(seg, 0x1001, AlState.OP) == (AlState.OP, 0)
    for gap_ns in (50_000, 50_000, 90_000):
        now[0] += gap_ns
        run(seg, Datagram.logical(Cmd.LWR, 0, b"\x01" * 16))
        assert (slave.state, slave.error) == (AlState.OP, False)
    now[0] += 1_000_000
    run(seg, Datagram.logical(Cmd.LWR, 0, b"\x01" * 16))
    assert (slave.state, slave.error, slave.status_code) == (AlState.SAFEOP, True, 0x001B)
    [d] = run(seg, fp(Cmd.FPRD, 0x1001, 0x0442, 1))
    assert d.data == b"\x01"                                     # expired once


# -- replies compared with real hardware ---------------------------------------------------

def _exchanges(path: Path) -> list[tuple[bytes, bytes]]:
    """(master frame, the frame that came back) in capture order.  A frame that passed an
    ESC has the locally-administered bit set in its source MAC (ETG.1000.4)."""
    frames = [bytes(p) for p, _ in RawPcapNgReader(str(path)) if bytes(p)[12:14] == b"\x88\xa4"]
    pairs = []
    for sent, back in zip(frames, frames[1:]):
        if not sent[6] & 0x02 and back[6] & 0x02:
            pairs.append((sent, back))
    return pairs


def _compare(seg: VirtualSegment, path: Path, registers: set[int],
             at: frozenset[tuple[int, int]] = frozenset()) -> list[tuple[int, int]]:
    """Replay the master's frames; the (ADO, AL status or 0) of every datagram compared:
    those at ``registers``, those at (station address, ADO) in ``at`` and all logical
    ones.  Returns the list, asserting on the way."""
    seen = []
    for n, (sent, back) in enumerate(_exchanges(path)):
        ours = wire.decode(seg.process(sent)).datagrams
        real = wire.decode(back).datagrams
        for mine, theirs in zip(ours, real):
            logical = theirs.cmd in (Cmd.LRD, Cmd.LWR, Cmd.LRW)
            if not (logical or theirs.ado in registers or (theirs.adp, theirs.ado) in at):
                continue
            assert (bytes(mine.data), mine.wkc) == (bytes(theirs.data), theirs.wkc), (
                f"exchange {n}: {Cmd(theirs.cmd).name} 0x{theirs.ado:04X}")
            seen.append((-1 if logical else theirs.ado,
                         theirs.data[0] if theirs.ado == 0x0130 and theirs.wkc else 0))
    return seen


def test_soem_start_up_of_ek1100_el1004_replies_as_the_hardware(beckhoff, corpus):
    """SOEM writes AL control 0x0011, 0x0012, 0x0004: a real EK1100 (0x0141 = 0x0D) and
    EL1004 (0x0141 = 0x01) read back exactly that, status code 0; DL status as theirs, and
    the features of the EK1100's ET1100, the chip the emulated ESC reports (type 0x11)."""
    seg = line(beckhoff, "EK1100", "EL1004")
    seen = _compare(seg, corpus / "pcap" / "ethercrab" / "soem-sdinfo-ek1100-el1004.pcapng",
                    {0x0130, 0x0110}, frozenset({(0x1001, 0x0008)}))
    states = [status for ado, status in seen if ado == 0x0130]
    assert {0x11, 0x12, 0x04} <= set(states), states
    assert (0x0110, 0) in seen and (0x0008, 0) in seen


def test_ethercrab_run_to_op_replies_as_the_hardware(beckhoff, corpus):
    """EtherCrab brings EK1100 + EL2828 + EL2889 to OP and runs process data: AL status,
    DL status, the process data frames and the FMMU/SM blocks past the ESC's own (no
    working counter) come back as from the hardware."""
    seg = line(beckhoff, "EK1100", "EL2828", "EL2889")
    path = corpus / "pcap" / "ethercrab" / "replay-ek1100-el2828-el2889.pcapng"
    seen = _compare(seg, path, {0x0130, 0x0110, fmmu_register(8), sm_register(8)})
    assert (0x0130, 0x08) in seen and (-1, 0) in seen


def test_mailbox_status_shows_the_read_event_once_emptied():
    """A real LAN9252 (SOES firmware) reads 0x02 in SM0's status after its firmware took a
    message and in SM1's after SOEM read the reply (ethercrab-rs/ethercrab
    dumps/soem-single-lan9252.pcapng): status bit 1, "buffer completely read"."""
    seg = line(Library([EXAMPLES / "esi"], cache=False), "EXD-402")
    address_all(seg)
    configure(seg, 0x1001, 0, SmConfig(0x1000, 128, 0x26, True))
    configure(seg, 0x1001, 1, SmConfig(0x1080, 128, 0x22, True))
    assert request(seg, 0x1001, AlState.PREOP) == (AlState.PREOP, 0)

    def status(sm: int) -> int:
        [d] = run(seg, fp(Cmd.FPRD, 0x1001, sm_register(sm) + 5, 1))
        return d.data[0]

    assert (status(0), status(1)) == (0x00, 0x00)
    run(seg, fp(Cmd.FPWR, 0x1001, 0x1000, SDO_UPLOAD_1018_01.ljust(128, b"\0")))
    assert (status(0), status(1)) == (0x02, 0x09)
    [answer] = run(seg, fp(Cmd.FPRD, 0x1001, 0x1080, 128))
    assert answer.wkc == 1
    assert (status(0), status(1)) == (0x02, 0x02)
