"""One SoE read or write with one drive of a line no other master is driving
(``ecatcfg soe``).

The slave is prepared as for ``ecatcfg sdo`` (``sdo_tool.mailbox_session``: its mailbox
from its SII, brought to PREOP if it is below, SM1 emptied), but the SII must list SoE
(word 0x1C bit 4) instead of CoE; then one :class:`~ecatcfg.runtime.master.soe_client.
SoeTransfer` goes through the mailbox.  The slave stays in the state it was brought to.
"""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.esi.idn import idn_text
from ecatcfg.runtime.master.lockstep import Job
from ecatcfg.runtime.master.replay import TIMEOUT_MAILBOX, ApplyError, MailboxChannel
from ecatcfg.runtime.master.sdo_tool import SdoToolError, SlaveMailbox, mailbox_session
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.soe import ELEMENT_ATTRIBUTE, ELEMENT_VALUE, fragment_sizes


class SoeToolError(SdoToolError):
    """The transfer could not be done; ``soe_error`` is the drive's SoE error code when it
    answered with one."""

    def __init__(self, message: str, soe_error: int | None = None,
                 al_code: int | None = None) -> None:
        super().__init__(message, al_code=al_code)
        self.soe_error = soe_error


def soe_transfer(transport: Transport, position: int, idn: int, data: bytes | None = None,
                 *, drive_no: int = 0, elements: int = ELEMENT_VALUE,
                 timeout: float = TIMEOUT_MAILBOX,
                 info: SlaveMailbox | None = None) -> bytes:
    """Read (``data is None``) or write ``data`` to ``idn`` of drive ``drive_no`` of the
    slave at ``position``; returns what a read got (``b""`` for a write).  Raises
    :class:`SoeToolError` (with ``soe_error`` when the drive refused), or the preparation's
    :class:`SdoToolError`."""
    from ecatcfg.runtime.master.soe_client import SoeRefused, SoeTransfer, soe_job

    info = info if info is not None else SlaveMailbox(position)
    info.protocol = "SoE"
    result: list[bytes] = []
    what = f"SoE {'read' if data is None else 'write'} {idn_text(idn)} (drive {drive_no})"

    def work(channel: MailboxChannel, size: int, counter: Callable[[], int]) -> Job:
        try:
            transfer = SoeTransfer(idn, data, drive_no=drive_no, elements=elements,
                                   mbx_out_size=size, counter=counter)
        except ValueError as exc:
            raise SoeToolError(f"slave {position}: {exc}") from None
        if data is not None and len(fragment_sizes(len(data), size)) > 1:
            # The session's first message goes with counter 0, which a slave never takes
            # for a repeat (sdo_tool): a first fragment sent again after a lost frame
            # would then be taken twice and break the write.  A read goes first instead
            # (its answer, an error too, does not matter), so the fragments count 1..7.
            try:
                yield from soe_job(channel, SoeTransfer(idn, drive_no=drive_no,
                                                        elements=ELEMENT_ATTRIBUTE,
                                                        mbx_out_size=size, counter=counter),
                                   None, None, timeout)
            except SoeRefused:
                pass
        try:
            yield from soe_job(channel, transfer, None, None, timeout)
        except SoeRefused as exc:
            raise SoeToolError(f"slave {position}: {exc.message}",
                               soe_error=exc.soe_error) from None
        except ApplyError as exc:
            raise SoeToolError(f"slave {position}, {what}: {exc.message}") from None
        result.append(transfer.result if data is None else b"")

    mailbox_session(transport, position, work, info)
    return result[0]


__all__ = ["SoeToolError", "soe_transfer"]
