"""A virtual EtherCAT segment: emulated slaves in a line or a tree, answering frames on a link.

A frame passes every slave in bus order and returns to the master.  In a tree
(``runtime/wiring.py``) bus order is the order in which the frame, going through each
ESC's open ports in the processing order 0 -> 3 -> 1 -> 2, reaches the slaves; each one
processes it once, so the datagram rules below are the same as on a line.  The cabling
shows in each slave's DL status (0x0110) and in the receive times its ports latch
(``runtime/segment/dc_clock.py``); a cable removed (:meth:`VirtualSegment.remove_cable`) takes
the slaves behind it out of the frame and closes the port it was plugged into.

Each datagram is processed in place in the frame's buffer with the addressing and
working-counter rules of ETG.1000.4 (``docs/protocol-notes.md`` §1): auto-increment (ADP
counts up at each slave; the one that sees 0 acts), configured station address (or alias
with 0x0103 bit 0), broadcast (every slave; reads OR into the data), logical (every slave whose FMMUs overlap, down to single
bits), and ARMW/FRMW (one slave reads, all others write).  Processing datagram by datagram
over all slaves gives the same result as slave by slave over all datagrams: slaves only
meet through the frame's bytes, and each slave still sees the datagrams in order.

Logical datagrams are the hot path of a running network: for each (command, address,
length) the segment works out once which bytes or bits of which slave it touches, and
keeps that plan until an FMMU or SyncManager register changes.
"""

from __future__ import annotations

import heapq
import random
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ecatcfg.esc import (AUTO_INCREMENT_CMDS, BROADCAST_CMDS, CONFIGURED_ADDRESS_CMDS, Cmd,
                         FmmuType, Reg)
from ecatcfg.runtime.segment.dc_clock import DcModel
from ecatcfg.runtime.segment.slave import (MEMORY_SIZE, PROCESS_RAM, RUNNING_STATES, EmulatedSlave,
                                           StateChange)
from ecatcfg.runtime.segment.syncman import SmKind, SmState
from ecatcfg.runtime.wiring import Wiring
from ecatcfg.runtime.wire import DG_HEADER_LEN, FrameError, datagram_offsets

if TYPE_CHECKING:
    from ecatcfg.runtime.link import Link
    from ecatcfg.runtime.segment.timing import Timing

_READS = {Cmd.APRD, Cmd.FPRD, Cmd.BRD, Cmd.LRD}
_WRITES = {Cmd.APWR, Cmd.FPWR, Cmd.BWR, Cmd.LWR}
_AUTO_INC = AUTO_INCREMENT_CMDS
_CONFIGURED = CONFIGURED_ADDRESS_CMDS
_BROADCAST = BROADCAST_CMDS
# An FMMU access of a logical datagram (see _op): frame offset, physical address, byte length
# or 0, masked bit groups (frame byte, memory byte, shift, mask), SM gate, completes the SM.
_Op = tuple[int, int, int, tuple[tuple[int, int, int, int], ...], "SmState | None", bool]
# A slave a logical datagram meets: the slave, its memory, its write ops, its read ops, and
# the register bytes (below PROCESS_RAM) its write ops reach, if any: (first, end).
_Hit = tuple[EmulatedSlave, bytearray, list[_Op], list[_Op], "tuple[int, int] | None"]

_LOGICAL: dict[int, tuple[bool, bool]] = {Cmd.LRD: (True, False), Cmd.LWR: (False, True),
                                          Cmd.LRW: (True, True)}        # (reads, writes)
_ADDRESS_REGISTERS = (Reg.STATION_ADDRESS, Reg.DL_CONTROL_2 + 1)
_AL_STATUS = int(Reg.AL_STATUS)
_ESC_CONFIG = int(Reg.ESC_CONFIG)
# What changes the IRQ: reading DL status (0x0110), the ECAT event mask (0x0200) up to the
# event request (0x0210-0x0211).
_EVENTS_END = int(Reg.ECAT_EVENT_REQUEST) + 2


@dataclass(frozen=True, slots=True)
class LossyPort:
    """A bad cable or connector at ``port`` (0-3) of ``slave`` (its name, or its bus
    position with every cable in place): a frame received there has a CRC error with
    probability ``share``."""

    slave: str | int
    port: int
    share: float


@dataclass(frozen=True, slots=True)
class Faults:
    """Seeded fault injection on the wire: a share of frames is lost (half of them on the
    way to the slaves, half on the way back, after processing), corrupted (one bit of
    the returned EtherCAT data flipped) or delayed by ``delay_s``; ``lossy`` ports receive
    frames with CRC errors, which the ESCs count (``VirtualSegment.process_lossy``)."""

    drop: float = 0.0
    corrupt: float = 0.0
    delay: float = 0.0
    delay_s: float = 0.005
    seed: int = 0
    lossy: tuple[LossyPort, ...] = ()


class VirtualSegment:
    """Emulated slaves in bus order (position 0 is the first after the master)."""

    def __init__(self, slaves: list[EmulatedSlave], faults: Faults | None = None, *,
                 clock_ns: Callable[[], int] | None = None,
                 timing: Timing | None = None, dc: DcModel | None = None,
                 wiring: Wiring | None = None) -> None:
        """``clock_ns``: the time (ns, monotonic) the slaves live in; wall time by default,
        a simulated clock for deterministic tests of time-dependent behaviour.
        ``timing``: how long the slaves take (``runtime/segment/timing.py``); None: no time.
        ``dc``: the slaves' clocks (drift, start) and the segment's timing; ``DcModel()``
        by default (seeded drift within ±100 ppm).  ``wiring``: where each of ``slaves``
        is plugged (indices into ``slaves``); a line in the order given by default.
        ``self.slaves`` holds them in bus order, ``self.wired`` in the order given."""
        self.wired = list(slaves)
        self.wiring = wiring or Wiring.line(len(slaves))
        if len(self.wiring.plugs) != len(slaves):
            raise ValueError(f"the wiring has {len(self.wiring.plugs)} slaves, the segment "
                             f"{len(slaves)}")
        self.cut: set[int] = set()          # slaves (indices into wired) unplugged
        self.slaves: list[EmulatedSlave] = []
        self._mems: list[bytearray] = []
        self._irq: int | None = None       # the IRQ all slaves OR in; None: work it out
        self.clock_ns: Callable[[], int] = clock_ns or time.monotonic_ns
        self.dc_model = dc or DcModel()
        # While a frame passes, the slaves see the time it was sent (plus their place on
        # the line, runtime/segment/dc_clock.py): one frame, one instant.
        self._frame_ns: int | None = None
        self.faults = faults or Faults()
        self._rng = random.Random(self.faults.seed)
        self._plans: dict[tuple[int, int, int], list[_Hit]] = {}
        self._by_address: dict[int, list[EmulatedSlave]] | None = None
        self.frames = 0
        self.on_state_change: Callable[[StateChange], None] | None = None
        self.swaps = 0                      # devices swapped in (seeds their clocks)
        clocks = self.dc_model.clocks(len(slaves), self.clock_ns())
        for k, slave in enumerate(slaves):
            slave.dc = clocks[k]
            self._attach(slave)
        self._rewire()
        self._timed: list[EmulatedSlave] = []
        self.timing: Timing | None = None
        self.set_timing(timing)
        # Lossy ports by (index into wired, port); a name or position is resolved once.
        self._lossy: dict[tuple[int, int], float] = {}
        for lossy in self.faults.lossy:
            if not 0 <= lossy.port <= 3 or not 0.0 <= lossy.share <= 1.0:
                raise ValueError(f"lossy port {lossy.port} share {lossy.share}: ports are "
                                 "0-3 and a share is between 0 and 1")
            self._lossy[(self._wired_index(lossy.slave), lossy.port)] = lossy.share

    def set_clock(self, clock_ns: Callable[[], int]) -> None:
        """Live on ``clock_ns`` from now on (a simulated clock, before the first frame):
        the slaves' local clocks start again from their seeded values on it."""
        self.clock_ns = clock_ns
        for slave, clock in zip(self.wired, self.dc_model.clocks(len(self.wired), clock_ns())):
            slave.dc = clock
        self._rewire()

    def _attach(self, slave: EmulatedSlave) -> None:
        """The segment's time and callbacks for ``slave``."""
        slave.clock_ns = self._now
        slave.on_mapping_change = self._plans.clear
        slave.on_state_change = self._state_changed

    def _rewire(self) -> None:
        """Bus order, positions, DL status and port times from the wiring and the cuts."""
        order = self.wiring.order(self.cut)
        times = self.dc_model.port_times(self.wiring, self.cut)
        for k, slave in enumerate(self.wired):
            slave.dc.set_ports(times[k])
            slave.set_ports(self.wiring.links(k, self.cut))
        for pos, k in enumerate(order):
            self.wired[k].position = pos
        self.slaves = [self.wired[k] for k in order]
        self._mems = [s.mem for s in self.slaves]
        self._irq = None
        self._by_address = None
        self._plans.clear()

    def _wired_index(self, slave: EmulatedSlave | str | int) -> int:
        if isinstance(slave, int):
            if not 0 <= slave < len(self.slaves):
                raise ValueError(f"no slave at position {slave} (the frame reaches "
                                 f"{len(self.slaves)})")
            slave = self.slaves[slave]
        elif isinstance(slave, str):
            named = [s for s in self.wired if s.name == slave]
            if len(named) != 1:
                raise ValueError(f"no slave named {slave!r}" if not named
                                 else f"{len(named)} slaves are named {slave!r}")
            slave = named[0]
        return next(k for k, s in enumerate(self.wired) if s is slave)

    def remove_cable(self, slave: EmulatedSlave | str | int) -> list[EmulatedSlave]:
        """Unplug the cable into ``slave``'s port 0 (a slave, its name, or its position):
        the port it was plugged into closes its loop and shows no link, and the frame no
        longer reaches it and the slaves behind it.  Returns the slaves that are gone."""
        k = self._wired_index(slave)
        if self.wiring.plugs[k] is None:
            raise ValueError(f"slave {self.wired[k].name!r} is plugged into the master")
        before = set(map(id, self.slaves))
        self.cut.add(k)
        self._rewire()
        after = set(map(id, self.slaves))
        return [s for s in self.wired if id(s) in before and id(s) not in after]

    def restore_cable(self, slave: EmulatedSlave | str) -> None:
        """Plug back the cable :meth:`remove_cable` removed."""
        self.cut.discard(self._wired_index(slave))
        self._rewire()

    def power_cycle(self, slave: EmulatedSlave | str | int) -> None:
        """Switch ``slave`` (a slave, its name, or its position) off and on: its registers
        reset, its EEPROM keeps what was written (``EmulatedSlave.power_cycle``); its links
        come back as they were."""
        self.wired[self._wired_index(slave)].power_cycle()
        self._rewire()

    def swap(self, slave: EmulatedSlave | str | int,
             replacement: EmulatedSlave) -> EmulatedSlave:
        """Unplug the device at ``slave``'s place (a slave, its name, or its position) and
        plug ``replacement`` in with the same cables: another device, or one of the same
        type with another alias or serial number.  The replacement has just been switched
        on: INIT, registers reset, what its own EEPROM holds loaded (``power_cycle``), its
        local clock from 0; it gets the segment's clock, timing model and callbacks and the
        old device's place (ports, links, position).  The old device is gone from the
        segment, detached from it, and returned."""
        k = self._wired_index(slave)
        old = self.wired[k]
        if any(replacement is s for s in self.wired):
            raise ValueError(f"slave {replacement.name!r} is already in the segment")
        # The cables must fit: every port the place uses (0 toward the master, and those
        # with a slave behind) exists on the replacement and is of the same kind (port
        # descriptor 0x0007, two bits per port: 2 E-bus, 3 MII; ESC Section II).
        for port in (0, *self.wiring.children[k]):
            had, has = (s.mem[Reg.PORT_DESCRIPTOR] >> 2 * port & 3 for s in (old, replacement))
            if has != had:
                kinds = {0: "no port", 1: "an unconfigured port", 2: "E-bus", 3: "Ethernet"}
                raise ValueError(f"{replacement.name!r} does not fit in the place of "
                                 f"{old.name!r}: its port {port} is {kinds[has]}, the cable "
                                 f"there needs {kinds[had]}")
        old.on_state_change = old.on_mapping_change = None
        old.clock_ns = time.monotonic_ns
        replacement.power_cycle()
        self.swaps += 1
        replacement.dc = self.dc_model.powered_on(self.swaps, self.clock_ns())
        self._attach(replacement)
        self.wired[k] = replacement
        self._rewire()
        self._set_slave_timing(replacement)
        self._timed = [s for s in self.wired if s.timing is not None]
        return old

    def set_timing(self, timing: Timing | None) -> None:
        """Give every slave its kind's times (``runtime/segment/timing.py``), or none."""
        self.timing = timing
        for slave in self.wired:
            self._set_slave_timing(slave)
        self._timed = [s for s in self.wired if s.timing is not None]

    def _set_slave_timing(self, slave: EmulatedSlave) -> None:
        slave.timing = self.timing.for_slave(slave) if self.timing is not None else None

    def settle(self) -> None:
        """Make what the slaves finished by now visible (timing model)."""
        for slave in self._timed:
            if slave.busy:
                slave.settle()

    def _now(self) -> int:
        frame = self._frame_ns
        return self.clock_ns() if frame is None else frame

    def _state_changed(self, change: StateChange) -> None:
        if self.on_state_change:
            self.on_state_change(change)

    # -- one frame ---------------------------------------------------------------------------

    def process(self, frame: bytes | bytearray) -> bytearray:
        """The frame as it comes back to the master after passing every slave."""
        buf = bytearray(frame)
        self.frames += 1
        if self._timed:
            self.settle()
        try:
            offsets = datagram_offsets(buf)
        except FrameError:
            return buf                  # an ESC forwards what it cannot process
        view = memoryview(buf)
        self._frame_ns = self.clock_ns()
        try:
            for pos, n in offsets:
                self._datagram(buf, view, pos, n)
        finally:
            self._frame_ns = None
            view.release()
        if self.slaves:
            buf[6] |= 0x02              # the first ESC sets the U/L bit of the source MAC
        return buf

    def process_lossy(self, frame: bytes | bytearray) -> bytearray | None:
        """The frame as it comes back, or ``None`` when a lossy port gave it a CRC error
        (the master drops it).  The frame's receptions are walked in the order they happen
        (``Wiring.receptions``); the ESC whose port received the error counts an invalid
        frame there, every later reception counts a forwarded error, and only the slaves
        that processed the frame before the error commit it: the first ESC to see an error
        and all after it discard their register operations (ESC Section I, "Errors and
        forwarded errors")."""
        if not self._lossy:
            return self.process(frame)
        walk = self.wiring.receptions(self.cut)
        hit = next((i for i, at in enumerate(walk)
                    if at in self._lossy and self._rng.random() < self._lossy[at]), None)
        if hit is None:
            return self.process(frame)
        for i, (k, port) in enumerate(walk[hit:]):
            self.wired[k].frame_error(port, forwarded=i > 0)
        reached = sum(1 for k, port in walk[:hit] if port == 0)
        if reached:
            # The slaves before the error, in bus order, process the frame; it is lost.
            slaves, mems = self.slaves, self._mems
            self.slaves, self._mems = slaves[:reached], mems[:reached]
            self._irq = self._by_address = None
            self._plans.clear()
            try:
                self.process(frame)
            finally:
                self.slaves, self._mems = slaves, mems
                self._irq = self._by_address = None
                self._plans.clear()
        return None

    def _datagram(self, buf: bytearray, view: memoryview, pos: int, n: int) -> None:
        # IRQ: every slave ORs its unmasked ECAT event requests (0x0210 & 0x0200) into the
        # datagram as it passes, before processing it (ETG.1000.4 IRQ field; a real EL1004
        # still shows its DL status event in the reply that reads 0x0110 and clears it).
        # Worked out again only after a datagram that may change it (one that touches the
        # event mask or request, or reads DL status): cyclic frames pay nothing.
        irq = self._irq
        if irq is None:
            irq = 0
            for m in self._mems:
                irq |= m[0x0210] & m[0x0200] | (m[0x0211] & m[0x0201]) << 8
            self._irq = irq
        if irq:
            buf[pos + 8] |= irq & 0xFF
            buf[pos + 9] |= irq >> 8
        cmd = buf[pos]
        if cmd not in _LOGICAL:
            ado, = struct.unpack_from("<H", buf, pos + 4)
            if (ado < Reg.DL_STATUS + 2 and ado + n > Reg.DL_STATUS
                    or ado < _EVENTS_END and ado + n > Reg.ECAT_EVENT_MASK):
                self._irq = None
        data = view[pos + DG_HEADER_LEN:pos + DG_HEADER_LEN + n]
        wkc_at = pos + DG_HEADER_LEN + n
        if cmd in _LOGICAL:
            address, = struct.unpack_from("<I", buf, pos + 2)
            added = self._logical(cmd, address, data)
        else:
            adp, ado = struct.unpack_from("<HH", buf, pos + 2)
            if cmd in _AUTO_INC:
                index = -adp & 0xFFFF
                targets = [self.slaves[index]] if index < len(self.slaves) else []
                added = self._physical(cmd, targets, ado, data, index)
            elif cmd in _CONFIGURED:
                targets = self._addressed(adp)
                added = self._physical(cmd, targets, ado, data,
                                       targets[0].position if targets else -1)
            elif cmd in _BROADCAST:
                added = self._broadcast(cmd, ado, data)
            else:
                return                  # NOP and unknown commands pass untouched
            if cmd in _AUTO_INC or cmd in _BROADCAST:
                struct.pack_into("<H", buf, pos + 2, (adp + len(self.slaves)) & 0xFFFF)
        if added:
            wkc, = struct.unpack_from("<H", buf, wkc_at)
            struct.pack_into("<H", buf, wkc_at, (wkc + added) & 0xFFFF)

    def _addressed(self, address: int) -> list[EmulatedSlave]:
        if self._by_address is None:
            table: dict[int, list[EmulatedSlave]] = {}
            for s in self.slaves:
                table.setdefault(s.station_address, []).append(s)
                if s.alias_enabled and s.alias and s.alias != s.station_address:
                    table.setdefault(s.alias, []).append(s)
            self._by_address = table
        return self._by_address.get(address, [])

    def _physical(self, cmd: int, targets: list[EmulatedSlave], ado: int,
                  data: memoryview, reader: int) -> int:
        """APxx/FPxx on ``targets``; ARMW/FRMW: slave ``reader`` reads, the others write."""
        n = len(data)
        if cmd in (Cmd.ARMW, Cmd.FRMW):
            if not 0 <= reader < len(self.slaves):
                return 0
            added = 0
            received = bytes(data)
            for s in self.slaves:
                if s.position == reader:
                    got = s.read(ado, n)
                    if got is not None:
                        data[:] = got
                        added += 1
                elif s.write(ado, bytes(data) if s.position > reader else received):
                    added += 1
            return added
        added = 0
        for s in targets:
            if cmd in _READS:
                got = s.read(ado, n)
                if got is not None:
                    data[:] = got
                    added += 1
            elif cmd in _WRITES:
                if self._write(s, ado, data):
                    added += 1
            else:                                       # APRW / FPRW
                old = s.read(ado, n)
                wrote = self._write(s, ado, data)
                if old is not None:
                    data[:] = old
                added += (1 if old is not None else 0) + (2 if wrote else 0)
        return added

    def _broadcast(self, cmd: int, ado: int, data: memoryview) -> int:
        n = len(data)
        if cmd == Cmd.BRD and ado + n <= PROCESS_RAM and not (
                ado < Reg.DC_SYSTEM_TIME + 8 and ado + n > Reg.DC_SYSTEM_TIME) and not (
                ado < Reg.DL_STATUS + 2 and ado + n > Reg.DL_STATUS):
            # Plain registers (a cyclic BRD of AL status): no side effects (reading system
            # time and DL status has some), just OR them.
            end = ado + n
            merged = int.from_bytes(data, "little")
            for s in self.slaves:
                merged |= int.from_bytes(s.mem[ado:end], "little")
            data[:] = merged.to_bytes(n, "little")
            return len(self.slaves)
        added = 0
        for s in self.slaves:
            if cmd == Cmd.BWR:
                added += self._write(s, ado, data)
                continue
            got = s.read(ado, n)
            wrote = self._write(s, ado, data) if cmd == Cmd.BRW else False
            if got is not None:
                merged = int.from_bytes(data, "little") | int.from_bytes(got, "little")
                data[:] = merged.to_bytes(n, "little")
                added += 1
            added += 2 if wrote else 0
        return added

    def _write(self, slave: EmulatedSlave, ado: int, data: memoryview) -> bool:
        n = len(data)
        ok = slave.write(ado, bytes(data))
        if ok and ado < _ADDRESS_REGISTERS[1] and ado + n > _ADDRESS_REGISTERS[0]:
            self._by_address = None
        if ok and ado <= Reg.DC_RECEIVE_TIME_PORT0 < ado + n:
            self._latch(slave)
        return ok

    def _latch(self, slave: EmulatedSlave) -> None:
        """Receive times of a 0x0900 write, in the slave's local time: the frame reaches
        each port after the slaves before it and the subtrees behind the ports taken
        before (``DcModel.port_times``)."""
        sent = self._now()
        clock = slave.dc
        slave.latch_receive_times(tuple(None if t is None else clock.local(sent + t)
                                        for t in clock.ports))

    # -- logical addressing ------------------------------------------------------------------

    def _logical(self, cmd: int, address: int, data: memoryview) -> int:
        key = (cmd, address, len(data))
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = self._plan(cmd, address, len(data))
        lrw = cmd == Cmd.LRW
        now = self.clock_ns() / 1e9
        added = 0
        # Plain tuples and locals: this loop runs for every slave of every cyclic frame.
        for slave, mem, writes, reads, registers in plan:
            # Firmware moves process data in SAFEOP and OP exactly (it enables the SMs on its
            # side then).  An ESC without firmware (device emulation, 0x0141 bit 0) serves
            # its FMMUs and SMs whatever AL status says: a real EL2828 and EL2889 in PREOP
            # count an LRW (ethercrab-rs/ethercrab tests/replay-dc.pcapng, working counter
            # 4); their output pins are driven in OP only (EmulatedSlave.outputs).
            running = mem[_ESC_CONFIG] & 0x01 or mem[_AL_STATUS] & 0x0F in RUNNING_STATES
            hit_write = hit_read = False
            # An FMMU that write-maps registers: the ESC's register rules hold as for a
            # physical write (only the mapping differs), checked after the bytes moved.
            before = None if registers is None else bytes(mem[registers[0]:registers[1]])
            for offset, phys, length, bits, sm, completes in writes:   # outputs first (LRW)
                if sm is not None and not (running and sm.enabled and sm.length):
                    continue
                if length == 1:
                    mem[phys] = data[offset]
                elif length:
                    mem[phys:phys + length] = data[offset:offset + length]
                else:
                    for fbyte, pbyte, shift, mask in bits:
                        value = data[fbyte] >> shift if shift >= 0 else data[fbyte] << -shift
                        mem[pbyte] = mem[pbyte] & ~mask & 0xFF | value & mask
                if completes:
                    slave.outputs_written(now)
                hit_write = True
            for offset, phys, length, bits, sm, _ in reads:
                if sm is not None and not (running and sm.enabled and sm.length):
                    continue
                if length == 1:
                    data[offset] = mem[phys]
                elif length:
                    data[offset:offset + length] = mem[phys:phys + length]
                else:
                    for fbyte, pbyte, shift, mask in bits:
                        value = mem[pbyte] << shift if shift >= 0 else mem[pbyte] >> -shift
                        data[fbyte] = data[fbyte] & ~mask & 0xFF | value & mask
                hit_read = True
            if before is not None and registers is not None and hit_write:
                slave.registers_mapped_written(registers[0], before)
            if lrw:
                added += (1 if hit_read else 0) + (2 if hit_write else 0)
            elif hit_read or hit_write:
                added += 1
        return added

    def _plan(self, cmd: int, address: int, n: int) -> list[_Hit]:
        """Per slave whose FMMUs the datagram meets: (slave, its memory, write ops, read
        ops), each op a tuple (frame offset, physical address, byte length or 0, bit
        groups, SM gate, completes the SM)."""
        reads, writes = _LOGICAL[cmd]
        lo, hi = address * 8, (address + n) * 8           # the datagram's logical bits
        plan: list[_Hit] = []
        for slave in self.slaves:
            read_ops: list[_Op] = []
            write_ops: list[_Op] = []
            registers: tuple[int, int] | None = None
            for f in slave.fmmus:
                first = f.logical_start * 8 + f.logical_start_bit
                last = first + f.bit_length                 # exclusive
                b0, b1 = max(lo, first), min(hi, last)
                if b0 >= b1:
                    continue
                phys0 = f.physical_start * 8 + f.physical_start_bit + (b0 - first)
                # Physical addresses are 16 bits: what an FMMU maps past the ESC's last
                # byte is not there to read or write (and a slave's memory never grows).
                b1 = min(b1, b0 + MEMORY_SIZE * 8 - phys0)
                if b0 >= b1:
                    continue
                if writes and f.type & FmmuType.WRITE:
                    write_ops.append(_op(slave, True, b0 - lo, phys0, b1 - b0))
                    first_reg, end_reg = phys0 // 8, min((phys0 + b1 - b0 + 7) // 8,
                                                         PROCESS_RAM)
                    if first_reg < end_reg and not slave.mapped_write_is_plain(first_reg,
                                                                                end_reg):
                        registers = (first_reg, end_reg) if registers is None else (
                            min(registers[0], first_reg), max(registers[1], end_reg))
                if reads and f.type & FmmuType.READ:
                    read_ops.append(_op(slave, False, b0 - lo, phys0, b1 - b0))
            if read_ops or write_ops:
                plan.append((slave, slave.mem, write_ops, read_ops, registers))
        return plan

    # -- running on a link -------------------------------------------------------------------

    def round_trip_ns(self, size: int) -> int:
        """How long after the master starts sending a frame of ``size`` bytes (Ethernet
        header on, no FCS) its last byte is back: the bytes at 100 Mbit/s (80 ns per byte,
        with preamble and start delimiter, padding to 60 bytes and FCS: ETG.1000.4 runs
        on IEEE 802.3 100BASE-TX) plus, per slave the frame reaches, the processing delay
        out, the forwarding delay back and a cable crossed twice (:class:`DcModel`)."""
        on_wire = (max(size, 60) + 4 + 8) * 80
        model = self.dc_model
        return on_wire + len(self.slaves) * (model.processing_ns + model.forwarding_ns
                                             + 2 * model.cable_ns)

    def tick(self) -> None:
        """What the slaves do on their own between frames, as of now (``clock_ns``): work
        done under the timing model shows, SM watchdogs expire.  :meth:`serve` runs it
        every 2 ms, a simulated wire (``runtime/simwire.py``) before every frame."""
        slave_now = self.clock_ns() / 1e9
        self.settle()
        for s in self.wired:            # unplugged slaves time out too
            s.check_watchdog(slave_now)

    def answer(self, frame: bytes | bytearray) -> tuple[bytearray | None, float]:
        """The frame through the wire's faults (:class:`Faults`) and the slaves: the reply
        (``None``: lost on the way out or back, or a CRC error) and how much later than
        usual it comes back (s; a delayed frame)."""
        faults = self.faults
        rng = self._rng
        if faults.drop and rng.random() < faults.drop / 2:
            return None, 0.0                               # lost on the way out
        reply = self.process_lossy(frame)
        if reply is None:
            return None, 0.0                               # a CRC error: dropped
        if faults.drop and rng.random() < faults.drop / 2:
            return None, 0.0                               # lost on the way back
        if faults.corrupt and rng.random() < faults.corrupt and len(reply) > 16:
            bit = rng.randrange((len(reply) - 16) * 8)
            reply[16 + bit // 8] ^= 1 << bit % 8
        if faults.delay and rng.random() < faults.delay:
            return reply, faults.delay_s
        return reply, 0.0

    def serve(self, link: Link, *, duration: float | None = None,
              stop: threading.Event | None = None,
              on_ready: Callable[[], None] | None = None,
              on_tick: Callable[[], None] | None = None) -> None:
        """Answer frames from ``link`` until ``stop`` is set or ``duration`` has passed, in
        real time (the host's clock paces the loop; the slaves live on ``clock_ns``).
        ``on_tick`` runs every 2 ms between frames: where a caller changes the segment
        (a power cycle asked for by a signal) without cutting a frame in two."""
        end = time.monotonic() + duration if duration is not None else None
        delayed: list[tuple[float, int, bytes]] = []
        sequence = 0
        next_tick = 0.0
        if on_ready:
            on_ready()
        while not (stop is not None and stop.is_set()):
            now = time.monotonic()
            if end is not None and now >= end:
                break
            while delayed and delayed[0][0] <= now:
                link.send(heapq.heappop(delayed)[2])
            if now >= next_tick:
                self.tick()
                if on_tick is not None:
                    on_tick()
                next_tick = now + 0.002
            wait = 0.002
            if delayed:
                wait = min(wait, max(0.0, delayed[0][0] - now))
            frame = link.recv(wait)
            if frame is None:
                continue
            reply, late = self.answer(frame)
            if reply is None:
                continue
            if late:
                sequence += 1
                heapq.heappush(delayed, (now + late, sequence, bytes(reply)))
                continue
            link.send(bytes(reply))


def _op(slave: EmulatedSlave, write: bool, frame_bit: int, phys_bit: int,
        bits: int) -> _Op:
    """The access of ``bits`` bits from datagram bit ``frame_bit`` to physical bit
    ``phys_bit``: a byte run when both sides are byte-aligned, otherwise masked byte
    operations (one per pair of frame and memory bytes the bits meet in).  The op is gated
    by the process-data SM it goes through (no working counter while that SM is off or
    the slave is below SAFEOP) and says whether it completes that SM's buffer."""
    phys = phys_bit // 8
    sm = next((s for s in slave.sms if s.active and not s.is_mailbox
               and s.start <= phys < s.end), None)
    last_phys = (phys_bit + bits - 1) // 8
    completes = (write and sm is not None and sm.kind is SmKind.OUTPUTS
                 and last_phys >= sm.end - 1)
    if frame_bit % 8 == 0 and phys_bit % 8 == 0 and bits % 8 == 0:
        return (frame_bit // 8, phys, bits // 8, (), sm, completes)
    # Group the bits by (frame byte, memory byte): within a pair the shift between frame
    # bit and memory bit is constant (it differs by 8 between neighbouring pairs).
    groups: dict[tuple[int, int, int], int] = {}
    for i in range(bits):
        fb, pb = frame_bit + i, phys_bit + i
        key = (fb // 8, pb // 8, fb % 8 - pb % 8)
        groups[key] = groups.get(key, 0) | 1 << (pb % 8 if write else fb % 8)
    # write: memory bits = frame byte >> shift; read: frame bits = memory byte << shift
    masked = tuple((fbyte, pbyte, shift, mask)
                   for (fbyte, pbyte, shift), mask in groups.items())
    return (frame_bit // 8, phys, 0, masked, sm, completes)
