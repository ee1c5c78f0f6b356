"""FMMUs and SyncManagers against the slaves' process data and the cyclic commands: an FMMU
outside every cyclic command, an FMMU that leaves a slave's ``ProcessData`` bits out, a
process-data SyncManager whose direction is not its data's, SyncManager areas that overlap.
The registers are those the slave's InitCmds write on the way up (FMMUs 0x0600 + 16·n,
SyncManagers 0x0800 + 8·n; ESC Section II); a logical bit is placed in the process image
through the cyclic command that carries it (its ``InputOffs``/``OutputOffs`` in its frame's
convention, :attr:`~ecatcfg.eni.plan.Frame.data_shift`)."""

from __future__ import annotations

from ecatcfg.eni.check.context import CheckContext
from ecatcfg.eni.check.rules import declare
from ecatcfg.eni.check.network import is_unmapped_fmmu
from ecatcfg.eni.plan import SlavePlan, register_writes_at
from ecatcfg.record import replace
from ecatcfg.esc import (FMMU_SIZE, SM_DIR_ECAT_READS, SM_DIR_ECAT_WRITES, SM_DIR_MASK,
                         SM_MODE_MAILBOX, SM_MODE_MASK, SM_SIZE, SM_WATCHDOG_ENABLE,
                         WATCHDOG_DIVIDER_DEFAULT, Cmd, FmmuConfig, FmmuType, Reg, SmConfig,
                         Transition, watchdog_base_ns)

OUTSIDE = declare("ENI108", "error", "an FMMU outside every cyclic command", """
    An FMMU the slave's InitCmds set maps logical addresses (start + length) that no
    logical cyclic command (LRD, LWR, LRW) covers whole: outside every command, or past the
    end of the one it starts in.  The bytes outside are in no datagram, so the slave's
    outputs there are never written (its SM watchdog expires) and its inputs never read,
    and the working counter misses the slave where the FMMU is wholly outside.  apply
    refuses the file (eni/contents.py).  An FMMU setting encrypted by EC-Engineer is not
    this: it is ENI003.""")
BITS = declare("ENI109", "error", "a slave's process data that its FMMUs do not map", """
    The bits of a slave's ProcessData/Send (outputs) or Recv (inputs), in the process image,
    must be the bits its write or read FMMUs map there (logical start and start bit to the
    end bit of the last byte; the logical address placed in the image by the cyclic command
    that carries it).  An FMMU that starts at another bit (a logical start bit 4 for data
    that starts at bit 0), ends early (an end bit that leaves 4 inputs out) or was moved
    onto other bits leaves the slave's variables unexchanged: the master reads or writes
    bits the slave never puts in the frame, or another slave's.""")
DIRECTION = declare("ENI110", "error", "a SyncManager's direction is not its data's", """
    A process-data SyncManager the InitCmds enable has a control byte (0x0804 + 8·n, bits
    2-3: 01 the master writes, 00 the master reads) that is not the direction of its data:
    ProcessData/SmN Type (Outputs, Inputs) or the FMMU over it (write, read).  The ESC does
    not take the master's outputs into a SyncManager it reads, nor hand it inputs to a
    SyncManager it writes; a slave with firmware refuses SAFEOP (AL status code 0x001D for
    outputs, 0x001E for inputs; SOES ESC_checkSM23).""")
SM_OVERLAP = declare("ENI120", "error", "two SyncManagers' areas overlap", """
    Two SyncManagers the InitCmds enable on the way up have overlapping areas (start and
    length, ESC Section I, SyncManager): the slave's mailbox and process data then write
    into each other (a mailbox as long as the next area reaches into it: no reply arrives).
    The three buffers a buffered SyncManager takes in the ESC's memory are not counted:
    vendors' ESI files place 1-byte buffered SyncManagers at consecutive addresses (the
    Beckhoff EP2xxx at 0x1000 and 0x1001).""")

# The ESC's process data RAM starts at 0x1000 (ESC Section I, address space); an FMMU below
# maps a register (a mailbox FMMU over SM1's status byte 0x080D), not process data.
_PROCESS_MEMORY = 0x1000
# A logical cyclic command: logical start, length, image offset of its input data, reads?,
# image offset of its output data, writes? (offsets in bytes of the image).
Window = tuple[int, int, int, bool, int, bool]
_UP = (Transition.IP, Transition.PS, Transition.SO)
_INPUT_CMDS = (Cmd.LRD, Cmd.LRW)
_OUTPUT_CMDS = (Cmd.LWR, Cmd.LRW)


WATCHDOG = declare("ENI121", "error", "an SM watchdog shorter than the cycle", """
    A slave's output SyncManager has its watchdog on (control byte bit 6) and the SM
    watchdog time the InitCmds set (0x0420 × (divider 0x0400 + 2) × 40 ns; ESC Section II)
    is not longer than the shortest cycle of the ENI (Cyclic/CycleTime, else the slave's
    DC CycleTime0): the watchdog
    expires between two output frames.  A slave with firmware then leaves OP for
    SAFEOP+ERR with AL status code 0x001B (sync manager watchdog) and clears its outputs;
    one without firmware clears its output pins.""")


def check(ctx: CheckContext) -> None:
    for item in ctx.plan.unsupported:
        if is_unmapped_fmmu(item.what):
            slave = next((s for s in ctx.plan.slaves if s.name == item.slave), None)
            ctx.add(OUTSIDE, item.line, item.what, slave)
    windows = _windows(ctx)
    cycles = [c.cycle_time for c in ctx.plan.cyclic if c.cycle_time]
    for slave in ctx.plan.slaves:
        _bits(ctx, slave, windows)
        _sync_managers(ctx, slave)
        # The cycle: the ENI's Cyclic/CycleTime, else the slave's DC SYNC0 cycle.
        dc = slave.dc.cycle_time0 // 1000 if slave.dc is not None else 0
        if cycles or dc:
            _watchdog(ctx, slave, min(cycles) if cycles else dc)


def _last_word(slave: SlavePlan, register: int) -> tuple[int, int] | None:
    """The last value (and command position) the InitCmds write to a 16-bit register."""
    found = None
    for _, record, _, position in register_writes_at(slave, register, 2, 1):
        found = (int.from_bytes(record, "little"), position)
    return found


def _watchdog(ctx: CheckContext, slave: SlavePlan, cycle_us: int) -> None:
    watched = [SmConfig.from_bytes(r) for n, r, t, _ in
               register_writes_at(slave, Reg.SM0, SM_SIZE, 16) if n >= 2 and _going_up(t)]
    if not any(sm.enable and sm.length and sm.control & SM_WATCHDOG_ENABLE
               and sm.control & SM_DIR_MASK == SM_DIR_ECAT_WRITES for sm in watched):
        return
    units = _last_word(slave, Reg.WATCHDOG_SM)
    if units is None:
        return                       # the ESC's own 100 ms: not set by this file
    divider = _last_word(slave, Reg.WATCHDOG_DIVIDER)
    base = watchdog_base_ns(divider[0] if divider else WATCHDOG_DIVIDER_DEFAULT)
    limit_ns = units[0] * base
    if units[0] and limit_ns <= cycle_us * 1000:
        ctx.add(WATCHDOG, _line(ctx, slave, units[1]),
                f"SM watchdog {limit_ns / 1000:g} µs ({units[0]} × {base} ns), the cycle "
                f"{cycle_us} µs: it expires between two output frames; the slave leaves "
                "OP with AL status code 0x001B", slave)


def _line(ctx: CheckContext, slave: SlavePlan, position: int) -> int | None:
    return ctx.lines.listed(slave, "InitCmds", position, len(slave.init_cmds))


def _going_up(transitions: frozenset[Transition]) -> bool:
    return any(t in _UP for t in transitions)


def _windows(ctx: CheckContext) -> list[Window]:
    """(logical start, length, image offset of the inputs, reads?, image offset of the
    outputs, writes?) of each logical cyclic command, the offsets in bytes of the image."""
    out = []
    for cyclic in ctx.plan.cyclic:
        for frame in cyclic.frames:
            shift = frame.data_shift
            for cmd in frame.cmds:
                if cmd.addr is None or cmd.cmd not in (Cmd.LRD, Cmd.LWR, Cmd.LRW):
                    continue
                out.append((cmd.addr, cmd.length, cmd.input_offs + shift,
                            cmd.cmd in _INPUT_CMDS, cmd.output_offs + shift,
                            cmd.cmd in _OUTPUT_CMDS))
    return out


def _image_bits(fmmu: FmmuConfig, reads: bool,
                windows: list[Window]) -> set[int] | None:
    """The image bits (inputs for a read FMMU, outputs for a write one) the FMMU maps; None
    when a byte of it is in no command of that direction (ENI108 says so)."""
    bits: set[int] = set()
    first = fmmu.logical_start * 8 + fmmu.logical_start_bit
    for bit in range(first, first + max(fmmu.bit_length, 0)):
        byte = bit // 8
        for addr, length, in_offs, in_ok, out_offs, out_ok in windows:
            if addr <= byte < addr + length and (in_ok if reads else out_ok):
                offset = in_offs if reads else out_offs
                bits.add((offset + byte - addr) * 8 + bit % 8)
                break
        else:
            return None
    return bits


def _bits(ctx: CheckContext, slave: SlavePlan,
          windows: list[Window]) -> None:
    pd = slave.process_data
    if pd is None or not windows:
        return
    if any(u.slave == slave.name and u.what.startswith("FMMU") for u in ctx.plan.unsupported):
        return                       # FMMUs left out of the plan: ENI003 / ENI108
    fmmus = [(FmmuConfig.from_bytes(record), position)
             for _, record, transitions, position
             in register_writes_at(slave, Reg.FMMU0, FMMU_SIZE, 16) if _going_up(transitions)]
    fmmus = [(f, p) for f, p in fmmus if f.active and f.length and f.type != FmmuType.UNUSED
             and f.physical_start >= _PROCESS_MEMORY]
    for kind, ranges, reads in (("Recv", pd.recv, True), ("Send", pd.send, False)):
        want = {b for r in ranges for b in range(r.bit_start, r.bit_start + r.bit_length)}
        mine = [(f, p) for f, p in fmmus
                if f.type & (FmmuType.READ if reads else FmmuType.WRITE)]
        if not want or not mine:
            continue                 # no FMMU at all: ENI102
        mapped: set[int] = set()
        for fmmu, _ in mine:
            found = _image_bits(fmmu, reads, windows)
            if found is None:
                return               # outside the commands: ENI108
            mapped |= found
        missing = sorted(want - mapped)
        if missing:
            fmmu, position = _owner(mine, set(missing), reads, windows)
            runs = _runs(missing)
            ctx.add(BITS, _line(ctx, slave, position),
                    f"ProcessData/{kind} bit(s) {runs} ({len(missing)} of {len(want)}) are "
                    f"mapped by no {'read' if reads else 'write'} FMMU (FMMU at logical "
                    f"0x{fmmu.logical_start:08X}.{fmmu.logical_start_bit}, "
                    f"{fmmu.length} byte(s) to bit {fmmu.logical_stop_bit}): "
                    f"{'inputs the master never reads' if reads else 'outputs the slave never gets'}",
                    slave)


def _owner(mine: list[tuple[FmmuConfig, int]], missing: set[int], reads: bool,
           windows: list[Window]) -> tuple[FmmuConfig, int]:
    """The FMMU a finding about ``missing`` bits names: the one whose whole bytes hold
    them (its start or stop bit leaves them out; a slave may have several FMMUs of one
    direction, an EJ2918 two write ones), else the first."""
    for fmmu, position in mine:
        whole = replace(fmmu, logical_start_bit=0, logical_stop_bit=7)
        if (_image_bits(whole, reads, windows) or set()) & missing:
            return fmmu, position
    return mine[0]


def _runs(bits: list[int]) -> str:
    runs: list[tuple[int, int]] = []
    for b in bits:
        if runs and runs[-1][1] == b - 1:
            runs[-1] = (runs[-1][0], b)
        else:
            runs.append((b, b))
    text = ", ".join(f"{a}..{b}" if a != b else f"{a}" for a, b in runs[:3])
    return text + (", ..." if len(runs) > 3 else "")


def _sync_managers(ctx: CheckContext, slave: SlavePlan) -> None:
    last: dict[int, tuple[SmConfig, int]] = {}
    for n, record, transitions, position in register_writes_at(slave, Reg.SM0, SM_SIZE, 16):
        if _going_up(transitions):
            last[n] = (SmConfig.from_bytes(record), position)
    enabled = {n: (sm, p) for n, (sm, p) in last.items() if sm.enable and sm.length}
    types = {s.number: s.type for s in (slave.process_data.sms if slave.process_data else [])}
    fmmus = [FmmuConfig.from_bytes(r) for _, r, t, _ in
             register_writes_at(slave, Reg.FMMU0, FMMU_SIZE, 16) if _going_up(t)]
    for n, (sm, position) in sorted(enabled.items()):
        if sm.control & SM_MODE_MASK == SM_MODE_MAILBOX:
            continue
        kind = types.get(n)
        if kind not in ("Outputs", "Inputs"):
            over = [f.type for f in fmmus if f.active and f.length
                    and f.physical_start <= sm.start < f.physical_start + f.length]
            kind = ("Outputs" if over and all(t == FmmuType.WRITE for t in over) else
                    "Inputs" if over and all(t == FmmuType.READ for t in over) else None)
        if kind is None:
            continue
        want = SM_DIR_ECAT_WRITES if kind == "Outputs" else SM_DIR_ECAT_READS
        if sm.control & SM_DIR_MASK != want:
            said = "reads" if sm.control & SM_DIR_MASK == SM_DIR_ECAT_READS else \
                "writes" if sm.control & SM_DIR_MASK == SM_DIR_ECAT_WRITES else "neither reads nor writes"
            code = "0x001D" if kind == "Outputs" else "0x001E"
            ctx.add(DIRECTION, _line(ctx, slave, position),
                    f"SM{n} ({kind}) is set with control byte 0x{sm.control:02X}: the master "
                    f"{said} it; a slave refuses SAFEOP with AL status code {code}", slave)
    areas = sorted((sm.start, sm.start + sm.length, n, p) for n, (sm, p) in enabled.items())
    for (s0, e0, n0, p0), (s1, e1, n1, _) in zip(areas, areas[1:]):
        if s1 < e0:
            # Named at the one that reaches into the next: its length is the usual fault.
            ctx.add(SM_OVERLAP, _line(ctx, slave, p0),
                    f"SM{n0} (0x{s0:04X}..0x{e0 - 1:04X}) reaches into SM{n1} (0x{s1:04X}.."
                    f"0x{e1 - 1:04X})", slave)
