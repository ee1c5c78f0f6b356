"""The Network API in a few lines: toggle an output and read an input on a virtual segment.

Run it with ``python -m ecatcfg.examples.toggle``.  It compiles the example topology (the
same as ``ecatcfg compile examples/topology.yaml --esi examples/esi -o line.eni.xml``),
brings the line up on a virtual segment emulating the example devices, and then, once per
bus cycle, toggles lamp 1 and reads button 1.  On hardware, open the ENI with a link to
the network card instead: ``Network("line.eni.xml", RawLink("eth1"))``.
"""

from __future__ import annotations

from ecatcfg.compiler import build, topology
from ecatcfg.esi.library import Library
from ecatcfg.examples import example_dir
from ecatcfg.runtime import Network

LAMP = "lamps.Channel 1-8.Output 1"
BUTTON = "buttons.Channel 1.Input"


def main(cycles: int = 6) -> None:
    esi = example_dir() / "esi"
    plan = build.compile_topology(topology.load(example_dir() / "topology.yaml"),
                                  Library([esi], cache=False)).plan
    with Network.virtual(plan, esi=[esi]) as net:
        net.up()                                         # scan, verify, INIT -> OP
        button_terminal = net.segment.slaves[1]          # the emulated "buttons" terminal
        for n in range(cycles):
            button_terminal.set_inputs(bytes([n % 3 == 0]))   # someone presses button 1
            net[LAMP] = not net[LAMP]                    # toggle lamp 1
            net.cycle()
            net.cycle()                                  # inputs come back a cycle later
            print(f"cycle {n + 1}: lamp 1 {'on ' if net[LAMP] else 'off'}  "
                  f"button 1 {'pressed' if net[BUTTON] else 'released'}  "
                  f"(lamps terminal outputs 0x{net.segment.slaves[3].outputs().hex()})")
    # Leaving the block brought the line back to INIT.


if __name__ == "__main__":
    main()
