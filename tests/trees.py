"""The branched network of the acceptance (a coupler, a junction, drives, terminals and a
UR20 station) and the wiring rule, written here independently of
``ecatcfg.compiler.wiring``: a hand-written tree (parent and port letter per slave) and a
depth-first walk that takes each ESC's ports in the order the ESC datasheets give for a
frame (0, 3, 1, 2: A, D, B, C).

Devices are the corpus files the SOEM tests use (Beckhoff EK1100, EK1122, EL1809, EL2008,
the Elmo drive) and a Weidmueller UR20 station (``test_modular``)."""

from __future__ import annotations

EK1100 = "0x2:0x44c2c52:0x120000"       # Physics YKY
EK1122 = "0x2:0x4622c52:0x120000"       # KYKY
EL1809 = "0x2:0x7113052:0x120000"       # KK
EL2008 = "0x2:0x7d83052:0x120000"       # KK
ELMO = "0x9a:0x30924:0x10420"           # YY
UR20_MODULES = ["UR20-4DI-P", "UR20-4DO-P", "UR20-4AI-UI-16"]

# A coupler; on its E-bus a junction with three branches: an axis on D, an axis on B, the
# E-bus going on at C to a line of I/O terminals; the UR20 station on the coupler's
# Ethernet out (C).  Defaults and named ports mixed.
ACCEPTANCE = f"""\
master: {{name: tree, cycle_time_us: 1000}}
slaves:
  - {{name: coupler, device: '{EK1100}'}}
  - {{name: junction, device: '{EK1122}'}}
  - {{name: axis1, device: '{ELMO}', parent: junction, port: D}}
  - {{name: axis2, device: '{ELMO}', parent: junction, port: B}}
  - {{name: inputs, device: '{EL1809}', parent: junction, port: C}}
  - {{name: outputs, device: '{EL2008}'}}
  - name: station
    device: UR20-FBC-EC
    parent: coupler
    modules: {{1: [{", ".join(UR20_MODULES)}]}}
"""

# The same wiring, listed in another order (every slave that is not plugged into the one
# before it names its parent and port).
ACCEPTANCE_SHUFFLED = f"""\
master: {{name: tree, cycle_time_us: 1000}}
slaves:
  - {{name: coupler, device: '{EK1100}'}}
  - name: station
    device: UR20-FBC-EC
    parent: coupler
    port: C
    modules: {{1: [{", ".join(UR20_MODULES)}]}}
  - {{name: junction, device: '{EK1122}', parent: coupler, port: B}}
  - {{name: outputs, device: '{EL2008}', parent: inputs, port: B}}
  - {{name: inputs, device: '{EL1809}', parent: junction, port: C}}
  - {{name: axis2, device: '{ELMO}', parent: junction, port: B}}
  - {{name: axis1, device: '{ELMO}', parent: junction, port: D}}
"""

# Where each slave is plugged (parent, port letter), worked out by hand from the file and
# the default rule: the junction (E-bus port A) on the coupler's E-bus port B; the output
# terminal on the input terminal's port B; the station on the coupler's first free Ethernet
# port, C.
ACCEPTANCE_TREE: dict[str, tuple[str, str] | None] = {
    "coupler": None, "junction": ("coupler", "B"), "axis1": ("junction", "D"),
    "axis2": ("junction", "B"), "inputs": ("junction", "C"), "outputs": ("inputs", "B"),
    "station": ("coupler", "C")}
ACCEPTANCE_ORDER = ["coupler", "junction", "axis1", "axis2", "inputs", "outputs", "station"]

FRAME_PORT_ORDER = "ADBC"                # ESC ports 0, 3, 1, 2


def bus_order(tree: dict[str, tuple[str, str] | None]) -> list[str]:
    """The order a frame reaches the slaves of ``tree``: depth first from the root, each
    slave's ports in FRAME_PORT_ORDER."""
    root, = (name for name, up in tree.items() if up is None)
    out: list[str] = []

    def visit(name: str) -> None:
        out.append(name)
        below = {up[1]: child for child, up in tree.items() if up and up[0] == name}
        for letter in FRAME_PORT_ORDER:
            if letter in below:
                visit(below[letter])

    visit(root)
    return out
