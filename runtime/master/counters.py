"""The ESC error counters of each slave (``ecatcfg counters``): registers 0x0300-0x0313
(ETG.1000.4; ESC Section II), read by position.

Per port n: invalid frames 0x0300 + 2n (a CRC error this ESC saw first), physical-layer
RX errors 0x0301 + 2n, forwarded RX errors 0x0308 + n (an error a previous ESC saw and
marked), lost links 0x0310 + n; per ESC: ECAT processing unit errors 0x030C and PDI errors
0x030D.  The port that counts invalid frames while the ports after it count forwarded
ones is where the bad cable or connector is (ESC Section I, "Errors and forwarded
errors").  Clearing writes zeros over the whole block: a write to any of 0x0300-0x030C
clears those, to any of 0x0310-0x0313 the lost link counters.

Only the ports the ESC has are listed: the port descriptor 0x0007 gives two bits per port
(ESC Section II: 0 not implemented, 1 not configured by the SII, 2 E-bus, 3 MII/RMII), so
a 2-port terminal shows ports A and B, not four ports of which two can never count."""

from __future__ import annotations


from ecatcfg.runtime.clock import monotonic
from ecatcfg.esc import PORT_LETTERS, Cmd, Reg
from ecatcfg.record import record
from ecatcfg.runtime.master.al_tool import StatesError
from ecatcfg.runtime.master.lockstep import Job, run_jobs
from ecatcfg.runtime.master.replay import TIMEOUT_COMMAND
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram

BLOCK = 0x0314 - Reg.RX_ERROR_COUNTER          # 0x0300..0x0313
PORT_COUNTERS = ("invalid_frames", "rx_errors", "forwarded_rx_errors", "lost_links")


# Port descriptor values of a port that exists (0x0007, two bits per port: E-bus, MII).
PORT_PRESENT = (2, 3)


@record(frozen=True)
class SlaveCounters:
    position: int
    ports: tuple[dict[str, int], ...]          # per port A-D: PORT_COUNTERS
    processing_unit_errors: int
    pdi_errors: int
    port_descriptor: int = 0xFF                # 0x0007; all four ports when not read

    @classmethod
    def from_block(cls, position: int, data: bytes,
                   port_descriptor: int = 0xFF) -> SlaveCounters:
        ports = tuple({"invalid_frames": data[2 * n], "rx_errors": data[2 * n + 1],
                       "forwarded_rx_errors": data[8 + n], "lost_links": data[0x10 + n]}
                      for n in range(4))
        return cls(position, ports, data[0x0C], data[0x0D], port_descriptor)

    def present(self) -> list[int]:
        """The numbers (0 = A) of the ports this ESC has, from its port descriptor (all
        four when it names none: a slave that answered has at least the port it was
        reached through, and which that is cannot be told)."""
        found = [n for n in range(4) if self.port_descriptor >> 2 * n & 3 in PORT_PRESENT]
        return found or list(range(4))

    def present_ports(self) -> list[tuple[str, dict[str, int]]]:
        """(letter, counters) of each port the ESC has."""
        return [(PORT_LETTERS[n], self.ports[n]) for n in self.present()]

    def flat(self) -> dict[str, int]:
        """``{"A.invalid_frames": 3, ..., "processing_unit_errors": 0, "pdi_errors": 0}``."""
        out = {f"{letter}.{k}": v for letter, p in self.present_ports() for k, v in p.items()}
        out["processing_unit_errors"] = self.processing_unit_errors
        out["pdi_errors"] = self.pdi_errors
        return out

    def first_errors(self) -> list[str]:
        """The ports where this ESC saw errors first (invalid frames or RX errors)."""
        return [letter for letter, p in self.present_ports()
                if p["invalid_frames"] or p["rx_errors"]]


def _job(position: int, clear: bool, out: dict[int, SlaveCounters]) -> Job:
    adp = -position & 0xFFFF
    deadline = monotonic() + TIMEOUT_COMMAND
    read = Datagram.physical(Cmd.APRD, adp, Reg.RX_ERROR_COUNTER, BLOCK)
    ports = Datagram.physical(Cmd.APRD, adp, Reg.PORT_DESCRIPTOR, 1)
    while True:
        reply = yield [read, ports]                     # one frame
        if reply is not None and reply[0].wkc == 1 and reply[1].wkc == 1:
            out[position] = SlaveCounters.from_block(position, bytes(reply[0].data),
                                                     reply[1].data[0])
            break
        if monotonic() > deadline:
            raise StatesError(f"slave {position}: no answer to the error counter read "
                              "(0x0300-0x0313)")
    if not clear:
        return
    wipe = Datagram.physical(Cmd.APWR, adp, Reg.RX_ERROR_COUNTER, bytes(BLOCK))
    while True:
        reply = yield [wipe]
        if reply is not None and reply[0].wkc == 1:
            return
        if monotonic() > deadline:
            raise StatesError(f"slave {position}: clearing the error counters (0x0300) "
                              "was not answered")


def read_counters(transport: Transport, positions: list[int],
                  clear: bool = False) -> list[SlaveCounters]:
    """Each slave's counters; with ``clear``, cleared right after they were read."""
    out: dict[int, SlaveCounters] = {}
    run_jobs(transport, [_job(p, clear, out) for p in positions])
    return [out[p] for p in positions]


def changes(before: list[SlaveCounters],
            after: list[SlaveCounters]) -> list[tuple[int, str, int, int]]:
    """(position, counter, old, new) of every counter that changed."""
    out: list[tuple[int, str, int, int]] = []
    for b, a in zip(before, after):
        old, new = b.flat(), a.flat()
        out.extend((a.position, k, old[k], v) for k, v in new.items() if v != old[k])
    return out


__all__ = ["PORT_COUNTERS", "PORT_PRESENT", "SlaveCounters", "changes", "read_counters"]
