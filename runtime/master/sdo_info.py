"""The master's SDO Information client (ETG.1000.6 §5.6.3): a slave's object dictionary as
the slave describes it, with Get OD List, Get Object Description and Get Entry Description
(``ecatcfg od``).

:class:`SdoInfoRequest` is one request and its (fragmented) response, pure protocol logic
with the interface of the SDO transactions (``sdo_client.py``), so ``replay.sdo_job`` moves
its bytes (``od_tool.py`` walks a whole dictionary with it).  The byte layouts are the
shared codec's (``runtime/mailbox.py``), which the emulated slave's server uses too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from ecatcfg.runtime.mailbox import (
    ABORT_UNKNOWN_COMMAND, OD_LIST_ALL, Decoded, Emergency, EntryDescription, MailboxCounter,
    MailboxError, MailboxProtocolError, ObjectDescription, SdoAbort, SdoInfo, SdoInfoOpcode,
    decode, encode_entry_description_request, encode_object_description_request,
    encode_od_list_request, encode_sdo_info_error, pad_to,
)

CounterSource = Callable[[], int]
_RESPONSE = {
    SdoInfoOpcode.OD_LIST_REQUEST: SdoInfoOpcode.OD_LIST_RESPONSE,
    SdoInfoOpcode.OBJECT_DESCRIPTION_REQUEST: SdoInfoOpcode.OBJECT_DESCRIPTION_RESPONSE,
    SdoInfoOpcode.ENTRY_DESCRIPTION_REQUEST: SdoInfoOpcode.ENTRY_DESCRIPTION_RESPONSE,
}


class SdoInfoRequest:
    """One SDO information request; ``result`` is the response's service data, its
    fragments joined, once ``done``.  ``index``/``subindex`` name what is asked about in
    errors (0 for the OD list)."""

    def __init__(self, opcode: SdoInfoOpcode, index: int = 0, subindex: int = 0, *,
                 mbx_out_size: int = 128, counter: CounterSource | None = None,
                 list_type: int = OD_LIST_ALL) -> None:
        self.opcode = opcode
        self.index = index
        self.subindex = subindex
        self.list_type = list_type
        self.mbx_out_size = mbx_out_size
        self.counter: CounterSource = counter if counter is not None else MailboxCounter()
        self.emergencies: list[Emergency] = []
        self.done = False
        self._data = bytearray()
        self._fragments_left: int | None = None

    @property
    def result(self) -> bytes:
        if not self.done:
            raise RuntimeError("the SDO information response is not complete")
        return bytes(self._data)

    def first_request(self) -> bytes:
        counter = self.counter()
        if self.opcode == SdoInfoOpcode.OD_LIST_REQUEST:
            msg = encode_od_list_request(self.list_type, counter)
        elif self.opcode == SdoInfoOpcode.OBJECT_DESCRIPTION_REQUEST:
            msg = encode_object_description_request(self.index, counter)
        else:
            msg = encode_entry_description_request(self.index, self.subindex, 0, counter)
        return pad_to(msg, self.mbx_out_size)

    def abort_request(self, code: int) -> bytes:
        """An SDO information error for the slave (a client ends a fragmented response it
        cannot take with one, as SOEM does)."""
        self.done = True
        return pad_to(encode_sdo_info_error(code, self.counter()), self.mbx_out_size)

    def on_response(self, msg: bytes) -> bytes | None:
        """Digest one message from SM1; ``None``: nothing to send (the response is complete,
        or more fragments or the answer are still to come)."""
        content = self._info(msg)
        if content is None:
            return None
        code = content.abort_code
        if code is not None:
            self.done = True
            raise SdoAbort(code, self.index, self.subindex)
        if content.opcode != _RESPONSE[self.opcode]:
            raise self._fail(f"SDO information opcode {content.opcode} where "
                             f"{_RESPONSE[self.opcode]} was expected")
        if self._fragments_left is not None and content.fragments_left != \
                self._fragments_left - 1:
            raise self._fail(f"fragment with {content.fragments_left} left after one with "
                             f"{self._fragments_left}")
        self._fragments_left = content.fragments_left
        self._data += content.body
        if not content.incomplete:
            self.done = True
        return None

    def _info(self, msg: bytes) -> SdoInfo | None:
        try:
            _header, content = decode(msg)
        except MailboxProtocolError as error:
            raise self._fail(f"unreadable mailbox response: {error}") from None
        return self._coe(content)

    def _coe(self, content: Decoded) -> SdoInfo | None:
        if isinstance(content, MailboxError):
            self.done = True
            raise MailboxProtocolError(f"{self.what()}: the slave answered with mailbox "
                                       f"error {content.detail} ({content.name})",
                                       detail=content.detail)
        if isinstance(content, Emergency):
            self.emergencies.append(content)
            return None
        if not isinstance(content, SdoInfo):
            raise self._fail(f"{type(content).__name__} where an SDO information response "
                             "was expected")
        return content

    def what(self) -> str:
        if self.opcode == SdoInfoOpcode.OD_LIST_REQUEST:
            return "Get OD List"
        if self.opcode == SdoInfoOpcode.OBJECT_DESCRIPTION_REQUEST:
            return f"Get Object Description 0x{self.index:04X}"
        return f"Get Entry Description 0x{self.index:04X}:{self.subindex:02X}"

    def _fail(self, what: str) -> MailboxProtocolError:
        self.done = True
        return MailboxProtocolError(f"{self.what()}: {what}",
                                    abort_code=ABORT_UNKNOWN_COMMAND)


@dataclass(slots=True)
class DescribedObject:
    """One object as the slave describes it: the object description and its entries'."""

    description: ObjectDescription
    entries: dict[int, EntryDescription] = field(default_factory=dict)
    # Subindexes the slave answered with an SDO information error (abort code), e.g. the
    # gaps of a record numbered 0, 4, 5.
    missing: dict[int, int] = field(default_factory=dict)
    # With values uploaded (``od --values``): subindex -> the bytes the slave gave, or the
    # abort code it answered that entry's upload with; whether the values came by one
    # complete access.
    values: dict[int, bytes] = field(default_factory=dict)
    value_aborts: dict[int, int] = field(default_factory=dict)
    complete_access: bool = False
