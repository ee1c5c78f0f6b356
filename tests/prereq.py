"""Skip or fail: a test whose prerequisite this machine lacks.

Locally a missing prerequisite skips the test and the reason names it; in CI it fails
instead, so that nothing CI can provide is silently skipped there.  CI is ``CI=true`` (set by
the usual CI services) or the variable of that kind of prerequisite set to 1 (``.ci/run``
sets all three):

- ``ECATCFG_REQUIRE_CORPUS``: the real vendor files of the corpus (``ECATCFG_CORPUS``, by
  default ``../shared/corpus`` beside the checkout) and of the extra corpus
  (``ECATCFG_CORPUS_EXTRA``, by default ``../shared/corpus-extra``);
- ``ECATCFG_REQUIRE_RUNTIME``: root with network namespaces, veth pairs and raw sockets,
  tshark, pysoem (``rig.py``);
- ``ECATCFG_REQUIRE_TOOLS``: a C compiler (the generated headers are compiled) and Debian's
  ``chromium`` (``ecatcfg report``'s page is opened in it, ``test_report.py``).

Python packages of the ``test`` extra are imported plainly: without them a test errors.
"""

from __future__ import annotations

import os
from typing import NoReturn

import pytest

CORPUS = "ECATCFG_REQUIRE_CORPUS"
RUNTIME = "ECATCFG_REQUIRE_RUNTIME"
TOOLS = "ECATCFG_REQUIRE_TOOLS"
KINDS = (CORPUS, RUNTIME, TOOLS)


def required(env: str) -> bool:
    """True in CI: a missing prerequisite of this kind fails the test."""
    return os.environ.get("CI") == "true" or os.environ.get(env) == "1"


def missing(what: str, reason: str, env: str) -> NoReturn:
    """Skip (locally) or fail (in CI) a test that needs ``what``, which is missing."""
    assert env in KINDS, env
    if required(env):
        pytest.fail(f"{what} is required in CI (CI=true or {env}=1) but unavailable: "
                    f"{reason}", pytrace=False)
    pytest.skip(f"{what} unavailable: {reason} (skipped; set {env}=1 to make this a "
                f"failure)")
