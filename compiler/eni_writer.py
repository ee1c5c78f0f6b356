"""Moved to :mod:`ecatcfg.eni.writer` (the plan model and the ENI format sit between the compiler
and the runtime); this module keeps ``ecatcfg.compiler.eni_writer`` importable for existing code.
New code imports from :mod:`ecatcfg.eni.writer`."""

from ecatcfg.eni.writer import *  # noqa: F401,F403  (re-export)
