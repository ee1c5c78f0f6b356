"""XSD001: validation against the ETG.2000 schema set the user points at (``--schema-dir``).

The schemas are ETG's and never ship with ecatcfg.  The file for a document is chosen by its
root element: ``EtherCATInfo.xsd`` or ``EtherCATModule.xsd`` in that folder (they include
``EtherCATBase.xsd`` from beside themselves).  lxml's XMLSchema (libxml2) is the validator.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path

from lxml import etree

from ecatcfg.errors import UsageError

# Schema files are local and trusted to include their neighbours, but never fetch anything.
_XSD_PARSER = etree.XMLParser(resolve_entities=False, no_network=True)


class SchemaSet:
    """The schemas of one folder, compiled on first use and kept for the process."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise UsageError(f"--schema-dir {folder}: no such folder")
        self._compiled: dict[str, etree.XMLSchema | None] = {}

    def path_for(self, root: str) -> Path:
        return self.folder / f"{root}.xsd"

    def schema_for(self, root: str) -> etree.XMLSchema | None:
        """The compiled schema for a root element, ``None`` if the folder has none."""
        if root not in self._compiled:
            path = self.path_for(root)
            if not path.is_file():
                self._compiled[root] = None
            else:
                try:
                    self._compiled[root] = etree.XMLSchema(
                        etree.parse(str(path), _XSD_PARSER))
                except (etree.XMLSchemaParseError, etree.XMLSyntaxError) as exc:
                    raise UsageError(f"{path}: not a usable XML schema: {exc}") from None
        return self._compiled[root]

    def validate(self, tree: etree._ElementTree) -> list[tuple[int, int | None, str]] | None:
        """``(line, column, message)`` per schema error; ``None`` when no schema applies."""
        root = etree.QName(tree.getroot()).localname
        if root == "EtherCATInfoList":
            # IgH's list: each EtherCATInfo document against the ESI schema (a copy keeps
            # the element's lines, so errors point into the file).
            found: list[tuple[int, int | None, str]] = []
            schema = self.schema_for("EtherCATInfo")
            if schema is None:
                return None
            for doc in tree.getroot():
                if isinstance(doc.tag, str) and not schema.validate(
                        etree.ElementTree(copy.deepcopy(doc))):
                    found += [(e.line, e.column or None, readable(e.message))
                              for e in schema.error_log]
            return found
        schema = self.schema_for(root)
        if schema is None:
            return None
        if schema.validate(tree):
            return []
        return [(e.line, e.column or None, readable(e.message)) for e in schema.error_log]


_NAMESPACE = re.compile(r"\{[^}]*\}")
_EXPECTED = re.compile(r"Expected is (?:one of )?\( ?(.*?) ?\)\.")


def readable(message: str) -> str:
    """libxml2's schema message without namespace braces and with a tidier 'expected' list."""
    message = _NAMESPACE.sub("", message)
    message = _EXPECTED.sub(lambda m: f"Expected: {m.group(1)}.", message)
    return message.replace("This element is not expected.", "not expected here.")
