"""Telling a service manager how ``apply`` is doing: the ``sd_notify`` datagram protocol.

systemd (and s6, dinit ... which speak the same protocol) start a ``Type=notify`` service
with ``NOTIFY_SOCKET`` naming an AF_UNIX datagram socket; the service sends newline-separated
``KEY=value`` assignments to it: ``READY=1`` once it does its job, ``STATUS=...`` for humans,
``WATCHDOG=1`` at least every ``WATCHDOG_USEC`` microseconds when the unit has a watchdog
(``WatchdogSec=``), ``STOPPING=1`` when it begins to shut down.  A path starting with ``@``
is in the abstract namespace (a leading NUL byte).  The protocol is documented in
sd_notify(3) and sd_watchdog_enabled(3) of the systemd manual; it is a few lines of socket
code, so no library is needed.

Without ``NOTIFY_SOCKET`` every call is a no-op: ``apply`` run by hand behaves as before.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Mapping


class Notifier:
    """The ``NOTIFY_SOCKET`` of this process, if any, and its watchdog period."""

    def __init__(self, address: str | None, watchdog_usec: int | None = None) -> None:
        self.address = address
        # sd_watchdog_enabled(3): ping at half the period so one late ping is not fatal.
        self.watchdog_interval = watchdog_usec / 2e6 if watchdog_usec else None
        self._last_ping = 0.0
        self._sock: socket.socket | None = None
        self.error: str | None = None        # why the last send failed (never raised)

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> Notifier:
        """From ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID`` (the watchdog is
        ours when the PID is unset or is this process, as sd_watchdog_enabled(3) says)."""
        env = os.environ if env is None else env
        address = env.get("NOTIFY_SOCKET") or None
        usec: int | None = None
        pid = env.get("WATCHDOG_PID")
        if env.get("WATCHDOG_USEC") and (not pid or pid == str(os.getpid())):
            try:
                usec = int(env["WATCHDOG_USEC"])
            except ValueError:
                usec = None
            if usec is not None and usec <= 0:
                usec = None
        return cls(address, usec)

    @property
    def active(self) -> bool:
        return self.address is not None

    def send(self, **fields: str | int) -> bool:
        """One datagram of ``KEY=value`` lines; ``False`` (and :attr:`error`) if it could not
        be sent: a service manager that went away must not stop the slaves' way down."""
        if self.address is None:
            return False
        text = "\n".join(f"{key}={value}" for key, value in fields.items()) + "\n"
        address = "\0" + self.address[1:] if self.address.startswith("@") else self.address
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(text.encode(), address)
        except OSError as exc:
            self.error = f"{self.address}: {exc.strerror or exc}"
            return False
        return True

    def ready(self, status: str) -> None:
        self.send(READY=1, STATUS=status)
        self._last_ping = time.monotonic()

    def status(self, status: str) -> None:
        self.send(STATUS=status)

    def stopping(self, status: str) -> None:
        self.send(STOPPING=1, STATUS=status)

    def watchdog(self) -> None:
        """``WATCHDOG=1`` if half the watchdog period has gone by since the last one: call it
        as often as you like from the loop whose liveness it vouches for."""
        if self.watchdog_interval is None or self.address is None:
            return
        now = time.monotonic()
        if now - self._last_ping >= self.watchdog_interval:
            self._last_ping = now
            self.send(WATCHDOG=1)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
