"""CoE CompleteAccess from subindex 1 (ETG.1000.6: a complete access starts at subindex 0 or
1; from 1, subindex 0 and its 16-bit slot are not in the data).  TwinCAT writes a terminal's
settings record (0x8000) that way, and a real terminal takes it.

The settings record of the self-written ESI below is laid out the way vendors' records are:
its SubItem BitOffs leave reserved bits between the entries (bits 19-21 and 23-31), and a
second record declares no subindex 1 at all.  A configurator writes such a record as the
ESI places its entries, so the image is 8 bytes with the UINT at byte 2; packing the
entries one after the other would give 7 bytes with the UINT at byte 1.

Independent references: the byte positions come from the BitOffs written in the fixture
(not from the code under test), tshark decodes the master's request (complete access flag,
subindex 1, size, data) from the capture of a whole ``apply``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import MAILBOX_PD_SMS, device_xml, esi_xml, write
from rig import start_simulate
from test_apply import check_pcap
from test_sdo_server import SI0, Slave, sub
from test_soem import soem

from ecatcfg.eni import reader as eni_reader
from ecatcfg.esi.reader import read_bytes
from ecatcfg.runtime.segment import emulate
from ecatcfg.runtime.mailbox import SdoAbort
from ecatcfg.runtime.segment.objects import ObjectDictionary

SETTINGS = f"""
<Profile><ProfileNo>5001</ProfileNo><Dictionary>
  <DataTypes>
    <DataType><Name>DT8000</Name><BitSize>80</BitSize>{SI0}
      {sub(1, "Enable user scale", "BOOL", 1, 16)}{sub(2, "Presentation", "BIT2", 2, 17)}
      {sub(6, "Enable filter", "BOOL", 1, 22)}{sub(17, "Filter settings", "UINT", 16, 32)}
      {sub(18, "User scale gain", "DINT", 32, 48)}
    </DataType>
    <DataType><Name>DT8010</Name><BitSize>48</BitSize>{SI0}
      {sub(2, "Limit", "UINT", 16, 32)}
    </DataType>
  </DataTypes>
  <Objects>
    <Object><Index>#x8000</Index><Name>Settings Ch.1</Name><Type>DT8000</Type>
      <BitSize>80</BitSize></Object>
    <Object><Index>#x8010</Index><Name>Limits Ch.1</Name><Type>DT8010</Type>
      <BitSize>48</BitSize></Object>
  </Objects>
</Dictionary></Profile>
{MAILBOX_PD_SMS}
<Mailbox><CoE SdoInfo="1" CompleteAccess="1"/></Mailbox>
"""

# Enable user scale 1, Presentation 2 (bits 1-2), Enable filter 1 (bit 6); a reserved
# byte; Filter settings 0x1234; User scale gain -2.
IMAGE_FROM_1 = bytes.fromhex("45" "00" "3412" "feffffff")


def settings_device():
    esi = read_bytes(esi_xml(device_xml("CA1", body=SETTINGS)).encode(), "ca.xml")
    assert [p for p in esi.problems if p.severity == "error"] == []
    return esi.devices[0]


@pytest.fixture
def slave() -> Slave:
    return Slave(ObjectDictionary.from_device(settings_device()))


def test_download_from_subindex_1_places_entries_at_their_bit_offsets(slave):
    slave.download(0x8000, 1, IMAGE_FROM_1, ca=True)
    od = slave.od
    assert [od.int_value(0x8000, s) for s in (1, 2, 6, 17)] == [1, 2, 1, 0x1234]
    assert od[0x8000][18].value == bytes.fromhex("feffffff")
    assert od.int_value(0x8000, 0) == 18                 # SI0 is not in the data: unchanged
    assert slave.upload(0x8000, 1, ca=True) == IMAGE_FROM_1
    # From subindex 0 the same image follows SI0 and its pad byte.
    assert slave.upload(0x8000, 0, ca=True) == bytes([18, 0]) + IMAGE_FROM_1


def test_a_record_without_subindex_1(slave):
    slave.download(0x8010, 1, bytes.fromhex("0000" "e803"), ca=True)
    assert slave.od.int_value(0x8010, 2) == 1000
    assert slave.upload(0x8010, 1, ca=True) == bytes.fromhex("0000e803")
    with pytest.raises(SdoAbort) as err:             # not a complete access: no subindex 1
        slave.upload(0x8010, 1)
    assert err.value.code == 0x06090011


def test_an_image_longer_than_the_record_is_refused(slave):
    with pytest.raises(SdoAbort) as err:
        slave.download(0x8000, 1, IMAGE_FROM_1 + b"\0", ca=True)
    assert err.value.code == 0x06070012


TOPOLOGY = """slaves:
  - name: rtd
    device: CA1
    sdos:
      - {index: 0x8000, subindex: 1, data: '45 00 3412 feffffff', complete_access: true}
"""


def _apply(eni: Path, *args: str) -> tuple[int, dict, str]:
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "apply", str(eni), "--virtual",
                           "--format", "json", "--simulated-time", "--cycles", "2", *args],
                          capture_output=True, text=True, timeout=120)
    return done.returncode, json.loads(done.stdout or "{}"), done.stderr


@pytest.fixture
def compiled(tmp_path) -> tuple[Path, Path]:
    esi = write(tmp_path, "ca.xml", esi_xml(device_xml("CA1", body=SETTINGS)))
    topo = write(tmp_path, "line.yaml", TOPOLOGY)
    return esi, _compile(topo, esi, tmp_path / "line.eni.xml")


def _compile(topo: Path, esi: Path, eni: Path) -> Path:
    """``ecatcfg compile`` of ``topo`` against ``esi`` into ``eni``, as a user runs it."""
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(esi), "-o", str(eni), "--no-cache"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return eni


def test_apply_writes_the_settings_from_subindex_1(compiled, tshark_path, tmp_path):
    """The emulated terminal takes the download (it used to refuse the 8 bytes: its image
    was packed to 7), and tshark reads the request as a complete access from subindex 1."""
    esi, eni = compiled
    pcap = tmp_path / "ca.pcapng"
    rc, report, err = _apply(eni, "--esi", str(esi), "--pcap", str(pcap))
    assert rc == 0 and report["slaves"][0]["highest_state"] == "OP", err
    plan = eni_reader.read_file(eni)
    [cmd] = [c for c in plan.slaves[0].mailbox.coe_init_cmds if c.index == 0x8000]
    assert (cmd.subindex, cmd.complete_access, cmd.data) == (1, True, IMAGE_FROM_1)
    assert check_pcap(pcap, plan) >= 1


def test_a_slave_from_the_eni_alone_takes_it_too(compiled):
    """Without the ESI the emulated slave knows the object only from the ENI's download: it
    used to abort with 0x06020000 (object does not exist), as the download from subindex 1
    created nothing."""
    _, eni = compiled
    rc, report, err = _apply(eni)
    assert rc == 0 and report["slaves"][0]["highest_state"] == "OP", err
    plan = eni_reader.read_file(eni)
    [spec] = emulate.specs_from_eni(plan, None, "line.eni.xml")
    slave = emulate.emulated_slave(spec)
    assert slave.od is not None
    od = slave.od
    assert od.read(0x8000, 1, None, complete_access=True) == bytes(8)
    od.write(0x8000, 1, IMAGE_FROM_1, None, complete_access=True)
    assert od.read(0x8000, 1, None, complete_access=True) == IMAGE_FROM_1
    assert od.int_value(0x8000, 0) == 1


def test_soem_writes_and_reads_from_subindex_1_on_simulate(veth_netns, pysoem_module,
                                                             tmp_path):
    """SOEM, an independent master, downloads the settings with its own complete access
    from subindex 1 to ``ecatcfg simulate`` and reads them back the same way, then from
    subindex 0 (SI0 and its pad byte first)."""
    esi = write(tmp_path, "ca.xml", esi_xml(device_xml("CA1", body=SETTINGS)))
    topo = write(tmp_path, "line.yaml", "slaves:\n  - {name: rtd, device: CA1}\n")
    sim, lines = start_simulate(veth_netns, "--esi", str(esi), "--topology", str(topo))
    assert lines and lines[-1].startswith("ready:"), "".join(lines) + sim.stderr.read()
    report = soem(veth_netns, {"ca_write": [[0, 0x8000, 1, IMAGE_FROM_1.hex()]],
                               "ca_read": [[0, 0x8000, 1], [0, 0x8000, 0]], "cycles": 2})
    sim.terminate()
    sim.communicate(timeout=10)
    assert report["ca_read"] == [IMAGE_FROM_1.hex(), "1200" + IMAGE_FROM_1.hex()]


def test_a_device_whose_esi_has_no_dictionary_takes_it(tmp_path):
    """Its ESI declares CoE but no object dictionary: nothing says the object is missing, so
    the emulated device takes the ENI's download (it used to abort with 0x06020000) and
    keeps its bytes."""
    bare = SETTINGS[SETTINGS.index("</Profile>") + len("</Profile>"):]
    esi = write(tmp_path, "bare.xml", esi_xml(device_xml("CA1", body=bare)))
    full = write(tmp_path, "ca.xml", esi_xml(device_xml("CA1", body=SETTINGS)))
    topo = write(tmp_path, "line.yaml", TOPOLOGY)
    eni = _compile(topo, full, tmp_path / "line.eni.xml")
    rc, report, err = _apply(eni, "--esi", str(esi), "--no-cache")
    assert rc == 0 and report["slaves"][0]["highest_state"] == "OP", err
    plan = eni_reader.read_file(eni)
    from ecatcfg.esi.library import Library
    [spec] = emulate.specs_from_eni(plan, Library([esi], cache=False), "line.eni.xml")
    assert spec.eni_only is None and spec.extra_writes
    slave = emulate.emulated_slave(spec)
    assert slave.od is not None and 0x8000 in slave.od
