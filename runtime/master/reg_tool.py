"""Read or write ESC registers of one slave by position (``ecatcfg reg``), as IgH's
``ethercat reg_read`` / ``reg_write`` do: APRD/APWR, so no station address is needed.
A slave that does not have the register (or refuses the write) answers with working
counter 0, which is reported as such."""

from __future__ import annotations


from ecatcfg.runtime.clock import clock_of
from ecatcfg.esc import MAX_DATAGRAM_DATA, Cmd
from ecatcfg.runtime.master.al_tool import StatesError, positions_on_line
from ecatcfg.runtime.master.replay import TIMEOUT_COMMAND
from ecatcfg.runtime.link import Link
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram

MEMORY_END = 0x10000


class RegisterError(StatesError):
    """A register access the slave did not answer or refused."""


# How long ``frames_of_another_master`` listens before a write: several cycles of any master
# that cycles at 1 to 10 ms (TwinCAT's, IgH's and SOEM's usual 1 ms, a 10 ms task).
LISTEN_S = 0.05


def frames_of_another_master(link: Link, seconds: float = LISTEN_S) -> int:
    """EtherCAT frames that arrive on ``link`` while this process sends nothing: another
    master is running the line (its frames come back through the same interface).  On an
    EtherCAT line nothing else sends frames, so any frame at all is one."""
    monotonic = clock_of(link).monotonic     # a simulated wire's own time
    end = monotonic() + seconds
    seen = 0
    while (left := end - monotonic()) > 0:
        if link.recv(left) is not None:
            seen += 1
    return seen


def check_range(address: int, length: int) -> None:
    """``ValueError`` for an access no datagram can make."""
    if not 0 <= address < MEMORY_END:
        raise ValueError(f"address 0x{address:X} is outside the ESC's 64 KiB")
    if not 1 <= length <= MAX_DATAGRAM_DATA:
        raise ValueError(f"length {length}: 1 to {MAX_DATAGRAM_DATA} bytes in one datagram")
    if address + length > MEMORY_END:
        raise ValueError(f"0x{address:04X}:{length} runs past 0xFFFF")


def _exchange(transport: Transport, dg: Datagram, what: str) -> Datagram:
    monotonic = transport.clock.monotonic
    deadline = monotonic() + TIMEOUT_COMMAND
    while True:
        back = transport.exchange([dg])
        if back is not None:
            if back[0].wkc == 1:
                return back[0]
            raise RegisterError(f"{what}: working counter {back[0].wkc}, expected 1 (the "
                                "slave does not have this register area or refused)")
        if monotonic() > deadline:
            raise RegisterError(f"{what}: no reply (frames lost)")


def read(transport: Transport, position: int, address: int, length: int) -> bytes:
    check_range(address, length)
    positions_on_line(transport, position)
    dg = Datagram.physical(Cmd.APRD, -position & 0xFFFF, address, length)
    return bytes(_exchange(transport, dg, f"slave {position}: APRD 0x{address:04X}:"
                                          f"{length}").data)


def write(transport: Transport, position: int, address: int, data: bytes) -> bytes:
    """Write ``data`` and read the same bytes back (what the slave holds now: read-only
    bits keep their value)."""
    check_range(address, len(data))
    positions_on_line(transport, position)
    adp = -position & 0xFFFF
    _exchange(transport, Datagram.physical(Cmd.APWR, adp, address, data),
              f"slave {position}: APWR 0x{address:04X}:{len(data)}")
    back = Datagram.physical(Cmd.APRD, adp, address, len(data))
    return bytes(_exchange(transport, back, f"slave {position}: APRD 0x{address:04X}:"
                                            f"{len(data)}").data)


__all__ = ["RegisterError", "check_range", "read", "write"]
