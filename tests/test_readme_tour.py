"""The README's short tour writes its files into ``tour/``, which git ignores, never beside
the checkout's own files."""

from __future__ import annotations

import os
import re
import shlex
import subprocess

import pytest

from conftest import ROOT
from installed import ECATCFG

# The options of ecatcfg's commands that name a file to write, and the shell's redirection.
WRITES = ("-o", "--output", "--header", "--pcap", "--topology-out", ">")


def tour_commands() -> list[list[str]]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## A short tour", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```sh\n(.*?)\n```", section, re.S)
    assert block, "the tour has a shell block"
    commands = []
    for line in block.group(1).splitlines():
        for part in line.split("&&"):
            words = shlex.split(part, comments=True)
            if words:
                commands.append(words)
    return commands


def written(words: list[str]) -> list[str]:
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w in WRITES]


def test_every_file_the_tour_writes_is_under_the_ignored_tour_folder():
    commands = tour_commands()
    outputs = [out for words in commands for out in written(words)]
    assert len(outputs) >= 7, outputs        # ENIs, header, schema, pcap, scan, SII image
    assert all(out.startswith("tour/") for out in outputs), outputs
    assert commands[0] == ["mkdir", "-p", "tour"]
    ignored = (ROOT / ".gitignore").read_text().splitlines()
    assert "/tour/" in ignored


def test_the_tours_file_commands_write_only_into_tour(tmp_path):
    # The commands that need no bus nor the user's own files, run as written from a
    # folder laid out like the checkout (its examples/).
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    env = dict(os.environ)
    runnable = [w for w in tour_commands()
                if w[0] == "mkdir" or (w[0] == "ecatcfg" and w[1] in ("compile", "schema"))]
    assert len(runnable) == 4, runnable
    for words in runnable:
        out_file = None
        if ">" in words:
            words, out_file = words[:words.index(">")], words[words.index(">") + 1]
        argv = ([*ECATCFG, *words[1:]] if words[0] == "ecatcfg"
                else words)
        done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, timeout=120)
        assert done.returncode == 0, done.stderr
        if out_file is not None:
            (tmp_path / out_file).write_bytes(done.stdout)
    made = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")
                  if not str(p.relative_to(tmp_path)).startswith("examples"))
    assert made == ["tour", "tour/line.eni.xml", "tour/line.h", "tour/topology.schema.json",
                    "tour/tree.eni.xml"]


def test_tour_folder_is_ignored_by_git(tmp_path):
    # git itself says so (when the checkout is a git work tree).
    done = subprocess.run(["git", "check-ignore", "-q", "tour/line.eni.xml"], cwd=ROOT,
                          capture_output=True)
    if done.returncode == 128:           # not a git work tree (an unpacked sdist)
        pytest.skip("not a git work tree")
    assert done.returncode == 0, "tour/ is not ignored by git"

