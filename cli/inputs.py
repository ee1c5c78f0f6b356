"""What kind of file a command was given: an ESI, an ENI or a topology (shared by ``show``
and ``diff``, which take any of them)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from ecatcfg.errors import EcatcfgError, UsageError

# The root element's name after the XML declaration, comments and processing instructions
# (a namespace prefix allowed).
_ROOT = re.compile(rb"^(?:\s|<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)*<(?:[\w.-]+:)?([\w.-]+)",
                   re.S)
_ENI_ROOTS = ("EtherCATConfig", "EncryptedEtherCATConfig")


def root_tag(path: str) -> str | None:
    """The root element's local name, or None for a file that does not start as XML."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"{path}: no such file")
    try:
        with p.open("rb") as f:
            head = f.read(65536)
    except OSError as exc:
        raise EcatcfgError(f"cannot read: {exc.strerror}", path) from None
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    m = _ROOT.match(head)
    return m.group(1).decode() if m else None


def kind(path: str) -> Literal["eni", "esi", "topology"]:
    """An ENI or ESI by its root element; anything not XML is taken for a topology."""
    tag = root_tag(path)
    if tag in _ENI_ROOTS:
        return "eni"
    if tag in ("EtherCATInfo", "EtherCATInfoList"):
        return "esi"
    if tag is not None:
        raise EcatcfgError(f"root element <{tag}> is neither an ENI (EtherCATConfig) nor "
                           "an ESI (EtherCATInfo)", path, 1)
    return "topology"
