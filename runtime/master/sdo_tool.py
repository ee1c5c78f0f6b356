"""One SDO transfer with one slave of a line no other master is driving (``ecatcfg sdo``).

There is no ENI here: the mailbox comes from the slave's own SII, the way a master finds it
while scanning (ETG.2010 words 0x18/0x1A standard receive/send mailbox offset and size,
word 0x1C protocols; ``docs/protocol-notes.md`` §7).  The slave is addressed by its position
until it has a station address, then by that address:

1. count the slaves (BRD), read AL status and station address of the one asked for;
2. read SII words 0x18-0x1C (the EEPROM belongs to EtherCAT while reading); refuse
   a slave without the CoE bit (0x04) in word 0x1C (``ecatcfg soe``: the SoE bit, 0x10,
   ``SlaveMailbox.protocol``);
3. give it a station address when it has none (0x1000 + position + 1, or the next free one);
4. if it is below PREOP: SM0/SM1 from the SII (control 0x26/0x22, enabled), EEPROM to the
   PDI (0x0500 = 1), AL control PREOP with error acknowledge (0x12) and wait for PREOP;
   if it is in PREOP, SAFEOP or OP already, take SM0/SM1 as they are configured;
5. empty SM1 of a message some earlier transfer left there, then one SDO transfer.

The slave stays in the state it was brought to (PREOP, or the one it was in).

The first request of the transfer goes out with mailbox counter 0 ("not used", as IgH sends
all of its messages): a slave drops a message whose counter equals the previous one it got
(SOES ``mbxincnt``; ``docs/protocol-notes.md`` §5), and an earlier run of this tool on a
slave still in PREOP may well have ended on counter 1.  Later messages of the transfer count 1..7.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from dataclasses import dataclass

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import MailboxArea, MailboxPlan
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (AL_ERROR_ACK, AL_STATE_MASK, AL_STATUS_ERROR, MAILBOX_PROTOCOL_BITS,
                         SII_MAILBOX_PROTOCOLS, SII_STD_MAILBOX, SM1_STATUS, SM_CONTROL_MBOX_IN,
                         SM_CONTROL_MBOX_OUT, SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES, SM_DIR_MASK,
                         SM_MODE_MAILBOX, SM_MODE_MASK, SM_STATUS_MAILBOX_FULL, AlState, Cmd, Reg,
                         SmConfig, al_state_name, al_status_name, mailbox_protocol_names)
from ecatcfg.runtime.master.lockstep import Job, Step, run_jobs
from ecatcfg.runtime.mailbox import NORMAL_OVERHEAD, abort_name
from ecatcfg.runtime.master.reached import awaited_al_status
from ecatcfg.runtime.master.replay import (TIMEOUT_COMMAND, TIMEOUT_MAILBOX,
                                           TIMEOUT_STATE, ApplyError, MailboxChannel, sdo_job)
from ecatcfg.runtime.master.scan import count_slaves, sii_words
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram

FIRST_STATION_ADDRESS = 0x1000  # + position + 1, as SOEM and ENIs number them
STALE_MESSAGES = 16            # at most this many old messages are taken out of SM1


class SdoToolError(EcatcfgError):
    """The transfer could not be done; ``abort_code`` is set when the slave aborted it."""

    def __init__(self, message: str, abort_code: int | None = None,
                 al_code: int | None = None) -> None:
        super().__init__(message)
        self.abort_code = abort_code
        self.al_code = al_code


@dataclass(slots=True)
class SlaveMailbox:
    """What the preparation found and did: for reports and tests."""

    position: int
    station_address: int = 0
    state_before: int = 0              # AL status (state | error flag) as found
    state: int = 0                     # AL state the transfer ran in
    protocols: int = 0                 # SII word 0x1C
    send: SmConfig | None = None       # SM0
    recv: SmConfig | None = None       # SM1
    configured: bool = False           # True: this run wrote SM0/SM1 and requested PREOP
    stale_messages: int = 0            # old messages taken out of SM1 before the transfer
    protocol: str = "CoE"              # the mailbox protocol the SII must list (SoE: soe_tool)


# -- INDEX:SUB and values -------------------------------------------------------------------

_ADDRESS = re.compile(r"^\s*(?:0x|#x)?([0-9a-f]{1,4})\s*:\s*(?:0x|#x)?([0-9a-f]{1,2})\s*$",
                      re.IGNORECASE)


def parse_address(text: str) -> tuple[int, int]:
    """``0x1018:01``, ``1018:1``, ``0x6060:0`` -> (index, subindex).  Both parts are
    hexadecimal, with or without ``0x`` (the way CoE objects are written: 0x1C12:0A)."""
    m = _ADDRESS.match(text)
    if not m:
        raise ValueError(f"{text!r} is not INDEX:SUB (hexadecimal, e.g. 0x1018:01 or "
                         "0x6060:0)")
    return int(m.group(1), 16), int(m.group(2), 16)


def protocol_names(word: int) -> str:
    names = mailbox_protocol_names(word)
    return ", ".join(names) if names else "none"


# -- the transfer -----------------------------------------------------------------------------

def sdo_transfer(transport: Transport, position: int, index: int, sub: int,
                 data: bytes | None = None, complete_access: bool = False, *,
                 timeout: float = TIMEOUT_MAILBOX,
                 info: SlaveMailbox | None = None) -> bytes:
    """Upload (``data is None``) or download ``data`` to ``index:sub`` of the slave at
    ``position``; returns the uploaded bytes (``b""`` for a download).

    Raises :class:`SdoToolError` (an abort carries ``abort_code``), or
    :class:`~ecatcfg.runtime.master.replay.ApplyError` when no frame comes back at all.
    ``info`` (optional) is filled with what the preparation found.
    """
    if complete_access and sub > 1:
        raise SdoToolError("complete access starts at subindex 0 or 1, not "
                           f"{sub} (ETG.1000.6)")
    result: list[bytes] = []
    info = info if info is not None else SlaveMailbox(position)

    def work(channel: MailboxChannel, size: int, counter: Callable[[], int]) -> Job:
        yield from _transfer(info, channel, size, counter, index, sub, data,
                             complete_access, timeout, result)

    mailbox_session(transport, position, work, info)
    return result[0]


def mailbox_session(transport: Transport, position: int,
                    work: Callable[[MailboxChannel, int, Callable[[], int]], Job],
                    info: SlaveMailbox | None = None) -> SlaveMailbox:
    """Prepare the slave at ``position`` as for an SDO transfer (steps 1-5 above), then run
    ``work(channel, SM0 length, counter)`` over its mailbox; returns what the preparation
    found.  Raises :class:`SdoToolError` as :func:`sdo_transfer` does."""
    n = count_slaves(transport)
    if not 0 <= position < n:
        raise SdoToolError(f"no slave at position {position}: the line has {n} "
                           f"slave{'s' if n != 1 else ''}"
                           + (f" (positions 0..{n - 1})" if n > 1 else ""))
    info = info if info is not None else SlaveMailbox(position)
    info.position = position
    run_jobs(transport, [_session(info, work)])
    return info


def _session(info: SlaveMailbox,
             work: Callable[[MailboxChannel, int, Callable[[], int]], Job]) -> Job:
    channel, counter = yield from open_mailbox(info)
    yield from work(channel, channel.plan.send.length, counter)


def open_mailbox(info: SlaveMailbox) -> Step[tuple[MailboxChannel, Callable[[], int]]]:
    """A job step: prepare the slave at ``info.position`` (steps 2-5 above, the slave known
    to be on the line) and return its mailbox channel with the counters for the transfers
    that follow; any number of transfers may then use it, with no second preparation
    (``runtime/master/diagnose.py`` reads many objects in a row).  Raises
    :class:`SdoToolError` as :func:`sdo_transfer` does."""
    yield from _prepare(info)
    send, recv = info.send, info.recv
    assert send is not None and recv is not None
    plan = MailboxPlan(MailboxArea(send.start, send.length),
                       MailboxArea(recv.start, recv.length), protocols=[info.protocol])
    channel = MailboxChannel(info.station_address, plan)
    yield from empty_sm1(info, channel)
    return channel, MailboxCounter()


def _transfer(info: SlaveMailbox, channel: MailboxChannel, size: int,
              counter: Callable[[], int], index: int, sub: int, data: bytes | None,
              complete_access: bool, timeout: float, result: list[bytes]) -> Job:
    from ecatcfg.runtime.master.sdo_client import SdoDownload, SdoUpload

    what = f"SDO {'upload' if data is None else 'download'} 0x{index:04X}:{sub:02X}"
    t: SdoUpload | SdoDownload
    try:
        if data is None:
            t = SdoUpload(index, sub, complete_access, size, counter)
        else:
            t = SdoDownload(index, sub, data, complete_access, size, counter)
    except ValueError as exc:                # an SM0 too small for any SDO
        raise SdoToolError(f"slave {info.position}: {exc}") from None
    try:
        yield from sdo_job(channel, t, None, None, timeout)
    except ApplyError as exc:
        if exc.abort_code is not None:
            raise SdoToolError(f"slave {info.position}: {exc.message}",
                               abort_code=exc.abort_code) from None
        raise SdoToolError(f"slave {info.position}, {what}: {exc}") from None
    result.append(t.result if isinstance(t, SdoUpload) else b"")


class MailboxCounter:
    """Mailbox counters for one transfer: 0 first (never taken for a repeat), then 1..7."""

    def __init__(self) -> None:
        self.last: int | None = None

    def __call__(self) -> int:
        self.last = 0 if self.last is None else self.last % 7 + 1
        return self.last


# -- preparing the slave ----------------------------------------------------------------------

def access(dg: Datagram, deadline: float, what: str, wkc: int = 1) -> Step[Datagram]:
    """Send ``dg`` until it comes back with working counter ``wkc``; the returned datagram."""
    last = "no reply (frames lost)"
    while True:
        reply = yield [dg]
        if reply is not None:
            if reply[0].wkc == wkc:
                return reply[0]
            last = f"working counter {reply[0].wkc}, expected {wkc}"
        if monotonic() > deadline:
            raise SdoToolError(f"{what}: {last}")


def _prepare(info: SlaveMailbox) -> Job:
    pos = info.position
    adp = -pos & 0xFFFF
    who = f"slave {pos}"
    deadline = monotonic() + TIMEOUT_COMMAND
    status = yield from access(Datagram.physical(Cmd.APRD, adp, Reg.AL_STATUS, 6), deadline,
                                f"{who}: reading the AL status (0x0130)")
    al_status = struct.unpack_from("<H", status.data)[0]
    info.state_before = al_status
    state = al_status & AL_STATE_MASK
    if state == AlState.BOOT:
        raise SdoToolError(f"{who} is in BOOT; {info.protocol} needs PREOP, SAFEOP or OP "
                           "(request INIT first)")

    # The mailbox from the SII, read while the EEPROM belongs to EtherCAT (0x0500 = 0);
    # a slave that is past INIT gets it back as it was (its PDI may be using it).
    owner = yield from access(Datagram.physical(Cmd.APRD, adp, Reg.EEPROM_CONFIG, 1),
                               deadline, f"{who}: reading the SII EEPROM owner (0x0500)")
    pdi_owned = bool(owner.data[0] & 0x01)
    yield from access(Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONFIG, b"\x00"),
                       deadline, f"{who}: taking the SII EEPROM (0x0500)")
    sii_deadline = monotonic() + TIMEOUT_COMMAND
    try:
        mbx = yield from sii_words(pos, SII_STD_MAILBOX, sii_deadline)
        proto = yield from sii_words(pos, SII_MAILBOX_PROTOCOLS, sii_deadline)
    except ApplyError as exc:
        raise SdoToolError(str(exc)) from None
    rx_start, rx_size, tx_start, tx_size = struct.unpack("<4H", mbx)
    info.protocols = protocols = struct.unpack_from("<H", proto)[0]
    if not protocols & MAILBOX_PROTOCOL_BITS[info.protocol]:
        if pdi_owned:
            yield from access(Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONFIG, b"\x01"),
                               deadline, f"{who}: handing the SII EEPROM back (0x0500)")
        thing = "SDO" if info.protocol == "CoE" else "IDN" if info.protocol == "SoE" else "data"
        raise SdoToolError(f"{who} does not support {info.protocol}: its SII lists the "
                           f"mailbox protocols 0x{protocols:04X} ({protocol_names(protocols)}), "
                           f"so there is no {thing} to read or write")

    address = yield from station_address_of(info, adp, who)
    info.station_address = address

    if state in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        deadline = monotonic() + TIMEOUT_COMMAND
        regs = yield from access(Datagram.physical(Cmd.FPRD, address, Reg.SM0, 16),
                                  deadline, f"{who}: reading SM0/SM1 (0x0800)")
        sm0 = SmConfig.from_bytes(regs.data[:8])
        sm1 = SmConfig.from_bytes(regs.data[8:16])
        if _is_mailbox(sm0, True) and _is_mailbox(sm1, False):
            if pdi_owned:
                yield from access(Datagram.physical(Cmd.FPWR, address, Reg.EEPROM_CONFIG,
                                                     b"\x01"),
                                   deadline, f"{who}: handing the SII EEPROM back to the "
                                             "PDI (0x0500)")
            info.send, info.recv, info.state = sm0, sm1, state
            return
        if state != AlState.PREOP or not al_status & AL_STATUS_ERROR:
            raise SdoToolError(f"{who} is in {AlState(state).name} but SM0/SM1 are not "
                               f"configured as its mailbox (SM0 {_sm_text(sm0)}, SM1 "
                               f"{_sm_text(sm1)}); bring it to INIT first")
    # Below PREOP (or PREOP+ERR without a mailbox): configure it from the SII.
    if not rx_size or not tx_size:
        raise SdoToolError(f"{who}: the SII gives no standard mailbox (word 0x18: receive "
                           f"0x{rx_start:04X}/{rx_size}, word 0x1A: send "
                           f"0x{tx_start:04X}/{tx_size})")
    if rx_size < NORMAL_OVERHEAD + 1:
        raise SdoToolError(f"{who}: a {rx_size}-byte receive mailbox cannot carry an SDO")
    sm0 = SmConfig(rx_start, rx_size, SM_CONTROL_MBOX_OUT, True)
    sm1 = SmConfig(tx_start, tx_size, SM_CONTROL_MBOX_IN, True)
    deadline = monotonic() + TIMEOUT_COMMAND
    if state != AlState.INIT:
        # PREOP+ERR without a mailbox: back to INIT before the SMs change.
        yield from request_state(address, AlState.INIT, who)
    yield from access(Datagram.physical(Cmd.FPWR, address, Reg.SM0,
                                         sm0.to_bytes() + sm1.to_bytes()),
                       deadline, f"{who}: writing SM0/SM1 (0x0800)")
    yield from access(Datagram.physical(Cmd.FPWR, address, Reg.EEPROM_CONFIG, b"\x01"),
                       deadline, f"{who}: handing the SII EEPROM to the PDI (0x0500)")
    yield from request_state(address, AlState.PREOP, who)
    info.send, info.recv, info.state, info.configured = sm0, sm1, AlState.PREOP, True


def _is_mailbox(sm: SmConfig, master_writes: bool) -> bool:
    direction = SM_DIR_ECAT_WRITES if master_writes else SM_DIR_ECAT_READS
    return (sm.enable and sm.length > 0 and sm.control & SM_MODE_MASK == SM_MODE_MAILBOX
            and sm.control & SM_DIR_MASK == direction)


def _sm_text(sm: SmConfig) -> str:
    return (f"0x{sm.start:04X}/{sm.length} control 0x{sm.control:02X}"
            f"{' enabled' if sm.enable else ' disabled'}")


def station_address_of(info: SlaveMailbox, adp: int, who: str) -> Step[int]:
    """The slave's configured station address; it gets one when it has none."""
    deadline = monotonic() + TIMEOUT_COMMAND
    reply = yield from access(Datagram.physical(Cmd.APRD, adp, Reg.STATION_ADDRESS, 2),
                               deadline, f"{who}: reading the station address (0x0010)")
    address: int = struct.unpack("<H", reply.data)[0]
    if address:
        # Fixed addressing must reach this slave alone.
        probe = Datagram.physical(Cmd.FPRD, address, Reg.STATION_ADDRESS, 2)
        while True:
            back = yield [probe]
            if back is not None:
                break
            if monotonic() > deadline:
                raise SdoToolError(f"{who}: no answer to FPRD 0x{address:04X}")
        if back[0].wkc != 1:
            raise SdoToolError(f"{who} has station address 0x{address:04X}, which "
                               f"{back[0].wkc} slaves answer to; give the slaves unique "
                               "addresses (ecatcfg apply) or power the line off and on")
        return address
    for candidate in range(FIRST_STATION_ADDRESS + info.position + 1, 0xFFFF):
        probe = Datagram.physical(Cmd.FPRD, candidate, Reg.STATION_ADDRESS, 2)
        while True:
            back = yield [probe]
            if back is not None:
                break
            if monotonic() > deadline:
                raise SdoToolError(f"{who}: no answer while choosing a station address")
        if back[0].wkc == 0:
            break
    else:                                               # pragma: no cover (65000 slaves)
        raise SdoToolError(f"{who}: no free station address")
    yield from access(Datagram.physical(Cmd.APWR, adp, Reg.STATION_ADDRESS,
                                         struct.pack("<H", candidate)),
                       deadline, f"{who}: writing station address 0x{candidate:04X}")
    return candidate


def request_state(address: int, target: AlState, who: str) -> Job:
    """AL control = target | acknowledge; wait until AL status shows it (or a refusal)."""
    deadline = monotonic() + TIMEOUT_COMMAND
    yield from access(Datagram.physical(Cmd.FPWR, address, Reg.AL_CONTROL,
                                         struct.pack("<H", target | AL_ERROR_ACK)),
                       deadline, f"{who}: requesting {target.name} (0x0120)")
    data = yield from awaited_al_status(
        Datagram.physical(Cmd.FPRD, address, Reg.AL_STATUS, 6), target, TIMEOUT_STATE)
    if data is None:
        raise SdoToolError(f"{who}: no answer to AL status reads (0x0130)")
    al_status, _, code = struct.unpack_from("<HHH", data)
    if al_status & 0x1F != target:
        raise _refused(who, target, al_status, code,
                       timed_out=not al_status & AL_STATUS_ERROR)


def _refused(who: str, target: AlState, al_status: int, code: int,
             timed_out: bool = False) -> SdoToolError:
    text = f"{who} refused {target.name}: it stays in {al_state_name(al_status)}"
    if code or al_status & AL_STATUS_ERROR:
        text += f", AL status code 0x{code:04X} ({al_status_name(code)})"
    if timed_out:
        text += f" (after {TIMEOUT_STATE:g} s)"
    return SdoToolError(text, al_code=code)


def empty_sm1(info: SlaveMailbox, channel: MailboxChannel) -> Job:
    """Take out the messages an earlier transfer left for SM1 (a slave may have queued more
    than one, e.g. two answers to a request that was written twice)."""
    deadline = monotonic() + TIMEOUT_COMMAND
    who = f"slave {info.position}"
    status_dg = Datagram.physical(Cmd.FPRD, channel.address, SM1_STATUS, 3)
    recv = channel.plan.recv
    read = Datagram.physical(Cmd.FPRD, channel.address, recv.start, recv.length)
    for _ in range(STALE_MESSAGES):
        status = yield from access(status_dg, deadline,
                                    f"{who}: reading the SM1 status (0x080D)")
        if not status.data[0] & SM_STATUS_MAILBOX_FULL:
            return
        info.stale_messages += 1
        # Any reply will do: a read whose frame was lost on the way back may have emptied
        # SM1 already, and then the next one gets working counter 0.
        while True:
            reply = yield [read]
            if reply is not None:
                break
            if monotonic() > deadline:
                raise SdoToolError(f"{who}: emptying SM1: no reply (frames lost)")
    raise SdoToolError(f"{who}: SM1 does not stop filling ({STALE_MESSAGES} messages "
                       "read): is another master using this slave's mailbox?")


__all__ = ["MailboxCounter", "SdoToolError", "SlaveMailbox", "abort_name", "access",
           "empty_sm1", "mailbox_session", "open_mailbox", "parse_address", "protocol_names",
           "request_state", "sdo_transfer", "station_address_of"]
