"""The virtual segment against wire captures of real slaves (docs/conformance.md).

Every corpus capture is replayed by the harness in ``tests/conformance.py``: its slaves are
identified from the capture's own SII reads, the same line is built from the corpus ESI
files, the master's frames go through it in memory and every returned datagram is compared
with the hardware's.  The expectations are the hardware's replies in the captures
(ethercrab-rs/ethercrab ``dumps/`` and ``tests/``), never values the emulator computes.

``RECORDED`` is the table of docs/conformance.md: no usable capture has a difference, and
the other figures may only get better.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conformance import BY_RULE, DIFFERENT, EQUAL, KNOWN_LIMIT, captures, replay

from ecatcfg.esi.library import Library
from ecatcfg.runtime.slave import EmulatedSlave

# capture -> (usable, compared, equal, by rule, known limit, different)
RECORDED: dict[str, tuple[bool, int, int, int, int, int]] = {
    "ethercrab/replay-dc.pcapng": (True, 2838, 1946, 364, 528, 0),
    "ethercrab/replay-ek1100-alias-address.pcapng": (True, 650, 396, 107, 147, 0),
    "ethercrab/replay-ek1100-el2828-el2889.pcapng": (True, 2062, 1424, 106, 532, 0),
    "ethercrab/rs-detect-slaves-ek1100-el1004.pcapng": (False, 0, 0, 0, 0, 0),
    "ethercrab/rs-detect-slaves-ek1100-only.pcapng": (False, 0, 0, 0, 0, 0),
    "ethercrab/soem-dual-lan9252.pcapng": (False, 0, 0, 0, 0, 0),
    "ethercrab/soem-sdinfo-ek1100-el1004.pcapng": (True, 290, 187, 7, 96, 0),
    "ethercrab/soem-sdinfo-ek1100-only.pcapng": (True, 94, 43, 47, 4, 0),
    "ethercrab/soem-single-lan9252.pcapng": (False, 0, 0, 0, 0, 0),
    "ethercrab/twincat-scan-boxes.pcapng": (True, 842, 812, 24, 6, 0),
    "ethercrab/twincat-scan-devices-2.pcapng": (False, 0, 0, 0, 0, 0),
    "twincat-akd-nc-mode.pcapng": (False, 0, 0, 0, 0, 0),
    "twincat-run-ek1100-el1004.pcapng": (False, 0, 0, 0, 0, 0),
    "twincat-scan-devices.pcapng": (False, 0, 0, 0, 0, 0),
}


@pytest.fixture(scope="module")
def library(corpus: Path) -> Library:
    return Library([corpus / "esi"], cache=False)


def _report(corpus: Path, library: Library, name: str):
    return replay(corpus / "pcap" / name, library, name)


def test_every_capture_is_listed(corpus):
    names = {str(p.relative_to(corpus / "pcap")) for p in captures(corpus)}
    assert names == set(RECORDED)


@pytest.mark.parametrize("name", sorted(RECORDED))
def test_capture_conforms_no_worse_than_recorded(corpus, library, name):
    usable, compared, equal, by_rule, limit, different = RECORDED[name]
    r = _report(corpus, library, name)
    assert r.usable == usable, r.reason
    assert r.compared == compared
    c = r.counts
    assert different == 0 and c[DIFFERENT] == 0, "\n".join(map(str, r.differences[:20]))
    assert c[KNOWN_LIMIT] <= limit, r.limits
    assert c[EQUAL] + c[BY_RULE] >= equal + by_rule


def test_slaves_are_identified_from_the_captures_sii_reads(corpus, library):
    """Vendor, product and revision as the SII words 0x08-0x0D in the capture say them;
    the LAN9252 captures name Microchip's 0x9:0x9252, for which the corpus has no ESI."""
    r = _report(corpus, library, "ethercrab/twincat-scan-boxes.pcapng")
    assert r.slaves == ["EK1100 (0x2:0x44c2c52:0x120000)", "EL1004 (0x2:0x3ec3052:0x130000)"]
    lan = _report(corpus, library, "ethercrab/soem-single-lan9252.pcapng")
    assert not lan.usable and "0x9:0x9252:0x1" in lan.reason


def test_a_broken_register_shows_as_a_difference(corpus, library, monkeypatch):
    """Break the emulator on purpose (DL status with a loop bit the hardware does not
    show): the harness reports the reads of 0x0110 as different."""
    name = "ethercrab/soem-sdinfo-ek1100-only.pcapng"
    assert _report(corpus, library, name).counts[DIFFERENT] == 0
    original = EmulatedSlave.set_ports

    def broken(self: EmulatedSlave, links: tuple[bool, bool, bool, bool]) -> None:
        original(self, links)
        self.mem[0x0110] |= 0x08

    monkeypatch.setattr(EmulatedSlave, "set_ports", broken)
    r = _report(corpus, library, name)
    assert r.counts[DIFFERENT] > 0
    assert any(d.field == "0x0110" for d in r.differences), r.differences


def test_the_chip_the_captures_show_decides_working_counters(corpus, library, monkeypatch):
    """Break the ESC model on purpose: every slave the most capable ESC (8 FMMUs, 8 SMs,
    a DC unit), as before runtime/esc_chips.py knew the EL2828's ET1200 without DC.  The
    EtherCrab replay then differs in working counters of FMMU/SM and DC registers."""
    import ecatcfg.runtime.emulate as emulate
    from ecatcfg.runtime.esc_chips import GENERIC
    name = "ethercrab/replay-ek1100-el2828-el2889.pcapng"
    monkeypatch.setattr(emulate, "chip_for", lambda vendor, product: GENERIC)
    r = _report(corpus, library, name)
    wkc = {d.what.split()[2] for d in r.differences if d.field == "wkc"}
    assert {"0x0630", "0x0820"} <= wkc, r.differences[:10]       # FMMU 3, SM 4
    assert any(d.field == "wkc" and "0x0910" in d.what for d in r.differences)
