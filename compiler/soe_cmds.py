"""A slave's SoE InitCmds: the ESI's ``Mailbox/SoE/InitCmd`` and the topology's ``soe:``.

Both become the ENI's ``Mailbox/SoE/InitCmds`` (ETG.2100): write requests (OpCode 3) of
the value element (0x40) of one IDN of one drive, in a transition the schema allows
(``esi/idn.py`` ``ENI_TRANSITIONS``).  The ESI's come first, in file order, those the ESI
gives for INIT->PREOP moved to the head of PREOP->SAFEOP (``esi/idn.py``
``eni_transition`` says why); then the topology's.  A topology entry for an IDN and drive
the ESI already writes in the same transition replaces that write in place and keeps its
comment, as a topology SDO replaces the ESI's CoE InitCmd of the same object
(``compiler/resolve.py``); any other entry is added after the ESI's.

Checked here, each error at its line: an ESI InitCmd without IDN or Data, for a drive the
device does not have (``@Chn`` against ``@ChannelCount``, lint ESI216 and ESI217), or in a
transition no ENI can carry; a topology entry for a device without SoE, a drive it does
not have, a transition the ENI schema does not allow, a value the IDN's type cannot hold
or an IDN whose type is unknown without 'type' or 'data'.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from ecatcfg.compiler.topology import Soe
from ecatcfg.eni.plan import SoeInitCmd
from ecatcfg.esc import Transition
from ecatcfg.esi import datatypes
from ecatcfg.esi.idn import ENI_TRANSITIONS, STANDARD_IDNS, eni_transition, idn_text, standard
from ecatcfg.esi.model import Device, Module
from ecatcfg.esi.model import SoeInitCmd as EsiSoeInitCmd
from ecatcfg.record import replace


class Errors(Protocol):
    def add(self, message: str, *path: str | int) -> None: ...


def drive_count(device: Device) -> int:
    """The drives behind the slave (``SoeSettings.drives``; 1 without ``Mailbox/SoE``)."""
    soe = device.mailbox.soe if device.mailbox else None
    return soe.drives if soe is not None else 1


def esi_problem(cmd: EsiSoeInitCmd, device: Device) -> str:
    """Why an ESI SoE InitCmd cannot be written to an ENI ("" when it can)."""
    if cmd.idn is None:
        return "has no IDN"
    if cmd.data is None:
        return f"writes {idn_text(cmd.idn)} but has no Data"
    count = drive_count(device)
    if not 0 <= cmd.channel < count:
        return (f"writes {idn_text(cmd.idn)} of drive {cmd.channel} (Chn), but the device "
                f"has {count} drive{'s' if count != 1 else ''} (ChannelCount)")
    bad = [t for t in cmd.transitions if eni_transition(t) is None]
    if bad or not cmd.transitions:
        return (f"writes {idn_text(cmd.idn)} in transition {', '.join(bad) or '(none)'}: "
                "an SoE write needs the mailbox, so one of IP (sent as PS), "
                + ", ".join(t.value for t in ENI_TRANSITIONS))
    return ""


def _from_esi(cmd: EsiSoeInitCmd) -> SoeInitCmd:
    assert cmd.idn is not None and cmd.data is not None
    transitions: list[Transition] = []
    for t in cmd.transitions:
        eni = eni_transition(t)
        if eni is not None and eni not in transitions:
            transitions.append(eni)
    return SoeInitCmd(transitions, cmd.comment or _comment(cmd.idn), cmd.idn, cmd.data,
                      drive_no=cmd.channel)


def _comment(idn: int) -> str:
    known = standard(idn)
    return f"{idn_text(idn)} {known.name}" if known else f"write {idn_text(idn)}"


def init_cmds(name: str, device: Device, entries: list[Soe], slave: tuple[str | int, ...],
              errors: Errors, modules: Sequence[Module] = ()) -> list[SoeInitCmd]:
    """The slave's SoE InitCmds; problems go to ``errors`` at ``slave`` (the slave's place
    in the topology) and its keys.  ETG.2000 gives modules no SoE (``ModuleType/Mailbox``
    has CoE only), so a plugged module's SoE InitCmds are an error, never left out."""
    for module in modules:
        extra = module.mailbox.soe if module.mailbox else None
        if extra is not None and extra.init_cmds:
            errors.add(f"slave {name!r}: the module at {module.source} has SoE InitCmds ("
                       f"{extra.init_cmds[0].source}), which ETG.2000 gives devices only; "
                       "ecatcfg would not send them", *slave, "modules")
    soe = device.mailbox.soe if device.mailbox else None
    given = soe.init_cmds if soe else []
    cmds: list[SoeInitCmd] = []
    early: list[SoeInitCmd] = []          # the ESI's INIT->PREOP writes: first in PS
    for c in given:
        problem = esi_problem(c, device)
        if problem:
            errors.add(f"slave {name!r}: the SoE InitCmd at {c.source} {problem}; it cannot "
                       "be written to the ENI", *slave, "device")
            continue
        (early if "IP" in c.transitions else cmds).append(_from_esi(c))
    cmds = early + cmds
    for i, entry in enumerate(entries):
        where = (*slave, "soe", i)
        cmd = _from_topology(name, device, entry, where, errors)
        if cmd is not None:
            _place(cmds, cmd)
    return cmds


def _from_topology(name: str, device: Device, entry: Soe, where: tuple[str | int, ...],
                   errors: Errors) -> SoeInitCmd | None:
    shown = f"{idn_text(entry.idn)} (drive {entry.drive})"
    mailbox = device.mailbox
    if mailbox is None or "SoE" not in mailbox.protocols:
        protocols = ", ".join(mailbox.protocols) if mailbox and mailbox.protocols else \
            "no mailbox protocol"
        errors.add(f"slave {name!r}: {device.type_name} has no SoE mailbox (its ESI, "
                   f"{device.source}, lists {protocols}), so {shown} cannot be written",
                   *where)
        return None
    if entry.transition not in ENI_TRANSITIONS:
        errors.add(f"slave {name!r}: {shown}: an SoE write cannot run in transition "
                   f"{entry.transition.value} (ETG.2100 allows "
                   + ", ".join(t.value for t in ENI_TRANSITIONS) + "; PS reaches the drive "
                   "in PREOP)", *where, "transition")
        return None
    count = drive_count(device)
    if entry.drive >= count:
        errors.add(f"slave {name!r}: {shown}: {device.type_name} has {count} "
                   f"drive{'s' if count != 1 else ''} (ESI SoE ChannelCount), numbered from 0",
                   *where, "drive")
        return None
    data = _data(name, entry, shown, where, errors)
    if data is None:
        return None
    return SoeInitCmd([entry.transition], entry.comment or _comment(entry.idn), entry.idn,
                      data, drive_no=entry.drive)


def _data(name: str, entry: Soe, shown: str, where: tuple[str | int, ...],
          errors: Errors) -> bytes | None:
    if entry.data is not None:
        return bytes.fromhex(entry.data.replace(" ", ""))
    assert entry.value is not None          # Soe's validator: one of value and data
    known = standard(entry.idn)
    type_name = entry.type or (known.type if known else None)
    if type_name is None:
        known_idns = ", ".join(idn_text(idn) for idn in sorted(STANDARD_IDNS))
        errors.add(f"slave {name!r}: {shown} is not among the IDNs ecatcfg knows the type "
                   f"of ({known_idns}); give 'type' (e.g. UINT) or 'data'", *where)
        return None
    if known is not None and entry.type is not None:
        given, want = datatypes.bit_size(entry.type), datatypes.bit_size(known.type)
        if given is None or given != want:
            errors.add(f"slave {name!r}: {shown} ({known.name}) is {want} bits "
                       f"({known.type}), but 'type' {entry.type} is "
                       f"{given if given is not None else 'of unknown'} bits", *where, "type")
            return None
    try:
        return datatypes.encode(entry.value, type_name)
    except datatypes.ValueTypeError as exc:
        errors.add(f"slave {name!r}: {shown}: {exc}", *where, "value")
        return None


def _place(cmds: list[SoeInitCmd], cmd: SoeInitCmd) -> None:
    """A topology write replaces the ESI's write of the same IDN and drive in the same
    transition, in place and with its comment; others are added at the end."""
    t = cmd.transitions[0]
    for n, esi in enumerate(cmds):
        if (esi.idn, esi.drive_no) == (cmd.idn, cmd.drive_no) and t in esi.transitions:
            replaced = replace(cmd, comment=esi.comment)
            if esi.transitions == [t]:
                cmds[n] = replaced
            else:
                cmds[n] = replace(esi, transitions=[x for x in esi.transitions if x != t])
                cmds.insert(n + 1, replaced)
            return
    cmds.append(cmd)
