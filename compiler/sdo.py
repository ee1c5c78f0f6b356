"""Moved to :mod:`ecatcfg.esi.datatypes` (:func:`~ecatcfg.esi.datatypes.encode`, used by the
compiler and by ``ecatcfg sdo`` alike); this module keeps ``ecatcfg.compiler.sdo`` importable
for existing code."""

from ecatcfg.esi.datatypes import ValueTypeError as SdoValueError  # noqa: F401 (re-export)
from ecatcfg.esi.datatypes import encode  # noqa: F401 (re-export)
