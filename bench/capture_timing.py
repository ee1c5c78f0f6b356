"""Slave timing measured in wire captures of real hardware: the figures behind the timing
model's table (``runtime/segment/timing.py``, ``docs/timing.md``) and its fit per device kind.

Run: ``python3 bench/capture_timing.py [CAPTURE.pcapng ...] [--events]``; without captures,
every capture of both test corpora (the ``pcap/`` folders of the corpus folders named by
``ECATCFG_CORPUS`` and ``ECATCFG_CORPUS_EXTRA``, as for the tests).  The
captures are pcapng files with both the master's frames and the slaves' replies, e.g.
ethercrab-rs/ethercrab ``dumps/*.pcapng`` and ``tests/replay-*.pcapng``.  Prints, per
capture and slave (station address, the identity read from its SII, its device kind), every
event it can time, with bounds:

- **EEPROM read**: from the read command (a write of 0x0100 to 0x0502) to the first status
  poll of 0x0502 without the busy bit (0x8000);
- **state change**, per transition (``IP``, ``PS``, ...): from an AL control write (0x0120)
  to the first AL status read (0x0130) that shows the requested state;
- **mailbox reply**: from a complete write of the mailbox-out SM (SM0) to the first read
  that finds the mailbox-in SM (SM1) full (its status 0x080D bit 3, or a read of the SM1
  area with a working counter);
- **reply start**: from such a write, made while SM1's status showed the read event of the
  master's last read (bit 1), to the first status read without it: the firmware has
  written the first byte of its reply (the ESC clears the event then).

A capture stamps each frame when the master's host sends it (Q) and when the reply comes
back (R); the slave acted somewhere in between.  A polling master sees a reply only at its
next poll, so the duration of an event lies in the window [Q(last poll that still saw the
old value) - R(command), R(first poll that saw the new value) - Q(command)], printed as
``lo..hi`` ms; the lower bound is 0 when no poll saw the old value.  The polls' spacing
limits the precision: a master that polls every 3 ms (TwinCAT here) gives windows of about
3 ms.

**Device kind** (``runtime/segment/timing.py`` ``kind_of``): from the device's ESI in the corpora
(the exact revision, else the nearest of the same product), emulated and classified as the
timing model classifies it.  A device no ESI of the corpora describes is classified by the
same rule read from its SII (a real EEPROM dump of the corpus with its vendor and product,
else the words the capture read): ESC configuration bit 0 of word 0 -> ``esc``; CiA 402
channels in the GENERAL category or the control/status words 0x6040/0x6041 in its PDO
categories -> ``drive``; otherwise ``firmware``.  The output says which way each was found.

**Fit** (:func:`fit`): per kind and quantity, the figure that lies inside the most windows
(a constant the emulated slave takes is then in step with the hardware at as many of the
master's polls as any constant can be), counting first the windows of slaves an ESI of the
corpora describes (those the emulator can build), then all: the windows' endpoints are the
candidates, the best count wins, a tie goes to the later region (a master that waits for
the slower slave also waits for the faster); the figure is the middle of the region where
the chosen windows overlap.  The windows it leaves out are listed.  EEPROM reads are timed by the ESC, not
the firmware: they are fitted over every slave.

Nothing here is asserted: the script reports, the table in docs/timing.md quotes it, and
``tests/test_timing_fit.py`` checks the table against the windows.
"""

from __future__ import annotations

import argparse
import os
import statistics
import struct
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library
    from ecatcfg.esi.sii import SiiImage

ROOT = Path(__file__).resolve().parent.parent

FPRD, FPWR, APRD, APWR, BRD, BWR = 0x04, 0x05, 0x01, 0x02, 0x07, 0x08
READS = {FPRD, APRD}
WRITES = {FPWR, APWR}
MBX_TYPES = {1: "AoE", 2: "EoE", 3: "CoE", 4: "FoE", 5: "SoE", 15: "VoE"}
STATES = {1: "INIT", 2: "PREOP", 3: "BOOT", 4: "SAFEOP", 8: "OP"}
# The timing model's transition names (runtime/segment/timing.py TRANSITIONS) by (from, to) state.
TRANSITIONS = {(1, 2): "IP", (2, 4): "PS", (4, 8): "SO", (8, 4): "OS", (4, 2): "SP",
               (4, 1): "SI", (8, 2): "OP", (8, 1): "OI", (2, 1): "PI"}
MAILBOX, EEPROM, REPLY_START = "mailbox", "eeprom", "reply start"


@dataclass
class Datagram:
    cmd: int
    adp: int
    ado: int
    data: bytes
    wkc: int


@dataclass
class Exchange:
    """One frame: when the master sent it, when it came back, what came back."""

    sent: float
    back: float
    datagrams: list[Datagram]


def read_exchanges(path: Path) -> list[Exchange]:
    from scapy.utils import RawPcapNgReader
    pending: dict[bytes, tuple[float, int]] = {}
    out: list[Exchange] = []
    for pkt, meta in RawPcapNgReader(str(path)):
        if pkt[12:14] != b"\x88\xa4":
            continue
        t = ((meta.tshigh << 32) | meta.tslow) / meta.tsresol
        dgs, pos = [], 16
        while pos + 12 <= len(pkt):
            cmd, _idx, adp, ado, flags = struct.unpack_from("<BBHHH", pkt, pos)
            n = flags & 0x7FF
            data = bytes(pkt[pos + 10:pos + 10 + n])
            wkc, = struct.unpack_from("<H", pkt, pos + 10 + n) if pos + 12 + n <= len(pkt) \
                else (0,)
            dgs.append(Datagram(cmd, adp, ado, data, wkc))
            pos += 12 + n
            if not flags & 0x8000:
                break
        if not dgs:
            continue
        # The same frame going out and coming back: the first ESC sets the U/L bit of the
        # source MAC; match on the datagram headers (command, index) of the frame.
        key = bytes(pkt[16:18])
        if not pkt[6] & 0x02:
            pending[key] = (t, len(out))
            continue
        sent = pending.pop(key, None)
        if sent is not None:
            out.append(Exchange(sent[0], t, dgs))
    out.sort(key=lambda e: e.sent)
    return out


@dataclass
class Slave:
    words: dict[int, int] = field(default_factory=dict)
    eeprom_address: int = 0
    sm: dict[int, tuple[int, int]] = field(default_factory=dict)      # n -> (start, length)
    state: int = 1
    want: int = 1                   # the state of the AL control write being timed
    sm1_read_event: bool = False    # SM1 status bit 1 at the last read: a reply was read

    def dword(self, word: int) -> int | None:
        """SII words ``word`` and ``word + 1`` as the capture read them."""
        low, high = self.words.get(word), self.words.get(word + 1)
        return None if low is None or high is None else low | high << 16


@dataclass
class Pending:
    kind: str           # "eeprom", "state", "mailbox"
    what: str
    sent: float
    back: float
    last_old: float | None = None
    quantity: str = ""


@dataclass
class Event:
    station: str
    kind: str           # "eeprom", "state", "mailbox"
    what: str
    lo_ms: float
    hi_ms: float
    quantity: str = ""  # what the timing model calls it: "eeprom", "mailbox", "IP", "PS", ...


def analyse(exchanges: list[Exchange]) -> tuple[list[Event], dict[str, Slave]]:
    positions: dict[int, int] = {}              # auto-increment position -> station
    for ex in exchanges:
        for d in ex.datagrams:
            if d.cmd == APWR and d.ado == 0x0010 and len(d.data) >= 2 and d.wkc:
                positions[-d.adp & 0xFFFF] = d.data[0] | d.data[1] << 8
    slaves: dict[str, Slave] = defaultdict(Slave)
    open_: dict[tuple[str, str], Pending] = {}
    events: list[Event] = []

    def key(d: Datagram) -> str | None:
        if d.cmd in (FPRD, FPWR):
            return f"{d.adp:#06x}"
        if d.cmd in (APRD, APWR):
            pos = -d.adp & 0xFFFF
            return f"{positions[pos]:#06x}" if pos in positions else f"pos {pos}"
        if d.cmd == BRD and d.ado == 0x0130 and d.wkc == 1 and len(positions) == 1:
            # one slave on the line (SOEM's state checks are broadcast reads)
            return f"{next(iter(positions.values())):#06x}"
        return None

    def close(k: str, kind: str, ex: Exchange, done: bool) -> None:
        p = open_.get((k, kind))
        if p is None:
            return
        if not done:
            p.last_old = ex.sent
            return
        lo = max(0.0, (p.last_old - p.back) * 1e3) if p.last_old is not None else 0.0
        quantity = p.quantity or kind
        events.append(Event(k, kind, p.what, lo, (ex.back - p.sent) * 1e3, quantity))
        del open_[(k, kind)]

    for ex in exchanges:
        for d in ex.datagrams:
            k = key(d)
            if k is None or not d.wkc:
                # an empty mailbox: no working counter for the SM1 read
                if k is not None and d.cmd in READS and (k, "mailbox") in open_:
                    sm1 = slaves[k].sm.get(1)
                    if sm1 and d.ado == sm1[0]:
                        close(k, "mailbox", ex, False)
                continue
            s = slaves[k]
            if d.cmd in WRITES:
                if d.ado == 0x0502 and len(d.data) >= 2:
                    control = d.data[0] | d.data[1] << 8
                    if len(d.data) >= 6:
                        s.eeprom_address = struct.unpack_from("<I", d.data, 2)[0]
                    if control & 0x0700 == 0x0100:
                        open_[(k, "eeprom")] = Pending("eeprom", "read 8 bytes", ex.sent,
                                                       ex.back)
                elif d.ado == 0x0504 and len(d.data) >= 4:
                    s.eeprom_address = struct.unpack_from("<I", d.data)[0]
                elif 0x0800 <= d.ado < 0x0840:
                    for n in range(8):
                        reg = 0x0800 + 8 * n
                        if d.ado <= reg and reg + 4 <= d.ado + len(d.data):
                            s.sm[n] = struct.unpack_from("<HH", d.data, reg - d.ado)
                elif d.ado == 0x0120 and len(d.data) >= 1:
                    want = d.data[0] & 0x0F
                    if want != s.state and want in STATES:
                        open_[(k, "state")] = Pending(
                            "state", f"{STATES.get(s.state, s.state)}->{STATES[want]}",
                            ex.sent, ex.back,
                            quantity=TRANSITIONS.get((s.state, want), "state"))
                        s.want = want
                elif (sm0 := s.sm.get(0)) and d.ado == sm0[0] and len(d.data) >= 6:
                    mtype = MBX_TYPES.get(d.data[5] & 0x0F, str(d.data[5] & 0x0F))
                    what = mtype
                    if mtype == "CoE" and len(d.data) >= 9:
                        service = d.data[7] >> 4
                        what = {2: "CoE SDO " + ("upload" if d.data[8] >> 5 == 2
                                                 else "download"),
                                8: "CoE SDO info"}.get(service, f"CoE service {service}")
                    open_[(k, "mailbox")] = Pending("mailbox", what, ex.sent, ex.back)
                    if s.sm1_read_event:
                        # The master read the last reply: the read event (SM1 status bit
                        # 1) stays until the firmware writes the first byte of the next.
                        open_[(k, REPLY_START)] = Pending(REPLY_START, what, ex.sent,
                                                          ex.back)
            elif d.cmd in READS or d.cmd == BRD:
                if d.ado == 0x0502 and (k, "eeprom") in open_ and len(d.data) >= 2:
                    status = d.data[0] | d.data[1] << 8
                    close(k, "eeprom", ex, not status & 0x8000)
                elif d.ado == 0x0508 and len(d.data) >= 4:
                    for i in range(len(d.data) // 2):
                        s.words[s.eeprom_address + i] = d.data[2 * i] | d.data[2 * i + 1] << 8
                elif d.ado == 0x0130 and len(d.data) >= 1:
                    state = d.data[0] & 0x0F
                    p = open_.get((k, "state"))
                    if p is not None:
                        if d.data[0] & 0x10:            # refused: not a transition time
                            del open_[(k, "state")]
                        else:
                            close(k, "state", ex, state == s.want)
                    s.state = state
                elif d.ado in (0x0805, 0x080D) and len(d.data) > 0x080D - d.ado:
                    status = d.data[0x080D - d.ado]           # SM1 status, alone or in a block
                    s.sm1_read_event = bool(status & 0x02)
                    close(k, REPLY_START, ex, not status & 0x02)
                    close(k, "mailbox", ex, bool(status & 0x08))
                elif (k, "mailbox") in open_:
                    sm1 = s.sm.get(1)
                    if sm1 and d.ado == sm1[0]:
                        close(k, "mailbox", ex, True)
    return events, dict(slaves)


# -- which device, which kind ---------------------------------------------------------------

@dataclass(frozen=True)
class Device:
    """A captured slave as the fit sees it."""

    label: str          # e.g. "EK1914 (0x2:0x77a2c52:0x120000)"
    kind: str | None    # esc / firmware / drive; None: nothing tells
    source: str         # how the kind was found
    esi: bool = False   # an ESI of the corpora describes it: the emulator can build it
    own: bool = False   # it has its own measured figures (timing.DEVICES), not its kind's

    @property
    def figures(self) -> str | None:
        """Whose figures the emulated slave takes: its own (its type, e.g. "EL6910") or
        its kind's."""
        return self.label.split(" (")[0] if self.own else self.kind


def sii_dumps(folder: Path) -> dict[str, bytes]:
    """Real SII EEPROM dumps (raw images, whatever the file's extension), by file name."""
    return {p.name: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()} \
        if folder.is_dir() else {}


def classify(slave: Slave, library: Library, dumps: dict[str, bytes]) -> Device:
    """The device kind of a captured slave (module docstring)."""
    vendor, product, revision = slave.dword(0x08), slave.dword(0x0A), slave.dword(0x0C)
    if vendor is None or product is None:
        return Device("?", None, "vendor and product not read from its SII")
    label = f"0x{vendor:x}:0x{product:x}" + (f":0x{revision:x}" if revision is not None
                                               else "")
    same = [e for e in library.entries
            if (e.vendor_id, e.product_code) == (vendor, product)]
    if same:
        from ecatcfg.runtime.segment.emulate import SlaveSpec, emulated_slave
        from ecatcfg.runtime.segment.timing import DEVICES, kind_of
        entry = (min(same, key=lambda e: (abs((e.revision or 0) - revision), e.file))
                 if revision is not None else max(same, key=lambda e: e.revision or 0))
        note = "" if entry.revision == revision else \
            f", revision 0x{entry.revision or 0:x} of the ESI" + \
            (" (the capture reads none)" if revision is None else "")
        kind = kind_of(emulated_slave(SlaveSpec(library.device(entry))))
        return Device(f"{entry.type} ({label})", kind,
                      f"ESI {Path(entry.file).name} line {entry.line}{note}", esi=True,
                      own=(vendor, product) in DEVICES)
    from ecatcfg.esc import ESC_DEVICE_EMULATION
    from ecatcfg.esi import sii
    for name, data in dumps.items():
        if len(data) >= 0x18 and struct.unpack_from("<II", data, 0x10) == (vendor, product):
            return Device(label, sii_kind(sii.decode(data, source=name)),
                          f"no ESI in the corpora; SII dump {name}")
    words = bytearray(2 * (max(slave.words) + 1))
    for address, value in slave.words.items():
        struct.pack_into("<H", words, 2 * address, value)
    try:
        image = sii.decode(bytes(words), source="capture")
    except sii.SiiError:
        # A partial read (SOEM reads only what it needs): word 0 still tells device
        # emulation, the categories that could tell a drive are not there.
        if 0 not in slave.words:
            return Device(label, None, "no ESI in the corpora, no SII dump, SII word 0 not "
                          "read")
        esc = bool(slave.words[0] >> 8 & ESC_DEVICE_EMULATION)
        return Device(label, "esc" if esc else "firmware",
                      f"no ESI in the corpora, no SII dump; SII word 0 of the "
                      f"{len(slave.words)} words the capture read (no categories read: "
                      "not told from a drive)")
    return Device(label, sii_kind(image),
                  f"no ESI in the corpora, no SII dump; the {len(slave.words)} SII words "
                  "the capture read")


def sii_kind(image: SiiImage) -> str:
    """``kind_of``'s rule read from an SII image: ESC configuration (word 0 high byte)
    bit 0 device emulation -> esc; CiA 402 channels (GENERAL category byte 0x0C, ETG.1000.6
    SII) or the control/status words in a PDO category -> drive; otherwise firmware."""
    from ecatcfg.esc import ESC_DEVICE_EMULATION
    from ecatcfg.runtime.segment.timing import CIA402_WORDS
    if image.pdi_control >> 8 & ESC_DEVICE_EMULATION:
        return "esc"
    if image.general is not None and image.general.ds402_channels:
        return "drive"
    if any(e.index in CIA402_WORDS for p in image.txpdos + image.rxpdos for e in p.entries):
        return "drive"
    return "firmware"


# -- measuring and fitting ------------------------------------------------------------------

@dataclass(frozen=True)
class Window:
    """One timed event of one captured slave: its duration lies in [lo_ms, hi_ms]."""

    capture: str
    station: str
    device: Device
    quantity: str
    what: str
    lo_ms: float
    hi_ms: float

    def holds(self, figure_ms: float) -> bool:
        return self.lo_ms <= figure_ms <= self.hi_ms


def measure(path: Path, library: Library, dumps: dict[str, bytes],
            name: str | None = None) -> list[Window]:
    """Every timed event of one capture, with its slave's device and kind."""
    events, slaves = analyse(read_exchanges(path))
    devices = {station: classify(s, library, dumps) for station, s in slaves.items()}
    unknown = Device("?", None, "never identified")
    return [Window(name or path.name, e.station, devices.get(e.station, unknown), e.quantity,
                   e.what, e.lo_ms, e.hi_ms) for e in events]


@dataclass(frozen=True)
class Fit:
    figure_ms: float
    region: tuple[float, float]     # where the chosen windows overlap
    in_step: int
    out_of_step: list[Window]


def score(windows: list[Window], figure_ms: float) -> tuple[int, int]:
    """How many windows of slaves an ESI of the corpora describes hold ``figure_ms``, and
    how many windows in all."""
    held = [w for w in windows if w.holds(figure_ms)]
    return sum(w.device.esi for w in held), len(held)


def fit(windows: list[Window]) -> Fit:
    """The figure inside the most windows (module docstring): first those of slaves an ESI
    of the corpora describes (the slaves the emulator can build from them), then all."""
    candidates = sorted({w.lo_ms for w in windows} | {w.hi_ms for w in windows})
    best = max(candidates, key=lambda x: (score(windows, x), x))
    inside = [w for w in windows if w.holds(best)]
    region = (max(w.lo_ms for w in inside), min(w.hi_ms for w in inside))
    return Fit((region[0] + region[1]) / 2, region, len(inside),
               [w for w in windows if not w.holds(best)])


def spread(values: list[float]) -> str:
    return (f"{min(values):.3f}/{statistics.median(values):.3f}/{max(values):.3f}"
            if values else "-")


def summary(windows: list[Window]) -> str:
    """n, the largest lower bound, the smallest upper bound, and min/median/max of the
    lower bounds, the upper bounds and the windows' midpoints."""
    los, his = [w.lo_ms for w in windows], [w.hi_ms for w in windows]
    mids = [(w.lo_ms + w.hi_ms) / 2 for w in windows]
    return (f"n={len(windows):3}  [{max(los):.3f}, {min(his):.3f}]  lo {spread(los)}  "
            f"hi {spread(his)}  mid {spread(mids)} ms")


ORDER = (EEPROM, MAILBOX, REPLY_START, "IP", "PS", "SO", "OS", "SP", "SI", "OP", "OI", "PI")


def _quantity_key(q: str) -> tuple[int, str]:
    return (ORDER.index(q) if q in ORDER else len(ORDER), q)


def by_kind(windows: list[Window]) -> dict[tuple[str, str], list[Window]]:
    """The windows per (kind, quantity) the fit uses: EEPROM reads under ``"all"`` (the ESC
    reads the EEPROM, whatever runs behind it); a device with its own figures
    (``timing.DEVICES``) under its type instead of its kind; slaves of no kind left out."""
    groups: dict[tuple[str, str], list[Window]] = defaultdict(list)
    for w in windows:
        figures = w.device.figures
        if figures is None:
            continue
        groups[("all" if w.quantity == EEPROM else figures, w.quantity)].append(w)
    return dict(groups)


def corpus_captures(corpora: list[Path]) -> list[tuple[Path, str]]:
    """Every capture of the corpora, named as docs/conformance.md names them."""
    found = []
    for root in corpora:
        prefix = "" if root == corpora[0] else "corpus-extra/"
        for path in sorted((root / "pcap").rglob("*.pcap*")):
            found.append((path, prefix + path.relative_to(root / "pcap").as_posix()))
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("captures", nargs="*", type=Path,
                    help="pcapng files (default: every capture of both corpora)")
    ap.add_argument("--corpus", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus")))
    ap.add_argument("--corpus-extra", type=Path, default=Path(os.environ.get(
        "ECATCFG_CORPUS_EXTRA", ROOT.parent / "shared" / "corpus-extra")))
    ap.add_argument("--events", action="store_true", help="every event, not just the summary")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT.parent))
    from ecatcfg.esi.library import Library
    corpora = [c for c in (args.corpus, args.corpus_extra) if (c / "esi").is_dir()]
    library = Library([c / "esi" for c in corpora])
    dumps = sii_dumps(args.corpus / "sii")
    paths = [(p, p.name) for p in args.captures] or corpus_captures(corpora)
    every: list[Window] = []
    for path, name in paths:
        windows = measure(path, library, dumps, name)
        every += windows
        print(f"\n## {name}")
        stations: dict[str, list[Window]] = defaultdict(list)
        for w in windows:
            stations[w.station].append(w)
        for station, ws in sorted(stations.items()):
            d = ws[0].device
            print(f"slave {station}: {d.label}, kind {d.kind or '?'} ({d.source})")
            groups: dict[str, list[Window]] = defaultdict(list)
            for w in ws:
                groups[w.quantity].append(w)
                if args.events:
                    print(f"    {w.quantity:8} {w.what:24} {w.lo_ms:8.3f}..{w.hi_ms:.3f} ms")
            for q in sorted(groups, key=_quantity_key):
                print(f"  {q:8} {summary(groups[q])}")
    print("\n## Fit per kind (EEPROM reads over every slave)")
    for (kind, q), ws in sorted(by_kind(every).items(),
                                key=lambda i: (i[0][0], _quantity_key(i[0][1]))):
        f = fit(ws)
        devices = sorted({w.device.label.split(" (")[0] for w in ws})
        print(f"{kind:8} {q:8} {summary(ws)}")
        print(f"{'':17} fit {f.figure_ms:.3f} ms (most overlap {f.region[0]:.3f}.."
              f"{f.region[1]:.3f}): {f.in_step} of {len(ws)} windows in step; devices: "
              f"{', '.join(devices)}")
        for w in f.out_of_step:
            print(f"{'':19} out of step: {w.capture} {w.station} {w.device.label} {w.what} "
                  f"{w.lo_ms:.3f}..{w.hi_ms:.3f}")
    unknown = {(w.capture, w.station, w.device.source) for w in every if w.device.kind is None}
    for capture, station, why in sorted(unknown):
        print(f"not fitted: {capture} slave {station}: {why}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
