"""``ecatcfg diff`` of two ENIs: what a master would do differently, not how a tool wrote it.

Both files are read into :class:`NetworkPlan` objects (any tool's ENI, in any combination)
and compared as what they make the master do:

- slaves by name: added, removed, moved (position), identity (vendor, product, revision);
- each slave's PDO assignment (the PDOs per SyncManager) and the mapping of the PDOs it
  assigns (entries ``index:sub``, bit length);
- process-image variables by name: moved (old and new ``byte.bit``: the change that
  silently breaks a PLC program), resized, retyped, added, removed; a shift of the whole
  image, or of every variable of one slave, is one line, followed by what moved otherwise;
- InitCmds per slave and transition, in words (:mod:`ecatcfg.eni.words`): added, removed,
  changed;
- DC (reference clock, cycle and shift times) and the bus cycle time; the process-data
  commands of the cyclic frames (command, length, expected working counter); the
  slave-to-slave copies (``CopyInfos``), in their order, by the variables they copy from
  and to (TwinCAT's frame-shaped offsets and a compact image compare equal).

What is not a difference (docs/show-diff-check.md, "What diff does not count"):

- ``Comment`` texts, the order of slaves' independent elements, number spellings;
- the order of register InitCmds within one transition (each ESC register is written by
  its own command; a tool's order among them is its own);
- how a CoE download sequence writes an array object: the PDO assignment (0x1C10-0x1C2F)
  and mapping (0x1600-0x17FF, 0x1A00-0x1BFF) objects are compared by what they hold once
  the transition's downloads are done (``esc.array_downloads``): EC-Engineer clears
  0x1C12:00 before a CompleteAccess write of 0x1C12, TwinCAT writes the CompleteAccess
  alone, another tool writes subindex by subindex; all three assign the same PDOs;
- for other objects, only the last download of each ``index:sub`` in a transition counts;
  likewise for SoE, only the last write of each IDN of each drive in a transition.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable
from typing import Any

from ecatcfg.eni.plan import (CoeInitCmd, EoeInitCmd, FoeInitCmd, InitCmd, NetworkPlan,
                              PassiveSlave, SlavePlan, SoeInitCmd, Variable)
from ecatcfg.eni.words import (coe_words, command_name, copy_words, eoe_words, foe_words,
                               init_cmd_words, mapping_entry, soe_words)
from ecatcfg.esi.idn import idn_text
from ecatcfg.esi.datatypes import canonical
from ecatcfg.eni.pdo_held import entry_size
from ecatcfg.esc import LOGICAL_CMDS, Transition, array_downloads
from ecatcfg.record import record


@record
class Change:
    """One difference.  ``kind`` (for JSON and tests): slave-added, slave-removed,
    slave-moved, identity, pdo-assignment, pdo-mapping, image-moved, variables-moved,
    variable-moved, variable-changed,
    variable-added, variable-removed, initcmd-added, initcmd-removed, initcmd-changed, dc,
    cycle-time, frames, copies, unsupported-added, unsupported-removed, and for topologies
    slave-setting and master-setting."""

    kind: str
    slave: str | None
    what: str
    old: str | None = None
    new: str | None = None
    transition: str | None = None

    def describe(self) -> str:
        where = f"{self.slave!r}" if self.slave is not None else "network"
        when = f" {self.transition}" if self.transition else ""
        text = f"{self.kind:<16} {where}{when}: {self.what}"
        if self.old is not None and self.new is not None:
            return f"{text}: {self.old} -> {self.new}"
        if self.old is not None:
            return f"{text}: {self.old}"
        if self.new is not None:
            return f"{text}: {self.new}"
        return text

    def as_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "slave": self.slave, "transition": self.transition,
                "what": self.what, "old": self.old, "new": self.new}


def _identity(s: SlavePlan | PassiveSlave) -> str:
    return f"0x{s.vendor_id:08X}:0x{s.product_code:08X}:0x{s.revision:08X}"


def _positions(plan: NetworkPlan) -> dict[str, str]:
    """A slave's place: its bus position, or for a passive one the slave it follows."""
    out = {s.name: f"position {s.position}" for s in plan.slaves}
    for p in plan.passive:
        out[p.name] = (f"passive after {plan.slaves[p.after - 1].name!r}" if p.after
                       else "passive first")
    return out


def _slaves(a: NetworkPlan, b: NetworkPlan) -> list[Change]:
    out: list[Change] = []
    old = {s.name: s for s in a.in_file_order()}
    new = {s.name: s for s in b.in_file_order()}
    pa, pb = _positions(a), _positions(b)
    for name, s in old.items():
        if name not in new:
            out.append(Change("slave-removed", name, _identity(s), old=pa[name]))
    for name, s in new.items():
        if name not in old:
            out.append(Change("slave-added", name, _identity(s), new=pb[name]))
            continue
        if pa[name] != pb[name]:
            out.append(Change("slave-moved", name, "place", pa[name], pb[name]))
        if _identity(old[name]) != _identity(s):
            out.append(Change("identity", name, "vendor:product:revision",
                              _identity(old[name]), _identity(s)))
    return out


def _assignment(s: SlavePlan) -> dict[int, list[int]]:
    pd = s.process_data
    return {} if pd is None else {sm.number: list(sm.pdos) for sm in pd.sms if sm.pdos}


def _mappings(s: SlavePlan) -> dict[int, list[str]]:
    pd = s.process_data
    if pd is None:
        return {}
    assigned = {i for pdos in _assignment(s).values() for i in pdos}
    return {p.index: [mapping_entry(e.index << 16 | e.subindex << 8 | e.bit_len)
                      for e in p.entries]
            for p in pd.pdos if p.index in assigned or p.sm is not None}


def _pdo_list(pdos: list[int]) -> str:
    return ", ".join(f"0x{i:04X}" for i in pdos) or "none"


def _process_data(name: str, a: SlavePlan, b: SlavePlan) -> list[Change]:
    out: list[Change] = []
    sa, sb = _assignment(a), _assignment(b)
    for sm in sorted(set(sa) | set(sb)):
        if sa.get(sm, []) != sb.get(sm, []):
            out.append(Change("pdo-assignment", name, f"sm {sm}", _pdo_list(sa.get(sm, [])),
                              _pdo_list(sb.get(sm, []))))
    ma, mb = _mappings(a), _mappings(b)
    for index in sorted(set(ma) & set(mb)):
        if ma[index] != mb[index]:
            out.append(Change("pdo-mapping", name, f"0x{index:04X}",
                              "; ".join(ma[index]) or "empty", "; ".join(mb[index]) or "empty"))
    return out


_is_array_object = entry_size      # the entry size of a PDO object (eni/pdo_held.py)


def _coe_state(cmds: Iterable[CoeInitCmd]) -> dict[tuple[int, int | None], str]:
    """What one transition's CoE downloads leave in the device, in words: a PDO object by
    its final contents, any other ``index:sub`` by its last download (uploads by their
    words)."""
    arrays: dict[int, list[tuple[int, bytes, bool]]] = {}
    out: dict[tuple[int, int | None], str] = {}
    for c in cmds:
        if c.disabled:
            continue
        size = _is_array_object(c.index)
        if c.ccs == 1 and size:
            arrays.setdefault(c.index, []).append((c.subindex, c.data, c.complete_access))
        else:
            out[(c.index, c.subindex)] = coe_words(c)
    for index, writes in arrays.items():
        size = _is_array_object(index)
        count, entries = array_downloads(writes, size)
        if count is None:
            held = [f":{k:02X} {_entry(index, v)}" for k, v in sorted(entries.items())]
        else:
            held = [_entry(index, entries.get(k, 0)) for k in range(1, count + 1)]
        out[(index, None)] = f"SDO 0x{index:04X} = {count if count is not None else '?'}" \
            + (": " + ", ".join(held) if held else "")
    return out


def _entry(index: int, value: int) -> str:
    return f"0x{value:04X}" if _is_array_object(index) == 2 else mapping_entry(value)


_RECORD = re.compile(r"^(?:set|clear) ((?:sm|fmmu) \d+)")
_CLEARED = re.compile(r"^clear (sm|fmmu) (\d+)-(\d+)$")


def _record_words(words: str) -> list[str]:
    """The words of each SyncManager or FMMU record a command writes (``clear fmmu 0-15``
    is sixteen), or the command's words."""
    out = []
    for part in words.split("; "):
        cleared = _CLEARED.match(part)
        if cleared:
            kind, first, last = cleared.group(1), int(cleared.group(2)), int(cleared.group(3))
            out += [f"clear {kind} {n}" for n in range(first, last + 1)]
        else:
            out.append(part)
    return out


def _register_state(cmds: list[InitCmd], eoe: list[EoeInitCmd | FoeInitCmd],
                    t: Transition) -> dict[str, Counter[str]]:
    """A transition's register (and EoE and FoE) commands in words, by the register they
    address."""
    out: dict[str, Counter[str]] = {}
    for c in cmds:
        if t not in c.transitions:
            continue
        where = f"0x{c.ado:04X}" if c.ado is not None else \
            f"0x{c.addr:08X}" if c.addr is not None else command_name(c.cmd)
        # One write of several SyncManagers or FMMUs (TwinCAT's SM0+SM1 in 16 bytes) is
        # one change per record, as two writes of one record each are.
        for part in _record_words(init_cmd_words(c)):
            record = _RECORD.match(part)
            out.setdefault(record.group(1) if record else where, Counter())[part] += 1
    for e in eoe:
        if t in e.transitions and not e.disabled:
            if isinstance(e, FoeInitCmd):
                out.setdefault("FoE", Counter())[foe_words(e)] += 1
            else:
                out.setdefault("EoE", Counter())[eoe_words(e)] += 1
    return out


def _register_changes(name: str | None, prefix: str, a: list[InitCmd],
                      eoe_a: list[EoeInitCmd | FoeInitCmd], b: list[InitCmd],
                      eoe_b: list[EoeInitCmd | FoeInitCmd], t: Transition) -> list[Change]:
    out: list[Change] = []
    ra, rb = _register_state(a, eoe_a, t), _register_state(b, eoe_b, t)
    for where in sorted(set(ra) | set(rb)):
        old, new = ra.get(where, Counter()), rb.get(where, Counter())
        gone, came = sorted((old - new).elements()), sorted((new - old).elements())
        what = prefix + where
        for o, n in zip(gone, came):
            out.append(Change("initcmd-changed", name, what, o, n, t.value))
        for o in gone[len(came):]:
            out.append(Change("initcmd-removed", name, what, old=o, transition=t.value))
        for n in came[len(gone):]:
            out.append(Change("initcmd-added", name, what, new=n, transition=t.value))
    return out


def _master_init_cmds(a: NetworkPlan, b: NetworkPlan) -> list[Change]:
    """The master's own InitCmds (``Config/Master/InitCmds``: broadcasts before or after
    the slaves' commands)."""
    return [c for t in Transition for c in _register_changes(
        None, "master ", a.master.init_cmds, [], b.master.init_cmds, [], t)]


def _eoe_foe(slave: SlavePlan) -> list[EoeInitCmd | FoeInitCmd]:
    """The slave's EoE and FoE InitCmds: compared in words like its register commands."""
    if slave.mailbox is None:
        return []
    return [*slave.mailbox.eoe_init_cmds, *slave.mailbox.foe_init_cmds]


def _init_cmds(name: str, a: SlavePlan, b: SlavePlan) -> list[Change]:
    out: list[Change] = []
    for t in Transition:
        out += _register_changes(name, "", a.init_cmds, _eoe_foe(a), b.init_cmds,
                                 _eoe_foe(b), t)
        ca = _coe_state(c for c in (a.mailbox.coe_init_cmds if a.mailbox else [])
                        if t in c.transitions)
        cb = _coe_state(c for c in (b.mailbox.coe_init_cmds if b.mailbox else [])
                        if t in c.transitions)
        for key in sorted(set(ca) | set(cb), key=lambda k: (k[0], -1 if k[1] is None
                                                            else k[1])):
            what = f"0x{key[0]:04X}" + ("" if key[1] is None else f":{key[1]:02X}")
            if key not in cb:
                out.append(Change("initcmd-removed", name, what, old=ca[key],
                                  transition=t.value))
            elif key not in ca:
                out.append(Change("initcmd-added", name, what, new=cb[key],
                                  transition=t.value))
            elif ca[key] != cb[key]:
                out.append(Change("initcmd-changed", name, what, ca[key], cb[key], t.value))
        out += _soe_changes(name, a, b, t)
    return out


def _soe_state(s: SlavePlan, t: Transition) -> dict[tuple[int, int], str]:
    """What one transition's SoE writes leave in the drives: each (drive, IDN) by its last
    write, in words."""
    cmds: list[SoeInitCmd] = s.mailbox.soe_init_cmds if s.mailbox else []
    return {(c.drive_no, c.idn): soe_words(c) for c in cmds
            if t in c.transitions and not c.disabled}


def _soe_changes(name: str, a: SlavePlan, b: SlavePlan, t: Transition) -> list[Change]:
    out: list[Change] = []
    sa, sb = _soe_state(a, t), _soe_state(b, t)
    for key in sorted(set(sa) | set(sb)):
        what = f"SoE {idn_text(key[1])} (drive {key[0]})"
        if key not in sb:
            out.append(Change("initcmd-removed", name, what, old=sa[key], transition=t.value))
        elif key not in sa:
            out.append(Change("initcmd-added", name, what, new=sb[key], transition=t.value))
        elif sa[key] != sb[key]:
            out.append(Change("initcmd-changed", name, what, sa[key], sb[key], t.value))
    return out


def _dc(name: str, a: SlavePlan, b: SlavePlan) -> list[Change]:
    def spell(s: SlavePlan) -> str:
        if s.dc is None:
            return "none"
        d = s.dc
        return (f"{'reference clock, ' if d.reference_clock else ''}cycle {d.cycle_time0} ns"
                f"{f' + {d.cycle_time1} ns' if d.cycle_time1 else ''}, shift {d.shift_time} ns")
    return [] if spell(a) == spell(b) else [Change("dc", name, "DC", spell(a), spell(b))]


_ONE_BIT = frozenset({"BOOL", "BIT", "BIT1"})


def _type(v: Variable) -> str | None:
    """A variable's type as compared: canonical spelling (``esi/datatypes.py``), and one
    bit spelled ``BIT`` (TwinCAT) or ``BOOL`` (EC-Engineer, ecatcfg) counts as the same."""
    if v.data_type is None:
        return None
    name = canonical(v.data_type) or v.data_type.strip()
    return "BOOL" if v.bit_size == 1 and name in _ONE_BIT else name


def _offset(v: Variable) -> str:
    return f"{v.bit_offs // 8}.{v.bit_offs % 8}"


def _shift(bits: int) -> str:
    """A move in the process image, in bytes and bits: ``+56 bytes``, ``-3 bits``."""
    sign, size = ("+" if bits > 0 else "-"), abs(bits)
    parts = [f"{size // 8} byte{'s' * (size // 8 != 1)}"] if size // 8 else []
    parts += [f"{size % 8} bit{'s' * (size % 8 != 1)}"] if size % 8 else []
    return sign + " ".join(parts)


def _owners(a: NetworkPlan, b: NetworkPlan) -> list[str]:
    """Slave names, longest first: a variable belongs to the slave whose name it starts with
    followed by a dot (``Term 2 (EL2008).Channel 1.Output``), as TwinCAT, EC-Engineer and
    compile name them."""
    names = {s.name for plan in (a, b) for s in plan.in_file_order()}
    return sorted(names, key=len, reverse=True)


def _owner(name: str, owners: list[str]) -> str | None:
    return next((s for s in owners if name.startswith(s + ".")), None)


Move = tuple[str, Variable, Variable]


def _moves(direction: str, moved: list[Move], common: list[str],
           owners: list[str]) -> list[Change]:
    """The moved variables of one direction, summarised where they moved together.

    A shift of the whole image (a slave added in front, another tool's image base) moves
    hundreds of variables by one amount: that is one ``image-moved`` line, saying how many
    of the variables both files have moved by how much; a slave whose every variable moved
    by one amount is one ``variables-moved`` line.  What moved otherwise follows, a
    ``variable-moved`` line each: the differences a reader must look at."""
    out: list[Change] = []

    def shift(m: Move) -> int:
        return m[2].bit_offs - m[1].bit_offs

    rest = moved
    if moved:
        delta, count = Counter(shift(m) for m in moved).most_common(1)[0]
        if count >= 2 and 2 * count > len(common):
            what = (f"{direction}: all {count} variables" if count == len(common)
                    else f"{direction}: {count} of {len(common)} variables")
            out.append(Change("image-moved", None, what, new=f"moved by {_shift(delta)}"))
            rest = [m for m in moved if shift(m) != delta]
    per_slave = Counter(_owner(name, owners) for name in common)
    groups: dict[str | None, list[Move]] = {}
    for m in rest:
        groups.setdefault(_owner(m[0], owners), []).append(m)
    summarised = {slave for slave, ms in groups.items()
                  if slave is not None and len(ms) >= 2 and len(ms) == per_slave[slave]
                  and len({shift(m) for m in ms}) == 1}
    for slave in sorted(summarised, key=lambda s: [m[0] for m in rest].index(groups[s][0][0])):
        ms = groups[slave]
        out.append(Change("variables-moved", slave, f"{direction}: all {len(ms)} variables",
                          new=f"moved by {_shift(shift(ms[0]))}"))
    for name, o, v in rest:
        if _owner(name, owners) not in summarised:
            out.append(Change("variable-moved", None, f"{direction} {name}",
                              _offset(o), _offset(v)))
    return out


def _variables(a: NetworkPlan, b: NetworkPlan) -> list[Change]:
    out: list[Change] = []
    owners = _owners(a, b)
    for direction, va, vb in (("in", a.process_image.inputs, b.process_image.inputs),
                              ("out", a.process_image.outputs, b.process_image.outputs)):
        old, new = {v.name: v for v in va}, {v.name: v for v in vb}
        for name, v in old.items():
            if name not in new:
                out.append(Change("variable-removed", None, f"{direction} {name}",
                                  old=_offset(v)))
        moved: list[Move] = []
        changed: list[Change] = []
        for name, v in new.items():
            if name not in old:
                out.append(Change("variable-added", None, f"{direction} {name}",
                                  new=_offset(v)))
                continue
            o = old[name]
            if o.bit_offs != v.bit_offs:
                moved.append((name, o, v))
            if (o.bit_size, _type(o)) != (v.bit_size, _type(v)):
                changed.append(Change("variable-changed", None, f"{direction} {name}",
                                      f"{o.bit_size} bit {o.data_type}",
                                      f"{v.bit_size} bit {v.data_type}"))
        common = [name for name in new if name in old]
        out += _moves(direction, moved, common, owners) + changed
    return out


def _frames(a: NetworkPlan, b: NetworkPlan) -> list[Change]:
    out: list[Change] = []
    ca = ", ".join("none" if c.cycle_time is None else str(c.cycle_time) for c in a.cyclic)
    cb = ", ".join("none" if c.cycle_time is None else str(c.cycle_time) for c in b.cyclic)
    if ca != cb:
        out.append(Change("cycle-time", None, "cycle time (us)", ca or "none", cb or "none"))

    def logical(plan: NetworkPlan) -> list[str]:
        """The process-data commands (not the mailbox-state read: a tool's polling)."""
        states = plan.master.mailbox_states
        skip = range(states[0], states[0] + max(states[1], 1)) if states else range(0)
        return [f"{command_name(c.cmd)} len {c.length} wkc {c.cnt}"
                for cyc in plan.cyclic for f in cyc.frames for c in f.cmds
                if c.cmd in LOGICAL_CMDS and c.addr not in skip]
    la, lb = logical(a), logical(b)
    if la != lb:
        out.append(Change("frames", None, "process-data commands",
                          "; ".join(la) or "none", "; ".join(lb) or "none"))
    wa, wb = copies_in_words(a), copies_in_words(b)
    if wa != wb:
        out.append(Change("copies", None, "slave-to-slave copies",
                          "; ".join(wa) or "none", "; ".join(wb) or "none"))
    return out


def copies_in_words(plan: NetworkPlan) -> list[str]:
    """Every CopyInfo of the plan in ENI order, in words (:func:`copy_words`)."""
    image = plan.process_image
    return [copy_words(copy, image.inputs, image.outputs)
            for cyc in plan.cyclic for f in cyc.frames for c in f.cmds for copy in c.copy_infos]


def _unsupported(a: NetworkPlan, b: NetworkPlan) -> list[Change]:
    """What the reader kept but apply does not do (``eni/contents.py``: VoE InitCmds,
    encrypted FMMU settings, ...) is compared by what it is, so nothing in a file goes
    uncompared without a word."""
    def parts(plan: NetworkPlan) -> Counter[tuple[str | None, str, str, int]]:
        return Counter((u.slave, u.element, u.what, u.commands) for u in plan.unsupported)
    old, new = parts(a), parts(b)
    return [Change("unsupported-removed", slave, f"{element}: {what}",
                   old=f"{commands} command(s)") for slave, element, what, commands
            in sorted((old - new).elements(), key=str)] + \
        [Change("unsupported-added", slave, f"{element}: {what}", new=f"{commands} command(s)")
         for slave, element, what, commands in sorted((new - old).elements(), key=str)]


def diff(a: NetworkPlan, b: NetworkPlan) -> list[Change]:
    """Every difference between ``a`` (old) and ``b`` (new) the module docstring lists."""
    out = _slaves(a, b) + _master_init_cmds(a, b)
    old = {s.name: s for s in a.slaves}
    for s in b.slaves:
        o = old.get(s.name)
        if o is None:
            continue
        out += _process_data(s.name, o, s)
        out += _init_cmds(s.name, o, s)
        out += _dc(s.name, o, s)
    return out + _variables(a, b) + _frames(a, b) + _unsupported(a, b)
