"""Slotted record classes, declared like dataclasses but cheap to define at import.

``@record`` reads a class the way ``@dataclass(slots=True)`` does (annotated fields, in
order, with optional defaults or ``field(default_factory=...)``) and gives it
``__slots__``, ``__init__``, ``__repr__``, ``__eq__``, ``__match_args__`` and pickling;
``@record(frozen=True)`` also makes instances read-only and hashable.  Like dataclasses it
refuses a field without a default after one with, and an unhashable default (use
``field(default_factory=...)``); unlike them it refuses a class body that defines one of
the methods it writes (a class that needs its own ``__eq__`` is better a plain class).

Why not ``dataclasses``: in Python 3.11 ``@dataclass`` compiles three to six methods per
class from source text at import time, 0.25-0.6 ms per class.  The plan model, the mailbox
codec and the master define 49 such classes, which with the ``dataclasses`` module itself
(it imports ``inspect``) came to 26 of the 39 ms that ``ecatcfg apply`` spent importing
before it sent its first frame (docs/BENCHMARKS.md, "Startup").  Here only ``__init__`` is
compiled (about 0.06 ms, the same code ``dataclass`` would generate, so constructing is as
fast); the other methods are shared functions.

The ESI model and the compiler's internals keep ``dataclasses``: they are not on the
startup path of ``apply``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, dataclass_transform, overload

T = TypeVar("T")

_NO_DEFAULT = object()
_USE_FACTORY = object()                     # the __init__ default of a default_factory field


class _Factory:
    __slots__ = ("make",)

    def __init__(self, make: Callable[[], Any]) -> None:
        self.make = make


class FrozenInstanceError(AttributeError):
    """Assignment to a field of a ``@record(frozen=True)`` instance."""


# Typed as :func:`dataclasses.field` is: the call stands for a value of the field's type.
@overload
def field(*, default: T) -> T: ...
@overload
def field(*, default_factory: Callable[[], T]) -> T: ...
def field(*, default: Any = _NO_DEFAULT, default_factory: Callable[[], Any] | None = None) -> Any:
    """A field's default, as in :func:`dataclasses.field`: a value, or a factory called for
    every new instance (mutable defaults: ``field(default_factory=list)``)."""
    if default_factory is not None:
        if default is not _NO_DEFAULT:
            raise ValueError("field() takes default or default_factory, not both")
        return _Factory(default_factory)
    return default


# Type checkers learn from ``dataclass_transform`` (PEP 681) that a record class gets the
# ``__init__``, ``__eq__`` and ``__match_args__`` a dataclass would, that ``frozen=True`` makes
# it read-only, and that ``field()`` declares a field's default.
@overload
def record(cls: type[T], /) -> type[T]: ...
@overload
def record(*, frozen: bool = False) -> Callable[[type[T]], type[T]]: ...
@dataclass_transform(field_specifiers=(field,))
def record(cls: type[T] | None = None, /, *, frozen: bool = False) -> Any:
    """Class decorator: ``@record`` or ``@record(frozen=True)`` (see the module docstring)."""
    def wrap(c: type[T]) -> type[T]:
        return _build(c, frozen)
    return wrap if cls is None else wrap(cls)


def fields(obj: Any) -> tuple[str, ...]:
    """The field names of a record class or instance, in declaration order."""
    names: tuple[str, ...] = obj.__record_fields__
    return names


def replace(obj: T, **changes: Any) -> T:
    """A copy of the record ``obj`` with some fields changed (:func:`dataclasses.replace`)."""
    values = {name: getattr(obj, name) for name in fields(obj)}
    unknown = set(changes) - set(values)
    if unknown:
        raise TypeError(f"{type(obj).__name__} has no field {', '.join(sorted(unknown))}")
    values.update(changes)
    return type(obj)(**values)


# -- the shared methods ------------------------------------------------------------------------

def _values(self: Any) -> tuple[Any, ...]:
    return tuple(getattr(self, name) for name in self.__record_fields__)


def _repr(self: Any) -> str:
    inner = ", ".join(f"{name}={getattr(self, name)!r}" for name in self.__record_fields__)
    return f"{type(self).__qualname__}({inner})"


def _eq(self: Any, other: Any) -> Any:
    if other.__class__ is self.__class__:
        return _values(self) == _values(other)
    return NotImplemented


def _hash(self: Any) -> int:
    return hash(_values(self))


def _reduce(self: Any) -> tuple[type, tuple[Any, ...]]:
    """Pickle and copy by calling the class with the field values."""
    return type(self), _values(self)


def _frozen_setattr(self: Any, name: str, value: Any) -> None:
    raise FrozenInstanceError(f"cannot assign to field {name!r} of a frozen "
                              f"{type(self).__name__}")


def _frozen_delattr(self: Any, name: str) -> None:
    raise FrozenInstanceError(f"cannot delete field {name!r} of a frozen "
                              f"{type(self).__name__}")


# -- building a class ---------------------------------------------------------------------------

def _build(cls: type, frozen: bool) -> type:
    if any(hasattr(base, "__record_fields__") for base in cls.__mro__[1:]):
        raise TypeError(f"{cls.__name__}: records do not inherit from records")
    generated = {"__init__", "__repr__", "__eq__", "__hash__", "__setattr__", "__delattr__",
                 "__reduce__", "__slots__"} & set(cls.__dict__)
    if generated:
        raise TypeError(f"{cls.__name__}: @record writes {', '.join(sorted(generated))} "
                        "itself; use a plain class for your own")
    annotations = cls.__dict__.get("__annotations__", {})
    names = tuple(n for n, a in annotations.items() if not _is_classvar(a))
    defaults = {n: cls.__dict__[n] for n in names if n in cls.__dict__}
    seen_default = None
    for name in names:
        value = defaults.get(name, _NO_DEFAULT)
        if value is _NO_DEFAULT and seen_default:
            raise TypeError(f"{cls.__name__}: field {name!r} without a default follows "
                            f"{seen_default!r}, which has one")
        if value is not _NO_DEFAULT:
            seen_default = name
        if not isinstance(value, _Factory) and type(value).__hash__ is None:
            # dataclasses' rule: an unhashable default (list, dict, bytearray ...) would be
            # one object shared by every instance.
            raise ValueError(f"{cls.__name__}.{name}: mutable default "
                             f"{type(value).__name__}; use field(default_factory=...)")

    body = {k: v for k, v in cls.__dict__.items()
            if k not in defaults and k not in ("__dict__", "__weakref__")}
    body.update(__slots__=names, __match_args__=names, __record_fields__=names,
                __init__=_make_init(cls, names, defaults, frozen),
                __repr__=_repr, __eq__=_eq, __reduce__=_reduce)
    if frozen:
        body.update(__hash__=_hash, __setattr__=_frozen_setattr, __delattr__=_frozen_delattr)
    else:
        body["__hash__"] = None             # mutable and compared by value: not hashable
    new = type(cls)(cls.__name__, cls.__bases__, body)
    new.__qualname__ = cls.__qualname__
    return new


def _is_classvar(annotation: Any) -> bool:
    """``ClassVar[...]`` as a string (postponed annotations) or as the typing object."""
    text = annotation if isinstance(annotation, str) else repr(annotation)
    return text.startswith(("ClassVar", "typing.ClassVar"))


def _make_init(cls: type, names: tuple[str, ...], defaults: dict[str, Any],
               frozen: bool) -> Callable[..., None]:
    """The same ``__init__`` dataclasses would write, compiled in one go."""
    env: dict[str, Any] = {"_USE_FACTORY": _USE_FACTORY, "_set": object.__setattr__}
    params, lines = ["self"], []
    for name in names:
        value = defaults.get(name, _NO_DEFAULT)
        given = name
        if value is _NO_DEFAULT:
            params.append(name)
        elif isinstance(value, _Factory):
            env[f"_make_{name}"] = value.make
            params.append(f"{name}=_USE_FACTORY")
            given = f"_make_{name}() if {name} is _USE_FACTORY else {name}"
        else:
            env[f"_default_{name}"] = value
            params.append(f"{name}=_default_{name}")
        lines.append(f"_set(self, {name!r}, {given})" if frozen else f"self.{name} = {given}")
    source = f"def __init__({', '.join(params)}):\n    " + "\n    ".join(lines or ["pass"])
    exec(source, env)                       # noqa: S102 - our own generated source
    init: Callable[..., None] = env["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__module__ = cls.__module__
    return init
