"""Beremiz's EtherLab-plugin file as a topology.

A Beremiz project keeps its EtherCAT network in ``ethercat@etherlab/.../config.xml``: an
ENI's root element and slave list, but no ENI (``docs/eni-exports.md`` §11).  Beremiz
reads it with its own schema (``etherlab/EthercatMaster.py``): ``Info/PhysAddr`` is the
slave's position, ``Info/AutoIncAddr`` its alias, the mailbox areas are placeholders (start
0, length 0), there is no process data, and ``Mailbox/CoE/InitCmds`` are the user's
start-up SDOs (transition ``II``, ``Ccs`` 0, ``Data`` the value as a hex number).  Beremiz
never runs the file: it generates IgH master code from the ESI files
(``etherlab/EthercatCFileGenerator.py``), each SDO an ``ecrt_master_sdo_download`` of the
value in the size of the ESI's object, before the master is activated (slaves in PREOP).

:func:`plugin_topology` gives the same network as a topology for ``compile``: the slaves
in position order, each selected by its identity, with its alias when it has one, and the
SDOs as ``sdos:`` values written in PREOP->SAFEOP (compile encodes each by the object's
type, as Beremiz's generator does); the PDOs are the ESI defaults.
"""

from __future__ import annotations

import json

from lxml import etree

from ecatcfg.errors import EcatcfgError
from ecatcfg.esi.values import parse_int

# The schema Beremiz names on its file (its own copy of the ESI schema): no tool's ENI does.
_SCHEMA_LOCATION = "EtherCATInfo.xsd"
_XSI = "{http://www.w3.org/2001/XMLSchema-instance}noNamespaceSchemaLocation"


def is_plugin_file(root: etree._Element) -> bool:
    """Whether ``root`` is Beremiz's plugin file: ``EtherCATConfig`` naming the ESI schema,
    with slaves but neither cyclic frames, a process image nor process data."""
    if root.tag != "EtherCATConfig" or root.get(_XSI, "").rpartition("/")[2] \
            != _SCHEMA_LOCATION:
        return False
    config = root.find("Config")
    return config is not None and config.find("Slave") is not None \
        and config.find("Cyclic") is None and config.find("ProcessImage") is None \
        and config.find("Slave/ProcessData") is None


def plugin_topology(data: bytes, shown: str) -> str | None:
    """The topology (JSON) of Beremiz's plugin file ``data``, or None when it is not one."""
    if _SCHEMA_LOCATION.encode() not in data[:4096]:
        return None
    from ecatcfg.esi import xmlsafe
    root = xmlsafe.parse_bytes(data, shown, strip=False).getroot()
    if not is_plugin_file(root):
        return None
    slaves = []
    for el in root.iterfind("Config/Slave"):
        info = el.find("Info")
        name = (info.findtext("Name") if info is not None else None) or ""

        def number(tag: str, at: etree._Element = el) -> int:
            text = at.findtext(f"Info/{tag}")
            value = parse_int(text) if text is not None else None
            if value is None:
                raise EcatcfgError(f"slave {name!r}: <Info/{tag}> is not a number",
                                   shown, at.sourceline)
            return value

        slave: dict[str, object] = {
            "name": name.strip() or f"slave {number('PhysAddr')}",
            "device": f"0x{number('VendorId'):x}:0x{number('ProductCode'):x}"
                      f":0x{number('RevisionNo'):x}"}
        if number("AutoIncAddr"):
            slave["alias"] = number("AutoIncAddr")
        sdos = []
        for cmd in el.iterfind("Mailbox/CoE/InitCmds/InitCmd"):
            index, sub = (parse_int(cmd.findtext(t) or "") for t in ("Index", "SubIndex"))
            value = (cmd.findtext("Data") or "").strip()
            if index is None or sub is None or not value:
                raise EcatcfgError(f"slave {name!r}: a start-up SDO without a readable "
                                   "index, subindex or value", shown, cmd.sourceline)
            try:
                number_value = int(value, 16)      # Beremiz writes the value, not bytes
            except ValueError:
                raise EcatcfgError(f"slave {name!r}: start-up SDO value {value!r} is not "
                                   "a hex number", shown, cmd.sourceline) from None
            sdo: dict[str, object] = {"index": index, "subindex": sub,
                                      "value": number_value, "transition": "PS"}
            comment = (cmd.findtext("Comment") or "").strip()
            if comment:
                sdo["comment"] = comment
            sdos.append(sdo)
        if sdos:
            slave["sdos"] = sdos
        slaves.append((number("PhysAddr"), el.sourceline, slave))
    positions = [p for p, _, _ in slaves]
    if len(set(positions)) != len(positions):
        raise EcatcfgError("two slaves give the same <PhysAddr> (Beremiz's position)", shown)
    master = (root.findtext("Config/Master/Info/Name") or "").strip() or "beremiz"
    return json.dumps({"master": {"name": master},
                       "slaves": [s for _, _, s in sorted(slaves, key=lambda t: t[0])]},
                      indent=1)
