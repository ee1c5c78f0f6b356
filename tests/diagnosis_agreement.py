"""The emulator/diagnosis agreement: every refusal of an emulated slave is diagnosed with the rule the
emulator applied.  Shared by ``tests/test_diagnosis_agreement.py`` (a fixed sample in CI)
and ``bench/diagnosis_agreement.py`` (every corpus ENI, every fault).

A case is one ENI brought up on the in-memory virtual segment, with or without the ESI
files, either as it is or with one fault planted by :func:`faults` (seeded: the same seed
plants the same faults).  The segment emulates the slaves of the ENI *as written* (the
devices on the line); the master runs the ENI *with the fault* (a user's edit), so a fault
reaches the emulated firmware instead of changing the device it emulates.  For every slave
that refused a state (``EmulatedSlave.refusal``), the diagnosis the master made
(``ApplyError.causes``, from ``runtime/master/diagnose.py``) must give the same AL status
code, name the emulator's rule among its ``rules`` (``runtime/refusals.py``) and never fall
back to "the slave's firmware checks more".
"""

from __future__ import annotations

import copy
import random
import struct
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from ecatcfg.eni.plan import CoeInitCmd, InitCmd, NetworkPlan, SlavePlan
from ecatcfg.esc import Reg, Transition

GENERIC = "checks more"          # the text the diagnosis must not fall back to


@dataclass
class Fault:
    name: str                    # the fault class (what the generator planted)
    slave: str
    what: str                    # the command changed, in words
    plan: NetworkPlan


@dataclass
class Outcome:
    """One case: the refusals seen and each disagreement (empty: the diagnosis agrees)."""

    case: str
    refusals: list[tuple[str, int, str]] = field(default_factory=list)  # slave, code, rule
    disagreements: list[str] = field(default_factory=list)
    error: str = ""              # the ApplyError's first line, when the bring-up failed
    # Each emulated slave's 0x0500 after the diagnosis (who has its EEPROM).
    eeprom_config: dict[str, int] = field(default_factory=dict)


# -- planting faults ---------------------------------------------------------------------------

def _reg_writes(slave: SlavePlan, ado: int, transition: Transition) -> list[InitCmd]:
    return [c for c in slave.init_cmds if c.ado == ado and transition in c.transitions
            and c.cmd in (2, 5, 8) and c.payload and any(c.payload)]


def _process_sms(slave: SlavePlan) -> list[tuple[int, InitCmd]]:
    """(SM number, the PS write that configures it) of each process-data SM with data."""
    out = []
    for n in range(2, 8):
        for c in _reg_writes(slave, Reg.SM0 + 8 * n, Transition.PS):
            if len(c.payload) >= 8 and c.payload[6] & 1 and c.payload[2:4] != b"\0\0":
                out.append((n, c))
    return out


def _set(cmd: InitCmd | CoeInitCmd, offset: int, fmt: str, value: int) -> None:
    data = bytearray(cmd.payload if isinstance(cmd, InitCmd) else cmd.data)
    struct.pack_into(fmt, data, offset, value)
    cmd.data = bytes(data)


def _coe(slave: SlavePlan, test: Callable[[CoeInitCmd], bool]) -> list[CoeInitCmd]:
    cmds = slave.mailbox.coe_init_cmds if slave.mailbox else []
    return [c for c in cmds if not c.disabled and c.ccs == 1 and test(c)]


def _slots(cmds: list[CoeInitCmd], objects: Callable[[int], bool], size: int
           ) -> list[tuple[int, int, int, int]]:
    """(command, byte offset, index, subindex) of each entry value the enabled downloads
    write to ``objects`` (assignment entries of 2 bytes, mapping entries of 4): one
    subindex write, or a complete access from subindex 0 (count, a pad byte, the entries;
    ETG.1000.6 complete access)."""
    out = []
    for k, c in enumerate(cmds):
        if c.disabled or c.ccs != 1 or not objects(c.index):
            continue
        if not c.complete_access and c.subindex >= 1 and len(c.data) == size:
            out.append((k, 0, c.index, c.subindex))
        elif c.complete_access and c.subindex == 0 and c.data:
            for n in range(1, c.data[0] + 1):
                if 2 + size * n <= len(c.data):
                    out.append((k, 2 + size * (n - 1), c.index, n))
    return out


def _planters(slave: SlavePlan, rng: random.Random
              ) -> Iterator[tuple[str, str, Callable[[SlavePlan], None]]]:
    """(fault class, what, how to plant it in a copy of ``slave``) for what this slave's
    commands allow."""
    sms = _process_sms(slave)
    if sms:
        n, cmd = rng.choice(sms)
        k = slave.init_cmds.index(cmd)
        length = struct.unpack_from("<H", cmd.payload, 2)[0]
        new = length - 1 if length > 1 else length + 1

        def sm_length(s: SlavePlan, k: int = k, new: int = new) -> None:
            _set(s.init_cmds[k], 2, "<H", new)
        yield "sm-length", f"SM{n} length {length} -> {new}", sm_length

        def sm_disabled(s: SlavePlan, k: int = k) -> None:
            _set(s.init_cmds[k], 6, "<B", s.init_cmds[k].payload[6] & ~1)
        yield "sm-disabled", f"SM{n} enable bit cleared", sm_disabled

        def sm_start(s: SlavePlan, k: int = k) -> None:
            start = struct.unpack_from("<H", s.init_cmds[k].payload, 0)[0]
            _set(s.init_cmds[k], 0, "<H", start + 0x40)
        yield "sm-start", f"SM{n} start + 0x40", sm_start

        def sm_control(s: SlavePlan, k: int = k) -> None:
            _set(s.init_cmds[k], 4, "<B", s.init_cmds[k].payload[4] ^ 0x04)
        yield "sm-control", f"SM{n} direction bit flipped", sm_control
    fmmus = [c for n in range(8) for c in _reg_writes(slave, Reg.FMMU0 + 16 * n,
                                                         Transition.PS)
             if len(c.payload) >= 16 and c.payload[12] & 1]
    if fmmus:
        k = slave.init_cmds.index(rng.choice(fmmus))

        def fmmu_off(s: SlavePlan, k: int = k) -> None:
            _set(s.init_cmds[k], 12, "<B", 0)
        yield "no-fmmu", "an FMMU disabled", fmmu_off
    cmds = slave.mailbox.coe_init_cmds if slave.mailbox else []
    counts = [(k, 0) for k, c in enumerate(cmds) if c in _coe(slave, lambda c: True)
              and 0x1C12 <= c.index <= 0x1C13 and c.subindex == 0 and c.data
              and c.data[0] > 0]
    if counts:
        k, _ = rng.choice(counts)

        def assign_short(s: SlavePlan, k: int = k) -> None:
            assert s.mailbox is not None
            cmd = s.mailbox.coe_init_cmds[k]
            _set(cmd, 0, "<B", cmd.data[0] - 1)
        yield "assign-short", f"0x{cmds[k].index:04X}:00 one PDO fewer", assign_short
    slots = _slots(cmds, lambda i: 0x1C12 <= i <= 0x1C13, 2)
    if slots:
        k, offset, index, sub = rng.choice(slots)
        bad = 0x17FF if index == 0x1C12 else 0x1BFF

        def pdo_missing(s: SlavePlan, k: int = k, offset: int = offset, bad: int = bad
                        ) -> None:
            assert s.mailbox is not None
            _set(s.mailbox.coe_init_cmds[k], offset, "<H", bad)
        yield "pdo-missing", f"0x{index:04X}:{sub:02X} = 0x{bad:04X}", pdo_missing
    entries = [slot for slot in _slots(cmds, lambda i: 0x1600 <= i <= 0x17FF
                                       or 0x1A00 <= i <= 0x1BFF, 4)
               if int.from_bytes(cmds[slot[0]].data[slot[1]:slot[1] + 4], "little") >> 16]
    if entries:
        k, offset, pdo, sub = rng.choice(entries)
        bits = cmds[k].data[offset]
        for name, index, obj_sub in (("entry-not-mappable", 0x1000, 0),
                                     ("entry-missing", 0x5FFF, 1),
                                     ("extra-entry", 0x1008, 0)):
            def entry(s: SlavePlan, k: int = k, offset: int = offset,
                      word: int = index << 16 | obj_sub << 8 | bits) -> None:
                assert s.mailbox is not None
                _set(s.mailbox.coe_init_cmds[k], offset, "<I", word)
            yield name, (f"0x{pdo:04X}:{sub:02X} maps 0x{index:04X}:{obj_sub:02X} "
                         f"({bits} bits)"), entry
    cycles = _reg_writes(slave, Reg.DC_SYNC0_CYCLE_TIME, Transition.PS)
    if cycles:
        k = slave.init_cmds.index(cycles[0])
        for name, ns in (("sync0-zero", 0), ("sync0-below-minimum", 1000)):
            def sync0(s: SlavePlan, k: int = k, ns: int = ns) -> None:
                _set(s.init_cmds[k], 0, "<I", ns)
            yield name, f"SYNC0 cycle {ns} ns", sync0
    watchdog = _reg_writes(slave, Reg.WATCHDOG_SM, Transition.IP)
    if watchdog and _process_sms(slave):
        k = slave.init_cmds.index(watchdog[0])

        def short_watchdog(s: SlavePlan, k: int = k) -> None:
            _set(s.init_cmds[k], 0, "<H", 1)
        yield "watchdog", "SM watchdog time 1 (one base tick, 100 µs by default)", \
            short_watchdog
    mailbox = _reg_writes(slave, Reg.SM0, Transition.IP)
    if mailbox:
        k = slave.init_cmds.index(mailbox[0])

        def mbx(s: SlavePlan, k: int = k) -> None:
            length = struct.unpack_from("<H", s.init_cmds[k].payload, 2)[0]
            _set(s.init_cmds[k], 2, "<H", length - 2)
        yield "mailbox-sm", "SM0 (mailbox out) 2 bytes shorter", mbx


def faults(plan: NetworkPlan, seed: int) -> list[Fault]:
    """One planted fault per (slave, fault class) the slave's commands allow, in copies of
    ``plan``; which SM, FMMU or object each one hits is drawn from ``seed``."""
    rng = random.Random(seed)
    out = []
    for position, slave in enumerate(plan.slaves):
        for name, what, plant in _planters(slave, rng):
            changed = copy.deepcopy(plan)
            plant(changed.slaves[position])
            out.append(Fault(name, slave.name, what, changed))
    return out


# -- running a case ----------------------------------------------------------------------------

def run_case(case: str, original: NetworkPlan, plan: NetworkPlan, library: Any, *,
             master_esi: bool = True, cycles: int = 5) -> Outcome:
    """Bring ``plan`` up on a segment that emulates ``original``'s slaves (from ``library``,
    or from the ENI alone when None) and compare every refusal with its diagnosis
    (``master_esi``: the master's diagnosis compares with the same ESI files; False: it
    has none, as ``doctor`` without ``--esi``); ``cycles`` in OP after it is reached, the
    refusals then diagnosed by ``doctor``)."""
    from ecatcfg.runtime import Network
    from ecatcfg.runtime.link import MemoryLink
    from ecatcfg.runtime.master.replay import ApplyError
    from ecatcfg.runtime.segment import emulate

    out = Outcome(case)
    segment = emulate.segment(emulate.specs_from_eni(original, library, case))
    ours, theirs = MemoryLink.pair()
    stop = threading.Event()
    thread = threading.Thread(target=segment.serve, args=(theirs,), kwargs={"stop": stop},
                              daemon=True)
    thread.start()

    def close() -> None:
        stop.set()
        thread.join(2)
        theirs.close()

    causes: list[dict[str, Any]] = []
    esi = library if master_esi else None
    net = Network(plan, ours, skip_unsupported=True, esi=esi, recovery=False,
                  dc_threshold_ns=0, _closers=[close])
    try:
        net.up()
        # A few cycles in OP: a slave that leaves it (its SM watchdog) is found by the
        # master's doctor, which diagnoses every slave not in OP.
        net.run(cycles)
        if any(s.refusal is not None for s in segment.slaves):
            from ecatcfg.esc import AlState
            from ecatcfg.runtime.master.diagnose import doctor
            _count, findings = doctor(net.master.transport, AlState.OP, net.plan, esi)
            causes = [f.cause.as_json() for f in findings if f.cause is not None]
    except ApplyError as exc:
        causes = exc.causes
        out.error = exc.message.splitlines()[0]
    finally:
        net.close()
    by_position = {c.get("position"): c for c in causes}
    out.eeprom_config = {s.name: s.mem[Reg.EEPROM_CONFIG] for s in segment.slaves}
    for slave in segment.slaves:
        refusal = slave.refusal
        if refusal is None:
            continue
        out.refusals.append((slave.name, refusal.code, refusal.rule.value))
        cause = by_position.get(slave.position)
        said = f"{case}: slave {slave.name!r} refused with 0x{refusal.code:04X} " \
               f"{refusal.rule.value} ({refusal.detail})"
        if cause is None:
            out.disagreements.append(f"{said}; no diagnosis")
            continue
        lines = cause.get("cause") or []
        if cause.get("al_status_code") != refusal.code:
            out.disagreements.append(f"{said}; diagnosed 0x{cause.get('al_status_code'):04X}")
        if refusal.rule.value not in (cause.get("rules") or []):
            out.disagreements.append(f"{said}; the diagnosis names {cause.get('rules')}: "
                                     f"{lines}")
        if any(GENERIC in line for line in lines):
            out.disagreements.append(f"{said}; the diagnosis says {GENERIC!r}: {lines}")
    return out
