"""What kind of file a command was given: an ESI, an ENI or a topology (shared by ``show``
and ``diff``, which take any of them, and by ``report`` and ``export``), and what is said
when paths hold no ESI file at all (``lint``, ``devices``)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from ecatcfg.errors import EcatcfgError, UsageError
from ecatcfg.fileio import check_input

# The root element's name after the XML declaration, comments and processing instructions
# (a namespace prefix allowed).
_ROOT = re.compile(rb"^(?:\s|<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)*<(?:[\w.-]+:)?([\w.-]+)",
                   re.S)
_ENI_ROOTS = ("EtherCATConfig", "EncryptedEtherCATConfig")


def root_tag(path: str) -> str | None:
    """The root element's local name, or None for a file that does not start as XML."""
    p = Path(path)
    check_input(p, path)                # a device node or FIFO: refused as such
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
    if tag == "EtherCATInfo":
        return "esi"
    if tag is not None:
        raise EcatcfgError(f"root element <{tag}> is neither an ENI (EtherCATConfig) nor "
                           "an ESI (EtherCATInfo)", path, 1)
    return "topology"


def no_esi_files(paths: list[str]) -> str:
    """The refusal of ``lint`` and ``devices`` when their paths hold no ESI file at all: in
    CI a mistyped path would otherwise pass as "0 files checked"."""
    return (f"no ESI file in {', '.join(paths)}: nothing was read (a mistyped path?); "
            "--allow-empty accepts that")
