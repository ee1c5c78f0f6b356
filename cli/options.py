"""Options several commands share, defined once: the line and slave of the online commands
(``--iface``, ``--slave``), numbers within a range, the EEPROM backup of the commands that
write an SII, and the rule options of ``lint`` and ``check`` (``--select``, ``--ignore``,
``--explain``, ``--list-rules``).  A command module imports these, never another command's
own helpers."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from typing import Any

MAX_POSITION = 0xFFFF          # an auto-increment position is a 16-bit address (ETG.1000.4)


def number(maximum: int) -> Callable[[str], int]:
    """An argparse type: a number from 0 to ``maximum``, decimal or ``0x``; anything else is
    a usage error (exit 2) naming the text."""
    def parse(text: str) -> int:
        try:
            value = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r} (decimal or 0x..)") \
                from None
        if not 0 <= value <= maximum:
            raise argparse.ArgumentTypeError(f"{text} is not between 0 and 0x{maximum:X} "
                                             "(positions count from 0)" if maximum ==
                                             MAX_POSITION else
                                             f"{text} is not between 0 and 0x{maximum:X}")
        return value
    return parse


def add_iface(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("--iface", required=required, metavar="IF",
                   help="network interface of the EtherCAT line")


def add_slave(p: argparse.ArgumentParser, required: bool = True) -> None:
    """``--slave POS``: the slave's position on the line; optional ones mean all slaves."""
    p.add_argument("--slave", required=required, type=number(MAX_POSITION), metavar="POS",
                   help="position of the slave on the line (0 = first)" if required else
                   "only the slave at this position (0 = first); default all")


def add_line(p: argparse.ArgumentParser) -> None:
    """``--iface IF --slave POS``: the one slave an online command talks to."""
    add_iface(p)
    add_slave(p)


def add_backup(p: argparse.ArgumentParser) -> None:
    """``--backup FILE.bin`` of the commands that write a slave's EEPROM."""
    p.add_argument("--backup", metavar="FILE.bin",
                   help="where to save the current image before writing (default "
                        "sii-backup-posPOS-DATE-TIME.bin in the current folder)")


def add_prefer(p: argparse.ArgumentParser) -> None:
    """``--prefer PATH``: which of several ESI files that describe one identity differently
    wins (the choice by evidence comes first where a command has an ENI or a live line)."""
    p.add_argument("--prefer", action="append", default=[], metavar="PATH",
                   help="an ESI file or folder of --esi whose description wins where files "
                        "describe one device (vendor, product, revision) differently; "
                        "repeatable, first wins (default: the one the ENI or the slave's "
                        "SII agrees with, where there is one; else an error naming the files)")


def seconds(text: str) -> float:
    """An argparse type: a positive number of seconds."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text}: must be positive")
    return value


def add_timeout(p: argparse.ArgumentParser, default: float,
                waits_for: str = "each answer of the slave") -> None:
    """``--timeout S`` of a command that waits for a slave."""
    p.add_argument("--timeout", type=seconds, default=default, metavar="S",
                   help=f"seconds to wait for {waits_for} (default {default:g})")


def add_rule_options(p: argparse.ArgumentParser) -> None:
    """The rule options of ``lint`` and ``check``."""
    p.add_argument("--select", action="append", metavar="IDS",
                   help="only these rules (comma-separated ids or prefixes; repeatable)")
    p.add_argument("--ignore", action="append", metavar="IDS",
                   help="skip these rules (comma-separated ids or prefixes; repeatable)")
    p.add_argument("--explain", metavar="ID", help="explain one rule and exit")
    p.add_argument("--list-rules", action="store_true", help="list every rule and exit")


def rule_help(args: argparse.Namespace, rules: Mapping[str, Any], command: str) -> bool:
    """``--explain ID`` or ``--list-rules`` printed (True: the command is done), else False.
    ``rules``: id -> a rule with ``id``, ``severity``, ``summary`` and ``explanation``."""
    import textwrap

    from ecatcfg.errors import UsageError

    if args.explain:
        rule = rules.get(args.explain.strip().upper())
        if rule is None:
            raise UsageError(f"unknown rule {args.explain!r}; `ecatcfg {command} "
                             "--list-rules` lists them")
        print(f"{rule.id} ({rule.severity}): {rule.summary}\n")
        print(textwrap.fill(" ".join(rule.explanation.split()), width=88))
        return True
    if args.list_rules:
        for rule in sorted(rules.values(), key=lambda r: r.id):
            print(f"{rule.id}  {rule.severity:<7}  {rule.summary}")
        return True
    return False


__all__ = ["MAX_POSITION", "add_backup", "add_iface", "add_line", "add_prefer",
           "add_rule_options", "add_slave", "add_timeout", "number", "rule_help", "seconds"]
