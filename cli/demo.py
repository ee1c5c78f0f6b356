"""``ecatcfg demo``: the main job on the embedded default (the README's first command).

Compiles the example topology shipped inside the package (``examples/topology.yaml`` with the
self-written ESI files in ``examples/esi/``) into an ENI and a C header, then applies that
ENI to a virtual segment emulating the same devices: scan and verify, INIT -> OP, a few
cycles of process data (buttons pressed on the emulated input terminals, a running light on
the output terminal), and back to INIT.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("demo", help="run the main job on the embedded example",
                       description="Compile the example topology shipped inside the package "
                                   "into an ENI and a C header, then apply it to a virtual "
                                   "segment up to OP; needs no arguments and no hardware.")
    p.add_argument("--out-dir", default="ecatcfg-demo", metavar="DIR",
                   help="where to write demo.eni.xml and demo.h (default: ./ecatcfg-demo)")
    p.add_argument("--cycles", type=int, default=8, metavar="N",
                   help="bus cycles to show in OP (default: 8)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ecatcfg import __version__
    from ecatcfg.compiler import build, header, topology
    from ecatcfg.eni import writer as eni_writer
    from ecatcfg.errors import UsageError
    from ecatcfg.esi.library import Library
    from ecatcfg.examples import example_dir
    from ecatcfg.fileio import write_atomic

    folder = example_dir()
    loaded = topology.load(folder / "topology.yaml", "examples/topology.yaml")
    result = build.compile_topology(loaded, Library([folder / "esi"], cache=False))
    plan = result.plan
    out = Path(args.out_dir)
    eni, h = out / "demo.eni.xml", out / "demo.h"
    files = [(eni, eni_writer.to_bytes(plan, generator=f"ecatcfg {__version__}")),
             (h, header.render(plan, "examples/topology.yaml", guard=header.guard_for(h.name)))]
    # A file named like the folder, a folder named like a file, no permission: exit 2.
    for path, data in [(out, None)] + files:
        try:
            if data is None:
                out.mkdir(parents=True, exist_ok=True)
            else:
                write_atomic(path, data)
        except OSError as exc:
            raise UsageError(f"cannot write {path}: {exc.strerror}") from None

    print(f"Example line compiled ({folder / 'topology.yaml'}):\n")
    print(f"  {'slave':10} {'device':18} {'addr':>5} {'out':>5} {'in':>5}  mailbox  DC")
    for s in plan.slaves:
        pd = s.process_data
        out_bits = sum(r.bit_length for r in pd.send) if pd else 0
        in_bits = sum(r.bit_length for r in pd.recv) if pd else 0
        device = next(x.device for x in loaded.topology.slaves if x.name == s.name)
        print(f"  {s.name:10} {device:18} {s.phys_addr:>5} {_bits(out_bits):>5} "
              f"{_bits(in_bits):>5}  {'CoE' if s.mailbox else '-':7}  "
              f"{'ref clock' if s.dc and s.dc.reference_clock else 'yes' if s.dc else '-'}")
    for n, frame in enumerate(plan.cyclic[0].frames):
        cmds = ", ".join(f"{c.comment.split(';')[1].strip() if ';' in c.comment else c.cmd}"
                         f"{f' (WKC {c.cnt})' if c.cnt else ''}" for c in frame.cmds)
        print(f"\n  cyclic frame {n + 1} every {plan.cyclic[0].cycle_time} us: {cmds}")
    init = sum(len(s.init_cmds) for s in plan.slaves)
    coe = sum(len(s.mailbox.coe_init_cmds) for s in plan.slaves if s.mailbox)
    print(f"  {init} register InitCmds, {coe} CoE InitCmds, process image "
          f"{plan.process_image.outputs_size} bytes")
    for w in result.warnings:
        print(f"  warning: {w}")
    print(f"\nwrote {eni} and {h}\n")
    return _apply(eni, folder / "esi", max(args.cycles, 0))


def _apply(eni: Path, esi: Path, cycles: int) -> int:
    """Apply the compiled ENI to a virtual segment of the example devices and show it run."""
    import struct

    from ecatcfg.cli.report import ApplyReport
    from ecatcfg.eni import reader as eni_reader
    from ecatcfg.esc import AlState
    from ecatcfg.runtime.network import Network

    plan = eni_reader.read_file(eni)
    report = ApplyReport(plan, str(eni))
    print(f"Applying {eni} to a virtual segment of the example devices:")
    with Network.virtual(plan, [esi], on_event=report.event) as net:
        net.up(AlState.OP)
        net.reset_stats()               # the statistics count the cycles shown below
        inputs = {s.name: s for s in net.segment.slaves if s.device.type_name == "EX1004"}
        lamps = [v for v in net.variables if v.startswith("lamps.")]
        shown = [v for v in net.variables if v.startswith(("buttons.", "sensors."))]
        drive = next((s for s in net.segment.slaves if s.name == "axis1"), None)
        status = next((v for v in net.variables if v.startswith("axis1.")
                       and v.lower().replace(" ", "").endswith("statusword")), None)
        position = next((v for v in net.variables if v.startswith("axis1.")
                         and v.lower().endswith("position actual value")), None)
        print("\nTwo bus cycles a row (the inputs of a cycle come back with the next "
              "frame):")
        print(f"{'row':>5}  {'lamps (out)':12} {'buttons+sensors (in)':20} "
              f"{'axis1 status word, position (in)' if status else ''}")
        for n in range(cycles):
            # The emulated terminals "see" inputs and the emulated drive reports a status
            # word ("operation enabled") and a moving position, as its application would;
            # the master drives a running light.
            for i, slave in enumerate(inputs.values()):
                slave.set_inputs(bytes([(n >> i) & 0x0F]))
            if drive is not None:
                drive.set_inputs(struct.pack("<Hi", 0x0237, 1000 * n))
            for k, name in enumerate(lamps):
                net[name] = k == n % len(lamps)
            net.cycle()
            net.cycle()            # the inputs of this cycle come back with the next frame
            out = "".join("1" if net[v] else "0" for v in lamps)
            got = "".join("1" if net[v] else "0" for v in shown)
            word = f"0x{net[status]:04X} {net[position]:>7}" if status and position else ""
            print(f"{n + 1:>5}  {out:12} {got:20} {word}")
        print()
        report.final_states(net.master.read_states(), net.master.progress)
        report.finish(net, None, AlState.OP)
    return 0


def _bits(bits: int) -> str:
    return "-" if not bits else f"{bits // 8}B" if bits % 8 == 0 else f"{bits}b"
