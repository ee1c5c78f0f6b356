"""SARIF 2.1.0 for GitHub code scanning: one rule descriptor per rule in effect, one result
per finding with its physical location (file as given, 1-based line and column)."""

from __future__ import annotations

import json
import re
from pathlib import PurePath
from typing import Any, TextIO
from urllib.parse import quote

from ecatcfg import __version__
from ecatcfg.esi.lint.finding import FileResult
from ecatcfg.esi.lint.rules import Rule

SCHEMA = "https://json.schemastore.org/sarif-2.1.0.json"
_LEVEL = {"error": "error", "warning": "warning", "info": "note"}


def write(results: list[FileResult], rules: dict[str, Rule], out: TextIO,
          tool: str = "ecatcfg lint", tag: str = "esi") -> None:
    """``tool`` and ``tag`` name the command and what it reads (``ecatcfg check``: eni)."""
    ids = sorted(rules)
    index = {rid: i for i, rid in enumerate(ids)}
    descriptors = [{
        "id": rid,
        "name": _camel(rules[rid].summary),
        "shortDescription": {"text": rules[rid].summary},
        "fullDescription": {"text": rules[rid].explanation},
        "help": {"text": rules[rid].explanation},
        "defaultConfiguration": {"level": _LEVEL[rules[rid].severity]},
        "properties": {"tags": ["ethercat", tag]},
    } for rid in ids]
    sarif_results = []
    for result in results:
        for f in result.findings:
            region = {}
            if f.line:
                region["startLine"] = f.line
                if f.column:
                    region["startColumn"] = f.column
            physical: dict[str, Any] = {"artifactLocation": {"uri": _uri(f.file)}}
            if region:
                physical["region"] = region
            item = {
                "ruleId": f.rule,
                "ruleIndex": index[f.rule],
                "level": _LEVEL[f.severity],
                "message": {"text": f.message},
                "locations": [{"physicalLocation": physical}],
            }
            if f.device is not None:
                item["properties"] = {"device": f.device.as_json()}
            sarif_results.append(item)
    doc = {
        "$schema": SCHEMA,
        "version": "2.1.0",
        "runs": [{
            "tool": {"driver": {
                "name": tool,
                "semanticVersion": __version__,
                "rules": descriptors,
            }},
            "results": sarif_results,
            "columnKind": "unicodeCodePoints",
        }],
    }
    json.dump(doc, out, indent=1)
    out.write("\n")


def _uri(path: str) -> str:
    """A relative URI reference as GitHub resolves it against the checkout."""
    p = PurePath(path)
    text = p.as_posix()
    if p.is_absolute():
        return "file://" + "/".join(quote(part, safe="") for part in text.split("/"))
    return "/".join(quote(part, safe="") for part in text.split("/"))


def _camel(summary: str) -> str:
    """``"a PDO entry's DataType differs"`` -> ``"APdoEntrySDataTypeDiffers"``."""
    return "".join(w[:1].upper() + w[1:].lower() if w.isupper() and len(w) > 1 else
                   w[:1].upper() + w[1:] for w in re.split(r"[^A-Za-z0-9]+", summary) if w)
