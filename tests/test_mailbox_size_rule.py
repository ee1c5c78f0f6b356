"""One rule for a mailbox SyncManager's size, followed everywhere (esi/model.py,
``SyncManager.mailbox_size``): DefaultSize, else MaxSize, else MinSize.

A schema-valid ESI whose MBoxOut/MBoxIn carry only ``MinSize="128"`` used to compile into an
ENI whose SM0/SM1 InitCmds said 128 bytes but whose ``Mailbox/Send|Recv/Length`` said 0; the
SII builder wrote 0 into the standard mailbox words and lint said nothing.  Here the ENI and
the SII image are read back with lxml and ``struct`` at fixed offsets (ETG.2100 element
names, ETG.2010 SII words 0x18-0x1B), not with the project's own readers, and the expected
sizes are literals.
"""

from __future__ import annotations

import json
import struct

import pytest
from lxml import etree

from conftest import write
from ecatcfg.cli import main
from lint_fixtures import SM0, SM1, drive, esi

MIN_ONLY = (SM0.replace('DefaultSize="128"', 'MinSize="128"'),
            SM1.replace('DefaultSize="128"', 'MinSize="128"'))
MIN_AND_MAX = (SM0.replace('DefaultSize="128"', 'MinSize="64" MaxSize="128"'),
               SM1.replace('DefaultSize="128"', 'MinSize="32" MaxSize="96"'))


def line(tmp_path, sms: tuple[str, str]):
    folder = tmp_path / "esi"
    folder.mkdir()
    write(folder, "fx.xml", esi(drive(sm0=sms[0], sm1=sms[1])))
    topo = write(tmp_path, "line.yaml", "slaves:\n  - {name: d1, device: FX1}\n")
    return folder, topo


def eni_sizes(path) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """(SM0/SM1 InitCmds as (register, length), (Mailbox Send Length, Recv Length))."""
    slave = etree.parse(str(path)).getroot().find("Config/Slave")
    sm_cmds = []
    for cmd in slave.iterfind("InitCmds/InitCmd"):
        ado = int(cmd.findtext("Ado"))
        if int(cmd.findtext("Cmd")) == 5 and ado in (0x0800, 0x0808) and cmd.findtext("Data"):
            data = bytes.fromhex(cmd.findtext("Data"))
            if len(data) == 8:                           # one SM image, not the clear
                sm_cmds.append((ado, struct.unpack_from("<H", data, 2)[0]))
    mbx = slave.find("Mailbox")
    return sm_cmds, (int(mbx.findtext("Send/Length")), int(mbx.findtext("Recv/Length")))


@pytest.mark.parametrize("sms,out_size,in_size", [(MIN_ONLY, 128, 128),
                                                   (MIN_AND_MAX, 128, 96)],
                         ids=["MinSize only", "MinSize and MaxSize"])
def test_mailbox_sizes_agree_in_eni_sii_apply_and_lint(tmp_path, capsys, sms, out_size,
                                                       in_size):
    folder, topo = line(tmp_path, sms)
    eni = tmp_path / "line.eni.xml"
    assert main(["compile", str(topo), "--esi", str(folder), "-o", str(eni),
                 "--no-cache"]) == 0, capsys.readouterr().err

    sm_cmds, mailbox = eni_sizes(eni)
    assert sm_cmds == [(0x0800, out_size), (0x0808, in_size)]
    assert mailbox == (out_size, in_size)

    # The emulated slave checks SM0/SM1 against its own mailbox: PREOP and on to OP.
    capsys.readouterr()
    assert main(["apply", str(eni), "--virtual", "--esi", str(folder), "--cycles", "3",
                 "--format", "json", "--no-cache"]) == 0, capsys.readouterr().err
    report = json.loads(capsys.readouterr().out)
    assert [s.get("highest_state", s["state"]) for s in report["slaves"]] == ["OP"]

    # The SII image: standard mailbox words 0x18-0x1B (byte 0x30).
    image = tmp_path / "fx.bin"
    assert main(["sii", "build", str(folder), "--device", "FX1", "-o", str(image)]) == 0
    words = struct.unpack_from("<4H", image.read_bytes(), 0x30)
    assert words == (0x1000, out_size, 0x1080, in_size)

    # lint: a warning for each mailbox SM without DefaultSize, naming the size taken.
    capsys.readouterr()
    assert main(["lint", str(folder), "--format", "json", "--no-config"]) == 0
    findings = json.loads(capsys.readouterr().out)["findings"]
    assert [(f["rule"], f["severity"]) for f in findings] == [("ESI212", "warning")] * 2
    assert f"{out_size} bytes" in findings[0]["message"]
    assert f"{in_size} bytes" in findings[1]["message"]


def test_a_mailbox_without_any_size_is_a_lint_error(tmp_path, capsys):
    folder, _ = line(tmp_path, (SM0.replace('DefaultSize="128" ', ""), SM1))
    assert main(["lint", str(folder), "--format", "json", "--no-config"]) == 1
    findings = json.loads(capsys.readouterr().out)["findings"]
    assert [(f["rule"], f["severity"]) for f in findings] == [("ESI213", "error")]


def _recv_length(eni, length: int) -> None:
    """SM1's InitCmd and ``Mailbox/Recv/Length`` set to ``length``, with lxml."""
    tree = etree.parse(str(eni))
    slave = tree.getroot().find("Config/Slave")
    for cmd in slave.iterfind("InitCmds/InitCmd"):
        data = bytes.fromhex(cmd.findtext("Data") or "")
        if int(cmd.findtext("Ado")) == 0x0808 and len(data) == 8:
            cmd.find("Data").text = (data[:2] + struct.pack("<H", length) + data[4:]).hex()
    slave.find("Mailbox/Recv/Length").text = str(length)
    tree.write(str(eni))


@pytest.mark.parametrize("length,takes", [(64, True), (32, True), (96, True), (31, False),
                                          (100, False)])
def test_check_and_the_emulated_slave_take_the_same_mailbox_lengths(tmp_path, capsys,
                                                                    length, takes):
    """ETG.2000: MinSize..MaxSize are the sizes the slave accepts, DefaultSize (here none:
    MaxSize) the one a configurator programs.  SM1 of 32..96 bytes: check (ENI501) and
    the slave emulated from the same ESI (0x0016 before PREOP) take exactly the lengths
    inside the bounds: one rule, not two."""
    folder, topo = line(tmp_path, MIN_AND_MAX)
    eni = tmp_path / "line.eni.xml"
    assert main(["compile", str(topo), "--esi", str(folder), "-o", str(eni),
                 "--no-cache"]) == 0, capsys.readouterr().err
    _recv_length(eni, length)
    capsys.readouterr()
    checked = main(["check", str(eni), "--esi", str(folder), "--format", "json", "--no-cache"])
    rules = [f["rule"] for f in json.loads(capsys.readouterr().out)["findings"]
             if f["severity"] == "error"]
    assert (checked, rules) == ((0, []) if takes else (1, ["ENI501"]))
    applied = main(["apply", str(eni), "--virtual", "--esi", str(folder), "--cycles", "3",
                    "--no-cache"])
    said = capsys.readouterr()
    assert (applied == 0) == takes, said
    if not takes:
        assert "0x0016" in said.out + said.err
