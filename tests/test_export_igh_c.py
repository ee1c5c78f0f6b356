"""``ecatcfg export --format igh-c``: the C it writes compiles with ``-Wall -Wextra -Werror``
against the IgH master's own ``ecrt.h`` (from the master's archive in the corpus), and,
linked with a recording implementation of the ``ecrt_*`` calls
(``fixtures/igh/recorder.c``, after libfakeethercat's semantics) and run with its
``-DECATCFG_MAIN`` task, configures IgH as the ENI says: for every ENI of both corpora the
export accepts, the slave configurations, SyncManagers, PDO assignment and mapping,
start-up SDOs in order, DC, watchdog and reference clock the program makes, and the place
of each variable it registers, equal what the test reads from the ENI itself with lxml.
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

IGH_ARCHIVE = "third-party/igh-ethercat-master-userspace.tar.gz"
RECORDER = Path(__file__).parent / "fixtures" / "igh" / "recorder.c"
STRICT = ["gcc", "-std=c11", "-Wall", "-Wextra", "-Werror"]

# ETG.1000.6 CoE communication area: PDO assignment and mapping objects.
ASSIGNMENT = range(0x1C10, 0x1C30)
MAPPING = (range(0x1600, 0x1800), range(0x1A00, 0x1C00))
# ecrt.h ec_watchdog_mode_t
WD_DEFAULT, WD_ENABLE, WD_DISABLE = 0, 1, 2


@pytest.fixture(scope="module")
def ecrt_include(corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder of ``ecrt.h`` unpacked from the IgH master's archive."""
    if shutil.which("gcc") is None:
        prereq.missing("gcc", "not on the PATH", prereq.TOOLS)
    folder = tmp_path_factory.mktemp("igh")
    with tarfile.open(corpus / IGH_ARCHIVE) as archive:
        member = next(m for m in archive.getmembers() if m.name.endswith("include/ecrt.h"))
        archive.extractall(folder, members=[member], filter="data")
    return next(folder.rglob("ecrt.h")).parent


@pytest.fixture(scope="module")
def recorder(ecrt_include: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    obj = tmp_path_factory.mktemp("recorder") / "recorder.o"
    done = subprocess.run([*STRICT, f"-I{ecrt_include}", "-c", str(RECORDER), "-o", str(obj)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return obj


def export(eni: Path, out: Path, fmt: str = "igh-c") -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           fmt, "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=120)


def build_and_run(source: Path, ecrt_include: Path, recorder: Path) -> str:
    """The exported source built strictly with its main, linked with the recorder, run for
    two cycles: its output."""
    program = source.with_suffix("")
    done = subprocess.run([*STRICT, "-DECATCFG_MAIN", f"-I{ecrt_include}",
                           f"-I{source.parent}", str(source), str(recorder), "-o",
                           str(program)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"{source}: {done.stderr}"
    run = subprocess.run([str(program), "2"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    return run.stdout


# -- the ENI read with lxml (ETG.2100), independently of ecatcfg's reader ----------------

def _int(text: str | None, default: int | None = None) -> int:
    if text is None or not text.strip():
        assert default is not None
        return default
    text = text.strip()
    return int(text[2:], 16) if text[:2] in ("#x", "#X") else int(text, 0)


def _bool(text: str | None) -> bool:
    return (text or "").strip().lower() in ("1", "true")


def _transitions(cmd: etree._Element) -> list[str]:
    return [t.text.strip() for t in cmd.iterfind("Transition") if t.text]


def _eoe_expected(slave: etree._Element, pos: int) -> list[str]:
    """The EoE set IP parameter requests of the slave (ETG.1000.6 EoE: flags, then MAC,
    IP address, subnet mask, gateway, DNS server at fixed places, IPv4 numbers
    little-endian, and the DNS name), each field the last one set, as the recorder prints
    IgH's EoE calls.  ENI files write the body alone or after the 4-byte EoE header of a
    set IP parameter request (frame type 2)."""
    fields: dict[str, str] = {}
    for c in slave.iterfind("Mailbox/EoE/InitCmds/InitCmd"):
        if _bool(c.findtext("Disabled")):
            continue
        data = bytes.fromhex((c.findtext("Data") or "").strip())
        body = data[4:] if data[0] & 0x0F == 2 and len(data) == 4 + 58 else data
        flags = int.from_bytes(body[:4], "little")
        if flags & 1:
            fields["mac"] = ":".join(f"{b:02x}" for b in body[4:10])
        for bit, name, at in ((2, "ip", 10), (4, "subnet", 14), (8, "gateway", 18),
                              (16, "dns", 22)):
            if flags & bit:
                fields[name] = ".".join(str(b) for b in reversed(body[at:at + 4]))
        if flags & 32:
            fields["name"] = body[26:58].split(b"\0")[0].decode()
    return [f"eoe {pos} {k} {fields[k]}" for k in ("mac", "ip", "subnet", "gateway", "dns",
                                                   "name") if k in fields]


def eni_expectations(path: Path) -> tuple[list[str], list[tuple[str, int, int, int]]]:
    """(the configuration calls, in the order the export makes them, as the recorder prints
    them; each variable a slave's PDOs hold: (name, slave, PDO, bit offset within the PDO)),
    from the ENI file."""
    root = etree.parse(str(path)).getroot()
    slaves = [s for s in root.iterfind("Config/Slave")
              if s.find("Info/PhysAddr") is not None or s.find("Info/AutoIncAddr") is not None]
    calls: list[str] = []
    reference = None
    pdo_bits: list[dict[bool, list[tuple[int, list[tuple[int, int, int]]]]]] = []
    for pos, slave in enumerate(slaves):
        # (ETG.2100 types them xs:int: a vendor ID of bit 31 set may be written negative)
        vendor = _int(slave.findtext("Info/VendorId")) & 0xFFFFFFFF
        product = _int(slave.findtext("Info/ProductCode")) & 0xFFFFFFFF
        calls.append(f"slave_config 0 {pos} {vendor} {product}")
        pd = slave.find("ProcessData")
        sms: dict[int, etree._Element] = {}
        pdos: list[etree._Element] = []
        if pd is not None:
            sms = {int(el.tag[2:]): el for el in pd if re.fullmatch(r"Sm\d+", str(el.tag))}
            pdos = [p for p in pd if p.tag in ("RxPdo", "TxPdo")]
        assigned: set[int] = set()
        per_dir: dict[bool, list[tuple[int, list[tuple[int, int, int]]]]] = {True: [],
                                                                             False: []}
        numbers = sorted(set(sms) | {int(p.get("Sm")) for p in pdos if p.get("Sm")})
        for n in numbers:
            mine = [p for p in pdos if p.get("Sm") is not None and int(p.get("Sm")) == n]
            sm = sms.get(n)
            listed = [_int(x.text) for x in sm.iterfind("Pdo")] if sm is not None else []
            if listed:
                mine = [next(p for p in mine if _int(p.findtext("Index")) == i) for i in listed]
            if sm is not None:
                output = sm.findtext("Type") == "Outputs"
                wd = WD_ENABLE if _int(sm.findtext("ControlByte"), 0) & 0x40 else WD_DISABLE
            else:
                output = mine[0].tag == "RxPdo"
                wd = WD_DEFAULT
            calls.append(f"sync {pos} {n} {'out' if output else 'in'} {wd} {len(mine)}")
            for p in mine:
                index = _int(p.findtext("Index"))
                assigned.add(index)
                entries = [(_int(e.findtext("Index")), _int(e.findtext("SubIndex"), 0),
                            _int(e.findtext("BitLen"))) for e in p.iterfind("Entry")]
                calls.append(f"pdo {pos} {n} {index} {len(entries)}")
                calls += [f"entry {pos} {n} {index} {i} {s} {b}" for i, s, b in entries]
                per_dir[output].append((index, entries))
        pdo_bits.append(per_dir)
        coe = [c for c in slave.iterfind("Mailbox/CoE/InitCmds/InitCmd")
               if not _bool(c.findtext("Disabled"))]
        for ip_first in (True, False):
            for c in coe:
                if ("IP" in _transitions(c)) != ip_first:
                    continue
                index = _int(c.findtext("Index"))
                if index in ASSIGNMENT or (any(index in r for r in MAPPING)
                                           and index in assigned):
                    continue                  # the PDO tables say it
                kind = "complete_sdo" if _bool(c.get("CompleteAccess")) else "sdo"
                calls.append(f"{kind} {pos} {index} {_int(c.findtext('SubIndex'), 0)} "
                             f"{(c.findtext('Data') or '').strip().lower() or '-'}")
        calls += _eoe_expected(slave, pos)
        assign = divider = intervals = 0
        for c in slave.iterfind("InitCmds/InitCmd"):
            ado = c.findtext("Ado")
            data = bytes.fromhex((c.findtext("Data") or "").strip())
            if ado is None or not data:
                continue
            ado_n = _int(ado)
            if ado_n == 0x0980 and "PS" in _transitions(c):
                assign = int.from_bytes(data[:2], "little")
            elif ado_n == 0x0400 and int.from_bytes(data[:2], "little"):
                divider = int.from_bytes(data[:2], "little")
            elif ado_n == 0x0420 and int.from_bytes(data[:2], "little"):
                intervals = int.from_bytes(data[:2], "little")
        if divider or intervals:
            calls.append(f"watchdog {pos} {divider} {intervals}")
        dc = slave.find("DC")
        if assign:
            calls.append(f"dc {pos} {assign} {_int(dc.findtext('CycleTime0'))} "
                         f"{_int(dc.findtext('ShiftTime'), 0)} "
                         f"{_int(dc.findtext('CycleTime1'), 0)} 0")
        if dc is not None and _bool(dc.findtext("ReferenceClock")) and reference is None:
            reference = pos
    if reference is not None:
        calls.append(f"reference_clock {reference}")
    variables = []
    for output, where in ((True, "Outputs"), (False, "Inputs")):
        found = root.findall(f"Config/ProcessImage/{where}/Variable")
        for v in sorted(found, key=lambda v: _int(v.findtext("BitOffs"))):
            offs = _int(v.findtext("BitOffs"))
            for pos, slave in enumerate(slaves):
                r = slave.find(f"ProcessData/{'Send' if output else 'Recv'}")
                if r is None:
                    continue
                start = _int(r.findtext("BitStart"))
                if start <= offs < start + _int(r.findtext("BitLength")):
                    local = offs - start
                    for index, entries in pdo_bits[pos][output]:
                        size = sum(b for _, _, b in entries)
                        if local < size:
                            variables.append((v.findtext("Name") or "", pos, index, local))
                            break
                        local -= size
                    break
    return calls, variables


def recorded(output: str) -> tuple[list[str], list[tuple[str, int, int, int]]]:
    """(the configuration calls; each variable: name, slave, PDO and bit offset within the
    PDO, from the offset the program printed and the PDO blocks laid in the domain)."""
    config = [line for line in output.splitlines()
              if line.split(" ", 1)[0] in ("slave_config", "sync", "pdo", "entry", "sdo",
                                           "complete_sdo", "idn", "eoe", "dc",
                                           "watchdog", "reference_clock")]
    blocks = [tuple(map(int, line.split()[1:])) for line in output.splitlines()
              if line.startswith("map ")]
    variables = []
    # (a name may hold a line break: the ENI's own name, byte for byte)
    shown = re.findall(r"^variable (.*?) offset (\d+) bit (\d+)$", output, re.M | re.S)
    for name, offset, bit in shown:
        at = int(offset) * 8 + int(bit)
        pos, _sm, pdo, start, size = next(b for b in blocks
                                          if b[3] * 8 <= at < (b[3] + b[4]) * 8)
        variables.append((name, pos, pdo, at - start * 8))
    return config, variables


def _accepted(path: Path):
    from ecatcfg.eni.export.igh import igh_config
    from ecatcfg.eni.export.steps import ExportError
    from ecatcfg.eni.reader import read_file
    from ecatcfg.errors import EcatcfgError
    try:
        return igh_config(read_file(path), path)
    except (ExportError, EcatcfgError):
        return None


def test_every_accepted_corpus_eni_configures_igh_as_the_eni_says(
        corpus, corpus_extra, ecrt_include, recorder, tmp_path):
    from ecatcfg.eni.export import igh_c
    checked = 0
    for path in sorted([*corpus.glob("eni/**/*.xml"), *corpus_extra.glob("eni/**/*.xml")]):
        config = _accepted(path)
        if config is None:
            continue                          # refused by name: the sweep below
        source = tmp_path / f"eni{checked}.c"
        text, header = igh_c.render(config, source.with_suffix(".h").name, path.name,
                                    "0" * 64, "test")
        source.write_bytes(text)
        source.with_suffix(".h").write_bytes(header)
        output = build_and_run(source, ecrt_include, recorder)
        calls, variables = recorded(output)
        want_calls, want_variables = eni_expectations(path)
        assert calls == want_calls, path
        assert variables == want_variables, path
        assert re.search(r"^cycles 2 incomplete 0 ", output, re.M), output
        checked += 1
    assert checked >= 25


def test_the_export_is_deterministic_and_says_where_it_came_from(corpus, tmp_path):
    eni = corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml"
    a, b = tmp_path / "a" / "line.c", tmp_path / "b" / "line.c"
    for path in (a, b):
        path.parent.mkdir()
        done = export(eni, path)
        assert done.returncode == 0, done.stderr
    assert a.read_bytes() == b.read_bytes()
    assert a.with_suffix(".h").read_bytes() == b.with_suffix(".h").read_bytes()
    header = a.with_suffix(".h").read_text()
    digest = hashlib.sha256(eni.read_bytes()).hexdigest()
    assert f'#define ECATCFG_ENI_SHA256 "{digest}"' in header
    assert f'#define ECATCFG_ENI_NAME "{eni.name}"' in header
    assert '#include "line.h"' in a.read_text()


def test_a_variable_is_read_by_its_eni_name(corpus, ecrt_include, recorder, tmp_path):
    """An application that names the ENI's variable gets its registered place."""
    eni = corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml"
    source = tmp_path / "line.c"
    assert export(eni, source).returncode == 0
    app = tmp_path / "app.c"
    app.write_text('#include <stdio.h>\n#include "line.h"\n'
                   "int main(void) {\n"
                   "    ec_master_t *m = ecrt_request_master(0);\n"
                   "    if (ecatcfg_configure(m, ecrt_master_create_domain(m))) return 1;\n"
                   '    printf("%s %u %u\\n", ecatcfg_variables[ECATCFG_SLAVE_1002_EC_'
                   'TRAINING_GENERATOR_COUNTER2_VALUE].name, ecatcfg_offset[ECATCFG_SLAVE_'
                   "1002_EC_TRAINING_GENERATOR_COUNTER2_VALUE], ecatcfg_bit_position[ECATCFG_"
                   "SLAVE_1002_EC_TRAINING_GENERATOR_COUNTER2_VALUE]);\n"
                   "    return 0;\n}\n")
    program = tmp_path / "app"
    done = subprocess.run([*STRICT, f"-I{ecrt_include}", f"-I{tmp_path}", str(app),
                           str(source), str(recorder), "-o", str(program)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    out = subprocess.run([str(program)], capture_output=True, text=True, timeout=30).stdout
    # Counter2 (0x1A01) of the generator: its Value first; the block of 0x1A01 is laid when
    # its first entry is registered, after every PDO registered before it.
    last = out.strip().splitlines()[-1]
    blocks = {tuple(map(int, line.split()[1:4])): int(line.split()[4])
              for line in out.splitlines() if line.startswith("map ")}
    assert last == (f"Slave_1002 [EC-Training Generator].Counter2.Value "
                    f"{blocks[(1, 3, 0x1A01)]} 0")


@pytest.mark.parametrize("eni", corpus_enis())
def test_every_corpus_eni_exports_for_igh_or_is_refused_by_name(request, eni):
    """Each ENI gives the IgH configuration or an error naming the file and the line (of
    the command, else of the slave) where it says what IgH cannot be told."""
    from ecatcfg.eni.export.igh import igh_config
    from ecatcfg.eni.export.steps import ExportError
    path = corpus_eni(request, eni)
    plan = plan_or_refused(path)
    if plan is None:
        return
    try:
        config = igh_config(plan, path)
    except ExportError as exc:
        assert exc.file == str(path)
        assert exc.line is not None or "master" in exc.message or plan.unsupported
        assert "slave" in exc.message or "master" in exc.message
        return
    assert len(config.slaves) == len(plan.slaves)


def _edited(corpus: Path, tmp_path: Path, edit) -> Path:
    """The acontis training ENI of the corpus with ``edit(first slave element)`` applied."""
    tree = etree.parse(str(corpus / "eni" / "acontis-doc" / "acontis-TrainingSlaves-ENI.xml"))
    edit(tree.getroot().find("Config/Slave"))
    path = tmp_path / "edited.xml"
    tree.write(str(path), xml_declaration=True, encoding="utf-8")
    return path


def _soe(transitions: list[str], drive: int, idn: int, data: str, elements: int = 0x40,
         op_code: int = 3) -> etree._Element:
    cmd = etree.Element("InitCmd")
    for t in transitions:
        etree.SubElement(cmd, "Transition").text = t
    for tag, text in (("Comment", "test"), ("OpCode", str(op_code)),
                      ("DriveNo", str(drive)), ("IDN", str(idn)),
                      ("Elements", str(elements)), ("Attribute", "0"), ("Data", data)):
        etree.SubElement(cmd, tag).text = text
    return cmd


def _add_soe(*cmds: etree._Element):
    def edit(slave: etree._Element) -> None:
        mailbox = slave.find("Mailbox")
        etree.SubElement(mailbox, "Protocol").text = "SoE"
        init_cmds = etree.SubElement(etree.SubElement(mailbox, "SoE"), "InitCmds")
        for cmd in cmds:
            init_cmds.append(cmd)
    return edit


def test_soe_writes_are_idns_in_the_state_igh_writes_them(corpus, ecrt_include, recorder,
                                                           tmp_path):
    """A write of PREOP->SAFEOP is an IDN of PREOP, one of SAFEOP->OP an IDN of SAFEOP, one
    of both is both; drive number, IDN and data as the ENI has them, in its order."""
    eni = _edited(corpus, tmp_path, _add_soe(_soe(["PS", "SO"], 0, 32, "0b00"),
                                             _soe(["PS"], 1, 0x8000 | 47, "e8030000")))
    source = tmp_path / "soe.c"
    done = export(eni, source)
    assert done.returncode == 0, done.stderr
    output = build_and_run(source, ecrt_include, recorder)
    idns = [line for line in output.splitlines() if line.startswith("idn ")]
    # ecrt.h ec_al_state_t: PREOP 2, SAFEOP 4
    assert idns == ["idn 0 0 32 2 0b00", "idn 0 0 32 4 0b00", "idn 0 1 32815 2 e8030000"]


@pytest.mark.parametrize("edit, words", [
    (_add_soe(_soe(["PS"], 0, 32, "0b00", elements=0x08)),
     "SoE write S-0-0032 (drive 0) elements 0x08 = 0b 00: IgH's IDN configuration"),
    (_add_soe(_soe(["SO", "OS"], 0, 32, "0b00")),
     "SoE write S-0-0032 (drive 0) = 0b 00 in SO/OS: IgH makes start-up commands"),
], ids=["soe-element", "soe-transition"])
def test_what_igh_cannot_be_told_is_refused_by_line(corpus, tmp_path, edit, words):
    eni = _edited(corpus, tmp_path, edit)
    done = export(eni, tmp_path / "out.c")
    assert done.returncode == 1
    assert re.search(rf"{re.escape(str(eni))}:\d+: slave 0 \('Slave_1001 \[EC-Training "
                     rf"Sampler\]'\): {re.escape(words)}", done.stderr), done.stderr
    assert not (tmp_path / "out.c").exists() and not (tmp_path / "out.h").exists()


def _coe_in(transition: str):
    def edit(slave: etree._Element) -> None:
        cmd = slave.find("Mailbox/CoE/InitCmds/InitCmd")
        for t in cmd.findall("Transition"):
            cmd.remove(t)
        t = etree.Element("Transition")
        t.text = transition
        cmd.insert(0, t)
    return edit


def _register_write(ado: int, data: str):
    def edit(slave: etree._Element) -> None:
        cmd = etree.SubElement(slave.find("InitCmds"), "InitCmd")
        for tag, text in (("Transition", "IP"), ("Comment", "test"), ("Requires", "cycle"),
                          ("Cmd", "5"), ("Adp", "1001"), ("Ado", str(ado)),
                          ("Data", data), ("Retries", "3")):
            etree.SubElement(cmd, tag).text = text
    return edit


@pytest.mark.parametrize("edit, words", [
    (_coe_in("SO"), "SDO 0x1C12:00 = 0 in SO: IgH makes start-up commands in PREOP"),
    (_register_write(0x0410, "0000"), "IgH writes no register 0x0410 = 0x0000"),
    (_register_write(0x09A8, "0100"), "IgH writes no register 0x09A8 = 0x0001"),
], ids=["coe-in-so", "pdi-watchdog-off", "latch-control"])
def test_commands_igh_has_no_place_for_are_refused_by_line(corpus, tmp_path, edit, words):
    eni = _edited(corpus, tmp_path, edit)
    done = export(eni, tmp_path / "out.c")
    assert done.returncode == 1, done.stderr
    assert re.search(rf"{re.escape(str(eni))}:\d+: slave 0 \(.*\): .*{re.escape(words)}",
                     done.stderr), done.stderr


def test_register_writes_of_reset_values_are_noted(corpus, ecrt_include, recorder, tmp_path):
    """A write of the PDI watchdog's reset value (which IgH leaves) is accepted and noted in
    the code; the watchdog divider and SM time become ecrt_slave_config_watchdog."""
    def edit(slave: etree._Element) -> None:
        _register_write(0x0410, "e803")(slave)
        _register_write(0x0400, "c209")(slave)
        _register_write(0x0420, "1027")(slave)
    eni = _edited(corpus, tmp_path, edit)
    source = tmp_path / "wd.c"
    done = export(eni, source)
    assert done.returncode == 0, done.stderr
    assert "PDI watchdog time's reset value, which IgH does not change" in source.read_text()
    output = build_and_run(source, ecrt_include, recorder)
    assert "watchdog 0 2498 10000" in output.splitlines()


def test_the_example_line_configures_igh_as_its_eni_says(ecrt_include, recorder, tmp_path):
    """Our own ENI of the example line through the command: a drive whose two TxPDOs both
    hold 0x6041:00, registered by place, DC with SYNC0, start-up SDOs."""
    from conftest import compile_example
    eni = compile_example(tmp_path / "line.eni.xml")
    source = tmp_path / "line.c"
    done = export(eni, source)
    assert done.returncode == 0, done.stderr
    assert "ecrt_slave_config_reg_pdo_entry_pos" in source.read_text()
    output = build_and_run(source, ecrt_include, recorder)
    assert recorded(output) == eni_expectations(eni)
    assert any(line.startswith("dc 4 ") for line in output.splitlines())


def test_eoe_requests_are_igh_eoe_parameters(corpus, ecrt_include, recorder, tmp_path):
    """Two set IP parameter requests (the body alone, as Elmo's tool writes it): IgH gets
    each field from the last request that sets it."""
    def body(flags: int, ip: str = "0.0.0.0", mask: str = "0.0.0.0", name: str = "") -> str:
        def le(address: str) -> bytes:
            return bytes(reversed([int(x) for x in address.split(".")]))
        data = (flags.to_bytes(4, "little") + bytes(6) + le(ip) + le(mask) + bytes(8) +
                name.encode().ljust(32, b"\0"))
        return data.hex()

    def edit(slave: etree._Element) -> None:
        mailbox = slave.find("Mailbox")
        etree.SubElement(mailbox, "Protocol").text = "EoE"
        cmds = etree.SubElement(etree.SubElement(mailbox, "EoE"), "InitCmds")
        for data in (body(0x02 | 0x04 | 0x20, "192.168.1.4", "255.255.0.0", "first"),
                     body(0x02 | 0x20, "10.0.0.7", name="drive")):
            cmd = etree.SubElement(cmds, "InitCmd")
            for tag, text in (("Transition", "IP"), ("Comment", "eoe"), ("Data", data)):
                etree.SubElement(cmd, tag).text = text
    eni = _edited(corpus, tmp_path, edit)
    source = tmp_path / "eoe.c"
    done = export(eni, source)
    assert done.returncode == 0, done.stderr
    calls, _ = recorded(build_and_run(source, ecrt_include, recorder))
    assert [c for c in calls if c.startswith("eoe ")] == [
        "eoe 0 ip 10.0.0.7", "eoe 0 subnet 255.255.0.0", "eoe 0 name drive"]
    assert calls == eni_expectations(eni)[0]
    for fmt in ("lcec", "ros2"):
        done = export(eni, tmp_path / f"out-{fmt}.xml", fmt)
        assert done.returncode == 1 and "no EoE configuration" in done.stderr, done.stderr
