"""Replaying an ENI's InitCmds: one job per command (register, CoE, EoE).

The ENI says what to send (Cmd, Adp/Ado or Addr, Data or DataLength) and what must come
back: ``Cnt`` (the working counter; resent up to ``Retries`` times otherwise) and
``Validate`` (data under a mask; polled until it matches or its timeout runs out).  Where
the file gives no timeout (ours carry them only in Validate), the defaults below apply.
A frame that is lost is sent again until the command's timeout; register writes are
idempotent and mailbox messages carry a counter, so resending is safe.

How a slave's commands of one transition are chained is ``transition.py``.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, TypeVar

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import (CoeInitCmd, EoeInitCmd, FoeInitCmd, InitCmd, MailboxPlan,
                              NetworkPlan, SoeInitCmd)
from ecatcfg.eni.compare import compared, matches
from ecatcfg.eni.mailbox_states import state_bits
from ecatcfg.eni.words import init_cmd_name
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (AL_STATUS_ERROR, SM1_STATUS, SM_ACTIVATE_REPEAT, SM_PDI_REPEAT_ACK,
                         SM_STATUS_MAILBOX_FULL, Cmd, Reg, al_state_name, al_status_name)
from ecatcfg.record import record
from ecatcfg.runtime.master.lockstep import Job, Step, until_answered
from ecatcfg.runtime.wire import Datagram, datagram_for

if TYPE_CHECKING:     # imported where used: only ENIs with CoE InitCmds need the SDO client
    from ecatcfg.runtime.mailbox import MailboxProtocolError, SdoAbort
    from ecatcfg.runtime.master.sdo_client import SdoDownload, SdoUpload
    from ecatcfg.runtime.master.sdo_info import SdoInfoRequest

Transaction = TypeVar("Transaction", bound="SdoDownload | SdoUpload | SdoInfoRequest")

# Defaults where the ENI gives no timeout (seconds).
TIMEOUT_COMMAND = 1.0          # a plain register command, lost frames included
TIMEOUT_STATE = 5.0            # an AL state check (SOEM waits 2 s, IgH 5 s)
TIMEOUT_VALIDATE = 0.5         # any other Validate without Timeout
TIMEOUT_MAILBOX = 3.0          # one SDO transfer or EoE request (SOEM: 700 ms per response)
RETRIES = 3                    # working-counter retries when Retries is not given
ERROR_GRACE = 0.02             # s an AL error flag must persist before we give up early
# Polling (Validate, SM1): the first polls go out at once (emulated and fast slaves answer
# within microseconds), then every POLL_INTERVAL, so a slow slave is not flooded.
FAST_POLLS = 3
POLL_INTERVAL = 0.001

REPEAT_AFTER = 0.05            # s SM1 must stay empty after a lost read before a repeat


class ApplyError(EcatcfgError):
    """A slave or command that did not do what the ENI expects.  ``init_cmd``: the slave's
    InitCmd (the plan's object) that failed, when one did; the :class:`Network` names its
    file and line from it (``eni/source.py``)."""

    def __init__(self, message: str, slave: str | None = None,
                 command: str | None = None, al_code: int | None = None,
                 abort_code: int | None = None) -> None:
        where = " ".join(x for x in (f"slave {slave!r}" if slave else "",
                                     f"[{command}]" if command else "") if x)
        super().__init__(f"{where}: {message}" if where else message)
        self.slave = slave
        self.command = command
        self.al_code = al_code
        self.abort_code = abort_code
        self.init_cmd: (InitCmd | CoeInitCmd | EoeInitCmd | SoeInitCmd | FoeInitCmd
                        | None) = None
        # Why, as read from the slaves afterwards (runtime/master/diagnose.py): one JSON
        # object per slave ("slave", "al_status_code", "cause": lines, and the values read).
        self.causes: list[dict[str, Any]] = []

    def add_cause(self, slave: str | None, cause: dict[str, Any], text: str) -> None:
        """Say the cause of ``slave``'s refusal under the message (and in JSON)."""
        self.causes.append({"slave": slave, **cause})
        self.message += f"\n  cause{f' ({slave})' if slave else ''}: {text}"
        self.args = (self.message,)


@record
class SlaveProgress:
    """What the report shows per slave: the last command run."""

    name: str
    last_command: str = ""


def pause(seconds: float) -> Job:
    """Let the other jobs' rounds go by for ``seconds`` without sending anything."""
    until = monotonic() + seconds
    while monotonic() < until:
        yield []


def _is_state_check(cmd: InitCmd) -> bool:
    return cmd.validate is not None and cmd.ado == Reg.AL_STATUS


def command_timeout(cmd: InitCmd) -> float:
    if cmd.timeout:
        return cmd.timeout / 1000
    if cmd.validate is not None:
        if cmd.validate.timeout:
            return cmd.validate.timeout / 1000
        return TIMEOUT_STATE if _is_state_check(cmd) else TIMEOUT_VALIDATE
    return TIMEOUT_COMMAND




def init_cmd_job(cmd: InitCmd, who: str | None, data: bytes | None = None,
                 progress: SlaveProgress | None = None) -> Job:
    """Send one InitCmd until its working counter and Validate are satisfied."""
    what = init_cmd_name(cmd)
    if progress is not None:
        progress.last_command = what
    dg = datagram_for(cmd, data if data is not None else
                      cmd.data if cmd.data is not None else bytes(cmd.length))
    deadline = monotonic() + command_timeout(cmd)
    retries = RETRIES if cmd.retries is None else cmd.retries
    wrong_wkc = 0
    polls = 0
    error_since: float | None = None
    last = "no reply (frames lost)"
    while True:
        reply = yield [dg]
        now = monotonic()
        if reply is not None:
            got = reply[0]
            if cmd.cnt is not None and got.wkc > cmd.cnt:
                # More slaves answered than the ENI expects (two with one station address
                # or alias, a logical window mapped twice): no resend can change that.
                raise ApplyError(f"working counter {got.wkc}, expected {cmd.cnt}: more "
                                 "slaves answered than the ENI expects (two slaves with "
                                 "one address?)", who, what)
            if cmd.cnt is not None and got.wkc != cmd.cnt:
                wrong_wkc += 1
                last = f"working counter {got.wkc}, expected {cmd.cnt}"
                if wrong_wkc > retries:
                    raise ApplyError(f"{last} ({wrong_wkc} attempts)", who, what)
            elif cmd.validate is not None and not matches(got.data, cmd.validate):
                last = (f"read {got.data.hex()}, expected "
                        f"{compared(cmd.validate.compare)}{cmd.validate.data.hex()}") + (
                    f" under mask {cmd.validate.mask.hex()}" if cmd.validate.mask else "")
                if _is_state_check(cmd) and len(got.data) >= 2 \
                        and got.data[0] & AL_STATUS_ERROR \
                        and not cmd.validate.data[0] & AL_STATUS_ERROR:
                    # The slave refused the state: an error flag that stays is final.
                    error_since = error_since or now
                    if now - error_since >= ERROR_GRACE:
                        raise _refused(got.data, who, what)
                else:
                    error_since = None
                polls += 1
                if polls > FAST_POLLS and now < deadline:
                    yield from pause(POLL_INTERVAL)
            else:
                return
        if now > deadline:
            if _is_state_check(cmd) and reply is not None and len(reply[0].data) >= 6:
                raise _refused(reply[0].data, who, what, timed_out=True)
            raise ApplyError(f"{last} after {command_timeout(cmd):g} s", who, what)


def _refused(status: bytes | bytearray, who: str | None, comment: str,
             timed_out: bool = False) -> ApplyError:
    al_status, = struct.unpack_from("<H", status, 0)
    code = struct.unpack_from("<H", status, 4)[0] if len(status) >= 6 else None
    text = f"slave stays in {al_state_name(al_status)}"
    if code is None:
        # An ENI whose state check reads 0x0130 alone (2 bytes) never reads the code
        # (0x0134): saying 0x0000 "no error" would be a guess.  al_code None asks the
        # caller to read it (Network._explain).
        if al_status & AL_STATUS_ERROR:
            text += " (the ENI's check does not read the AL status code, 0x0134)"
    elif code or al_status & AL_STATUS_ERROR:
        text += f", AL status code 0x{code:04X} ({al_status_name(code)})"
    if timed_out:
        text += " (timed out)"
    return ApplyError(text, who, comment, al_code=code)


# -- mailbox ----------------------------------------------------------------------------------

@record
class MailboxStatePoll:
    """The LRD over the ENI's ``Master/MailboxStates`` area: one datagram reads the
    mailbox-full bits of every slave whose FMMU maps SM1's status there
    (``eni/mailbox_states.py``).  The channels of all slaves that wait for an answer yield
    this same object, and a round sends it once (``lockstep``): the polls of 64 drives
    cost one datagram of 8 bytes instead of 64 datagrams of 1 byte (TwinCAT's way)."""

    datagram: Datagram

    @classmethod
    def over(cls, area: tuple[int, int]) -> MailboxStatePoll:
        """The poll of ``area`` (StartAddr, Count slaves: one bit each)."""
        start, count = area
        return cls(Datagram.logical(Cmd.LRD, start, bytes((count + 7) // 8)))


@record
class MailboxChannel:
    """The master's side of one slave's mailbox: where SM0/SM1 are, the message counter
    and the repeat toggle (ETG.1000.4 mailbox repeat)."""

    address: int
    plan: MailboxPlan
    counter_value: int = 0
    sent_messages: int = 0
    last_received: int = 0       # counter of the slave's last message taken
    lost_reads: int = 0          # SM1 reads whose frame was lost (a message may be gone)
    # A request that goes with the SM1 reads of :meth:`receive`, behind them in the same
    # frame, before the reply read is taken (``mailbox_pipeline.py``): ``ahead_taken`` once
    # SM0 took it (working counter 1), ``ahead_tried`` once a frame carried it at all (a
    # lost frame may have delivered it).
    ahead: bytes | None = None
    ahead_taken: bool = False
    ahead_tried: bool = False
    # Where the slave's mailbox-full flag is read while an answer is awaited: bit
    # ``state_bit`` of the shared LRD ``poll``, else (None) SM1's own status byte.
    poll: MailboxStatePoll | None = None
    state_bit: int = 0

    def again(self) -> MailboxChannel:
        """The channel of this slave starting over (brought back: counters from the
        start), its mailbox-full flag read where it was."""
        return MailboxChannel(self.address, self.plan, poll=self.poll,
                              state_bit=self.state_bit)

    def _says_full(self, got: Datagram) -> bool:
        """Whether the poll's reply says the slave posted a message.  The LRD counts 1 for
        each slave whose FMMU mapped its bit; a slave that did not answer leaves its bit
        at 0 (as read), so a set bit is this slave's flag (ESC datasheet section I,
        FMMU; the ENI's bits are each one slave's: ``eni/mailbox_states.py``)."""
        if self.poll is None:
            return got.wkc == 1 and bool(got.data[0] & SM_STATUS_MAILBOX_FULL)
        bit = self.state_bit
        return got.wkc >= 1 and bool(got.data[bit // 8] >> bit % 8 & 1)

    def counter(self) -> int:
        """The next mailbox counter, 1..7 (0 means 'not used'; SOEM never sends it)."""
        self.counter_value = self.counter_value % 7 + 1
        return self.counter_value

    def send(self, message: bytes, deadline: float, who: str | None,
             what: str | None) -> Job:
        """Write one request into SM0 (the whole SM, so the ESC sees the buffer complete)."""
        yield from until_answered([self._sm0_write(message)], deadline, ApplyError(
            "the mailbox (SM0) did not take the request", who, what))
        self.sent_messages += 1

    def _sm0_write(self, message: bytes) -> Datagram:
        sm0 = self.plan.send
        return Datagram.physical(Cmd.FPWR, self.address, sm0.start,
                                 message.ljust(sm0.length, b"\x00")[:sm0.length])

    def send_ahead(self, message: bytes) -> None:
        """Let ``message`` go with the SM1 reads of the next :meth:`receive`, behind them in
        the same frame: the reply read and the next request cost one frame, not two.  The
        ESC works through a frame's datagrams in order (ETG.1000.4 4.2; ESC datasheet
        section I, "frame processing"), and the firmware only sees SM0 after the frame has
        passed, so the read in front returns the previous reply (or nothing), never this
        request's.  SM0 refuses the write while it is still full (working counter 0): it
        is then carried again with the next read."""
        self.ahead, self.ahead_taken, self.ahead_tried = message, False, False

    def settle_ahead(self, deadline: float, who: str | None, what: str | None) -> Job:
        """Make sure the request sent ahead is in the slave: written on its own if no read
        carried it into SM0 (a copy of one a lost frame delivered carries the same counter,
        which the slave drops as a repeat: ETG.1000.4 mailbox counter)."""
        if self.ahead is not None and not self.ahead_taken:
            yield from self.send(self.ahead, deadline, who, what)
        self.ahead = None

    def drop_ahead(self, deadline: float) -> Job:
        """After a refusal: take back the request sent ahead.  One no frame carried is just
        forgotten; one the slave may have is answered, and that answer is read and dropped
        (within ``deadline``), so SM1 holds no reply to it for whoever reads next."""
        if self.ahead is None:
            return
        tried = self.ahead_taken or self.ahead_tried
        self.ahead = None
        if tried:
            try:
                yield from self.receive(deadline, None, None)
            except ApplyError:
                pass                       # it never got in, or its answer is late: no harm

    def receive(self, deadline: float, who: str | None, what: str | None) -> Step[bytes]:
        """Read the slave's next message from SM1.  Reading an empty mailbox gets working
        counter 0 and changes nothing, so SM1 is read directly at first, instead of
        polling its status before.  While the answer is not there, the slave's bit of the
        ENI's MailboxStates area is polled with the LRD all slaves share
        (:class:`MailboxStatePoll`), else SM1's status byte (0x080D bit 3, mailbox full:
        ESC datasheet section II, SyncManager status), 1 byte where a read takes the whole
        SM1, so that the polls of many slow slaves share a frame; once it says full, SM1
        is read.  If a read's frame was lost, the
        message may have been taken out of SM1 on the way: when SM1 then stays empty for
        ``REPEAT_AFTER`` (a slow firmware may simply not have answered yet), the repeat
        toggle asks the slave to post its last message again (ETG.1000.4 mailbox
        repeat)."""
        sm1 = self.plan.recv
        read = Datagram.physical(Cmd.FPRD, self.address, sm1.start, sm1.length)
        status = self.poll.datagram if self.poll is not None else \
            Datagram.physical(Cmd.FPRD, self.address, SM1_STATUS, 1)
        direct = True          # read SM1 itself: at first, and once its status says full
        lost_at: float | None = None
        empty = 0
        while True:
            # A request sent ahead goes behind the read, but not after a lost frame: until
            # the reply it may have cost is back, no new answer may join the one awaited.
            ahead = self.ahead if not self.ahead_taken and lost_at is None else None
            first = read if direct else status
            reply = yield [first] if ahead is None else [first, self._sm0_write(ahead)]
            now = monotonic()
            if ahead is not None:
                self.ahead_tried = True
                if reply is not None and reply[1].wkc == 1:
                    self.ahead_taken = True
                    self.sent_messages += 1
            if not direct and reply is not None and self._says_full(reply[0]) and \
                    now <= deadline:
                direct = True
                continue
            if direct and reply is not None and reply[0].wkc == 1:
                message = bytes(reply[0].data)
                counter = message[5] >> 4 & 0x07 if len(message) >= 6 else 0
                if counter and counter == self.last_received:
                    # A repeat that came before the answer: the slave re-posted the
                    # message we already have (ETG.1000.4: equal counters are repeats).
                    # A slave that only ever shows that message (its SM1 never emptied:
                    # read shorter than the SM) must not keep the master here forever.
                    if now > deadline:
                        raise ApplyError("no mailbox response in time (SM1 keeps the "
                                         "previous message)", who, what)
                    continue
                self.last_received = counter
                return message
            if now > deadline:
                raise ApplyError("no mailbox response in time", who, what)
            lost_read = reply is None and direct        # a lost status poll took nothing
            direct = False
            if reply is None:
                if lost_read:
                    self.lost_reads += 1
                    lost_at = lost_at or now
            elif lost_at is not None and now - lost_at >= REPEAT_AFTER:
                yield from self._repeat(deadline, who, what)
                lost_at = None
            else:
                empty += 1
                if empty > FAST_POLLS:
                    yield from pause(POLL_INTERVAL)

    def _repeat(self, deadline: float, who: str | None, what: str | None) -> Job:
        """Toggle the repeat request (0x080E bit 1) from what the register holds, then wait
        for the slave's acknowledge in 0x080F bit 1."""
        # SM1 status, activate and PDI control: 3 bytes from 0x080D
        status = Datagram.physical(Cmd.FPRD, self.address, SM1_STATUS, 3)
        failed = ApplyError("mailbox repeat request failed", who, what)
        [got] = yield from until_answered([status], deadline, failed)
        value = got.data[1] ^ SM_ACTIVATE_REPEAT
        toggle = Datagram.physical(Cmd.FPWR, self.address, SM1_STATUS + 1,
                                   bytes([value]))
        yield from until_answered([toggle], deadline, failed)
        while True:                                  # the slave acknowledges the toggle
            reply = yield [status]
            if reply is not None and reply[0].wkc == 1 and \
                    bool(reply[0].data[2] & SM_PDI_REPEAT_ACK) == bool(value & SM_ACTIVATE_REPEAT):
                return
            if monotonic() > deadline:
                raise ApplyError("the slave did not acknowledge the mailbox repeat", who,
                                 what)


def mailbox_channels(plan: NetworkPlan) -> dict[str, MailboxChannel]:
    """The mailbox channel of each slave with a mailbox.  The slaves whose mailbox-full
    flag the ENI maps into ``Master/MailboxStates`` (``eni/mailbox_states.py``) poll it
    with one LRD they share; the others (no MailboxStates, no StatusBitAddr, or one the
    area does not hold: ``check`` rule ENI122) poll SM1's status byte."""
    bits = {b.slave: b.bit for b in state_bits(plan)[0]}
    area = plan.master.mailbox_states
    poll = MailboxStatePoll.over(area) if bits and area is not None else None
    return {s.name: MailboxChannel(s.phys_addr, s.mailbox,
                                   poll=poll if s.name in bits else None,
                                   state_bit=bits.get(s.name, 0))
            for s in plan.slaves if s.mailbox is not None}


def sdo_job(channel: MailboxChannel, transaction: Transaction, who: str | None,
            what: str | None, timeout: float = TIMEOUT_MAILBOX) -> Step[Transaction]:
    """One SDO transfer (``runtime/master/sdo_client.py`` transaction) through the mailbox."""
    from ecatcfg.runtime.mailbox import MailboxProtocolError, SdoAbort

    deadline = monotonic() + timeout
    request: bytes | None = transaction.first_request()
    try:
        while True:
            if request is not None:
                yield from channel.send(request, deadline, who, what)
            response = yield from channel.receive(deadline, who, what)
            request = transaction.on_response(response)
            if request is None and transaction.done:
                return transaction
    except (SdoAbort, MailboxProtocolError) as error:
        raise sdo_failure(error, who, what) from None


def sdo_failure(error: SdoAbort | MailboxProtocolError, who: str | None,
                what: str | None) -> ApplyError:
    """An SDO transfer's abort or protocol error as the slave's and command's error."""
    from ecatcfg.runtime.mailbox import SdoAbort

    if isinstance(error, SdoAbort):
        return ApplyError(str(error), who, what, abort_code=error.code)
    return ApplyError(f"mailbox protocol error: {error}", who, what)


def coe_init_cmd_job(channel: MailboxChannel, cmd: CoeInitCmd, who: str | None,
                     progress: SlaveProgress | None = None) -> Job:
    what = coe_init_cmd_what(cmd)
    if progress is not None:
        progress.last_command = what
    t = coe_transfer(channel, cmd, who, what)
    yield from sdo_job(channel, t, who, what, coe_init_cmd_timeout(cmd))


def coe_init_cmd_what(cmd: CoeInitCmd) -> str:
    return cmd.comment.strip() and cmd.comment or f"SDO 0x{cmd.index:04X}:{cmd.subindex:02X}"


def coe_init_cmd_timeout(cmd: CoeInitCmd) -> float:
    return cmd.timeout / 1000 if cmd.timeout else TIMEOUT_MAILBOX


def coe_transfer(channel: MailboxChannel, cmd: CoeInitCmd, who: str | None,
                 what: str) -> SdoUpload | SdoDownload:
    """The SDO transfer (``sdo_client.py``) of a CoE InitCmd, its counters the channel's."""
    from ecatcfg.runtime.master.sdo_client import SdoDownload, SdoUpload

    size = channel.plan.send.length
    try:
        if cmd.ccs == 2:                          # upload (rare in ENIs: a read check)
            return SdoUpload(cmd.index, cmd.subindex, cmd.complete_access, size,
                             channel.counter)
        return SdoDownload(cmd.index, cmd.subindex, cmd.data, cmd.complete_access, size,
                           channel.counter)
    except ValueError as exc:                     # the ENI's SM0 is too small for any SDO
        raise ApplyError(f"the mailbox cannot carry this SDO: {exc}", who, what) from None


def eoe_init_cmd_job(channel: MailboxChannel, cmd: EoeInitCmd, who: str | None,
                     progress: SlaveProgress | None = None) -> Job:
    """One EoE set IP parameter request and its response (ETG.1000.6 §5.7; IgH
    ``fsm_eoe.c``, SOEM ``ecx_EOEsetIp``; ``docs/protocol-notes.md`` §9).  The request goes
    with the EoE header whichever encoding the ENI wrote (``ecatcfg.eoe.decode_init_data``).
    CoE emergencies and EoE fragments (Ethernet frames the slave sends) that arrive before the
    response are set aside, as IgH files them apart by type; anything else fails."""
    from ecatcfg.eoe import FrameType, decode_frame, encode_set_ip_request, result_name
    from ecatcfg.runtime.mailbox import (Emergency, MailboxError, MailboxProtocolError,
                                         MbxType, decode, encode_mailbox)

    what = cmd.comment.strip() and cmd.comment or "EoE set IP parameter"
    if progress is not None:
        progress.last_command = what
    try:
        request = cmd.request
        payload = encode_set_ip_request(request.params, request.port)
    except ValueError as exc:                     # a plan not read from a file
        raise ApplyError(f"not an EoE set IP parameter request: {exc}", who, what) from None
    message = encode_mailbox(MbxType.EOE, payload, channel.counter())
    if len(message) > channel.plan.send.length:
        raise ApplyError(f"the mailbox (SM0, {channel.plan.send.length} bytes) cannot carry "
                         f"the EoE request ({len(message)} bytes)", who, what)
    deadline = monotonic() + (cmd.timeout / 1000 if cmd.timeout else TIMEOUT_MAILBOX)
    yield from channel.send(message, deadline, who, what)
    while True:
        response = yield from channel.receive(deadline, who, what)
        try:
            _header, content = decode(response)
        except MailboxProtocolError as exc:
            raise ApplyError(f"unreadable mailbox response to the EoE request: {exc}", who,
                             what) from None
        if isinstance(content, Emergency):
            continue
        if isinstance(content, MailboxError):
            raise ApplyError(f"the slave answered the EoE request with mailbox error "
                             f"{content.detail} ({content.name})", who, what)
        if not isinstance(content, tuple) or content[0] != MbxType.EOE:
            kind = content[0] if isinstance(content, tuple) else MbxType.COE
            raise ApplyError(f"mailbox type {kind} where an EoE response was expected",
                             who, what)
        try:
            frame = decode_frame(content[1])
        except ValueError as exc:
            raise ApplyError(f"unreadable EoE response: {exc}", who, what) from None
        if frame.type == FrameType.FRAGMENT:
            continue
        if frame.type != FrameType.SET_IP_RESPONSE:
            raise ApplyError(f"EoE frame type {frame.type} where a set IP parameter response "
                             f"(type {FrameType.SET_IP_RESPONSE:d}) was expected", who, what)
        if frame.info2:
            raise ApplyError(f"EoE set IP parameter refused: result 0x{frame.info2:04X} "
                             f"({result_name(frame.info2)})", who, what)
        return
