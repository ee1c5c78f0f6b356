"""bench/soe.py counts the mailbox frames it reports from the frames themselves, and its
in-memory transfers of a list IDN in fragments check what they measure: the fragment
counts are ETG.1000.6's (data of SM size - 10 per fragment, worked out by hand here) and
the list read back is the one written.  Frame counts only; nothing here is timed."""

from __future__ import annotations

import sys
from types import ModuleType

import pytest

from conftest import ROOT
from ecatcfg.runtime.wire import Datagram, encode

SM0, SM1 = 0x1800, 0x1880
FPWR, FPRD, LRW, BRD = 5, 4, 12, 7


@pytest.fixture
def soe_bench(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(ROOT / "bench"))      # its own imports: startup, ...
    monkeypatch.delitem(sys.modules, "soe", raising=False)
    import soe as module
    return module


def test_the_census_counts_sm0_writes_sm1_reads_and_the_messages_sm1_gave(soe_bench):
    census = soe_bench.MailboxCensus(SM0, SM1)
    write = [Datagram.physical(FPWR, 0x1001, SM0, bytes(128))]
    poll = [Datagram.physical(FPRD, 0x1001, SM1, 128)]
    mixed = [Datagram.logical(LRW, 0, 8), Datagram.physical(FPRD, 0x1001, SM1, 128),
             Datagram.physical(BRD, 0, 0x0130, 2)]
    for datagrams, wkc in ((write, 1), (poll, 0), (poll, 1), (mixed, 1)):
        census(encode(datagrams), True)
        for dg in datagrams:
            dg.wkc = wkc                     # the reply: an empty SM1 is read with WKC 0
        census(encode(datagrams), False)
    assert census.count(0) == {"frames": 4, "sm0 writes": 1, "sm1 reads": 3,
                               "sm1 messages": 2}
    assert census.count(2)["frames"] == 3    # from the third recorded frame (the first poll)


def test_fragments_are_those_of_the_mailbox_size(soe_bench):
    # 128-byte mailbox: 118 data bytes a fragment; 1024-byte mailbox: 1014.
    assert [soe_bench.fragments(n, 128) for n in (2, 118, 119, 1024, 4096)] == [1, 1, 2, 9, 35]
    assert [soe_bench.fragments(n, 1024) for n in (1014, 1015, 4096)] == [1, 2, 5]


def test_a_list_idn_goes_in_fragments_at_the_frame_minimum(soe_bench):
    res = soe_bench.transfers([1024], [128], repeat=1)
    write, read = res["mbx 128, write 1024 B"], res["mbx 128, read 1024 B"]
    # 9 SM0 writes and the one SM1 read of the drive's answer; 1 SM0 write and 9 SM1 reads.
    assert (write["fragments"], write["frames"], write["sm1 reads"]) == (9, 10, 1)
    assert (read["fragments"], read["frames"], read["sm1 reads"]) == (9, 10, 9)
    # ecatcfg soe writes in fragments after an attribute read (soe_tool.py): 2 frames more.
    assert write["tool_session_frames"] - read["tool_session_frames"] == 2
