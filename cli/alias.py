"""``ecatcfg alias set``: a slave's configured station alias, programmed into its EEPROM.

    ecatcfg alias set --iface IF --slave POS N [--backup FILE.bin]

The alias lives in SII word 4 and the ESC copies it into register 0x0012 when it loads the
EEPROM at power-on (ESC Section II, 0x0012): the new alias is read back from the EEPROM at
once, and the slave answers to it after its next power cycle.
"""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_backup, add_line, number

    p = sub.add_parser("alias", help="set a slave's station alias in its EEPROM",
                       description="A slave's configured station alias (SII word 4).")
    actions = p.add_subparsers(dest="alias_action", metavar="ACTION", required=True)
    s = actions.add_parser(
        "set", help="write the alias into SII word 4",
        description="Write the configured station alias of the slave at a position into "
                    "its EEPROM: the current image is read and saved first (backup file "
                    "named in the output), word 4 and the configuration-area checksum "
                    "(word 7) are written and read back.  The ESC loads the alias into "
                    "register 0x0012 at power-on: it takes effect after a power cycle.",
        epilog="Exit 1 when the write stops or the read-back differs.")
    add_line(s)
    s.add_argument("alias", type=number(0xFFFF), metavar="N",
                   help="the alias, 0-65535 (decimal or 0x..); 0 = no alias")
    add_backup(s)
    s.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ecatcfg.cli.sii_program import program

    code = program(args.iface, args.slave, b"", backup=args.backup, force=False,
                   source="", alias=args.alias)
    if code == 0:
        print(f"alias {args.alias} is in the EEPROM; the slave loads it into register "
              "0x0012 at its next power-on (switch it off and on)")
    return code
