"""``ecatcfg watch``: process data by variable name, outputs forced by name.

Over a veth pair: the example line emulated in namespace B (in this process, so the test
sees what each emulated slave's application gets), ``watch ENI --iface`` in namespace A with
two outputs forced; the forced values must reach the emulated slaves' outputs while it
runs.  Without a wire: the line format in a pipe, the table on a terminal, usage errors.
"""

from __future__ import annotations

import json
import os
import pty
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from rig import serving

from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
LINE = ["EX1100", "EX1004", "EX1004", "EX2008", "EXD-402"]
LAMP = "lamps.Channel 1-8.Output 1"
VELOCITY = "axis1.RxPDO 2 (CSV).Target velocity"


@pytest.fixture(scope="module")
def eni(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("watch") / "line.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", "examples/topology.yaml",
                           "--esi", "examples/esi", "-o", str(path)], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    return path


def watch(*argv: str, tty: bool = False) -> subprocess.CompletedProcess | str:
    cmd = [sys.executable, "-m", "ecatcfg", "watch", *argv]
    if not tty:
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert "Traceback" not in done.stderr, done.stderr
        return done
    main, child = pty.openpty()
    proc = subprocess.Popen(cmd, stdout=child, stderr=subprocess.PIPE, cwd=ROOT,
                            env={**os.environ, "COLUMNS": "120"})
    os.close(child)
    out = bytearray()
    while True:
        try:
            chunk = os.read(main, 4096)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    proc.wait(120)
    assert proc.returncode == 0, proc.stderr.read().decode() if proc.stderr else ""
    return out.decode(errors="replace")


def test_forced_outputs_reach_the_emulated_slaves(veth_netns, eni):
    lib = Library([ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                   for i, s in enumerate(LINE)])
    lamps, drive = seg.slaves[3], seg.slaves[4]
    seen: dict[str, object] = {}
    result: list[subprocess.CompletedProcess] = []
    with serving(veth_netns, seg):
        thread = threading.Thread(target=lambda: result.append(veth_netns.run_in(
            veth_netns.ns_a, [sys.executable, "-m", "ecatcfg", "watch", str(eni), "--iface",
                              veth_netns.if_a, "--force", f"{LAMP}=1", "--force",
                              f"{VELOCITY}=-1234", "--cycles", "2000", "--format", "json"],
            timeout=120, cwd=ROOT)))
        thread.start()
        deadline = time.monotonic() + 100
        while thread.is_alive() and time.monotonic() < deadline and len(seen) < 2:
            out = lamps.outputs()
            if out and out[0] & 1:
                seen["lamp"] = out[0]
            out = drive.outputs()
            # RxPDO 0x1601: controlword (2 bytes), target velocity (DINT)
            if len(out) >= 6 and int.from_bytes(out[2:6], "little", signed=True) == -1234:
                seen["velocity"] = -1234
            time.sleep(0.002)
        thread.join(120)
    done = result[0]
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 0, done.stderr
    assert seen == {"lamp": 1, "velocity": -1234}
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    first = {line["name"]: line for line in lines}
    assert first[LAMP]["value"] is True and first[LAMP]["output"]
    assert first[VELOCITY]["value"] == -1234
    assert not first["buttons.Channel 1.Input"]["output"]


def test_a_pipe_gets_lines_and_a_terminal_a_table(eni):
    args = [str(eni), "--virtual", "--esi", str(ESI), "--cycles", "20", "--match",
            "lamps.*", "--force", f"{LAMP}=true"]
    done = watch(*args)
    assert done.returncode == 0, done.stderr
    rows = [line.split(None, 2) for line in done.stdout.splitlines()]
    assert [(r[1], r[2]) for r in rows] == \
        [("out", f"{LAMP} = 1 (forced)")] + \
        [("out", f"lamps.Channel 1-8.Output {n} = 0") for n in range(2, 9)]
    table = watch(*args, tty=True)
    assert "variable" in table and f"{LAMP}" in table and "1 (forced)" in table


def test_usage_errors_exit_2(eni):
    for argv, message in (
            (["--force", "buttons.Channel 1.Input=1"], "is an input"),
            (["--force", "lamps.Channel 1-8.Output 9=1"], "did you mean"),
            (["--force", f"{LAMP}=maybe"], "is not a value"),
            (["--match", "nothing.*"], "no variable of the ENI matches"),
            (["--interval", "0"], "must be positive")):
        done = watch(str(eni), "--virtual", "--esi", str(ESI), "--cycles", "2", *argv)
        assert done.returncode == 2 and message in done.stderr, (argv, done.stderr)
    done = watch(str(eni), "--virtual", "--esi", str(ESI), "--cycles", "2", "--force",
                 f"{VELOCITY}=0x80000000")
    assert done.returncode == 2 and "outside DINT range" in done.stderr, done.stderr
