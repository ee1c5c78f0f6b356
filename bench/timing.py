"""Timing helpers shared by the benchmark scripts (run as `python3 bench/NAME.py`)."""

from __future__ import annotations

import resource
import statistics
import time
from typing import Callable


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def cpu_timed(fn: Callable[[], object]) -> float:
    """CPU time (user + system) of this process and of the child processes ``fn`` waited
    for: on a machine shared with other jobs, what a run costs rather than how long it
    waited for a core."""
    def now() -> float:
        own = resource.getrusage(resource.RUSAGE_SELF)
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime
    start = now()
    fn()
    return now() - start


def interleaved(base: Callable[[], object], cand: Callable[[], object],
                repeat: int, clock: Callable[[Callable[[], object]], float] = timed
                ) -> tuple[list[float], list[float]]:
    """Run baseline and candidate alternately, so machine noise hits both alike
    (``clock``: :func:`timed`, wall time, or :func:`cpu_timed`)."""
    b, c = [], []
    for _ in range(repeat):
        b.append(clock(base))
        c.append(clock(cand))
    return b, c


def ms(values: list[float]) -> str:
    """``min / median`` in milliseconds."""
    return f"{min(values) * 1e3:.0f} / {statistics.median(values) * 1e3:.0f}"


def ratio(b: list[float], c: list[float]) -> str:
    """Candidate over baseline, ``min / median``."""
    return f"{min(c) / min(b):.2f}x / {statistics.median(c) / statistics.median(b):.2f}x"
