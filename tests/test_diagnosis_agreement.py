"""The emulator against the diagnosis.  Every refusal an emulated
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
          "corpus/rocos-ethercat/eni1.xml",
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


# -- the cases a user met --------------------------------------------------------------------

def _elmo_with_digital_outputs(corpus):
    """The rocos Elmo ENI as a configurator re-exports it with the drive's digital outputs
    added to its mapping: the configurable RxPDO 0x1607 gets 0x60FE:01 (digital outputs,
    PdoMapping R in the vendor's ESI) and 0x60FE:02 (the outputs' bit mask, Flags without
    PdoMapping), and 0x1C12 assigns it in place of 0x161C."""
    from ecatcfg.eni import reader
    from ecatcfg.eni.plan import CoeInitCmd
    from ecatcfg.esc import Transition
    plan = reader.read_file(corpus / "eni" / "rocos-ethercat" / "eni.xml")
    slave = plan.slaves[0]
    assert slave.mailbox is not None
    cmds = slave.mailbox.coe_init_cmds
    last = max(k for k, c in enumerate(cmds) if c.index == 0x1C12)
    for c in cmds:
        if c.index == 0x1C12 and c.subindex == 5:
            c.data = (0x1607).to_bytes(2, "little")
    added = [CoeInitCmd([Transition.PS], "digital outputs", 0x1607, sub, data)
             for sub, data in ((1, bytes.fromhex("2001fe60")), (2, bytes.fromhex("2002fe60")),
                               (0, b"\x02"))]
    cmds[last:last] = added
    return plan


@pytest.mark.parametrize("master_esi", [True, False], ids=["esi", "sdo-info"])
def test_elmo_with_a_non_mappable_digital_output_entry_names_the_entry(corpus, master_esi):
    from ecatcfg.eni import reader
    from ecatcfg.esi.library import Library
    original = reader.read_file(corpus / "eni" / "rocos-ethercat" / "eni.xml")
    library = Library([corpus / "esi" / "drives"], cache=False)
    # Without ESI files the master reads the same rule from the slave's SDO Information
    # (the entry's access word has no RxPDO bit, ETG.1000.6 Get Entry Description).
    outcome = run_case("elmo + digital outputs", original, _elmo_with_digital_outputs(corpus),
                       library, master_esi=master_esi)
    assert outcome.refusals == [("Slave_1001 [Elmo Drive ]", 0x001D, "entry-not-mappable")]
    assert not outcome.disagreements, outcome.disagreements


def test_a_pdo_takes_its_direction_from_its_sm_not_its_index_range(corpus_extra):
    """The FB1111 SPI-Slave's ESI lists RxPdo 0x1A00 on SM2 (outputs) and TxPdo 0x1600 on
    SM3: a TwinCAT export maps the user's variables into them.  The emulated firmware takes
    a PDO's direction from the SM it is assigned to (0x1C00), so the output variables of
    0x1A00 count for SM2; it used to take "T" from the index and refuse (0x001D) what its
    diagnosis then called consistent."""
    from dataclasses import replace

    from ecatcfg.esi.library import Library
    from ecatcfg.esi.model import PdoEntry
    from ecatcfg.runtime.segment.objects import ObjectDictionary
    library = Library([corpus_extra / "esi" / "dls" / "Beckhoff FB1XXX.xml"], cache=False)
    device = library.device(library.find("0x2:0x04570862:0x0258008D").entry)
    [rx] = device.rx_pdos
    [tx] = device.tx_pdos
    assert (rx.index, rx.sm, tx.index, tx.sm) == (0x1A00, 2, 0x1600, 3)
    variables = {"rx": [PdoEntry(0x7000, 1, 16, "UINT", {1033: "Out"}, rx.source)],
                 "tx": [PdoEntry(0x6000, 1, 8, "USINT", {1033: "In"}, tx.source)]}
    device = replace(device, rx_pdos=[replace(rx, entries=variables["rx"])],
                     tx_pdos=[replace(tx, entries=variables["tx"])])
    od = ObjectDictionary.from_device(device)
    assert od.assignment(2) == ([(0x7000, 1, 16)], None)
    assert od.assignment(3) == ([(0x6000, 1, 8)], None)


def test_an_eeprom_the_pdi_holds_is_read_and_given_back(example_plan, example_library):
    """An ENI that assigns the EEPROM to the PDI (0x0500 = 1, as the hydra ENIs do): the
    diagnosis takes it for its SII reads and gives it back (SOEM ecx_eeprom2master /
    ecx_eeprom2pdi), so an SM moved from where the SII puts it is still named."""
    import copy

    from ecatcfg.eni.plan import InitCmd
    from ecatcfg.esc import Cmd, Reg, Transition
    fault = next(f for f in faults(example_plan, SEED)
                 if f.name == "sm-start" and f.slave == "axis1")
    plan = copy.deepcopy(fault.plan)
    axis = plan.slave("axis1")
    axis.init_cmds.insert(0, InitCmd([Transition.PS], "EEPROM to PDI", int(Cmd.FPWR), 1,
                                     adp=axis.phys_addr, ado=Reg.EEPROM_CONFIG, data=b"\x01"))
    outcome = run_case("sm-start, EEPROM at the PDI", example_plan, plan, example_library)
    assert [r for _, _, r in outcome.refusals] == ["sm-start"]
    assert not outcome.disagreements, outcome.disagreements
    assert outcome.eeprom_config["axis1"] == 0x01
