"""A slave built from the ENI alone carries the DC mode the ENI runs it in: its SII DC
category (ETG.2010 category 60) has the activation the ENI writes to 0x0980 and the ENI's
SYNC0 cycle; a slave the ENI runs without DC has none (runtime/segment/eni_device.py)."""

from __future__ import annotations

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esi import sii
from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.eni_device import device_from_eni

DC_ACTIVATION = 0x0980          # ESC: cyclic unit control (0x0980) and activation (0x0981)


@pytest.fixture(scope="module")
def eni() -> bytes:
    built = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                   Library([EXAMPLES / "esi"], cache=False)).plan
    return eni_writer.to_bytes(built)


def _slave(eni: bytes, name: str) -> etree._Element:
    [slave] = [s for s in etree.fromstring(eni).iter("Slave") if s.findtext("Info/Name") == name]
    return slave


def _activation(slave: etree._Element) -> int:
    """The non-zero value the slave's InitCmds write to 0x0980 (Data is the bytes on the
    wire, little-endian)."""
    values = {int.from_bytes(bytes.fromhex(c.findtext("Data") or ""), "little")
              for c in slave.iter("InitCmd") if int(c.findtext("Ado") or "-1") == DC_ACTIVATION}
    [value] = values - {0}
    return value


def _sii(eni: bytes, name: str) -> sii.SiiImage:
    plan = eni_reader.read_bytes(eni, "line.eni.xml")
    return sii.decode(sii.build(device_from_eni(plan.slave(name), plan, "line.eni.xml")))


def test_the_drive_from_the_eni_has_the_eni_s_dc_mode_in_its_sii(eni):
    xml = _slave(eni, "axis1")
    img = _sii(eni, "axis1")
    running = [m for m in img.dc if m.assign_activate]
    assert [(m.assign_activate, m.cycle_time0) for m in running] == [
        (_activation(xml), int(xml.findtext("DC/CycleTime0") or ""))]
    assert _activation(xml) == 0x0300                       # cyclic unit + SYNC0 (ESC 0x0981)


def test_a_slave_without_dc_in_the_eni_has_no_dc_category(eni):
    assert _slave(eni, "buttons").find("DC") is None
    assert _sii(eni, "buttons").dc == []
