"""The refusal of an ENI names how many things apply does not do, in the singular for one,
and a mailbox protocol nobody knows as such, at its line (eni/contents.py ``refuse``, in
the test's own process: the CLI tests of tests/test_unsupported.py see the same text from
a child process)."""

from __future__ import annotations

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import contents
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.contents import UnsupportedEniError
from ecatcfg.esi.library import Library

MAILBOX = "//Slave[Info/Name='axis1']/Mailbox"
# A protocol no ETG.2100 version has: two InitCmds of it.
XOE = ("<XoE><InitCmds>" + "<InitCmd><Transition>PS</Transition><Timeout>1000</Timeout>"
       "<Data>0100</Data></InitCmd>" * 2 + "</InitCmds></XoE>")


@pytest.fixture(scope="module")
def example_eni() -> bytes:
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([EXAMPLES / "esi"], cache=False)).plan
    return eni_writer.to_bytes(plan)


def _refusal(eni: bytes, *fragments: str) -> tuple[str, int]:
    """The refusal of ``eni`` with ``fragments`` in the drive's mailbox; the line of the
    first fragment."""
    root = etree.fromstring(eni)
    for fragment in fragments:
        root.xpath(MAILBOX)[0].append(etree.fromstring(fragment))
    data = etree.tostring(root)
    line = etree.fromstring(data).xpath(MAILBOX)[0][-len(fragments)].sourceline
    plan = eni_reader.read_bytes(data, "line.xml")
    with pytest.raises(UnsupportedEniError) as exc:
        contents.refuse(plan, "line.xml")
    return str(exc.value), line


def test_one_thing_is_said_in_the_singular(example_eni):
    message, line = _refusal(example_eni, XOE)
    assert message.startswith("line.xml: the ENI asks for 1 thing apply does not do; nothing "
                              "was written to the bus:\n")
    assert (f"line.xml:{line}: slave 'axis1': XoE InitCmds (a mailbox protocol ecatcfg does "
            "not know)") in message


def test_two_things_in_the_plural(example_eni):
    message, _ = _refusal(example_eni, XOE, XOE.replace("XoE", "YoE"))
    assert message.startswith("line.xml: the ENI asks for 2 things apply does not do")
    assert "YoE InitCmds (a mailbox protocol ecatcfg does not know)" in message
