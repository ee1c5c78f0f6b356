"""``ecatcfg export --format soem-c``: the C source and header it writes, built with gcc
against SOEM's own sources (from the pysoem source archive in the corpus, unpacked into a
temporary folder), link into a program that takes ``ecatcfg simulate`` of the example line
over a veth pair to OP with the ENI's PDO assignment and runs 1,000 cycles without
working-counter errors.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
from conftest import EXAMPLES, compile_example
from rig import start_simulate
from test_export_pysoem import send_recv_bits

SOEM_ARCHIVE = "third-party/pysoem-1.1.13.tar.gz"
# How long a cycle waits for its frame: the emulated slaves are a Python process on a
# loaded 2-core machine, whose reply can take longer than SOEM's 2 ms default
# (EC_TIMEOUTRET); a frame still missing after this counts as a working-counter error.
REPLY_US = "50000"


def export_c(eni: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "soem-c", "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=60)


@pytest.fixture(scope="module")
def soem_sources(corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SOEM's source tree (``soem/`` of the pysoem archive), unpacked for this test."""
    if shutil.which("gcc") is None:
        pytest.fail("gcc is not installed")
    folder = tmp_path_factory.mktemp("soem-src")
    with tarfile.open(corpus / SOEM_ARCHIVE) as archive:
        members = [m for m in archive.getmembers() if "/soem/" in m.name]
        archive.extractall(folder, members=members, filter="data")
    return next(folder.glob("pysoem-*/soem"))


def build(soem: Path, source: Path, main: bool = True) -> Path:
    """gcc: the exported file strictly (-Werror), SOEM's own sources as SOEM builds them
    for pysoem (EC_VER2: the context API); linked into one program."""
    includes = [f"-I{soem / d}" for d in ("soem", "osal", "osal/linux", "oshw/linux")]
    defines = ["-D_GNU_SOURCE", "-DEC_VER2"] + (["-DECATCFG_MAIN"] if main else [])
    ours = source.with_suffix(".o")
    done = subprocess.run(["gcc", "-O2", "-std=c11", "-Wall", "-Wextra", "-Werror", "-c",
                           *defines, f"-I{source.parent}", *includes, str(source), "-o",
                           str(ours)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    program = source.with_suffix("")
    soem_files = [*sorted((soem / "soem").glob("*.c")), soem / "osal/linux/osal.c",
                  *sorted((soem / "oshw/linux").glob("*.c"))]
    done = subprocess.run(["gcc", "-O2", "-w", *defines, *includes, str(ours),
                           *map(str, soem_files), "-lpthread", "-lrt", "-o", str(program)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return program


@pytest.fixture(scope="module")
def example_eni(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return compile_example(tmp_path_factory.mktemp("export-c") / "line.eni.xml")


def test_the_c_export_reaches_op_and_runs_1000_cycles(veth_netns, soem_sources, example_eni,
                                                       tmp_path):
    source = tmp_path / "line.c"
    done = export_c(example_eni, source)
    assert done.returncode == 0, done.stderr
    program = build(soem_sources, source)
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(EXAMPLES / "topology.yaml"), duration=300)
    assert lines and lines[-1].startswith("ready: 5 slaves"), "".join(lines)
    run = veth_netns.run_in(veth_netns.ns_a,
                            [str(program), veth_netns.if_a, "1000", REPLY_US], timeout=240)
    assert run.returncode == 0, run.stdout + run.stderr
    # Each slave's output and input bits as SOEM mapped them: the ENI's Send and Recv.
    bits = [(int(o), int(i)) for o, i in
            re.findall(r"^slave \d+ bits (\d+) (\d+)$", run.stdout, re.M)]
    assert bits == send_recv_bits(example_eni)
    assert "state 8\n" in run.stdout, run.stdout
    assert re.search(r"^cycles 1000 wkc_errors 0 ", run.stdout, re.M), run.stdout


def test_the_header_asserts_its_offsets(soem_sources, example_eni, tmp_path):
    """A struct offset that is not the ENI's stops the build (the compile-time check)."""
    source = tmp_path / "line.c"
    assert export_c(example_eni, source).returncode == 0
    header = source.with_suffix(".h")
    text = header.read_text()
    assert "== 2, \"ecatcfg_axis1_4_out_t.axis1_rxpdo_2_csv_target_velocity\"" in text
    header.write_text(text.replace("    uint16_t axis1_rxpdo_2_csv_controlword;",
                                   "    uint32_t axis1_rxpdo_2_csv_controlword;"))
    with pytest.raises(AssertionError, match="static assertion failed"):
        build(soem_sources, source, main=False)


def test_the_c_export_is_deterministic_and_says_where_it_came_from(example_eni, tmp_path):
    import hashlib
    a, b = tmp_path / "a" / "line.c", tmp_path / "b" / "line.c"
    for path in (a, b):
        path.parent.mkdir()
        assert export_c(example_eni, path).returncode == 0
    assert a.read_bytes() == b.read_bytes()
    assert a.with_suffix(".h").read_bytes() == b.with_suffix(".h").read_bytes()
    digest = hashlib.sha256(example_eni.read_bytes()).hexdigest()
    header = a.with_suffix(".h").read_text()
    assert f'#define ECATCFG_ENI_SHA256 "{digest}"' in header
    assert '#define ECATCFG_ENI_NAME "line.eni.xml"' in header
    assert '#include "line.h"' in a.read_text()


def test_ec_engineer_elmo_eni_gives_soem_what_our_eni_gives(veth_netns, soem_sources,
                                                            corpus, tmp_path):
    """The Elmo drive of an EC-Engineer export in the corpus and our ENI compiled for the
    same drive (same PDOs, DC mode and SDOs): the C programs exported from each map the
    same bits, reach OP and run 1,000 cycles without working-counter errors."""
    from test_export_pysoem import ELMO_TOPOLOGY
    topo = tmp_path / "elmo.yaml"
    topo.write_text(ELMO_TOPOLOGY)
    ours = tmp_path / "ours.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(corpus / "esi" / "drives"), "-o", str(ours), "--no-cache"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    theirs = corpus / "eni" / "rocos-ethercat" / "eni.xml"
    results = []
    for eni in (theirs, ours):
        source = tmp_path / eni.stem / "drive.c"
        source.parent.mkdir()
        done = export_c(eni, source)
        assert done.returncode == 0, done.stderr
        program = build(soem_sources, source)
        sim, lines = start_simulate(veth_netns, "--esi", str(corpus / "esi" / "drives"),
                                    "--topology", str(topo), duration=300)
        assert lines and lines[-1].startswith("ready: 1 slaves"), "".join(lines)
        run = veth_netns.run_in(veth_netns.ns_a,
                                [str(program), veth_netns.if_a, "1000", REPLY_US],
                                timeout=240)
        sim.terminate()
        sim.communicate(timeout=20)
        assert run.returncode == 0, run.stdout + run.stderr
        bits = [(int(o), int(i)) for o, i in
                re.findall(r"^slave \d+ bits (\d+) (\d+)$", run.stdout, re.M)]
        assert bits == send_recv_bits(eni)
        assert "state 8\n" in run.stdout, run.stdout
        assert re.search(r"^cycles 1000 wkc_errors 0 ", run.stdout, re.M), run.stdout
        results.append(bits)
    assert results[0] == results[1]


def test_small_terminals_in_c_where_soem_packs_them(veth_netns, soem_sources, corpus,
                                                    tmp_path):
    """The small-terminal line of test_export_soem_layout.py through the C export: SOEM's
    mapping agrees with the header (ecatcfg_config_map checks each slave's bits, IOmap
    place and start bit and returns 0), and every variable read through ECATCFG_VARIABLES
    is what the emulated slave holds, every output written through it what the slave
    gets.  A header number changed by hand makes ecatcfg_config_map fail naming the
    slave."""
    from export_agreement import eni_variables
    from rig import serving
    from test_export_soem_layout import SMALL_LINE

    from ecatcfg.eni.reader import read_file
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate

    beckhoff = corpus / "esi" / "beckhoff"
    topo = tmp_path / "small.yaml"
    topo.write_text(SMALL_LINE)
    eni = tmp_path / "small.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(beckhoff), "-o", str(eni), "--no-cache"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    source = tmp_path / "small.c"
    assert export_c(eni, source).returncode == 0
    program = build(soem_sources, source)
    seg = emulate.segment(emulate.specs_from_eni(read_file(eni),
                                                 Library([beckhoff], cache=False), str(eni)))
    variables, _ = eni_variables(eni)
    pattern = bytes.fromhex("a5c3")            # each slave's inputs; 0x5A for the outputs
    outputs: dict[int, bytes] = {}

    def keep(k: int, slave):
        original = slave.outputs_written

        def written(now: float | None = None) -> None:
            original(now)
            if slave.state == 8:                # the program leaves OP (outputs zero) last
                outputs[k] = slave.outputs()
        return written
    for k, s in enumerate(seg.slaves):
        s.outputs_written = keep(k, s)
    with serving(veth_netns, seg):
        for s in seg.slaves:
            s.set_inputs(pattern[:sum(n for _, n in s.input_areas())])
        run = veth_netns.run_in(veth_netns.ns_a, [str(program), veth_netns.if_a, "50",
                                                  REPLY_US, "5a"], timeout=240)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "state 8\n" in run.stdout, run.stdout
    printed = re.findall(r"^var (\d+) (\d+) (.*)$", run.stdout, re.M)
    values = {name: (int(i), int(v)) for i, v, name in printed}
    assert len(values) == len(variables) == 36
    checked = 0
    for v in variables:
        index, value = values[v.name]
        if v.direction == "input":
            assert value == pattern[v.offset // 8] >> v.offset % 8 & 1, v.name
        else:
            # the program set it to 0x5A.. >> index % 8; the emulated slave has it
            assert value == 0x5A >> index % 8 & 1, v.name
            got = outputs[v.slave][v.offset // 8] >> v.offset % 8 & 1
            assert got == value, v.name
        checked += 1
    assert checked == 36
    # A start bit in the C table changed by hand: the mapping check names the slave.
    text = source.read_text()
    row = "{ 0, 0, 0, 4, 2, 2 },    /* sensors */"
    assert row in text, text
    source.write_text(text.replace(row, "{ 0, 0, 0, 4, 2, 0 },    /* sensors */"))
    program = build(soem_sources, source)
    seg = emulate.segment(emulate.specs_from_eni(read_file(eni),
                                                 Library([beckhoff], cache=False), str(eni)))
    with serving(veth_netns, seg):
        run = veth_netns.run_in(veth_netns.ns_a, [str(program), veth_netns.if_a, "5",
                                                  REPLY_US], timeout=240)
    assert run.returncode == 1
    assert "slave 2: SOEM mapped inputs: 4 bit(s) at IOmap byte 2 bit 2, the header has 4 " \
           "at byte 2 bit 0" in run.stderr, run.stderr


def test_a_refused_sdo_is_returned_with_slave_object_and_abort_code(veth_netns,
                                                                    soem_sources,
                                                                    example_eni, tmp_path):
    """The start-up SDO moved to an object the drive does not have: ecatcfg_config_map
    returns non-zero with the slave, the object and the abort code (0x06020000, object
    does not exist), and the program stops before SAFEOP."""
    from lxml import etree
    tree = etree.parse(str(example_eni))
    cmd = tree.xpath("//CoE/InitCmds/InitCmd[Index='24672']")[0]
    cmd.find("Index").text = str(0x2FFF)
    eni = tmp_path / "refused.xml"
    tree.write(str(eni), xml_declaration=True, encoding="utf-8")
    source = tmp_path / "refused.c"
    assert export_c(eni, source).returncode == 0
    program = build(soem_sources, source)
    sim, lines = start_simulate(veth_netns, "--esi", str(EXAMPLES / "esi"), "--topology",
                                str(EXAMPLES / "topology.yaml"), duration=300)
    assert lines and lines[-1].startswith("ready: 5 slaves"), "".join(lines)
    run = veth_netns.run_in(veth_netns.ns_a, [str(program), veth_netns.if_a, "5", REPLY_US],
                            timeout=240)
    assert run.returncode == 1, run.stdout + run.stderr
    assert "slave 4: SDO 0x2FFF:00 = 9: refused, abort code 0x06020000\n" in run.stderr
    assert "ecatcfg_config_map: slave 4: SDO 0x2FFF:00 = 9: abort code 0x06020000" in \
        run.stderr
    assert "state" not in run.stdout


def test_the_c_export_of_every_corpus_eni_compiles(soem_sources, corpus, corpus_extra,
                                                   tmp_path):
    """Every real ENI the export accepts gives C that gcc takes with -Wall -Wextra -Werror,
    its struct offsets asserted (names with line breaks, odd types and bit entries of
    real files included)."""
    from ecatcfg.eni.export.steps import ExportError, slave_setups
    from ecatcfg.eni.reader import read_file
    from ecatcfg.errors import EcatcfgError
    built = 0
    for eni in sorted([*corpus.glob("eni/**/*.xml"), *corpus_extra.glob("eni/**/*.xml")]):
        try:
            setups = slave_setups(read_file(eni), eni)
        except (ExportError, EcatcfgError):
            continue                          # refused by name: test_export_corpus.py
        source = tmp_path / f"eni{built}.c"
        done = export_c(eni, source)
        assert done.returncode == 0, done.stderr
        assert len(setups) > 0
        includes = [f"-I{soem_sources / d}" for d in ("soem", "osal", "osal/linux",
                                                       "oshw/linux")]
        done = subprocess.run(["gcc", "-fsyntax-only", "-std=c11", "-Wall", "-Wextra",
                               "-Werror", "-D_GNU_SOURCE", "-DEC_VER2", "-DECATCFG_MAIN",
                               f"-I{tmp_path}", *includes, str(source)],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, f"{eni}: {done.stderr}"
        built += 1
    assert built >= 10
