"""Agreement 2 (issue 39): the emulator against the diagnosis.  Every refusal an emulated
slave makes carries a rule (``runtime/refusals.py``), and the master's diagnosis, which
reads only what the slave holds on the wire, must give the same AL status code, name that
rule and never say "the slave's firmware checks more".  Cases: a fixed sample of corpus ENIs
with and without their ESI files, unchanged and with each fault class the seeded generator
(``diagnosis_agreement.py``) plants; the whole corpus runs in
``bench/diagnosis_agreement.py``.  The example line (its ESIs are ours) runs every fault."""

from __future__ import annotations

import pytest

from conftest import CORPORA, EXAMPLES, corpus_eni
from diagnosis_agreement import faults, run_case

SEED = 39
# A sample that covers ESI devices with a dictionary (Elmo Gold; Beckhoff terminals and a
# coupler without CoE), ENI-only slaves of two exporters and a DC line, small enough for CI.
SAMPLE = ["corpus/rocos-ethercat/eni.xml", "corpus/jn-ec-master/mega_master_eni.xml",
          "corpus-extra/marcelgehrig-ethercattest/01_ENI_1Elmo_1000ms.xml",
          "corpus-extra/pmec-linear-actuator/linear_actuator.xml"]


def _library(request: pytest.FixtureRequest, with_esi: bool):
    if not with_esi:
        return None
    from ecatcfg.esi.library import Library
    folders = [str(request.getfixturevalue(name.replace("-", "_")) / "esi")
               for name in CORPORA]
    return Library(folders, prefer=folders[:1])


def _check(outcomes) -> None:
    bad = [d for o in outcomes for d in o.disagreements]
    assert not bad, "\n".join(bad)


@pytest.fixture(scope="module")
def example_library():
    from ecatcfg.esi.library import Library
    return Library([EXAMPLES / "esi"], cache=False)


def test_every_fault_on_the_example_line_is_diagnosed_with_the_emulators_rule(
        example_plan, example_library):
    outcomes = []
    seen: set[str] = set()
    for fault in faults(example_plan, SEED):
        for library in (example_library, None):
            o = run_case(f"example {fault.name} {fault.slave} "
                         f"{'esi' if library else 'eni-only'}", example_plan, fault.plan,
                         library)
            outcomes.append(o)
            seen.update(rule for _, _, rule in o.refusals)
    _check(outcomes)
    # The generator reaches the rules it is for (with the example's ESIs, which give their
    # objects' flags): a harness whose faults never refuse would agree vacuously.
    assert {"sm-length", "sm-disabled", "sm-start", "sm-control", "no-fmmu", "pdo-missing",
            "entry-not-mappable", "entry-missing", "mailbox-sm"} <= seen, seen


@pytest.mark.parametrize("with_esi", [True, False], ids=["esi", "eni-only"])
@pytest.mark.parametrize("eni", SAMPLE)
def test_corpus_sample_refusals_are_diagnosed_with_the_emulators_rule(request, eni, with_esi):
    from ecatcfg.eni import reader
    path = corpus_eni(request, eni)
    plan = reader.read_file(path)
    library = _library(request, with_esi)
    outcomes = [run_case(f"{eni} unchanged", plan, plan, library)]
    assert not outcomes[0].refusals, outcomes[0]
    for fault in faults(plan, SEED)[:24]:
        outcomes.append(run_case(f"{eni} {fault.name} {fault.slave} ({fault.what})", plan,
                                 fault.plan, library))
    _check(outcomes)
    assert any(o.refusals for o in outcomes[1:])
