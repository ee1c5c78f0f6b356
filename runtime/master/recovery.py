"""Keeping a running network whole: slaves that drop out and come back.

While the network cycles, the :class:`Supervisor` watches every cycle's working counters
and the AL status the cyclic frames carry (the ENI's ``BRD`` of 0x0130, whose working
counter counts the slaves that answered and whose data ORs their states).  When either is
off it reads each slave's AL status: a slave that does not answer (a cable pulled, power
lost) or that left the network's state (SAFEOP+ERR after its SM watchdog expired) goes
*offline*: it is reported once, the working counters the cycle expects are lowered by what
it adds (:func:`wkc_share`), and its input bits in the process image are cleared every
cycle and marked invalid, so the other slaves' data stays valid and checked.

While a slave is offline, every :data:`PROBE_INTERVAL` one frame reads the station address
and AL status at every position.  A slave that still has its station address kept its
configuration (a cable pulled and plugged back): its errors are acknowledged and it is
brought from its state back up to the network's.  A position that answers with station
address 0 holds a slave that was powered off and on (or replaced): its identity is read
from its SII and compared with the ENI (another device is refused and reported, and is not
configured), then its InitCmds are replayed from INIT up to the network's state, with its
DC system time offset and delay set again first.  Failed attempts are retried with a
back-off (:data:`BACKOFF_FIRST` doubling up to :data:`BACKOFF_MAX`), at most
:data:`MAX_ATTEMPTS` times; a later attempt starts from INIT.

All of this runs between the cycles, one round of frames per cycle (``lockstep.one_round``),
so the cyclic frames of the other slaves never stop: the recovery's frames are sent after
the cycle's, with the cycle time as their timeout.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Protocol

from ecatcfg.runtime.clock import monotonic, using
from ecatcfg.eni.plan import NetworkPlan, SlavePlan, register_writes
from ecatcfg.esc import (AL_ERROR_ACK, AL_STATE_MASK, AL_STATUS_ERROR, AUTO_INCREMENT_CMDS,
                         BROADCAST_CMDS, CONFIGURED_ADDRESS_CMDS, FMMU_SIZE, LOGICAL_CMDS,
                         REGISTER_READS, REGISTER_WRITES, AlState, Cmd, FmmuConfig, FmmuType,
                         Reg, Transition, al_state_name, al_status_name, wkc_increment)
from ecatcfg.record import field, record
from ecatcfg.runtime.master import hotconnect
from ecatcfg.runtime.master.hotconnect import at_position
from ecatcfg.runtime.master.lockstep import Job, Pending, Step, one_round, start, until_answered
from ecatcfg.runtime.master.replay import (TIMEOUT_COMMAND, TIMEOUT_STATE, ApplyError,
                                           MailboxChannel, MailboxStatePoll, SlaveProgress)
from ecatcfg.runtime.master.transition import slave_transition_job
from ecatcfg.runtime.wire import Datagram

if TYPE_CHECKING:
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.master.cyclic import CyclicFrames, _Slot
    from ecatcfg.runtime.master.diagnose import Cause
    from ecatcfg.runtime.master.transport import Transport

PROBE_INTERVAL = 0.1           # s between looks for the slaves that are offline
DIAGNOSE_INTERVAL = 0.02       # s at least between two AL status reads of every slave
BACKOFF_FIRST = 0.1            # s after the first failed attempt, doubling ...
BACKOFF_MAX = 5.0              # ... up to this
MAX_ATTEMPTS = 5               # attempts to bring a slave back before giving up

_UP = {AlState.INIT: Transition.IP, AlState.PREOP: Transition.PS,
       AlState.SAFEOP: Transition.SO}
_READS_FROM = (FmmuType.READ, FmmuType.READ_WRITE)
_WRITES_TO = (FmmuType.WRITE, FmmuType.READ_WRITE)

_AL_STATE_AND_ERROR = AL_STATE_MASK | AL_STATUS_ERROR   # what the cyclic AL status BRD shows


@record
class SlaveHealth:
    """One slave as the supervisor sees it (``Network.health``)."""

    name: str
    position: int               # where it is on the line (auto-increment position)
    online: bool = True         # in the network's state, its data exchanged and valid
    reason: str = ""            # why it is offline
    since: float = 0.0          # monotonic() it went offline
    attempts: int = 0           # failed attempts to bring it back
    joining: bool = False       # being brought back now
    gave_up: bool = False       # MAX_ATTEMPTS failed: Network.recover() tries again
    next_try: float = 0.0
    refused: set[tuple[object, ...]] = field(default_factory=set)   # reported, once each
    cause: list[str] = field(default_factory=list)  # why it left, or its last refusal


# -- what each slave adds to the cyclic frames --------------------------------------------------

def fmmus(slave: SlavePlan) -> list[FmmuConfig]:
    """The FMMUs the slave's InitCmds configure (their last setting that activates them)."""
    out = []
    for records in register_writes(slave, Reg.FMMU0, FMMU_SIZE, 16).values():
        active = [FmmuConfig.from_bytes(data) for data, _ in records]
        last = [f for f in active if f.active]
        if last:
            out.append(last[-1])
    return out


def _overlaps(f: FmmuConfig, addr: int, length: int) -> bool:
    return f.length > 0 and f.logical_start < addr + length and addr < f.logical_start + f.length


def wkc_share(slave: SlavePlan, cmd_slot: _Slot) -> int:
    """What ``slave`` adds to the working counter of one cyclic command (ETG.1000.4): a
    logical read adds 1 where a read FMMU of the slave overlaps the command's window, a
    logical write 2 where a write FMMU does; broadcasts count every slave; physical
    commands only the slave addressed."""
    c = cmd_slot.cmd
    if c.cmd in (Cmd.ARMW, Cmd.FRMW):
        return wkc_increment(c.cmd, slave.dc is not None, False)
    if c.cmd in LOGICAL_CMDS:
        mapped = [f for f in fmmus(slave) if _overlaps(f, c.addr or 0, c.length)]
        reads = c.cmd != Cmd.LWR and any(f.type in _READS_FROM for f in mapped)
        writes = c.cmd != Cmd.LRD and any(f.type in _WRITES_TO for f in mapped)
        return wkc_increment(c.cmd, reads, writes)
    if c.cmd in AUTO_INCREMENT_CMDS:
        addressed = c.adp == slave.auto_inc_addr
    elif c.cmd in CONFIGURED_ADDRESS_CMDS:
        addressed = c.adp == slave.phys_addr
    else:
        addressed = c.cmd in BROADCAST_CMDS
    return wkc_increment(c.cmd, addressed and c.cmd in REGISTER_READS,
                         addressed and c.cmd in REGISTER_WRITES)


def input_bits(slave: SlavePlan, cyclic: CyclicFrames) -> list[tuple[int, int]]:
    """The input image bytes (offset, bit mask) the slave's read FMMUs fill: what is
    cleared while it is offline."""
    masks: dict[int, int] = {}
    for frame in cyclic.frames:
        for s in frame:
            c = s.cmd
            if c.cmd not in (Cmd.LRD, Cmd.LRW):
                continue
            addr = c.addr or 0
            for f in fmmus(slave):
                if f.type not in (FmmuType.READ, FmmuType.READ_WRITE) or \
                        not _overlaps(f, addr, c.length):
                    continue
                first = f.logical_start * 8 + f.logical_start_bit
                last = (f.logical_start + f.length - 1) * 8 + f.logical_stop_bit
                for bit in range(max(first, addr * 8), min(last, (addr + c.length) * 8 - 1) + 1):
                    at = s.in_at + bit // 8 - addr
                    masks[at] = masks.get(at, 0) | 1 << bit % 8
    return sorted(masks.items())


# -- the supervisor ------------------------------------------------------------------------------

class SupervisedMaster(Protocol):
    """What the supervisor uses of the master that cycles
    (:class:`~ecatcfg.runtime.master.bringup.Master`): the master creates its supervisor,
    so this module names the master's parts it needs instead of importing it."""

    @property
    def plan(self) -> NetworkPlan: ...
    @property
    def slaves(self) -> list[SlavePlan]: ...
    @property
    def state(self) -> AlState: ...
    @property
    def cyclic(self) -> CyclicFrames: ...
    @property
    def transport(self) -> Transport: ...
    @property
    def accept_newer_revision(self) -> bool: ...
    @property
    def progress(self) -> dict[str, SlaveProgress]: ...
    @property
    def mailboxes(self) -> dict[str, MailboxChannel]: ...
    @property
    def esi(self) -> Library | None: ...

    def layout(self, present: set[str]) -> None: ...
    def dc_rejoin_job(self, slave: SlavePlan) -> Step[None]: ...
    def dc_wait_job(self, slave: SlavePlan) -> Step[None]: ...
    def _event(self, kind: str, text: str, slave: str | None = None) -> None: ...


class Supervisor:
    """Watches a cycling network and brings back its slaves (see the module docstring)."""

    def __init__(self, master: SupervisedMaster, absent_groups: set[str] | None = None) -> None:
        """``absent_groups``: the heads of the hot-connect groups that were not on the line
        at start-up (``runtime/master/hotconnect.py``); their slaves start offline."""
        self.master = master
        self.groups = hotconnect.groups(master.plan.slaves)
        self.absent_groups = set(absent_groups or ())
        # The group of each slave in one (groups never overlap: eni/reader.py).
        self._group_of = {m.name: head for head, members in self.groups.items()
                          for m in members}
        self.health = {s.name: SlaveHealth(s.name, s.position) for s in master.plan.slaves}
        for name in self._absent_members():
            h = self.health[name]
            h.online, h.since = False, self._now()
            h.reason = f"its hot-connect group ({self._group_of[name]!r}) is not on the line"
        self._pending: Pending = []
        self._incoming: list[Job] = []                # started, first round next cycle
        self._diagnosing = False
        self._probing = False
        self._next_diagnosis = 0.0
        self._next_probe = 0.0
        self._bind()

    def _absent_members(self) -> set[str]:
        return {m.name for head in self.absent_groups for m in self.groups[head]}

    def _bind(self) -> None:
        """Where every slave is and what it adds to the master's cyclic frames (again after
        a hot-connect group came or went): plans at their positions, working counter
        shares, input bits; the expected working counters lowered for the slaves that
        are not online."""
        master = self.master
        present = {s.name for s in master.plan.slaves} - self._absent_members()
        if {s.name for s in master.slaves} != present:
            master.layout(present)
        where = hotconnect.positions(master.plan.slaves, present)
        self._by_name = {s.name: at_position(s, where[s.name]) for s in master.plan.slaves}
        for name, h in self.health.items():
            h.position = where[name]
        cyclic = master.cyclic
        self._slots = [s for frame in cyclic.frames for s in frame]
        for slot in self._slots:
            slot.expected = slot.cmd.cnt
        self._shares = {name: [(slot, share) for slot in self._slots
                               if (share := wkc_share(s, slot))]
                        for name, s in self._by_name.items()}
        self._inputs = {name: input_bits(s, cyclic) for name, s in self._by_name.items()}
        self._al_slots = [slot for slot in self._slots if slot.cmd.cmd == Cmd.BRD
                          and slot.cmd.ado == Reg.AL_STATUS and slot.cmd.length >= 1]
        # The ENI's cyclic LRD of Master/MailboxStates ("Poll Mailbox State"), when the
        # mailboxes poll that area: its data answers their poll in the round after it.
        poll = next((c.poll for c in master.mailboxes.values() if c.poll is not None), None)
        self._state_poll: tuple[MailboxStatePoll, _Slot] | None = None
        if poll is not None:
            self._state_poll = next(
                ((poll, slot) for slot in self._slots if slot.cmd.cmd == Cmd.LRD
                 and slot.cmd.addr == poll.datagram.address
                 and slot.cmd.length >= len(poll.datagram.data)), None)
        for name, h in self.health.items():
            if not h.online:
                for slot, share in self._shares[name]:
                    if slot.expected is not None:
                        slot.expected -= share
        cyclic.expected_changed()
        self._update_clear()
        self.timeout = max(cyclic.cycle_time_us / 1e6, 0.001)
        self._all_online = all(h.online for h in self.health.values())

    # -- every cycle --------------------------------------------------------------------------

    def after_cycle(self, ok: bool) -> bool:
        """Run after each cycle's frames: clear the offline slaves' inputs, look for
        slaves that dropped out, go one round on with the recovery's frames.  Returns
        whether every *online* slave's data came back as expected."""
        inputs = self.master.cyclic.inputs
        if ok and self._all_online and not self._pending:
            # The usual cycle: nothing to look after if the AL status is as expected
            # (_al_wrong, written out: a call costs as much as the check).
            want = self.master.state
            for slot in self._al_slots:
                if slot.wkc >= 0 and inputs[slot.in_at] & _AL_STATE_AND_ERROR != want:
                    break
            else:
                return True
        now = self._now()
        if not ok:
            ok = self._tolerated()
        if not ok or self._al_wrong(inputs):
            # The ORed AL status also shows the slaves already offline or joining: then
            # it cannot tell whether another one left the state.  Look at every slave,
            # but only as often as the probes, and count the cycle as good.
            unsure = ok and not self._all_online
            if not unsure:
                ok = False
            if not self._diagnosing and now >= self._next_diagnosis:
                self._diagnosing = True
                self._next_diagnosis = now + (PROBE_INTERVAL if unsure else DIAGNOSE_INTERVAL)
                self._incoming.append(self._diagnose())
        if not self._probing and now >= self._next_probe and any(
                not h.online and not h.joining and not h.gave_up and now >= h.next_try
                for h in self.health.values()):
            self._probing = True
            self._next_probe = now + PROBE_INTERVAL
            self._incoming.append(self._probe())
        if self._incoming:
            with using(self.master.transport.clock):     # the jobs' first deadlines
                self._pending += start(self._incoming)
            self._incoming = []
        if self._pending:
            self._pending = one_round(self.master.transport, self._pending, self.timeout,
                                      self._job_failed, self._cycled_mailbox_states())
        # Last: the slaves found offline in this cycle's round are cleared at once.
        inputs = self.master.cyclic.inputs
        for at, keep in self._clear:
            inputs[at] &= keep
        return ok

    def _cycled_mailbox_states(self) -> dict[int, Datagram] | None:
        """The mailbox-full bits this cycle's frame read (the ENI's LRD of
        Master/MailboxStates, in the input image), as the reply to the mailboxes' own
        poll of the area, which then stays off the wire (TwinCAT polls the mailboxes in the
        cyclic frame).  None when the cyclic frame has no such command in this state, or
        it did not come back."""
        if self._state_poll is None:
            return None
        poll, slot = self._state_poll
        if slot.wkc < 1 or self.master.state.name not in slot.cmd.states:
            return None
        n = len(poll.datagram.data)
        got = Datagram.logical(Cmd.LRD, poll.datagram.address,
                               bytes(self.master.cyclic.inputs[slot.in_at:slot.in_at + n]))
        got.wkc = slot.wkc
        return {id(poll.datagram): got}

    def _al_wrong(self, inputs: bytearray) -> bool:
        """The cyclic BRD of the AL status: any slave out of the network's state (the
        data ORs every answering slave's state and error bits)."""
        want = self.master.state            # an IntEnum compares as its int (no int() call)
        for slot in self._al_slots:
            if slot.wkc >= 0 and inputs[slot.in_at] & _AL_STATE_AND_ERROR != want:
                return True
        return False

    def _tolerated(self) -> bool:
        """A working counter that is off only by what slaves that are offline or being
        brought back add (back on the wire but not configured yet, or passing through
        INIT..SAFEOP with part of their share) is no error of the others; it means one
        may be back, so the next probe goes at once."""
        down = [name for name, h in self.health.items() if not h.online]
        for slot in self._slots:
            if slot.expected is None or slot.wkc == slot.expected:
                continue
            if slot.wkc < slot.expected:
                return False
            extra = sum(share for name in down for s, share in self._shares[name] if s is slot)
            if slot.wkc > slot.expected + extra:
                return False
            self._next_probe = min(self._next_probe, self._now())
        return True

    def _job_failed(self, job: Job, exc: Exception) -> None:
        if not isinstance(exc, ApplyError):
            raise exc

    # -- going offline and coming back ---------------------------------------------------------

    def _now(self) -> float:
        """Seconds on the master's clock (the wire's: simulated on a simulated wire)."""
        return self.master.transport.clock.monotonic()

    def _event(self, kind: str, text: str, slave: str) -> None:
        self.master._event(kind, text, slave)

    def _where(self, h: SlaveHealth) -> str:
        return f"slave {h.name!r} (position {h.position})"

    def _offline(self, name: str, reason: str, announce: bool = True) -> None:
        """``name`` goes offline at once (its share of the working counters, its inputs
        cleared); the event now, or (``announce`` false) once its cause is read."""
        h = self.health[name]
        if not h.online:
            return
        h.online, h.reason, h.since = False, reason, self._now()
        self._all_online = False
        h.attempts, h.gave_up, h.next_try = 0, False, 0.0
        h.cause = []
        for slot, share in self._shares[name]:
            if slot.expected is not None:
                slot.expected -= share
        self.master.cyclic.expected_changed()
        self._update_clear()
        if announce:
            self._event("offline", f"{self._where(h)} {reason}; the others go on", name)
        self._group_left(name)

    def _offline_cause(self, slave: SlavePlan, code: int) -> Job:
        """The cause of a slave that left the network's state with an AL status code
        (0x001B after its watchdog expired, 0x001A ...), read between the cycles; then its
        offline event, with the cause.  Bringing it back waits for this (``joining``), so
        the slave is read as it was found."""
        h = self.health[slave.name]
        h.joining = True
        try:
            cause = yield from self._cause(slave, h.position, code,
                                           self.master.mailboxes.get(slave.name))
        finally:
            h.joining = False
        why = ""
        if cause is not None:
            h.cause = cause.lines
            why = f"; cause: {cause.text()}"
        self._event("offline", f"{self._where(h)} {h.reason}; the others go on{why}",
                    slave.name)

    def _online(self, name: str) -> None:
        h = self.health[name]
        for slot, share in self._shares[name]:
            if slot.expected is not None:
                slot.expected += share
        self.master.cyclic.expected_changed()
        h.online, h.joining, h.reason, h.attempts, h.cause = True, False, "", 0, []
        self._all_online = all(h.online for h in self.health.values())
        h.refused.clear()
        self._update_clear()
        self._event("online", f"{self._where(h)} is back in {self.master.state.name} after "
                              f"{self._now() - h.since:.2f} s", name)

    def _group_left(self, name: str) -> None:
        """A hot-connect group whose every slave stopped answering has left the line:
        the slaves behind it move up."""
        for head, members in self.groups.items():
            if head in self.absent_groups or name not in {m.name for m in members}:
                continue
            if all(not self.health[m.name].online and not self.health[m.name].joining
                   and self.health[m.name].reason == "stopped answering" for m in members):
                self.absent_groups.add(head)
                self._event("hot-connect", f"hot-connect group {head!r} "
                                           f"({hotconnect.slaves(len(members))}) left the "
                                           f"line; the others go on", head)
                self._bind()

    def _group_back(self, head: str) -> None:
        """The head of an absent group was found and identified: the group is on the line
        again, the slaves behind it move down."""
        self.absent_groups.discard(head)
        self._event("hot-connect", f"hot-connect group {head!r} is on the line; bringing it "
                                   f"up", head)
        self._bind()

    def _update_clear(self) -> None:
        bits: dict[int, int] = {}
        for name, h in self.health.items():
            if not h.online:
                for at, mask in self._inputs[name]:
                    bits[at] = bits.get(at, 0) | mask
        self._clear = [(at, ~mask & 0xFF) for at, mask in sorted(bits.items())]

    def recover(self, name: str) -> None:
        """Try again to bring back a slave the supervisor gave up on."""
        h = self.health[name]
        h.gave_up, h.attempts, h.next_try = False, 0, 0.0

    def _failed(self, h: SlaveHealth, error: str, cause: Cause | None = None) -> None:
        h.joining = False
        h.attempts += 1
        h.cause = cause.lines if cause is not None else []
        why = f"; cause: {cause.text()}" if cause is not None else ""
        if h.attempts >= MAX_ATTEMPTS:
            h.gave_up = True
            self._event("offline", f"{self._where(h)}: gave up after {h.attempts} attempts "
                                   f"({error}){why}", h.name)
            return
        wait = min(BACKOFF_FIRST * 2 ** (h.attempts - 1), BACKOFF_MAX)
        h.next_try = self._now() + wait
        self._event("retry", f"{self._where(h)}: attempt {h.attempts} of {MAX_ATTEMPTS} "
                             f"failed ({error}); again in {wait:g} s{why}", h.name)

    # -- jobs ------------------------------------------------------------------------------

    def _diagnose(self) -> Job:
        """Every online slave's AL status by its station address."""
        try:
            online = [self._by_name[n] for n, h in self.health.items()
                      if h.online and not h.joining]
            reads = [Datagram.physical(Cmd.FPRD, s.phys_addr, Reg.AL_STATUS, 6)
                     for s in online]
            for _ in range(3):
                back = yield reads
                if back is not None:
                    break
            else:
                return
            want = self.master.state
            for s, dg in zip(online, back):
                if dg.wkc == 0:
                    self._offline(s.name, "stopped answering")
                    continue
                status, _, code = struct.unpack("<HHH", dg.data)
                if status & AL_STATE_MASK != want or status & AL_STATUS_ERROR:
                    text = f"fell to {al_state_name(status)}"
                    if status & AL_STATUS_ERROR or code:
                        text += f", AL status code 0x{code:04X} ({al_status_name(code)})"
                    was_online = self.health[s.name].online
                    self._offline(s.name, text, announce=not code)
                    if code and was_online:
                        self._incoming.append(self._offline_cause(s, code))
        finally:
            self._diagnosing = False

    def _probe(self) -> Job:
        """Look at every position for the offline slaves: station address and AL status."""
        try:
            count = yield [Datagram.physical(Cmd.BRD, 0, Reg.AL_STATUS, 2)]
            if count is None:
                return
            n = count[0].wkc
            reads = [dg for pos in range(n) for dg in (
                Datagram.physical(Cmd.APRD, -pos & 0xFFFF, Reg.STATION_ADDRESS, 2),
                Datagram.physical(Cmd.APRD, -pos & 0xFFFF, Reg.AL_STATUS, 6))]
            back = yield reads
            if back is None:
                return
            by_address = {s.phys_addr: s for s in self._by_name.values()}
            absent = self._absent_members()
            now = monotonic()
            for pos in range(n):
                addr_dg, state_dg = back[2 * pos], back[2 * pos + 1]
                if addr_dg.wkc != 1 or state_dg.wkc != 1:
                    continue
                address, = struct.unpack("<H", addr_dg.data)
                status, = struct.unpack_from("<H", state_dg.data)
                slave = by_address.get(address)
                configured = slave is not None
                if slave is None:
                    # A slave without its station address (powered off and on, another
                    # device, or a hot-connect group plugged in): the offline slave
                    # expected at this position.
                    slave = next((self._by_name[name] for name, h in self.health.items()
                                  if not h.online and h.position == pos
                                  and (name not in absent or name in self.absent_groups)),
                                 None)
                if slave is None:
                    continue
                h = self.health[slave.name]
                if h.online or h.joining or h.gave_up or now < h.next_try:
                    continue
                if slave.name in absent and slave.name not in self.absent_groups:
                    continue            # a group's slaves join after its head
                h.joining = True
                if slave.name in self.absent_groups:
                    self._incoming.append(self._identify(slave, pos, configured, status))
                else:
                    self._incoming.append(self._rejoin(slave, pos, configured, status))
        finally:
            self._probing = False

    def _identify(self, head: SlavePlan, position: int, configured: bool, status: int
                  ) -> Job:
        """The head of an absent hot-connect group at ``position``: its IdentifyCmds, then
        the group is back on the line and the head is brought up (its members follow
        with the next probes)."""
        h = self.health[head.name]
        found: dict[tuple[str, int], bool] = {}
        yield from hotconnect.identify_job(head, position, found)
        if not found[(head.name, position)]:
            h.joining = False
            h.next_try = monotonic() + PROBE_INTERVAL
            if ("identify", position) not in h.refused:
                h.refused.add(("identify", position))
                self._event("refused", f"hot-connect group {head.name!r}: the slave at "
                            f"position {position} is not its head (its IdentifyCmds "
                            f"failed); it is not configured", head.name)
            return
        self._group_back(head.name)
        yield from self._rejoin(self._by_name[head.name], position, configured, status)

    def _rejoin(self, plan: SlavePlan, position: int, configured: bool, status: int) -> Job:
        """Verify the slave at ``position`` is the ENI's ``plan`` and bring it up to the
        network's state."""
        h = self.health[plan.name]
        slave = at_position(plan, position)
        master = self.master
        channel: MailboxChannel | None = None
        try:
            from ecatcfg.runtime.master.scan import FoundSlave, compare, identity_job
            found: dict[int, FoundSlave] = {}
            yield from identity_job(position, found)
            got = found[position]
            # The start-up check's rule (other device; other revision, a newer one only
            # when the start-up took newer ones).
            problem = compare(master.plan.slaves, plan, got, master.accept_newer_revision)
            if problem:
                h.joining = False
                h.next_try = monotonic() + PROBE_INTERVAL
                if got.identity not in h.refused:
                    h.refused.add(got.identity)
                    self._event("refused", f"{self._where(h)}: another device is in its "
                                f"place ({problem}: 0x{got.vendor_id:x}:0x{got.product_code:x}"
                                f":0x{got.revision:x}, the ENI has 0x{plan.vendor_id:x}:"
                                f"0x{plan.product_code:x}:0x{plan.revision:x}); it is not "
                                "configured", plan.name)
                return
            state = AlState(status & AL_STATE_MASK) if status & AL_STATE_MASK in (
                1, 2, 4, 8) else AlState.INIT
            if status & AL_STATUS_ERROR:
                yield from _request(slave, AlState(state) | AL_ERROR_ACK, None)
            if not configured or h.attempts > 0 or state == AlState.INIT:
                if state != AlState.INIT:
                    yield from _request(slave, AlState.INIT, AlState.INIT)
                state = AlState.INIT
                old = master.mailboxes.get(plan.name)
                channel = None if slave.mailbox is None else old.again() \
                    if old is not None else MailboxChannel(slave.phys_addr, slave.mailbox)
                # A slave in INIT asked for INIT: its INIT->INIT commands, as at start-up
                # (esc.TRANSITION_RULES).
                yield from slave_transition_job(slave, Transition.II,
                                                master.progress[plan.name])
            else:
                channel = master.mailboxes.get(plan.name)
            if channel is not None:
                master.mailboxes[plan.name] = channel
            while state < master.state:
                transition = _UP[state]
                if transition == Transition.PS and slave.dc is not None:
                    yield from master.dc_rejoin_job(slave)
                if transition == Transition.SO and slave.dc is not None:
                    yield from master.dc_wait_job(slave)
                yield from slave_transition_job(slave, transition, master.progress[plan.name],
                                                channel)
                state = transition.target
            self._online(plan.name)
        except ApplyError as exc:
            cause = None
            if exc.al_code:
                # Why, read from the slave as it refused, one round per cycle as the
                # attempt itself (docs/diagnostics.md).
                cause = yield from self._cause(slave, position, exc.al_code, channel)
            self._failed(h, str(exc), cause)

    def _cause(self, slave: SlavePlan, position: int, code: int,
               channel: MailboxChannel | None) -> Step[Cause | None]:
        """The cause of a refusal during an attempt (``diagnose.explain_step``); None when
        the slave cannot be read (it left the line again)."""
        from ecatcfg.runtime.master.diagnose import Context, bus_cycle, explain_step
        context = Context(slave=slave, channel=channel, bus_cycle_ns=bus_cycle(self.master.plan),
                          esi=self.master.esi)
        try:
            return (yield from explain_step(position, code, context))
        except ApplyError:
            return None


def _request(slave: SlavePlan, control: int, wait: AlState | None) -> Step[None]:
    """Write AL control by position; with ``wait``, until the slave shows that state."""
    adp = slave.auto_inc_addr
    write = Datagram.physical(Cmd.APWR, adp, Reg.AL_CONTROL, struct.pack("<H", control))
    yield from until_answered([write], monotonic() + TIMEOUT_COMMAND,
                              ApplyError("no answer to the AL control write", slave.name))
    if wait is None:
        return
    read = Datagram.physical(Cmd.APRD, adp, Reg.AL_STATUS, 2)
    deadline = monotonic() + TIMEOUT_STATE
    while True:
        back = yield [read]
        if back is not None and back[0].wkc == 1 and back[0].data[0] & AL_STATE_MASK == wait:
            return
        if monotonic() > deadline:
            raise ApplyError(f"did not go to {wait.name}", slave.name)
