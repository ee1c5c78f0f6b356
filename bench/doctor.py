"""How long ``ecatcfg doctor`` takes to say why slaves refuse, against a bare scan.

    python3 bench/doctor.py [--repeat N]

In memory (``Network.virtual``) with the timing model (``runtime/segment/timing.py``: the
drive answers its mailbox in 1.749 ms, an SII word takes 0.72 ms) on a line of three
CiA 402 drives (the example drive of ``examples/esi``, each with the example line's PDOs:
RxPDO 0x1601, TxPDOs 0x1A00 and the remapped 0x1A01), whose ENI gives every drive's output
SyncManager one byte too few: each refuses SAFEOP with AL status 0x001D and stays in
PREOP+ERR.  Then, each repetition:

- baseline: a bare scan of the line (``runtime/master/scan.py``: count, identities from
  the SII, DL status), what every online tool starts with;
- doctor: ``diagnose.doctor`` with the ENI, target OP: for each drive its AL status, SM and
  FMMU registers, and the PDO assignment and mapping it holds, read over CoE (0x1C12, its
  PDO's mapping entries, 0x1C13 is not read for 0x001D), and 0x10F3 where present.

The figure that matters is the ratio doctor / scan, measured in the same run.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import struct
import sys
import tempfile
import time
from pathlib import Path

from ecatcfg.compiler import build, topology
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.master.diagnose import doctor
from ecatcfg.runtime.master.replay import ApplyError
from ecatcfg.runtime.master.scan import scan
from ecatcfg.runtime.segment.timing import Timing

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
DRIVE = """
  - name: axis{n}
    device: "0xE0000ECA:0x7201"
    rx_pdos: [0x1601]
    tx_pdos: [0x1A00, 0x1A01]
    pdo_mapping:
      0x1A01: [[0x6041, 0, 16], [0x6064, 0, 32], [0x606C, 0, 32]]
"""


def broken_plan():  # type: ignore[no-untyped-def]
    """Three drives, each with SM2 5 bytes long instead of 6."""
    text = "master: {name: three-drives, cycle_time_us: 1000}\nslaves:\n" + "".join(
        DRIVE.format(n=n) for n in (1, 2, 3))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "three.yaml"
        path.write_text(text)
        plan = build.compile_topology(topology.load(path),
                                      Library([EXAMPLES / "esi"], cache=False)).plan
    for slave in plan.slaves:
        for cmd in slave.init_cmds:
            if cmd.comment == "set sm 2 (outputs)":
                data = bytearray(cmd.payload)
                struct.pack_into("<H", data, 2, 5)
                cmd.data = bytes(data)
    return plan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    plan = broken_plan()
    scans: list[float] = []
    doctors: list[float] = []
    frames: dict[str, int] = {}
    with Network.virtual(plan, esi=[EXAMPLES / "esi"], esi_cache=False,
                         timing=Timing(), dc_threshold_ns=0) as net:
        try:
            net.up()
        except ApplyError:
            pass
        else:
            sys.exit("the broken ENI was not refused")
        transport = net.master.transport
        for _ in range(args.repeat):
            sent = transport.counters.frames_sent
            t0 = time.perf_counter()
            scan(transport)
            scans.append(time.perf_counter() - t0)
            frames["scan"] = transport.counters.frames_sent - sent
            sent = transport.counters.frames_sent
            t0 = time.perf_counter()
            count, findings = doctor(transport, AlState.OP, plan)
            doctors.append(time.perf_counter() - t0)
            frames["doctor"] = transport.counters.frames_sent - sent
            causes = [f.cause for f in findings]
            if count != 3 or len(causes) != 3 or any(
                    c is None or c.code != 0x001D or "gives 6 bytes" not in c.lines[0]
                    for c in causes):
                sys.exit(f"unexpected findings: {findings}")
    print(f"{platform.machine()}, Python {platform.python_version()}, repeat {args.repeat}")
    print(f"{'what':28} {'min':>9} {'median':>9} {'frames':>7}")
    for name, key, times in (("scan (baseline)", "scan", scans),
                             ("doctor, 3 slaves 0x001D", "doctor", doctors)):
        print(f"{name:28} {min(times) * 1e3:7.1f}ms {statistics.median(times) * 1e3:7.1f}ms "
              f"{frames[key]:7}")
    print(f"ratio doctor / scan (median): "
          f"{statistics.median(doctors) / statistics.median(scans):.1f}x")


if __name__ == "__main__":
    main()
