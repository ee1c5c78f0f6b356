"""The bounded fuzz campaign (docs/fuzzing.md): every target of ``tests/fuzzing.py``, seeded,
a fixed number of inputs each (about 25 s in all on the 2-core CI machine).

An input may be accepted or rejected with ecatcfg's own located error; a crash, a hang (more
than 5 s of CPU or 30 s of wall time), an error that does not say where, or a broken
invariant of the emulated ESC fails the test, and hypothesis shrinks the input first
(``Mutant(...)`` names the seed and the edits).  ``bench/fuzz.py`` runs the same targets for
much longer, and one mutation kind at a time (``test_mutation_kind`` checks the kinds).
"""

from __future__ import annotations

import re

import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings

import fuzzing

SEED = 20261123


def campaign(target: fuzzing.Target, examples: int,
             kinds: frozenset[str] | None = None) -> list:
    # A fixed seed: the same inputs on every run (hypothesis's derandomize mode draws the
    # simplest values first, which finds far less in a few hundred inputs); no example
    # database (nothing is written into the checkout); no deadline: the harness's own
    # watchdog (CPU time) decides what a hang is, whatever the machine's load.
    @seed(SEED)
    @settings(max_examples=examples, database=None, deadline=None,
              suppress_health_check=list(HealthCheck), print_blob=False,
              phases=(Phase.explicit, Phase.generate, Phase.shrink))
    @given(target.strategy(kinds))
    def check(value):
        target.counts[fuzzing.run(target, value)] += 1
        seen.append(value)

    seen: list = []
    check()
    return seen


@pytest.mark.parametrize("name", list(fuzzing.TARGETS))
def test_fuzz(name: str) -> None:
    target = fuzzing.TARGETS[name]
    campaign(target, target.ci_examples)
    # The campaign is worth something only if inputs get through as well as fail.
    assert target.counts["accepted"] + target.counts["rejected"] >= target.ci_examples
    if name not in ("lint",):           # lint reports findings, it never rejects a file
        assert target.counts["accepted"] and (target.counts["rejected"]
                                              or name in ("segment", "frame_decoder"))


# -- mutation kinds (bench/fuzz.py --mutations) ----------------------------------------------

def _digits(text: str) -> int:
    """Decimal digits of the number ``text`` (``#x``/``0x`` hex or decimal), counted without
    converting it (Python cannot ``str()`` one past 4300 digits)."""
    body = text.strip().lstrip("+-")
    if body[:2] in ("#x", "0x"):
        return int(len(body[2:].lstrip("0")) * 1.2041) + 1        # log10(16) digits per hex
    return len(body.lstrip("0"))


def _value(text: str) -> int:
    body = text.strip()
    sign = -1 if body.startswith("-") else 1
    body = body.lstrip("+-")
    return sign * (int(body[2:], 16) if body[:2] in ("#x", "0x") else int(body))


# What each kind promises of the numbers it puts in (the bench's per-class campaigns rely on
# it: a kind that drifted into another would report the other's class).
NUMBER_CHECKS = {
    "huge-numbers": lambda t: _digits(t) > 4300,
    "negative-sizes": lambda t: _value(t) < 0,
    "huge-counts": lambda t: _value(t) > 0xFFFF,
    "boundaries": lambda t: 0 <= _value(t) <= 0xFFFF,
}


@pytest.mark.parametrize("kind", fuzzing.MUTATION_KINDS)
def test_mutation_kind(kind: str) -> None:
    """A campaign of one mutation kind (``eni_reader``, which takes every kind: the ENI read,
    written and read back) makes only edits of that kind, and they reach the file."""
    target = fuzzing.TARGETS["eni_reader"]
    target.counts.clear()
    inputs = campaign(target, 30, frozenset([kind]))
    assert len(inputs) >= 30
    if kind in NUMBER_CHECKS:           # InitCmd data and repeats are mostly read as given
        assert target.counts["rejected"]
    if kind != "huge-numbers":          # none of those fits any field
        assert target.counts["accepted"]
    # An edit may put in what was there (a field set to its value): rarely.
    assert sum(m.data() != fuzzing.eni_seeds()[m.seed] for m in inputs) >= 0.9 * len(inputs)
    for m in inputs:
        seed = fuzzing.eni_seeds()[m.seed]
        data = m.data()
        assert m.edits
        last = {edit[1:3]: edit[3] for edit in m.edits if edit[0] == "value"}
        for edit in m.edits:
            if kind in NUMBER_CHECKS:
                assert edit[0] == "value" and NUMBER_CHECKS[kind](edit[3]), (kind, edit)
                assert last[edit[1:3]].encode() in data        # a later edit of that place wins
            elif kind == "repeated-elements":
                assert edit[0] == "repeat"
                tag = re.compile(rb"<" + re.escape(edit[1].encode()) + rb"[\s/>]")
                assert len(tag.findall(data)) > len(tag.findall(seed))
            else:
                assert edit[0] == "register"
        if kind == "registers":
            # Only InitCmd data changed: same text outside the hex of <Data> elements.
            def strip(b: bytes) -> bytes:
                return re.sub(rb"<Data>[0-9a-f]*</Data>", b"<Data/>", b)
            assert strip(data) == strip(seed)


def test_register_edit_sets_the_field_in_the_initcmd_data() -> None:
    """A ``register`` edit: the drive's FMMU 0 (outputs) mapped onto AL status 0x0130, the
    rest of the 16-byte image as the compiler wrote it (ETG.1000.4 FMMU layout: physical
    start at bytes 8-9, little-endian)."""
    seed = fuzzing.eni_seeds()[1]
    fmmu = [i for i, kind, _ in fuzzing.register_places(seed) if kind == "fmmu"]
    spans = dict(fuzzing.xml_spans(seed).groups)["InitCmd/Data"]
    for i in fmmu:
        a, b = spans[i]
        before = bytes.fromhex(seed[a:b].decode())
        data = fuzzing.Mutant("eni", 1, (("register", i, 0, "physical_start", 0x0130),)).data()
        after = bytes.fromhex(data[a:b].decode())
        assert after[8:10] == b"\x30\x01"
        assert after[:8] + after[10:] == before[:8] + before[10:]
    assert len(fmmu) >= 4
