"""The virtual segment against wire captures of real slaves (docs/conformance.md).

Every capture of both corpora is replayed by the harness in ``tests/conformance.py``: its
slaves are identified from the capture's own SII reads, the same line is built from the ESI
files of both corpora, the master's frames go through it in memory and every returned
datagram is compared with the hardware's.  The expectations are the hardware's replies in
the captures (ethercrab-rs/ethercrab ``dumps/`` and ``tests/``), never values the emulator
computes.

``RECORDED`` is the table of docs/conformance.md: no usable capture has a difference, and
the other figures may only get better.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from conformance import BY_RULE, DIFFERENT, EQUAL, KNOWN_LIMIT, captures, replay, sii_dumps

from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.slave import EmulatedSlave

EXTRA = "corpus-extra/"          # captures of ../shared/corpus-extra/pcap

# capture -> (usable, compared, equal, by rule, known limit, different)
RECORDED: dict[str, tuple[bool, int, int, int, int, int]] = {
    "ethercrab/replay-dc.pcapng": (True, 2838, 1946, 364, 528, 0),
    "ethercrab/replay-ek1100-alias-address.pcapng": (True, 650, 396, 107, 147, 0),
    "ethercrab/replay-ek1100-el2828-el2889.pcapng": (True, 2062, 1425, 105, 532, 0),
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
    # corpus-extra (its MANIFEST.md): EtherCrab on real Beckhoff lines.
    EXTRA + "ethercrab/replay-issue-255.pcapng": (True, 1684, 1147, 5, 532, 0),
    EXTRA + "ethercrab/rs-example-sii-el2004.pcapng": (True, 127, 96, 0, 31, 0),
    # EK1100 + EL6910 TwinSAFE logic (revision 0x140000, emulated from the ESI of 0x110000)
    # and an EK1914 whose SDO reads of 0x1001 and 0x1008 are answered with abort codes.
    EXTRA + "ethercrab/replay-mailbox-el6910.pcapng": (True, 1690, 1513, 135, 42, 0),
    EXTRA + "ethercrab/replay-sdo-error.pcapng": (True, 278, 252, 1, 25, 0),
    # No ESI for the EL3004 rev 0x150000 (0x2:0xbbc3052) nor the Kollmorgen AKD in either
    # corpus (test_slaves_without_an_esi_are_named).
    EXTRA + "ethercrab/replay-ek1914-el3004-configure.pcapng": (False, 0, 0, 0, 0, 0),
    EXTRA + "ethercrab/replay-ek1914-no-complete-access.pcapng": (False, 0, 0, 0, 0, 0),
    EXTRA + "ethercrab/replay-ek1914-segmented-upload.pcapng": (False, 0, 0, 0, 0, 0),
    EXTRA + "ethercrab/soem-sdinfo-akd.pcapng": (False, 0, 0, 0, 0, 0),
}


# Why a capture is not replayed, named: a slave no ESI of either corpus describes at any
# revision (its SII and object dictionary are known only from the device itself: the
# EL3004 0x0bbc3052 beside the EK1914, the Kollmorgen AKD, Microchip's LAN9252 running
# SOES), or a master that never reads the slaves' identity from their SII.
NO_ESI_EL3004 = "slave 1: no ESI for 0x2:0xbbc3052:0x150000"
NO_ESI_AKD = "slave 0: no ESI for 0x6a:0x414b44:0x2"
NO_ESI_LAN9252 = "slave 0: no ESI for 0x9:0x9252:0x1"
NOT_IDENTIFIED = "slave 0: vendor, product and revision not read from its SII"
NOT_REPLAYED: dict[str, str] = {
    "ethercrab/rs-detect-slaves-ek1100-el1004.pcapng": NOT_IDENTIFIED,
    "ethercrab/rs-detect-slaves-ek1100-only.pcapng": NOT_IDENTIFIED,
    "ethercrab/soem-dual-lan9252.pcapng": NO_ESI_LAN9252,
    "ethercrab/soem-single-lan9252.pcapng": NO_ESI_LAN9252,
    "ethercrab/twincat-scan-devices-2.pcapng": NOT_IDENTIFIED,
    "twincat-akd-nc-mode.pcapng": NO_ESI_AKD,
    "twincat-run-ek1100-el1004.pcapng": NOT_IDENTIFIED,
    "twincat-scan-devices.pcapng": "no master frame with its returned frame",
    EXTRA + "ethercrab/replay-ek1914-el3004-configure.pcapng": NO_ESI_EL3004,
    EXTRA + "ethercrab/replay-ek1914-no-complete-access.pcapng": NO_ESI_EL3004,
    EXTRA + "ethercrab/replay-ek1914-segmented-upload.pcapng": NO_ESI_EL3004,
    EXTRA + "ethercrab/soem-sdinfo-akd.pcapng": NO_ESI_AKD,
}


@pytest.fixture(scope="module")
def library(corpus: Path, corpus_extra: Path) -> Library:
    return Library([corpus / "esi", corpus_extra / "esi"], cache=False)


@pytest.fixture(scope="module")
def dumps(corpus: Path) -> dict[str, bytes]:
    return sii_dumps(corpus / "sii")


def _report(corpus: Path, library: Library, name: str, dumps: dict[str, bytes] | None = None):
    """``corpus``: the corpus, or the extra corpus for a name starting with EXTRA."""
    return replay(corpus / "pcap" / name.removeprefix(EXTRA), library, name, dumps)


def test_every_capture_is_listed(corpus, corpus_extra):
    names = {str(p.relative_to(corpus / "pcap")) for p in captures(corpus)}
    names |= {EXTRA + str(p.relative_to(corpus_extra / "pcap")) for p in captures(corpus_extra)}
    assert names == set(RECORDED)


@pytest.mark.parametrize("name", sorted(RECORDED))
def test_capture_conforms_no_worse_than_recorded(request, library, dumps, name):
    """Every capture: its figures, or (not usable) the reason named in NOT_REPLAYED."""
    usable, compared, equal, by_rule, limit, different = RECORDED[name]
    assert usable == (name not in NOT_REPLAYED)
    corpus = request.getfixturevalue("corpus_extra" if name.startswith(EXTRA) else "corpus")
    r = _report(corpus, library, name, dumps)
    assert r.usable == usable, r.reason
    assert usable or r.reason.startswith(NOT_REPLAYED[name]), r.reason
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
    a DC unit), as before runtime/segment/esc_chips.py knew the EL2828's ET1200 without DC.  The
    EtherCrab replay then differs in working counters of FMMU/SM and DC registers."""
    import ecatcfg.runtime.segment.emulate as emulate
    from ecatcfg.runtime.segment.esc_chips import GENERIC
    name = "ethercrab/replay-ek1100-el2828-el2889.pcapng"
    monkeypatch.setattr(emulate, "chip_for", lambda vendor, product: GENERIC)
    r = _report(corpus, library, name)
    wkc = {d.what.split()[2] for d in r.differences if d.field == "wkc"}
    assert {"0x0630", "0x0820"} <= wkc, r.differences[:10]       # FMMU 3, SM 4
    assert any(d.field == "wkc" and "0x0910" in d.what for d in r.differences)


def test_a_revision_the_master_does_not_read_comes_from_an_agreeing_sii_dump(
        corpus_extra, library, dumps):
    """EtherCrab in 2022 read SII words 0x08-0x0B (vendor, product) and the EL2004's
    category area, never the revision.  The corpus dump el2004-eeprom-dump.bin (same
    repository and commit as the capture) holds every one of the 102 words read of the
    first EL2004: its revision 0x100000 is taken; the EK1100's 4 words agree with
    ek1100.hex (0x120000) only.  Without the dumps the capture is not usable, and says why."""
    name = EXTRA + "ethercrab/rs-example-sii-el2004.pcapng"
    r = _report(corpus_extra, library, name, dumps)
    assert r.slaves == [
        "EK1100 (0x2:0x44c2c52:0x120000, revision not read: SII dump ek1100.hex holds the 4 "
        "words read)",
        "EL2004 (0x2:0x7d43052:0x100000, revision not read: SII dump el2004-eeprom-dump.bin "
        "holds the 102 words read)",
        "EL2004 (0x2:0x7d43052:0x100000, revision not read: SII dump el2004-eeprom-dump.bin "
        "holds the 4 words read)"]
    bare = _report(corpus_extra, library, name)
    assert not bare.usable
    assert bare.reason.startswith("slave 0: vendor, product and revision not read")


def test_slaves_without_an_esi_are_named(corpus_extra, library, dumps):
    """The EK1914 captures' EL3004 (rev 0x150000) and the AKD: no ESI in either corpus."""
    for name, missing in (("ethercrab/replay-ek1914-el3004-configure.pcapng",
                           "slave 1: no ESI for 0x2:0xbbc3052:0x150000"),
                          ("ethercrab/soem-sdinfo-akd.pcapng",
                           "slave 0: no ESI for 0x6a:0x414b44:0x2")):
        r = _report(corpus_extra, library, EXTRA + name, dumps)
        assert not r.usable and r.reason == missing + " in the corpus", r.reason


def test_the_el2004s_three_fmmus_decide_a_working_counter(corpus_extra, library, dumps,
                                                          monkeypatch):
    """Break the ESC model on purpose: the EL2004 the most capable ESC again.  The BWR
    clearing FMMU 3 then counts on all three slaves; the hardware counted only the EK1100."""
    import ecatcfg.runtime.segment.emulate as emulate
    from ecatcfg.runtime.segment.esc_chips import GENERIC, chip_for
    name = EXTRA + "ethercrab/rs-example-sii-el2004.pcapng"
    monkeypatch.setattr(emulate, "chip_for", lambda vendor, product: GENERIC
                        if (vendor, product) == (0x2, 0x07D43052) else chip_for(vendor, product))
    r = _report(corpus_extra, library, name, dumps)
    assert [(d.what, d.field, d.expected, d.got) for d in r.differences] == [
        ("BWR 0x0000 0x0630", "wkc", "1", "3")]


def test_what_the_el6910_and_the_sdo_aborts_leave_to_named_limits(corpus_extra, library, dumps):
    """The EL6910 (revision 0x140000; the corpus has the ESI of 0x110000) and the EK1914
    whose reads of 0x1001 and 0x1008 are aborted: every datagram is equal, by rule or one
    of these limits.  The real mailbox buffer keeps what the firmware wrote before past
    the message's length (the EK1914's diagnosis texts, the EL6910's uninitialised RAM);
    the EL6910's firmware answers 0x100A "04 (V01.11)" and five spaces where its ESI
    types a STRING(11) with no value; the EK1914 twice clears the read event of SM1 with
    no request pending."""
    el6910 = _report(corpus_extra, library, EXTRA + "ethercrab/replay-mailbox-el6910.pcapng",
                     dumps)
    assert el6910.slaves[1] == "EL6910 (0x2:0x1afe3052:0x140000, ESI of revision 0x110000)"
    version = "version string 0x1009/0x100A: the firmware's own, its ESI gives none"
    past = "mailbox-in bytes past the message (earlier contents)"
    assert el6910.limits == {"SII category area layout (word 0x40 on)": 32, past: 10,
                             version: 1}
    aborts = _report(corpus_extra, library, EXTRA + "ethercrab/replay-sdo-error.pcapng", dumps)
    assert aborts.limits == {
        "SII category area layout (word 0x40 on)": 16, past: 7,
        "mailbox-in read event (SM status bit 1) cleared by the firmware with no request": 2}


def test_the_el6910_starts_its_replies_when_the_real_one_does(corpus_extra, library, dumps,
                                                               monkeypatch):
    """The EL6910's firmware writes the first byte of a reply about 1.16 ms after the
    request (SM1's read event clears), its last about 0.6 ms later: emulated so, 8 polls
    of SM1's status fall between the two clocks (the reply-start rule).  Break it on
    purpose, the read event held until the reply is there: over a hundred polls more."""
    from ecatcfg.runtime.segment import timing
    name = EXTRA + "ethercrab/replay-mailbox-el6910.pcapng"
    rule = "the firmware starts writing its reply at a varying time"
    assert _report(corpus_extra, library, name, dumps).rules[rule] == 8
    monkeypatch.setattr(timing, "DEVICES", {timing.EL6910: replace(
        timing.DEVICES[timing.EL6910], reply_start_ns=None)})
    assert _report(corpus_extra, library, name, dumps).rules[rule] > 100


def test_the_el6910_takes_its_own_time(corpus_extra, library, dumps, monkeypatch):
    """Without its measured figures (runtime/segment/timing.py DEVICES) the EL6910 takes
    the firmware kind's: in PREOP after 1.335 ms where the real one is still in INIT
    (1.51-1.60 ms), so the AL status reads differ."""
    from ecatcfg.runtime.segment import timing
    name = EXTRA + "ethercrab/replay-mailbox-el6910.pcapng"
    monkeypatch.setattr(timing, "DEVICES", {})
    r = _report(corpus_extra, library, name, dumps)
    assert {d.field for d in r.differences} == {"0x0130"}, r.differences[:5]


def test_a_mailbox_reply_there_on_one_side_only_is_the_reply_times_rule(
        corpus_extra, library, dumps, monkeypatch):
    """The EL6910's replies take 1.65-2.07 ms, the emulated one 1.763 ms: at a few polls
    of SM1's status one is there and the other not yet.  Only within 2.1 ms of the
    request: without that time (the rule off) exactly those polls differ, in 0x080D."""
    import conformance
    name = EXTRA + "ethercrab/replay-mailbox-el6910.pcapng"
    r = _report(corpus_extra, library, name, dumps)
    polls = r.rules["mailbox reply time varies"]
    assert polls > 0
    monkeypatch.setattr(conformance, "REPLY_VARIES_NS", 0)
    r = _report(corpus_extra, library, name, dumps)
    assert {(d.what, d.field) for d in r.differences} == {("FPRD 0x1001 0x080D", "0x080D")}
    assert len(r.differences) == polls


def test_an_sdo_download_answer_echoes_the_data_as_the_hardware_does(corpus_extra, library,
                                                                      dumps, monkeypatch):
    """The EL6910 answers the download of 0xF008 (code word 1) with the 4 data bytes of
    the request in the reserved bytes of the response; an emulated answer with zeros
    there differs (runtime/segment/sdo_server.py)."""
    from ecatcfg.runtime.segment import sdo_server
    name = EXTRA + "ethercrab/replay-mailbox-el6910.pcapng"
    assert _report(corpus_extra, library, name, dumps).counts[DIFFERENT] == 0
    monkeypatch.setattr(sdo_server, "echo_request_data", lambda response, request: response)
    r = _report(corpus_extra, library, name, dumps)
    assert [(d.what, d.field, d.expected, d.got) for d in r.differences] == [
        ("FPRD 0x1001 0x1100", "0x110C", "01", "00")]
