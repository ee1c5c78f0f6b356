"""The topology's slave-to-slave copies (``master.copies``) as ENI ``CopyInfos``.

Each copy names an input and an output variable by their ENI names; it becomes a
``CopyInfo`` (ETG.2100 ``CopyInfosType``) of the cyclic command whose input data holds
the input variable, with both offsets in the process image the variables' ``BitOffs``
are in (``eni/plan.py`` ``CopyInfo``).  A name the image does not have, two sizes that
differ, or an input no command reads in OP is an error at the copy's line.
"""

from __future__ import annotations

from difflib import get_close_matches

from ecatcfg.compiler.topology import LoadedTopology
from ecatcfg.eni.plan import CopyInfo, CyclicCmd, NetworkPlan, Variable
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import INPUT_IMAGE_CMDS


def add_copies(loaded: LoadedTopology, plan: NetworkPlan) -> list[EcatcfgError]:
    """Append each copy to its command in ``plan``; the errors, each at its line."""
    errors: list[EcatcfgError] = []
    image = plan.process_image
    inputs = {v.name: v for v in image.inputs}
    outputs = {v.name: v for v in image.outputs}
    for k, copy in enumerate(loaded.topology.master.copies):
        source = _variable(loaded, inputs, copy.source, "input", ("master", "copies", k,
                                                                   "from"), errors)
        target = _variable(loaded, outputs, copy.to, "output", ("master", "copies", k, "to"),
                           errors)
        if source is None or target is None:
            continue
        if source.bit_size != target.bit_size:
            errors.append(loaded.error(
                f"copy {copy.source!r} ({_bits(source)}) to {copy.to!r} ({_bits(target)}): "
                "the sizes differ", "master", "copies", k))
            continue
        cmd = _reading(plan, source)
        if cmd is None:
            errors.append(loaded.error(f"no cyclic command reads {copy.source!r} in OP",
                                       "master", "copies", k, "from"))
            continue
        cmd.copy_infos.append(CopyInfo(source.bit_offs, target.bit_offs, source.bit_size))
    return errors


def _variable(loaded: LoadedTopology, variables: dict[str, Variable], name: str,
              direction: str, path: tuple[str | int, ...],
              errors: list[EcatcfgError]) -> Variable | None:
    found = variables.get(name)
    if found is None:
        close = get_close_matches(name, list(variables), 3)
        hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        errors.append(loaded.error(f"{name!r} is not an {direction} variable of the "
                                   f"process image{hint}", *path))
    return found


def _reading(plan: NetworkPlan, var: Variable) -> CyclicCmd | None:
    """The first command that reads the variable's bits into the input image in OP."""
    for cyclic in plan.cyclic:
        for frame in cyclic.frames:
            shift = frame.data_shift
            for cmd in frame.cmds:
                first = 8 * (cmd.input_offs + shift)
                if cmd.cmd in INPUT_IMAGE_CMDS and "OP" in cmd.states and \
                        first <= var.bit_offs and \
                        var.bit_offs + var.bit_size <= first + 8 * cmd.length:
                    return cmd
    return None


def _bits(var: Variable) -> str:
    return f"{var.bit_size} bit{'s' if var.bit_size != 1 else ''}"
