"""Capture conformance: the virtual segment against wire captures of real slaves.

A capture taken at the master holds each frame twice: as the master sent it and as it came
back after passing every slave (the first ESC sets the U/L bit, bit 1 of the first byte, of
the source MAC; ETG.1000.4).  For each capture this module

1. pairs every returned frame with the request it answers (the oldest outstanding request
   with the same datagram headers: command, index, address, length);
2. identifies the slaves from the capture's own SII reads (vendor, product and revision,
   words 0x08-0x0D read through 0x0502-0x050F), position by position; a capture whose
   slaves cannot all be identified, or are not all in the ESI library, is not usable;
3. builds the same line on a :class:`~ecatcfg.runtime.segment.virtual.VirtualSegment` from the ESI
   files, on a clock that follows the capture's timestamps;
4. sends every master frame through ``VirtualSegment.process`` in capture order and compares
   each reply with the real one, datagram by datagram: header, data and working counter.

Each datagram ends in one of four classes: *equal* (byte for byte), *by rule* (every
differing byte is a value that depends on time or on the physical link and passes that
value's rule), *known limit* (some differing byte is a value no ESI determines, the rest
equal or by rule) or *different*.  The rules and limits, with their reasons, are listed in
``docs/conformance.md``; a working-counter difference is always *different*.

``bench/conformance.py`` prints the table; ``tests/test_conformance.py`` guards it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from ecatcfg.esc import (SM_STATUS_MAILBOX_FULL, SM_STATUS_READ_EVENT, SM_STATUS_WRITE_EVENT, Cmd,
                         sm_register)
from ecatcfg.esi.coe import device_dictionary
from ecatcfg.esi.library import Library, SelectorError
from ecatcfg.runtime import wire
from ecatcfg.runtime.pcap import read_capture
from ecatcfg.runtime.segment.dc_clock import DcModel
from ecatcfg.runtime.segment.emulate import SlaveSpec, emulated_slave
from ecatcfg.runtime.segment.syncman import SmKind
from ecatcfg.runtime.segment.virtual import VirtualSegment
from ecatcfg.runtime.segment.timing import Timing
from ecatcfg.runtime.wire import Datagram

ETHERTYPE = b"\x88\xa4"
AUTO_INC = {Cmd.APRD, Cmd.APWR, Cmd.APRW, Cmd.ARMW}
CONFIGURED = {Cmd.FPRD, Cmd.FPWR, Cmd.FPRW, Cmd.FRMW}
BROADCAST = {Cmd.BRD, Cmd.BWR, Cmd.BRW}
LOGICAL = {Cmd.LRD, Cmd.LWR, Cmd.LRW}
READS = {Cmd.APRD, Cmd.FPRD, Cmd.BRD, Cmd.APRW, Cmd.FPRW, Cmd.BRW, Cmd.ARMW, Cmd.FRMW}
WRITES = {Cmd.APWR, Cmd.FPWR, Cmd.BWR, Cmd.APRW, Cmd.FPRW, Cmd.BRW}
EEPROM_ADDRESS, EEPROM_DATA = 0x0504, 0x0508


# -- the capture -----------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Exchange:
    """A master frame (its number in the capture, 1-based as Wireshark counts) and the
    frame that came back, or None when none did."""

    number: int
    time_ns: int
    request: bytes
    reply: bytes | None


def _frames(path: Path) -> Iterator[tuple[int, int, bytes]]:
    """The EtherCAT frames of a pcapng or classic libpcap capture (``runtime/pcap.py``)."""
    for number, time_ns, frame in read_capture(path):
        if frame[12:14] == ETHERTYPE:
            yield number, time_ns, frame


def _shape(frame: bytes) -> tuple[tuple[int, int, int | None, int, int], ...] | None:
    """What a frame keeps on its way round the line: per datagram command, index, address
    (the position of an auto-increment or broadcast datagram counts up), length."""
    try:
        return tuple((d.cmd, d.idx, None if d.cmd in AUTO_INC | BROADCAST else d.adp,
                      d.ado, len(d.data)) for d in wire.decode(frame).datagrams)
    except wire.FrameError:
        return None


def exchanges(path: Path) -> list[Exchange]:
    """The master's frames in capture order, each with the frame that answers it."""
    out: list[Exchange] = []
    pending: dict[object, list[int]] = {}
    for number, time_ns, frame in _frames(path):
        shape = _shape(frame)
        if shape is None:
            continue
        if not frame[6] & 0x02:                              # sent by the master
            pending.setdefault(shape, []).append(len(out))
            out.append(Exchange(number, time_ns, frame, None))
        elif pending.get(shape):
            i = pending[shape].pop(0)
            e = out[i]
            out[i] = Exchange(e.number, e.time_ns, e.request, frame)
    return out


# -- the slaves, from the capture's SII reads -------------------------------------------------

@dataclass(slots=True)
class Slave:
    position: int
    sii: dict[int, int] = field(default_factory=dict)      # word address -> word

    def word(self, address: int) -> int | None:
        return self.sii.get(address)

    def dword(self, address: int) -> int | None:
        lo, hi = self.sii.get(address), self.sii.get(address + 1)
        return None if lo is None or hi is None else lo | hi << 16

    @property
    def identity(self) -> tuple[int, int, int] | None:
        ids = [self.dword(a) for a in (0x08, 0x0A, 0x0C)]
        if any(v is None for v in ids):
            return None
        vendor, product, revision = ids
        assert vendor is not None and product is not None and revision is not None
        return vendor, product, revision


def _datagram_pairs(ex: list[Exchange]) -> Iterator[tuple[int, int, Datagram, Datagram]]:
    for e in ex:
        if e.reply is None:
            continue
        sent, back = wire.decode(e.request).datagrams, wire.decode(e.reply).datagrams
        for i, (s, b) in enumerate(zip(sent, back)):
            yield e.number, i, s, b


def slaves_seen(ex: list[Exchange]) -> list[Slave]:
    """The line as the capture shows it: how many slaves answered (the largest working
    counter of a broadcast read or write, the furthest auto-increment position answered)
    and what each one's SII said.  Station addresses come from the master's writes to
    0x0010 (auto-increment: the position is minus the address in the request)."""
    count = 0
    station: dict[int, int] = {}                 # station address -> position
    eeprom_address: dict[int, int] = {}          # position -> word address
    found: dict[int, Slave] = {}

    def targets(sent: Datagram, wkc: int) -> list[int]:
        if not wkc:
            return []
        if sent.cmd in AUTO_INC:
            return [-sent.adp & 0xFFFF]
        if sent.cmd in CONFIGURED:
            return [station[sent.adp]] if sent.adp in station else []
        if sent.cmd in (Cmd.BWR, Cmd.BRW):
            return list(range(max(count, wkc)))
        return []

    for _, _, sent, back in _datagram_pairs(ex):
        if sent.cmd in LOGICAL:
            continue
        if sent.cmd in BROADCAST:
            count = max(count, back.wkc // (3 if sent.cmd == Cmd.BRW else 1))
        if sent.cmd in AUTO_INC and back.wkc:
            count = max(count, (-sent.adp & 0xFFFF) + 1)
        ado, n = sent.ado, len(sent.data)
        who = targets(sent, back.wkc)
        if sent.cmd in WRITES and ado <= 0x0010 < ado + n - 1:
            value, = struct.unpack_from("<H", sent.data, 0x0010 - ado)
            for pos in who:
                for a, p in list(station.items()):
                    if p == pos:
                        del station[a]
                station[value] = pos
        if sent.cmd in WRITES and ado <= EEPROM_ADDRESS < ado + n - 1:
            word, = struct.unpack_from("<H", sent.data, EEPROM_ADDRESS - ado)
            for pos in who:
                eeprom_address[pos] = word
        if sent.cmd in READS and ado <= EEPROM_DATA and ado + n >= EEPROM_DATA + 4 \
                and len(who) == 1:
            pos = who[0]
            if ado <= EEPROM_ADDRESS < ado + n - 1:
                addr = struct.unpack_from("<H", back.data, EEPROM_ADDRESS - ado)[0]
            elif pos in eeprom_address:
                addr = eeprom_address[pos]
            else:
                continue
            if ado <= 0x0502 < ado + n - 1:
                control, = struct.unpack_from("<H", back.data, 0x0502 - ado)
                if control & 0x8000:
                    continue                                 # still busy: no data yet
            raw = back.data[EEPROM_DATA - ado:EEPROM_DATA - ado + 8]
            slave = found.setdefault(pos, Slave(pos))
            for k in range(len(raw) // 2):
                slave.sii[addr + k] = struct.unpack_from("<H", raw, 2 * k)[0]
    return [found.get(pos, Slave(pos)) for pos in range(count)]


# -- the comparison ---------------------------------------------------------------------------

EQUAL, BY_RULE, KNOWN_LIMIT, DIFFERENT = "equal", "by rule", "known limit", "different"


@dataclass(frozen=True, slots=True)
class Difference:
    frame: int            # the master frame's number in the capture
    datagram: int         # its index in the frame
    what: str             # e.g. "FPRD 0x1001 0x0502" or "LRW 0x00000000"
    field: str            # "wkc", "header" or a register address
    expected: str
    got: str

    def __str__(self) -> str:
        return (f"frame {self.frame} datagram {self.datagram} {self.what} {self.field}: "
                f"hardware {self.expected}, emulated {self.got}")


@dataclass(slots=True)
class Report:
    name: str
    slaves: list[str]
    usable: bool
    reason: str = ""
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        (EQUAL, BY_RULE, KNOWN_LIMIT, DIFFERENT), 0))
    differences: list[Difference] = field(default_factory=list)
    limits: dict[str, int] = field(default_factory=dict)    # known limit -> datagrams
    rules: dict[str, int] = field(default_factory=dict)     # rule -> datagrams

    @property
    def compared(self) -> int:
        return sum(self.counts.values())


def _what(d: Datagram) -> str:
    name = Cmd(d.cmd).name if d.cmd in Cmd._value2member_map_ else f"cmd{d.cmd}"
    if d.cmd in LOGICAL:
        return f"{name} 0x{d.address:08X}"
    return f"{name} 0x{d.adp:04X} 0x{d.ado:04X}"


class Replay:
    """One capture replayed against its line; see the module docstring."""

    def __init__(self, name: str, ex: list[Exchange], seg: VirtualSegment) -> None:
        self.name = name
        self.exchanges = ex
        self.segment = seg
        self.now = ex[0].time_ns if ex else 0
        self.state = State()
        seg.clock_ns = self._clock
        for s in seg.slaves:
            s.clock_ns = self._clock

    def _clock(self) -> int:
        return self.now

    def run(self, report: Report) -> None:
        for e in self.exchanges:
            self.now = e.time_ns
            ours = bytes(self.segment.process(e.request))
            if e.reply is None:
                continue
            sent = wire.decode(e.request).datagrams
            real = wire.decode(e.reply).datagrams
            mine = wire.decode(ours).datagrams
            if len(real) != len(mine):
                report.counts[DIFFERENT] += 1
                report.differences.append(Difference(e.number, 0, "frame", "datagrams",
                                                     str(len(real)), str(len(mine))))
                continue
            for i, (s, r, m) in enumerate(zip(sent, real, mine)):
                verdict, notes = classify(self, e, i, s, r, m)
                report.counts[verdict] += 1
                for kind, text, diff in notes:
                    if kind == BY_RULE:
                        report.rules[text] = report.rules.get(text, 0) + 1
                    elif kind == KNOWN_LIMIT:
                        report.limits[text] = report.limits.get(text, 0) + 1
                    elif diff is not None:
                        report.differences.append(diff)


def sii_dumps(folder: Path) -> dict[str, bytes]:
    """Real SII EEPROM dumps (raw images, whatever the file's extension), by file name."""
    return {p.name: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _revision_from_dumps(slave: Slave, dumps: dict[str, bytes]) -> tuple[int, str] | None:
    """The revision (SII words 0x0C-0x0D) of the dumps that hold every word the capture
    read of ``slave``, when they agree on one; and which dumps those are."""
    agree: dict[int, list[str]] = {}
    for name, data in dumps.items():
        if len(data) >= 0x1C and all(2 * a + 2 <= len(data) and
                                     struct.unpack_from("<H", data, 2 * a)[0] == v
                                     for a, v in slave.sii.items()):
            agree.setdefault(struct.unpack_from("<I", data, 0x18)[0], []).append(name)
    if len(agree) != 1:
        return None
    [(revision, names)] = agree.items()
    return revision, ", ".join(names)


def _describe(slave: Slave, library: Library,
              dumps: dict[str, bytes]) -> tuple[str, SlaveSpec | None, str]:
    """The slave's label, the spec to emulate it (None when it cannot be) and why not.

    A master that reads vendor and product but not the revision (EtherCrab in 2022) leaves
    the revision to the corpus SII dumps: the one of the dumps that agree with every word
    the capture read of the slave (the label says which and how many words).
    A revision the corpus lacks is emulated from the ESI of the nearest revision of the
    same product, with the revision number the hardware reports (the label says so): one
    product's revisions share their ESC, SMs and process data far more often than not, and
    every register the substitute gets wrong still shows up as a difference."""
    identity = slave.identity
    source = ""
    if identity is None and slave.dword(0x08) is not None and slave.dword(0x0A) is not None:
        found = _revision_from_dumps(slave, dumps)
        if found is not None:
            identity = (slave.dword(0x08) or 0, slave.dword(0x0A) or 0, found[0])
            source = (f", revision not read: SII dump {found[1]} holds the {len(slave.sii)} "
                      "words read")
    if identity is None:
        return (f"#{slave.position} ?", None,
                f"slave {slave.position}: vendor, product and revision not read from its SII")
    vendor, product, revision = identity
    label = f"0x{vendor:x}:0x{product:x}:0x{revision:x}"
    try:
        entry = library.find(label).entry
        note = ""
    except SelectorError:
        same = [e for e in library.entries
                if (e.vendor_id, e.product_code) == (vendor, product) and e.revision is not None]
        if not same:
            return (f"#{slave.position} {label}", None,
                    f"slave {slave.position}: no ESI for {label} in the corpus")
        entry = min(same, key=lambda e: abs((e.revision or 0) - revision))
        note = f", ESI of revision 0x{entry.revision or 0:x}"
    device = replace(library.device(entry), revision=revision)
    spec = SlaveSpec(device, f"{entry.type}-{slave.position}", serial=slave.dword(0x0E) or 0,
                     alias=slave.word(0x04) or 0)
    return f"{entry.type} ({label}{note}{source})", spec, ""


def replay(path: Path, library: Library, name: str | None = None,
           dumps: dict[str, bytes] | None = None) -> Report:
    """Identify, build, replay and compare one capture; ``dumps``: real SII images
    (:func:`sii_dumps`) for slaves whose revision the capture does not read."""
    name = name or path.name
    ex = exchanges(path)
    answered = sum(1 for e in ex if e.reply is not None)
    if not answered:
        return Report(name, [], False, "no master frame with its returned frame")
    seen = slaves_seen(ex)
    if not seen:
        return Report(name, [], False, "no slave answered")
    labels: list[str] = []
    specs: list[SlaveSpec] = []
    reasons: list[str] = []
    for s in seen:
        label, spec, reason = _describe(s, library, dumps or {})
        labels.append(label)
        if spec is None:
            reasons.append(reason)
        else:
            specs.append(spec)
    if reasons:
        return Report(name, labels, False, "; ".join(reasons))
    # The slaves take their time as real ones do (runtime/segment/timing.py): the clock follows
    # the capture's timestamps, so an EEPROM read is busy when the hardware's was.  Their
    # quartzes are ideal: how far a real one is off is no ESI's fact (the clocks start
    # where the hardware's were, _start_clock_where_the_hardware_was).
    seg = VirtualSegment([emulated_slave(s) for s in specs], timing=Timing(),
                         dc=DcModel(drift_ppm=0))
    report = Report(name, labels, True)
    Replay(name, ex, seg).run(report)
    return report


# -- classification -------------------------------------------------------------------------

Note = tuple[str, str, "Difference | None"]


def _ranges(real: bytes, mine: bytes) -> list[tuple[int, int]]:
    """Runs of differing bytes: [(first, end), ...]."""
    out: list[tuple[int, int]] = []
    for i, (a, b) in enumerate(zip(real, mine)):
        if a != b:
            if out and out[-1][1] == i:
                out[-1] = (out[-1][0], i + 1)
            else:
                out.append((i, i + 1))
    return out


# Registers whose value comes from the ESC chip, which no ESI names: type, revision, build,
# FMMU and SM counts, RAM size, port descriptor, features (ESC Section II, 0x0000-0x0009).
CHIP = (0x0000, 0x000A)
EEPROM_CONTROL = 0x0502
DL_STATUS_EVENT = 0x0004            # IRQ / ECAT event request bit 2


class State:
    """What the rules remember between datagrams: each slave's last latch values as read
    from the hardware and from the emulation, and which slaves' DL status was read."""

    def __init__(self) -> None:
        self.last: dict[tuple[int, int], tuple[int, int]] = {}   # (pos, reg) -> (hw, emu)
        self.dl_read: set[int] = set()
        self.clock_set: set[int] = set()                          # clocks started
        self.request_ns: dict[int, int] = {}     # pos -> when its mailbox-out SM was written


def _targets(rp: Replay, sent: Datagram) -> list[int]:
    seg = rp.segment
    if sent.cmd in AUTO_INC:
        pos = -sent.adp & 0xFFFF
        return [pos] if pos < len(seg.slaves) else []
    if sent.cmd in CONFIGURED:
        return [s.position for s in seg._addressed(sent.adp)]
    if sent.cmd in BROADCAST:
        return [s.position for s in seg.slaves]
    return []


def _u(data: bytes, at: int, n: int) -> int | None:
    return int.from_bytes(data[at:at + n], "little") if at >= 0 and at + n <= len(data) \
        else None


def _register_rule(rp: Replay, sent: Datagram, real: Datagram, mine: Datagram, reg: int,
                   who: list[int]) -> tuple[str, str]:
    """(class, rule or limit) for one differing register byte of a read."""
    pos = who[0] if len(who) == 1 else None
    ado = sent.ado
    if CHIP[0] <= reg < CHIP[1]:
        return KNOWN_LIMIT, "ESC chip registers 0x0000-0x0009"
    if reg in (EEPROM_CONTROL, EEPROM_CONTROL + 1):
        hw, emu = _u(real.data, EEPROM_CONTROL - ado, 2), _u(mine.data, EEPROM_CONTROL - ado, 2)
        if hw is None or emu is None:
            hw, emu = real.data[reg - ado] << 8 * (reg - EEPROM_CONTROL), \
                mine.data[reg - ado] << 8 * (reg - EEPROM_CONTROL)
        chip = (hw ^ emu) & 0x0010          # reserved bit 4: set by ET1200-class chips
        hw, emu = hw & ~0x0010, emu & ~0x0010
        limit = (KNOWN_LIMIT, "EEPROM control bit 4 (reserved, set by some chips)")
        if hw == emu:
            return limit
        if hw & 0x8000 and (hw & ~0x8700) == (emu & ~0x8700) and not emu & 0x8700:
            return limit if chip else (BY_RULE, "EEPROM busy while a read is in flight")
        if emu & 0x8000 and (hw & ~0x8700) == (emu & ~0x8700) and not hw & 0x8700:
            # The emulated read takes the table's time (0.69 ms, runtime/segment/timing.py;
            # captured reads end within 0.49-0.96 ms): a faster real read is done already.
            return limit if chip else (BY_RULE, "EEPROM read time varies (0.49-0.96 ms)")
        return DIFFERENT, ""
    if EEPROM_DATA <= reg < EEPROM_DATA + 8 and pos is not None:
        slave = rp.segment.slaves[pos]
        word = int.from_bytes(slave.mem[EEPROM_ADDRESS:EEPROM_ADDRESS + 4], "little") \
            + (reg - EEPROM_DATA) // 2
        if word in (0x0E, 0x0F):
            return KNOWN_LIMIT, "SII serial number (words 0x0E-0x0F)"
        if word >= 0x40:
            return KNOWN_LIMIT, "SII category area layout (word 0x40 on)"
        return DIFFERENT, ""
    if 0x0900 <= reg < 0x0910 and pos is not None:
        port = (reg - 0x0900) // 4
        slave = rp.segment.slaves[pos]
        dl = int.from_bytes(slave.mem[0x0110:0x0112], "little")
        if not dl & (0x0010 << port):
            return BY_RULE, "receive time of a port without link"
        return _moves_together(rp, sent, real, mine, pos, 0x0900 + 4 * port, 4,
                               "receive time latched at each 0x0900 write")
    if 0x0918 <= reg < 0x0920 and pos is not None:
        return _moves_together(rp, sent, real, mine, pos, 0x0918, 8,
                               "receive time of the processing unit latched with port 0")
    if 0x0910 <= reg < 0x0918:
        return _moves_together(rp, sent, real, mine, pos if pos is not None else -1,
                               0x0910, 8, "system time advances")
    if 0x092C <= reg < 0x0930 and pos is not None:
        hw, emu = _u(real.data, 0x092C - ado, 4), _u(mine.data, 0x092C - ado, 4)
        if hw is not None and emu is not None and emu & 0x7FFF_FFFF <= max(
                hw & 0x7FFF_FFFF, 1000):
            return BY_RULE, "system time difference no larger than the hardware's"
    if pos is not None:
        found = _mailbox_rule(rp, sent, real, mine, reg, pos)
        if found is not None:
            return found
    return DIFFERENT, ""


# CoE objects whose value is the device's own, which an ESI types but gives no value for:
# the hardware and software versions (ETG.1000.6 0x1009, 0x100A; the EL6910's ESI types
# 0x100A STRING(11), its firmware answers "04 (V01.11)" and five spaces).
VERSION_STRINGS = (0x1009, 0x100A)
COE, SDO_UPLOAD_RESPONSE = 3, 2       # mailbox type; server command specifier (bits 7:5)
# How long after its request a reply may be there on one side only: the slowest reply of a
# device with an ESI in the captures (the EL6910's 0xF008 download, at most 2.07 ms).
REPLY_VARIES_NS = 2_100_000


def _note_mailbox_request(rp: Replay, sent: Datagram, real: Datagram, who: list[int]) -> None:
    """When the master's write of a slave's mailbox-out SM (a request) was taken."""
    if sent.cmd not in WRITES or len(who) != 1 or not real.wkc:
        return
    slave = rp.segment.slaves[who[0]]
    out = next((sm for sm in slave.sms if sm.active and sm.kind is SmKind.MAILBOX_OUT), None)
    if out is not None and sent.ado <= out.start < sent.ado + len(sent.data):
        rp.state.request_ns[who[0]] = rp.now


def _mailbox_rule(rp: Replay, sent: Datagram, real: Datagram, mine: Datagram, reg: int,
                  pos: int) -> tuple[str, str] | None:
    """(class, rule or limit) for a differing byte of the slave's mailbox-in SM: its status
    register or its buffer; None when no mailbox rule applies."""
    slave = rp.segment.slaves[pos]
    sm = slave._mailbox_in_sm()
    if sm is None:
        return None
    if reg == sm_register(sm.number) + 5:                            # SM status
        hw, emu = real.data[reg - sent.ado], mine.data[reg - sent.ado]
        since = rp.now - rp.state.request_ns.get(pos, rp.now)
        if hw ^ emu == SM_STATUS_READ_EVENT:
            # Both empty; the read event of the master's last read clears when the
            # firmware writes the first byte of its next reply (runtime/segment/timing.py
            # reply_start_ns), which varies as the reply time does (the EL6910's within
            # 0.98-1.24 ms of the request).
            if 0 < since <= REPLY_VARIES_NS:
                return BY_RULE, "the firmware starts writing its reply at a varying time"
            # The EK1914 also clears it twice of eight with no request pending (0.28 and
            # 1.07 ms after the master's read): when its loop does that is its own.
            return KNOWN_LIMIT, ("mailbox-in read event (SM status bit 1) cleared by the "
                                 "firmware with no request")
        full = SM_STATUS_MAILBOX_FULL | SM_STATUS_WRITE_EVENT
        if {hw & full, emu & full} == {0, full} and (hw ^ emu) & ~(
                full | SM_STATUS_READ_EVENT) == 0 and 0 < since <= REPLY_VARIES_NS:
            # The emulated reply takes the table's time (runtime/segment/timing.py), a
            # real one varies (the EL6910's 1.65-2.07 ms): one is there, the other not
            # yet.  A master that reads SM1 on it would get another working counter:
            # that stays different.
            return BY_RULE, "mailbox reply time varies"
        return None
    if not sm.start <= reg < sm.end or sent.ado > sm.start:
        return None
    at = sm.start - sent.ado
    hw_len, emu_len = _u(real.data, at, 2), _u(mine.data, at, 2)
    if hw_len is None or emu_len is None:
        return None
    if reg - sm.start >= 6 + max(hw_len, emu_len):
        # The mailbox header's length ends the message (ETG.1000.4); what follows in the
        # buffer is what the slave's firmware wrote there before (earlier replies, its
        # diagnosis texts, uninitialised RAM), the emulated ESC's buffer is zeros.
        return KNOWN_LIMIT, "mailbox-in bytes past the message (earlier contents)"
    hw_obj, emu_obj = _upload_of(real.data[at:]), _upload_of(mine.data[at:])
    if hw_obj is not None and hw_obj == emu_obj and hw_obj[0] in VERSION_STRINGS:
        dic = device_dictionary(slave.device)
        obj = dic.objects.get(hw_obj[0]) if dic is not None else None
        info = obj.info if obj is not None else None
        if info is None or (info.default_data is None and info.default_string is None):
            return KNOWN_LIMIT, ("version string 0x1009/0x100A: the firmware's own, its "
                                 "ESI gives none")
    return None


def _upload_of(message: bytes) -> tuple[int, int] | None:
    """(index, subindex) of a CoE SDO upload response, else None."""
    if len(message) < 12 or message[5] & 0x0F != COE or message[8] >> 5 != \
            SDO_UPLOAD_RESPONSE:
        return None
    return int.from_bytes(message[9:11], "little"), message[11]


def _moves_together(rp: Replay, sent: Datagram, real: Datagram, mine: Datagram, pos: int,
                    reg: int, n: int, rule: str) -> tuple[str, str]:
    """A time value in two clocks: the emulated one changes exactly when the hardware's
    does (a latch moves at each latching write, system time at every read)."""
    hw, emu = _u(real.data, reg - sent.ado, n), _u(mine.data, reg - sent.ado, n)
    if hw is None or emu is None:           # a part of the value: compare what is there
        return BY_RULE, rule
    before = rp.state.last.get((pos, reg))
    rp.state.last[(pos, reg)] = (hw, emu)
    if before is None or (hw != before[0]) == (emu != before[1]):
        return BY_RULE, rule
    return DIFFERENT, ""


def _start_clock_where_the_hardware_was(rp: Replay, sent: Datagram, real: Datagram,
                                        mine: Datagram, who: list[int]) -> None:
    """An emulated clock starts where the real one was (when a slave was powered on is
    no ESI's fact): at the first read of a slave's 64-bit receive time 0x0918, its local
    clock and latches move by the hardware's value minus the emulated one, so the offsets
    the master works out from the hardware's latches fit the emulated clock too."""
    if sent.cmd not in READS or len(who) != 1 or not real.wkc or not mine.wkc:
        return
    hw, emu = _u(real.data, 0x0918 - sent.ado, 8), _u(mine.data, 0x0918 - sent.ado, 8)
    pos = who[0]
    if hw is None or emu is None or pos in rp.state.clock_set:
        return
    rp.state.clock_set.add(pos)
    delta = (hw - emu + (1 << 63)) % (1 << 64) - (1 << 63)
    slave = rp.segment.slaves[pos]
    slave.dc.shift(delta)
    mem = slave.mem
    for reg in (0x0900, 0x0904, 0x0908, 0x090C):
        value = int.from_bytes(mem[reg:reg + 4], "little")
        if value:
            mem[reg:reg + 4] = ((value + delta) % (1 << 32)).to_bytes(4, "little")
    value = int.from_bytes(mem[0x0918:0x0920], "little")
    mem[0x0918:0x0920] = ((value + delta) % (1 << 64)).to_bytes(8, "little")


def classify(rp: Replay, e: Exchange, i: int, sent: Datagram, real: Datagram,
             mine: Datagram) -> tuple[str, list[Note]]:
    what = _what(sent)
    notes: list[Note] = []
    who = _targets(rp, sent)
    if (real.cmd, real.idx, real.address, len(real.data)) != (
            mine.cmd, mine.idx, mine.address, len(mine.data)):
        return DIFFERENT, [(DIFFERENT, "header", Difference(
            e.number, i, what, "header", _what(real), _what(mine)))]
    if real.wkc != mine.wkc:
        notes.append((DIFFERENT, "wkc", Difference(e.number, i, what, "wkc",
                                                   str(real.wkc), str(mine.wkc))))
    done: set[str] = set()
    for a, b in _ranges(real.data, mine.data):
        for k in range(a, b):
            if sent.cmd in LOGICAL or sent.cmd not in READS:
                kind, text = DIFFERENT, ""
            else:
                kind, text = _register_rule(rp, sent, real, mine, sent.ado + k, who)
            if kind != DIFFERENT:
                if text not in done:
                    notes.append((kind, text, None))
                    done.add(text)
                continue
            reg = f"+{k}" if sent.cmd in LOGICAL else f"0x{sent.ado + k:04X}"
            notes.append((DIFFERENT, reg, Difference(e.number, i, what, reg,
                                                     real.data[k:k + 1].hex(),
                                                     mine.data[k:k + 1].hex())))
    _start_clock_where_the_hardware_was(rp, sent, real, mine, who)
    _note_mailbox_request(rp, sent, real, who)
    if real.irq != mine.irq:
        diff = real.irq ^ mine.irq
        everyone = len(rp.state.dl_read) >= len(rp.segment.slaves)
        if diff == DL_STATUS_EVENT and (real.irq & DL_STATUS_EVENT or not everyone):
            notes.append((BY_RULE, "DL status event of a link change", None))
        else:
            notes.append((DIFFERENT, "irq", Difference(
                e.number, i, what, "irq", f"0x{real.irq:04X}", f"0x{mine.irq:04X}")))
    if sent.cmd in READS and sent.ado <= 0x0111 < sent.ado + len(sent.data) and real.wkc:
        rp.state.dl_read.update(who)         # the event is known from the next datagram on
    kinds = {k for k, _, _ in notes}
    verdict = (DIFFERENT if DIFFERENT in kinds else KNOWN_LIMIT if KNOWN_LIMIT in kinds
               else BY_RULE if BY_RULE in kinds else EQUAL)
    return verdict, notes


# -- the table -------------------------------------------------------------------------------

def captures(corpus: Path) -> list[Path]:
    """Every wire capture of the corpus (pcapng, or classic libpcap: ``.pcap``, ``.cap``),
    in name order."""
    return sorted(p for p in (corpus / "pcap").rglob("*")
                  if p.is_file() and p.suffix.lower() in (".pcapng", ".pcap", ".cap"))


def table(reports: list[Report]) -> str:
    """The markdown table of docs/conformance.md."""
    rows = ["| capture | slaves | usable | compared | equal | by rule | known limit "
            "| different |", "|---|---|---|---|---|---|---|---|"]
    for r in reports:
        usable = "yes" if r.usable else f"no: {r.reason}"
        c = r.counts
        rows.append(f"| {r.name} | {', '.join(r.slaves) or '-'} | {usable} | {r.compared} "
                    f"| {c[EQUAL]} | {c[BY_RULE]} | {c[KNOWN_LIMIT]} | {c[DIFFERENT]} |")
    return "\n".join(rows)
