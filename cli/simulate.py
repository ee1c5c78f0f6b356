"""``ecatcfg simulate``: run a virtual segment of slaves emulated from their ESI files."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.segment.emulate import SlaveSpec
    from ecatcfg.runtime.segment.slave import EmulatedSlave, StateChange
    from ecatcfg.runtime.segment.timing import Timing
    from ecatcfg.runtime.segment.virtual import LossyPort
    from ecatcfg.runtime.segment.virtual import VirtualSegment


# Columns of the slave table: a longer name or device is cut with an ellipsis, so the
# columns after it stay aligned (the full names are in the state-change lines).
NAME_WIDTH = 16
DEVICE_WIDTH = 14


def cut_to(text: str, width: int) -> str:
    """``text`` padded to ``width``, or cut to it with "…" as its last character."""
    return f"{text:{width}}" if len(text) <= width else text[:width - 1] + "\u2026"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_prefer

    p = sub.add_parser(
        "simulate", help="run a virtual EtherCAT segment on a network interface",
        description="Emulate a line or tree of slaves from their ESI files (or, with "
                    "--eni, from the ENI alone where no ESI is given) and answer EtherCAT frames "
                    "on a network interface (raw Ethernet, EtherType 0x88A4), so a master "
                    "(ecatcfg apply, SOEM, TwinCAT) can configure and run them without "
                    "hardware.  Prints the slaves, then 'ready: N slaves on IF' once it "
                    "answers frames, then every state change.  Stops on Ctrl-C or after "
                    "--duration.",
        epilog="Use an interface no other network uses: a veth end inside a network "
               "namespace is the usual choice.")
    p.add_argument("--esi", action="append", default=[], metavar="PATH",
                   help="ESI file or folder (searched recursively); repeatable.  Needed for "
                        "--topology; with --eni a slave whose device is not there is "
                        "emulated from the ENI alone")
    add_prefer(p)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--topology", metavar="T",
                     help="the slaves of a topology file, plugged as it says")
    src.add_argument("--eni", metavar="ENI",
                     help="the slaves an ENI describes, plugged as its PreviousPort says")
    p.add_argument("--iface", required=True, metavar="IF", help="network interface to serve")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--drop", type=float, default=0.0, metavar="P",
                   help="lose this share of frames (0..1), half before and half after "
                        "the slaves processed them")
    p.add_argument("--faults", action="append", default=[], metavar="SLAVE:PORT:P",
                   help="a lossy port: frames received on PORT (A-D or 0-3) of SLAVE (its "
                        "name, or its bus position with every cable in place) get a CRC "
                        "error with probability P; the ESCs count them in their error "
                        "counters (0x0300-0x030B) and the frame is lost; repeatable")
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="seed of the fault injection (same seed, same faults)")
    p.add_argument("--realistic", action="store_true",
                   help="slaves take the time real ones do: mailbox replies, state changes "
                        "and EEPROM reads per device kind, from the table in docs/timing.md")
    p.add_argument("--timing", metavar="FILE",
                   help="JSON file overriding figures of that table (implies --realistic)")
    p.add_argument("--cut", action="append", default=[], metavar="SLAVE",
                   help="remove the cable into this slave's port 0 (its name, or its bus "
                        "position with every cable in place): it and the slaves behind it "
                        "are not on the frame, the port it was plugged into has no link; "
                        "repeatable")
    p.add_argument("--input", action="append", default=[], metavar="NAME=VALUE",
                   help="hold an input of an emulated slave at VALUE, named as the process "
                        "image names it ('buttons.Channel 1.Input=1', "
                        "'axis1.TxPDO 1 (CSP).Position actual value=-200') or by index "
                        "('axis1.0x6064:00=5'); it follows the slave's PDO mapping; "
                        "repeatable")
    p.add_argument("--control", action="store_true",
                   help="read commands from standard input while serving, one a line, each "
                        "answered 'ok: ...' or 'error: ...': set NAME VALUE, release NAME, "
                        "cut SLAVE, plug SLAVE, power SLAVE|all, inputs [SLAVE], help")
    p.add_argument("--allow-esi-errors", action="store_true",
                   help="with --topology: emulate a device although its ESI has an error that "
                        "stops compile (a warning per finding instead)")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    p.set_defaults(run=run)


# A passive slave (no ESC) of the line: listed, never emulated.  (name, device, vendor,
# product, revision, where the identity comes from)
Passive = tuple[str, str, int, int, int, str]


def run(args: argparse.Namespace) -> int:
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.runtime.link import RawLink
    from ecatcfg.runtime.segment import emulate
    from ecatcfg.runtime.segment.virtual import Faults

    _check_args(args)
    lib = _library(args)
    source = args.topology or args.eni
    notes: list[str] = []
    if args.topology:
        assert lib is not None
        specs, passive = _from_topology(args, lib)
    else:
        specs, passive, notes = _from_eni(args, lib)
    if not specs:
        raise EcatcfgError(f"{source}: no slaves to emulate")
    timing = _timing(args)
    try:
        seg = emulate.segment(specs, Faults(drop=args.drop, seed=args.seed,
                                            lossy=_lossy_ports(args.faults)), timing)
    except ValueError as exc:
        raise EcatcfgError(f"{source}: {exc}") from None
    removed = _cut_cables(seg, args.cut)
    held = _hold_inputs(seg, args.input)
    # The interface is opened before anything is printed: a missing one is the only
    # thing the user reads, not a table of slaves that will never answer.
    link = RawLink(args.iface)
    for note in notes:
        print(note, file=sys.stderr)
    for name, gone in removed:
        print(f"cable into {name} removed: "
              + ", ".join(s.name for s in gone) + " not on the frame", flush=True)
    _print_slaves(seg, passive, timing is not None)
    for text in held:
        print(f"input {text}", flush=True)
    _serve(seg, link, args, passive)
    return 0


def _hold_inputs(seg: VirtualSegment, assignments: list[str]) -> list[str]:
    """``--input NAME=VALUE``: each held; a wrong name or value is a usage error."""
    from ecatcfg.cli.simulate_control import hold
    from ecatcfg.errors import UsageError

    done = []
    for assignment in assignments:
        try:
            done.append(hold(seg, assignment))
        except ValueError as exc:
            raise UsageError(f"--input {exc}") from None
    return done


def _lossy_ports(specs: list[str]) -> tuple[LossyPort, ...]:
    """``--faults SLAVE:PORT:P`` as lossy ports (a usage error for a malformed one)."""
    from ecatcfg.errors import UsageError
    from ecatcfg.esc import PORT_LETTERS
    from ecatcfg.runtime.segment.virtual import LossyPort

    out: list[LossyPort] = []
    for spec in specs:
        parts = spec.rsplit(":", 2)
        port_text = parts[1].strip().upper() if len(parts) == 3 else ""
        port = (PORT_LETTERS.index(port_text) if port_text and port_text in PORT_LETTERS
                else int(port_text) if port_text.isdigit() else -1)
        try:
            share = float(parts[2]) if len(parts) == 3 else -1.0
        except ValueError:
            share = -1.0
        if len(parts) != 3 or not parts[0] or not 0 <= port <= 3 or not 0.0 <= share <= 1.0:
            raise UsageError(f"--faults {spec}: SLAVE:PORT:P, e.g. lamps:A:0.2 (PORT A-D or "
                             "0-3, P between 0 and 1)")
        slave: str | int = int(parts[0]) if parts[0].isdigit() else parts[0]
        out.append(LossyPort(slave, port, share))
    return tuple(out)


def _check_args(args: argparse.Namespace) -> None:
    from pathlib import Path

    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import check_input

    if not 0.0 <= args.drop <= 1.0:
        raise UsageError(f"--drop {args.drop}: a share between 0 and 1")
    if args.duration is not None and args.duration <= 0:
        raise UsageError(f"--duration {args.duration}: must be positive")
    source = args.topology or args.eni
    if not Path(source).exists():
        raise UsageError(f"{source}: no such file")
    # A device node or FIFO is refused before the interface is opened (the readers refuse it
    # too: fileio.read_input).
    check_input(source)
    if args.timing:
        check_input(args.timing, f"--timing {args.timing}")
    if args.topology and not args.esi:
        raise UsageError("--topology needs --esi (the ESI files of the slaves to emulate)")
    if args.prefer and not args.esi:
        raise UsageError("--prefer ranks files of --esi: give them with --esi")


def _library(args: argparse.Namespace) -> Library | None:
    """The ESI library of ``--esi``, if given; its file problems are errors."""
    from ecatcfg.errors import EcatcfgError
    from ecatcfg.esi.library import Library

    lib = Library(args.esi, cache=not args.no_cache, prefer=args.prefer) if args.esi else None
    if lib is not None and lib.problems:
        for problem in lib.problems:
            print(f"error: {problem}", file=sys.stderr)
        raise EcatcfgError(f"{len(lib.problems)} ESI file problem(s)")
    return lib


def _from_topology(args: argparse.Namespace, lib: Library
                   ) -> tuple[list[SlaveSpec], list[Passive]]:
    """The slaves of ``--topology``: the compiler resolves the topology (its checks, the
    modules in the slots); the segment emulates the devices it resolved."""
    from ecatcfg.compiler import topology
    from ecatcfg.compiler.passive import split
    from ecatcfg.compiler.plugged import plugged_devices
    from ecatcfg.runtime.segment import emulate
    from ecatcfg.runtime.wiring import Plug

    # Unknown keys are reported with the errors resolving the rest finds.
    loaded = topology.load(args.topology, unknown_keys="defer")
    devices = topology.checked(loaded, lambda: plugged_devices(
        loaded, lib, allow_esi_errors=args.allow_esi_errors))
    for d in devices:
        for warning in d.esi_warnings:
            print(f"warning: {warning}", file=sys.stderr)
    specs = [emulate.SlaveSpec(d.device, d.name, alias=d.alias, plug=None
                               if d.parent is None or d.parent_port is None
                               else Plug(d.parent, d.parent_port))
             for d in devices]
    passive = [(p.cfg.name, p.device.type_name, p.device.vendor.id or 0,
                p.device.product_code or 0, p.device.revision or 0, "ESI")
               for p in split(loaded, lib).passive]
    return specs, passive


def _from_eni(args: argparse.Namespace, lib: Library | None
              ) -> tuple[list[SlaveSpec], list[Passive], list[str]]:
    """The slaves of ``--eni`` (from the ESI where ``--esi`` has it, else from the ENI
    alone), and notes on what the ENI holds that apply would refuse."""
    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.eni.contents import line_of
    from ecatcfg.runtime.segment import emulate

    plan = eni_reader.read_file(args.eni)
    # Not the master: what apply would refuse asks nothing of the emulated slaves,
    # but the user learns that it is there and not used (once the interface is open).
    notes = [f"note: ignored (apply would refuse it): {line_of(part, args.eni)}"
             for part in plan.unsupported]
    specs = emulate.specs_from_eni(plan, lib, args.eni)
    # Which of differing ESI files of one identity the ENI's evidence chose, and why.
    notes += [f"note: slave {s.name!r}: {s.esi_choice}" for s in specs if s.esi_choice]
    passive = [(p.name, "passive", p.vendor_id, p.product_code, p.revision, "ENI")
               for p in plan.passive]
    return specs, passive, notes


def _timing(args: argparse.Namespace) -> Timing | None:
    """How long the slaves take: ``--timing FILE``, the table with ``--realistic``, else
    no time at all."""
    from pathlib import Path

    from ecatcfg.errors import UsageError

    if args.timing:
        if not Path(args.timing).exists():
            raise UsageError(f"--timing {args.timing}: no such file")
        from ecatcfg.runtime.segment import timing as timing_model
        return timing_model.load(args.timing)
    if args.realistic:
        from ecatcfg.runtime.segment.timing import Timing
        return Timing()
    return None


def _cut_cables(seg: VirtualSegment, which: list[str]
                ) -> list[tuple[str, list[EmulatedSlave]]]:
    """Remove the cables of ``--cut`` (slave names, or bus positions with every cable in
    place): each slave's name and the slaves no longer on the frame."""
    from ecatcfg.errors import UsageError

    cut = []
    for name in which:
        by_position = name.isdigit() and int(name) < len(seg.wired)
        named = [s for s in seg.wired if s.name == name]
        if not named and not by_position:
            raise UsageError(f"--cut {name}: no slave of that name or position (the "
                             f"slaves are {', '.join(s.name for s in seg.wired)})")
        target = named[0] if named else next(s for s in seg.wired
                                             if s.position == int(name))
        cut.append(target)
    removed = []
    for target in cut:
        try:
            removed.append((target.name, seg.remove_cable(target)))
        except ValueError as exc:
            raise UsageError(f"--cut {target.name}: {exc}") from None
    return removed


def _print_slaves(seg: VirtualSegment, passive: list[Passive], timing: bool) -> None:
    print(f"{'pos':>3}  {'name':{NAME_WIDTH}} {'device':{DEVICE_WIDTH}} {'vendor':>10} "
          f"{'product':>10} {'revision':>10}  {'from':4} mailbox"
          + ("  timing" if timing else ""))
    for s in seg.slaves:
        dev = s.device
        mbx = ",".join(dev.mailbox.protocols) if dev.mailbox else "-"
        print(f"{s.position:>3}  {cut_to(s.name, NAME_WIDTH)} "
              f"{cut_to(dev.type_name, DEVICE_WIDTH)} "
              f"0x{dev.vendor.id or 0:08x} 0x{dev.product_code or 0:08x} "
              f"0x{dev.revision or 0:08x}  {'ENI' if s.eni_only else 'ESI':4} {mbx}"
              + (f"  {s.timing.kind}" if s.timing else ""))
    for name, device, vendor, product, revision, origin in passive:
        # A slave without an ESC (ETG.2100: no PhysAddr/AutoIncAddr) answers no frame:
        # nothing to emulate.
        print(f"  -  {cut_to(name, NAME_WIDTH)} {cut_to(device, DEVICE_WIDTH)} "
              f"0x{vendor:08x} 0x{product:08x} "
              f"0x{revision:08x}  {origin:4} passive: no ESC, not emulated")
    for s in seg.slaves:
        if s.eni_only is not None:
            print(f"note: slave {s.position} ({s.name}) emulated from the ENI alone: "
                  f"{s.eni_only}")


def _serve(seg: VirtualSegment, link: RawLink, args: argparse.Namespace,
           passive: list[Passive]) -> None:
    """Answer frames on ``link`` until ``--duration`` ends or a signal stops the run,
    printing each slave's state changes."""
    import signal
    import threading

    def report(change: StateChange) -> None:
        flag = f" ERR 0x{change.code:04X}" if change.error else ""
        note = f"; {change.note}" if change.note else ""
        print(f"slave {change.position} ({change.name}): {change.state.name}{flag}{note}",
              flush=True)

    seg.on_state_change = report
    # SIGINT (Ctrl-C), SIGTERM and SIGHUP end the run the same clean way as --duration, as
    # they stop apply.  Each is set explicitly: a shell starts a background job (`&`) with
    # SIGINT ignored (POSIX, "Signals" of the Shell Command Language) and Python then leaves
    # it ignored, so `kill -INT` would not stop a simulate started from a script.
    stop = threading.Event()
    stopped_by: list[str] = []

    def on_signal(number: int, _frame: object) -> None:
        stopped_by.append(signal.Signals(number).name)
        stop.set()

    for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(number, on_signal)
    # SIGUSR1 switches the line's power off and on (every slave's power_cycle: registers
    # reset, EEPROM kept, a firmware written over FoE started), between two frames.
    power = threading.Event()
    signal.signal(signal.SIGUSR1, lambda _n, _f: power.set())

    control = None
    if args.control:
        from ecatcfg.cli.simulate_control import Control
        control = Control(seg)

    def on_tick() -> None:
        if power.is_set():
            power.clear()
            for slave in list(seg.wired):
                seg.power_cycle(slave)
            print(f"power cycle: {len(seg.wired)} slaves switched off and on", flush=True)
        if control is not None:
            control.tick()
        else:
            for s in seg.wired:         # held inputs where the current mapping puts them
                s.apply_held_inputs()
    with link:
        seg.serve(link, duration=args.duration, stop=stop, on_tick=on_tick,
                  on_ready=lambda: print(f"ready: {len(seg.slaves)} slaves on "
                                         f"{args.iface}" + (
                                             f" ({len(passive)} passive not emulated)"
                                             if passive else ""), flush=True))
    by = f" ({stopped_by[0]})" if stopped_by else ""
    print(f"stopped after {seg.frames} frames{by}", flush=True)
