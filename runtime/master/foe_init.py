"""The FoE InitCmds of an ENI in apply's transitions (ENI ``Mailbox/FoE/InitCmds``), and
the loop that moves any FoE transfer through a slave's mailbox (``foe_tool.py`` uses it
too).

An FoE InitCmd's ``Data`` is one FoE message (ETG.2100 ``MailboxCmdType``: "data of the
mailbox cmd (excl. the mailbox)").  Apply runs read requests: it sends the request with the
file's name and password and reads the file to its end, acknowledging each data packet
(``foe_client.FoeRead``), so the slave's FoE state machine is idle again when the
transition goes on; the contents are not kept (an ENI has no place for them).  A refusal
(an FoE error, e.g. 0x8001 not found or 0x800A no rights) fails the transition with the
slave, the command and the code named.  Other FoE messages never reach here: the reader
refuses them (``eni/contents.py``).
"""

from __future__ import annotations


from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import FoeInitCmd
from ecatcfg.esc import FoeOpCode
from ecatcfg.runtime.master.foe_client import FoeRead, FoeTransferError, FoeWrite
from ecatcfg.runtime.master.lockstep import Job
from ecatcfg.runtime.master.replay import (TIMEOUT_COMMAND, TIMEOUT_MAILBOX, ApplyError,
                                           MailboxChannel, SlaveProgress)

# The most a read InitCmd takes from a slave: the file is read to its end and dropped.
READ_LIMIT = 16 * 1024 * 1024


def run_transfer(channel: MailboxChannel, t: FoeRead | FoeWrite, timeout: float,
                 who: str | None, what: str) -> Job:
    """Move the transfer's messages through the mailbox until it is done; each reply
    within ``timeout`` s.  Raises :class:`FoeTransferError`."""
    request: bytes | None = t.first_request()
    while True:
        if request is not None:
            yield from channel.send(request, monotonic() + TIMEOUT_COMMAND, who, what)
        if t.done:
            if t.wrong_number is not None:
                raise t.wrong_number
            return
        try:
            # Unnamed: the callers put the slave and the command in front of the
            # FoeTransferError's text, which would else name them twice.
            reply = yield from channel.receive(monotonic() + timeout, None, None)
        except ApplyError as exc:
            raise FoeTransferError(exc.message) from None
        request = t.on_response(reply)


def foe_init_cmd_job(channel: MailboxChannel, cmd: FoeInitCmd, who: str | None,
                     progress: SlaveProgress | None = None) -> Job:
    """One FoE read request InitCmd: the file read to its end."""
    what = cmd.comment.strip() or f"FoE read {cmd.file_name!r}"
    if progress is not None:
        progress.last_command = what
    if cmd.opcode != FoeOpCode.READ:            # a plan not read from a file
        raise ApplyError(f"FoE InitCmd with OpCode {cmd.opcode}: apply runs read requests "
                         "(1) only", who, what)
    size = channel.plan.send.length, channel.plan.recv.length
    try:
        t = FoeRead(cmd.file_name, cmd.password, mbx_out_size=size[0], mbx_in_size=size[1],
                    counter=channel.counter, limit=READ_LIMIT)
    except ValueError as exc:
        raise ApplyError(str(exc), who, what) from None
    timeout = cmd.timeout / 1000 if cmd.timeout else TIMEOUT_MAILBOX
    try:
        yield from run_transfer(channel, t, timeout, who, what)
    except FoeTransferError as exc:
        raise ApplyError(f"FoE read of {cmd.file_name!r}: {exc}", who, what) from None
