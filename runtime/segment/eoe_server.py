"""The EoE server of an emulated slave: the EoE messages the mailbox hands it
(``mailbox_server.py``, which checks the mailbox header first), the EoE messages to answer
(ETG.1000.6 §5.7; the layouts are ``ecatcfg/eoe.py``'s, sources in
``docs/protocol-notes.md`` §9).

It answers as SOES ``esc_eoe.c`` (``ESC_eoeprocess``), the open slave stack, does:

- **set IP parameter request** (type 2): the parameters it sets are stored, those it does
  not set keep their values (SOES ``EOE_set_ip``), and the response (type 3) carries result
  0.  A device whose ESI says ``<EoE IP="false">`` (ETG.2000) refuses a request that sets
  anything of the IP stack (address, mask, gateway, DNS) with result 0x0201 (no IP support)
  and stores nothing: the result SOES gives when the application has no IP stack.  A body
  that does not decode gets result 0x0001 (unspecified error).
- **get IP parameter request** (type 6): the response (type 7) carries the parameters
  stored so far, only those (SOES ``EOE_get_ip``).
- **fragments** (type 0) carry Ethernet frames: no tunnel is emulated, so they are dropped
  without an answer, as a slave answers no Ethernet frame it does not route anywhere.
  Whatever frame info 2 holds (fragment, offset and frame numbers) a fragment is never a
  request and never answered: SOES discards one out of sequence and hands a whole frame
  to its IP stack.
- **anything else**: a response of the request's own type with result 0x0002 (unsupported
  frame type), as SOES answers (the Beckhoff slave stack answers type 3 instead).
- shorter than the 4-byte EoE header: mailbox error 6 (size too short).

The port of the request is echoed; the emulation has one Ethernet port.
"""

from __future__ import annotations

from ecatcfg.eoe import (
    FrameType, IpParameters, Result, decode_frame, decode_ip_parameters, encode_get_ip_response,
    encode_response, encode_set_ip_response,
)
from ecatcfg.esc import AlState
from ecatcfg.esi.model import EoeSettings
from ecatcfg.runtime.mailbox import (MailboxProtocolError, MbxErrorDetail, MbxType,
                                     encode_mailbox)


class EoeServer:
    """EoE over one slave's mailbox.  ``settings``: the ESI's ``Mailbox/EoE`` attributes
    (``None``: the ESI gives none); ``mbx_in_size``: the SM1 length, which bounds a
    response."""

    def __init__(self, settings: EoeSettings | None, mbx_in_size: int) -> None:
        self.settings = settings
        self.mbx_in_size = mbx_in_size
        self.params: IpParameters | None = None     # what the master has set, if anything

    def reset(self) -> None:
        """The mailbox starts afresh (INIT -> PREOP): the IP parameters stay, as a device
        keeps its network settings while it is powered (SOES keeps ``nic_ports``)."""

    @property
    def ip_supported(self) -> bool:
        return self.settings is None or self.settings.ip is not False

    def handle(self, data: bytes, state: AlState) -> list[bytes]:
        """The messages answering one EoE message (``data``: what follows the mailbox
        header), as whole mailbox messages with counter 0 and no padding (the mailbox
        stamps and pads them)."""
        try:
            frame = decode_frame(data)
        except ValueError as exc:
            raise MailboxProtocolError(f"EoE: {exc}",
                                       detail=MbxErrorDetail.SIZE_TOO_SHORT) from None
        if frame.type == FrameType.FRAGMENT:
            return []
        if frame.type == FrameType.SET_IP_REQUEST:
            return [self._eoe(encode_set_ip_response(self._set_ip(frame.body), frame.port))]
        if frame.type == FrameType.GET_IP_REQUEST:
            reply = self._eoe(encode_get_ip_response(self.params or IpParameters(),
                                                     frame.port))
            if len(reply) > self.mbx_in_size:
                reply = self._eoe(encode_response(FrameType.GET_IP_RESPONSE,
                                                  Result.UNSPECIFIED_ERROR, frame.port))
            return [reply]
        return [self._eoe(encode_response(frame.type, Result.UNSUPPORTED_FRAME_TYPE,
                                          frame.port))]

    def _set_ip(self, body: bytes) -> int:
        """Store what a set IP parameter body sets; the result code to answer."""
        try:
            params = decode_ip_parameters(body)
        except ValueError:
            return Result.UNSPECIFIED_ERROR
        if params.sets_ip and not self.ip_supported:
            return Result.NO_IP_SUPPORT
        self.params = params if self.params is None else self.params.updated(params)
        return Result.SUCCESS

    @staticmethod
    def _eoe(payload: bytes) -> bytes:
        return encode_mailbox(MbxType.EOE, payload)
