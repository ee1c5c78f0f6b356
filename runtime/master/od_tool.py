"""A slave's object dictionary uploaded with SDO Information (``ecatcfg od``), and what
differs from its ESI dictionary.

The slave is prepared as for ``ecatcfg sdo`` (``sdo_tool.mailbox_session``: mailbox from
its SII, PREOP if it is below); then Get OD List (all objects), and for each object its
description and the description of each subindex 0 .. max subindex, the way SOEM's
``ecx_readODlist``/``ecx_readODdescription``/``ecx_readOE`` walk a dictionary
(ETG.1000.6 §5.6.3).  A subindex the slave answers with an SDO information error is a gap
(records numbered 0, 4, 5), kept with its abort code.
"""

from __future__ import annotations

from collections.abc import Callable

from ecatcfg.esi.coe import DictEntry, device_dictionary, lookup
from ecatcfg.esi.datatypes import canonical, coe_type, coe_type_name
from ecatcfg.esi.model import Device, pick_name
from ecatcfg.runtime.mailbox import (
    ACCESS_READ_SHIFT, ACCESS_WRITE_SHIFT, OBJECT_CODE_NAMES, EntryDescription,
    ObjectDescription, SdoInfoOpcode, decode_od_list,
)
from ecatcfg.runtime.master.lockstep import Job, Step
from ecatcfg.runtime.master.replay import TIMEOUT_MAILBOX, ApplyError, MailboxChannel, sdo_job
from ecatcfg.runtime.master.sdo_info import DescribedObject, SdoInfoRequest
from ecatcfg.runtime.master.sdo_tool import SdoToolError, SlaveMailbox, mailbox_session
from ecatcfg.runtime.master.transport import Transport

_STATES = ("PreOp", "SafeOp", "Op")


def upload_dictionary(transport: Transport, position: int, *,
                      timeout: float = TIMEOUT_MAILBOX,
                      info: SlaveMailbox | None = None) -> list[DescribedObject]:
    """The dictionary of the slave at ``position`` as it describes it.  Raises
    :class:`SdoToolError` (an SDO information error of the OD list or an object
    description carries ``abort_code``)."""
    result: list[DescribedObject] = []
    info = info if info is not None else SlaveMailbox(position)

    def work(channel: MailboxChannel, size: int, counter: Callable[[], int]) -> Job:
        try:
            result.extend((yield from read_dictionary(channel, size, counter, timeout)))
        except ApplyError as exc:
            raise SdoToolError(f"slave {position}: {exc}",
                               abort_code=exc.abort_code) from None

    mailbox_session(transport, position, work, info)
    return result


def read_dictionary(channel: MailboxChannel, mbx_out_size: int, counter: Callable[[], int],
                    timeout: float = TIMEOUT_MAILBOX) -> Step[list[DescribedObject]]:
    """The slave's whole dictionary over SDO Information (each request within
    ``timeout``)."""

    def ask(opcode: SdoInfoOpcode, index: int = 0, sub: int = 0) -> Step[bytes]:
        request = SdoInfoRequest(opcode, index, sub, mbx_out_size=mbx_out_size,
                                 counter=counter)
        done = yield from sdo_job(channel, request, None, request.what(), timeout)
        return done.result

    _list_type, indices = decode_od_list((yield from ask(SdoInfoOpcode.OD_LIST_REQUEST)))
    objects: list[DescribedObject] = []
    for index in indices:
        desc = ObjectDescription.unpack(
            (yield from ask(SdoInfoOpcode.OBJECT_DESCRIPTION_REQUEST, index)))
        obj = DescribedObject(desc)
        for sub in range(desc.max_subindex + 1):
            try:
                data = yield from ask(SdoInfoOpcode.ENTRY_DESCRIPTION_REQUEST, index, sub)
            except ApplyError as error:
                if error.abort_code is None:
                    raise
                obj.missing[sub] = error.abort_code
                continue
            obj.entries[sub] = EntryDescription.unpack(data)
        objects.append(obj)
    return objects


# -- words and JSON ----------------------------------------------------------------------------

def access_text(word: int) -> dict[str, list[str]]:
    """The states an access word lets an entry be read and written in."""
    return {"read": [s for k, s in enumerate(_STATES) if word >> (ACCESS_READ_SHIFT + k) & 1],
            "write": [s for k, s in enumerate(_STATES)
                      if word >> (ACCESS_WRITE_SHIFT + k) & 1]}


def access_short(word: int) -> str:
    """``ro``, ``rw``, ``wo`` or ``--`` from the access word, with the states when they
    are not all three (``rw(w:PreOp)``)."""
    states = access_text(word)
    mode = ("r" if states["read"] else "") + ("w" if states["write"] else "")
    mode = {"r": "ro", "w": "wo", "rw": "rw"}.get(mode, "--")
    if states["write"] and len(states["write"]) < 3:
        mode += f"(w:{','.join(states['write'])})"
    return mode


def as_json(objects: list[DescribedObject]) -> list[dict[str, object]]:
    out: list[dict[str, object]] = []
    for obj in objects:
        d = obj.description
        out.append({
            "index": d.index, "name": d.name, "object_code": d.object_code,
            "object": OBJECT_CODE_NAMES.get(d.object_code, str(d.object_code)),
            "data_type": d.data_type, "max_subindex": d.max_subindex,
            "entries": [{"subindex": e.subindex, "name": e.name, "data_type": e.data_type,
                         "type": coe_type_name(e.data_type), "bit_length": e.bit_length,
                         "access": e.access, **access_text(e.access),
                         "rxpdo": bool(e.access & 0x40), "txpdo": bool(e.access & 0x80)}
                        for e in obj.entries.values()],
            "missing_subindexes": {str(k): v for k, v in obj.missing.items()},
        })
    return out


# -- against the ESI ----------------------------------------------------------------------------

def compare_with_esi(objects: list[DescribedObject],
                     device: Device) -> tuple[list[str], list[str]]:
    """(differences, extras) between the uploaded dictionary and the device's ESI
    dictionary.  Differences: objects and entries the ESI has and the slave has not, entries
    whose data type, bit length or access differ.  Extras: objects and entries only the
    slave has (a device may have more than its ESI describes: the objects a master needs
    that the ESI leaves out).  Types are compared as CoE data type indices; an ESI type
    without one (a dictionary's own type) is not compared."""
    dic = device_dictionary(device)
    if dic is None or not dic.objects:
        return ["the ESI device describes no object dictionary"], []
    found: list[str] = []
    extras: list[str] = []
    uploaded = {o.description.index: o for o in objects}
    for index in sorted(set(dic.objects) - set(uploaded)):
        found.append(f"0x{index:04X} {pick_name(dic.objects[index].names)}: in the ESI, "
                     "not on the slave")
    for index in sorted(set(uploaded) - set(dic.objects)):
        extras.append(f"0x{index:04X} {uploaded[index].description.name}: on the slave, "
                      "not in the ESI")
    for index in sorted(set(uploaded) & set(dic.objects)):
        for sub, entry in uploaded[index].entries.items():
            esi = lookup(dic, index, sub)
            if not isinstance(esi, DictEntry):
                extras.append(f"0x{index:04X}:{sub:02X} {entry.name}: on the slave, not in "
                              "the ESI")
                continue
            found.extend(_entry_differences(index, entry, esi))
        for sub in range(256):
            esi = lookup(dic, index, sub)
            if isinstance(esi, DictEntry) and sub not in uploaded[index].entries:
                found.append(f"0x{index:04X}:{sub:02X}: in the ESI, not on the slave")
    return found, extras


def _entry_differences(index: int, entry: EntryDescription, esi: DictEntry) -> list[str]:
    where = f"0x{index:04X}:{entry.subindex:02X} {entry.name}"
    out: list[str] = []
    esi_code = coe_type(esi.type)
    if canonical(esi.type) is not None and esi_code and esi_code != entry.data_type:
        out.append(f"{where}: type {coe_type_name(entry.data_type)} on the slave, "
                   f"{esi.type} in the ESI")
    if esi.bit_size is not None and esi.bit_size != entry.bit_length:
        out.append(f"{where}: {entry.bit_length} bits on the slave, {esi.bit_size} in the "
                   "ESI")
    access = esi.flags.access if esi.flags is not None else None
    if access is not None:
        slave = access_text(entry.access)
        esi_read = [s for s in _STATES if access.readable_in(s)]
        esi_write = [s for s in _STATES if access.writable_in(s)]
        if slave["read"] != esi_read or slave["write"] != esi_write:
            out.append(f"{where}: access {access_short(entry.access)} on the slave, "
                       f"{_esi_access(esi_read, esi_write)} in the ESI")
    return out


def _esi_access(read: list[str], write: list[str]) -> str:
    mode = {"r": "ro", "w": "wo", "rw": "rw"}.get(("r" if read else "") + ("w" if write
                                                                            else ""), "--")
    if write and len(write) < 3:
        mode += f"(w:{','.join(write)})"
    return mode
