"""Frame links: how the master and the virtual segment put whole Ethernet frames on a wire.

A link moves complete Ethernet frames (destination MAC, source MAC, EtherType, payload; no FCS)
and nothing else: no parsing, no padding, no scapy.  This is the per-frame hot path.

- :class:`RawLink`: an ``AF_PACKET``/``SOCK_RAW`` socket bound to one interface and EtherType
  0x88A4 (a NIC, or one end of a veth pair).  It never returns the copies of frames sent on the
  same interface (``PACKET_OUTGOING``), accepts frames shorter than 60 bytes (veth does not pad)
  and sends bytes exactly as given (use :func:`pad60` to pad the way a NIC would).
- :class:`MemoryLink`: an in-memory, thread-safe pair of ends for unit tests of the master and
  the virtual segment without sockets or privileges.

Both have ``fileno()`` for ``select``/``poll``: it is readable while a frame is waiting.
``recv(timeout)`` waits at most ``timeout`` seconds (``None``: forever, ``0``: just look) and
returns ``None`` when nothing came.  Errors a user can cause (a missing interface, no
privileges, a frame larger than the MTU, a closed link) raise :class:`LinkError` or
:class:`~ecatcfg.errors.UsageError` with a one-line message naming the interface.
"""

from __future__ import annotations

import errno
import fcntl
import functools
import os
import select
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Protocol, Self, runtime_checkable

from ..errors import EcatcfgError, UsageError
from ..esc import ETH_HEADER_SIZE, ETHERTYPE, MIN_FRAME

__all__ = ["Link", "RawLink", "MemoryLink", "LinkError", "pad60", "ETH_HEADER_SIZE",
           "MIN_FRAME"]
DEFAULT_MTU = 1500

_SOL_PACKET = getattr(socket, "SOL_PACKET", 263)
_PACKET_IGNORE_OUTGOING = getattr(socket, "PACKET_IGNORE_OUTGOING", 23)   # Linux >= 4.20
_SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
_SIOCGIFMTU = 0x8921
_RCVBUF = 4 << 20        # room for bursts while the receiving thread is not scheduled

PURE_PYTHON_VARIABLE = "ECATCFG_PURE_PYTHON"


def _compiled_exchange() -> Callable[..., tuple[int, int]] | None:
    """The compiled exchange of a cyclic frame (runtime/_exchange.c), if the build could
    compile it and ``ECATCFG_PURE_PYTHON`` is not set (non-empty, not ``0``): an install
    without a C compiler has none and cycles in Python (docs/architecture.md, "The
    compiled cyclic exchange")."""
    if os.environ.get(PURE_PYTHON_VARIABLE, "") not in ("", "0"):
        return None
    try:
        # By its full name: "from . import" would read as an import of the package
        # itself to the import graph's checks (the extension has no .py file).
        from ecatcfg.runtime._exchange import exchange
    except ImportError:
        return None
    return exchange


_COMPILED = _compiled_exchange()


def cyclic_exchange_path() -> str:
    """Which path a RawLink's cyclic frames take: for ``ecatcfg --version``."""
    return "compiled" if _COMPILED is not None else "pure Python"


class LinkError(EcatcfgError):
    """A frame could not be sent or received (oversized frame, interface down, closed link)."""


@runtime_checkable
class Link(Protocol):
    """What the master and the virtual segment need from a wire."""

    # The frame is on its way when send returns: the caller may reuse the buffer.
    def send(self, frame: bytes | bytearray) -> None: ...

    def recv(self, timeout: float | None) -> bytes | None: ...

    def fileno(self) -> int: ...

    def close(self) -> None: ...


def pad60(frame: bytes) -> bytes:
    """``frame`` padded with zero bytes to the 60-byte Ethernet minimum, as a NIC sends it."""
    n = len(frame)
    return frame if n >= MIN_FRAME else frame + bytes(MIN_FRAME - n)


def _too_big(iface: str, size: int, mtu: int) -> LinkError:
    return LinkError(f"{iface}: frame of {size} bytes is too large for the MTU of {mtu} "
                     f"bytes (at most {mtu + ETH_HEADER_SIZE} bytes per frame, Ethernet header "
                     f"included)")


def _too_short(iface: str, size: int) -> LinkError:
    return LinkError(f"{iface}: frame of {size} bytes is shorter than an Ethernet header "
                     f"({ETH_HEADER_SIZE} bytes)")


class _Base:
    """Context-manager support shared by the links."""

    __slots__ = ()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        raise NotImplementedError           # each link closes its own way

    def recv(self, timeout: float | None) -> bytes | None:
        raise NotImplementedError           # each link receives its own way

    def recv_into(self, buffer: bytearray, timeout: float | None = None) -> int:
        """The next frame copied into ``buffer``: its length, or 0 after ``timeout``
        (links without a socket to read into; RawLink reads straight into it)."""
        frame = self.recv(timeout)
        if frame is None:
            return 0
        n = len(frame)
        buffer[:n] = frame
        return n


def check_frame(iface: str, closed: bool, size: int, mtu: int) -> None:
    """What an in-memory link refuses to send, as a NIC would (the same messages as
    RawLink's): anything on a closed link, a frame past the MTU or shorter than a header."""
    if closed:
        raise LinkError(f"{iface}: link is closed")
    if size > mtu + ETH_HEADER_SIZE:
        raise _too_big(iface, size, mtu)
    if size < ETH_HEADER_SIZE:
        raise _too_short(iface, size)


# --------------------------------------------------------------------------- raw sockets

class RawLink(_Base):
    """EtherType-0x88A4 frames on one network interface through an ``AF_PACKET`` socket.

    The socket lives in the network namespace of the thread that opens it (see
    ``tests/rig.py`` for opening one inside another namespace).
    """

    __slots__ = ("iface", "ethertype", "mtu", "_sock", "_fd", "_bufsize", "_closed", "_rcvtimeo",
                 "_outgoing_dropped", "exchange_frame")

    def __init__(self, iface: str, *, ethertype: int = ETHERTYPE, rcvbuf: int = _RCVBUF) -> None:
        self.iface = iface
        self.ethertype = ethertype
        self._closed = True
        self._rcvtimeo = 0.0        # s, the SO_RCVTIMEO recv_into set (0: none)
        # Whether the kernel drops the copies of our own frames (PACKET_IGNORE_OUTGOING
        # accepted): then recv_into needs no source address to tell them apart.
        self._outgoing_dropped = False
        # The compiled exchange of a prepared frame on this socket, (prepared.compiled,
        # reply, idx, timeout) -> (size or 0 if lost, stray replies), used by
        # Transport.exchange_prepared (errors through exchange_error); a partial, not a
        # method: no Python frame per cycle.  None: the frames go through send/recv_into.
        self.exchange_frame: Callable[..., tuple[int, int]] | None = None
        try:
            # Protocol 0 receives nothing until bind() names the EtherType; a socket created
            # with the protocol costs the kernel an RCU grace period (6-16 ms) at creation
            # and again at release (measured in bench/startup.py).
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
        except PermissionError as exc:
            raise UsageError(f"{iface}: opening a raw Ethernet socket needs root or the "
                             f"CAP_NET_RAW capability ({exc.strerror})") from None
        except (AttributeError, OSError) as exc:
            raise UsageError(f"{iface}: raw Ethernet sockets (AF_PACKET) are not available "
                             f"here: {exc}") from None
        try:
            try:
                sock.bind((iface, ethertype))
            except OSError as exc:
                if exc.errno in (errno.ENODEV, errno.ENXIO, None):
                    raise UsageError(f"no such network interface: {iface!r}"
                                     f"{_available_interfaces()}") from None
                raise UsageError(f"{iface}: cannot bind a raw socket: {exc}") from None
            try:
                sock.setsockopt(_SOL_PACKET, _PACKET_IGNORE_OUTGOING, 1)
                self._outgoing_dropped = True
            except OSError:
                pass          # old kernel: outgoing copies are still filtered in recv()
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            except OSError:
                pass
            if os.geteuid() == 0:       # root may exceed net.core.rmem_max
                try:
                    sock.setsockopt(socket.SOL_SOCKET, _SO_RCVBUFFORCE, rcvbuf)
                except OSError:
                    pass
            self.mtu = _interface_mtu(sock, iface)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._fd = sock.fileno()
        if _COMPILED is not None:
            self.exchange_frame = functools.partial(_COMPILED, sock)
        # A frame never exceeds MTU + header (+ 4 for a VLAN tag); keep room for larger MTUs.
        self._bufsize = max(self.mtu + ETH_HEADER_SIZE + 4, 2048)
        self._closed = False

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"fd={self._fd}"
        return f"RawLink({self.iface!r}, {state})"

    def fileno(self) -> int:
        return self._fd

    def send(self, frame: bytes | bytearray) -> None:
        """Send ``frame`` (bytes-like) exactly as given; blocks only while the send buffer is
        full."""
        try:
            self._sock.send(frame)
        except OSError as exc:
            raise self._send_error(exc, len(frame)) from None

    def _send_error(self, exc: OSError, size: int) -> Exception:
        if self._closed:
            return LinkError(f"{self.iface}: link is closed")
        if exc.errno == errno.EMSGSIZE:
            mtu = _interface_mtu(self._sock, self.iface, self.mtu)
            return _too_big(self.iface, size, mtu)
        if exc.errno == errno.EINVAL and size < ETH_HEADER_SIZE:
            return _too_short(self.iface, size)
        if exc.errno in (errno.ENETDOWN, errno.ENXIO):
            return LinkError(f"{self.iface}: interface is down ({exc.strerror})")
        if exc.errno == errno.ENODEV:
            return LinkError(f"{self.iface}: interface has gone away ({exc.strerror})")
        return LinkError(f"{self.iface}: sending a frame of {size} bytes failed: {exc}")

    def recv(self, timeout: float | None = None) -> bytes | None:
        """The next received frame, or ``None`` after ``timeout`` seconds.

        Timeouts are rounded up to whole milliseconds (``poll``); never returns early.
        """
        sock, bufsize = self._sock, self._bufsize
        deadline = None
        while True:
            try:
                data, addr = sock.recvfrom(bufsize, socket.MSG_DONTWAIT)
            except BlockingIOError:
                pass
            except OSError as exc:
                raise self._recv_error(exc) from None
            else:
                if addr[2] != socket.PACKET_OUTGOING:
                    return data
                continue
            # Nothing waiting: sleep in poll() until a frame arrives or the time is up.
            if timeout is None:
                wait = None
            else:
                now = time.monotonic()
                if deadline is None:
                    deadline = now + timeout
                remaining = deadline - now
                if remaining <= 0:
                    return None
                wait = remaining * 1000.0
            # A poll object per wait (not one shared): threads may wait on one link together.
            poller = select.poll()
            poller.register(self._fd, select.POLLIN)
            if not poller.poll(wait):
                if deadline is not None and time.monotonic() >= deadline:
                    return None
            elif self._closed:
                raise LinkError(f"{self.iface}: link is closed")

    def recv_into(self, buffer: bytearray, timeout: float | None = None) -> int:
        """The next received frame copied into ``buffer`` (at least MTU + 18 bytes long):
        its length, or 0 after ``timeout`` seconds.  Allocates no frame (the cyclic path).

        One blocking ``recvfrom_into`` bounded by ``SO_RCVTIMEO`` (set when the timeout
        changes by more than 0.5 ms), as SOEM waits: no poll() before it and no exception
        while a reply is on its way.  May wait up to 0.5 ms past ``timeout``.

        Where the kernel drops our own frames (``PACKET_IGNORE_OUTGOING``), a plain
        ``recv_into``: ``recvfrom_into`` builds the sender's address per frame, and for
        ``AF_PACKET`` CPython looks the interface's name up with an ``ioctl``
        (``SIOCGIFNAME``, socketmodule.c ``makesockaddr``), a system call and four objects
        per cycle (docs/BENCHMARKS.md, "Cyclic")."""
        sock, outgoing = self._sock, socket.PACKET_OUTGOING
        plain = self._outgoing_dropped
        deadline = None if timeout is None else time.monotonic() + timeout
        wait = timeout
        while True:
            if wait is None:
                wait = 0.0                  # SO_RCVTIMEO 0: block until a frame comes
            elif wait <= 0:
                return 0
            if abs(wait - self._rcvtimeo) > 0.0005:
                sec = int(wait)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO,
                                struct.pack("ll", sec, max(1, int((wait - sec) * 1e6))
                                            if wait else 0))
                self._rcvtimeo = wait
            try:
                if plain:
                    n = sock.recv_into(buffer)
                    if self._closed:
                        raise LinkError(f"{self.iface}: link is closed")
                    return n
                n, addr = sock.recvfrom_into(buffer)
            except (BlockingIOError, InterruptedError):
                n, addr = 0, None
            except OSError as exc:
                raise self._recv_error(exc) from None
            if self._closed:
                raise LinkError(f"{self.iface}: link is closed")
            if addr is not None and addr[2] != outgoing:
                return n
            wait = None if deadline is None else deadline - time.monotonic()

    def exchange_error(self, exc: OSError, size: int) -> Exception:
        """The error :attr:`exchange_frame` raised, as :meth:`send` and :meth:`recv_into`
        would have raised it (runtime/_exchange.c names the call in ``filename``)."""
        if exc.filename == "send":
            return self._send_error(exc, size)
        return self._recv_error(exc)

    def recv_many(self, max_frames: int, timeout: float | None = None) -> list[bytes]:
        """Up to ``max_frames`` frames: waits up to ``timeout`` for the first one, then takes
        whatever else is already waiting without blocking.  ``[]`` on timeout."""
        first = self.recv(timeout)
        if first is None:
            return []
        frames = [first]
        sock, bufsize, outgoing = self._sock, self._bufsize, socket.PACKET_OUTGOING
        while len(frames) < max_frames:
            try:
                data, addr = sock.recvfrom(bufsize, socket.MSG_DONTWAIT)
            except BlockingIOError:
                break
            except OSError as exc:
                raise self._recv_error(exc) from None
            if addr[2] != outgoing:
                frames.append(data)
        return frames

    def _recv_error(self, exc: OSError) -> Exception:
        if self._closed or exc.errno == errno.EBADF:
            return LinkError(f"{self.iface}: link is closed")
        if exc.errno in (errno.ENETDOWN, errno.ENODEV, errno.ENXIO):
            return LinkError(f"{self.iface}: interface is down or has gone away "
                             f"({exc.strerror})")
        return LinkError(f"{self.iface}: receiving failed: {exc}")

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sock.close()


def _interface_mtu(sock: socket.socket, iface: str, default: int = DEFAULT_MTU) -> int:
    """The MTU of ``iface`` as seen from the socket's network namespace."""
    try:
        req = struct.pack("16si12x", iface.encode()[:15], 0)
        mtu: int = struct.unpack_from("16si", fcntl.ioctl(sock.fileno(), _SIOCGIFMTU, req))[1]
        return mtu
    except (OSError, UnicodeEncodeError):
        return default


def _available_interfaces() -> str:
    try:
        names = sorted(name for _, name in socket.if_nameindex())
    except OSError:
        return ""
    return f" (interfaces here: {', '.join(names)})" if names else ""


# --------------------------------------------------------------------------- in memory

class MemoryLink(_Base):
    """One end of an in-memory wire; make both ends with :meth:`pair`.

    What one end sends the other receives, in order.  Each end's receive queue holds at most
    ``capacity`` frames; a frame arriving at a full queue is dropped and counted in
    :attr:`dropped` (a NIC ring overflowing), so a sender never blocks.  Frames sent after the
    peer closed are lost, as on a cable with nothing at the other end.  Frames longer than
    ``mtu + 14`` bytes raise the same :class:`LinkError` as :class:`RawLink` does.
    """

    def __init__(self, name: str = "mem", *, capacity: int = 1024, mtu: int = DEFAULT_MTU) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1")
        self.iface = name
        self.capacity = capacity
        self.mtu = mtu
        self.dropped = 0
        self._queue: deque[bytes] = deque()
        self._cv = threading.Condition(threading.Lock())
        self._peer: MemoryLink | None = None
        self._closed = False
        self._wake_r = -1           # created on the first fileno() call
        self._wake_w = -1
        self._signalled = False

    @classmethod
    def pair(cls, *, capacity: int = 1024, mtu: int = DEFAULT_MTU,
             names: tuple[str, str] = ("mem-a", "mem-b")) -> tuple[MemoryLink, MemoryLink]:
        a = cls(names[0], capacity=capacity, mtu=mtu)
        b = cls(names[1], capacity=capacity, mtu=mtu)
        a._peer, b._peer = b, a
        return a, b

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"{len(self._queue)} queued"
        return f"MemoryLink({self.iface!r}, {state})"

    def __len__(self) -> int:
        """Frames waiting to be received."""
        return len(self._queue)

    def send(self, frame: bytes | bytearray) -> None:
        check_frame(self.iface, self._closed, len(frame), self.mtu)
        peer = self._peer
        if peer is not None:
            peer._deliver(bytes(frame))

    def _deliver(self, frame: bytes) -> None:
        with self._cv:
            if self._closed:
                return
            queue = self._queue
            if len(queue) >= self.capacity:
                self.dropped += 1
                return
            queue.append(frame)
            if len(queue) == 1:
                self._cv.notify()
                self._set_wakeup()

    def recv(self, timeout: float | None = None) -> bytes | None:
        with self._cv:
            queue = self._queue
            if not queue:
                if self._closed:
                    raise LinkError(f"{self.iface}: link is closed")
                if timeout is None:
                    while not queue and not self._closed:
                        self._cv.wait()
                elif timeout > 0:
                    deadline = time.monotonic() + timeout
                    while not queue and not self._closed:
                        remaining = deadline - time.monotonic()
                        if remaining <= 0:
                            break
                        self._cv.wait(remaining)
                if not queue:
                    if self._closed:
                        raise LinkError(f"{self.iface}: link is closed")
                    return None
            frame = queue.popleft()
            if not queue:
                self._clear_wakeup()
            if queue:
                self._cv.notify()       # another receiving thread may take the next one
            return frame

    def recv_many(self, max_frames: int, timeout: float | None = None) -> list[bytes]:
        """Up to ``max_frames`` frames: waits up to ``timeout`` for the first one, then takes
        whatever else is waiting.  ``[]`` on timeout."""
        first = self.recv(timeout)
        if first is None:
            return []
        frames = [first]
        with self._cv:
            queue = self._queue
            while queue and len(frames) < max_frames:
                frames.append(queue.popleft())
            if not queue:
                self._clear_wakeup()
        return frames

    def fileno(self) -> int:
        """A descriptor that is readable while a frame is waiting (for ``select``)."""
        with self._cv:
            if self._closed:
                raise LinkError(f"{self.iface}: link is closed")
            if self._wake_r < 0:
                if hasattr(os, "eventfd"):
                    fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
                    self._wake_r = self._wake_w = fd
                else:                       # not Linux
                    self._wake_r, self._wake_w = os.pipe()
                    os.set_blocking(self._wake_r, False)
                    os.set_blocking(self._wake_w, False)
                if self._queue:
                    self._set_wakeup()
            return self._wake_r

    # Both helpers run with self._cv held; the descriptor is readable exactly while the queue
    # is not empty.
    def _set_wakeup(self) -> None:
        if self._wake_w >= 0 and not self._signalled:
            self._signalled = True
            if self._wake_w == self._wake_r:
                os.eventfd_write(self._wake_w, 1)
            else:
                os.write(self._wake_w, b"\0")

    def _clear_wakeup(self) -> None:
        if self._signalled:
            self._signalled = False
            try:
                if self._wake_w == self._wake_r:
                    os.eventfd_read(self._wake_r)
                else:
                    os.read(self._wake_r, 1)
            except BlockingIOError:
                pass

    def close(self) -> None:
        with self._cv:
            if self._closed:
                return
            self._closed = True
            self._queue.clear()
            self._cv.notify_all()
            fds = {self._wake_r, self._wake_w} - {-1}
            self._wake_r = self._wake_w = -1
            self._signalled = False
        for fd in fds:
            os.close(fd)
