"""The SOEM export: a C source and header with an identity check, the start-up writes of
each slave made by ``ecatcfg_config_map`` before SOEM's own mapping (every failure returned
to the caller, slave, object and abort code named), SOEM's mapping checked against the
header, each slave's process data as a packed struct whose offsets are asserted at compile
time, a table of every variable where SOEM puts it, and (with ``-DECATCFG_MAIN``) a
minimal ``main`` that runs the cycle.

What each slave's start-up does comes from :func:`ecatcfg.eni.export.steps.slave_setups`,
where SOEM puts its data from :mod:`ecatcfg.eni.export.soem_image`; this module decides the
C names and the struct layout, ``templates/soem_setup.c.j2`` and ``soem_setup.h.j2`` lay
them out.  The code uses SOEM's context API (``ecx_*``), the one
pysoem builds SOEM for (``EC_VER2``).
"""

from __future__ import annotations

import functools
from importlib import resources
from typing import TYPE_CHECKING

from ecatcfg.eni.export import soem_image
from ecatcfg.eni.export.steps import ImageEntry, SlaveSetup
from ecatcfg.esc import DC_ACTIVATE_SYNC1
from ecatcfg.esi import datatypes
from ecatcfg.esi.c_names import C_TYPES, comment, identifier, identifiers
from ecatcfg.record import record

if TYPE_CHECKING:
    import jinja2

C_TEMPLATE, H_TEMPLATE = "soem_setup.c.j2", "soem_setup.h.j2"


@record
class Field:
    name: str
    ctype: str
    offset: int                               # bytes
    count: int                                # > 1: an array of bytes
    note: str


@record
class Struct:
    name: str
    size: int
    fields: list[Field]


def _typed(e: ImageEntry) -> str | None:
    """The C type of an entry that starts on a byte and has the size of its IEC type."""
    iec = (e.data_type or "").upper()
    if e.bit_offs % 8 or iec not in C_TYPES or datatypes.bit_size(iec) != e.bit_size \
            or e.bit_size % 8:
        return None
    return C_TYPES[iec][0]


def layout(type_name: str, entries: list[ImageEntry], bits: int,
           start_bit: int = 0) -> Struct | None:
    """A slave's outputs or inputs (``bits`` long, from bit ``start_bit`` of the byte SOEM's
    ``outputs``/``inputs`` pointer gives: its ``Ostartbit``/``Istartbit``) as a packed
    struct: typed fields where an entry starts on a byte with its type's size, byte arrays
    for the rest (bit entries, gaps; the bits are named in the field's note, at SOEM's
    bit)."""
    size = (start_bit + bits + 7) // 8
    entries = [ImageEntry(e.name, start_bit + e.bit_offs, e.bit_size, e.data_type)
               for e in entries]
    if not size:
        return None
    names = identifiers([e.name for e in entries])
    typed: dict[int, tuple[ImageEntry, str, str]] = {}
    notes: dict[int, list[str]] = {}
    for e, name in zip(entries, names):
        ctype = _typed(e)
        if ctype is not None and e.bit_offs // 8 not in typed:
            typed[e.bit_offs // 8] = (e, ctype, name.lower())
        else:
            notes.setdefault(e.bit_offs // 8, []).append(
                f"{e.name} byte {e.bit_offs // 8} bit {e.bit_offs % 8}, {e.bit_size} bit")
    fields: list[Field] = []
    byte = 0
    while byte < size:
        if byte in typed:
            e, ctype, name = typed[byte]
            fields.append(Field(name, ctype, byte, 1, comment(f"{e.name} ({e.data_type})")))
            byte += e.bit_size // 8
            continue
        start = byte
        while byte < size and byte not in typed:
            byte += 1
        note = "; ".join(n for b in range(start, byte) for n in notes.get(b, []))
        fields.append(Field(f"bytes_{start}", "uint8_t", start, byte - start,
                            comment(note or "not mapped to a variable")))
    return Struct(type_name, size, fields)


@record
class SlaveCode:
    setup: SlaveSetup
    ident: str
    hooked: bool
    sync1: bool
    outputs: Struct | None
    inputs: Struct | None
    out_area: soem_image.SoemArea | None
    in_area: soem_image.SoemArea | None
    notes: list[str]


def _slave_code(s: SlaveSetup, image: soem_image.SoemImage) -> SlaveCode:
    ident = f"{identifier(s.name).lower()}_{s.position}"
    out, inp = image.area(s.position, "output"), image.area(s.position, "input")
    return SlaveCode(s, ident, bool(s.registers or s.sdos or s.soe or s.sync_activation),
                     bool(s.sync_activation & DC_ACTIVATE_SYNC1),
                     layout(f"ecatcfg_{ident}_out_t", s.outputs, s.output_bits,
                            out.start_bit if out else 0),
                     layout(f"ecatcfg_{ident}_in_t", s.inputs, s.input_bits,
                            inp.start_bit if inp else 0),
                     out, inp,
                     [n for a in (out, inp) if a
                      for n in [soem_image.eni_note(s, a, image)] if n])


def _c_string(text: str) -> str:
    """``text`` as the inside of a C string literal (UTF-8; quotes, backslashes and bytes
    outside printable ASCII as octal escapes, so no escape runs into the next char)."""
    return "".join(chr(b) if 0x20 <= b < 0x7F and chr(b) not in '"\\?' else f"\\{b:03o}"
                   for b in text.encode("utf-8"))


def _bytes(data: bytes) -> str:
    return ", ".join(f"0x{b:02X}" for b in data)


@functools.cache
def _env() -> jinja2.Environment:
    import jinja2
    folder = resources.files("ecatcfg.templates")
    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(lambda name: folder.joinpath(name).read_text("utf-8")),
        autoescape=False, keep_trailing_newline=True, trim_blocks=True, lstrip_blocks=True,
        undefined=jinja2.StrictUndefined)
    env.filters["comment"] = comment
    env.filters["c_bytes"] = _bytes
    env.filters["c_string"] = _c_string
    return env


def expected_wkc(setups: list[SlaveSetup]) -> int:
    """The working counter of SOEM's one LRW over the whole image (ETG.1000.4: a slave
    adds 1 when it writes its inputs, 2 when it reads its outputs, 3 for both)."""
    return sum(2 * (s.output_bits > 0) + (s.input_bits > 0) for s in setups)


def render(setups: list[SlaveSetup], header_name: str, eni_name: str, eni_sha256: str,
           version: str) -> tuple[bytes, bytes]:
    """(the C source, the header named ``header_name``) for the slaves' ``setups``."""
    image = soem_image.soem_image(setups)
    slaves = [_slave_code(s, image) for s in setups]
    guard = "ECATCFG_" + identifier(header_name)
    values = dict(slaves=slaves, header=comment(header_name), guard=guard, image=image,
                  eni_name=comment(eni_name), eni_sha256=eni_sha256, version=version,
                  expected_wkc=expected_wkc(setups),
                  any_dc=any(s.sync_activation for s in setups))
    env = _env()
    return (env.get_template(C_TEMPLATE).render(**values).encode("ascii"),
            env.get_template(H_TEMPLATE).render(**values).encode("ascii"))
