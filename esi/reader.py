"""ETG.2000 reader: an ESI file (lxml tree) -> :class:`~ecatcfg.esi.model.EsiFile`.

One pass over each element's children, dispatching on the tag.  Values are converted with
``esi.values``; a value that cannot be read becomes ``None`` plus a :class:`ReadProblem` with
the file and line, so one bad default deep in a dictionary does not cost the whole file.
Elements that ETG.2000 does not define at that place are kept as :class:`IgnoredElement`
for lint; elements the schema defines but a configurator does not need (images, URLs,
diagnosis texts, vendor-specific blocks) are skipped silently.
"""

from __future__ import annotations

import gc
import threading
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from lxml import etree

from ecatcfg.errors import EcatcfgError
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.model import (
    Access, ArrayInfo, CoeInitCmd, CoeSettings, DataType, DataTypeSubItem, Dc, DcOpMode,
    Device, DeviceInfo, DictObject, Dictionary, Eeprom, EoeSettings, EsiFile, Fmmu, Group,
    IgnoredElement, Mailbox, MAILBOX_PROTOCOLS, Module, ModulePdoGroup, ObjectFlags,
    ObjectInfo, Pdo, PdoEntry, Profile, ProblemKind, ReadProblem, Severity, Slot, SlotGroup,
    Slots, SoeInitCmd, SoeSettings, Source, STATES, SyncManager, Vendor, sm_type_from_control,
)
from ecatcfg.esi.values import INT64_MIN, UINT64_MAX, parse_bool, parse_hex_bytes, parse_int

ROOTS = ("EtherCATInfo", "EtherCATModule", "EtherCATInfoList")
# IgH's ``ethercat xml`` writes what it reads from the slaves' SII as one EtherCATInfo per
# slave, inside <EtherCATInfoList> when there are several (tool/CommandXml.cpp): the file is
# read as the list of its documents.
LIST_ROOT = "EtherCATInfoList"


def documents(root: etree._Element) -> list[etree._Element]:
    """The ESI documents of a file: the root, or a list's EtherCATInfo children."""
    if root.tag == LIST_ROOT:
        return [el for el in root.iterchildren("EtherCATInfo")]
    return [root]


def device_elements(root: etree._Element) -> list[etree._Element]:
    """Every Device of the file's documents, in file order (the ``ordinal`` of the index)."""
    return [dev for doc in documents(root) for dev in doc.iterfind("Descriptions/Devices/Device")]

# Children that ETG.2000 (EtherCATInfo.xsd / EtherCATBase.xsd, version 1.17) allows at each
# place but that this reader does not model.  A child in neither this set nor the reader's own
# dispatch is reported as an IgnoredElement.
_SKIPPED: dict[str, frozenset[str]] = {
    "EtherCATInfo": frozenset(),
    "Vendor": frozenset(("Comment", "URL", "DescriptionURL", "Image16x14", "ImageFile16x14",
                         "ImageData16x14", "VendorSpecific")),
    "Descriptions": frozenset(),
    "Group": frozenset(("Comment", "Image16x14", "ImageFile16x14", "ImageData16x14",
                        "VendorSpecific")),
    "Device": frozenset(("Sci", "HideType", "AlternativeType", "SubDevice", "Comment", "URL",
                         "Su", "ESC", "Image16x14", "ImageFile16x14", "ImageData16x14",
                         "VendorSpecific")),
    "Info": frozenset(("Electrical", "EtherCATController", "Port", "ExecutionUnit",
                       "VendorSpecific", "StationAliasSupported", "DeviceFeature")),
    "Pdo": frozenset(("ExcludedSm",)),
    "Entry": frozenset(("Comment",)),
    "Mailbox": frozenset(("VendorSpecific",)),
    "CoE": frozenset(("Object",)),
    "SoE": frozenset(("DiagFile", "DiagMessages")),      # text for a diagnosis display
    "InitCmd": frozenset(),
    "Dc": frozenset(("VendorSpecific",)),
    "OpMode": frozenset(("Sm",)),
    "Eeprom": frozenset(("VendorSpecific",)),
    "Profile": frozenset(("SubAddInfo", "ChannelCount", "ChannelInfo", "DiagFile",
                          "DiagMessages", "VendorSpecific")),
    "Dictionary": frozenset(("UnitTypes",)),
    "DataType": frozenset(("Comment", "Properties", "Xml")),
    "SubItem": frozenset(("DisplayName", "Comment", "DefaultString", "DefaultData", "MinValue",
                          "MaxValue", "DefaultValue", "Property", "Xml")),
    "Object": frozenset(("Comment", "Properties", "Xml")),
    "ObjectInfo": frozenset(("DisplayName", "Unit")),
    "Flags": frozenset(("SafetyMapping", "Attribute", "Transition")),
    "Slots": frozenset(("SlotSelections",)),
    "SlotGroupData": frozenset(("ImageFile16x14", "ImageData16x14")),
    "Slot": frozenset(("Image16x14", "ImageFile16x14", "ImageData16x14")),
    "Module": frozenset(("SafetyParaMapping", "Image16x14", "ImageFile16x14",
                         "ImageData16x14", "VendorSpecific")),
}

# What each number field can hold, by the name the reader gives it: a number outside is a
# ReadProblem at its line (the field then reads as absent), never a value later code cannot
# use (a negative length packed as unsigned, a 4000-digit number printed, a 2**48-bit object
# allocated).  Fields not listed hold what 64 bits hold (esi/values.py).  The widths are the
# ones the value ends up in on the wire or in the slave:
MAX_SUBINDEX = 0xFF
_U8, _U16, _U32 = (0, 0xFF), (0, 0xFFFF), (0, 0xFFFF_FFFF)
# Identity numbers: 32-bit (SII words 0x08..0x0F, objects 0x1018:01..03, ETG.1000.6); some
# tools write them as signed decimal, so the negative half is read as written too.
_IDENTITY = (-(1 << 31), 0xFFFF_FFFF)
# An object's size: ETG.1000.6 sets no bound below segmented SDO's UNSIGNED32 byte count;
# ours is 65535 bytes (524280 bits) per object, entry, type and offset, what a 16-bit byte
# count holds, which the largest objects vendors describe stay under (Beckhoff EK10xx: an
# ARRAY of 64008 bytes) and which keeps an emulated dictionary's memory bounded; an array
# has no more elements than bits.  A subindex is an UNSIGNED8 (ETG.1000.6 5.6.2).
_BITS = (0, 0xFFFF * 8)
_RANGES: dict[str, tuple[int, int]] = {
    "Vendor/Id": _IDENTITY, "Type/@ProductCode": _IDENTITY, "Type/@RevisionNo": _IDENTITY,
    # AL status/mailbox timeouts in ms (ETG.2000 Info/StateMachine, Info/Mailbox; UDINT).
    **{f"{kind}/Timeout/{name}": _U32 for kind in ("StateMachine", "Mailbox")
       for name in ("PreopTimeout", "SafeopOpTimeout", "BackToInitTimeout",
                    "BackToSafeopTimeout", "RequestTimeout", "ResponseTimeout")},
    "Info/IdentificationAdo": _U16,                     # an ESC register address
    # SyncManager registers 0x0800+8n (ETG.1000.4 6.7.2): start address and length are
    # 16 bits, control and enable one byte each.
    "Sm/@StartAddress": _U16, "Sm/@DefaultSize": _U16, "Sm/@MinSize": _U16,
    "Sm/@MaxSize": _U16, "Sm/@ControlByte": _U8, "Sm/@Enable": _U8,
    # An ESC has at most 16 SyncManagers and 16 FMMUs (ETG.1000.4 6.6, 6.7).
    "Fmmu/@Sm": (0, 15), "RxPdo/@Sm": (0, 15), "TxPdo/@Sm": (0, 15),
    "Fmmu/@Su": _U8, "RxPdo/@Su": _U8, "TxPdo/@Su": _U8,
    # A PDO mapping entry (objects 0x1600/0x1A00, ETG.1000.6 5.6.7.4.7) is index:16,
    # subindex:8, bit length:8; a PDO is an object index.  BitLen is read up to 16 bits:
    # lint ESI113 says why 256..65535 cannot be mapped (and stops compile).
    "RxPdo/Index": _U16, "TxPdo/Index": _U16, "RxPdo/Exclude": _U16, "TxPdo/Exclude": _U16,
    "Entry/Index": _U16, "Entry/SubIndex": _U8, "Entry/BitLen": _U16,
    "InitCmd/Index": _U16, "InitCmd/SubIndex": _U8,
    "SoE/InitCmd/IDN": _U16, "SoE/InitCmd/@Chn": _U8, "SoE/@ChannelCount": _U8,
    "OpMode/AssignActivate": _U16,                      # register 0x0980, 16 bits
    "Category/CatNo": _U16,                             # SII category type (ETG.2010)
    # Object 0x1000 device type: profile number in the low word, additional info in the
    # high word (ETG.1000.6 5.6.7.4.1).
    "Profile/ProfileNo": _U16, "Profile/AddInfo": _U16,
    "DataType/BitSize": _BITS, "SubItem/BitSize": _BITS, "Object/BitSize": _BITS,
    "SubItem/BitOffs": _BITS, "DataType/Index": _U16, "Object/Index": _U16,
    "SubItem/SubIdx": _U8, "ArrayInfo/LBound": _U8, "ArrayInfo/Elements": _BITS,
    "Type/@ModuleIdent": _IDENTITY,
    # A slot group's number moves object indices (16 bits) by number x increment.
    "SlotGroupData/@SlotGroup": _U16, "Slot/@SlotGroup": _U16,
}

_ANY = (INT64_MIN, UINT64_MAX)
_STATE_BY_LOWER = {s.lower(): s for s in STATES}
_new_source = tuple.__new__     # Source(...) without NamedTuple's Python-level __new__


class EsiReadError(EcatcfgError):
    """A file that cannot be read as an ESI file at all (not XML, wrong root element)."""


def read_file(path: str | Path, shown_as: str | None = None) -> EsiFile:
    """Read one ESI file or module library into the model."""
    name = shown_as or str(path)
    return read_tree(xmlsafe.parse_file(path, name), name)


def element_spans(tree: etree._ElementTree, path: str) -> list[tuple[int, int | None]]:
    """(first line, first line after it) of each element at ``path`` below the root, in
    document order (``None``: it runs to the end of the file)."""
    spans: list[tuple[int, int | None]] = []
    for el in tree.getroot().iterfind(path):
        node: etree._Element | None = el
        end: int | None = None
        while node is not None and end is None:
            nxt = node.getnext()
            if nxt is not None:
                end = nxt.sourceline
            node = node.getparent()
        spans.append((el.sourceline or 0, end))
    return spans


@dataclass(frozen=True, slots=True)
class ElementSpans:
    """Where each Device and Module element of a file lies (``element_spans``): what lint
    ties a finding's line to."""

    devices: list[tuple[int, int | None]]
    modules: list[tuple[int, int | None]]


def spans_of(tree: etree._ElementTree) -> ElementSpans:
    """The spans of a parsed, namespace-stripped ESI tree's Device and Module elements."""
    within = "EtherCATInfo/" if tree.getroot().tag == LIST_ROOT else ""
    return ElementSpans(element_spans(tree, f"{within}Descriptions/Devices/Device"),
                        element_spans(tree, f"{within}Descriptions/Modules/Module")
                        + element_spans(tree, "Modules/Module"))


def read_bytes(data: bytes, shown_as: str) -> EsiFile:
    return read_tree(xmlsafe.parse_bytes(data, shown_as), shown_as)


def read_tree(tree: etree._ElementTree, file: str) -> EsiFile:
    root = tree.getroot()
    check_root(root, file)
    # A big file makes ~100k small objects and no cycles; the cyclic GC would otherwise
    # rescan the growing heap dozens of times (measured: ~20% of a full corpus read).
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        if root.tag != LIST_ROOT:
            return _Reader(file).read_root(root)
        return _read_list(root, file)
    finally:
        if was_enabled:
            gc.enable()


class FileReader:
    """One file's model, its Device elements read one by one when asked for.

    A compile uses one or two devices of a Beckhoff family file of 24 to 124: everything
    else of the file (vendor, groups, modules, references) is read at once, each Device
    when :meth:`device` asks for it, all of them by :meth:`model`.  ``esi`` is the file
    with the devices read so far, in file order; its ``problems`` and ``ignored`` hold
    those of the parts read.  An EtherCATInfoList (several documents, each with its own
    vendor) is read whole at once."""

    def __init__(self, tree: etree._ElementTree, file: str) -> None:
        root = tree.getroot()
        check_root(root, file)
        # The Device elements not read yet (``None`` once read: what is read lets its
        # element, and at last the tree, go).
        self._elements: list[etree._Element | None] = []
        self._devices: dict[int, Device] = {}
        self._lock = threading.Lock()
        if root.tag == LIST_ROOT:
            self.esi = read_tree(tree, file)
            self._devices = dict(enumerate(self.esi.devices))
            self._elements = [None] * len(self._devices)
        else:
            self._reader = _Reader(file)
            later: list[etree._Element] = []
            with _gc_paused():
                self.esi = self._reader.read_root(root, later)
            self._reader.later = None
            self._elements = list(later)

    def device(self, ordinal: int) -> Device:
        """The Device ``ordinal`` of the file (``device_elements`` order), read once."""
        dev = self._devices.get(ordinal)
        if dev is None:
            with self._lock:            # two threads: one reads it, both get that one
                dev = self._devices.get(ordinal)
                el = self._elements[ordinal]
                if dev is None and el is not None:
                    with _gc_paused():
                        dev = self._reader.device(el, self.esi.vendor)
                    dev.vendor = self.esi.vendor
                    self._devices[ordinal] = dev
                    self._elements[ordinal] = None
                    self.esi.devices = [self._devices[i] for i in sorted(self._devices)]
        assert dev is not None
        return dev

    def model(self) -> EsiFile:
        """The whole file: every Device read (those read already are kept)."""
        if len(self._devices) < len(self._elements):
            for ordinal in range(len(self._elements)):
                self.device(ordinal)
        return self.esi


class _gc_paused:
    """The cyclic GC off while a model is read (see ``read_tree``)."""

    def __enter__(self) -> None:
        self.was_enabled = gc.isenabled()
        gc.disable()

    def __exit__(self, *exc: object) -> None:
        if self.was_enabled:
            gc.enable()


def _read_list(root: etree._Element, file: str) -> EsiFile:
    """An EtherCATInfoList as one file of all its documents' devices, each with its own
    vendor (``Device.vendor``); the file's vendor is the first document's."""
    # One list of problems and ignored elements for all documents: a dictionary read later
    # adds to the file's.
    problems: list[ReadProblem] = []
    ignored: list[IgnoredElement] = []
    docs = [_Reader(file, problems, ignored).read_root(doc) for doc in documents(root)]
    first = docs[0].vendor if docs else Vendor(None, {}, _new_source(Source, (file, 1)))
    esi = EsiFile(file, LIST_ROOT, first, version=root.get("Version"))
    for doc in docs:
        esi.groups += doc.groups
        esi.devices += doc.devices
        esi.info_references += doc.info_references
    esi._problems = problems
    esi._ignored = ignored
    return esi


def check_root(root: etree._Element, file: str) -> None:
    if root.tag not in ROOTS:
        raise EsiReadError(f"root element is <{root.tag!s}>, expected <EtherCATInfo>, "
                           "<EtherCATModule> or <EtherCATInfoList>: not an ESI file", file,
                           root.sourceline)
    if root.tag == LIST_ROOT:
        for el in root:
            if isinstance(el.tag, str) and el.tag != "EtherCATInfo":
                raise EsiReadError(f"<{el.tag}> in an <EtherCATInfoList>: a list holds "
                                   "<EtherCATInfo> documents", file, el.sourceline)


def text_of(el: etree._Element) -> str:
    return (el.text or "").strip()


class _Reader:
    """Reads one file; collects problems and ignored elements as it goes."""

    def __init__(self, file: str, problems: list[ReadProblem] | None = None,
                 ignored: list[IgnoredElement] | None = None) -> None:
        self.file = file
        # The file's lists (``EsiFile.problems``, ``ignored``): a dictionary read on first
        # use (``Profile.read_later``) adds to them then.
        self.problems: list[ReadProblem] = [] if problems is None else problems
        self.ignored: list[IgnoredElement] = [] if ignored is None else ignored
        self.later: list[etree._Element] | None = None

    # -- values ---------------------------------------------------------------------------

    def src(self, el: etree._Element) -> Source:
        # Inlined as `_new_source(Source, (self.file, el.sourceline or 0))` in the dictionary
        # readers, which run ~100k times on the corpus.
        return _new_source(Source, (self.file, el.sourceline or 0))

    def _problem(self, el: etree._Element, what: str, exc: ValueError,
                 severity: Severity, kind: ProblemKind = "number") -> None:
        self.problems.append(ReadProblem(self.src(el), f"{what}: {exc}", severity, kind=kind))

    # int_/bool_/hex_ are the hot path of a full read (~150k calls on the corpus): kept flat.
    def int_(self, raw: str | None, el: etree._Element, what: str,
             severity: Severity = "warning") -> int | None:
        if raw is None:
            return None
        try:
            return parse_int(raw, *_RANGES.get(what, _ANY))
        except ValueError as exc:
            self._problem(el, what, exc, severity)
            return None

    def bool_(self, raw: str | None, el: etree._Element, what: str,
              default: bool = False) -> bool:
        if raw is None:
            return default
        try:
            return parse_bool(raw)
        except ValueError as exc:
            self._problem(el, what, exc, "warning", "flag")
            return default

    def hex_(self, raw: str | None, el: etree._Element, what: str) -> bytes | None:
        if raw is None:
            return None
        try:
            return parse_hex_bytes(raw)
        except ValueError as exc:
            self._problem(el, what, exc, "warning", "data")
            return None

    def unknown(self, ch: etree._Element, context: str, parent: etree._Element) -> None:
        """Record ``ch`` unless ETG.2000 allows it here (or it is a comment/PI)."""
        tag = ch.tag
        if isinstance(tag, str) and tag not in _SKIPPED[context]:
            self.ignored.append(IgnoredElement(self.src(ch), tag, str(parent.tag)))

    @staticmethod
    def add_name(names: dict[int, str], el: etree._Element) -> None:
        lcid = el.get("LcId")
        key = 1033
        if lcid is not None:
            try:
                key = int(lcid)
            except ValueError:
                pass
        names.setdefault(key, text_of(el))

    # -- file level -----------------------------------------------------------------------

    def read_root(self, root: etree._Element,
                  later: list[etree._Element] | None = None) -> EsiFile:
        """The file; ``later``: its Device elements are put there, not read (``FileReader``)."""
        self.later = later
        vendor = Vendor(None, {}, self.src(root))
        esi = EsiFile(self.file, str(root.tag), vendor, version=root.get("Version"))
        for ch in root:
            tag = ch.tag
            if tag == "Vendor":
                esi.vendor = vendor = self.vendor(ch)
            elif tag == "InfoReference":
                esi.info_references.append((text_of(ch), self.src(ch)))
            elif tag == "Descriptions":
                self.descriptions(ch, esi)
            elif tag == "Modules" and root.tag == "EtherCATModule":
                esi.modules.extend(self.module(m) for m in ch if m.tag == "Module")
            else:
                self.unknown(ch, "EtherCATInfo", root)
        for dev in esi.devices:
            dev.vendor = vendor
        esi._problems = self.problems
        esi._ignored = self.ignored
        return esi

    def vendor(self, el: etree._Element) -> Vendor:
        vendor = Vendor(None, {}, self.src(el))
        for ch in el:
            if ch.tag == "Id":
                vendor.id = self.int_(ch.text, ch, "Vendor/Id", "error")
            elif ch.tag == "Name":
                self.add_name(vendor.names, ch)
            else:
                self.unknown(ch, "Vendor", el)
        return vendor

    def descriptions(self, el: etree._Element, esi: EsiFile) -> None:
        for ch in el:
            tag = ch.tag
            if tag == "Groups":
                for g in ch:
                    if g.tag == "Group":
                        esi.groups.append(self.group(g))
                    else:
                        self.unknown(g, "Descriptions", ch)
            elif tag == "Devices":
                for d in ch:
                    if d.tag == "Device":
                        if self.later is not None:
                            self.later.append(d)
                        else:
                            esi.devices.append(self.device(d, esi.vendor))
                    else:
                        self.unknown(d, "Descriptions", ch)
            elif tag == "Modules":
                for m in ch:
                    if m.tag == "Module":
                        esi.modules.append(self.module(m))
                    else:
                        self.unknown(m, "Descriptions", ch)
            else:
                self.unknown(ch, "Descriptions", el)

    def group(self, el: etree._Element) -> Group:
        group = Group("", {}, self.src(el))
        for ch in el:
            if ch.tag == "Type":
                group.type = text_of(ch)
            elif ch.tag == "Name":
                self.add_name(group.names, ch)
            else:
                self.unknown(ch, "Group", el)
        return group

    # -- device ---------------------------------------------------------------------------

    def device(self, el: etree._Element, vendor: Vendor) -> Device:
        dev = Device("", None, None, {}, self.src(el), vendor, physics=el.get("Physics"))
        for ch in el:
            tag = ch.tag
            if tag == "RxPdo" or tag == "TxPdo":
                pdo = self.pdo(ch)
                (dev.rx_pdos if tag == "RxPdo" else dev.tx_pdos).append(pdo)
            elif tag == "Sm":
                dev.sms.append(self.sm(ch, len(dev.sms)))
            elif tag == "Fmmu":
                dev.fmmus.append(self.fmmu(ch, len(dev.fmmus)))
            elif tag == "Type":
                dev.type_name = text_of(ch)
                dev.product_code = self.int_(ch.get("ProductCode"), ch, "Type/@ProductCode",
                                             "error")
                dev.revision = self.int_(ch.get("RevisionNo"), ch, "Type/@RevisionNo", "error")
                dev.module_pdo_group = self.int_(ch.get("ModulePdoGroup"), ch,
                                                 "Type/@ModulePdoGroup")
                dev.use_lrd_lwr = self.bool_(ch.get("UseLrdLwr"), ch, "Type/@UseLrdLwr")
            elif tag == "Name":
                self.add_name(dev.names, ch)
            elif tag == "GroupType":
                dev.group_type = text_of(ch)
            elif tag == "Info":
                dev.info = self.info(ch)
            elif tag == "Mailbox":
                dev.mailbox = self.mailbox(ch)
            elif tag == "Dc":
                dev.dc = self.dc(ch)
            elif tag == "Eeprom":
                dev.eeprom = self.eeprom(ch)
            elif tag == "Profile":
                dev.profiles.append(self.profile(ch))
            elif tag == "Slots":
                dev.slots = self.slots(ch)
            else:
                self.unknown(ch, "Device", el)
        for sm in dev.sms:
            if sm.type is None and sm.control_byte is not None:
                # An Sm without type text: its control byte says what the ESC does with it.
                named = any(p.sm == sm.number for p in dev.rx_pdos + dev.tx_pdos)
                sm.type = sm_type_from_control(sm.control_byte, named)
                sm.type_from_control = True
        return dev

    def info(self, el: etree._Element) -> DeviceInfo:
        info = DeviceInfo(self.src(el))
        for ch in el:
            tag = ch.tag
            if tag == "StateMachine":
                for t in ch.iterfind("Timeout/*"):
                    name = str(t.tag)
                    attr = _STATE_TIMEOUTS.get(name)
                    if attr:
                        setattr(info, attr, self.int_(t.text, t, f"StateMachine/Timeout/{name}"))
            elif tag == "Mailbox":
                for t in ch.iterfind("Timeout/*"):
                    name = str(t.tag)
                    attr = _MAILBOX_TIMEOUTS.get(name)
                    if attr:
                        setattr(info, attr, self.int_(t.text, t, f"Mailbox/Timeout/{name}"))
            elif tag == "IdentificationAdo":
                info.identification_ado = self.int_(ch.text, ch, "Info/IdentificationAdo")
            elif tag == "IdentificationReg134":
                info.identification_reg134 = self.bool_(ch.text, ch,
                                                        "Info/IdentificationReg134")
            else:
                if tag == "Electrical":
                    cur = ch.find("EBusCurrent")
                    if cur is not None:
                        info.ebus_current = self.int_(cur.text, cur, "Electrical/EBusCurrent")
                self.unknown(ch, "Info", el)
        return info

    def sm(self, el: etree._Element, number: int) -> SyncManager:
        g = el.get
        return SyncManager(
            number=number,
            type=text_of(el) or None,
            source=self.src(el),
            start_address=self.int_(g("StartAddress"), el, "Sm/@StartAddress"),
            control_byte=self.int_(g("ControlByte"), el, "Sm/@ControlByte"),
            default_size=self.int_(g("DefaultSize"), el, "Sm/@DefaultSize"),
            min_size=self.int_(g("MinSize"), el, "Sm/@MinSize"),
            max_size=self.int_(g("MaxSize"), el, "Sm/@MaxSize"),
            enable=self.enable(g("Enable"), el),
            op_only=self.bool_(g("OpOnly"), el, "Sm/@OpOnly"),
            virtual=self.bool_(g("Virtual"), el, "Sm/@Virtual"),
            watchdog=(None if g("Watchdog") is None
                      else self.bool_(g("Watchdog"), el, "Sm/@Watchdog")),
            one_byte_mode=self.bool_(g("OneByteMode"), el, "Sm/@OneByteMode"),
            fixed_assignment=self.bool_(g("FixedAssignment"), el, "Sm/@FixedAssignment"),
        )

    def enable(self, raw: str | None, el: etree._Element) -> int | None:
        """Sm/@Enable: a HexDecValue in the schema, but a flag; ``true``/``false`` occur."""
        if raw is not None and raw.strip().lower() in ("true", "false"):
            return int(parse_bool(raw))
        return self.int_(raw, el, "Sm/@Enable")

    def fmmu(self, el: etree._Element, number: int) -> Fmmu:
        return Fmmu(number, text_of(el) or None, self.src(el),
                    sm=self.int_(el.get("Sm"), el, "Fmmu/@Sm"),
                    su=self.int_(el.get("Su"), el, "Fmmu/@Su"),
                    op_only=self.bool_(el.get("OpOnly"), el, "Fmmu/@OpOnly"))

    def pdo(self, el: etree._Element) -> Pdo:
        g = el.get
        tag = str(el.tag)
        pdo = Pdo("rx" if tag == "RxPdo" else "tx", None, {}, self.src(el),
                  sm=self.int_(g("Sm"), el, f"{tag}/@Sm"),
                  su=self.int_(g("Su"), el, f"{tag}/@Su"),
                  fixed=self.bool_(g("Fixed"), el, f"{tag}/@Fixed"),
                  mandatory=self.bool_(g("Mandatory"), el, f"{tag}/@Mandatory"),
                  virtual=self.bool_(g("Virtual"), el, f"{tag}/@Virtual"),
                  os_fac=self.int_(g("OSFac"), el, f"{tag}/@OSFac"),
                  os_min=self.int_(g("OSMin"), el, f"{tag}/@OSMin"),
                  os_max=self.int_(g("OSMax"), el, f"{tag}/@OSMax"),
                  os_index_inc=self.int_(g("OSIndexInc"), el, f"{tag}/@OSIndexInc"),
                  pdo_order=self.int_(g("PdoOrder"), el, f"{tag}/@PdoOrder"),
                  overwritten_by_module=self.bool_(g("OverwrittenByModule"), el,
                                                   f"{tag}/@OverwrittenByModule"))
        for ch in el:
            ctag = ch.tag
            if ctag == "Entry":
                pdo.entries.append(self.entry(ch))
            elif ctag == "Index":
                pdo.index = self.int_(ch.text, ch, f"{tag}/Index", "error")
                pdo.depend_on_slot = self.bool_(ch.get("DependOnSlot"), ch, "@DependOnSlot")
                pdo.depend_on_slot_group = self.bool_(ch.get("DependOnSlotGroup"), ch,
                                                      "@DependOnSlotGroup")
            elif ctag == "Name":
                self.add_name(pdo.names, ch)
            elif ctag == "Exclude":
                value = self.int_(ch.text, ch, f"{tag}/Exclude")
                if value is not None:
                    pdo.excludes.append(value)
                    if ch.get("DependOnSlot") is not None \
                            or ch.get("DependOnSlotGroup") is not None:
                        pdo.exclude_depends[value] = (
                            self.bool_(ch.get("DependOnSlot"), ch, "@DependOnSlot"),
                            self.bool_(ch.get("DependOnSlotGroup"), ch, "@DependOnSlotGroup"))
            else:
                self.unknown(ch, "Pdo", el)
        return pdo

    def entry(self, el: etree._Element) -> PdoEntry:
        entry = PdoEntry(None, None, None, None, {}, _new_source(Source, (self.file, el.sourceline or 0)))
        for ch in el:
            tag = ch.tag
            if tag == "Index":
                entry.index = self.int_(ch.text, ch, "Entry/Index", "error")
                if ch.get("DependOnSlot") is not None:
                    entry.depend_on_slot = self.bool_(ch.get("DependOnSlot"), ch,
                                                      "@DependOnSlot")
                entry.depend_on_slot_group = self.bool_(ch.get("DependOnSlotGroup"), ch,
                                                        "@DependOnSlotGroup")
            # A SubIndex of at most two digits, a BitLen of at most four, are within
            # their ranges (_RANGES): taken as they are (~13k entries on the corpus).
            elif tag == "SubIndex":
                t = ch.text
                if t is not None and len(t) <= 2 and t.isdigit() and t.isascii():
                    entry.subindex = int(t)
                else:
                    entry.subindex = self.int_(t, ch, "Entry/SubIndex", "error")
            elif tag == "BitLen":
                t = ch.text
                if t is not None and len(t) <= 4 and t.isdigit() and t.isascii():
                    entry.bit_len = int(t)
                else:
                    entry.bit_len = self.int_(t, ch, "Entry/BitLen", "error")
            elif tag == "DataType":
                entry.data_type = (ch.text or "").strip()
            elif tag == "Name":
                self.add_name(entry.names, ch)
            else:
                self.unknown(ch, "Entry", el)
        return entry

    def mailbox(self, el: etree._Element) -> Mailbox:
        mbx = Mailbox([], self.src(el),
                      data_link_layer=self.bool_(el.get("DataLinkLayer"), el,
                                                 "Mailbox/@DataLinkLayer"))
        for ch in el:
            tag = ch.tag
            if tag in MAILBOX_PROTOCOLS:
                mbx.protocols.append(tag)
                if tag == "CoE":
                    mbx.coe = self.coe(ch)
                elif tag == "EoE":
                    mbx.eoe = self.eoe(ch)
                elif tag == "SoE":
                    mbx.soe = self.soe(ch)
            else:
                self.unknown(ch, "Mailbox", el)
        return mbx

    def eoe(self, el: etree._Element) -> EoeSettings:
        def flag(name: str) -> bool | None:
            raw = el.get(name)
            return None if raw is None else self.bool_(raw, el, f"EoE/@{name}")

        return EoeSettings(self.src(el), ip=flag("IP"), mac=flag("MAC"),
                           timestamp=flag("TimeStamp"),
                           init_cmds=[self.src(ch) for ch in el if ch.tag == "InitCmd"])

    def soe(self, el: etree._Element) -> SoeSettings:
        soe = SoeSettings(self.src(el),
                          channel_count=self.int_(el.get("ChannelCount"), el,
                                                  "SoE/@ChannelCount"),
                          drive_follows_bit3=(
                              None if el.get("DriveFollowsBit3Support") is None else
                              self.bool_(el.get("DriveFollowsBit3Support"), el,
                                         "SoE/@DriveFollowsBit3Support")))
        for ch in el:
            if ch.tag == "InitCmd":
                soe.init_cmds.append(self.soe_init_cmd(ch))
            else:
                self.unknown(ch, "SoE", el)
        return soe

    def soe_init_cmd(self, el: etree._Element) -> SoeInitCmd:
        cmd = SoeInitCmd([], None, None, self.src(el),
                         channel=self.int_(el.get("Chn"), el, "SoE/InitCmd/@Chn") or 0)
        for ch in el:
            tag = ch.tag
            if tag == "Transition":
                cmd.transitions.append(text_of(ch))
            elif tag == "IDN":
                cmd.idn = self.int_(ch.text, ch, "SoE/InitCmd/IDN", "error")
            elif tag == "Data":
                cmd.data = self.hex_(ch.text or "", ch, "SoE/InitCmd/Data")
            elif tag == "Comment":
                cmd.comment = text_of(ch)
            else:
                self.unknown(ch, "InitCmd", el)
        return cmd

    def coe(self, el: etree._Element) -> CoeSettings:
        g = el.get
        coe = CoeSettings(self.src(el),
                          sdo_info=self.bool_(g("SdoInfo"), el, "CoE/@SdoInfo"),
                          pdo_assign=self.bool_(g("PdoAssign"), el, "CoE/@PdoAssign"),
                          pdo_config=self.bool_(g("PdoConfig"), el, "CoE/@PdoConfig"),
                          pdo_upload=self.bool_(g("PdoUpload"), el, "CoE/@PdoUpload"),
                          complete_access=self.bool_(g("CompleteAccess"), el,
                                                     "CoE/@CompleteAccess"),
                          segmented_sdo=self.bool_(g("SegmentedSdo"), el, "CoE/@SegmentedSdo"))
        for ch in el:
            if ch.tag == "InitCmd":
                coe.init_cmds.append(self.coe_init_cmd(ch))
            else:
                self.unknown(ch, "CoE", el)
        return coe

    def coe_init_cmd(self, el: etree._Element) -> CoeInitCmd:
        cmd = CoeInitCmd([], None, None, None, self.src(el),
                         complete_access=self.bool_(el.get("CompleteAccess"), el,
                                                    "InitCmd/@CompleteAccess"),
                         fixed=self.bool_(el.get("Fixed"), el, "InitCmd/@Fixed"))
        for ch in el:
            tag = ch.tag
            if tag == "Transition":
                cmd.transitions.append(text_of(ch))
            elif tag == "Index":
                cmd.index = self.int_(ch.text, ch, "InitCmd/Index", "error")
                cmd.depend_on_slot = self.bool_(ch.get("DependOnSlot"), ch, "@DependOnSlot")
                cmd.depend_on_slot_group = self.bool_(ch.get("DependOnSlotGroup"), ch,
                                                      "@DependOnSlotGroup")
            elif tag == "SubIndex":
                cmd.subindex = self.int_(ch.text, ch, "InitCmd/SubIndex", "error")
            elif tag == "Data":
                cmd.data = self.hex_(ch.text or "", ch, "InitCmd/Data")
            elif tag == "Comment":
                cmd.comment = text_of(ch)
            else:
                self.unknown(ch, "InitCmd", el)
        return cmd

    def dc(self, el: etree._Element) -> Dc:
        dc = Dc([], self.src(el))
        for ch in el:
            if ch.tag == "OpMode":
                dc.opmodes.append(self.opmode(ch))
            else:
                self.unknown(ch, "Dc", el)
        return dc

    def opmode(self, el: etree._Element) -> DcOpMode:
        mode = DcOpMode("", self.src(el))
        for ch in el:
            tag = ch.tag
            if tag == "Name":
                mode.name = text_of(ch)
            elif tag == "Desc":
                mode.desc = text_of(ch)
            elif tag == "AssignActivate":
                mode.assign_activate = self.int_(ch.text, ch, "OpMode/AssignActivate")
            elif tag in _DC_TIMES:
                setattr(mode, _DC_TIMES[tag], self.int_(ch.text, ch, f"OpMode/{tag}"))
                if tag.startswith("CycleTime") and ch.get("Factor") is not None:
                    setattr(mode, _DC_TIMES[tag] + "_factor",
                            self.int_(ch.get("Factor"), ch, f"{tag}/@Factor"))
            elif tag == "VendorSpecific":
                tc = ch.find("TwinCAT")
                if tc is not None:
                    mode.use_from_build = self.int_(tc.get("UseFromBuildNo"), tc,
                                                    "TwinCAT/@UseFromBuildNo")
                    mode.ignore_from_build = self.int_(tc.get("IgnoreFromBuildNo"), tc,
                                                       "TwinCAT/@IgnoreFromBuildNo")
            else:
                self.unknown(ch, "OpMode", el)
        return mode

    def eeprom(self, el: etree._Element) -> Eeprom:
        eep = Eeprom(self.src(el), assign_to_pdi=self.bool_(el.get("AssignToPdi"), el,
                                                            "Eeprom/@AssignToPdi"))
        for ch in el:
            tag = ch.tag
            if tag == "ByteSize":
                eep.byte_size = self.int_(ch.text, ch, "Eeprom/ByteSize")
            elif tag == "ConfigData":
                eep.config_data = self.hex_(ch.text or "", ch, "Eeprom/ConfigData")
            elif tag == "BootStrap":
                eep.boot_strap = self.hex_(ch.text or "", ch, "Eeprom/BootStrap")
            elif tag == "Data":
                eep.data = self.hex_(ch.text or "", ch, "Eeprom/Data")
            elif tag == "Category":
                cat_no = self.int_(ch.findtext("CatNo"), ch, "Category/CatNo")
                data = self.hex_(ch.findtext("Data") or "", ch, "Category/Data")
                if cat_no is not None and data is not None:
                    eep.categories.append((cat_no, data))
            else:
                self.unknown(ch, "Eeprom", el)
        return eep

    # -- profile and dictionary ----------------------------------------------------------

    def profile(self, el: etree._Element) -> Profile:
        prof = Profile(self.src(el), channel=self.int_(el.get("Channel"), el, "@Channel"))
        dictionaries = []
        for ch in el:
            tag = ch.tag
            if tag == "ProfileNo":
                prof.profile_no = self.int_(ch.text, ch, "Profile/ProfileNo")
            elif tag == "AddInfo":
                prof.add_info = self.int_(ch.text, ch, "Profile/AddInfo")
            elif tag == "Dictionary":
                dictionaries.append(ch)
            elif tag == "DictionaryFile":
                prof.dictionary_file = text_of(ch)
            else:
                self.unknown(ch, "Profile", el)
        if dictionaries:
            # Read when first asked for (``Profile.dictionary``): the dictionaries are two
            # thirds of the reader's time over the corpus, and most devices' are never used.
            prof.read_later(partial(self.dictionaries, dictionaries))
        return prof

    def dictionaries(self, elements: list[etree._Element]) -> Dictionary:
        """A Profile's dictionary, read on first use (the last, if the element repeats;
        each one's problems are reported)."""
        with _gc_paused():                  # as in read_tree: many small acyclic objects
            return [self.dictionary(el) for el in elements][-1]

    def dictionary(self, el: etree._Element) -> Dictionary:
        dic = Dictionary({}, {}, self.src(el))
        for ch in el:
            tag = ch.tag
            if tag == "DataTypes":
                for dt in ch:
                    if dt.tag == "DataType":
                        d = self.data_type(dt)
                        dic.data_types.setdefault(d.name, d)
                    else:
                        self.unknown(dt, "Dictionary", ch)
            elif tag == "Objects":
                for ob in ch:
                    if ob.tag == "Object":
                        o = self.dict_object(ob)
                        if o.index is not None:
                            dic.objects.setdefault(o.index, o)
                    else:
                        self.unknown(ob, "Dictionary", ch)
            else:
                self.unknown(ch, "Dictionary", el)
        self.check_array_parts(dic)
        return dic

    def check_array_parts(self, dic: Dictionary) -> None:
        """A record's SubItem without SubIdx whose type is an array stands for one entry per
        element (esi.coe.lookup, the emulated dictionary); more elements than subindices
        1..255 (an UNSIGNED8, ETG.1000.6 5.6.2) cannot be entries of one object.  Such a
        SubItem is an error at its line and left out of the record (its entries could
        never be addressed)."""
        for dt in dic.data_types.values():
            kept = []
            for item in dt.sub_items:
                arr = dic.data_types.get(item.type) if item.subindex is None else None
                n = arr.array_info[0].elements if arr is not None and arr.array_info else 0
                if n > MAX_SUBINDEX:
                    self.problems.append(ReadProblem(
                        item.source, f"SubItem {item.name!r}: its type {item.type!r} has {n} "
                        f"elements: they do not fit the subindices 1..{MAX_SUBINDEX} of a record",
                        "error", kind="number"))
                    continue
                kept.append(item)
            dt.sub_items = kept

    # The dictionary readers below visit ~350 000 elements on the corpus (most of them the
    # DataType SubItems and the Object Info SubItems of the Beckhoff terminal files): each
    # record is made once from locals, and the common spellings are taken inline (a short
    # decimal number, hexBinary without white space); anything else goes through int_ and
    # hex_, which give the same value or the same ReadProblem as for any other element.

    def data_type(self, el: etree._Element) -> DataType:
        name = ""
        bit_size = index = None
        base_type: str | None = None
        array_info: list[ArrayInfo] = []
        sub_items: list[DataTypeSubItem] = []
        enums: dict[int, str] = {}
        sub_item = self.dt_sub_item
        for ch in el:
            tag = ch.tag
            if tag == "SubItem":
                sub_items.append(sub_item(ch))
            elif tag == "Name":
                name = (ch.text or "").strip()
            elif tag == "BitSize":
                bit_size = self.int_(ch.text, ch, "DataType/BitSize")
            elif tag == "BaseType":
                base_type = (ch.text or "").strip()
            elif tag == "Index":
                index = self.int_(ch.text, ch, "DataType/Index")
            elif tag == "ArrayInfo":
                lb = self.int_(ch.findtext("LBound"), ch, "ArrayInfo/LBound")
                n = self.int_(ch.findtext("Elements"), ch, "ArrayInfo/Elements")
                if lb is not None and n is not None:
                    if lb >= 1 and lb + n - 1 > MAX_SUBINDEX:
                        # LBound >= 1: a CoE array, one subindex per element (0 is the
                        # count); subindices are UNSIGNED8 (ETG.1000.6 5.6.2).
                        self.problems.append(ReadProblem(
                            self.src(ch), f"ArrayInfo: elements {lb}..{lb + n - 1} of a CoE "
                            f"array are subindices and do not fit 8 bits (1..{MAX_SUBINDEX})", "error",
                            kind="number"))
                    else:
                        array_info.append(ArrayInfo(lb, n))
            elif tag == "EnumInfo":
                value = self.int_(ch.findtext("Enum"), ch, "EnumInfo/Enum")
                if value is not None:
                    enums[value] = (ch.findtext("Text") or "").strip()
            else:
                self.unknown(ch, "DataType", el)
        return DataType(name, bit_size, _new_source(Source, (self.file, el.sourceline or 0)),
                        base_type, index, array_info, sub_items, enums)

    def dt_sub_item(self, el: etree._Element) -> DataTypeSubItem:
        subindex = bit_size = bit_offset = None
        name = type_ = ""
        flags = None
        for ch in el:
            tag = ch.tag
            # A SubIdx of at most two digits, a BitSize or BitOffs of at most five, are
            # within their ranges (_RANGES): taken as they are.
            if tag == "SubIdx":
                t = ch.text
                if t is not None and len(t) <= 2 and t.isdigit() and t.isascii():
                    subindex = int(t)
                else:
                    subindex = self.int_(t, ch, "SubItem/SubIdx")
            elif tag == "Name":
                name = (ch.text or "").strip()
            elif tag == "Type":
                type_ = (ch.text or "").strip()
            elif tag == "BitSize":
                t = ch.text
                if t is not None and len(t) <= 5 and t.isdigit() and t.isascii():
                    bit_size = int(t)
                else:
                    bit_size = self.int_(t, ch, "SubItem/BitSize")
            elif tag == "BitOffs":
                t = ch.text
                if t is not None and len(t) <= 5 and t.isdigit() and t.isascii():
                    bit_offset = int(t)
                else:
                    bit_offset = self.int_(t, ch, "SubItem/BitOffs")
            elif tag == "Flags":
                flags = self.flags(ch)
            else:
                self.unknown(ch, "SubItem", el)
        return DataTypeSubItem(subindex, name, type_, bit_size, bit_offset, flags,
                               _new_source(Source, (self.file, el.sourceline or 0)))

    def dict_object(self, el: etree._Element) -> DictObject:
        obj = DictObject(None, {}, "", None, _new_source(Source, (self.file, el.sourceline or 0)))
        for ch in el:
            tag = ch.tag
            if tag == "Index":
                obj.index = self.int_(ch.text, ch, "Object/Index", "error")
                if ch.get("DependOnSlot") is not None:
                    obj.depend_on_slot = self.bool_(ch.get("DependOnSlot"), ch,
                                                    "@DependOnSlot")
                obj.depend_on_slot_group = self.bool_(ch.get("DependOnSlotGroup"), ch,
                                                      "@DependOnSlotGroup")
            elif tag == "Name":
                self.add_name(obj.names, ch)
            elif tag == "Type":
                obj.type = (ch.text or "").strip()
            elif tag == "BitSize":
                obj.bit_size = self.int_(ch.text, ch, "Object/BitSize")
            elif tag == "Info":
                obj.info = self.object_info(ch)
            elif tag == "Flags":
                obj.flags = self.flags(ch)
            else:
                self.unknown(ch, "Object", el)
        return obj

    def object_info(self, el: etree._Element) -> ObjectInfo:
        default_data = min_data = max_data = None
        default_value = min_value = max_value = None
        default_string = None
        sub_items: list[tuple[str, ObjectInfo]] = []
        for ch in el:
            tag = ch.tag
            if tag == "SubItem":
                name, sub = "", None
                for part in ch:
                    ptag = part.tag
                    if ptag == "Name":
                        name = part.text or ""
                    elif ptag == "Info":
                        sub = self.object_info(part)
                sub_items.append((name, ObjectInfo() if sub is None else sub))
            elif tag == "DefaultData":
                # bytes.fromhex takes what parse_hex_bytes takes when the digits come in
                # pairs, and refuses the rest (white space inside a pair, bad digits),
                # which hex_ then reads or reports.
                t = ch.text or ""
                try:
                    default_data = bytes.fromhex(t)
                except ValueError:
                    default_data = self.hex_(t, ch, "Info/DefaultData")
            elif tag == "DefaultValue":
                default_value = self.int_(ch.text, ch, "Info/DefaultValue")
            elif tag == "DefaultString":
                default_string = ch.text or ""
            elif tag == "MinValue":
                min_value = self.int_(ch.text, ch, "Info/MinValue")
            elif tag == "MaxValue":
                max_value = self.int_(ch.text, ch, "Info/MaxValue")
            elif tag == "MinData":
                min_data = self.hex_(ch.text or "", ch, "Info/MinData")
            elif tag == "MaxData":
                max_data = self.hex_(ch.text or "", ch, "Info/MaxData")
            else:
                self.unknown(ch, "ObjectInfo", el)
        return ObjectInfo(default_data, default_value, default_string, min_value, max_value,
                          min_data, max_data, sub_items,
                          _new_source(Source, (self.file, el.sourceline or 0)))

    def flags(self, el: etree._Element) -> ObjectFlags:
        access = category = pdo_mapping = sdo_access = None
        backup = setting = None
        for ch in el:
            tag = ch.tag
            if tag == "Access":
                if ch.get("ReadRestrictions") is None and ch.get("WriteRestrictions") is None:
                    access = Access((ch.text or "").strip().lower())    # the common case
                else:
                    access = self.access(ch)
            elif tag == "Category":
                category = (ch.text or "").strip()
            elif tag == "PdoMapping":
                pdo_mapping = (ch.text or "").strip().upper()
            elif tag == "SdoAccess":
                sdo_access = (ch.text or "").strip()
            elif tag == "Backup":
                backup = self.int_(ch.text, ch, "Flags/Backup")
            elif tag == "Setting":
                setting = self.int_(ch.text, ch, "Flags/Setting")
            else:
                self.unknown(ch, "Flags", el)
        return ObjectFlags(access, category, pdo_mapping, sdo_access, backup, setting,
                           _new_source(Source, (self.file, el.sourceline or 0)))

    def access(self, el: etree._Element) -> Access:
        read_raw, write_raw = el.get("ReadRestrictions"), el.get("WriteRestrictions")
        acc = Access((el.text or "").strip().lower())
        for attr, raw in (("ReadRestrictions", read_raw), ("WriteRestrictions", write_raw)):
            if raw is None:
                continue
            states = []
            for part in raw.strip().split("_"):
                state = _STATE_BY_LOWER.get(part.lower())
                if state is None:
                    self.problems.append(ReadProblem(
                        self.src(el), f"Access/@{attr}: unknown state {part!r} in {raw!r}",
                        kind="text"))
                else:
                    states.append(state)
            if attr == "ReadRestrictions":
                acc.read_states = frozenset(states)
            else:
                acc.write_states = frozenset(states)
        return acc

    # -- modular devices ------------------------------------------------------------------

    def slots(self, el: etree._Element) -> Slots:
        slots = Slots([], self.src(el),
                      slot_pdo_increment=self.int_(el.get("SlotPdoIncrement"), el,
                                                   "Slots/@SlotPdoIncrement"),
                      slot_index_increment=self.int_(el.get("SlotIndexIncrement"), el,
                                                     "Slots/@SlotIndexIncrement"),
                      slot_group_pdo_increment=self.int_(
                          el.get("SlotGroupPdoIncrement"), el, "Slots/@SlotGroupPdoIncrement"),
                      slot_group_index_increment=self.int_(
                          el.get("SlotGroupIndexIncrement"), el,
                          "Slots/@SlotGroupIndexIncrement"),
                      download_module_ident_list=self.bool_(
                          el.get("DownloadModuleIdentList"), el,
                          "Slots/@DownloadModuleIdentList"),
                      download_transition=(el.get("DownloadModuleListTransition")
                                           or "PS").strip())
        for ch in el:
            if ch.tag == "Slot":
                slots.slots.append(self.slot(ch))
            elif ch.tag == "ModulePdoGroup":
                slots.pdo_groups.append(ModulePdoGroup(
                    self.int_(ch.get("RxPdo"), ch, "ModulePdoGroup/@RxPdo"),
                    self.int_(ch.get("TxPdo"), ch, "ModulePdoGroup/@TxPdo"),
                    self.int_(ch.get("Alignment"), ch, "ModulePdoGroup/@Alignment")))
            elif ch.tag == "SlotGroupData":
                slots.groups.append(self.slot_group(ch))
            else:
                self.unknown(ch, "Slots", el)
        return slots

    def slot(self, el: etree._Element) -> Slot:
        g = el.get
        slot = Slot({}, self.src(el),
                    min_instances=self.int_(g("MinInstances"), el, "Slot/@MinInstances"),
                    max_instances=self.int_(g("MaxInstances"), el, "Slot/@MaxInstances"),
                    default_ident=self.int_(g("Default"), el, "Slot/@Default"),
                    slot_pdo_increment=self.int_(g("SlotPdoIncrement"), el,
                                                 "Slot/@SlotPdoIncrement"),
                    slot_index_increment=self.int_(g("SlotIndexIncrement"), el,
                                                   "Slot/@SlotIndexIncrement"),
                    slot_group=self.int_(g("SlotGroup"), el, "Slot/@SlotGroup"),
                    slot_group_pdo_increment=self.int_(g("SlotGroupPdoIncrement"), el,
                                                       "Slot/@SlotGroupPdoIncrement"),
                    slot_group_index_increment=self.int_(g("SlotGroupIndexIncrement"), el,
                                                         "Slot/@SlotGroupIndexIncrement"))
        for ch in el:
            tag = ch.tag
            if tag == "ModuleIdent":
                ident = self.int_(ch.text, ch, "Slot/ModuleIdent")
                if ident is not None:
                    slot.module_idents.append(ident)
                    if ch.get("Default") is not None and \
                            self.bool_(ch.get("Default"), ch, "ModuleIdent/@Default"):
                        slot.default_ident = ident
            elif tag == "ModuleClass":
                slot.module_classes.append((ch.findtext("Class") or "").strip())
            elif tag == "Name":
                self.add_name(slot.names, ch)
            else:
                self.unknown(ch, "Slot", el)
        return slot

    def slot_group(self, el: etree._Element) -> SlotGroup:
        """Slots/SlotGroupData: its number (required: a group without one cannot be told
        from another, a ReadProblem at its line) and its names; its image is for people."""
        raw = el.get("SlotGroup")
        number = self.int_(raw, el, "SlotGroupData/@SlotGroup", "error")
        if raw is None:
            self.problems.append(ReadProblem(self.src(el), "SlotGroupData has no SlotGroup "
                                             "number", "error"))
        group = SlotGroup(number, {}, self.src(el))
        for ch in el:
            if ch.tag == "Name":
                self.add_name(group.names, ch)
            else:
                self.unknown(ch, "SlotGroupData", el)
        return group

    def module(self, el: etree._Element) -> Module:
        mod = Module(None, "", {}, self.src(el))
        for ch in el:
            tag = ch.tag
            if tag == "Type":
                mod.type_name = text_of(ch)
                mod.ident = self.int_(ch.get("ModuleIdent"), ch, "Type/@ModuleIdent", "error")
                mod.module_class = ch.get("ModuleClass")
                mod.pdo_group = self.int_(ch.get("ModulePdoGroup"), ch, "@ModulePdoGroup")
            elif tag == "Name":
                self.add_name(mod.names, ch)
            elif tag == "RxPdo":
                mod.rx_pdos.append(self.pdo(ch))
            elif tag == "TxPdo":
                mod.tx_pdos.append(self.pdo(ch))
            elif tag == "Mailbox":
                mod.mailbox = self.mailbox(ch)
            elif tag == "Profile":
                mod.profile = self.profile(ch)
            elif tag == "DcOpModeName":
                mod.dc_opmode_name = text_of(ch)
            else:
                self.unknown(ch, "Module", el)
        return mod


_STATE_TIMEOUTS = {
    "PreopTimeout": "preop_timeout",
    "SafeopOpTimeout": "safeop_op_timeout",
    "BackToInitTimeout": "back_to_init_timeout",
    "BackToSafeopTimeout": "back_to_safeop_timeout",
}
_MAILBOX_TIMEOUTS = {
    "RequestTimeout": "mailbox_request_timeout",
    "ResponseTimeout": "mailbox_response_timeout",
}
_DC_TIMES = {
    "CycleTimeSync0": "cycle_time_sync0",
    "ShiftTimeSync0": "shift_time_sync0",
    "CycleTimeSync1": "cycle_time_sync1",
    "ShiftTimeSync1": "shift_time_sync1",
}
