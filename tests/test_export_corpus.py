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


def test_a_master_register_write_no_target_can_make_is_refused_by_every_export(tmp_path):
    """A master InitCmd that writes a register outside what a master sets up itself (here
    BWR 0x0F00, digital outputs) has no place in SOEM's per-slave hooks nor in IgH's
    start-up: each export refuses it naming the master and the command."""
    from lxml import etree

    from conftest import compile_example
    from ecatcfg.eni.export.igh import igh_config
    from ecatcfg.eni.reader import read_file

    eni = compile_example(tmp_path / "line.xml")
    tree = etree.parse(str(eni))
    cmds = tree.find("Config/Master/InitCmds")
    extra = etree.SubElement(cmds, "InitCmd")
    for tag, text in (("Transition", "IP"), ("BeforeSlave", "0"), ("Comment", "outputs"),
                      ("Cmd", "8"), ("Adp", "0"), ("Ado", str(0x0F00)), ("Data", "01"),
                      ("Retries", "3")):
        etree.SubElement(extra, tag).text = text
    tree.write(str(eni))
    plan = read_file(eni)
    for make in (lambda: slave_setups(plan, eni), lambda: igh_config(plan, eni)):
        with pytest.raises(ExportError, match=r"the master: InitCmd .*0x0F00"):
            make()
