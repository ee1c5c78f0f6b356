"""How the tests run ecatcfg's command line: one definition.

By default a test runs the checkout's ``ecatcfg`` through the interpreter that runs pytest.
``tests/test_wheel.py`` also runs the end-to-end command-line tests against the package a
user installs: it builds the wheel, installs it into a fresh venv and sets
``ECATCFG_TEST_PYTHON`` to that venv's interpreter.  Then every command those tests run goes
through that interpreter in isolated mode (``-I``: no PYTHONPATH, no current folder on the
path), so a module missing from the wheel fails there as it would for the user (``check``,
``report`` and ``export`` once did, and the editable checkout hid it).
"""

from __future__ import annotations

import os
import sys

#: The venv interpreter of an installed ecatcfg, when the tests run against one.
INSTALLED_PYTHON = os.environ.get("ECATCFG_TEST_PYTHON") or None
#: ``python`` as the examples in the docs run it.
PYTHON = [INSTALLED_PYTHON, "-I"] if INSTALLED_PYTHON else [sys.executable]
#: ``ecatcfg`` as a user types it.
ECATCFG = [*PYTHON, "-m", "ecatcfg"]
