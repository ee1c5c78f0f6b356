"""Sweep cases of real files that fail today for a reason we know, each named with its reason
and the work that removes it.

The corpus sweeps glob every file of both corpora, so a new real file becomes a case the day
it arrives.  Where such a case fails for a reason that is understood but not yet fixed, it is
listed here instead of being skipped: the case still runs, and ``conftest.py`` requires it to
fail *with the failure written here* (a regular expression searched in the failure's text).
It then counts as an expected failure (``xfailed``, with the reason).  Any other failure of a
listed case fails the run, and so does a listed case that passes: the entry must then be
taken out, in the commit that makes it pass.  Nothing here hides a new kind of failure.

Keys are pytest node ids (``tests/FILE.py::TEST[PARAMS]``); the work that removes an entry is
named in words.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Known:
    failure: str       # regular expression searched in the failure's text
    reason: str        # why it fails today, in words
    until: str         # the work that removes the entry


# Empty: every corpus sweep case passes, or fails as a real slave would and is asserted so
# in its own test (tests/test_eni_only.py names those).  A new corpus file that fails for a
# known reason gets its entry here, with the work that removes it.
KNOWN: dict[str, Known] = {}
