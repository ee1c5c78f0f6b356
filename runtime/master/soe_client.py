"""SoE client of the master: reading and writing a drive's IDNs over the mailbox
(ETG.1000.6 5.8; the layouts are ``runtime/soe.py``'s), and the replay of an ENI's SoE
InitCmds (``Mailbox/SoE/InitCmds``).

:class:`SoeTransfer` is the protocol logic without I/O, as ``sdo_client.py`` is for SDOs:
the messages to write into SM0 (one read request, or a write's fragments: data larger than
SM0 goes in several messages with Incomplete set, none of which the drive answers but the
last), and what the messages from SM1 mean (a read response, possibly in fragments put
together again; a write response; an error reply with its SoE error code).  :func:`soe_job`
moves the bytes through a :class:`MailboxChannel`, as ``sdo_job`` does (SOEM
``ecx_SoEread``/``ecx_SoEwrite``, IgH ``fsm_soe.c``).

CoE emergencies that arrive in between are set aside, as the SDO client does, and so is a
whole answer of the other kind (a read response while writing), left by a request the
slave took twice; a message of another protocol or a response for another IDN or drive
fails the transfer.
"""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import SoeInitCmd
from ecatcfg.eni.words import soe_init_cmd_name
from ecatcfg.esi.idn import MAX_DRIVE, idn_text
from ecatcfg.runtime.mailbox import (
    Emergency,
    MailboxError,
    MailboxHeader,
    MailboxProtocolError,
    MbxType,
    decode,
    pad_to,
)
from ecatcfg.runtime.master.lockstep import Job, Step
from ecatcfg.runtime.master.replay import (
    TIMEOUT_MAILBOX,
    ApplyError,
    MailboxChannel,
    SlaveProgress,
)
from ecatcfg.runtime.master.sdo_client import CounterSource
from ecatcfg.runtime.soe import (
    ELEMENT_VALUE,
    SOE_OVERHEAD,
    Reassembly,
    SoeError,
    SoeMessage,
    SoeOpCode,
    decode_soe,
    encode_fragments,
    encode_read_request,
)


def _stamped(message: bytes, counter: int) -> bytes:
    """``message`` with mailbox counter ``counter``."""
    h = MailboxHeader.unpack(message)
    return MailboxHeader(h.length, h.address, h.channel, h.priority, h.type,
                         counter).pack() + message[len(h.pack()):]


class SoeTransfer:
    """One SoE read (``data is None``) or write of ``idn`` of drive ``drive_no``: the
    ``elements`` flags say which parts (0x40 the value).  ``mbx_out_size``: SM0's length,
    which bounds each request fragment.  ``result`` is what a read returned."""

    def __init__(self, idn: int, data: bytes | None = None, *, drive_no: int = 0,
                 elements: int = ELEMENT_VALUE, mbx_out_size: int = 128,
                 counter: CounterSource | None = None) -> None:
        if not 0 <= drive_no <= MAX_DRIVE:
            raise ValueError(f"drive number {drive_no}: SoE addresses drives 0..7")
        if mbx_out_size < SOE_OVERHEAD + (1 if data else 0):
            raise ValueError(f"a {mbx_out_size}-byte SM0 cannot carry an SoE request")
        self.idn = idn
        self.data = data
        self.drive_no = drive_no
        self.elements = elements
        self.mbx_out_size = mbx_out_size
        self.counter = counter if counter is not None else (lambda: 0)
        self.emergencies: list[Emergency] = []
        self.stale: list[SoeMessage] = []
        self.done = False
        self.responses = 0               # SoE messages of the answer taken so far
        self.broken = ""                 # why the fragments of a read do not fit together
        self._reply = Reassembly()

    def restart(self) -> None:
        """Forget the answer so far, to ask again (a read is free of side effects)."""
        self.done = False
        self.responses = 0
        self.broken = ""
        self._reply = Reassembly()

    @property
    def action(self) -> str:
        return "reading" if self.data is None else "writing"

    @property
    def what(self) -> str:
        return f"{idn_text(self.idn)} of drive {self.drive_no}"

    @property
    def result(self) -> bytes:
        if not self.done:
            raise RuntimeError("the SoE transfer has not finished")
        return bytes(self._reply.data)

    def requests(self) -> list[bytes]:
        """The messages for SM0, in order, each padded to SM0's length."""
        if self.data is None:
            messages = [encode_read_request(self.idn, drive_no=self.drive_no,
                                            elements=self.elements)]
        else:
            messages = encode_fragments(SoeOpCode.WRITE_REQUEST, self.idn, self.data,
                                        self.mbx_out_size, drive_no=self.drive_no,
                                        elements=self.elements)
        return [pad_to(_stamped(m, self.counter()), self.mbx_out_size) for m in messages]

    def on_response(self, message: bytes) -> bool:
        """Digest one message from SM1; ``True`` once the transfer is done (a read's last
        fragment or a write's response), ``False`` while more is to come.  Raises
        :class:`SoeError` for an error reply, :class:`MailboxProtocolError` for anything
        that is not the answer."""
        try:
            _header, content = decode(message)
        except MailboxProtocolError as exc:
            raise self._fail(f"unreadable mailbox response: {exc}") from None
        if isinstance(content, Emergency):
            self.emergencies.append(content)
            return False
        if isinstance(content, MailboxError):
            self.done = True
            raise MailboxProtocolError(
                f"{self.what}: the slave answered with mailbox error {content.detail} "
                f"({content.name})", detail=content.detail)
        if not isinstance(content, tuple) or content[0] != MbxType.SOE:
            kind = content[0] if isinstance(content, tuple) else MbxType.COE
            raise self._fail(f"mailbox type {kind} where an SoE response was expected")
        soe = decode_soe(content[1])
        want = (SoeOpCode.READ_RESPONSE if self.data is None else SoeOpCode.WRITE_RESPONSE)
        if soe.error:
            # SOEM takes an error reply to a write with either response opcode.
            if soe.op_code in (want, SoeOpCode.READ_RESPONSE) and soe.error_code is not None:
                self.done = True
                raise SoeError(soe.error_code, self.idn, self.drive_no, self.action)
            raise self._fail(f"error reply with opcode {soe.op_code} and no error code")
        other = (SoeOpCode.WRITE_RESPONSE if self.data is None else SoeOpCode.READ_RESPONSE)
        if soe.op_code == other and not soe.incomplete:
            # The answer to an earlier request of the other kind that the slave took twice
            # (a first message with counter 0, sent again after a lost frame, is never
            # dropped as a repeat): set aside, as an emergency is.
            self.stale.append(soe)
            return False
        if soe.op_code != want or soe.drive_no != self.drive_no:
            raise self._fail(f"SoE opcode {soe.op_code} of drive {soe.drive_no} where "
                             f"opcode {want:d} of drive {self.drive_no} was expected")
        if not soe.incomplete and soe.idn != self.idn:
            raise self._fail(f"response for {idn_text(soe.idn)}")
        self.responses += 1
        if self.data is not None:
            self.done = True
            return True
        try:
            whole = self._reply.add(soe)
        except ValueError as exc:
            # Read on to the answer's last fragment, so that none of it is left in SM1.
            self.broken = self.broken or f"read response fragments: {exc}"
            whole = None if soe.incomplete else b""
        self.done = whole is not None
        return self.done

    def _fail(self, what: str) -> MailboxProtocolError:
        self.done = True
        return MailboxProtocolError(f"{self.what}: {what}")


class SoeRefused(ApplyError):
    """A drive answered with an SoE error code (``soe_error``)."""

    def __init__(self, message: str, slave: str | None, command: str | None,
                 soe_error: int) -> None:
        super().__init__(message, slave, command)
        self.soe_error = soe_error


def soe_job(channel: MailboxChannel, transfer: SoeTransfer, who: str | None,
            what: str | None, timeout: float = TIMEOUT_MAILBOX) -> Step[SoeTransfer]:
    """One SoE transfer through the slave's mailbox; SoE errors and protocol errors become
    an :class:`ApplyError` naming the slave, the IDN and the drive.

    A drive posts a long read response's fragments one after the other without being asked
    for each (unlike SDO segments).  An SM1 read whose frame is lost on the way back may
    have taken a fragment out of the mailbox, and the mailbox repeat only brings back a
    message when SM1 stays empty, not when the next fragment is already there: the
    fragments that arrive then may fit together without the lost one.  So a read during
    which an SM1 read was lost is asked again (until the timeout).  Fragments that do not
    fit together otherwise are the drive's error."""
    deadline = monotonic() + timeout
    try:
        while True:
            lost = channel.lost_reads
            for request in transfer.requests():
                yield from channel.send(request, deadline, who, what)
            while not transfer.on_response((yield from channel.receive(deadline, who,
                                                                       what))):
                pass
            if transfer.data is None and channel.lost_reads != lost:
                transfer.restart()
                continue
            if transfer.broken:
                raise MailboxProtocolError(f"{transfer.what}: {transfer.broken}")
            return transfer
    except SoeError as error:
        raise SoeRefused(str(error), who, what, error.code) from None
    except MailboxProtocolError as error:
        raise ApplyError(f"mailbox protocol error: {error}", who, what) from None


def soe_init_cmd_job(channel: MailboxChannel, cmd: SoeInitCmd, who: str | None,
                     transition: str, progress: SlaveProgress | None = None) -> Job:
    """One SoE InitCmd: the write request (op code 3, the only one ETG.2100 documents for
    ``Mailbox/SoE/InitCmds``) of its IDN, drive and elements.  An error names the IDN,
    the drive and the transition."""
    yield from soe_init_cmds_job(channel, [cmd], who, transition, progress)


def soe_init_cmds_job(channel: MailboxChannel, cmds: list[SoeInitCmd], who: str | None,
                      transition: str, progress: SlaveProgress | None = None) -> Job:
    """A drive's SoE InitCmds of a transition, in order, each write's request ahead of the
    answer to the one before where it may go (``mailbox_pipeline.py``)."""
    from ecatcfg.runtime.master.mailbox_pipeline import Transfer, pipelined

    def maker(cmd: SoeInitCmd) -> Callable[[], Transfer]:
        return lambda: _SoeWrite(channel, cmd, who, transition)
    yield from pipelined(channel, [maker(c) for c in cmds], who, progress)


class _SoeWrite:
    """An SoE InitCmd's write as ``mailbox_pipeline.pipelined`` moves it."""

    def __init__(self, channel: MailboxChannel, cmd: SoeInitCmd, who: str | None,
                 transition: str) -> None:
        self.cmd = cmd
        self.who = who
        self.transition = transition
        self.what = soe_init_cmd_name(cmd)
        self.timeout = cmd.timeout / 1000 if cmd.timeout else TIMEOUT_MAILBOX
        self.channel = channel
        self.transfer: SoeTransfer | None = None

    @property
    def key(self) -> tuple[int, ...]:
        return (self.cmd.idn, self.cmd.drive_no)

    @property
    def done(self) -> bool:
        return self.transfer is not None and self.transfer.done

    def start(self) -> list[bytes]:
        if self.transfer is None:
            cmd, transition = self.cmd, self.transition
            if cmd.op_code != SoeOpCode.WRITE_REQUEST:
                raise ApplyError(f"SoE InitCmd with op code {cmd.op_code}: only write "
                                 f"requests (op code 3) configure a drive (transition "
                                 f"{transition})", self.who, self.what)
            try:
                self.transfer = SoeTransfer(cmd.idn, cmd.data, drive_no=cmd.drive_no,
                                            elements=cmd.elements,
                                            mbx_out_size=self.channel.plan.send.length,
                                            counter=self.channel.counter)
            except ValueError as exc:
                raise ApplyError(f"{exc} (transition {transition})", self.who,
                                 self.what) from None
            self._opening = self.transfer.requests()
        return self._opening

    def last_request_out(self) -> bool:
        # A write's requests all go at its start; the drive answers the last one.
        return self.transfer is not None and not self.transfer.done

    def on_response(self, message: bytes) -> bytes | None:
        assert self.transfer is not None, "a response before the request"
        self.transfer.on_response(message)
        return None

    def answers(self, message: bytes) -> bool:
        """A write response or an error reply for this IDN of this drive."""
        try:
            _header, content = decode(message)
            if not isinstance(content, tuple) or content[0] != MbxType.SOE:
                return False
            soe = decode_soe(content[1])
        except (MailboxProtocolError, ValueError):
            return False
        return bool(soe.op_code == SoeOpCode.WRITE_RESPONSE or soe.error) and \
            (soe.idn, soe.drive_no) == self.key

    def failure(self, error: Exception) -> ApplyError | None:
        failure: ApplyError
        if isinstance(error, SoeError):
            failure = SoeRefused(str(error), self.who, self.what, error.code)
        elif isinstance(error, MailboxProtocolError):
            failure = ApplyError(f"mailbox protocol error: {error}", self.who, self.what)
        elif isinstance(error, ApplyError):
            failure = error
        else:
            return None
        if f"(transition {self.transition})" not in failure.message:
            failure.message += f" (transition {self.transition})"
            failure.args = (failure.message,)
        return failure


__all__ = ["SoeRefused", "SoeTransfer", "soe_init_cmd_job", "soe_init_cmds_job",
           "soe_job"]
