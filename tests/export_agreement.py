"""The pysoem export against SOEM itself, for one ENI.

``agree(rig, eni, tmp)``: the ENI's slaves emulated in this process (as ``ecatcfg simulate
--eni`` builds them, with an ESI library where given) answer on the rig's namespace B;
pysoem, with the module ``ecatcfg export --format pysoem`` wrote, runs in namespace A
(``export_io_probe.py``).  Compared:

- **places**: every variable of the module's ``VARIABLES`` against where SOEM put it: the
  FMMU registers SOEM programmed (read back from each slave: logical start and start bit
  of the first FMMU of each direction, which is where ``slave.outputs``/``.inputs`` point,
  group 0 starting at IOmap byte 0) plus the variable's bit within its slave's data, read
  from the ENI file with lxml (its ``ProcessImage`` BitOffs less its slave's
  ``Send``/``Recv`` BitStart, each range from a whole byte);
- **inputs**: patterns (0x55, 0x33, 0x0F, 0xAA, seeded random bytes) set in every emulated
  slave's input SyncManagers read back by name through ``VARIABLES`` (from the bytes pysoem
  gives) and through the module's ``read``: every bit of every slave with fewer than 8
  bits, up to ``sample`` variables of each other slave;
- **outputs**: the same for outputs written by name, checked in the emulated slave's
  output SyncManagers.

Used by ``test_export_agreement.py`` (a fixed sample, in CI) and
``bench/export_agreement.py`` (every corpus ENI).
"""

from __future__ import annotations

import json
import os
import queue
import random
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

PROBE = Path(__file__).with_name("export_io_probe.py")
PATTERNS = (0x55, 0x33, 0x0F, 0xAA, None)     # None: seeded random bytes
REPLY_S = 120.0


@dataclass
class EniVar:
    name: str
    slave: int
    direction: str                            # "output" / "input"
    offset: int                               # bit within the slave's own data
    bit_size: int


@dataclass
class Result:
    eni: str
    # agree / partial (a slave below OP: its data not compared) / refused / no-op (SOEM did
    # not map the line) / disagree / error
    outcome: str = "agree"
    detail: str = ""
    variables: int = 0
    places: int = 0                           # variables compared with SOEM's FMMUs
    bits_read: int = 0
    bits_written: int = 0
    retried: int = 0                          # runs again after a no-op or error
    disagreements: list[str] = field(default_factory=list)


def eni_variables(eni: Path) -> tuple[list[EniVar], list[tuple[int, int]]]:
    """Each variable's slave and bit within that slave's data, read from the ENI file; and
    each slave's (Send, Recv) bit lengths."""
    root = etree.parse(str(eni)).getroot()
    # The slaves with an ESC (PhysAddr or AutoIncAddr; the rest are passive terminals) at
    # their bus position, the negated auto-increment address.
    slaves = {}
    for s in root.findall("Config/Slave"):
        auto_inc = s.findtext("Info/AutoIncAddr")
        if auto_inc is not None:
            slaves[-int(auto_inc) & 0xFFFF] = s
        elif s.findtext("Info/PhysAddr") is not None:
            slaves[len(slaves)] = s
    ranges: list[dict[str, list[tuple[int, int]]]] = []
    bits = []
    for _, s in sorted(slaves.items()):
        r = {}
        for direction, tag in (("output", "Send"), ("input", "Recv")):
            r[direction] = [(int(x.findtext("BitStart")), int(x.findtext("BitLength")))
                            for x in s.findall(f"ProcessData/{tag}")]
        ranges.append(r)
        bits.append((sum(n for _, n in r["output"]), sum(n for _, n in r["input"])))
    out = []
    for direction, tag in (("output", "Outputs"), ("input", "Inputs")):
        for v in root.findall(f"Config/ProcessImage/{tag}/Variable"):
            offs, size = int(v.findtext("BitOffs")), int(v.findtext("BitSize"))
            for k, r in enumerate(ranges):
                base = 0
                for start, length in r[direction]:
                    if start <= offs < start + length:
                        out.append(EniVar(v.findtext("Name") or "", k, direction,
                                          base + offs - start, size))
                        break
                    base += (length + 7) // 8 * 8
                else:
                    continue
                break
    return out, bits


def soem_starts(fmmus: list[list[str]]) -> dict[tuple[int, str], int]:
    """(slave, direction) -> the IOmap bit where SOEM put the slave's first bit: its first
    active FMMU of that direction (FMMU register image: logical start, length, start bit,
    stop bit, physical start, physical start bit, type, activate; ETG.1000.4)."""
    from ecatcfg.esc import FmmuConfig, FmmuType
    starts: dict[tuple[int, str], int] = {}
    for k, regs in enumerate(fmmus):
        for text in regs:
            if not text:                      # never answered: the slave counts as unmapped
                continue
            f = FmmuConfig.from_bytes(bytes.fromhex(text))
            if not f.active or f.type not in (FmmuType.READ, FmmuType.WRITE):
                continue
            direction = "input" if f.type == FmmuType.READ else "output"
            starts.setdefault((k, direction), f.logical_start * 8 + f.logical_start_bit)
    return starts


class ProbeSilent(RuntimeError):
    """The probe ended or hung without its next line."""


class LineSilent(RuntimeError):
    """The line stopped answering process data: nothing read then is the line's."""


class Probe:
    """export_io_probe.py in namespace A, one JSON line per step."""

    def __init__(self, rig, module: Path) -> None:
        self.proc = rig.popen_in(rig.ns_a, [sys.executable, str(PROBE), rig.if_a,
                                            str(module)],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        # Lines through a thread: select() on a buffered pipe misses a second line that
        # arrived with the first (it is in the buffer, not the pipe).
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for text in self.proc.stdout:
            self.lines.put(text)
        self.lines.put("")

    def line(self) -> dict:
        try:
            text = self.lines.get(timeout=REPLY_S)
        except queue.Empty:
            text = ""
        if not text:
            if self.proc.poll() is None:     # its Python stack on stderr, then the end
                os.killpg(self.proc.pid, signal.SIGUSR1)
                time.sleep(1)
            self.proc.kill()
            self.proc.wait()
            assert self.proc.stderr is not None
            err = self.proc.stderr.read()[-2000:]
            raise ProbeSilent(f"the probe said nothing (exit {self.proc.returncode}): {err}")
        return json.loads(text)

    def ask(self, command: dict) -> dict:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(command) + "\n")
        self.proc.stdin.flush()
        return self.line()

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write('{"stop": true}\n')
                self.proc.stdin.flush()
                self.proc.wait(30)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()


def _pattern(p: int | None, n: int, rng: random.Random) -> bytes:
    return bytes(rng.randrange(256) for _ in range(n)) if p is None else bytes([p]) * n


def _value(data: bytes, offset: int, size: int) -> int:
    return int.from_bytes(data, "little") >> offset & ((1 << size) - 1)


def agree(rig, eni: Path, tmp: Path, library=None, sample: int = 4, seed: int = 39,
          check_io: bool = True) -> Result:
    """The comparison for ``eni`` (see the module docstring)."""
    from rig import serving

    from ecatcfg.eni.reader import read_file
    from ecatcfg.runtime.segment import emulate

    result = Result(str(eni))
    tmp.mkdir(parents=True, exist_ok=True)
    module = tmp / "agreement_setup.py"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "pysoem", "-o", str(module), "--no-cache"], capture_output=True,
                          text=True, timeout=120)
    if done.returncode != 0:
        result.outcome, result.detail = "refused", done.stderr.strip().splitlines()[-1]
        return result
    variables, bits = eni_variables(eni)
    result.variables = len(variables)
    plan = read_file(eni)
    seg = emulate.segment(emulate.specs_from_eni(plan, library, str(eni)))
    rng = random.Random(seed)
    with serving(rig, seg):
        probe = Probe(rig, module)
        try:
            mapped = probe.line()
            if "error" in mapped:
                result.outcome, result.detail = "no-op", mapped["error"]
                return result
            _compare_places(result, module, mapped, variables)
            op = probe.line()
            if not check_io:
                return result
            # A slave the emulation keeps below OP (refusing the ENI's configuration: a
            # matter of check and apply, not of the export) does not stop the others: inputs
            # are compared for the slaves in SAFEOP or OP, outputs for those in OP.
            reached = {k: int(s.state) for k, s in enumerate(seg.slaves)}
            if op["op"] == 0:
                result.outcome = "no-op"
                result.detail = "SOEM's read of the AL states got no answer in OP"
                return result
            if op["op"] != 8:
                below = [f"{seg.slaves[k].name} ({state})" for k, state in reached.items()
                         if state != 8]
                result.outcome = "partial"
                result.detail = f"state {op['op']} instead of OP; not in OP: " + \
                    ", ".join(below)
            _compare_io(result, probe, seg, variables, bits, sample, rng, reached)
        except ProbeSilent as exc:
            result.outcome, result.detail = "error", str(exc)
            return result
        except LineSilent as exc:
            result.outcome, result.detail = "no-op", str(exc)
            result.disagreements.clear()
            return result
        finally:
            probe.close()
    if result.disagreements:
        result.outcome = "disagree"
    return result


def _table(module: Path) -> dict:
    import importlib.util
    spec = importlib.util.spec_from_file_location(f"m{time.monotonic_ns()}", module)
    assert spec is not None and spec.loader is not None
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m.VARIABLES


def _compare_places(result: Result, module: Path, mapped: dict,
                    variables: list[EniVar]) -> None:
    table = _table(module)
    starts = soem_starts(mapped["fmmus"])
    slave_bytes = {}
    for k, (o, i) in enumerate(mapped["sizes"]):
        slave_bytes[(k, "output")], slave_bytes[(k, "input")] = o, i
    for v in variables:
        entry = table.get(v.name)
        start = starts.get((v.slave, v.direction))
        if entry is None or start is None:
            result.disagreements.append(f"{v.name}: in the table {entry is not None}, "
                                        f"SOEM mapped slave {v.slave} {start is not None}")
            continue
        result.places += 1
        at = start % 8 + v.offset              # from the byte slave.<direction> points at
        want = (v.slave, v.direction, at // 8, at % 8, start // 8 + at // 8)
        got = (entry.slave, entry.direction, entry.byte, entry.bit, entry.iomap_byte)
        if want != got:
            result.disagreements.append(f"{v.name}: SOEM slave/direction/byte/bit/IOmap "
                                        f"byte {want}, the module {got}")


def _compare_io(result: Result, probe: Probe, seg, variables: list[EniVar],
                bits: list[tuple[int, int]], sample: int, rng: random.Random,
                reached: dict[int, int]) -> None:
    chosen: list[EniVar] = []
    for k, (o, i) in enumerate(bits):
        for direction, n in (("output", o), ("input", i)):
            if reached.get(k, 0) < (8 if direction == "output" else 4):
                continue
            mine = [v for v in variables if v.slave == k and v.direction == direction
                    and v.bit_size <= 64]
            chosen += mine if n < 8 else mine[:sample]
    inputs = [v for v in chosen if v.direction == "input"]
    outputs = [v for v in chosen if v.direction == "output"]
    for p in PATTERNS:
        data = {}
        for k, s in enumerate(seg.slaves):
            n = sum(length for _, length in s.input_areas())
            data[k] = _pattern(p, n, rng)
            s.set_inputs(data[k])
        if inputs:
            reply = probe.ask({"read": [v.name for v in inputs]})
            if not reply["settled"]:
                raise LineSilent(f"no steady working counter before reading pattern {p}")
            for v in inputs:
                want = _value(data[v.slave], v.offset, v.bit_size)
                got, through = reply["values"][v.name], reply["module"][v.name]
                if got is not None and got != want:
                    result.disagreements.append(f"{v.name}: pattern {p}: the emulated slave "
                                                f"holds {want}, read by the table {got}")
                if got is None and isinstance(through, int):
                    result.disagreements.append(f"{v.name}: beyond pysoem's bytes, yet the "
                                                f"module read {through}")
                if got is not None and through != want:
                    result.disagreements.append(f"{v.name}: pattern {p}: read() gave "
                                                f"{through}, the slave holds {want}")
                result.bits_read += v.bit_size if got is not None else 0
        if outputs:
            values = {v.name: _value(_pattern(p, 8, rng), v.offset % 8, v.bit_size)
                      for v in outputs}
            reply = probe.ask({"write": values})
            if not reply["settled"]:
                raise LineSilent(f"no steady working counter after writing pattern {p}")
            for v in outputs:
                if not reply["written"][v.name]:
                    continue
                if seg.slaves[v.slave].state != 8:      # its outputs are safe (zero) now
                    left = f"{seg.slaves[v.slave].name} left OP"
                    if left not in result.detail:
                        result.detail = f"{result.detail}; {left}".lstrip("; ")
                    continue
                have = seg.slaves[v.slave].outputs()
                if _value(have, v.offset, v.bit_size) != values[v.name]:
                    result.disagreements.append(
                        f"{v.name}: wrote {values[v.name]}, the emulated slave got "
                        f"{_value(have, v.offset, v.bit_size)}")
                result.bits_written += v.bit_size


def agree_in_ci(rig, eni: Path, tmp: Path, library=None, sample: int = 4,
                tries: int = 2) -> Result:
    """:func:`agree`, again (up to ``tries`` runs in all) when pysoem did not map the line or
    the probe went silent, never after a disagreement.  SOEM takes a mailbox or EEPROM read
    that times out as data (a PDO mapping cut short, a revision of 0), and on a loaded
    machine the emulated line, a Python process, sometimes answers after SOEM stopped
    waiting: the module's checks then raise, as they should, and nothing was compared."""
    details = []
    for run in range(tries):
        result = agree(rig, eni, tmp / f"run{run}", library, sample)
        result.retried = run
        if result.outcome not in ("no-op", "error"):
            return result
        details.append(result.detail)
    result.detail = f"{tries} runs: " + " / ".join(details)
    return result
