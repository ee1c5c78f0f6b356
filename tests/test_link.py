"""Frame links (runtime/link.py), the network-namespace rig (tests/rig.py) and CI set-up.

MemoryLink tests run everywhere.  RawLink, pysoem and tshark tests need root (network
namespaces), pysoem and tshark: they skip locally without them and fail in CI
(ECATCFG_REQUIRE_RUNTIME=1 or CI=true).
"""

from __future__ import annotations

import json
import logging
import os
import re
import select
import shutil
import socket
import subprocess
import sys
import threading
import time

import prereq
import pytest
import rig
from conftest import ROOT

from ecatcfg.errors import EcatcfgError, UsageError
from ecatcfg.esc import ETHERTYPE
from ecatcfg.runtime.link import Link, LinkError, MemoryLink, RawLink, pad60

BROADCAST = b"\xff" * 6
SRC = bytes.fromhex("020000000001")


def frame(payload: bytes = b"", ethertype: int = ETHERTYPE, src: bytes = SRC) -> bytes:
    return BROADCAST + src + ethertype.to_bytes(2, "big") + payload


def numbered(i: int, size: int = 30) -> bytes:
    """A ``size``-byte EtherCAT-typed frame carrying ``i``."""
    return frame(i.to_bytes(4, "big")).ljust(size, b"\0")


# --------------------------------------------------------------------------- CI and README

def readme_test_command() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Set-up: two commands", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```sh\n(.*?)\n```", section, re.S)
    assert len(blocks) == 2, "the set-up section has two shell commands"
    assert "\n" not in blocks[1].strip(), "the second command is one copy-pasteable line"
    return blocks[1].strip()


def test_ci_runs_the_readme_test_command_verbatim():
    command = readme_test_command()
    assert "apt-get install -y tshark" in command and '".[test]"' in command
    assert "chromium" in command          # the report tests' browser (tests/test_report.py)
    assert command.endswith("python3 -m pytest")
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert command in ci, ".ci/run must run exactly the README's second set-up command"
    assert "export ECATCFG_REQUIRE_RUNTIME=1" in ci
    assert "export ECATCFG_REQUIRE_CORPUS=1" in ci
    assert "export ECATCFG_REQUIRE_TOOLS=1" in ci
    for kind in prereq.KINDS:
        assert ci.index(f"export {kind}=1") < ci.index(command)


def test_ci_runs_the_newest_allowed_versions_after_the_locked_run(tmp_path):
    """The second step: .ci/newest, after the README's (locked) command, only when that one
    passed; it installs without the lock, upgrading every dependency, into a venv of its
    own, and runs pytest with the arguments given."""
    command = readme_test_command()
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert ".ci/newest" in ci and ci.index(command) < ci.index(".ci/newest")
    newest = ROOT / ".ci" / "newest"
    assert os.access(newest, os.X_OK)
    script = newest.read_text()
    install = next(line for line in script.splitlines() if "-e \".[test]\"" in line)
    assert "--upgrade-strategy eager" in install and "test-lock" not in install
    assert "python3 -m venv" in script and '-m pytest "$@"' in script
    assert ".ci/newest" in (ROOT / "README.md").read_text()
    # The locked step's failure stops CI before the second one, wherever in the README's
    # && list it fails (set -e alone stops only on the list's last command): .ci/run run
    # with a python3 whose pip fails, in a copy of the checkout's .ci.
    (tmp_path / ".ci").mkdir()
    for name in ("run", "newest"):
        (tmp_path / ".ci" / name).write_text((ROOT / ".ci" / name).read_text())
        (tmp_path / ".ci" / name).chmod(0o755)
    (tmp_path / ".ci" / "newest").write_text(f"#!/bin/sh\ntouch {tmp_path}/ran-newest\n")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("python3", "tshark", "chromium"):
        (bin_dir / tool).write_text("#!/bin/sh\nexit 3\n" if tool == "python3" else
                                    "#!/bin/sh\nexit 0\n")
        (bin_dir / tool).chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}"}
    done = subprocess.run([str(tmp_path / ".ci" / "run")], env=env, capture_output=True,
                          timeout=30)
    assert done.returncode == 3 and not (tmp_path / "ran-newest").exists()


def test_missing_prerequisites_skip_locally_and_fail_in_ci(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.delenv(rig.REQUIRE_ENV, raising=False)
    with pytest.raises(pytest.skip.Exception, match="tshark unavailable: gone"):
        rig.unavailable("tshark", "gone")
    for var, value in ((rig.REQUIRE_ENV, "1"), ("CI", "true")):
        with monkeypatch.context() as m:
            m.setenv(var, value)
            with pytest.raises(pytest.fail.Exception, match="required in CI"):
                rig.unavailable("tshark", "gone")


@pytest.mark.parametrize("kind", prereq.KINDS)
def test_every_kind_of_prerequisite_skips_by_name_locally_and_fails_in_ci(monkeypatch, kind):
    for other in prereq.KINDS + ("CI",):
        monkeypatch.delenv(other, raising=False)
    with pytest.raises(pytest.skip.Exception, match=f"a thing unavailable: gone .*{kind}=1"):
        prereq.missing("a thing", "gone", kind)
    for other in prereq.KINDS:                     # another kind's variable does not count
        if other != kind:
            monkeypatch.setenv(other, "1")
    with pytest.raises(pytest.skip.Exception):
        prereq.missing("a thing", "gone", kind)
    for var, value in ((kind, "1"), ("CI", "true")):
        with monkeypatch.context() as m:
            m.setenv(var, value)
            with pytest.raises(pytest.fail.Exception, match="a thing is required in CI"):
                prereq.missing("a thing", "gone", kind)


# --------------------------------------------------------------------------- MemoryLink

def test_memory_pair_delivers_in_order_both_ways():
    a, b = MemoryLink.pair()
    with a, b:
        assert isinstance(a, Link) and isinstance(b, Link)
        for i in range(5):
            a.send(numbered(i))
        b.send(numbered(99))
        assert [b.recv(0) for _ in range(5)] == [numbered(i) for i in range(5)]
        assert a.recv(0) == numbered(99)
        assert a.recv(0) is None and b.recv(0) is None


def test_memory_recv_times_out_with_none():
    a, b = MemoryLink.pair()
    start = time.monotonic()
    assert b.recv(0.05) is None
    assert 0.05 <= time.monotonic() - start < 1.0
    assert b.recv_many(10, 0.01) == []


def test_memory_link_is_bounded_and_counts_drops():
    a, b = MemoryLink.pair(capacity=8)
    for i in range(13):
        a.send(numbered(i))
    assert len(b) == 8 and b.dropped == 5
    assert b.recv_many(100, 0) == [numbered(i) for i in range(8)]
    assert b.recv(0) is None


def test_memory_link_checks_frame_size_like_a_nic():
    a, b = MemoryLink.pair()
    a.send(frame(bytes(1500)))
    assert len(b.recv(0)) == 1514
    with pytest.raises(LinkError, match="frame of 1515 bytes is too large for the MTU of 1500"):
        a.send(frame(bytes(1501)))
    with pytest.raises(LinkError, match="shorter than an Ethernet header"):
        a.send(b"\x01" * 13)


def test_memory_fileno_is_readable_exactly_while_frames_wait():
    a, b = MemoryLink.pair()
    b.send(numbered(1))             # queued before anyone asked for the descriptor
    fd = a.fileno()
    assert select.select([fd], [], [], 0)[0] == [fd]
    assert a.recv(0) == numbered(1)
    assert select.select([fd], [], [], 0)[0] == []
    b.send(numbered(2))
    b.send(numbered(3))
    assert select.select([fd], [], [], 0)[0] == [fd]
    assert a.recv_many(10, 0) == [numbered(2), numbered(3)]
    assert select.select([fd], [], [], 0)[0] == []
    threading.Timer(0.02, b.send, (numbered(4),)).start()
    assert select.select([fd], [], [], 2)[0] == [fd]
    a.close()
    b.close()


def test_memory_link_concurrent_senders_and_receivers():
    a, b = MemoryLink.pair(capacity=100_000)
    senders, per_sender = 4, 2000
    got: list[list[bytes]] = [[], []]
    sent = threading.Event()

    def send(s: int) -> None:
        for i in range(per_sender):
            a.send(numbered(s * 1_000_000 + i))

    def receive(k: int) -> None:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            f = b.recv(0.02)
            if f is not None:
                got[k].append(f)
            elif sent.is_set() and not len(b):
                return

    receivers = [threading.Thread(target=receive, args=(k,)) for k in range(2)]
    senders_ = [threading.Thread(target=send, args=(s,)) for s in range(senders)]
    for t in receivers + senders_:
        t.start()
    for t in senders_:
        t.join(10)
    sent.set()
    for t in receivers:
        t.join(10)
    assert not any(t.is_alive() for t in receivers + senders_)
    values = [int.from_bytes(f[14:18], "big") for f in got[0] + got[1]]
    assert sorted(values) == sorted(s * 1_000_000 + i for s in range(senders)
                                    for i in range(per_sender))
    assert b.dropped == 0
    for k in range(2):              # each receiver saw every sender's frames in order
        mine = [int.from_bytes(f[14:18], "big") for f in got[k]]
        for s in range(senders):
            seq = [v for v in mine if v // 1_000_000 == s]
            assert seq == sorted(seq)


def test_memory_link_close():
    a, b = MemoryLink.pair()
    waiter: list[BaseException] = []

    def wait() -> None:
        try:
            b.recv(None)
        except LinkError as exc:
            waiter.append(exc)

    t = threading.Thread(target=wait)
    t.start()
    time.sleep(0.02)
    b.close()                       # wakes the blocked receiver
    t.join(2)
    assert not t.is_alive() and "closed" in str(waiter[0])
    a.send(numbered(1))             # nobody at the other end: the frame is lost
    with pytest.raises(LinkError, match="closed"):
        b.recv(0)
    with pytest.raises(LinkError, match="closed"):
        b.send(numbered(1))
    b.close()                       # idempotent
    a.close()


def test_pad60():
    assert pad60(frame(bytes(16))) == frame(bytes(16)) + bytes(30)
    assert len(pad60(frame())) == 60
    big = frame(bytes(100))
    assert pad60(big) is big


def test_rawlink_without_privileges_says_what_is_needed(monkeypatch):
    def refuse(*args, **kwargs):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(socket, "socket", refuse)
    with pytest.raises(UsageError, match=r"eth7: .*needs root or the CAP_NET_RAW capability"):
        RawLink("eth7")


# --------------------------------------------------------------------------- RawLink on veth

def test_rig_namespaces_and_links(veth_netns):
    r = veth_netns
    ours = os.readlink("/proc/thread-self/ns/net")
    inside = rig.run_in_netns(r.ns_a, os.readlink, "/proc/thread-self/ns/net")
    assert inside != ours
    a, b = r.socket_in(r.ns_a), r.socket_in(r.ns_b)
    assert os.readlink("/proc/thread-self/ns/net") == ours      # the test never moved
    names = {os.readlink(f"/proc/self/task/{t}/ns/net") for t in os.listdir("/proc/self/task")}
    assert names == {ours}                                       # nor did any other thread
    assert (a.iface, b.iface, a.mtu) == ("va", "vb", 1500)
    ipv6 = r.run_in(r.ns_b, ["cat", "/proc/sys/net/ipv6/conf/vb/disable_ipv6"], timeout=10)
    assert ipv6.stdout.strip() in ("1", "")


def test_rawlink_both_ways_short_frames_unpadded(veth_netns):
    r = veth_netns
    a, b = r.socket_in(r.ns_a), r.socket_in(r.ns_b)
    short = numbered(7, size=30)
    a.send(short)
    assert b.recv(2) == short                   # 30 bytes in, 30 bytes out: veth does not pad
    b.send(pad60(numbered(8)))
    assert a.recv(2) == pad60(numbered(8))
    assert a.recv(0.05) is None and b.recv(0.05) is None       # no echo of our own frames


def test_rawlink_does_not_receive_outgoing_copies(veth_netns):
    r = veth_netns
    a, a2 = r.socket_in(r.ns_a), r.socket_in(r.ns_a)           # two sockets on one interface
    b = r.socket_in(r.ns_b)
    a.send(numbered(1))
    assert b.recv(2) == numbered(1)
    assert a.recv(0.05) is None and a2.recv(0) is None
    b.send(numbered(2))
    assert a.recv(2) == numbered(2) and a2.recv(2) == numbered(2)


def test_rawlink_mtu_limit(veth_netns):
    r = veth_netns
    a, b = r.socket_in(r.ns_a), r.socket_in(r.ns_b)
    full = frame(bytes(range(256)) * 5 + bytes(220))
    assert len(full) == 1514
    a.send(full)
    assert b.recv(2) == full
    with pytest.raises(LinkError) as err:
        a.send(full + b"\0")
    assert str(err.value) == ("va: frame of 1515 bytes is too large for the MTU of 1500 bytes "
                              "(at most 1514 bytes per frame, Ethernet header included)")
    with pytest.raises(LinkError, match="shorter than an Ethernet header"):
        a.send(b"\xff" * 10)


def test_rawlink_receives_only_ethercat_frames(veth_netns):
    r = veth_netns
    a, b = r.socket_in(r.ns_a), r.socket_in(r.ns_b)
    for ethertype in (0x0800, 0x86DD, 0x88B5, 0x8100):
        a.send(frame(bytes(46), ethertype=ethertype))
    a.send(numbered(5))
    assert b.recv(2) == numbered(5)
    assert b.recv(0.05) is None


def test_rawlink_recv_many_and_timeout(veth_netns):
    r = veth_netns
    a, b = r.socket_in(r.ns_a), r.socket_in(r.ns_b)
    start = time.monotonic()
    assert b.recv(0.03) is None and b.recv_many(5, 0.0) == []
    assert time.monotonic() - start >= 0.03
    for i in range(20):
        a.send(numbered(i))
    got = []
    deadline = time.monotonic() + 2
    while len(got) < 20 and time.monotonic() < deadline:
        got += b.recv_many(8, 0.5)
    assert got == [numbered(i) for i in range(20)]
    assert select.select([b], [], [], 0)[0] == []


def test_rawlink_missing_interface_is_named(veth_netns):
    with pytest.raises(UsageError, match=r"no such network interface: 'ecatnope0' "
                                         r"\(interfaces here: lo, va\)"):
        veth_netns.socket_in(veth_netns.ns_a, "ecatnope0")


def test_rawlink_without_cap_net_raw_in_a_real_process(veth_netns):
    if shutil.which("setpriv") is None:
        rig.unavailable("setpriv (util-linux)", "not on PATH")
    code = ("from ecatcfg.runtime.link import RawLink\n"
            "try:\n    RawLink('va')\nexcept Exception as e:\n    print(type(e).__name__, e)\n")
    out = veth_netns.run_in(veth_netns.ns_a, ["setpriv", "--bounding-set=-net_raw",
                                              "--inh-caps=-net_raw", sys.executable, "-c", code],
                            timeout=20)
    assert out.stdout.strip() == ("UsageError va: opening a raw Ethernet socket needs root or "
                                  "the CAP_NET_RAW capability (Operation not permitted)"), out


def test_rig_cleans_up_after_a_failing_test():
    rig.require_netns()
    with pytest.raises(RuntimeError, match="boom"):
        with rig.veth_pair() as r:
            sleeper = r.popen_in(r.ns_b, ["sleep", "60"])
            link = r.socket_in(r.ns_a)
            raise RuntimeError("boom")
    assert sleeper.wait(5) is not None
    assert not (rig.NETNS_DIR / r.ns_a).exists() and not (rig.NETNS_DIR / r.ns_b).exists()
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert r.ns_a not in names and r.ns_b not in names
    with pytest.raises(EcatcfgError, match="closed"):
        link.recv(0)


# --------------------------------------------------------------------------- pysoem, tshark

PYSOEM_PROBE = """
import json, time, pysoem
m = pysoem.Master()
m.open({iface!r})
t = time.monotonic()
n = m.config_init()
dt = time.monotonic() - t
adapters = [a.name for a in pysoem.find_adapters()]
m.close()
print(json.dumps({{"slaves": n, "seconds": dt, "adapters": adapters}}))
"""


def test_pysoem_runs_inside_a_namespace(veth_netns, pysoem_module):
    r = veth_netns
    out = r.run_in(r.ns_a, [sys.executable, "-c", PYSOEM_PROBE.format(iface=r.if_a)],
                   timeout=20)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["slaves"] <= 0                # nothing answers on the other side
    assert r.if_a in result["adapters"]


@pytest.fixture(scope="module")
def ecat_pcap(tmp_path_factory):
    """Two EtherCAT frames (BRD; FPWR AL control + BRD) and a truncated third one."""
    logging.getLogger("scapy.runtime").setLevel(logging.CRITICAL)
    from scapy.contrib.ethercat import EtherCat, EtherCatBRD, EtherCatFPWR
    from scapy.layers.l2 import Ether
    from scapy.utils import wrpcap

    eth = Ether(dst="ff:ff:ff:ff:ff:ff", src="02:00:00:00:00:01", type=ETHERTYPE)
    good = [eth / EtherCat() / EtherCatBRD(idx=1, adp=0, ado=0, len=2, data=[0, 0]),
            eth / EtherCat() / EtherCatFPWR(idx=2, adp=0x1001, ado=0x0120, len=2, data=[2, 0])
            / EtherCatBRD(idx=3, adp=0, ado=0x0130, len=2, data=[0, 0], wkc=1)]
    raw = [bytes(p) for p in good]
    truncated = raw[0][:14] + bytes([0x40, 0x10]) + raw[0][16:20]   # claims 64 bytes, has 4
    folder = tmp_path_factory.mktemp("pcap")
    wrpcap(str(folder / "good.pcap"), [Ether(b) for b in raw])
    wrpcap(str(folder / "bad.pcap"), [Ether(b) for b in raw + [truncated]])
    return folder


def test_tshark_reads_fields_back(ecat_pcap, tshark_path):
    fields = ["frame.number", "ecatf.length", "ecat.cmd", "ecat.idx", "ecat.adp", "ecat.ado",
              "ecat.cnt", "ecat.reg.alctrl"]
    rows = rig.tshark_fields(ecat_pcap / "good.pcap", fields)
    assert [r["frame.number"] for r in rows] == [["1"], ["2"]]
    assert rows[0]["ecat.cmd"] == ["0x07"] and rows[0]["ecat.reg.alctrl"] == []
    assert rows[1]["ecat.cmd"] == ["0x05", "0x07"]
    assert rows[1]["ecat.idx"] == ["0x02", "0x03"]
    assert rows[1]["ecat.adp"] == ["0x1001", "0x0000"]
    assert rows[1]["ecat.ado"] == ["0x0120", "0x0130"]
    assert rows[1]["ecat.cnt"] == ["0", "1"]
    assert int(rows[1]["ecat.reg.alctrl"][0], 0) == 2


def test_tshark_unknown_field_is_an_error(ecat_pcap, tshark_path):
    with pytest.raises(rig.TsharkError, match="ecat.len"):
        rig.tshark_fields(ecat_pcap / "good.pcap", ["frame.number", "ecat.len"])


def test_tshark_malformed(ecat_pcap, tshark_path):
    assert rig.tshark_malformed(ecat_pcap / "bad.pcap") == [
        {"frame": 3, "messages": ["Malformed Packet (Exception occurred)"]}]
