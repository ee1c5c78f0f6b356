"""Timing helpers shared by the benchmark scripts (run as `python3 bench/NAME.py`)."""

from __future__ import annotations

import statistics
import time
from typing import Callable


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def interleaved(base: Callable[[], object], cand: Callable[[], object],
                repeat: int) -> tuple[list[float], list[float]]:
    """Run baseline and candidate alternately, so machine noise hits both alike."""
    b, c = [], []
    for _ in range(repeat):
        b.append(timed(base))
        c.append(timed(cand))
    return b, c


def ms(values: list[float]) -> str:
    """``min / median`` in milliseconds."""
    return f"{min(values) * 1e3:.0f} / {statistics.median(values) * 1e3:.0f}"


def ratio(b: list[float], c: list[float]) -> str:
    """Candidate over baseline, ``min / median``."""
    return f"{min(c) / min(b):.2f}x / {statistics.median(c) / statistics.median(b):.2f}x"
