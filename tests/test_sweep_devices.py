"""Every device on its own emulation, a fixed sample of it (``bench/sweep_devices.py`` runs
every device of both corpora with the same code, ``tests/sweep.py``), and the fixes the
sweep led to, each on a self-written ESI of the same shape.

The references are not ecatcfg's own: the ETG.2100 schema judges each ENI, the virtual
segment emulates the device from its ESI (not from the ENI), and a device that does not
reach OP must be one ``ecatcfg lint`` reports an error for.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from conftest import MAILBOX_PD_SMS, device_xml, esi_xml, write

import sweep

from ecatcfg.compiler import build, topology
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import AL_ERROR_ACK, AlState, Reg
from ecatcfg.esi.library import Library
from ecatcfg.runtime.network import Network

# Every 47th device of both corpora sorted by key, and every 8th modular one (slots): about
# 40 devices from simple I/O terminals to drives, CoE, DC and modular devices, passive
# terminals and devices whose refusal lint explains.
EVERY, EVERY_MODULAR = 47, 8


@pytest.fixture(scope="module")
def corpora(corpus: Path, corpus_extra: Path) -> dict[str, Path]:
    return {"corpus": corpus, "corpus-extra": corpus_extra}


@pytest.fixture(scope="module")
def sample(corpora: dict[str, Path]) -> list[sweep.Case]:
    every = sweep.cases(corpora)
    chosen = sweep.sample(every, EVERY)
    chosen += [c for c in sweep.sample([c for c in every if c.slots], EVERY_MODULAR)
               if c not in chosen]
    return chosen


def test_the_sample_covers_the_device_classes(sample: list[sweep.Case]) -> None:
    assert 35 <= len(sample) <= 50
    assert {c.corpus for c in sample} == {"corpus", "corpus-extra"}
    assert sum(c.has_coe for c in sample) >= 10
    assert sum(not c.has_coe for c in sample) >= 10
    assert sum(c.has_dc for c in sample) >= 5
    assert sum(c.slots for c in sample) >= 5


def test_every_sample_device_reaches_op_or_lint_explains_why_not(
        corpora: dict[str, Path], sample: list[sweep.Case]) -> None:
    errors = sweep.lint_errors(corpora, {(c.corpus, c.file) for c in sample})
    worker = sweep.Worker(corpora)
    results = []
    for case in sample:
        r = worker.run(case)
        r.lint_errors = sweep.errors_for(case, errors)
        results.append(r)
    bad = [f"{r.key} ({r.type}): {r.outcome}: {r.message}" for r in results
           if r.outcome in ("schema-invalid", "not-emulated", "crash") or not r.explained]
    assert not bad, "\n".join(bad)
    # Most of them work; a sample that only fails with reasons would test nothing.
    assert sum(r.outcome == "op" for r in results) >= len(results) * 3 // 4


# -- device emulation with a mailbox --------------------------------------------------------

# A CoE device whose ESC mirrors AL control into AL status (ConfigData byte 1 = ESC
# configuration 0x0141, bit 0 device emulation; PDI 0x80 below it): the shape of the
# research-board ESIs of the extra corpus (march, pollen) with a microcontroller on SPI.
EMULATING_COE = device_xml(
    "FXE1", "#x21", "#x1",
    body=MAILBOX_PD_SMS + '<Mailbox><CoE SdoInfo="1"/></Mailbox>'
         "<Eeprom><ByteSize>2048</ByteSize><ConfigData>8001000000000000</ConfigData></Eeprom>")


def _compile(esi: Path, device: str) -> bytes:
    text = f'{{"master": {{"name": "m"}}, "slaves": [{{"name": "s", "device": "{device}"}}]}}'
    result = build.compile_topology(topology.loads(text, "t.json"), Library([esi], cache=False))
    return eni_writer.to_bytes(result.plan)


def test_a_mailbox_device_in_device_emulation_gets_no_error_acknowledge(tmp_path: Path) -> None:
    """The ESC copies AL control into AL status as written (ESC doc Section II, 0x0120 and
    0x0141): the acknowledge bit TwinCAT writes to slaves with a mailbox would read back as
    the error flag, and the state check (mask 0x1F) would fail with AL status code 0."""
    from lxml import etree
    esi = write(tmp_path, "fxe.xml", esi_xml(EMULATING_COE))
    eni = etree.fromstring(_compile(esi, "FXE1"))
    writes = [bytes.fromhex(c.findtext("Data") or "") for c in eni.iter("InitCmd")
              if c.findtext("Ado") == str(int(Reg.AL_CONTROL))]
    assert writes and all(struct.unpack("<H", w)[0] & AL_ERROR_ACK == 0 for w in writes)
    plain = write(tmp_path, "fx.xml", esi_xml(EMULATING_COE.replace(
        "<ConfigData>8001", "<ConfigData>8000")))
    eni = etree.fromstring(_compile(plain, "FXE1"))
    assert any(struct.unpack("<H", bytes.fromhex(c.findtext("Data") or "0000"))[0]
               & AL_ERROR_ACK for c in eni.iter("InitCmd")
               if c.findtext("Ado") == str(int(Reg.AL_CONTROL)))


def test_a_mailbox_device_in_device_emulation_reaches_op(tmp_path: Path) -> None:
    esi = write(tmp_path, "fxe.xml", esi_xml(EMULATING_COE))
    eni = write(tmp_path, "fxe-eni.xml", _compile(esi, "FXE1"))
    with Network.virtual(eni, [esi], esi_cache=False) as net:
        assert net.segment is not None and net.segment.slaves[0].device_emulation
        net.up(AlState.OP)
        assert [s.state for s in net.master.read_states() if s] == [AlState.OP]


# -- a PDO without an Index ------------------------------------------------------------------

def test_a_pdo_without_an_index_is_an_error_naming_its_esi_line(tmp_path: Path) -> None:
    """The Ref/Chn PDOs of old Beckhoff files (EL3142 in the extra corpus): compiled as PDO
    0x0000 with no entries, the device's inputs were lost and apply failed at 0x1C13:02."""
    from ecatcfg.compiler.topology import TopologyError
    body = MAILBOX_PD_SMS.replace(
        '<TxPdo Fixed="1" Mandatory="1" Sm="3"><Index>#x1A00</Index>',
        '<TxPdo Fixed="1" Mandatory="1" Sm="3">') + '<Mailbox><CoE PdoAssign="1"/></Mailbox>'
    assert body != MAILBOX_PD_SMS + '<Mailbox><CoE PdoAssign="1"/></Mailbox>'
    text = esi_xml(device_xml("FXR", "#x22", "#x1", body=body))
    esi = write(tmp_path, "fxr.xml", text)
    line = text[:text.index("<TxPdo")].count("\n") + 1
    with pytest.raises(TopologyError) as exc:
        _compile(esi, "FXR")
    assert f"TxPdo at {esi}:{line} has no Index" in str(exc.value)


def test_a_refusal_for_an_esi_error_is_explained_only_by_that_rule() -> None:
    # compile's gate and lint must agree: a refusal naming ESI101 is not explained by an
    # unrelated lint error of the device.
    message = ("sweep(x).yaml:1: slave 'dut': /c/esi/a.xml:361: ESI101 RxPdo 0x1A00 is "
               "outside 0x1600-0x17FF (an ESI error that changes what compile writes; ...)")
    refused = sweep.Result("k", "T", "0x2:0x1", "refused", message)
    refused.lint_errors = ["XSD001 element not expected"]
    assert not refused.explained
    refused.lint_errors.append("ESI101 RxPdo 0x1A00 is outside 0x1600-0x17FF")
    assert refused.explained
