"""``ecatcfg foe write|read``: one FoE file transfer with one slave, no ENI needed."""

from __future__ import annotations

import argparse
from typing import Any

EPILOG = ("The slave is taken to INIT, its mailbox SyncManagers are written from its SII "
          "(the bootstrap mailbox for BOOT, the standard one for PREOP), the state is "
          "requested, the file moves in data packets of mailbox size - 12 bytes, and the "
          "slave is left in INIT; its identity is read from the SII before and after "
          "(a new firmware's revision shows once the device has been powered off and on).  "
          "--state defaults to BOOT when the SII gives a bootstrap mailbox, else PREOP.  "
          "Use it on a line no other master is driving.  Exit 1 on an FoE error (code and "
          "name on stderr), a refused state or no answer.")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_line, add_timeout

    p = sub.add_parser(
        "foe", help="write or read a file of one slave over FoE (firmware updates)",
        description="One FoE transfer with the slave at position --slave (0 = the first "
                    "after the master): 'write' sends FILE, 'read' stores the slave's "
                    "file in FILE.",
        epilog=EPILOG)
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for action, text in (("write", "send FILE to the slave"),
                         ("read", "read the slave's file into FILE")):
        a = actions.add_parser(action, help=text, description=f"FoE {action}: {text}.",
                               epilog=EPILOG)
        add_line(a)
        a.add_argument("file", metavar="FILE",
                       help="the file to send" if action == "write"
                       else "where to store the file read")
        a.add_argument("--name", metavar="NAME",
                       help="the file's name on the slave (default: FILE's name)")
        a.add_argument("--password", default="0", metavar="HEX",
                       help="FoE password, 32 bits hexadecimal (default 0)")
        a.add_argument("--state", choices=["boot", "preop"],
                       help="the state the transfer runs in (default: boot when the "
                            "slave has a bootstrap mailbox, else preop)")
        add_timeout(a, 10.0, "one reply of the slave")
        if action == "read":
            a.add_argument("--max-size", type=int, default=64 * 1024 * 1024, metavar="BYTES",
                           help="refuse a file longer than this (default 64 MiB)")
        a.add_argument("--format", choices=["text", "json"], default="text")
        a.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    from pathlib import Path

    from ecatcfg.cli.paths import output_file
    from ecatcfg.errors import UsageError
    from ecatcfg.esc import AlState
    from ecatcfg.fileio import read_input, write_atomic
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.master import foe_tool
    from ecatcfg.runtime.master.transport import Transport

    if getattr(args, "max_size", 0) < 0:
        raise UsageError(f"--max-size {args.max_size}: a file has 0 bytes or more")
    try:
        password = foe_tool.parse_password(args.password)
    except ValueError as exc:
        raise UsageError(f"--password: {exc}") from None
    path = Path(args.file)
    data: bytes | None = None
    if args.action == "write":
        if not path.exists():
            raise UsageError(f"{args.file}: no such file")
        try:
            data = read_input(path, args.file)
        except OSError as exc:
            raise UsageError(f"{args.file}: cannot read: {exc.strerror}") from None
    else:
        output_file(path, stdout=False)       # stdout has the transfer's report
    name = args.name if args.name is not None else path.name
    if not name:
        raise UsageError("--name: the file needs a name on the slave")
    state = {None: None, "boot": AlState.BOOT, "preop": AlState.PREOP}[args.state]
    bar = _Bar(sys.stderr) if args.format == "text" and sys.stderr.isatty() else None
    with RawLink(args.iface) as link:
        try:
            report = foe_tool.foe_transfer(
                Transport(link), args.slave, name, data, password=password, state=state,
                timeout=args.timeout, progress=bar, limit=getattr(args, "max_size", None))
        finally:
            if bar is not None:
                bar.close()
    if data is None:
        # Replaced whole or not at all: an interrupted or refused write never leaves a
        # firmware image half-written where a later `foe write` could send it.
        try:
            write_atomic(path, report.data)
        except OSError as exc:
            raise UsageError(f"{args.file}: cannot write: {exc.strerror}") from None
    out = _json(report)
    if args.format == "json":
        print(json.dumps(out, indent=2))
    else:
        _print_text(report, path)
    return 0


def _json(report: Any) -> dict[str, Any]:
    return {"slave": report.position, "action": report.action, "name": report.name,
            "state": report.state, "station_address": report.station_address,
            "al_status_before": report.al_status_before,
            "mailbox": {"receive": report.mailbox[0], "send": report.mailbox[1]},
            "bytes": report.size, "packets": report.packets,
            "busy_replies": report.busy_replies, "seconds": round(report.seconds, 6),
            "frames": report.frames,
            "identity_before": report.identity_before.as_dict()
            if report.identity_before else None,
            "identity_after": report.identity_after.as_dict()
            if report.identity_after else None}


def _print_text(report: Any, path: Any) -> None:
    rate = report.size / report.seconds / 1024 if report.seconds else 0.0
    verb = "written to" if report.action == "write" else "read from"
    print(f"{report.name!r}: {report.size} bytes {verb} slave {report.position} in "
          f"{report.state} ({report.packets} packets, {report.busy_replies} busy replies, "
          f"{report.seconds:.3f} s, {rate:.1f} KiB/s)")
    if report.action == "read":
        print(f"stored in {path}")
    for label, ident in (("before", report.identity_before), ("after", report.identity_after)):
        if ident is not None:
            print(f"identity {label}: vendor 0x{ident.vendor_id:08X} product "
                  f"0x{ident.product_code:08X} revision 0x{ident.revision:08X} serial "
                  f"{ident.serial_no}")


class _Bar:
    """A progress bar on a terminal (rich, as ``apply`` draws its progress): bytes moved
    of the file's size (a write; a read's size is unknown until its last packet), and the
    slave's last busy report (done/entire)."""

    def __init__(self, stream: Any) -> None:
        from rich.console import Console
        from rich.progress import (BarColumn, DownloadColumn, Progress, TextColumn,
                                   TransferSpeedColumn)

        self.progress = Progress(TextColumn("FoE"), BarColumn(), DownloadColumn(),
                                 TransferSpeedColumn(), TextColumn("{task.fields[busy]}"),
                                 console=Console(file=stream), transient=False)
        self.task = self.progress.add_task("foe", total=None, busy="")
        self.started = False

    def __call__(self, progress: Any) -> None:
        if not self.started:
            self.progress.start()
            self.started = True
        busy = f"busy {progress.busy[0]}/{progress.busy[1]}" if progress.busy else ""
        self.progress.update(self.task, completed=progress.done, total=progress.total,
                             busy=busy)

    def close(self) -> None:
        if self.started:
            self.progress.stop()
