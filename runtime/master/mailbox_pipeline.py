"""A slave's CoE or SoE InitCmds of one transition with the next request ahead: one frame
per start-up write where one after the other took two.

Written one after the other, every SDO costs a frame that writes the request into SM0 and
a frame that reads the answer from SM1 (the firmware needs time: a read in the frame of the
write finds SM1 empty).  An ENI's start-up list does not depend on the answers (each
InitCmd's request is fixed; the slave's answer only says whether it took it), so the next
request goes in the frame that reads the answer to the one before, behind that read
(:meth:`MailboxChannel.send_ahead`).  The ESC processes a frame's datagrams in order
(ETG.1000.4 4.2) and the firmware sees SM0 only after the frame has passed, so the read
returns the previous answer or nothing; SM0 takes the write when the firmware has taken the
request before (ESC datasheet section I, SyncManager mailbox mode: a write into a full
buffer is refused with working counter 0, and is then carried again with the next read).
The slave thus holds at most one request while its answer to the one before waits in SM1:
what a mailbox of one buffer each way allows.

A request goes ahead only when

- the transfer out has sent its last request: an expedited SDO download, or a normal one
  whose data all went in the first message (a segment depends on the answer to the segment
  before: ETG.1000.6 5.6.2.3, the toggle; an upload may turn into segments); an SoE write,
  whose fragments all went (the drive answers the last one only, ETG.1000.6 5.8), and
- the next command addresses another object: SDO download responses and aborts echo the
  index and subindex (ETG.1000.6 5.6.2.2, 5.6.2.7), SoE write responses and error replies
  the IDN and drive (ETG.1000.6 5.8.2), which tell the two answers apart.

A refusal (an abort) of the command before finds the next one's request already in the
slave, as a master that sends an ENI's whole list would: the transition fails on the refused
command either way; the answer to the request ahead is read and dropped
(:meth:`MailboxChannel.drop_ahead`), so nobody later takes it for theirs.

Loss: a frame lost on its way back may have taken the awaited answer out of SM1 and
delivered the request ahead.  The next request is then held back (``receive``), and the
answer that comes next is the awaited one (SM1 stays empty: the repeat toggle brings it
back, ETG.1000.4 mailbox repeat) or the one to the request ahead.  In the second case the
answer is gone for good (a repeat would post the newer answer again) and the outcome of the
command before is unknown.  Sending that one again alone is not safe (after a PDO
assignment's count, CiA 301 refuses its entries), so the slave's list of the transition
is run again from its first command, one request at a time: the list is made to be run
from any state the slave may be in (it is run again whenever the slave comes back to the
transition: ENIs clear an assignment's count before its entries), and a line that loses
frames is no place for requests ahead.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from ecatcfg.eni.plan import CoeInitCmd, SoeInitCmd
from ecatcfg.runtime.clock import monotonic
from ecatcfg.runtime.mailbox import (Abort, DownloadResponse, MailboxProtocolError, SdoAbort,
                                     UploadResponse, decode)
from ecatcfg.runtime.master.lockstep import Job
from ecatcfg.runtime.master.replay import (ApplyError, MailboxChannel, SlaveProgress,
                                           coe_init_cmd_timeout, coe_init_cmd_what,
                                           coe_transfer, sdo_failure)
from ecatcfg.runtime.master.sdo_client import SdoDownload, SdoUpload

DROP_AHEAD_S = 0.2     # s the answer to a request ahead may take after a refusal (SOES
#                       demo firmware on a LAN9252: 37-40 ms, docs/timing.md)


class Transfer(Protocol):
    """One InitCmd's transfer as the pipeline moves it."""

    what: str
    timeout: float

    @property
    def cmd(self) -> CoeInitCmd | SoeInitCmd:
        """The InitCmd, named by the error when it fails."""
        ...

    @property
    def key(self) -> tuple[int, ...]:
        """The object it addresses, as its answers echo it."""
        ...

    @property
    def done(self) -> bool: ...

    def start(self) -> list[bytes]:
        """The requests that open the transfer (made, with their mailbox counters, at the
        first call; the same list after).  Raises :class:`ApplyError` for a command that
        cannot be sent (made here, not when the transfer is, so that the slave's progress
        names the command first)."""
        ...

    def last_request_out(self) -> bool:
        """The answer to the request out ends the transfer or refuses it."""
        ...

    def on_response(self, message: bytes) -> bytes | None:
        """Digest one message from SM1: the next request, or ``None``."""
        ...

    def answers(self, message: bytes) -> bool:
        """``message`` is an answer about this transfer's object."""
        ...

    def failure(self, error: Exception) -> ApplyError | None:
        """The transfer's error (its protocol's, or an :class:`ApplyError` of the
        mailbox) as the slave's and command's; ``None`` if not its kind."""
        ...


def coe_init_cmds_job(channel: MailboxChannel, cmds: list[CoeInitCmd], who: str | None,
                      progress: SlaveProgress | None = None) -> Job:
    """Run ``cmds`` (one slave's CoE InitCmds of a transition, in order) through the
    slave's mailbox; an :class:`ApplyError` names the command that failed (``init_cmd``)."""
    yield from pipelined(channel, [_sdo_maker(channel, c, who) for c in cmds], who,
                         progress)


def pipelined(channel: MailboxChannel, transfers: list[Callable[[], Transfer]],
              who: str | None, progress: SlaveProgress | None = None) -> Job:
    """Run the transfers (each made when its turn comes or its request goes ahead) in
    order, each next one's request ahead where it may go (module docstring)."""
    i = 0
    strict_until = 0        # transfers before this index go without a request ahead
    ahead: Transfer | None = None    # transfers[i], made while the one before was out
    while i < len(transfers):
        again = False
        failing: Transfer | None = None
        try:
            t = ahead if ahead is not None else transfers[i]()
            ahead = None
            failing = t
            if progress is not None:
                progress.last_command = t.what
            deadline = monotonic() + t.timeout
            requests: list[bytes] = []
            if channel.ahead is not None:
                yield from channel.settle_ahead(deadline, who, t.what)
            else:
                requests = t.start()
            may_go = strict_until <= i + 1 < len(transfers)
            while True:
                for request in requests:
                    yield from channel.send(request, deadline, who, t.what)
                requests = []
                if may_go and ahead is None and t.last_request_out():
                    may_go = False
                    ahead = transfers[i + 1]()
                    opening = _opening(ahead) if ahead.key != t.key else []
                    if len(opening) == 1:
                        channel.send_ahead(opening[0])
                response = yield from channel.receive(deadline, who, t.what)
                if ahead is not None and channel.ahead is not None and \
                        ahead.answers(response):
                    # The answer to ``t`` went with a lost frame; this one is the next
                    # transfer's.  Take it, then run the list again (module docstring).
                    channel.ahead = None
                    failing = ahead
                    ahead.on_response(response)
                    ahead, strict_until, again = None, len(transfers), True
                    break
                follow = t.on_response(response)
                if follow is None and t.done:
                    break
                if follow is not None:
                    requests = [follow]
        except Exception as error:
            failure = failing.failure(error) if failing is not None else (
                error if isinstance(error, ApplyError) else None)
            if failure is None:
                raise
            yield from channel.drop_ahead(monotonic() + DROP_AHEAD_S)
            if failing is not None:
                failure.init_cmd = failure.init_cmd or failing.cmd
            raise failure from None
        i = 0 if again else i + 1


def _opening(t: Transfer) -> list[bytes]:
    """The requests that open ``t``; none when it cannot be made (its own turn then says
    why, naming it)."""
    try:
        return t.start()
    except ApplyError:
        return []


# -- CoE --------------------------------------------------------------------------------------

def _sdo_maker(channel: MailboxChannel, cmd: CoeInitCmd,
               who: str | None) -> Callable[[], Transfer]:
    return lambda: _Sdo(channel, cmd, who)


class _Sdo:
    """A CoE InitCmd's SDO transfer (``sdo_client.py``)."""

    def __init__(self, channel: MailboxChannel, cmd: CoeInitCmd, who: str | None) -> None:
        self.cmd = cmd
        self.who = who
        self.what = coe_init_cmd_what(cmd)
        self.timeout = coe_init_cmd_timeout(cmd)
        self.channel = channel
        self.transfer: SdoDownload | SdoUpload | None = None

    @property
    def key(self) -> tuple[int, ...]:
        return (self.cmd.index, self.cmd.subindex)

    @property
    def done(self) -> bool:
        return self.transfer is not None and self.transfer.done

    def start(self) -> list[bytes]:
        if self.transfer is None:
            self.transfer = coe_transfer(self.channel, self.cmd, self.who, self.what)
            self._opening = [self.transfer.first_request()]
        return self._opening

    def last_request_out(self) -> bool:
        t = self.transfer
        return isinstance(t, SdoDownload) and t.last_request_out

    def on_response(self, message: bytes) -> bytes | None:
        assert self.transfer is not None, "a response before the request"
        return self.transfer.on_response(message)

    def answers(self, message: bytes) -> bool:
        """An initiate response or an abort that echoes the index and subindex."""
        try:
            _header, content = decode(message)
        except MailboxProtocolError:
            return False
        return (isinstance(content, (DownloadResponse, UploadResponse, Abort))
                and (content.index, content.subindex) == self.key)

    def failure(self, error: Exception) -> ApplyError | None:
        if isinstance(error, (SdoAbort, MailboxProtocolError)):
            return sdo_failure(error, self.who, self.what)
        return error if isinstance(error, ApplyError) else None
