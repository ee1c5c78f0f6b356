"""The project's build backend: setuptools, with its working folders outside the checkout.

setuptools builds in the source tree: ``pip install .`` leaves ``build/`` (a full, stale copy
of the sources under ``build/lib`` that mypy, grep and readers then find) and
``ecatcfg.egg-info/`` beside the code, and ``pip install -e .`` leaves the egg-info.  This
backend is setuptools' own (``setuptools.build_meta``, every hook unchanged); before any hook
runs it points setuptools' ``egg_info`` and ``build`` commands at a temporary folder through
an extra configuration file (``DIST_EXTRA_CONFIG``, read by setuptools' distutils like a
``setup.cfg``), removed when the hook's process ends.  A ``DIST_EXTRA_CONFIG`` the user set
is left alone.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

from setuptools.build_meta import *  # noqa: F403  (the hooks, unchanged)


def _work_outside_the_checkout() -> None:
    if os.environ.get("DIST_EXTRA_CONFIG"):
        return
    work = tempfile.mkdtemp(prefix="ecatcfg-build-")
    atexit.register(shutil.rmtree, work, True)
    config = os.path.join(work, "setup.cfg")
    with open(config, "w", encoding="utf-8") as f:
        f.write(f"[egg_info]\negg_base = {work}\n\n[build]\nbuild_base = "
                f"{os.path.join(work, 'build')}\n")
    os.environ["DIST_EXTRA_CONFIG"] = config


_work_outside_the_checkout()
