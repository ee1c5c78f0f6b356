"""A virtual segment's clocks are reproducible: the same DC model seed gives every slave the
same quartz drift and start time, another seed other ones (runtime/segment/dc_clock.py
``DcModel``; what lets a DC test that failed be run again as it was)."""

from __future__ import annotations

from ecatcfg.runtime.segment.dc_clock import DcModel

NOW = 5_000_000_000


def _line(seed: int) -> list[tuple[float, int]]:
    return [(c.drift, c.port0_ns) for c in DcModel(seed=seed).clocks(4, NOW)]


def test_the_same_seed_gives_the_same_clocks():
    first = _line(7)
    assert first == _line(7)
    assert len({drift for drift, _ in first}) == 4          # each slave its own quartz
    assert all(abs(drift) <= 100e-6 for drift, _ in first)  # within the model's ±100 ppm


def test_another_seed_gives_other_clocks():
    assert _line(7) != _line(8)
