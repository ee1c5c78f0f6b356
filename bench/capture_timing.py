"""Slave timing measured in wire captures of real hardware: the figures behind the timing
model's table (``runtime/timing.py``, ``docs/timing.md``).

Run: ``python3 bench/capture_timing.py CAPTURE.pcapng ...`` (pcapng files with both the
master's frames and the slaves' replies, e.g. ethercrab-rs/ethercrab ``dumps/*.pcapng`` and
``tests/replay-*.pcapng``).  Prints, per capture and slave (station address and the
identity read from its SII), every event it can time, with bounds:

- **EEPROM read**: from the read command (a write of 0x0100 to 0x0502) to the first status
  poll of 0x0502 without the busy bit (0x8000);
- **state change**: from an AL control write (0x0120) to the first AL status read
  (0x0130) that shows the requested state;
- **mailbox reply**: from a complete write of the mailbox-out SM (SM0) to the first read
  that finds the mailbox-in SM (SM1) full (its status 0x080D bit 3, or a read of the SM1
  area with a working counter).

A capture stamps each frame when the master's host sends it (Q) and when the reply comes
back (R); the slave acted somewhere in between.  So the duration of an event lies in
[Q(last poll that still saw the old value) - R(command), R(first poll that saw the new
value) - Q(command)], printed as ``lo..hi`` ms; the lower bound is 0 when no poll saw the
old value.  The polls' spacing limits the precision: a master that polls every 3 ms
(TwinCAT here) gives windows of about 3 ms.

Nothing here is asserted: the script reports, the table in docs/timing.md quotes it.
"""

from __future__ import annotations

import argparse
import statistics
import struct
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

FPRD, FPWR, APRD, APWR, BRD, BWR = 0x04, 0x05, 0x01, 0x02, 0x07, 0x08
READS = {FPRD, APRD}
WRITES = {FPWR, APWR}
KNOWN = {(0x2, 0x044C2C52): "EK1100", (0x2, 0x03EC3052): "EL1004",
         (0x2, 0x0B0C3052): "EL2828", (0x2, 0x0B493052): "EL2889",
         (0x2, 0x07D43052): "EL2004", (0x6A, 0x00414B44): "Kollmorgen AKD",
         (0x9, 0x9252): "LAN9252 (SOES)", (0x1337, None): "SOES slave"}
MBX_TYPES = {1: "AoE", 2: "EoE", 3: "CoE", 4: "FoE", 5: "SoE", 15: "VoE"}
STATES = {1: "INIT", 2: "PREOP", 3: "BOOT", 4: "SAFEOP", 8: "OP"}


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

    def name(self) -> str:
        vendor = self.words.get(8, 0) | self.words.get(9, 0) << 16
        product = self.words.get(10, 0) | self.words.get(11, 0) << 16
        if not vendor:
            return "?"
        return KNOWN.get((vendor, product)) or KNOWN.get((vendor, None)) or \
            f"{vendor:#x}:{product:#x}"


@dataclass
class Pending:
    kind: str           # "eeprom", "state", "mailbox"
    what: str
    sent: float
    back: float
    last_old: float | None = None


@dataclass
class Event:
    station: str
    kind: str
    what: str
    lo_ms: float
    hi_ms: float


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
        events.append(Event(k, kind, p.what, lo, (ex.back - p.sent) * 1e3))
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
                            ex.sent, ex.back)
                        open_[(k, "state")].last_old = None
                        s.want = want                               # type: ignore[attr-defined]
                elif (sm0 := s.sm.get(0)) and d.ado == sm0[0] and len(d.data) >= 6:
                    mtype = MBX_TYPES.get(d.data[5] & 0x0F, str(d.data[5] & 0x0F))
                    what = mtype
                    if mtype == "CoE" and len(d.data) >= 9:
                        service = d.data[7] >> 4
                        what = {2: "CoE SDO " + ("upload" if d.data[8] >> 5 == 2
                                                 else "download"),
                                8: "CoE SDO info"}.get(service, f"CoE service {service}")
                    open_[(k, "mailbox")] = Pending("mailbox", what, ex.sent, ex.back)
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
                        want = getattr(s, "want", None)
                        if d.data[0] & 0x10:            # refused: not a transition time
                            del open_[(k, "state")]
                        else:
                            close(k, "state", ex, state == want)
                    s.state = state
                elif (k, "mailbox") in open_:
                    sm1 = s.sm.get(1)
                    if d.ado == 0x080D and len(d.data) >= 1:
                        close(k, "mailbox", ex, bool(d.data[0] & 0x08))
                    elif d.ado == 0x0805 and len(d.data) >= 9:    # SM1 status in a block
                        close(k, "mailbox", ex, bool(d.data[8] & 0x08))
                    elif sm1 and d.ado == sm1[0]:
                        close(k, "mailbox", ex, True)
    return events, dict(slaves)


def summarise(events: list[Event]) -> list[tuple[str, str, int, float, float, float, float]]:
    """(kind, what, count, max of the lower bounds, median of the upper bounds, min of
    the upper bounds, median of the windows' midpoints: the figure the table quotes)."""
    groups: dict[tuple[str, str], list[Event]] = defaultdict(list)
    for e in events:
        groups[(e.kind, e.what)].append(e)
    return [(kind, what, len(es), max(e.lo_ms for e in es),
             statistics.median(e.hi_ms for e in es), min(e.hi_ms for e in es),
             statistics.median((e.lo_ms + e.hi_ms) / 2 for e in es))
            for (kind, what), es in sorted(groups.items())]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("captures", nargs="+", type=Path)
    ap.add_argument("--events", action="store_true", help="every event, not just the summary")
    args = ap.parse_args()
    for path in args.captures:
        events, slaves = analyse(read_exchanges(path))
        print(f"\n## {path.name}")
        by_station: dict[str, list[Event]] = defaultdict(list)
        for e in events:
            by_station[e.station].append(e)
        for station, es in sorted(by_station.items()):
            print(f"slave {station} ({slaves[station].name() if station in slaves else '?'})")
            if args.events:
                for e in es:
                    print(f"    {e.kind:8} {e.what:24} {e.lo_ms:8.3f}..{e.hi_ms:.3f} ms")
            for kind, what, n, lo, med, hi_min, mid in summarise(es):
                print(f"  {kind:8} {what:16} n={n:3}  lower bound max {lo:7.3f}, upper "
                      f"bound min {hi_min:7.3f} / median {med:7.3f}, midpoint median "
                      f"{mid:7.3f} ms")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
