"""Every example in README.md and docs/*.md is run: each fenced ``sh`` and
``python`` block, in a temporary folder laid out like the checkout (its ``examples/``).

- Shell blocks run command by command (a line, or its ``&&`` parts), ``ecatcfg`` as
  ``python -m ecatcfg``, ``> FILE`` as a redirection; each must exit 0 (``lint`` and
  ``check``: 0 or 1, "exit 1 on errors" as the docs say; ``diff``: 0 or 1, "1 when they
  differ"; ``doctor``: 0 or 1, "1 when a slave is not in the target state", which depends
  on what the examples before it left the simulated line in) without a traceback.
- A command with ``--iface`` needs a bus: it runs in a network namespace whose veth end is
  served by ``ecatcfg simulate`` of the example line (tests/rig.py); ``simulate`` itself
  runs in a namespace pair of its own until it is ready, then is stopped with SIGINT.
- Python blocks run as a script; one that opens a ``RawLink`` runs in the namespace with
  the bus.
- The doc's stand-ins for the reader's own files are replaced by files the test has
  (``PLACEHOLDERS``: real vendor ESIs and schemas from the corpus, an ENI of another tool).
- A block the test does not run says so in the doc, on the line before it:
  ``*Not run by the tests: <reason>.*``; such blocks are few (``MAX_NOT_RUN``).

Unlabelled blocks are synopses, output or diagrams, not commands.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

import rig
from conftest import ROOT
from installed import ECATCFG, PYTHON

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.S | re.M)
NOT_RUN = re.compile(r"^\*Not run by the tests: (.+)\*$")
MAX_NOT_RUN = 4
IFACE = "eth1"                    # the docs' stand-in for the master's interface


def placeholders(corpus: Path) -> dict[str, str]:
    """The docs' stand-ins -> what the test uses for them."""
    return {
        "vendor-esi/": f"{corpus}/esi/beckhoff/",          # real vendor ESI files
        "etg/esi-1.17": f"{corpus}/schemas/esi-1.17",      # the ETG.2000 schema
        "their.eni.xml": f"{corpus}/eni/jn-ec-master/mega_master_eni.xml",  # TwinCAT-style
        "devices/": "examples/esi/",
        "el1809-new.bin": "el1809.bin",                    # the image read just before
        "dump.bin": "el2004.bin",
    }


@dataclass
class Example:
    file: Path
    line: int
    lang: str
    text: str
    not_run: str | None

    def __str__(self) -> str:
        shown = self.file.relative_to(ROOT) if self.file.is_relative_to(ROOT) else self.file
        return f"{shown}:{self.line}"


def examples(docs: list[Path] = DOCS) -> list[Example]:
    found = []
    for path in docs:
        text = path.read_text()
        for m in FENCE.finditer(text):
            if m.group(1) not in ("sh", "python"):
                continue
            before = [ln for ln in text[:m.start()].splitlines() if ln.strip()]
            mark = NOT_RUN.match(before[-1].strip()) if before else None
            found.append(Example(path, text.count("\n", 0, m.start()) + 1, m.group(1),
                                 m.group(2), mark.group(1) if mark else None))
    return found


def commands(text: str) -> list[list[str]]:
    """The commands of a shell block: each line's ``&&`` parts, comments left out."""
    out = []
    for line in text.splitlines():
        words = shlex.split(line, comments=True)
        while words:
            part = words[:words.index("&&")] if "&&" in words else words
            out.append(part)
            words = words[len(part) + 1:]
    return out


def _argv(words: list[str]) -> list[str]:
    if words[0] == "ecatcfg":
        return [*ECATCFG, *words[1:]]
    if words[0] in ("python3", "python"):
        return [*PYTHON, *words[1:]]
    return words


class Bench:
    """The temporary folder, the placeholders, and the bus when a command needs one."""

    def __init__(self, folder: Path, corpus: Path) -> None:
        self.folder, self.subs = folder, placeholders(corpus)
        self._rig: rig.VethRig | None = None
        self._rigs: list = []
        self.ran: list[str] = []            # the commands run, as the docs write them
        (folder / "examples").symlink_to(ROOT / "examples")
        # The ENI the runtime examples open (README tour: compile's first example).
        self.run(["ecatcfg", "compile", "examples/topology.yaml", "--esi", "examples/esi",
                  "-o", "line.eni.xml"])

    def substitute(self, text: str) -> str:
        for stand_in, real in self.subs.items():
            text = text.replace(stand_in, real)
        return text

    def bus(self) -> rig.VethRig:
        """A veth pair whose B end the example line answers on (simulate)."""
        if self._rig is None:
            self._rig = self._new_rig()
            sim, lines = rig.start_simulate(self._rig, "--esi", str(ROOT / "examples/esi"),
                                            "--topology", str(ROOT / "examples/topology.yaml"),
                                            duration=600)
            assert lines and lines[-1].startswith("ready:"), lines
        return self._rig

    def _new_rig(self) -> rig.VethRig:
        context = rig.veth_pair("doc")
        found = context.__enter__()
        self._rigs.append(context)
        return found

    def close(self) -> None:
        for context in reversed(self._rigs):
            context.__exit__(None, None, None)

    def run(self, words: list[str], where: str = "") -> None:
        out_file = None
        if ">" in words:
            words, out_file = words[:words.index(">")], words[words.index(">") + 1]
        if words[:2] == ["ecatcfg", "simulate"]:
            return self.simulate(words, where)
        argv = _argv(words)
        self.ran.append(shlex.join(words))
        if IFACE in words:
            bus = self.bus()
            argv = [bus.if_a if w == IFACE else w for w in argv]
            done = bus.run_in(bus.ns_a, argv, timeout=120, cwd=self.folder, text=False)
        else:
            done = subprocess.run(argv, cwd=self.folder, capture_output=True, timeout=120)
        err = done.stderr.decode(errors="replace")
        # lint and check exit 1 on an error finding, diff when the files differ, as the docs say.
        allowed = (0, 1) if words[:2] in (["ecatcfg", "lint"], ["ecatcfg", "check"],
                                          ["ecatcfg", "diff"], ["ecatcfg", "doctor"]) \
            else (0,)
        assert done.returncode in allowed and "Traceback" not in err, (
            f"{where}: {shlex.join(words)} exited {done.returncode}:\n{err[-3000:]}")
        if out_file is not None:
            (self.folder / out_file).write_bytes(done.stdout)

    def simulate(self, words: list[str], where: str) -> None:
        """``simulate``: up to ``ready:`` on a veth end of its own, then SIGINT (Ctrl-C);
        it must stop by itself with exit 0."""
        pair = self._new_rig()
        argv = _argv(words)
        self.ran.append(shlex.join(words))
        iface = argv[argv.index("--iface") + 1]
        argv[argv.index("--iface") + 1] = pair.if_b
        sim = pair.popen_in(pair.ns_b, argv, cwd=self.folder, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
        assert sim.stdout is not None
        lines = []
        for line in sim.stdout:
            lines.append(line)
            if line.startswith("ready:"):
                break
        assert lines and lines[-1].startswith("ready:"), (
            f"{where}: simulate on {iface} never got ready: {lines} {sim.stderr.read()}")
        os.killpg(sim.pid, signal.SIGINT)
        sim.communicate(timeout=20)
        assert sim.returncode == 0, f"{where}: simulate exited {sim.returncode} on SIGINT"


def run_example(example: Example, bench: Bench) -> None:
    text = bench.substitute(example.text)
    if example.lang == "sh":
        for words in commands(text):
            bench.run(words, str(example))
        return
    script = bench.folder / "example.py"
    script.write_text(text)
    argv = [*PYTHON, str(script)]
    if "RawLink(" in text:
        bus = bench.bus()
        script.write_text(text.replace(f'"{IFACE}"', f'"{bus.if_a}"'))
        done = bus.run_in(bus.ns_a, argv, timeout=120, cwd=bench.folder)
    else:
        done = subprocess.run(argv, cwd=bench.folder, capture_output=True, text=True,
                              timeout=120)
    assert done.returncode == 0, f"{example}: the Python example failed:\n{done.stderr[-3000:]}"


# ------------------------------------------------------------------------------------ tests

def test_examples_not_run_are_marked_with_a_reason_and_few():
    found = examples()
    marked = [e for e in found if e.not_run]
    assert len(found) >= 12, [str(e) for e in found]
    assert len(marked) <= MAX_NOT_RUN, [f"{e}: {e.not_run}" for e in marked]
    assert all(len(e.not_run or "") > 20 for e in marked)


def test_commands_of_a_block():
    assert commands("a b  # c\nd 'e f' && g > h\n\n# only a comment\n") == [
        ["a", "b"], ["d", "e f"], ["g", ">", "h"]]


@pytest.fixture
def bench(tmp_path, corpus):
    rig.require_netns()
    made = Bench(tmp_path, corpus)
    yield made
    made.close()


def test_every_example_in_the_docs_runs(bench):
    run = [e for e in examples() if e.not_run is None]
    for example in run:
        run_example(example, bench)
    # The bus commands ran too: on the simulated line, and simulate itself.
    on_bus = [c for c in bench.ran if IFACE in c.split()]
    assert len(on_bus) >= 6 and any(c.startswith("ecatcfg simulate") for c in bench.ran), \
        bench.ran
    assert sum(e.lang == "python" for e in run) >= 3


def test_a_broken_example_fails(bench, tmp_path):
    """The runner notices an example broken on purpose: an option misspelt in a copy of
    the tour's compile command, and a Python example that names a variable the ENI lacks."""
    doc = tmp_path / "broken.md"
    doc.write_text("```sh\necatcfg compile examples/topology.yaml --esi examples/esi "
                   "--outptu x.eni.xml\n```\n\n```python\nfrom ecatcfg.runtime import Network"
                   "\nfrom ecatcfg.runtime.link import RawLink\nwith Network('line.eni.xml', "
                   "RawLink(\"eth1\")) as net:\n    net.up()\n    net['no such'] = 1\n```\n")
    broken = examples([doc])
    assert [e.lang for e in broken] == ["sh", "python"]
    with pytest.raises(AssertionError, match="exited 2"):
        run_example(broken[0], bench)
    with pytest.raises(AssertionError, match="no process variable 'no such'"):
        run_example(broken[1], bench)
