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

    python3 bench/doctor.py --veth [--repeat N]

The same line served by ``ecatcfg simulate`` on one end of a veth pair (its own network
namespace, ``tests/rig.py``; root needed), brought up with the broken ENI by ``ecatcfg apply
--stay`` (the drives stay in PREOP+ERR), then ``ecatcfg scan --iface`` (baseline) and
``ecatcfg doctor ENI --iface`` as processes in the master's namespace, as a user runs them;
each process's wall time, Python's start-up included, and ``scan()`` and ``doctor()`` in
this process through a raw socket in the same namespace (time and frames).  The commands
run with the ``PYTHONPATH`` this script gets, so two trees can be compared in one sitting.
``--realistic``: ``simulate --realistic`` (the timing model's slaves).
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


def over_veth(repeat: int, realistic: bool) -> None:

    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root / "tests"))
    import rig

    from ecatcfg.eni import writer as eni_writer

    broken = broken_plan()
    with tempfile.TemporaryDirectory() as tmp, rig.veth_pair("doc") as veth:
        eni = Path(tmp) / "three.eni.xml"
        eni.write_bytes(eni_writer.to_bytes(broken))
        sim, lines = rig.start_simulate(veth, "--esi", str(EXAMPLES / "esi"), "--eni",
                                        str(eni), *(["--realistic"] if realistic else []),
                                        duration=600)
        if not lines or not lines[-1].startswith("ready:"):
            sys.exit(f"simulate did not start: {lines}")
        try:
            ecatcfg = [sys.executable, "-m", "ecatcfg"]
            up = veth.run_in(veth.ns_a, ecatcfg + ["apply", str(eni), "--iface", veth.if_a,
                                                   "--stay", "--no-cache"], timeout=120)
            if up.returncode != 1 or "0x001D" not in up.stdout + up.stderr:
                sys.exit(f"apply did not stop at the refusal: {up.stdout}{up.stderr}")
            times: dict[str, list[float]] = {"scan": [], "doctor": [], "in": [],
                                             "in-scan": []}
            frames = {"in": 0, "in-scan": 0}
            from ecatcfg.runtime.master.transport import Transport
            for _ in range(repeat):
                # In this process, through a raw socket in the master's namespace: the
                # diagnosis alone, and its frames.
                with veth.socket_in(veth.ns_a) as link:
                    transport = Transport(link)
                    for key, call in (("in-scan", lambda: scan(transport)),
                                      ("in", lambda: doctor(transport, AlState.OP,
                                                            broken))):
                        sent = transport.counters.frames_sent
                        t0 = time.perf_counter()
                        call()
                        times[key].append(time.perf_counter() - t0)
                        frames[key] = transport.counters.frames_sent - sent
                for what, argv in (("scan", ["scan", "--iface", veth.if_a]),
                                   ("doctor", ["doctor", str(eni), "--iface", veth.if_a])):
                    t0 = time.perf_counter()
                    done = veth.run_in(veth.ns_a, ecatcfg + argv, timeout=120)
                    times[what].append(time.perf_counter() - t0)
                    if what == "doctor" and done.stdout.count("gives 6 bytes") != 3:
                        sys.exit(f"unexpected doctor output: {done.stdout}{done.stderr}")
                    if what == "scan" and done.returncode != 0:
                        sys.exit(f"scan failed: {done.stdout}{done.stderr}")
        finally:
            sim.send_signal(2)
            sim.wait(10)
    print(f"over veth{' (simulate --realistic)' if realistic else ''}: "
          f"{platform.machine()}, Python {platform.python_version()}, repeat {repeat}")
    print(f"{'what':32} {'min':>9} {'median':>9} {'frames':>7}")
    for name, key in (("scan() in process (baseline)", "in-scan"),
                      ("doctor() in process", "in"),
                      ("ecatcfg scan (baseline)", "scan"),
                      ("ecatcfg doctor, 3 x 0x001D", "doctor")):
        print(f"{name:32} {min(times[key]) * 1e3:7.1f}ms "
              f"{statistics.median(times[key]) * 1e3:7.1f}ms {frames.get(key, ''):>7}")
    for a, b in (("in", "in-scan"), ("doctor", "scan")):
        print(f"ratio {a} / {b} (median): "
              f"{statistics.median(times[a]) / statistics.median(times[b]):.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--veth", action="store_true",
                        help="ecatcfg scan and doctor as processes over a veth pair")
    parser.add_argument("--realistic", action="store_true",
                        help="with --veth: simulate --realistic (slaves that take the time "
                             "real ones do)")
    args = parser.parse_args()
    if args.veth:
        over_veth(args.repeat, args.realistic)
        return
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
