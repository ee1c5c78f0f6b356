"""``ecatcfg export``: an ENI (any tool's) as code for a master people already run.

:mod:`.steps` works out, from the :class:`~ecatcfg.eni.plan.NetworkPlan`, what each slave's
hook must do that SOEM does not do itself, and refuses what no hook can carry;
:mod:`.pysoem_module` writes it as a Python module for pysoem.  The templates are in
``templates/``.
"""
