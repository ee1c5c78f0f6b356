"""How long a slave that drops out takes to come back, against the line's own start-up.

    python3 bench/recovery.py [--repeat N]

In memory (``Network.virtual``) with the timing model (``runtime/segment/timing.py``: slaves that
take as long as real ones), each repetition on a fresh network:

- baseline: ``net.up()`` of the example line (examples/topology.yaml: coupler, three I/O
  terminals, a CiA 402 drive with DC), scan to OP;
- power cycle: the drive's cable pulled, the drive switched off and on, the cable back;
  from the cable coming back until the drive is online in OP again;
- hot-connect: the tree example's junction group (3 slaves, plus the nested outputs group)
  absent at start-up and plugged in while the rest runs; from the cable coming in until
  all are online; against ``net.up()`` of the whole tree.

It also counts the cycles that were not valid while the slave came back (the others' data
must keep flowing: 0 expected).  The cycle runs every 1 ms, as apply's would.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

from ecatcfg.compiler import build, topology
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.segment.timing import Timing

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _cycle_until(net: Network, done, limit: float = 10.0) -> tuple[float, int]:
    start = time.perf_counter()
    bad = 0
    next_at = start
    while not done():
        if time.perf_counter() - start > limit:
            raise RuntimeError("did not come back")
        bad += not net.cycle()
        next_at += 0.001
        delay = next_at - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    return time.perf_counter() - start, bad


def power_cycle(plan, esi) -> tuple[float, float, int]:
    with Network.virtual(plan, esi=esi, timing=Timing()) as net:
        t0 = time.perf_counter()
        net.up()
        up = time.perf_counter() - t0
        _cycle_until(net, lambda: net.master.cyclic.stats.cycles > 100)
        net.segment.remove_cable("axis1")
        net.segment.wired[[s.name for s in net.segment.wired].index("axis1")].power_cycle()
        _cycle_until(net, lambda: not net.online("axis1"))
        net.segment.restore_cable("axis1")
        back, bad = _cycle_until(net, lambda: net.online("axis1"))
        return up, back, bad


def hot_connect(plan, esi) -> tuple[float, float, int]:
    with Network.virtual(plan, esi=esi, timing=Timing()) as net:
        t0 = time.perf_counter()
        net.up()                                # the whole tree: the baseline
        up = time.perf_counter() - t0
    with Network.virtual(plan, esi=esi, timing=Timing()) as net:
        net.segment.remove_cable("junction")    # both groups absent at start-up
        net.up()
        _cycle_until(net, lambda: net.master.cyclic.stats.cycles > 100)
        net.segment.restore_cable("junction")
        back, bad = _cycle_until(net, lambda: all(h.online for h in net.health.values()))
        return up, back, bad


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    esi = [EXAMPLES / "esi"]
    line = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library(esi, cache=False)).plan
    tree_esi = [EXAMPLES / "tree" / "esi", EXAMPLES / "esi"]
    tree = build.compile_topology(topology.load(EXAMPLES / "tree" / "hotconnect.yaml"),
                                  Library(tree_esi, cache=False)).plan
    print(f"machine: {platform.machine()}, {platform.system()} {platform.release()}, "
          f"Python {platform.python_version()}")
    for name, run, plan, files in (("drive power-cycled", power_cycle, line, esi),
                                   ("hot-connect group joins", hot_connect, tree, tree_esi)):
        ups, backs, bads = [], [], []
        for _ in range(args.repeat):
            up, back, bad = run(plan, files)
            ups.append(up)
            backs.append(back)
            bads.append(bad)
        print(f"{name}: back in {min(backs) * 1e3:.0f} / {statistics.median(backs) * 1e3:.0f} "
              f"ms (min / median), whole start-up {min(ups) * 1e3:.0f} / "
              f"{statistics.median(ups) * 1e3:.0f} ms, ratio "
              f"{statistics.median(backs) / statistics.median(ups):.2f}x; "
              f"invalid cycles meanwhile: {max(bads)} at most")


if __name__ == "__main__":
    main()
