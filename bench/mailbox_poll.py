"""What polling the mailbox-full bits through Master/MailboxStates costs against polling each
slave's SM1 status byte, on lines of EXD-402 drives that answer a mailbox request after the
fitted firmware time (runtime/segment/timing.py, 1.749 ms), in memory on the simulated
clock: the figures are the same on every machine and under any load.

Each line runs twice from one compiled ENI: as compiled (its drives' bits in MailboxStates,
one LRD for all waiting drives) and with MailboxStates taken out (each waiting drive's SM1
status byte read by its own FPRD, as before the LRD).  Reported per run: frames and
datagram bytes the master sent to OP, the status polls of either kind (the ENI's cyclic
frames, which carry the area's LRD too, not counted), and the simulated time to OP and of
each transition (the drives' 9 PDO-assignment SDOs each).

Run: ``python3 bench/mailbox_poll.py [--drives 8,64]``
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
AREA_CMD = 10                           # LRD


def plan_of(n: int) -> Any:
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import reader, writer
    from ecatcfg.esi.library import Library
    text = "slaves:\n" + "".join(f"  - {{name: axis{i}, device: EXD-402}}\n" for i in range(n))
    plan = build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library([ESI], cache=False)).plan
    return reader.read_bytes(writer.to_bytes(plan), "t.eni.xml")


def run(plan: Any) -> dict[str, Any]:
    from ecatcfg.runtime import Network, wire
    from ecatcfg.runtime.clock import SimClock
    from ecatcfg.runtime.pcap import read_capture
    from ecatcfg.runtime.segment.timing import Timing

    area = plan.master.mailbox_states
    steps: list[str] = []
    clock = SimClock()
    with tempfile.TemporaryDirectory() as tmp:
        pcap = Path(tmp) / "run.pcap"

        def on_event(event: Any) -> None:
            if event.kind == "transition" and " in " in event.text:
                steps.append(event.text)        # "PS: SAFEOP in 120 ms, 40 frames"
        with Network.virtual(plan, esi=[ESI], timing=Timing(), pcap=pcap, clock=clock,
                             on_event=on_event) as net:
            start = clock.monotonic()
            net.up()
            took = clock.monotonic() - start
            to_op = net.master.transport.counters.frames_sent
        # The frames to OP (the way down when the network closes is not counted).
        sent = [wire.decode(f).datagrams for _, _, f in read_capture(pcap)][::2][:to_op]
    fprd = sum(1 for f in sent for d in f
               if d.cmd == 4 and d.ado == 0x080D and len(d.data) == 1)
    lrd = sum(1 for f in sent for d in f if area is not None and d.cmd == AREA_CMD
              and d.address == area[0] and not any(x.cmd == 7 for x in f))
    return {"frames_to_op": len(sent),
            "datagram_bytes": sum(10 + len(d.data) + 2 for f in sent for d in f),
            "sm1_status_fprds": fprd, "mailbox_state_lrds": lrd,
            "to_op_ms": round(took * 1000, 1), "transitions": steps[:4]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drives", default="8,64")
    args = parser.parse_args()
    out = {}
    for n in (int(x) for x in args.drives.split(",")):
        plan = plan_of(n)
        fallback = copy.deepcopy(plan)
        fallback.master.mailbox_states = None
        out[n] = {"sm1 status": run(fallback), "MailboxStates": run(plan)}
        for how, figures in out[n].items():
            print(f"{n} drives, {how}: {json.dumps(figures)}", flush=True)


if __name__ == "__main__":
    main()
