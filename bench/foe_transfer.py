"""FoE transfer benchmark: a 1 MiB file written to and read back from an emulated slave,
in memory and over a veth pair, against the mailbox-size limit.

Run from the checkout (root, for the namespaces):  python3 bench/foe_transfer.py [--size B]
[--repeat R] [--no-veth]

The slave is the FoE fixture device EXF1000 (``tests/fixtures/ecatcfg-EXF-foe.xml``): a
244-byte bootstrap mailbox (BOOT, firmware files) and a 128-byte standard mailbox (PREOP).
For each, the file goes in data packets of mailbox size - 12 bytes (6 mailbox header, 6 FoE
header), so a transfer has at least ceil(size / (mbx - 12)) packets; each packet costs at
least two frames (one that writes SM0, one that reads the answer from SM1), so the
theoretical minimum of the session's frames is 2 x (packets + 1) (the request and its
answer too).  Reported per case: packets (checked against that count), frames sent by the
master in the whole session (scan, SII, states and the transfer) and their ratio to the
minimum, the transfer's time (request to last ack, ``FoeReport.seconds``) and throughput,
min / median of R repeats.

- **memory**: ``runtime/master/foe_tool.foe_transfer`` against ``VirtualSegment.serve`` on
  a thread over ``MemoryLink``;
- **veth**: ``ecatcfg simulate`` in one network namespace, ``ecatcfg foe write|read
  --format json`` in the other (``bench/virtual_segment.py``'s ``Bench``), each a process.

Nothing is asserted but the packet count and that the file read back equals the file
written: the figures go to docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import struct
import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "tests" / "fixtures" / "ecatcfg-EXF-foe.xml"
VENDOR, PRODUCT = 0xE0000ECA, 0xF100
CASES = (("BOOT", "app.efw", 244), ("PREOP", "data.bin", 128))


def payload(size: int, firmware: bool) -> bytes:
    body = bytes((i * 31 + 7) & 0xFF for i in range(size))
    if not firmware:
        return body
    # The emulation's firmware format (docs/runtime.md, FoE): ECFW, vendor, product, revision.
    return (b"ECFW" + struct.pack("<III", VENDOR, PRODUCT, 0x00020000) + body)[:size]


def summary(rows: list[dict], size: int, mbx: int) -> dict:
    packets = {r["packets"] for r in rows}
    expect = math.ceil(size / (mbx - 12)) + (size % (mbx - 12) == 0)
    if packets != {expect}:
        raise SystemExit(f"packets {packets}, expected {expect}")
    secs = sorted(r["seconds"] for r in rows)
    frames = sorted(r["frames"] for r in rows)
    minimum = 2 * (expect + 1)
    return {"packets": expect, "frames": frames[0], "frames_ratio": frames[0] / minimum,
            "min_s": secs[0], "median_s": statistics.median(secs),
            "best_kib_s": size / 1024 / secs[0],
            "median_kib_s": size / 1024 / statistics.median(secs)}


def in_memory(size: int, repeat: int) -> dict[str, dict]:
    from ecatcfg.esc import AlState
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.link import MemoryLink
    from ecatcfg.runtime.master import foe_tool
    from ecatcfg.runtime.master.transport import Transport
    from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

    lib = Library([ESI], cache=False)
    out = {}
    for state, name, mbx in CASES:
        seg = segment([SlaveSpec(lib.device(lib.find("EXF1000").entry), "box")])
        a, b = MemoryLink.pair()
        stop = threading.Event()
        thread = threading.Thread(target=seg.serve, args=(b,), kwargs={"stop": stop},
                                  daemon=True)
        thread.start()
        transport = Transport(a)
        data = payload(size, state == "BOOT")
        for action in ("write", "read"):
            rows = []
            for _ in range(repeat):
                report = foe_tool.foe_transfer(transport, 0, name,
                                               data if action == "write" else None,
                                               state=AlState[state])
                if action == "read" and report.data != data:
                    raise SystemExit("the file read back differs")
                rows.append({"packets": report.packets, "seconds": report.seconds,
                             "frames": report.frames})
            out[f"memory {action} {state} (mbx {mbx})"] = summary(rows, size, mbx)
        stop.set()
        thread.join(2)
    return out


def over_veth(size: int, repeat: int) -> dict[str, dict]:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from virtual_segment import IF_A, IF_B, Bench

    out = {}
    bench = Bench()
    with tempfile.TemporaryDirectory() as tmp:
        topo = Path(tmp) / "line.yaml"
        topo.write_text("slaves:\n  - {name: box, device: EXF1000}\n")
        try:
            bench.up()
            sim = bench.start(bench.ns_b, [sys.executable, "-m", "ecatcfg", "simulate",
                                           "--esi", str(ESI), "--topology", str(topo),
                                           "--iface", IF_B, "--duration", "3600",
                                           "--no-cache"])
            while True:
                line = sim.lines.get(timeout=60)                # type: ignore[attr-defined]
                if line is None or line.startswith("ready:"):
                    break
            for state, name, mbx in CASES:
                data = payload(size, state == "BOOT")
                src, back = Path(tmp) / name, Path(tmp) / f"back-{name}"
                src.write_bytes(data)
                for action in ("write", "read"):
                    rows = []
                    for _ in range(repeat):
                        argv = [sys.executable, "-m", "ecatcfg", "foe", action, "--iface",
                                IF_A, "--slave", "0", "--state", state.lower(),
                                str(src if action == "write" else back), "--name", name,
                                "--format", "json"]
                        rows.append(json.loads(bench.run(bench.ns_a, argv, timeout=600)))
                        if action == "read" and back.read_bytes() != data:
                            raise SystemExit("the file read back over veth differs")
                    out[f"veth {action} {state} (mbx {mbx})"] = summary(rows, size, mbx)
        finally:
            bench.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=1024 * 1024)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-veth", action="store_true")
    args = ap.parse_args()
    print(f"# {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"file {args.size} bytes, repeat {args.repeat}")
    results = in_memory(args.size, args.repeat)
    if not args.no_veth:
        results.update(over_veth(args.size, args.repeat))
    print("| case | packets | frames (ratio to 2 x (packets + 1)) | time min / median "
          "| KiB/s best / median |")
    print("|---|---|---|---|---|")
    for case, r in results.items():
        print(f"| {case} | {r['packets']} | {r['frames']} ({r['frames_ratio']:.2f}x) | "
              f"{r['min_s']:.2f} / {r['median_s']:.2f} s | {r['best_kib_s']:.0f} / "
              f"{r['median_kib_s']:.0f} |")


if __name__ == "__main__":
    main()
