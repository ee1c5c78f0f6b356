"""Cyclic benchmark: ecatcfg's bus cycle against SOEM's (pysoem) on the same virtual segment
over veth, and the period jitter of a real-time ``Network.run`` against this machine's
floor measured by ``cyclictest`` (rt-tests), all in one run.

Run from the checkout, as root (network namespaces, AF_PACKET, SCHED_FIFO):
    python3 bench/cyclic.py [--rounds 5] [--cycles 5000] [--rate-seconds 2]
                            [--jitter-seconds 60] [--priority 80] [--cpu 1] [--busy-wait 200]

Method:
  1. Two fresh network namespaces with a veth pair (``virtual_segment.Bench``); ``ecatcfg
     simulate`` in B serves a 3-slave line of the example devices (EX1100 coupler, EX1004
     inputs, EX2008 outputs: one LRW of process data, plus the ENI's state check), pinned
     to CPU 0 under SCHED_FIFO 70 (the slaves must not be what is measured).  The line is
     compiled once to an ENI (``ecatcfg compile``, not timed).
  2. CPU time per cycle: a master process in A brings the line to OP, runs 500 cycles of
     warm-up, then ``--cycles`` cycles back to back, timed with ``time.thread_time()``
     (CPU time of the cycling thread: user + system, waiting excluded) and wall time.
     ecatcfg: ``Network.cycle()``; SOEM: ``send_processdata(); receive_processdata(2000)``
     (both sleep in the kernel while the reply travels: not CPU time).  They alternate
     (ecatcfg, ecatcfg in pure Python (``ECATCFG_PURE_PYTHON=1``: the fallback of an
     install without a C compiler), ecatcfg with ``recovery=False``, SOEM,
     ``--baseline``'s ecatcfg),
     ``--rounds`` processes each, the master on CPU 0 with the simulator (``same``) or on
     CPU 1 (``split``, ``--layouts``); min and median over rounds.  ``floor``: ecatcfg's
     own Python per cycle, in this process, on a link that answers at once.
  3. Highest cycle rate without lost frames: each master paces itself to an absolute
     deadline (``Network.run`` with the cycle time set; for SOEM the same loop in Python)
     at periods from 1000 us down, ``--rate-seconds`` each; a period is sustained when no
     frame was lost (ecatcfg: lost_frames; SOEM: a working counter below the expected)
     and the cycles achieved are at least 99 % of the nominal rate.
  4. Period jitter at 1 kHz over ``--jitter-seconds``, in turn: ``cyclictest -p PRIO -m -a
     CPU -i 1000 -v`` (every sample's wake-up latency printed; the periods are 1000 us + the
     difference of successive latencies), then ``Network.run`` with ``RealtimeOptions(PRIO,
     lock_memory, CPU)``, without and with ``--busy-wait``.  Jitter for both = |period -
     median period| (``CycleStats.jitter``): p50 / p99 / max.  cyclictest's own latency
     figures are printed beside.
"""

from __future__ import annotations

import argparse
import copy as copying
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from timing import ratio  # noqa: E402
from virtual_segment import IF_A, IF_B, Bench, run_as_root, stop, wait_for  # noqa: E402

LINE = [("coupler", "EX1100"), ("inputs", "EX1004"), ("outputs", "EX2008")]
PERIODS_US = [1000, 500, 250, 200, 150, 125, 100, 80, 60, 50]
WARMUP = 500
LAYOUTS = {"same": 0, "split": 1}


# ------------------------------------------------------------------ the workers (namespace A)

def worker_ecatcfg(args: argparse.Namespace) -> dict:
    from ecatcfg.runtime.link import RawLink, cyclic_exchange_path
    from ecatcfg.runtime.network import Network

    out: dict = {}
    with Network(args.eni, RawLink(IF_A), recovery=not args.no_recovery) as net:
        net.up()
        for _ in range(WARMUP):
            net.cycle()
        if args.mode == "cpu":
            stats = net.reset_stats()
            cpu, wall = time.thread_time(), time.perf_counter()
            for _ in range(args.cycles):
                net.cycle()
            out["cpu_us"] = (time.thread_time() - cpu) / args.cycles * 1e6
            out["wall_us"] = (time.perf_counter() - wall) / args.cycles * 1e6
            out["lost"] = stats.lost_frames + stats.wkc_errors
            out["exchange"] = cyclic_exchange_path()
        elif args.mode == "rate":
            out["rates"] = []
            for period in args.periods:
                net.master.cyclic.cycle_time_us = period
                n = int(args.seconds * 1e6 / period)
                start = time.perf_counter()
                net.run(n)
                took = time.perf_counter() - start
                st = net.run_stats
                assert st is not None
                out["rates"].append({"period_us": period, "cycles": n,
                                     "achieved_hz": n / took,
                                     "lost": st.lost_frames + st.wkc_errors,
                                     "long": sorted(st.periods_us)[-3:]})
        elif args.mode == "profile":
            import cProfile
            import io
            import pstats
            prof = cProfile.Profile()
            prof.enable()
            for _ in range(args.cycles):
                net.cycle()
            prof.disable()
            text = io.StringIO()
            pstats.Stats(prof, stream=text).sort_stats("tottime").print_stats(25)
            out["profile"] = text.getvalue()
        else:                                               # jitter
            from ecatcfg.runtime.master import realtime
            opts = realtime.options(priority=args.priority, lock_memory=True,
                                    cpus=[args.cpu], busy_wait_us=args.busy_wait)
            n = int(args.seconds * 1000)
            net.master.cyclic.cycle_time_us = 1000
            cpu = time.process_time()
            net.run(n, realtime=opts, background=True).join()
            st = net.run_stats
            assert st is not None
            out["cpu_us"] = (time.process_time() - cpu) / n * 1e6
            out["cycles"], out["lost"] = st.cycles, st.lost_frames + st.wkc_errors
            out["jitter"] = st.jitter()
            periods = st.periods_us
            out["periods"] = len(periods)
            # The long ones, where they fell: a pattern (every N s) points at a cause.
            out["long"] = [(k, round(p)) for k, p in enumerate(periods) if p > 2000][:40]
    return out


def worker_soem(args: argparse.Namespace) -> dict:
    import pysoem

    m = pysoem.Master()
    m.open(IF_A)
    out: dict = {}
    try:
        if m.config_init() != len(LINE):
            raise SystemExit("SOEM did not find the line")
        m.config_map()
        m.state = pysoem.SAFEOP_STATE
        m.write_state()
        m.state_check(pysoem.SAFEOP_STATE, 5_000_000)
        m.send_processdata()
        m.receive_processdata(10_000)
        m.state = pysoem.OP_STATE
        m.write_state()
        for _ in range(2000):
            m.send_processdata()
            m.receive_processdata(10_000)
            if m.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        else:
            raise SystemExit("SOEM did not reach OP")
        expected = m.expected_wkc
        send, receive = m.send_processdata, m.receive_processdata
        for _ in range(WARMUP):
            send()
            receive(2000)
        if args.mode == "cpu":
            lost = 0
            cpu, wall = time.thread_time(), time.perf_counter()
            for _ in range(args.cycles):
                send()
                if receive(2000) < expected:
                    lost += 1
            out["cpu_us"] = (time.thread_time() - cpu) / args.cycles * 1e6
            out["wall_us"] = (time.perf_counter() - wall) / args.cycles * 1e6
            out["lost"] = lost
        else:                                               # rate
            out["rates"] = []
            clock, sleep = time.perf_counter, time.sleep
            for period_us in args.periods:
                period = period_us / 1e6
                n = int(args.seconds / period)
                lost = 0
                start = next_at = clock()
                for _ in range(n):          # the loop of Network._loop, without busy-wait
                    send()
                    if receive(2000) < expected:
                        lost += 1
                    next_at += period
                    now = clock()
                    if now >= next_at:
                        next_at = now
                    else:
                        sleep(next_at - now)
                took = clock() - start
                out["rates"].append({"period_us": period_us, "cycles": n,
                                     "achieved_hz": n / took, "lost": lost})
        m.state = pysoem.INIT_STATE
        m.write_state()
    finally:
        m.close()
    return out


# ------------------------------------------------------------------ cyclictest

def cyclictest(priority: int, cpu: int, seconds: float) -> dict:
    """cyclictest at 1 kHz: its wake-up latencies, and the periods they imply."""
    exe = shutil.which("cyclictest")
    if exe is None:
        return {"missing": "cyclictest not found (Debian: apt-get install rt-tests)"}
    n = int(seconds * 1000)
    done = subprocess.run([exe, "-p", str(priority), "-m", "-a", str(cpu), "-i", "1000",
                           "-l", str(n), "-t", "1", "-v", "-q"],
                          capture_output=True, text=True, timeout=seconds * 3 + 30)
    lat: list[int] = []
    for line in done.stdout.splitlines():
        parts = line.replace(" ", "").split(":")
        if len(parts) == 3 and all(p.isdigit() for p in parts):
            lat.append(int(parts[2]))
    if not lat:
        return {"error": done.stderr.strip()[-500:] or "no samples"}
    periods = [1000.0 + b - a for a, b in zip(lat, lat[1:])]
    return {"samples": len(lat), "latency": pcts([float(v) for v in lat], absolute=True),
            "jitter": deviation(periods)}


def pcts(values: list[float], absolute: bool = False) -> dict[str, float]:
    v = sorted(values)
    return {"p50": v[len(v) // 2], "p99": v[min(len(v) - 1, int(len(v) * 0.99))],
            "max": v[-1]}


def deviation(periods: list[float]) -> dict[str, float]:
    """The same figure as CycleStats.jitter: |period - median period|, p50/p99/max."""
    from ecatcfg.runtime.master.cyclic import CycleStats
    st = CycleStats()
    for p in periods:
        st.add_period(p)
    return st.jitter()


# ------------------------------------------------------------------ the run

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--cycles", type=int, default=5000)
    ap.add_argument("--rate-seconds", type=float, default=2.0)
    ap.add_argument("--jitter-seconds", type=float, default=60.0)
    ap.add_argument("--priority", type=int, default=80)
    ap.add_argument("--cpu", type=int, default=1)
    ap.add_argument("--busy-wait", type=int, default=200)
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--layouts", default="same,split",
                    help="where the master runs for the CPU rounds: same (CPU 0, with the "
                         "simulator) or split (CPU 1)")
    ap.add_argument("--skip", default="", help="parts to leave out: cpu,rate,jitter")
    ap.add_argument("--profile", action="store_true",
                    help="first print a cProfile of ecatcfg's cycles over veth")
    ap.add_argument("--baseline", metavar="DIR",
                    help="also time the ecatcfg that DIR/ecatcfg is (e.g. a checkout of an "
                         "earlier commit), as a third master in the CPU rounds")
    # The workers, started in namespace A by the run:
    ap.add_argument("--worker", choices=["ecatcfg", "soem"], help=argparse.SUPPRESS)
    ap.add_argument("--mode", choices=["cpu", "rate", "jitter", "profile"],
                    help=argparse.SUPPRESS)
    ap.add_argument("--eni", help=argparse.SUPPRESS)
    ap.add_argument("--no-recovery", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=2.0, help=argparse.SUPPRESS)
    ap.add_argument("--periods", type=lambda s: [int(x) for x in s.split(",")],
                    default=PERIODS_US, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        result = (worker_ecatcfg if args.worker == "ecatcfg" else worker_soem)(args)
        print(json.dumps(result), flush=True)
        return
    run_as_root(ap, args, LAYOUTS, "cyclic", run)


def run(args: argparse.Namespace, tmp: Path) -> None:
    root = HERE.parent
    py = sys.executable
    topo = tmp / "line3.yaml"
    topo.write_text("slaves:\n" + "".join(f"  - {{name: {n}, device: '{d}'}}\n"
                                          for n, d in LINE))
    esi = str(root / "examples" / "esi")
    eni = tmp / "line3.eni.xml"
    subprocess.run([py, "-m", "ecatcfg", "compile", str(topo), "--esi", esi, "-o", str(eni),
                    "--no-cache"], check=True, capture_output=True, timeout=120)
    bench = Bench()
    skip = set(args.skip.split(",")) - {""}
    results: dict = {"machine": machine(), "args": {k: v for k, v in vars(args).items()
                                                    if k in ("rounds", "cycles",
                                                             "rate_seconds",
                                                             "jitter_seconds", "priority",
                                                             "cpu", "busy_wait")}}
    try:
        bench.up()
        # The slaves answer at SCHED_FIFO 70 on CPU 0: real slaves answer in microseconds
        # whatever the host does, and this measures the master, not the emulator's
        # scheduling (without it a busy CPU 0 delays replies past the 10 ms timeout).
        sim = bench.start(bench.ns_b, ["chrt", "-f", "70", "taskset", "-c", "0", py, "-m",
                                       "ecatcfg", "simulate",
                                       "--topology", str(topo), "--iface", IF_B, "--esi",
                                       esi, "--no-cache", "--duration", "3600"])
        wait_for(sim, "ready:", 120)

        def worker(kind: str, mode: str, *extra: str, path: str | None = None,
                   cpu: int | None = None, pure: bool = False) -> dict:
            env = ["env", f"PYTHONPATH={path}"] if path else []
            if pure:        # the fallback, as an install without a C compiler runs it
                env = [*(env or ["env"]), "ECATCFG_PURE_PYTHON=1"]
            # Both masters in the same place: CPU ``cpu`` (the simulator is on CPU 0).
            pin = ["taskset", "-c", str(cpu)] if cpu is not None else []
            out = bench.run(bench.ns_a, [*pin, *env, py, str(Path(__file__).resolve()), "--worker",
                                         kind, "--mode", mode, "--eni", str(eni),
                                         "--cycles", str(args.cycles), *extra], 900)
            return json.loads(out.strip().splitlines()[-1])

        if "floor" not in skip:
            results["floor"] = python_floor(eni, esi)
            print("floor", json.dumps(results["floor"]), flush=True)
        if args.profile:
            print(worker("ecatcfg", "profile")["profile"], flush=True)
        if "cpu" not in skip:
            results["cpu"] = {}
            for layout in args.layouts.split(","):
                cpu = LAYOUTS[layout]
                ours, soem, base, bare, pure = [], [], [], [], []
                for k in range(args.rounds + 1):        # round 0: warm-up, not counted
                    a = worker("ecatcfg", "cpu", cpu=cpu)
                    p = worker("ecatcfg", "cpu", cpu=cpu, pure=True)
                    d = worker("ecatcfg", "cpu", "--no-recovery", cpu=cpu)
                    b = worker("soem", "cpu", cpu=cpu)
                    c = worker("ecatcfg", "cpu", path=args.baseline, cpu=cpu) \
                        if args.baseline else None
                    print(f"{layout} round {k}: ecatcfg {a}  pure Python {p}  soem {b}  "
                          f"baseline {c}", flush=True)
                    if k:
                        ours.append(a)
                        pure.append(p)
                        soem.append(b)
                        bare.append(d)
                        if c is not None:
                            base.append(c)
                oc = [r["cpu_us"] for r in ours]
                sc = [r["cpu_us"] for r in soem]
                res = {
                    "exchange": ours[0]["exchange"],
                    "ecatcfg_cpu_us": mm(oc), "soem_cpu_us": mm(sc),
                    "ratio_min_median": ratio(sc, oc),
                    "pure_python_cpu_us": mm([r["cpu_us"] for r in pure]),
                    "pure_python_over_soem": ratio(sc, [r["cpu_us"] for r in pure]),
                    "ecatcfg_no_recovery_cpu_us": mm([r["cpu_us"] for r in bare]),
                    "no_recovery_over_soem": ratio(sc, [r["cpu_us"] for r in bare]),
                    "ecatcfg_wall_us": mm([r["wall_us"] for r in ours]),
                    "soem_wall_us": mm([r["wall_us"] for r in soem]),
                    "lost": [r["lost"] for r in ours] + [r["lost"] for r in soem]}
                if base:
                    bc = [r["cpu_us"] for r in base]
                    res["baseline_cpu_us"] = mm(bc)
                    res["baseline_over_soem"] = ratio(sc, bc)
                    res["ecatcfg_over_baseline"] = ratio(bc, oc)
                results["cpu"][layout] = res
                print(layout, json.dumps(res), flush=True)
        if "rate" not in skip:
            periods = ",".join(map(str, PERIODS_US))
            rate = {}
            for kind in ("ecatcfg", "soem"):
                r = worker(kind, "rate", "--seconds", str(args.rate_seconds),
                           "--periods", periods, cpu=args.cpu)["rates"]
                ok = [x for x in r if x["lost"] == 0
                      and x["achieved_hz"] >= 0.99 * 1e6 / x["period_us"]]
                rate[kind] = {"runs": r, "highest_hz": max((1e6 / x["period_us"] for x in ok),
                                                           default=0)}
                print(kind, json.dumps(rate[kind]), flush=True)
            results["rate"] = rate
        if "jitter" not in skip:
            jit = {"cyclictest": cyclictest(args.priority, args.cpu, args.jitter_seconds)}
            print("cyclictest", json.dumps(jit["cyclictest"]), flush=True)
            for margin in (0, args.busy_wait):
                r = worker_jitter(worker, args, margin)
                jit[f"ecatcfg_busy_wait_{margin}"] = r
                print(f"ecatcfg busy-wait {margin}", json.dumps(r), flush=True)
            results["jitter"] = jit
        stop(sim)
    finally:
        bench.close()
    print(json.dumps(results, indent=1))


def python_floor(eni: Path, esi: str, cycles: int = 100_000) -> dict:
    """ecatcfg's own CPU per cycle without a wire: in this process, a link that answers
    at once with the reply the emulated line gave to the first cycle (the index copied
    in), so only the master's Python runs; with and without the recovery supervisor, and
    without it with slave-to-slave copies (one of a whole byte, one and eight of 4 bits
    at other bit positions)."""
    from ecatcfg.eni import reader
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime import wire
    from ecatcfg.runtime.segment import emulate
    from ecatcfg.runtime.network import Network
    from ecatcfg.eni.plan import CopyInfo
    from ecatcfg.esc import Cmd

    read = plan = reader.read_file(eni)

    class Echo:
        def __init__(self) -> None:
            self.segment = emulate.segment(emulate.specs_from_eni(
                plan, Library([esi], cache=False), "line"))
            self.reply = bytearray()
            self.canned: tuple[bytearray, list[int]] | None = None

        def send(self, frame: bytes | bytearray) -> None:
            if self.canned is None:
                self.reply = self.segment.process(frame)
                return
            reply, at = self.canned
            for k in at:
                reply[k] = frame[k]
            self.reply = reply

        def recv_into(self, buffer: bytearray, timeout: float | None) -> int:
            n = len(self.reply)
            buffer[:n] = self.reply
            return n

        def recv(self, timeout: float | None) -> bytes:
            return bytes(self.reply)

        def fileno(self) -> int:
            return -1

        def close(self) -> None:
            pass

    # Slave-to-slave copies on the process-data LRW (docs/runtime.md, "Slave-to-slave
    # copies"): the inputs' first variable to the outputs', whole bytes or bit by bit.
    first_in = min(v.bit_offs for v in plan.process_image.inputs)
    first_out = min(v.bit_offs for v in plan.process_image.outputs)
    aligned = CopyInfo(first_in // 8 * 8, first_out // 8 * 8, 8)
    bits = CopyInfo(first_in, first_out + 1, 4)
    variants = {"with_recovery": (True, []), "without_recovery": (False, []),
                "copies_1_aligned": (False, [aligned]), "copies_1_bits": (False, [bits]),
                "copies_8_bits": (False, [bits] * 8)}
    out = {}
    for name, (recovery, copies) in variants.items():
        plan = copying.deepcopy(read)
        lrw = next(c for cyc in plan.cyclic for f in cyc.frames for c in f.cmds
                   if c.cmd == Cmd.LRW)
        lrw.copy_infos = list(copies)
        link = Echo()
        net = Network(plan, link, recovery=recovery)   # type: ignore[arg-type]
        net.up()
        net.cycle()
        if len(net.master.cyclic.prepared(net.state)) != 1:
            return {"skipped": "more than one cyclic frame"}
        link.canned = (bytearray(link.reply),
                       [pos + 1 for pos, _ in wire.datagram_offsets(link.reply)])
        best = []
        for _ in range(3):
            start = time.thread_time()
            for _ in range(cycles):
                net.cycle()
            best.append((time.thread_time() - start) / cycles * 1e6)
        out[name] = round(min(best), 2)
    return out


def worker_jitter(worker, args: argparse.Namespace, margin: int) -> dict:
    return worker("ecatcfg", "jitter", "--seconds", str(args.jitter_seconds),
                  "--priority", str(args.priority), "--cpu", str(args.cpu),
                  "--busy-wait", str(margin))


def mm(values: list[float]) -> str:
    return f"{min(values):.1f} / {statistics.median(values):.1f}"


def machine() -> dict:
    rt = Path("/sys/kernel/realtime")
    return {"kernel": platform.release(), "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "preempt_rt": rt.exists() and rt.read_text().strip() == "1",
            "preempt": _preempt()}


def _preempt() -> str:
    try:
        return subprocess.run(["uname", "-v"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return "?"


if __name__ == "__main__":
    main()
