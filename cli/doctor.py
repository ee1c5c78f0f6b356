"""``ecatcfg doctor``: every slave on a line that is not in its target state, and why."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ecatcfg.eni.plan import NetworkPlan
    from ecatcfg.esi.evidence import Evidence
    from ecatcfg.runtime.master.transport import Transport

STATES = {"init": 1, "preop": 2, "safeop": 4, "op": 8}


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_iface, add_prefer

    p = sub.add_parser(
        "doctor", help="why slaves on a line are not in their target state",
        description="Read every slave's AL status on the line (by position) and, for each "
                    "one not in the target state or with the error flag, the cause of its "
                    "AL status code as the slave holds it: SyncManager and FMMU registers "
                    "and the PDO assignment over CoE for 0x001D/0x001E, the watchdog "
                    "registers for 0x001B, the DC registers and the minimum cycle time the "
                    "slave reports (0x1C32:05) for 0x0035, with --esi also the device's DC "
                    "op modes and ESI minimum cycle time, the newest 0x10F3 "
                    "diagnosis message where the slave has one.  With an ENI, slaves "
                    "whose SII identity is not the ENI's are reported too, and the DC "
                    "cycle time the ENI asks for is shown; without one, each slave is "
                    "named by the identity in its SII (and its device type with --esi).  "
                    "Nothing is configured; a mailbox is set up from the SII only for a slave below PREOP whose "
                    "CoE objects are read (as 'ecatcfg sdo' does).",
        epilog="Exit 0 when every slave is in the target state, 1 otherwise.")
    p.add_argument("eni", nargs="?", metavar="ENI", help="the ENI the line should match")
    add_iface(p)
    p.add_argument("--state", choices=list(STATES), default="op",
                   help="the target state of every slave (default op)")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (repeatable; folders searched for *.xml): each "
                        "slave's device, found by the identity in its SII, for the causes "
                        "that compare with it (a DC refusal: the device's DC op modes and "
                        "minimum cycle time)")
    add_prefer(p)
    p.add_argument("--no-cache", action="store_true",
                   help="read the ESI files without the index cache")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json

    from ecatcfg.cli.identity import slave_identities
    from ecatcfg.esc import AlState
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master.diagnose import doctor
    from ecatcfg.runtime.master.transport import Transport

    target = AlState(STATES[args.state])
    plan = None
    if args.eni:
        from pathlib import Path

        from ecatcfg.eni import reader as eni_reader
        from ecatcfg.errors import UsageError
        from ecatcfg.fileio import check_input
        check_input(args.eni)
        if not Path(args.eni).is_file():
            raise UsageError(f"{args.eni}: no such file")
        plan = eni_reader.read_file(args.eni)
    library = None
    if args.esi:
        from ecatcfg.esi.library import Library
        library = Library(args.esi, cache=not args.no_cache, prefer=args.prefer)
    elif args.prefer:
        from ecatcfg.errors import UsageError
        raise UsageError("--prefer ranks files of --esi: give them with --esi")
    with RawLink(args.iface) as link:
        transport = Transport(link)
        if library is not None:
            library = library.guided(_line_evidence(transport, plan, args.eni))
        count, findings = doctor(transport, target, plan, library)
        # Without an ENI a slave has no name: it is shown by the identity in its SII (and
        # the device of that identity in --esi).
        who = slave_identities(transport, [f.position for f in findings], library) \
            if plan is None and findings else {}
    out: dict[str, Any] = {"iface": args.iface, "eni": args.eni, "target": target.name,
                           "slaves": count, "ok": not findings,
                           "findings": [{**f.as_json(), **(who[f.position].as_json()
                                                            if f.position in who else {})}
                                        for f in findings]}
    if args.format == "json":
        print(json.dumps(out, indent=2))
    else:
        if not findings:
            print(f"all {count} slaves in {target.name}")
        for f in findings:
            name = f.name if f.name else who[f.position].text() if f.position in who \
                else None
            shown = f"slave {f.position}" + (f" ({name})" if name else "")
            print(f"{shown}: {f.state}, not {target.name}" if f.state != target.name
                  else f"{shown}: {f.state}")
            for line in f.identity:
                print(f"  identity: {line}")
            if f.cause is not None:
                print(f"  {f.cause.text()}")
            elif f.state != "no answer" and not f.identity:
                print(f"  no error flag (AL status code 0x0000): nothing refused "
                      f"{target.name}; no request for it reached the slave")
    return 0 if not findings else 1


def _line_evidence(transport: Transport, plan: NetworkPlan | None, eni: str | None
                   ) -> Callable[[int, int, int], Evidence | None]:
    """Evidence for choosing among ESI files that describe one identity differently (asked
    for only then): the SII of the first slave on the line with that identity, read from
    its EEPROM; where it cannot be read, what the ENI says of its slaves of that identity."""
    from ecatcfg.cli.identity import sii_evidence
    from ecatcfg.eni.evidence import evidence_by_identity
    from ecatcfg.runtime.master.scan import scan

    by_eni = evidence_by_identity(plan, eni or "the ENI") if plan is not None else {}
    known: dict[tuple[int, int, int], Evidence | None] = {}

    def evidence_for(vendor: int, product: int, revision: int) -> Evidence | None:
        key = (vendor, product, revision)
        if key not in known:
            found = [s.position for s in scan(transport)
                     if (s.vendor_id, s.product_code, s.revision) == key]
            sii = sii_evidence(transport, found[0])[0] if found else None
            known[key] = sii if sii is not None else by_eni.get(key)
        return known[key]
    return evidence_for
