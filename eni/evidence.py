"""What an ENI says of a slave, as evidence for choosing among ESI descriptions of its identity.

Where several ESI files describe one vendor, product and revision differently
(``esi/evidence.py``), the ENI itself shows which description its configurator used: it
lists the device's PDOs with their entries, its SyncManagers and its mailbox.  A candidate
Device agrees with an ENI slave (:class:`EniSlaveEvidence`) when:

- every PDO the ENI lists is one of the Device's, of the same direction, with the same
  entries (index, subindex, bit length, in order) -- unless the ENI writes that PDO's
  mapping object by CoE and the Device's PDO is not ``Fixed`` (then the mapping is the
  ENI's to give, ETG.1000.6 5.6.7.4);
- for each process-data SyncManager whose assignment object (0x1C10 + SM) the ENI does not
  write, the PDOs the ENI assigns to it are the Device's default assignment for it (its
  PDOs with ``Sm``, not ``Virtual``: what the device uses when nobody writes 0x1C1x;
  ETG.2000 ``RxPdo/TxPdo@Sm``).  A configurator lists every PDO of a description, so a PDO
  the Device assigns by default that the ENI does not have at all is a disagreement too;
- every SyncManager of the ENI's process data has the Device's number, type and start
  address;
- the ENI's mailbox (none, or SM0/SM1 start addresses and lengths, protocols) is one the
  Device has: the starts are its MBoxOut/MBoxIn SyncManagers', the lengths within their
  MinSize..MaxSize (or the size :attr:`SyncManager.mailbox_size` gives), the protocols
  among its own.

A modular device's PDOs come from the modules plugged (the ENI's 0xF030 list), not from the
Device: for a Device with slots only the SyncManagers and the mailbox are compared.
"""

from __future__ import annotations

from dataclasses import dataclass

from ecatcfg.esc import SM_PDO_ASSIGN
from ecatcfg.eni.plan import NetworkPlan, PdoDesc, SlavePlan
from ecatcfg.esi.evidence import Evidence, all_of, indices_said
from ecatcfg.esi.model import Device, Pdo
from ecatcfg.esi.sii import assigned_pdos


@dataclass(frozen=True, slots=True)
class EniSlaveEvidence:
    """An ENI slave's PDOs, SyncManagers and mailbox (see the module docstring)."""

    slave: SlavePlan
    shown: str                      # the ENI, as messages name it

    @property
    def what(self) -> str:
        return f"the ENI's slave {self.slave.name!r} ({self.shown})"

    def disagreements(self, device: Device) -> list[str]:
        out: list[str] = []
        if device.slots is None:
            out += _pdos(self.slave, device)
        out += _sms(self.slave, device)
        out += _mailbox(self.slave, device)
        return out


def evidence_by_identity(plan: NetworkPlan, shown: str
                         ) -> dict[tuple[int, int, int], Evidence]:
    """The evidence of each identity an ENI's slaves have (every slave of it at once)."""
    slaves: dict[tuple[int, int, int], list[SlavePlan]] = {}
    for s in plan.slaves:
        slaves.setdefault((s.vendor_id, s.product_code, s.revision), []).append(s)
    out: dict[tuple[int, int, int], Evidence] = {}
    for identity, group in slaves.items():
        found = all_of(EniSlaveEvidence(s, shown) for s in group)
        if found is not None:
            out[identity] = found
    return out


def _name(direction: str) -> str:
    return "RxPdo" if direction == "rx" else "TxPdo"


def _written(slave: SlavePlan) -> set[int]:
    """The objects the ENI's CoE InitCmds download."""
    cmds = slave.mailbox.coe_init_cmds if slave.mailbox else []
    return {c.index for c in cmds if c.ccs == 1 and not c.disabled}


def _pdos(slave: SlavePlan, device: Device) -> list[str]:
    pd = slave.process_data
    listed: list[PdoDesc] = pd.pdos if pd is not None else []
    written = _written(slave)
    own: dict[tuple[str, int], Pdo] = {(p.direction, p.index): p for p in device.pdos
                                       if p.index is not None}
    out: list[str] = []
    missing = [p for p in listed if (p.direction, p.index) not in own]
    for direction in ("tx", "rx"):
        gone = [p.index for p in missing if p.direction == direction]
        if gone:
            out.append(f"the ENI's {_name(direction)} {indices_said(gone)} not in it")
    changed = []
    for p in listed:
        mine = own.get((p.direction, p.index))
        if mine is None or (p.index in written and not mine.fixed):
            continue
        if [(e.index, e.subindex, e.bit_len) for e in p.entries] != \
                [(e.index, e.subindex, e.bit_len) for e in mine.entries]:
            changed.append(p)
    for direction in ("tx", "rx"):
        diff = [p.index for p in changed if p.direction == direction]
        if diff:
            out.append(f"{_name(direction)} {indices_said(diff)} entries differ from the ENI's")
    # The default assignment, where the ENI does not write the assignment object.  What
    # the ENI assigns to each SM: the SM's Pdo list, else the PDOs whose Sm names it (the
    # one reading of it, eni/check/network.py; imported here, not at the top: the check
    # package imports this module).
    from ecatcfg.eni.check.network import sm_pdos
    in_eni = {p.index for p in listed}
    eni_assigned: dict[int, set[int]] = {}
    for p in listed:
        if p.sm is not None:
            eni_assigned.setdefault(p.sm, set()).add(p.index)
    for sm in pd.sms if pd is not None else []:
        eni_assigned[sm.number] = {p.index for p in sm_pdos(slave, sm)}
    default: dict[int, set[int]] = {}
    for mine in assigned_pdos(device.pdos):    # each has an Sm and an index
        default.setdefault(mine.sm or 0, set()).add(mine.index or 0)
    for number in sorted(set(default) | set(eni_assigned)):
        if SM_PDO_ASSIGN + number in written:
            continue
        ours, theirs = default.get(number, set()), eni_assigned.get(number, set())
        unlisted = sorted(i for i in ours - theirs if i not in in_eni)
        unassigned = sorted(i for i in ours - theirs if i in in_eni)
        # (a PDO the Device lacks altogether is said above)
        extra = sorted(i for i in theirs - ours if any((d, i) in own for d in ("rx", "tx")))
        if unlisted:
            out.append(f"PDO {indices_said(unlisted)} (assigned to SM{number} by default) not "
                       "in the ENI")
        if unassigned:
            out.append(f"PDO {indices_said(unassigned)} assigned to SM{number} by default, not "
                       "by the ENI (which writes no 0x%04X)" % (SM_PDO_ASSIGN + number))
        if extra:
            out.append(f"the ENI assigns PDO {indices_said(extra)} to SM{number}, not assigned "
                       "there by default (and writes no 0x%04X)" % (SM_PDO_ASSIGN + number))
    return out


def _sms(slave: SlavePlan, device: Device) -> list[str]:
    out: list[str] = []
    for sm in slave.process_data.sms if slave.process_data is not None else []:
        mine = device.sms[sm.number] if sm.number < len(device.sms) else None
        if mine is None:
            out.append(f"the ENI's SM{sm.number} ({sm.type}) is not one of its "
                       f"{len(device.sms)} SyncManagers")
        elif mine.type != sm.type or (mine.start_address is not None
                                      and mine.start_address != sm.start_address):
            out.append(f"SM{sm.number} is {mine.type} at 0x{mine.start_address or 0:04X}, "
                       f"the ENI's {sm.type} at 0x{sm.start_address:04X}")
    return out


def _mailbox(slave: SlavePlan, device: Device) -> list[str]:
    mb = slave.mailbox
    boxes = [sm for sm in device.sms[:2] if sm.is_mailbox]
    if mb is None:
        return ["it has a mailbox, the ENI's slave none"] if boxes else []
    if len(boxes) < 2:
        return ["the ENI's slave has a mailbox, it none (no MBoxOut/MBoxIn SM0/SM1)"]
    out: list[str] = []
    for area, name, sm in ((mb.send, "Send", boxes[0]), (mb.recv, "Recv", boxes[1])):
        lo = sm.min_size if sm.min_size is not None else sm.mailbox_size
        hi = sm.max_size if sm.max_size is not None else sm.mailbox_size
        if not lo <= area.length <= hi and area.length != sm.mailbox_size:
            out.append(f"Mailbox/{name} length {area.length}, SM{sm.number} takes "
                       + (f"{lo}..{hi}" if lo != hi else f"{lo}"))
        if sm.start_address is not None and area.start != sm.start_address:
            out.append(f"Mailbox/{name} start 0x{area.start:04X}, SM{sm.number}'s "
                       f"0x{sm.start_address:04X}")
    own = set(device.mailbox.protocols) if device.mailbox is not None else set()
    lacking = [p for p in mb.protocols if p not in own]
    if lacking:
        out.append(f"the ENI's mailbox protocol {'/'.join(lacking)} not among its "
                   f"{'/'.join(sorted(own)) or 'none'}")
    return out

