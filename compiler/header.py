"""C header of the process image (``ecatcfg compile --header FILE.h``).

Python decides everything (identifiers, C types, ordering); ``templates/process_image.h.j2``
only lays it out.  The output is ASCII, deterministic and ends with a newline.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import jinja2

from ecatcfg.eni.plan import NetworkPlan, Variable
from ecatcfg.esi import datatypes
from ecatcfg.esi.c_names import C_TYPES, comment, identifiers
from ecatcfg.fileio import write_atomic

TEMPLATE = "process_image.h.j2"

_GETTER = {"bit": "get_bit", "bits": "get_bits", "unsigned": "get_bits", "signed": "get_sbits",
           "float": "get_real", "double": "get_lreal"}


@dataclass(frozen=True, slots=True)
class Row:
    """One variable as the template shows it."""

    macro: str          # PREFIX_IN_<ID> / PREFIX_OUT_<ID>
    name: str
    iec: str
    byte: int
    bit: int
    bits: int
    ctype: str
    note: str           # how to read it
    comment: str | None


def guard_for(filename: str, prefix: str = "ECAT") -> str:
    """Include guard from the header's file name: ``io-map.h`` -> ``IO_MAP_H``."""
    ident = re.sub(r"[^A-Za-z0-9]+", "_", filename).strip("_").upper()
    return ident if ident[:1].isalpha() else f"{prefix}_{ident}".rstrip("_")


def _c_type(var: Variable, fn: str) -> tuple[str, str, str]:
    """(IEC type shown, C type, how to read it)."""
    iec = datatypes.canonical(var.data_type) if var.data_type else None
    if iec in C_TYPES and datatypes.bit_size(iec) == var.bit_size:
        ctype, what = C_TYPES[iec]
        return iec, ctype, f"{what}: {fn}{_GETTER[what]}()"
    shown = iec or var.data_type or "no type"
    if var.bit_size < 8 and not var.data_type:
        return shown, "uint8_t", f"bits: {fn}get_bits()"
    return shown, "uint8_t", f"byte array [{(var.bit_size + 7) // 8}]: memcpy from _BYTE"


def _rows(variables: list[Variable], macro_prefix: str, fn: str) -> list[Row]:
    ordered = sorted(variables, key=lambda v: v.bit_offs)        # stable: ties keep plan order
    rows = []
    for var, ident in zip(ordered, identifiers([v.name for v in ordered])):
        iec, ctype, note = _c_type(var, fn)
        rows.append(Row(f"{macro_prefix}_{ident}", var.name, iec, var.bit_offs // 8,
                        var.bit_offs % 8, var.bit_size, ctype, note, var.comment))
    return rows


@functools.cache
def _template() -> jinja2.Template:
    folder = resources.files("ecatcfg.templates")
    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(lambda name: folder.joinpath(name).read_text("utf-8")),
        autoescape=False, keep_trailing_newline=True, trim_blocks=True, lstrip_blocks=True,
        undefined=jinja2.StrictUndefined)
    env.filters["comment"] = comment
    return env.get_template(TEMPLATE)


def render(plan: NetworkPlan, source_name: str, guard: str | None = None,
           prefix: str = "ECAT") -> bytes:
    """The header text for ``plan``; ``source_name`` names the topology/ENI it came from."""
    if not re.fullmatch(r"[A-Z][A-Z0-9]*", prefix):
        raise ValueError(f"prefix must be upper-case letters and digits: {prefix!r}")
    guard = guard or f"{prefix}_PROCESS_IMAGE_H"
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", guard):
        raise ValueError(f"not a C identifier: {guard!r}")
    image, fn = plan.process_image, f"{prefix.lower()}_"
    cycle = plan.cyclic[0].cycle_time if plan.cyclic else None
    text = _template().render(
        P=prefix, fn=fn, guard=guard, source=source_name, master=plan.master.name,
        cycle_time=cycle, inputs_size=image.inputs_size, outputs_size=image.outputs_size,
        inputs=_rows(image.inputs, f"{prefix}_IN", fn),
        outputs=_rows(image.outputs, f"{prefix}_OUT", fn))
    return text.encode("ascii")        # anything non-ASCII left is a bug: fail loudly


def write(plan: NetworkPlan, path: str | Path, source_name: str) -> None:
    """Render and write atomically; the include guard comes from the file name."""
    write_atomic(path, render(plan, source_name, guard_for(Path(path).name)))
