"""``ecatcfg compile TOPOLOGY --esi PATH... -o ENI [--header FILE.h]``: topology -> ENI."""

from __future__ import annotations

import argparse
import gc
import sys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_prefer

    p = sub.add_parser("compile", help="compile a topology and ESI files into an ENI",
                       description="Compile a topology (YAML or JSON: slaves in bus order) "
                                   "with the vendor ESI files into an ENI (ETG.2100). "
                                   "Nothing is written when the topology has errors; the "
                                   "outputs are written atomically and are byte-identical "
                                   "for the same inputs.")
    p.add_argument("topology", metavar="TOPOLOGY", help="topology file (.yaml, .yml, .json)")
    p.add_argument("--esi", action="append", required=True, metavar="PATH",
                   help="ESI file or folder (searched recursively); repeatable")
    add_prefer(p)
    p.add_argument("-o", "--output", required=True, metavar="ENI",
                   help="ENI file to write ('-': standard output)")
    p.add_argument("--header", metavar="FILE.h",
                   help="also write a C header of the process image ('-': standard output)")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    p.add_argument("--allow-esi-errors", action="store_true",
                   help="compile although a used device's ESI has an error that changes what "
                        "is written (lint's rules marked \"stops compile\"); a warning per "
                        "finding instead")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    # One pass over inputs of bounded size, with little cyclic garbage (about 8 000 objects
    # on a 512-slave line): the cyclic GC would rescan the ESI models it reads (hundreds of
    # thousands of objects) some 25 times, a sixth of a cold compile's CPU time.
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        return _run(args)
    finally:
        if was_enabled:
            gc.enable()


def _run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ecatcfg import __version__
    from ecatcfg.cli.paths import messages, output_file
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.errors import EcatcfgError, UsageError
    from ecatcfg.esi.library import Library
    from ecatcfg.fileio import write_atomic

    if not Path(args.topology).exists():
        raise UsageError(f"{args.topology}: no such file")
    outputs = [args.output] + ([args.header] if args.header else [])
    for out in outputs:
        # Checked before anything is written: a failure after the ENI would leave it behind.
        output_file(out)
    # One output must not replace the other, nor the topology it is compiled from.
    targets = [Path(p).resolve() for p in [args.topology] + outputs]
    if len(set(targets)) < len(targets):
        raise UsageError("the topology, -o and --header must be three different files")
    # Unknown keys are reported with the errors the compiler finds in the rest.
    loaded = topology.load(args.topology, unknown_keys="defer")
    lib = Library(args.esi, cache=not args.no_cache, prefer=args.prefer)
    if lib.problems:
        for problem in lib.problems:
            print(f"error: {problem}", file=sys.stderr)
        raise EcatcfgError(f"{len(lib.problems)} ESI file problem(s); nothing written")
    result = topology.checked(loaded, lambda: build.compile_topology(
        loaded, lib, allow_esi_errors=args.allow_esi_errors))
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    # Render everything before writing anything: an error leaves no file behind.
    eni = eni_writer.to_bytes(result.plan, generator=f"ecatcfg {__version__}")
    h = None
    if args.header:
        from ecatcfg.compiler import header      # its templates need jinja2: only for a header
        h = header.render(result.plan, Path(args.topology).name,
                          guard=header.guard_for(Path(args.header).name))
    for target, data in [(args.output, eni)] + ([(args.header, h)] if h is not None else []):
        try:
            write_atomic(target, data)
        except OSError as exc:      # name the user's file, not the temporary one beside it
            raise UsageError(f"cannot write {target}: {exc.strerror}") from None
    plan = result.plan
    frames = sum(len(c.frames) for c in plan.cyclic)
    passive = f" and {len(plan.passive)} passive" if plan.passive else ""
    print(f"wrote {args.output}: {len(plan.slaves)} slaves{passive}, {frames} cyclic frame"
          f"{'s' if frames != 1 else ''}, process image {plan.process_image.outputs_size} "
          f"bytes" + (f"; header {args.header}" if h is not None else ""),
          file=messages(args.output, args.header))
    return 0
