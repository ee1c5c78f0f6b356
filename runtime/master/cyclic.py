"""The ENI's cyclic frames: process data out and in, working counters, cycle statistics.

``Cyclic/Frame/Cmd`` gives each cyclic datagram, the states it runs in, its expected
working counter (``Cnt``) and where its data sits in the process image (``InputOffs`` /
``OutputOffs``), in either of the two conventions ``Frame.data_shift`` tells apart
(``eni/plan.py``: a compact image, or TwinCAT's frame-shaped one).

The hot path (docs/BENCHMARKS.md, "Cyclic"): each frame is encoded once per AL state
(:class:`_Prepared`, by ``wire.encode``, the one home of the layout); a cycle copies the
output image into it through memoryviews, sets the datagram index, receives the reply
into a buffer of its own, checks its shape and reads the working counters with one
``struct`` call at fixed offsets, and copies the read data into the input image.  No
``Datagram``, list or frame is built per cycle.

Slave-to-slave copies (``CopyInfos``, :class:`~ecatcfg.eni.plan.CopyInfo`) run after the
last frame of a cycle came back and before the next cycle sends: in ENI order, each only
when its command brought back the working counter the ENI expects (its ``Cnt``; without
one, when the command came back at all).  A copy of a command whose working counter was
wrong or whose frame was lost is not made, so the destination keeps the last valid value
(ETG.2100 ``CopyInfosType``: "valid input data of this command").  Each copy is compiled
once per AL state and image: bits within one byte on each side are one read-mask-shift-
write of two bytes; more, in whole bytes, a memoryview slice assignment; anything else one
read-mask-shift-write of the bytes it touches (docs/BENCHMARKS.md, "What slave-to-slave
copies cost per cycle").
"""

from __future__ import annotations

import struct
from array import array

from ecatcfg.eni.plan import CopyInfo, CyclicCmd, NetworkPlan
from ecatcfg.esc import INPUT_IMAGE_CMDS, AlState, Cmd, Reg
from ecatcfg.record import record
from ecatcfg.runtime import wire
from ecatcfg.runtime.master.transport import Transport

_READS = INPUT_IMAGE_CMDS
_FLAG_SHAPE = wire.LEN_MASK | wire.MORE          # what a slave never changes in len|flags
PERIODS_KEPT = 65_536       # the last periods CycleStats keeps (jitter), in a ring
REPLY_BUFFER = 2048         # > 1514, the largest Ethernet frame without FCS


@record
class _Slot:
    cmd: CyclicCmd
    in_at: int                  # data offset in the input image
    out_at: int                 # ... and in the output image
    # The working counter this cycle must bring back: the ENI's Cnt, lowered by what the
    # slaves that are offline would add (runtime/master/recovery.py); None: not checked.
    expected: int | None = None
    wkc: int = -1               # what the last cycle brought back; -1: its frame was lost


@record(frozen=True)
class CommandCount:
    """One cyclic command after a cycle (:meth:`CyclicFrames.working_counters`)."""

    cmd: CyclicCmd
    wkc: int                    # -1: its frame was lost (or it was not sent)
    expected: int | None        # None: not checked
    in_at: int                  # its data's offset in the input image
    out_at: int                 # ... and in the output image

    @property
    def ok(self) -> bool:
        return self.expected is None or self.wkc == self.expected


class CycleStats:
    """What the cycles run since the last reset counted.  A plain class, not a ``@record``:
    its repr is a summary (``print(net.run_stats)``), not the 65,536 periods it keeps."""

    __slots__ = ("cycles", "lost_frames", "wkc_errors", "wkc_error_cmds", "late", "_ring",
                 "_count")

    def __init__(self) -> None:
        self.cycles = 0
        self.lost_frames = 0
        self.wkc_errors = 0
        self.wkc_error_cmds: dict[str, int] = {}
        # Cycles that ended after the next one's deadline (Network.run starts that one at
        # once, without catching up): the deadline misses of the run.
        self.late = 0
        # The periods in a ring of doubles, made at the first period: appending to a list
        # would allocate a float per cycle.
        self._ring: array[float] | None = None
        self._count = 0

    def add_period(self, us: float) -> None:
        ring = self._ring
        if ring is None:
            ring = self._ring = array("d", bytes(8 * PERIODS_KEPT))
        ring[self._count % PERIODS_KEPT] = us
        self._count += 1

    @property
    def periods_us(self) -> list[float]:
        """The last (at most ``PERIODS_KEPT``) cycle periods, oldest first, in us."""
        ring, n = self._ring, self._count
        if ring is None:
            return []
        if n <= PERIODS_KEPT:
            return ring[:n].tolist()
        at = n % PERIODS_KEPT
        return (ring[at:] + ring[:at]).tolist()

    def jitter(self) -> dict[str, float]:
        """p50/p99/max of the cycle period's deviation from the nominal, in us."""
        if len(self.periods_us) < 2:
            return {"p50": 0.0, "p99": 0.0, "max": 0.0}
        middle = _median(sorted(self.periods_us))
        devs = sorted(abs(p - middle) for p in self.periods_us)
        return {"p50": devs[len(devs) // 2], "p99": devs[min(len(devs) - 1,
                                                             int(len(devs) * 0.99))],
                "max": devs[-1]}

    def __repr__(self) -> str:
        periods = sorted(self.periods_us)
        measured = (f"period min/median/max {periods[0]:.1f}/{_median(periods):.1f}/"
                    f"{periods[-1]:.1f} us over the last {len(periods)}" if periods
                    else "no period measured")
        return (f"CycleStats({self.cycles} cycles, {self.lost_frames} lost frames, "
                f"{self.wkc_errors} working-counter errors, {self.late} late; {measured})")


def _median(ordered: list[float]) -> float:
    # Without the statistics module (it imports decimal and fractions, 4 ms that apply's
    # startup need not pay).
    n = len(ordered)
    return (ordered[(n - 1) // 2] + ordered[n // 2]) / 2


class _Prepared:
    """One cyclic frame of one AL state, encoded once, with the places a cycle touches."""

    __slots__ = ("slots", "frame", "index_at", "index_le", "reply_mask", "length", "_header",
                 "_wkcs", "_expect", "_shape", "_out_copies", "_in_copies", "inputs_bound",
                 "outputs_bound", "compiled", "_slave_copies", "good")

    def __init__(self, slots: list[_Slot], constant: list[bytes]) -> None:
        self.slots = slots
        frame = bytearray(wire.encode([wire.datagram_for(s.cmd, data)
                                       for s, data in zip(slots, constant)]))
        self.frame = frame
        places = wire.datagram_offsets(frame)
        self.index_at = tuple(pos + 1 for pos, _ in places)
        last, n = places[-1]
        self.length = last + wire.DG_HEADER_LEN + n + wire.WKC.size
        # The same check for the compiled exchange (runtime/_exchange.c): the index
        # offsets as 16-bit little-endian numbers, and per byte of the reply the bits that
        # must be as sent, from the same struct as :meth:`matches` (its B and H fields).
        self.index_le = b"".join(at.to_bytes(2, "little") for at in self.index_at)
        self.reply_mask = _reply_mask(self.length, places)
        # The fixed offsets, read with one struct call each: EtherType, EtherCAT header
        # and each datagram's cmd, index and len|flags; and each datagram's WKC.
        self._header = struct.Struct("<12xHH" + "".join(f"BB4xH2x{n}x2x" for _, n in places))
        self._wkcs = struct.Struct(f"<{wire.FRAME_HEADER_END}x" + "".join(
            f"{wire.DG_HEADER_LEN}x{n}xH" for _, n in places))
        sent = self._header.unpack_from(frame)
        # What a reply under index i reads as, made at the index's first use.
        self._expect: list[tuple[int, ...] | None] = [None] * 256
        self._shape = sent
        self._out_copies: tuple[tuple[memoryview, memoryview], ...] = ()
        self._in_copies: tuple[tuple[memoryview, memoryview], ...] = ()
        self.inputs_bound: bytearray | None = None       # the images bind() was given
        self.outputs_bound: bytearray | None = None
        # What the compiled exchange gets (runtime/_exchange.c), one tuple made by bind():
        # the frame, index_le, reply_mask, the same copies as int32 triples (offset in the
        # frame, in the output image, length) and (in the reply, in the input image,
        # length) with the images.
        self.compiled: tuple[bytearray, bytes, bytes, bytes, bytearray, bytes, bytearray] \
            = (frame, self.index_le, self.reply_mask, b"", bytearray(), b"", bytearray())
        # Per command with CopyInfos: the command's slot, the working counter that makes
        # its input data valid (-1: any that came back) and its compiled copies.
        self._slave_copies: tuple[tuple[_Slot, int, tuple[_CopyOp, ...]], ...] = ()
        # The working counters of the last reply whose every checked one was as expected,
        # and which the slots hold: a reply with the same ones needs no look at each slot
        # (docs/BENCHMARKS.md, "Cyclic").  None after a loss, an error, a change of state
        # or of what a slot expects (CyclicFrames.expected_changed).
        self.good: tuple[int, ...] | None = None

    def bind(self, inputs: bytearray, outputs: bytearray, reply: bytearray) -> None:
        """Views from the frame to the images (again if the images were replaced)."""
        if inputs is self.inputs_bound and outputs is self.outputs_bound:
            return
        frame, places = memoryview(self.frame), wire.datagram_offsets(self.frame)
        back, ins, outs = memoryview(reply), memoryview(inputs), memoryview(outputs)
        out_copies, in_copies = [], []
        out_table, in_table = array("i"), array("i")
        for s, (pos, n) in zip(self.slots, places):
            data = pos + wire.DG_HEADER_LEN
            if s.cmd.cmd in (Cmd.LWR, Cmd.LRW):      # process data from the output image
                out_copies.append((frame[data:data + n], outs[s.out_at:s.out_at + n]))
                out_table.extend((data, s.out_at, n))
            if s.cmd.cmd in _READS:
                in_copies.append((ins[s.in_at:s.in_at + n], back[data:data + n]))
                in_table.extend((data, s.in_at, n))
        self._out_copies, self._in_copies = tuple(out_copies), tuple(in_copies)
        self.compiled = (self.frame, self.index_le, self.reply_mask, out_table.tobytes(),
                         outputs, in_table.tobytes(), inputs)
        self._slave_copies = tuple(
            (s, -1 if s.cmd.cnt is None else s.cmd.cnt,
             tuple(_compile(c, ins, outs) for c in s.cmd.copy_infos))
            for s in self.slots if s.cmd.copy_infos)
        self.inputs_bound, self.outputs_bound = inputs, outputs

    def fill(self) -> None:
        """The output image into the frame (before it is sent)."""
        for to, source in self._out_copies:
            to[:] = source

    def take(self) -> None:
        """The reply's read data into the input image (once it matched)."""
        for to, source in self._in_copies:
            to[:] = source

    def matches(self, reply: bytearray, size: int, idx: int) -> bool:
        """The reply is this frame come back under ``idx``: EtherType and EtherCAT header
        as sent, and every datagram's command, index and length (ignoring the circulating
        bit a slave may set).  :attr:`reply_mask` says the same for the compiled path."""
        if size < self.length:
            return False
        got = self._header.unpack_from(reply)
        expect = self._expect[idx]
        if expect is None:
            expect = self._expect[idx] = tuple(
                idx if k > 1 and k % 3 == 0 else v for k, v in enumerate(self._shape))
        if got != expect:
            if got[0] != expect[0] or got[1] != expect[1]:
                return False
            for k in range(2, len(got), 3):   # the slow way: masked len|flags
                if got[k] != expect[k] or got[k + 1] != idx \
                        or got[k + 2] & _FLAG_SHAPE != expect[k + 2] & _FLAG_SHAPE:
                    return False
        return True

    def copy_slave_to_slave(self) -> None:
        """This frame's CopyInfos, for the commands whose input data is valid."""
        inputs, outputs = self.inputs_bound, self.outputs_bound
        assert inputs is not None and outputs is not None   # bound before the exchange
        for slot, want, ops in self._slave_copies:
            wkc = slot.wkc
            # Valid input data: the working counter the ENI expects, or, without a Cnt,
            # one at least: 0 means no slave put data in (and -1, the frame was lost).
            if wkc != want if want >= 0 else wkc <= 0:
                continue                      # invalid this cycle: keep the last value
            for op in ops:
                if len(op) == 2:              # whole bytes
                    op[0][:] = op[1]
                elif len(op) == 6:            # within one byte each side
                    sb, ss, mask, db, ds, keep = op
                    outputs[db] = outputs[db] & keep | (inputs[sb] >> ss & mask) << ds
                else:
                    sb, se, ss, mask, db, de, ds, keep = op
                    value = int.from_bytes(inputs[sb:se], "little") >> ss & mask
                    outputs[db:de] = (int.from_bytes(outputs[db:de], "little") & keep
                                      | value << ds).to_bytes(de - db, "little")


def _reply_mask(length: int, places: list[tuple[int, int]]) -> bytes:
    """Per byte of a reply, the bits :meth:`_Prepared.matches` compares with the frame as
    sent: EtherType and EtherCAT header (bytes 12-15), each datagram's command and index,
    and its len|flags but for the circulating bit (``_FLAG_SHAPE``)."""
    mask = bytearray(length)
    mask[12:wire.FRAME_HEADER_END] = b"\xff" * (wire.FRAME_HEADER_END - 12)
    for pos, _ in places:
        mask[pos] = mask[pos + 1] = 0xFF
        mask[pos + 6:pos + 8] = _FLAG_SHAPE.to_bytes(2, "little")
    return bytes(mask)


# A compiled copy: (destination view, source view) for whole bytes; for bits within one
# source and one destination byte, the source byte, shift and mask and the destination
# byte, shift and the mask of the bits it keeps (no allocation: 8x cheaper than the
# general form); else the source's bytes [sb, se), its shift and mask, the destination's
# bytes [db, de), shift and the mask of the bits it keeps.
_CopyOp = (tuple[memoryview, memoryview] | tuple[int, int, int, int, int, int]
           | tuple[int, int, int, int, int, int, int, int])


def _compile(c: CopyInfo, inputs: memoryview, outputs: memoryview) -> _CopyOp:
    """One copy over the images.  A bit offset counts from bit 0 of byte 0, least
    significant bit first, as the ``ProcessImage`` variables' ``BitOffs`` (ETG.2100)."""
    src, dst, n = c.src_bit_offs, c.dst_bit_offs, c.bit_size
    mask = (1 << n) - 1
    if src % 8 + n <= 8 and dst % 8 + n <= 8:     # a whole byte too: cheaper than a view
        return src // 8, src % 8, mask, dst // 8, dst % 8, 0xFF ^ (mask << dst % 8)
    if not (src | dst | n) & 7:
        return outputs[dst // 8:(dst + n) // 8], inputs[src // 8:(src + n) // 8]
    db, de = dst // 8, (dst + n + 7) // 8
    return (src // 8, (src + n + 7) // 8, src % 8, mask, db, de, dst % 8,
            ((1 << 8 * (de - db)) - 1) ^ (mask << dst % 8))


class CyclicFrames:
    """The cyclic frames of an ENI and its process image (inputs and outputs)."""

    def __init__(self, plan: NetworkPlan) -> None:
        frames = [f for cyc in plan.cyclic for f in cyc.frames]
        # The ENI's cycle time; TwinCAT files often have none, then the DC SYNC0 cycle
        # the slaves were given; 1 ms without either.
        dc_cycle = next((s.dc.cycle_time0 // 1000 for s in plan.slaves
                         if s.dc is not None and s.dc.cycle_time0), None)
        self.cycle_time_us = next((c.cycle_time for c in plan.cyclic if c.cycle_time), None) \
            or dc_cycle or 1000
        self.frames: list[list[_Slot]] = []
        # The images' sizes: the ProcessImage's, or as far as a command's data reaches
        # (the same sizes the reader checks each CopyInfo against).
        in_size, out_size = plan.image_bytes()
        for f in frames:
            shift = f.data_shift
            # "Bus shift" (APWR/FPWR of 0x0910) writes the master's own clock into the
            # reference clock; this master follows the reference instead (ARMW), and sending
            # the file's zeros would feed the reference's drift loop a huge error.
            slots = [_Slot(c, c.input_offs + shift, c.output_offs + shift, c.cnt)
                     for c in f.cmds
                     if not (c.cmd in (Cmd.APWR, Cmd.FPWR) and c.ado == Reg.DC_SYSTEM_TIME)]
            self.frames.append(slots)
        # Whether any command has CopyInfos: a cycle without them pays one test.
        self.copies = any(c.copy_infos for f in frames for c in f.cmds)
        self.inputs = bytearray(in_size)
        self.outputs = bytearray(out_size)
        self.stats = CycleStats()
        self._last_start: float | None = None
        self._prepared: dict[AlState, tuple[_Prepared, ...]] = {}
        self._reply = bytearray(REPLY_BUFFER)
        self._last_prepared: tuple[_Prepared, ...] = ()

    def working_counters(self) -> list[list[CommandCount]]:
        """Per frame, each command with the working counter the last cycle brought back
        (-1: its frame was lost, or the command is not sent in this state) and the one it
        expects, and where its data lies in the images: for ``ecatcfg watch``'s status line
        and TwinCAT's diagnostic variables.  Read between cycles."""
        return [[CommandCount(s.cmd, s.wkc, s.expected, s.in_at, s.out_at) for s in slots]
                for slots in self.frames]

    def prepared(self, state: AlState) -> tuple[_Prepared, ...]:
        """The frames of ``state``, encoded (once per state)."""
        found = self._prepared.get(state)
        if found is None:
            found = self._prepared[state] = tuple(
                _Prepared(active, [_constant(s) for s in active])
                for active in ([s for s in slots if state.name in s.cmd.states]
                               for slots in self.frames) if active)
        return found

    def expected_changed(self) -> None:
        """A slot's ``expected`` changed (runtime/master/recovery.py): the next cycle looks
        at every working counter again."""
        for frames in self._prepared.values():
            for p in frames:
                p.good = None

    def restart_periods(self) -> None:
        """The next cycle starts the periods afresh (not measured from a cycle before)."""
        self._last_start = None

    def exchange(self, transport: Transport, state: AlState, timeout: float = 0.01) -> bool:
        """One cycle: every frame with the commands of ``state``; ``True`` if all came back
        with the working counters expected (each slot's ``expected``)."""
        now = transport.clock.monotonic()
        stats = self.stats
        last = self._last_start
        if last is not None:
            ring = stats._ring           # CycleStats.add_period, written out (per cycle)
            if ring is not None:
                ring[stats._count % PERIODS_KEPT] = (now - last) * 1e6
                stats._count += 1
            else:
                stats.add_period((now - last) * 1e6)
        self._last_start = now
        stats.cycles += 1
        ok = True
        inputs, outputs, reply = self.inputs, self.outputs, self._reply
        prepared = self._prepared.get(state) or self.prepared(state)
        if prepared is not self._last_prepared:     # another state: other slots' counts
            self._last_prepared = prepared
            self.expected_changed()
        exchange = transport.exchange_prepared
        # The exchange fills the frame from the output image and takes the inputs
        # (compiled or Python: Transport.exchange_prepared).
        for p in prepared:
            if p.inputs_bound is not inputs or p.outputs_bound is not outputs:
                p.bind(inputs, outputs, reply)
            if not exchange(p, reply, timeout):
                stats.lost_frames += 1
                for s in p.slots:
                    s.wkc = -1
                p.good = None
                ok = False
                continue
            wkcs = p._wkcs.unpack_from(reply)
            if wkcs == p.good:
                continue                    # as the last good cycle: the slots hold them
            good: tuple[int, ...] | None = wkcs
            for s, wkc in zip(p.slots, wkcs):
                s.wkc = wkc
                if s.expected is not None and wkc != s.expected:
                    stats.wkc_errors += 1
                    key = s.cmd.comment or f"cmd {s.cmd.cmd}"
                    stats.wkc_error_cmds[key] = stats.wkc_error_cmds.get(key, 0) + 1
                    ok = False
                    good = None
            p.good = good
        if self.copies:
            for p in prepared:
                p.copy_slave_to_slave()
        return ok


def _constant(s: _Slot) -> bytes:
    """What a datagram carries apart from the output image: the ENI's data, else zeros."""
    c = s.cmd
    if c.cmd in (Cmd.LWR, Cmd.LRW) or c.data is None:
        return bytes(c.length)
    return c.data
