"""Who is on the wire: count the slaves, read each one's identity from its SII EEPROM and
its DL status, and work out from the DL statuses where each one is plugged (a tree).

Nothing but the SII interface registers (0x0500-0x050F) is written, and slaves are
addressed by position (auto-increment), so a scan can run before any configuration and
changes nothing a later configuration relies on.  Identity words: vendor 0x08, product
0x0A, revision 0x0C, serial 0x0E (ETG.1000.6 / ETG.2010; ``docs/protocol-notes.md`` §7).
"""

from __future__ import annotations

import struct

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.compare import revision_check
from ecatcfg.eni.plan import NetworkPlan, SlavePlan
from ecatcfg.esc import (EEPROM_BUSY, EEPROM_ERROR_ACKNOWLEDGE, EEPROM_ERRORS, EEPROM_R64,
                         PORT_LETTERS, SII_REVISION, SII_VENDOR_ID, Cmd, Reg,
                         eeprom_read_request)
from ecatcfg.record import record
from ecatcfg.runtime.master.lockstep import Job, Step, run_jobs, until_answered
from ecatcfg.runtime.master.replay import ApplyError
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram
from ecatcfg.runtime.wiring import Plug, eni_plugs, plugs_from_dl_status

EEPROM_TIMEOUT = 0.5           # s per slave (IgH: 20 ms per access, 500 ms for loading)
COUNT_ATTEMPTS = 5


@record(frozen=True)
class FoundSlave:
    position: int
    vendor_id: int
    product_code: int
    revision: int
    serial_no: int
    dl_status: int = 0             # 0x0110: which ports have a link and communication
    plug: Plug | None = None       # where it is plugged (positions); None: the master

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

        def waiting() -> None:
            # Checked only where a reply brought no progress: a reply that answers is used
            # even when it comes after the deadline (the master's own process may have
            # been descheduled past it on a busy host; the EEPROM had answered).
            if monotonic() > deadline:
                raise ApplyError(f"position {position}: the SII EEPROM does not answer")
        while True:
            reply = yield [request] if phase == "request" else [status] if phase == "poll" \
                else [value]
            if reply is None or reply[0].wkc != 1:
                waiting()
                continue
            if phase == "request":
                phase = "poll"
            elif phase == "poll":
                control, = struct.unpack("<H", reply[0].data)
                if control & EEPROM_BUSY:
                    waiting()
                    continue
                if control & EEPROM_ERROR_ACKNOWLEDGE and not control & EEPROM_ERRORS \
                        & ~EEPROM_ERROR_ACKNOWLEDGE:
                    # The EEPROM did not acknowledge: it is still busy with its own write
                    # cycle after a word was written (ESC Section II 0x0502 bit 13). Ask
                    # again until the deadline.
                    phase = "request"
                    waiting()
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


def identity_job(position: int, out: dict[int, FoundSlave]) -> Job:
    deadline = monotonic() + EEPROM_TIMEOUT
    adp = -position & 0xFFFF
    # The EEPROM belongs to the EtherCAT side for the reading (0x0500 = 0).
    owner = Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONFIG, b"\x00")
    yield from until_answered([owner], deadline, ApplyError(f"position {position}: no answer"))
    first = yield from sii_words(position, SII_VENDOR_ID, deadline)
    second = yield from sii_words(position, SII_REVISION, deadline)
    vendor, product = struct.unpack("<II", first)
    revision, serial = struct.unpack("<II", second)
    dl = Datagram.physical(Cmd.APRD, adp, Reg.DL_STATUS, 2)
    got = yield from until_answered([dl], deadline, ApplyError(f"position {position}: no "
                                                                "answer to DL status"))
    status, = struct.unpack("<H", got[0].data)
    out[position] = FoundSlave(position, vendor, product, revision, serial, status)


def scan(transport: Transport) -> list[FoundSlave]:
    """The slaves on the line in bus order, with their SII identity, DL status and where
    each is plugged."""
    n = count_slaves(transport)
    found: dict[int, FoundSlave] = {}
    run_jobs(transport, [identity_job(p, found) for p in range(n)])
    slaves = [found[p] for p in range(n)]
    plugs = plugs_from_dl_status([s.dl_status for s in slaves])
    return [FoundSlave(s.position, s.vendor_id, s.product_code, s.revision, s.serial_no,
                       s.dl_status, plug) for s, plug in zip(slaves, plugs)]


def identities(transport: Transport, positions: list[int]) -> dict[int, FoundSlave]:
    """The SII identity and DL status of each slave in ``positions`` (no plug: that needs
    the whole line); a slave whose SII does not answer is left out, so that one dead
    EEPROM does not hide the others (``states``, ``doctor``)."""
    out: dict[int, FoundSlave] = {}
    run_jobs(transport, [_or_nothing(identity_job(p, out)) for p in positions])
    return out


def _or_nothing(job: Job) -> Job:
    try:
        yield from job
    except ApplyError:
        return


# The SII categories are read one after the other from this word on (ETG.2010: after the
# 64-word header); a bound on how far to look for GENERAL (the largest SII is 64 KiB).
SII_FIRST_CATEGORY = 0x0040
_SII_WORDS_MAX = 0x8000


def sii_head_job(position: int, out: dict[int, bytes]) -> Job:
    """The SII from word 0 through its GENERAL category (the device's name, order number,
    group, CoE details), STRINGS included where it comes first as ETG.2010 has it: the
    header, then category by category (type, length in words, data) until GENERAL or the
    end marker.  Not the whole EEPROM: a scan of names reads a few hundred bytes."""
    from ecatcfg.esi.sii import CAT_END, CAT_GENERAL, CATEGORY_HEADER

    deadline = monotonic() + EEPROM_TIMEOUT
    adp = -position & 0xFFFF
    owner = Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONFIG, b"\x00")
    yield from until_answered([owner], deadline, ApplyError(f"position {position}: no answer"))
    data = b""

    def upto(words: int) -> Step[None]:
        nonlocal data, deadline
        while len(data) < 2 * words:
            deadline = monotonic() + EEPROM_TIMEOUT
            data += yield from sii_words(position, len(data) // 2, deadline)

    word = SII_FIRST_CATEGORY
    while word < _SII_WORDS_MAX:
        yield from upto(word + 2)
        kind, length = CATEGORY_HEADER.unpack_from(data, 2 * word)
        if kind == CAT_END:
            break
        yield from upto(word + 2 + length)
        word += 2 + length
        if kind == CAT_GENERAL:
            break
    out[position] = data[:2 * word]


def sii_heads(transport: Transport, positions: list[int]) -> dict[int, bytes]:
    """:func:`sii_head_job` of each slave in ``positions``, all at once; a slave whose SII
    does not answer is left out."""
    out: dict[int, bytes] = {}
    run_jobs(transport, [_or_nothing(sii_head_job(p, out)) for p in positions])
    return out


@record(frozen=True)
class Mismatch:
    position: int
    expected: str
    found: str
    problem: str


def verify(plan: NetworkPlan, found: list[FoundSlave],
           accept_newer_revision: bool = False) -> list[Mismatch]:
    """Compare the slaves found with the ENI: missing, extra, other device, other revision
    (a newer one passes when ``accept_newer_revision``), and, when the ENI says where its
    slaves are plugged (``PreviousPort``), the tree: slaves are paired port by port from
    the first one, so a slave in another port than the ENI's is reported with both places,
    and the slaves behind a missing link are reported missing by name.  An ENI without
    ``PreviousPort`` is compared in bus order."""
    expected = sorted(plan.slaves, key=lambda s: s.position)
    if not any(s.previous_ports for s in expected[1:]) or any(
            f.plug is None for f in found[1:]):
        return _verify_line(expected, found, accept_newer_revision)
    want = eni_plugs(expected, "the ENI")
    line = all(p is None or p == Plug(k - 1, 1) for k, p in enumerate(want))
    pairs = _pair(want, [f.plug for f in found])
    paired = set(pairs.values())
    by_found = {f: e for e, f in pairs.items()}

    def ids(s: SlavePlan | FoundSlave) -> str:
        return f"0x{s.vendor_id:x}:0x{s.product_code:x}:0x{s.revision:x}"

    def where_expected(e: int) -> str:
        plug = want[e]
        return "" if line or plug is None else \
            f" behind {expected[plug.parent].name} port {PORT_LETTERS[plug.port]}"

    def where_found(f: int) -> str:
        plug = found[f].plug
        if line or plug is None:
            return ""
        parent = by_found.get(plug.parent)
        shown = expected[parent].name if parent is not None else f"position {plug.parent}"
        return f" behind {shown} port {PORT_LETTERS[plug.port]}"

    problems: list[Mismatch] = []
    extra = [f for f in range(len(found)) if f not in paired]
    for e, want_slave in enumerate(expected):
        w = f"{want_slave.name} ({ids(want_slave)}){where_expected(e)}"
        f = pairs.get(e)
        if f is None:
            moved = next((x for x in extra if (found[x].vendor_id, found[x].product_code)
                          == (want_slave.vendor_id, want_slave.product_code)), None)
            if moved is not None:
                extra.remove(moved)
                problems.append(Mismatch(want_slave.position, w,
                                         f"{ids(found[moved])}{where_found(moved)}",
                                         f"plugged into another port (found at position "
                                         f"{moved})"))
            else:
                plug = want[e]
                behind = "" if plug is None or plug.parent not in pairs else (
                    f" (no slave on port {PORT_LETTERS[plug.port]} of "
                    f"{expected[plug.parent].name}: cable or slave missing)")
                problems.append(Mismatch(want_slave.position, w, "-",
                                         "missing slave" + ("" if line else behind)))
            continue
        problem = compare(expected, want_slave, found[f], accept_newer_revision)
        if problem:
            problems.append(Mismatch(want_slave.position, w, ids(found[f]), problem))
    for f in extra:
        problems.append(Mismatch(f, "-", f"{ids(found[f])}{where_found(f)}", "extra slave"))
    return problems


def paired(plan: NetworkPlan, found: list[FoundSlave]) -> dict[int, int]:
    """Which slave found (its auto-increment position) is the ENI's slave at each position,
    as :func:`verify` pairs them: in bus order, or port by port through the tree."""
    expected = sorted(plan.slaves, key=lambda s: s.position)
    if not any(s.previous_ports for s in expected[1:]) or any(
            f.plug is None for f in found[1:]):
        return {expected[k].position: k for k in range(min(len(expected), len(found)))}
    pairs = _pair(eni_plugs(expected, "the ENI"), [f.plug for f in found])
    return {expected[e].position: f for e, f in pairs.items()}


def _pair(want: list[Plug | None], got: list[Plug | None]) -> dict[int, int]:
    """Expected slave -> found slave, walking both trees from their first slaves and
    pairing the slaves on the same port of paired parents."""
    def children(plugs: list[Plug | None]) -> list[dict[int, int]]:
        out: list[dict[int, int]] = [{} for _ in plugs]
        for k, plug in enumerate(plugs):
            if plug is not None:
                out[plug.parent][plug.port] = k
        return out

    mine, theirs = children(want), children(got)
    pairs: dict[int, int] = {}
    todo = [(0, 0)] if want and got else []
    while todo:
        e, f = todo.pop()
        pairs[e] = f
        todo.extend((c, theirs[f][port]) for port, c in mine[e].items() if port in theirs[f])
    return pairs


def compare(expected: list[SlavePlan], want: SlavePlan, got: FoundSlave,
            accept_newer_revision: bool) -> str:
    """What is wrong with ``got`` in the place of ``want`` ("" when nothing)."""
    if (got.vendor_id, got.product_code) != (want.vendor_id, want.product_code):
        others = [s.position for s in expected if (s.vendor_id, s.product_code) ==
                  (got.vendor_id, got.product_code)]
        return "other device" + (
            f" (the ENI has it at position {others[0]}: swapped?)" if others else "")
    check = revision_check(want)      # the ENI's own revision check, with its compare type
    if check is not None:
        if not check(got.revision, want.revision):
            return "other revision (the ENI's revision check refuses it)"
    elif got.revision != want.revision and not (
            accept_newer_revision and got.revision > want.revision):
        return "other revision" + (" (newer: --accept-newer-revision takes it)"
                                   if got.revision > want.revision else "")
    return ""


def _verify_line(expected: list[SlavePlan], found: list[FoundSlave],
                 accept_newer_revision: bool) -> list[Mismatch]:
    """Compare in bus order."""
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
        else:
            problem = compare(expected, want, got, accept_newer_revision)
            if problem:
                problems.append(Mismatch(pos, w, g, problem))
    return problems
