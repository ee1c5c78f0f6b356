"""``ecatcfg export`` over every real ENI of both corpora: each gives a pysoem module that
is valid Python and C files, or an error that names the file (and the line and slave where
the ENI has them), never a traceback and never a silent omission."""

from __future__ import annotations

import ast

import pytest
from conftest import corpus_eni, corpus_enis, plan_or_refused

from ecatcfg.eni.export import pysoem_module, soem_c
from ecatcfg.eni.export.steps import ExportError, slave_setups


@pytest.mark.parametrize("eni", corpus_enis())
def test_every_corpus_eni_exports_or_is_refused_by_name(request, eni):
    path = corpus_eni(request, eni)
    plan = plan_or_refused(path)
    if plan is None:
        return
    try:
        setups = slave_setups(plan, path)
    except ExportError as exc:
        assert exc.file == str(path)
        assert exc.line is not None or "master" in exc.message or plan.unsupported
        return
    module = pysoem_module.render(setups, path.name, "0" * 64, "test").decode()
    ast.parse(module)
    source, header = soem_c.render(setups, "x.h", path.name, "0" * 64, "test")
    assert source.isascii() and header.isascii()
    # Every CoE download of the hook transitions is in the module, once each.
    wanted = sum(1 for s in plan.slaves if s.mailbox for c in s.mailbox.coe_init_cmds
                 if not c.disabled)
    assert module.count("slave.sdo_write(") == wanted
