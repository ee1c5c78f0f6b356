"""The device library: ESI files and folders indexed by vendor, product and revision.

``Library(paths)`` walks the given files and folders (recursively, ``*.xml``), summarises each
file (from the on-disk cache when the content is known) and answers selectors as the
command-line contract (``docs/architecture.md``) defines them::

    VENDOR:PRODUCT[:REVISION]   hex (0x..) or decimal; no revision = the highest, said so
    Type name                   compared with surrounding white space trimmed

Full device models are read on demand (``Library.device``) and kept per file.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass
from typing import Iterable
from pathlib import Path, PureWindowsPath

from ecatcfg.errors import EcatcfgError, UsageError
from ecatcfg.esi import reader, xmlsafe
from ecatcfg.esi.cache import IndexCache, content_digest
from ecatcfg.esi.index import DeviceEntry, FileSummary, summarize
from ecatcfg.esi.model import Device, EsiFile, Module, format_selector
from ecatcfg.esi.values import parse_int


class SelectorError(EcatcfgError):
    """A selector that names no device, or several."""


@dataclass(slots=True)
class Selection:
    entry: DeviceEntry
    note: str | None = None      # e.g. which revision was taken when none was given


@dataclass(slots=True)
class LibraryFile:
    path: Path                   # where it is, resolved (absolute, no symlinks)
    shown: str                   # how messages name it
    summary: FileSummary


class Library:
    """The devices of a set of ESI files and folders, found by selector.

    Indexing reads only a summary of each file (identity, names, counts; from the
    :class:`IndexCache` when the file's content is known), so a library over a vendor's
    whole download is quick to build.  :meth:`find` answers a selector with the device it
    names (and a note when it had to choose a revision), :meth:`device` gives that device's
    full model, read from its file on first use and kept.  Module libraries an ESI names by
    ``InfoReference`` are looked up beside it (:meth:`modules_for`).

    Attributes: ``files`` (every ESI file indexed), ``entries`` (every device, in file
    order), ``skipped`` (XML files inside folders that are not ESI files) and ``problems``
    (what could not be read, each an error naming file and line; the library holds the
    rest).
    """

    def __init__(self, paths: list[str | Path], cache: IndexCache | None | bool = True) -> None:
        """Index ``paths``: ESI files, and folders searched recursively for ``*.xml``.

        ``cache``: an :class:`IndexCache`, ``True`` for the default one
        (``$XDG_CACHE_HOME/ecatcfg``), ``False``/``None`` for none.  Files named directly
        must be ESI files (a file that is not one is a problem); inside folders, XML files
        with another root element (an ENI beside the ESIs, say) are skipped and listed in
        ``skipped``.  A path that does not exist raises :class:`UsageError`.
        """
        self.cache = IndexCache() if cache is True else (cache or None)
        self.files: list[LibraryFile] = []
        self.skipped: list[str] = []
        self.problems: list[EcatcfgError] = []
        self._models: dict[Path, EsiFile] = {}
        for given in paths:
            for path, shown, explicit in expand_paths(given):
                self._add(path.resolve(), shown, explicit)
        if self.cache is not None:
            self.cache.flush()
        self.entries: list[DeviceEntry] = self._entries()

    # -- indexing -------------------------------------------------------------------------

    def _add(self, path: Path, shown: str, named_directly: bool) -> None:
        try:
            summary = self._summary(path, shown)
        except reader.EsiReadError as exc:
            if named_directly:
                self.problems.append(exc)
            else:
                self.skipped.append(shown)
            return
        except xmlsafe.XmlError as exc:
            self.problems.append(exc)
            return
        for line, message in summary.errors:
            self.problems.append(EcatcfgError(message, shown, line))
        self.files.append(LibraryFile(path, shown, summary))

    def _summary(self, path: Path, shown: str) -> FileSummary:
        cache = self.cache
        try:
            st = path.stat()
        except OSError as exc:
            raise xmlsafe.XmlError(f"cannot read: {exc.strerror}", shown) from None
        if cache is not None:
            known = cache.known_digest(path, st)
            summary = cache.get(known) if known is not None else None
            if summary is not None:
                return summary
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise xmlsafe.XmlError(f"cannot read: {exc.strerror}", shown) from None
        if cache is None:
            return summarize(xmlsafe.parse_bytes(data, shown), shown)
        digest = content_digest(data)
        summary = cache.get(digest)
        if summary is None:
            summary = summarize(xmlsafe.parse_bytes(data, shown), shown)
            cache.put(digest, summary)
        cache.remember(path, st, digest)
        return summary

    def _entries(self) -> list[DeviceEntry]:
        entries = []
        for lf in self.files:
            s = lf.summary
            modules = s.modules + sum(
                target.summary.modules for target in
                (self.resolve_reference(lf, ref) for ref in s.info_references) if target)
            for d in s.devices:
                entries.append(DeviceEntry(
                    file=lf.shown, line=d["line"], ordinal=d["ordinal"], vendor_id=s.vendor_id,
                    product_code=d["product_code"], revision=d["revision"], type=d["type"],
                    name=d["name"], group=d["group"], rx_pdos=d["rx_pdos"],
                    tx_pdos=d["tx_pdos"], rx_entries=d["rx_entries"],
                    tx_entries=d["tx_entries"], mailbox=d["mailbox"],
                    dc_opmodes=d["dc_opmodes"], slots=d["slots"], modules=modules))
        return entries

    # -- module libraries -----------------------------------------------------------------

    def resolve_reference(self, lf: LibraryFile, ref: str) -> LibraryFile | None:
        """The module library an ``InfoReference`` names, or ``None`` (see
        :func:`find_reference`)."""
        by_path = {other.path: other for other in self.files if other is not lf}
        found = find_reference(lf.path, ref, by_path)
        return by_path[found] if found is not None else None

    def unresolved_references(self) -> list[tuple[LibraryFile, str]]:
        return [(lf, ref) for lf in self.files for ref in lf.summary.info_references
                if self.resolve_reference(lf, ref) is None]

    def missing_module_libraries(self, entry: DeviceEntry) -> list[str]:
        """The ``InfoReference`` module libraries of a device's file that are not loaded."""
        lf = self._file(entry.file)
        return [r for r in lf.summary.info_references if self.resolve_reference(lf, r) is None]

    def modules_for(self, entry: DeviceEntry) -> dict[int, Module]:
        """Module ident -> Module for a device: its own file's modules, then referenced ones."""
        lf = self._file(entry.file)
        found: dict[int, Module] = {}
        sources = [lf] + [t for t in (self.resolve_reference(lf, r)
                                      for r in lf.summary.info_references) if t]
        for src in sources:
            for module in self.load(src).modules:
                if module.ident is not None:
                    found.setdefault(module.ident, module)
        return found

    # -- lookup ---------------------------------------------------------------------------

    def find(self, selector: str) -> Selection:
        """The one device ``selector`` names, or :class:`SelectorError` saying why not."""
        numbers = parse_selector(selector)
        if numbers is None:
            return self._find_by_name(selector)
        vendor, product, revision = numbers
        same = [e for e in self.entries if e.vendor_id == vendor and e.product_code == product]
        if not same:
            raise SelectorError(f"no device {format_selector(vendor, product, revision)} in "
                                f"the library ({self._describe_paths()})")
        if revision is not None:
            exact = [e for e in same if e.revision == revision]
            if exact:
                return Selection(exact[0])
            raise SelectorError(
                f"revision 0x{revision:x} of 0x{vendor:x}:0x{product:x} "
                f"({same[0].type}) is not in the library; available: "
                + ", ".join(_selector(e) for e in _by_revision(same)))
        return _highest(same)

    def _find_by_name(self, name: str) -> Selection:
        wanted = name.strip()
        matches = [e for e in self.entries if e.type.strip() == wanted]
        if not matches:
            folded = wanted.casefold()
            matches = [e for e in self.entries if e.type.strip().casefold() == folded]
        if not matches:
            names = sorted({e.type.strip() for e in self.entries})
            close = difflib.get_close_matches(wanted, names, n=5, cutoff=0.6)
            hint = f"; closest: {', '.join(close)}" if close else ""
            raise SelectorError(f"no device with Type name {wanted!r} in the library "
                                f"({self._describe_paths()}){hint}")
        products = {(e.vendor_id, e.product_code) for e in matches}
        if len(products) > 1:
            listed = ", ".join(f"{_selector(e)} ({e.file}:{e.line})"
                               for e in _by_revision(matches))
            raise SelectorError(f"Type name {wanted!r} matches {len(products)} products; "
                                f"select one by VENDOR:PRODUCT[:REVISION]: {listed}")
        return _highest(matches)

    def device(self, selector: str | DeviceEntry) -> Device:
        """The full model of the device ``selector`` names."""
        entry = selector if isinstance(selector, DeviceEntry) else self.find(selector).entry
        return self.load(self._file(entry.file)).devices[entry.ordinal]

    def load(self, lf: LibraryFile) -> EsiFile:
        model = self._models.get(lf.path)
        if model is None:
            model = self._models[lf.path] = reader.read_file(lf.path, lf.shown)
        return model

    def _file(self, shown: str) -> LibraryFile:
        return next(lf for lf in self.files if lf.shown == shown)

    def _describe_paths(self) -> str:
        n = len(self.entries)
        return f"{n} device{'s' if n != 1 else ''} in {len(self.files)} files"


def parse_selector(selector: str) -> tuple[int, int, int | None] | None:
    """``(vendor, product, revision)`` for a numeric selector, ``None`` for a Type name."""
    parts = selector.strip().split(":")
    if len(parts) not in (2, 3):
        return None
    try:
        numbers = [parse_int(p) for p in parts]
    except ValueError:
        return None
    return numbers[0], numbers[1], numbers[2] if len(numbers) == 3 else None


def _selector(e: DeviceEntry) -> str:
    return format_selector(e.vendor_id, e.product_code, e.revision)


def _by_revision(entries: list[DeviceEntry]) -> list[DeviceEntry]:
    return sorted(entries, key=lambda e: (e.vendor_id or 0, e.product_code or 0,
                                          e.revision if e.revision is not None else -1))


def _highest(entries: list[DeviceEntry]) -> Selection:
    ordered = _by_revision(entries)
    best = ordered[-1]
    revisions = sorted({e.revision for e in entries if e.revision is not None})
    if len(revisions) <= 1 and len(entries) == 1:
        note = None if best.revision is None else (
            f"no revision given; took {_selector(best)}, the only revision")
    else:
        note = (f"no revision given; took {_selector(best)}, the highest of "
                + ", ".join(f"0x{r:x}" for r in revisions))
    return Selection(best, note)


def find_reference(referencing: Path, ref: str, candidates: Iterable[Path]) -> Path | None:
    """Where the module library named by an ``InfoReference`` in ``referencing`` is.

    Tried in order: the path relative to the referencing file (Windows separators
    accepted), then any of ``candidates`` (resolved paths) with the same file name
    (case-insensitive): vendor files refer to ``Sub\\Folder\\File.xml`` while the file often
    lies beside them.
    """
    parts = PureWindowsPath(ref).parts
    if not parts:
        return None
    candidate = referencing.parent.joinpath(*parts).resolve()
    by_name = PureWindowsPath(ref).name.lower()
    candidates = list(candidates)
    if candidate in candidates:
        return candidate
    for other in candidates:
        if other.name.lower() == by_name and other != referencing:
            return other
    return None


def expand_paths(given: str | Path) -> list[tuple[Path, str, bool]]:
    """``(path, shown name, named directly)`` for a file or a folder searched recursively."""
    path = Path(given)
    if path.is_file():
        return [(path, str(given), True)]
    if path.is_dir():
        found = []
        for dirpath, dirnames, filenames in os.walk(path):
            dirnames.sort()
            for fn in sorted(filenames):
                if fn.lower().endswith(".xml"):
                    full = Path(dirpath) / fn
                    found.append((full, os.path.join(str(given), os.path.relpath(full, path)),
                                  False))
        return found
    raise UsageError(f"{given}: no such file or folder")
