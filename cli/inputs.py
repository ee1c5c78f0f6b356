"""What kind of file a command was given: an ESI, an ENI or a topology (shared by ``show``
and ``diff``, which take any of them, and by ``report`` and ``export``), and what is said
when paths hold no ESI file at all (``lint``, ``devices``)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from ecatcfg.errors import EcatcfgError, UsageError
from ecatcfg.fileio import check_input, read_head

if TYPE_CHECKING:
    from ecatcfg.eni.plan import NetworkPlan

# The root element's name after the XML declaration, comments and processing instructions
# (a namespace prefix allowed).
_ROOT = re.compile(rb"^(?:\s|<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)*<(?:[\w.-]+:)?([\w.-]+)",
                   re.S)
_ENI_ROOTS = ("EtherCATConfig", "EncryptedEtherCATConfig")


def root_tag(path: str) -> str | None:
    """The root element's local name, or None for a file that does not start as XML."""
    found = _root(path)
    return found[0] if found else None


def _root(path: str) -> tuple[str, int] | None:
    """The root element's local name and line, or None for a file that does not start as
    XML."""
    p = Path(path)
    check_input(p, path)                # a device node or FIFO: refused as such
    if not p.is_file():
        raise UsageError(f"{path}: no such file")
    try:
        head = read_head(p, path)
    except OSError as exc:
        raise EcatcfgError(f"cannot read: {exc.strerror}", path) from None
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    m = _ROOT.match(head)
    return (m.group(1).decode(), head.count(b"\n", 0, m.start(1)) + 1) if m else None


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


def require_eni(path: str, esi_hint: str = "") -> None:
    """``path`` must be an ENI (``report``, ``export``, ``show``); anything else is a usage
    error (exit 2) that says what the file is, as ``apply`` and ``check`` say it: a file that
    is not XML gets the XML parser's reason at its line and column (``esi.xmlsafe``, the
    parser every ENI is read with), an XML file its root element at its line.  An ESI
    gets ``esi_hint`` after it."""
    found = _root(path)
    if found is None:
        from ecatcfg.esi import xmlsafe
        from ecatcfg.fileio import read_input
        try:
            xmlsafe.parse_bytes(read_input(path, path), path)
        except xmlsafe.XmlError as exc:
            raise UsageError(f"not an ENI: {exc.message}", exc.file, exc.line,
                             exc.column) from None
        return              # XML after all (a prologue past the head): the reader judges it
    tag, line = found
    if tag in _ENI_ROOTS:
        return
    what = " (an ESI" + (f": {esi_hint}" if esi_hint else "") + ")" \
        if tag == "EtherCATInfo" else ""
    raise UsageError(f"not an ENI: the root element is <{tag}>{what}, expected "
                     "<EtherCATConfig>", path, line)


def eni_for_output(eni: str, output: str, no_cache: bool, does: str
                   ) -> tuple[NetworkPlan, Path]:
    """What ``export`` and ``report`` start from: the ENI checked to be one (what else it
    is, at which line, otherwise), the output path (``-``: standard output), never the ENI
    itself, and the ENI's plan (through the plan cache unless ``no_cache``).  ``does``: what
    the command does with the ENI, for the message ("exports", "reports on")."""
    from ecatcfg.cli.paths import output_file
    from ecatcfg.eni.cache import PlanCache, read_file
    from ecatcfg.eni.reader import read_file as read_uncached

    require_eni(eni)
    out = output_file(output)
    if out.resolve() == Path(eni).resolve():
        raise UsageError(f"-o {output}: would replace the ENI it {does}")
    return (read_uncached(eni) if no_cache else read_file(eni, cache=PlanCache())), out


def no_esi_files(paths: list[str]) -> str:
    """The refusal of ``lint`` and ``devices`` when their paths hold no ESI file at all: in
    CI a mistyped path would otherwise pass as "0 files checked"."""
    return (f"no ESI file in {', '.join(paths)}: nothing was read (a mistyped path?); "
            "--allow-empty accepts that")
