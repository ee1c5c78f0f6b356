"""The logical process image: FMMUs, cyclic frames, working counters and variables.

Two layouts (``docs/eni-exports.md`` §4):

* ``lrw`` (EC-Engineer): one LRW per frame from 0x10000000; a slave's outputs and inputs
  share one region of max(outputs, inputs) bits, so the next slave's data never overlaps.
* ``lrd_lwr`` (TwinCAT): outputs in LWR windows from 0x01000000, inputs in LRD windows
  from the next 2 KiB boundary after all outputs.

Slaves whose data is not a whole number of bytes (1-bit digital terminals) are packed at
the bit where the previous one ended, as real configurators do, so four 2-channel terminals
share one byte; byte-sized data starts on a byte.  A frame never carries more than
1500 bytes of EtherCAT payload (2-byte header + 12 bytes per datagram + data), so no datagram
exceeds 1486 data bytes; a slave is never split across two datagrams.

The process image is compact (EC-Engineer style): every cyclic command gets its own byte
range, the same in the input and the output image; process data first, then the status
commands.  A command's ``InputOffs``/``OutputOffs`` is where its data sits in the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ecatcfg.eni.plan import BitRange, CyclicCmd, Frame, Variable
from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.errors import EcatcfgError
from ecatcfg.eni.standard import mailbox_state_fmmu, pd_fmmu
from ecatcfg.esc import (FRAME_PAYLOAD, MAILBOX_STATE_ADDR, Cmd, FmmuConfig, FmmuType, Reg,
                         frame_bytes, wkc_increment)
from ecatcfg.esi import datatypes

LRW_BASE = 0x10000000
LWR_BASE = 0x01000000
WINDOW_ALIGN = 0x800
STATE_ALL = ["PREOP", "SAFEOP", "OP"]
STATE_PD = ["SAFEOP", "OP"]


class LayoutError(EcatcfgError):
    """A slave whose process data cannot be laid out; ``slave`` is its index in the
    topology file (where the error points)."""

    def __init__(self, message: str, slave: int) -> None:
        super().__init__(message)
        self.slave = slave


@dataclass(slots=True)
class SlaveLayout:
    sm_bits: dict[int, int] = field(default_factory=dict)     # PD SM -> assigned bits
    fmmus: list[tuple[FmmuConfig, str]] = field(default_factory=list)   # FMMU 0, 1, ...
    send: BitRange | None = None
    recv: BitRange | None = None
    status_bit: int | None = None
    outputs: list[Variable] = field(default_factory=list)
    inputs: list[Variable] = field(default_factory=list)


@dataclass(slots=True)
class Layout:
    slaves: list[SlaveLayout]
    frames: list[Frame]
    image_size: int
    mailbox_state_count: int


@dataclass(slots=True)
class _Region:
    slave: int                     # index into the slave list
    bit: int                       # bit offset inside its datagram
    bits: int


@dataclass(slots=True)
class _Datagram:
    cmd: Cmd
    regions: list[_Region] = field(default_factory=list)
    bits: int = 0
    addr: int = 0
    image_offs: int = 0

    @property
    def length(self) -> int:
        return (self.bits + 7) // 8


# ((SM, bits) of outputs, (SM, bits) of inputs) of one slave
SlaveBits = tuple[list[tuple[int, int]], list[tuple[int, int]]]


def pd_bits(slave: ResolvedSlave) -> SlaveBits:
    """((SM, bits) of outputs, (SM, bits) of inputs), SMs in number order."""
    out: list[tuple[int, int]] = []
    inp: list[tuple[int, int]] = []
    for sm in sorted(slave.device.sms, key=lambda s: s.number):
        if sm.is_mailbox or sm.virtual or sm.type not in ("Outputs", "Inputs"):
            continue
        bits = sum(e.bit_len for p in slave.assigned(sm.number) for e in p.entries)
        (out if sm.type == "Outputs" else inp).append((sm.number, bits))
    return out, inp


def fmmu_groups(slave: ResolvedSlave, sms: list[tuple[int, int]],
                direction: str) -> list[list[tuple[int, int]]]:
    """The SMs (with data) of one direction, grouped by the FMMU that maps them.

    One FMMU per SM, unless the ESI declares fewer ``Outputs``/``Inputs`` FMMUs than there
    are SMs with data: then SMs whose memory follows on from the previous one's (EL2809:
    SM0 0x0F00 + SM1 0x0F01, one byte each) share one FMMU, as TwinCAT maps them.  Only a
    whole-byte SM can be followed that way: the FMMU maps logical bits to physical bits
    one to one.
    """
    used = [(n, bits) for n, bits in sms if bits]
    declared = sum(1 for f in slave.device.fmmus if f.type == direction)
    if not slave.device.fmmus or declared >= len(used):
        return [[x] for x in used]
    start = {sm.number: sm.start_address or 0 for sm in slave.device.sms}
    groups: list[list[tuple[int, int]]] = []
    for n, bits in used:
        if groups:
            last_n, last_bits = groups[-1][-1]
            whole = all(b % 8 == 0 for _, b in groups[-1])
            if whole and start[last_n] + last_bits // 8 == start[n]:
                groups[-1].append((n, bits))
                continue
        groups.append([(n, bits)])
    return groups


def _place(cursor: int, bits: int) -> int:
    """Where a region of ``bits`` starts: byte-sized data on a byte, bit-sized at the bit."""
    return cursor if bits % 8 else (cursor + 7) // 8 * 8


def build(slaves: list[ResolvedSlave], layout: str, uses_dc: bool,
          mailbox_state: list[int]) -> Layout:
    """Lay out the process data of ``slaves`` (bus order).  ``mailbox_state`` lists the
    indices of slaves polled through the mailbox-state bit."""
    sizes = [pd_bits(s) for s in slaves]
    if layout == "lrw":
        for slave, (out, inp) in zip(slaves, sizes):
            if slave.device.use_lrd_lwr and (out or inp):
                # ETG.2000 Type/@UseLrdLwr: an LRW would reach the device, which does not
                # take one (Beckhoff EL2002 rev 0x270B0000, Murrelektronik Impact67).
                raise LayoutError(f"slave {slave.name!r}: its ESI says UseLrdLwr (device "
                                  f"{slave.device.type_name} takes process data by LRD and "
                                  "LWR, not LRW); set the master's `layout: lrd_lwr`",
                                  slave.index)
    status_len = (len(mailbox_state) + 7) // 8
    misc = [2] + ([status_len] if mailbox_state else []) + ([4] if uses_dc else [])
    kinds = [Cmd.LRW] if layout == "lrw" else [Cmd.LWR, Cmd.LRD]

    frames: list[list[_Datagram]] = [[_Datagram(k) for k in kinds]]
    for i, (out, inp) in enumerate(sizes):
        o, n = sum(b for _, b in out), sum(b for _, b in inp)
        if not o and not n:
            continue
        wants = [max(o, n)] if layout == "lrw" else [o, n]
        for attempt in range(2):
            dgs = frames[-1]
            starts = [_place(d.bits, w) for d, w in zip(dgs, wants)]
            lengths = [(s + w + 7) // 8 if w else d.length
                       for d, s, w in zip(dgs, starts, wants)]
            extra = misc if len(frames) == 1 else []
            if frame_bytes([x for x in lengths if x] + extra) <= FRAME_PAYLOAD:
                for d, s, w in zip(dgs, starts, wants):
                    if w:
                        d.regions.append(_Region(i, s, w))
                        d.bits = s + w
                break
            if attempt or not any(d.regions for d in dgs):
                raise LayoutError(f"slave {slaves[i].name!r} has more process data "
                                  f"({(max(wants) + 7) // 8} bytes) than one frame can carry",
                                  slaves[i].index)
            frames.append([_Datagram(k) for k in kinds])

    # Logical addresses: consecutive windows; LRD windows after all LWR ones (TwinCAT).
    datagrams = [d for f in frames for d in f if d.regions]
    addr = {Cmd.LRW: LRW_BASE, Cmd.LWR: LWR_BASE}
    for d in datagrams:
        if d.cmd != Cmd.LRD:
            d.addr = addr[d.cmd]
            addr[d.cmd] += d.length
    lrd = LWR_BASE + max(WINDOW_ALIGN, -(-(addr[Cmd.LWR] - LWR_BASE) // WINDOW_ALIGN)
                         * WINDOW_ALIGN)
    for d in datagrams:
        if d.cmd == Cmd.LRD:
            d.addr, lrd = lrd, lrd + d.length

    # The image: process data first, then the status commands of the first frame.
    offs = 0
    for d in datagrams:
        d.image_offs, offs = offs, offs + d.length
    out_frames: list[Frame] = []
    results = [SlaveLayout() for _ in slaves]
    for n, f in enumerate(frames):
        cmds: list[CyclicCmd] = []
        if n == 0:
            if uses_dc:
                ref = next(s for s in slaves if s.dc_mode and s.dc_mode.assign_activate)
                cmds.append(CyclicCmd(STATE_ALL, "DC; ARMW; System Time Register", Cmd.ARMW,
                                      4, adp=(-ref.position) & 0xFFFF, ado=Reg.DC_SYSTEM_TIME,
                                      input_offs=offs, output_offs=offs))
                offs += 4
            if mailbox_state:
                cmds.append(CyclicCmd(STATE_ALL, "MISC; LRD; Poll Mailbox State", Cmd.LRD,
                                      status_len, addr=MAILBOX_STATE_ADDR,
                                      input_offs=offs, output_offs=offs))
                offs += status_len
        for d in f:
            if not d.regions:
                continue
            cmds.append(CyclicCmd(STATE_PD, f"PD; {d.cmd.name};", d.cmd, d.length, addr=d.addr,
                                  cnt=_wkc(d, sizes), input_offs=d.image_offs,
                                  output_offs=d.image_offs))
            for r in d.regions:
                _map_region(results[r.slave], slaves[r.slave], sizes[r.slave], d, r)
        if n == 0:
            cmds.append(CyclicCmd(STATE_ALL, "MISC; BRD; AL Status Register", Cmd.BRD, 2,
                                  adp=0, ado=Reg.AL_STATUS, cnt=len(slaves),
                                  input_offs=offs, output_offs=offs))
            offs += 2
        out_frames.append(Frame(cmds))

    for bit, i in enumerate(mailbox_state):
        results[i].status_bit = bit
        results[i].fmmus.insert(_mailbox_state_position(slaves[i], results[i]),
                                (mailbox_state_fmmu(MAILBOX_STATE_ADDR, bit), "mailbox state"))
    return Layout(results, out_frames, offs, len(mailbox_state))


def _mailbox_state_position(slave: ResolvedSlave, result: SlaveLayout) -> int:
    """Which FMMU the mailbox-state bit takes: the ESI's Fmmu list gives each FMMU's use
    in order (ETG.2000 ``Device/Fmmu``), and the process-data FMMUs the slave uses keep
    that order around it, as TwinCAT numbers them (``Fmmu`` MBoxState, Outputs, Inputs:
    FMMU 0 mailbox state, 1 outputs, 2 inputs; Inputs, MBoxState: 0 inputs, 1 mailbox
    state).  Before it: as many of the used process-data FMMUs of each kind as the ESI
    lists of that kind before its MBoxState entry."""
    kinds = [f.type for f in slave.device.fmmus]
    before = kinds[:kinds.index("MBoxState")] if "MBoxState" in kinds else kinds
    used = [label.capitalize() for _, label in result.fmmus]
    return sum(min(used.count(kind), before.count(kind)) for kind in ("Outputs", "Inputs"))


def _wkc(d: _Datagram, sizes: list[SlaveBits]) -> int:
    """Expected working counter: LRW +2 per slave written, +1 per slave read; LWR +1 per
    slave with outputs; LRD +1 per slave with inputs (ETG.1000.4; IgH ``datagram_pair.c``,
    ``docs/protocol-notes.md`` §1)."""
    total = 0
    for r in d.regions:
        out, inp = sizes[r.slave]
        has_out, has_in = any(b for _, b in out), any(b for _, b in inp)
        total += wkc_increment(d.cmd, has_in and d.cmd != Cmd.LWR,
                               has_out and d.cmd != Cmd.LRD)
    return total


def _map_region(result: SlaveLayout, slave: ResolvedSlave, size: SlaveBits, d: _Datagram,
                r: _Region) -> None:
    out, inp = size
    directions = []
    if d.cmd in (Cmd.LRW, Cmd.LWR):
        directions.append(("outputs", out, FmmuType.WRITE))
    if d.cmd in (Cmd.LRW, Cmd.LRD):
        directions.append(("inputs", inp, FmmuType.READ))
    for label, sms, kind in directions:
        bit = r.bit
        start = d.image_offs * 8 + r.bit
        total = 0
        for sm_number, bits in sms:
            result.sm_bits[sm_number] = bits
        for group in fmmu_groups(slave, sms, label.capitalize()):
            sm = next(s for s in slave.device.sms if s.number == group[0][0])
            bits = sum(b for _, b in group)
            result.fmmus.append((pd_fmmu(d.addr * 8 + bit, bits, sm.start_address or 0,
                                         kind), label))
            for sm_number, sm_bits in group:
                _variables(result, slave, sm_number, d.image_offs * 8 + bit, label)
                bit += sm_bits
            total += bits
        if total:
            rng = BitRange(start, total)
            if label == "outputs":
                result.send = rng
            else:
                result.recv = rng


def _variables(result: SlaveLayout, slave: ResolvedSlave, sm: int, bit: int,
               label: str) -> None:
    target = result.outputs if label == "outputs" else result.inputs
    for pdo in slave.assigned(sm):
        pdo_name = pdo.name           # a module's carries its position: "Module 2 (X).In"
        for e in pdo.entries:
            if e.index:
                entry = e.name or f"0x{e.index:04X}:{e.subindex:02X}"
                target.append(Variable(f"{slave.name}.{pdo_name}.{entry}", e.bit_len, bit,
                                       iec_type(e.data_type, e.bit_len)))
            bit += e.bit_len


def iec_type(data_type: str | None, bits: int) -> str:
    """The IEC 61131 name a process variable is declared with."""
    if bits == 1:
        return "BOOL"
    if data_type:
        base = datatypes.canonical(data_type)
        if base is not None and datatypes.bit_size(base) == bits:
            return base
    known = {8: "USINT", 16: "UINT", 32: "UDINT", 64: "ULINT"}
    if bits in known:
        return known[bits]
    return f"BIT{bits}" if bits < 8 else f"ARRAY [0..{(bits + 7) // 8 - 1}] OF BYTE"
