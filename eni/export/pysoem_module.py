"""The pysoem export: a Python module with a ``config_func`` hook per slave and ``setup``.

What each hook does comes from :func:`ecatcfg.eni.export.steps.slave_setups`; this module
only writes it with ``templates/pysoem_setup.py.j2``; where each variable is comes from
:mod:`ecatcfg.eni.export.soem_image` (SOEM's own IOmap layout, not the ENI's addresses).
Names are written with ``repr``, data as ``bytes.fromhex('0a16')``, so the module's text
depends on the ENI alone (the same ENI gives the same bytes) and a person can read it.
"""

from __future__ import annotations

import functools
from importlib import resources
from typing import TYPE_CHECKING

from ecatcfg.eni.export import soem_image
from ecatcfg.eni.export.steps import ExportError, SlaveSetup
from ecatcfg.esc import DC_ACTIVATE_SYNC1
from ecatcfg.record import record

if TYPE_CHECKING:
    import jinja2

TEMPLATE = "pysoem_setup.py.j2"


def _one_line(text: str) -> str:
    """Text for a ``#`` comment: one line (a name from a file may hold line breaks)."""
    return " ".join(text.split())


def _hex_bytes(data: bytes | None) -> str:
    """Data as a person reads it: ``bytes.fromhex('0a16')`` rather than ``b'\\n\\x16'``."""
    return "None" if data is None else f"bytes.fromhex({data.hex()!r})"


@record
class _Place:
    place: soem_image.SoemPlace
    reachable: bool
    last: int                                 # the variable's last IOmap byte


def _sync1(activation: int) -> bool:
    return bool(activation & DC_ACTIVATE_SYNC1)


@functools.cache
def _template() -> jinja2.Template:
    import jinja2
    folder = resources.files("ecatcfg.templates")
    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(lambda name: folder.joinpath(name).read_text("utf-8")),
        autoescape=False, keep_trailing_newline=True, trim_blocks=True, lstrip_blocks=True,
        undefined=jinja2.StrictUndefined)
    env.filters["py"] = repr
    env.filters["line"] = _one_line
    env.filters["hex_bytes"] = _hex_bytes
    env.tests["sync1"] = _sync1
    return env.get_template(TEMPLATE)


def check(setups: list[SlaveSetup], file: str) -> None:
    """Refuse what pysoem cannot do: variables SOEM does not map
    (:func:`ecatcfg.eni.export.soem_image.check`), SoE writes (pysoem 1.1 wraps SOEM's CoE, FoE and
    register calls, not ``ecx_SoEwrite``; leaving them out would start the drive without
    its parameters).  The SOEM C export makes them."""
    soem_image.check(setups, file)
    for s in setups:
        if s.soe:
            step = s.soe[0]
            raise ExportError(f"slave {s.position} ({s.name!r}): {step.words}: pysoem has no "
                              f"SoE call ({len(s.soe)} SoE write(s) in all); export "
                              "--format soem-c makes them with ecx_SoEwrite", file, step.line)


def render(setups: list[SlaveSetup], eni_name: str, eni_sha256: str, version: str) -> bytes:
    """The module's text for the slaves' ``setups`` of the ENI named ``eni_name``."""
    image = soem_image.soem_image(setups)
    places: dict[int, list[_Place]] = {s.position: [] for s in setups}
    for p in image.places:
        places[p.slave].append(_Place(p, image.reachable(p),
                                      p.iomap_byte + (p.bit + p.bit_size - 1) // 8))
    notes = {s.position: [n for a in image.areas if a.slave == s.position
                          for n in [soem_image.eni_note(s, a, image)] if n]
             for s in setups}
    text = _template().render(slaves=setups, eni_name=eni_name, eni_sha256=eni_sha256,
                              version=version, image=image, places=places, notes=notes,
                              names={s.position: s.name for s in setups},
                              any_dc=any(s.sync_activation for s in setups))
    return text.encode("utf-8")
