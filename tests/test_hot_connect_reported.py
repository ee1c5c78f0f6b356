"""A hot-connect group that comes and goes is reported as a hot-connect event about its
head, each time: absent at start-up, on the line again, gone (runtime/master/recovery.py).
The line runs on simulated time: the bounds are its clock's, not the host's."""

from __future__ import annotations

from test_recovery import BOUND_S, grouped_network, grouped_segment, plan, with_group  # noqa: F401

from ecatcfg.esc import AlState


def test_the_group_coming_and_going_is_reported_about_its_head(plan):  # noqa: F811
    grouped = with_group(plan, "lamps", 2)             # lamps and the drive behind it
    seg = grouped_segment(grouped, "lamps")
    seg.remove_cable("lamps")
    with grouped_network(grouped, seg, "memory") as (net, events):
        net.up()
        assert net.state == AlState.OP
        seg.restore_cable("lamps")
        start = net.clock.monotonic()
        while not (net.online("lamps") and net.online("axis1")):
            assert net.clock.monotonic() - start < BOUND_S
            net.cycle()
            net.clock.sleep(0.0005)
        seg.remove_cable("lamps")
        start = net.clock.monotonic()
        while net.online("lamps"):
            assert net.clock.monotonic() - start < BOUND_S
            net.cycle()
    assert [(e.kind, e.slave, e.text) for e in events if "hot-connect group" in e.text] == [
        ("hot-connect", "lamps",
         "hot-connect group 'lamps' (2 slaves) is not on the line; the others go on"),
        ("hot-connect", "lamps", "hot-connect group 'lamps' is on the line; bringing it up"),
        ("hot-connect", "lamps",
         "hot-connect group 'lamps' (2 slaves) left the line; the others go on")]
