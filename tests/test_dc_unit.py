"""Which emulated ESC has a DC unit (``runtime/segment/esc_chips.py`` ``has_dc_unit``): the rule
against every real slave of every capture, the emulated registers of a DC-less ESC, and a
master that brings up a line with one in front of a DC drive.

Independent references: the working counters the real slaves gave for their DC registers
(0x0910-0x09FF) in the wire captures of both corpora, read here without the emulator; the
ESI files of the vendors for those slaves; self-written ESIs for the emulated registers.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from conformance import (AUTO_INC, CONFIGURED, WRITES, _datagram_pairs, _describe, captures,
                         exchanges, sii_dumps, slaves_seen)

from conftest import EXAMPLES, device_xml, esi_xml, write
from ecatcfg.esc import ESC_FEATURE_DC, Cmd, Reg
from ecatcfg.esi.library import Library
from ecatcfg.esi.reader import read_bytes
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, emulated_slave, segment
from ecatcfg.runtime.segment.esc_chips import chip_for, chip_of, has_dc_unit
from ecatcfg.runtime.wire import Datagram

DC_UNIT = range(Reg.DC_SYSTEM_TIME, 0x0A00)
EL2889 = (0x2, 0x0B493052)


def dc_answers(path: Path) -> dict[int, bool]:
    """Position -> whether the real slave answered an access addressed to it alone (auto
    increment or configured address) wholly inside its DC system-time unit; positions the
    master never asked are left out."""
    station: dict[int, int] = {}
    seen: dict[int, set[bool]] = {}
    for _, _, sent, back in _datagram_pairs(exchanges(path)):
        ado, n = sent.ado, len(sent.data)
        if sent.cmd in WRITES and sent.cmd in AUTO_INC and ado <= 0x0010 < ado + n - 1 \
                and back.wkc:
            station[struct.unpack_from("<H", sent.data, 0x0010 - ado)[0]] = -sent.adp & 0xFFFF
        if not (ado in DC_UNIT and ado + n - 1 in DC_UNIT):
            continue
        if sent.cmd in AUTO_INC and sent.cmd != Cmd.ARMW:
            pos: int | None = -sent.adp & 0xFFFF
        elif sent.cmd in CONFIGURED and sent.cmd != Cmd.FRMW:
            pos = station.get(sent.adp)
        else:
            continue
        if pos is not None and not (sent.cmd in WRITES and ado == Reg.DC_SYSTEM_TIME_DIFFERENCE):
            seen.setdefault(pos, set()).add(back.wkc > 0)
    assert all(len(v) == 1 for v in seen.values()), (path.name, seen)
    return {pos: v.pop() for pos, v in seen.items()}


@pytest.fixture(scope="module")
def observed(corpus: Path, corpus_extra: Path) -> dict[tuple[int, int], tuple[str, bool, bool]]:
    """(vendor, product) -> (type, the hardware's DC unit, the rule's answer from its ESI),
    over every slave of every capture that touches its DC registers and has an ESI."""
    library = Library([corpus / "esi", corpus_extra / "esi"], cache=False)
    dumps = sii_dumps(corpus / "sii")
    out: dict[tuple[int, int], tuple[str, bool, bool]] = {}
    for path in captures(corpus) + captures(corpus_extra):
        answers = dc_answers(path)
        for slave in slaves_seen(exchanges(path)):
            if slave.position not in answers:
                continue
            _, spec, _ = _describe(slave, library, dumps)
            if spec is None:
                continue
            dev = spec.device
            key = (dev.vendor.id or 0, dev.product_code or 0)
            real = answers[slave.position]
            assert out.get(key, (dev.type_name, real))[1] == real, (path.name, key)
            emulated = chip_of(dev, chip_for(*key)).dc_unit
            assert emulated == real, (path.name, dev.type_name, real)
            out[key] = (dev.type_name, real, has_dc_unit(dev))
    return out


def test_the_rule_classifies_the_real_slaves_as_their_replies_show(observed):
    """EK1100 (ConfigData 0x0D: DC SYNC and latch units on) runs its DC unit; the EK1914
    coupler with TwinSAFE logic (0x00), the EL2828 (0x01) and the EL6910 TwinSAFE logic
    terminal answer none of its registers.
    The one slave the ESI cannot tell is the EL2889 (0x01, no DC op mode, yet a DC unit):
    the chip table keeps what its capture shows, and the emulated chip of every slave
    agrees with the hardware (checked in the fixture)."""
    real = {name: dc for name, dc, _ in observed.values()}
    assert real == {"EK1100": True, "EL1004": False, "EL2828": False, "EL2889": True,
                    "EK1914": False, "EL6910": False}
    wrong = {name for name, dc, rule in observed.values() if dc != rule}
    assert wrong == {"EL2889"}
    assert chip_for(*EL2889).dc_unit


COUPLER = ('<Info><Electrical><EBusCurrent>-500</EBusCurrent></Electrical></Info>'
           '<Eeprom><ByteSize>2048</ByteSize><ConfigData>{config}</ConfigData></Eeprom>')
DC_MODE = ('<Dc><OpMode><Name>DC</Name><AssignActivate>#x300</AssignActivate>'
           '<CycleTimeSync0 Factor="1">0</CycleTimeSync0></OpMode></Dc>')


def device(config: str, dc: str = "", name: str = "CPL"):
    body = (DC_MODE if dc else "") + COUPLER.format(config=config)
    esi = read_bytes(esi_xml(device_xml(name, body=body)).encode(), "c.xml")
    assert [p for p in esi.problems if p.severity == "error"] == []
    return esi.devices[0]


@pytest.mark.parametrize("config,dc,unit", [
    ("0500", False, False),          # EK1914: PDI 0x05, ESC configuration 0x00
    ("0401", False, False),          # EL2828: digital I/O, device emulation only
    ("000D", False, True),           # EK1100: device emulation + DC SYNC + DC latch
    ("0004", False, True),           # DC SYNC output unit alone
    ("0008", False, True),           # DC latch input unit alone
    ("0500", True, True),            # a DC op mode with AssignActivate 0x300
])
def test_rule_on_self_written_descriptions(config, dc, unit):
    assert has_dc_unit(device(config, "dc" if dc else "")) is unit


def test_an_esi_without_esc_configuration_keeps_the_most_capable_esc():
    esi = read_bytes(esi_xml(device_xml("BARE")).encode(), "b.xml")
    assert has_dc_unit(esi.devices[0])


def run(seg, *dgs: Datagram) -> list[Datagram]:
    return wire.decode(seg.process(wire.encode(list(dgs)))).datagrams


def test_a_dc_less_esc_answers_like_the_ek1914():
    """What the EK1914 captures show: the port receive times answer, the system-time unit
    gives no working counter (FPRD 0x0918, FRMW 0x0910, BWR 0x0910 counting the DC ESC
    only), and the feature register still says "DC supported" (0x00FC)."""
    seg = segment([SlaveSpec(device("0500"), "ek1914"), SlaveSpec(device("000D", name="EK"),
                                                                  "ek1100")])
    for pos in range(2):
        [d] = run(seg, Datagram.physical(Cmd.APWR, -pos & 0xFFFF, 0x0010,
                                         struct.pack("<H", 0x1001 + pos)))
        assert d.wkc == 1
    rx, unit, feat = run(seg, Datagram.physical(Cmd.FPRD, 0x1001, 0x0900, 16),
                         Datagram.physical(Cmd.FPRD, 0x1001, 0x0918, 8),
                         Datagram.physical(Cmd.FPRD, 0x1001, Reg.ESC_FEATURES, 2))
    assert (rx.wkc, unit.wkc, feat.wkc) == (1, 0, 1)
    assert struct.unpack("<H", feat.data)[0] & ESC_FEATURE_DC
    [bwr] = run(seg, Datagram.physical(Cmd.BWR, 0, Reg.DC_SYSTEM_TIME, bytes(8)))
    assert bwr.wkc == 1
    [frmw] = run(seg, Datagram.physical(Cmd.FRMW, 0x1002, Reg.DC_SYSTEM_TIME, 8))
    assert frmw.wkc == 1
    [unit2] = run(seg, Datagram.physical(Cmd.FPRD, 0x1002, 0x0918, 8))
    assert unit2.wkc == 1
    assert not emulated_slave(SlaveSpec(device("0500"))).chip.dc_unit


def test_a_line_with_a_dc_less_coupler_before_a_dc_drive_reaches_op(tmp_path):
    """The master takes the reference clock from the ENI (the drive, the first slave with
    DC), not from the coupler's 0x0008, and the coupler is not among the DC slaves: the
    line reaches OP with the drive's clock synchronised."""
    esi = write(tmp_path, "coupler.xml", esi_xml(device_xml("CPL", body=COUPLER.format(
        config="0500"))))
    topo = write(tmp_path, "line.yaml", "master: {cycle_time_us: 1000}\nslaves:\n"
                 "  - {name: coupler, device: CPL}\n"
                 "  - {name: axis, device: '0xE0000ECA:0x7201', dc: DC}\n")
    eni = tmp_path / "line.eni.xml"
    common = ["--esi", str(esi), "--esi", str(EXAMPLES / "esi"), "--no-cache"]
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "-o",
                           str(eni), *common], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--format", "json", "--simulated-time", "--cycles", "20", *common],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert [s["highest_state"] for s in report["slaves"]] == ["OP", "OP"]
    assert any("DC: 1 slaves" in e for e in report["events"]), report["events"]
