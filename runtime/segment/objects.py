"""The runtime object dictionary of an emulated CoE slave: what an SDO read or write of an
object does, and the process-data views the emulated ESC takes from it.

Every object has subentries (``od_entries.py``) with a type, a bit size, access rights per
AL state and a current value (little-endian bytes, as on the wire) initialised from the ESI
defaults; :meth:`ObjectDictionary.from_device` builds them from the device's ESI
(``od_from_esi.py``, which also adds the objects a master needs that many ESIs leave out).

Access rules and abort codes follow ``docs/protocol-notes.md`` §6 ("protocol-notes §6") and
SOES (``esc_coe.c``, ``ESC_download_pre_objecthandler``); where both are silent the choice is
commented where it is made.  The SDO server (``sdo_server``) is the wire side; this module
only knows objects, bytes and AL states.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

from ecatcfg.esc import (RX_PDO_MAPPING, SM_COMM_TYPE, SM_PDO_ASSIGN, SM_TYPE_CODES,
                         TX_PDO_MAPPING, AlState, is_pdo_object)
from ecatcfg.esi.datatypes import download_fits
from ecatcfg.esi.model import Device
from ecatcfg.runtime.mailbox import (
    ABORT_CA_NOT_SUPPORTED, ABORT_LENGTH_TOO_HIGH, ABORT_LENGTH_TOO_LOW, ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX, ABORT_READ_ONLY, ABORT_SUBINDEX0_NOT_ZERO, ABORT_TYPE_MISMATCH,
    ABORT_UNSUPPORTED_ACCESS, ABORT_VALUE_RANGE, ABORT_VALUE_TOO_HIGH, ABORT_VALUE_TOO_LOW,
    ABORT_WRITE_ONLY, ABORT_WRONG_STATE, SdoAbort,
)
from ecatcfg.runtime.refusals import Rule
from ecatcfg.runtime.segment import od_from_esi
from ecatcfg.runtime.segment.od_entries import OdEntry, OdObject, fit_bytes


# -- the dictionary ---------------------------------------------------------------------

class ObjectDictionary:
    """Objects by index, with SDO-style access (:meth:`read`, :meth:`write`) that raises
    :class:`SdoAbort` with the code a slave would answer, and the process-data views an
    emulated ESC needs (:meth:`sm_bits`, :meth:`rx_entries`, :meth:`tx_entries`).

    ``state=None`` means internal access (the ESC or a test): no access-right checks.
    """

    def __init__(self, objects: Iterable[OdObject] = ()) -> None:
        self.objects: dict[int, OdObject] = {o.index: o for o in objects}
        # Whether an ESI dictionary describes the device's objects: only then is an object
        # it does not list one the device lacks (assignment()).
        self.described = False
        self._injected: dict[tuple[int, int], int] = {}

    @classmethod
    def from_device(cls, device: Device) -> ObjectDictionary:
        from ecatcfg.esi.coe import dictionary_with_objects
        od = cls(od_from_esi.build(device))
        od.described = dictionary_with_objects(device) is not None
        return od

    def __contains__(self, index: object) -> bool:
        return index in self.objects

    def __getitem__(self, index: int) -> OdObject:
        return self.objects[index]

    def __iter__(self) -> Iterator[OdObject]:
        return iter(self.objects.values())

    def __len__(self) -> int:
        return len(self.objects)

    def add(self, obj: OdObject) -> OdObject:
        self.objects[obj.index] = obj
        return obj

    def inject_abort(self, index: int, sub: int, code: int | None) -> None:
        """Make every SDO read or write of ``index:sub`` (also a complete access covering
        it) abort with ``code``; ``None`` removes the fault."""
        if code is None:
            self._injected.pop((index, sub), None)
        else:
            self._injected[(index, sub)] = code

    # -- internal access (no rights checked) ----------------------------------------------

    def value(self, index: int, sub: int = 0) -> bytes:
        return self._entry(index, sub).value

    def int_value(self, index: int, sub: int = 0) -> int:
        return self._entry(index, sub).as_int()

    def set_value(self, index: int, sub: int, data: bytes) -> None:
        entry = self._entry(index, sub)
        entry.value = bytes(data) if entry.variable_length else fit_bytes(data, entry.byte_size)

    # -- SDO access -----------------------------------------------------------------------

    def read(self, index: int, sub: int, state: AlState | None, *,
             complete_access: bool = False) -> bytes:
        obj = self._object(index)
        if complete_access:
            return self._read_complete(obj, sub, state)
        entry = self._sub(obj, sub)
        self._check_injected(index, (sub,))
        if state is not None:
            self._check_read(index, entry, state)
        return entry.value

    def write(self, index: int, sub: int, data: bytes, state: AlState | None, *,
              complete_access: bool = False) -> None:
        obj = self._object(index)
        if complete_access:
            self._write_complete(obj, sub, bytes(data), state)
            return
        entry = self._sub(obj, sub)
        self._check_injected(index, (sub,))
        if state is not None:
            self._check_write(index, entry, state)
        value = self._sized(index, entry, bytes(data))
        if state is not None:
            self._check_si0_rule(obj, sub)
        self._check_range(obj, entry, value)
        entry.value = value

    def check_write(self, index: int, sub: int, size: int | None, state: AlState | None, *,
                    complete_access: bool = False) -> None:
        """The aborts a download of ``size`` bytes to ``index:sub`` gets before its data
        is there (a server checks this at the initiate of a segmented download, as SOES
        compares the announced size with the object's)."""
        obj = self._object(index)
        if complete_access:
            entries = self._ca_entries(obj, sub)
            self._check_injected(index, [e.subindex for e in entries])
            if state is not None:
                self._check_any(index, entries, state, write=True)
            _, total = self._layout(obj, entries)
            if size is not None and size > (total + 7) // 8:
                raise SdoAbort(ABORT_LENGTH_TOO_HIGH, index, sub)
            return
        entry = self._sub(obj, sub)
        self._check_injected(index, (sub,))
        if state is not None:
            self._check_write(index, entry, state)
        code = self._length_abort(entry, size) if size is not None else None
        if code is not None:
            raise SdoAbort(code, index, sub)
        if state is not None:
            self._check_si0_rule(obj, sub)

    # -- checks ---------------------------------------------------------------------------

    def _object(self, index: int) -> OdObject:
        obj = self.objects.get(index)
        if obj is None:
            raise SdoAbort(ABORT_NO_OBJECT, index, 0)
        return obj

    @staticmethod
    def _sub(obj: OdObject, sub: int) -> OdEntry:
        entry = obj.entries.get(sub)
        if entry is None:
            raise SdoAbort(ABORT_NO_SUBINDEX, obj.index, sub)
        return entry

    def _entry(self, index: int, sub: int) -> OdEntry:
        return self._sub(self._object(index), sub)

    def _check_injected(self, index: int, subs: Iterable[int]) -> None:
        for sub in subs:
            code = self._injected.get((index, sub))
            if code is not None:
                raise SdoAbort(code, index, sub)

    @staticmethod
    def _check_read(index: int, entry: OdEntry, state: AlState) -> None:
        if "r" not in entry.access or not entry.read_states:
            raise SdoAbort(ABORT_WRITE_ONLY, index, entry.subindex)
        if state not in entry.read_states:
            raise SdoAbort(ABORT_WRONG_STATE, index, entry.subindex)

    @staticmethod
    def _check_write(index: int, entry: OdEntry, state: AlState) -> None:
        if "w" not in entry.access or not entry.write_states:
            raise SdoAbort(ABORT_READ_ONLY, index, entry.subindex)
        if state not in entry.write_states:
            # Writable, but not in this AL state (e.g. 0x1C12 in SAFEOP; SOES ATYPE_RWpre).
            raise SdoAbort(ABORT_WRONG_STATE, index, entry.subindex)

    @staticmethod
    def _check_any(index: int, entries: list[OdEntry], state: AlState, write: bool) -> None:
        """Complete access: fine if some entry may be accessed now; else the code for the
        entry that comes closest (wrong state before no access at all)."""
        able: Callable[[OdEntry], bool] = ((lambda e: e.writable(state)) if write
                                           else (lambda e: e.readable(state)))
        if not entries or any(able(e) for e in entries):
            return
        letter = "w" if write else "r"
        if any(letter in e.access and (e.write_states if write else e.read_states)
               for e in entries):
            raise SdoAbort(ABORT_WRONG_STATE, index, entries[0].subindex)
        raise SdoAbort(ABORT_READ_ONLY if write else ABORT_WRITE_ONLY, index,
                       entries[0].subindex if entries else 0)

    @staticmethod
    def _length_abort(entry: OdEntry, length: int) -> int | None:
        """The abort for writing ``length`` bytes to ``entry`` (None: fine)."""
        # Which lengths fit is the rule lint checks ESI InitCmds by (esi/datatypes.py): a
        # visible/octet string may be written shorter than its declared size, the rest
        # zero (CANopen visible strings are NUL-terminated); a number takes its size.
        if entry.variable_length or download_fits(entry.type, entry.byte_size, length):
            return None
        if entry.kind == "string":
            return ABORT_LENGTH_TOO_HIGH if length > entry.byte_size else ABORT_LENGTH_TOO_LOW
        # Numbers: SOES answers any length mismatch with 0x06070010 (ABORT_TYPEMISMATCH).
        return ABORT_TYPE_MISMATCH

    def _sized(self, index: int, entry: OdEntry, data: bytes) -> bytes:
        """The value to store for ``data`` written to ``entry``, or the length abort."""
        code = self._length_abort(entry, len(data))
        if code is not None:
            raise SdoAbort(code, index, entry.subindex)
        return data if entry.variable_length else data.ljust(entry.byte_size, b"\0")

    @staticmethod
    def _check_si0_rule(obj: OdObject, sub: int) -> None:
        # PDO mapping and assignment objects: entries may only be written while SI0 is 0
        # (SOES ESC_download_pre_objecthandler; protocol-notes §6 abort 0x06010003).
        if sub >= 1 and is_pdo_object(obj.index) and obj.count != 0:
            raise SdoAbort(ABORT_SUBINDEX0_NOT_ZERO, obj.index, sub)

    @staticmethod
    def _check_range(obj: OdObject, entry: OdEntry, value: bytes) -> None:
        kind = entry.kind
        if kind not in ("signed", "unsigned") or not 0 < entry.bit_size <= 64:
            return
        number = int.from_bytes(value, "little", signed=kind == "signed")
        if entry.subindex == 0 and not obj.variable and number > obj.max_subindex:
            # More entries in use than the object has.
            raise SdoAbort(ABORT_VALUE_TOO_HIGH, obj.index, entry.subindex)
        if entry.bit_size % 8 and not 0 <= number < 1 << entry.bit_size:
            # BOOL / BITn written with a value that does not fit its bits.
            raise SdoAbort(ABORT_VALUE_RANGE, obj.index, entry.subindex)
        if entry.max_value is not None and number > entry.max_value:
            raise SdoAbort(ABORT_VALUE_TOO_HIGH, obj.index, entry.subindex)
        if entry.min_value is not None and number < entry.min_value:
            raise SdoAbort(ABORT_VALUE_TOO_LOW, obj.index, entry.subindex)

    # -- complete access (protocol-notes §6) ------------------------------------------------

    def _ca_entries(self, obj: OdObject, sub: int, *, upload: bool = False) -> list[OdEntry]:
        """The entries a complete access starting at ``sub`` covers, in order.

        Subindex must be 0 or 1 (SOES aborts 0x06010000 otherwise).  Uploads cover the
        entries up to the current value of SI0; downloads may cover every entry the object
        has (the data length says how many).  Where SOES (all declared entries) and the
        Beckhoff SSC (arrays: up to the current SI0) differ on uploads, we follow the SSC:
        a 0x1C12 with one PDO assigned reads back as ``01 00 xx xx``, as TwinCAT writes it.
        """
        if sub > 1:
            raise SdoAbort(ABORT_UNSUPPORTED_ACCESS, obj.index, sub)
        if obj.variable:
            entry = self._sub(obj, sub)
            if entry.kind == "string" or entry.variable_length:
                raise SdoAbort(ABORT_CA_NOT_SUPPORTED, obj.index, sub)
            return [entry]
        if sub == 0 or not any(s >= 1 for s in obj.entries):
            self._sub(obj, sub)
        # From subindex 1: the entries from 1 on, also when the ESI declares no subindex 1
        # (a record whose first bits are reserved, as many Beckhoff settings objects).
        last = min(obj.count, obj.max_subindex) if upload else obj.max_subindex
        entries = [e for s, e in obj.entries.items() if sub <= s and (s == 0 or s <= last)]
        if any(e.variable_length for e in entries):
            raise SdoAbort(ABORT_CA_NOT_SUPPORTED, obj.index, sub)
        return entries

    @staticmethod
    def _layout(obj: OdObject,
                entries: list[OdEntry]) -> tuple[list[tuple[OdEntry, int, int]], int]:
        """(entry, bit offset, bit length on the wire) and the total bits.

        Where the ESI places every entry of a record (DataType SubItem BitOffs, consistent:
        SI0 at 0, the others from bit 16 on, none overlapping), the image follows it, gaps
        included: the bits of subindices the ESI does not describe are the device's
        reserved bits, and a configurator writes the record as the ESI lays it out (a
        complete access from subindex 1 starts at the record's bit 16).  Otherwise SI0
        takes 16 bits unless the object is a variable, bit-sized entries are packed, the
        others start on a byte boundary (SOES ``complete_access_subindex_loop``)."""
        placed = ObjectDictionary._placed(obj)
        if placed is not None and entries:
            start = 0 if entries[0].subindex == 0 else 16
            out = [(e, placed[e.subindex] - start, 8 if e.subindex == 0 else e.bit_size)
                   for e in entries]
            return out, max(off + bits for _, off, bits in out)
        out = []
        pos = 0
        for e in entries:
            if e.subindex == 0 and not obj.variable:
                out.append((e, pos, 8))
                pos += 16
                continue
            if e.bit_size % 8 == 0 and pos % 8:
                pos += 8 - pos % 8
            out.append((e, pos, e.bit_size))
            pos += e.bit_size
        return out, pos

    @staticmethod
    def _placed(obj: OdObject) -> dict[int, int] | None:
        """Subindex -> BitOffs when the ESI gives a consistent one for every entry of the
        record, else None."""
        if obj.variable or any(e.bit_offset is None for e in obj.entries.values()):
            return None
        end = 0
        placed: dict[int, int] = {}
        for sub, e in obj.entries.items():                  # in subindex order
            off = e.bit_offset
            assert off is not None
            if (sub == 0) != (off == 0) or (sub > 0 and off < 16) or off < end \
                    or e.variable_length:
                return None
            placed[sub] = off
            end = off + (16 if sub == 0 else e.bit_size)
        return placed

    def _read_complete(self, obj: OdObject, sub: int, state: AlState | None) -> bytes:
        entries = self._ca_entries(obj, sub, upload=True)
        self._check_injected(obj.index, [e.subindex for e in entries])
        if state is not None:
            self._check_any(obj.index, entries, state, write=False)
        layout, total = self._layout(obj, entries)
        acc = 0
        for e, off, bits in layout:
            if state is not None and not e.readable(state):
                continue                      # unreadable entries read as zeros (SOES)
            value = int.from_bytes(e.value, "little") & ((1 << bits) - 1)
            acc |= value << off
        return acc.to_bytes((total + 7) // 8, "little")

    def _write_complete(self, obj: OdObject, sub: int, data: bytes,
                        state: AlState | None) -> None:
        entries = self._ca_entries(obj, sub)
        layout, total = self._layout(obj, entries)
        if not data:
            raise SdoAbort(ABORT_LENGTH_TOO_LOW, obj.index, sub)
        if len(data) > (total + 7) // 8:
            raise SdoAbort(ABORT_LENGTH_TOO_HIGH, obj.index, sub)
        end = len(data) * 8
        covered = [(e, off, bits) for e, off, bits in layout if off < end]
        if any(off + bits > end for _, off, bits in covered):
            # The data stops inside an entry (SOES accepts shorter data for the conformance
            # tool, but only whole entries make sense).
            raise SdoAbort(ABORT_TYPE_MISMATCH, obj.index, sub)
        self._check_injected(obj.index, [e.subindex for e, _, _ in covered])
        if state is not None:
            self._check_any(obj.index, [e for e, _, _ in covered], state, write=True)
        acc = int.from_bytes(data, "little")
        updates: list[tuple[OdEntry, bytes]] = []
        for e, off, bits in covered:
            if state is not None and not e.writable(state):
                continue                      # read-only entries are skipped (SOES)
            value = ((acc >> off) & ((1 << bits) - 1)).to_bytes(e.byte_size, "little")
            self._check_range(obj, e, value)
            updates.append((e, value))
        for e, value in updates:
            e.value = value

    # -- process data views ---------------------------------------------------------------

    def sm_entries(self, sm: int) -> list[tuple[int, int, int]] | None:
        """(index, subindex, bit length) of every mapped entry of SM ``sm``, in process
        image order (padding gaps have index 0); ``None`` when the current assignment
        (0x1C10+sm) or a mapping it names cannot be used (:meth:`assignment_problem`)."""
        entries, _problem = self.assignment(sm)
        return entries

    def assignment(self, sm: int) -> tuple[list[tuple[int, int, int]] | None,
                                            tuple[Rule, str] | None]:
        """:meth:`sm_entries` and, where they cannot be used, the rule and the values that
        break it (``runtime/refusals.py``), as the firmware finds them walking the
        assignment in order:

        - the assignment object 0x1C10+sm must exist (``NO_ASSIGNMENT``);
        - each PDO it assigns must be a mapping object the slave has (``PDO_MISSING``);
        - each entry a mapping holds must be an object and subindex the slave has, where
          its ESI describes its objects (``ENTRY_MISSING``), and mappable in the SM's
          direction where the ESI gives the entry's Flags (``ENTRY_NOT_MAPPABLE``:
          PdoMapping without R for an output SM, without T for an input SM).

        The direction is the SM's (its 0x1C00 communication type: 3 outputs, 4 inputs),
        not the PDO index range: an ESI may put an RxPdo 0x1A00 on an output SM (the
        FB1111 SPI-Slave does) and the device then takes it.  An entry the ESI does not
        describe (no dictionary, an object without Flags, a device from the ENI alone) is
        taken as it is: the ESI does not say the device checks it (docs/diagnostics.md,
        "Where the ESI does not say the device checks")."""
        index = SM_PDO_ASSIGN + sm
        assign = self.objects.get(index)
        if assign is None or assign.variable:
            return None, (Rule.NO_ASSIGNMENT, f"0x{index:04X} does not exist")
        direction = self._sm_direction(sm)
        out: list[tuple[int, int, int]] = []
        for n in range(1, assign.count + 1):
            slot = assign.entries.get(n)
            if slot is None:
                return None, (Rule.NO_ASSIGNMENT,
                              f"0x{index:04X}:00 = {assign.count}, but 0x{index:04X} has "
                              f"no subindex {n}")
            pdo_index = slot.as_int() & 0xFFFF
            pdo_dir = direction or ("R" if pdo_index in RX_PDO_MAPPING else
                                    "T" if pdo_index in TX_PDO_MAPPING else None)
            mapping = self.objects.get(pdo_index)
            if pdo_dir is None or mapping is None or mapping.variable or (
                    pdo_index not in RX_PDO_MAPPING and pdo_index not in TX_PDO_MAPPING):
                return None, (Rule.PDO_MISSING,
                              f"0x{index:04X}:{n:02X} = 0x{pdo_index:04X}, which is no PDO "
                              "mapping object of the slave")
            for k in range(1, mapping.count + 1):
                item = mapping.entries.get(k)
                if item is None:
                    return None, (Rule.PDO_MISSING,
                                  f"0x{pdo_index:04X}:00 = {mapping.count}, but "
                                  f"0x{pdo_index:04X} has no subindex {k}")
                word = item.as_int() & 0xFFFFFFFF
                obj_index, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
                where = f"0x{pdo_index:04X}:{k:02X} maps 0x{obj_index:04X}:{sub:02X}"
                if obj_index != 0:
                    problem = self._mapped_problem(mapping, obj_index, sub, pdo_dir, where)
                    if problem is not None:
                        return None, problem
                out.append((obj_index, sub, bits))
        return out, None

    def _sm_direction(self, sm: int) -> str | None:
        """"R" for an output SM, "T" for an input SM, as 0x1C00:(sm+1) gives its
        communication type (ETG.1000.6: 3 process data output, 4 process data input);
        None where the slave has no such entry."""
        types = self.objects.get(SM_COMM_TYPE)
        entry = types.entries.get(sm + 1) if types is not None else None
        kind = entry.as_int() if entry is not None else None
        return ("R" if kind == SM_TYPE_CODES["Outputs"] else "T"
                if kind == SM_TYPE_CODES["Inputs"] else None)

    def _mapped_problem(self, mapping: OdObject, index: int, sub: int, direction: str,
                        where: str) -> tuple[Rule, str] | None:
        target = self.objects.get(index)
        entry = target.entries.get(sub) if target is not None else None
        if entry is None:
            # A virtual PDO's variable need not be an object (OdObject.virtual_pdo); an
            # object the ESI does not describe is the device's to have.
            described = self.described and (target is not None or not mapping.virtual_pdo)
            if not described:
                return None
            return Rule.ENTRY_MISSING, (f"{where}: the slave has no "
                                        + (f"subindex {sub} in 0x{index:04X}" if target
                                           else f"object 0x{index:04X}"))
        if entry.mapping_said and direction not in entry.mappable:
            said = "/".join(entry.mappable) or "none"
            kind = "an RxPDO (outputs)" if direction == "R" else "a TxPDO (inputs)"
            return Rule.ENTRY_NOT_MAPPABLE, (f"{where}, which may not be mapped into {kind}: "
                                             f"its PdoMapping is {said}")
        return None

    def sm_bits(self, sm: int) -> int | None:
        """Process-data size of SM ``sm`` in bits from the current 0x1C1n assignment and
        mapping objects; ``None`` if that assignment is invalid (the ESC then refuses
        SAFEOP with 0x001D / 0x001E, protocol-notes §3)."""
        entries = self.sm_entries(sm)
        return None if entries is None else sum(bits for _, _, bits in entries)

    def rx_entries(self, sm: int) -> list[tuple[int, int, int]]:
        """The output (RxPDO) entries of SM ``sm``; empty when its assignment is invalid."""
        return self.sm_entries(sm) or []

    def tx_entries(self, sm: int) -> list[tuple[int, int, int]]:
        """The input (TxPDO) entries of SM ``sm``; empty when its assignment is invalid."""
        return self.sm_entries(sm) or []

