"""Inputs of emulated slaves set by name from the command line (``simulate --input``) and
while a master runs (``simulate --control``), with cables pulled and power cycled.

SOEM (pysoem, a master nobody here wrote) reads the inputs over veth; where each input lies
in a slave's input bytes is worked out here from the example ESI files with lxml (the
default PDO assignment: the TxPDOs with an Sm, in file order; entries packed in order), not
from the segment's code.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from lxml import etree

import rig
from installed import ECATCFG
from test_soem import soem

from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.inputs import find_input

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
TOPOLOGY = ROOT / "examples" / "topology.yaml"


def _num(text: str) -> int:
    text = text.strip()
    return int(text[2:], 16) if text.lower().startswith("#x") else int(text)


def default_inputs(type_name: str) -> list[tuple[str, int, int, int]]:
    """(PDO name.entry name, index, subindex, bit offset) of each input entry of the ESI
    device ``type_name`` in its default assignment, straight from the XML."""
    for f in ESI.glob("*.xml"):
        for dev in etree.parse(str(f)).iter("Device"):
            if dev.findtext("Type").strip() != type_name:
                continue
            out, bit = [], 0
            for pdo in dev.iterfind("TxPdo"):
                if pdo.get("Sm") is None:
                    continue
                for e in pdo.iterfind("Entry"):
                    bits = int(e.findtext("BitLen"))
                    if _num(e.findtext("Index")):
                        out.append((f"{pdo.findtext('Name')}.{e.findtext('Name')}",
                                    _num(e.findtext("Index")), _num(e.findtext("SubIndex")),
                                    bit))
                    bit += bits
            return out
    raise AssertionError(type_name)


def test_an_input_held_by_name_lies_where_the_default_mapping_puts_it():
    lib = Library([ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find(t).entry), n)
                   for t, n in (("EX1100", "coupler"), ("EX1004", "buttons"))])
    buttons = seg.slaves[1]
    name, index, sub, bit = default_inputs("EX1004")[2]          # channel 3
    entry = find_input(seg, f"buttons.{name}")
    assert (entry.index, entry.subindex, entry.bits) == (index, sub, 1)
    assert find_input(seg, f"buttons.0x{index:04X}:{sub:02X}") == entry
    entry.hold(entry.parse("on"))
    [(start, length)] = buttons.input_areas()
    assert buttons.mem[start] == 1 << bit
    entry.release()
    assert buttons.held_inputs == {}
    with pytest.raises(ValueError, match="has no input of that name; its inputs: "):
        find_input(seg, "buttons.Channel 9.Input")
    with pytest.raises(ValueError, match="no emulated slave of that name"):
        find_input(seg, "nobody.Channel 1.Input")
    with pytest.raises(ValueError, match="does not fit 1 bits"):
        entry.parse("2")


def test_held_inputs_survive_a_power_cycle():
    """A button still pressed when the power comes back is still pressed."""
    lib = Library([ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EX1004").entry), "buttons")])
    entry = find_input(seg, "buttons.Channel 1.Input")
    entry.hold(1)
    seg.power_cycle(seg.slaves[0])
    seg.slaves[0].apply_held_inputs()
    [(start, _)] = seg.slaves[0].input_areas()
    assert seg.slaves[0].mem[start] & 1


def _start(pair: rig.VethRig, *args: str) -> subprocess.Popen[str]:
    sim = pair.popen_in(pair.ns_b, [*ECATCFG, "simulate", "--esi", str(ESI), "--topology",
                                    str(TOPOLOGY), "--iface", pair.if_b, "--duration", "120",
                                    "--no-cache", *args],
                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE, text=True)
    assert sim.stdout is not None
    lines = []
    for line in sim.stdout:
        lines.append(line)
        if line.startswith("ready:"):
            return sim
    raise AssertionError("".join(lines) + (sim.stderr.read() if sim.stderr else ""))


def _command(sim: subprocess.Popen[str], line: str) -> str:
    assert sim.stdin is not None and sim.stdout is not None
    sim.stdin.write(line + "\n")
    sim.stdin.flush()
    while True:
        answer = sim.stdout.readline()
        assert answer, "simulate ended"
        if answer.startswith(("ok:", "error:")):
            return answer.strip()


def test_inputs_set_on_the_command_line_and_while_soem_runs(veth_netns, pysoem_module):
    drive = {n: bit for n, _, _, bit in default_inputs("EXD-402")}
    position = drive["TxPDO 1 (CSP).Position actual value"]
    assert position % 8 == 0
    sim = _start(veth_netns, "--input", "buttons.Channel 3.Input=1", "--input",
                 "axis1.TxPDO 1 (CSP).Position actual value=-2", "--control")
    try:
        report = soem(veth_netns, {"cycles": 5})
        assert report.get("op") == 8, report
        names = ["coupler", "buttons", "sensors", "lamps", "axis1"]
        inputs = dict(zip(names, report["inputs"]))
        # SOEM packs the two 4-bit terminals into one byte, buttons' bits 0-3 and the
        # sensors' 4-7 (ecx_config_map_group: a slave of under 8 bits starts at the next
        # free bit), and gives each slave that byte: channel 3 of buttons is bit 2.
        assert inputs["buttons"] == inputs["sensors"] == "04"
        assert bytes.fromhex(inputs["axis1"])[position // 8:position // 8 + 4] == \
            (-2).to_bytes(4, "little", signed=True)

        # While it runs: a button released, a sensor set, by name, answered line by line.
        assert _command(sim, "set buttons.Channel 3.Input 0") == \
            "ok: buttons.Channel 3.Input = 0"
        assert _command(sim, "sensors.Channel 1.Input=on") == "ok: sensors.Channel 1.Input = 1"
        assert _command(sim, "set buttons.Channel 9.Input 1").startswith(
            "error: buttons.Channel 9.Input: slave 'buttons' has no input of that name")
        report = soem(veth_netns, {"cycles": 5})
        inputs = dict(zip(names, report["inputs"]))
        assert inputs["buttons"] == inputs["sensors"] == "10"   # sensors' channel 1: bit 4

        # A power cycle keeps what is held; a pulled cable takes the slaves behind it off.
        assert _command(sim, "power sensors") == "ok: 1 slave switched off and on"
        assert _command(sim, "cut lamps") == \
            "ok: cable into lamps removed: lamps, axis1 off the frame"
        report = soem(veth_netns, {"cycles": 5})
        assert report["found"] == 3
        assert dict(zip(names, report["inputs"]))["sensors"] == "10"
        assert _command(sim, "plug lamps") == "ok: cable into lamps back"
        assert soem(veth_netns, {"cycles": 5})["found"] == 5
    finally:
        if sim.stdin is not None:
            sim.stdin.close()
        sim.terminate()
        sim.wait(20)


def test_a_wrong_input_on_the_command_line_is_a_usage_error(tmp_path):
    done = subprocess.run([*ECATCFG, "simulate", "--esi", str(ESI), "--topology",
                           str(TOPOLOGY), "--iface", "lo", "--input", "buttons.Nope=1",
                           "--no-cache"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "--input buttons.Nope: slave 'buttons' has no input of that name" in done.stderr
