"""Inputs that are not what they seem: a path that is not a regular file, one too large to
be an EtherCAT description, a file that is not XML.

Every command reads its files through ``fileio.read_input``; a device node, a FIFO or a pipe
has no end, and read whole it grew memory until a ``MemoryError`` or the OOM killer.  Each
command here runs in a child whose address space is capped, so a regression fails the test
(a traceback, a timeout) instead of taking the machine's memory.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import EXAMPLES, ROOT, write
from ecatcfg import fileio
from ecatcfg.errors import UsageError

# Python, lxml and the runtime take a few hundred MB of address space; an input read whole
# from /dev/zero passes this in well under a second.
_ADDRESS_SPACE = 2 << 30
TOPOLOGY = str(EXAMPLES / "topology.yaml")
ESI = str(EXAMPLES / "esi")


def _capped() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (_ADDRESS_SPACE, _ADDRESS_SPACE))


def ecatcfg(*args: str, stdin: object = subprocess.DEVNULL,
            timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", *args], capture_output=True,
                          text=True, cwd=ROOT, stdin=stdin, preexec_fn=_capped,
                          timeout=timeout)


def _commands(bad: str, tmp: Path) -> dict[str, list[str]]:
    """Every command and option that reads a user's file, with ``bad`` in that place."""
    out = str(tmp / "out")
    return {
        "compile topology": ["compile", bad, "--esi", ESI, "-o", out + ".xml"],
        "compile --esi": ["compile", TOPOLOGY, "--esi", bad, "-o", out + ".xml"],
        "sii show": ["sii", "show", bad],
        "sii build": ["sii", "build", bad, "--device", "EX1100", "-o", out + ".bin"],
        "apply --virtual": ["apply", bad, "--virtual", "--cycles", "1"],
        "graph": ["graph", bad],
        "simulate --eni": ["simulate", "--eni", bad, "--iface", "ecatcfg-none0"],
        "simulate --topology": ["simulate", "--topology", bad, "--esi", ESI,
                                "--iface", "ecatcfg-none0"],
        "simulate --timing": ["simulate", "--topology", TOPOLOGY, "--esi", ESI,
                              "--timing", bad, "--iface", "ecatcfg-none0"],
        "show": ["show", bad],
        "check": ["check", bad],
        "report": ["report", bad, "-o", out + ".html"],
        "export": ["export", bad, "--format", "pysoem", "-o", out + ".py"],
        "diff": ["diff", bad, TOPOLOGY],
        "lint": ["lint", bad],
        "lint --config": ["lint", ESI, "--config", bad],
        "devices": ["devices", bad],
    }


COMMANDS = list(_commands("X", Path("/")))


def _refused(done: subprocess.CompletedProcess[str], shown: str, what: str) -> None:
    assert "Traceback" not in done.stderr and "MemoryError" not in done.stderr, done.stderr
    assert done.returncode == 2, done.stderr
    assert f"{shown}: is {what}, not a regular file" in done.stderr, done.stderr


@pytest.mark.parametrize("command", COMMANDS)
def test_a_character_device_is_refused_by_every_command(command, tmp_path):
    done = ecatcfg(*_commands("/dev/zero", tmp_path)[command])
    _refused(done, "/dev/zero", "a character device")


@pytest.mark.parametrize("command", ["compile topology", "apply --virtual", "sii show",
                                     "simulate --timing", "devices", "check"])
def test_a_fifo_without_a_writer_is_refused_not_waited_on(command, tmp_path):
    fifo = tmp_path / "in.xml"
    os.mkfifo(fifo)
    done = ecatcfg(*_commands(str(fifo), tmp_path)[command], timeout=30)
    _refused(done, str(fifo), "a FIFO or pipe")


@pytest.mark.parametrize("command", ["compile topology", "apply --virtual", "graph"])
def test_an_endless_pipe_is_refused(command, tmp_path):
    """``ecatcfg compile /dev/stdin < <(yes)``: the pipe never ends."""
    yes = subprocess.Popen(["yes", "<EtherCATConfig>"], stdout=subprocess.PIPE)
    try:
        assert yes.stdout is not None
        done = ecatcfg(*_commands("/dev/stdin", tmp_path)[command], stdin=yes.stdout,
                       timeout=30)
    finally:
        yes.kill()
        yes.wait()
    _refused(done, "/dev/stdin", "a FIFO or pipe")


def test_a_file_past_the_size_bound_is_refused_before_it_is_read(tmp_path):
    # Sparse: the file system stores none of it, and nothing of it is read.
    huge = tmp_path / "huge.yaml"
    with open(huge, "wb") as f:
        f.truncate(fileio.MAX_INPUT_BYTES + 1)
    done = ecatcfg("compile", str(huge), "--esi", ESI, "-o", str(tmp_path / "out.xml"))
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert f"{huge}: larger than {fileio.MAX_INPUT_BYTES >> 20} MiB" in done.stderr
    assert not (tmp_path / "out.xml").exists()


def test_the_bound_holds_at_exactly_its_size(tmp_path):
    at = write(tmp_path, "at.bin", b"x" * 10)
    assert fileio.read_input(at, limit=10) == b"x" * 10
    past = write(tmp_path, "past.bin", b"x" * 11)
    with pytest.raises(UsageError, match=r"past\.bin: larger than"):
        fileio.read_input(past, limit=10)
    # A regular file whose size says 0 but that has more (procfs): the bound holds on what
    # is read, not only on the size the file system reports.
    assert os.stat("/proc/self/maps").st_size == 0
    with pytest.raises(UsageError, match="larger than"):
        fileio.read_input("/proc/self/maps", limit=10)


def test_a_missing_file_is_still_the_readers_own_error(tmp_path):
    """read_input leaves a missing file to its caller's words (``OSError``)."""
    with pytest.raises(FileNotFoundError):
        fileio.read_input(tmp_path / "none.xml")
    done = ecatcfg("compile", str(tmp_path / "none.yaml"), "--esi", ESI, "-o",
                   str(tmp_path / "o.xml"))
    assert done.returncode == 2 and "none.yaml: no such file" in done.stderr


# -- a file that is not XML given where an ENI is expected ----------------------------------

NOT_XML = {
    "a topology": b"slaves:\n  - {name: a, device: EX1100}\n",
    "binary": b"\x00\x01\x02\xff\xfe garbage",
    "text after blank lines": b"\n\n   plain text, no markup\n",
}


@pytest.mark.parametrize("what", list(NOT_XML))
@pytest.mark.parametrize("command", ["report", "export", "show"])
def test_a_file_that_is_not_xml_is_called_what_it_is(command, what, tmp_path):
    """report and export said "not an ENI (topology)" of anything that was not XML; now
    they say what apply and check say: the XML parser's reason, at its line and column.
    The reference is lxml itself, parsing the same bytes."""
    from lxml import etree
    data = NOT_XML[what]
    path = write(tmp_path, "input.xml", data)
    with pytest.raises(etree.XMLSyntaxError) as parsed:
        etree.fromstring(data)
    line, column = parsed.value.position
    reason = parsed.value.msg.split(", line ")[0]
    done = ecatcfg(*_commands(str(path), tmp_path)[command])
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert f"{path}:{line}:{column}: not an ENI: not well-formed XML: {reason}" \
        in done.stderr, done.stderr
    assert "(topology)" not in done.stderr
    # apply says the same of the same file (its reader's words, exit 1)
    applied = ecatcfg("apply", str(path), "--virtual", "--cycles", "1")
    assert f"{path}:{line}:{column}: not well-formed XML: {reason}" in applied.stderr


@pytest.mark.parametrize("command", ["report", "export"])
def test_an_esi_is_called_an_esi_at_its_root_element(command, tmp_path):
    esi = write(tmp_path, "device.xml", b"<?xml version='1.0'?>\n<!-- a device -->\n"
                                        b"<EtherCATInfo/>\n")
    done = ecatcfg(*_commands(str(esi), tmp_path)[command])
    assert done.returncode == 2
    assert f"{esi}:3: not an ENI: the root element is <EtherCATInfo> (an ESI), expected " \
        "<EtherCATConfig>" in done.stderr


@pytest.mark.parametrize("command", ["lint", "devices", "compile --esi"])
def test_a_fifo_met_in_a_folder_is_refused_by_name(command, tmp_path):
    """A folder is searched for *.xml; a FIFO among them (no writer) is named and refused,
    not waited on."""
    import shutil
    folder = tmp_path / "esi"
    shutil.copytree(ESI, folder)
    fifo = folder / "zz.xml"
    os.mkfifo(fifo)
    done = ecatcfg(*_commands(str(folder), tmp_path)[command], timeout=30)
    _refused(done, str(fifo), "a FIFO or pipe")


def test_the_file_opened_is_checked_not_only_its_name(tmp_path, monkeypatch):
    """A name that passed the check and was then swapped for a FIFO: the opened file is
    refused too, and opening it did not wait for a writer (O_NONBLOCK)."""
    from conftest import FifoUnblock
    fifo = tmp_path / "swapped.xml"
    os.mkfifo(fifo)
    monkeypatch.setattr(fileio, "check_input", lambda *args: None)
    with FifoUnblock(fifo, seconds=10) as unblock:
        with pytest.raises(UsageError, match=r"swapped\.xml: is a FIFO or pipe"):
            fileio.read_input(fifo)
        with pytest.raises(UsageError, match=r"swapped\.xml: is a FIFO or pipe"):
            fileio.read_head(fifo)
    assert not unblock.needed
