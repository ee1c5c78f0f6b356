"""``ecatcfg export``: an ENI (any tool's) as code for a master people already run.

:mod:`.steps` works out, from the :class:`~ecatcfg.eni.plan.NetworkPlan`, what each slave's
start-up must do that SOEM does not do itself, and refuses what no hook can carry;
:mod:`.soem_image` where SOEM's ``config_map`` puts each slave's data and each variable (its
own layout, not the ENI's addresses); :mod:`.pysoem_module` writes it as a Python module for
pysoem, :mod:`.soem_c` as C for SOEM.  The templates are in ``templates/``.
"""
