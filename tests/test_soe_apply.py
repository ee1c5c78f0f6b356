"""SoE from a topology to a running drive, through the command line only: ``ecatcfg
compile`` writes the self-written two-axis drive's start-up IDNs (its ESI's and the
topology's ``soe:``) into the ENI, ``ecatcfg apply --virtual`` brings the emulated drive to
OP, and what went over the wire is read back by tshark.

The references are not ecatcfg's: the ENI is judged by the ETG.2100 schema, the writes
expected on the wire are taken from the ENI file with lxml (its ``Mailbox/SoE/InitCmds``, in
file order per transition), and Wireshark's EtherCAT mailbox dissector decodes the frames.
The drive is the one of ``tests/fixtures/esi/soe_drive.xml``: its PS writes (S-0-0001,
S-0-0002, S-0-0032 on drive 0) are what it needs before SAFEOP."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from lxml import etree
from rig import soe_messages, tshark_malformed

from conftest import FIXTURES, write

ESI = FIXTURES / "esi" / "soe_drive.xml"
TOPOLOGY = """\
master: {name: soe-line, cycle_time_us: 1000}
slaves:
  - name: axes
    device: TSD-2 SoE
    soe:
      - {idn: S-0-0001, value: 2000}
      - {idn: P-0-0100, data: "02000000", transition: SO, drive: 1}
"""
ORDER = ("PS", "SO")                # the transitions that carry SoE writes up to OP


def ecatcfg(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", *map(str, args)],
                          capture_output=True, text=True, timeout=180)


def compiled(tmp_path: Path) -> Path:
    eni = tmp_path / "soe.xml"
    done = ecatcfg("compile", write(tmp_path, "t.yaml", TOPOLOGY), "--esi", ESI, "-o", eni)
    assert done.returncode == 0, done.stderr
    return eni


def eni_writes(eni: Path) -> list[tuple[int, int, bytes]]:
    """(drive, IDN, data) of the ENI's enabled SoE InitCmds, PS ones then SO ones, each
    transition in file order: the order a master sends them in on the way to OP."""
    cmds = etree.parse(str(eni)).findall(".//Slave/Mailbox/SoE/InitCmds/InitCmd")
    out = []
    for transition in ORDER:
        for c in cmds:
            if transition in [t.text for t in c.findall("Transition")] \
                    and c.findtext("Disabled", "false") not in ("true", "1"):
                out.append((int(c.findtext("DriveNo")), int(c.findtext("IDN")),
                            bytes.fromhex(c.findtext("Data", ""))))
    return out


def wire_writes(pcap: Path) -> list[tuple[int, int, bytes]]:
    """(drive, IDN, data) of each SoE write request tshark finds, once per request."""
    return [(drive, idn, data) for op, drive, _, _, idn, data in soe_messages(pcap)
            if op == 3]


def test_compiled_soe_drive_reaches_op_with_every_idn_written_in_order(tmp_path, eni_schema,
                                                                       tshark_path):
    eni = compiled(tmp_path)
    assert eni_schema.validate(etree.parse(str(eni))), eni_schema.error_log
    expected = eni_writes(eni)
    # The ESI's drive-0 PS writes and the topology's two entries are all there.
    assert (0, 1, (2000).to_bytes(2, "little")) in expected       # S-0-0001 replaced
    assert (1, 0x8064, bytes.fromhex("02000000")) == expected[-1]  # P-0-0100, SO, drive 1
    assert {(d, i) for d, i, _ in expected} >= {(0, 1), (0, 2), (0, 32)}
    pcap = tmp_path / "up.pcapng"
    done = ecatcfg("apply", eni, "--virtual", "--esi", ESI, "--simulated-time", "--cycles", "5",
                   "--pcap", pcap, "--format", "json")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["ok"] is True
    assert [s["highest_state"] for s in report["slaves"]] == ["OP"]
    assert wire_writes(pcap) == expected
    assert tshark_malformed(pcap) == []


def test_a_missing_required_idn_is_a_named_refusal_of_safeop(tmp_path):
    eni = compiled(tmp_path)
    tree = etree.parse(str(eni))
    [s2] = [c for c in tree.findall(".//Slave/Mailbox/SoE/InitCmds/InitCmd")
            if c.findtext("IDN") == "2" and c.findtext("DriveNo") == "0"]
    s2.getparent().remove(s2)
    tree.write(str(eni))
    done = ecatcfg("apply", eni, "--virtual", "--esi", ESI, "--simulated-time", "--cycles", "5")
    assert done.returncode == 1, done.stdout + done.stderr
    said = done.stdout + done.stderr
    assert "slave 'axes'" in said
    assert "0x0045" in said and "PREOP" in said
    assert "S-0-0021 of drive 0 lists S-0-0002" in said
    assert "Traceback" not in said
