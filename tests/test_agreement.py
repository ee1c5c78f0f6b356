"""The check/apply agreement on a fixed sample: ``check`` reports an error if and only if
``apply --virtual`` of the same file fails, with the ESI files and from the ENI alone, on
real ENIs unmodified and with each fault class of ``faults.py`` planted by its seeded
generator; every planted fault check must report is an error at the line of the element
the generator changed (found again in the written file by lxml, not by the code under
test).  The independent side is the emulated line: slaves built from their vendors' ESI
files (or from the ENI alone) that refuse what a slave's firmware refuses.

A disagreement is allowed only where the fault class says no slave can see it (data in
the wrong bits of the master's image: ``Fault.slave_refuses``) or where it is one of the
documented limits (``agreement.LIMITS``, docs/show-diff-check.md).  The whole matrix, all
ENIs and more seeds, is ``bench/agreement.py`` (figures in docs/BENCHMARKS.md).
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from agreement import LIMITS, Outcome, run_matrix
from compiled_lines import compile_line, line
from conftest import compile_example
from faults import FAULTS, plant

from ecatcfg.esi.library import Library

# Real ENIs of set-ups the corpus has ESI files for, and one each without: an Elmo drive
# (entry-by-entry CoE PDO downloads, DC), Beckhoff terminals behind an EK1100 (devices
# without firmware), the acontis training slaves (CompleteAccess downloads, no ESI), an
# Elmo ENI whose ProcessData has no Sm elements.
SAMPLE = ["corpus/eni/rocos-ethercat/eni.xml", "corpus/eni/jn-ec-master/mega_master_eni.xml",
          "corpus/eni/acontis-doc/acontis-TrainingSlaves-ENI.xml",
          "corpus/eni/rocos-ethercat/eni1.xml"]
SEED = 39
# Lines of corpus devices as compile writes them (compiled_lines.py draws such lines by
# seed for the bench; these two are fixed): drives of four vendors with CoE PDO
# downloads, one with DC (Mitsubishi MR-J4-TM, Elmo, Synapticon SOMANET, an open-source
# EaserCAT); a coupler with DC before an EtherCAT P coupler, digital inputs and a
# junction (Inovance GL20, Beckhoff EK1200, EJ2918, EK1322).
LINES = {
    "drives": [("0xa1e:0x201:0x20002", None), ("0x9a:0x30924:0x1", "DC Sync"),
               ("0x22d2:0x201:0xa000002", None), ("0xaaa:0xbbbccc:0x2", None)],
    "coupler and terminals": [("0x100000:0x10f41001:0x1006000", "Synchron"),
                              ("0x2:0x4b02c52:0x1388", None), ("0x2:0xb662852:0x110000", None),
                              ("0x2:0x52a2c52:0x110000", None)],
}


@pytest.fixture(scope="module")
def library(corpus: Path, corpus_extra: Path, tmp_path_factory: pytest.TempPathFactory
            ) -> Library:
    from ecatcfg.esi.cache import IndexCache
    home = tmp_path_factory.mktemp("esi-index")
    return Library([corpus / "esi", corpus_extra / "esi", Path(__file__).parent.parent
                    / "examples" / "esi"], cache=IndexCache(home / "ecatcfg"),
                   prefer=[corpus / "esi" / "drives"])


def _enis(corpus: Path, tmp_path: Path, library: Library) -> dict[str, bytes]:
    enis = {name: (corpus.parent / name).read_bytes() for name in SAMPLE}
    enis["examples (compiled)"] = compile_example(tmp_path / "line.xml").read_bytes()
    for name, devices in LINES.items():
        enis[f"compiled line: {name}"] = compile_line(library, [
            {"name": f"slave{n}", "device": device, **({"dc": dc} if dc else {})}
            for n, (device, dc) in enumerate(devices, start=1)])
    return enis


def test_check_errs_exactly_where_apply_fails(corpus: Path, tmp_path: Path,
                                              library: Library) -> None:
    started = time.perf_counter()
    outcomes = run_matrix(_enis(corpus, tmp_path, library), [None, *FAULTS], [SEED],
                          {False: None, True: library})
    bad = [o.describe() for o in outcomes if not o.explained]
    assert not bad, "\n".join(bad)
    # Every fault class was planted somewhere in the sample, and every one a slave
    # refuses made apply fail somewhere (the emulation is not blind to it).
    planted = {o.fault for o in outcomes if o.fault is not None}
    assert planted == set(FAULTS), set(FAULTS) - planted
    refused = {o.fault for o in outcomes if o.fault is not None and o.apply_says}
    for name, fault in FAULTS.items():
        if fault.slave_refuses is True:
            assert name in refused, name
    # The unmodified files agree without any limit.
    assert all(o.agree for o in outcomes if o.fault is None)
    print(f"{len(outcomes)} cases in {time.perf_counter() - started:.1f} s")


def test_a_planted_fault_is_found_again_at_its_line(corpus: Path) -> None:
    """The generator's own promise, checked with plain XPath: the same seed plants the same
    fault, and the element it names holds the change."""
    data = (corpus / "eni" / "rocos-ethercat" / "eni.xml").read_bytes()
    first, again = plant(data, "assign-short", SEED), plant(data, "assign-short", SEED)
    assert first is not None and again is not None and first[0] == again[0]
    from lxml import etree
    changed, where = first
    [cmd] = etree.fromstring(changed).getroottree().xpath(where.path)
    [before] = etree.fromstring(data).getroottree().xpath(where.path)
    assert int(cmd.findtext("Data"), 16) == int(before.findtext("Data"), 16) - 1
    assert cmd.findtext("Index") in ("7186", "7187")      # 0x1C12 / 0x1C13


def test_every_limit_is_documented() -> None:
    docs = (Path(__file__).parent.parent / "docs" / "show-diff-check.md").read_text()
    for name in LIMITS:
        assert f"`{name}`" in docs, name
    for name in FAULTS:
        assert f"`{name}`" in docs, name


def test_an_outcome_is_judged_by_its_class() -> None:
    """The verdict itself: a check error on a fault no slave sees is allowed only for the
    classes that say so; a slave that refuses while check is clean is never allowed."""
    quiet = Outcome("x.xml", "fmmu-overlap", 1, True, ["5: ENI109 m"], [], [], None,
                    frozenset({5}))
    assert quiet.agree and quiet.explained
    missed = Outcome("x.xml", "assign-short", 1, True, [], [], [], "0x001D",
                     frozenset({5}))
    assert not missed.agree and not missed.explained
    elsewhere = Outcome("x.xml", "assign-short", 1, True, ["7: ENI205 m"], [], [], "0x001D",
                        frozenset({5}))
    assert elsewhere.agree and not elsewhere.explained
    # A watchdog check errs on that the emulated slave kept to is a disagreement: apply
    # judges a slave that left OP after the cycles (cli/apply.py, Master.check_kept).
    kept = Outcome("x.xml", "watchdog", 1, False, ["5: ENI121 m"], [], [], None,
                   frozenset({5}))
    assert not kept.agree and kept.limit is None and not kept.explained


def test_a_refusal_read_without_its_code_is_not_called_no_error() -> None:
    """The apply side of the matrix found it: an ENI whose state check reads AL status
    0x0130 alone (2 bytes; rocos-ethercat eni1.xml) made a refusal read "AL status code
    0x0000 (no error)".  The code register (0x0134) was not read: nothing is guessed."""
    from ecatcfg.runtime.master.replay import _refused
    short = _refused(bytes([0x12, 0x00]), "drive", "check device state for SAFEOP")
    assert "0x0000" not in str(short) and "does not read the AL status code" in str(short)
    assert short.al_code is None
    full = _refused(bytes([0x12, 0, 0, 0, 0x35, 0]), "drive", "check device state for SAFEOP")
    assert "AL status code 0x0035" in str(full) and full.al_code == 0x35


def test_a_compiled_line_is_drawn_again_by_its_seed(corpus: Path, corpus_extra: Path,
                                                    library: Library, eni_schema) -> None:
    """The generator of compiled lines (the bench's cases): the same seed draws the same
    devices, the line is the ENI compile writes for them (valid against ETG.2100's schema),
    and its slaves are the devices drawn, read back with plain lxml."""
    from lxml import etree

    from compiled_lines import candidates
    pool = candidates(library, tuple(str((root / "esi").resolve())
                                     for root in (corpus, corpus_extra)))
    assert {str(Path(e.file).resolve()).split("/esi/")[0] for e in pool} == {
        str(corpus.resolve()), str(corpus_extra.resolve())}
    first, again = line(library, pool, 3), line(library, pool, 3)
    assert first is not None and again is not None
    assert first.devices == again.devices and first.eni == again.eni
    assert 2 <= len(first.devices) <= 4
    doc = etree.fromstring(first.eni)
    assert eni_schema.validate(doc.getroottree()), eni_schema.error_log
    got = [":".join(hex(int(s.findtext(f"Info/{t}"))) for t in ("VendorId", "ProductCode",
                                                                  "RevisionNo"))
           for s in doc.iterfind("Config/Slave")]
    assert got == list(first.devices)
