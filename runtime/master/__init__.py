"""The master: brings a line of slaves up from an ENI and keeps it cycling.

``bringup.py`` is the :class:`~ecatcfg.runtime.master.bringup.Master` (scan and verify,
each transition's InitCmds, DC, cyclic frames); below it ``transport.py`` (frames out,
replies matched), ``lockstep.py`` (slaves' command chains sharing frames), ``replay.py``
(one InitCmd: register, CoE, EoE), ``scan.py``, ``cyclic.py``, ``reached.py`` (whether a
state is reached), ``modules.py`` (a station's plugged modules), ``hotconnect.py`` and
``recovery.py`` (slaves that drop out and come back), ``realtime.py`` (the cycling thread's
scheduling).  SoE and FoE: ``soe_client.py`` (SoE reads, writes and InitCmds),
``foe_client.py`` and ``foe_init.py`` (FoE transfers and InitCmds).  The tools:
``sdo_client.py`` / ``sdo_tool.py`` (``ecatcfg sdo``), ``soe_tool.py`` (``ecatcfg soe``),
``foe_tool.py`` (``ecatcfg foe``) and ``eeprom.py`` (SII read and write), ``diagnose.py``
(why a slave refuses a state: ``ecatcfg doctor`` and the cause lines of apply's errors).

This side drives the wire: it imports the shared codec (``runtime/wire.py``,
``mailbox.py``, ``soe.py``, ``foe.py``, ``link.py``, ``wiring.py``) and never :mod:`ecatcfg.runtime.segment`
(import-linter contract in ``pyproject.toml``, ``docs/architecture.md``).
"""
