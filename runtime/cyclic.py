"""The ENI's cyclic frames: process data out and in, working counters, cycle statistics.

``Cyclic/Frame/Cmd`` gives each cyclic datagram, the states it runs in, its expected
working counter (``Cnt``) and where its data sits in the process image (``InputOffs`` /
``OutputOffs``).  Two conventions exist (``docs/eni-exports.md`` §4): EC-Engineer and
ecatcfg write offsets into a compact image (the data starts at the offset); TwinCAT's image
is shaped like the frame, and its offsets are those of the datagram *header* in the
Ethernet frame (16 for the first), so the data starts 10 bytes later.  A frame whose
offsets are exactly its datagrams' header positions is read the TwinCAT way.
"""

from __future__ import annotations

import time

from ecatcfg.eni.plan import CyclicCmd, NetworkPlan
from ecatcfg.esc import AlState, Cmd, Reg
from ecatcfg.record import field, record
from ecatcfg.runtime import wire
from ecatcfg.runtime.transport import Transport
from ecatcfg.runtime.wire import Datagram

_READS = {Cmd.LRD, Cmd.LRW, Cmd.APRD, Cmd.FPRD, Cmd.BRD, Cmd.ARMW, Cmd.FRMW}


@record
class _Slot:
    cmd: CyclicCmd
    in_at: int                  # data offset in the input image
    out_at: int                 # ... and in the output image
    # The working counter this cycle must bring back: the ENI's Cnt, lowered by what the
    # slaves that are offline would add (runtime/recovery.py); None: not checked.
    expected: int | None = None
    wkc: int = -1               # what the last cycle brought back; -1: its frame was lost


@record
class CycleStats:
    cycles: int = 0
    lost_frames: int = 0
    wkc_errors: int = 0
    wkc_error_cmds: dict[str, int] = field(default_factory=dict)
    periods_us: list[float] = field(default_factory=list)

    def jitter(self) -> dict[str, float]:
        """p50/p99/max of the cycle period's deviation from the nominal, in us."""
        if len(self.periods_us) < 2:
            return {"p50": 0.0, "p99": 0.0, "max": 0.0}
        # The median without the statistics module (it imports decimal and fractions, 4 ms
        # that apply's startup need not pay).
        ordered = sorted(self.periods_us)
        n = len(ordered)
        middle = (ordered[(n - 1) // 2] + ordered[n // 2]) / 2
        devs = sorted(abs(p - middle) for p in self.periods_us)
        return {"p50": devs[len(devs) // 2], "p99": devs[min(len(devs) - 1,
                                                             int(len(devs) * 0.99))],
                "max": devs[-1]}


def _frame_shaped(cmds: list[CyclicCmd]) -> bool:
    pos = wire.FRAME_HEADER_END
    for c in cmds:
        if c.input_offs != pos or c.output_offs != pos:
            return False
        pos += wire.DG_HEADER_LEN + c.length + wire.WKC.size
    return True


class CyclicFrames:
    """The cyclic frames of an ENI and its process image (inputs and outputs)."""

    def __init__(self, plan: NetworkPlan) -> None:
        image = plan.process_image
        frames = [f for cyc in plan.cyclic for f in cyc.frames]
        # The ENI's cycle time; TwinCAT files often have none, then the DC SYNC0 cycle
        # the slaves were given; 1 ms without either.
        dc_cycle = next((s.dc.cycle_time0 // 1000 for s in plan.slaves
                         if s.dc is not None and s.dc.cycle_time0), None)
        self.cycle_time_us = next((c.cycle_time for c in plan.cyclic if c.cycle_time), None) \
            or dc_cycle or 1000
        self.frames: list[list[_Slot]] = []
        in_size, out_size = image.inputs_size, image.outputs_size
        for f in frames:
            shift = wire.DG_HEADER_LEN if _frame_shaped(f.cmds) else 0
            # "Bus shift" (APWR/FPWR of 0x0910) writes the master's own clock into the
            # reference clock; this master follows the reference instead (ARMW), and sending
            # the file's zeros would feed the reference's drift loop a huge error.
            slots = [_Slot(c, c.input_offs + shift, c.output_offs + shift, c.cnt)
                     for c in f.cmds
                     if not (c.cmd in (Cmd.APWR, Cmd.FPWR) and c.ado == Reg.DC_SYSTEM_TIME)]
            for s in slots:
                in_size = max(in_size, s.in_at + s.cmd.length)
                out_size = max(out_size, s.out_at + s.cmd.length)
            self.frames.append(slots)
        self.inputs = bytearray(in_size)
        self.outputs = bytearray(out_size)
        self.stats = CycleStats()
        self._last_start: float | None = None

    def exchange(self, transport: Transport, state: AlState, timeout: float = 0.01) -> bool:
        """One cycle: every frame with the commands of ``state``; ``True`` if all came back
        with the working counters the ENI expects."""
        now = time.perf_counter()
        if self._last_start is not None:
            self.stats.periods_us.append((now - self._last_start) * 1e6)
            if len(self.stats.periods_us) > 100_000:
                del self.stats.periods_us[:50_000]
        self._last_start = now
        self.stats.cycles += 1
        name = state.name
        ok = True
        for slots in self.frames:
            active = [s for s in slots if name in s.cmd.states]
            if not active:
                continue
            dgs = [self._datagram(s) for s in active]
            back = transport.exchange(dgs, timeout)
            if back is None:
                self.stats.lost_frames += 1
                for s in active:
                    s.wkc = -1
                ok = False
                continue
            for s, dg in zip(active, back):
                if s.cmd.cmd in _READS:
                    self.inputs[s.in_at:s.in_at + s.cmd.length] = dg.data
                s.wkc = dg.wkc
                if s.expected is not None and dg.wkc != s.expected:
                    self.stats.wkc_errors += 1
                    key = s.cmd.comment or f"cmd {s.cmd.cmd}"
                    self.stats.wkc_error_cmds[key] = self.stats.wkc_error_cmds.get(key, 0) + 1
                    ok = False
        return ok

    def _datagram(self, s: _Slot) -> Datagram:
        c = s.cmd
        if c.cmd in (Cmd.LWR, Cmd.LRW):           # process data from the output image
            data = bytes(self.outputs[s.out_at:s.out_at + c.length])
        else:
            data = c.data if c.data is not None else bytes(c.length)
        return wire.datagram_for(c, data)
