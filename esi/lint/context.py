"""What a check sees of the file being linted, beyond the device model itself."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path, PureWindowsPath

from ecatcfg.errors import EcatcfgError
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.library import find_reference
from ecatcfg.esi.model import EsiFile, Source
from ecatcfg.esi.values import parse_int


@dataclass(slots=True)
class Reference:
    """An ``InfoReference`` of the file and the module library it resolved to."""

    text: str
    source: Source
    path: Path | None
    module_idents: frozenset[int] = frozenset()
    error: str | None = None          # the library exists but cannot be read


@dataclass(slots=True)
class FileContext:
    esi: EsiFile
    path: Path                        # resolved
    others: list[Path] = field(default_factory=list)   # the other files being linted
    _references: list[Reference] | None = None

    @property
    def references(self) -> list[Reference]:
        if self._references is None:
            self._references = [self._resolve(text, src)
                                for text, src in self.esi.info_references]
        return self._references

    def known_module_idents(self) -> frozenset[int] | None:
        """Module idents of this file and every library it references; ``None`` when a
        reference is unresolved (then slot checks would only repeat that finding)."""
        idents = {m.ident for m in self.esi.modules if m.ident is not None}
        for ref in self.references:
            if ref.path is None or ref.error:
                return None
            idents |= ref.module_idents
        return frozenset(idents)

    def _resolve(self, text: str, source: Source) -> Reference:
        parts = PureWindowsPath(text).parts
        target: Path | None = None
        try:
            if parts:
                direct = self.path.parent.joinpath(*parts)
                if direct.is_file():
                    target = direct.resolve()
                else:
                    beside = [p.resolve() for p in self.path.parent.glob("*.xml")]
                    target = find_reference(self.path, text, self.others + beside)
        except (OSError, RuntimeError) as exc:   # a name too long, a symlink loop
            return Reference(text, source, None, error=f"cannot look it up: {exc}")
        if target is None:
            return Reference(text, source, None)
        try:
            return Reference(text, source, target, _module_idents(target))
        except EcatcfgError as exc:
            return Reference(text, source, target, error=str(exc))


@lru_cache(maxsize=32)
def _module_idents(path: Path) -> frozenset[int]:
    """The ``Module/Type/@ModuleIdent`` values of a module library (read once per process)."""
    tree = xmlsafe.parse_file(path)
    idents = set()
    for raw in tree.getroot().iterfind(".//Module/Type"):
        try:
            idents.add(parse_int(raw.get("ModuleIdent", "")))
        except ValueError:
            pass
    return frozenset(idents)
