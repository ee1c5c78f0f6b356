"""Safe XML parsing for files that come from outside (ESI now, ENI later).

No external entities, no DTD loading, no network; libxml2's amplification limit stops
entity-expansion bombs at once, and any entity declaration is refused outright: ETG files never
need one, and an unexpanded entity would silently lose data.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from lxml import etree

from ecatcfg.errors import EcatcfgError
from ecatcfg.fileio import read_input

if TYPE_CHECKING:                   # the opaque result of resolve_*(), named only in the stubs
    from lxml.etree._docloader import _InputDocument


class XmlError(EcatcfgError):
    """A file that is not well-formed or not safe to read."""


class _RefuseExternal(etree.Resolver):
    """Answers every request for an external resource (a DOCTYPE's DTD, an external entity)
    with an empty document: libxml2 asks even with ``load_dtd=False``, and would otherwise
    open the named local file."""

    def resolve(self, system_url: str | None, public_id: str | None,
                context: object) -> _InputDocument:
        return self.resolve_string("", context)


def _parser() -> etree.XMLParser:
    parser = etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,       # keep libxml2's size and depth limits
        remove_blank_text=False,
        collect_ids=False,
    )
    parser.resolvers.add(_RefuseExternal())
    return parser


_PARSER = _parser()
_POSITION = re.compile(r",? line \d+, column \d+$")


def parse_bytes(data: bytes, file: str, strip: bool = True) -> etree._ElementTree:
    """Parse a whole document held in memory; ``file`` is only used in messages.

    ``strip=False`` keeps a default namespace (for schema validation); call
    :func:`strip_namespaces` before reading the tree as ESI.
    """
    try:
        root = etree.fromstring(data, _PARSER)
    except etree.XMLSyntaxError as exc:
        line, column = exc.position if exc.position else (exc.lineno, None)
        message = _POSITION.sub("", exc.msg)      # the location is reported separately
        encoding = "encoding" in message or "UTF-8" in message
        raise (_not_utf8(data, file) if encoding else None) or XmlError(
            f"not well-formed XML: {message}", file, line or None, column or None) from None
    tree = root.getroottree()
    if tree.docinfo.system_url or tree.docinfo.public_id:
        at = data.find(b"<!DOCTYPE")
        raise XmlError("the document refers to an external DTD "
                       f"({tree.docinfo.system_url or tree.docinfo.public_id!r}); ESI files need "
                       "none and external references are not followed",
                       file, data.count(b"\n", 0, at) + 1 if at >= 0 else 1)
    dtd = tree.docinfo.internalDTD
    if dtd is not None:
        for entity in dtd.iterentities():
            at = data.find(b"<!ENTITY")
            raise XmlError(f"the document declares the entity {entity.name!r}; entity "
                           "declarations are not allowed (possible XXE or entity bomb)",
                           file, data.count(b"\n", 0, at) + 1 if at >= 0 else 1)
    if strip:
        strip_namespaces(tree)
    return tree


_DECLARED_ENCODING = re.compile(rb"^\s*<\?xml[^>]*\bencoding\s*=", re.S)
_BOMS = (b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff")


def _not_utf8(data: bytes, file: str) -> XmlError | None:
    """A document that declares no encoding is UTF-8 (XML 1.0 §4.3.3); one that is not,
    such as IgH's ``ethercat xml`` output with a raw Latin-1 "µ" from a slave's SII, is
    refused at the first byte that is not UTF-8, with its line and column and the fix.
    ``None`` when the file declares an encoding or is UTF-8 (another error)."""
    if _DECLARED_ENCODING.match(data) or data.startswith(_BOMS):
        return None
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        at = exc.start
        line = data.count(b"\n", 0, at) + 1
        column = at - (data.rfind(b"\n", 0, at) + 1) + 1
        latin = data[at:at + 1].decode("latin-1")
        return XmlError(
            f"byte 0x{data[at]:02X} is not UTF-8, and the file declares no encoding "
            f"(in Latin-1 it would be {latin!r}); if the file is Latin-1, as IgH's ethercat "
            "xml writes a slave's names, declare it: <?xml version=\"1.0\" "
            "encoding=\"ISO-8859-1\"?>", file, line, column)
    return None


def read_file(path: str | Path, shown_as: str | None = None) -> bytes:
    """The content of ``path``; a failure is an :class:`XmlError` naming ``shown_as``."""
    name = shown_as or str(path)
    try:
        return read_input(path, name)
    except OSError as exc:
        raise XmlError(f"cannot read: {exc.strerror}", name) from None


def parse_file(path: str | Path, shown_as: str | None = None) -> etree._ElementTree:
    """Read and parse ``path``; errors name ``shown_as`` (the path as the user gave it)."""
    name = shown_as or str(path)
    return parse_bytes(read_file(path, name), name)


def strip_namespaces(tree: etree._ElementTree) -> None:
    """ESI elements carry no namespace; a few generators add a default one anyway."""
    root = tree.getroot()
    if not (isinstance(root.tag, str) and root.tag.startswith("{")):
        return
    for el in root.iter():
        tag = el.tag
        if isinstance(tag, str) and tag[0] == "{":
            el.tag = tag.rpartition("}")[2]
