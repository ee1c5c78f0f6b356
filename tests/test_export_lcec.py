"""``ecatcfg export --format lcec``: the ``ethercat.xml`` it writes is read by LinuxCNC
EtherCAT's own configuration parser, built unchanged from the linuxcnc-ethercat archive of
the corpus (``src/lcec_conf.c``, ``lcec_conf_util.c``, ``lcec_conf_icmds.c``,
``lcec_malloc.c``, with libexpat) against the few HAL and RTAPI functions it calls
(``fixtures/lcec/``: the harness prints the configuration records the parser hands to
lcec's realtime part instead of waiting for HAL); for every ENI of both corpora the export
accepts, those records are the ENI's slaves, SyncManagers, PDO assignment and mapping,
start-up SDOs in order, DC, watchdog, cycle and reference clock as the test reads them
from the ENI with lxml, and each ENI variable's entry has a HAL pin.
"""

from __future__ import annotations

import hashlib
import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import prereq
import pytest
from conftest import corpus_eni, corpus_enis, plan_or_refused
from lxml import etree
from test_export_igh_c import _accepted, _int, eni_expectations

LCEC_ARCHIVE = "third-party/linuxcnc-ethercat.tar.gz"
IGH_ARCHIVE = "third-party/igh-ethercat-master-userspace.tar.gz"
FIXTURES = Path(__file__).parent / "fixtures" / "lcec"
PARSER_SOURCES = ("lcec_conf.c", "lcec_conf_util.c", "lcec_conf_icmds.c", "lcec_malloc.c")


@pytest.fixture(scope="module")
def lcec_conf(corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """lcec's configuration parser from the archive, linked with the HAL harness."""
    if shutil.which("gcc") is None:
        prereq.missing("gcc", "not on the PATH", prereq.TOOLS)
    if not Path("/usr/include/expat.h").is_file():
        # lcec's parser is built on libexpat (Debian's libexpat1-dev, which the Python
        # headers' package depends on)
        prereq.missing("libexpat's header", "/usr/include/expat.h not found", prereq.TOOLS)
    folder = tmp_path_factory.mktemp("lcec")
    with tarfile.open(corpus / LCEC_ARCHIVE) as archive:
        members = [m for m in archive.getmembers()
                   if re.search(r"(^|/)src/[^/]+\.[ch]$", m.name)]
        archive.extractall(folder, members=members, filter="data")
    with tarfile.open(corpus / IGH_ARCHIVE) as archive:
        member = next(m for m in archive.getmembers() if m.name.endswith("include/ecrt.h"))
        archive.extractall(folder, members=[member], filter="data")
    src = next(folder.rglob("lcec_conf.c")).parent
    include = next(folder.rglob("ecrt.h")).parent
    program = folder / "lcec_conf"
    # lcec's own sources as they are (their warnings are theirs: -w); the harness strictly.
    objects = []
    for name in PARSER_SOURCES:
        obj = folder / name.replace(".c", ".o")
        done = subprocess.run(["gcc", "-std=gnu11", "-w", f"-I{FIXTURES}", f"-I{src}",
                               f"-I{include}", "-c", str(src / name), "-o", str(obj)],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        objects.append(str(obj))
    done = subprocess.run(["gcc", "-std=gnu11", "-Wall", "-Wextra", "-Werror",
                           f"-I{FIXTURES}", f"-I{src}", f"-I{include}",
                           str(FIXTURES / "harness.c"), *objects, "-lexpat", "-o",
                           str(program)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return program


def parse(lcec_conf: Path, xml: Path) -> list[str]:
    # (an initCmds file is opened by its name as given: from the folder of the XML)
    done = subprocess.run([str(lcec_conf), xml.name], capture_output=True, text=True,
                          timeout=60, cwd=xml.parent)
    assert done.returncode == 0, f"{xml}: {done.stdout}{done.stderr}"
    lines = done.stdout.splitlines()
    assert lines[-1] == "end", lines[-5:]
    return lines[:-1]


def by_slave(records: list[str]) -> tuple[str, list[dict[str, list[str]]]]:
    """(the master record, each slave's records by kind, in the file's order)."""
    master, slaves = "", []
    for line in records:
        kind = line.split(" ", 1)[0]
        if kind == "master":
            master = line
        elif kind == "slave":
            slaves.append({"slave": [line]})
        else:
            slaves[-1].setdefault(kind, []).append(line)
    return master, slaves


def expected_records(path: Path) -> tuple[str, list[dict[str, list[str]]], list[tuple]]:
    """What lcec must read for the ENI: the master record (but its name), each slave's
    records by kind (the slave's name left out), and the ENI's variables (name, slave,
    PDO, bit offset in the PDO), from the calls IgH must be given (test_export_igh_c)."""
    calls, variables = eni_expectations(path)
    root = etree.parse(str(path)).getroot()
    cycle_us = root.findtext("Config/Cyclic/CycleTime")
    slaves: list[dict[str, list[str]]] = []
    reference = -1
    dc_cycles = []
    for call in calls:
        kind, *f = call.split()
        if kind == "slave_config":
            slaves.append({"slave": [f"slave {f[1]} generic {f[2]} {f[3]}"]})
            continue
        slave = slaves[-1] if kind != "reference_clock" else {}
        if kind == "sync":
            slave.setdefault("sync", []).append(f"sync {f[1]} {f[2]} {f[4]}")
        elif kind == "pdo":
            slave.setdefault("pdo", []).append(f"pdo {f[2]} {f[3]}")
        elif kind == "entry":
            slave.setdefault("entry", []).append(f"entry {f[3]} {f[4]} {f[5]}")
        elif kind in ("sdo", "complete_sdo"):
            sub = "-1" if kind == "complete_sdo" else f[2]
            slave.setdefault("sdo", []).append(f"sdo {f[1]} {sub} {f[3]}")
        elif kind == "dc":
            slave["dc"] = [f"dc {' '.join(f[1:])}"]
            dc_cycles.append(int(f[2]))
        elif kind == "watchdog":
            slave["watchdog"] = [f"watchdog {f[1]} {f[2]}"]
        elif kind == "reference_clock":
            reference = int(f[0])
    cycle = _int(cycle_us) * 1000 if cycle_us else (dc_cycles[0] if dc_cycles else 1_000_000)
    # refClockSyncCycles 1 with DC: lcec syncs the reference clock every cycle (R2M)
    master = f"master 0 {cycle} {1 if dc_cycles else 0} 0 {reference}"
    return master, slaves, variables


def _comparable(slaves: list[dict[str, list[str]]]) -> list[dict[str, list[str]]]:
    """The parsed records as expected_records has them: a slave without its configPdos
    and name, entries without their pins."""
    out = []
    for s in slaves:
        s = dict(s)
        s["slave"] = [" ".join(s["slave"][0].split()[:5])]
        if "entry" in s:
            s["entry"] = [" ".join(e.split()[:4]) for e in s["entry"]]
        s.pop("complex", None)
        out.append(s)
    return out


def pinned(slaves: list[dict[str, list[str]]], records: list[str]) -> set[tuple[int, int, int]]:
    """(slave, PDO, bit offset in the PDO) of each entry with a pin (or complex pins)."""
    out = set()
    position, pdo, bit = -1, 0, 0
    for line in records:
        f = line.split()
        if f[0] == "slave":
            position = int(f[1])
        elif f[0] == "pdo":
            pdo, bit = int(f[1]), 0
        elif f[0] == "entry":
            if f[6] != "-" or f[5] == "3":          # a pin, or lcecPdoEntTypeComplex
                out.add((position, pdo, bit))
            bit += int(f[3])
    return out


def _variable_entries(path: Path, variables: list[tuple]) -> set[tuple[int, int, int]]:
    """(slave, PDO, bit) of each variable's first entry that is not a gap."""
    root = etree.parse(str(path)).getroot()
    slaves = [s for s in root.iterfind("Config/Slave")
              if s.find("Info/PhysAddr") is not None or s.find("Info/AutoIncAddr") is not None]
    out = set()
    for _name, pos, pdo_index, bit in variables:
        pdo = next(p for p in slaves[pos].iterfind("ProcessData/*")
                   if p.tag in ("RxPdo", "TxPdo") and _int(p.findtext("Index")) == pdo_index
                   and p.get("Sm") is not None)
        at = 0
        for e in pdo.iterfind("Entry"):
            if at >= bit and _int(e.findtext("Index")):
                out.add((pos, pdo_index, at))
                break
            at += _int(e.findtext("BitLen"))
    return out


def export(eni: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "lcec", "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=120)


def test_lcec_reads_every_accepted_corpus_eni_as_the_eni_says(corpus, corpus_extra,
                                                              lcec_conf, tmp_path):
    from ecatcfg.eni.export import lcec
    from ecatcfg.eni.export.steps import ExportError
    checked = 0
    for path in sorted([*corpus.glob("eni/**/*.xml"), *corpus_extra.glob("eni/**/*.xml")]):
        config = _accepted(path)
        if config is None:
            continue                          # refused for IgH: test_export_igh_c
        try:
            xml, extra = lcec.render(config, str(path), path.name, "0" * 64, "test")
        except ExportError:
            continue                          # refused for lcec: the sweep below
        out = tmp_path / f"eni{checked}.xml"
        out.write_bytes(xml)
        assert extra == []                    # no corpus ENI has SoE writes
        records = parse(lcec_conf, out)
        master, slaves = by_slave(records)
        want_master, want_slaves, variables = expected_records(path)
        assert " ".join(master.split()[:6]) == want_master, path
        assert _comparable(slaves) == want_slaves, path
        assert _variable_entries(path, variables) <= pinned(slaves, records), path
        checked += 1
    assert checked >= 25


def test_the_export_is_deterministic_and_says_where_it_came_from(corpus, tmp_path):
    eni = corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml"
    a, b = tmp_path / "a.xml", tmp_path / "b.xml"
    for path in (a, b):
        done = export(eni, path)
        assert done.returncode == 0, done.stderr
    assert a.read_bytes() == b.read_bytes()
    digest = hashlib.sha256(eni.read_bytes()).hexdigest()
    assert f"from {eni.name}, sha256 {digest}." in a.read_text()


def test_pins_are_named_after_the_variables_within_hal_names(corpus, corpus_extra, lcec_conf,
                                                            tmp_path):
    """HAL names are at most 47 characters ("lcec.0.<slave>.<pin>"); an array of bytes
    becomes a complex entry of a pin per byte."""
    eni = corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml"
    out = tmp_path / "line.xml"
    assert export(eni, out).returncode == 0
    records = parse(lcec_conf, out)
    names = {r.split()[6]: r for r in records if r.startswith("slave ")}
    slave_name = next(iter(names))
    pins = [r.split()[6] for r in records if r.startswith("entry ") and r.split()[6] != "-"]
    assert "outputdigital.bit0" in pins and "inputanalog.triangle" in pins
    assert all(len(f"lcec.0.{slave_name}.{p}") <= 47 for p in pins)
    # an ARRAY [0..9] OF BYTE of a safety PLC: a complex entry of ten 8-bit pins
    out = tmp_path / "moobot.xml"
    assert export(corpus_extra / "eni" / "altinay-moobot" / "ENI.xml", out).returncode == 0
    complex_pins = [r for r in parse(lcec_conf, out) if r.startswith("complex ")]
    assert len(complex_pins) >= 10 and all(r.split()[2] == "8" for r in complex_pins)


@pytest.mark.parametrize("eni", corpus_enis())
def test_every_corpus_eni_exports_for_lcec_or_is_refused_by_name(request, eni):
    from ecatcfg.eni.export import lcec
    from ecatcfg.eni.export.igh import igh_config
    from ecatcfg.eni.export.steps import ExportError
    path = corpus_eni(request, eni)
    plan = plan_or_refused(path)
    if plan is None:
        return
    try:
        xml, _initcmds = lcec.render(igh_config(plan, path), str(path), path.name, "0" * 64,
                                     "t")
    except ExportError as exc:
        assert exc.file == str(path)
        assert exc.line is not None or "master" in exc.message or plan.unsupported
        assert "slave" in exc.message or "master" in exc.message
        return
    etree.fromstring(xml)


def test_soe_writes_go_to_an_initcmds_file_lcec_reads(corpus, lcec_conf, tmp_path):
    """lcec's <idnConfig> cannot be read (its parser tests "drive" twice), so SoE writes go
    to an initCmds file beside the XML, which lcec's parser reads as IDNs of PREOP (PS) and
    SAFEOP (SO): ecrt.h ec_al_state_t 2 and 4."""
    from test_export_igh_c import _add_soe, _edited, _soe
    eni = _edited(corpus, tmp_path, _add_soe(_soe(["PS", "SO"], 0, 32, "0b00"),
                                             _soe(["PS"], 1, 0x8000 | 47, "e8030000")))
    out = tmp_path / "machine.xml"
    done = export(eni, out)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "machine_0_soe.xml").is_file()
    records = parse(lcec_conf, out)
    assert [r for r in records if r.startswith("idn ")] == [
        "idn 0 32 2 0b00", "idn 0 32 4 0b00", "idn 1 32815 2 e8030000"]


def test_a_duplicate_entry_is_refused_by_name(tmp_path):
    """lcec registers a pin's entry by index and subindex: a variable on an entry that is
    twice in the slave's PDOs is refused, nothing written."""
    from conftest import compile_example
    line = compile_example(tmp_path / "line.eni.xml")
    done = export(line, tmp_path / "line.xml")
    assert done.returncode == 1
    assert re.search(r":\d+: slave 4 \('axis1'\): variable 'axis1.TxPDO 1 \(CSP\).Statusword': "
                     r"entry 0x6041:00 is twice in the slave's PDOs", done.stderr), done.stderr
    assert not (tmp_path / "line.xml").exists()
