"""Moved to :mod:`ecatcfg.eni.plan` (the plan model and the ENI format sit between the compiler
and the runtime); this module keeps ``ecatcfg.compiler.plan`` importable for existing code.
New code imports from :mod:`ecatcfg.eni.plan`."""

from ecatcfg.eni.plan import *  # noqa: F401,F403  (re-export)
