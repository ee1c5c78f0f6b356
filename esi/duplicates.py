"""Whether two ESI Device elements with one identity describe the same device, and how not.

Several files can describe one vendor, product and revision (two downloads of a vendor's
family file, a vendor's own builds of one product with different PDO sets).  A master
configured from the wrong one gets a wrong process image, so the library compares them
(``esi/library.py``) and lint reports them across files (ESI007, ESI008).

What is compared is the Device element as the ETG.2000 schema (EtherCATInfo.xsd) gives it,
normalised, not the file's bytes and not our parsed model: an element the reader does not
model still counts, so a file we have not seen cannot hide a difference from us.  Left out
are the parts that do not change what a master does on the wire: localised display texts
(the schema's ``NameType`` elements: names, comments, descriptions, URLs, except the names
that identify something, see ``_NAMING_PARENTS``), images, the catalogue group, the tool hints
``HideType`` and ``AlternativeType``, diagnosis texts and ``VendorSpecific`` blocks (tool data
a generic master does not act on).  Numbers compare by value (``#x1A00`` = ``6656``) and
booleans by truth (``true`` = ``1``); surrounding white space, XML comments and attribute
order do not count.  Element order does (SyncManager and FMMU numbers are positions).

A device with slots takes its modules from the file (``Descriptions/Modules``) and from
module libraries named by ``InfoReference``: those modules and references are compared too.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from lxml import etree

from ecatcfg.esi import reader
from ecatcfg.esi.values import parse_int

# Display-only elements, anywhere in a Device (ETG.2000 EtherCATInfo.xsd, EtherCATBase.xsd).
_DESCRIPTIVE = frozenset((
    "Comment", "Desc", "Description", "DisplayName", "URL", "DescriptionURL", "Hint",
    "Image16x14", "ImageFile16x14", "ImageData16x14", "GroupType", "HideType",
    "AlternativeType", "VendorSpecific", "DiagMessages", "DiagFile",
))
# ``Name`` is a display text (NameType) except where it is what other parts refer to: a DC
# op mode is chosen by name (topology ``dc``), a data type is referred to by its name from
# objects and subitems, and a subitem's name is how arrays and records list their members.
_NAMING_PARENTS = frozenset(("OpMode", "DataType", "SubItem"))
_BOOLEAN_WORDS = {"true": "1", "false": "0"}

Node = tuple[str, tuple[tuple[str, str], ...], str, tuple["Node", ...]]   # tag, attrs, text, kids


def _value(text: str) -> str:
    """A value as compared: numbers by value, booleans by truth, white space trimmed."""
    s = text.strip()
    if not s:
        return ""
    word = _BOOLEAN_WORDS.get(s.lower())
    if word is not None:
        return word
    try:
        return str(parse_int(s))
    except ValueError:
        return s


def _keep(el: etree._Element, parent_tag: str) -> bool:
    tag = el.tag
    if not isinstance(tag, str) or tag in _DESCRIPTIVE:
        return False
    return tag != "Name" or parent_tag in _NAMING_PARENTS


def node(el: etree._Element) -> Node:
    """The normalised form of an element (see the module docstring)."""
    tag = str(el.tag)
    kids = tuple(node(ch) for ch in el if _keep(ch, tag))
    attrs = tuple(sorted((str(k), _value(v)) for k, v in el.attrib.items()))
    return tag, attrs, _value(el.text or "") if not kids else "", kids


@dataclass(frozen=True, slots=True)
class Description:
    """One Device element, normalised, with the modules its slots can take."""

    device: Node
    modules: tuple[Node, ...] = ()          # the file's Module elements (devices with slots)
    references: tuple[str, ...] = ()        # its file's InfoReference names (ditto)
    _digest: str = field(default="", init=False, repr=False, compare=False)

    @property
    def digest(self) -> str:
        # Computed once: the repr of a drive's Device element with its dictionary is
        # megabytes, and the library compares one description for every slave that uses it.
        if not self._digest:
            object.__setattr__(self, "_digest", hashlib.blake2b(
                repr((self.device, self.modules, self.references)).encode(),
                digest_size=16).hexdigest())
        return self._digest


def describe(device: etree._Element) -> Description:
    """The Description of a Device element of a parsed (namespace-stripped) ESI tree."""
    dev = node(device)
    if not any(k[0] == "Slots" for k in dev[3]):
        return Description(dev)
    root = device.getroottree().getroot()
    return Description(dev, tuple(node(m) for m in root.iterfind("Descriptions/Modules/Module")),
                       tuple(_value(r.text or "") for r in root.iterfind("InfoReference")))


def device_elements(tree: etree._ElementTree) -> list[etree._Element]:
    """The Device elements of a file, in the order the library numbers them (``ordinal``)."""
    return reader.device_elements(tree.getroot())


# -- what differs ------------------------------------------------------------------------------

def differences(a: Description, b: Description, name_a: str, name_b: str,
                limit: int = 4) -> list[str]:
    """What differs between two descriptions, in a few words each (``TxPdo 0x1A00 entries
    differ``, ``Sm count 4 vs 2``, ``dictionary: object 0x8000 only in A``); at most
    ``limit`` items, the last saying how many more there are."""
    found = list(_device_diffs(a.device, b.device, name_a, name_b))
    found += _keyed(a.modules, b.modules, "module", _module_key, name_a, name_b)
    if a.references != b.references:
        found.append("InfoReference module libraries differ")
    if len(found) > limit:
        found = found[:limit - 1] + [f"{len(found) - limit + 1} more"]
    return found


def _child(n: Node, tag: str) -> Node | None:
    return next((k for k in n[3] if k[0] == tag), None)


def _children(n: Node, tag: str) -> list[Node]:
    return [k for k in n[3] if k[0] == tag]


def _text_of(n: Node, tag: str) -> str:
    ch = _child(n, tag)
    return ch[2] if ch is not None else ""


def _hex(text: str) -> str:
    try:
        return f"0x{int(text):04X}"
    except ValueError:
        return text or "?"


def _index_key(n: Node) -> str:
    return _hex(_text_of(n, "Index"))


def _module_key(n: Node) -> str:
    t = _child(n, "Type")
    ident = dict(t[1]).get("ModuleIdent", "") if t is not None else ""
    return _hex(ident) if ident else (t[2] if t is not None else "?")


def _keyed(a: tuple[Node, ...] | list[Node], b: tuple[Node, ...] | list[Node], what: str,
           key: Callable[[Node], str], name_a: str, name_b: str,
           detail: str | None = None) -> list[str]:
    """Elements matched by a key (a PDO's or object's index): those only on one side, and
    those that differ (``detail``: a child tag whose difference is named, e.g. Entry), each
    kind in one item (``3 objects only in A: 0x1000, 0x1008, 0x1009``)."""
    da: dict[str, Node] = {}
    db: dict[str, Node] = {}
    for n in a:
        da.setdefault(key(n), n)
    for n in b:
        db.setdefault(key(n), n)
    if len(da) != len(a) or len(db) != len(b):        # a key used twice: compare as lists
        return [f"{what} list differs"] if tuple(a) != tuple(b) else []
    only_a = [k for k in da if k not in db]
    only_b = [k for k in db if k not in da]
    changed = [k for k in da if k in db and da[k] != db[k]]
    in_detail = [k for k in changed if detail is not None
                 and _children(da[k], detail) != _children(db[k], detail)]
    out = [_items(what, keys, f"only in {name}") for keys, name in
           ((only_a, name_a), (only_b, name_b)) if keys]
    if in_detail:
        out.append(_items(what, in_detail, "entries differ" if detail == "Entry"
                          else f"{str(detail).lower()} lists differ", plural_verb=False))
    rest = [k for k in changed if k not in in_detail]
    if rest:
        out.append(_items(what, rest, "differ" if len(rest) > 1 else "differs",
                          plural_verb=False))
    return out


def _items(what: str, keys: list[str], said: str, plural_verb: bool = True) -> str:
    """``TxPdo 0x1A00 only in A``; ``3 objects only in A: 0x1000, 0x1008, 0x1009``;
    ``TxPdo 0x1A00, 0x1A01 entries differ``."""
    shown = ", ".join(keys[:4]) + (", ..." if len(keys) > 4 else "")
    if len(keys) == 1:
        return f"{what} {keys[0]} {said}"
    if plural_verb:
        return f"{len(keys)} {what}s {said}: {shown}"
    return f"{what} {shown} {said}" if len(keys) <= 4 else f"{len(keys)} {what}s {said}: {shown}"


def _counted(a: list[Node], b: list[Node], what: str) -> list[str]:
    """Elements whose position is their number (SyncManagers, FMMUs)."""
    if len(a) != len(b):
        return [f"{what} count {len(a)} vs {len(b)}"]
    changed = [str(i) for i, (x, y) in enumerate(zip(a, b)) if x != y]
    return [f"{what} {', '.join(changed)} {'differ' if len(changed) > 1 else 'differs'}"] \
        if changed else []


def _device_diffs(a: Node, b: Node, name_a: str, name_b: str) -> Iterator[str]:
    tags: list[str] = []
    for k in a[3] + b[3]:
        if k[0] not in tags:
            tags.append(k[0])
    if a[1] != b[1]:
        yield "Device attributes differ"
    for tag in tags:
        xa, xb = _children(a, tag), _children(b, tag)
        if xa == xb:
            continue
        if tag in ("RxPdo", "TxPdo"):
            yield from _keyed(xa, xb, tag, _index_key, name_a, name_b, "Entry")
        elif tag in ("Sm", "Fmmu"):
            yield from _counted(xa, xb, tag)
        elif tag == "Profile" and len(xa) == len(xb) == 1:
            yield from _profile(xa[0], xb[0], name_a, name_b)
        elif tag == "Type" and len(xa) == len(xb) == 1 and xa[0][1] == xb[0][1]:
            yield f"Type name {xa[0][2]!r} vs {xb[0][2]!r}"
        elif len(xa) == len(xb) == 1:
            yield _first_difference(xa[0], xb[0], tag)
        elif not xa or not xb:
            yield f"{tag} only in {name_a if xa else name_b}"
        else:
            yield f"{tag} count {len(xa)} vs {len(xb)}" if len(xa) != len(xb) \
                else f"{tag} differs"


def _profile(a: Node, b: Node, name_a: str, name_b: str) -> Iterator[str]:
    dic_a, dic_b = _child(a, "Dictionary"), _child(b, "Dictionary")
    rest_a = tuple(k for k in a[3] if k[0] != "Dictionary")
    rest_b = tuple(k for k in b[3] if k[0] != "Dictionary")
    if rest_a != rest_b or a[1] != b[1]:
        yield "Profile differs (outside the dictionary)"
    if dic_a == dic_b:
        return
    if dic_a is None or dic_b is None:
        yield f"dictionary only in {name_a if dic_a is not None else name_b}"
        return
    objects = [_child(d, "Objects") for d in (dic_a, dic_b)]
    yield from (f"dictionary: {x}" for x in _keyed(
        _children(objects[0], "Object") if objects[0] else [],
        _children(objects[1], "Object") if objects[1] else [],
        "object", _index_key, name_a, name_b))
    types = [_child(d, "DataTypes") for d in (dic_a, dic_b)]
    yield from (f"dictionary: {x}" for x in _keyed(
        _children(types[0], "DataType") if types[0] else [],
        _children(types[1], "DataType") if types[1] else [],
        "data type", lambda n: _text_of(n, "Name") or "?", name_a, name_b))
    other_a = tuple(k for k in dic_a[3] if k[0] not in ("Objects", "DataTypes"))
    other_b = tuple(k for k in dic_b[3] if k[0] not in ("Objects", "DataTypes"))
    if other_a != other_b:
        yield "dictionary differs (outside objects and data types)"


def _first_difference(a: Node, b: Node, path: str) -> str:
    """``Mailbox/CoE/InitCmd differs``: the path down to the first element that differs."""
    while a[1] == b[1] and a[2] == b[2] and len(a[3]) == len(b[3]):
        pairs = [(x, y) for x, y in zip(a[3], b[3]) if x != y]
        if not pairs:
            break
        a, b = pairs[0]
        if a[0] != b[0]:
            break
        path += f"/{a[0]}"
    return f"{path} differs"
