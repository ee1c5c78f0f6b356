"""The runtime test rig: two network namespaces joined by a veth pair, plus tshark and pysoem.

Importable helpers and pytest fixtures (registered in ``conftest.py``):

- ``veth_netns`` (fixture) / :func:`veth_pair` (context manager): namespaces
  ``ecat-<pid>-<random>-a`` and ``-b`` with ``va`` in the first and ``vb`` in the second, both
  up, ``lo`` up, IPv6 off (no autoconfiguration noise).  Everything is deleted afterwards, also
  when the test fails; processes started with :meth:`VethRig.popen_in` are stopped.
- :meth:`VethRig.socket_in` opens a :class:`~ecatcfg.runtime.link.RawLink` inside a namespace
  from the test process itself (``setns(2)`` in a short-lived thread of its own, so the test's
  threads never change namespace; a packet socket stays in the namespace it was made in).
- :func:`require_netns`, :func:`require_tshark`, :func:`require_pysoem` (and the fixtures
  ``tshark_path``, ``pysoem_module``): when the machine lacks root/namespaces, tshark or pysoem
  the test is *skipped* locally but *fails* when ``ECATCFG_REQUIRE_RUNTIME=1`` or ``CI=true``
  (``.ci/run`` sets the former), as ``ECATCFG_REQUIRE_CORPUS`` does for the corpus.
- :func:`tshark_fields` and :func:`tshark_malformed`: one tshark run per pcap.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import prereq
import pytest

if TYPE_CHECKING:       # imported when used: conftest imports this module for every test
    from ecatcfg.runtime.link import RawLink

T = TypeVar("T")

REQUIRE_ENV = prereq.RUNTIME
CLONE_NEWNET = 0x40000000
NETNS_DIR = Path("/run/netns")
IF_A, IF_B = "va", "vb"
# CapEff bits: CAP_NET_ADMIN (veth, netns), CAP_NET_RAW (AF_PACKET), CAP_SYS_ADMIN (setns).
_CAPS = {12: "CAP_NET_ADMIN", 13: "CAP_NET_RAW", 21: "CAP_SYS_ADMIN"}


# --------------------------------------------------------------------------- skip or fail

def runtime_required() -> bool:
    """True in CI: missing runtime prerequisites fail instead of skipping."""
    return prereq.required(REQUIRE_ENV)


def unavailable(what: str, reason: str) -> None:
    """Skip (locally) or fail (in CI) a test whose runtime prerequisite ``what`` is
    missing (``prereq.py``)."""
    prereq.missing(what, reason, REQUIRE_ENV)


@functools.cache
def netns_unavailable_reason() -> str | None:
    """Why network namespaces and veth pairs cannot be used here, or None when they can."""
    if not sys.platform.startswith("linux"):
        return f"network namespaces need Linux, this is {sys.platform}"
    if shutil.which("ip") is None:
        return "the `ip` command (iproute2) is not installed"
    try:
        status = Path("/proc/self/status").read_text()
        cap_eff = int(next(line.split()[1] for line in status.splitlines()
                           if line.startswith("CapEff:")), 16)
    except (OSError, StopIteration, ValueError) as exc:
        return f"cannot read the process capabilities ({exc})"
    missing = [name for bit, name in _CAPS.items() if not cap_eff >> bit & 1]
    if missing:
        return (f"needs root: {', '.join(missing)} missing (uid {os.geteuid()}); veth pairs, "
                f"namespaces and raw sockets need CAP_NET_ADMIN, CAP_NET_RAW and CAP_SYS_ADMIN")
    if not hasattr(_libc(), "setns"):
        return "the C library has no setns()"
    return None


def require_netns() -> None:
    """Skip/fail unless namespaces, veth pairs and raw sockets are usable."""
    reason = netns_unavailable_reason()
    if reason:
        unavailable("root with network namespaces", reason)


def require_tshark() -> str:
    """The path of tshark; skip/fail when it is not installed."""
    path = shutil.which("tshark")
    if path is None:
        unavailable("tshark", "not on PATH (Debian: apt-get install -y tshark)")
    return path  # type: ignore[return-value]


def require_pysoem():
    """The pysoem module; skip/fail when it cannot be imported."""
    try:
        import pysoem
    except ImportError as exc:
        unavailable("pysoem", f"cannot import it ({exc}); pip install -e '.[test]'")
    return pysoem


# --------------------------------------------------------------------------- setns

@functools.cache
def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(None, use_errno=True)


def _setns(fd: int) -> None:
    if _libc().setns(fd, CLONE_NEWNET) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"setns(CLONE_NEWNET): {os.strerror(err)}")


def run_in_netns(ns: str, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``fn(*args, **kwargs)`` called in network namespace ``ns``; returns its result.

    The call runs in a new thread that joins the namespace and ends afterwards (switching back
    first), so no thread of the caller ever changes namespace.  Sockets made there stay there.
    """
    target = NETNS_DIR / ns
    outcome: dict[str, Any] = {}

    def body() -> None:
        try:
            home = os.open("/proc/thread-self/ns/net", os.O_RDONLY | os.O_CLOEXEC)
            try:
                fd = os.open(target, os.O_RDONLY | os.O_CLOEXEC)
                try:
                    _setns(fd)
                finally:
                    os.close(fd)
                try:
                    outcome["value"] = fn(*args, **kwargs)
                finally:
                    _setns(home)
            finally:
                os.close(home)
        except BaseException as exc:        # handed to the caller's thread
            outcome["error"] = exc

    thread = threading.Thread(target=body, name=f"netns-{ns}", daemon=True)
    thread.start()
    thread.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


def _disable_ipv6() -> None:
    """IPv6 off for all current and future interfaces of the calling thread's namespace."""
    for conf in ("all", "default"):
        path = Path(f"/proc/sys/net/ipv6/conf/{conf}/disable_ipv6")
        if path.exists():
            path.write_text("1\n")


# --------------------------------------------------------------------------- the rig

def _ip(*args: str, stdin: str | None = None) -> None:
    proc = subprocess.run(["ip", *args], input=stdin, capture_output=True, text=True,
                          timeout=20)
    if proc.returncode != 0:
        raise RuntimeError(f"`ip {' '.join(args)}` failed (exit {proc.returncode}): "
                           f"{proc.stderr.strip()}")


class VethRig:
    """Two namespaces and the veth pair between them; made by :func:`veth_pair`."""

    def __init__(self, ns_a: str, ns_b: str) -> None:
        self.ns_a, self.ns_b = ns_a, ns_b
        self.if_a, self.if_b = IF_A, IF_B
        self._procs: list[subprocess.Popen] = []
        self._links: list["RawLink"] = []

    def __repr__(self) -> str:
        return f"VethRig({self.ns_a}:{self.if_a} <-> {self.ns_b}:{self.if_b})"

    def iface_of(self, ns: str) -> str:
        return {self.ns_a: self.if_a, self.ns_b: self.if_b}[ns]

    def socket_in(self, ns: str, iface: str | None = None, **kwargs: Any) -> RawLink:
        """A RawLink on ``iface`` (default: the rig's end in ``ns``) opened inside ``ns``;
        closed when the rig goes away."""
        from ecatcfg.runtime.link import RawLink
        link = run_in_netns(ns, RawLink, iface or self.iface_of(ns), **kwargs)
        self._links.append(link)
        return link

    def popen_in(self, ns: str, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen:
        """``argv`` started inside ``ns`` (``ip netns exec``) in a session of its own; stopped
        with its process group when the rig goes away."""
        kwargs.setdefault("start_new_session", True)
        proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], **kwargs)
        self._procs.append(proc)
        return proc

    def run_in(self, ns: str, argv: Sequence[str], *, timeout: float = 20,
               input: str | bytes | None = None, **kwargs: Any) -> subprocess.CompletedProcess:
        """``argv`` run to completion inside ``ns``, output captured as text by default;
        killed with its children after ``timeout`` seconds (``subprocess.TimeoutExpired``)."""
        kwargs.setdefault("stdout", subprocess.PIPE)
        kwargs.setdefault("stderr", subprocess.PIPE)
        kwargs.setdefault("text", True)
        if input is not None:
            kwargs["stdin"] = subprocess.PIPE
        proc = self.popen_in(ns, argv, **kwargs)
        try:
            out, err = proc.communicate(input, timeout=timeout)
        except subprocess.TimeoutExpired:
            _stop(proc, grace=0)
            proc.communicate()
            raise
        return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)

    def close(self) -> None:
        errors = []
        for link in self._links:
            link.close()
        for proc in self._procs:
            _stop(proc)
        for ns in (self.ns_a, self.ns_b):
            # Anything still inside our private namespaces was started by this rig.
            try:
                pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True,
                                      text=True, timeout=10).stdout.split()
            except (OSError, subprocess.SubprocessError):
                pids = []
            for pid in pids:
                with contextlib.suppress(ProcessLookupError, ValueError):
                    os.kill(int(pid), signal.SIGKILL)
            if (NETNS_DIR / ns).exists():
                try:
                    _ip("netns", "del", ns)
                except RuntimeError as exc:
                    errors.append(str(exc))
        if errors:
            raise RuntimeError("; ".join(errors))


def _stop(proc: subprocess.Popen, grace: float = 2.0) -> None:
    """End a process the rig started, and its process group."""
    if proc.poll() is not None:
        return
    for sig in ((signal.SIGTERM, signal.SIGKILL) if grace > 0 else (signal.SIGKILL,)):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(sig)
        try:
            proc.wait(timeout=grace if sig == signal.SIGTERM else 10)
            return
        except subprocess.TimeoutExpired:
            continue


@contextlib.contextmanager
def serving(rig: VethRig, segment) -> Iterator:
    """``segment`` (a ``VirtualSegment``) answering frames on the rig's end in namespace B,
    in a thread of this process; stopped when the block ends."""
    link = rig.socket_in(rig.ns_b)
    stop = threading.Event()
    thread = threading.Thread(target=segment.serve, args=(link,), kwargs={"stop": stop},
                              daemon=True, name="segment-ns-b")
    thread.start()
    try:
        yield segment
    finally:
        stop.set()
        thread.join(5)


@contextlib.contextmanager
def veth_pair(prefix: str = "ecat") -> Iterator[VethRig]:
    """Two fresh network namespaces joined by a veth pair (see the module docstring)."""
    tag = f"{prefix}-{os.getpid()}-{secrets.token_hex(3)}"
    rig = VethRig(f"{tag}-a", f"{tag}-b")
    try:
        _ip("netns", "add", rig.ns_a)
        _ip("netns", "add", rig.ns_b)
        for ns in (rig.ns_a, rig.ns_b):
            run_in_netns(ns, _disable_ipv6)
        # Created directly inside the namespaces: names never clash with the host's.
        _ip("link", "add", IF_A, "netns", rig.ns_a, "type", "veth",
            "peer", "name", IF_B, "netns", rig.ns_b)
        for ns, iface in ((rig.ns_a, IF_A), (rig.ns_b, IF_B)):
            _ip("-n", ns, "-batch", "-", stdin=f"link set lo up\nlink set {iface} up\n")
        yield rig
    finally:
        rig.close()


@pytest.fixture
def veth_netns() -> Iterator[VethRig]:
    """A :class:`VethRig`; skips/fails via :func:`require_netns` when unavailable."""
    require_netns()
    with veth_pair() as rig:
        yield rig


@pytest.fixture(scope="session")
def tshark_path() -> str:
    return require_tshark()


@pytest.fixture(scope="session")
def pysoem_module():
    return require_pysoem()


# --------------------------------------------------------------------------- tshark

class TsharkError(RuntimeError):
    """tshark exited with an error (e.g. an unknown field name); carries its stderr."""


def _tshark(pcap: str | os.PathLike, *args: str, timeout: float = 60) -> list[dict]:
    tshark = require_tshark()
    cmd = [tshark, "-n", "-r", os.fspath(pcap), "-T", "json", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    stderr = "\n".join(line for line in proc.stderr.splitlines()
                       if not line.startswith("Running as user"))
    if proc.returncode != 0:
        raise TsharkError(f"tshark exited with {proc.returncode} on {os.fspath(pcap)}: "
                          f"{stderr.strip() or '(no message)'}\n  command: {' '.join(cmd)}")
    return json.loads(proc.stdout) if proc.stdout.strip() else []


def tshark_fields(pcap: str | os.PathLike, fields: Sequence[str], *,
                  display_filter: str | None = None) -> list[dict[str, list[str]]]:
    """The values of ``fields`` for every packet of ``pcap``, in one tshark run.

    One dict per packet (in file order, after ``display_filter``): field name → list of the
    values tshark shows, one per occurrence (so a frame with 2 datagrams gives 2 ``ecat.cmd``
    values); ``[]`` when the packet lacks the field.  Values are tshark's text ("0x07", "1").
    An unknown field name raises :class:`TsharkError` (tshark refuses to run).
    """
    if isinstance(fields, str):
        raise TypeError("fields must be a list of field names, not one string")
    args = [arg for field in fields for arg in ("-e", field)]
    if display_filter:
        args += ["-Y", display_filter]
    packets = _tshark(pcap, *args)
    return [{field: list(p["_source"]["layers"].get(field, [])) for field in fields}
            for p in packets]


def soe_messages(pcap: str | os.PathLike) -> list[tuple[int, int, bool, bool, int, bytes]]:
    """Every SoE message tshark decodes in ``pcap``, once each and in order: (op code,
    drive, incomplete, error, IDN or fragments left, data).

    Only the frames as they came back count (the first ESC sets the locally administered
    bit of the source address): they hold every message, the SM0 writes unchanged and the
    SM1 reads filled, where the frames going out hold the writes again.  A frame may carry
    several messages (the read of an answer and, behind it, the next request: the master's
    requests ahead), in order.  tshark shows data for write requests and read responses
    (op codes 3 and 2) only."""
    fields = ["eth.src", "ecat_mailbox.soe_opcode", "ecat_mailbox.soe_header_driveno",
              "ecat_mailbox.soe_header_incomplete", "ecat_mailbox.soe_header_error",
              "ecat_mailbox.soe_idn", "ecat_mailbox.soe_frag", "ecat_mailbox.soe_data"]
    out = []
    for p in tshark_fields(pcap, fields, display_filter="ecat_mailbox.soe"):
        src, ops, drives, incompletes, errors, idns, frags, datas = p.values()
        if not int(src[0][:2], 16) & 0x02:
            continue
        idn_or_frag = {False: iter(idns), True: iter(frags)}
        data = iter(datas)
        for op, drive, incomplete, error in zip(ops, drives, incompletes, errors):
            fragment = incomplete in ("1", "True")
            text = next(data) if op in ("2", "3") else ""
            out.append((int(op), int(drive), fragment, error in ("1", "True"),
                        int(next(idn_or_frag[fragment]), 0),
                        bytes.fromhex(text.replace(":", ""))))
    return out


def tshark_malformed(pcap: str | os.PathLike) -> list[dict[str, Any]]:
    """Packets of ``pcap`` that tshark finds malformed, with an expert error, or with an
    EtherCAT mailbox/CoE 'invalid' marker: ``[{"frame": N, "messages": [...]}]``, ``[]`` when
    all is well.  Note that tshark does not check the EtherCAT header length against the
    datagrams; tests must check lengths themselves."""
    flt = ('_ws.malformed || _ws.expert.severity >= "Error" || ecat_mailbox.invalid '
           '|| ecat_mailbox.coe.invalid')
    packets = _tshark(pcap, "-Y", flt, "-e", "frame.number", "-e", "_ws.expert.message",
                      "-e", "_ws.malformed")
    out = []
    for p in packets:
        layers = p["_source"]["layers"]
        messages = list(layers.get("_ws.expert.message", [])) or \
            [m for m in layers.get("_ws.malformed", []) if m != "_ws.malformed"] or \
            ["invalid EtherCAT mailbox"]
        out.append({"frame": int(layers["frame.number"][0]), "messages": messages})
    return out


def serve_in_memory(segment, clock=None, *, wallclock: bool = False
                    ) -> tuple[Any, Callable[[], None]]:
    """``segment`` behind an in-memory link: (the master's end of the link, a function that
    stops what serves it).  On simulated time by default: the segment on ``clock`` (a
    fresh ``SimClock`` if none) behind a simulated wire (``runtime/simwire.py``), no thread,
    nothing to stop; a ``Transport`` on the link takes its clock.  ``wallclock``: the
    segment on the host's clock behind a ``SynchronousLink`` (answered in the sending
    thread, as ``Network.virtual`` does without a clock), where real time is the point."""
    from ecatcfg.runtime.simwire import SimulatedLink, SynchronousLink

    if not wallclock:
        from ecatcfg.runtime.clock import SimClock
        clock = clock or SimClock()
        segment.set_clock(clock.monotonic_ns)
        return SimulatedLink(clock, segment), lambda: None
    return SynchronousLink(segment), lambda: None


def start_simulate(rig: VethRig, *args: str, duration: float = 60) -> tuple[
        subprocess.Popen, list[str]]:
    """``ecatcfg simulate ARGS --iface`` on the rig's B end (its namespace), read until it
    prints ``ready:``: (the process, the lines it printed up to that one).  The last line
    is not ``ready:`` when simulate ended first; callers assert on it (and may read
    ``stderr``).  The rig stops the process when it goes away."""
    from installed import ECATCFG

    sim = rig.popen_in(rig.ns_b, [*ECATCFG, "simulate", *args,
                                  "--iface", rig.if_b, "--duration", str(duration),
                                  "--no-cache"],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    assert sim.stdout is not None
    for line in sim.stdout:
        lines.append(line)
        if line.startswith("ready:"):
            break
    return sim, lines
