"""The ETG.2000 schema verdict of an independent validator, the ``xmlschema`` package (pure
Python; it shares no code with libxml2, which lxml and so ``ecatcfg lint``'s XSD001 use).

Run as a script, it validates the files it is given and prints one JSON object per file:
``{"file": ..., "errors": [...]}``, each error with what ``tests/test_lint_corpus.py``
needs to match it with a lint finding:

* ``kind``: ``unexpected`` (a child the parent's content model rejects), ``incomplete``
  (an element whose required children are missing), ``value`` (a
  simple-type value), ``attribute`` (an attribute the type does not allow), ``keyref`` (a
  key reference without its key), or ``other``;
* ``line``: where libxml2 would report it: the rejected *child* for ``unexpected``
  (xmlschema reports the parent whose content it checked), else the element's line;
* ``parent_line`` (``unexpected``): the line of the parent whose content is rejected;
* ``tag``: the rejected child (``unexpected``) or the incomplete element;
* ``value`` and ``times`` (``keyref``): the missing key value and how often it is referenced
  (xmlschema reports a failed keyref once, on the element that holds the key, with "(N
  times)"); ``span``: the first and last line of
  the element's subtree;
* ``after_rejection``: the error lies in a child that comes at or after one its parent's
  content model rejected, or below such a child.  libxml2 stops validating an element's
  remaining children at the first one it rejects; xmlschema goes on.

Usage: ``python3 xsd_reference.py SCHEMA_DIR FILE...`` (the schema named after each file's
root element, ``EtherCATInfo.xsd`` or ``EtherCATModule.xsd``, from ``SCHEMA_DIR``).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any

import xmlschema
from lxml import etree

_UNEXPECTED = re.compile(r"Unexpected child with tag '([^']+)' at position (\d+)")
_INCOMPLETE = re.compile(r"The content of element '([^']+)' is not complete")
_KEYREF = re.compile(r"value \('([^']*)',\) not found for XsdKey.*?(?:\((\d+) times\))?$")


def _children(elem) -> list:
    return [c for c in elem if isinstance(c.tag, str)]


def _span(elem) -> tuple[int, int]:
    lines = [e.sourceline for e in elem.iter() if isinstance(e.tag, str)]
    return min(lines), max(lines)


def validate(schema: xmlschema.XMLSchema, tree: Any) -> list[dict]:
    raw = list(schema.iter_errors(tree))
    rejected: dict = {}                  # parent element -> index of its rejected child
    for e in raw:
        m = _UNEXPECTED.match(e.reason or "")
        if m and e.elem is not None:
            rejected[e.elem] = int(m.group(2)) - 1
    errors = []
    for e in raw:
        reason = e.reason or ""
        elem: Any = e.elem              # an lxml element: the tree given was lxml's
        out: dict = {"reason": reason, "line": elem.sourceline if elem is not None else None}
        if elem is not None:
            out["span"] = _span(elem)
        m = _UNEXPECTED.match(reason)
        k = _KEYREF.match(reason)
        if m and elem is not None:
            child = _children(elem)[int(m.group(2)) - 1]
            out.update(kind="unexpected", tag=m.group(1), line=child.sourceline,
                       parent_line=elem.sourceline)
        elif i := _INCOMPLETE.match(reason):
            out.update(kind="incomplete", tag=i.group(1))
        elif k:
            out.update(kind="keyref", value=k.group(1), times=int(k.group(2) or 1))
        elif reason.startswith("invalid value"):
            out["kind"] = "value"
        elif "attribute not allowed" in reason:
            out["kind"] = "attribute"
        else:
            out["kind"] = "other"
        out["after_rejection"] = _after_rejection(elem, rejected)
        errors.append(out)
    return errors


def _after_rejection(elem, rejected: dict) -> bool:
    node = elem
    while node is not None and node.getparent() is not None:
        parent = node.getparent()
        if parent in rejected and _children(parent).index(node) >= rejected[parent]:
            return True
        node = parent
    return False


def main(argv: list[str]) -> None:
    schema_dir, files = Path(argv[0]), argv[1:]
    schemas: dict[str, xmlschema.XMLSchema] = {}
    for name in files:
        tree = etree.parse(name)
        root = etree.QName(tree.getroot()).localname
        if root not in schemas:
            schemas[root] = xmlschema.XMLSchema(str(schema_dir / f"{root}.xsd"))
        print(json.dumps({"file": name, "errors": validate(schemas[root], tree)}))


if __name__ == "__main__":
    main(sys.argv[1:])
