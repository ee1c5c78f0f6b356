"""The device model: what an ESI file (ETG.2000) says about a slave, as typed Python objects.

Plain slotted dataclasses rather than pydantic models: a full read of the 3 MB Beckhoff files
creates ~150 000 objects, and the reader (``esi.reader``) already validates every value as it
converts it (numbers, booleans, hexBinary, enumerations), recording what it could not read as
:class:`ReadProblem` with the file and line.  Every object carries ``source`` (file, line) so
lint findings and compiler errors can point at the XML that defined it.

Names follow ETG.2000 element names in snake case (``RxPdo`` -> :class:`Pdo` with
``direction="rx"``, ``Sm`` -> :class:`SyncManager`, ``Fmmu`` -> :class:`Fmmu`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

from ecatcfg.esc import (ESC_DEVICE_EMULATION, SM_CONTROL_MBOX_IN, SM_CONTROL_MBOX_OUT,
                         SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES, SM_DIR_MASK, SM_MODE_BUFFERED,
                         SM_MODE_MAILBOX, SM_MODE_MASK)
from ecatcfg.esi.idn import MAX_DRIVE

# LcId 1033 is English (US); ETG.2000 makes it the default language of a NameType.
ENGLISH = 1033

MAILBOX_PROTOCOLS = ("AoE", "EoE", "CoE", "FoE", "SoE", "VoE")   # the elements under Mailbox

# AL state names used in ETG.2000 access restrictions (Flags/Access ReadRestrictions,
# WriteRestrictions: e.g. "PreOp_SafeOp").
STATES = ("PreOp", "SafeOp", "Op")


class Source(NamedTuple):
    """Where a model object was defined: the file as the user named it and a 1-based line."""

    file: str
    line: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}"


Severity = Literal["error", "warning"]
ProblemKind = Literal["number", "data", "flag", "text"]


@dataclass(slots=True)
class ReadProblem:
    """Something the reader could not take as written; the value is left as ``None``.

    ``severity`` is ``"error"`` when the device cannot be identified or used (a bad product
    code), ``"warning"`` otherwise (a bad default value deep in the dictionary).
    """

    source: Source
    message: str
    severity: Severity = "warning"
    column: int | None = None
    # What could not be read: "number" (hex/decimal), "data" (hexBinary), "flag" (boolean),
    # "text" (an enumerated word such as an AL state); lint maps them to its rules.
    kind: ProblemKind = "number"


@dataclass(slots=True)
class IgnoredElement:
    """An element the reader does not know (not in ETG.2000 at that place); lint reports it."""

    source: Source
    tag: str
    parent: str


def pick_name(names: dict[int, str], lcid: int = ENGLISH) -> str:
    """The text in ``lcid``, else English, else the first language given, else ``""``."""
    if lcid in names:
        return names[lcid]
    if ENGLISH in names:
        return names[ENGLISH]
    return next(iter(names.values()), "")


@dataclass(slots=True)
class Vendor:
    id: int | None
    names: dict[int, str]
    source: Source

    @property
    def name(self) -> str:
        return pick_name(self.names)


@dataclass(slots=True)
class Group:
    type: str
    names: dict[int, str]
    source: Source

    @property
    def name(self) -> str:
        return pick_name(self.names)


@dataclass(slots=True)
class Access:
    """Flags/Access: ``ro``, ``rw`` or ``wo``, optionally limited to some AL states."""

    value: str
    read_states: frozenset[str] = frozenset(STATES)
    write_states: frozenset[str] = frozenset(STATES)

    def readable_in(self, state: str) -> bool:
        return "r" in self.value and state in self.read_states

    def writable_in(self, state: str) -> bool:
        return "w" in self.value and state in self.write_states


@dataclass(slots=True)
class ObjectFlags:
    access: Access | None = None
    category: str | None = None       # m(andatory) / o(ptional) / c(onditional)
    pdo_mapping: str | None = None    # "R", "T", "RT", "TR" (ETG.2000: which PDO kind)
    sdo_access: str | None = None     # CompleteAccess / SubIndexAccess
    backup: int | None = None
    setting: int | None = None
    source: Source | None = None


@dataclass(slots=True)
class ObjectInfo:
    """Object/Info or one of its SubItem/Info: defaults and limits."""

    default_data: bytes | None = None
    default_value: int | None = None
    default_string: str | None = None
    min_value: int | None = None
    max_value: int | None = None
    min_data: bytes | None = None
    max_data: bytes | None = None
    sub_items: list[tuple[str, ObjectInfo]] = field(default_factory=list)
    source: Source | None = None      # None for a SubItem that gives no Info


@dataclass(slots=True)
class ArrayInfo:
    lbound: int
    elements: int


@dataclass(slots=True)
class DataTypeSubItem:
    """DataType/SubItem: one member of a record or array type."""

    subindex: int | None
    name: str
    type: str
    bit_size: int | None
    bit_offset: int | None
    flags: ObjectFlags | None
    source: Source


@dataclass(slots=True)
class DataType:
    name: str
    bit_size: int | None
    source: Source
    base_type: str | None = None
    index: int | None = None
    array_info: list[ArrayInfo] = field(default_factory=list)
    sub_items: list[DataTypeSubItem] = field(default_factory=list)
    enums: dict[int, str] = field(default_factory=dict)


@dataclass(slots=True)
class DictObject:
    """Dictionary/Objects/Object: one CoE object (index) with its type and flags."""

    index: int | None
    names: dict[int, str]
    type: str
    bit_size: int | None
    source: Source
    info: ObjectInfo | None = None
    flags: ObjectFlags | None = None
    depend_on_slot: bool = False
    depend_on_slot_group: bool = False      # ETG.2000 Index@DependOnSlotGroup (esi/slots.py)

    @property
    def name(self) -> str:
        return pick_name(self.names)


@dataclass(slots=True)
class Dictionary:
    """Profile/Dictionary: the object dictionary a CoE slave declares."""

    data_types: dict[str, DataType]
    objects: dict[int, DictObject]
    source: Source

    def sub_items(self, obj: DictObject) -> list[DataTypeSubItem]:
        """The subitems of ``obj`` by its data type (empty for a simple variable)."""
        dt = self.data_types.get(obj.type)
        return dt.sub_items if dt is not None else []


# One lock for every dictionary read on first use: reads are rare (once per Profile) and
# the reader appends to its file's lists of problems, which two threads must not do at once.
_READ_LOCK = threading.Lock()


class Profile:
    """Device/Profile (or a Module's): the device profile and its object dictionary.

    The reader fills ``dictionary`` when it is first asked for, from the Dictionary element
    it kept (:meth:`read_later`): the dictionaries are two thirds of a full read of the
    Beckhoff terminal files, and a compile uses those of a few devices.  What the reader
    could not take in a dictionary joins the file's ``problems`` and ``ignored`` then
    (asking the file for those reads every dictionary not read yet, as lint does);
    :meth:`EsiFile.read_dictionaries` reads them all at once.  Until then the Profile
    keeps the element, and with it the whole parsed document, alive."""

    __slots__ = ("source", "profile_no", "add_info", "channel", "dictionary_file",
                 "_dictionary", "_read")

    def __init__(self, source: Source, profile_no: int | None = None,
                 add_info: int | None = None, channel: int | None = None,
                 dictionary: Dictionary | None = None,
                 dictionary_file: str | None = None) -> None:
        self.source = source
        self.profile_no = profile_no
        self.add_info = add_info
        self.channel = channel
        self.dictionary_file = dictionary_file
        self._dictionary = dictionary
        self._read: Callable[[], Dictionary] | None = None

    @property
    def dictionary(self) -> Dictionary | None:
        if self._read is not None:
            with _READ_LOCK:
                read = self._read
                if read is not None:            # not read by another thread meanwhile
                    self._dictionary = read()
                    self._read = None
        return self._dictionary

    @dictionary.setter
    def dictionary(self, value: Dictionary | None) -> None:
        with _READ_LOCK:
            self._dictionary = value
            self._read = None

    def read_later(self, read: Callable[[], Dictionary]) -> None:
        """Take the dictionary from ``read()`` when it is first asked for."""
        self._dictionary = None
        self._read = read

    @property
    def dictionary_pending(self) -> bool:
        """Whether the dictionary is still to be read (for tests and measurements)."""
        return self._read is not None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Profile):
            return NotImplemented
        return ((self.source, self.profile_no, self.add_info, self.channel,
                 self.dictionary, self.dictionary_file)
                == (other.source, other.profile_no, other.add_info, other.channel,
                    other.dictionary, other.dictionary_file))

    __hash__ = None     # type: ignore[assignment]   # mutable, as the dataclasses here

    def __repr__(self) -> str:
        return (f"Profile(source={self.source!r}, profile_no={self.profile_no!r}, "
                f"add_info={self.add_info!r}, channel={self.channel!r}, "
                f"dictionary={self.dictionary!r}, dictionary_file={self.dictionary_file!r})")


@dataclass(slots=True)
class PdoEntry:
    """RxPdo/Entry or TxPdo/Entry; ``index == 0`` is a padding (gap) entry."""

    index: int | None
    subindex: int | None
    bit_len: int | None
    data_type: str | None
    names: dict[int, str]
    source: Source
    depend_on_slot: bool = False
    depend_on_slot_group: bool = False

    @property
    def name(self) -> str:
        return pick_name(self.names)

    @property
    def is_padding(self) -> bool:
        return self.index == 0


@dataclass(slots=True)
class Pdo:
    """An RxPdo (outputs, master -> slave) or TxPdo (inputs, slave -> master)."""

    direction: Literal["rx", "tx"]
    index: int | None
    names: dict[int, str]
    source: Source
    sm: int | None = None
    su: int | None = None
    fixed: bool = False
    mandatory: bool = False
    virtual: bool = False
    excludes: list[int] = field(default_factory=list)
    entries: list[PdoEntry] = field(default_factory=list)
    os_fac: int | None = None
    os_min: int | None = None
    os_max: int | None = None
    os_index_inc: int | None = None
    pdo_order: int | None = None
    depend_on_slot: bool = False
    depend_on_slot_group: bool = False
    # Exclude -> its own (DependOnSlot, DependOnSlotGroup), where the Exclude element gives
    # either; an Exclude without them moves as the PDO's Index does (esi/slots.py).
    exclude_depends: dict[int, tuple[bool, bool]] = field(default_factory=dict)
    # A device PDO that the module plugged in the slot replaces by its own (ETG.2000
    # ``OverwrittenByModule``; Beckhoff TwinSAFE and EP/EJ terminals with a default module).
    overwritten_by_module: bool = False

    @property
    def name(self) -> str:
        return pick_name(self.names)

    @property
    def bit_length(self) -> int:
        """Sum of the entries' BitLen (entries without a valid BitLen count as 0)."""
        return sum(e.bit_len or 0 for e in self.entries)


SmType = Literal["MBoxOut", "MBoxIn", "Outputs", "Inputs"]


def sm_type_from_control(control: int, carries_pdos: bool) -> SmType | None:
    """The type of a SyncManager whose ESI ``Sm`` gives none (no text: IgH's ``ethercat
    xml`` writes its dumps so), from what its control byte sets the ESC up for (register
    0x0804): bits 3:2 the direction (01 the master writes: MBoxOut or Outputs; 00 the master
    reads: MBoxIn or Inputs; IgH's ``ec_sync_default_direction`` reads the same bits), bits
    1:0 the mode (10 one buffer: a mailbox; 00 three buffers: process data).  A one-buffer
    SM that the device's PDOs name (``Pdo@Sm``) is process data in mailbox mode, as the
    EL1252 has (lint ESI206), not a mailbox: SOEM too types an SM from the PDOs its SII
    assigns to it.  ``None`` when a reserved bit pattern leaves the type open."""
    mode, direction = control & SM_MODE_MASK, control & SM_DIR_MASK
    if direction not in (SM_DIR_ECAT_WRITES, SM_DIR_ECAT_READS) \
            or mode not in (SM_MODE_BUFFERED, SM_MODE_MAILBOX):
        return None
    writes = direction == SM_DIR_ECAT_WRITES
    if mode == SM_MODE_MAILBOX and not carries_pdos:
        return "MBoxOut" if writes else "MBoxIn"
    return "Outputs" if writes else "Inputs"


@dataclass(slots=True)
class SyncManager:
    """Device/Sm, numbered by its position in the file (SM0, SM1, ...)."""

    number: int
    type: str | None                 # MBoxOut / MBoxIn / Outputs / Inputs (None if empty)
    source: Source
    start_address: int | None = None
    control_byte: int | None = None
    default_size: int | None = None
    min_size: int | None = None
    max_size: int | None = None
    enable: int | None = None
    op_only: bool = False
    virtual: bool = False
    watchdog: bool | None = None
    one_byte_mode: bool = False
    fixed_assignment: bool = False
    # The Sm element has no type text: ``type`` is what its ControlByte gives
    # (``sm_type_from_control``; lint ESI215 says so), or None when the byte gives none.
    type_from_control: bool = False

    @property
    def is_mailbox(self) -> bool:
        return self.type in ("MBoxOut", "MBoxIn")

    @property
    def mailbox_size(self) -> int:
        """The length of a mailbox SM, the one rule every part of ecatcfg follows: the ENI's
        SM0/SM1 InitCmds and ``Mailbox/Send|Recv/Length``, the SII's standard mailbox words
        and SYNCM category, the emulated slave's mailbox check and lint.

        ETG.2000 (``Device/Sm``) gives ``DefaultSize`` as the size to configure and
        ``MinSize``/``MaxSize`` as the sizes the slave accepts.  Without ``DefaultSize`` the
        file still bounds the size: ``MaxSize`` is the largest mailbox the slave takes (the
        fewest segments per transfer), else ``MinSize`` is the one size the file vouches for;
        with none of them the size is 0 (lint ESI212 and ESI213 report both cases)."""
        for size in (self.default_size, self.max_size, self.min_size):
            if size is not None:
                return size
        return 0

    def takes_mailbox_length(self, length: int) -> bool:
        """Whether the slave takes a mailbox SM of ``length`` bytes, the one rule of the
        ENI check (ENI501) and the emulated firmware's mailbox check (0x0016).

        ETG.2000 ``Device/Sm``: ``MinSize`` and ``MaxSize`` are the sizes the slave accepts,
        ``DefaultSize`` the one a configurator programs.  A slave takes any length in
        ``MinSize..MaxSize`` (the Slave Stack Code's mailbox check bounds the SM length by
        its MIN_MBX_SIZE and MAX_MBX_SIZE and works with the length it is given), a bound
        the file does not give being :attr:`mailbox_size`, and always :attr:`mailbox_size`
        itself, the size every part of ecatcfg configures, even where it lies outside the
        bounds (lint reports that contradiction in the ESI).  A file with no size at all
        bounds nothing: only its :attr:`mailbox_size`, 0, which no mailbox has."""
        size = self.mailbox_size
        lo = self.min_size if self.min_size is not None else size
        hi = self.max_size if self.max_size is not None else size
        return lo <= length <= hi or length == size

    def mailbox_lengths_text(self) -> str:
        """The lengths :meth:`takes_mailbox_length` takes, for a message."""
        size = self.mailbox_size
        lo = self.min_size if self.min_size is not None else size
        hi = self.max_size if self.max_size is not None else size
        bounds = f"{lo}..{hi}" if lo != hi else f"{lo}"
        return bounds if lo <= size <= hi else f"{bounds} or {size}"

    @property
    def mailbox_control(self) -> int:
        """The control byte of a mailbox SM: ``ControlByte``, else the standard mailbox
        control (0x26 for MBoxOut, 0x22 for MBoxIn; esc.py)."""
        if self.control_byte is not None:
            return self.control_byte
        return SM_CONTROL_MBOX_OUT if self.type == "MBoxOut" else SM_CONTROL_MBOX_IN


@dataclass(slots=True)
class Fmmu:
    """Device/Fmmu: its use (Outputs / Inputs / MBoxState) and optional SM binding."""

    number: int
    type: str | None
    source: Source
    sm: int | None = None
    su: int | None = None
    op_only: bool = False


@dataclass(slots=True)
class CoeInitCmd:
    """Mailbox/CoE/InitCmd: an SDO download the master does in the given transitions."""

    transitions: list[str]
    index: int | None
    subindex: int | None
    data: bytes | None
    source: Source
    complete_access: bool = False
    fixed: bool = False
    comment: str | None = None
    depend_on_slot: bool = False
    depend_on_slot_group: bool = False


@dataclass(slots=True)
class CoeSettings:
    source: Source
    sdo_info: bool = False
    pdo_assign: bool = False
    pdo_config: bool = False
    pdo_upload: bool = False
    complete_access: bool = False
    segmented_sdo: bool = False
    init_cmds: list[CoeInitCmd] = field(default_factory=list)


@dataclass(slots=True)
class EoeSettings:
    """Mailbox/EoE's attributes (ETG.2000): what the device's EoE supports beyond Ethernet
    frames: IP parameters, a MAC address, time stamps.  ``None`` where the file does not
    say (the schema's default is false, but devices that leave them out, such as the Elmo
    drives, take IP parameters: their own tool sets them)."""

    source: Source
    ip: bool | None = None
    mac: bool | None = None
    timestamp: bool | None = None
    # Where the ESI's own EoE InitCmds are (ETG.2000 EoE/InitCmd: Transition, Type, Data):
    # not implemented, so a compile that would lose them refuses the device.
    init_cmds: list[Source] = field(default_factory=list)


@dataclass(slots=True)
class SoeInitCmd:
    """Mailbox/SoE/InitCmd (ETG.2000): an IDN the master writes over SoE (Servo drive
    profile over EtherCAT, IEC 61800-7-304) in the given transitions.  ``idn`` is the
    16-bit IDN number as the file writes it (bit 15 = P parameter, bits 14:12 the
    parameter set, 11:0 the number); ``channel`` is the drive number (``@Chn``)."""

    transitions: list[str]
    idn: int | None
    data: bytes | None
    source: Source
    comment: str | None = None
    channel: int = 0


@dataclass(slots=True)
class SoeSettings:
    """Device/Mailbox/SoE: the drive's start-up IDN writes and its channel count."""

    source: Source
    init_cmds: list[SoeInitCmd] = field(default_factory=list)
    channel_count: int | None = None                 # @ChannelCount: drives per slave
    drive_follows_bit3: bool | None = None           # @DriveFollowsBit3Support

    @property
    def drives(self) -> int:
        """The drives behind the slave: ``@ChannelCount``, 1 where the file does not say
        (ETG.2000 gives no default; the single-axis AX5101 leaves it out and writes no
        ``InitCmd@Chn``), at most the 8 the SoE header's 3-bit drive number addresses."""
        count = self.channel_count if self.channel_count else 1
        return min(count, MAX_DRIVE + 1)


@dataclass(slots=True)
class Mailbox:
    """Device/Mailbox: the protocols the slave speaks; CoE details in ``coe``, EoE's in
    ``eoe``, SoE's in ``soe``."""

    protocols: list[str]
    source: Source
    coe: CoeSettings | None = None
    data_link_layer: bool = False
    eoe: EoeSettings | None = None
    soe: SoeSettings | None = None


@dataclass(slots=True)
class DcOpMode:
    """Dc/OpMode: a distributed-clock mode and the registers 0x0980/0x09A0/0x09A4 settings.

    ``cycle_time_sync0`` is the value in ns, used when ``*_factor`` is absent; a factor means
    "that many times the bus cycle" (ETG.2000; negative factor = a fraction of it).
    """

    name: str
    source: Source
    desc: str | None = None
    assign_activate: int | None = None
    cycle_time_sync0: int | None = None
    cycle_time_sync0_factor: int | None = None
    shift_time_sync0: int | None = None
    cycle_time_sync1: int | None = None
    cycle_time_sync1_factor: int | None = None
    shift_time_sync1: int | None = None
    # VendorSpecific/TwinCAT @UseFromBuildNo / @IgnoreFromBuildNo: Beckhoff files give two
    # versions of a mode under one name, each for a range of TwinCAT builds.
    use_from_build: int | None = None
    ignore_from_build: int | None = None

    def overlaps(self, other: DcOpMode) -> bool:
        """Whether both modes apply to some common TwinCAT build (always, without ranges)."""
        lo = max(self.use_from_build or 0, other.use_from_build or 0)
        hi = min(self.ignore_from_build or 1 << 62, other.ignore_from_build or 1 << 62)
        return lo < hi


@dataclass(slots=True)
class Dc:
    opmodes: list[DcOpMode]
    source: Source


@dataclass(slots=True)
class Eeprom:
    """Device/Eeprom: either the whole image (``data``) or its size and config words."""

    source: Source
    byte_size: int | None = None
    config_data: bytes | None = None
    boot_strap: bytes | None = None
    data: bytes | None = None
    categories: list[tuple[int, bytes]] = field(default_factory=list)
    assign_to_pdi: bool = False


@dataclass(slots=True)
class DeviceInfo:
    """Device/Info: timeouts (ms), E-bus current (mA) and identification settings."""

    source: Source
    preop_timeout: int | None = None
    safeop_op_timeout: int | None = None
    back_to_init_timeout: int | None = None
    back_to_safeop_timeout: int | None = None
    mailbox_request_timeout: int | None = None
    mailbox_response_timeout: int | None = None
    ebus_current: int | None = None
    identification_ado: int | None = None      # where the device shows its ID (EK1101: 0x1000)
    identification_reg134: bool = False        # explicit device ID in AL status code 0x0134


@dataclass(slots=True)
class Slot:
    """Slots/Slot of a modular device (ETG.2000 MDP): which modules may sit in it."""

    names: dict[int, str]
    source: Source
    min_instances: int | None = None
    max_instances: int | None = None
    module_idents: list[int] = field(default_factory=list)
    default_ident: int | None = None
    module_classes: list[str] = field(default_factory=list)
    slot_pdo_increment: int | None = None
    slot_index_increment: int | None = None
    slot_group: int | None = None           # the SlotGroupData/@SlotGroup it belongs to
    slot_group_pdo_increment: int | None = None
    slot_group_index_increment: int | None = None

    @property
    def name(self) -> str:
        return pick_name(self.names)


@dataclass(slots=True)
class SlotGroup:
    """Slots/SlotGroupData: a group of slots (a drive's axis, a safety terminal's logic), by
    its number; the modules in its slots have their ``DependOnSlotGroup`` indices moved by
    number x SlotGroupIndexIncrement / SlotGroupPdoIncrement (esi/slots.py)."""

    number: int | None                      # None: unreadable (a ReadProblem at its line)
    names: dict[int, str]
    source: Source

    @property
    def name(self) -> str:
        return pick_name(self.names)


@dataclass(slots=True)
class ModulePdoGroup:
    """Slots/ModulePdoGroup: where the PDOs of one group of modules start (their order in
    the assignment follows the group's position in the list)."""

    rx_pdo: int | None
    tx_pdo: int | None
    alignment: int | None = None


@dataclass(slots=True)
class Slots:
    slots: list[Slot]
    source: Source
    slot_pdo_increment: int | None = None
    slot_index_increment: int | None = None
    slot_group_pdo_increment: int | None = None
    slot_group_index_increment: int | None = None
    groups: list[SlotGroup] = field(default_factory=list)      # SlotGroupData, in order
    # Write the configured module ident list (0xF030) in this transition (ETG.2000
    # ``DownloadModuleIdentList``, ``DownloadModuleListTransition``, default PS).
    download_module_ident_list: bool = False
    download_transition: str = "PS"
    pdo_groups: list[ModulePdoGroup] = field(default_factory=list)


@dataclass(slots=True)
class Module:
    """Descriptions/Modules/Module (or a module library's Module): a pluggable module."""

    ident: int | None
    type_name: str
    names: dict[int, str]
    source: Source
    module_class: str | None = None
    pdo_group: int | None = None
    rx_pdos: list[Pdo] = field(default_factory=list)
    tx_pdos: list[Pdo] = field(default_factory=list)
    mailbox: Mailbox | None = None
    profile: Profile | None = None
    dc_opmode_name: str | None = None

    @property
    def name(self) -> str:
        return pick_name(self.names)


@dataclass(slots=True)
class Device:
    """Descriptions/Devices/Device: one product revision as a configurator needs it."""

    type_name: str
    product_code: int | None
    revision: int | None
    names: dict[int, str]
    source: Source
    vendor: Vendor
    physics: str | None = None
    group_type: str | None = None
    info: DeviceInfo | None = None
    fmmus: list[Fmmu] = field(default_factory=list)
    sms: list[SyncManager] = field(default_factory=list)
    rx_pdos: list[Pdo] = field(default_factory=list)
    tx_pdos: list[Pdo] = field(default_factory=list)
    mailbox: Mailbox | None = None
    dc: Dc | None = None
    eeprom: Eeprom | None = None
    profiles: list[Profile] = field(default_factory=list)
    slots: Slots | None = None
    module_pdo_group: int | None = None     # Type/@ModulePdoGroup: the group of its own PDOs
    # Type/@UseLrdLwr (ETG.2000): the device takes its process data by LRD and LWR, not by
    # LRW (compile's layout must be lrd_lwr for it).
    use_lrd_lwr: bool = False
    # Not from the ESI: the idents of the modules plugged, by position (0: an empty slot),
    # for a device put together with its modules (esi/slots.py ``with_modules``).
    plugged: tuple[int, ...] = ()

    @property
    def name(self) -> str:
        return pick_name(self.names)

    @property
    def selector(self) -> str:
        """The exact ``VENDOR:PRODUCT:REVISION`` selector of this device."""
        return format_selector(self.vendor.id, self.product_code, self.revision)

    @property
    def dictionary(self) -> Dictionary | None:
        """The object dictionary (the first Profile that has one)."""
        for p in self.profiles:
            if p.dictionary is not None:
                return p.dictionary
        return None

    @property
    def pdos(self) -> list[Pdo]:
        return self.rx_pdos + self.tx_pdos

    @property
    def passive(self) -> bool:
        """A device without an EtherCAT Slave Controller: a passive terminal (end cap,
        potential feed).  ETG.2000 makes ``Type/@ProductCode`` optional; vendors describe
        such terminals with no ProductCode and nothing an ESC would have (Beckhoff's
        EL9011, EL9100: ``Type``, names, ``GroupType``).  A device that lacks a ProductCode
        but has SyncManagers, FMMUs, PDOs, a mailbox, DC, an EEPROM or slots is not
        passive: its identity is missing."""
        return self.product_code is None and not (
            self.sms or self.fmmus or self.rx_pdos or self.tx_pdos or self.mailbox
            or self.dc or self.eeprom or self.slots)

    @property
    def device_emulation(self) -> bool:
        """The ESC mirrors AL control into AL status itself (no firmware sets it): bit 0 of
        the ESC configuration, the high byte of SII word 0, which the ESC loads into 0x0141
        (ESC doc Section II, 0x0141; ``docs/protocol-notes.md`` §2).  Read from the ESI's
        ``Eeprom/ConfigData`` (or its whole image, ``Eeprom/Data``); without either, no."""
        eep = self.eeprom
        word0 = eep and (eep.config_data or eep.data)
        return bool(word0 and len(word0) >= 2 and word0[1] & ESC_DEVICE_EMULATION)

    def sm_by_type(self, sm_type: str) -> list[SyncManager]:
        return [sm for sm in self.sms if sm.type == sm_type]

    def default_sm(self, direction: str) -> SyncManager | None:
        """The process-data SyncManager of a PDO direction (``rx`` = outputs, ``tx`` =
        inputs): the first non-virtual ``Outputs`` or ``Inputs`` SM.  A PDO without ``Sm``,
        or whose ``Sm`` is not of its direction, is assigned here."""
        wanted = "Outputs" if direction == "rx" else "Inputs"
        return next((sm for sm in self.sms if sm.type == wanted and not sm.virtual), None)


@dataclass(slots=True)
class EsiFile:
    """One ESI file: root ``EtherCATInfo`` (devices) or ``EtherCATModule`` (module library)."""

    path: str
    root: str
    vendor: Vendor
    version: str | None = None
    groups: list[Group] = field(default_factory=list)
    devices: list[Device] = field(default_factory=list)
    modules: list[Module] = field(default_factory=list)
    info_references: list[tuple[str, Source]] = field(default_factory=list)
    # What ``problems`` and ``ignored`` give once every dictionary is read; the reader
    # adds a dictionary's when it reads it (on first use).
    _problems: list[ReadProblem] = field(default_factory=list)
    _ignored: list[IgnoredElement] = field(default_factory=list)

    @property
    def problems(self) -> list[ReadProblem]:
        """What the reader could not take as written, anywhere in the file (the
        dictionaries not read yet are read first; a file the library reads a device at a
        time holds the devices read so far, ``reader.FileReader``)."""
        self.read_dictionaries()
        return self._problems

    @property
    def ignored(self) -> list[IgnoredElement]:
        """The elements ETG.2000 does not define where they are, anywhere in the file (the
        dictionaries not read yet are read first)."""
        self.read_dictionaries()
        return self._ignored

    def group(self, type_: str | None) -> Group | None:
        return next((g for g in self.groups if g.type == type_), None)

    def profiles(self) -> list[Profile]:
        """Every Profile of the file's devices, then of its modules."""
        found = [p for dev in self.devices for p in dev.profiles]
        return found + [m.profile for m in self.modules if m.profile is not None]

    def read_dictionaries(self) -> EsiFile:
        """Read every object dictionary not read yet, so that ``problems`` and ``ignored``
        hold what the reader found in all of them."""
        for profile in self.profiles():
            if profile.dictionary_pending:
                _ = profile.dictionary
        return self


def format_selector(vendor: int | None, product: int | None, revision: int | None) -> str:
    parts = [vendor, product, revision]
    return ":".join("?" if p is None else f"0x{p:x}" for p in parts)
