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
import copy
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

HANG_S = 5.0            # an input that uses more CPU than this is a hang (a defect) ...
HANG_WALL_S = 30.0      # ... and so is one that runs longer than this (a wait without end)
SHORT_WAIT_S = 0.2      # every wait of the master is cut to this in the runtime targets
SHORT_DRIFT_FRAMES = 100  # static drift compensation frames in the campaign (2000 in apply)
DC_WAIT_S = 2.0         # ... and the DC convergence wait to this (under the hang limits)


class Defect(AssertionError):
    """An outcome the harness does not allow (other than an exception escaping)."""


class Hang(Defect):
    """An input used more than :data:`HANG_S` of CPU or ran longer than :data:`HANG_WALL_S`."""


# -- outcomes ---------------------------------------------------------------------------------

@contextlib.contextmanager
def watchdog(seconds: float = HANG_S, wall: float = HANG_WALL_S) -> Iterator[None]:
    """Raise :class:`Hang` in the main thread when the block uses more than ``seconds`` of
    CPU, or runs longer than ``wall`` (a wait that never ends uses little CPU).  CPU time,
    not wall time, for the first: on a machine shared with other work an input that takes
    20 ms alone can take seconds of wall time, and that is no hang.  Signals (SIGPROF,
    SIGALRM): a Python loop is interrupted; a long call in C is caught when it returns.
    The alarms repeat every second until the block ends: a :class:`Hang` raised where it is
    swallowed (a garbage-collector callback, an ``except Exception`` in the code under
    test) is raised again."""
    start, cpu = time.monotonic(), time.process_time()

    def fire(signum, frame):
        what = "CPU" if signum == signal.SIGPROF else "wall time"
        raise Hang(f"no result after {seconds if signum == signal.SIGPROF else wall:g} s "
                   f"of {what}")

    main = threading.current_thread() is threading.main_thread()    # signals go there
    if main:
        old = {s: signal.signal(s, fire) for s in (signal.SIGPROF, signal.SIGALRM)}
        signal.setitimer(signal.ITIMER_PROF, seconds, 1.0)
        signal.setitimer(signal.ITIMER_REAL, wall, 1.0)
    try:
        yield
    finally:
        if main:
            signal.setitimer(signal.ITIMER_PROF, 0)
            signal.setitimer(signal.ITIMER_REAL, 0)
            for s, handler in old.items():
                signal.signal(s, handler)
    took, used = time.monotonic() - start, time.process_time() - cpu
    if used > seconds or took > wall:
        raise Hang(f"the input took {used:.1f} s of CPU (limit {seconds:g} s), {took:.1f} s "
                   f"of wall time (limit {wall:g} s)")


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
    # Built lazily (seeds cost a compile); called with the mutation kinds to draw from, or
    # None for the target's own mix (the test suite's campaign).
    strategy: Callable[[frozenset[str] | None], st.SearchStrategy]
    call: Callable[[Any], None]
    located: Callable[[EcatcfgError], bool]
    ci_examples: int                             # inputs in the test suite's campaign
    kinds: tuple[str, ...] = ()                  # the MUTATION_KINDS its strategy takes
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


# -- mutation kinds ---------------------------------------------------------------------------
#
# What an edit puts into a seed, by kind.  The default strategies mix them all; ``--mutations``
# in bench/fuzz.py (and ``mutants(..., kinds=...)``) draws from a few only.  Hypothesis stops a
# run at its first failure and shrinks it towards the simplest input, so in a mix the kind
# with the simplest failing input (a BitLen of -1) hides the others (a number of 4 000 hex
# digits, a count of 2^31): one kind at a time, each shows its own.

#: Python refuses ``str()`` of an int with more decimal digits than this (CPython's default
#: ``sys.get_int_max_str_digits()``, 4300): a number that long crashes any message, log or
#: JSON it reaches.
STR_DIGITS_LIMIT = 4300


def number_kind(text: str) -> str:
    """The kind a number of :data:`NUMBERS` belongs to, from what it is: ``huge-numbers``
    (past :data:`STR_DIGITS_LIMIT` decimal digits), ``negative-sizes`` (below 0),
    ``huge-counts`` (above 65535: no size or count of an object, PDO or SyncManager is, and
    2^31..2^70 make lists, images and loops that never end), else ``boundaries``."""
    body = text.strip().lstrip("+-")
    negative = text.strip().startswith("-")
    if body[:2] in ("#x", "0x"):
        value = int(body[2:], 16)        # a power-of-two base: no digit limit
    elif len(body) > STR_DIGITS_LIMIT:
        return "huge-numbers"
    else:
        value = int(body)
    if value.bit_length() * 0.30103 > STR_DIGITS_LIMIT:      # log10(2)
        return "huge-numbers"
    if negative and value:
        return "negative-sizes"
    return "huge-counts" if value > 0xFFFF else "boundaries"


def _numbers_of(kind: str) -> tuple[str, ...]:
    return tuple(n for n in NUMBERS if _NUMBER.fullmatch(n.encode()) and number_kind(n) == kind)


#: Number kinds: beyond the fixed numbers of each kind, numbers drawn at random within it.
NUMBER_KINDS: dict[str, Callable[[], st.SearchStrategy[str]]] = {
    "boundaries": lambda: st.one_of(st.sampled_from(_numbers_of("boundaries")),
                                    st.integers(0, 0xFFFF).map(str)),
    "negative-sizes": lambda: st.one_of(st.sampled_from(_numbers_of("negative-sizes")),
                                        st.integers(-2**33, -1).map(str)),
    "huge-counts": lambda: st.one_of(st.sampled_from(_numbers_of("huge-counts")),
                                     st.integers(0x10000, 2**72).map(str),
                                     st.integers(0x10000, 2**72).map(lambda n: f"#x{n:X}")),
    "huge-numbers": lambda: st.one_of(
        st.sampled_from(_numbers_of("huge-numbers")),
        st.builds(lambda sign, prefix, digit, n: f"{sign}{prefix}{digit * n}",
                  st.sampled_from(("", "-")), st.sampled_from(("#x", "0x")),
                  st.sampled_from("123456789ABCDEF"), st.integers(3600, 6000)),
        st.integers(STR_DIGITS_LIMIT + 1, 6000).map(lambda n: "9" * n)),
}
#: Structure kinds: ``repeated-elements`` gives an element (a container too: ``Sm2``,
#: ``RxPdo``, ``Entry``) again right after itself; ``registers`` changes one field of an
#: FMMU or SyncManager register image that an ENI InitCmd writes (the master replays it
#: as written, so the emulated ESC gets it: an FMMU that maps logical memory onto AL
#: status, a SyncManager over the registers).
STRUCTURE_KINDS = ("repeated-elements", "registers")
MUTATION_KINDS = (*NUMBER_KINDS, *STRUCTURE_KINDS)


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
      ``duplicate`` a run, ``truncate`` from there on;
    - ``('repeat', tag, i, n)``: the i-th element ``tag`` (a container too) given n more
      times right after itself;
    - ``('register', i, entry, field, value)``: in the i-th ``InitCmd/Data`` (an InitCmd
      writing FMMU or SyncManager registers), the ``entry``-th register image's ``field``
      (an :class:`~ecatcfg.esc.FmmuConfig` or :class:`~ecatcfg.esc.SmConfig` field) set
      to ``value``.
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
            elif e[0] == "register":
                span = dict(xml_spans(data).groups)["InitCmd/Data"][e[1]]
                values[span] = _register_edit(values.get(span, data[span[0]:span[1]]),
                                              register_kind(data, e[1]), *e[2:])
        data = _apply(data, values)
        for e in self.edits:
            if e[0] == "element":
                data = _element(data, e[1], e[2], e[3])
            elif e[0] == "repeat":
                data = _repeat(data, e[1], e[2], e[3])
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


@functools.cache
def element_tags(data: bytes) -> tuple[tuple[str, int], ...]:
    """Each element name of the seed and how often it occurs (containers too)."""
    counts = collections.Counter(m.group(1).decode() for m in re.finditer(
        rb"<([A-Za-z_][\w.:-]*)[\s/>]", data))
    return tuple(sorted(counts.items()))


def _repeat(data: bytes, tag: str, i: int, repeat: int) -> bytes:
    """The i-th element ``tag`` and its content, given ``repeat`` more times after it."""
    name = re.escape(tag.encode())
    starts = [m.start() for m in re.finditer(rb"<" + name + rb"[\s/>]", data)]
    if not starts:
        return data
    first = starts[i % len(starts)]
    depth, end = 0, -1
    for m in re.finditer(rb"<(/?)" + name + rb"(?:\s[^<>]*?)?(/?)>", data[first:]):
        if m.group(2):               # <tag/>: empty, no nesting
            if depth == 0:
                end = first + m.end()
                break
        elif m.group(1):
            depth -= 1
            if depth == 0:
                end = first + m.end()
                break
        else:
            depth += 1
    if end < 0:
        return data
    return data[:end] + data[first:end] * repeat + data[end:]


# The register images an InitCmd may write, by the register block its <Ado> falls in
# (ETG.1000.4: FMMUs at 0x0600 + 16·n, SyncManagers at 0x0800 + 8·n).
def _register_blocks() -> dict[str, tuple[int, int, int, Any]]:
    from ecatcfg.esc import FMMU_SIZE, SM_SIZE, FmmuConfig, Reg, SmConfig
    return {"fmmu": (Reg.FMMU0, 16 * FMMU_SIZE, FMMU_SIZE, FmmuConfig),
            "sm": (Reg.SM0, 16 * SM_SIZE, SM_SIZE, SmConfig)}


@functools.cache
def register_places(data: bytes) -> tuple[tuple[int, str, int], ...]:
    """InitCmds that set up FMMU or SyncManager register images: (index of their
    ``InitCmd/Data`` value, ``fmmu`` or ``sm``, how many images the data holds).  The
    clears (all zero) are left out: one field changed there is mostly still a disabled
    image."""
    places = dict(xml_spans(data).groups).get("InitCmd/Data", ())
    where = {span: i for i, span in enumerate(places)}
    out = []
    for m in re.finditer(rb"<InitCmd>(.*?)</InitCmd>", data, re.S):
        ado = re.search(rb"<Ado>\s*([0-9]+|#x[0-9a-fA-F]+)\s*</Ado>", m.group(1))
        value = re.search(rb"<Data>([0-9a-fA-F]*)</Data>", m.group(1))
        if not ado or not value:
            continue
        text = ado.group(1).decode()
        address = int(text[2:], 16) if text.startswith("#x") else int(text)
        span = (m.start(1) + value.start(1), m.start(1) + value.end(1))
        for kind, (base, size, entry, _) in _register_blocks().items():
            n = len(value.group(1)) // 2 // entry
            if base <= address < base + size and (address - base) % entry == 0 and n \
                    and span in where and value.group(1).strip(b"0"):
                out.append((where[span], kind, n))
    return tuple(out)


def register_kind(data: bytes, i: int) -> str:
    return next(kind for index, kind, _ in register_places(data) if index == i)


def _register_edit(text: bytes, kind: str, entry: int, name: str, value: int) -> bytes:
    """Hex data of register images with one field of the ``entry``-th one set (through the
    images' own layouts in esc.py)."""
    from ecatcfg.record import replace
    _, _, size, config = _register_blocks()[kind]
    raw = bytearray(bytes.fromhex(text.decode()))
    image = config.from_bytes(raw[entry * size:(entry + 1) * size])
    raw[entry * size:(entry + 1) * size] = replace(image, **{name: value}).to_bytes()
    return raw.hex().encode()


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
            elements: bool = False, byte_ops: int = 0, numeric: bool = False,
            kinds: frozenset[str] | None = None) -> Mutant:
    """A :class:`Mutant` of a seed of ``family`` with up to ``values`` XML value edits
    (``numeric``: numbers by numbers only), ``scalars`` YAML scalar edits, maybe one
    element edit and up to ``byte_ops`` byte edits; ``yaml_values``: YAML values (not keys)
    replaced by values a topology holds, or numbers.

    ``kinds`` (of :data:`MUTATION_KINDS`): instead, 1 to ``values`` edits of those kinds
    only: numbers of the number kinds into numeric fields (or YAML values), elements
    repeated, register fields changed."""
    seeds = SEEDS[family]()
    seed = draw(st.integers(0, len(seeds) - 1))
    data = seeds[seed]
    edits: list[tuple] = []
    if kinds is not None:
        return Mutant(family, seed, tuple(draw(_kind_edits(data, family, kinds, values or 3))))
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


@st.composite
def _kind_edits(draw, data: bytes, family: str, kinds: frozenset[str], most: int) -> list[tuple]:
    numbers = [NUMBER_KINDS[k]() for k in sorted(kinds & set(NUMBER_KINDS))]
    sorts = []
    if numbers:
        sorts.append("yaml_value" if family == "topology" else "value")
    if "repeated-elements" in kinds and family != "topology":
        sorts.append("repeat")
    if "registers" in kinds and register_places(data):
        sorts.append("register")
    if not sorts:
        raise ValueError(f"no edit of the kinds {sorted(kinds)} applies to a {family} seed")
    edits: list[tuple] = []
    for _ in range(draw(st.integers(1, most))):
        sort = draw(st.sampled_from(sorts))
        if sort == "value":
            group, places = draw(st.sampled_from(numeric_groups(data)))
            edits.append(("value", group, draw(st.integers(0, len(places) - 1)),
                          draw(st.one_of(numbers))))
        elif sort == "yaml_value":
            edits.append(("yaml_value", draw(st.integers(0, len(yaml_spans(data, True)) - 1)),
                          draw(st.one_of(numbers))))
        elif sort == "repeat":
            tag, count = draw(st.sampled_from(element_tags(data)))
            edits.append(("repeat", tag, draw(st.integers(0, count - 1)),
                          draw(st.integers(1, 2))))
        else:
            # FMMU and SyncManager images as often as each other (a seed has more SMs).
            kind = draw(st.sampled_from(sorted({k for _, k, _ in register_places(data)})))
            index, kind, n = draw(st.sampled_from([p for p in register_places(data)
                                                   if p[1] == kind]))
            name, values = draw(st.sampled_from(sorted(REGISTER_FIELDS[kind].items())))
            entry = draw(st.integers(0, n - 1))
            a, b = dict(xml_spans(data).groups)["InitCmd/Data"][index]
            size, config = _register_blocks()[kind][2:]
            image = config.from_bytes(bytes.fromhex(data[a:b].decode())[entry * size:])
            now = int(getattr(image, name))          # a new value, not the one it has
            # The field's values of note three times in four, anything else the fourth.
            seen, bits = values
            value = st.one_of(st.sampled_from(seen), st.sampled_from(seen),
                              st.sampled_from(seen), st.integers(0, (1 << bits) - 1))
            edits.append(("register", index, entry, name,
                          draw(value.filter(lambda v: v != now))))
    return edits


def xml_inputs(family: str, kinds: frozenset[str] | None = None) -> st.SearchStrategy[Mutant]:
    if kinds is not None:
        return mutants(family, values=3, kinds=kinds)
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


# The fields of an SM and an FMMU register image (esc.SmConfig, esc.FmmuConfig), each with
# values a real configuration holds (the examples'), boundaries (register space: AL control
# and status, the SMs; the end of memory) and its width in bits.
REGISTER_FIELDS: dict[str, dict[str, tuple[tuple[int, ...], int]]] = {
    "sm": {"start": ((0x0130, 0x1080, 0x1000, 0x0000, 0xFFF0, 0x1100, 0x1180, 0x0F00, 0x0100,
                      0x0FFF, 0xFFFF), 16),
           "length": ((128, 0xFFFF, 6, 1, 0, 2, 0x1000), 16),
           "control": ((0x22, 0x26, 0x64, 0x20, 0x00, 0x44, 0x02), 8),
           "status": ((0, 0x08, 0x09), 8), "enable": ((3, 1, 2, 0), 8),   # + repeat
           "pdi_control": ((0, 1, 2), 8)},
    "fmmu": {"logical_start": ((0, 1, 0x10000, 0x09000000, 0xFFFFFFFF), 32),
             "length": ((0, 1, 2, 8, 0xFFFF), 16),
             "logical_start_bit": ((0, 7), 3), "logical_stop_bit": ((0, 7), 3),
             "physical_start": ((0x1000, 0x1100, 0x1180, 0x080D, 0x0130, 0x0120, 0x0000,
                                 0xFFFF), 16),
             "physical_start_bit": ((0, 7), 3), "type": ((1, 2, 3), 2), "active": ((1,), 1)},
}


def _sm_image() -> st.SearchStrategy[bytes]:
    """One SyncManager's 8 registers, each field a value a real configuration holds (the
    examples' SMs), a boundary (register space, end of memory), or anything; activate
    with and without the repeat request."""
    f = REGISTER_FIELDS["sm"]
    return st.builds(lambda start, length, control, status, act, pdi: struct.pack(
        "<HHBBBB", start, length, control, status, act, pdi),
        _field(*f["start"]), _field(*f["length"]), _field(*f["control"]),
        _field(*f["status"]), _field(*f["enable"]), _field(*f["pdi_control"]))


def _fmmu_image() -> st.SearchStrategy[bytes]:
    f = REGISTER_FIELDS["fmmu"]
    return st.builds(lambda log, length, sbit, ebit, phys, pbit, kind, act: struct.pack(
        "<IHBBHBBB3x", log, length, sbit, ebit, phys, pbit, kind, act),
        *(_field(*f[name]) for name in ("logical_start", "length", "logical_start_bit",
                                        "logical_stop_bit")),
        *(_field(*f[name]) for name in ("physical_start", "physical_start_bit", "type",
                                        "active")))


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
    """The master's link straight into a virtual segment, in the caller's thread, on
    simulated time (``clock``: the master's transport takes it, the segment is set on it):
    a frame sent is processed at once, costing its round trip, and its reply (after
    ``tamper``) waits to be received.  No threads and no host time, so a run is
    repeatable; a lost reply costs the master's timeout in simulated time only."""

    def __init__(self, segment, tamper: Callable[[bytes], list[bytes]] | None = None) -> None:
        from ecatcfg.runtime.clock import SimClock
        self.clock = SimClock()
        segment.set_clock(self.clock.monotonic_ns)
        self.segment = segment
        self.tamper = tamper
        self.queue: collections.deque[bytes] = collections.deque()
        self.sent: list[bytes] = []

    def send(self, frame: bytes) -> None:
        self.sent.append(bytes(frame))
        self.segment.tick()                     # watchdogs and timing as of now
        reply = bytes(self.segment.process(frame))
        self.clock.advance(self.segment.round_trip_ns(len(frame)))
        self.queue.extend(self.tamper(reply) if self.tamper else [reply])

    def recv(self, timeout: float | None = None) -> bytes | None:
        if self.queue:
            return self.queue.popleft()
        if timeout:
            self.clock.sleep(timeout)
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
    # The static drift compensation's 2000 identical FRMWs test nothing a few do not (the
    # convergence wait after them still reads 0x092C until the clocks agree): most of a
    # DC line's frames, and most of the campaign's time, otherwise.
    saved.append((master, "DRIFT_FRAMES", master.DRIFT_FRAMES))
    master.DRIFT_FRAMES = SHORT_DRIFT_FRAMES
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
            # Every variable read, every output written (0 fits any type), as an
            # application does: the image offsets the ENI gives are used here.
            for name in net.variables:
                net[name]
            for var in plan.process_image.outputs:
                net[var.name] = 0
            net.cycle()
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


@functools.cache
def _seed_line_in_op(seed: int):
    return line_in_op(eni_seeds()[seed])


def feed_segment(value: tuple[int, list[bytes]]) -> None:
    """Frames from the wire into a line in OP: the segment answers every frame (returns it,
    same length), and each emulated ESC keeps its 64 KiB and a valid AL state."""
    from ecatcfg.runtime.segment.slave import MEMORY_SIZE
    seed, sequence = value
    # A copy of the seed's line brought up once: the same state as replaying its bring-up
    # (about a tenth of the time), and no input sees what an earlier one did to the line.
    segment = copy.deepcopy(_seed_line_in_op(seed))
    for f in sequence:
        reply = segment.process(f)
        if len(reply) != len(f):
            raise Defect(f"the segment returned {len(reply)} bytes for a {len(f)}-byte frame")
        for s in segment.slaves:
            if len(s.mem) != MEMORY_SIZE:
                raise Defect(f"slave {s.name!r}: ESC memory is now {len(s.mem)} bytes")
            s.state       # raises if AL status holds no state


def _init_cmd_frames(plan, transition: str) -> list[bytes]:
    """The ENI's register InitCmds of one transition as frames, one datagram each, in the
    order a master sends them: the master's before the slaves, each slave's, the master's
    after (CoE InitCmds are mailbox traffic, left out)."""
    from ecatcfg.esc import LOGICAL_CMDS
    from ecatcfg.runtime import wire
    from ecatcfg.runtime.wire import Datagram
    master = [c for c in plan.master.init_cmds if transition in c.transitions]
    cmds = [c for c in master if c.before_slave] + [
        c for s in plan.slaves for c in s.init_cmds if transition in c.transitions] + [
        c for c in master if not c.before_slave]
    frames = []
    for c in cmds:
        data = c.data if c.data is not None else bytes(c.length)
        if c.cmd in LOGICAL_CMDS:
            dg = Datagram.logical(c.cmd, c.addr or 0, data)
        else:
            dg = Datagram.physical(c.cmd, c.adp or 0, c.ado or 0, data)
        frames.append(wire.encode([dg]))
    return frames


def _cyclic_frames(plan, state: str) -> list[bytes]:
    """The ENI's cyclic frames of a state, outputs all zero (as before an application
    writes any)."""
    from ecatcfg.esc import LOGICAL_CMDS
    from ecatcfg.runtime import wire
    from ecatcfg.runtime.wire import Datagram
    frames = []
    for cyclic in plan.cyclic:
        for f in cyclic.frames:
            dgs = [Datagram.logical(c.cmd, c.addr or 0, bytes(c.length)) if c.cmd in LOGICAL_CMDS
                   else Datagram.physical(c.cmd, c.adp or 0, c.ado or 0, bytes(c.length))
                   for c in f.cmds if state in c.states]
            if dgs:
                frames.append(wire.encode(dgs))
    return frames


def eni_on_segment(m: Mutant) -> None:
    """An ENI the reader accepts, sent straight to a virtual segment of its slaves: the
    register InitCmds of INIT to PREOP to SAFEOP, its cyclic frames in SAFEOP (the LRW or
    LWR of the outputs), SAFEOP to OP (the AL control write), cyclic frames in OP.  No
    master: no waits, no checks of the replies, so what an InitCmd sets up reaches the
    emulated ESC even where a master would stop at the next check (an FMMU that maps the
    outputs onto AL status, then an AL control write).  The segment must answer every
    frame and each ESC keep its invariants, as in :func:`feed_segment`."""
    from ecatcfg.eni import reader
    from ecatcfg.runtime.segment.slave import MEMORY_SIZE
    plan = reader.read_bytes(m.data(), "fuzz.eni.xml")
    segment = line_for(plan)
    frames = (_init_cmd_frames(plan, "IP") + _init_cmd_frames(plan, "PS")
              + _cyclic_frames(plan, "SAFEOP") * 2 + _init_cmd_frames(plan, "SO")
              + _cyclic_frames(plan, "OP") * 2)
    for f in frames:
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
    # A plan the reader gives is one the writer takes, and what the writer writes the
    # reader reads again ("writing a plan and reading it back gives an equal plan",
    # architecture.md): a NetworkPlan is the one model between all readers and writers.
    from ecatcfg.eni import reader, writer
    plan = reader.read_bytes(m.data(), "fuzz.eni.xml")
    written = writer.to_bytes(plan, generator="fuzz")
    try:
        reader.read_bytes(written, "written.eni.xml")
    except EcatcfgError as exc:
        raise Defect(f"the reader refuses what the writer wrote of a plan it read: {exc}")


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


def _eni_apply_inputs(kinds: frozenset[str] | None) -> st.SearchStrategy[Mutant]:
    # Numbers only (and repeated elements, register images): a broken XML or a missing
    # element is the reader's business (the eni_reader target); this one feeds plans the
    # reader accepts to the master and the emulation, with the values they put on the wire.
    return mutants("eni", values=3, numeric=kinds is None, kinds=kinds)


def _frame_inputs() -> st.SearchStrategy[bytes]:
    from ecatcfg.runtime import wire
    valid = st.lists(datagram(), min_size=1, max_size=3).map(wire.encode)
    return st.one_of(valid, valid.flatmap(lambda d: byte_edits(d, max_edits=3)),
                     st.binary(max_size=80))


_IN_FILE = located_in_file

_NUMBERS = tuple(NUMBER_KINDS)
_XML_KINDS = (*_NUMBERS, "repeated-elements")

TARGETS: dict[str, Target] = {t.name: t for t in (
    Target("esi_reader", "ESI files (example devices, values/elements/bytes mutated)",
           lambda k: xml_inputs("esi", k), _esi, _IN_FILE("fuzz.xml"), 200, _XML_KINDS),
    Target("esi_device", "ESI files (numbers far out of range, negative sizes, huge counts) "
           "through Library, SII build, the emulated slave and compile",
           lambda k: mutants("esi", values=3, numeric=True, kinds=k), _esi_device,
           _in_fuzz_esi, 100, _XML_KINDS),
    Target("lint", "ESI files through every lint rule", lambda k: xml_inputs("esi", k),
           _lint, _IN_FILE("fuzz.xml"), 120, _XML_KINDS),
    Target("topology", "topology YAML/JSON (scalars, explicit tags, syntax mutated)",
           lambda k: yaml_inputs("topology"), _topology, _IN_FILE("fuzz.yaml"), 300),
    Target("compiler", "topologies compiled against the example ESI files, ENI written "
           "and read back", lambda k: mutants("topology", yaml_values=2, kinds=k),
           _compile, _IN_FILE("fuzz.yaml"), 200, _NUMBERS),
    Target("eni_reader", "ENI files (compiled from the examples, mutated), read, written "
           "and read back", lambda k: xml_inputs("eni", k), _eni, _IN_FILE("fuzz.eni.xml"),
           250, (*_XML_KINDS, "registers")),
    Target("eni_apply", "ENIs the reader accepts, applied on the virtual segment (every "
           "process variable read, every output written)",
           _eni_apply_inputs, _eni_apply, located_on_line, 400, MUTATION_KINDS),
    Target("eni_segment", "ENIs the reader accepts (register images, numbers), their "
           "InitCmds and cyclic frames sent straight to a virtual segment (no master)",
           lambda k: mutants("eni", values=3, kinds=k or frozenset({"registers",
                                                                    "boundaries"})),
           eni_on_segment, located_on_line, 100, MUTATION_KINDS),
    Target("sii_decoder", "SII images built from the example devices, mutated",
           lambda k: sii_inputs(), _sii, _IN_FILE("fuzz.bin"), 400),
    Target("frame_decoder", "Ethernet frames into the datagram decoder",
           lambda k: _frame_inputs(), _frame_decode, lambda exc: True, 200),
    Target("segment", "frames from the wire against a line in OP",
           lambda k: st.tuples(st.integers(0, len(eni_seeds()) - 1), frames()),
           feed_segment, located_on_line, 250),
    Target("master", "replies damaged on their way back to the master (bring-up, cycles, "
           "way down)", lambda k: st.tuples(st.integers(0, len(eni_seeds()) - 1),
                                            reply_faults()),
           master_with_faults, located_on_line, 120),
)}
