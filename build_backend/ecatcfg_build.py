"""The project's build backend: setuptools, with its working folders outside the checkout.

setuptools builds in the source tree: ``pip install .`` leaves ``build/`` (a full, stale copy
of the sources under ``build/lib`` that mypy, grep and readers then find) and
``ecatcfg.egg-info/`` beside the code, and ``pip install -e .`` leaves the egg-info.  This
backend is setuptools' own (``setuptools.build_meta``, every hook unchanged); before any hook
runs it points setuptools' ``egg_info`` and ``build`` commands at a temporary folder through
an extra configuration file (``DIST_EXTRA_CONFIG``, read by setuptools' distutils like a
``setup.cfg``), removed when the hook's process ends.  A ``DIST_EXTRA_CONFIG`` the user set
is left alone.

It also declares the one C extension, ``ecatcfg.runtime._exchange`` (runtime/_exchange.c,
the compiled exchange of a cyclic frame), as *optional*: where no C compiler (or no
Python.h) is found, setuptools warns and builds the same package without it, and the
runtime cycles in pure Python (docs/architecture.md, "The compiled cyclic exchange").  The
checkout has no setup.py (it would be a module of the package, which the checkout is):
the backend's ``run_setup`` calls ``setup()`` with the extension instead of running one.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

from setuptools import Extension, build_meta

EXTENSION = Extension("ecatcfg.runtime._exchange", ["runtime/_exchange.c"], optional=True)


class _Backend(build_meta._BuildMetaBackend):
    """setuptools' backend, whose ``setup()`` also gets the optional extension."""

    def run_setup(self, setup_script: str = "setup.py") -> None:
        if os.path.exists(setup_script):        # (never in this checkout)
            super().run_setup(setup_script)
            return
        import setuptools
        setuptools.setup(ext_modules=[EXTENSION])


_BACKEND = _Backend()
get_requires_for_build_sdist = _BACKEND.get_requires_for_build_sdist
get_requires_for_build_wheel = _BACKEND.get_requires_for_build_wheel
prepare_metadata_for_build_wheel = _BACKEND.prepare_metadata_for_build_wheel
build_wheel = _BACKEND.build_wheel
build_sdist = _BACKEND.build_sdist
get_requires_for_build_editable = _BACKEND.get_requires_for_build_editable
prepare_metadata_for_build_editable = _BACKEND.prepare_metadata_for_build_editable
build_editable = _BACKEND.build_editable


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
