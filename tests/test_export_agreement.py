"""The pysoem export against SOEM itself on a fixed sample of the corpus ENIs
(``export_agreement.py`` says how); ``bench/export_agreement.py`` runs every corpus ENI
(figures in docs/BENCHMARKS.md).

The sample: an ENI of the corpora with slaves of fewer than 8 bits (LUPA: two 2-bit
input terminals after byte-oriented ones; the two others, FOSWEC2 and Pendulum2, hold a
slave the ENI-only emulation keeps in PREOP, so that SOEM waits for OP in vain: the bench
runs them), and lines of other shapes: drives with DC (hydra), Beckhoff I/O with an
EtherCAT Training set (acontis), an EC-Engineer line of 6 drives (rocos tech6), a TwinCAT
mixed line (altinay), a line whose inputs and outputs are of odd sizes (FOSTWIN), a line
of Beckhoff terminals with an EL2008 (jn-ec-master).  About 20 s here, under load; the small-terminal
packing within a byte is tests/test_export_soem_layout.py's line.
"""

from __future__ import annotations

import pytest
from conftest import corpus_eni
from export_agreement import agree_in_ci

SAMPLE = [
    "corpus-extra/pmec-lupa/LUPA1kHz_DC.xml",
    "corpus-extra/hydra/hydra20150421.xml",
    "corpus/acontis-doc/acontis-TrainingSlaves-ENI.xml",
    "corpus/rocos-ethercat/eni_tech6.xml",
    "corpus-extra/altinay-moobot/ENI.xml",
    "corpus-extra/pmec-fostwin/FOSTWIN-Primary1.xml",
    "corpus/jn-ec-master/mega_master_eni.xml",
]


@pytest.mark.parametrize("eni", SAMPLE)
def test_the_exported_table_is_soem_s_and_reads_back_by_name(request, veth_netns,
                                                             pysoem_module, tmp_path, eni):
    result = agree_in_ci(veth_netns, corpus_eni(request, eni), tmp_path)
    assert result.outcome in ("agree", "partial"), \
        "\n".join([result.outcome, result.detail, *result.disagreements[:40]])
    assert not result.disagreements
    assert result.places == result.variables > 0
    assert result.bits_read > 0 and result.bits_written > 0
