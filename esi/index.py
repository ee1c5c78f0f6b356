"""Shallow per-file summaries: what ``ecatcfg devices`` lists and what selectors match against.

A summary is taken straight from the lxml tree (one pass over each Device's children, counts
done by lxml in C), not from the full model: listing the 16 MB corpus then costs little more
than parsing it, and the summary is small enough to cache as JSON (``esi.cache``).
Counts follow the ``devices --format json`` contract (``docs/architecture.md``):
``rx_pdos``/``tx_pdos`` are the Device's own RxPdo/TxPdo elements, ``rx_entries``/``tx_entries``
their Entry elements.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from lxml import etree

from ecatcfg.esi.model import ENGLISH, MAILBOX_PROTOCOLS
from ecatcfg.esi.reader import LIST_ROOT, check_root, documents
from ecatcfg.esi.values import parse_int

# Bump when the summary's fields change: old cache entries are then ignored.
SUMMARY_VERSION = 2      # 2: a device's own vendor_id (EtherCATInfoList)


@dataclass(slots=True)
class DeviceEntry:
    """One device as the library indexes it (not the full model: see ``Library.device``)."""

    file: str                 # the path as the user gave it (joined inside a given folder)
    line: int
    ordinal: int              # position among the file's Device elements
    vendor_id: int | None
    product_code: int | None
    revision: int | None
    type: str
    name: str
    group: str
    rx_pdos: int
    tx_pdos: int
    rx_entries: int
    tx_entries: int
    mailbox: list[str]
    dc_opmodes: list[str]
    slots: int
    modules: int              # modules available to the slots (own file + module libraries)

    def as_json(self) -> dict[str, Any]:
        data = asdict(self)
        del data["ordinal"]
        return data


@dataclass(slots=True)
class FileSummary:
    """What one ESI file holds, independent of where it lies (cached by content hash)."""

    root: str
    vendor_id: int | None
    vendor_name: str
    devices: list[dict[str, Any]] = field(default_factory=list)
    modules: int = 0
    info_references: list[str] = field(default_factory=list)
    errors: list[tuple[int, str]] = field(default_factory=list)   # (line, message)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: object) -> FileSummary:
        """The summary :meth:`to_json` gave, read back from a cache file.  Anything else (a
        field missing or of another type, a device record without its ``name``: a damaged
        or foreign file) is a ``ValueError``, so the cache treats it as absent and the file
        is summarized again, instead of a ``KeyError`` in every later run."""
        if not isinstance(data, dict) or set(data) != _SUMMARY_FIELDS:
            raise ValueError("not a file summary of this layout")
        _check(data, _SUMMARY_VALUES, "summary")
        for d in data["devices"]:
            if not isinstance(d, dict) or set(d) != set(DEVICE_VALUES):
                raise ValueError("a device record of another layout")
            _check(d, DEVICE_VALUES, "device")
        for e in data["errors"]:
            if not (isinstance(e, list) and len(e) == 2 and _is(e[0], "int")
                    and _is(e[1], "str")):
                raise ValueError("an error record is not [line, message]")
        summary = cls(**data)
        summary.errors = [(line, msg) for line, msg in summary.errors]
        return summary


# What each value of a summary and of its device records (``_device``) is, checked when a
# cached summary is read back (``FileSummary.from_json``).  JSON's true/false are Python
# bools, which are ints too: a bool is never an "int" here.
_Kind = Literal["int", "int?", "str", "strs", "list"]
DEVICE_VALUES: dict[str, _Kind] = {
    "line": "int", "ordinal": "int", "product_code": "int?", "revision": "int?",
    "type": "str", "name": "str", "group": "str", "rx_pdos": "int", "tx_pdos": "int",
    "rx_entries": "int", "tx_entries": "int", "mailbox": "strs", "dc_opmodes": "strs",
    "slots": "int",
}
_SUMMARY_VALUES: dict[str, _Kind] = {
    "root": "str", "vendor_id": "int?", "vendor_name": "str", "devices": "list",
    "modules": "int", "info_references": "strs", "errors": "list",
}
_SUMMARY_FIELDS = set(_SUMMARY_VALUES)


def _is(value: object, kind: _Kind) -> bool:
    if kind == "int?" and value is None:
        return True
    if kind in ("int", "int?"):
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "str":
        return isinstance(value, str)
    if kind == "strs":
        return isinstance(value, list) and all(isinstance(v, str) for v in value)
    return isinstance(value, list)


def _check(record: dict[str, Any], kinds: dict[str, _Kind], what: str) -> None:
    for key, kind in kinds.items():
        if not _is(record[key], kind):
            raise ValueError(f"{what} field {key!r} is not {kind}")


def summarize(tree: etree._ElementTree, file: str) -> FileSummary:
    root = tree.getroot()
    check_root(root, file)
    errors: list[tuple[int, str]] = []

    def number(raw: str | None, el: etree._Element, what: str) -> int | None:
        if raw is None:
            return None
        try:
            return parse_int(raw)
        except ValueError as exc:
            errors.append((el.sourceline or 0, f"{what}: {exc}"))
            return None

    def vendor(doc: etree._Element) -> tuple[int | None, str]:
        vendor_el = doc.find("Vendor")
        vendor_id, vendor_name = None, ""
        if vendor_el is not None:
            id_el = vendor_el.find("Id")
            if id_el is not None:
                vendor_id = number(id_el.text, id_el, "Vendor/Id")
            vendor_name = _english(vendor_el.findall("Name"))
        return vendor_id, vendor_name

    docs = documents(root)
    vendor_id, vendor_name = vendor(docs[0]) if docs else (None, "")
    summary = FileSummary(str(root.tag), vendor_id, vendor_name, errors=errors)
    summary.info_references = [(el.text or "").strip() for doc in docs
                               for el in doc.iterfind("InfoReference")]
    if root.tag == "EtherCATModule":
        summary.modules = len(root.findall("Modules/Module"))
        return summary
    ordinal = 0
    for doc in docs:
        summary.modules += len(doc.findall("Descriptions/Modules/Module"))
        own = vendor(doc)[0] if root.tag == LIST_ROOT else vendor_id
        for dev in doc.iterfind("Descriptions/Devices/Device"):
            device = _device(dev, ordinal, number)
            device["vendor_id"] = own
            summary.devices.append(device)
            ordinal += 1
    return summary


def _device(dev: etree._Element, ordinal: int,
            number: Callable[[str | None, etree._Element, str], int | None]) -> dict[str, Any]:
    d: dict[str, Any] = {
        "line": dev.sourceline or 0, "ordinal": ordinal, "product_code": None,
        "revision": None, "type": "", "name": "", "group": "", "rx_pdos": 0, "tx_pdos": 0,
        "rx_entries": 0, "tx_entries": 0, "mailbox": [], "dc_opmodes": [], "slots": 0,
    }
    names = []
    for ch in dev:
        tag = ch.tag
        if tag == "RxPdo":
            d["rx_pdos"] += 1
            d["rx_entries"] += len(ch.findall("Entry"))
        elif tag == "TxPdo":
            d["tx_pdos"] += 1
            d["tx_entries"] += len(ch.findall("Entry"))
        elif tag == "Type":
            d["type"] = (ch.text or "").strip()
            d["product_code"] = number(ch.get("ProductCode"), ch, "Type/@ProductCode")
            d["revision"] = number(ch.get("RevisionNo"), ch, "Type/@RevisionNo")
        elif tag == "Name":
            names.append(ch)
        elif tag == "GroupType":
            d["group"] = (ch.text or "").strip()
        elif tag == "Mailbox":
            d["mailbox"] = [p.tag for p in ch if p.tag in MAILBOX_PROTOCOLS]
        elif tag == "Dc":
            d["dc_opmodes"] = [(m.findtext("Name") or "").strip() for m in ch.iterfind("OpMode")]
        elif tag == "Slots":
            d["slots"] = len(ch.findall("Slot"))
    d["name"] = _english(names)
    return d


def _english(names: list[etree._Element]) -> str:
    """The English (LcId 1033, or no LcId) text of a list of NameType elements."""
    first = None
    for el in names:
        text = (el.text or "").strip()
        lcid = el.get("LcId")
        if lcid is None or lcid.strip() == str(ENGLISH):
            return text
        if first is None:
            first = text
    return first or ""
