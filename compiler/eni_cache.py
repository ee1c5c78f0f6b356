"""Moved to :mod:`ecatcfg.eni.cache` (the plan model and the ENI format sit between the compiler
and the runtime); this module keeps ``ecatcfg.compiler.eni_cache`` importable for existing code.
New code imports from :mod:`ecatcfg.eni.cache`."""

from ecatcfg.eni.cache import *  # noqa: F401,F403  (re-export)
