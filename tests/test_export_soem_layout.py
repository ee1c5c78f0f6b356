"""The pysoem export places small terminals' bits where SOEM packs them.

A line of Beckhoff terminals from the corpus ESIs: 2-, 4- and 4-bit inputs (the third runs
from bit 6 of one byte into the next), 4-, 2- and 4-bit outputs (likewise), and a 16-bit
input terminal that starts on the next whole byte.  SOEM packs slaves with fewer than 8
bits into shared bytes (``Istartbit``/``Ostartbit``); the ENI we compile places the same
slaves elsewhere in its own image.  pysoem with the exported module configures the
emulated line over veth (the slaves as ``simulate --eni --esi`` builds them), and
``tests/export_agreement.py`` compares every variable of the module's table with the FMMUs
SOEM programmed, and every input and output bit, set or written in the emulated slaves,
read back by name.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from ecatcfg.esi.library import Library
from export_agreement import agree_in_ci

SMALL_LINE = """
master: {name: small, cycle_time_us: 1000}
slaves:
  - {name: coupler, device: "0x2:0x44c2c52:0x120000"}    # EK1100
  - {name: two, device: EL1002}
  - {name: sensors, device: EL1004}
  - {name: more, device: EL1004}
  - {name: out4, device: EL2004}
  - {name: out2, device: EL2002}
  - {name: out4b, device: EL2004}
  - {name: wide, device: EL1809}
"""


@pytest.fixture(scope="module")
def beckhoff(corpus: Path) -> Path:
    return corpus / "esi" / "beckhoff"


@pytest.fixture(scope="module")
def small_eni(beckhoff: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("small")
    topo = folder / "small.yaml"
    topo.write_text(SMALL_LINE)
    eni = folder / "small.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(beckhoff), "-o", str(eni), "--no-cache"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return eni


def test_small_terminals_read_and_write_where_soem_packs_them(veth_netns, pysoem_module,
                                                              beckhoff, small_eni,
                                                              tmp_path):
    result = agree_in_ci(veth_netns, small_eni, tmp_path, Library([beckhoff], cache=False))
    assert result.outcome == "agree", "\n".join([result.detail, *result.disagreements])
    # Every input bit of the three small input terminals but the two of `more` that lie in
    # a byte pysoem gives to no slave (bits 0-1 of IOmap byte 3; `wide` starts at byte 4),
    # the 16 of `wide` (4 of them, sampled), each under 5 patterns; and the outputs alike
    # (out4b's bits 2-3 are in output byte 1, which no slave's output bytes cover).
    assert result.bits_read == 5 * (2 + 4 + 2 + 4)
    assert result.bits_written == 5 * (4 + 2 + 2)


def test_the_module_names_soem_s_places_and_says_where_the_eni_differs(small_eni,
                                                                       tmp_path):
    module = tmp_path / "small_setup.py"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(small_eni),
                           "--format", "pysoem", "-o", str(module), "--no-cache"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    text = module.read_text()
    namespace: dict = {}
    exec(compile(text, str(module), "exec"), namespace)
    variables = namespace["VARIABLES"]
    # SOEM (ecx_config_create_input_mappings): outputs 0-1 (out4 bits 0-3, out2 4-5, out4b
    # 6-9), inputs from byte 2: two bits 0-1, sensors 2-5, more 6-9, wide bytes 4-5.
    assert tuple(variables["sensors.Channel 1.Input"]) == (2, "input", 0, 2, 1, "BOOL", 2)
    assert tuple(variables["more.Channel 3.Input"]) == (3, "input", 1, 0, 1, "BOOL", 3)
    assert tuple(variables["out4b.Channel 1.Output"]) == (6, "output", 0, 6, 1, "BOOL", 0)
    assert tuple(variables["wide.Channel 9.Input"]) == (7, "input", 1, 0, 1, "BOOL", 5)
    # The ENI we compiled puts `sensors` at bit 2 of its image, as SOEM does, but out4 at
    # bit 10: the module says so where they differ and only there.
    assert "slave 4 ('out4'): SOEM puts its 4 output bit(s) at IOmap byte 0 bit 0" in text
    assert "slave 2 ('sensors'): SOEM puts" not in text
