"""Real-time options for the cycling thread: SCHED_FIFO, locked memory, CPU affinity and
an early wake-up with a busy-wait to the period boundary.

What a Linux real-time application does (``man 7 sched``, ``man 2 mlockall``; the same
steps as ``cyclictest -p PRIO -m -a CPU``):

- ``SCHED_FIFO`` at ``priority`` (1-99): the cycling thread runs before every normal task
  on its CPU.  Refused (EPERM) without root, ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` of
  at least the priority (``ulimit -r``, systemd ``LimitRTPRIO=``).
- ``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page of the process is paged out, so no cycle
  waits for a page fault on swapped memory.  Refused (EPERM/ENOMEM) without root,
  ``CAP_IPC_LOCK`` or an ``RLIMIT_MEMLOCK`` as large as the process (``ulimit -l``,
  systemd ``LimitMEMLOCK=``).
- CPU affinity: the thread runs only on the CPUs listed (best an isolated one, see
  ``docs/runtime.md``).  A CPU that does not exist or that the process may not use (a
  cgroup ``cpuset``, ``taskset`` around the process) is refused.
- ``busy_wait_us``: the loop sleeps until that long before the period boundary, then spins
  on the clock to the boundary; the sleep's wake-up latency is absorbed by the spin at the
  cost of that much CPU time per cycle.

:func:`apply` changes the *calling thread* (priority, affinity; the memory lock is for the
whole process) and returns what undoes it.  A refusal is a :class:`RealtimeError` saying
what was refused and how to grant it; the settings made before it are undone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import resource
from collections.abc import Callable, Iterable

from ecatcfg.errors import EcatcfgError, UsageError
from ecatcfg.record import record

MCL_CURRENT, MCL_FUTURE = 1, 2                  # <sys/mman.h>
PR_SET_TIMERSLACK, PR_GET_TIMERSLACK = 29, 30  # <linux/prctl.h>
MAX_BUSY_WAIT_US = 10_000


class RealtimeError(EcatcfgError):
    """A real-time option the system refused (a permission or a limit)."""


@record(frozen=True)
class RealtimeOptions:
    """``priority``: SCHED_FIFO priority 1-99 (None: the normal scheduler);
    ``lock_memory``: mlockall; ``cpus``: the CPUs the cycling thread may run on (None: any);
    ``busy_wait_us``: wake this long before each period boundary and spin to it (0: sleep
    to the boundary)."""

    priority: int | None = None
    lock_memory: bool = False
    cpus: frozenset[int] | None = None
    busy_wait_us: int = 0

    @property
    def busy_wait_s(self) -> float:
        return self.busy_wait_us / 1e6


def options(priority: int | None = None, lock_memory: bool = False,
            cpus: Iterable[int] | None = None, busy_wait_us: int = 0) -> RealtimeOptions:
    """Checked :class:`RealtimeOptions`; a value out of range is a :class:`UsageError`."""
    if priority is not None:
        top = os.sched_get_priority_max(os.SCHED_FIFO)
        if not 1 <= priority <= top:
            raise UsageError(f"real-time priority {priority}: must be 1 to {top} "
                             f"(SCHED_FIFO)")
    cpu_set: frozenset[int] | None = None
    if cpus is not None:
        cpu_set = frozenset(cpus)
        if not cpu_set:
            raise UsageError("CPU list is empty")
        if min(cpu_set) < 0:
            raise UsageError(f"CPU {min(cpu_set)}: CPU numbers start at 0")
    if not 0 <= busy_wait_us <= MAX_BUSY_WAIT_US:
        raise UsageError(f"busy-wait {busy_wait_us} us: must be 0 to {MAX_BUSY_WAIT_US} us")
    return RealtimeOptions(priority, lock_memory, cpu_set, busy_wait_us)


def parse_cpus(text: str) -> frozenset[int]:
    """``"1"``, ``"0,2"``, ``"2-3"`` (taskset/cpuset list syntax) as a set of CPU numbers."""
    cpus: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        try:
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                if lo > hi:
                    raise ValueError
                cpus.update(range(lo, hi + 1))
            else:
                cpus.add(int(part))
        except ValueError:
            raise UsageError(f"CPU list {text!r}: expected numbers and ranges such as "
                             f"'1' or '0,2-3'") from None
    return frozenset(cpus)


def _cpu_list(cpus: Iterable[int]) -> str:
    return ",".join(str(c) for c in sorted(cpus)) or "none"


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def _limit(which: int) -> str:
    soft, _hard = resource.getrlimit(which)
    return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)


def apply(opts: RealtimeOptions | None) -> Callable[[], None]:
    """Apply ``opts`` to the calling thread; returns the function that restores what it
    changed.  ``None`` or empty options change nothing."""
    undo: list[Callable[[], object]] = []

    def restore() -> None:
        for step in reversed(undo):
            try:
                step()
            except OSError:
                pass            # best effort: the thread ends or the process exits soon

    if opts is None:
        return restore
    try:
        if opts.lock_memory:
            _lock_memory(undo)
        if opts.cpus is not None:
            _set_affinity(opts.cpus, undo)
        if opts.priority is not None:
            _set_fifo(opts.priority, undo)
        if opts.priority is not None or opts.busy_wait_us:
            _timer_slack(undo)
    except BaseException:
        restore()
        raise
    return restore


def lock_memory() -> Callable[[], object]:
    """Lock the process's memory now (``mlockall``); returns the function that unlocks it.
    ``mlockall(MCL_CURRENT)`` faults in and pins every page the process has: hundreds of
    milliseconds for a process of a few hundred MB on a busy host, longer than a slave's
    SM watchdog, so a run with ``lock_memory`` locks before the slaves reach OP
    (cli/apply.prepare_cycling); the run's own :func:`apply` then finds it done."""
    global _held
    undo: list[Callable[[], object]] = []
    _lock_memory(undo)          # adds no undo when already held: its holder unlocks
    _held = True

    def unlock() -> None:
        global _held
        if undo:
            _held = False
            undo[0]()
    return unlock


# Whether :func:`lock_memory` holds the process's memory locked: a run's :func:`apply` then
# leaves it as it is (mlockall again walks every page once more: as long as the first).
_held = False


def _lock_memory(undo: list[Callable[[], object]]) -> None:
    if _held:
        return                  # locked before the run, unlocked by whoever locked it
    libc = _libc()
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        raise RealtimeError(
            f"locking the process's memory (mlockall) was refused ({os.strerror(err)}): "
            f"run as root, or grant CAP_IPC_LOCK (systemd: AmbientCapabilities="
            f"CAP_IPC_LOCK), or raise the locked-memory limit (RLIMIT_MEMLOCK, now "
            f"{_limit(resource.RLIMIT_MEMLOCK)} bytes) with `ulimit -l unlimited` or "
            f"LimitMEMLOCK=infinity in the systemd unit")
    undo.append(libc.munlockall)


def _set_affinity(cpus: frozenset[int], undo: list[Callable[[], object]]) -> None:
    before = os.sched_getaffinity(0)
    count = os.cpu_count() or 1
    missing = sorted(c for c in cpus if c >= count)
    if missing:
        raise RealtimeError(f"CPU {_cpu_list(missing)} does not exist on this machine "
                            f"(CPUs 0-{count - 1}; this process may use "
                            f"{_cpu_list(before)})")
    try:
        os.sched_setaffinity(0, cpus)
    except OSError as exc:
        if exc.errno == errno.EINVAL:
            raise RealtimeError(
                f"running on CPU {_cpu_list(cpus)} was refused: this process may use only "
                f"CPU {_cpu_list(before)} (a cgroup cpuset, taskset or systemd "
                f"CPUAffinity= restricts it)") from None
        raise RealtimeError(f"setting the CPU affinity to {_cpu_list(cpus)} was refused "
                            f"({exc.strerror}): run as root or grant CAP_SYS_NICE") from None
    undo.append(lambda: os.sched_setaffinity(0, before))


def _set_fifo(priority: int, undo: list[Callable[[], object]]) -> None:
    policy = os.sched_getscheduler(0)
    param = os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        if exc.errno != errno.EPERM:
            raise RealtimeError(f"SCHED_FIFO priority {priority} was refused "
                                f"({exc.strerror})") from None
        raise RealtimeError(
            f"real-time scheduling (SCHED_FIFO priority {priority}) was refused "
            f"({exc.strerror}): run as root, or grant CAP_SYS_NICE (systemd: "
            f"AmbientCapabilities=CAP_SYS_NICE), or raise the real-time priority limit "
            f"(RLIMIT_RTPRIO, now {_limit(resource.RLIMIT_RTPRIO)}) to at least {priority} "
            f"with `ulimit -r {priority}` or LimitRTPRIO={priority} in the systemd unit"
        ) from None
    undo.append(lambda: os.sched_setscheduler(0, policy, param))


def _timer_slack(undo: list[Callable[[], object]]) -> None:
    """1 ns timer slack: a normal thread's sleeps may end up to 50 us late by design
    (``man 2 prctl``, PR_SET_TIMERSLACK); real-time threads have none, a busy-waiting
    normal one wants none either."""
    libc = _libc()
    before = libc.prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0)
    if libc.prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0 and before > 0:
        undo.append(lambda: libc.prctl(PR_SET_TIMERSLACK, before, 0, 0, 0))
