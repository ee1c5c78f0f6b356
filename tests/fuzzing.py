"""The fuzz harness: one target per parser and per end of the wire (docs/fuzzing.md).

A *target* turns one input into one outcome.  Allowed outcomes are ``accepted`` and
``rejected`` (ecatcfg's own :class:`~ecatcfg.errors.EcatcfgError` with a located message:
file and line, or slave and command); anything else is a defect: another exception escapes
(a crash), an input runs longer than :data:`HANG_S` (a hang), an error does not say where,
or an invariant of the emulated hardware breaks.  :func:`run` raises :class:`Defect` (or the
escaping exception itself) for those, so hypothesis shrinks the input that shows them.

Inputs come from hypothesis strategies that mutate real seeds (the example ESI files,
topology and the ENI compiled from them, SII images built from the example devices, the
frames of a real bring-up), aware of the input's structure: XML element values and
attributes, YAML scalars (with explicit tags), SII category headers, EtherCAT datagrams
over the ESC registers, and the master's replies on their way back.  The same targets run
in the test suite (``tests/test_fuzz.py``, a bounded and seeded campaign) and in
``bench/fuzz.py`` (a long campaign).
"""

from __future__ import annotations

import collections
import contextlib
import functools
import re
import signal
import struct
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hypothesis import strategies as st
from hypothesis.configuration import set_hypothesis_home_dir

from ecatcfg.errors import EcatcfgError

# Hypothesis keeps caches (constants found in the source) under ./.hypothesis by default:
# not in the checkout.
set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "ecatcfg-hypothesis")

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
ESI_DIR = EXAMPLES / "esi"

HANG_S = 5.0            # an input that takes longer than this is a hang (a defect)
SHORT_WAIT_S = 0.2      # every wait of the master is cut to this in the runtime targets
DC_WAIT_S = 2.0         # ... and the DC convergence wait to this (under the 5 s hang limit)


class Defect(AssertionError):
    """An outcome the harness does not allow (other than an exception escaping)."""


class Hang(Defect):
    """An input ran longer than :data:`HANG_S`."""


# -- outcomes ---------------------------------------------------------------------------------

@contextlib.contextmanager
def watchdog(seconds: float = HANG_S) -> Iterator[None]:
    """Raise :class:`Hang` in the main thread when the block runs longer than ``seconds``
    (SIGALRM: a Python loop is interrupted; a long call in C is caught when it returns)."""
    start = time.monotonic()

    def fire(signum, frame):
        raise Hang(f"no result after {seconds:g} s")

    main = threading.current_thread() is threading.main_thread()    # signals go there
    if main:
        old = signal.signal(signal.SIGALRM, fire)
        signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        if main:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
    took = time.monotonic() - start
    if took > seconds:
        raise Hang(f"the input took {took:.1f} s (limit {seconds:g} s)")


def located_in_file(shown: str) -> Callable[[EcatcfgError], bool]:
    """An error about a file names that file and a line in it (or the offending byte)."""
    def check(exc: EcatcfgError) -> bool:
        errors = getattr(exc, "problems", None) or [exc]
        return all(e.file == shown and (e.line or getattr(e, "offset", None) is not None)
                   for e in errors)
    return check


def located_on_line(exc: EcatcfgError) -> bool:
    """An error of the master or the emulation names a slave or a command, or is about
    the whole line (nothing answered, the line does not match the ENI); an error about the
    ENI names its file and line."""
    from ecatcfg.runtime.master.replay import ApplyError
    if isinstance(exc, ApplyError):
        return True
    return bool(exc.file and exc.line) or "slave" in exc.message


def run(target: Target, value: Any) -> str:
    """``accepted`` or ``rejected``; raises for a defect."""
    with watchdog():
        try:
            target.call(value)
        except EcatcfgError as exc:
            if not target.located(exc):
                raise Defect(f"{type(exc).__name__} without a location: {exc}") from exc
            return "rejected"
    return "accepted"


@dataclass
class Target:
    name: str
    what: str                                    # the input, for the report
    strategy: Callable[[], st.SearchStrategy]    # built lazily: seeds cost a compile
    call: Callable[[Any], None]
    located: Callable[[EcatcfgError], bool]
    ci_examples: int                             # inputs in the test suite's campaign
    counts: collections.Counter = field(default_factory=collections.Counter)


# -- seeds ------------------------------------------------------------------------------------

@functools.cache
def library():
    from ecatcfg.esi.library import Library
    return Library([str(ESI_DIR)], cache=False)


SMALL_TOPOLOGY = """\
master: {name: small, cycle_time_us: 2000, layout: lrd_lwr}
slaves:
  - {name: in, device: EX1004}
  - name: drive
    device: "0xE0000ECA:0x7201"
    dc: DC
    sdos: [{index: 0x6060, value: 8}]
"""


@functools.cache
def esi_seeds() -> tuple[bytes, ...]:
    return tuple(p.read_bytes() for p in sorted(ESI_DIR.glob("*.xml")))


@functools.cache
def topology_seeds() -> tuple[bytes, ...]:
    example = (EXAMPLES / "topology.yaml").read_bytes()
    return (example, SMALL_TOPOLOGY.encode(),
            b'{"slaves": [{"name": "a", "device": "EX2008", "station_address": 1001}]}')


def compile_text(text: bytes, shown: str = "topology.yaml") -> bytes:
    """The ENI a topology compiles to (what ``ecatcfg compile`` writes)."""
    from ecatcfg.compiler import topology
    from ecatcfg.compiler.build import compile_topology
    from ecatcfg.eni import writer
    result = compile_topology(topology.loads(text, shown), library())
    return writer.to_bytes(result.plan, generator="fuzz")


@functools.cache
def eni_seeds() -> tuple[bytes, ...]:
    return tuple(compile_text(t) for t in topology_seeds()[:2])


@functools.cache
def sii_seeds() -> tuple[bytes, ...]:
    from ecatcfg.esi import sii
    lib = library()
    return tuple(sii.build(lib.device(e)) for e in lib.entries)


# -- mutation of text seeds -------------------------------------------------------------------

NUMBERS = ("0", "1", "-1", "2", "3", "7", "8", "15", "16", "127", "128", "255", "256", "-128",
           "4095", "4096", "32767", "32768", "65535", "65536", "-32768", "-32769",
           "2147483647", "2147483648", "-2147483648", "-2147483649", "4294967295",
           "4294967296", "18446744073709551616", "#x0", "#x1", "#xFF", "#x100", "#xFFFF",
           "#x10000", "#xFFFFFFFF", "#x100000000", "0x7FFFFFFF", "0xFFFFFFFFFFFFFFFFFF",
           "1" * 25, "9" * 4301,
           # Far out of range: wider than 64 bits, sizes of 2**36..2**70 bits,
           # a 32-bit subindex or count, negative sizes.
           "#x" + "F" * 4000, str(1 << 36), str(1 << 48), str(1 << 70), "#x7FFFFFFF", "-16",
           "-#x10", "#x10000000000000000")
TEXTS = ("", " ", "abc", "1.5", "1e3", "-0", "+1", "nan", "true", "false", "#x", "0x",
         "#xG", "\u00e9", "\U0001F600", "A" * 3000, "0 0", "\t1\n")
_NUMBER = re.compile(rb"\s*[+-]?(?:[0-9]+|#x[0-9a-fA-F]+|0x[0-9a-fA-F]+)\s*")


def interesting_value() -> st.SearchStrategy[str]:
    return st.one_of(st.sampled_from(NUMBERS), st.sampled_from(TEXTS),
                     st.integers(-2**40, 2**40).map(str), st.text(max_size=12))


def number_value() -> st.SearchStrategy[str]:
    # Negative numbers on their own too: the classic wrong value of an unsigned field.
    return st.one_of(st.sampled_from([n for n in NUMBERS if _NUMBER.fullmatch(n.encode())]),
                     st.integers(-2**33, 2**33).map(str), st.integers(-2**33, -1).map(str))


@dataclass(frozen=True)
class Mutant:
    """A seed and what was done to it, in a form a person can read in a failing example:
    ``Mutant('eni', 0, [('value', 'InitCmd/Cmd', 17, '256')])`` is the first ENI seed with
    the 18th ``InitCmd/Cmd`` set to 256.  Edits, applied in order:

    - ``('value', group, i, text)``: the i-th value of ``group`` (an element's text as
      ``Parent/Tag``, an attribute as ``@Name``) replaced by ``text`` (escaped for XML);
    - ``('scalar', i, text)``: the i-th YAML scalar replaced by ``text`` as written
      (``'yaml_value'``: the i-th scalar that is a value, not a key);
    - ``('element', group, i, n)``: the element holding that value dropped (n = 0) or
      repeated n more times;
    - ``('bytes', op, position, argument)``: ``flip`` a bit, ``insert`` bytes, ``delete`` or
      ``duplicate`` a run, ``truncate`` from there on.
    """

    family: str
    seed: int
    edits: tuple[tuple, ...]

    def __repr__(self) -> str:
        shown = [tuple(v if not isinstance(v, (str, bytes)) or len(v) <= 60
                       else v[:30] + (b"..." if isinstance(v, bytes) else "...") + v[-10:]
                       for v in e) for e in self.edits]
        return f"Mutant({self.family!r}, {self.seed}, {shown})"

    def data(self) -> bytes:
        data = SEEDS[self.family]()[self.seed]
        values: dict[tuple[int, int], bytes] = {}
        for e in self.edits:
            if e[0] == "value":
                values[dict(xml_spans(data).groups)[e[1]][e[2]]] = _escape(e[3])
            elif e[0] in ("scalar", "yaml_value"):
                values[yaml_spans(data, e[0] == "yaml_value")[e[1]]] = e[2].encode(
                    "utf-8", "surrogatepass")
        data = _apply(data, values)
        for e in self.edits:
            if e[0] == "element":
                data = _element(data, e[1], e[2], e[3])
            elif e[0] == "bytes":
                data = _byte_op(data, e[1], e[2], e[3])
        return data


SEEDS: dict[str, Callable[[], tuple[bytes, ...]]] = {}


@dataclass(frozen=True)
class Spans:
    """The places in a seed where a value sits, grouped by what holds them (``Cmd/Adp``,
    ``@Sm`` ...), so that a rare field is chosen as often as a frequent one."""

    data: bytes
    groups: tuple[tuple[str, tuple[tuple[int, int], ...]], ...]


_XML_TEXT = re.compile(rb"<([A-Za-z_][\w.-]*)(?:\s[^<>]*)?>([^<]*)</([\w.:-]+)>")
_XML_ATTR = re.compile(rb"\s([A-Za-z_][\w.:-]*)=\"([^\"<]*)\"")


@functools.cache
def xml_spans(data: bytes) -> Spans:
    groups: dict[str, list[tuple[int, int]]] = collections.defaultdict(list)
    parents = _parents(data)
    for m in _XML_TEXT.finditer(data):
        groups[f"{parents.get(m.start(), '')}/{m.group(1).decode()}"].append(m.span(2))
    for m in _XML_ATTR.finditer(data):
        groups[f"@{m.group(1).decode()}"].append(m.span(2))
    return Spans(data, tuple((k, tuple(v)) for k, v in sorted(groups.items())))


@functools.cache
def numeric_groups(data: bytes) -> tuple[tuple[str, tuple[tuple[int, int], ...]], ...]:
    spans = xml_spans(data)
    return tuple((name, places) for name, places in spans.groups
                 if all(_NUMBER.fullmatch(data[a:b]) for a, b in places))


def _parents(data: bytes) -> dict[int, str]:
    """For each start tag's offset, the tag of the element it sits in."""
    parents: dict[int, str] = {}
    stack: list[str] = []
    for m in re.finditer(rb"<(/?)([A-Za-z_][\w.:-]*)[^<>]*?(/?)>", data):
        closing, tag, empty = m.group(1), m.group(2).decode(), m.group(3)
        if closing:
            if stack:
                stack.pop()
            continue
        parents[m.start()] = stack[-1] if stack else ""
        if not empty:
            stack.append(tag)
    return parents


def _escape(value: str) -> bytes:
    return value.replace("&", "&amp;").replace("<", "&lt;").replace('"', "&quot;").encode(
        "utf-8", "surrogatepass")


def _apply(data: bytes, edits: dict[tuple[int, int], bytes]) -> bytes:
    out = bytearray(data)
    for (start, end), value in sorted(edits.items(), reverse=True):
        out[start:end] = value
    return bytes(out)


def _element(data: bytes, group: str, i: int, repeat: int) -> bytes:
    places = dict(xml_spans(data).groups).get(group)
    if not places:
        return data
    start, end = places[i % len(places)]
    first = data.rfind(b"<", 0, start)         # the element around the value
    last = data.find(b">", end) + 1
    if group.startswith("@") or first < 0 or last <= 0:
        return data
    return data[:last] + data[first:last] * repeat + data[last:] if repeat else \
        data[:first] + data[last:]


def _byte_op(data: bytes, op: str, pos: int, arg: Any) -> bytes:
    out = bytearray(data)
    pos = min(pos, len(out))
    if op == "flip" and pos < len(out):
        out[pos] ^= 1 << arg
    elif op == "insert":
        out[pos:pos] = arg
    elif op == "delete":
        del out[pos:pos + arg]
    elif op == "duplicate":
        out[pos:pos] = out[pos:pos + arg]
    elif op == "truncate":
        del out[pos:]
    return bytes(out)


RAW_TOKENS = (b"<", b">", b"</", b"/>", b"&", b"&amp;", b"&#0;", b"&#xD800;", b"<!--", b"-->",
              b"<![CDATA[", b"]]>", b"<?xml version='1.0'?>", b"<!DOCTYPE a>", b'"', b"'",
              b"\x00", b"\xff\xfe", b"\xc3", b"\n", b"\t", b" ", b":", b"#x", b"0x", b"-",
              b"- ", b": ", b"{", b"}", b"[", b"]", b",", b"!!", b"&a ", b"*a", b"<<: ",
              b"---\n", b"...\n", b"%YAML 1.1\n", b"|\n", b">\n", b"? ", b"!!binary ")


def _byte_edit(size: int) -> st.SearchStrategy[tuple]:
    pos = st.integers(0, size)
    return st.one_of(
        st.tuples(st.just("flip"), pos, st.integers(0, 7)),
        st.tuples(st.just("insert"), pos, st.one_of(st.sampled_from(RAW_TOKENS),
                                                    st.binary(min_size=1, max_size=8))),
        st.tuples(st.just("delete"), pos, st.integers(1, 64)),
        st.tuples(st.just("duplicate"), pos, st.integers(1, 256)),
        st.tuples(st.just("truncate"), pos, st.just(0)))


@st.composite
def byte_edits(draw, data: bytes, max_edits: int = 4) -> bytes:
    """Bytes (a frame) damaged by up to ``max_edits`` byte edits."""
    for _ in range(draw(st.integers(1, max_edits))):
        data = _byte_op(data, *draw(_byte_edit(len(data))))
    return data


@st.composite
def mutants(draw, family: str, *, values: int = 0, scalars: int = 0, yaml_values: int = 0,
            elements: bool = False, byte_ops: int = 0, numeric: bool = False) -> Mutant:
    """A :class:`Mutant` of a seed of ``family`` with up to ``values`` XML value edits
    (``numeric``: numbers by numbers only), ``scalars`` YAML scalar edits, maybe one
    element edit and up to ``byte_ops`` byte edits; ``yaml_values``: YAML values (not keys)
    replaced by values a topology holds, or numbers."""
    seeds = SEEDS[family]()
    seed = draw(st.integers(0, len(seeds) - 1))
    data = seeds[seed]
    edits: list[tuple] = []
    if values:
        groups = numeric_groups(data) if numeric else xml_spans(data).groups
        text = number_value() if numeric else interesting_value()
        for _ in range(draw(st.integers(1, values))):
            group, places = draw(st.sampled_from(groups))
            edits.append(("value", group, draw(st.integers(0, len(places) - 1)), draw(text)))
    if scalars:
        places = yaml_spans(data)
        for _ in range(draw(st.integers(1, scalars))):
            edits.append(("scalar", draw(st.integers(0, len(places) - 1)), draw(yaml_value())))
    if yaml_values:
        places = yaml_spans(data, True)
        text = st.one_of(st.sampled_from(TOPOLOGY_VALUES), number_value())
        for _ in range(draw(st.integers(1, yaml_values))):
            edits.append(("yaml_value", draw(st.integers(0, len(places) - 1)), draw(text)))
    if elements and draw(st.booleans()):
        group, places = draw(st.sampled_from(xml_spans(data).groups))
        edits.append(("element", group, draw(st.integers(0, len(places) - 1)),
                      draw(st.integers(0, 3))))
    if byte_ops:
        for _ in range(draw(st.integers(0 if edits else 1, byte_ops))):
            edits.append(("bytes", *draw(_byte_edit(len(data)))))
    return Mutant(family, seed, tuple(edits))


def xml_inputs(family: str) -> st.SearchStrategy[Mutant]:
    return st.one_of(mutants(family, values=6), mutants(family, values=3, elements=True),
                     mutants(family, values=2, byte_ops=3), mutants(family, byte_ops=4))


# -- YAML -------------------------------------------------------------------------------------

YAML_TAGS = ("!!int", "!!float", "!!bool", "!!null", "!!str", "!!timestamp", "!!binary",
             "!!seq", "!!map", "!!set", "!!omap", "!!pairs", "!!merge", "!!value",
             "!!python/name:os.system", "!!python/object:object", "!local", "!<tag:x>")
YAML_VALUES = NUMBERS + TEXTS + (
    "0x10000", "0o17", "0b101", "1_000", "1:30", ".inf", "-.inf", ".nan", "~", "null",
    "yes", "no", "on", "2001-12-14", "2001-13-45", "2001-12-14t21:59:43.10-05:00",
    "[1, 2]", "{a: 1}", "'x'", '"\\x00"', '"\\ud800"', "&a x", "*a", "*b", "[*a, *a]",
    "abc", "- x", "{", "[", "|\n  text", "\"a\nb\"", "?", "x: y: z")
# Values a topology holds: a mutant made of them still compiles often enough.
TOPOLOGY_VALUES = (
    "EX1100", "EX1004", "EX1008", "EX2008", "0xE0000ECA:0x7201", "0xE0000ECA:0x7201:0x1",
    "0x1600", "0x1601", "0x1A00", "0x1A01", "0x6060", "0x1C12", "0xF030", "IP", "PS", "SO",
    "SP", "OP", "lrw", "lrd_lwr", "DC", "FreeRun", "lamps", "1001", "0x07D0")


@functools.cache
def yaml_spans(data: bytes, values_only: bool = False) -> tuple[tuple[int, int], ...]:
    """Where each scalar of the seed sits (keys and values, or ``values_only``)."""
    import yaml
    text = data.decode()
    spans = []
    previous = None
    for token in yaml.scan(text, Loader=yaml.SafeLoader):
        if isinstance(token, yaml.ScalarToken) and (not values_only or isinstance(
                previous, (yaml.ValueToken, yaml.BlockEntryToken, yaml.FlowEntryToken,
                           yaml.FlowSequenceStartToken))):
            spans.append((len(text[:token.start_mark.index].encode()),
                          len(text[:token.end_mark.index].encode())))
        previous = token
    return tuple(spans)


def yaml_value() -> st.SearchStrategy[str]:
    tagged = st.tuples(st.sampled_from(YAML_TAGS), st.sampled_from(YAML_VALUES)).map(
        lambda p: f"{p[0]} {p[1]}")
    return st.one_of(st.sampled_from(YAML_VALUES), tagged,
                     st.integers(-2**70, 2**70).map(str), st.text(max_size=10))


def yaml_inputs(family: str) -> st.SearchStrategy[Mutant]:
    return st.one_of(mutants(family, scalars=4), mutants(family, scalars=2, byte_ops=2),
                     mutants(family, byte_ops=4))


SEEDS.update(esi=lambda: esi_seeds(), topology=lambda: topology_seeds(),
             eni=lambda: eni_seeds())


# -- SII --------------------------------------------------------------------------------------

@st.composite
def sii_inputs(draw) -> bytes:
    """An SII image with header words, category headers or bytes changed, or cut short."""
    data = bytearray(draw(st.sampled_from(sii_seeds())))
    words = [0x0000, 0xFFFF, 0x0001, 0x7FFF, 0x8000, 0x0A, 0x1E, 0x28, 0x29, 0x32, 0x33,
             0x3C, 0x3F, 0x0003, 0x0004, 0x0100]
    for _ in range(draw(st.integers(1, 5))):
        kind = draw(st.sampled_from(("word", "category", "byte", "cut")))
        if kind == "word" and len(data) >= 2:
            at = 2 * draw(st.integers(0, len(data) // 2 - 1))
            struct.pack_into("<H", data, at, draw(st.one_of(st.sampled_from(words),
                                                            st.integers(0, 0xFFFF))))
        elif kind == "category":
            at = _category_offsets(bytes(data))
            if at:
                pos = draw(st.sampled_from(at))
                struct.pack_into("<HH", data, pos, draw(st.sampled_from(words)),
                                 draw(st.one_of(st.sampled_from(words), st.integers(0, 0xFFFF))))
        elif kind == "byte" and data:
            data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
        elif kind == "cut":
            del data[draw(st.integers(0, len(data))):]
    return bytes(data)


def _category_offsets(data: bytes) -> list[int]:
    out, pos = [], 0x80
    while pos + 4 <= len(data):
        ctype, words = struct.unpack_from("<HH", data, pos)
        out.append(pos)
        if ctype == 0xFFFF:
            break
        pos += 4 + 2 * words
    return out


# -- frames -----------------------------------------------------------------------------------

# Registers worth aiming at: identity, addresses, DL, AL control/status, watchdogs, SII
# interface, FMMUs, SyncManagers, DC; and process memory where mailboxes and PDOs sit.
REGISTERS = (0x0000, 0x0010, 0x0012, 0x0100, 0x0101, 0x0103, 0x0110, 0x0120, 0x0121, 0x0130,
             0x0134, 0x0140, 0x0200, 0x0300, 0x0400, 0x0410, 0x0420, 0x0440, 0x0500, 0x0502,
             0x0504, 0x0508, 0x0600, 0x0610, 0x0620, 0x06F0, 0x0800, 0x0805, 0x0806, 0x0808,
             0x080D, 0x080E, 0x0810, 0x0818, 0x0820, 0x0838, 0x0900, 0x0910, 0x0918, 0x0920,
             0x0928, 0x0930, 0x0934, 0x0980, 0x0981, 0x0990, 0x09A0, 0x0FFF, 0x1000, 0x1080,
             0x1100, 0x1180, 0x1200, 0x1800, 0x1C00, 0xFFF0, 0xFFFF)
# Station addresses of the seed lines (1001..), auto-increment positions (0, -1, ...), others.
STATIONS = (0, 1, 1001, 1002, 1003, 1004, 1005, 0xFFFF, 0xFFFE, 0xFFFD, 0xFFFC, 0xFFFB)
AL_REQUESTS = (0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x08, 0x0F, 0x11, 0x12, 0x14, 0x18, 0x1F,
               0x20, 0xFF)
MAILBOX_OUT, MAILBOX_IN = 0x1000, 0x1080          # the example devices' mailboxes
MAILBOX_SIZE = 128


def _field(seed_values: tuple[int, ...], bits: int) -> st.SearchStrategy[int]:
    return st.one_of(st.sampled_from(seed_values), st.integers(0, (1 << bits) - 1))


def _sm_image() -> st.SearchStrategy[bytes]:
    """One SyncManager's 8 registers, each field a value a real configuration holds (the
    examples' SMs), a boundary (register space, end of memory), or anything; activate
    with and without the repeat request."""
    return st.builds(lambda start, length, control, status, act, pdi: struct.pack(
        "<HHBBBB", start, length, control, status, act, pdi),
        _field((0x0130, 0x1080, 0x1000, 0x0000, 0xFFF0, 0x1100, 0x1180, 0x0F00, 0x0100,
                0x0FFF, 0xFFFF), 16),
        _field((128, 0xFFFF, 6, 1, 0, 2, 0x1000), 16),
        _field((0x22, 0x26, 0x64, 0x20, 0x00, 0x44, 0x02), 8),
        _field((0, 0x08, 0x09), 8), _field((3, 1, 2, 0), 8), _field((0, 1, 2), 8))


def _fmmu_image() -> st.SearchStrategy[bytes]:
    return st.builds(lambda log, length, sbit, ebit, phys, pbit, kind, act: struct.pack(
        "<IHBBHBBB3x", log, length, sbit, ebit, phys, pbit, kind, act),
        _field((0, 1, 0x10000, 0x09000000, 0xFFFFFFFF), 32), _field((0, 1, 2, 8, 0xFFFF), 16),
        _field((0, 7), 3), _field((0, 7), 3),
        _field((0x1000, 0x1100, 0x1180, 0x080D, 0x0130, 0x0000, 0xFFFF), 16),
        _field((0, 7), 3), _field((1, 2, 3), 2), _field((1,), 1))


def _mailbox_message() -> st.SearchStrategy[bytes]:
    """A mailbox message as a master writes it into SM0: header (length, address, channel
    and priority, type and counter), then CoE and SDO headers, with any field odd."""
    header = st.builds(lambda length, address, chan, kind, cnt: struct.pack(
        "<HHBB", length, address, chan, kind | cnt << 4),
        _field((10, 6, 0, 122, 128, 0xFFFF), 16), _field((0,), 16), _field((0,), 8),
        _field((3, 0, 1, 2, 4, 5, 15), 4), st.integers(0, 7))
    coe = _field((0x2000, 0x3000, 0x8000, 0x1000), 16).map(lambda w: struct.pack("<H", w))
    sdo = st.builds(lambda command, index, sub, rest: struct.pack("<BHB", command, index, sub)
                    + rest,
                    _field((0x40, 0x23, 0x2B, 0x2F, 0x21, 0x60, 0x00, 0x10, 0x80, 0x01,
                            0x51, 0x61), 8),
                    _field((0x1000, 0x1018, 0x1C12, 0x1C13, 0x1600, 0x1A00, 0x6060, 0xF030,
                            0x10F1), 16),
                    _field((0, 1, 2, 0xFF), 8), st.binary(max_size=12))
    body = st.one_of(st.tuples(coe, sdo).map(b"".join), st.binary(max_size=20))
    return st.tuples(header, body).map(b"".join)


def _sized(data: bytes, size: int) -> bytes:
    return data[:size].ljust(size, b"\0")


@st.composite
def datagram(draw):
    """One datagram of a kind a master sends (or a wrong one): register writes of SM, FMMU,
    AL control, SII and DC blocks, mailbox messages into SM0, mailbox and register reads,
    logical process data, or anything at all."""
    from ecatcfg.esc import Cmd
    from ecatcfg.runtime.wire import Datagram
    kind = draw(st.sampled_from(("sm", "fmmu", "al", "sii", "dc", "mailbox", "read",
                                 "logical", "any")))
    writes = (Cmd.BWR, Cmd.FPWR, Cmd.APWR, Cmd.BRW, Cmd.FPRW, Cmd.APRW, Cmd.FRMW, Cmd.ARMW)
    cmd = draw(st.sampled_from(writes))
    adp = draw(st.sampled_from(STATIONS))
    if kind == "sm":
        first = draw(st.integers(0, 7))
        ado = 0x0800 + 8 * first
        data = b"".join(draw(st.lists(_sm_image(), min_size=1, max_size=8 - first)))
        data += draw(st.binary(max_size=2))
    elif kind == "fmmu":
        first = draw(st.integers(0, 7))
        ado = 0x0600 + 16 * first
        data = b"".join(draw(st.lists(_fmmu_image(), min_size=1, max_size=4)))
    elif kind == "al":
        ado, data = 0x0120, bytes([draw(st.sampled_from(AL_REQUESTS)), draw(st.integers(0, 255))])
    elif kind == "sii":
        ado = 0x0500
        data = struct.pack("<BBHI", draw(_field((0, 1), 8)), draw(_field((0,), 8)),
                           draw(_field((0x0100, 0x0201, 0x0300, 0x0400), 16)),
                           draw(_field((0, 8, 0x40, 0xFFFF), 32)))
    elif kind == "dc":
        ado = draw(st.sampled_from((0x0900, 0x0910, 0x0920, 0x0928, 0x0930, 0x0980, 0x0981,
                                    0x0990, 0x09A0)))
        data = draw(st.binary(min_size=1, max_size=16))
    elif kind == "mailbox":
        ado = draw(_field((MAILBOX_OUT,), 16))
        data = _sized(draw(_mailbox_message()), draw(_field((MAILBOX_SIZE, 6, 16), 8)))
    elif kind == "read":
        cmd = draw(st.sampled_from((Cmd.FPRD, Cmd.APRD, Cmd.BRD, Cmd.NOP)))
        ado = draw(st.one_of(st.just(MAILBOX_IN), st.sampled_from(REGISTERS)))
        data = bytes(draw(_field((MAILBOX_SIZE, 2, 6, 8), 7)))
    elif kind == "logical":
        cmd = draw(st.sampled_from((Cmd.LRD, Cmd.LWR, Cmd.LRW)))
        return Datagram.logical(cmd, draw(_field((0, 1, 0x09000000), 32)),
                                draw(st.binary(max_size=40)))
    else:
        cmd = draw(st.integers(0, 255))
        ado = draw(_field(REGISTERS, 16))
        data = draw(st.binary(max_size=80))
    return Datagram.physical(cmd, adp, ado, data)


@st.composite
def frame(draw) -> bytes:
    """An EtherCAT frame from the wire: well-formed datagrams, sometimes damaged."""
    from ecatcfg.runtime import wire
    dgs = draw(st.lists(datagram(), min_size=1, max_size=3))
    for i, dg in enumerate(dgs):
        dg.idx = i
        dg.wkc = draw(st.sampled_from((0, 0, 0, 1, 0xFFFF)))
    data = wire.encode(dgs)
    if draw(st.integers(0, 9)) == 0:
        data = draw(byte_edits(data, max_edits=2))
    return data


def frames() -> st.SearchStrategy[list[bytes]]:
    return st.lists(frame(), min_size=1, max_size=4)


# -- the virtual line -------------------------------------------------------------------------

class LoopLink:
    """The master's link straight into a virtual segment, in the caller's thread: a frame
    sent is processed at once and its reply (after ``tamper``) waits to be received.  No
    threads, so a run is repeatable; a lost reply costs the master's timeout in sleep."""

    def __init__(self, segment, tamper: Callable[[bytes], list[bytes]] | None = None) -> None:
        self.segment = segment
        self.tamper = tamper
        self.queue: collections.deque[bytes] = collections.deque()
        self.sent: list[bytes] = []

    def send(self, frame: bytes) -> None:
        self.sent.append(bytes(frame))
        reply = bytes(self.segment.process(frame))
        self.queue.extend(self.tamper(reply) if self.tamper else [reply])

    def recv(self, timeout: float | None = None) -> bytes | None:
        if self.queue:
            return self.queue.popleft()
        if timeout:
            time.sleep(min(timeout, 0.005))
        return None

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        pass


@contextlib.contextmanager
def short_waits() -> Iterator[None]:
    """Every wait of the master fires after at most :data:`SHORT_WAIT_S`: a timeout that
    fires is an allowed outcome, and waiting it out in full would only slow the campaign."""
    from ecatcfg.runtime.master import bringup as master, replay, scan
    saved = [(m, n, getattr(m, n)) for m, n in (
        (replay, "TIMEOUT_COMMAND"), (replay, "TIMEOUT_STATE"), (replay, "TIMEOUT_VALIDATE"),
        (replay, "TIMEOUT_MAILBOX"), (master, "TIMEOUT_COMMAND"), (scan, "EEPROM_TIMEOUT"))]
    for module, name, _ in saved:
        setattr(module, name, SHORT_WAIT_S)
    try:
        yield
    finally:
        for module, name, value in saved:
            setattr(module, name, value)


def _cap_timeouts(plan) -> None:
    """The ENI's own timeouts (ms), cut to :data:`SHORT_WAIT_S` like the defaults."""
    limit = int(SHORT_WAIT_S * 1000)
    cmds = list(plan.master.init_cmds)
    for s in plan.slaves:
        cmds += s.init_cmds
        for c in s.mailbox.coe_init_cmds if s.mailbox else []:
            if c.timeout is not None and c.timeout > limit:
                c.timeout = limit
    for c in cmds:
        if c.timeout is not None and c.timeout > limit:
            c.timeout = limit
        if c.validate is not None and c.validate.timeout > limit:
            c.validate.timeout = limit


def line_for(plan, shown: str = "fuzz.eni.xml"):
    """A fresh virtual segment emulating the ENI's slaves from the example ESI files."""
    from ecatcfg.runtime.segment import emulate
    return emulate.segment(emulate.specs_from_eni(plan, library(), shown))


def apply_plan(plan, tamper=None, cycles: int = 3) -> None:
    """What ``ecatcfg apply --virtual`` does with a plan: up to OP, cycles, the states,
    every process variable, down to INIT."""
    from ecatcfg.runtime.network import Network
    link = LoopLink(line_for(plan), tamper)
    with short_waits():
        # The DC convergence wait too (5 s by default, the hang limit): a mutated DC command
        # can keep the clocks apart, and waiting that out is an allowed outcome, not a hang.
        net = Network(plan, link, dc_timeout_s=DC_WAIT_S)
        net.master.transport.timeout = 0.005
        failure = None
        try:
            net.up()
            for _ in range(cycles):
                net.cycle()
            for name in net.variables:
                net[name]
        except EcatcfgError as exc:
            failure = exc
        net.master.read_states()
        try:
            if net.state > 1:
                net.down()
        finally:
            net.close()
        if failure is not None:
            raise failure


@functools.cache
def bring_up_traffic(eni: bytes) -> tuple[bytes, ...]:
    """The frames the master sends to bring the ENI's line to OP (recorded once)."""
    from ecatcfg.eni import reader
    from ecatcfg.runtime.network import Network
    plan = reader.read_bytes(eni, "seed.eni.xml")
    link = LoopLink(line_for(plan))
    net = Network(plan, link)
    net.up()
    net.cycle()
    return tuple(link.sent)


def line_in_op(eni: bytes):
    """A fresh segment in OP: the recorded bring-up replayed into it."""
    from ecatcfg.eni import reader
    from ecatcfg.esc import AlState
    segment = line_for(reader.read_bytes(eni, "seed.eni.xml"))
    for f in bring_up_traffic(eni):
        segment.process(f)
    assert all(s.state == AlState.OP for s in segment.slaves), "the seed line is not in OP"
    return segment


def feed_segment(value: tuple[int, list[bytes]]) -> None:
    """Frames from the wire into a line in OP: the segment answers every frame (returns it,
    same length), and each emulated ESC keeps its 64 KiB and a valid AL state."""
    from ecatcfg.runtime.segment.slave import MEMORY_SIZE
    seed, sequence = value
    segment = line_in_op(eni_seeds()[seed])
    for f in sequence:
        reply = segment.process(f)
        if len(reply) != len(f):
            raise Defect(f"the segment returned {len(reply)} bytes for a {len(f)}-byte frame")
        for s in segment.slaves:
            if len(s.mem) != MEMORY_SIZE:
                raise Defect(f"slave {s.name!r}: ESC memory is now {len(s.mem)} bytes")
            s.state       # raises if AL status holds no state


# -- replies at the master --------------------------------------------------------------------

REPLY_DAMAGE = ("truncate", "ecat_length", "dg_length", "wkc", "index", "cmd", "data",
                "mailbox", "more_flag", "drop", "duplicate", "stale", "junk")


# Fields of a mailbox message as it comes back in an SM1 read: (offset, size, mask) of the
# header's length, type, counter; the CoE service; the SDO command, index, subindex and
# size or data (ETG.1000.4 mailbox header, ETG.1000.6 CoE and SDO headers).
MAILBOX_FIELDS = {"length": (0, 2, 0xFFFF), "type": (5, 1, 0x0F), "counter": (5, 1, 0x70),
                  "service": (6, 2, 0xF000), "sdo_command": (8, 1, 0xFF),
                  "index": (9, 2, 0xFFFF), "subindex": (11, 1, 0xFF), "size": (12, 4, 0xFFFF_FFFF),
                  "bytes": (0, 0, 0)}


@dataclass(frozen=True)
class ReplyFault:
    """Damage done to one reply on its way back: the ``nth`` reply that ``kind`` applies
    to (a mailbox read for ``mailbox``, any reply otherwise).  ``value`` picks a datagram
    or a length, ``word`` is a value written, ``field`` the mailbox field it goes into."""

    kind: str
    nth: int
    value: int
    word: int
    field: str
    data: bytes


def reply_faults() -> st.SearchStrategy[list[ReplyFault]]:
    # Half of the faults go to mailbox replies: a few per bring-up, but the most parsing.
    kind = st.one_of(st.sampled_from(REPLY_DAMAGE), st.just("mailbox"))
    fault = st.builds(ReplyFault, kind, st.integers(0, 320),
                      _field((0, 1, 2, 3, 0xFF, 0x7FF, 0xFFFF), 16),
                      _field((0, 1, 2, 3, 4, 6, 10, 0x7F, 0x80, 0xFF, 0x1000, 0x2000, 0x3000,
                              0x8000, 0xFFFF, 0xFFFF_FFFF), 32),
                      st.sampled_from(list(MAILBOX_FIELDS)),
                      st.binary(min_size=1, max_size=16))
    return st.lists(fault, min_size=1, max_size=4)


def _is_mailbox_read(frame: bytes) -> list[int]:
    """Offsets of datagrams that carry a mailbox message back (FPRD of process memory,
    answered)."""
    from ecatcfg.runtime import wire
    found = []
    try:
        offsets = wire.datagram_offsets(frame)
    except wire.FrameError:
        return found
    for pos, n in offsets:
        ado, = struct.unpack_from("<H", frame, pos + 4)
        wkc, = struct.unpack_from("<H", frame, pos + wire.DG_HEADER_LEN + n)
        if frame[pos] == 4 and ado >= 0x1000 and n >= 6 and wkc:
            found.append(pos)
    return found


class Tamper:
    """Applies :class:`ReplyFault` s to the replies as they pass."""

    def __init__(self, faults: list[ReplyFault]) -> None:
        self.faults = faults
        self.seen = collections.Counter()
        self.held: list[bytes] = []

    def __call__(self, reply: bytes) -> list[bytes]:
        out = self.held + [reply]
        self.held = []
        mailbox = _is_mailbox_read(reply)
        replies, reads = self.seen["any"], self.seen["mailbox"]
        self.seen["any"] += 1
        self.seen["mailbox"] += bool(mailbox)
        for f in self.faults:
            if f.kind == "mailbox":
                hit = bool(mailbox) and f.nth % 8 == reads      # a bring-up has ~10
            else:
                hit = f.nth == replies
            if hit:
                out = self._damage(f, out, mailbox)
        return out

    def _damage(self, f: ReplyFault, out: list[bytes], mailbox: list[int]) -> list[bytes]:
        from ecatcfg.runtime import wire
        if not out:
            return out
        frame = bytearray(out[-1])
        offsets = []
        try:
            offsets = wire.datagram_offsets(frame)
        except wire.FrameError:
            pass
        pos, n = offsets[f.value % len(offsets)] if offsets else (wire.FRAME_HEADER_END, 0)
        if f.kind == "truncate":
            del frame[f.value % (len(frame) + 1):]
        elif f.kind == "ecat_length" and len(frame) >= wire.FRAME_HEADER_END:
            struct.pack_into("<H", frame, wire.ETH_LEN, (f.value & 0x7FF) | 0x1000)
        elif f.kind == "dg_length" and offsets:
            flags, = struct.unpack_from("<H", frame, pos + 6)
            struct.pack_into("<H", frame, pos + 6, flags & ~0x7FF | f.value & 0x7FF)
        elif f.kind == "wkc" and offsets:
            struct.pack_into("<H", frame, pos + wire.DG_HEADER_LEN + n, f.value)
        elif f.kind == "index" and offsets:
            frame[pos + 1] = f.value & 0xFF
        elif f.kind == "cmd" and offsets:
            frame[pos] = f.value & 0xFF
        elif f.kind == "data" and offsets and n:
            at = pos + wire.DG_HEADER_LEN + f.value % n
            frame[at:at + len(f.data)] = f.data[:pos + wire.DG_HEADER_LEN + n - at]
        elif f.kind == "mailbox" and mailbox:
            # One field of the mailbox, CoE or SDO header set to an odd value, or bytes.
            base = mailbox[0] + wire.DG_HEADER_LEN
            offset, size, mask = MAILBOX_FIELDS[f.field]
            if size:
                shift = (mask & -mask).bit_length() - 1
                old = int.from_bytes(frame[base + offset:base + offset + size], "little")
                new = old & ~mask | (f.word << shift) & mask
                frame[base + offset:base + offset + size] = new.to_bytes(size, "little")
            else:
                at = base + f.value % 16
                frame[at:at + len(f.data)] = f.data[:max(0, len(frame) - at - 2)]
        elif f.kind == "more_flag" and offsets:
            frame[pos + 7] ^= 0x80
        elif f.kind == "drop":
            return out[:-1]
        elif f.kind == "duplicate":
            return out + [bytes(frame)]
        elif f.kind == "stale":
            self.held.append(bytes(frame))
            return out[:-1]
        elif f.kind == "junk":
            return out + [bytes(f.data)]
        out[-1] = bytes(frame)
        return out


def master_with_faults(value: tuple[int, list[ReplyFault]]) -> None:
    from ecatcfg.eni import reader
    seed, faults = value
    plan = reader.read_bytes(eni_seeds()[seed], "seed.eni.xml")
    apply_plan(plan, Tamper(faults))


# -- the targets ------------------------------------------------------------------------------

def _esi(m: Mutant) -> None:
    from ecatcfg.esi import reader
    reader.read_bytes(m.data(), "fuzz.xml")


def _esi_device(m: Mutant) -> None:
    # What `simulate`, `emulate` and `Network.virtual` make of an ESI the reader loads: each
    # device through the Library, its SII image and its emulated slave (object dictionary,
    # SDO server), and a compile of it.
    from ecatcfg.compiler import topology
    from ecatcfg.compiler.build import compile_topology
    from ecatcfg.esi import sii
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment.emulate import SlaveSpec, emulated_slave
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "fuzz.xml").write_bytes(m.data())
        lib = Library([tmp], cache=False)
        for entry in lib.entries:
            device = lib.device(entry)
            sii.build(device)
            emulated_slave(SlaveSpec(device, name="fuzz"))
            if device.product_code is not None and device.vendor.id is not None:
                text = (f"master: {{name: m}}\nslaves:\n  - {{name: d, device: "
                        f"'{device.vendor.id:#x}:{device.product_code:#x}'}}\n")
                compile_topology(topology.loads(text, "fuzz.yaml"), lib)


def _in_fuzz_esi(exc: EcatcfgError) -> bool:
    # The ESI is read from a temporary folder: the file is named by its path there; compile
    # names the topology's line (and the ESI's in its message).
    errors = getattr(exc, "problems", None) or [exc]
    return all(str(e.file).endswith(("fuzz.xml", "fuzz.yaml")) and (e.line or getattr(e, "offset", None)
                                                      is not None) for e in errors)


def _lint(m: Mutant) -> None:
    from ecatcfg.esi.lint.rules import RULES
    from ecatcfg.esi.lint.runner import LintOptions, Target as LintTarget, lint_file
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzz.xml"
        path.write_bytes(m.data())
        lint_file(LintTarget(path, "fuzz.xml", True), LintOptions(frozenset(RULES)), [path])


def _topology(m: Mutant) -> None:
    from ecatcfg.compiler import topology
    topology.loads(m.data(), "fuzz.yaml")


def _compile(m: Mutant) -> None:
    from ecatcfg.compiler import header, topology
    from ecatcfg.compiler.build import compile_topology
    from ecatcfg.eni import reader, writer
    result = compile_topology(topology.loads(m.data(), "fuzz.yaml"), library())
    eni = writer.to_bytes(result.plan, generator="fuzz")
    header.render(result.plan, "fuzz.yaml", guard=header.guard_for("fuzz.h"))
    reader.read_bytes(eni, "fuzz.eni.xml")       # what we write, we read


def _eni(m: Mutant) -> None:
    from ecatcfg.eni import reader
    reader.read_bytes(m.data(), "fuzz.eni.xml")


def _eni_apply(m: Mutant) -> None:
    from ecatcfg.eni import reader
    plan = reader.read_bytes(m.data(), "fuzz.eni.xml")
    _cap_timeouts(plan)
    apply_plan(plan)


def _sii(data: bytes) -> None:
    from ecatcfg.esi import sii
    sii.decode(data, source="fuzz.bin")


def _frame_decode(data: bytes) -> None:
    from ecatcfg.runtime import wire
    wire.decode(data)


def _eni_apply_inputs() -> st.SearchStrategy[Mutant]:
    # Numbers only: a broken XML or a missing element is the reader's business (the
    # eni_reader target); this one feeds plans the reader accepts to the master and the
    # emulation, with the values they put on the wire.
    return mutants("eni", values=3, numeric=True)


def _frame_inputs() -> st.SearchStrategy[bytes]:
    from ecatcfg.runtime import wire
    valid = st.lists(datagram(), min_size=1, max_size=3).map(wire.encode)
    return st.one_of(valid, valid.flatmap(lambda d: byte_edits(d, max_edits=3)),
                     st.binary(max_size=80))


_IN_FILE = located_in_file

TARGETS: dict[str, Target] = {t.name: t for t in (
    Target("esi_reader", "ESI files (example devices, values/elements/bytes mutated)",
           lambda: xml_inputs("esi"), _esi, _IN_FILE("fuzz.xml"), 200),
    Target("esi_device", "ESI files (numbers far out of range, negative sizes, huge counts) "
           "through Library, SII build, the emulated slave and compile",
           lambda: mutants("esi", values=3, numeric=True), _esi_device, _in_fuzz_esi, 100),
    Target("lint", "ESI files through every lint rule", lambda: xml_inputs("esi"),
           _lint, _IN_FILE("fuzz.xml"), 120),
    Target("topology", "topology YAML/JSON (scalars, explicit tags, syntax mutated)",
           lambda: yaml_inputs("topology"), _topology, _IN_FILE("fuzz.yaml"), 300),
    Target("compiler", "topologies compiled against the example ESI files, ENI written "
           "and read back", lambda: mutants("topology", yaml_values=2),
           _compile, _IN_FILE("fuzz.yaml"), 200),
    Target("eni_reader", "ENI files (compiled from the examples, mutated)",
           lambda: xml_inputs("eni"), _eni, _IN_FILE("fuzz.eni.xml"), 250),
    Target("eni_apply", "ENIs the reader accepts, applied on the virtual segment",
           _eni_apply_inputs, _eni_apply, located_on_line, 400),
    Target("sii_decoder", "SII images built from the example devices, mutated",
           sii_inputs, _sii, _IN_FILE("fuzz.bin"), 400),
    Target("frame_decoder", "Ethernet frames into the datagram decoder", _frame_inputs,
           _frame_decode, lambda exc: True, 200),
    Target("segment", "frames from the wire against a line in OP",
           lambda: st.tuples(st.integers(0, len(eni_seeds()) - 1), frames()),
           feed_segment, located_on_line, 250),
    Target("master", "replies damaged on their way back to the master (bring-up, cycles, "
           "way down)", lambda: st.tuples(st.integers(0, len(eni_seeds()) - 1),
                                          reply_faults()),
           master_with_faults, located_on_line, 120),
)}
