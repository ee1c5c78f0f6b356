"""One object of an emulated CoE slave's dictionary (:class:`OdObject`, an index) and its
subentries (:class:`OdEntry`, a subindex): type, bit size, access rights per AL state and
the current value as wire bytes.  Built from the ESI by ``od_from_esi.py``; read and
written by SDO rules in ``objects.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ecatcfg.esc import AlState
from ecatcfg.esi.datatypes import canonical

# The states a mailbox works in: who may read or write an entry by default.
MAILBOX_STATES = frozenset((AlState.PREOP, AlState.SAFEOP, AlState.OP))

_SIGNED = frozenset(("SINT", "INT", "INT24", "DINT", "INT40", "INT48", "INT56", "LINT"))
_FLOAT = frozenset(("REAL", "LREAL"))
_STRINGS = ("STRING", "WSTRING", "OCTET_STRING", "UNICODE_STRING", "DOMAIN")


def _kind(type_name: str) -> str:
    """``unsigned``, ``signed``, ``float``, ``string`` (visible/octet/unicode/domain) or
    ``octets`` (arrays, records used as values, unknown types)."""
    if type_name in _SIGNED:
        return "signed"
    if type_name in _FLOAT:
        return "float"
    if type_name.startswith(_STRINGS):
        return "string"
    if type_name.startswith("ARRAY") or canonical(type_name) is None:
        return "octets"
    return "unsigned"


@dataclass(slots=True)
class OdEntry:
    """One subindex: its type, size, access and current value (wire bytes)."""

    subindex: int
    name: str
    type: str                     # canonical base type name when known, else the ESI name
    bit_size: int                 # 0: variable length (STRING(0), DOMAIN)
    value: bytes
    access: str = "rw"            # "ro", "rw" or "wo"
    read_states: frozenset[AlState] = MAILBOX_STATES
    write_states: frozenset[AlState] = MAILBOX_STATES
    mappable: str = ""            # "R" (RxPDO), "T" (TxPDO) or both
    # Whether the ESI gives the entry's Flags, so that ``mappable`` is its word on PDO
    # mapping (PdoMapping absent: not mappable); False: the ESI says nothing, and the
    # emulated firmware takes the entry into any PDO (objects.py, sm_entries).
    mapping_said: bool = False
    min_value: int | None = None
    max_value: int | None = None
    # Where the entry sits in the object's complete-access image (ESI DataType SubItem
    # BitOffs, counted from subindex 0); None: packed by the rule in ObjectDictionary._layout.
    bit_offset: int | None = None

    @property
    def kind(self) -> str:
        return _kind(self.type)

    @property
    def byte_size(self) -> int:
        return (self.bit_size + 7) // 8

    @property
    def variable_length(self) -> bool:
        return self.bit_size == 0

    def readable(self, state: AlState) -> bool:
        return "r" in self.access and state in self.read_states

    def writable(self, state: AlState) -> bool:
        return "w" in self.access and state in self.write_states

    def as_int(self) -> int:
        return int.from_bytes(self.value, "little", signed=self.kind == "signed")


@dataclass(slots=True)
class OdObject:
    """One index.  A simple variable (``variable``) has only subindex 0; arrays and records
    have subindex 0 = number of entries and their entries."""

    index: int
    name: str
    entries: dict[int, OdEntry] = field(default_factory=dict)
    variable: bool = False
    # An ARRAY (entries 1..n of one type; ETG.2000 an array DataType, or the PDO mapping and
    # assignment objects built without one) rather than a RECORD: the object code SDO
    # Information describes the object with.
    array: bool = False
    # The mapping object of a virtual PDO (ETG.2000 Pdo@Virtual): the device configures its
    # variables from the mapping the master writes, so an entry may name an object the
    # dictionary does not have.
    virtual_pdo: bool = False

    def __getitem__(self, subindex: int) -> OdEntry:
        return self.entries[subindex]

    def add(self, entry: OdEntry) -> OdEntry:
        self.entries[entry.subindex] = entry
        self.entries = dict(sorted(self.entries.items()))
        return entry

    @property
    def max_subindex(self) -> int:
        return max(self.entries, default=0)

    @property
    def count(self) -> int:
        """The current value of subindex 0 (number of entries in use)."""
        si0 = self.entries.get(0)
        return si0.as_int() if si0 is not None and not self.variable else 0


def fit_bytes(data: bytes, nbytes: int) -> bytes:
    """``data`` truncated or zero-padded to ``nbytes`` (as is for variable length)."""
    if nbytes <= 0:
        return bytes(data)
    return bytes(data[:nbytes]).ljust(nbytes, b"\0")
