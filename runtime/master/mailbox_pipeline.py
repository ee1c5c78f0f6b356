"""A slave's CoE InitCmds of one transition with the next request ahead: one frame per
start-up write where one after the other took two.

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

- the transfer out has sent its last request: an expedited download, or a normal one whose
  data all went in the first message (a segment depends on the answer to the segment before:
  ETG.1000.6 5.6.2.3, the toggle; an upload may turn into segments), and
- the next command addresses another object: download responses and aborts echo the index
  and subindex (ETG.1000.6 5.6.2.2, 5.6.2.7), which tell the two answers apart.

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

import time

from ecatcfg.eni.plan import CoeInitCmd
from ecatcfg.runtime.mailbox import (Abort, DownloadResponse, MailboxProtocolError, SdoAbort,
                                     UploadResponse, decode)
from ecatcfg.runtime.master.lockstep import Job
from ecatcfg.runtime.master.replay import (ApplyError, MailboxChannel, SlaveProgress,
                                           coe_init_cmd_timeout, coe_init_cmd_what,
                                           coe_transfer, sdo_failure)
from ecatcfg.runtime.master.sdo_client import SdoDownload, SdoUpload

DROP_AHEAD_S = 0.2     # s the answer to a request ahead may take after a refusal (SOES
#                       demo firmware on a LAN9252: 37-40 ms, docs/timing.md)


def coe_init_cmds_job(channel: MailboxChannel, cmds: list[CoeInitCmd], who: str | None,
                      progress: SlaveProgress | None = None) -> Job:
    """Run ``cmds`` (one slave's CoE InitCmds of a transition, in order) through the
    slave's mailbox; an :class:`ApplyError` names the command that failed (``init_cmd``)."""
    i = 0
    strict_until = 0        # commands before this index go without a request ahead
    ahead: SdoDownload | SdoUpload | None = None    # cmds[i]'s transfer, its request out
    while i < len(cmds):
        cmd = failing = cmds[i]
        what = coe_init_cmd_what(cmd)
        if progress is not None:
            progress.last_command = what
        deadline = time.monotonic() + coe_init_cmd_timeout(cmd)
        again = False
        try:
            request: bytes | None = None
            if ahead is not None:
                t, ahead = ahead, None
                yield from channel.settle_ahead(deadline, who, what)
            else:
                t = coe_transfer(channel, cmd, who, what)
                request = t.first_request()
            nxt = cmds[i + 1] if strict_until <= i + 1 < len(cmds) else None
            while True:
                if request is not None:
                    yield from channel.send(request, deadline, who, what)
                if ahead is None and nxt is not None and _goes_ahead(t, cmd, nxt):
                    ahead = _transfer_ahead(channel, nxt, who)
                    if ahead is not None:
                        channel.send_ahead(ahead.first_request())
                response = yield from channel.receive(deadline, who, what)
                if ahead is not None and nxt is not None and _answers(response, nxt):
                    # The answer to ``cmd`` went with a lost frame; this one is the next
                    # command's.  Take it, then run the list again (module docstring).
                    channel.ahead = None
                    failing = nxt
                    ahead.on_response(response)
                    ahead, strict_until, again = None, len(cmds), True
                    break
                request = t.on_response(response)
                if request is None and t.done:
                    break
        except (SdoAbort, MailboxProtocolError, ApplyError) as error:
            yield from channel.drop_ahead(time.monotonic() + DROP_AHEAD_S)
            failure = error if isinstance(error, ApplyError) else sdo_failure(
                error, who, coe_init_cmd_what(failing))
            failure.init_cmd = failure.init_cmd or failing
            raise failure from None
        i = 0 if again else i + 1


def _goes_ahead(t: SdoDownload | SdoUpload, cmd: CoeInitCmd, nxt: CoeInitCmd) -> bool:
    """The next command's request may go before ``t``'s answer is read (module
    docstring)."""
    return (isinstance(t, SdoDownload) and t.last_request_out
            and (nxt.index, nxt.subindex) != (cmd.index, cmd.subindex))


def _transfer_ahead(channel: MailboxChannel, cmd: CoeInitCmd,
                    who: str | None) -> SdoDownload | SdoUpload | None:
    """The next command's transfer, or ``None`` when it cannot have one (its own turn
    then says why, naming it)."""
    try:
        return coe_transfer(channel, cmd, who, coe_init_cmd_what(cmd))
    except ApplyError:
        return None


def _answers(message: bytes, cmd: CoeInitCmd) -> bool:
    """``message`` is a CoE answer to ``cmd``'s object (an initiate response or an abort
    that echoes its index and subindex)."""
    try:
        _header, content = decode(message)
    except MailboxProtocolError:
        return False
    return (isinstance(content, (DownloadResponse, UploadResponse, Abort))
            and (content.index, content.subindex) == (cmd.index, cmd.subindex))
