"""``ecatcfg watch``: process data by variable name, outputs forced by name.

Over a veth pair: the example line emulated in namespace B (in this process, so the test
sees what each emulated slave's application gets), ``watch ENI --iface`` in namespace A with
two outputs forced, then outputs forced and released by commands written to its stdin; the
forced values must reach the emulated slaves' outputs (their output SyncManagers' memory)
while it runs, and a released one must go back.  In memory: the same commands through a
pipe to ``watch --virtual`` run in this process, so the test reads the emulated slaves of
its virtual segment.  On a pseudo-terminal: keys typed into the live table (completion, a
refused value, release, ``q``, Ctrl-C), and the terminal's mode put back afterwards.
Without a wire: the line format in a pipe, the table on a terminal, usage errors.
"""

from __future__ import annotations

import fcntl
import json
import os
import pty
import select
import signal
import subprocess
import termios
import sys
import threading
import time
from pathlib import Path

import pytest
from lxml import etree
from rig import serving

from ecatcfg.esc import AlState
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
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120,
                              stdin=subprocess.DEVNULL)
        assert "Traceback" not in done.stderr, done.stderr
        return done
    main, child = pty.openpty()
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=child,
                            stderr=subprocess.PIPE, cwd=ROOT,
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
            timeout=120, cwd=ROOT, stdin=subprocess.DEVNULL)))
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
    objects = [json.loads(line) for line in done.stdout.splitlines()]
    lines = [o for o in objects if "name" in o]
    first = {line["name"]: line for line in lines}
    # The status at the end: every slave in OP, the LRW's working counter as the ENI's Cnt
    # (read here with lxml) expects.
    final = objects[-1]["status"]
    cnt = [int(c.findtext("Cnt")) for c in etree.parse(str(eni)).iterfind(
        "Config/Cyclic/Frame/Cmd") if c.findtext("Cmd") == "12"]
    assert (final["state"], final["online"], final["slaves"]) == ("OP", 5, 5)
    assert [(c["wkc"], c["expected"]) for c in final["working_counters"]] == \
        [(n, n) for n in cnt]
    assert first[LAMP]["value"] is True and first[LAMP]["output"] and first[LAMP]["forced"]
    assert first[VELOCITY]["value"] == -1234
    assert not first["buttons.Channel 1.Input"]["output"]


def test_a_pipe_gets_lines_and_a_terminal_a_table(eni):
    args = [str(eni), "--virtual", "--esi", str(ESI), "--cycles", "20", "--match",
            "lamps.*", "--force", f"{LAMP}=true"]
    done = watch(*args)
    assert done.returncode == 0, done.stderr
    rows = [line.split(None, 2) for line in done.stdout.splitlines()]
    status = [r[2] for r in rows if r[1] == "status:"]
    assert status and status[-1].startswith("cycle 20 | 5/5 slaves in OP | LRW logical "
                                            "0x10000000 wkc 7/7 | lost 0 | late "), status
    rows = [r for r in rows if r[1] != "status:"]
    assert [(r[1], r[2]) for r in rows] == \
        [("out", f"{LAMP} = 1 (forced)")] + \
        [("out", f"lamps.Channel 1-8.Output {n} = 0") for n in range(2, 9)]
    table = watch(*args, tty=True)
    assert "variable" in table and f"{LAMP}" in table and "1 (forced)" in table


def test_twincats_diagnostic_variables_are_what_the_master_knows(corpus):
    """TwinCAT's ENI puts InfoData.State and WcState.WcState of each slave in the input
    image (its master fills them; the slaves never send them): watch shows the slaves'
    state (8 = OP, Beckhoff's InfoData.State table) and a valid working counter (0), not
    the 0 the image holds, and the slave counts."""
    eni = corpus / "eni" / "jn-ec-master" / "mega_master_eni.xml"
    names = [v.findtext("Name") for v in etree.parse(str(eni)).iterfind(
        "Config/ProcessImage/Inputs/Variable")]
    states = [n for n in names if n.endswith(".InfoData.State") and n.startswith("Term ")]
    wc = [n for n in names if n.endswith(".WcState.WcState") and n.startswith("Term ")]
    assert len(states) == 4 and len(wc) >= 2
    done = watch(str(eni), "--virtual", "--cycles", "30", "--format", "json", "--match",
                 "*InfoData.State", "--match", "*WcState*", "--match", "*SlaveCount")
    assert done.returncode == 0, done.stderr
    last = {}
    for o in map(json.loads, done.stdout.splitlines()):
        if "name" in o:
            last[o["name"]] = o["value"]
    assert {n: last[n] for n in states} == {n: 8 for n in states}
    assert {n: last[n] for n in wc} == {n: 0 for n in wc}
    assert last["InfoData.CfgSlaveCount"] == last["Inputs.SlaveCount"] == 4
    assert last["Inputs.Frm0WcState"] == 0


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


# -- commands while it runs ---------------------------------------------------------------

LAMP3 = "lamps.Channel 1-8.Output 3"


def lamp_bits(slave) -> int:
    """The EX2008's eight outputs as its application sees them (output SM memory in OP)."""
    out = slave.outputs()
    return out[0] if out else 0


def velocity(slave) -> int:
    out = slave.outputs()          # RxPDO 0x1601: controlword (2 bytes), target velocity
    return int.from_bytes(out[2:6], "little", signed=True) if len(out) >= 6 else 0


def wait_for(what, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = what()
        if got:
            return got
        time.sleep(0.002)
    return what()


def test_commands_from_a_pipe_reach_the_emulated_slaves_in_memory(eni, monkeypatch, capsys):
    """``watch --virtual`` in this process, its stdin a pipe: a forced value is in the
    emulated slave's output SM while the line cycles, a released one goes back to 0, a
    wrong command is said with its line number and ``q`` ends the watch early (exit 2, as
    a command was refused)."""
    from ecatcfg.cli import main
    from ecatcfg.runtime.network import Network

    nets: list[Network] = []
    virtual = Network.virtual

    def capture(*args, **kwargs):
        net = virtual(*args, **kwargs)
        nets.append(net)
        return net

    monkeypatch.setattr(Network, "virtual", capture)
    read_end, write_end = os.pipe()
    monkeypatch.setattr(sys, "stdin", os.fdopen(read_end, "r"))
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(main(
        ["watch", str(eni), "--virtual", "--esi", str(ESI), "--no-cache", "--cycles", "600000",
         "--match", "lamps.*", "--match", "axis1.*"])))
    thread.start()
    try:
        assert wait_for(lambda: nets and nets[0].state == AlState.OP), "the line did not come up"
        lamps, drive = nets[0].segment.slaves[3], nets[0].segment.slaves[4]
        assert lamp_bits(lamps) == 0
        os.write(write_end, f"f {LAMP3} 1\nforce {VELOCITY}=-1234\n".encode())
        assert wait_for(lambda: lamp_bits(lamps) == 0b100 and velocity(drive) == -1234), \
            (lamp_bits(lamps), velocity(drive))
        os.write(write_end, f"force buttons.Channel 1.Input 1\nf {LAMP3} 2\n"
                            f"unforce {LAMP3}\n".encode())
        assert wait_for(lambda: lamp_bits(lamps) == 0), lamp_bits(lamps)
        assert lamps.state == AlState.OP and velocity(drive) == -1234
        os.write(write_end, b"u *\n")
        assert wait_for(lambda: velocity(drive) == 0)
        os.write(write_end, f"f {LAMP} 1\nu {LAMP}\n".encode())   # together: a trace each
        os.write(write_end, b"q\n")
        thread.join(30)
        assert not thread.is_alive(), "q did not end the watch"
    finally:
        os.close(write_end)
        if thread.is_alive() and nets:
            nets[0].stop()
        thread.join(60)
    out, err = capsys.readouterr()
    assert codes == [2], err
    assert "Traceback" not in err
    assert f"stdin line 3: force buttons.Channel 1.Input 1: 'buttons.Channel 1.Input' is " \
           "an input" in err
    assert f"stdin line 4: f {LAMP3} 2: '{LAMP3}': 2 is outside BOOL range 0..1" in err
    last = {line.split(None, 2)[2]: n for n, line in enumerate(out.splitlines())}
    # Each command's change is printed before the next one runs, also of commands that
    # came in one read and left the output as it was.
    assert last[f"{LAMP3} = 1 (forced)"] < last[f"{LAMP3} = 0"] < last[f"{VELOCITY} = 0"] \
        < last[f"{LAMP} = 1 (forced)"] < last[f"{LAMP} = 0"]


def test_commands_from_a_pipe_over_veth(veth_netns, eni):
    """``watch --iface`` in namespace A, its stdin a pipe written while it runs: the emulated
    line in namespace B gets the forced value, then the released one, then ``q`` stops it
    (exit 0: every command was taken)."""
    lib = Library([ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                   for i, s in enumerate(LINE)])
    lamps = seg.slaves[3]
    with serving(veth_netns, seg):
        proc = veth_netns.popen_in(
            veth_netns.ns_a, [sys.executable, "-m", "ecatcfg", "watch", str(eni), "--iface",
                              veth_netns.if_a, "--cycles", "600000", "--match", "lamps.*"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
        try:
            assert wait_for(lambda: lamps.state == AlState.OP, 60), lamps.state
            proc.stdin.write(f"force {LAMP3}=true\n".encode())
            proc.stdin.flush()
            assert wait_for(lambda: lamp_bits(lamps) == 0b100), lamp_bits(lamps)
            proc.stdin.write(f"release {LAMP3}\n".encode())
            proc.stdin.flush()
            assert wait_for(lambda: lamp_bits(lamps) == 0), lamp_bits(lamps)
            assert lamps.state == AlState.OP
            proc.stdin.write(b"q\n")
            proc.stdin.flush()
            out, err = proc.communicate(timeout=30)     # q, not the end of --cycles
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    err_text = err.decode()
    assert "Traceback" not in err_text, err_text
    assert proc.returncode == 0, err_text
    assert f"{LAMP3} = 1 (forced)" in out.decode()


def test_command_words_values_and_completion(eni):
    """The commands on a network not yet up (its output image is written all the same):
    both spellings of force, values per type, release putting back the value from before,
    refusals that change nothing, completion of command words and names."""
    from ecatcfg.cli.watch_commands import Commands
    from ecatcfg.runtime.network import Network
    from ecatcfg.runtime.watch import Watch

    with Network.virtual(str(eni), [ESI], esi_cache=False) as net:
        net[VELOCITY] = 77                   # what the output held before it was forced
        commands = Commands(Watch(net))
        assert commands.run("   ") is None
        done = commands.run(f"force {VELOCITY}=-0x10")
        assert done is not None and not done.error and net[VELOCITY] == -16
        done = commands.run(f"F  {VELOCITY}   2147483647 ")
        assert done is not None and not done.error and net[VELOCITY] == 2147483647
        for line, message in (
                (f"f {VELOCITY} 2147483648", "2147483648 is outside DINT range"),
                (f"f {VELOCITY} 1.5", "'1.5' is not a value for DINT"),
                (f"f {LAMP3} on", None),
                ("f buttons.Channel 1.Input 1", "is an input; only outputs can be forced"),
                ("f lamps.Channel 1-8.Output 9 1", "did you mean"),
                (f"f {LAMP3}", "give NAME VALUE or NAME=VALUE"),
                ("u lamps.Channel 1-8.Output 1", "is not forced (forced: "),
                ("u nothing*", "no forced output matches"),
                ("stop", "unknown command 'stop'")):
            done = commands.run(line)
            assert done is not None and done.error == (message is not None), (line, done)
            assert message is None or message in done.message, (line, done.message)
        assert net[VELOCITY] == 2147483647 and net[LAMP3] is True
        assert commands.status() == f"forced: {VELOCITY} = 2147483647, {LAMP3} = 1"
        done = commands.run(f"unforce {VELOCITY}")
        assert done is not None and done.message == f"released {VELOCITY} = 77"
        assert net[VELOCITY] == 77 and commands.status() == f"forced: {LAMP3} = 1"
        assert commands.complete("unf") == ("unforce ", [])
        assert commands.complete("") == ("", ["force", "unforce", "release", "quit", "help"])
        assert commands.complete("u la") == (f"u {LAMP3} ", [])
        line, found = commands.complete("f axis1.RxPDO 2 (CSV).T")
        assert line == f"f {VELOCITY} " and found == []
        line, found = commands.complete("force lamps.")
        assert line == "force lamps.Channel 1-8.Output " and len(found) == 8
        assert commands.run("q") == commands.run("quit") and commands.run("exit").quit


class Terminal:
    """``ecatcfg watch`` on a pseudo-terminal that is its controlling terminal (so Ctrl-C
    typed is a SIGINT), stderr a pipe; the test keeps the terminal's own end open to read
    its mode."""

    def __init__(self, *argv: str) -> None:
        self.main, self.tty = pty.openpty()
        fcntl.ioctl(self.tty, termios.TIOCSWINSZ, b"\x32\x00\xc8\x00\x00\x00\x00\x00")
        self.mode = termios.tcgetattr(self.tty)
        tty = self.tty

        def controlling() -> None:
            os.setsid()
            fcntl.ioctl(tty, termios.TIOCSCTTY, 0)

        self.proc = subprocess.Popen(
            [sys.executable, "-m", "ecatcfg", "watch", *argv], stdin=tty, stdout=tty,
            stderr=subprocess.PIPE, cwd=ROOT, preexec_fn=controlling,
            env={**os.environ, "COLUMNS": "200", "LINES": "50"})
        self.out = bytearray()

    def read(self, timeout: float = 0.05) -> None:
        while select.select([self.main], [], [], timeout)[0]:
            try:
                chunk = os.read(self.main, 65536)
            except OSError:
                return
            if not chunk:
                return
            self.out += chunk

    def expect(self, text: str, timeout: float = 30.0) -> None:
        """Wait until ``text`` is drawn after what was read so far."""
        mark = len(self.out)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.read()
            if text.encode() in self.out[mark:]:
                return
        last = self.out[-2000:].decode(errors="replace")
        raise AssertionError(f"{text!r} not drawn; last: {last}")

    def type(self, keys: str) -> None:
        os.write(self.main, keys.encode())

    def finish(self) -> str:
        deadline = time.monotonic() + 30          # q or Ctrl-C, not the end of --cycles
        while self.proc.poll() is None and time.monotonic() < deadline:
            self.read()
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)
        self.read()
        err = self.proc.stderr.read().decode() if self.proc.stderr else ""
        return err

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        os.close(self.main)
        os.close(self.tty)


def test_keys_typed_into_the_live_table(eni):
    """Tab completes a name, Enter forces it, a value out of range is a red status line and
    changes nothing, ``u`` releases, ``q`` quits; the terminal is in cbreak mode (no echo,
    no line buffering) while the table runs and in its own mode again afterwards."""
    term = Terminal(str(eni), "--virtual", "--esi", str(ESI), "--match", "lamps.*",
                    "--cycles", "600000")
    try:
        term.expect("forced: none")
        lflag = termios.tcgetattr(term.tty)[3]
        assert not lflag & (termios.ICANON | termios.ECHO), "stdin not in cbreak mode"
        term.type("f lamps.C\t")
        term.expect("> f lamps.Channel 1-8.Output ")
        term.type("3 1\r")
        term.expect(f"forced: {LAMP3} = 1")
        term.expect("1 (forced)")
        term.type(f"f {LAMP3} 7\r")
        term.expect(f"error: f {LAMP3} 7: '{LAMP3}': 7 is outside BOOL range 0..1")
        term.type("frobnicate\r")
        term.expect("error: frobnicate: unknown command 'frobnicate'")
        term.type(f"u {LAMP3}\r")
        term.expect(f"released {LAMP3} = 0")
        term.expect("forced: none")
        term.type("q")
        err = term.finish()
        assert term.proc.returncode == 0, err
        assert "Traceback" not in err, err
        assert termios.tcgetattr(term.tty) == term.mode
    finally:
        term.close()


@pytest.mark.parametrize("stop", ["ctrl-c", "sigterm", "sighup"])
def test_a_signal_in_the_live_table_puts_the_terminal_back(eni, stop):
    """Ctrl-C typed (SIGINT from the terminal: cbreak mode keeps signals on), SIGTERM or
    SIGHUP stops the watch with the terminal's mode put back, no traceback."""
    term = Terminal(str(eni), "--virtual", "--esi", str(ESI), "--match", "lamps.*",
                    "--cycles", "600000")
    try:
        term.expect("forced: none")
        term.type(f"f {LAMP3}")        # a line half typed
        term.expect(f"> f {LAMP3}")
        if stop == "ctrl-c":
            term.type("\x03")
        else:
            term.proc.send_signal(signal.SIGTERM if stop == "sigterm" else signal.SIGHUP)
        err = term.finish()
        assert term.proc.returncode == 0, err
        assert "Traceback" not in err, err
        assert termios.tcgetattr(term.tty) == term.mode
    finally:
        term.close()
