"""A slave's ESC watchdogs from the topology (``watchdog:`` of the slave, then of the
master), as the register values the standard set-up writes in INIT->PREOP
(:class:`ecatcfg.eni.standard.Watchdogs`).

The topology gives times in ms; the registers count in the time base the divider sets
(ESC Section II 0x0400: (divider + 2) x 40 ns, ``esc.watchdog_base_ns``).  A time that is
not a whole number of bases, or more bases than the 16-bit register (0x0410, 0x0420) holds,
is an error at its line: writing a rounded value would be a watchdog the user did not ask
for.  The ESI gives no watchdog times (ETG.2000 has only the obsolete ``Sm/@Watchdog``
flag; the SM watchdog runs for an SM whose control byte has bit 6 set), so keys left out
take the ESC's power-on values, which are also what TwinCAT and EC-Engineer write: divider
2498 and 100 ms (with another divider, still 100 ms: the times are what the user reads).
"""

from __future__ import annotations

from decimal import Decimal
from typing import Protocol

from ecatcfg.compiler.topology import Watchdog
from ecatcfg.eni.standard import Watchdogs
from ecatcfg.esc import WATCHDOG_DIVIDER_DEFAULT, WATCHDOG_TIME_DEFAULT, Reg, watchdog_base_ns

REGISTER_MAX = 0xFFFF
# The time a key left out stands for: the power-on 1000 x 100 us (what both tools write).
DEFAULT_MS = WATCHDOG_TIME_DEFAULT * watchdog_base_ns(WATCHDOG_DIVIDER_DEFAULT) // 1_000_000


class Errors(Protocol):
    def add(self, message: str, *path: str | int) -> None: ...


def resolve(name: str, own: Watchdog | None, master: Watchdog | None,
            where: tuple[str | int, ...], errors: Errors) -> Watchdogs | None:
    """The register values for a slave, or None when neither the slave nor the master sets
    watchdogs (or a time does not fit: an error is added).  ``where``: the slave's place in
    the topology; a key's value comes from the slave, else from the master, else the
    default: divider 2498 and 100 ms (the time, whatever the divider)."""
    if own is None and master is None:
        return None
    given = [(cfg, at) for cfg, at in ((own, (*where, "watchdog")),
                                       (master, ("master", "watchdog"))) if cfg is not None]
    divider, divider_at = next(((cfg.divider, (*at, "divider")) for cfg, at in given
                                if cfg.divider is not None),
                               (WATCHDOG_DIVIDER_DEFAULT, given[0][1]))
    base_ns = watchdog_base_ns(divider)
    values: dict[str, int] = {}
    for key, register in (("pdi_ms", Reg.WATCHDOG_PDI), ("sm_ms", Reg.WATCHDOG_SM)):
        ms, at, told = next(((ms, (*at, key), "") for cfg, at in given
                             if (ms := getattr(cfg, key)) is not None),
                            (DEFAULT_MS, divider_at, " (the default; give it)"))
        exact = Decimal(repr(float(ms)))
        ticks = _ticks(exact, base_ns)
        if ticks is None or ticks > REGISTER_MAX:
            errors.add(f"slave {name!r}: watchdog {key} {ms:g}{told}: "
                       + _why(exact, base_ns, register), *at)
            continue
        values[key] = ticks
    if len(values) < 2:
        return None
    return Watchdogs(divider, values["pdi_ms"], values["sm_ms"])


def _ticks(ms: Decimal, base_ns: int) -> int | None:
    """``ms`` in time bases, None if it is not a whole number of them."""
    ticks = ms * 1_000_000 / base_ns
    return int(ticks) if ticks == ticks.to_integral_value() else None


def _why(ms: Decimal, base_ns: int, register: int) -> str:
    base = _duration(base_ns)
    ticks = ms * 1_000_000 / base_ns
    if ticks != ticks.to_integral_value():
        low = int(ticks) * base_ns
        return (f"not a whole number of watchdog time bases of {base} (the nearest are "
                f"{_ms(low)} and {_ms(low + base_ns)} ms)")
    return (f"{int(ticks)} time bases of {base}; register 0x{register:04X} holds at most "
            f"{REGISTER_MAX} ({_ms(REGISTER_MAX * base_ns)} ms)")


def _duration(ns: int) -> str:
    return f"{ns // 1000} us" if ns % 1000 == 0 else f"{ns} ns"


def _ms(ns: int) -> str:
    return f"{Decimal(ns) / 1_000_000:f}".rstrip("0").rstrip(".") if ns else "0"
