"""``[tool.ecatcfg.lint]`` in the user's pyproject.toml, found from the current folder upward.

    [tool.ecatcfg.lint]
    select = ["ESI1", "ESI2", "XSD001"]   # rule ids or prefixes; default: all
    ignore = ["ESI006"]
    schema-dir = "third_party/etg/esi-1.17"   # relative to the pyproject.toml
    jobs = 2

Command-line options override the file's values.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ecatcfg.errors import UsageError
from ecatcfg.fileio import read_input

KEYS = ("select", "ignore", "schema-dir", "jobs")


@dataclass(slots=True)
class LintConfig:
    source: Path | None = None
    select: list[str] | None = None
    ignore: list[str] = field(default_factory=list)
    schema_dir: Path | None = None
    jobs: int | None = None


def find_pyproject(start: Path) -> Path | None:
    for folder in [start, *start.parents]:
        candidate = folder / "pyproject.toml"
        if candidate.is_file():
            return candidate
    return None


def load(path: Path | None) -> LintConfig:
    """The lint table of ``path`` (a pyproject.toml); an empty config when it has none."""
    if path is None:
        return LintConfig()
    try:
        doc = tomllib.loads(read_input(path).decode("utf-8"))
    except OSError as exc:
        raise UsageError(f"cannot read: {exc.strerror}", str(path)) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"not valid TOML: {exc}", str(path)) from None
    table: object = doc
    for key in ("tool", "ecatcfg", "lint"):
        if not isinstance(table, dict):
            raise UsageError(f"{path}: [{key}]'s parent is not a table")
        table = table.get(key)
        if table is None:
            return LintConfig(source=path)
    where = f"{path} [tool.ecatcfg.lint]"
    if not isinstance(table, dict):
        raise UsageError(f"{where}: must be a table")
    unknown = sorted(set(table) - set(KEYS))
    if unknown:
        raise UsageError(f"{where}: unknown key(s) {', '.join(unknown)}; "
                         f"known: {', '.join(KEYS)}")
    cfg = LintConfig(source=path)
    if "select" in table:
        cfg.select = _id_list(table["select"], f"{where} select")
    if "ignore" in table:
        cfg.ignore = _id_list(table["ignore"], f"{where} ignore")
    if "schema-dir" in table:
        if not isinstance(table["schema-dir"], str):
            raise UsageError(f"{where} schema-dir: must be a string (a folder)")
        cfg.schema_dir = (path.parent / table["schema-dir"])
    if "jobs" in table:
        if not isinstance(table["jobs"], int) or isinstance(table["jobs"], bool) \
                or table["jobs"] < 1:
            raise UsageError(f"{where} jobs: must be a positive integer")
        cfg.jobs = table["jobs"]
    return cfg


def _id_list(value: object, where: str) -> list[str]:
    if isinstance(value, str):
        return split_ids(value)
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return [v.strip() for v in value if v.strip()]
    raise UsageError(f"{where}: must be a list of rule ids")


def split_ids(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]
