"""Topology model, NetworkPlan and the ENI writer/reader (ETG.2100).

Empty until the compile issue lands; the package exists so the layout of the design card
(``ecatcfg.compiler``) is in place and importable from an installed wheel.
"""
