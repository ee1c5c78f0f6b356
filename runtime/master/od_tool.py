"""A slave's object dictionary uploaded with SDO Information (``ecatcfg od``), and what
differs from its ESI dictionary.

The slave is prepared as for ``ecatcfg sdo`` (``sdo_tool.mailbox_session``: mailbox from
its SII, PREOP if it is below); then Get OD List (all objects), and for each object its
description and the description of each subindex 0 .. max subindex, the way SOEM's
``ecx_readODlist``/``ecx_readODdescription``/``ecx_readOE`` walk a dictionary
(ETG.1000.6 §5.6.3).  A subindex the slave answers with an SDO information error is a gap
(records numbered 0, 4, 5), kept with its abort code.

With values (``od --values``, what TwinCAT's CoE-Online shows beside each entry), each
object's entries are uploaded in the same session: a record or array with one complete
access from subindex 0 where the slave takes it (ETG.1000.6 SDO complete access; a slave
that refuses it is asked entry by entry from then on), split with the layout SOES and the
SSC upload (subindex 0 in 16 bits, bit-sized entries packed, the others on byte
boundaries); where the bytes do not come to that layout's length (a record with reserved
gaps), entry by entry.
Writing stays with ``ecatcfg sdo write``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from ecatcfg.esc import RX_PDO_MAPPING, TX_PDO_MAPPING, is_pdo_object
from ecatcfg.esi.coe import (
    PDO_CONFIG_WRITE_STATES, DictEntry, device_dictionary, lookup, resolve_type,
    standard_entry_type,
)
from ecatcfg.esi.datatypes import ValueTypeError, canonical, coe_type, coe_type_name, decode
from ecatcfg.esi.model import Device, pick_name
from ecatcfg.runtime.mailbox import (
    ABORT_UNKNOWN_COMMAND, ABORT_UNSUPPORTED_ACCESS, ACCESS_READ_SHIFT, ACCESS_WRITE_SHIFT,
    OBJECT_CODE_NAMES, OBJECT_CODE_VAR, EntryDescription, ObjectDescription, SdoInfoOpcode,
    decode_od_list,
)
from ecatcfg.runtime.master.lockstep import Job, Step
from ecatcfg.runtime.master.replay import TIMEOUT_MAILBOX, ApplyError, MailboxChannel, sdo_job
from ecatcfg.runtime.master.sdo_client import SdoUpload
from ecatcfg.runtime.master.sdo_info import DescribedObject, SdoInfoRequest
from ecatcfg.runtime.master.sdo_tool import SdoToolError, SlaveMailbox, mailbox_session
from ecatcfg.runtime.master.transport import Transport

_STATES = ("PreOp", "SafeOp", "Op")


def upload_dictionary(transport: Transport, position: int, *,
                      timeout: float = TIMEOUT_MAILBOX,
                      info: SlaveMailbox | None = None, values: bool = False,
                      complete_access: bool = True) -> list[DescribedObject]:
    """The dictionary of the slave at ``position`` as it describes it, with each entry's
    value when ``values`` (by complete access where the slave takes it, unless
    ``complete_access`` is False).  Raises :class:`SdoToolError` (an SDO information
    error of the OD list or an object description carries ``abort_code``)."""
    result: list[DescribedObject] = []
    info = info if info is not None else SlaveMailbox(position)

    def work(channel: MailboxChannel, size: int, counter: Callable[[], int]) -> Job:
        try:
            result.extend((yield from read_dictionary(channel, size, counter, timeout)))
            if values:
                yield from read_values(channel, size, counter, result, timeout,
                                       complete_access)
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


# CA refusals that say the slave takes no complete access at all (SOES: 0x06010000 for an
# object it will not read whole; an SSC without CA: an unknown command specifier): after
# one, the other objects are read entry by entry without asking again.
_NO_COMPLETE_ACCESS = (ABORT_UNSUPPORTED_ACCESS, ABORT_UNKNOWN_COMMAND)


def read_values(channel: MailboxChannel, mbx_out_size: int, counter: Callable[[], int],
                objects: list[DescribedObject], timeout: float = TIMEOUT_MAILBOX,
                complete_access: bool = True) -> Step[None]:
    """Upload the value of every described entry into ``objects`` (``values``, or the
    abort code in ``value_aborts``)."""

    def upload(index: int, sub: int, whole: bool) -> Step[bytes]:
        t = SdoUpload(index, sub, whole, mbx_out_size, counter)
        yield from sdo_job(channel, t, None, None, timeout)
        return t.result

    use_ca = complete_access
    for obj in objects:
        d = obj.description
        left = sorted(obj.entries)
        if use_ca and d.object_code != OBJECT_CODE_VAR and 0 in obj.entries \
                and len(obj.entries) > 1:
            try:
                data = yield from upload(d.index, 0, True)
            except ApplyError as error:
                if error.abort_code is None:
                    raise
                if error.abort_code in _NO_COMPLETE_ACCESS:
                    use_ca = False
            else:
                split = split_complete(obj, data)
                if split is not None:
                    obj.values.update(split)
                    obj.complete_access = True
                    left = [s for s in left if s not in split]
        for sub in left:
            try:
                obj.values[sub] = yield from upload(d.index, sub, False)
            except ApplyError as error:
                if error.abort_code is None:
                    raise
                obj.value_aborts[sub] = error.abort_code


def split_complete(obj: DescribedObject, data: bytes) -> dict[int, bytes] | None:
    """The entries' bytes in a complete-access upload from subindex 0, laid out as SOES
    and the SSC lay it out (subindex 0 as 8 bits in a 16-bit slot, then the entries up to
    subindex 0's value in order: bit-sized ones packed, the others from a byte boundary);
    ``None`` when ``data`` is not that layout's length (the device places its entries
    otherwise, e.g. with reserved gaps)."""
    if not data or any(s not in obj.entries for s in range(1, data[0] + 1)):
        return None
    out = {0: data[:1]}
    pos = 16
    acc = int.from_bytes(data, "little")
    for sub in range(1, data[0] + 1):
        bits = obj.entries[sub].bit_length
        if bits % 8 == 0 and pos % 8:
            pos += 8 - pos % 8
        value = acc >> pos & ((1 << bits) - 1)
        out[sub] = value.to_bytes((bits + 7) // 8, "little")
        pos += bits
    return out if (pos + 7) // 8 == len(data) else None


def value_of(entry: EntryDescription, data: bytes) -> int | float | str | bool:
    """The value of an entry's bytes by its data type; hex bytes where the type has no
    single value (a record, a domain, a type the slave defines)."""
    try:
        return decode(data, coe_type_name(entry.data_type))
    except ValueTypeError:
        return data.hex()


def value_text(entry: EntryDescription, data: bytes) -> str:
    """A value as CoE-Online shows it: a number (unsigned ones of 16 bits or more in hex
    with the number after it; a PDO mapping entry with the object, subindex and bits it
    maps), a quoted string, or hex bytes."""
    value = value_of(entry, data)
    type_name = coe_type_name(entry.data_type)
    if isinstance(value, (bool, float)):
        return str(value)
    if isinstance(value, int):
        if entry.bit_length >= 16 and type_name.startswith("U"):
            text = f"0x{value:0{(entry.bit_length + 3) // 4}X} ({value})"
            mapping = entry.index in RX_PDO_MAPPING or entry.index in TX_PDO_MAPPING
            if mapping and entry.subindex and value:     # index << 16 | sub << 8 | bits
                text = f"0x{value:08X} (0x{value >> 16:04X}:{value >> 8 & 0xFF:02X}, " \
                       f"{value & 0xFF} bit)"
            return text
        return str(value)
    if canonical(type_name) is not None and "STRING" in type_name \
            and "OCTET" not in type_name:
        return repr(value)
    return value


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
                         "rxpdo": bool(e.access & 0x40), "txpdo": bool(e.access & 0x80),
                         **_value_json(obj, e)}
                        for e in obj.entries.values()],
            "missing_subindexes": {str(k): v for k, v in obj.missing.items()},
        })
        if obj.values or obj.value_aborts:
            out[-1]["complete_access"] = obj.complete_access
    return out


def _value_json(obj: DescribedObject, e: EntryDescription) -> dict[str, object]:
    if e.subindex in obj.values:
        raw = obj.values[e.subindex]
        return {"value": value_of(e, raw), "raw": raw.hex()}
    if e.subindex in obj.value_aborts:
        return {"abort_code": obj.value_aborts[e.subindex]}
    return {}


# -- against the ESI ----------------------------------------------------------------------------

@dataclass(slots=True)
class Comparison:
    """What ``od --esi`` found.  ``differences``: what the ESI has and the slave has not,
    and entries whose meaning differs (ETG.1020 data type, bit length, access per state).
    ``extras``: objects and entries only the slave has (a device may have more than its
    ESI describes).  ``esi_notes``: communication entries the ESI types otherwise than
    ETG.1000.6 fixes them while the slave answers the standard (the ESI's mistake, not the
    slave's)."""

    differences: list[str] = field(default_factory=list)
    extras: list[str] = field(default_factory=list)
    esi_notes: list[str] = field(default_factory=list)


def compare_with_esi(objects: list[DescribedObject], device: Device) -> Comparison:
    """The uploaded dictionary against the device's ESI dictionary, by meaning: types as
    the ETG.1020 base type an ESI name or a dictionary type renaming one stands for (an
    ESI type without one, a dictionary's own record type, is not compared), access as the
    states it allows reading and writing in."""
    dic = device_dictionary(device)
    if dic is None or not dic.objects:
        return Comparison(["the ESI device describes no object dictionary"])
    out = Comparison()
    found, extras = out.differences, out.extras
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
            type_name, bits = resolve_type(dic, esi.type)
            if esi.bit_size is not None:
                bits = esi.bit_size
            standard = standard_entry_type(index, sub)
            if standard is not None and (type_name, bits) != standard \
                    and (coe_type(standard[0]), standard[1]) \
                    == (entry.data_type, entry.bit_length):
                out.esi_notes.append(
                    f"0x{index:04X}:{sub:02X} {entry.name}: {esi.type} of {bits} bits in "
                    f"the ESI; ETG.1000.6 and the slave: {standard[0]} of {standard[1]}")
                type_name, bits = standard
            found.extend(_entry_differences(index, entry, esi, type_name, bits))
        for sub in range(256):
            esi = lookup(dic, index, sub)
            if isinstance(esi, DictEntry) and sub not in uploaded[index].entries:
                found.append(f"0x{index:04X}:{sub:02X}: in the ESI, not on the slave")
    return out


def _entry_differences(index: int, entry: EntryDescription, esi: DictEntry,
                       type_name: str, bits: int | None) -> list[str]:
    where = f"0x{index:04X}:{entry.subindex:02X} {entry.name}"
    out: list[str] = []
    esi_code = coe_type(type_name)
    if canonical(type_name) is not None and esi_code and esi_code != entry.data_type:
        out.append(f"{where}: type {coe_type_name(entry.data_type)} on the slave, "
                   f"{esi.type} in the ESI")
    if bits is not None and bits != entry.bit_length:
        out.append(f"{where}: {entry.bit_length} bits on the slave, {bits} in the "
                   "ESI")
    access = esi.flags.access if esi.flags is not None else None
    if access is not None:
        slave = access_text(entry.access)
        esi_read = [s for s in _STATES if access.readable_in(s)]
        esi_write = [s for s in _STATES if access.writable_in(s)]
        slave_write, esi_writes = slave["write"], esi_write
        if is_pdo_object(index):
            # Writable after PREOP means nothing for a PDO mapping or assignment: the
            # layout is fixed at PREOP->SAFEOP (esi.coe.PDO_CONFIG_WRITE_STATES).
            esi_writes = [s for s in esi_write if s in PDO_CONFIG_WRITE_STATES]
            slave_write = [s for s in slave_write if s in PDO_CONFIG_WRITE_STATES]
        if slave["read"] != esi_read or slave_write != esi_writes:
            out.append(f"{where}: access {access_short(entry.access)} on the slave, "
                       f"{_esi_access(esi_read, esi_write)} in the ESI")
    return out


def _esi_access(read: list[str], write: list[str]) -> str:
    """The ESI's access as ``access_short`` spells the slave's."""
    mode = {"r": "ro", "w": "wo", "rw": "rw"}.get(("r" if read else "") + ("w" if write
                                                                            else ""), "--")
    if write and len(write) < 3:
        mode += f"(w:{','.join(write)})"
    return mode
