"""Moved to :mod:`ecatcfg.eni.reader` (the plan model and the ENI format sit between the compiler
and the runtime); this module keeps ``ecatcfg.compiler.eni_reader`` importable for existing code.
New code imports from :mod:`ecatcfg.eni.reader`."""

from ecatcfg.eni.reader import *  # noqa: F401,F403  (re-export)
