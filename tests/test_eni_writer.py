"""The ENI writer spells its text as lxml's pretty printer spells the same tree.

The writer emits the document as text in document order (``eni/writer.py``: building an
lxml tree of a 512-slave line took longer than compiling it).  The reference here is lxml
itself: our output parsed back (``remove_blank_text``) and pretty-printed by lxml must give
our bytes, for a hand-built plan that uses every element and for every real ENI of both
corpora written back; and every character, in an element's text and in an attribute, is
escaped or refused as lxml escapes or refuses it.
"""

from __future__ import annotations

import re
import sys

import pytest
from lxml import etree

from conftest import corpus_eni, corpus_enis, plan_or_refused
from test_eni_io import rich_plan

from ecatcfg.eni.plan import MasterPlan, NetworkPlan
from ecatcfg.eni.writer import to_bytes

_DECLARATION = b'<?xml version="1.0" encoding="UTF-8"?>\n'
_EMPTY_TEXT = re.compile(rb"<([A-Za-z0-9]+)></\1>")


def lxml_spelling(data: bytes) -> bytes:
    """``data`` as lxml pretty-prints the tree it parses to."""
    assert data.startswith(_DECLARATION)
    root = etree.fromstring(data, etree.XMLParser(remove_blank_text=True))
    return _DECLARATION + etree.tostring(root.getroottree(), encoding="UTF-8",
                                         xml_declaration=False, pretty_print=True)


def same_as_lxml(data: bytes) -> None:
    # An element whose text is "" (the writer's ``<Comment></Comment>``, an optional text
    # that is there but empty) parses back without text, which lxml writes ``<Comment/>``;
    # test_an_empty_text_is_spelled_as_lxml_spells_it holds that spelling on its own.
    assert _EMPTY_TEXT.sub(rb"<\1/>", data) == lxml_spelling(data)


def test_a_plan_with_every_element_is_spelled_as_lxml_spells_it():
    for generator in (None, "ecatcfg 1.0", "x -- y --->"):
        data = to_bytes(rich_plan(), generator)
        same_as_lxml(data)
    assert b"<Comment></Comment>" in to_bytes(rich_plan())      # the plan has one


def test_an_empty_text_is_spelled_as_lxml_spells_it():
    el = etree.Element("Comment")
    el.text = ""
    plan = rich_plan()
    plan.cyclic[0].frames[0].comment = ""
    assert b"\n        " + etree.tostring(el, encoding="UTF-8") + b"\n" in to_bytes(plan)
    # and an element with neither text nor children (a master without InitCmds)
    childless = etree.tostring(etree.Element("InitCmds"), encoding="UTF-8")
    assert b"\n      " + childless + b"\n" in to_bytes(NetworkPlan(master=MasterPlan("m")))


@pytest.mark.parametrize("eni", corpus_enis())
def test_every_real_eni_written_back_is_spelled_as_lxml_spells_it(request, eni):
    plan = plan_or_refused(corpus_eni(request, eni))
    if plan is not None:
        same_as_lxml(to_bytes(plan, "ecatcfg"))


def _chunks() -> list[str]:
    """Every code point of the BMP but the surrogates, and every 97th beyond, in 512s."""
    points = [c for c in range(0x10000) if not 0xD800 <= c <= 0xDFFF]
    points += list(range(0x10000, sys.maxunicode + 1, 97)) + [sys.maxunicode]
    return ["".join(map(chr, points[i:i + 512])) for i in range(0, len(points), 512)]


def _lxml_text(text: str) -> bytes | None:
    el = etree.Element("Name")
    try:
        el.text = text
    except ValueError:
        return None
    return etree.tostring(el, encoding="UTF-8")


def _lxml_attribute(value: str) -> bytes | None:
    el = etree.Element("EtherCATConfig")
    try:
        el.set("Version", value)
    except ValueError:
        return None
    return etree.tostring(el, encoding="UTF-8")[len(b"<EtherCATConfig "):-len(b"/>")]


def test_every_character_is_escaped_or_refused_as_lxml_does():
    checked = refused = 0
    for chunk in _chunks():
        for text in ([chunk] if _lxml_text(chunk) is not None else list(chunk)):
            plan = NetworkPlan(master=MasterPlan(name=text), version=text)
            expected_text, expected_attr = _lxml_text(text), _lxml_attribute(text)
            if expected_text is None:
                assert expected_attr is None
                with pytest.raises(ValueError, match="XML compatible"):
                    to_bytes(plan)
                refused += 1
                continue
            data = to_bytes(plan)
            assert b"\n        " + expected_text + b"\n" in data, repr(text)
            assert b" " + expected_attr + b" " in data, repr(text)
            checked += len(text)
    assert refused == 32 - 3 + 2        # C0 controls but tab, newline, CR; U+FFFE, U+FFFF
    assert checked > 60000


def test_a_generator_comment_with_a_control_character_is_refused():
    with pytest.raises(ValueError, match="XML compatible"):
        to_bytes(rich_plan(), "ecatcfg\x01")
