"""The SDO Information server of an emulated CoE slave (ETG.1000.6 §5.6.3): Get OD List, Get
Object Description and Get Entry Description, answered from the slave's object dictionary
(built from its ESI, ``od_from_esi.py``).  The byte layouts are the shared codec's
(``runtime/mailbox.py``), which the master's client uses too.

As SOES answers (``SDO_getodlist``, ``SDO_getod``, ``SDO_geted``): an OD list longer than
SM1 goes in fragments, the first with the list type, the others with indices only; an
object or entry description is one message whose name is cut to what SM1 holds (SOEM's
client reads a description from one message, and Wireshark's dissector takes every
message of those opcodes for a whole description).

Choices where the sources are silent:

- the data type of a RECORD object is given as 0, as SOES gives it (the emulation keeps no
  record type index; a device may name one, e.g. 0x0023 for the identity); a VAR gives its
  own type, an ARRAY its elements' (SOES gives subindex 0's; CiA 301 describes an array
  by the type of its elements);
- the max subindex is the highest subindex the object has (SOES gives an array's or
  record's subindex 0 value, the entries in use), so a client describes every entry;
- an entry description carries none of the optional values (unit, default, minimum,
  maximum): the response's value info says so, whatever the request asked for;
- the backup and settings lists are empty (an ESI's Backup/Setting flags are not kept);
- other opcodes are answered with an SDO information error carrying abort 0x06010000, as
  SOES answers opcodes it does not implement.
"""

from __future__ import annotations

import struct

from ecatcfg.esc import AlState
from ecatcfg.esi.datatypes import coe_type
from ecatcfg.runtime.mailbox import (
    ABORT_NO_OBJECT, ABORT_NO_SUBINDEX, ABORT_UNSUPPORTED_ACCESS, ACCESS_READ_SHIFT,
    ACCESS_RXPDO, ACCESS_TXPDO, ACCESS_WRITE_SHIFT, OBJECT_CODE_ARRAY, OBJECT_CODE_RECORD,
    OBJECT_CODE_VAR, OD_LIST_ALL, OD_LIST_LENGTHS, OD_LIST_RXPDO_MAPPABLE,
    OD_LIST_TXPDO_MAPPABLE, SDO_INFO_OVERHEAD, EntryDescription, ObjectDescription, SdoInfo,
    SdoInfoOpcode, encode_sdo_info, encode_sdo_info_error, encode_sdo_info_fragments,
    od_list_data,
)
from ecatcfg.runtime.segment.od_entries import OdEntry, OdObject
from ecatcfg.runtime.segment.objects import ObjectDictionary

# The AL states in the order of the access word's read and write bits.
_ACCESS_STATES = (AlState.PREOP, AlState.SAFEOP, AlState.OP)


def access_word(entry: OdEntry) -> int:
    """The object access word of an entry description: read and write per state, and
    whether it maps into an RxPDO or a TxPDO."""
    word = 0
    for bit, state in enumerate(_ACCESS_STATES):
        if entry.readable(state):
            word |= 1 << (ACCESS_READ_SHIFT + bit)
        if entry.writable(state):
            word |= 1 << (ACCESS_WRITE_SHIFT + bit)
    if "R" in entry.mappable:
        word |= ACCESS_RXPDO
    if "T" in entry.mappable:
        word |= ACCESS_TXPDO
    return word


def object_description(obj: OdObject) -> ObjectDescription:
    if obj.variable:
        code, described = OBJECT_CODE_VAR, obj.entries.get(0)
    elif obj.array:
        code, described = OBJECT_CODE_ARRAY, obj.entries.get(1)
    else:
        code, described = OBJECT_CODE_RECORD, None
    dtype = coe_type(described.type) if described is not None else 0
    return ObjectDescription(obj.index, dtype, obj.max_subindex, code, obj.name)


def entry_description(index: int, entry: OdEntry) -> EntryDescription:
    return EntryDescription(index, entry.subindex, 0, coe_type(entry.type),
                            entry.bit_size, access_word(entry), entry.name)


class SdoInfoServer:
    """Answers SDO information requests from ``od`` in a ``mbx_in_size``-byte SM1."""

    def __init__(self, od: ObjectDictionary, mbx_in_size: int) -> None:
        self.od = od
        self.mbx_in_size = mbx_in_size

    def handle(self, msg: SdoInfo) -> list[bytes]:
        try:
            opcode, data = self._answer(msg)
        except _InfoError as error:
            return [encode_sdo_info_error(error.code)]
        if opcode == SdoInfoOpcode.OD_LIST_RESPONSE:
            return encode_sdo_info_fragments(opcode, data, self.mbx_in_size)
        return [encode_sdo_info(opcode, data[:self.mbx_in_size - SDO_INFO_OVERHEAD])]

    def _answer(self, msg: SdoInfo) -> tuple[int, bytes]:
        body = msg.body
        if msg.opcode == SdoInfoOpcode.OD_LIST_REQUEST and len(body) >= 2:
            list_type = struct.unpack_from("<H", body)[0]
            return SdoInfoOpcode.OD_LIST_RESPONSE, self._od_list(list_type)
        if msg.opcode == SdoInfoOpcode.OBJECT_DESCRIPTION_REQUEST and len(body) >= 2:
            obj = self._object(struct.unpack_from("<H", body)[0])
            return SdoInfoOpcode.OBJECT_DESCRIPTION_RESPONSE, object_description(obj).pack()
        if msg.opcode == SdoInfoOpcode.ENTRY_DESCRIPTION_REQUEST and len(body) >= 4:
            index, sub, _value_info = struct.unpack_from("<HBB", body)
            entry = self._object(index).entries.get(sub)
            if entry is None:
                raise _InfoError(ABORT_NO_SUBINDEX)
            return (SdoInfoOpcode.ENTRY_DESCRIPTION_RESPONSE,
                    entry_description(index, entry).pack())
        raise _InfoError(ABORT_UNSUPPORTED_ACCESS)

    def _object(self, index: int) -> OdObject:
        if index not in self.od:
            raise _InfoError(ABORT_NO_OBJECT)
        return self.od[index]

    def _od_list(self, list_type: int) -> bytes:
        lists = {
            OD_LIST_ALL: [o.index for o in self.od],
            OD_LIST_RXPDO_MAPPABLE: [o.index for o in self.od
                                     if any("R" in e.mappable for e in o.entries.values())],
            OD_LIST_TXPDO_MAPPABLE: [o.index for o in self.od
                                     if any("T" in e.mappable for e in o.entries.values())],
        }
        if list_type == OD_LIST_LENGTHS:
            counts = [len(lists.get(t, [])) for t in range(OD_LIST_ALL, OD_LIST_ALL + 5)]
            return struct.pack("<6H", list_type, *counts)
        if list_type > OD_LIST_ALL + 4:
            raise _InfoError(ABORT_UNSUPPORTED_ACCESS)
        return od_list_data(list_type, sorted(lists.get(list_type, [])))


class _InfoError(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code
