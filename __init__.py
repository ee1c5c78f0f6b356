"""ecatcfg: EtherCAT configuration compiler and network configurator.

The central models are the :class:`~ecatcfg.esi.model.Device` (read from vendor ESI files,
ETG.2000) and, in later work, the NetworkPlan produced by the compiler.  Keep this module
light: ``import ecatcfg`` and ``ecatcfg --help`` must not pull in lxml, scapy or the runtime.
"""

__version__ = "0.1.0"
