"""``ecatcfg pdos``: the PDO assignment and mapping an emulated slave holds after ``apply``,
against the ENI applied, read here with lxml (ETG.2100 ``ProcessData/RxPdo|TxPdo`` with
their ``Sm`` attribute: the PDOs assigned to that SyncManager, and their entries).

The example line's drive is configured away from its ESI defaults (RxPDO 0x1601 instead of
0x1600, 0x1A01 remapped with a third entry), so what ``pdos`` reads is what apply wrote.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from lxml import etree
from rig import serving

from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
LINE = ["EX1100", "EX1004", "EX1004", "EX2008", "EXD-402"]
DRIVE = 4


def _number(text: str) -> int:
    text = text.strip()
    return int(text[2:], 16) if text.startswith("#x") else int(text)


def eni_assignment(eni: Path, position: int) -> dict[int, list[tuple[int, list]]]:
    """SM -> [(PDO index, [(entry index, subindex, bit length)])] of the ENI's slave."""
    slave = etree.parse(str(eni)).findall(".//Config/Slave")[position]
    out: dict[int, list] = {}
    for kind in ("RxPdo", "TxPdo"):
        for pdo in slave.findall(f"ProcessData/{kind}"):
            if pdo.get("Sm") is None:
                continue                            # described, not assigned
            entries = [(_number(e.findtext("Index")), _number(e.findtext("SubIndex") or "0"),
                        _number(e.findtext("BitLen"))) for e in pdo.findall("Entry")]
            out.setdefault(int(pdo.get("Sm")), []).append(
                (_number(pdo.findtext("Index")), entries))
    return out


def ecatcfg_in(rig, *argv: str) -> dict | str:
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface", rig.if_a],
                      timeout=120, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def test_pdos_after_apply_equal_the_enis_assignment(veth_netns, tmp_path):
    eni = tmp_path / "line.eni.xml"
    compiled = subprocess.run([sys.executable, "-m", "ecatcfg", "compile",
                               "examples/topology.yaml", "--esi", "examples/esi", "-o",
                               str(eni)], capture_output=True, text=True, cwd=ROOT,
                              timeout=120)
    assert compiled.returncode == 0, compiled.stderr
    want = eni_assignment(eni, DRIVE)
    assert [p for p, _ in want[2]] == [0x1601]         # not the ESI's default 0x1600

    lib = Library([ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                   for i, s in enumerate(LINE)])
    with serving(veth_netns, seg):
        ecatcfg_in(veth_netns, "apply", str(eni), "--state", "op", "--cycles", "20", "--stay")
        out = json.loads(ecatcfg_in(veth_netns, "pdos", "--slave", str(DRIVE), "--esi",
                                    str(ESI), "--format", "json"))
        text = ecatcfg_in(veth_netns, "pdos", "--slave", str(DRIVE), "--esi", str(ESI))
    got = {sm["sm"]: [(p["index"], [(e["index"], e["subindex"], e["bit_length"])
                                    for e in p["entries"]]) for p in sm["pdos"]]
           for sm in out["sync_managers"]}
    assert got == want
    assert [(sm["sm"], sm["type"], sm["assign_index"]) for sm in out["sync_managers"]] \
        == [(2, "outputs", 0x1C12), (3, "inputs", 0x1C13)]
    # Names from the ESI: the PDO and the objects it maps.
    assert "SM2 outputs: 0x1C12 = 0x1601  (48 bits)" in text
    assert "0x60FF:00  32 bit  Target velocity" in text


def test_a_slave_without_0x1c00_is_read_as_sm2_outputs_and_sm3_inputs():
    # A dictionary without the SM communication types (many small devices leave it out):
    # the standard SyncManagers' assignment objects are read, here the ESI defaults.
    from rig import serve_in_memory

    from ecatcfg.runtime.master import pdo_tool
    from ecatcfg.runtime.master.transport import Transport

    lib = Library([ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    del seg.slaves[0].od.objects[0x1C00]
    link, close = serve_in_memory(seg)
    try:
        held = pdo_tool.read_pdos(Transport(link), 0)
    finally:
        close()
    assert [(a.sm, a.sm_type, [p.index for p in a.pdos]) for a in held] \
        == [(2, 3, [0x1600]), (3, 4, [0x1A00])]
    assert [(e.index, e.subindex, e.bit_length) for e in held[0].pdos[0].entries] \
        == [(0x6040, 0, 16), (0x607A, 0, 32)]


def test_usage_errors_exit_2():
    for argv in (["--slave", "-1"], ["--slave", "0", "--timeout", "0"]):
        done = subprocess.run([sys.executable, "-m", "ecatcfg", "pdos", "--iface", "lo",
                               *argv], capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
