"""The topology file: the user's line of slaves, validated by pydantic, with YAML line numbers.

YAML (or JSON, which YAML reads too) is composed into nodes first, so every value keeps the
line it was written on: pydantic's error locations (``slaves.2.rx_pdos.0``) and the
compiler's own errors map back to ``topology.yaml:14``.  Keys are those of
``docs/compile.md`` (the topology section; ``ecatcfg schema topology`` prints the JSON
Schema); unknown keys are errors (a typo must not be silently ignored).
"""

from __future__ import annotations

import difflib
import ipaddress
import json
import types
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import (Annotated, Any, Callable, Literal, TypeVar, Union, get_args,
                    get_origin)

import yaml
from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Discriminator,
                      Field, Tag, ValidationError, WithJsonSchema, field_validator,
                      model_validator)

from ecatcfg.eoe import DNS_NAME_SIZE
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import PORT_LETTERS, Transition
from ecatcfg.esi.datatypes import bit_size as type_bits
from ecatcfg.esi.idn import MAX_DRIVE, NOTATION_PATTERN, parse_idn
from ecatcfg.esi.values import parse_int
from ecatcfg.fileio import read_input

Path_ = tuple[str | int, ...]

# libyaml's composer when PyYAML has it (10x faster on big topologies); marks are the same.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# Composing follows aliases: a few anchors can expand to millions of nodes ("billion laughs").
MAX_NODES = 200_000
# A topology nests about six levels deep; much deeper input only exhausts the stack.
MAX_DEPTH = 64
_INT = "tag:yaml.org,2002:int"
# What a YAML 1.1 int, float, bool, null or timestamp looks like: the patterns PyYAML's
# resolver tells untagged scalars by, so a tagged one is held to the same form.
_SCALAR_SYNTAX = {tag: regexp for resolvers in yaml.resolver.Resolver.yaml_implicit_resolvers
                  .values() for tag, regexp in resolvers
                  if tag.rpartition(":")[2] in ("int", "float", "bool", "null", "timestamp")}
# Characters XML 1.0 cannot carry (names and comments end up in the ENI).
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


class TopologyError(EcatcfgError):
    """One or more errors in a topology file, each with its line."""

    def __init__(self, problems: list[EcatcfgError]) -> None:
        # In line order, whichever check found them (the reader's keys, the compiler's
        # devices, PDOs, DC, SDOs): the user reads the file from the top.  Stable: errors
        # of one line keep the order they were found in.
        problems = sorted(problems, key=lambda p: p.line or 0)
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


def _xml_text(value: str) -> str:
    bad = _NOT_XML.search(value)
    if bad:
        raise ValueError(f"character U+{ord(bad.group()):04X} cannot be written to an ENI (XML)")
    return value


def _num(lo: int | None = None, hi: int | None = None) -> tuple[Any, ...]:
    """The metadata of an integer that may also be written "0x1A00", "#x1A00" or "26", for
    ``Annotated[int, *_num(lo, hi)]``.  The JSON Schema says so (and keeps the bounds): with
    the validator first, pydantic wrote ``type: integer`` with non-standard ``ge``/``le``
    keys, so editors flagged ``"0x00001111"``."""
    number: dict[str, Any] = {"type": "integer"}
    if lo is not None:
        number["minimum"] = lo
    if hi is not None:
        number["maximum"] = hi
    text = {"type": "string", "pattern": r"^\s*([+-]?[0-9]+|(0[xX]|#[xX])[0-9A-Fa-f]+)\s*$"}
    return (Field(ge=lo, le=hi), BeforeValidator(_number),
            WithJsonSchema({"anyOf": [number, text]}))


# Type aliases (``Annotated[int, ...]`` is an int to a type checker, a validated number to
# pydantic).
XmlText = Annotated[str, AfterValidator(_xml_text)]
Index = Annotated[int, *_num(0, 0xFFFF)]
SubIndex = Annotated[int, *_num(0, 0xFF)]
Address = Annotated[int, *_num(1, 0xFFFF)]
CycleTime = Annotated[int, *_num(1, 10_000_000)]
SlotNumber = Annotated[int, *_num(1)]
ModuleIdent = Annotated[int, *_num(0, 0xFFFFFFFF)]


def _module_selector(value: Any) -> int | str:
    """A module ident (a number, "0x..", "#x..") or the module's Type name (other text)."""
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise ValueError(f"a module is its ident or its Type name, not {value!r}")
    number: int
    if isinstance(value, str):
        try:
            number = parse_int(value)
        except ValueError:
            if not value.strip():
                raise ValueError("a module name cannot be empty") from None
            return _xml_text(value.strip())
    else:
        number = value
    if not 0 <= number <= 0xFFFFFFFF:
        raise ValueError(f"module ident {number} is not a 32-bit number")
    return number


def _slot_modules(value: Any) -> list[int | str]:
    """One module, or the list of modules of a slot that takes several, as a list."""
    if isinstance(value, list):
        if not value:
            raise ValueError("an empty list plugs nothing: leave the slot out")
        return [_module_selector(v) for v in value]
    return [_module_selector(value)]


def _port(value: Any) -> int:
    """A port of the parent: its letter A-D (as ENI PreviousPort writes it) or ESC port 0-3."""
    if isinstance(value, str) and value in tuple(PORT_LETTERS):
        return PORT_LETTERS.index(value)
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(PORT_LETTERS):
        return value
    raise ValueError(f"a port is A, B, C or D (ESC ports 0-3), not {value!r}")


# ESC port 0-3 of the parent slave, written A-D (or 0-3).
Port = Annotated[int, BeforeValidator(_port), WithJsonSchema(
    {"anyOf": [{"type": "string", "enum": list(PORT_LETTERS)},
               {"type": "integer", "minimum": 0, "maximum": len(PORT_LETTERS) - 1}],
     "description": "The parent's port: A-D (ESC ports 0-3; A leads toward the master)"})]


_SELECTOR_SCHEMA = {"anyOf": [{"type": "integer", "minimum": 0, "maximum": 0xFFFFFFFF},
                              {"type": "string", "minLength": 1}]}
# A slot's modules: one module (ident or Type name) or a list of them, in plug order.
SlotModules = Annotated[list[int | str], BeforeValidator(_slot_modules), WithJsonSchema(
    {"anyOf": [_SELECTOR_SCHEMA, {"type": "array", "items": _SELECTOR_SCHEMA, "minItems": 1}],
     "description": "Module ident (number, 0x.., #x..) or Type name, or a list of them"})]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Copy(_Model):
    """A slave-to-slave copy (ENI ``CopyInfo``): each cycle, after the input variable came
    back valid, the master copies it into the output variable, which the next cycle sends."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True,
                              serialize_by_alias=True)

    source: XmlText = Field(alias="from", min_length=1,
                            description="An input variable, by its ENI name "
                                        "('sensors.Channel 1.Input')")
    to: XmlText = Field(min_length=1, description="An output variable of the same bit size "
                                                  "('lamps.Channel 1-8.Output 3')")


class Master(_Model):
    """The master and its cycle."""

    name: XmlText = Field(default="ecatcfg", min_length=1,
                          description="Master name in the ENI")
    cycle_time_us: CycleTime = Field(default=1000, description="Bus cycle in microseconds "
                                                       "(DC SYNC0 factor 1)")
    watchdog: Watchdog | None = Field(
        default=None, description="Watchdogs of every slave with an ESC (a slave's own keys "
                                  "win); default: none written, the ESCs keep theirs")
    layout: Literal["lrw", "lrd_lwr"] = Field(
        default="lrw", description="lrw: one LRW per frame, outputs and inputs of a slave "
                                   "overlap (EC-Engineer style); lrd_lwr: separate LWR and "
                                   "LRD windows (TwinCAT style)")
    copies: list[Copy] = Field(
        default_factory=list, description="Slave-to-slave copies, made by the master each "
                                          "cycle in this order (ENI CopyInfos)")


def _bool_as_int(v: Any) -> Any:
    """YAML's true/false as 1/0 for a ``value`` that is a number."""
    return int(v) if isinstance(v, bool) else v


def _value_or_data(value: object, data: str | None) -> None:
    """An SDO's or IDN's start-up value: exactly one of a typed ``value`` and raw ``data``
    (hex bytes in wire order)."""
    if (value is None) == (data is None):
        raise ValueError("give exactly one of 'value' and 'data'")
    if data is not None and not re.fullmatch(r"(?:[0-9A-Fa-f]{2})+", data.replace(" ", "")):
        raise ValueError(f"data {data!r} is not hex bytes (e.g. '0a00')")


class Sdo(_Model):
    """A startup SDO download, typed from the device's object dictionary."""

    index: Index
    subindex: SubIndex = 0
    value: int | float | str | None = Field(
        default=None,
        description="Value encoded by the object's data type (integers, REAL, STRING)")
    data: str | None = Field(default=None,
                             description="Raw bytes in hex (wire order) instead of value")
    type: str | None = Field(default=None,
                             description="Data type when the ESI has no dictionary")
    transition: Transition = Field(default=Transition.PS,
                                   description="When to write it (IP, PS, SO, ...)")
    complete_access: bool = False
    comment: XmlText | None = None

    @field_validator("value", mode="before")
    @classmethod
    def _value(cls, v: Any) -> Any:
        return _bool_as_int(v)

    @model_validator(mode="after")
    def _one_of(self) -> Sdo:
        _value_or_data(self.value, self.data)
        # CompleteAccess writes a whole object from subindex 0 or 1 (ETG.1000.6): its bytes
        # are the object's layout, which one typed value cannot give.
        if self.complete_access and (self.subindex > 1 or self.data is None):
            raise ValueError("complete_access needs 'data' (the object's bytes) and "
                             "subindex 0 or 1")
        return self


def _idn(value: Any) -> int:
    """An IDN in its notation (``S-0-0001``, ``P-0-0010``: ``esi/idn.py``)."""
    if not isinstance(value, str):
        raise ValueError(f"an IDN is written S-<set>-<number> or P-<set>-<number> "
                         f"(e.g. S-0-0001), not {value!r}")
    return parse_idn(value)


Idn = Annotated[int, BeforeValidator(_idn), WithJsonSchema(
    {"type": "string", "pattern": NOTATION_PATTERN,
     "description": "IDN, e.g. S-0-0001 or P-0-0010"})]


class Soe(_Model):
    """A start-up SoE write (an IDN of a servo drive), typed from the short table of
    standard IDNs (``esi/idn.py``) or by 'type', or given as raw bytes."""

    idn: Idn
    drive: Annotated[int, *_num(0, MAX_DRIVE)] = Field(
        default=0, description="Drive number behind the slave (ESI InitCmd@Chn), 0-7")
    value: int | float | str | None = Field(
        default=None, description="Value encoded by the IDN's type (the standard IDNs' or "
                                  "'type')")
    data: str | None = Field(default=None,
                             description="Raw bytes in hex (wire order) instead of value")
    type: str | None = Field(default=None,
                             description="Data type of an IDN the table does not know "
                                         "(e.g. UINT, UDINT)")
    transition: Transition = Field(default=Transition.PS,
                                   description="When to write it: PS, SO, SP, OP or OS")
    comment: XmlText | None = None

    @field_validator("value", mode="before")
    @classmethod
    def _value(cls, v: Any) -> Any:
        return _bool_as_int(v)

    @model_validator(mode="after")
    def _one_of(self) -> Soe:
        _value_or_data(self.value, self.data)
        return self


BitLen = Annotated[int, *_num(1, 0xFF)]


class MappingVariable(_Model):
    """A mapped entry with its name and data type: how the variables of a virtual PDO are
    given (ETG.2100 ``Pdo@Virtual``: the PDO is configured from the variables mapped into
    it, which the device's dictionary need not describe)."""

    index: Index
    subindex: SubIndex = 0
    bits: BitLen | None = Field(default=None, description="Bit length (default: the type's)")
    type: str | None = Field(default=None, description="Data type, e.g. UINT, BOOL, BIT4")
    name: XmlText | None = Field(default=None, min_length=1,
                                 description="Variable name (default: the dictionary's)")

    @model_validator(mode="after")
    def _sized(self) -> MappingVariable:
        if self.type is not None:
            size = type_bits(self.type)
            if size is None:
                raise ValueError(f"unknown data type {self.type!r} (a base type such as "
                                 "BOOL, BIT4, USINT, UINT, UDINT, REAL)")
            if self.bits is not None and self.bits != size:
                raise ValueError(f"type {self.type} is {size} bits, not {self.bits}")
            if not 1 <= size <= 0xFF:
                raise ValueError(f"type {self.type} ({size} bits) cannot be mapped "
                                 "(a PDO entry is 1 to 255 bits)")
        elif self.bits is None:
            raise ValueError("give 'bits' or 'type'")
        return self

    @property
    def bit_len(self) -> int:
        if self.bits is not None:
            return self.bits
        size = type_bits(self.type or "")
        assert size is not None                       # checked by _sized
        return size


def _entry_form(value: Any) -> str:
    """Which spelling a mapping entry is: a mapping is the written-out one, anything else
    the [index, subindex, bits] list (so an error speaks of the one the user wrote)."""
    return "dict" if isinstance(value, (dict, MappingVariable)) else "list"


MappingEntry = Annotated[
    Annotated[tuple[Index, SubIndex, BitLen], Tag("list")]
    | Annotated[MappingVariable, Tag("dict")],
    Discriminator(_entry_form)]


# -- EoE IP parameters and watchdogs (docs/compile.md "EoE IP parameters", "Watchdogs") -----

_MAC = re.compile(r"[0-9A-Fa-f]{2}([:-])[0-9A-Fa-f]{2}(?:\1[0-9A-Fa-f]{2}){4}")
MAC_AUTO = "auto"


def _ipv4(value: Any) -> str:
    """A dotted IPv4 address (the text is kept; the compiler converts it)."""
    if not isinstance(value, str):
        raise ValueError(f"an IPv4 address is written a.b.c.d, not {value!r}")
    try:
        ipaddress.IPv4Address(value.strip())
    except ValueError as exc:
        raise ValueError(f"{value!r} is not an IPv4 address: {exc}") from None
    return value.strip()


def _ip_interface(value: Any) -> str:
    """An IPv4 address with an optional prefix length or netmask: 192.168.1.10/24,
    192.168.1.10/255.255.255.0 or 192.168.1.10."""
    if not isinstance(value, str):
        raise ValueError(f"an IPv4 address is written a.b.c.d[/prefix], not {value!r}")
    try:
        ipaddress.IPv4Interface(value.strip())
    except ValueError as exc:
        raise ValueError(f"{value!r} is not an IPv4 address with an optional /prefix or "
                         f"/netmask: {exc}") from None
    mask = value.strip().partition("/")[2]
    if "." in mask:
        _netmask(mask)
    return value.strip()


def _netmask(value: Any) -> str:
    text = _ipv4(value)
    # Ones, then zeros (ipaddress would also take a host mask, 0.0.0.255).
    zeros = ~int(ipaddress.IPv4Address(text)) & 0xFFFFFFFF
    if zeros & (zeros + 1):
        raise ValueError(f"{text!r} is not a netmask (ones, then zeros)")
    return text


def _mac(value: Any) -> str:
    """Six bytes in hex, separated by ':' or '-', or ``auto``; a unicast address (the
    group bit, bit 0 of the first byte, clear: IEEE 802)."""
    if isinstance(value, int) and not isinstance(value, bool):
        # YAML 1.1 reads 10:18:20:11:01:04 as a base-60 number.
        raise ValueError("write the MAC address in quotes (YAML reads digits separated by "
                         "':' as a base-60 number)")
    if not isinstance(value, str):
        raise ValueError(f"a MAC address is six hex bytes (02:00:00:00:03:e9), not {value!r}")
    text = value.strip()
    if text == MAC_AUTO:
        return text
    if not _MAC.fullmatch(text):
        raise ValueError(f"{value!r} is not a MAC address (six hex bytes separated by ':' "
                         "or '-', e.g. 02:00:00:00:03:e9), nor 'auto'")
    if int(text[:2], 16) & 0x01:
        raise ValueError(f"{text} is a group (multicast) address; a device's is unicast")
    return text


def _dns_name(value: str) -> str:
    if not value.isascii() or not value.isprintable():
        raise ValueError(f"{value!r}: a DNS name is printable ASCII")
    if len(value) > DNS_NAME_SIZE:
        raise ValueError(f"{value!r} has {len(value)} characters; the set IP parameter "
                         f"request holds {DNS_NAME_SIZE} (ETG.1000.6)")
    return value


Ipv4 = Annotated[str, BeforeValidator(_ipv4),
                 WithJsonSchema({"type": "string", "format": "ipv4"})]
Ipv4Interface = Annotated[str, BeforeValidator(_ip_interface), WithJsonSchema(
    {"type": "string", "pattern": r"^\s*[0-9.]+(/[0-9.]+)?\s*$"})]
Netmask = Annotated[str, BeforeValidator(_netmask),
                    WithJsonSchema({"type": "string", "format": "ipv4"})]
Mac = Annotated[str, BeforeValidator(_mac), WithJsonSchema(
    {"type": "string", "pattern": r"^\s*(auto|[0-9A-Fa-f]{2}([:-][0-9A-Fa-f]{2}){5})\s*$"})]


class Eoe(_Model):
    """EoE IP parameters of a slave: one set IP parameter request (ETG.1000.6 EoE) in
    INIT->PREOP, written as EC-Engineer writes it.  Parameters left out are not set."""

    ip: Ipv4Interface | None = Field(
        default=None, description="IPv4 address, with the subnet as /prefix or /netmask "
                                  "(192.168.1.10/24)")
    subnet_mask: Netmask | None = Field(
        default=None, description="Subnet mask, if not given with 'ip'")
    gateway: Ipv4 | None = Field(default=None, description="Default gateway")
    dns: Ipv4 | None = Field(default=None, description="DNS server")
    dns_name: Annotated[str, AfterValidator(_dns_name), WithJsonSchema(
        {"type": "string", "maxLength": DNS_NAME_SIZE})] | None = Field(
        default=None, description=f"Host name (DNS name), at most {DNS_NAME_SIZE} characters")
    mac: Mac | None = Field(
        default=None, description="MAC address of the slave's EoE port; 'auto': "
                                  "02:00:00:00 and the station address, as EC-Engineer "
                                  "writes it")

    @model_validator(mode="after")
    def _consistent(self) -> Eoe:
        if all(v is None for v in (self.ip, self.subnet_mask, self.gateway, self.dns,
                                   self.dns_name, self.mac)):
            raise ValueError("sets nothing: give ip, subnet_mask, gateway, dns, dns_name "
                             "or mac")
        if self.ip is not None and "/" in self.ip and self.subnet_mask is not None:
            given = ipaddress.IPv4Interface(self.ip).netmask
            if given != ipaddress.IPv4Address(self.subnet_mask):
                raise ValueError(f"ip {self.ip} gives subnet mask {given}, subnet_mask says "
                                 f"{self.subnet_mask}")
        return self


def _not_bool(value: Any) -> Any:
    if isinstance(value, bool):
        raise ValueError("expected a number, not true/false")
    return value


# A watchdog time in ms: a number (decimals allowed: 0.5), 0 = off.
WatchdogMs = Annotated[float, Field(ge=0, allow_inf_nan=False), BeforeValidator(_not_bool)]


class Watchdog(_Model):
    """The ESC watchdogs, written in INIT->PREOP as TwinCAT and EC-Engineer write them
    (registers 0x0400, 0x0410, 0x0420).  A key left out takes the master's value, else the
    ESC's power-on value (divider 2498, 100 ms)."""

    divider: Annotated[int, *_num(0, 0xFFFF)] | None = Field(
        default=None, description="Register 0x0400 (TwinCAT: multiplier): time base "
                                  "(divider + 2) x 40 ns; default 2498 = 100 us")
    pdi_ms: WatchdogMs | None = Field(
        default=None, description="PDI watchdog (0x0410) in ms, a whole number of time "
                                  "bases; 0 = off; default 100")
    sm_ms: WatchdogMs | None = Field(
        default=None, description="SyncManager (process data) watchdog (0x0420) in ms, a "
                                  "whole number of time bases; 0 = off; default 100")


class Slave(_Model):
    """One slave; plugged into the slave before it unless it names its parent."""

    name: XmlText = Field(min_length=1, pattern=r"^[^\x00-\x1f\x7f]+$",
                          description="Unique name; prefixes its process variables")
    device: str = Field(min_length=1,
                        description='ESI Type name or "VENDOR:PRODUCT[:REVISION]"')
    esi: str | None = Field(
        default=None, min_length=1,
        description="The ESI file that describes the device, where several describe it "
                    "differently: a path relative to the topology file, or a file of the "
                    "library by its name as given with --esi or its file name")
    station_address: Address | None = Field(default=None,
                                            description="Default 1001, 1002, ...")
    alias: Address | None = Field(
        default=None,
        description="Expected station alias (register 0x0012), checked in INIT->PREOP; "
                    "identifies the head of a hot-connect group")
    hot_connect: bool = Field(
        default=False,
        description="Head of a hot-connect group: this slave and every slave behind it (its "
                    "branch; slaves behind another head form that head's group) may be "
                    "absent at start-up and join later. Needs 'alias' or 'device_id'")
    device_id: Annotated[int, *_num(0, 0xFFFF)] | None = Field(
        default=None,
        description="Explicit device ID (ID switch) of a hot-connect group's head, where "
                    "the ESI says the device has one (Info/IdentificationAdo or "
                    "IdentificationReg134)")
    rx_pdos: list[Index] | None = Field(default=None,
                                        description="RxPDOs to assign (default: ESI)")
    tx_pdos: list[Index] | None = Field(default=None,
                                        description="TxPDOs to assign (default: ESI)")
    # At least one entry: an empty PDO is left out of rx_pdos/tx_pdos, not assigned.
    pdo_mapping: dict[Index, Annotated[list[MappingEntry], Field(min_length=1)]] = Field(
        default_factory=dict,
        description="PDO index -> its entries, each [index, subindex, bit length] or "
                    "{index, subindex, bits or type, name}; index 0 is a gap of that many "
                    "bits")
    modules: dict[SlotNumber, SlotModules] = Field(
        default_factory=dict,
        description="Slot number (from 1) -> its module, or the list of modules in a slot "
                    "that takes several (a station's row of I/O modules, in order)")
    sdos: list[Sdo] = Field(default_factory=list)
    soe: list[Soe] = Field(default_factory=list,
                           description="SoE start-up writes (servo drive IDNs)")
    dc: str | None = Field(default=None, description="DC OpMode name from the ESI")
    eoe: Eoe | None = Field(default=None, description="EoE IP parameters to set")
    watchdog: Watchdog | None = Field(
        default=None, description="Watchdogs to write ({}: the master's, else the "
                                  "defaults); its keys win over the master's")
    parent: XmlText | None = Field(
        default=None, min_length=1,
        description="Name of the slave this one is plugged into (default: the nearest slave "
                    "before it with a free port of the kind of this slave's port A)")
    port: Port | None = Field(
        default=None, description="The parent's port it is plugged into, B-D (default: the "
                                  "parent's first free port of the right kind in processing "
                                  "order D, B, C); needs parent")

    @model_validator(mode="after")
    def _port_needs_parent(self) -> Slave:
        if self.port is not None and self.parent is None:
            raise ValueError("'port' needs 'parent' (the slave whose port it is)")
        return self


class Topology(_Model):
    """An EtherCAT network: the master and its slaves, a line in bus order or a tree of
    branches through junctions (``parent``/``port``)."""

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
    """A validated topology.  ``unknown``: the unknown keys left out of it, when it was
    loaded with ``unknown_keys="defer"``; :func:`checked` reports them with whatever the
    compiler finds in the rest."""

    topology: Topology
    file: str
    lines: dict[Path_, int]
    unknown: list[EcatcfgError] = field(default_factory=list)

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
        if len(path) > MAX_DEPTH:       # aliases can nest deeper than the text shows
            raise EcatcfgError(f"values nested more than {MAX_DEPTH} levels deep",
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
        syntax = _SCALAR_SYNTAX.get(node.tag)
        if syntax is not None and not syntax.match(node.value):
            # An explicit tag the text does not fit (!!float abc, !!int zz, !!bool 0,
            # !!timestamp 0): refused before PyYAML's constructor, which assumes the text
            # has the type's form and fails in its own ways when it has not.
            raise self._not_valid(node)
        digits = sum(map(str.isdigit, node.value)) if node.tag == _INT else 0
        if digits > sys.get_int_max_str_digits():
            raise self._not_valid(node, f"{digits} digits, more than Python converts")
        try:
            value = self.loader.construct_object(node, deep=True)
        except yaml.YAMLError as exc:        # a tag SafeLoader does not know (!foo, !!python/..)
            problem = getattr(exc, "problem", None) or str(exc)
            raise EcatcfgError(f"not valid here: {problem}", self.file,
                               node.start_mark.line + 1) from None
        except ValueError as exc:            # a date outside the calendar (2001-13-45)
            raise self._not_valid(node, str(exc)) from None
        # A hex int has few decimal digits in its text and many in its value (0x and 3 600
        # letters: 4 335 digits): any message or JSON that shows it would fail with Python's
        # digit limit, so it is refused here, as the decimal ones are above.
        limit = sys.get_int_max_str_digits()
        if isinstance(value, int) and limit and value.bit_length() * _LOG10_2 > limit:
            raise self._not_valid(node, f"about {int(value.bit_length() * _LOG10_2)} "
                                        "digits, more than Python converts")
        return value

    def _not_valid(self, node: yaml.Node, reason: str = "") -> EcatcfgError:
        kind = node.tag.rpartition(":")[2] or node.tag
        text = node.value if len(node.value) <= 40 else f"{node.value[:40]}..."
        return EcatcfgError(f"{text!r} is not a valid {kind}" + (f": {reason}" if reason
                                                                 else ""),
                            self.file, node.start_mark.line + 1, node.start_mark.column + 1)


_LOG10_2 = 0.30103     # decimal digits per bit


def load(path: str | Path, shown_as: str | None = None,
         unknown_keys: Literal["error", "defer"] = "error") -> LoadedTopology:
    shown = shown_as or str(path)
    try:
        text = read_input(path, shown)
    except OSError as exc:
        raise EcatcfgError(f"cannot read: {exc.strerror}", shown) from None
    # Beremiz's EtherLab-plugin file is read as the topology it describes.
    from ecatcfg.compiler.beremiz import plugin_topology
    converted = plugin_topology(text, shown)
    if converted is not None:
        return loads(converted, f"{shown} (Beremiz's plugin file, read as a topology)",
                     unknown_keys)
    return loads(text, shown, unknown_keys)


_T = TypeVar("_T")


def checked(loaded: LoadedTopology, check: Callable[[], _T]) -> _T:
    """``check()`` (the compiler, on ``loaded``), raising its errors together with the
    unknown keys ``loaded`` was read without, in line order.

    An unknown key is never used: the rest of the topology means the same with or without
    it, so what the compiler finds there is what the next run would find once the key is
    gone, and the user sees every error at once instead of one kind per run.  A topology
    that is not valid otherwise (a missing or mistyped value) is not compiled: a value the
    model cannot hold has no meaning to resolve, and pydantic already lists all of those
    together."""
    try:
        result = check()
    except TopologyError as exc:
        raise TopologyError(loaded.unknown + exc.problems) from None
    except EcatcfgError as exc:
        if loaded.unknown:
            raise TopologyError(loaded.unknown + [exc]) from None
        raise
    if loaded.unknown:
        raise TopologyError(loaded.unknown)
    return result


def loads(data: bytes | str, shown: str,
          unknown_keys: Literal["error", "defer"] = "error") -> LoadedTopology:
    """The topology in ``data``.  Errors of the reader and of the model are raised (a
    :class:`TopologyError` lists every one); with ``unknown_keys="defer"``, unknown keys
    alone are not raised but left out and listed in ``LoadedTopology.unknown`` (the caller
    reports them through :func:`checked`)."""
    _refuse_xml(data, shown)
    if isinstance(data, bytes):
        raw = data
        try:
            data = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = raw.count(b"\n", 0, exc.start) + 1
            raise EcatcfgError(f"not UTF-8 text (byte {exc.start})", shown, line,
                               exc.start - raw.rfind(b"\n", 0, exc.start)) from None
    try:
        _prescan_any_library(data, shown)
        node = yaml.compose(data, Loader=_LOADER)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context
        if mark and data[mark.index:mark.index + 1] == "\t":     # the usual cause
            problem = "a tab; YAML indents with spaces"
        raise EcatcfgError(f"not valid YAML/JSON: {problem}", shown,
                           mark.line + 1 if mark else None,
                           mark.column + 1 if mark else None) from None
    except yaml.reader.ReaderError as exc:
        # A character YAML does not allow; libyaml gives a byte offset, PyYAML a character
        # index, so the place is found again in the text.
        bad = yaml.reader.Reader.NON_PRINTABLE.search(data)
        at = bad.start() if bad else 0
        raise EcatcfgError(f"not valid YAML/JSON: character U+{ord(data[at]):04X} is not "
                           f"allowed ({exc.reason})" if bad else
                           f"not valid YAML/JSON: {exc.reason}", shown,
                           data.count("\n", 0, at) + 1,
                           at - data.rfind("\n", 0, at)) from None
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
        errors = exc.errors()
        problems = [_problem(err, shown, walker.lines) for err in errors]
        if unknown_keys == "error" or any(e["type"] != "extra_forbidden" for e in errors):
            raise TopologyError(problems) from None
        try:
            for err in errors:
                _drop(raw, [p for p in err["loc"] if not _is_pydantic_tag(p)])
            topology = Topology.model_validate(raw)
        except ValidationError as again:
            # A model's own check that did not run while it had an unknown key ('value'
            # misspelt: then neither 'value' nor 'data' is given): reported with the keys.
            raise TopologyError(problems + [_problem(err, shown, walker.lines)
                                            for err in again.errors()]) from None
        except (LookupError, TypeError):
            # Not expected (the keys left out were extra); never compile a guess.
            raise TopologyError(problems) from None
        return LoadedTopology(topology, shown, walker.lines, problems)
    return LoadedTopology(topology, shown, walker.lines)


def _drop(raw: Any, path: list[str | int]) -> None:
    """Leave the key at ``path`` out of the document ``raw``."""
    for part in path[:-1]:
        raw = raw[part]
    del raw[path[-1]]


# How far into a file its root element is looked for (past the XML declaration and comments).
XML_HEAD = 1 << 20
# The root elements of the ETG's XML formats (ETG.2000 ESI, ETG.2100 ENI).
_XML_ROOTS = {"EtherCATInfo": "an ESI (device description)",
              "EtherCATInfoList": "a list of ESI documents (IgH's ethercat xml)",
              "EtherCATConfig": "an ENI (network configuration)"}
_XML_START = re.compile(r"<\?xml\b|<!--|<!DOCTYPE|<[A-Za-z_]")
_XML_ROOT = re.compile(r"<([A-Za-z_][\w.:-]*)")
_XML_PROLOG = re.compile(r"\s*(?:<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)", re.S)


def _refuse_xml(data: bytes | str, shown: str) -> None:
    """XML is not YAML: PyYAML would read an ENI as one long string and the model would say
    "a topology is a mapping" (or, for an ISO-8859-1 export, "not UTF-8").  Say what the
    file is, by its root element, and that ``compile`` wants a topology (an ENI goes to
    ``apply``, an ESI to ``--esi``).  Looked for before the text is decoded: XML declares
    its own encoding; the names of its markup are ASCII in every encoding but UTF-16."""
    head = data[:XML_HEAD]
    if isinstance(head, bytes):
        utf16 = head.startswith((b"\xff\xfe", b"\xfe\xff"))
        head = head.decode("utf-16" if utf16 else "latin-1", errors="replace") \
            if not head.startswith(b"\xef\xbb\xbf") else head[3:].decode("latin-1")
    text = head.lstrip("\ufeff")
    if not _XML_START.match(text.lstrip()):
        return
    at = len(text) - len(text.lstrip())
    while (prolog := _XML_PROLOG.match(text, at)) and prolog.end() > at:
        at = prolog.end()
    at += len(text[at:]) - len(text[at:].lstrip())
    root = _XML_ROOT.match(text, at)
    if root is None:
        return
    name = root.group(1)
    what = _XML_ROOTS.get(name.rpartition(":")[2])
    raise EcatcfgError(f"this is {what + ': ' if what else ''}XML with root element <{name}>, "
                       "not a topology "
                       "(YAML or JSON)", shown, text.count("\n", 0, at) + 1)


def _prescan_any_library(data: str, shown: str) -> None:
    """:func:`_prescan` with ``_LOADER``, whatever limits of its own the YAML library has.

    libyaml 0.2.6 (in PyYAML 6.0.4's wheels) refuses a document nested deeper than its own
    limit (1000) with its own ScannerError, and it does so before the parser's events
    reach our depth check: in a flow collection its scanner reads the opening brackets
    ahead, looking for a simple key.  PyYAML's own parser keeps its state on a list (no
    limit, no recursion) and gives the same marks, so the refused text is scanned again
    with it: too deep or too big gives this reader's own message, with its line; input
    that is not YAML fails there too, and the library's first error is what is reported.
    Only the text up to where the library stopped is scanned again, and only when it
    opens more flow collections than MAX_DEPTH: block nesting takes a line per level, so
    its events reach the check before any library reads that far ahead (PyYAML's parser is
    some 50 times slower than libyaml on a long scalar)."""
    try:
        _prescan(data, shown, _LOADER)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        # libyaml counts marks in characters; an offset in bytes would only reach further.
        upto = data if mark is None else data[:mark.index + 1]
        if _LOADER is not yaml.SafeLoader and upto.count("[") + upto.count("{") > MAX_DEPTH:
            try:
                _prescan(upto, shown, yaml.SafeLoader)
            except yaml.YAMLError:
                pass
        raise


def _prescan(data: str, shown: str, loader: Any) -> None:
    """Refuse huge or deeply nested input from the parser's event stream, before composing
    builds a node for every value (a 100 MB file would take minutes and gigabytes)."""
    events = depth = 0
    for event in yaml.parse(data, Loader=loader):
        events += 1
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
        if events > MAX_NODES or depth > MAX_DEPTH:
            what = (f"more than {MAX_NODES} values" if events > MAX_NODES
                    else f"values nested more than {MAX_DEPTH} levels deep")
            mark = event.start_mark                 # always set by yaml's own parsers
            raise EcatcfgError(f"{what}; this is not a topology", shown,
                               mark.line + 1 if mark is not None else None)


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
        msg = "unknown key" + _did_you_mean(path)
    elif err["type"] == "missing":
        msg = "required key is missing"
    value = err.get("input")
    shown_value = "" if err["type"] in ("missing", "extra_forbidden") or isinstance(
        value, (dict, list)) else f" (got {json.dumps(value, default=str)[:60]})"
    return EcatcfgError(f"{where}: {msg}{shown_value}", shown, line or lines.get(()))


def _is_pydantic_tag(part: str | int) -> bool:
    return isinstance(part, str) and (part in ("int", "float", "str", "tuple", "list",
                                               "dict")
                                      or part.startswith("function-")
                                      or part.endswith("[...]") or "[" in part)


def _did_you_mean(path: Path_) -> str:
    """"; did you mean 'cycle_time_us'?" for a misspelt key: the closest of the keys allowed
    where it is written (difflib's ratio, its default cut-off of 0.6)."""
    if not path or not isinstance(path[-1], str):
        return ""
    model = _model_at(path[:-1])
    if model is None:
        return ""
    close = difflib.get_close_matches(path[-1], list(model.model_fields), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def _model_at(path: Path_) -> type[BaseModel] | None:
    """The model whose keys the mapping at ``path`` (of a :class:`Topology`) takes."""
    kind: Any = Topology
    for part in path:
        kind = _unwrap(kind)
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            info = kind.model_fields.get(part) if isinstance(part, str) else None
            if info is None:
                return None
            kind = info.annotation
        elif get_origin(kind) is list and isinstance(part, int):
            kind = get_args(kind)[0]
        elif get_origin(kind) is dict:
            kind = get_args(kind)[1]
        else:
            return None
    kind = _unwrap(kind)
    return kind if isinstance(kind, type) and issubclass(kind, BaseModel) else None


def _unwrap(kind: Any) -> Any:
    """``kind`` without Annotated metadata and None; of a union, its one model."""
    while True:
        origin = get_origin(kind)
        if origin is Annotated:
            kind = get_args(kind)[0]
        elif origin is Union or origin is types.UnionType:
            members = [_unwrap(a) for a in get_args(kind) if a is not type(None)]
            models = [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]
            if len(members) == 1:
                kind = members[0]
            else:
                return models[0] if len(models) == 1 else kind
        else:
            return kind
