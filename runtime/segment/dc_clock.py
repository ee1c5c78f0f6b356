"""The clock inside an emulated ESC: a drifting local time and its time control loop.

A real ESC counts its local time from its own quartz, which runs fast or slow by some ppm;
system time is local time + offset (0x0920).  When a write of the reference clock's system
time (ARMW/FRMW to 0x0910) passes a slave, its time control loop compares it with its own
copy (Beckhoff ESC Section I "Distributed Clocks", 9.1.5 Drift compensation):

    dt = (local time + offset - propagation delay) - received system time  (lower 32 bits)

shows the mean of dt in 0x092C (sign-magnitude, bit 31 set when the local copy is smaller,
Section II 0x092C) and corrects the speed of the local clock gradually, never by a jump, so
a master must send the reference's time many times before the clocks agree.

The register description gives the loop's inputs and meaning, not its internal arithmetic;
the emulated loop is a phase and frequency lock (the structure of the ESC's two filters,
0x0934 averaging the received differences, 0x0935 averaging the clock period deviation):

- **phase**: each sample schedules a correction of ``-dt x 64 / SpeedCounterStart``
  (0x0930: "larger values -> smaller bandwidth and smoother adjustment"; 1/64 of the
  difference at the reset value 0x1000), slewed at no more than ``MAX_CORRECTION``;
- **frequency** (0x0932 Speed Counter Diff): the rate at which dt moved between two samples,
  less the slew applied meanwhile, is the clock's remaining deviation from the reference;
  2^-(0x0935 - 4) of it (1/256 at the reset value 0x0C) goes into the learned speed
  correction, which is bounded by ``MAX_CORRECTION`` as the register's range
  ±(SpeedCounterStart - 0x7F) bounds it;
- 0x092C shows dt averaged over 2^(0x0934) samples (exponential mean; 16 at the reset
  value 4).

Per sample, not per second: as on hardware the number of drift frames decides convergence.
With ±100 ppm quartzes the loop settles to a few ns in about two thousand samples (EtherCrab
and KickCAT send 15 000 static drift frames; IgH waits up to 5 s for |0x092C| to drop).

The segment's timing (Section I 9.1.2, "t_P" and "t_F" of Table 26): a frame that enters
a slave's port 0 at ``a`` leaves its processing unit towards the first open downstream
port (processing order 3, 1, 2; ``runtime/wiring.py``) at ``a + t_P``, crosses a cable,
goes round the subtree behind that port and comes back across the cable to the same port,
where the slave latches its receive time; the forwarding path takes it on to the next open
port in ``t_F``, and after the last one out of port 0.  A slave with no open downstream
port turns the frame round in its processing unit (``a + t_P`` back out of port 0).  On a
line this is: slave k's port 0 after the processing delay of every slave before it plus
a cable each, and its port 1 after the round trip through the rest of the line.
"""

from __future__ import annotations

import random
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ecatcfg.runtime.wiring import CHILD_PORTS

if TYPE_CHECKING:
    from ecatcfg.runtime.wiring import Wiring

# Receive times of the four ports (ns after the frame was sent; None: no frame arrives).
PortTimes = tuple["int | None", "int | None", "int | None", "int | None"]

PROCESSING_DELAY_NS = 600      # port 0 -> processing unit -> port 1, on the way out
FORWARDING_DELAY_NS = 200      # port 1 -> port 0 alongside the processing unit, way back
CABLE_DELAY_NS = 10            # 2 m of cable at ~5 ns/m
# The largest speed correction: one ns per 0x7F+1 = 128 cycles of the 10 ns local clock
# (the Speed Counter Diff range stops 0x7F short of Speed Counter Start): ~781 ppm.
MAX_CORRECTION = 1 / 1280
SPEED_COUNTER_START = 0x1000   # 0x0930 reset value
TIME_FILTER_DEPTH = 4          # 0x0934 reset value
SPEED_FILTER_DEPTH = 12        # 0x0935 reset value


@dataclass(frozen=True, slots=True)
class DcModel:
    """The clocks and line timing of a virtual segment: each slave's quartz deviates by a
    seeded value uniform in ±``drift_ppm`` and its local clock started anywhere in the last
    ``start_spread_ns`` (slaves power on at different times)."""

    drift_ppm: float = 100.0
    seed: int = 0
    processing_ns: int = PROCESSING_DELAY_NS
    forwarding_ns: int = FORWARDING_DELAY_NS
    cable_ns: int = CABLE_DELAY_NS
    start_spread_ns: int = 60_000_000_000

    def __post_init__(self) -> None:
        if not 0 <= self.drift_ppm <= 10_000:
            raise ValueError(f"drift_ppm must be within 0..10000, not {self.drift_ppm}")
        if min(self.processing_ns, self.forwarding_ns, self.cable_ns,
               self.start_spread_ns) < 0:
            raise ValueError("DC model delays and start spread must not be negative")

    def clocks(self, n: int, now: int) -> list[DcClock]:
        """The clocks of ``n`` slaves at time ``now`` (ns), drift and start seeded in that
        order; their port times come from :meth:`port_times`."""
        rng = random.Random(self.seed)
        out = []
        for _ in range(n):
            drift = rng.uniform(-self.drift_ppm, self.drift_ppm) * 1e-6
            start = rng.randrange(self.start_spread_ns) if self.start_spread_ns else 0
            out.append(DcClock(drift, start, now))
        return out

    def powered_on(self, key: int, now: int) -> DcClock:
        """The clock of a device switched on at ``now`` (a device swapped into the segment):
        local time 0 then, its drift seeded from ``key`` (each new device its own)."""
        rng = random.Random(f"{self.seed}:{key}")
        return DcClock(rng.uniform(-self.drift_ppm, self.drift_ppm) * 1e-6, 0, now)

    def port_times(self, wiring: Wiring, cut: Iterable[int] = ()) -> list[PortTimes]:
        """Per slave of ``wiring`` (the cables into ``cut`` removed): when a frame sent at 0
        reaches each of its ports (port 0 on the way out, the others on the way back from
        the slaves behind them; see the module docstring).  All None for a slave the frame
        does not reach."""
        order = wiring.order(cut)
        p, f, c = self.processing_ns, self.forwarding_ns, self.cable_ns
        n = len(wiring.plugs)
        below = [0] * n                     # port 0 in -> port 0 out, the subtree's loop
        out_at: list[dict[int, int]] = [{} for _ in range(n)]   # child port -> leaves, from a
        back_at: list[dict[int, int]] = [{} for _ in range(n)]  # ... and comes back
        reached = set(order)
        for k in reversed(order):           # children before their parent
            t = p
            ports = wiring.children[k]
            for port in CHILD_PORTS:
                child = ports.get(port)
                if child is None or child not in reached:
                    continue
                out_at[k][port] = t
                back_at[k][port] = t + 2 * c + below[child]
                t = back_at[k][port] + f
            below[k] = t
        arrive = [0] * n
        times: list[PortTimes] = [(None, None, None, None)] * n
        for k in order:                     # parents before their children
            a = arrive[k]
            for port, child in wiring.children[k].items():
                if port in out_at[k]:
                    arrive[child] = a + out_at[k][port] + c
            rx = [a, None, None, None]
            for port, back in back_at[k].items():
                rx[port] = a + back
            times[k] = (rx[0], rx[1], rx[2], rx[3])
        return times


class DcClock:
    """One ESC's local clock (ns) as a function of the segment's time ``t`` (ns), and its
    time control loop."""

    __slots__ = ("drift", "port0_ns", "ports", "diff", "freq", "samples",
                 "_t", "_local", "_pending", "_applied", "_last_t", "_last_dt")

    def __init__(self, drift: float = 0.0, start_ns: int = 0, now: int = 0,
                 ports: PortTimes = (0, None, None, None)) -> None:
        self.drift = drift                 # quartz deviation (1e-6 = 1 ppm fast)
        self.ports = ports                 # a frame sent at t reaches port n at t + this
        self.port0_ns = ports[0] or 0      # ... port 0 and the processing unit
        self.diff = 0.0                    # 0x092C: mean system time difference (ns)
        self.freq = 0.0                    # learned speed correction (0x0932)
        self.samples = 0                   # received system times since the last reset
        self._t = now                      # anchor: segment time ...
        self._local = float(start_ns)      # ... and the local time then
        self._pending = 0.0                # phase correction still to slew (ns)
        self._applied = 0.0                # slewed since the last sample (ns)
        self._last_t: int | None = None
        self._last_dt = 0

    def set_ports(self, ports: PortTimes) -> None:
        """The slave's place in the segment changed (a cable removed or put back)."""
        self.ports = ports
        self.port0_ns = ports[0] or 0

    def local(self, t: int) -> int:
        """Local time at segment time ``t``."""
        elapsed = t - self._t
        value = self._local + elapsed * (1.0 + self.drift) * (1.0 + self.freq)
        if self._pending:
            value += self._slewed(elapsed)
        return int(round(value))

    def shift(self, ns: int) -> None:
        """Set the clock ``ns`` later, as if it had been started that much earlier (a
        replay starts an emulated clock where the real one was)."""
        self._local += ns

    def _slewed(self, elapsed: int) -> float:
        room = MAX_CORRECTION * max(elapsed, 0)
        p = self._pending
        return max(-room, min(room, p))

    def _anchor(self, t: int) -> None:
        """Carry the clock to ``t`` so rate and slew can change from there."""
        elapsed = t - self._t
        slewed = self._slewed(elapsed) if self._pending else 0.0
        self._local += elapsed * (1.0 + self.drift) * (1.0 + self.freq) + slewed
        self._pending -= slewed
        self._applied += slewed
        self._t = t

    def reset_loop(self, t: int) -> None:
        """A write of Speed Counter Start (0x0930) resets the filters (Section I 9.1.4)."""
        self._anchor(t)
        self.diff = self.freq = self._pending = self._applied = 0.0
        self.samples = 0
        self._last_t = None

    def sample(self, t: int, dt: int, speed_start: int, time_depth: int,
               speed_depth: int) -> None:
        """A received system time at segment time ``t``, ``dt`` ns off (see the module
        docstring); the filter depths and speed counter start as in 0x0930-0x0935."""
        self._anchor(t)
        self.samples += 1
        self.diff += (dt - self.diff) / (1 << min(time_depth, 15))
        if self._last_t is not None and t > self._last_t:
            rate = (dt - self._last_dt - self._applied) / (t - self._last_t)
            gain = 1.0 / (1 << max(0, min(speed_depth, 15) - 4))
            self.freq = max(-MAX_CORRECTION, min(MAX_CORRECTION, self.freq - gain * rate))
        self._last_t, self._last_dt = t, dt
        self._applied = 0.0
        self._pending = -dt * 64 / max(speed_start, 0x80)

    def speed_counter_diff(self, speed_start: int) -> int:
        """0x0932: the learned correction in the register's range ±(start - 0x7F)."""
        span = max(speed_start, 0x80) - 0x7F
        return int(round(self.freq / MAX_CORRECTION * span))
