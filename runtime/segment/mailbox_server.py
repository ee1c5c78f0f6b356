"""The mailbox of an emulated slave: a message the master wrote into SM0 in, the answers
for SM1 out, whatever the protocol.

What every protocol shares is checked here, once, before any protocol sees the message, as
SOES ``ESC_mbxprocess`` does (``docs/protocol-notes.md`` §5):

- shorter than the 6-byte header: mailbox error 6 (size too short);
- a non-zero counter equal to the previous one: a repeat, dropped without an answer (SOES
  ``mbxincnt``);
- a length of 0 or one that runs past SM0: error 5 (invalid mailbox header);
- a channel other than 0: error 3 (invalid channel);
- a type the slave does not speak: error 2 (unsupported protocol), as SOES
  ``ESC_xoeprocess`` answers it.

Then the message's data (what follows the header, ``length`` bytes) goes to the protocol's
server: CoE to the SDO server (``sdo_server.py``), EoE to the EoE server
(``eoe_server.py``), SoE to the SoE server (``soe_server.py``), FoE to the FoE server
(``foe_server.py``).  In BOOT the mailbox is the
bootstrap one (its own SM0/SM1 sizes, ``boot_sizes``) and speaks FoE only: a boot loader
has nothing else (ETG.1000.6: BOOT is for firmware download over FoE), so any other type
gets error 2 (unsupported protocol).  A server answers with whole mailbox messages, or raises
:class:`MailboxProtocolError` with the detail of the mailbox error reply to send.  Every
answer leaves through here: it gets the slave's next counter (1..7, SOES
``ESC_claimbuffer``) and is padded to the SM1 length, because writing the last byte of SM1
is what marks the mailbox full (protocol-notes §3).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ecatcfg.esc import AlState
from ecatcfg.runtime.mailbox import (
    MBX_HEADER_SIZE, MailboxCounter, MailboxHeader, MailboxProtocolError, MbxErrorDetail,
    MbxType, encode_mailbox_error, pad_to,
)

if TYPE_CHECKING:     # built by runtime/segment/emulate.py for the slaves that speak them
    from ecatcfg.runtime.segment.eoe_server import EoeServer
    from ecatcfg.runtime.segment.foe_server import FoeServer
    from ecatcfg.runtime.segment.sdo_server import SdoServer
    from ecatcfg.runtime.segment.soe_server import SoeServer


class MailboxServer:
    """One slave's mailbox.  ``mbx_out_size`` / ``mbx_in_size``: the SM0 (master -> slave)
    and SM1 (slave -> master) lengths; ``coe`` / ``eoe`` / ``soe``: the protocol servers,
    ``None`` for a protocol the slave does not speak; ``foe`` with ``boot_sizes``, the
    bootstrap SM0/SM1 lengths (``None``: no bootstrap mailbox)."""

    def __init__(self, mbx_out_size: int, mbx_in_size: int, *, coe: SdoServer | None = None,
                 eoe: EoeServer | None = None, soe: SoeServer | None = None,
                 foe: FoeServer | None = None,
                 boot_sizes: tuple[int, int] | None = None) -> None:
        self.mbx_out_size = mbx_out_size
        self.mbx_in_size = mbx_in_size
        self.coe = coe
        self.eoe = eoe
        self.soe = soe
        self.foe = foe
        self.boot_sizes = boot_sizes
        self._counter = MailboxCounter()
        self._last_counter: int | None = None

    def reset(self) -> None:
        """The mailbox starts afresh (INIT -> PREOP): forget the last counter and whatever
        the protocols have in progress, as SOES does when it starts the mailbox."""
        self._last_counter = None
        for server in (self.coe, self.eoe, self.soe, self.foe):
            if server is not None:
                server.reset()

    def handle(self, request: bytes, state: AlState) -> list[bytes]:
        """The messages (headers included, padded to SM1) answering one mailbox message as
        the master wrote it into SM0 (the whole SM area, padding included)."""
        out_size, in_size = self.sizes(state)
        if len(request) < MBX_HEADER_SIZE:
            return [self._error(MbxErrorDetail.SIZE_TOO_SHORT, in_size)]
        header = MailboxHeader.unpack(request)
        if header.counter and header.counter == self._last_counter:
            return []
        self._last_counter = header.counter
        if header.length == 0 or header.length > min(len(request),
                                                     out_size) - MBX_HEADER_SIZE:
            return [self._error(MbxErrorDetail.INVALID_HEADER, in_size)]
        if header.channel != 0:
            return [self._error(MbxErrorDetail.INVALID_CHANNEL, in_size)]
        data = request[MBX_HEADER_SIZE:MBX_HEADER_SIZE + header.length]
        boot = state == AlState.BOOT
        try:
            if header.type == MbxType.FOE and self.foe is not None:
                replies = self.foe.handle(data, state, out_size, in_size)
            else:
                server: SdoServer | EoeServer | SoeServer | None = None
                if header.type == MbxType.COE and not boot:
                    server = self.coe
                elif header.type == MbxType.EOE and not boot:
                    server = self.eoe
                elif header.type == MbxType.SOE and not boot:
                    server = self.soe
                if server is None:
                    return [self._error(MbxErrorDetail.UNSUPPORTED_PROTOCOL, in_size)]
                replies = server.handle(data, state)
        except MailboxProtocolError as error:
            return [self._error(error.detail or MbxErrorDetail.SYNTAX, in_size)]
        return [self._out(reply, in_size) for reply in replies]

    def sizes(self, state: AlState) -> tuple[int, int]:
        """The SM0 and SM1 lengths of the mailbox in ``state``: the bootstrap mailbox's in
        BOOT."""
        if state == AlState.BOOT and self.boot_sizes is not None:
            return self.boot_sizes
        return self.mbx_out_size, self.mbx_in_size

    def _out(self, message: bytes, in_size: int) -> bytes:
        """``message`` with the slave's next counter, padded to SM1."""
        h = MailboxHeader.unpack(message)
        stamped = MailboxHeader(h.length, h.address, h.channel, h.priority, h.type,
                                self._counter())
        return pad_to(stamped.pack() + message[MBX_HEADER_SIZE:], in_size)

    def _error(self, detail: int, in_size: int) -> bytes:
        return self._out(encode_mailbox_error(detail), in_size)
