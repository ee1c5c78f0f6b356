"""``ecatcfg.record``: the dataclass-like records of the plan, the mailbox codec and the
master behave as ``@dataclass(slots=True)`` / ``(frozen=True, slots=True)`` did."""

from __future__ import annotations

import copy
import pickle
from dataclasses import dataclass
from dataclasses import field as dc_field

import pytest

from ecatcfg.record import FrozenInstanceError, field, fields, record, replace


@record
class Point:
    """A docstring stays."""

    x: int
    y: int = 0
    tags: list[str] = field(default_factory=list)

    @property
    def norm1(self) -> int:
        return abs(self.x) + abs(self.y)


@record(frozen=True)
class Key:
    index: int
    subindex: int = 0


@record(frozen=True)
class OtherKey:
    index: int
    subindex: int = 0


# The same classes as dataclasses: the reference the records are compared with.
@dataclass(slots=True)
class DcPoint:
    x: int
    y: int = 0
    tags: list[str] = dc_field(default_factory=list)


def test_construction_defaults_and_factories_as_dataclasses():
    for cls in (Point, DcPoint):
        a, b = cls(1), cls(x=1, y=2, tags=["t"])
        assert (a.x, a.y, a.tags, b.x, b.y, b.tags) == (1, 0, [], 1, 2, ["t"])
        assert cls(1).tags is not cls(1).tags              # a new list per instance
    with pytest.raises(TypeError):
        Point()                                            # x has no default
    with pytest.raises(TypeError):
        Point(1, 2, [], 4)


def test_repr_eq_and_hash_as_dataclasses():
    assert repr(Point(1, 2)) == "Point(x=1, y=2, tags=[])"
    assert repr(Point(1, 2)) == repr(DcPoint(1, 2)).replace("DcPoint", "Point")
    assert Point(1, 2) == Point(1, 2) and Point(1, 2) != Point(2, 1)
    assert Key(1) != OtherKey(1)                           # other class, same values
    assert Point(1) != (1, 0, [])
    with pytest.raises(TypeError):
        hash(Point(1))                                     # mutable: unhashable, as dataclasses
    assert hash(Key(0x1C12, 1)) == hash(Key(0x1C12, 1))
    assert {Key(1), Key(1), Key(2)} == {Key(1), Key(2)}


def test_slots_no_stray_attributes_and_frozen():
    p = Point(1)
    p.y = 5
    assert p.y == 5
    with pytest.raises(AttributeError):
        p.z = 1                                            # a typo is an error, not a new field
    k = Key(1)
    with pytest.raises(FrozenInstanceError):
        k.index = 2
    with pytest.raises(FrozenInstanceError):
        del k.index
    assert not hasattr(p, "__dict__")
    assert Point.__doc__ == "A docstring stays." and Point(3, -4).norm1 == 7


def test_pickle_copy_replace_fields_and_match():
    for obj in (Point(1, 2, ["a"]), Key(0x6060, 0)):
        assert pickle.loads(pickle.dumps(obj)) == obj
        assert copy.deepcopy(obj) == obj and copy.copy(obj) == obj
    p = Point(1, 2, ["a"])
    assert replace(p, y=3) == Point(1, 3, ["a"]) and p.y == 2
    assert replace(Key(1, 2), subindex=5) == Key(1, 5)
    with pytest.raises(TypeError, match="no field"):
        replace(p, z=1)
    assert fields(Point) == ("x", "y", "tags") == fields(p)
    match Key(0x1C12, 3):
        case Key(index, sub):
            assert (index, sub) == (0x1C12, 3)


def test_declaration_errors_as_dataclasses():
    with pytest.raises(TypeError, match="without a default"):
        @record
        class Bad:
            a: int = 0
            b: int
    with pytest.raises(ValueError, match="mutable default"):
        @record
        class Shared:
            items: list = []                               # noqa: RUF012
    with pytest.raises(TypeError, match="inherit"):
        @record
        class Sub(Point):
            z: int = 0
    with pytest.raises(ValueError, match="bytearray"):
        @record
        class SharedBuffer:
            buf: bytearray = bytearray(4)
    with pytest.raises(TypeError, match="__repr__"):
        @record
        class OwnRepr:
            x: int

            def __repr__(self) -> str:
                return "mine"


def test_class_variables_are_not_fields():
    import typing

    @record
    class Limits:
        x: int
        limit: typing.ClassVar[int] = 5
        _LAYOUT = "<HH"                                    # not annotated: a class attribute

    assert fields(Limits) == ("x",) and Limits.limit == 5 and Limits(1)._LAYOUT == "<HH"


def test_the_apply_path_imports_no_dataclasses():
    """The point of ecatcfg.record: ``apply`` imports neither dataclasses nor inspect."""
    import subprocess
    import sys
    probe = ("import sys\n"
             "import ecatcfg.cli.apply, ecatcfg.cli.report, ecatcfg.eni.cache\n"
             "import ecatcfg.runtime.network, ecatcfg.runtime.link\n"
             "import ecatcfg.runtime.master.sdo_client\n"
             "print(sorted(m for m in ('dataclasses', 'inspect', 'lxml', 'hashlib',\n"
             "                         'statistics', 'rich') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"
