"""The IgH export: a C source and header for an application of the IgH EtherCAT master
(``ecrt.h``): ``ecatcfg_configure(master, domain)`` makes one slave configuration per ENI
slave with its PDO tables, start-up SDOs, SoE IDNs, DC and watchdogs, and registers every
ENI variable that is a PDO entry in the domain, its offset in ``ecatcfg_offset[]`` under
the variable's name; ``-DECATCFG_MAIN`` adds a minimal cyclic task.

What each slave gets comes from :func:`ecatcfg.eni.export.igh.igh_config`; this module
decides the C names, ``templates/igh_setup.c.j2`` and ``igh_setup.h.j2`` lay them out.
"""

from __future__ import annotations

from ecatcfg.eni.export.igh import IghConfig, IghSlave
from ecatcfg.eni.export.soem_c import _env
from ecatcfg.eni.export.steps import SdoStep
from ecatcfg.esi.c_names import comment, identifier, identifiers
from ecatcfg.record import record

C_TEMPLATE, H_TEMPLATE = "igh_setup.c.j2", "igh_setup.h.j2"

# ecrt_slave_config_sdo8/16/32 take a value and download it little-endian (EC_WRITE_U16..
# in IgH's slave_config.c); any other size goes as bytes.
SDO_BY_VALUE = {1: "sdo8", 2: "sdo16", 4: "sdo32"}


@record
class SdoCall:
    step: SdoStep
    function: str                             # sdo8/16/32, sdo, complete_sdo
    value: str                                # the value, or the name of the byte array


@record
class SlaveCode:
    slave: IghSlave
    ident: str                                # ecatcfg_s<position>
    sdos: list[SdoCall]


def c_string(text: str) -> str:
    """``text`` as the inside of a C string literal of ASCII characters, byte for byte (its
    UTF-8): a quote, backslash, ``?`` (trigraphs) and anything not printable ASCII as an
    escape, so the application gets the ENI's name exactly."""
    out = []
    for byte in text.encode("utf-8"):
        char = chr(byte)
        out.append(f"\\{char}" if char in '"\\?' else char if 0x20 <= byte < 0x7F
                   else f"\\{byte:03o}")
    return "".join(out)


def _slave_code(s: IghSlave) -> SlaveCode:
    ident = f"ecatcfg_s{s.position}"
    calls = []
    for n, step in enumerate(s.sdos):
        if not step.complete_access and len(step.data) in SDO_BY_VALUE:
            value = int.from_bytes(step.data, "little")
            calls.append(SdoCall(step, SDO_BY_VALUE[len(step.data)],
                                 f"0x{value:0{2 * len(step.data)}X}"))
        else:
            calls.append(SdoCall(step, "complete_sdo" if step.complete_access else "sdo",
                                 f"{ident}_sdo{n}"))
    return SlaveCode(s, ident, calls)


def render(config: IghConfig, header_name: str, eni_name: str, eni_sha256: str,
           version: str) -> tuple[bytes, bytes]:
    """(the C source, the header named ``header_name``) of ``config``."""
    slaves = [_slave_code(s) for s in config.slaves]
    names = [f"ECATCFG_{i}" for i in identifiers([r.name for r in config.registrations])]
    guard = "ECATCFG_" + identifier(header_name)
    values = dict(slaves=slaves, config=config, names=names,
                  regs=list(zip(config.registrations, names)), header=comment(header_name),
                  guard=guard, eni_name=comment(eni_name), eni_sha256=eni_sha256,
                  version=version, any_dc=any(s.dc for s in config.slaves),
                  any_ipv4=any(s.eoe and s.eoe.params.values[1:5] != (None,) * 4
                               for s in config.slaves),
                  by_position={s.position: k for k, s in enumerate(config.slaves)})
    env = _env().overlay()
    env.filters["c_string"] = c_string
    return (env.get_template(C_TEMPLATE).render(**values).encode("ascii"),
            env.get_template(H_TEMPLATE).render(**values).encode("ascii"))
