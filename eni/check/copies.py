"""Checks of an ENI's slave-to-slave copies (``Cyclic/Frame/Cmd/CopyInfos``, ETG.2100
``CopyInfosType``) against the same file's commands and slaves: where each copy reads,
and who receives what it writes.  Copies outside the images never reach the plan (the
reader refuses them, ``eni/reader.py``); they are reported here under their own rule."""

from __future__ import annotations

from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.image_map import bit_owners
from ecatcfg.eni.plan import COPY_ELEMENT
from ecatcfg.esc import INPUT_IMAGE_CMDS, Cmd

OUTSIDE = declare("ENI111", "error", "a slave-to-slave copy outside the process image", """
    A CopyInfo's source (SrcBitOffs + BitSize, in the input image) or destination
    (DstBitOffs + BitSize, in the output image) ends past the image: the ProcessImage's
    ByteSize, or as far as a cyclic command's data reaches.  No master can copy bits that
    are not there; apply refuses the file (the copy is skipped with --skip-unsupported).""")
SOURCE = declare("ENI112", "error", "a copy's source is not its command's input data", """
    ETG.2100 has the master copy "valid input data of this command": the command the
    CopyInfos belong to must read data into the input image (LRD, LRW, APRD, FPRD, BRD,
    ARMW, FRMW) and the source bits must be in its data (InputOffs, in its frame's
    convention, + DataLength).  Otherwise the copy is made when this command's working
    counter is right, which says nothing about the bits it copies: stale or foreign data
    reaches the outputs.""")
NOBODY = declare("ENI113", "warning", "a copy writes output bits no slave receives", """
    A CopyInfo's destination bits are not in any slave's ProcessData/Send range: the
    copied value is sent to no slave's outputs (a wrong DstBitOffs, or one counted in
    another image convention: TwinCAT's frame-shaped image puts a command's data 10 bytes
    after its OutputOffs).""")
TWICE = declare("ENI114", "warning", "two copies write the same output bits", """
    Two CopyInfos' destinations overlap: each cycle the master makes them in the ENI's
    order and the later one overwrites the earlier in the shared bits, so one of the
    copies never reaches the slave.""")


def check(ctx: CheckContext) -> None:
    for item in ctx.plan.unsupported:
        if item.element == COPY_ELEMENT:
            ctx.add(OUTSIDE, item.line, item.what)
    receivers = bit_owners(ctx.plan, "out")
    written: list[tuple[int, int, str]] = []            # destination bits, and where
    for ci, cyclic in enumerate(ctx.plan.cyclic):
        for fi, frame in enumerate(cyclic.frames):
            shift = frame.data_shift
            for k, cmd in enumerate(frame.cmds):
                first = 8 * (cmd.input_offs + shift)
                for j, copy in enumerate(cmd.copy_infos):
                    line = ctx.lines.copy_info(ci, fi, k, j, len(cmd.copy_infos))
                    name = f"CopyInfo {j + 1} of cyclic {_name(cmd.cmd)} ({copy.describe()})"
                    src, dst, n = copy.src_bit_offs, copy.dst_bit_offs, copy.bit_size
                    if cmd.cmd not in INPUT_IMAGE_CMDS:
                        ctx.add(SOURCE, line, f"{name}: the command reads no input data")
                    elif not first <= src or src + n > first + 8 * cmd.length:
                        ctx.add(SOURCE, line, f"{name}: the source is not in the command's "
                                f"input data (bits {first}..{first + 8 * cmd.length - 1})")
                    missing = [b for b in range(dst, dst + n) if b not in receivers]
                    if missing:
                        ctx.add(NOBODY, line, f"{name}: {len(missing)} of its {n} output bits "
                                f"(the first: bit {missing[0]}) are no slave's outputs")
                    for lo, hi, other in written:
                        if lo < dst + n and dst < hi:
                            ctx.add(TWICE, line, f"{name} overwrites output bits "
                                    f"{max(lo, dst)}..{min(hi, dst + n) - 1} of {other}")
                    written.append((dst, dst + n, f"CopyInfo {j + 1} at line {line}"))


def _name(cmd: int) -> str:
    try:
        return Cmd(cmd).name
    except ValueError:
        return f"command {cmd}"
