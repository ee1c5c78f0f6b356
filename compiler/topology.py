"""The topology file: the user's line of slaves, validated by pydantic, with YAML line numbers.

YAML (or JSON, which YAML reads too) is composed into nodes first, so every value keeps the
line it was written on: pydantic's error locations (``slaves.2.rx_pdos.0``) and the
compiler's own errors map back to ``topology.yaml:14``.  Keys follow the contract in
ARCHITECTURE.md; unknown keys are errors (a typo must not be silently ignored).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError,
                      field_validator, model_validator)

from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import Transition
from ecatcfg.esi.values import parse_int

Path_ = tuple[str | int, ...]

# libyaml's composer when PyYAML has it (10x faster on big topologies); marks are the same.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# Composing follows aliases: a few anchors can expand to millions of nodes ("billion laughs").
MAX_NODES = 200_000


class TopologyError(EcatcfgError):
    """One or more errors in a topology file, each with its line."""

    def __init__(self, problems: list[EcatcfgError]) -> None:
        first = problems[0]
        super().__init__(first.message, first.file, first.line, first.column)
        self.problems = problems

    def __str__(self) -> str:
        if len(self.problems) == 1:
            return str(self.problems[0])
        return (f"{len(self.problems)} errors in the topology:\n"
                + "\n".join(f"  {p}" for p in self.problems))


def _number(value: Any) -> Any:
    """Accept 0x1C12 (YAML reads it as a number), "0x1C12", "#x1C12" and decimal strings."""
    if isinstance(value, str):
        try:
            return parse_int(value)
        except ValueError:
            raise ValueError(f"{value!r} is not a number (decimal, 0x.. or #x..)") from None
    if isinstance(value, bool):
        raise ValueError("expected a number, not true/false")
    return value


Number = Annotated[int, BeforeValidator(_number)]
Index = Annotated[int, BeforeValidator(_number), Field(ge=0, le=0xFFFF)]
SubIndex = Annotated[int, BeforeValidator(_number), Field(ge=0, le=0xFF)]
Address = Annotated[int, BeforeValidator(_number), Field(ge=1, le=0xFFFF)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Master(_Model):
    """The master and its cycle."""

    name: str = Field("ecatcfg", min_length=1, description="Master name in the ENI")
    cycle_time_us: int = Field(1000, ge=1, le=10_000_000,
                               description="Bus cycle in microseconds (DC SYNC0 factor 1)")
    layout: Literal["lrw", "lrd_lwr"] = Field(
        "lrw", description="lrw: one LRW per frame, outputs and inputs of a slave overlap "
                           "(EC-Engineer style); lrd_lwr: separate LWR and LRD windows "
                           "(TwinCAT style)")


class Sdo(_Model):
    """A startup SDO download, typed from the device's object dictionary."""

    index: Index
    subindex: SubIndex = 0
    value: int | float | str | None = Field(
        None, description="Value encoded by the object's data type (integers, REAL, STRING)")
    data: str | None = Field(None, description="Raw bytes in hex (wire order) instead of value")
    type: str | None = Field(None, description="Data type when the ESI has no dictionary")
    transition: Transition = Field(Transition.PS, description="When to write it (IP, PS, SO, ...)")
    complete_access: bool = False
    comment: str | None = None

    @field_validator("value", mode="before")
    @classmethod
    def _value(cls, v: Any) -> Any:
        if isinstance(v, bool):
            return int(v)
        return v

    @model_validator(mode="after")
    def _one_of(self) -> Sdo:
        if (self.value is None) == (self.data is None):
            raise ValueError("give exactly one of 'value' and 'data'")
        if self.data is not None and not re.fullmatch(r"(?:[0-9A-Fa-f]{2})+",
                                                       self.data.replace(" ", "")):
            raise ValueError(f"data {self.data!r} is not hex bytes (e.g. '0a00')")
        return self


MappingEntry = tuple[Index, SubIndex, Annotated[int, Field(ge=1, le=0xFF)]]


class Slave(_Model):
    """One slave, in bus order."""

    name: str = Field(min_length=1, pattern=r"^[^\x00-\x1f\x7f]+$",
                      description="Unique name; prefixes its process variables")
    device: str = Field(min_length=1,
                        description='ESI Type name or "VENDOR:PRODUCT[:REVISION]"')
    station_address: Address | None = Field(None, description="Default 1001, 1002, ...")
    alias: Annotated[int, BeforeValidator(_number), Field(ge=1, le=0xFFFF)] | None = Field(
        None, description="Expected station alias (register 0x0012), checked in INIT->PREOP")
    rx_pdos: list[Index] | None = Field(None, description="RxPDOs to assign (default: ESI)")
    tx_pdos: list[Index] | None = Field(None, description="TxPDOs to assign (default: ESI)")
    pdo_mapping: dict[Index, list[MappingEntry]] = Field(
        default_factory=dict, description="PDO index -> [[index, subindex, bit length], ...]")
    modules: dict[Annotated[int, BeforeValidator(_number), Field(ge=1)],
                  Annotated[int, BeforeValidator(_number), Field(ge=0, le=0xFFFFFFFF)]] = Field(
        default_factory=dict, description="Slot number (from 1) -> module ident")
    sdos: list[Sdo] = Field(default_factory=list)
    dc: str | None = Field(None, description="DC OpMode name from the ESI")


class Topology(_Model):
    """An EtherCAT line: the master and its slaves in bus order."""

    master: Master = Field(default_factory=Master)
    slaves: list[Slave] = Field(min_length=1)     # unique names: checked by the compiler


def json_schema() -> dict[str, Any]:
    schema = Topology.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "ecatcfg topology"
    return schema


# -- loading with line numbers -------------------------------------------------------------

@dataclass(slots=True)
class LoadedTopology:
    topology: Topology
    file: str
    lines: dict[Path_, int]

    def line(self, *path: str | int) -> int | None:
        """The line of the value at ``path``, or of its nearest parent that has one."""
        p: Path_ = tuple(path)
        while p:
            if p in self.lines:
                return self.lines[p]
            p = p[:-1]
        return self.lines.get((), None)

    def error(self, message: str, *path: str | int) -> EcatcfgError:
        return EcatcfgError(message, self.file, self.line(*path))


class _Walker:
    """Turns composed YAML nodes into Python values and records each value's line."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.lines: dict[Path_, int] = {}
        self.count = 0
        self.loader = yaml.SafeLoader("")

    def value(self, node: yaml.Node, path: Path_) -> Any:
        self.count += 1
        if self.count > MAX_NODES:
            raise EcatcfgError(f"more than {MAX_NODES} values (YAML aliases expanding?)",
                               self.file, node.start_mark.line + 1)
        self.lines.setdefault(path, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            out: dict[Any, Any] = {}
            for k, v in node.value:
                if k.tag == "tag:yaml.org,2002:merge":
                    raise EcatcfgError("YAML merge keys ('<<') are not supported",
                                       self.file, k.start_mark.line + 1)
                key = self.value(k, path + ("<key>",))
                if isinstance(key, (list, dict)):
                    raise EcatcfgError("a key must be a plain value", self.file,
                                       k.start_mark.line + 1)
                if key in out:
                    raise EcatcfgError(f"key {key!r} appears twice", self.file,
                                       k.start_mark.line + 1)
                sub = path + (key,)
                # Errors about a key point at the key's line (pydantic also names str keys).
                self.lines[sub] = k.start_mark.line + 1
                self.lines.setdefault(path + (str(key),), k.start_mark.line + 1)
                out[key] = self.value(v, sub)
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self.value(v, path + (i,)) for i, v in enumerate(node.value)]
        return self.loader.construct_object(node, deep=True)


def load(path: str | Path, shown_as: str | None = None) -> LoadedTopology:
    shown = shown_as or str(path)
    try:
        text = Path(path).read_bytes()
    except OSError as exc:
        raise EcatcfgError(f"cannot read: {exc.strerror}", shown) from None
    return loads(text, shown)


def loads(data: bytes | str, shown: str) -> LoadedTopology:
    if isinstance(data, bytes):
        try:
            data = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise EcatcfgError(f"not UTF-8 text (byte {exc.start})", shown) from None
    try:
        node = yaml.compose(data, Loader=_LOADER)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        raise EcatcfgError(f"not valid YAML/JSON: {exc.problem or exc.context}", shown,
                           mark.line + 1 if mark else None,
                           mark.column + 1 if mark else None) from None
    except yaml.YAMLError as exc:
        raise EcatcfgError(f"not valid YAML/JSON: {exc}", shown) from None
    if node is None:
        raise EcatcfgError("the topology is empty", shown, 1)
    walker = _Walker(shown)
    raw = walker.value(node, ())
    if not isinstance(raw, dict):
        raise EcatcfgError("a topology is a mapping with 'master' and 'slaves'", shown, 1)
    try:
        topology = Topology.model_validate(raw)
    except ValidationError as exc:
        raise TopologyError([_problem(err, shown, walker.lines)
                             for err in exc.errors()]) from None
    return LoadedTopology(topology, shown, walker.lines)


def _problem(err: Any, shown: str, lines: dict[Path_, int]) -> EcatcfgError:
    loc = tuple(err["loc"])
    # pydantic appends the union member or the validator kind to the location; drop what
    # is not a key of the document.
    where = ".".join(str(p) for p in loc if not _is_pydantic_tag(p)) or "(top level)"
    path = tuple(p for p in loc if not _is_pydantic_tag(p))
    line = None
    p = path
    while p:
        if p in lines:
            line = lines[p]
            break
        p = p[:-1]
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif err["type"] == "missing":
        msg = "required key is missing"
    value = err.get("input")
    shown_value = "" if err["type"] in ("missing", "extra_forbidden") or isinstance(
        value, (dict, list)) else f" (got {json.dumps(value, default=str)[:60]})"
    return EcatcfgError(f"{where}: {msg}{shown_value}", shown, line or lines.get(()))


def _is_pydantic_tag(part: str | int) -> bool:
    return isinstance(part, str) and (part in ("int", "float", "str", "tuple", "list")
                                      or part.startswith("function-")
                                      or part.endswith("[...]") or "[" in part)
