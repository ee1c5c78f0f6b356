"""``ecatcfg report ENI -o network.html``: an ENI's network as one self-contained HTML page
(``eni/report.py``): topology, slaves, process image, cyclic frames, InitCmds, and the
findings of ``check``.

The page is written atomically, and nothing is written when the ENI has errors (the
reader's message names the file and line; exit 1).
"""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_prefer

    p = sub.add_parser("report", help="an ENI's network as one self-contained HTML page",
                       description="Write an HTML page of an ENI (ours or any tool's): the "
                                   "topology drawn as SVG (terminals side by side as on the "
                                   "DIN rail, each box with its device type and vendor), a "
                                   "searchable slave table, the process image as a map of "
                                   "bytes and bits coloured by slave, the cyclic frames with "
                                   "the slaves each datagram serves and what each adds to "
                                   "its working counter, the InitCmds per transition, which "
                                   "check rules ran and the check findings.  The page "
                                   "loads nothing from anywhere: attach it to a ticket, open "
                                   "it offline.")
    p.add_argument("eni", metavar="ENI", help="ENI file")
    p.add_argument("-o", "--output", required=True, metavar="HTML",
                   help="the page to write (atomically; '-': standard output)")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (repeatable): device types and vendor names "
                        "for the boxes, and for the check findings each slave against its "
                        "device, as `ecatcfg check --esi` does; without it the ENI is "
                        "checked against itself")
    add_prefer(p)
    p.add_argument("--no-check", action="store_true",
                   help="leave the check findings out (the page says check was not run)")
    p.add_argument("--no-cache", action="store_true",
                   help="do not use the ESI index cache and the ENI plan cache")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:

    from ecatcfg.cli.inputs import eni_for_output
    from ecatcfg.eni import report, report_devices
    from ecatcfg.eni.check import check_eni
    from ecatcfg.errors import UsageError

    plan, out = eni_for_output(args.eni, args.output, args.no_cache, "reports on")
    findings = None
    library = None
    if args.esi:
        from ecatcfg.esi.library import Library
        library = Library(args.esi, cache=not args.no_cache, prefer=args.prefer)
        for problem in library.problems:
            print(f"ecatcfg report: note: {problem} (its devices are not in the library)",
                  file=sys.stderr)
    labels = report_devices.labels(plan, report_devices.product_revisions(args.eni), library)
    coverage = None
    if not args.no_check:
        coverage = report_devices.coverage(plan, labels, library is not None)
        notes: list[str] = []
        findings = check_eni(args.eni, library, use_cache=not args.no_cache,
                             notes=notes).findings
        for note in notes:      # which of differing ESI files the ENI's evidence chose
            print(f"ecatcfg report: note: {note}", file=sys.stderr)
    try:
        report.write(plan, out, args.eni, findings=findings, labels=labels,
                     coverage=coverage)
    except OSError as exc:
        raise UsageError(f"-o {args.output}: cannot write: {exc.strerror}") from None
    checked = "" if findings is None or coverage is None else \
        f", {len(findings)} check findings ({coverage.sentence()})"
    print(f"wrote {args.output}: {len(plan.slaves) + len(plan.passive)} slaves, "
          f"{len(plan.process_image.inputs) + len(plan.process_image.outputs)} variables"
          f"{checked}", file=sys.stderr)
    return 0
