"""Explicit device identification in the emulated ESC (ETG.1020 "Requesting ID"; Beckhoff ESC
Section II: AL control 0x0120 bit 5 "Device Identification request", AL status 0x0130 bit 5
"Device Identification loaded", AL status code 0x0134): the master sets the request bit,
a device with an ID (an ID switch) shows it in 0x0134 and sets AL status bit 5; a device
without one ignores the request.

Every value is written by hand from those register descriptions and read back with
datagrams as a master reads them.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from conftest import EXAMPLES

from ecatcfg.esc import Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([EXAMPLES / "esi"], cache=False)


def line(lib: Library, *types: str) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(t).entry), f"{t}-{i}")
                    for i, t in enumerate(types)])


def al_control(seg: VirtualSegment, position: int, value: int) -> None:
    [d] = wire.decode(seg.process(wire.encode([wire.Datagram.physical(
        Cmd.APWR, -position & 0xFFFF, 0x0120, struct.pack("<H", value))]))).datagrams
    assert d.wkc == 1


def al_status(seg: VirtualSegment, position: int) -> tuple[int, int]:
    """(AL status 0x0130, AL status code 0x0134) in one 6-byte read."""
    [d] = wire.decode(seg.process(wire.encode([wire.Datagram.physical(
        Cmd.APRD, -position & 0xFFFF, 0x0130, 6)]))).datagrams
    assert d.wkc == 1
    status, _, code = struct.unpack("<HHH", d.data)
    return status, code


def test_the_id_is_shown_while_the_master_asks(lib):
    seg = line(lib, "EX1100", "EX1004")
    seg.slaves[1].device_id = 0x0107
    assert al_status(seg, 1) == (0x0001, 0)                   # INIT, nothing asked
    al_control(seg, 1, 0x0021)                                # INIT + ID request
    assert al_status(seg, 1) == (0x0021, 0x0107)
    al_control(seg, 1, 0x0001)                                # request withdrawn
    assert al_status(seg, 1) == (0x0001, 0)


def test_a_device_without_an_id_ignores_the_request(lib):
    seg = line(lib, "EX1100", "EX1004")
    assert seg.slaves[1].device_id is None
    al_control(seg, 1, 0x0021)
    assert al_status(seg, 1) == (0x0001, 0)


def test_the_id_stays_through_a_state_change_and_an_error_shows_its_code(lib):
    """EX1004 has no mailbox: INIT -> PREOP needs nothing.  PREOP -> SAFEOP without its
    process-data SM is refused with 0x001E (invalid input configuration): the error's
    code replaces the ID until it is acknowledged."""
    seg = line(lib, "EX1100", "EX1004")
    seg.slaves[1].device_id = 0xBEEF
    al_control(seg, 1, 0x0021)                                # INIT + ID request
    al_control(seg, 1, 0x0022)                                # PREOP, still asking
    assert al_status(seg, 1) == (0x0022, 0xBEEF)
    al_control(seg, 1, 0x0024)                                # SAFEOP: refused
    assert al_status(seg, 1) == (0x0012, 0x001E)
    al_control(seg, 1, 0x0032)                                # acknowledge, stay, ask
    assert al_status(seg, 1) == (0x0022, 0xBEEF)


def test_the_switch_is_read_at_each_request_and_kept_over_a_power_cycle(lib):
    seg = line(lib, "EX1100", "EX1004")
    slave = seg.slaves[1]
    slave.device_id = 3
    al_control(seg, 1, 0x0021)
    assert al_status(seg, 1) == (0x0021, 3)
    seg.power_cycle(1)
    assert al_status(seg, 1) == (0x0001, 0)                   # reset: nothing shown
    slave.device_id = 4                                       # the switch turned
    al_control(seg, 1, 0x0021)
    assert al_status(seg, 1) == (0x0021, 4)
    with pytest.raises(ValueError, match="16 bits"):
        slave.device_id = 0x10000


def test_device_emulation_mirrors_the_bit_and_loads_no_id(corpus: Path):
    """An ESC without firmware copies AL control into AL status (Section II 0x0120 note)
    and has nothing to load an ID with: 0x0134 stays."""
    beckhoff = Library([corpus / "esi" / "beckhoff"], cache=False)
    seg = line(beckhoff, "EK1100", "EL1809")
    assert seg.slaves[1].device_emulation
    seg.slaves[1].device_id = 9
    al_control(seg, 1, 0x0021)
    assert al_status(seg, 1) == (0x0021, 0)


def test_an_id_switch_the_esi_places_in_memory_reads_there(corpus: Path):
    """The EK1101's ESI says ``<IdentificationAdo>#x1000</IdentificationAdo>``: its ID
    switch is read at 0x1000 (16 bits), in every state, kept over a power cycle."""
    beckhoff = Library([corpus / "esi" / "beckhoff"], cache=False)
    seg = line(beckhoff, "EK1101")
    seg.slaves[0].device_id = 0x0042

    def at_0x1000() -> int:
        [d] = wire.decode(seg.process(wire.encode([wire.Datagram.physical(
            Cmd.APRD, 0, 0x1000, 2)]))).datagrams
        assert d.wkc == 1
        value: int = struct.unpack("<H", d.data)[0]
        return value

    assert at_0x1000() == 0x0042
    seg.power_cycle(0)
    assert at_0x1000() == 0x0042
