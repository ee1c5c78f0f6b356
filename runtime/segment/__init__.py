"""The virtual segment: emulated slaves on a link, the side of the wire a real line is.

``virtual.py`` is the line (:class:`~ecatcfg.runtime.segment.virtual.VirtualSegment`: bus
order, logical addressing, faults, cables); ``slave.py`` an emulated ESC with its AL state
machine, ``syncman.py`` its SyncManagers, ``esc_chips.py`` which ESC a device has,
``dc_clock.py`` its clock and the line's delays, ``timing.py`` how long its firmware takes.
The mailbox (``mailbox_server.py``) hands messages to ``sdo_server.py`` over the object
dictionary (``objects.py``), to ``eoe_server.py``, ``soe_server.py`` (SoE drives) and
``foe_server.py`` (files, firmware, BOOT).  ``emulate.py`` builds slaves from ESI
devices, or from an ENI alone (``eni_device.py``).

This side follows the hardware, not our master: it imports the shared codec
(``runtime/wire.py``, ``mailbox.py``, ``soe.py``, ``foe.py``, ``link.py``, ``wiring.py``) and never
:mod:`ecatcfg.runtime.master.bringup` (import-linter contract in ``pyproject.toml``,
``docs/architecture.md``).
"""
