"""The in-memory master/segment pair on the wall clock (runtime/simwire.py,
``SynchronousLink``): the slaves answer in the sending thread, so a host that does not
schedule a thread in time loses no frame; time-based behaviour still follows real time
(the slaves catch up with the wall clock before each frame)."""

from __future__ import annotations

import sys
import threading
import time

import pytest

from conftest import EXAMPLES
from ecatcfg.compiler import build, topology
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.plan import NetworkPlan
from ecatcfg.esc import AlState, Cmd, Reg
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network
from ecatcfg.runtime.clock import WALL
from ecatcfg.runtime.link import LinkError
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.segment.virtual import Faults
from ecatcfg.runtime.simwire import SynchronousLink
from ecatcfg.runtime.wire import Datagram, decode, encode

pytestmark = pytest.mark.wallclock

ESI = EXAMPLES / "esi"
BRD = [Datagram.physical(Cmd.BRD, 0, Reg.AL_STATUS, bytes(2))]


@pytest.fixture(scope="module")
def plan() -> NetworkPlan:
    built = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                   Library([ESI], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(built), "example.eni.xml")


def test_the_reply_is_back_when_send_returns(plan):
    """No other thread has to run for a frame to be answered: a look without waiting
    right after the send finds the reply, with every slave's working counter."""
    with Network.virtual(plan, esi=[ESI]) as net:
        link = net.link
        assert isinstance(link, SynchronousLink) and net.clock is WALL
        for _ in range(20):
            link.send(encode(BRD))
            reply = link.recv(0)
            assert reply is not None
            assert decode(reply).datagrams[0].wkc == len(net.segment.slaves) == 5
        assert link.recv(0) is None                 # one reply per frame, no more


def test_a_busy_interpreter_loses_no_frame(plan):
    """Another thread keeps the interpreter busy and holds the GIL 50 ms at a time (more
    than the 20 ms frame timeout): the start-up and 300 cycles lose no frame.  A segment
    served on a thread of its own waits for the GIL that long before it answers, and the
    master counts those frames lost.  (Working-counter errors may come: the master's own
    thread waits that long between two cycles too, and an SM watchdog of 100 ms can
    expire, as on a real line whose master stalls.)"""
    stop = threading.Event()

    def spin() -> None:
        x = 0
        while not stop.is_set():
            x += 1
    interval = sys.getswitchinterval()
    spinner = threading.Thread(target=spin, daemon=True)
    sys.setswitchinterval(0.05)
    spinner.start()
    try:
        with Network.virtual(plan, esi=[ESI]) as net:
            net.up()
            assert net.master.transport.counters.frames_lost == 0
            net.run(300)
            stats = net.run_stats
    finally:
        stop.set()
        sys.setswitchinterval(interval)
        spinner.join(5)
    assert stats is not None and stats.cycles == 300
    assert stats.lost_frames == 0, stats


def test_a_watchdog_expires_in_real_time_without_frames(plan):
    """The slaves live on the wall clock: after more than the SM watchdog's 100 ms of real
    silence, the next frame finds the output slave in SAFEOP+ERR 0x001B (caught up before
    the frame is processed, as its firmware would have done in the meantime)."""
    with Network.virtual(plan, esi=[ESI], recovery=False) as net:
        net.up()
        lamps = next(s for s in net.segment.slaves if s.name == "lamps")
        for _ in range(5):
            net.cycle()
        assert lamps.state == AlState.OP and not lamps.error
        time.sleep(0.15)                # longer on a busy host: expired all the same
        net.cycle()
        assert (lamps.state, lamps.error, lamps.status_code) == (AlState.SAFEOP, True, 0x001B)


def test_only_the_faults_lose_or_delay_a_frame(plan):
    """A dropped frame is never answered (the transport waits its timeout and counts it);
    a delayed reply comes back its delay later, in real time."""
    with Network.virtual(plan, esi=[ESI], faults=Faults(drop=1.0)) as net:
        transport = Transport(net.link)
        while transport.counters.frames_lost < 2:      # drop 1.0: three in four lost
            start = time.monotonic()
            if transport.exchange(BRD, timeout=0.02) is None:
                assert time.monotonic() - start >= 0.02
    with Network.virtual(plan, esi=[ESI], faults=Faults(delay=1.0, delay_s=0.05)) as net:
        link = net.link
        start = time.monotonic()
        link.send(encode(BRD))
        assert link.recv(0) is None                 # not back yet
        reply = link.recv(5)
        assert reply is not None and time.monotonic() - start >= 0.05


def test_another_thread_takes_the_reply_and_close_wakes_it(plan):
    """A thread waiting in recv gets the reply of a frame another thread sends (the link
    is shared under its lock); closing the link ends a wait with nothing on its way."""
    with Network.virtual(plan, esi=[ESI]) as net:
        link = net.link
        got: list[object] = []
        waiter = threading.Thread(target=lambda: got.append(link.recv(None)))
        waiter.start()
        time.sleep(0.05)
        link.send(encode(BRD))
        waiter.join(10)
        assert isinstance(got[0], bytes) and decode(got[0]).datagrams[0].wkc == 5

        def wait_closed() -> None:
            try:
                link.recv(None)
            except LinkError as exc:
                got.append(exc)
        waiter = threading.Thread(target=wait_closed)
        waiter.start()
        time.sleep(0.05)
        link.close()
        waiter.join(10)
        assert isinstance(got[-1], LinkError)


def test_a_reply_back_by_the_deadline_is_not_a_lost_frame(plan):
    """The transport looks once more when its deadline has passed: with no time at all to
    wait (a master thread descheduled from its send to past its deadline looks the same),
    the reply that is already back is taken, on both of its paths."""
    with Network.virtual(plan, esi=[ESI]) as net:
        transport = Transport(net.link)
        got = transport.exchange(BRD, timeout=0)
        assert got is not None and got[0].wkc == 5
        net.up()
        master = net.master
        lost = master.transport.counters.frames_lost
        for _ in range(3):                  # the cyclic frames: exchange_prepared
            assert master.cyclic.exchange(master.transport, master.state, timeout=0)
        assert master.transport.counters.frames_lost == lost
