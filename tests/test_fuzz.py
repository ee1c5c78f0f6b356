"""The bounded fuzz campaign (docs/fuzzing.md): every target of ``tests/fuzzing.py``, seeded,
a fixed number of inputs each (about 25 s in all on the 2-core CI machine).

An input may be accepted or rejected with ecatcfg's own located error; a crash, a hang of
more than 5 s, an error that does not say where, or a broken invariant of the emulated ESC
fails the test, and hypothesis shrinks the input first (``Mutant(...)`` names the seed and
the edits).  ``bench/fuzz.py`` runs the same targets for much longer.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings

import fuzzing

SEED = 20261123


def campaign(target: fuzzing.Target, examples: int) -> None:
    # A fixed seed: the same inputs on every run (hypothesis's derandomize mode draws the
    # simplest values first, which finds far less in a few hundred inputs); no example
    # database (nothing is written into the checkout); no deadline: the harness's own 5 s
    # watchdog decides what a hang is, whatever the machine's load.
    @seed(SEED)
    @settings(max_examples=examples, database=None, deadline=None,
              suppress_health_check=list(HealthCheck), print_blob=False,
              phases=(Phase.explicit, Phase.generate, Phase.shrink))
    @given(target.strategy())
    def check(value):
        target.counts[fuzzing.run(target, value)] += 1

    check()


@pytest.mark.parametrize("name", list(fuzzing.TARGETS))
def test_fuzz(name: str) -> None:
    target = fuzzing.TARGETS[name]
    campaign(target, target.ci_examples)
    # The campaign is worth something only if inputs get through as well as fail.
    assert target.counts["accepted"] + target.counts["rejected"] >= target.ci_examples
    if name not in ("lint",):           # lint reports findings, it never rejects a file
        assert target.counts["accepted"] and (target.counts["rejected"]
                                              or name in ("segment", "frame_decoder"))
