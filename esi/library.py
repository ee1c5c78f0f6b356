"""The device library: ESI files and folders indexed by vendor, product and revision.

``Library(paths)`` walks the given files and folders (recursively, ``*.xml``), summarises each
file (from the on-disk cache when the content is known) and answers selectors as the
command-line contract (``docs/architecture.md``) defines them::

    VENDOR:PRODUCT[:REVISION]   hex (0x..) or decimal; no revision = the highest, said so
    Type name                   compared with surrounding white space trimmed

Full device models are read on demand (``Library.device``) and kept per file.

One identity (vendor, product, revision) described by several Device elements (two downloads
of a family file, a vendor's own builds of one product) is one device when the descriptions
are the same (``esi/duplicates.py``: what changes what a master does, not the bytes); when
they differ, a selector naming it is an error listing each file and what differs, unless the
caller names the file (``within``: a topology's ``esi:``), the library was given an order
of precedence (``prefer``: the command line's ``--prefer``), or the caller brings evidence
that exactly one description agrees with (``evidence``: what an ENI says of the slave, or its
SII read on a line; ``esi/evidence.py``).  Descriptions are compared only for identities that
occur more than once, when one is selected.
"""

from __future__ import annotations

import copy
import difflib
import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path, PureWindowsPath

from lxml import etree

from ecatcfg.errors import EcatcfgError, UsageError
from ecatcfg.esi import reader, xmlsafe
from ecatcfg.esi.cache import IndexCache, content_digest
from ecatcfg.esi.duplicates import Description, describe, device_elements, differences
from ecatcfg.esi.evidence import Evidence, in_brief
from ecatcfg.esi.index import DeviceEntry, FileSummary, summarize
from ecatcfg.esi.model import Device, EsiFile, Module, format_selector
from ecatcfg.esi.values import parse_int
from ecatcfg.fileio import check_input, read_input


class SelectorError(EcatcfgError):
    """A selector that names no device, or several."""


class DuplicateError(SelectorError):
    """An identity that several ESI descriptions give differently, none of them chosen."""


class EsiChoiceError(SelectorError):
    """An ESI file named for a device (a topology's ``esi:``) that is not in the library or
    does not describe the device."""


@dataclass(slots=True)
class Selection:
    entry: DeviceEntry
    note: str | None = None      # e.g. which revision was taken when none was given
    preferred: str | None = None  # which of differing descriptions --prefer took, and why


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

    def __init__(self, paths: list[str | Path], cache: IndexCache | None | bool = True,
                 prefer: list[str | Path] | None = None) -> None:
        """Index ``paths``: ESI files, and folders searched recursively for ``*.xml``.

        ``cache``: an :class:`IndexCache`, ``True`` for the default one
        (``$XDG_CACHE_HOME/ecatcfg``), ``False``/``None`` for none.  Files named directly
        must be ESI files (a file that is not one is a problem); inside folders, XML files
        with another root element (an ENI beside the ESIs, say) are skipped and listed in
        ``skipped``.  A path that does not exist raises :class:`UsageError`.

        ``prefer``: files or folders of the library, most preferred first.  Where an identity
        is described differently by several files, the description from the first of these
        that holds one is taken (with a note) if that leaves one description; files under
        none of them come last.  A ``prefer`` path that does not exist or holds no file of
        the library raises :class:`UsageError`.
        """
        self.cache = IndexCache() if cache is True else (cache or None)
        self.files: list[LibraryFile] = []
        self.skipped: list[str] = []
        self.problems: list[EcatcfgError] = []
        self._models: dict[Path, reader.FileReader] = {}
        self._reading = threading.Lock()
        for given in paths:
            for path, shown, explicit in expand_paths(given):
                self._add(path.resolve(), shown, explicit)
        if self.cache is not None:
            self.cache.flush()
        self.entries: list[DeviceEntry] = self._entries()
        self.prefer: list[Path] = [self._preferred(p) for p in prefer or []]
        self._descriptions: dict[tuple[str, int], Description] = {}
        self._trees: dict[str, etree._ElementTree] = {}
        self._differing: dict[tuple[tuple[str, int], ...], list[tuple[int, list[str]]]] = {}
        # The content digest and element spans of each model read (``loaded``).
        self._loaded: dict[Path, tuple[str, reader.ElementSpans]] = {}
        self._found: dict[tuple[str, str | None], Selection] = {}   # find() without evidence
        self._revisions: dict[tuple[int | None, int | None], frozenset[int | None]] | None = None
        self.evidence_for: Callable[[int, int, int], Evidence | None] | None = None
        # What the evidence chose (the notes of :meth:`find`), in order: a caller that
        # selects through code it does not own (a check's rules) reports them.
        self.decisions: list[str] = []

    def _preferred(self, given: str | Path) -> Path:
        path = Path(given)
        if not path.exists():
            raise UsageError(f"--prefer {given}: no such file or folder")
        path = path.resolve()
        if not any(_under(lf.path, path) for lf in self.files):
            raise UsageError(f"--prefer {given}: no ESI file of the library is there (give it "
                             "with --esi too)")
        return path

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
            data = read_input(path, shown)
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
                    file=lf.shown, line=d["line"], ordinal=d["ordinal"],
                    vendor_id=d.get("vendor_id", s.vendor_id),
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
            for module in self._reader(src).esi.modules:     # read without the devices
                if module.ident is not None:
                    found.setdefault(module.ident, module)
        return found

    # -- lookup ---------------------------------------------------------------------------

    def entry_for_identity(self, vendor_id: int, product_code: int, revision: int,
                           evidence: Evidence | None = None
                           ) -> tuple[DeviceEntry | None, DeviceEntry | None, str | None]:
        """The entry of a slave found on a line by its SII identity: the exact revision
        (the ``prefer`` files first where several files have it), else (``other``) the
        highest revision of the same product, with a note saying which revisions there
        are.  Where several files describe the exact revision differently and ``prefer``
        does not decide, ``evidence`` (the slave's SII: ``esi/evidence.py``; without it,
        the :meth:`guided` evidence, asked for only then) chooses the one that agrees with
        it, with a note saying so, or the note says why it could not (the ``prefer``
        order's first is then taken, as without evidence)."""
        same = [e for e in self.entries
                if (e.vendor_id, e.product_code) == (vendor_id, product_code)]
        exact = min((e for e in same if e.revision == revision), key=self._rank,
                    default=None)
        if exact is not None and evidence is None and self.evidence_for is not None \
                and self.differs(vendor_id, product_code, revision):
            evidence = self.evidence_for(vendor_id, product_code, revision)
        if exact is not None and evidence is not None:
            try:
                chosen = self._one_description(Selection(exact), self.entries, evidence)
            except DuplicateError as exc:
                return exact, None, f"took {_where(exact)}, the first: {exc.message}"
            return chosen.entry, None, chosen.preferred
        other = None
        if exact is None and same:
            other = max(same, key=lambda e: e.revision if e.revision is not None else -1)
        note = None
        if other is not None:
            note = (f"revision 0x{revision:x} is not in the ESI files; they have "
                    + ", ".join(sorted({f"0x{e.revision:x}" for e in same
                                        if e.revision is not None})))
        return exact, other, note

    def revisions(self, vendor_id: int | None, product_code: int | None) -> frozenset[int | None]:
        """The revisions the library has of one product (asked once per slave of a line)."""
        if self._revisions is None:
            by_product: dict[tuple[int | None, int | None], set[int | None]] = {}
            for e in self.entries:
                by_product.setdefault((e.vendor_id, e.product_code), set()).add(e.revision)
            self._revisions = {k: frozenset(v) for k, v in by_product.items()}
        return self._revisions.get((vendor_id, product_code), frozenset())

    def differs(self, vendor_id: int, product_code: int, revision: int) -> bool:
        """Whether several descriptions give this identity differently (a caller that must
        read evidence from a slave to choose, its SII, reads it only then)."""
        same = [e for e in self.entries
                if (e.vendor_id, e.product_code, e.revision)
                == (vendor_id, product_code, revision)]
        return len(same) > 1 and bool(self.differing(same))

    def find(self, selector: str, within: LibraryFile | None = None,
             evidence: Evidence | None = None) -> Selection:
        """The one device ``selector`` names, or :class:`SelectorError` saying why not.

        ``within``: look only at the devices of that file (a topology's ``esi:``); a file
        that does not describe the device is an :class:`EsiChoiceError`.  An identity that
        several descriptions give differently, with no ``within`` and no ``prefer`` to
        choose, is chosen by ``evidence`` (what is known of the slave: its ENI, its SII;
        ``esi/evidence.py``) when exactly one of the descriptions agrees with it, else
        (and without evidence) a :class:`DuplicateError` naming each file and what
        differs.  Without ``evidence``, the library's own :meth:`guided` evidence is used.
        """
        # A line names a few devices for hundreds of slaves: without evidence (which may
        # choose differently per slave), what a selector finds in one library is found once.
        key = (selector, within.shown if within is not None else None)
        plain = evidence is None and self.evidence_for is None
        known = self._found.get(key) if plain else None
        if known is not None:
            return Selection(known.entry, known.note, known.preferred)
        scope = self.entries if within is None else [
            e for e in self.entries if e.file == within.shown]
        try:
            found = self._find(selector, scope)
        except SelectorError as exc:
            if within is None:
                raise
            raise EsiChoiceError(f"{within.shown} does not describe {selector!r}: "
                                 f"{exc.message}") from None
        if evidence is None and self.evidence_for is not None:
            e = found.entry
            if e.product_code is not None and e.revision is not None:
                evidence = self.evidence_for(e.vendor_id or 0, e.product_code, e.revision)
        chosen = self._one_description(found, scope, evidence)
        if plain:
            self._found[key] = Selection(chosen.entry, chosen.note, chosen.preferred)
        return chosen

    def guided(self, evidence_for: Callable[[int, int, int], Evidence | None]) -> Library:
        """This library (its files, models and caches shared) where :meth:`find` takes the
        evidence ``evidence_for(vendor, product, revision)`` gives when the caller gives
        none: a check of an ENI passes its slaves' evidence to code that selects by
        identity."""
        view = copy.copy(self)
        view.evidence_for = evidence_for
        view.decisions = []
        return view

    def select(self, selector: str, esi: str | None = None, base: Path | None = None
               ) -> Selection:
        """:meth:`find`, within the file ``esi`` names when one is given (a topology slave's
        ``esi:``, relative to ``base``: see :meth:`file_named`)."""
        return self.find(selector, self.file_named(esi, base) if esi is not None else None)

    def _find(self, selector: str, scope: list[DeviceEntry]) -> Selection:
        numbers = parse_selector(selector)
        if numbers is None:
            return self._find_by_name(selector, scope)
        vendor, product, revision = numbers
        same = [e for e in scope if e.vendor_id == vendor and e.product_code == product]
        if not same:
            raise SelectorError(f"no device {format_selector(vendor, product, revision)} in "
                                f"the library ({self._describe_paths(scope)})")
        if revision is not None:
            exact = [e for e in same if e.revision == revision]
            if exact:
                return Selection(exact[0])
            raise SelectorError(
                f"revision 0x{revision:x} of 0x{vendor:x}:0x{product:x} "
                f"({same[0].type}) is not in the library; available: "
                + ", ".join(_selector(e) for e in _by_revision(same)))
        return _highest(same)

    def _find_by_name(self, name: str, scope: list[DeviceEntry]) -> Selection:
        wanted = name.strip()
        matches = [e for e in scope if e.type.strip() == wanted]
        if not matches:
            folded = wanted.casefold()
            matches = [e for e in scope if e.type.strip().casefold() == folded]
        if not matches:
            names = sorted({e.type.strip() for e in scope})
            close = difflib.get_close_matches(wanted, names, n=5, cutoff=0.6)
            hint = f"; closest: {', '.join(close)}" if close else ""
            raise SelectorError(f"no device with Type name {wanted!r} in the library "
                                f"({self._describe_paths(scope)}){hint}")
        products = {(e.vendor_id, e.product_code) for e in matches}
        if len(products) > 1:
            listed = ", ".join(f"{_selector(e)} ({e.file}:{e.line})"
                               for e in _by_revision(matches))
            raise SelectorError(f"Type name {wanted!r} matches {len(products)} products; "
                                f"select one by VENDOR:PRODUCT[:REVISION]: {listed}")
        return _highest(matches)

    def device(self, selector: str | DeviceEntry) -> Device:
        """The full model of the device ``selector`` names (read once; the file's other
        devices are not read for it)."""
        entry = selector if isinstance(selector, DeviceEntry) else self.find(selector).entry
        return self._reader(self._file(entry.file)).device(entry.ordinal)

    def load(self, lf: LibraryFile) -> EsiFile:
        """The whole file's model (the devices read already are kept)."""
        return self._reader(lf).model()

    def _reader(self, lf: LibraryFile) -> reader.FileReader:
        found = self._models.get(lf.path)
        if found is None:
            with self._reading:         # two threads: one reads the file, both get it
                found = self._models.get(lf.path)
                if found is None:
                    data = xmlsafe.read_file(lf.path, lf.shown)
                    tree = xmlsafe.parse_bytes(data, lf.shown)
                    found = self._models[lf.path] = reader.FileReader(tree, lf.shown)
                    self._loaded[lf.path] = (content_digest(data), reader.spans_of(tree))
        return found

    def loaded(self, path: Path, digest: str, devices: frozenset[int] | None = None
               ) -> tuple[EsiFile, reader.ElementSpans] | None:
        """The model and element spans already read from ``path`` when it held the content
        of ``digest`` (``esi.cache.content_digest``), else ``None``: lint of a file the
        library read for a compile need not parse and read it a second time (the model of
        a 3 MB Beckhoff file takes longer to build than its lint rules take to run).
        ``devices``: only the Device elements at these lines are wanted; the model may
        then hold only the devices read so far, if they are among them (else every
        device is read)."""
        known = self._loaded.get(path)
        if known is None or known[0] != digest:
            return None
        found = self._models[path]
        have = {d.source.line for d in found.esi.devices}
        if devices is None or not devices <= have:
            found.model()
        return found.esi, known[1]

    def _file(self, shown: str) -> LibraryFile:
        return next(lf for lf in self.files if lf.shown == shown)

    def _describe_paths(self, scope: list[DeviceEntry] | None = None) -> str:
        if scope is not None and scope is not self.entries:
            n = len(scope)
            return f"{n} device{'s' if n != 1 else ''} in {scope[0].file if scope else 'it'}"
        n = len(self.entries)
        return f"{n} device{'s' if n != 1 else ''} in {len(self.files)} files"

    # -- one identity, several descriptions -----------------------------------------------

    def file_named(self, name: str, base: Path | None = None) -> LibraryFile:
        """The library file ``name`` names (a topology's ``esi:``): as the library shows it,
        a path (relative to ``base``, the topology's folder), or a file name that one
        library file has.  Anything else is an :class:`EsiChoiceError`."""
        for lf in self.files:
            if lf.shown == name:
                return lf
        path = Path(name)
        if base is not None and not path.is_absolute():
            path = base / path
        try:
            resolved = path.resolve()
        except (OSError, RuntimeError):
            resolved = path.absolute()
        for lf in self.files:
            if lf.path == resolved:
                return lf
        by_name = [lf for lf in self.files if lf.path.name == Path(name).name]
        if len(by_name) == 1 and Path(name).name == name:
            return by_name[0]
        if len(by_name) > 1 and Path(name).name == name:
            raise EsiChoiceError(f"{len(by_name)} ESI files are named {name!r}: "
                                 + ", ".join(lf.shown for lf in by_name)
                                 + "; give its path")
        names = sorted({lf.path.name for lf in self.files})
        close = difflib.get_close_matches(Path(name).name, names, n=3, cutoff=0.6)
        hint = f"; closest: {', '.join(close)}" if close else ""
        where = f" ({resolved})" if str(resolved) != name else ""
        raise EsiChoiceError(f"ESI file {name!r}{where} is not one of the library's "
                             f"{len(self.files)} files (given with --esi){hint}")

    def duplicates(self) -> list[list[DeviceEntry]]:
        """The entries of each identity that more than one Device element describes, in
        library order (devices without a product code have no identity to share)."""
        groups: dict[tuple[int | None, int, int | None], list[DeviceEntry]] = {}
        for e in self.entries:
            if e.product_code is not None:
                groups.setdefault((e.vendor_id, e.product_code, e.revision), []).append(e)
        return [g for g in groups.values() if len(g) > 1]

    def description(self, entry: DeviceEntry) -> Description:
        """What ``entry`` describes, normalised (``esi/duplicates.py``); parsed on demand."""
        key = (entry.file, entry.ordinal)
        found = self._descriptions.get(key)
        if found is None:
            tree = self._trees.pop(entry.file, None)
            if tree is None:
                lf = self._file(entry.file)
                tree = xmlsafe.parse_file(lf.path, lf.shown)
            # Keep the last few trees: the devices of one family file are often compared
            # one after another (a listing of duplicates), a tree is ten times its file.
            self._trees[entry.file] = tree
            while len(self._trees) > 4:
                del self._trees[next(iter(self._trees))]
            found = self._descriptions[key] = describe(device_elements(tree)[entry.ordinal])
        return found

    def differing(self, group: list[DeviceEntry]) -> list[tuple[DeviceEntry, list[str]]]:
        """The entries of ``group`` whose description is not the first's, each with what
        differs (empty: all describe the same device)."""
        # Asked for every slave of a line (512 times for one identity): the descriptions
        # of one library do not change, so neither does what differs between them.
        key = tuple((e.file, e.ordinal) for e in group)
        found = self._differing.get(key)
        if found is None:
            first = self.description(group[0])
            found = self._differing[key] = [
                (i, differences(first, self.description(e), _short(group[0]), _short(e)))
                for i, e in enumerate(group[1:], 1)
                if self.description(e).digest != first.digest]
        return [(group[i], list(d)) for i, d in found]

    def _one_description(self, found: Selection, scope: list[DeviceEntry],
                         evidence: Evidence | None = None) -> Selection:
        chosen = found.entry
        if chosen.product_code is None:
            return found
        same = [e for e in scope if (e.vendor_id, e.product_code, e.revision)
                == (chosen.vendor_id, chosen.product_code, chosen.revision)]
        if len(same) == 1 or not self.differing(same):
            return found                   # one description, however many files hold it
        ranks = [self._rank(e) for e in same]
        best = min(ranks)
        top = [e for e, r in zip(same, ranks) if r == best]
        if best < len(self.prefer) and not self.differing(top):
            others = [e for e in same if e not in top]
            said = "; ".join(f"{_where(e)}: {', '.join(d)}"
                             for e, d in self.differing([top[0]] + others))
            note = (f"{_selector(chosen)} ({chosen.type}) is described differently by "
                    f"{len({e.file for e in same})} ESI files; took {_where(top[0])} "
                    f"(--prefer {self.prefer[best]}); differs: {said}")
            against = evidence.disagreements(self.device(top[0])) if evidence else []
            if evidence is not None and against:
                note += (f"; it does not agree with {evidence.what}: "
                         + in_brief(against))
            return Selection(top[0], found.note, note)
        if evidence is not None:
            return self._by_evidence(found, same, evidence)
        raise DuplicateError(duplicate_message(chosen, same, self.differing(same)))

    def _by_evidence(self, found: Selection, same: list[DeviceEntry], evidence: Evidence
                     ) -> Selection:
        """The one description of ``same`` (differing descriptions of one identity) that
        agrees with ``evidence``, with a note saying why; else a :class:`DuplicateError`
        naming what disagrees, or, where several agree, what differs between them (what
        would decide)."""
        chosen = found.entry
        against = {id(e): evidence.disagreements(self.device(e)) for e in same}
        fits = [e for e in same if not against[id(e)]]
        files = len({e.file for e in same})
        head = (f"{_selector(chosen)} ({chosen.type}) is described differently by "
                + (f"{files} ESI files" if files > 1 else
                   f"{len(same)} Device elements of one file"))
        others = "; ".join(f"{_where(e)}: {in_brief(against[id(e)], 3)}" for e in same
                           if against[id(e)])
        if fits and not self.differing(fits):
            note = (f"{head}; took {_where(fits[0])}: the only description that agrees with "
                    f"{evidence.what}" + (f" (the others differ from it: {others})"
                                          if others else ""))
            self.decisions.append(note)
            return Selection(fits[0], found.note, note)
        if not fits:
            raise DuplicateError(
                f"{head}: {', '.join(_where(e) for e in same)}, and none agrees with "
                f"{evidence.what} ({others}); choose one: 'esi: FILE' on the slave in the "
                "topology, or --prefer FILE_OR_FOLDER")
        between = "; ".join(f"{_where(e)} vs {_where(fits[0])}: {', '.join(d)}"
                            for e, d in self.differing(fits))
        raise DuplicateError(
            f"{head}: {', '.join(_where(e) for e in same)}; {len(fits)} of them agree with "
            f"{evidence.what}: {', '.join(_where(e) for e in fits)}, which differ in what it "
            f"does not say ({between})"
            + (f"; the others do not agree ({others})" if others else "")
            + "; choose one: 'esi: FILE' on the slave in the topology, or --prefer "
            "FILE_OR_FOLDER")

    def _rank(self, entry: DeviceEntry) -> int:
        path = self._file(entry.file).path
        return next((i for i, p in enumerate(self.prefer) if _under(path, p)), len(self.prefer))


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


def _where(e: DeviceEntry) -> str:
    return f"{e.file}:{e.line}"


def _short(e: DeviceEntry) -> str:
    """A file's name and line, for the items of what differs (the message lists the paths)."""
    return f"{PureWindowsPath(e.file).name}:{e.line}"


def _under(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def duplicate_message(chosen: DeviceEntry, same: list[DeviceEntry],
                      differing: list[tuple[DeviceEntry, list[str]]]) -> str:
    """``0x2:...:... (EL1008) is described differently by 2 ESI files: A:12, B:40 (B:40 vs
    A:12: TxPdo 0x1A00 entries differ); ...``: every file, and what differs from the first."""
    files = len({e.file for e in same})
    by = f"{files} ESI files" if files > 1 else f"{len(same)} Device elements of one file"
    said = "; ".join(f"{_where(e)} vs {_where(same[0])}: {', '.join(d)}" for e, d in differing)
    return (f"{_selector(chosen)} ({chosen.type}) is described differently by {by}: "
            + ", ".join(_where(e) for e in same) + f" ({said}); choose one: 'esi: FILE' on "
            "the slave in the topology, or --prefer FILE_OR_FOLDER")


def _by_revision(entries: list[DeviceEntry]) -> list[DeviceEntry]:
    return sorted(entries, key=lambda e: (e.vendor_id or 0, e.product_code or 0,
                                          e.revision if e.revision is not None else -1))


def _highest(entries: list[DeviceEntry]) -> Selection:
    # The first entry of the highest revision (library order: a duplicate is settled by
    # Library._one_description).  The note names its file: a family file of another age
    # can hold a revision far above the others (a placeholder 0x270B0000, say).
    ordered = _by_revision(entries)
    top = ordered[-1].revision
    best = next(e for e in entries if e.revision == top)
    revisions = sorted({e.revision for e in entries if e.revision is not None})
    if len(revisions) <= 1:
        note = None if best.revision is None else (
            f"no revision given; took {_selector(best)}, the only revision")
    else:
        note = (f"no revision given; took {_selector(best)} ({_where(best)}), the highest of "
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
    check_input(path, str(given))           # a device node or FIFO: refused as such
    raise UsageError(f"{given}: no such file or folder")
