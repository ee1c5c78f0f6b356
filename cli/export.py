"""``ecatcfg export ENI --format pysoem|soem-c|igh-c|lcec -o FILE``: an ENI (any tool's) as code
for the master a user already runs (``eni/export/``); ``soem-c`` and ``igh-c`` write
``FILE`` (C) and the header beside it (``FILE`` with ``.h``).

The file is written atomically, and nothing is written when the ENI has errors or asks for
something the exported hooks cannot carry (the message names the file, line and slave;
exit 1).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ecatcfg.eni.plan import NetworkPlan

FORMATS = ("pysoem", "soem-c", "igh-c", "lcec")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("export", help="an ENI as set-up code for pysoem or SOEM (C)",
                       description="Write an ENI's configuration (ours or any tool's) in the "
                                   "form another master takes.  pysoem: a Python module "
                                   "whose setup(master), called after config_init(), checks "
                                   "each slave's identity and installs a config_func per "
                                   "slave that writes the ENI's PDO assignment, mapping and "
                                   "start-up SDOs and programs DC; the process image is "
                                   "listed by variable name.  soem-c: a C source and header "
                                   "with the same hooks for SOEM (PO2SOconfigx), the process "
                                   "data as packed structs with compile-time offset checks, "
                                   "and a minimal main (-DECATCFG_MAIN).  igh-c: a C source "
                                   "and header for the IgH master (ecrt.h): slave "
                                   "configurations with PDO tables, start-up SDOs, SoE IDNs, "
                                   "DC and watchdogs, the variables registered in a domain "
                                   "by name, and a minimal cyclic task (-DECATCFG_MAIN).  "
                                   "lcec: LinuxCNC's ethercat.xml (generic slaves with "
                                   "their PDO tree and HAL pins named after the variables, "
                                   "dcConf, watchdog, sdoConfig).")
    p.add_argument("eni", metavar="ENI", help="ENI file")
    p.add_argument("--format", required=True, choices=FORMATS, help="what to write")
    p.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="the file to write (atomically); soem-c, igh-c: the C source, its header "
                        "beside it with the suffix .h")
    p.add_argument("--no-cache", action="store_true", help="do not use the ENI plan cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import hashlib

    from ecatcfg import __version__
    from ecatcfg.cli.inputs import kind
    from ecatcfg.cli.paths import output_file
    from ecatcfg.eni.cache import PlanCache, read_file
    from ecatcfg.eni.export import pysoem_module, soem_c
    from ecatcfg.eni.export.steps import slave_setups
    from ecatcfg.eni.reader import read_file as read_uncached
    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import write_atomic

    found = kind(args.eni)
    if found != "eni":
        raise UsageError(f"{args.eni} is not an ENI ({found})")
    out = output_file(args.output)
    if out.resolve() == Path(args.eni).resolve():
        raise UsageError(f"-o {args.output}: would replace the ENI it exports")
    plan = read_uncached(args.eni) if args.no_cache else \
        read_file(args.eni, cache=PlanCache())
    digest = hashlib.sha256(Path(args.eni).read_bytes()).hexdigest()
    outputs: list[tuple[Path, bytes]]
    if args.format == "igh-c":
        return _write_igh_c(args, plan, out, digest)
    if args.format == "lcec":
        return _write_lcec(args, plan, out, digest)
    setups = slave_setups(plan, args.eni)
    if args.format == "pysoem":
        pysoem_module.check(setups, args.eni)
        outputs = [(out, pysoem_module.render(setups, Path(args.eni).name, digest,
                                              __version__))]
    else:
        header = out.with_suffix(".h")
        if header == out:
            raise UsageError(f"-o {args.output}: the C source needs another suffix than .h")
        source, text = soem_c.render(setups, header.name, Path(args.eni).name, digest,
                                     __version__)
        outputs = [(out, source), (header, text)]
    for path, data in outputs:
        try:
            write_atomic(path, data)
        except OSError as exc:
            raise UsageError(f"{path}: cannot write: {exc.strerror}") from None
    print(f"wrote {', '.join(str(p) for p, _ in outputs)}: {len(setups)} slaves, "
          f"{sum(len(s.sdos) for s in setups)} SDO downloads", file=sys.stderr)
    return 0


def _c_outputs(args: argparse.Namespace, out: Path) -> Path:
    from ecatcfg.errors import UsageError
    header = out.with_suffix(".h")
    if header == out:
        raise UsageError(f"-o {args.output}: the C source needs another suffix than .h")
    return header


def _write(outputs: list[tuple[Path, bytes]]) -> None:
    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import write_atomic
    for path, data in outputs:
        try:
            write_atomic(path, data)
        except OSError as exc:
            raise UsageError(f"{path}: cannot write: {exc.strerror}") from None


def _write_igh_c(args: argparse.Namespace, plan: NetworkPlan, out: Path, digest: str) -> int:
    from ecatcfg import __version__
    from ecatcfg.eni.export import igh_c
    from ecatcfg.eni.export.igh import igh_config
    config = igh_config(plan, args.eni)
    header = _c_outputs(args, out)
    source, text = igh_c.render(config, header.name, Path(args.eni).name, digest,
                                __version__)
    _write([(out, source), (header, text)])
    print(f"wrote {out}, {header}: {len(config.slaves)} slaves, "
          f"{sum(len(s.sdos) for s in config.slaves)} SDO downloads, "
          f"{len(config.registrations)} variables", file=sys.stderr)
    return 0


def _write_lcec(args: argparse.Namespace, plan: NetworkPlan, out: Path, digest: str) -> int:
    from ecatcfg import __version__
    from ecatcfg.eni.export import lcec
    from ecatcfg.eni.export.igh import igh_config
    config = igh_config(plan, args.eni)
    _write([(out, lcec.render(config, args.eni, Path(args.eni).name, digest, __version__))])
    print(f"wrote {out}: {len(config.slaves)} slaves, "
          f"{sum(len(s.sdos) for s in config.slaves)} SDO downloads", file=sys.stderr)
    return 0
