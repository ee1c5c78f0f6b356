"""``ecatcfg simulate`` stops cleanly on SIGINT, SIGTERM and SIGHUP (docs/runtime.md,
"ecatcfg simulate"), also when started as a shell starts a background job (``&``): with
SIGINT ignored, which the process inherits (POSIX, Shell Command Language, "Signals").

Real signals (``os.kill``) to a real ``simulate`` process serving a veth end in a private
network namespace (tests/rig.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import EXAMPLES

STOP_BOUND_S = 5.0          # from the signal to the process's exit


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)       # what `cmd &` in a script does


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP, signal.SIGTERM],
                         ids=lambda s: signal.Signals(s).name)
def test_simulate_started_with_sigint_ignored_stops_on_the_signal(veth_netns, sig):
    rig = veth_netns
    sim = rig.popen_in(rig.ns_b, [
        sys.executable, "-m", "ecatcfg", "simulate", "--esi", str(EXAMPLES / "esi"),
        "--topology", str(EXAMPLES / "topology.yaml"), "--iface", rig.if_b, "--duration",
        "120", "--no-cache"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=_ignore_sigint)
    assert sim.stdout is not None
    for line in sim.stdout:
        if line.startswith("ready:"):
            break
    else:
        raise AssertionError(f"simulate ended before ready: {sim.stderr.read()}")
    # The handler simulate set is in place (SigCgt of /proc/PID/status has the bit)...
    status = open(f"/proc/{sim.pid}/status").read()
    caught = int(next(line.split()[1] for line in status.splitlines()
                      if line.startswith("SigCgt:")), 16)
    assert caught >> (sig - 1) & 1, status
    sent = time.monotonic()
    os.kill(sim.pid, sig)
    try:
        out, err = sim.communicate(timeout=STOP_BOUND_S)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"simulate still running {STOP_BOUND_S} s after "
                             f"{signal.Signals(sig).name}") from None
    took = time.monotonic() - sent
    name = signal.Signals(sig).name
    assert sim.returncode == 0, err
    assert f"({name})" in out.splitlines()[-1] and out.splitlines()[-1].startswith(
        "stopped after "), out
    assert "Traceback" not in err, err
    assert took < STOP_BOUND_S


def test_the_ignored_sigint_reaches_the_started_program(veth_netns):
    # ... and the disposition simulate started with was SIG_IGN: the same start
    # (`ip netns exec`, preexec_fn) shows Python a SIGINT ignored.
    rig = veth_netns
    done = rig.run_in(rig.ns_b, [sys.executable, "-c", "import signal; print(signal."
                                 "getsignal(signal.SIGINT) is signal.SIG_IGN)"],
                      preexec_fn=_ignore_sigint)
    assert done.stdout.strip() == "True", done
