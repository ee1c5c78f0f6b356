"""Who is on the wire: count the slaves and read each one's identity from its SII EEPROM.

Nothing but the SII interface registers (0x0500-0x050F) is written, and slaves are
addressed by position (auto-increment), so a scan can run before any configuration and
changes nothing a later configuration relies on.  Identity words: vendor 0x08, product
0x0A, revision 0x0C, serial 0x0E (ETG.1000.6 / ETG.2010; ``docs/protocol-notes.md`` §7).
"""

from __future__ import annotations

import struct
import time

from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import (EEPROM_BUSY, EEPROM_ERRORS, EEPROM_R64, SII_REVISION, SII_VENDOR_ID, Cmd,
                         Reg, eeprom_read_request)
from ecatcfg.record import record
from ecatcfg.runtime.lockstep import Job, Step, run_jobs, until_answered
from ecatcfg.runtime.replay import ApplyError
from ecatcfg.runtime.transport import Transport
from ecatcfg.runtime.wire import Datagram

EEPROM_TIMEOUT = 0.5           # s per slave (IgH: 20 ms per access, 500 ms for loading)
COUNT_ATTEMPTS = 5


@record(frozen=True)
class FoundSlave:
    position: int
    vendor_id: int
    product_code: int
    revision: int
    serial_no: int

    @property
    def identity(self) -> tuple[int, int, int]:
        return self.vendor_id, self.product_code, self.revision


def count_slaves(transport: Transport) -> int:
    """BRD of the AL status register: every slave adds one to the working counter."""
    for _ in range(COUNT_ATTEMPTS):
        back = transport.exchange([Datagram.physical(Cmd.BRD, 0, Reg.AL_STATUS, 2)])
        if back is not None:
            return back[0].wkc
    raise ApplyError("no frame came back: is the interface connected to an EtherCAT line?")


def sii_words(position: int, word: int, deadline: float) -> Step[bytes]:
    """Four SII words from ``word`` on (two reads on ESCs that return 4 bytes at a time)."""
    adp = -position & 0xFFFF
    data = b""
    while len(data) < 8:
        request = Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONTROL,
                                    eeprom_read_request(word + len(data) // 2))
        status = Datagram.physical(Cmd.APRD, adp, Reg.EEPROM_CONTROL, 2)
        value = Datagram.physical(Cmd.APRD, adp, Reg.EEPROM_DATA, 8)
        phase = "request"
        while True:
            reply = yield [request] if phase == "request" else [status] if phase == "poll" \
                else [value]
            if time.monotonic() > deadline:
                raise ApplyError(f"position {position}: the SII EEPROM does not answer")
            if reply is None or reply[0].wkc != 1:
                continue
            if phase == "request":
                phase = "poll"
            elif phase == "poll":
                control, = struct.unpack("<H", reply[0].data)
                if control & EEPROM_BUSY:
                    continue
                if control & EEPROM_ERRORS:
                    raise ApplyError(f"position {position}: SII EEPROM error "
                                     f"(0x0502 = 0x{control:04X})")
                wide = bool(control & EEPROM_R64)
                phase = "read"
            else:
                data += bytes(reply[0].data[:8 if wide else 4])
                break
    return data[:8]


def _identity_job(position: int, out: dict[int, FoundSlave]) -> Job:
    deadline = time.monotonic() + EEPROM_TIMEOUT
    adp = -position & 0xFFFF
    # The EEPROM belongs to the EtherCAT side for the reading (0x0500 = 0).
    owner = Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONFIG, b"\x00")
    yield from until_answered([owner], deadline, ApplyError(f"position {position}: no answer"))
    first = yield from sii_words(position, SII_VENDOR_ID, deadline)
    second = yield from sii_words(position, SII_REVISION, deadline)
    vendor, product = struct.unpack("<II", first)
    revision, serial = struct.unpack("<II", second)
    out[position] = FoundSlave(position, vendor, product, revision, serial)


def scan(transport: Transport) -> list[FoundSlave]:
    """The slaves on the line in bus order, with their SII identity."""
    n = count_slaves(transport)
    found: dict[int, FoundSlave] = {}
    run_jobs(transport, [_identity_job(p, found) for p in range(n)])
    return [found[p] for p in range(n)]


@record(frozen=True)
class Mismatch:
    position: int
    expected: str
    found: str
    problem: str


def verify(plan: NetworkPlan, found: list[FoundSlave],
           accept_newer_revision: bool = False) -> list[Mismatch]:
    """Compare the line with the ENI in bus order: missing, extra, other device, other
    revision (a newer one passes when ``accept_newer_revision``)."""
    expected = sorted(plan.slaves, key=lambda s: s.position)
    problems = []
    for pos in range(max(len(expected), len(found))):
        want = expected[pos] if pos < len(expected) else None
        got = found[pos] if pos < len(found) else None
        w = (f"{want.name} (0x{want.vendor_id:x}:0x{want.product_code:x}:"
             f"0x{want.revision:x})" if want else "-")
        g = (f"0x{got.vendor_id:x}:0x{got.product_code:x}:0x{got.revision:x}"
             if got else "-")
        if want is None:
            problems.append(Mismatch(pos, w, g, "extra slave"))
        elif got is None:
            problems.append(Mismatch(pos, w, g, "missing slave"))
        elif (got.vendor_id, got.product_code) != (want.vendor_id, want.product_code):
            others = [s.position for s in expected if (s.vendor_id, s.product_code) ==
                      (got.vendor_id, got.product_code)]
            problems.append(Mismatch(pos, w, g, "other device" + (
                f" (the ENI has it at position {others[0]}: swapped?)" if others else "")))
        elif got.revision != want.revision and not (
                accept_newer_revision and got.revision > want.revision):
            problems.append(Mismatch(pos, w, g, "other revision" + (
                " (newer: --accept-newer-revision takes it)"
                if got.revision > want.revision else "")))
    return problems
