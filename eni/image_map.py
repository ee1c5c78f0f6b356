"""The process image as a map of bytes and bits, each bit owned by a slave.

Which slave a bit belongs to is what the ENI says of each slave, ``ProcessData/Send`` (its
outputs) and ``Recv`` (its inputs): ``BitStart``/``BitLength`` in the coordinates of the
``ProcessImage`` variables' ``BitOffs`` (ETG.2100), in every tool's files, TwinCAT's
frame-shaped image included.  A variable no slave's range covers (TwinCAT's frame state and
diagnostic variables) is shown without an owner, never dropped.
"""

from __future__ import annotations

from ecatcfg.eni.plan import NetworkPlan, PassiveSlave, Variable
from ecatcfg.record import field, record


@record
class BitCell:
    owner: int | None                        # index into NetworkPlan.in_file_order()
    variable: str | None                     # the variable that holds this bit


@record
class ByteRow:
    offset: int
    bits: list[BitCell]                      # bit 0 first
    starts: list[str] = field(default_factory=list)   # variables whose first bit is here


@record
class Gap:
    """Bytes that no slave and no variable uses, folded into one row."""

    first: int
    last: int


@record
class ImageMap:
    direction: str                           # "in" / "out"
    size: int                                # bytes, as the ENI's ProcessImage says
    rows: list[ByteRow | Gap]


def bit_owners(plan: NetworkPlan, direction: str) -> dict[int, int]:
    """Each bit of the image (``in`` or ``out``) a slave's range holds: the slave's index in
    ``in_file_order()``; the first range listed wins where two overlap."""
    owner: dict[int, int] = {}
    for k, slave in enumerate(plan.in_file_order()):
        if isinstance(slave, PassiveSlave) or slave.process_data is None:
            continue
        ranges = slave.process_data.recv if direction == "in" else \
            slave.process_data.send
        for r in ranges:
            for bit in range(r.bit_start, r.bit_start + r.bit_length):
                owner.setdefault(bit, k)
    return owner


def image_map(plan: NetworkPlan, direction: str) -> ImageMap:
    image = plan.process_image
    size = image.inputs_size if direction == "in" else image.outputs_size
    variables: list[Variable] = image.inputs if direction == "in" else image.outputs
    owner = bit_owners(plan, direction)
    holder: dict[int, str] = {}
    starts: dict[int, list[str]] = {}
    for v in variables:
        starts.setdefault(v.bit_offs // 8, []).append(v.name)
        for bit in range(v.bit_offs, v.bit_offs + v.bit_size):
            holder.setdefault(bit, v.name)
    used = {bit // 8 for bit in owner} | {bit // 8 for bit in holder}
    end = max([size] + [b + 1 for b in used])
    rows: list[ByteRow | Gap] = []
    offset = 0
    while offset < end:
        if offset in used:
            rows.append(ByteRow(offset, [BitCell(owner.get(offset * 8 + b),
                                                 holder.get(offset * 8 + b))
                                         for b in range(8)], starts.get(offset, [])))
            offset += 1
            continue
        last = offset
        while last + 1 < end and last + 1 not in used:
            last += 1
        rows.append(Gap(offset, last))
        offset = last + 1
    return ImageMap(direction, size, rows)

