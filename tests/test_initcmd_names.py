"""A failing InitCmd is named in apply's error and report whether or not the ENI gives it a
``Comment`` (optional in ETG.2100's ``ECatCmdType``): by its comment, else by its command
and register, with no empty brackets or stray spaces."""

from __future__ import annotations

import json
import re

import pytest

from conftest import EXAMPLES
from ecatcfg.cli import main
from ecatcfg.eni.plan import InitCmd
from ecatcfg.esc import Cmd, Transition
from ecatcfg.eni.words import init_cmd_name
from ecatcfg.runtime.master.replay import ApplyError

ESI = EXAMPLES / "esi"


def _failing_eni(tmp_path, capsys, comment: str | None) -> str:
    """The example line's ENI whose first slave's INIT->PREOP state check expects a state
    the slave never reports (0x0F under the mask), with a short timeout."""
    eni = tmp_path / "line.xml"
    assert main(["compile", str(EXAMPLES / "topology.yaml"), "--esi", str(ESI),
                 "-o", str(eni)]) == 0
    capsys.readouterr()
    text = eni.read_text()
    first = text.index("<Slave>")
    check = re.compile(r"<InitCmd>\s*<Transition>IP</Transition>\s*"
                       r"(<Comment>[^<]*</Comment>\s*)(?:(?!</InitCmd>).)*?<Ado>304</Ado>"
                       r"(?:(?!</InitCmd>).)*?<Validate>\s*<Data>0100</Data>", re.S)
    found = check.search(text, first)
    assert found, "the example's INIT->PREOP state check"
    old = found.group(0)
    new = old.replace(found.group(1), "" if comment is None else
                      f"<Comment>{comment}</Comment>").replace(
        "<Validate>\n            <Data>0100</Data>", "<Validate>\n            <Data>0f00</Data>")
    new_text = text[:found.start()] + new + text[found.end():]
    new_text = re.sub(r"(<Data>0f00</Data>\s*<DataMask>0f00</DataMask>\s*<Timeout>)\d+",
                      r"\g<1>300", new_text)
    eni.write_text(new_text)
    assert main(["apply", str(eni), "--virtual", "--esi", str(ESI), "--format", "json"]) == 1
    out = capsys.readouterr().out
    report = json.loads(out)
    return str(report["error"])


def test_an_initcmd_without_comment_is_named_by_command_and_register(tmp_path, capsys):
    error = _failing_eni(tmp_path, capsys, None)
    assert "slave 'coupler' [APRD 0x0130]: read " in error, error
    assert "  " not in error and "[]" not in error and " :" not in error


def test_an_initcmd_with_a_comment_is_named_by_it(tmp_path, capsys):
    error = _failing_eni(tmp_path, capsys, "check PREOP")
    assert "slave 'coupler' [check PREOP]: read " in error, error


@pytest.mark.parametrize("cmd, expected", [
    (InitCmd([Transition.IP], "", Cmd.FPWR, 2, adp=1001, ado=0x0120), "FPWR 0x0120"),
    (InitCmd([Transition.IP], "  ", Cmd.BWR, 1, adp=0, ado=0x0101), "BWR 0x0101"),
    (InitCmd([Transition.SO], "", Cmd.LWR, 4, addr=0x00010000), "LWR logical 0x00010000"),
    (InitCmd([Transition.IP], "", 99, 1), "command 99"),
    (InitCmd([Transition.IP], "set alias", Cmd.FPWR, 2, adp=1, ado=0x12), "set alias"),
])
def test_init_cmd_name(cmd, expected):
    assert init_cmd_name(cmd) == expected


def test_apply_error_without_slave_or_command_has_no_stray_space():
    assert str(ApplyError("lost", "s", "")) == "slave 's': lost"
    assert str(ApplyError("lost", None, "x")) == "[x]: lost"
    assert str(ApplyError("lost")) == "lost"
