"""``ecatcfg export ENI --format pysoem|soem-c|igh-c|lcec|ros2 -o FILE``: an ENI (any
tool's) as code for the master a user already runs (``eni/export/``); ``soem-c`` and
``igh-c`` write ``FILE`` (C) and the header beside it (``FILE`` with ``.h``); ``ros2``
writes ``FILE`` (the ros2_control fragment) and a generic-slave YAML per slave beside it;
``lcec`` ``FILE`` and an initCmds file per slave with SoE writes.

The file is written atomically, and nothing is written when the ENI has errors or asks for
something the exported hooks cannot carry (the message names the file, line and slave;
exit 1).
"""

from __future__ import annotations

import argparse
import sys

FORMATS = ("pysoem", "soem-c", "igh-c", "lcec", "ros2")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("export", help="an ENI as set-up code for pysoem or SOEM (C)",
                       description="Write an ENI's configuration (ours or any tool's) in the "
                                   "form another master takes.  pysoem: a Python module "
                                   "whose setup(master), called after config_init(), checks "
                                   "each slave's identity and installs a config_func per "
                                   "slave that writes the ENI's PDO assignment, mapping and "
                                   "start-up SDOs and programs DC; the process image is "
                                   "listed by variable name where SOEM's config_map puts "
                                   "it.  soem-c: a C source and header whose "
                                   "ecatcfg_config_map makes the same start-up writes, "
                                   "returns the first failure and checks SOEM's mapping; the "
                                   "process data as packed structs with compile-time offset "
                                   "checks, and a minimal main (-DECATCFG_MAIN).  igh-c: a C "
                                   "source and header for the IgH master (ecrt.h): slave "
                                   "configurations with PDO tables, start-up SDOs, SoE IDNs, "
                                   "DC and watchdogs, the variables registered in a domain "
                                   "by name, and a minimal cyclic task (-DECATCFG_MAIN).  "
                                   "lcec: LinuxCNC's ethercat.xml (generic slaves with "
                                   "their PDO tree and HAL pins named after the variables, "
                                   "dcConf, watchdog, sdoConfig; SoE writes in an "
                                   "initCmds file beside it).  ros2: for "
                                   "ethercat_driver_ros2, a generic-slave YAML per slave and "
                                   "the ros2_control fragment that loads them in bus "
                                   "order.")
    p.add_argument("eni", metavar="ENI", help="ENI file")
    p.add_argument("--format", required=True, choices=FORMATS, help="what to write")
    p.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="the file to write (atomically; pysoem: '-' for standard output); "
                        "soem-c, igh-c: the C source, its header beside it with the suffix "
                        ".h; lcec: ethercat.xml, an initCmds file per slave with SoE writes "
                        "beside it; ros2: the ros2_control fragment, a YAML per slave "
                        "beside it")
    p.add_argument("--no-cache", action="store_true", help="do not use the ENI plan cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import hashlib
    from pathlib import Path

    from ecatcfg import __version__
    from ecatcfg.cli import export_igh
    from ecatcfg.cli.inputs import eni_for_output
    from ecatcfg.eni.export import pysoem_module, soem_c, soem_image
    from ecatcfg.eni.export.steps import slave_setups
    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import STDOUT, read_input, write_atomic

    plan, out = eni_for_output(args.eni, args.output, args.no_cache, "exports")
    digest = hashlib.sha256(read_input(args.eni)).hexdigest()
    outputs: list[tuple[Path, bytes]]
    if args.format in export_igh.WRITERS:
        if str(out) == STDOUT:
            raise UsageError(f"-o -: {args.format} writes several files; give a file name")
        return export_igh.WRITERS[args.format](args, plan, out, digest)
    setups = slave_setups(plan, args.eni)
    if args.format == "pysoem":
        pysoem_module.check(setups, args.eni)
        outputs = [(out, pysoem_module.render(setups, Path(args.eni).name, digest,
                                              __version__))]
    else:
        if str(out) == STDOUT:
            raise UsageError("-o -: soem-c writes two files (the C source and its header); "
                             "give a file name")
        soem_image.check(setups, args.eni)     # what SOEM would not map: refused by name
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
