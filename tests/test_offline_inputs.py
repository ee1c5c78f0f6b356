"""While a slave is offline its inputs are cleared, and only its own: the bits its read FMMUs
fill are those of its variables in the ENI's process image, also when two bit-wise
slaves share one byte (runtime/master/recovery.py ``input_bits``)."""

from __future__ import annotations

import pytest

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esi.library import Library
from ecatcfg.runtime.master import recovery
from ecatcfg.runtime.master.cyclic import CyclicFrames


@pytest.fixture(scope="module")
def plan() -> NetworkPlan:
    built = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                   Library([EXAMPLES / "esi"], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(built), "example.eni.xml")


def variable_bits(plan: NetworkPlan, slave: str) -> dict[int, int]:
    """Byte -> bit mask of the slave's input variables (ENI ProcessImage/Inputs: BitOffs
    and BitSize of each Variable, named after its slave)."""
    masks: dict[int, int] = {}
    for v in plan.process_image.inputs:
        if v.name.startswith(f"{slave}."):
            for bit in range(v.bit_offs, v.bit_offs + v.bit_size):
                masks[bit // 8] = masks.get(bit // 8, 0) | 1 << bit % 8
    return masks


def test_two_slaves_sharing_a_byte_clear_only_their_own_bits(plan):
    cyclic = CyclicFrames(plan)
    buttons = dict(recovery.input_bits(plan.slave("buttons"), cyclic))
    sensors = dict(recovery.input_bits(plan.slave("sensors"), cyclic))
    # The example line packs the two EX1004s' 4 bits into one byte: the second's FMMU starts
    # at logical bit 4 (ETG.1000.4 FMMU: logical start bit).
    assert buttons == variable_bits(plan, "buttons") == {0: 0x0F}
    assert sensors == variable_bits(plan, "sensors") == {0: 0xF0}


def test_a_drive_clears_every_bit_of_its_inputs_and_none_of_the_others(plan):
    cyclic = CyclicFrames(plan)
    axis = dict(recovery.input_bits(plan.slave("axis1"), cyclic))
    for byte, mask in variable_bits(plan, "axis1").items():
        assert axis.get(byte, 0) & mask == mask, byte
    others = variable_bits(plan, "buttons") | variable_bits(plan, "sensors")
    assert not set(axis) & set(others)
    assert recovery.input_bits(plan.slave("lamps"), cyclic) == []      # outputs only
