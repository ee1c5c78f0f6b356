"""Outputs that are not regular files: a character device or a FIFO given as an output is
written directly and stays what it was, ``-`` is standard output, anything else is refused;
only a regular file (or a new path) is written beside and renamed over.

Renaming over ``-o /dev/null`` as root replaced the machine's ``/dev/null`` with a regular
file.  These tests make their own node in a temporary folder (``mknod``: a character device
with /dev/null's numbers, 1:3), never the real one.
"""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from conftest import EXAMPLES, ROOT, compile_example
from ecatcfg.errors import UsageError
from ecatcfg.fileio import write_atomic

TOPOLOGY = str(EXAMPLES / "topology.yaml")
ESI = str(EXAMPLES / "esi")
NULL = os.makedev(1, 3)                     # Linux: /dev/null's major and minor


def ecatcfg(*args: str, timeout: float = 120,
            cwd: Path = ROOT) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", *args], capture_output=True,
                          cwd=cwd, timeout=timeout, stdin=subprocess.DEVNULL)


@pytest.fixture
def null(tmp_path) -> Path:
    """A character device like /dev/null in a folder of its own (needs root: CAP_MKNOD)."""
    folder = tmp_path / "dev"
    folder.mkdir()
    node = folder / "null"
    try:
        os.mknod(node, 0o666 | stat.S_IFCHR, NULL)
    except PermissionError:
        pytest.skip("mknod needs CAP_MKNOD")
    return node


def _still_the_node(node: Path) -> None:
    st = os.lstat(node)
    assert stat.S_ISCHR(st.st_mode) and st.st_rdev == NULL, oct(st.st_mode)
    # Nothing was left beside it (a temporary file of an atomic write).
    assert [p.name for p in node.parent.iterdir()] == [node.name]


@pytest.fixture(scope="module")
def eni(tmp_path_factory) -> Path:
    return compile_example(tmp_path_factory.mktemp("eni") / "example.eni.xml")


def _writers(eni: Path, out: str) -> dict[str, list[str]]:
    """Every command that writes a file offline, writing it to ``out``."""
    return {
        "compile -o": ["compile", TOPOLOGY, "--esi", ESI, "-o", out, "--no-cache"],
        "compile --header": ["compile", TOPOLOGY, "--esi", ESI, "-o",
                             str(Path(out).parent.parent / "x.eni.xml"), "--header", out],
        "export pysoem": ["export", str(eni), "--format", "pysoem", "-o", out],
        "report": ["report", str(eni), "-o", out],
        "graph": ["graph", str(eni), "-o", out],
        "check -o": ["check", str(eni), "-o", out],
        "lint -o": ["lint", ESI, "-o", out, "--no-config"],
        "sii build": ["sii", "build", ESI, "--device", "EX1100", "-o", out],
        "apply --pcap": ["apply", str(eni), "--virtual", "--esi", ESI, "--simulated-time",
                         "--cycles", "2", "--pcap", out],
    }


WRITERS = list(_writers(Path("x"), "y"))


@pytest.mark.parametrize("command", WRITERS)
def test_a_character_device_stays_one(command, null, eni):
    done = ecatcfg(*_writers(eni, str(null))[command])
    assert done.returncode == 0, done.stderr.decode()
    _still_the_node(null)


def _read_fifo(fifo: Path) -> tuple[threading.Thread, list[bytes]]:
    got: list[bytes] = []

    def reader() -> None:
        with open(fifo, "rb") as f:
            got.append(f.read())
    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    return thread, got


@pytest.mark.parametrize("command", ["compile -o", "report", "apply --pcap"])
def test_a_fifo_is_written_through_and_stays_a_fifo(command, tmp_path, eni):
    (tmp_path / "io").mkdir()
    fifo = tmp_path / "io" / "out"
    os.mkfifo(fifo)
    thread, got = _read_fifo(fifo)
    done = ecatcfg(*_writers(eni, str(fifo))[command])
    thread.join(timeout=60)
    assert done.returncode == 0, done.stderr.decode()
    assert not thread.is_alive(), "the FIFO was never written"
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert [p.name for p in fifo.parent.iterdir()] == ["out"]
    # What came through is the whole output: the same as a regular file gets.
    regular = tmp_path / "io" / "regular"
    assert ecatcfg(*_writers(eni, str(regular))[command]).returncode == 0
    if command == "apply --pcap":
        # pcapng: a Section Header Block first (its type, then the byte-order magic), and
        # the same number of frames (Enhanced Packet Blocks) are not compared: timestamps.
        assert got[0][:4] == b"\x0a\x0d\x0d\x0a" and got[0][8:12] == b"\x4d\x3c\x2b\x1a"
        assert len(got[0]) > 1000
    elif command == "report":
        assert got[0].startswith(b"<!DOCTYPE html>") and got[0].rstrip().endswith(b"</html>")
    else:
        assert got[0] == regular.read_bytes()


@pytest.mark.parametrize("command", ["compile -o", "export pysoem", "report", "graph",
                                     "check -o", "sii build"])
def test_dash_is_standard_output(command, tmp_path, eni):
    regular = tmp_path / "regular"
    to_file = ecatcfg(*_writers(eni, str(regular))[command])
    to_stdout = ecatcfg(*_writers(eni, "-")[command], cwd=tmp_path)   # a file '-' lands here
    assert to_stdout.returncode == to_file.returncode == 0, to_stdout.stderr.decode()
    if command == "report":                 # the page names the file it reports on only
        assert to_stdout.stdout.startswith(b"<!DOCTYPE html>")
    else:
        assert to_stdout.stdout == regular.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["regular"]


def test_compile_to_stdout_says_what_it_wrote_on_stderr(tmp_path):
    done = ecatcfg("compile", TOPOLOGY, "--esi", ESI, "-o", "-", cwd=tmp_path)
    assert done.returncode == 0
    assert done.stdout.startswith(b"<?xml") and b"wrote -: 5 slaves" in done.stderr


@pytest.mark.parametrize("args, message", [
    (["export", "{eni}", "--format", "soem-c", "-o", "-"], "soem-c writes two files"),
    (["apply", "{eni}", "--virtual", "--esi", ESI, "--pcap", "-"],
     "cannot go to standard output"),
    (["compile", TOPOLOGY, "--esi", ESI, "-o", "-", "--header", "-"],
     "must be three different files"),
])
def test_dash_where_stdout_cannot_take_it_is_refused(args, message, eni, tmp_path):
    done = ecatcfg(*[a.format(eni=eni) for a in args], timeout=60, cwd=tmp_path)
    assert done.returncode == 2 and message in done.stderr.decode(), done.stderr.decode()


def test_a_socket_is_refused_and_left_alone(tmp_path):
    path = tmp_path / "s"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(path))
        done = ecatcfg("compile", TOPOLOGY, "--esi", ESI, "-o", str(path))
        assert done.returncode == 2
        assert f"{path}: is a socket, not a file to write" in done.stderr.decode()
        assert stat.S_ISSOCK(os.lstat(path).st_mode)


def test_write_atomic_writes_a_node_directly_and_a_regular_file_atomically(null, tmp_path):
    write_atomic(null, b"data")
    _still_the_node(null)
    target = tmp_path / "file"
    target.write_bytes(b"old")
    inode = os.stat(target).st_ino
    write_atomic(target, b"new")
    assert target.read_bytes() == b"new" and os.stat(target).st_ino != inode   # renamed
    with pytest.raises(UsageError, match="is a folder, not a file to write"):
        write_atomic(tmp_path, b"x")
